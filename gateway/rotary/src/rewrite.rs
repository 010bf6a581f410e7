//! Rewriting a 5-axis program (X Y Z A C, absolute, millimetres) so that every point
//! lands where it was programmed on the table with location errors: each programmed
//! point replaced by [`RotaryMachine::command_for`], feed moves split where the straight
//! line between two commands would leave the compensated path.
//!
//! The controller interpolates the five axes linearly between two commands, and the
//! programmed path is that same interpolation of the nominal axes; the commands are a
//! smooth but not linear function of the nominal axes, so a G1 is cut in halves until,
//! at the middle of every piece, the mean of the piece's two commands is within the
//! tolerances of the command for the nominal middle (`tolerance_mm` on X Y Z,
//! `tolerance_deg` on A C). Rapids (G0) get their end corrected only. The block keeps
//! its other words and comments; the axis words are all five written (4 decimals in
//! mm, 5 in degrees); the extra pieces follow it as `G1` lines.
//!
//! Every line is first read as the controller reads it, by the same check the 3-axis
//! rewrite uses ([`rewrite::dialect`], GRBL's interpreter on six axes X Y Z A B C):
//! what it would refuse (unknown or repeated words, `X1e308`, a feed motion without a
//! feed such as `F0` or a G93 block without F, an overlong line) is refused here first,
//! with GRBL's error code. Inverse-time feed (G93) moves are refused, since the pieces
//! of a split move would each need their own F.
//!
//! Refused, naming the line: inches (G20), incremental moves (G91), arcs (G2/G3),
//! G53/G28/G30/G92/G38.x (positions this rewrite cannot follow), an axis letter the
//! table does not have (B U V W), a move before all five axes have been named, and a
//! command past the axis limits.

use crate::machine::{Axes, RotaryError, RotaryMachine};
use protocol::grbl::gcode::Interpreter;
use protocol::nc::{self, Block};

/// Rewrite settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RewriteOptions {
    pub tolerance_mm: f64,
    pub tolerance_deg: f64,
    /// At most 2^max_depth pieces per move.
    pub max_depth: u32,
    /// The largest X Y Z correction (command minus programmed point) a move may get, mm;
    /// beyond it the line is refused (the live pass-through bounds it; infinite for a
    /// whole-program rewrite, whose output the operator reads before running it).
    pub max_correction_mm: f64,
}

impl Default for RewriteOptions {
    fn default() -> Self {
        Self {
            tolerance_mm: 0.0005,
            tolerance_deg: 0.00002,
            max_depth: 10,
            max_correction_mm: f64::INFINITY,
        }
    }
}

/// One written point: the programmed (nominal) axes and the command written for them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WrittenPoint {
    pub line: usize,
    pub nominal: Axes,
    pub command: Axes,
    pub feed_move: bool,
}

/// What a rewrite did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RewriteReport {
    pub lines: usize,
    pub moves: usize,
    pub pieces_added: usize,
    /// Every point written, in order (for checks against a truth).
    pub points: Vec<WrittenPoint>,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RewriteError {
    #[error("{0}")]
    Parse(String),
    #[error("line {line}: {why}")]
    Refused { line: usize, why: String },
}

fn refuse(line: usize, why: impl Into<String>) -> RewriteError {
    RewriteError::Refused {
        line,
        why: why.into(),
    }
}

fn lerp(a: &Axes, b: &Axes, t: f64) -> Axes {
    Axes::new(
        a.x + (b.x - a.x) * t,
        a.y + (b.y - a.y) * t,
        a.z + (b.z - a.z) * t,
        a.a + (b.a - a.a) * t,
        a.c + (b.c - a.c) * t,
    )
}

/// The pieces of a feed move from `n0` (command `c0`) to `n1` (command `c1`): the
/// nominal and command of each piece's end, in order, the last one `n1`.
#[allow(clippy::too_many_arguments)]
fn split(
    model: &RotaryMachine,
    opts: &RewriteOptions,
    line: usize,
    n0: &Axes,
    c0: &Axes,
    n1: &Axes,
    c1: &Axes,
    depth: u32,
    out: &mut Vec<(Axes, Axes)>,
) -> Result<(), RewriteError> {
    let nm = lerp(n0, n1, 0.5);
    let cm = model
        .command_for(&nm)
        .map_err(|e| refuse(line, format!("inside the move: {e}")))?;
    let straight = lerp(c0, c1, 0.5);
    let off_mm =
        ((cm.x - straight.x).powi(2) + (cm.y - straight.y).powi(2) + (cm.z - straight.z).powi(2))
            .sqrt();
    let off_deg = (cm.a - straight.a).abs().max((cm.c - straight.c).abs());
    if (off_mm <= opts.tolerance_mm && off_deg <= opts.tolerance_deg) || depth >= opts.max_depth {
        out.push((*n1, *c1));
        return Ok(());
    }
    split(model, opts, line, n0, c0, &nm, &cm, depth + 1, out)?;
    split(model, opts, line, &nm, &cm, n1, c1, depth + 1, out)
}

fn set_axes(block: &mut Block, c: &Axes) -> Result<(), RewriteError> {
    for (letter, v, d) in [
        ('X', c.x, 4),
        ('Y', c.y, 4),
        ('Z', c.z, 4),
        ('A', c.a, 5),
        ('C', c.c, 5),
    ] {
        block
            .set_word(letter, v, d)
            .map_err(|e| RewriteError::Parse(e.to_string()))?;
    }
    Ok(())
}

/// The rewrite as a state machine, one block at a time: what a whole-program rewrite
/// and the live pass-through share. It follows the five axes' programmed positions and
/// the motion mode; the controller's own state (from its `$G` and `$#` replies) can be
/// given, so that lines it would read in inches, incrementally or in a shifted work
/// frame are refused rather than corrected on a guess.
pub struct RotaryRewriter<'a> {
    model: &'a RotaryMachine,
    opts: RewriteOptions,
    known: [Option<f64>; 5],
    /// 0 (G0) or 1 (G1); G0 until told otherwise.
    motion: u8,
    last: Option<(Axes, Axes)>,
    /// The controller reads in inches / incrementally (from its `$G`), until a line
    /// sets G21 / G90.
    inches: bool,
    incremental: bool,
    /// Active work coordinate system (0 = G54) and the stored offsets (X Y Z A B C as
    /// the controller reports them); the rewrite works in machine coordinates, so a
    /// non-zero active offset refuses moves.
    coord_select: usize,
    offsets: [[f64; 6]; 6],
    /// The controller's reading of every line (X Y Z A B C): the shared dialect check.
    interpreter: Interpreter<6>,
    pub report: RewriteReport,
}

impl<'a> RotaryRewriter<'a> {
    pub fn new(model: &'a RotaryMachine, opts: RewriteOptions) -> Self {
        Self {
            model,
            opts,
            known: [None; 5],
            motion: 0,
            last: None,
            inches: false,
            incremental: false,
            coord_select: 0,
            offsets: [[0.0; 6]; 6],
            interpreter: Interpreter::<6>::with_axes(),
            report: RewriteReport::default(),
        }
    }

    /// Whether all five axes' positions are known.
    pub fn position_known(&self) -> bool {
        self.known.iter().all(Option::is_some)
    }

    /// The machine is at `command` (from an idle status report): the programmed
    /// position is the one whose command it is.
    pub fn set_position(&mut self, nominal: Axes, command: Axes) {
        self.known = [
            Some(nominal.x),
            Some(nominal.y),
            Some(nominal.z),
            Some(nominal.a),
            Some(nominal.c),
        ];
        self.last = Some((nominal, command));
        self.interpreter.position = [nominal.x, nominal.y, nominal.z, nominal.a, 0.0, nominal.c];
    }

    /// The position is no longer known (a reset, a homing, a lost controller).
    pub fn forget_position(&mut self) {
        self.known = [None; 5];
        self.last = None;
    }

    /// The controller was reset: its modal state is back to G0 G54 G21 G90.
    pub fn controller_reset(&mut self) {
        self.forget_position();
        self.motion = 0;
        self.inches = false;
        self.incremental = false;
        self.coord_select = 0;
        self.interpreter.reset();
    }

    /// The controller's modal words (its `$G` reply, e.g. `G0 G54 G17 G21 G90 G94 ...`).
    pub fn sync_modal(&mut self, words: &str) {
        // A reply the dialect check cannot read leaves its state as it was.
        let _ = rewrite::dialect::sync_modal(&mut self.interpreter, words);
        for w in words.split_whitespace() {
            match w {
                "G0" => self.motion = 0,
                "G1" => self.motion = 1,
                "G20" => self.inches = true,
                "G21" => self.inches = false,
                "G90" => self.incremental = false,
                "G91" => self.incremental = true,
                _ => {
                    if let Some(n) = w.strip_prefix('G').and_then(|n| n.parse::<usize>().ok()) {
                        if (54..=59).contains(&n) {
                            self.coord_select = n - 54;
                        }
                    }
                }
            }
        }
    }

    /// One stored work offset (`k` 0 = G54), as the controller reports it.
    pub fn set_work_offset(&mut self, k: usize, values: &[f64]) {
        if let Some(o) = self.offsets.get_mut(k) {
            for (slot, v) in o.iter_mut().zip(values) {
                *slot = *v;
            }
            self.interpreter.stored[k] = *o;
            self.interpreter.coord_system =
                self.interpreter.stored[self.interpreter.modal.coord_select];
        }
    }

    /// The programmed position whose command the controller reports (the inverse of
    /// `command_for`, through the model's forward chain and the nominal inverse).
    pub fn nominal_of(&self, command: &Axes) -> Result<Axes, RotaryError> {
        let pose = self.model.forward(command);
        RotaryMachine::nominal(self.model.constants).inverse(&pose, (command.a, command.c))
    }

    /// Rewrites one block (line `line`, 1-based): the block with its axis words
    /// replaced, then the extra pieces. The block is first read as the controller reads
    /// it ([`rewrite::dialect::read_line`]); what it would refuse is refused here. On an
    /// error nothing changes.
    pub fn block(&mut self, block: Block, line: usize) -> Result<Vec<Block>, RewriteError> {
        if block.has_no_words() {
            return Ok(vec![block]);
        }
        let before = self.interpreter.clone();
        let text = block.to_string();
        let text = text.trim_end_matches(['\r', '\n']);
        let dialect = rewrite::dialect::read_line(&mut self.interpreter, text, line)
            .map_err(|e| refuse(line, e.kind.to_string()));
        let out = dialect.and_then(|_| {
            let moves = block
                .words()
                .any(|w| matches!(w.letter().to_ascii_uppercase(), 'X' | 'Y' | 'Z' | 'A' | 'C'));
            if moves && self.interpreter.modal.inverse_time {
                return Err(refuse(
                    line,
                    rewrite::RewriteErrorKind::InverseTime.to_string(),
                ));
            }
            self.block_checked(block, line)
        });
        if out.is_err() {
            self.interpreter = before;
        }
        out
    }

    fn block_checked(&mut self, block: Block, line: usize) -> Result<Vec<Block>, RewriteError> {
        let mut known = self.known;
        let mut motion = self.motion;
        let (mut inches, mut incremental, mut coord) =
            (self.inches, self.incremental, self.coord_select);
        let mut has_axis = false;
        for w in block.words() {
            let letter = w.letter().to_ascii_uppercase();
            let v = w.value();
            match letter {
                'G' => {
                    let g = (v * 10.0).round() / 10.0;
                    if g == 0.0 || g == 1.0 {
                        motion = g as u8;
                    } else if g == 2.0 || g == 3.0 {
                        return Err(refuse(line, "arcs (G2/G3) are not rewritten for 5 axes"));
                    } else if g == 20.0 {
                        return Err(refuse(line, "inches (G20): the table's model is in mm"));
                    } else if g == 21.0 {
                        inches = false;
                    } else if g == 91.0 {
                        return Err(refuse(line, "incremental moves (G91) are not rewritten"));
                    } else if g == 90.0 {
                        incremental = false;
                    } else if (54.0..=59.0).contains(&g) && g.fract() == 0.0 {
                        coord = g as usize - 54;
                    } else if [53.0, 28.0, 30.0, 92.0].contains(&g) || (38.0..39.0).contains(&g) {
                        return Err(refuse(
                            line,
                            format!("G{g}: a position this rewrite cannot follow"),
                        ));
                    }
                }
                'X' | 'Y' | 'Z' | 'A' | 'C' => {
                    has_axis = true;
                    if !v.is_finite() {
                        return Err(refuse(line, format!("{letter}: not a number")));
                    }
                    let i = "XYZAC".find(letter).unwrap_or(0);
                    known[i] = Some(v);
                }
                'B' | 'U' | 'V' | 'W' => {
                    return Err(refuse(
                        line,
                        format!("axis {letter}: this table has X Y Z A C"),
                    ))
                }
                _ => {}
            }
        }
        if !has_axis {
            (
                self.motion,
                self.inches,
                self.incremental,
                self.coord_select,
            ) = (motion, inches, incremental, coord);
            return Ok(vec![block]);
        }
        if inches || incremental {
            return Err(refuse(
                line,
                "the controller reads this move in inches or incrementally (its $G says G20 or \
                 G91): send G21 G90 first",
            ));
        }
        if self.offsets[coord].iter().any(|v| *v != 0.0) {
            return Err(refuse(
                line,
                format!(
                    "the active work offset G{} is not zero on the controller: the table's \
                     model is in machine coordinates",
                    54 + coord
                ),
            ));
        }
        let Some(nominal) = (|| {
            Some(Axes::new(
                known[0]?, known[1]?, known[2]?, known[3]?, known[4]?,
            ))
        })() else {
            let missing: String = "XYZAC"
                .chars()
                .zip(known)
                .filter(|(_, v)| v.is_none())
                .map(|(c, _)| c)
                .collect();
            return Err(refuse(
                line,
                format!("axes {missing} not known yet (name all five in the first move)"),
            ));
        };
        let command = self
            .model
            .command_for(&nominal)
            .map_err(|e: RotaryError| refuse(line, e.to_string()))?;
        let mut pieces = Vec::new();
        match (&self.last, motion) {
            (Some((n0, c0)), 1) => split(
                self.model,
                &self.opts,
                line,
                n0,
                c0,
                &nominal,
                &command,
                0,
                &mut pieces,
            )?,
            _ => pieces.push((nominal, command)),
        }
        for (n, c) in &pieces {
            let mm = ((c.x - n.x).powi(2) + (c.y - n.y).powi(2) + (c.z - n.z).powi(2)).sqrt();
            if mm > self.opts.max_correction_mm {
                return Err(refuse(
                    line,
                    format!(
                        "the correction at X{:.4} Y{:.4} Z{:.4} A{:.4} C{:.4} is {:.1} um, beyond \
                         the bound of {:.1} um: refused",
                        n.x,
                        n.y,
                        n.z,
                        n.a,
                        n.c,
                        mm * 1000.0,
                        self.opts.max_correction_mm * 1000.0
                    ),
                ));
            }
        }
        let mut first = block;
        set_axes(&mut first, &pieces[0].1)?;
        let mut out = vec![first];
        let mut points = vec![WrittenPoint {
            line,
            nominal: pieces[0].0,
            command: pieces[0].1,
            feed_move: motion == 1,
        }];
        for (n, c) in &pieces[1..] {
            let mut extra = Block::new();
            extra
                .set_word('G', 1.0, 0)
                .map_err(|e| RewriteError::Parse(e.to_string()))?;
            set_axes(&mut extra, c)?;
            out.push(extra);
            points.push(WrittenPoint {
                line,
                nominal: *n,
                command: *c,
                feed_move: true,
            });
        }
        self.report.moves += 1;
        self.report.pieces_added += pieces.len() - 1;
        self.report.points.extend(points);
        (self.known, self.motion, self.last) = (known, motion, Some((nominal, command)));
        (self.inches, self.incremental, self.coord_select) = (inches, incremental, coord);
        Ok(out)
    }
}

/// Rewrites `text` for `model` (its errors and limits); the program's start position
/// is unknown until a move names all five axes.
pub fn rewrite_program(
    text: &str,
    model: &RotaryMachine,
    opts: &RewriteOptions,
) -> Result<(String, RewriteReport), RewriteError> {
    let mut rewriter = RotaryRewriter::new(model, *opts);
    let mut out = String::with_capacity(text.len() + text.len() / 4);
    let mut lines = 0;
    for (k, (raw, ending)) in nc::split_lines(text).enumerate() {
        lines = k + 1;
        let block = Block::parse(raw, k + 1).map_err(|e| RewriteError::Parse(e.to_string()))?;
        let ending = match ending {
            nc::LineEnding::None => "\n",
            e => e.as_str(),
        };
        for b in rewriter.block(block, k + 1)? {
            out.push_str(b.to_string().trim_end_matches(['\r', '\n']));
            out.push_str(ending);
        }
    }
    if !text.ends_with(['\n', '\r']) && out.ends_with('\n') {
        out.pop();
    }
    let mut report = rewriter.report;
    report.lines = lines;
    Ok((out, report))
}

//! The Fanuc dialect (ISO code, milling): a tape for a closed controller rewritten with
//! a [`Compensation`], to be drip-fed through its tape port (`gateway dnc`).
//!
//! The compensation itself is the GRBL rewriter's ([`Rewriter`]: moves split against the
//! tolerance, arcs as chords, backlash taken up where an axis's command turns back,
//! rapids corrected at their end); this module reads the Fanuc program as the controller
//! would ([`protocol::fanuc`]), hands each move to that rewriter in machine coordinates
//! and writes the commands back as the controller reads them:
//!
//! * Every block is read by Fanuc's interpreter (decimal-point rule, G90/G91, G17-G19,
//!   G20/G21, G54-G59 with the stored offsets, G92, G10 L2, G00-G03 with R or I/J/K);
//!   what it refuses is refused naming the block (line and text).
//! * Every block written is read back by a second interpreter standing for the
//!   controller, which must put the command where the rewrite meant it (within half
//!   the least input increment): the written program is checked, not trusted.
//! * Decimal points are always written (the output does not depend on parameter
//!   3401#0), rounded to the least input increment ([`FanucOptions::program`]: IS-B,
//!   0.001 mm / 0.0001 in, by default); in incremental mode each increment is taken
//!   from the controller's position after the previous rounded block, so rounding does
//!   not accumulate. A word with more than [`MAX_DIGITS`] digits, or a block longer than
//!   [`FanucOptions::max_block_chars`], is refused naming the block.
//! * `%`, the program number `O` and the sequence numbers `N` are kept (the extra
//!   pieces of a split move carry no `N`). Comments are not kept.
//! * Arcs become `G01` chords; every motion block written says `G00` or `G01`.
//! * `M98 P..` calls are expanded: the subprogram's blocks are rewritten where they run
//!   (a subprogram called at two places needs two different corrections), between
//!   comments `(CALL O8003 1 OF 3)` and `(END O8003)`. Subprograms come after the main
//!   program's M30/M02 on the same tape (`O8003` ... `M99`), or from a second text (the
//!   controller's stored programs). `M99 P..` (return to a sequence number) is refused.
//! * `G61`/`G64` go as written, so in `G61` every piece of a split move ends at rest
//!   (slower, never off the path: how far `G64` rounds a corner is the machine's
//!   parameters', which no manual gives, so the rewrite does not switch to it); a
//!   `G09` goes on the last piece, where the program asked to stop.
//! * Dwells (`G04`) and every block without motion go as written (F written with its
//!   point); `G92` is moved by the correction at the present point (the controller takes
//!   its corrected position for the present point, so the shift it sets is the one the
//!   program meant); `G10 L2` is written with decimal points.
//! * Blocks starting with `/` are rewritten for the block-skip switch as given: left
//!   out when it is on, rewritten as ordinary blocks when it is off (a skipped move
//!   changes every later correction, so the tape cannot keep both).
//!
//! Worked example (map: the tool lands 12 um short in X near X=50; IS-B, G21):
//! `N20G01X50.Y20.F600` becomes `N20G01X50.012Y20.F600.`.

use crate::{Compensation, Limits, Note, Options, Pose, RewriteError, Rewriter, N_AXIS};
use protocol::fanuc::{
    parse_line, Action, FanucBlock, FanucError, Interpreter, Line, Plane, MAX_DIGITS,
};
use protocol::grbl::gcode::{
    filter_line, Action as GrblAction, Interpreter as GrblInterpreter, Rate,
};
use std::collections::BTreeMap;

const LETTERS: [char; 3] = ['X', 'Y', 'Z'];

/// How to rewrite for one controller.
#[derive(Clone, Debug, PartialEq)]
pub struct FanucOptions {
    /// The controller's parameters that change how a program reads (decimal-point
    /// input, least input increments, the block-skip switch, subprogram nesting).
    pub program: protocol::fanuc::Options,
    /// Largest distance of the executed (straight) path from the compensated path, mm.
    pub tolerance_mm: f64,
    /// Largest correction accepted at any point, mm.
    pub max_correction_mm: f64,
    /// Soft limits, machine mm.
    pub limits: Option<Limits>,
    /// The machine position when the program starts (else the first moves must name
    /// every compensated axis in G90).
    pub start: Option<Pose>,
    /// The controller's stored offsets, machine mm: index 0 the external offset, 1..=6
    /// G54..G59.
    pub work_offsets: [[f64; 3]; 7],
    /// Longest block written, characters (end of block not counted). The public
    /// manuals found give no figure: 128 by default (*ours*); a longer block is
    /// refused naming the block.
    pub max_block_chars: usize,
    /// Pad every block to an even character count with a space, for a controller with
    /// its TV check on (an odd count raises alarm 002; DNC senders pad with a space).
    /// Default off.
    pub tv_pad: bool,
    /// The most characters the rewritten tape may hold (expanded subprograms and split
    /// moves grow it); passing it is refused naming the block.
    pub max_output_bytes: usize,
}

impl Default for FanucOptions {
    fn default() -> Self {
        Self {
            program: protocol::fanuc::Options::default(),
            tolerance_mm: 0.0005,
            max_correction_mm: 0.2,
            limits: None,
            start: None,
            work_offsets: [[0.0; 3]; 7],
            max_block_chars: 128,
            tv_pad: false,
            max_output_bytes: 256 << 20,
        }
    }
}

/// What a Fanuc rewrite did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FanucReport {
    /// The main program's number (`O....`), when it has one.
    pub program_number: Option<u32>,
    /// Blocks read (expanded calls counted once per run).
    pub blocks_in: usize,
    /// Blocks written (the `%` lines and comments not counted).
    pub blocks_out: usize,
    pub moves_compensated: usize,
    /// Blocks added by splitting moves and turning arcs into chords.
    pub segments_added: usize,
    /// Subprogram runs expanded.
    pub calls_expanded: usize,
    /// Blocks left out for the block-skip switch.
    pub skipped_blocks: usize,
    /// Largest |command - nominal| over the compensated axes, um.
    pub largest_correction_um: f64,
    /// Line of the tape holding that block.
    pub largest_correction_line: usize,
    pub notes: Vec<Note>,
}

/// One block of a tape, where it came from.
#[derive(Clone, Debug)]
struct Source {
    line: usize,
    text: String,
    block: FanucBlock,
}

/// A tape read: the main program's blocks and the subprograms defined on it.
struct Tape {
    main: Vec<Source>,
    subprograms: BTreeMap<u32, Vec<Source>>,
}

fn ends_program(b: &FanucBlock) -> bool {
    b.word('M')
        .is_some_and(|m| m.value == 2.0 || m.value == 30.0)
}

fn returns(b: &FanucBlock) -> bool {
    b.word('M').is_some_and(|m| m.value == 99.0)
}

/// Reads a tape: `%` (optional), the main program up to M30/M02 (or the closing `%`),
/// then subprogram definitions (`O....` ... `M99`). With `subprograms_only`, the whole
/// text is definitions (the controller's stored programs).
fn read_tape(text: &str, subprograms_only: bool, what: &str) -> Result<Tape, FanucError> {
    let mut tape = Tape {
        main: Vec::new(),
        subprograms: BTreeMap::new(),
    };
    let mut in_main = !subprograms_only;
    let mut current: Option<(u32, usize, Vec<Source>)> = None;
    let mut percents = 0;
    for (k, raw) in text.split('\n').enumerate() {
        let line = k + 1;
        let raw = raw.strip_suffix('\r').unwrap_or(raw);
        let fail = |m: String| FanucError::new(line, raw, format!("{what}: {m}"));
        let parsed = parse_line(raw, line).map_err(|mut e| {
            e.message = format!("{what}: {}", e.message);
            e
        })?;
        let block = match parsed {
            Line::Blank => continue,
            Line::Percent => {
                percents += 1;
                if percents > 2 {
                    return Err(fail("a third `%`: one tape per file".into()));
                }
                continue;
            }
            Line::Block(b) => b,
        };
        if percents >= 2 {
            return Err(fail("a block after the closing `%`".into()));
        }
        let source = Source {
            line,
            text: raw.to_string(),
            block,
        };
        if in_main {
            let end = ends_program(&source.block);
            tape.main.push(source);
            if end {
                in_main = false;
            }
            continue;
        }
        match &mut current {
            None => {
                let Some(n) = source.block.program_number() else {
                    return Err(fail(
                        "after the main program's M30/M02 only subprograms (O.... to M99) may follow"
                            .into(),
                    ));
                };
                if tape.subprograms.contains_key(&n) {
                    return Err(fail(format!("O{n} is defined twice")));
                }
                current = Some((n, line, Vec::new()));
            }
            Some((n, _, blocks)) => {
                if source.block.program_number().is_some() {
                    return Err(fail(format!("O{n} has no M99 before the next program")));
                }
                let end = returns(&source.block);
                blocks.push(source);
                if end {
                    let (n, _, blocks) = current.take().unwrap_or_default();
                    tape.subprograms.insert(n, blocks);
                }
            }
        }
    }
    if let Some((n, line, _)) = current {
        return Err(FanucError::new(
            line,
            &format!("O{n}"),
            format!("{what}: subprogram O{n} has no M99"),
        ));
    }
    Ok(tape)
}

/// Rewrites a Fanuc tape (`text`: the main program, and subprograms after its M30) with
/// `compensation`; `stored` holds the controller's stored subprograms (definitions
/// only), if any. The output is a `%` tape, LF end of block.
pub fn rewrite_fanuc(
    text: &str,
    stored: Option<&str>,
    compensation: &dyn Compensation,
    options: FanucOptions,
) -> Result<(String, FanucReport), FanucError> {
    let mut tape = read_tape(text, false, "program")?;
    if let Some(stored) = stored {
        for (n, blocks) in read_tape(stored, true, "subprograms")?.subprograms {
            if tape.subprograms.contains_key(&n) {
                let line = blocks.first().map_or(0, |s| s.line);
                return Err(FanucError::new(
                    line,
                    &format!("O{n}"),
                    format!("subprograms: O{n} is also defined on the program's tape"),
                ));
            }
            tape.subprograms.insert(n, blocks);
        }
    }
    if tape.main.is_empty() {
        return Err(FanucError::new(1, "", "program: no blocks"));
    }
    let mut w = Writer::new(compensation, &options)?;
    w.out.push_str("%\n");
    let main = std::mem::take(&mut tape.main);
    w.run_blocks(&main, &tape, &[], None)?;
    w.out.push_str("%\n");
    let mut report = w.report;
    let grbl = w.rewriter.into_report();
    report.largest_correction_um = grbl.largest_correction_um;
    report.largest_correction_line = grbl.largest_correction_line;
    report.notes.extend(grbl.notes);
    Ok((w.out, report))
}

/// Rounding of a written value: decimals of the least input increment.
fn decimals_of(increment: f64) -> usize {
    (-increment.log10()).round().clamp(0.0, 9.0) as usize
}

/// A dimension as Fanuc reads it with a point: trailing zeros trimmed, the point kept
/// (`12.`, `-0.5`, `0.`).
fn fanuc_number(value: f64, decimals: usize) -> Option<String> {
    let text = protocol::nc::format_number(value, decimals)?;
    let text = if text.contains('.') {
        text.trim_end_matches('0').to_string()
    } else {
        format!("{text}.")
    };
    Some(if text == "-0." { "0.".into() } else { text })
}

struct Writer<'a> {
    options: &'a FanucOptions,
    rewriter: Rewriter<'a>,
    /// The program as written: the programmed path.
    nominal: Interpreter,
    /// The controller reading the rewritten tape.
    controller: Interpreter,
    /// Commands of the pieces the GRBL rewriter wrote (machine mm).
    pieces: GrblInterpreter,
    /// Whether each axis's position is known.
    known: [bool; 3],
    compensated: [bool; 3],
    out: String,
    report: FanucReport,
}

impl<'a> Writer<'a> {
    fn new(
        compensation: &'a dyn Compensation,
        options: &'a FanucOptions,
    ) -> Result<Self, FanucError> {
        let bad = |m: String| FanucError::new(0, "", format!("options: {m}"));
        let rewriter = Rewriter::new(
            compensation,
            Options {
                tolerance_mm: options.tolerance_mm,
                max_correction_mm: options.max_correction_mm,
                limits: options.limits,
                start: options.start,
                ..Options::default()
            },
        )
        .map_err(|e| bad(e.to_string()))?;
        let p = &options.program;
        if !(p.increment_mm > 0.0
            && p.increment_mm <= 0.01
            && p.increment_inch > 0.0
            && p.increment_inch <= 0.001)
        {
            return Err(bad(
                "the least input increments must be at most 0.01 mm and 0.001 in".into(),
            ));
        }
        if options.max_block_chars < 16 {
            return Err(bad(
                "a block of fewer than 16 characters cannot hold a move".into(),
            ));
        }
        let start = options.start.unwrap_or([0.0; 3]);
        let mut nominal = Interpreter::new(options.program.clone(), start);
        nominal.work_offsets = options.work_offsets;
        let controller = nominal.clone();
        let mut pieces = GrblInterpreter::new();
        pieces.position = start;
        let mut compensated = [false; 3];
        for &a in compensation.axes() {
            if a < N_AXIS {
                compensated[a] = true;
            }
        }
        Ok(Self {
            options,
            rewriter,
            nominal,
            controller,
            pieces,
            known: [options.start.is_some(); 3],
            compensated,
            out: String::new(),
            report: FanucReport::default(),
        })
    }

    /// Runs `blocks` (the main program, or a subprogram called from `calls`, innermost
    /// last) and writes what they become. Returns at M99 (a subprogram) or M30/M02.
    fn run_blocks(
        &mut self,
        blocks: &[Source],
        tape: &Tape,
        calls: &[(u32, usize)],
        program: Option<u32>,
    ) -> Result<bool, FanucError> {
        for s in blocks {
            let fail = |m: String| {
                let mut m = m;
                for (n, line) in calls.iter().rev() {
                    m = format!("{m} (in O{n}, called from line {line})");
                }
                FanucError::new(s.line, &s.text, m)
            };
            let b = &s.block;
            if b.skip && self.options.program.block_skip {
                self.report.skipped_blocks += 1;
                continue;
            }
            self.report.blocks_in += 1;
            if let Some(n) = b.program_number() {
                if program.is_none() && calls.is_empty() {
                    self.report.program_number = Some(n);
                    self.emit(&format!("O{n}"), s, &fail)?;
                }
                continue;
            }
            if b.word('M').is_some_and(|m| m.value == 98.0) {
                self.call(s, tape, calls, &fail)?;
                continue;
            }
            if returns(b) {
                if program.is_none() {
                    return Err(fail(
                        "M99 in the main program: a tape cannot loop back (the controller alarms)"
                            .into(),
                    ));
                }
                if b.words.iter().any(|w| w.letter != 'M') {
                    return Err(fail(
                        "M99 with other words (a return to a sequence number, P) cannot be rewritten: put M99 alone in its block"
                            .into(),
                    ));
                }
                return Ok(false);
            }
            let before = self.nominal.clone();
            let actions = self
                .nominal
                .execute(b, s.line, &s.text)
                .map_err(|e| fail(e.message))?;
            self.block(s, &before, &actions, &fail)?;
            if actions.iter().any(|a| matches!(a, Action::End)) {
                return Ok(true);
            }
        }
        Ok(false)
    }

    fn call(
        &mut self,
        s: &Source,
        tape: &Tape,
        calls: &[(u32, usize)],
        fail: &dyn Fn(String) -> FanucError,
    ) -> Result<(), FanucError> {
        let b = &s.block;
        if b.words.iter().any(|w| !matches!(w.letter, 'M' | 'P')) {
            return Err(fail(
                "M98 with other words cannot be rewritten: put the call in a block of its own (N, M98, P)"
                    .into(),
            ));
        }
        let actions = self
            .nominal
            .execute(b, s.line, &s.text)
            .map_err(|e| fail(e.message))?;
        let Some(&Action::Call { program, repeats }) = actions.first() else {
            return Err(fail("M98 without a program to call".into()));
        };
        if calls.len() >= self.options.program.max_nesting {
            return Err(fail(format!(
                "M98 nests deeper than {} subprograms",
                self.options.program.max_nesting
            )));
        }
        let Some(blocks) = tape.subprograms.get(&program) else {
            return Err(fail(format!(
                "O{program} is not on the tape (put it after M30, O{program} ... M99) nor among the stored subprograms given"
            )));
        };
        let mut inner = calls.to_vec();
        inner.push((program, s.line));
        for k in 1..=repeats {
            self.comment(&format!("(CALL O{program} {k} OF {repeats})"));
            self.report.calls_expanded += 1;
            if self.run_blocks(blocks, tape, &inner, Some(program))? {
                return Err(fail(format!(
                    "O{program} ends the program (M30/M02) inside a call: not rewritten"
                )));
            }
            self.comment(&format!("(END O{program})"));
        }
        Ok(())
    }

    fn comment(&mut self, text: &str) {
        self.out.push_str(text);
        self.out.push('\n');
    }

    /// Writes one block: checks its length and digits, reads it as the controller
    /// would (and so learns where the controller is).
    fn emit(
        &mut self,
        text: &str,
        s: &Source,
        fail: &dyn Fn(String) -> FanucError,
    ) -> Result<(), FanucError> {
        let mut text = text.to_string();
        if self.options.tv_pad && text.len() % 2 == 1 {
            text.push(' ');
        }
        if text.len() > self.options.max_block_chars {
            return Err(fail(format!(
                "the rewritten block `{}` has {} characters, more than the controller's {} (max_block_chars)",
                text,
                text.len(),
                self.options.max_block_chars
            )));
        }
        let written = match parse_line(&text, s.line) {
            Ok(Line::Block(b)) => b,
            Ok(_) => return Err(fail(format!("the rewritten block `{text}` is empty"))),
            Err(e) => return Err(fail(format!("the rewritten block `{text}`: {}", e.message))),
        };
        if written.word('O').is_none() && written.word('M').is_none_or(|m| m.value != 98.0) {
            self.controller
                .execute(&written, s.line, &text)
                .map_err(|e| fail(format!("the rewritten block `{text}`: {}", e.message)))?;
        }
        self.out.push_str(&text);
        self.out.push('\n');
        self.report.blocks_out += 1;
        if self.out.len() > self.options.max_output_bytes {
            return Err(fail(format!(
                "the rewritten tape passes {} bytes, the most accepted (a larger tolerance, or fewer subprogram repeats, gives a shorter tape)",
                self.options.max_output_bytes
            )));
        }
        Ok(())
    }

    fn unit(&self) -> f64 {
        if self.nominal.modal.inch {
            25.4
        } else {
            1.0
        }
    }

    fn decimals(&self) -> usize {
        let p = &self.options.program;
        decimals_of(if self.nominal.modal.inch {
            p.increment_inch
        } else {
            p.increment_mm
        })
    }

    /// The words of `b` other than motion and axis words, as the controller reads them
    /// (F with its point): its G codes, the words for the block's first piece, and the
    /// words for its last piece: `G09` (the exact stop is at the programmed point) and
    /// M02/M30 (the program ends after the whole move). Without motion (`keep_motion`)
    /// every G code stays with the others.
    fn other_words(&self, b: &FanucBlock, keep_motion: bool) -> OtherWords {
        let mut g = String::new();
        let mut rest = String::new();
        let mut last_g = String::new();
        let mut end = String::new();
        for w in &b.words {
            match w.letter {
                'G' if !keep_motion && w.value <= 3.0 => {}
                'G' if !keep_motion && w.value == 9.0 => last_g.push_str(&w.text),
                'G' => g.push_str(&w.text),
                'X' | 'Y' | 'Z' | 'I' | 'J' | 'K' | 'R' => {}
                'F' if !w.point => rest.push_str(&format!(
                    "F{}",
                    fanuc_number(w.value, 4).unwrap_or_default()
                )),
                'M' if w.value == 2.0 || w.value == 30.0 => end.push_str(&w.text),
                _ => rest.push_str(&w.text),
            }
        }
        OtherWords {
            g,
            rest,
            last_g,
            end,
        }
    }

    fn block(
        &mut self,
        s: &Source,
        before: &Interpreter,
        actions: &[Action],
        fail: &dyn Fn(String) -> FanucError,
    ) -> Result<(), FanucError> {
        let b = &s.block;
        let n = b.n.map(|n| format!("N{n}")).unwrap_or_default();
        let g = |code: f64| b.g_codes().any(|c| c == code);
        let named: Vec<usize> = (0..3).filter(|&k| b.word(LETTERS[k]).is_some()).collect();
        if g(92.0) {
            return self.shift(s, before, &named, fail);
        }
        if g(10.0) {
            // Offsets: the values as the controller reads them, with points.
            let unit = self.unit();
            let decimals = self.decimals();
            let mut text = n.clone();
            for w in &b.words {
                if let Some(k) = LETTERS.iter().position(|l| *l == w.letter) {
                    let _ = k;
                    let v = before.dimension(w, before.modal.inch) / unit;
                    text.push(w.letter);
                    text.push_str(&self.number(v, decimals, w.letter, fail)?);
                } else {
                    text.push_str(&w.text);
                }
            }
            return self.emit(&text, s, fail);
        }
        let moves: Vec<&Action> = actions
            .iter()
            .filter(|a| {
                matches!(
                    a,
                    Action::Rapid { .. } | Action::Linear { .. } | Action::Arc { .. }
                )
            })
            .collect();
        let Some(motion) = moves.first() else {
            // No motion: as written (F with its point; a dwell untouched).
            let text = if g(4.0) {
                b.to_string()
            } else {
                let w = self.other_words(b, true);
                format!("{n}{}{}{}", w.g, w.rest, w.end)
            };
            return self.emit(&text, s, fail);
        };
        // Where each axis is known from here on.
        let mut known_after = self.known;
        for &k in &named {
            if self.nominal.modal.incremental && !self.known[k] && self.compensated[k] {
                return Err(fail(format!(
                    "an incremental (G91) move of {} from an unknown position cannot be corrected: start with an absolute (G90) move of every compensated axis, or give the start position",
                    LETTERS[k]
                )));
            }
            known_after[k] = true;
        }
        let arc = matches!(motion, Action::Arc { .. });
        if let Action::Arc { plane, .. } = motion {
            let (a, c, _) = plane.axes();
            for k in [a, c] {
                if !self.known[k] && self.compensated[k] {
                    return Err(fail(format!(
                        "an arc from an unknown {} position cannot be corrected: start with an absolute (G90) move of every compensated axis, or give the start position",
                        LETTERS[k]
                    )));
                }
            }
        }
        // The move in machine coordinates, for the GRBL rewriter (G90 G21, no offsets).
        let canonical = canonical_line(motion, before.position, &named)
            .ok_or_else(|| fail("a coordinate has no finite value".into()))?;
        let pieces = self
            .rewriter
            .line(&canonical, s.line)
            .map_err(|e: RewriteError| fail(e.kind.to_string()))?;
        self.known = known_after;
        // The commands, in order.
        let mut commands: Vec<(Pose, bool)> = Vec::new();
        for p in &pieces {
            let filtered = filter_line(p).map_err(|e| fail(e.to_string()))?;
            let acts = self
                .pieces
                .execute(&filtered, false)
                .map_err(|code| fail(format!("internal: piece `{p}` refused with error:{code}")))?;
            for a in acts {
                if let GrblAction::Move { target, rate, .. } = a {
                    commands.push((target, matches!(rate, Rate::Rapid)));
                }
            }
        }
        let unit = self.unit();
        let decimals = self.decimals();
        let increment = 10f64.powi(-(decimals as i32)) * unit;
        let incremental = self.nominal.modal.incremental;
        let words = self.other_words(b, false);
        for (k, (command, rapid)) in commands.iter().enumerate() {
            let last = k + 1 == commands.len();
            let mut text = String::new();
            if k == 0 {
                text.push_str(&n);
                text.push_str(&words.g);
            }
            if last {
                text.push_str(&words.last_g);
            }
            text.push_str(if *rapid { "G00" } else { "G01" });
            // The origin under the block's own work system (a G54-G59 in it applies
            // to its move).
            let origin = {
                let mut c = self.controller.clone();
                c.modal.work = self.nominal.modal.work;
                c.origin()
            };
            for i in 0..3 {
                let moved = (command[i] - self.controller.position[i]).abs() > increment / 2.0;
                let name = k == 0 && named.contains(&i) && !arc;
                let arc_axis = k == 0 && arc && named.contains(&i);
                if !(moved || name || arc_axis) {
                    continue;
                }
                let v = if incremental {
                    (command[i] - self.controller.position[i]) / unit
                } else {
                    (command[i] - origin[i]) / unit
                };
                text.push(LETTERS[i]);
                text.push_str(&self.number(v, decimals, LETTERS[i], fail)?);
            }
            if k == 0 {
                text.push_str(&words.rest);
            }
            if last {
                text.push_str(&words.end);
            }
            self.emit(&text, s, fail)?;
            for i in 0..3 {
                if (self.controller.position[i] - command[i]).abs() > increment / 2.0 + 1e-9 {
                    return Err(fail(format!(
                        "internal: the rewritten block `{text}` puts {} at {:.4} mm, not at the command {:.4} mm",
                        LETTERS[i], self.controller.position[i], command[i]
                    )));
                }
            }
        }
        self.report.moves_compensated += 1;
        self.report.segments_added += commands.len().saturating_sub(1);
        Ok(())
    }

    /// A value rounded to the increment, with its point, within the digits.
    fn number(
        &self,
        v: f64,
        decimals: usize,
        letter: char,
        fail: &dyn Fn(String) -> FanucError,
    ) -> Result<String, FanucError> {
        let t = fanuc_number(v, decimals)
            .ok_or_else(|| fail(format!("{letter} has no finite value")))?;
        let digits = t.chars().filter(char::is_ascii_digit).count();
        if digits > MAX_DIGITS {
            return Err(fail(format!(
                "{letter}{t} has {digits} digits, more than the controller's {MAX_DIGITS}"
            )));
        }
        Ok(t)
    }

    /// G92: each named compensated axis's value moved by the correction at the present
    /// point (see the module's documentation).
    fn shift(
        &mut self,
        s: &Source,
        before: &Interpreter,
        named: &[usize],
        fail: &dyn Fn(String) -> FanucError,
    ) -> Result<(), FanucError> {
        let b = &s.block;
        let unit = if before.modal.inch { 25.4 } else { 1.0 };
        let decimals = self.decimals();
        let mut text = b.n.map(|n| format!("N{n}")).unwrap_or_default();
        for w in &b.words {
            let Some(k) = LETTERS.iter().position(|l| *l == w.letter) else {
                text.push_str(&w.text);
                continue;
            };
            if self.compensated[k] && !self.known[k] {
                return Err(fail(format!(
                    "G92 on {} at an unknown position cannot be corrected: start with an absolute (G90) move of every compensated axis, or give the start position",
                    w.letter
                )));
            }
            let v = before.dimension(w, before.modal.inch) / unit
                + (self.controller.position[k] - before.position[k]) / unit;
            text.push(w.letter);
            text.push_str(&self.number(v, decimals, w.letter, fail)?);
        }
        let _ = named;
        self.emit(&text, s, fail)
    }
}

/// A block's words other than motion and axis words, by the piece of a split move
/// they go with (`Writer::other_words`).
struct OtherWords {
    /// G codes for the first piece (modes: they hold from there on).
    g: String,
    /// The other words for the first piece (F with its point, S, T, M...).
    rest: String,
    /// `G09` for the last piece: the exact stop is at the programmed point.
    last_g: String,
    /// M02/M30 for the last piece: the program ends after the whole move.
    end: String,
}

/// The move as one GRBL line in machine coordinates (G90 G21, no offsets): the named
/// axes (an arc: both axes of its plane too), the centre as I/J/K from the start.
fn canonical_line(motion: &Action, from: [f64; 3], named: &[usize]) -> Option<String> {
    let num = |v: f64| {
        let t = protocol::nc::format_number(v, 5)?;
        Some(if t.contains('.') {
            t.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            t
        })
    };
    let mut text = String::new();
    let (to, axes): ([f64; 3], Vec<usize>) = match motion {
        Action::Rapid { to } => {
            text.push_str("G0");
            (*to, named.to_vec())
        }
        Action::Linear { to, feed } => {
            text.push_str(&format!("G1F{}", num(*feed)?));
            (*to, named.to_vec())
        }
        Action::Arc {
            to,
            centre,
            clockwise,
            plane,
            feed,
        } => {
            let (a, b, _) = plane.axes();
            text.push_str(match plane {
                Plane::Xy => "G17",
                Plane::Zx => "G18",
                Plane::Yz => "G19",
            });
            text.push_str(if *clockwise { "G2" } else { "G3" });
            text.push_str(&format!("F{}", num(*feed)?));
            let mut axes: Vec<usize> = named.to_vec();
            for k in [a, b] {
                if !axes.contains(&k) {
                    axes.push(k);
                }
                text.push(['I', 'J', 'K'][k]);
                text.push_str(&num(centre[k] - from[k])?);
            }
            axes.sort_unstable();
            (*to, axes)
        }
        _ => return None,
    };
    for k in axes {
        text.push(LETTERS[k]);
        text.push_str(&num(to[k])?);
    }
    Some(text)
}

/// The rewrite of a tape as it arrives, line by line (a DNC sender drip-feeding
/// through the gateway): each line's rewritten text comes back at once, so the
/// controller can run the first blocks while the sender still sends. Subprograms must
/// be the controller's stored ones (`stored`): the definitions after a live tape's M30
/// come after the calls that need them, so a block after M30/M02 other than `%` is
/// refused naming it. The output is as [`rewrite_fanuc`]'s (its `%` lines included).
pub struct FanucStream<'a> {
    writer: Writer<'a>,
    stored: Tape,
    line: usize,
    percents: usize,
    ended: bool,
}

impl<'a> FanucStream<'a> {
    pub fn new(
        stored: Option<&str>,
        compensation: &'a dyn Compensation,
        options: &'a FanucOptions,
    ) -> Result<Self, FanucError> {
        let stored = match stored {
            Some(text) => read_tape(text, true, "subprograms")?,
            None => Tape {
                main: Vec::new(),
                subprograms: BTreeMap::new(),
            },
        };
        Ok(Self {
            writer: Writer::new(compensation, options)?,
            stored,
            line: 0,
            percents: 0,
            ended: false,
        })
    }

    /// One line of the tape (without its end of block): what to send for it (empty for
    /// a blank line, else whole lines each ending in LF).
    pub fn push_line(&mut self, raw: &str) -> Result<String, FanucError> {
        self.line += 1;
        let line = self.line;
        let raw = raw.strip_suffix('\r').unwrap_or(raw);
        let block = match parse_line(raw, line)? {
            Line::Blank => return Ok(String::new()),
            Line::Percent => {
                self.percents += 1;
                if self.percents > 2 {
                    return Err(FanucError::new(
                        line,
                        raw,
                        "a third `%`: one tape at a time",
                    ));
                }
                return Ok("%\n".into());
            }
            Line::Block(b) => b,
        };
        let refuse = |m: &str| Err(FanucError::new(line, raw, m));
        if self.percents >= 2 {
            return refuse("a block after the closing `%`");
        }
        if self.ended {
            return refuse(
                "a block after M30/M02 on a live tape: subprograms sent after the program cannot be expanded where it calls them; give them as the controller's stored subprograms",
            );
        }
        let source = Source {
            line,
            text: raw.to_string(),
            block,
        };
        self.ended =
            self.writer
                .run_blocks(std::slice::from_ref(&source), &self.stored, &[], None)?;
        Ok(std::mem::take(&mut self.writer.out))
    }

    /// The tape has ended: what the rewrite did.
    pub fn finish(self) -> FanucReport {
        let mut report = self.writer.report;
        let grbl = self.writer.rewriter.into_report();
        report.largest_correction_um = grbl.largest_correction_um;
        report.largest_correction_line = grbl.largest_correction_line;
        report.notes.extend(grbl.notes);
        report
    }
}

#[cfg(test)]
mod tests;

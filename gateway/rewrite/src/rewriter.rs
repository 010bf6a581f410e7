//! The block-by-block rewriter, usable on a whole file ([`rewrite_program`]) or line by
//! line as a sender streams them ([`Rewriter::line`], the live pass-through).

use crate::split::{distance, lerp, split, turns, MAX_SAMPLES, REVERSAL_SHARE};
use crate::{Approach, Compensation, Pose, AXIS_LETTERS, N_AXIS};
use protocol::grbl::codes::error_text;
use protocol::grbl::gcode::{filter_line, Action, FilterError, Interpreter, Motion, Rate};
use protocol::nc::{self, Block, Item, NcError, Word};
use std::fmt;

/// Soft limits of the machine, machine coordinates, mm.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limits {
    pub min: Pose,
    pub max: Pose,
}

/// How to rewrite.
#[derive(Clone, Debug, PartialEq)]
pub struct Options {
    /// Largest distance of the executed (straight) path from the compensated path, mm.
    pub tolerance_mm: f64,
    /// Largest correction (command minus nominal) accepted at any point, mm.
    pub max_correction_mm: f64,
    /// Every command must lie inside these (none: only the model's own extent).
    pub limits: Option<Limits>,
    /// The machine position when the program starts, if known.
    pub start: Option<Pose>,
    /// The controller's stored G54..G59 offsets (`$#`), machine mm.
    pub work_offsets: [Pose; 6],
    /// The controller's G92 offset (the `[G92:...]` line of `$#`), mm: added to the
    /// active work offset, as GRBL does, until a G92.1 clears it.
    pub g92_offset: Pose,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            tolerance_mm: 0.0005,
            max_correction_mm: 0.2,
            limits: None,
            start: None,
            work_offsets: [[0.0; N_AXIS]; 6],
            g92_offset: [0.0; N_AXIS],
        }
    }
}

/// Something worth telling the user that did not stop the rewrite.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Note {
    pub line: usize,
    pub text: String,
}

/// What a rewrite did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Report {
    pub input_lines: usize,
    pub output_lines: usize,
    /// Moves whose commands were corrected.
    pub moves_compensated: usize,
    /// Lines added by splitting moves and turning arcs into chords.
    pub segments_added: usize,
    /// Of those, the pieces that take up an axis's backlash on the spot where its
    /// command turns back (at a reversal, or where a correction stops creeping one way
    /// and creeps the other).
    pub backlash_takeups: usize,
    /// Largest |command - nominal| over the compensated axes, um.
    pub largest_correction_um: f64,
    /// Line of that largest correction.
    pub largest_correction_line: usize,
    pub notes: Vec<Note>,
}

/// Why a program cannot be rewritten: always names the line (1-based).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("line {line}: {kind}")]
pub struct RewriteError {
    pub line: usize,
    pub kind: RewriteErrorKind,
}

#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum RewriteErrorKind {
    #[error("{0}")]
    Syntax(NcError),
    #[error("the controller cannot receive this line: {0}")]
    Filter(FilterError),
    #[error("the controller would refuse this block with error:{code} ({})", error_text(*code))]
    Refused { code: u8 },
    #[error("the {axis} position is not known here (no absolute move has named it since the start, a homing, a jog or a probe): the move cannot be corrected; start with an absolute move of every compensated axis, or give the start position")]
    UnknownPosition { axis: char },
    #[error(
        "inverse time feed (G93) is not supported: splitting a move would change its duration"
    )]
    InverseTime,
    #[error("{0}")]
    Model(String),
    #[error(
        "the correction at ({}) is {got_um:.1} um, beyond the bound of {bound_um:.1} um: refused",
        fmt_pose(nominal)
    )]
    CorrectionTooLarge {
        nominal: Pose,
        got_um: f64,
        bound_um: f64,
    },
    #[error("the command {axis}{value:.4} mm is outside the soft limits {min:.3}..{max:.3} mm")]
    OutsideLimits {
        axis: char,
        value: f64,
        min: f64,
        max: f64,
    },
    #[error("options: {0}")]
    Options(String),
}

fn fmt_pose(p: &Pose) -> String {
    p.iter()
        .zip(AXIS_LETTERS)
        .map(|(v, l)| format!("{l}{v:.3}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// The rewriter's state between lines: the controller's interpreter (modal state,
/// nominal position, offsets), what it knows of the position, the last command written.
pub struct Rewriter<'a> {
    compensation: &'a dyn Compensation,
    options: Options,
    interpreter: Interpreter,
    known: [bool; N_AXIS],
    /// The last command written per axis, machine mm (as rounded in the output).
    command: Pose,
    approach: [Approach; N_AXIS],
    /// How far each axis's command has come back from the furthest point on its side
    /// without a turn (below the threshold), mm: see [`crate::split::turns`].
    retreat: Pose,
    compensated: [bool; N_AXIS],
    /// The model's feature length, asked once.
    feature_mm: f64,
    report: Report,
}

impl fmt::Debug for Rewriter<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Rewriter")
            .field("compensation", &self.compensation.describe())
            .field("known", &self.known)
            .field("command", &self.command)
            .finish()
    }
}

impl<'a> Rewriter<'a> {
    pub fn new(compensation: &'a dyn Compensation, options: Options) -> Result<Self, RewriteError> {
        let bad = |what: &str| RewriteError {
            line: 0,
            kind: RewriteErrorKind::Options(what.into()),
        };
        if !(options.tolerance_mm.is_finite() && options.tolerance_mm >= 1e-5) {
            return Err(bad("the tolerance must be at least 0.01 um"));
        }
        if !(options.max_correction_mm.is_finite() && options.max_correction_mm > 0.0) {
            return Err(bad("the correction bound must be positive"));
        }
        if !options
            .work_offsets
            .iter()
            .chain([&options.g92_offset])
            .flatten()
            .all(|v| v.is_finite())
        {
            return Err(bad("the work offsets must be finite numbers"));
        }
        let mut interpreter = Interpreter::new();
        for (k, offset) in options.work_offsets.iter().enumerate() {
            interpreter.stored[k] = *offset;
        }
        interpreter.coord_system = options.work_offsets[0];
        interpreter.coord_offset = options.g92_offset;
        // Arcs become chords within half the tolerance; each chord is split within the
        // other half.
        interpreter.arc_tolerance = options.tolerance_mm / 2.0;
        let mut compensated = [false; N_AXIS];
        for &a in compensation.axes() {
            if a < N_AXIS {
                compensated[a] = true;
            }
        }
        let mut rewriter = Self {
            compensation,
            options,
            interpreter,
            known: [false; N_AXIS],
            command: [0.0; N_AXIS],
            approach: [Approach::Forward; N_AXIS],
            retreat: [0.0; N_AXIS],
            compensated,
            feature_mm: compensation.feature_length_mm(),
            report: Report::default(),
        };
        if let Some(start) = rewriter.options.start {
            rewriter.set_machine_position(start);
        }
        Ok(rewriter)
    }

    /// The machine is at `p` (nominal machine coordinates), e.g. from a status report
    /// after homing. The last command is taken to be `p` itself.
    pub fn set_machine_position(&mut self, p: Pose) {
        self.interpreter.position = p;
        self.command = p;
        self.known = [true; N_AXIS];
        self.retreat = [0.0; N_AXIS];
    }

    /// The machine's command is `command` and the tool's nominal position `nominal`
    /// (the pass-through learns both from an idle status report).
    pub fn set_position(&mut self, nominal: Pose, command: Pose) {
        self.interpreter.position = nominal;
        self.command = command;
        self.known = [true; N_AXIS];
        self.retreat = [0.0; N_AXIS];
    }

    /// The controller's stored G54..G59 offsets (from its `$#` reply), machine mm.
    pub fn set_work_offsets(&mut self, offsets: [Pose; 6]) {
        for (k, o) in offsets.iter().enumerate() {
            self.interpreter.stored[k] = *o;
        }
        self.interpreter.coord_system = offsets[self.interpreter.modal.coord_select];
    }

    /// The stored G54..G59 offsets in use.
    pub fn work_offsets(&self) -> [Pose; 6] {
        let mut o = [[0.0; N_AXIS]; 6];
        o.copy_from_slice(&self.interpreter.stored[..6]);
        o
    }

    /// Whether every axis's position is known.
    pub fn position_known(&self) -> bool {
        self.known.iter().all(|&k| k)
    }

    /// The side each axis last moved from.
    pub fn approach(&self) -> [Approach; N_AXIS] {
        self.approach
    }

    /// Take the controller's modal state from its `$G` reply (the words inside
    /// `[GC:...]`, e.g. `G1 G54 G17 G21 G90 G94 M5 M9 T0 F500 S0`): motion, coordinate
    /// system, plane, units, distance and feed modes, and the feed.
    pub fn sync_modal(&mut self, gc_words: &str) -> Result<(), RewriteError> {
        crate::dialect::sync_modal(&mut self.interpreter, gc_words).map_err(|what| RewriteError {
            line: 0,
            kind: RewriteErrorKind::Options(what),
        })
    }

    /// The position is no longer known (a reset, a lost controller).
    pub fn forget_position(&mut self) {
        self.known = [false; N_AXIS];
    }

    /// The controller was reset: modal state back to defaults (offsets kept).
    pub fn controller_reset(&mut self) {
        self.interpreter.reset();
        self.forget_position();
    }

    /// Comment lines to put at the top of a rewritten program (a file; the live
    /// pass-through has no top): what the rewrite holds and what it does not.
    pub fn header(&self) -> Vec<String> {
        vec![
            format!(
                "(compensated by the gateway: feed moves within {} um of the programmed path)",
                self.options.tolerance_mm * 1000.0
            ),
            "(rapids G0 are corrected at their end only: their path is not controlled)".into(),
        ]
    }

    pub fn report(&self) -> &Report {
        &self.report
    }

    pub fn into_report(self) -> Report {
        self.report
    }

    fn fail(&self, line: usize, kind: RewriteErrorKind) -> RewriteError {
        RewriteError { line, kind }
    }

    fn note(&mut self, line: usize, text: impl Into<String>) {
        self.report.notes.push(Note {
            line,
            text: text.into(),
        });
    }

    /// Rewrites one line (without its line ending) into the lines to send instead. On an
    /// error nothing changes: the line may be corrected and offered again.
    pub fn line(&mut self, text: &str, line_no: usize) -> Result<Vec<String>, RewriteError> {
        self.report.input_lines += 1;
        let out = self.line_inner(text, line_no);
        match &out {
            Ok(lines) => self.report.output_lines += lines.len(),
            Err(_) => self.report.input_lines -= 1,
        }
        out
    }

    fn line_inner(&mut self, text: &str, line_no: usize) -> Result<Vec<String>, RewriteError> {
        let trimmed = text.trim_start();
        if trimmed.starts_with('$') {
            return Ok(self.system_line(trimmed, line_no));
        }
        let before = self.interpreter.clone();
        let Some((block, actions)) =
            crate::dialect::read_line(&mut self.interpreter, text, line_no)?
        else {
            return Ok(vec![text.to_string()]);
        };
        match self.block(&block, &before, &actions, line_no) {
            Ok(lines) => Ok(lines),
            Err(e) => {
                // Nothing happened: the controller's state is as before the line.
                self.interpreter = before;
                Err(e)
            }
        }
    }

    /// `$` lines go through as written; homing and jogs make the position unknown.
    fn system_line(&mut self, line: &str, line_no: usize) -> Vec<String> {
        let upper = line.to_ascii_uppercase();
        if upper.starts_with("$H") || upper.starts_with("$J=") {
            if self.known.iter().any(|&k| k) {
                self.note(
                    line_no,
                    "homing or jog: the position is unknown until the next absolute move",
                );
            }
            self.forget_position();
        }
        vec![line.to_string()]
    }

    fn block(
        &mut self,
        block: &Block,
        before: &Interpreter,
        actions: &[Action],
        line_no: usize,
    ) -> Result<Vec<String>, RewriteError> {
        let g = |code: f64| {
            block
                .words()
                .any(|w| w.letter() == 'G' && w.value() == code)
        };
        let modal = self.interpreter.modal;
        let moves: Vec<(Pose, Rate)> = actions
            .iter()
            .filter_map(|a| match a {
                Action::Move { target, rate, .. } => Some((*target, *rate)),
                _ => None,
            })
            .collect();
        let probes = actions.iter().any(|a| matches!(a, Action::Probe { .. }));
        if g(28.0) || g(30.0) || probes {
            // The end is a stored position or wherever the probe touched: pass through
            // unchanged, position unknown afterwards.
            self.note(
                line_no,
                "G28/G30 or probing moves are not compensated; the position is unknown until the next absolute move",
            );
            self.forget_position();
            return Ok(vec![block.to_string()]);
        }
        let named: Vec<usize> = (0..N_AXIS)
            .filter(|&i| block.word(AXIS_LETTERS[i]).is_some())
            .collect();
        let machine_coords = g(53.0);
        let absolute = !modal.incremental || machine_coords;
        let touches_compensated = named.iter().any(|&i| self.compensated[i])
            || moves.iter().any(|(t, _)| {
                (0..N_AXIS).any(|i| self.compensated[i] && t[i] != before.position[i])
            });
        let sets_offset = (g(92.0) || (g(10.0) && block.word('L').map(Word::value) == Some(20.0)))
            && named.iter().any(|&i| self.compensated[i]);
        if sets_offset {
            return self.offset_block(block, before, &named, line_no);
        }
        if moves.is_empty() || !touches_compensated {
            // Nothing the model changes: the block goes as written.
            for (target, _) in &moves {
                self.check_limits(target, line_no)?;
            }
            for (target, _) in &moves {
                self.command_passthrough(target);
            }
            if absolute && !moves.is_empty() {
                for &i in &named {
                    self.known[i] = true;
                }
            }
            return Ok(vec![block.to_string()]);
        }
        if modal.inverse_time {
            return Err(self.fail(line_no, RewriteErrorKind::InverseTime));
        }
        // Every compensated axis must be known at the end of the block.
        let mut known_after = self.known;
        if absolute {
            for &i in &named {
                known_after[i] = true;
            }
        }
        if let Some(axis) = (0..N_AXIS).find(|&i| self.compensated[i] && !known_after[i]) {
            return Err(self.fail(
                line_no,
                RewriteErrorKind::UnknownPosition {
                    axis: AXIS_LETTERS[axis],
                },
            ));
        }
        let start_known = (0..N_AXIS).all(|i| !self.compensated[i] || self.known[i]);
        if !absolute && !start_known {
            let axis = (0..N_AXIS).find(|&i| self.compensated[i] && !self.known[i]);
            return Err(self.fail(
                line_no,
                RewriteErrorKind::UnknownPosition {
                    axis: AXIS_LETTERS[axis.unwrap_or(0)],
                },
            ));
        }
        let is_arc = matches!(modal.motion, Motion::ArcCw | Motion::ArcCcw);
        let tolerance = if is_arc {
            self.options.tolerance_mm / 2.0
        } else {
            self.options.tolerance_mm
        };
        // The pieces: (nominal end, command, rapid).
        let mut pieces: Vec<(Pose, Pose, bool)> = Vec::new();
        let mut from = before.position;
        let mut from_command = self.command;
        let mut approach = self.approach;
        let mut retreat = self.retreat;
        let mut takeups = 0;
        let mut first_unknown = !start_known;
        let comp = self.compensation;
        let compensated = self.compensated;
        let threshold = REVERSAL_SHARE * self.options.tolerance_mm;
        let model = |e: String| RewriteError {
            line: line_no,
            kind: RewriteErrorKind::Model(e),
        };
        for (target, rate) in &moves {
            let rapid = matches!(rate, Rate::Rapid);
            if first_unknown {
                // Only the end is corrected; each moved axis arrives from the side it
                // moved from (as far as the interpreter knows).
                for i in 0..N_AXIS {
                    if target[i] > from[i] {
                        approach[i] = Approach::Forward;
                    } else if target[i] < from[i] {
                        approach[i] = Approach::Reverse;
                    }
                }
                retreat = [0.0; N_AXIS];
                let c = command_on(comp, &compensated, &approach, target, target).map_err(model)?;
                if !rapid {
                    self.note(
                        line_no,
                        "the start of this move is not known: only its end is corrected",
                    );
                }
                self.check_correction(target, &c, line_no)?;
                self.check_limits(&c, line_no)?;
                pieces.push((*target, c, rapid));
                first_unknown = false;
                from = *target;
                from_command = c;
                continue;
            }
            // Where each axis's command turns back along the move (a moving axis at a
            // reversal, one the program leaves still as its correction creeps up and
            // back): from there on the axis arrives from the other side. A rapid's path
            // is not controlled: only its end, on the side each axis's command last
            // moved to.
            let samples = if rapid { 1 } else { MAX_SAMPLES };
            let turns = turns(
                &from,
                &from_command,
                target,
                &approach,
                &retreat,
                &compensated,
                threshold,
                self.feature_mm,
                samples,
                &mut |p: &Pose, g: &Pose| command_on(comp, &compensated, &approach, p, g),
            )
            .map_err(model)?;
            retreat = turns.retreat;
            if rapid {
                approach = turns.runs.last().map_or(approach, |r| r.1);
                let mut guess = *target;
                for i in 0..N_AXIS {
                    guess[i] += from_command[i] - from[i];
                }
                let c = command_on(comp, &compensated, &approach, target, &guess).map_err(model)?;
                self.check_correction(target, &c, line_no)?;
                self.check_limits(&c, line_no)?;
                pieces.push((*target, c, true));
                from = *target;
                from_command = c;
                continue;
            }
            for (j, (t, sides)) in turns.runs.iter().enumerate() {
                let t_end = turns.runs.get(j + 1).map_or(1.0, |r| r.0);
                let at = |t: f64| {
                    if t == 0.0 {
                        from
                    } else if t == 1.0 {
                        *target
                    } else {
                        lerp(&from, target, t)
                    }
                };
                let (pa, pb) = (at(*t), at(t_end));
                if *sides != approach {
                    // An axis turns here: it first takes up its backlash on the spot (the
                    // model's command for the new side at the same point), so the slack
                    // is not taken up while the other axes already move (the tool would
                    // leave the path by the backlash).
                    let c =
                        command_on(comp, &compensated, sides, &pa, &from_command).map_err(model)?;
                    approach = *sides;
                    if c != from_command {
                        self.check_correction(&pa, &c, line_no)?;
                        self.check_limits(&c, line_no)?;
                        pieces.push((pa, c, false));
                        from_command = c;
                        takeups += 1;
                    }
                }
                let segment = split(
                    &pa,
                    &from_command,
                    &pb,
                    tolerance,
                    self.feature_mm,
                    &mut |p: &Pose, g: &Pose| command_on(comp, &compensated, &approach, p, g),
                )
                .map_err(model)?;
                for (p, c) in segment {
                    self.check_correction(&p, &c, line_no)?;
                    self.check_limits(&c, line_no)?;
                    pieces.push((p, c, false));
                    from_command = c;
                }
            }
            from = *target;
        }
        let lines = self.write_pieces(
            block,
            before.position,
            &pieces,
            is_arc,
            machine_coords,
            line_no,
        )?;
        self.known = known_after;
        self.approach = approach;
        self.retreat = retreat;
        self.report.moves_compensated += 1;
        self.report.backlash_takeups += takeups;
        self.report.segments_added += lines.len() - 1;
        Ok(lines)
    }

    /// G92 or G10 L20: the present point gets the given coordinates. The controller
    /// takes its own position, the corrected command, for the present point, so each
    /// compensated axis's value is moved by the correction there: the offset it sets is
    /// the one the program meant (else every later point would be off by the correction
    /// where the offset was set).
    fn offset_block(
        &mut self,
        block: &Block,
        before: &Interpreter,
        named: &[usize],
        line_no: usize,
    ) -> Result<Vec<String>, RewriteError> {
        let modal = self.interpreter.modal;
        let unit = if modal.inches { 25.4 } else { 1.0 };
        let decimals = if modal.inches { 5 } else { 4 };
        let mut edited = block.clone();
        let axes: Vec<usize> = named
            .iter()
            .copied()
            .filter(|&i| self.compensated[i])
            .collect();
        for i in axes {
            if !self.known[i] {
                self.note(
                    line_no,
                    format!(
                        "the {} position is not known here: the offset is set as written, off by the correction at the present point",
                        AXIS_LETTERS[i]
                    ),
                );
                continue;
            }
            let Some(w) = block.word(AXIS_LETTERS[i]) else {
                continue;
            };
            let value = w.value() + (self.command[i] - before.position[i]) / unit;
            edited
                .set_word(AXIS_LETTERS[i], round_to(value, decimals), decimals)
                .map_err(|e| self.fail(line_no, RewriteErrorKind::Model(e.to_string())))?;
        }
        let line = edited.to_string();
        filter_line(&line).map_err(|e| self.fail(line_no, RewriteErrorKind::Filter(e)))?;
        Ok(vec![line])
    }

    fn command_passthrough(&mut self, target: &Pose) {
        for i in 0..N_AXIS {
            if !self.compensated[i] {
                self.command[i] = target[i];
            }
        }
    }

    fn check_correction(&mut self, p: &Pose, c: &Pose, line_no: usize) -> Result<(), RewriteError> {
        let got = distance(p, c);
        if got > self.options.max_correction_mm {
            return Err(self.fail(
                line_no,
                RewriteErrorKind::CorrectionTooLarge {
                    nominal: *p,
                    got_um: got * 1000.0,
                    bound_um: self.options.max_correction_mm * 1000.0,
                },
            ));
        }
        if got * 1000.0 > self.report.largest_correction_um {
            self.report.largest_correction_um = got * 1000.0;
            self.report.largest_correction_line = line_no;
        }
        Ok(())
    }

    fn check_limits(&self, c: &Pose, line_no: usize) -> Result<(), RewriteError> {
        let Some(limits) = &self.options.limits else {
            return Ok(());
        };
        for i in 0..N_AXIS {
            if c[i] < limits.min[i] - 1e-9 || c[i] > limits.max[i] + 1e-9 {
                return Err(self.fail(
                    line_no,
                    RewriteErrorKind::OutsideLimits {
                        axis: AXIS_LETTERS[i],
                        value: c[i],
                        min: limits.min[i],
                        max: limits.max[i],
                    },
                ));
            }
        }
        Ok(())
    }

    /// The block with its axis words set to the first piece, then one `G1` (or `G0`)
    /// line per further piece. Numbers are rounded as written, and in incremental mode
    /// each increment is taken from the previous rounded command so rounding does not
    /// accumulate.
    fn write_pieces(
        &mut self,
        block: &Block,
        start: Pose,
        pieces: &[(Pose, Pose, bool)],
        is_arc: bool,
        machine_coords: bool,
        line_no: usize,
    ) -> Result<Vec<String>, RewriteError> {
        let modal = self.interpreter.modal;
        let unit = if modal.inches { 25.4 } else { 1.0 };
        let decimals = if modal.inches { 5 } else { 4 };
        let wco = self.interpreter.wco();
        let incremental = modal.incremental && !machine_coords;
        let mut lines = Vec::with_capacity(pieces.len());
        let mut previous_nominal = start;
        for (k, (nominal, command, rapid)) in pieces.iter().enumerate() {
            let mut words: Vec<(usize, f64)> = Vec::new();
            for i in 0..N_AXIS {
                let moved = previous_nominal[i] != nominal[i] || command[i] != self.command[i];
                let named = k == 0 && block.word(AXIS_LETTERS[i]).is_some();
                if !(moved || named || (self.compensated[i] && k == 0)) {
                    continue;
                }
                let value = if incremental {
                    (command[i] - self.command[i]) / unit
                } else if machine_coords {
                    command[i] / unit
                } else {
                    (command[i] - wco[i]) / unit
                };
                let rounded = round_to(value, decimals);
                self.command[i] = if incremental {
                    self.command[i] + rounded * unit
                } else if machine_coords {
                    rounded * unit
                } else {
                    rounded * unit + wco[i]
                };
                words.push((i, rounded));
            }
            let line = if k == 0 {
                let mut first = block.clone();
                self.edit_first(&mut first, &words, is_arc, decimals)
                    .map_err(|e| self.fail(line_no, RewriteErrorKind::Model(e.to_string())))?;
                first.ending = nc::LineEnding::None;
                first.to_string()
            } else {
                let mut text = String::new();
                if machine_coords {
                    text.push_str("G53");
                }
                text.push_str(if *rapid { "G0" } else { "G1" });
                for (i, v) in &words {
                    text.push(AXIS_LETTERS[*i]);
                    text.push_str(&nc::format_number(*v, decimals).unwrap_or_default());
                }
                text
            };
            filter_line(&line).map_err(|e| self.fail(line_no, RewriteErrorKind::Filter(e)))?;
            lines.push(line);
            previous_nominal = *nominal;
        }
        Ok(lines)
    }

    /// The original block with its axis words replaced; an arc becomes a `G1` chord
    /// (centre words removed).
    fn edit_first(
        &self,
        block: &mut Block,
        words: &[(usize, f64)],
        is_arc: bool,
        decimals: usize,
    ) -> Result<(), nc::EditError> {
        if is_arc {
            for letter in ['I', 'J', 'K', 'R'] {
                while block.remove_word(letter).is_some() {}
            }
            let mut replaced = false;
            for item in &mut block.items {
                if let Item::Word(w) = item {
                    if w.letter() == 'G' && (w.value() == 2.0 || w.value() == 3.0) {
                        w.set_value(1.0, 0)?;
                        replaced = true;
                    }
                }
            }
            if !replaced {
                // A modal arc continuation: say G1 explicitly.
                let g1 = Word::new('G', 1.0, 0)?;
                let spaced = block.items.iter().any(|i| matches!(i, Item::Space(_)));
                if spaced {
                    block.items.insert(0, Item::Space(" ".into()));
                }
                block.items.insert(0, Item::Word(g1));
            }
        }
        for (i, v) in words {
            block.set_word(AXIS_LETTERS[*i], *v, decimals)?;
        }
        Ok(())
    }
}

/// The model's command for `p` with each axis arriving from `sides`, from a first guess;
/// the axes the model does not compensate as programmed.
fn command_on(
    comp: &dyn Compensation,
    compensated: &[bool; N_AXIS],
    sides: &[Approach; N_AXIS],
    p: &Pose,
    guess: &Pose,
) -> Result<Pose, String> {
    let c = comp.command_near(p, sides, guess)?;
    let mut out = *p;
    for i in 0..N_AXIS {
        if compensated[i] {
            out[i] = c[i];
        }
    }
    Ok(out)
}

fn round_to(v: f64, decimals: usize) -> f64 {
    let scale = 10f64.powi(decimals as i32);
    (v * scale).round() / scale
}

/// Rewrites a whole program; the output keeps the input's line endings.
pub fn rewrite_program(
    text: &str,
    compensation: &dyn Compensation,
    options: Options,
) -> Result<(String, Report), RewriteError> {
    let mut rewriter = Rewriter::new(compensation, options)?;
    let mut out = String::with_capacity(text.len() + text.len() / 4);
    for (index, (line, ending)) in nc::split_lines(text).enumerate() {
        let ending = match ending {
            nc::LineEnding::None => "\n",
            e => e.as_str(),
        };
        for piece in rewriter.line(line, index + 1)? {
            out.push_str(&piece);
            out.push_str(ending);
        }
    }
    if !text.ends_with(['\n', '\r']) && out.ends_with('\n') {
        out.pop();
    }
    Ok((out, rewriter.into_report()))
}

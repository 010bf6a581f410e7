//! The Fanuc dialect (ISO code, milling), sans-IO: what a closed controller reads from
//! its tape port, shared by the DNC emulator (`emulators dnc`, which executes it) and the
//! program rewriter (`gateway dnc`, which writes it).
//!
//! * [`parse_line`]: one line of a tape (without its LF) into a [`Line`]: the `%` tape
//!   mark, a blank line, or a [`FanucBlock`] with its words as written (whether each
//!   number had a decimal point matters: see below). Built on [`crate::nc`]'s lexer.
//! * [`Interpreter`]: the modal state (G0-G3, G17-G19, G20/G21, G90/G91, G54-G59,
//!   G61/G64, G92, G10 offsets, F) and what a block does ([`Action`]), in machine
//!   millimetres.
//!
//! What the public manuals fix and how it is read here (`../shared/notes/
//! legacy-controllers.md` has the sources):
//! * Decimal-point rule (parameter 3401#0 DPI): with DPI = 0 a dimension word without a
//!   point counts in least input increments (`X760` = 0.760 mm on IS-B, 0.0001 in with
//!   G20); DPI = 1 is the "calculator type" (`X760` = 760 mm). Default: DPI = 0
//!   ([`Options::calculator_input`] false). The increment is an option (IS-B default).
//! * `G04`: `X` (or `U`) in seconds when written with a point, in least increments of
//!   0.001 s without one (DPI = 0); `P` in milliseconds, never with a point.
//! * `O` and `N`: 1 to 5 digits (16i), `O0`/`N0` refused; `/` at the block start skips
//!   the block while the block-skip switch is on ([`Options::block_skip`]).
//! * `M98 P<repeats><program 4 digits>` (`P68003`: O8003 six times), `M99` returns.
//! * `G10 L2 P<0-6> X Y Z`: work offsets (P0 the external offset, P1-P6 G54-G59);
//!   absolute with G90, added with G91.
//! * `G61` exact stop mode and `G64` cutting mode (group 15, modal; `G64` at power-up),
//!   `G09` exact stop for its own block only (group 00, beside a motion code): where a
//!   block ends at rest, never where the tool goes. How far `G64` rounds a corner
//!   depends on the machine's acceleration parameters, which no manual gives: a
//!   controller's rounding is not modelled ([`Modal::exact_stop`] records the mode).
//!
//! What the manuals leave open is an option with its default stated, or refused:
//! * F without a point is read as written, in units per minute (*ours*; the rewriter
//!   always writes F with a point, so its output does not depend on it).
//! * Codes outside the list above (cutter compensation, canned cycles, G53, G68,
//!   macros...) are refused naming the block: the emulator alarms, the rewriter refuses.
//!   Their cancel codes (G40, G49, G80) and G94, the spindle and coolant M codes (M03,
//!   M04, M05, M08, M09), S and T are accepted and do nothing on the simulated stage.
//! * Characters outside the ISO subset (lower case, `;`, `"`, bytes above 0x7F) are
//!   refused, as a Fanuc raises its TH alarm for them.

use crate::nc::{Block, Item};
use std::fmt;

/// Digits a word may hold (sign and point not counted): ±99999.999 on IS-B.
pub const MAX_DIGITS: usize = 8;

/// The controller's parameters that change how a program reads.
#[derive(Clone, Debug, PartialEq)]
pub struct Options {
    /// Parameter 3401#0 DPI: a dimension without a decimal point is in whole units
    /// (`true`, "calculator type") or in least input increments (`false`, the default).
    pub calculator_input: bool,
    /// Least input increment in mm for G21 (IS-B: 0.001).
    pub increment_mm: f64,
    /// Least input increment in inches for G20 (IS-B: 0.0001).
    pub increment_inch: f64,
    /// The block-skip switch on the panel: blocks starting with `/` are skipped.
    pub block_skip: bool,
    /// Subprogram nesting depth (M98 inside a subprogram). 4 per a secondary source
    /// (the Fanuc page was not found), so it is an option.
    pub max_nesting: usize,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            calculator_input: false,
            increment_mm: 0.001,
            increment_inch: 0.0001,
            block_skip: true,
            max_nesting: 4,
        }
    }
}

/// One word as written: its letter, its value as written and whether it had a point.
#[derive(Clone, Debug, PartialEq)]
pub struct FanucWord {
    pub letter: char,
    pub value: f64,
    pub point: bool,
    pub text: String,
}

/// One block: `[/][N..] words`, comments dropped.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FanucBlock {
    pub skip: bool,
    pub n: Option<u32>,
    pub words: Vec<FanucWord>,
}

impl FanucBlock {
    /// The word with this letter (at most one, except G).
    pub fn word(&self, letter: char) -> Option<&FanucWord> {
        self.words.iter().find(|w| w.letter == letter)
    }

    /// The values of the G words, in order.
    pub fn g_codes(&self) -> impl Iterator<Item = f64> + '_ {
        self.words
            .iter()
            .filter(|w| w.letter == 'G')
            .map(|w| w.value)
    }

    /// The program number when the block is `O....` (a program start).
    pub fn program_number(&self) -> Option<u32> {
        self.word('O').map(|w| w.value as u32)
    }
}

/// A line of a tape.
#[derive(Clone, Debug, PartialEq)]
pub enum Line {
    /// `%`: the tape's start or end.
    Percent,
    /// No words (blank, or a comment only).
    Blank,
    Block(FanucBlock),
}

/// Why a block was refused: the controller's alarm, in words, with the block's line.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("block {line} `{text}`: {message}")]
pub struct FanucError {
    /// 1-based line of the tape or file.
    pub line: usize,
    /// The block as written (at most 80 characters).
    pub text: String,
    pub message: String,
}

impl FanucError {
    pub fn new(line: usize, text: &str, message: impl Into<String>) -> Self {
        let text: String = text.chars().take(80).collect();
        Self {
            line,
            text,
            message: message.into(),
        }
    }
}

/// Reads one line of a tape, without its end of block (LF; a CR before it is the
/// sender's and dropped by the caller). `line` is 1-based, for errors.
pub fn parse_line(text: &str, line: usize) -> Result<Line, FanucError> {
    let fail = |m: String| FanucError::new(line, text, m);
    if let Some(c) = text
        .chars()
        .find(|c| !(c.is_ascii_graphic() || *c == ' ' || *c == '\t') || c.is_ascii_lowercase())
    {
        return Err(fail(format!(
            "character {c:?} is not ISO code as the controller reads it (TH alarm)"
        )));
    }
    if let Some(c) = text.chars().find(|c| matches!(c, ';' | '"' | ',' | '\'')) {
        return Err(fail(format!(
            "character `{c}` is not ISO code (the end of block is LF) (TH alarm)"
        )));
    }
    let block = Block::parse(text, line).map_err(|e| fail(e.kind.to_string()))?;
    if block.items.iter().any(|i| matches!(i, Item::ProgramMarker)) {
        if block.has_no_words() && !block.block_delete {
            return Ok(Line::Percent);
        }
        return Err(fail("`%` must stand alone on its line".into()));
    }
    if block.has_no_words() {
        return Ok(Line::Blank);
    }
    let mut out = FanucBlock {
        skip: block.block_delete,
        ..FanucBlock::default()
    };
    for w in block.words() {
        let number = &w.text()[1..];
        let number = number.trim_start();
        let point = number.contains('.');
        let digits = number.chars().filter(char::is_ascii_digit).count();
        if digits > MAX_DIGITS {
            return Err(fail(format!(
                "`{}` has more than {MAX_DIGITS} digits",
                w.text()
            )));
        }
        let letter = w.letter();
        if point
            && matches!(
                letter,
                'O' | 'N' | 'G' | 'M' | 'P' | 'L' | 'T' | 'S' | 'H' | 'D'
            )
        {
            return Err(fail(format!(
                "`{}`: a decimal point is not allowed in {letter}",
                w.text()
            )));
        }
        if matches!(letter, 'O' | 'N')
            && (!(1.0..=99999.0).contains(&w.value()) || number.starts_with(['-', '+']))
        {
            return Err(fail(format!("`{}`: {letter} is 1 to 99999", w.text())));
        }
        if letter != 'G' && out.words.iter().any(|o| o.letter == letter) {
            return Err(fail(format!("address {letter} twice in the block")));
        }
        out.words.push(FanucWord {
            letter,
            value: w.value(),
            point,
            text: w.text().to_string(),
        });
    }
    if let Some(i) = out.words.iter().position(|w| w.letter == 'N') {
        if i == 0 {
            out.n = Some(out.words.remove(0).value as u32);
        } else {
            return Err(fail("N must be the first word of the block".into()));
        }
    }
    if out.word('O').is_some() && out.words.len() > 1 {
        return Err(fail(
            "O (a program number) must stand alone in its block".into(),
        ));
    }
    Ok(Line::Block(out))
}

/// Motion mode (group 01).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Motion {
    Rapid,
    Linear,
    ArcCw,
    ArcCcw,
}

/// Plane of arcs (group 02): the two axes of the plane, the third is linear.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Plane {
    /// G17: X Y, centre I J.
    Xy,
    /// G18: Z X, centre K I.
    Zx,
    /// G19: Y Z, centre J K.
    Yz,
}

impl Plane {
    /// Axis indices (0 X, 1 Y, 2 Z) of the plane's first and second axis, and the third.
    pub fn axes(self) -> (usize, usize, usize) {
        match self {
            Plane::Xy => (0, 1, 2),
            Plane::Zx => (2, 0, 1),
            Plane::Yz => (1, 2, 0),
        }
    }
}

/// The modal state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Modal {
    pub motion: Motion,
    pub plane: Plane,
    pub inch: bool,
    pub incremental: bool,
    /// 1..=6: G54..G59.
    pub work: usize,
    /// Group 15: `G61` exact stop mode (every block ends at rest, its position
    /// checked) when true, `G64` cutting mode when false.
    pub exact_stop: bool,
}

impl Default for Modal {
    /// Power-on state as usually set by parameters: G00 G17 G21 G90 G54 G64.
    fn default() -> Self {
        Self {
            motion: Motion::Rapid,
            plane: Plane::Xy,
            inch: false,
            incremental: false,
            work: 1,
            exact_stop: false,
        }
    }
}

/// What a block makes the machine do, in machine coordinates (mm, X Y Z).
#[derive(Clone, Debug, PartialEq)]
pub enum Action {
    /// G00 to `to`.
    Rapid {
        to: [f64; 3],
    },
    /// G01 to `to` at `feed` mm/min.
    Linear {
        to: [f64; 3],
        feed: f64,
    },
    /// G02/G03 from the current position to `to` around `centre` (the plane's two
    /// coordinates are the arc's, the third axis moves linearly).
    Arc {
        to: [f64; 3],
        centre: [f64; 3],
        clockwise: bool,
        plane: Plane,
        feed: f64,
    },
    Dwell {
        seconds: f64,
    },
    /// M98: run program `program` `repeats` times.
    Call {
        program: u32,
        repeats: u32,
    },
    /// M99.
    Return,
    /// M02 or M30.
    End,
}

/// The controller's interpreter: modal state, offsets and position.
#[derive(Clone, Debug, PartialEq)]
pub struct Interpreter {
    pub options: Options,
    pub modal: Modal,
    /// mm/min, once programmed.
    pub feed: Option<f64>,
    /// Machine position, mm.
    pub position: [f64; 3],
    /// Work offsets, mm: index 0 the external offset (added to every system), 1..=6
    /// G54..G59.
    pub work_offsets: [[f64; 3]; 7],
    /// The G92 shift, mm.
    pub shift: [f64; 3],
}

fn axis_index(letter: char) -> Option<usize> {
    match letter {
        'X' => Some(0),
        'Y' => Some(1),
        'Z' => Some(2),
        _ => None,
    }
}

impl Interpreter {
    pub fn new(options: Options, position: [f64; 3]) -> Self {
        Self {
            options,
            modal: Modal::default(),
            feed: None,
            position,
            work_offsets: [[0.0; 3]; 7],
            shift: [0.0; 3],
        }
    }

    /// Where the program coordinate system (work offset + external + G92) has its zero,
    /// in machine mm.
    pub fn origin(&self) -> [f64; 3] {
        let w = self.work_offsets[self.modal.work];
        let e = self.work_offsets[0];
        [0, 1, 2].map(|k| w[k] + e[k] + self.shift[k])
    }

    /// A dimension word in mm, by the decimal-point rule.
    pub fn dimension(&self, w: &FanucWord, inch: bool) -> f64 {
        let unit = if inch { 25.4 } else { 1.0 };
        if w.point || self.options.calculator_input {
            w.value * unit
        } else if inch {
            w.value * self.options.increment_inch * unit
        } else {
            w.value * self.options.increment_mm
        }
    }

    /// Executes one block (already read by [`parse_line`]; a skipped block gives no
    /// action). A refused block changes nothing.
    pub fn execute(
        &mut self,
        block: &FanucBlock,
        line: usize,
        text: &str,
    ) -> Result<Vec<Action>, FanucError> {
        let mut next = self.clone();
        let actions = next.run(block, line, text)?;
        *self = next;
        Ok(actions)
    }

    fn run(
        &mut self,
        block: &FanucBlock,
        line: usize,
        text: &str,
    ) -> Result<Vec<Action>, FanucError> {
        let fail = |m: String| FanucError::new(line, text, m);
        if block.skip && self.options.block_skip {
            return Ok(Vec::new());
        }
        if block.word('O').is_some() {
            return Ok(Vec::new());
        }
        // Non-modal G codes of group 00 and the modal groups, one per group.
        #[derive(PartialEq, Clone, Copy)]
        enum NonModal {
            Dwell,
            Offset,
            Shift,
        }
        let mut non_modal = None;
        // 0 motion, 1 plane, 2 units, 3 distance, 4 work system, 5 the block's group 00
        // action, 6 path mode (group 15), 7 G09.
        let mut groups = [false; 8];
        let mut set_group = |g: usize, code: f64| {
            if std::mem::replace(&mut groups[g], true) {
                Err(fail(format!("two G codes of one group (G{code})")))
            } else {
                Ok(())
            }
        };
        let mut modal = self.modal;
        for code in block.g_codes() {
            match code as u32 {
                0 => (set_group(0, code)?, modal.motion = Motion::Rapid).1,
                1 => (set_group(0, code)?, modal.motion = Motion::Linear).1,
                2 => (set_group(0, code)?, modal.motion = Motion::ArcCw).1,
                3 => (set_group(0, code)?, modal.motion = Motion::ArcCcw).1,
                4 | 10 | 92 => {
                    set_group(5, code)?;
                    non_modal = Some(match code as u32 {
                        4 => NonModal::Dwell,
                        10 => NonModal::Offset,
                        _ => NonModal::Shift,
                    });
                }
                17 => (set_group(1, code)?, modal.plane = Plane::Xy).1,
                18 => (set_group(1, code)?, modal.plane = Plane::Zx).1,
                19 => (set_group(1, code)?, modal.plane = Plane::Yz).1,
                20 => (set_group(2, code)?, modal.inch = true).1,
                21 => (set_group(2, code)?, modal.inch = false).1,
                90 => (set_group(3, code)?, modal.incremental = false).1,
                91 => (set_group(3, code)?, modal.incremental = true).1,
                54..=59 => (set_group(4, code)?, modal.work = code as usize - 53).1,
                61 => (set_group(6, code)?, modal.exact_stop = true).1,
                64 => (set_group(6, code)?, modal.exact_stop = false).1,
                // Exact stop at this block's end: its position and action are the same.
                9 => set_group(7, code)?,
                40 | 49 | 80 | 94 => {}
                _ => return Err(fail(format!("G{code} is not supported"))),
            }
        }
        for w in &block.words {
            let ok = match w.letter {
                'G' | 'X' | 'Y' | 'Z' | 'F' | 'M' | 'S' | 'T' => true,
                'P' => {
                    matches!(non_modal, Some(NonModal::Dwell | NonModal::Offset))
                        || block.word('M').is_some_and(|m| m.value == 98.0)
                }
                'L' => non_modal == Some(NonModal::Offset),
                'U' => non_modal == Some(NonModal::Dwell),
                'I' | 'J' | 'K' | 'R' => matches!(modal.motion, Motion::ArcCw | Motion::ArcCcw),
                _ => false,
            };
            if !ok {
                return Err(fail(format!("address {} is not supported here", w.letter)));
            }
        }
        self.modal.plane = modal.plane;
        self.modal.inch = modal.inch;
        self.modal.incremental = modal.incremental;
        self.modal.work = modal.work;
        self.modal.exact_stop = modal.exact_stop;
        if let Some(f) = block.word('F') {
            let unit = if self.modal.inch { 25.4 } else { 1.0 };
            if !(f.value > 0.0) {
                return Err(fail(format!("`{}`: the feed must be positive", f.text)));
            }
            self.feed = Some(f.value * unit);
        }
        let mut actions = Vec::new();
        let axis_words: Vec<&FanucWord> = block
            .words
            .iter()
            .filter(|w| axis_index(w.letter).is_some())
            .collect();
        match non_modal {
            Some(NonModal::Dwell) => {
                let p = block.word('P');
                let x = block.word('X').or(block.word('U'));
                let seconds = match (p, x) {
                    (Some(p), None) => p.value / 1000.0,
                    (None, Some(x)) if x.point || self.options.calculator_input => x.value,
                    (None, Some(x)) => x.value * 0.001,
                    (None, None) => 0.0,
                    (Some(_), Some(_)) => {
                        return Err(fail("G04 with both P and X/U".into()));
                    }
                };
                if !(0.0..=99999.999).contains(&seconds) {
                    return Err(fail(format!("dwell of {seconds} s")));
                }
                if block.words.iter().any(|w| matches!(w.letter, 'Y' | 'Z')) {
                    return Err(fail("G04 with an axis word".into()));
                }
                actions.push(Action::Dwell { seconds });
            }
            Some(NonModal::Offset) => {
                let l = block.word('L').map(|w| w.value);
                let p = block.word('P').map(|w| w.value);
                let index = match (l, p) {
                    (Some(l), Some(p)) if l == 2.0 && (0.0..=6.0).contains(&p) => p as usize,
                    _ => {
                        return Err(fail(
                            "only G10 L2 P0..P6 (work offsets) is supported".into(),
                        ))
                    }
                };
                for w in &axis_words {
                    let k = axis_index(w.letter).unwrap_or(0);
                    let v = self.dimension(w, self.modal.inch);
                    if self.modal.incremental {
                        self.work_offsets[index][k] += v;
                    } else {
                        self.work_offsets[index][k] = v;
                    }
                }
            }
            Some(NonModal::Shift) => {
                let origin = self.origin();
                for w in &axis_words {
                    let k = axis_index(w.letter).unwrap_or(0);
                    let v = self.dimension(w, self.modal.inch);
                    // The current position reads `v` from now on.
                    self.shift[k] += self.position[k] - origin[k] - v;
                }
            }
            None => {
                self.modal.motion = modal.motion;
                if !axis_words.is_empty() {
                    actions.push(self.motion(block, &axis_words, &fail)?);
                } else if block
                    .words
                    .iter()
                    .any(|w| matches!(w.letter, 'I' | 'J' | 'K' | 'R'))
                {
                    return Err(fail("an arc without an end point".into()));
                }
            }
        }
        if let Some(m) = block.word('M') {
            match m.value as u32 {
                2 | 30 => actions.push(Action::End),
                3 | 4 | 5 | 8 | 9 => {}
                98 => {
                    let p = block
                        .word('P')
                        .ok_or_else(|| fail("M98 without P".into()))?
                        .value as u64;
                    let program = (p % 10_000) as u32;
                    let repeats = (p / 10_000).max(1) as u32;
                    if program == 0 || repeats > 9999 {
                        return Err(fail(format!("M98 P{p}: no such program")));
                    }
                    actions.push(Action::Call { program, repeats });
                }
                99 => actions.push(Action::Return),
                _ => return Err(fail(format!("{} is not supported", m.text))),
            }
        }
        Ok(actions)
    }

    fn motion(
        &mut self,
        block: &FanucBlock,
        axis_words: &[&FanucWord],
        fail: &dyn Fn(String) -> FanucError,
    ) -> Result<Action, FanucError> {
        let origin = self.origin();
        let mut to = self.position;
        for w in axis_words {
            let k = axis_index(w.letter).unwrap_or(0);
            let v = self.dimension(w, self.modal.inch);
            to[k] = if self.modal.incremental {
                self.position[k] + v
            } else {
                origin[k] + v
            };
        }
        let feed = || {
            self.feed
                .ok_or_else(|| fail("a feed motion without a feed (F)".into()))
        };
        let action = match self.modal.motion {
            Motion::Rapid => Action::Rapid { to },
            Motion::Linear => Action::Linear { to, feed: feed()? },
            Motion::ArcCw | Motion::ArcCcw => {
                let clockwise = self.modal.motion == Motion::ArcCw;
                let plane = self.modal.plane;
                let (a, b, _) = plane.axes();
                let from = self.position;
                let offset_letters = ['I', 'J', 'K'];
                let mut centre = from;
                if let Some(r) = block.word('R') {
                    if block
                        .words
                        .iter()
                        .any(|w| offset_letters.contains(&w.letter))
                    {
                        return Err(fail("an arc with both R and I/J/K".into()));
                    }
                    let r = self.dimension(r, self.modal.inch);
                    let (dx, dy) = (to[a] - from[a], to[b] - from[b]);
                    let d = dx.hypot(dy);
                    if d < 1e-9 {
                        return Err(fail("an R arc whose end is its start".into()));
                    }
                    let h2 = r * r - d * d / 4.0;
                    if h2 < -1e-6 * r.abs().max(1.0) {
                        return Err(fail(format!(
                            "radius {:.4} mm is shorter than half the chord {:.4} mm",
                            r.abs(),
                            d / 2.0
                        )));
                    }
                    let h = h2.max(0.0).sqrt();
                    // Left of the chord for a clockwise arc under 180 degrees.
                    let side = if clockwise == (r > 0.0) { -1.0 } else { 1.0 };
                    centre[a] = from[a] + dx / 2.0 - side * h * dy / d;
                    centre[b] = from[b] + dy / 2.0 + side * h * dx / d;
                } else {
                    for (k, letter) in offset_letters.iter().enumerate() {
                        if let Some(w) = block.word(*letter) {
                            if k != a && k != b {
                                return Err(fail(format!(
                                    "{letter} is not an axis of the arc's plane"
                                )));
                            }
                            centre[k] = from[k] + self.dimension(w, self.modal.inch);
                        }
                    }
                    let r0 = (from[a] - centre[a]).hypot(from[b] - centre[b]);
                    let r1 = (to[a] - centre[a]).hypot(to[b] - centre[b]);
                    if r0 < 1e-6 || (r0 - r1).abs() > 0.001 + 1e-6 * r0 {
                        return Err(fail(format!(
                            "the arc's end is not on its circle (radius {r0:.4} at the start, {r1:.4} at the end)"
                        )));
                    }
                }
                Action::Arc {
                    to,
                    centre,
                    clockwise,
                    plane,
                    feed: feed()?,
                }
            }
        };
        self.position = to;
        Ok(action)
    }
}

/// Points along an arc from `from` (exclusive) to its end (inclusive), chords within
/// `tolerance_mm` of the arc; a full circle when the end is the start (I/J/K form).
pub fn arc_points(from: [f64; 3], arc: &Action, tolerance_mm: f64) -> Vec<[f64; 3]> {
    let Action::Arc {
        to,
        centre,
        clockwise,
        plane,
        ..
    } = arc
    else {
        return Vec::new();
    };
    let (a, b, c) = plane.axes();
    let r = (from[a] - centre[a]).hypot(from[b] - centre[b]);
    let a0 = (from[b] - centre[b]).atan2(from[a] - centre[a]);
    let a1 = (to[b] - centre[b]).atan2(to[a] - centre[a]);
    let tau = std::f64::consts::TAU;
    let mut sweep = if *clockwise { a0 - a1 } else { a1 - a0 };
    sweep = sweep.rem_euclid(tau);
    if sweep < 1e-12 {
        sweep = tau;
    }
    let step = 2.0
        * (1.0 - tolerance_mm.max(1e-9) / r.max(1e-9))
            .clamp(-1.0, 1.0)
            .acos();
    let n = ((sweep / step.max(1e-6)).ceil() as usize).clamp(1, 100_000);
    let sign = if *clockwise { -1.0 } else { 1.0 };
    (1..=n)
        .map(|i| {
            if i == n {
                return *to;
            }
            let t = i as f64 / n as f64;
            let ang = a0 + sign * sweep * t;
            let mut p = [0.0; 3];
            p[a] = centre[a] + r * ang.cos();
            p[b] = centre[b] + r * ang.sin();
            p[c] = from[c] + (to[c] - from[c]) * t;
            p
        })
        .collect()
}

impl fmt::Display for FanucBlock {
    /// The block in the controller's form: `/`, `N`, then the words as written.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.skip {
            f.write_str("/")?;
        }
        if let Some(n) = self.n {
            write!(f, "N{n}")?;
        }
        for w in &self.words {
            f.write_str(&w.text)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn block(text: &str) -> FanucBlock {
        match parse_line(text, 1) {
            Ok(Line::Block(b)) => b,
            other => panic!("{text}: {other:?}"),
        }
    }

    fn run(i: &mut Interpreter, text: &str) -> Vec<Action> {
        i.execute(&block(text), 1, text).unwrap()
    }

    #[test]
    fn decimal_point_rule_and_calculator_input() {
        let mut i = Interpreter::new(Options::default(), [0.0; 3]);
        assert_eq!(
            run(&mut i, "G90G0X760Y1.5"),
            vec![Action::Rapid {
                to: [0.76, 1.5, 0.0]
            }]
        );
        run(&mut i, "G20");
        assert_eq!(
            run(&mut i, "X10000"),
            vec![Action::Rapid {
                to: [25.4, 1.5, 0.0]
            }]
        );
        let mut c = Interpreter::new(
            Options {
                calculator_input: true,
                ..Options::default()
            },
            [0.0; 3],
        );
        assert_eq!(
            run(&mut c, "G0X760"),
            vec![Action::Rapid {
                to: [760.0, 0.0, 0.0]
            }]
        );
    }

    #[test]
    fn exact_stop_codes_set_the_mode_and_move_as_written() {
        let mut i = Interpreter::new(Options::default(), [0.0; 3]);
        assert!(!i.modal.exact_stop, "G64 at power-up");
        assert_eq!(
            run(&mut i, "G61G01X1.F100"),
            vec![Action::Linear {
                to: [1.0, 0.0, 0.0],
                feed: 100.0
            }]
        );
        assert!(i.modal.exact_stop);
        // G09 stops its own block only and sets no mode; G64 sets cutting mode.
        assert_eq!(
            run(&mut i, "G64G09X2."),
            vec![Action::Linear {
                to: [2.0, 0.0, 0.0],
                feed: 100.0
            }]
        );
        assert!(!i.modal.exact_stop);
        for (text, why) in [
            ("G61G64X3.", "two G codes of one group (G64)"),
            ("G09G09X3.", "two G codes of one group (G9)"),
        ] {
            let e = i.execute(&block(text), 7, text).unwrap_err();
            assert!(e.to_string().contains(why), "{text}: {e}");
        }
        // No G code has a decimal here (`G61.1` is LinuxCNC's): refused as it is read.
        let e = parse_line("G61.1X3.", 8).unwrap_err();
        assert!(
            e.to_string()
                .contains("a decimal point is not allowed in G"),
            "{e}"
        );
        // A refused block changed nothing.
        assert_eq!(i.position, [2.0, 0.0, 0.0]);
        assert!(!i.modal.exact_stop);
    }

    #[test]
    fn dwell_words() {
        let mut i = Interpreter::new(Options::default(), [0.0; 3]);
        assert_eq!(run(&mut i, "G04X1.5"), vec![Action::Dwell { seconds: 1.5 }]);
        assert_eq!(
            run(&mut i, "G04X1500"),
            vec![Action::Dwell { seconds: 1.5 }]
        );
        assert_eq!(run(&mut i, "G04U2."), vec![Action::Dwell { seconds: 2.0 }]);
        assert_eq!(
            run(&mut i, "G04P250"),
            vec![Action::Dwell { seconds: 0.25 }]
        );
        assert!(parse_line("G04P2.5", 3)
            .unwrap_err()
            .to_string()
            .contains("block 3"));
        // A dwell moves nothing.
        assert_eq!(i.position, [0.0; 3]);
    }

    #[test]
    fn offsets_shift_and_incremental() {
        let mut i = Interpreter::new(Options::default(), [0.0; 3]);
        run(&mut i, "G10L2P2X10.Y20.");
        assert_eq!(
            run(&mut i, "G55G0X1.Y1."),
            vec![Action::Rapid {
                to: [11.0, 21.0, 0.0]
            }]
        );
        run(&mut i, "G92X0Y0");
        assert_eq!(
            run(&mut i, "G1X2.F100"),
            vec![Action::Linear {
                to: [13.0, 21.0, 0.0],
                feed: 100.0
            }]
        );
        assert_eq!(
            run(&mut i, "G91X-1."),
            vec![Action::Linear {
                to: [12.0, 21.0, 0.0],
                feed: 100.0
            }]
        );
    }

    #[test]
    fn arcs_by_radius_and_by_centre_agree() {
        let mut i = Interpreter::new(Options::default(), [0.0; 3]);
        run(&mut i, "G1F100.");
        let r = run(&mut i, "G2X10.Y0R5.");
        let mut j = Interpreter::new(Options::default(), [0.0; 3]);
        run(&mut j, "G1F100.");
        let c = run(&mut j, "G2X10.Y0I5.J0");
        let centre = |a: &Action| match a {
            Action::Arc { centre, .. } => *centre,
            _ => panic!(),
        };
        let (a, b) = (centre(&r[0]), centre(&c[0]));
        assert!(
            (a[0] - b[0]).abs() < 1e-9 && (a[1] - b[1]).abs() < 1e-9,
            "{a:?} {b:?}"
        );
        // Clockwise from (0,0) to (10,0) about (5,0) passes through (5,5).
        let pts = arc_points([0.0; 3], &c[0], 0.0001);
        assert!(pts.iter().any(|p| (p[0] - 5.0).abs() < 0.05 && p[1] > 4.99));
        assert_eq!(*pts.last().unwrap(), [10.0, 0.0, 0.0]);
    }

    #[test]
    fn refusals_name_the_block() {
        for (text, what) in [
            ("g1x1.", "ISO"),
            ("G1X1.;", "ISO"),
            ("G41X1.", "G41"),
            ("G1X1.", "feed"),
            ("O0", "1 to 99999"),
            ("X1.N5", "first word"),
            ("M98", "without P"),
            ("X123456789", "digits"),
            ("G2X1.Y1.R0.1F1.", "shorter than half"),
        ] {
            let r = parse_line(text, 7).and_then(|l| match l {
                Line::Block(b) => Interpreter::new(Options::default(), [0.0; 3])
                    .execute(&b, 7, text)
                    .map(|_| ()),
                _ => Ok(()),
            });
            let e = r.expect_err(text).to_string();
            assert!(e.contains("block 7") && e.contains(what), "{text}: {e}");
        }
    }

    #[test]
    fn subprogram_calls_and_skip() {
        let mut i = Interpreter::new(Options::default(), [0.0; 3]);
        assert_eq!(
            run(&mut i, "M98P68003"),
            vec![Action::Call {
                program: 8003,
                repeats: 6
            }]
        );
        assert_eq!(run(&mut i, "/G0X5."), vec![]);
        assert_eq!(parse_line("%", 1).unwrap(), Line::Percent);
        assert_eq!(parse_line("(ONLY A COMMENT)", 1).unwrap(), Line::Blank);
    }
}

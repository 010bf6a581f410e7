//! The G-code subset GRBL 1.1 accepts: GRBL's line filter, a parser and interpreter
//! that give the same `error:N` codes GRBL gives for the same block, and a writer.
//!
//! The interpreter follows GRBL's `gc_execute_line` in its documented order: words are
//! read (letters, numbers, repeated words, modal group clashes), then checked against
//! the modal state (feed rate defined, axis words present, arc geometry, unused words),
//! and only a block that passes every check changes the state. A refused block changes
//! nothing, as on the device. It is sans-IO: what a block asks for comes back as
//! [`Action`]s (moves in machine millimetres, dwells, syncs) for a caller to execute.
//!
//! Words come from the dialect-neutral [`crate::nc`] lexer; what is GRBL's stays here:
//! its line filter and 80-byte buffer, which letters and commands it knows, its modal
//! groups, its error codes ([`GcodeError`]) and the order it checks them in. The steps:
//!
//! * `read`: words into modal groups and value slots (errors while reading);
//! * `check`: the block against the state, in GRBL's order, into a plan (no change);
//! * `run`: the plan carried out: state changes and actions;
//! * `arc`: arcs as chords within the arc tolerance;
//! * `state`: the words, modal groups, actions and interpreter state the steps share.

mod arc;
#[cfg(test)]
mod axes;
#[cfg(test)]
mod characterization;
mod check;
mod error;
#[cfg(test)]
mod fuzz;
mod read;
mod run;
mod state;

pub use error::GcodeError;
pub use state::{
    Action, Interpreter, Modal, Motion, Plane, ProgramFlow, Rate, Spindle, Word, AXIS_LETTERS,
    FIRST_ROTARY, MAX_AXES, MM_PER_INCH, N_AXIS,
};

use crate::nc;
use read::BlockWords;
use std::fmt;

/// GRBL's line buffer is 80 bytes with a terminating zero: 79 characters fit.
pub const LINE_BUFFER_SIZE: usize = 80;

/// Why a line cannot go to GRBL as written.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum FilterError {
    #[error("{len} characters after removing spaces and comments; GRBL's line buffer holds {} (error:11)", LINE_BUFFER_SIZE - 1)]
    Overflow { len: usize },
    #[error("contains `{0}`, which GRBL would take as a real-time command")]
    Realtime(char),
    #[error("contains byte 0x{0:02X}, which GRBL discards")]
    NonAscii(u32),
}

/// GRBL's input filter (protocol.c), applied to the bytes of one line without its
/// ending: whitespace and control characters, `/`, `(...)` and `;...` comments are
/// dropped, letters upper-cased. Returns the filtered text and whether it overflowed
/// GRBL's line buffer (the device answers `error:11` for such a line).
pub fn filter_bytes(raw: &[u8]) -> (String, bool) {
    let mut out = String::new();
    // Bytes kept, as GRBL counts them (a byte above 0x7F is one character here but
    // two bytes of `out`).
    let mut kept = 0;
    let mut paren = false;
    let mut semicolon = false;
    let mut overflow = false;
    for &c in raw {
        if paren || semicolon || overflow {
            if c == b')' && paren {
                paren = false;
            }
            continue;
        }
        match c {
            0..=b' ' | b'/' => {}
            b'(' => paren = true,
            b';' => semicolon = true,
            _ if kept >= LINE_BUFFER_SIZE - 1 => overflow = true,
            _ => {
                out.push(c.to_ascii_uppercase() as char);
                kept += 1;
            }
        }
    }
    (out, overflow)
}

/// A host-side check of a program line: GRBL's filter, refusing what GRBL could not
/// receive intact (overflow, real-time characters, non-ASCII).
pub fn filter_line(raw: &str) -> Result<String, FilterError> {
    // Outside comments a real-time character would be intercepted; inside comments
    // it is removed here with the comment, so only the filtered text matters.
    let (text, overflow) = filter_bytes(raw.as_bytes());
    if overflow {
        return Err(FilterError::Overflow {
            len: filtered_len(raw.as_bytes()),
        });
    }
    if let Some(c) = text.chars().find(|c| !c.is_ascii()) {
        return Err(FilterError::NonAscii(c as u32));
    }
    if let Some(c) = text.chars().find(|c| matches!(c, '?' | '!' | '~')) {
        return Err(FilterError::Realtime(c));
    }
    Ok(text)
}

/// Length the filtered line would have without GRBL's limit (for the error message).
fn filtered_len(raw: &[u8]) -> usize {
    let mut n = 0;
    let (mut paren, mut semi) = (false, false);
    for &c in raw {
        if paren || semi {
            if c == b')' && paren {
                paren = false;
            }
            continue;
        }
        match c {
            0..=b' ' | b'/' => {}
            b'(' => paren = true,
            b';' => semi = true,
            _ => n += 1,
        }
    }
    n
}

/// Split a filtered line into words (GRBL step 1): error 1 for a missing letter,
/// error 2 for a missing or malformed number.
pub fn words(line: &str) -> Result<Vec<Word>, u8> {
    grbl_words(line).map_err(|e| e.code())
}

/// The nc lexer's words, read as GRBL reads a filtered line: upper-case letters each
/// followed at once by a number. What the lexer accepts besides (spaces, comments,
/// `/`, `%`, lower case) GRBL's filter would have removed, so here it is a character
/// where a letter should be (error 1), or for a space after the letter a missing
/// number (error 2). Errors come in the order the characters do, as on the device.
fn grbl_words(line: &str) -> Result<Vec<Word>, GcodeError> {
    nc::lex(line, 1).map(grbl_word).collect()
}

fn grbl_word(token: Result<nc::Token<'_>, nc::NcError>) -> Result<Word, GcodeError> {
    let token = token.map_err(|e| GcodeError::from_lex(&e))?;
    let nc::TokenKind::Word {
        letter,
        value,
        number,
    } = token.kind
    else {
        return Err(GcodeError::ExpectedCommandLetter);
    };
    if !token.text.starts_with(|c: char| c.is_ascii_uppercase()) {
        return Err(GcodeError::ExpectedCommandLetter);
    }
    if token.text.len() != 1 + number.len() {
        return Err(GcodeError::BadNumberFormat);
    }
    Ok(Word { letter, value })
}

impl<const N: usize> Default for Interpreter<N> {
    fn default() -> Self {
        Self::with_axes()
    }
}

impl Interpreter {
    /// GRBL 1.1's three axes, X Y Z.
    pub fn new() -> Self {
        Self::with_axes()
    }
}

impl<const N: usize> Interpreter<N> {
    /// Only 3 to 6 axes (X Y Z, then A B C) exist: checked when compiling.
    const AXES_IN_RANGE: () = assert!(N >= N_AXIS && N <= MAX_AXES);

    /// A controller with `N` axes, the first `N` of X Y Z A B C.
    pub fn with_axes() -> Self {
        let () = Self::AXES_IN_RANGE;
        Self {
            modal: Modal::default(),
            feed_rate: 0.0,
            spindle_speed: 0.0,
            tool: 0,
            line_number: 0,
            position: [0.0; N],
            coord_system: [0.0; N],
            coord_offset: [0.0; N],
            tool_length_offset: 0.0,
            stored: [[0.0; N]; 8],
            arc_tolerance: 0.002,
            probe: ([0.0; N], false),
            axes: N,
        }
    }

    /// Drive only the first `axes` of the `N` (clamped to 3..=N): a device that keeps
    /// six slots but was built with fewer axes.
    pub fn restrict_axes(mut self, axes: usize) -> Self {
        self.axes = axes.clamp(N_AXIS, N);
        self
    }

    /// GRBL's `gc_init` after a reset: modal state and G92 back to defaults, the G54
    /// offset reloaded, stored parameters kept, position synced by the caller.
    pub fn reset(&mut self) {
        let stored = self.stored;
        let position = self.position;
        let tol = self.arc_tolerance;
        let probe = self.probe;
        let axes = self.axes;
        *self = Self::with_axes();
        self.axes = axes;
        self.stored = stored;
        self.position = position;
        self.arc_tolerance = tol;
        self.probe = probe;
        self.coord_system = stored[0];
    }

    /// Work coordinate offset: what `WCO:` reports (MPos = WPos + WCO).
    pub fn wco(&self) -> [f64; N] {
        let mut w = [0.0; N];
        for i in 0..N {
            w[i] = self.coord_system[i] + self.coord_offset[i];
        }
        w[2] += self.tool_length_offset;
        w
    }

    /// `[GC:...]` contents (reply to `$G`), as GRBL 1.1 prints them.
    pub fn parser_state(&self) -> String {
        self.parser_state_with(false)
    }

    /// `$G` as GRBL prints it with `$13` (report inches) set or not. GRBL stores the
    /// feed in mm/min whatever G20/G21 says, and prints it in inches only with `$13=1`
    /// (`printFloat_RateValue`: 1 decimal in inches, none in mm).
    pub fn parser_state_with(&self, report_inches: bool) -> String {
        let m = &self.modal;
        let feed = if report_inches {
            format!("{:.1}", self.feed_rate / MM_PER_INCH)
        } else {
            format!("{:.0}", self.feed_rate)
        };
        format!(
            "{} G{} G{} G{} G{} G{}{}{}{} T{} F{feed} S{:.0}",
            motion_code(m.motion),
            54 + m.coord_select,
            plane_code(m.plane),
            if m.inches { 20 } else { 21 },
            if m.incremental { 91 } else { 90 },
            if m.inverse_time { 93 } else { 94 },
            program_flow_code(m.program_flow),
            spindle_code(m.spindle),
            if m.flood { " M8" } else { " M9" },
            self.tool,
            self.spindle_speed
        )
    }

    /// Execute one filtered line (`jog`: the part after `$J=`). On error the state is
    /// unchanged and GRBL's status code comes back.
    pub fn execute(&mut self, line: &str, jog: bool) -> Result<Vec<Action<N>>, u8> {
        self.execute_block(line, jog).map_err(|e| e.code())
    }

    /// GRBL's `gc_execute_line`: read the words, check the block against the state
    /// (without changing it), then run it.
    fn execute_block(&mut self, line: &str, jog: bool) -> Result<Vec<Action<N>>, GcodeError> {
        let words = grbl_words(line)?;
        let block = BlockWords::read(&words, self.modal, jog, self.axes)?;
        let plan = self.plan(block, jog)?;
        Ok(self.run(plan, jog))
    }
}

fn motion_code(motion: Motion) -> String {
    match motion {
        Motion::Rapid => "G0".into(),
        Motion::Linear => "G1".into(),
        Motion::ArcCw => "G2".into(),
        Motion::ArcCcw => "G3".into(),
        Motion::Probe(d) => format!("G38.{d}"),
        Motion::None => "G80".into(),
    }
}

fn plane_code(plane: Plane) -> u8 {
    match plane {
        Plane::XY => 17,
        Plane::ZX => 18,
        Plane::YZ => 19,
    }
}

/// The program flow word `$G` shows (none while running).
fn program_flow_code(flow: ProgramFlow) -> &'static str {
    match flow {
        ProgramFlow::Running => "",
        ProgramFlow::Paused => " M0",
        ProgramFlow::EndM2 => " M2",
        ProgramFlow::EndM30 => " M30",
    }
}

fn spindle_code(spindle: Spindle) -> &'static str {
    match spindle {
        Spindle::Cw => " M3",
        Spindle::Ccw => " M4",
        Spindle::Off => " M5",
    }
}

/// A G-code block to write: words in order, numbers with at most `decimals` decimals
/// and no trailing zeros, no spaces (fewer bytes in GRBL's RX buffer).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BlockWriter {
    words: Vec<(char, f64, usize)>,
}

impl BlockWriter {
    pub fn new() -> Self {
        Self::default()
    }

    /// A command word such as G53 or G1 (`G38.2` as `g(38.2)`).
    pub fn g(mut self, code: f64) -> Self {
        self.words.push(('G', code, 1));
        self
    }

    pub fn m(mut self, code: f64) -> Self {
        self.words.push(('M', code, 0));
        self
    }

    /// A value word with the given number of decimals.
    pub fn word(mut self, letter: char, value: f64, decimals: usize) -> Self {
        self.words.push((letter, value, decimals));
        self
    }
}

impl fmt::Display for BlockWriter {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (l, v, d) in &self.words {
            write!(f, "{l}{}", super::command::trim_float(*v, *d))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::super::codes::status as e;
    use super::*;

    fn run(i: &mut Interpreter, l: &str) -> Result<Vec<Action>, u8> {
        let (f, over) = filter_bytes(l.as_bytes());
        assert!(!over);
        i.execute(&f, false)
    }

    fn mv(target: [f64; 3], rate: Rate) -> Action {
        Action::Move {
            target,
            rate,
            line_number: None,
            jog: false,
        }
    }

    #[test]
    fn filter_matches_grbl() {
        assert_eq!(
            filter_bytes(b"g1 x1.5 (comment ? !) y-2 ; rest\r"),
            ("G1X1.5Y-2".to_string(), false)
        );
        assert_eq!(filter_bytes(b"/G0 X1"), ("G0X1".to_string(), false));
        let long = "X".repeat(100);
        assert!(filter_bytes(long.as_bytes()).1);
        assert!(!filter_bytes("X".repeat(79).as_bytes()).1);
        assert!(filter_bytes("X".repeat(80).as_bytes()).1);
        // Counted in bytes received, as GRBL counts them, whatever the bytes.
        assert!(!filter_bytes(&[0xFF; 79]).1);
        assert!(filter_bytes(&[0xFF; 80]).1);
        assert_eq!(filter_line("G1X1!"), Err(FilterError::Realtime('!')));
        assert_eq!(filter_line("G1X1 (ok?)").unwrap(), "G1X1");
    }

    #[test]
    fn word_errors() {
        let mut i = Interpreter::new();
        assert_eq!(run(&mut i, "1X"), Err(e::EXPECTED_COMMAND_LETTER));
        assert_eq!(run(&mut i, "G1X"), Err(e::BAD_NUMBER_FORMAT));
        assert_eq!(run(&mut i, "G1X."), Err(e::BAD_NUMBER_FORMAT));
        assert_eq!(run(&mut i, "G1X1.2.3"), Err(e::EXPECTED_COMMAND_LETTER));
        assert_eq!(run(&mut i, "G7"), Err(e::UNSUPPORTED_COMMAND));
        assert_eq!(run(&mut i, "M7"), Err(e::UNSUPPORTED_COMMAND));
        assert_eq!(run(&mut i, "G1.5"), Err(e::COMMAND_VALUE_NOT_INTEGER));
        assert_eq!(run(&mut i, "G59.1"), Err(e::COMMAND_VALUE_NOT_INTEGER));
        assert_eq!(run(&mut i, "G38.1X1"), Err(e::UNSUPPORTED_COMMAND));
        assert_eq!(run(&mut i, "G0G1X1"), Err(e::AXIS_COMMAND_CONFLICT));
        assert_eq!(run(&mut i, "G20G21"), Err(e::MODAL_GROUP_VIOLATION));
        assert_eq!(run(&mut i, "G0X1X2"), Err(e::WORD_REPEATED));
        assert_eq!(run(&mut i, "G1X1F-1"), Err(e::NEGATIVE_VALUE));
        assert_eq!(run(&mut i, "G1X1"), Err(e::UNDEFINED_FEED_RATE));
        assert_eq!(run(&mut i, "G4"), Err(e::VALUE_WORD_MISSING));
        assert_eq!(run(&mut i, "G2X1F100"), Err(e::NO_OFFSETS_IN_PLANE));
        assert_eq!(run(&mut i, "G2Z1F100"), Err(e::NO_AXIS_WORDS_IN_PLANE));
        assert_eq!(run(&mut i, "G2X10R1F100"), Err(e::ARC_RADIUS_ERROR));
        assert_eq!(run(&mut i, "G0X1P1"), Err(e::UNUSED_WORDS));
        assert_eq!(run(&mut i, "G80X1"), Err(e::AXIS_WORDS_EXIST));
        assert_eq!(run(&mut i, "G2G53X1F1"), Err(e::G53_INVALID_MOTION_MODE));
        assert_eq!(run(&mut i, "N99999999G0"), Err(e::INVALID_LINE_NUMBER));
        assert_eq!(run(&mut i, "T300"), Err(e::MAX_VALUE_EXCEEDED));
        assert_eq!(run(&mut i, "G10L2P9X1"), Err(e::UNSUPPORTED_COORD_SYS));
        assert_eq!(run(&mut i, "G10X1"), Err(e::VALUE_WORD_MISSING));
        assert_eq!(run(&mut i, "G10P1X1"), Err(e::UNSUPPORTED_COMMAND));
        assert_eq!(i, Interpreter::new(), "refused blocks change nothing");
        // GRBL 1.1h: without P, G10 L2 sets the active system (G54 here).
        run(&mut i, "G10L2X1").unwrap();
        assert_eq!(i, {
            let mut g54 = Interpreter::new();
            run(&mut g54, "G10L2P1X1").unwrap();
            g54
        });
    }

    #[test]
    fn moves_offsets_units_and_modes() {
        let mut i = Interpreter::new();
        assert_eq!(
            run(&mut i, "G0X10Y5").unwrap(),
            vec![mv([10.0, 5.0, 0.0], Rate::Rapid)]
        );
        assert_eq!(
            run(&mut i, "G1X11F600").unwrap(),
            vec![mv([11.0, 5.0, 0.0], Rate::Feed(600.0))]
        );
        assert_eq!(
            run(&mut i, "X12").unwrap(),
            vec![mv([12.0, 5.0, 0.0], Rate::Feed(600.0))]
        );
        assert_eq!(
            run(&mut i, "G1").unwrap(),
            vec![],
            "G1 with no axis words moves nothing"
        );
        run(&mut i, "G10L2P1X100").unwrap();
        assert_eq!(i.wco(), [100.0, 0.0, 0.0]);
        assert_eq!(
            run(&mut i, "X1").unwrap(),
            vec![mv([101.0, 5.0, 0.0], Rate::Feed(600.0))]
        );
        assert_eq!(
            run(&mut i, "G53X1").unwrap(),
            vec![mv([1.0, 5.0, 0.0], Rate::Feed(600.0))]
        );
        run(&mut i, "G92X0Y0").unwrap();
        assert_eq!(i.wco(), [1.0, 5.0, 0.0]);
        run(&mut i, "G92.1").unwrap();
        assert_eq!(i.wco(), [100.0, 0.0, 0.0]);
        run(&mut i, "G20G91").unwrap();
        assert_eq!(
            run(&mut i, "X1").unwrap(),
            vec![mv([26.4, 5.0, 0.0], Rate::Feed(600.0))]
        );
        // GRBL stores mm/min: G20 does not change how `$G` prints the feed; `$13=1` does.
        assert_eq!(i.parser_state(), "G1 G54 G17 G20 G91 G94 M5 M9 T0 F600 S0");
        assert_eq!(
            i.parser_state_with(true),
            "G1 G54 G17 G20 G91 G94 M5 M9 T0 F23.6 S0"
        );
        run(&mut i, "G21G90M3S1000").unwrap();
        assert!(i.parser_state().contains("M3") && i.parser_state().ends_with("S1000"));
        let a = run(&mut i, "M2").unwrap();
        assert_eq!(a.last(), Some(&Action::ProgramEnd));
        assert!(i.parser_state().starts_with("G1 G54 G17 G21 G90 G94 M5 M9"));
    }

    #[test]
    fn arcs_are_chords_on_the_circle_ending_at_the_target() {
        let mut i = Interpreter::new();
        i.arc_tolerance = 0.002;
        run(&mut i, "G0X10Y0").unwrap();
        let a = run(&mut i, "G3X-10Y0I-10J0F1000").unwrap();
        assert!(a.len() > 20, "{} segments", a.len());
        for act in &a {
            let Action::Move { target, .. } = act else {
                panic!()
            };
            let r = target[0].hypot(target[1]);
            assert!((r - 10.0).abs() < 1e-9, "point off the circle: {target:?}");
            assert!(target[1] >= -1e-9, "CCW from +X to -X passes through +Y");
        }
        assert_eq!(a.last(), Some(&mv([-10.0, 0.0, 0.0], Rate::Feed(1000.0))));
        // Radius form, same half circle clockwise goes through -Y.
        let mut j = Interpreter::new();
        run(&mut j, "G0X10Y0").unwrap();
        let b = run(&mut j, "G2X-10Y0R10F1000").unwrap();
        let Action::Move { target, .. } = b[b.len() / 2] else {
            panic!()
        };
        assert!(target[1] < -9.0, "{target:?}");
    }

    #[test]
    fn arcs_with_absurd_radii_are_bounded_like_grbls_u16_segment_count() {
        let t = std::time::Instant::now();
        let mut i = Interpreter::new();
        run(&mut i, "G0X0Y5").unwrap();
        let a = run(&mut i, "G3X0Y0R5555555555555555555555555555555F3000").unwrap();
        // GRBL counts segments in a u16: at most 65535 chords, the last the target.
        assert_eq!(a.len(), u16::MAX as usize);
        assert_eq!(a.last(), Some(&mv([0.0, 0.0, 0.0], Rate::Feed(3000.0))));
        // A huge IJK radius too, and a full circle of it.
        let mut j = Interpreter::new();
        let b = run(&mut j, "G2X0Y0I99999999999999999999J0F100").unwrap();
        assert!(b.len() <= u16::MAX as usize);
        assert!(
            t.elapsed() < std::time::Duration::from_secs(2),
            "{:?}",
            t.elapsed()
        );
    }

    #[test]
    fn jog_rules() {
        let mut i = Interpreter::new();
        assert_eq!(i.execute("G91X1", true), Err(e::UNDEFINED_FEED_RATE));
        assert_eq!(i.execute("G2X1F100", true), Err(e::INVALID_JOG_COMMAND));
        assert_eq!(i.execute("M3X1F100", true), Err(e::INVALID_JOG_COMMAND));
        let a = i.execute("G91X1F100", true).unwrap();
        assert_eq!(
            a,
            vec![Action::Move {
                target: [1.0, 0.0, 0.0],
                rate: Rate::Feed(100.0),
                line_number: None,
                jog: true
            }]
        );
        assert!(
            !i.modal.incremental,
            "a jog's G91 applies to its own line only"
        );
        assert_eq!(i.feed_rate, 0.0);
    }

    #[test]
    fn writer_is_compact() {
        let b = BlockWriter::new()
            .g(53.0)
            .g(1.0)
            .word('X', 10.00004, 4)
            .word('Y', 2.5, 4)
            .word('F', 3000.0, 0);
        assert_eq!(b.to_string(), "G53G1X10Y2.5F3000");
        assert_eq!(BlockWriter::new().g(38.2).to_string(), "G38.2");
    }
}

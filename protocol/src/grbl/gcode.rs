//! The G-code subset GRBL 1.1 accepts: GRBL's line filter, a parser and interpreter
//! that give the same `error:N` codes GRBL gives for the same block, and a writer.
//!
//! The interpreter follows GRBL's `gc_execute_line` in its documented order: words are
//! read (letters, numbers, repeated words, modal group clashes), then checked against
//! the modal state (feed rate defined, axis words present, arc geometry, unused words),
//! and only a block that passes every check changes the state. A refused block changes
//! nothing, as on the device. It is sans-IO: what a block asks for comes back as
//! [`Action`]s (moves in machine millimetres, dwells, syncs) for a caller to execute.

mod error;

pub use error::GcodeError;

use super::codes::status as e;
use crate::nc;
use std::f64::consts::PI;
use std::fmt;

/// GRBL's line buffer is 80 bytes with a terminating zero: 79 characters fit.
pub const LINE_BUFFER_SIZE: usize = 80;
pub const MM_PER_INCH: f64 = 25.4;
pub const N_AXIS: usize = 3;
const MAX_LINE_NUMBER: f64 = 10_000_000.0;
const MAX_TOOL_NUMBER: f64 = 255.0;
const ARC_ANGULAR_TRAVEL_EPSILON: f64 = 5e-7;

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
            _ if out.len() >= LINE_BUFFER_SIZE - 1 => overflow = true,
            _ => out.push(c.to_ascii_uppercase() as char),
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

/// One word of a block.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Word {
    pub letter: char,
    pub value: f64,
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

/// Motion modal group.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Motion {
    Rapid,
    Linear,
    ArcCw,
    ArcCcw,
    /// G38.2 .. G38.5 (the decimal digit).
    Probe(u8),
    /// G80.
    None,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Plane {
    XY,
    ZX,
    YZ,
}

impl Plane {
    /// (first axis, second axis, linear axis) of the plane, as GRBL orders them.
    fn axes(self) -> (usize, usize, usize) {
        match self {
            Plane::XY => (0, 1, 2),
            Plane::ZX => (2, 0, 1),
            Plane::YZ => (1, 2, 0),
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Spindle {
    Off,
    Cw,
    Ccw,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ProgramFlow {
    Running,
    Paused,
    EndM2,
    EndM30,
}

/// The modal state GRBL reports with `$G`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Modal {
    pub motion: Motion,
    pub coord_select: usize,
    pub plane: Plane,
    pub inches: bool,
    pub incremental: bool,
    pub inverse_time: bool,
    pub spindle: Spindle,
    pub flood: bool,
    pub program_flow: ProgramFlow,
    pub tool_length_dynamic: bool,
}

impl Default for Modal {
    fn default() -> Self {
        Self {
            motion: Motion::Rapid,
            coord_select: 0,
            plane: Plane::XY,
            inches: false,
            incremental: false,
            inverse_time: false,
            spindle: Spindle::Off,
            flood: false,
            program_flow: ProgramFlow::Running,
            tool_length_dynamic: false,
        }
    }
}

/// How fast a move goes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Rate {
    /// G0: the machine's maximum rate (rapid override applies).
    Rapid,
    /// Feed in mm/min (feed override applies).
    Feed(f64),
}

/// What an accepted block asks the machine to do, in order.
#[derive(Clone, Debug, PartialEq)]
pub enum Action {
    /// A straight move to a target in machine coordinates, mm. Arcs come as chords.
    Move {
        target: [f64; N_AXIS],
        rate: Rate,
        line_number: Option<u32>,
        jog: bool,
    },
    /// Wait for all motion to end (GRBL's buffer synchronisation).
    Sync,
    /// G4: wait for motion to end, then dwell this long (seconds).
    Dwell(f64),
    /// G38.x probe towards a target.
    Probe {
        target: [f64; N_AXIS],
        feed: f64,
        toward: bool,
        fail_is_error: bool,
    },
    /// M0: wait for motion to end, then feed hold until cycle start.
    Pause,
    /// M2/M30: wait for motion to end; `[MSG:Pgm End]`.
    ProgramEnd,
    /// Spindle or coolant state changed (after a sync).
    Accessories,
    /// A work coordinate offset changed (the next status report shows `WCO:`).
    WcoChanged,
}

/// GRBL's G-code interpreter state: modal state, planned position (machine mm), work
/// offsets and the stored coordinate systems (its EEPROM parameters).
#[derive(Clone, Debug, PartialEq)]
pub struct Interpreter {
    pub modal: Modal,
    pub feed_rate: f64,
    pub spindle_speed: f64,
    pub tool: u8,
    pub line_number: u32,
    /// Where the last planned block ends, machine coordinates, mm.
    pub position: [f64; N_AXIS],
    /// Offset of the active coordinate system (G54..G59).
    pub coord_system: [f64; N_AXIS],
    /// G92 offset.
    pub coord_offset: [f64; N_AXIS],
    pub tool_length_offset: f64,
    /// Stored G54..G59 (0..5), G28 (6), G30 (7).
    pub stored: [[f64; N_AXIS]; 8],
    /// `$12` arc tolerance, mm.
    pub arc_tolerance: f64,
    /// Last probe result (machine mm) and success.
    pub probe: ([f64; N_AXIS], bool),
}

impl Default for Interpreter {
    fn default() -> Self {
        Self::new()
    }
}

#[derive(Default)]
struct Values {
    xyz: [Option<f64>; N_AXIS],
    ijk: [Option<f64>; N_AXIS],
    f: Option<f64>,
    l: Option<f64>,
    n: Option<f64>,
    p: Option<f64>,
    r: Option<f64>,
    s: Option<f64>,
    t: Option<f64>,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum NonModal {
    None,
    Dwell,
    SetCoordData,
    GoHome0,
    SetHome0,
    GoHome1,
    SetHome1,
    AbsoluteOverride,
    SetCoordOffset,
    ResetCoordOffset,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum AxisCommand {
    None,
    NonModal,
    MotionMode,
    ToolLengthOffset,
}

impl Interpreter {
    pub fn new() -> Self {
        Self {
            modal: Modal::default(),
            feed_rate: 0.0,
            spindle_speed: 0.0,
            tool: 0,
            line_number: 0,
            position: [0.0; N_AXIS],
            coord_system: [0.0; N_AXIS],
            coord_offset: [0.0; N_AXIS],
            tool_length_offset: 0.0,
            stored: [[0.0; N_AXIS]; 8],
            arc_tolerance: 0.002,
            probe: ([0.0; N_AXIS], false),
        }
    }

    /// GRBL's `gc_init` after a reset: modal state and G92 back to defaults, the G54
    /// offset reloaded, stored parameters kept, position synced by the caller.
    pub fn reset(&mut self) {
        let stored = self.stored;
        let position = self.position;
        let tol = self.arc_tolerance;
        let probe = self.probe;
        *self = Self::new();
        self.stored = stored;
        self.position = position;
        self.arc_tolerance = tol;
        self.probe = probe;
        self.coord_system = stored[0];
    }

    /// Work coordinate offset: what `WCO:` reports (MPos = WPos + WCO).
    pub fn wco(&self) -> [f64; N_AXIS] {
        let mut w = [0.0; N_AXIS];
        for i in 0..N_AXIS {
            w[i] = self.coord_system[i] + self.coord_offset[i];
        }
        w[2] += self.tool_length_offset;
        w
    }

    /// `[GC:...]` contents (reply to `$G`), as GRBL 1.1 prints them.
    pub fn parser_state(&self) -> String {
        let m = &self.modal;
        let motion = match m.motion {
            Motion::Rapid => "G0".to_string(),
            Motion::Linear => "G1".into(),
            Motion::ArcCw => "G2".into(),
            Motion::ArcCcw => "G3".into(),
            Motion::Probe(d) => format!("G38.{d}"),
            Motion::None => "G80".into(),
        };
        let plane = match m.plane {
            Plane::XY => 17,
            Plane::ZX => 18,
            Plane::YZ => 19,
        };
        let mut s = format!(
            "{motion} G{} G{plane} G{} G{} G{}",
            54 + m.coord_select,
            if m.inches { 20 } else { 21 },
            if m.incremental { 91 } else { 90 },
            if m.inverse_time { 93 } else { 94 },
        );
        match m.program_flow {
            ProgramFlow::Running => {}
            ProgramFlow::Paused => s.push_str(" M0"),
            ProgramFlow::EndM2 => s.push_str(" M2"),
            ProgramFlow::EndM30 => s.push_str(" M30"),
        }
        s.push_str(match m.spindle {
            Spindle::Cw => " M3",
            Spindle::Ccw => " M4",
            Spindle::Off => " M5",
        });
        s.push_str(if m.flood { " M8" } else { " M9" });
        let feed = if m.inches {
            format!("{:.1}", self.feed_rate / MM_PER_INCH)
        } else {
            format!("{:.0}", self.feed_rate)
        };
        s.push_str(&format!(
            " T{} F{feed} S{:.0}",
            self.tool, self.spindle_speed
        ));
        s
    }

    /// Execute one filtered line (`jog`: the part after `$J=`). On error the state is
    /// unchanged and GRBL's status code comes back.
    pub fn execute(&mut self, line: &str, jog: bool) -> Result<Vec<Action>, u8> {
        let mut next = self.clone();
        let actions = next.execute_inner(line, jog)?;
        *self = next;
        Ok(actions)
    }

    fn execute_inner(&mut self, line: &str, jog: bool) -> Result<Vec<Action>, u8> {
        let words = words(line)?;
        let mut modal = self.modal;
        if jog {
            modal.motion = Motion::Linear;
            modal.inverse_time = false;
        }
        let mut v = Values::default();
        let mut non_modal = NonModal::None;
        let mut axis_command = AxisCommand::None;
        let mut groups: u32 = 0;
        let mut value_seen: u32 = 0;
        let mut explicit_motion = false;
        let mut program_flow = None;
        let mut spindle = None;
        let mut coolant = None;
        let mut tool_length_change = None;
        let mut coord_select = None;

        for w in &words {
            match w.letter {
                'G' | 'M' => {
                    let int_value = w.value.trunc() as i64;
                    let mut mantissa = ((w.value - w.value.trunc()) * 100.0).round() as i64;
                    let group: u32;
                    if w.letter == 'G' {
                        match int_value {
                            10 | 28 | 30 | 92 | 4 | 53 => {
                                if matches!(int_value, 10 | 28 | 30 | 92) && mantissa == 0 {
                                    if axis_command != AxisCommand::None {
                                        return Err(e::AXIS_COMMAND_CONFLICT);
                                    }
                                    axis_command = AxisCommand::NonModal;
                                }
                                group = 0;
                                non_modal = match (int_value, mantissa) {
                                    (4, _) => NonModal::Dwell,
                                    (53, _) => NonModal::AbsoluteOverride,
                                    (10, _) => NonModal::SetCoordData,
                                    (28, 0) => NonModal::GoHome0,
                                    (28, 10) => NonModal::SetHome0,
                                    (30, 0) => NonModal::GoHome1,
                                    (30, 10) => NonModal::SetHome1,
                                    (92, 0) => NonModal::SetCoordOffset,
                                    (92, 10) => NonModal::ResetCoordOffset,
                                    _ => return Err(e::UNSUPPORTED_COMMAND),
                                };
                                if matches!(int_value, 28 | 30 | 92) {
                                    mantissa = 0;
                                }
                            }
                            0 | 1 | 2 | 3 | 38 | 80 => {
                                if int_value != 80 {
                                    if axis_command != AxisCommand::None {
                                        return Err(e::AXIS_COMMAND_CONFLICT);
                                    }
                                    axis_command = AxisCommand::MotionMode;
                                }
                                group = 1;
                                modal.motion = match int_value {
                                    0 => Motion::Rapid,
                                    1 => Motion::Linear,
                                    2 => Motion::ArcCw,
                                    3 => Motion::ArcCcw,
                                    80 => Motion::None,
                                    _ => {
                                        if !matches!(mantissa, 20 | 30 | 40 | 50) {
                                            return Err(e::UNSUPPORTED_COMMAND);
                                        }
                                        let d = (mantissa / 10) as u8;
                                        mantissa = 0;
                                        Motion::Probe(d)
                                    }
                                };
                                explicit_motion = true;
                            }
                            17..=19 => {
                                group = 2;
                                modal.plane = match int_value {
                                    17 => Plane::XY,
                                    18 => Plane::ZX,
                                    _ => Plane::YZ,
                                };
                            }
                            90 | 91 => {
                                if mantissa == 0 {
                                    group = 3;
                                    modal.incremental = int_value == 91;
                                } else {
                                    group = 4;
                                    if mantissa != 10 || int_value == 90 {
                                        return Err(e::UNSUPPORTED_COMMAND);
                                    }
                                    mantissa = 0; // G91.1: arc offsets incremental, the default.
                                }
                            }
                            93 | 94 => {
                                group = 5;
                                modal.inverse_time = int_value == 93;
                            }
                            20 | 21 => {
                                group = 6;
                                modal.inches = int_value == 20;
                            }
                            40 => group = 7,
                            43 | 49 => {
                                if axis_command != AxisCommand::None {
                                    return Err(e::AXIS_COMMAND_CONFLICT);
                                }
                                axis_command = AxisCommand::ToolLengthOffset;
                                group = 8;
                                if int_value == 49 {
                                    tool_length_change = Some(false);
                                } else if mantissa == 10 {
                                    tool_length_change = Some(true);
                                    mantissa = 0;
                                } else {
                                    return Err(e::UNSUPPORTED_COMMAND);
                                }
                            }
                            54..=59 => {
                                group = 12;
                                coord_select = Some((int_value - 54) as usize);
                            }
                            61 => {
                                group = 13;
                                if mantissa != 0 {
                                    return Err(e::UNSUPPORTED_COMMAND);
                                }
                            }
                            _ => return Err(e::UNSUPPORTED_COMMAND),
                        }
                        if mantissa > 0 {
                            return Err(e::COMMAND_VALUE_NOT_INTEGER);
                        }
                    } else {
                        if mantissa > 0 {
                            return Err(e::COMMAND_VALUE_NOT_INTEGER);
                        }
                        match int_value {
                            0 | 1 | 2 | 30 => {
                                group = 20;
                                program_flow = match int_value {
                                    0 => Some(ProgramFlow::Paused),
                                    1 => None, // Optional stop: ignored by GRBL.
                                    2 => Some(ProgramFlow::EndM2),
                                    _ => Some(ProgramFlow::EndM30),
                                };
                            }
                            3..=5 => {
                                group = 21;
                                spindle = Some(match int_value {
                                    3 => Spindle::Cw,
                                    4 => Spindle::Ccw,
                                    _ => Spindle::Off,
                                });
                            }
                            8 | 9 => {
                                group = 22;
                                coolant = Some(int_value == 8);
                            }
                            _ => return Err(e::UNSUPPORTED_COMMAND),
                        }
                    }
                    if groups & (1 << group) != 0 {
                        return Err(e::MODAL_GROUP_VIOLATION);
                    }
                    groups |= 1 << group;
                }
                letter => {
                    let slot = match letter {
                        'F' => 0,
                        'I' => 1,
                        'J' => 2,
                        'K' => 3,
                        'L' => 4,
                        'N' => 5,
                        'P' => 6,
                        'R' => 7,
                        'S' => 8,
                        'T' => 9,
                        'X' => 10,
                        'Y' => 11,
                        'Z' => 12,
                        _ => return Err(e::UNSUPPORTED_COMMAND),
                    };
                    if value_seen & (1 << slot) != 0 {
                        return Err(e::WORD_REPEATED);
                    }
                    value_seen |= 1 << slot;
                    if matches!(letter, 'F' | 'N' | 'P' | 'T' | 'S') && w.value < 0.0 {
                        return Err(e::NEGATIVE_VALUE);
                    }
                    let x = w.value;
                    match letter {
                        'F' => v.f = Some(x),
                        'I' => v.ijk[0] = Some(x),
                        'J' => v.ijk[1] = Some(x),
                        'K' => v.ijk[2] = Some(x),
                        'L' => v.l = Some(x.trunc()),
                        'N' => v.n = Some(x.trunc()),
                        'P' => v.p = Some(x),
                        'R' => v.r = Some(x),
                        'S' => v.s = Some(x),
                        'T' => {
                            if x > MAX_TOOL_NUMBER {
                                return Err(e::MAX_VALUE_EXCEEDED);
                            }
                            v.t = Some(x.trunc())
                        }
                        'X' => v.xyz[0] = Some(x),
                        'Y' => v.xyz[1] = Some(x),
                        _ => v.xyz[2] = Some(x),
                    }
                }
            }
        }
        let _ = explicit_motion;
        let axis_words = v.xyz.iter().any(Option::is_some);
        if axis_words && axis_command == AxisCommand::None {
            axis_command = AxisCommand::MotionMode;
        }
        // Jog: only units, distance and G53; F required.
        if jog {
            let allowed = (1 << 3) | (1 << 6) | (1 << 0);
            if groups & !allowed != 0
                || !matches!(non_modal, NonModal::None | NonModal::AbsoluteOverride)
            {
                return Err(e::INVALID_JOG_COMMAND);
            }
            if v.f.is_none() {
                return Err(e::UNDEFINED_FEED_RATE);
            }
        }
        if let Some(n) = v.n {
            if n > MAX_LINE_NUMBER {
                return Err(e::INVALID_LINE_NUMBER);
            }
        }
        let unit = if modal.inches { MM_PER_INCH } else { 1.0 };
        // Feed rate.
        let mut feed = self.feed_rate;
        if modal.inverse_time {
            if axis_command == AxisCommand::MotionMode
                && !matches!(modal.motion, Motion::Rapid | Motion::None)
                && v.f.is_none()
            {
                return Err(e::UNDEFINED_FEED_RATE);
            }
            feed = v.f.unwrap_or(0.0); // 1/min, per block
        } else if let Some(f) = v.f {
            feed = f * unit;
        } else if self.modal.inverse_time {
            feed = 0.0; // Switching G93 -> G94 makes the feed undefined.
        }
        let spindle_speed = v.s.unwrap_or(self.spindle_speed);
        // Tool length offset.
        let mut tlo = self.tool_length_offset;
        if let Some(dynamic) = tool_length_change {
            if dynamic {
                if v.xyz[0].is_some() || v.xyz[1].is_some() || v.xyz[2].is_none() {
                    return Err(e::G43_DYNAMIC_AXIS_ERROR);
                }
                tlo = v.xyz[2].unwrap_or(0.0) * unit;
            } else {
                tlo = 0.0;
            }
            modal.tool_length_dynamic = dynamic;
        }
        // Coordinate system.
        let mut block_coord = self.coord_system;
        if let Some(cs) = coord_select {
            modal.coord_select = cs;
            block_coord = self.stored[cs];
        }
        // Non-modal checks and words.
        let mut new_stored: Option<(usize, [f64; N_AXIS])> = None;
        let mut new_offset = None;
        let mut dwell = None;
        match non_modal {
            NonModal::Dwell => {
                dwell = Some(v.p.take().ok_or(e::VALUE_WORD_MISSING)?);
            }
            NonModal::SetCoordData => {
                if !axis_words {
                    return Err(e::NO_AXIS_WORDS);
                }
                let (Some(p), Some(l)) = (v.p.take(), v.l.take()) else {
                    return Err(e::VALUE_WORD_MISSING);
                };
                let p = p.trunc() as usize;
                if p > 6 {
                    return Err(e::UNSUPPORTED_COORD_SYS);
                }
                let idx = if p > 0 { p - 1 } else { modal.coord_select };
                let mut data = self.stored[idx];
                for i in 0..N_AXIS {
                    if let Some(x) = v.xyz[i] {
                        data[i] = match l as i64 {
                            2 => x * unit,
                            20 => {
                                let mut d = self.position[i] - self.coord_offset[i] - x * unit;
                                if i == 2 {
                                    d -= tlo;
                                }
                                d
                            }
                            _ => return Err(e::UNSUPPORTED_COMMAND),
                        };
                    }
                }
                if !matches!(l as i64, 2 | 20) {
                    return Err(e::UNSUPPORTED_COMMAND);
                }
                new_stored = Some((idx, data));
            }
            NonModal::SetCoordOffset => {
                if !axis_words {
                    return Err(e::NO_AXIS_WORDS);
                }
                let mut off = self.coord_offset;
                for i in 0..N_AXIS {
                    if let Some(x) = v.xyz[i] {
                        off[i] = self.position[i] - block_coord[i] - x * unit;
                        if i == 2 {
                            off[i] -= tlo;
                        }
                    }
                }
                new_offset = Some(off);
            }
            NonModal::ResetCoordOffset => new_offset = Some([0.0; N_AXIS]),
            NonModal::AbsoluteOverride
                if !matches!(modal.motion, Motion::Rapid | Motion::Linear) =>
            {
                return Err(e::G53_INVALID_MOTION_MODE);
            }
            _ => {}
        }
        // Targets for axis words (non-modal and motion commands).
        let offset_now = new_offset.unwrap_or(self.coord_offset);
        let mut target = self.position;
        if matches!(
            axis_command,
            AxisCommand::MotionMode | AxisCommand::NonModal
        ) && !matches!(non_modal, NonModal::SetCoordData | NonModal::SetCoordOffset)
        {
            for i in 0..N_AXIS {
                if let Some(x) = v.xyz[i] {
                    let x = x * unit;
                    target[i] = if non_modal == NonModal::AbsoluteOverride {
                        x
                    } else if modal.incremental {
                        self.position[i] + x
                    } else {
                        let mut t = x + block_coord[i] + offset_now[i];
                        if i == 2 {
                            t += tlo;
                        }
                        t
                    };
                }
            }
        }
        // Motion mode checks.
        let mut actions = Vec::new();
        let mut arc: Option<([f64; N_AXIS], bool)> = None; // (offset, clockwise)
        let mut moves_motion = false;
        if modal.motion == Motion::None {
            if axis_words {
                return Err(e::AXIS_WORDS_EXIST);
            }
        } else if axis_command == AxisCommand::MotionMode {
            if modal.motion == Motion::Rapid {
                moves_motion = axis_words;
            } else {
                if feed == 0.0 {
                    return Err(e::UNDEFINED_FEED_RATE);
                }
                match modal.motion {
                    Motion::Linear => moves_motion = axis_words,
                    Motion::ArcCw | Motion::ArcCcw => {
                        if !axis_words {
                            return Err(e::NO_AXIS_WORDS);
                        }
                        let (a0, a1, _) = modal.plane.axes();
                        if v.xyz[a0].is_none() && v.xyz[a1].is_none() {
                            return Err(e::NO_AXIS_WORDS_IN_PLANE);
                        }
                        let cw = modal.motion == Motion::ArcCw;
                        let x = target[a0] - self.position[a0];
                        let y = target[a1] - self.position[a1];
                        let mut off = [0.0; N_AXIS];
                        if let Some(r0) = v.r.take() {
                            if x == 0.0 && y == 0.0 {
                                return Err(e::INVALID_TARGET);
                            }
                            let mut r = r0 * unit;
                            let h2 = 4.0 * r * r - x * x - y * y;
                            if h2 < 0.0 {
                                return Err(e::ARC_RADIUS_ERROR);
                            }
                            let mut h = -h2.sqrt() / x.hypot(y);
                            if !cw {
                                h = -h;
                            }
                            if r < 0.0 {
                                h = -h;
                                r = -r;
                            }
                            let _ = r;
                            off[a0] = 0.5 * (x - y * h);
                            off[a1] = 0.5 * (y + x * h);
                            v.ijk = [None; N_AXIS];
                        } else {
                            if v.ijk[a0].is_none() && v.ijk[a1].is_none() {
                                return Err(e::NO_OFFSETS_IN_PLANE);
                            }
                            off[a0] = v.ijk[a0].unwrap_or(0.0) * unit;
                            off[a1] = v.ijk[a1].unwrap_or(0.0) * unit;
                            let cx = x - off[a0];
                            let cy = y - off[a1];
                            let target_r = cx.hypot(cy);
                            let r = off[a0].hypot(off[a1]);
                            let dr = (target_r - r).abs();
                            if dr > 0.005 && (dr > 0.5 || dr > 0.001 * r) {
                                return Err(e::INVALID_TARGET);
                            }
                            v.ijk[a0] = None;
                            v.ijk[a1] = None;
                        }
                        arc = Some((off, cw));
                        moves_motion = true;
                    }
                    Motion::Probe(_) => {
                        if !axis_words {
                            return Err(e::NO_AXIS_WORDS);
                        }
                        if target == self.position {
                            return Err(e::INVALID_TARGET);
                        }
                        moves_motion = true;
                    }
                    _ => {}
                }
            }
        }
        // Unused words.
        if non_modal == NonModal::SetCoordData || non_modal == NonModal::SetCoordOffset {
            v.xyz = [None; N_AXIS];
        }
        if axis_command != AxisCommand::None {
            v.xyz = [None; N_AXIS];
        }
        if v.ijk.iter().any(Option::is_some) || v.r.is_some() || v.p.is_some() || v.l.is_some() {
            return Err(e::UNUSED_WORDS);
        }

        // ---- The block is valid: execute it (state changes, then actions). ----
        let line_number = v.n.map(|n| n as u32).filter(|&n| n > 0);
        if jog {
            // Jog motion changes nothing modal; only the planned position.
            let rate = Rate::Feed(feed);
            if target != self.position {
                actions.push(Action::Move {
                    target,
                    rate,
                    line_number,
                    jog: true,
                });
            }
            self.position = target;
            return Ok(actions);
        }
        if let Some(n) = v.n {
            self.line_number = n as u32;
        }
        self.feed_rate = if modal.inverse_time {
            self.feed_rate
        } else {
            feed
        };
        if !modal.inverse_time {
            self.feed_rate = feed;
        }
        if let Some(t) = v.t {
            self.tool = t as u8;
        }
        let accessories_changed = spindle.is_some_and(|s| s != self.modal.spindle)
            || (v.s.is_some()
                && spindle_speed != self.spindle_speed
                && self.modal.spindle != Spindle::Off)
            || coolant.is_some_and(|c| c != self.modal.flood);
        self.spindle_speed = spindle_speed;
        if let Some(s) = spindle {
            modal.spindle = s;
        }
        if let Some(c) = coolant {
            modal.flood = c;
        }
        if accessories_changed {
            actions.push(Action::Sync);
            actions.push(Action::Accessories);
        }
        if let Some(p) = dwell {
            actions.push(Action::Dwell(p));
        }
        let mut wco_changed = false;
        if tool_length_change.is_some() && tlo != self.tool_length_offset {
            self.tool_length_offset = tlo;
            wco_changed = true;
        }
        if coord_select.is_some() && block_coord != self.coord_system {
            self.coord_system = block_coord;
            wco_changed = true;
        }
        if let Some((idx, data)) = new_stored {
            self.stored[idx] = data;
            if idx == modal.coord_select {
                self.coord_system = data;
                wco_changed = true;
            }
        }
        if let Some(off) = new_offset {
            if off != self.coord_offset {
                self.coord_offset = off;
                wco_changed = true;
            }
        }
        if wco_changed {
            actions.push(Action::Sync);
            actions.push(Action::WcoChanged);
        }
        let rate = match modal.motion {
            Motion::Rapid => Rate::Rapid,
            _ => Rate::Feed(feed),
        };
        match non_modal {
            NonModal::GoHome0 | NonModal::GoHome1 => {
                let stored = self.stored[if non_modal == NonModal::GoHome0 { 6 } else { 7 }];
                if axis_words {
                    actions.push(Action::Move {
                        target,
                        rate: Rate::Rapid,
                        line_number,
                        jog: false,
                    });
                }
                actions.push(Action::Move {
                    target: stored,
                    rate: Rate::Rapid,
                    line_number,
                    jog: false,
                });
                self.position = stored;
            }
            NonModal::SetHome0 => self.stored[6] = self.position,
            NonModal::SetHome1 => self.stored[7] = self.position,
            _ => {}
        }
        if moves_motion {
            match (modal.motion, arc) {
                (Motion::ArcCw | Motion::ArcCcw, Some((off, cw))) => {
                    let seg_rate = |n: usize| {
                        if modal.inverse_time {
                            Rate::Feed(0.0_f64.max(feed * n as f64))
                        } else {
                            rate
                        }
                    };
                    let pts = arc_points(
                        self.position,
                        target,
                        off,
                        modal.plane.axes(),
                        cw,
                        self.arc_tolerance,
                    );
                    let n = pts.len();
                    for p in pts {
                        actions.push(Action::Move {
                            target: p,
                            rate: seg_rate(n),
                            line_number,
                            jog: false,
                        });
                    }
                }
                (Motion::Probe(d), _) => {
                    actions.push(Action::Probe {
                        target,
                        feed,
                        toward: d <= 3,
                        fail_is_error: d == 2 || d == 4,
                    });
                }
                _ => {
                    let rate = match rate {
                        Rate::Feed(f) if modal.inverse_time => {
                            let d: f64 = (0..N_AXIS)
                                .map(|i| (target[i] - self.position[i]).powi(2))
                                .sum::<f64>()
                                .sqrt();
                            Rate::Feed(f * d)
                        }
                        r => r,
                    };
                    actions.push(Action::Move {
                        target,
                        rate,
                        line_number,
                        jog: false,
                    });
                }
            }
            self.position = target;
        }
        if let Some(flow) = program_flow {
            match flow {
                ProgramFlow::Paused => {
                    actions.push(Action::Sync);
                    actions.push(Action::Pause);
                }
                _ => {
                    actions.push(Action::Sync);
                    modal.motion = Motion::Linear;
                    modal.plane = Plane::XY;
                    modal.incremental = false;
                    modal.inverse_time = false;
                    modal.coord_select = 0;
                    modal.spindle = Spindle::Off;
                    modal.flood = false;
                    self.coord_system = self.stored[0];
                    actions.push(Action::ProgramEnd);
                }
            }
            modal.program_flow = ProgramFlow::Running;
        }
        self.modal = modal;
        Ok(actions)
    }
}

/// Chord end points of an arc (GRBL's `mc_arc`): as many segments as keep the chord
/// within the arc tolerance; the last point is exactly the target.
fn arc_points(
    position: [f64; N_AXIS],
    target: [f64; N_AXIS],
    offset: [f64; N_AXIS],
    (a0, a1, lin): (usize, usize, usize),
    clockwise: bool,
    tolerance: f64,
) -> Vec<[f64; N_AXIS]> {
    let c0 = position[a0] + offset[a0];
    let c1 = position[a1] + offset[a1];
    let r0 = -offset[a0];
    let r1 = -offset[a1];
    let rt0 = target[a0] - c0;
    let rt1 = target[a1] - c1;
    let radius = r0.hypot(r1);
    let mut travel = (r0 * rt1 - r1 * rt0).atan2(r0 * rt0 + r1 * rt1);
    if clockwise {
        if travel >= -ARC_ANGULAR_TRAVEL_EPSILON {
            travel -= 2.0 * PI;
        }
    } else if travel <= ARC_ANGULAR_TRAVEL_EPSILON {
        travel += 2.0 * PI;
    }
    let tol = tolerance.max(1e-6);
    let segments = ((0.5 * travel * radius).abs() / (tol * (2.0 * radius - tol)).max(1e-12).sqrt())
        .floor() as usize;
    let mut pts = Vec::with_capacity(segments + 1);
    for k in 1..segments.max(1) {
        if segments <= 1 {
            break;
        }
        let a = travel * k as f64 / segments as f64;
        let (s, c) = a.sin_cos();
        let mut p = position;
        p[a0] = c0 + r0 * c - r1 * s;
        p[a1] = c1 + r0 * s + r1 * c;
        p[lin] = position[lin] + (target[lin] - position[lin]) * k as f64 / segments as f64;
        pts.push(p);
    }
    pts.push(target);
    pts
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
        assert_eq!(run(&mut i, "G10L2X1"), Err(e::VALUE_WORD_MISSING));
        assert_eq!(i, Interpreter::new(), "refused blocks change nothing");
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
        assert_eq!(i.parser_state(), "G1 G54 G17 G20 G91 G94 M5 M9 T0 F23.6 S0");
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

#[cfg(test)]
mod characterization;

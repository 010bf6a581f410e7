//! Step 1 of GRBL's `gc_execute_line`: read the words of a block into modal groups and
//! value slots, refusing what GRBL refuses while reading, in the order it does (per
//! word: unsupported command, non-integer value, axis command conflict, modal group
//! violation; unsupported letter, repeated word, negative value, tool number).

use super::error::GcodeError;
use super::state::{Modal, Motion, Plane, ProgramFlow, Spindle, Word, FIRST_ROTARY, MAX_AXES};

const MAX_TOOL_NUMBER: f64 = 255.0;

/// Value words of a block (GRBL truncates L, N and T).
#[derive(Default)]
pub(super) struct Values {
    /// X Y Z A B C (the reader refuses letters beyond the controller's axes).
    pub xyz: [Option<f64>; MAX_AXES],
    pub ijk: [Option<f64>; 3],
    pub f: Option<f64>,
    pub l: Option<f64>,
    pub n: Option<f64>,
    pub p: Option<f64>,
    pub r: Option<f64>,
    pub s: Option<f64>,
    pub t: Option<f64>,
}

impl Values {
    pub fn has_axis_words(&self) -> bool {
        self.xyz.iter().any(Option::is_some)
    }
}

/// Group 0 commands.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(super) enum NonModal {
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

/// Which command the block's axis words belong to (at most one may claim them).
#[derive(Clone, Copy, PartialEq, Eq)]
pub(super) enum AxisCommand {
    None,
    NonModal,
    MotionMode,
    ToolLengthOffset,
}

/// GRBL's modal group numbers (bits of [`BlockWords::groups`]).
pub(super) mod group {
    pub const NON_MODAL: u32 = 0;
    pub const MOTION: u32 = 1;
    pub const PLANE: u32 = 2;
    pub const DISTANCE: u32 = 3;
    pub const ARC_DISTANCE: u32 = 4;
    pub const FEED_RATE_MODE: u32 = 5;
    pub const UNITS: u32 = 6;
    pub const CUTTER_COMP: u32 = 7;
    pub const TOOL_LENGTH: u32 = 8;
    pub const COORD_SYSTEM: u32 = 12;
    pub const CONTROL_MODE: u32 = 13;
    pub const STOPPING: u32 = 20;
    pub const SPINDLE: u32 = 21;
    pub const COOLANT: u32 = 22;
}

/// What a block's words ask for, before any check against the interpreter's state.
pub(super) struct BlockWords {
    /// The modal state with this block's modal commands applied.
    pub modal: Modal,
    pub non_modal: NonModal,
    pub axis_command: AxisCommand,
    pub values: Values,
    pub program_flow: Option<ProgramFlow>,
    pub spindle: Option<Spindle>,
    pub coolant: Option<bool>,
    /// G43.1 (`true`) or G49 (`false`).
    pub tool_length_change: Option<bool>,
    pub coord_select: Option<usize>,
    /// Modal groups with a command in this block, one bit per group.
    pub groups: u32,
    /// Value letters seen, one bit per letter slot.
    values_seen: u32,
}

impl BlockWords {
    /// Reads every word in order; a jog starts from G1 G94 whatever the modal state.
    /// `axes`: how many of X Y Z A B C the controller has; a letter beyond them is
    /// unknown to it (error 20, as GRBL built without that axis answers).
    pub fn read(
        words: &[Word],
        mut modal: Modal,
        jog: bool,
        axes: usize,
    ) -> Result<Self, GcodeError> {
        if jog {
            modal.motion = Motion::Linear;
            modal.inverse_time = false;
        }
        let mut block = BlockWords::new(modal);
        for word in words {
            if axis_index(word.letter).is_some_and(|i| i >= axes) {
                return Err(GcodeError::UnsupportedCommand);
            }
            block.read_word(*word)?;
        }
        if block.values.has_axis_words() && block.axis_command == AxisCommand::None {
            block.axis_command = AxisCommand::MotionMode;
        }
        Ok(block)
    }

    fn new(modal: Modal) -> Self {
        BlockWords {
            modal,
            non_modal: NonModal::None,
            axis_command: AxisCommand::None,
            values: Values::default(),
            program_flow: None,
            spindle: None,
            coolant: None,
            tool_length_change: None,
            coord_select: None,
            groups: 0,
            values_seen: 0,
        }
    }

    fn read_word(&mut self, word: Word) -> Result<(), GcodeError> {
        match word.letter {
            'G' => self.read_command(word.value, Self::read_g),
            'M' => self.read_command(word.value, Self::read_m),
            letter => self.read_value(letter, word.value),
        }
    }

    /// Splits a command number as GRBL does (integer part, two decimals as "mantissa"),
    /// lets `read` take the command and clear the mantissa it accepts, then refuses a
    /// mantissa left over and a second command of the same modal group.
    fn read_command(
        &mut self,
        value: f64,
        read: fn(&mut Self, i64, &mut i64) -> Result<u32, GcodeError>,
    ) -> Result<(), GcodeError> {
        let int_value = value.trunc() as i64;
        let mut mantissa = ((value - value.trunc()) * 100.0).round() as i64;
        let group = read(self, int_value, &mut mantissa)?;
        if mantissa > 0 {
            return Err(GcodeError::CommandValueNotInteger);
        }
        self.claim_group(group)
    }

    fn claim_group(&mut self, group: u32) -> Result<(), GcodeError> {
        if self.groups & (1 << group) != 0 {
            return Err(GcodeError::ModalGroupViolation);
        }
        self.groups |= 1 << group;
        Ok(())
    }

    /// A command that uses the axis words; a second one in the block is error 24.
    fn claim_axis_words(&mut self, command: AxisCommand) -> Result<(), GcodeError> {
        if self.axis_command != AxisCommand::None {
            return Err(GcodeError::AxisCommandConflict);
        }
        self.axis_command = command;
        Ok(())
    }

    fn read_g(&mut self, int_value: i64, mantissa: &mut i64) -> Result<u32, GcodeError> {
        match int_value {
            4 | 10 | 28 | 30 | 53 | 92 => self.read_non_modal(int_value, mantissa),
            0..=3 | 38 | 80 => self.read_motion(int_value, mantissa),
            17..=19 => {
                self.modal.plane = [Plane::XY, Plane::ZX, Plane::YZ][(int_value - 17) as usize];
                Ok(group::PLANE)
            }
            90 | 91 => read_distance(&mut self.modal, int_value, mantissa),
            93 | 94 => {
                self.modal.inverse_time = int_value == 93;
                Ok(group::FEED_RATE_MODE)
            }
            20 | 21 => {
                self.modal.inches = int_value == 20;
                Ok(group::UNITS)
            }
            40 => Ok(group::CUTTER_COMP),
            43 | 49 => self.read_tool_length(int_value, mantissa),
            54..=59 => {
                self.coord_select = Some((int_value - 54) as usize);
                Ok(group::COORD_SYSTEM)
            }
            61 if *mantissa == 0 => Ok(group::CONTROL_MODE),
            _ => Err(GcodeError::UnsupportedCommand),
        }
    }

    /// G4, G10, G28(.1), G30(.1), G53, G92(.1).
    fn read_non_modal(&mut self, int_value: i64, mantissa: &mut i64) -> Result<u32, GcodeError> {
        if matches!(int_value, 10 | 28 | 30 | 92) && *mantissa == 0 {
            self.claim_axis_words(AxisCommand::NonModal)?;
        }
        self.non_modal = match (int_value, *mantissa) {
            (4, _) => NonModal::Dwell,
            (53, _) => NonModal::AbsoluteOverride,
            (10, _) => NonModal::SetCoordData,
            (28, 0) => NonModal::GoHome0,
            (28, 10) => NonModal::SetHome0,
            (30, 0) => NonModal::GoHome1,
            (30, 10) => NonModal::SetHome1,
            (92, 0) => NonModal::SetCoordOffset,
            (92, 10) => NonModal::ResetCoordOffset,
            _ => return Err(GcodeError::UnsupportedCommand),
        };
        if matches!(int_value, 28 | 30 | 92) {
            *mantissa = 0;
        }
        Ok(group::NON_MODAL)
    }

    /// G0..G3, G38.2..G38.5, G80.
    fn read_motion(&mut self, int_value: i64, mantissa: &mut i64) -> Result<u32, GcodeError> {
        if int_value != 80 {
            self.claim_axis_words(AxisCommand::MotionMode)?;
        }
        self.modal.motion = match int_value {
            0 => Motion::Rapid,
            1 => Motion::Linear,
            2 => Motion::ArcCw,
            3 => Motion::ArcCcw,
            80 => Motion::None,
            _ => read_probe(mantissa)?,
        };
        Ok(group::MOTION)
    }

    /// G43.1 (dynamic tool length offset) and G49 (cancel it).
    fn read_tool_length(&mut self, int_value: i64, mantissa: &mut i64) -> Result<u32, GcodeError> {
        self.claim_axis_words(AxisCommand::ToolLengthOffset)?;
        self.tool_length_change = match (int_value, *mantissa) {
            (49, _) => Some(false),
            (43, 10) => {
                *mantissa = 0;
                Some(true)
            }
            _ => return Err(GcodeError::UnsupportedCommand),
        };
        Ok(group::TOOL_LENGTH)
    }

    /// M0, M1, M2, M30, M3..M5, M8, M9 (a decimal is refused before the number).
    fn read_m(&mut self, int_value: i64, mantissa: &mut i64) -> Result<u32, GcodeError> {
        if *mantissa > 0 {
            return Err(GcodeError::CommandValueNotInteger);
        }
        match int_value {
            0 | 1 | 2 | 30 => {
                self.program_flow = program_flow(int_value);
                Ok(group::STOPPING)
            }
            3..=5 => {
                self.spindle =
                    Some([Spindle::Cw, Spindle::Ccw, Spindle::Off][(int_value - 3) as usize]);
                Ok(group::SPINDLE)
            }
            8 | 9 => {
                self.coolant = Some(int_value == 8);
                Ok(group::COOLANT)
            }
            _ => Err(GcodeError::UnsupportedCommand),
        }
    }

    fn read_value(&mut self, letter: char, value: f64) -> Result<(), GcodeError> {
        let slot = value_slot(letter).ok_or(GcodeError::UnsupportedCommand)?;
        if self.values_seen & (1 << slot) != 0 {
            return Err(GcodeError::WordRepeated);
        }
        self.values_seen |= 1 << slot;
        if matches!(letter, 'F' | 'N' | 'P' | 'T' | 'S') && value < 0.0 {
            return Err(GcodeError::NegativeValue);
        }
        if letter == 'T' && value > MAX_TOOL_NUMBER {
            return Err(GcodeError::MaxValueExceeded);
        }
        self.store_value(letter, value);
        Ok(())
    }

    fn store_value(&mut self, letter: char, x: f64) {
        let v = &mut self.values;
        let slot = match letter {
            'F' => &mut v.f,
            'I' | 'J' | 'K' => &mut v.ijk[(letter as u8 - b'I') as usize],
            'L' => &mut v.l,
            'N' => &mut v.n,
            'P' => &mut v.p,
            'R' => &mut v.r,
            'S' => &mut v.s,
            'T' => &mut v.t,
            _ => match axis_index(letter) {
                Some(i) => &mut v.xyz[i],
                None => return,
            },
        };
        *slot = Some(if matches!(letter, 'L' | 'N' | 'T') {
            x.trunc()
        } else {
            x
        });
    }
}

/// G90/G91 (group 3) and G91.1 (group 4: incremental arc offsets, GRBL's only mode).
fn read_distance(modal: &mut Modal, int_value: i64, mantissa: &mut i64) -> Result<u32, GcodeError> {
    if *mantissa == 0 {
        modal.incremental = int_value == 91;
        return Ok(group::DISTANCE);
    }
    if *mantissa != 10 || int_value == 90 {
        return Err(GcodeError::UnsupportedCommand);
    }
    *mantissa = 0;
    Ok(group::ARC_DISTANCE)
}

/// G38.2..G38.5 (the decimal digit is kept).
fn read_probe(mantissa: &mut i64) -> Result<Motion, GcodeError> {
    if !matches!(*mantissa, 20 | 30 | 40 | 50) {
        return Err(GcodeError::UnsupportedCommand);
    }
    let digit = (*mantissa / 10) as u8;
    *mantissa = 0;
    Ok(Motion::Probe(digit))
}

/// M0 pauses, M1 (optional stop) is ignored by GRBL, M2 and M30 end the program.
fn program_flow(int_value: i64) -> Option<ProgramFlow> {
    match int_value {
        0 => Some(ProgramFlow::Paused),
        2 => Some(ProgramFlow::EndM2),
        30 => Some(ProgramFlow::EndM30),
        _ => None,
    }
}

/// GRBL's bit for each value letter it knows (for repeated-word detection).
fn value_slot(letter: char) -> Option<u32> {
    "FIJKLNPRSTXYZABC".find(letter).map(|i| i as u32)
}

/// Index of an axis letter in report order (X Y Z A B C).
fn axis_index(letter: char) -> Option<usize> {
    match letter {
        'X' | 'Y' | 'Z' => Some((letter as u8 - b'X') as usize),
        'A' | 'B' | 'C' => Some(FIRST_ROTARY + (letter as u8 - b'A') as usize),
        _ => None,
    }
}

//! What the steps of the interpreter share: words, the modal groups, the actions a
//! block asks for, and the interpreter's state (its modal state, position, offsets).

/// Millimetres per inch (G20 programs are converted on reading).
pub const MM_PER_INCH: f64 = 25.4;
/// GRBL 1.1 drives X, Y and Z: the default number of axes.
pub const N_AXIS: usize = 3;
/// grblHAL drives up to six axes, lettered X Y Z A B C in that order (the first
/// `N` of them on an `N`-axis controller).
pub const MAX_AXES: usize = 6;
/// The axis letters in report order (`MPos:x,y,z,a,b,c`).
pub const AXIS_LETTERS: [char; MAX_AXES] = ['X', 'Y', 'Z', 'A', 'B', 'C'];
/// Axes from this index on (A, B, C) are rotary: degrees, never scaled by G20.
pub const FIRST_ROTARY: usize = 3;

/// One word of a block.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Word {
    pub letter: char,
    pub value: f64,
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
    pub(super) fn axes(self) -> (usize, usize, usize) {
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
pub enum Action<const N: usize = N_AXIS> {
    /// A straight move to a target in machine coordinates, mm (A B C: degrees). Arcs come as chords.
    Move {
        target: [f64; N],
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
        target: [f64; N],
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
pub struct Interpreter<const N: usize = N_AXIS> {
    pub modal: Modal,
    pub feed_rate: f64,
    pub spindle_speed: f64,
    pub tool: u8,
    pub line_number: u32,
    /// Where the last planned block ends, machine coordinates, mm.
    pub position: [f64; N],
    /// Offset of the active coordinate system (G54..G59).
    pub coord_system: [f64; N],
    /// G92 offset.
    pub coord_offset: [f64; N],
    pub tool_length_offset: f64,
    /// Stored G54..G59 (0..5), G28 (6), G30 (7).
    pub stored: [[f64; N]; 8],
    /// `$12` arc tolerance, mm.
    pub arc_tolerance: f64,
    /// Last probe result (machine mm) and success.
    pub probe: ([f64; N], bool),
    /// How many of X Y Z A B C the controller drives (3..=N; `N` unless restricted with
    /// [`Interpreter::restrict_axes`]): letters beyond are unknown to it (error 20).
    pub axes: usize,
}

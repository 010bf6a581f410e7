//! The GRBL 1.1 serial protocol, sans-IO.
//!
//! * [`realtime`]: the single bytes GRBL intercepts anywhere in the stream.
//! * [`command`]: the line commands (`$$`, `$I`, `$J=`, G-code...) as bytes.
//! * [`response`]: everything GRBL answers (`ok`, `error:N`, `ALARM:N`, status
//!   reports, `[MSG:]`, `[GC:]`, `[VER:]`, `[OPT:]`, `$n=`, banner) and a line decoder
//!   that works whatever the chunking.
//! * [`status`]: status reports with every field.
//! * [`settings`]: the `$n` settings table, GRBL's validation, typed access.
//! * [`stream`]: character-counting streaming (the 128-byte RX budget).
//! * [`gcode`]: GRBL's line filter, a G-code interpreter giving GRBL's error codes, and
//!   a compact block writer.
//! * [`codes`]: what each error and alarm number means.
//! * [`probe`]: the `[PRB:...]` report (3 to 6 axes, grblHAL's A B C) and the probe
//!   alarms.
//!
//! Nothing here does I/O or reads a clock: the driver and the emulator bring both.

pub mod codes;
pub mod command;
pub mod gcode;
pub mod probe;
pub mod realtime;
pub mod response;
pub mod settings;
pub mod status;
pub mod stream;

pub use codes::{alarm_text, error_text};
pub use command::Command;
pub use realtime::Realtime;
pub use response::{LineDecoder, Response};
pub use settings::Settings;
pub use status::{MachineState, StatusReport};
pub use stream::{CharCounter, ProgramStream, StreamProgress};

/// The version string the emulator announces and the driver was checked against.
pub const GRBL_VERSION: &str = "1.1h";
/// GRBL 1.1's planner: 16 blocks, of which 15 are usable (`[OPT:..,15,..]`).
pub const PLANNER_BLOCKS: usize = 15;

//! A closed industrial controller reached only through its tape port (DNC drip-feed):
//! [`device`] is the controller as a sans-IO state machine (receive buffer with DC1/DC3,
//! alarm NAK, reset SYN, Fanuc-dialect programs run on the shared simulated machine);
//! [`pty`] serves it on a real pseudo-terminal; [`cli`] is `emulators dnc`. See
//! docs/dnc.md.

pub mod cli;
pub mod device;
pub mod pty;

pub use device::{checksum_lines, DncConfig, DncDevice, DncStats, DC1, DC3, NAK, SYN};
pub use pty::DncPty;

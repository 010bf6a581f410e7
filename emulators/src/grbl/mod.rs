//! A GRBL 1.1 controller: [`device`] is the firmware's behaviour as a sans-IO state
//! machine on the shared simulated machine; [`pty`] serves it on a real
//! pseudo-terminal so any G-code sender (or the gateway's driver) can connect.

pub mod device;
pub mod pty;

pub use device::{DeviceStats, GrblConfig, GrblDevice};
pub use pty::{Foreign, ForeignPty, GrblPty};

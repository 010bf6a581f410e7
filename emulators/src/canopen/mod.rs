//! CiA 402 drives on CAN: [`node`] is one drive node's communication side (object
//! dictionary from an EDS, NMT, SDO server, PDOs as the master maps them, heartbeat,
//! EMCY, the power state machine), [`drives`] puts several of them on one bus, each
//! driving one axis of the shared simulated machine, and [`pty`] serves them behind an
//! emulated SLCAN adapter on a real pseudo-terminal (`emulators canopen`), or
//! `socketcan` (cargo feature `socketcan`, Linux) on a SocketCAN interface.

pub mod cli;
pub mod drives;
pub mod hub;
pub mod node;
pub mod pty;
#[cfg(all(target_os = "linux", feature = "socketcan"))]
pub mod socketcan;

pub use drives::{DriveSet, DriveSetConfig, SetStats, Trapezoid, DRIVE_EDS, DRIVE_EDS_NAME};
pub use hub::SlcanHub;
pub use pty::{AdapterStats, SharedSet, SlcanAdapter, SlcanPty};

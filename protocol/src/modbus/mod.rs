//! Modbus positioning drives, sans-IO.
//!
//! * [`profile`]: drive profiles (`config/drives/*.toml`): which register means what,
//!   checked when loaded (overlaps, gaps in the move block, word order, units).
//! * [`value`]: 16/32-bit register values in either word order, and drive units
//!   (counts, rpm, ms/1000 rpm) to and from millimetres.
//! * [`frame`]: PDUs, exception codes, RTU frames with CRC-16 and the TCP MBAP header.
//!
//! Nothing here does I/O or reads a clock.

pub mod frame;
pub mod profile;
pub mod value;

pub use frame::{crc16, Exception, Request, Response};
pub use profile::{Command, DriveProfile, DriveStatus, Register, Table};
pub use value::{DataType, Mechanics, Unit, WordOrder};

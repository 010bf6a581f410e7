//! CAN buses: one small async trait ([`CanBus`]) with two implementations, an SLCAN
//! adapter on a serial port ([`slcan::SlcanBus`], cargo feature `serial`) and a Linux
//! SocketCAN interface ([`socketcan::SocketCanBus`], cargo feature `socketcan`, Linux
//! only). Protocols above (CANopen) see frames only, never the adapter.

mod open;
#[cfg(feature = "serial")]
pub mod slcan;
#[cfg(all(target_os = "linux", feature = "socketcan"))]
pub mod socketcan;

use crate::error::DriverError;
use async_trait::async_trait;
use protocol::can::CanFrame;

pub use protocol::can::{CanFrame as Frame, CanId};

/// Counters every bus keeps.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct BusStats {
    pub frames_sent: u64,
    pub frames_received: u64,
    /// Lines from an SLCAN adapter that were not valid SLCAN (skipped).
    pub malformed: u64,
    /// Commands the adapter refused (SLCAN BEL), e.g. a frame sent while closed.
    pub adapter_errors: u64,
}

/// A CAN bus as the protocol layers see it.
///
/// `recv` must be cancel-safe (a frame is never lost when its future is dropped), so a
/// dispatcher can wait for a frame and for its own commands at once.
#[async_trait]
pub trait CanBus: Send {
    /// What it is, for messages (`slcan /dev/ttyACM0 @ 1000000`, `socketcan can0`).
    fn name(&self) -> &str;
    async fn send(&mut self, frame: &CanFrame) -> Result<(), DriverError>;
    async fn recv(&mut self) -> Result<CanFrame, DriverError>;
    fn stats(&self) -> BusStats;
}

pub use link_spec::can::BusSpec;
pub use open::open_bus;

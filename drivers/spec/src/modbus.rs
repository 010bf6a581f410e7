//! Modbus TCP and RTU positioning drives, one unit per axis.

use crate::axis::Axis;
use std::fmt;
use std::net::SocketAddr;
use std::time::Duration;

/// Serial parity (Modbus RTU's default is even; many drives are set to none).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Parity {
    None,
    Even,
    Odd,
}

/// Where the drives are.
#[derive(Clone, Debug, PartialEq)]
pub enum Endpoint {
    Tcp(SocketAddr),
    Rtu {
        path: String,
        baud: u32,
        parity: Parity,
    },
}

impl fmt::Display for Endpoint {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Endpoint::Tcp(a) => write!(f, "Modbus TCP {a}"),
            Endpoint::Rtu { path, baud, .. } => write!(f, "Modbus RTU {path} @{baud}"),
        }
    }
}

/// Deadlines and bounds.
#[derive(Clone, Debug, PartialEq)]
pub struct ModbusOptions {
    /// One request, from sending to the complete reply.
    pub timeout: Duration,
    /// Further attempts after a lost or garbled reply (exceptions are not retried).
    pub retries: u32,
    /// Opening the socket or the port.
    pub connect_timeout: Duration,
    /// Homing, and waiting for a move to end.
    pub motion_timeout: Duration,
    /// Status polling period while waiting for motion.
    pub poll_interval: Duration,
    /// RTU silent interval between frames; `None`: 3.5 characters at the baud rate
    /// (1.75 ms above 19200 baud), as the serial-line specification says.
    pub rtu_gap: Option<Duration>,
    /// RTU, after a failure: discard input until the line is quiet this long; `None`:
    /// the request timeout.
    pub rtu_quiet: Option<Duration>,
}

impl Default for ModbusOptions {
    fn default() -> Self {
        Self {
            timeout: Duration::from_millis(500),
            retries: 2,
            connect_timeout: Duration::from_secs(3),
            motion_timeout: Duration::from_secs(120),
            poll_interval: Duration::from_millis(10),
            rtu_gap: None,
            rtu_quiet: None,
        }
    }
}

/// Which axis a unit drives and its limits.
#[derive(Clone, Debug, PartialEq)]
pub struct ModbusAxisConfig {
    pub axis: Axis,
    /// Unit (slave) id, 1..=247.
    pub unit: u8,
    /// Soft limits, mm (machine coordinates).
    pub min_mm: f64,
    pub max_mm: f64,
    /// Defaults to the profile's `max_speed_mm_min`.
    pub max_feed_mm_min: Option<f64>,
}

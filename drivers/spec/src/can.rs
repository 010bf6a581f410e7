//! CAN buses.

/// Where a bus is.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum BusSpec {
    /// An SLCAN (Lawicel) adapter on a serial port, at a CAN bitrate (bits/s).
    Slcan { port: String, bitrate: u32 },
    /// A SocketCAN interface (`can0`, `vcan0`), already configured and up.
    SocketCan { interface: String },
}

impl std::fmt::Display for BusSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            BusSpec::Slcan { port, bitrate } => write!(f, "slcan {port} @ {bitrate} bit/s"),
            BusSpec::SocketCan { interface } => write!(f, "socketcan {interface}"),
        }
    }
}

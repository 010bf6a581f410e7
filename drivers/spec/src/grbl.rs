//! GRBL controllers on a serial port.

use std::time::Duration;

/// Timeouts and formats of the driver.
#[derive(Clone, Debug, PartialEq)]
pub struct GrblOptions {
    /// Whole connect handshake (`$I`, `$$`, first status).
    pub connect_timeout: Duration,
    /// One send-response command or status request.
    pub command_timeout: Duration,
    /// Homing, waiting for motion to end, and no progress at all while streaming.
    pub motion_timeout: Duration,
    /// Status polling period while waiting for motion.
    pub poll_interval: Duration,
    /// Decimals of coordinates sent in moves.
    pub decimals: usize,
}

impl Default for GrblOptions {
    fn default() -> Self {
        Self {
            connect_timeout: Duration::from_secs(5),
            command_timeout: Duration::from_secs(2),
            motion_timeout: Duration::from_secs(120),
            poll_interval: Duration::from_millis(20),
            decimals: 4,
        }
    }
}

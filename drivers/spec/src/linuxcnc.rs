//! LinuxCNC machines through `linuxcncrsh`, LinuxCNC's text remote shell over TCP.

use crate::axis::Axis;
use std::time::Duration;

/// The passwords, timeouts and formats of the LinuxCNC driver.
#[derive(Clone, Debug, PartialEq)]
pub struct LinuxcncOptions {
    /// `hello <password> ...` (linuxcncrsh `--connectpw`, default `EMC`).
    pub connect_password: String,
    /// `set enable <password>` (linuxcncrsh `--enablepw`, default `EMCTOO`).
    pub enable_password: String,
    /// The client name sent with `hello` (one word; linuxcncrsh keeps 79 bytes).
    pub client_name: String,
    /// Connecting and the whole handshake.
    pub connect_timeout: Duration,
    /// One command and its reply (state changes confirmed by a `get`).
    pub command_timeout: Duration,
    /// Homing and one move until the end of its motion.
    pub motion_timeout: Duration,
    /// Polling period while waiting for homing or for a state to be confirmed.
    pub poll_interval: Duration,
    /// Decimals of coordinates sent in MDI moves (LinuxCNC parses doubles).
    pub decimals: usize,
}

impl Default for LinuxcncOptions {
    fn default() -> Self {
        Self {
            connect_password: "EMC".into(),
            enable_password: "EMCTOO".into(),
            client_name: "xy-gateway".into(),
            connect_timeout: Duration::from_secs(5),
            command_timeout: Duration::from_secs(5),
            motion_timeout: Duration::from_secs(120),
            poll_interval: Duration::from_millis(10),
            decimals: 6,
        }
    }
}

/// One axis the gateway drives: its letter in LinuxCNC's `[TRAJ] COORDINATES`, the
/// joint that carries it (trivial kinematics: X on joint 0, Y on 1, Z on 2), whose
/// homing the driver checks, and its soft limits and fastest feed as the job states
/// them (linuxcncrsh does not tell them: `get ini` answers nothing usable in 2.9), at
/// most the INI's `[AXIS_*] MIN_LIMIT`, `MAX_LIMIT`, `MAX_VELOCITY` x 60.
#[derive(Clone, Debug, PartialEq)]
pub struct LinuxcncAxis {
    pub axis: Axis,
    pub joint: u8,
    pub min_mm: f64,
    pub max_mm: f64,
    pub max_feed_mm_min: f64,
}

//! CANopen CiA 402 drives.

use crate::axis::Axis;
use std::time::Duration;

/// One axis's drive: where it is on the bus and how its units relate to mm.
#[derive(Clone, Debug, PartialEq)]
pub struct AxisConfig {
    pub axis: Axis,
    pub node: u8,
    /// Drive position units (encoder counts) per mm.
    pub counts_per_mm: f64,
    pub min_mm: f64,
    pub max_mm: f64,
    pub max_feed_mm_min: f64,
    /// Profile acceleration and deceleration, mm/s^2.
    pub accel_mm_s2: f64,
    /// CiA 402 homing method (0x6098), e.g. 17 = negative limit switch.
    pub homing_method: i8,
}

/// Timing of the driver. Every wait is bounded by one of these.
#[derive(Clone, Debug, PartialEq)]
pub struct CanopenOptions {
    pub sdo_timeout: Duration,
    /// Heartbeat period the driver gives each node (0x1017), ms.
    pub heartbeat_ms: u16,
    /// Silence after which a node counts as lost.
    pub heartbeat_timeout: Duration,
    /// One state-machine step (statusword change after a controlword).
    pub state_timeout: Duration,
    pub motion_timeout: Duration,
    pub homing_timeout: Duration,
    /// TPDO2 (statusword + position) inhibit time, 100 us units.
    pub position_inhibit_100us: u16,
    /// TPDO2 event timer, ms (refresh even without change).
    pub position_event_ms: u16,
}

impl Default for CanopenOptions {
    fn default() -> Self {
        Self {
            sdo_timeout: Duration::from_millis(500),
            heartbeat_ms: 100,
            heartbeat_timeout: Duration::from_millis(350),
            state_timeout: Duration::from_secs(1),
            motion_timeout: Duration::from_secs(60),
            homing_timeout: Duration::from_secs(60),
            position_inhibit_100us: 20,
            position_event_ms: 100,
        }
    }
}

//! Shared set-up of the CANopen system tests: a simulated rig, the CiA 402 drive
//! emulator behind an SLCAN adapter on a real pseudo-terminal, and the driver
//! connected to it by path.

// Not every test binary that includes this module uses all of it.
#![allow(dead_code, unused_imports)]

use drivers::can::slcan::SlcanBus;
use drivers::canopen::{open_stage, AxisConfig, CanopenOptions, Network};
use drivers::{Axis, MultiAxisStage};
use emulators::canopen::{DriveSet, DriveSetConfig, SharedSet, SlcanPty};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use world::Clock;
pub use world::SharedRig;

pub const X_NODE: u8 = 1;
pub const Y_NODE: u8 = 2;

pub use system_tests::runtime;
pub use system_tests::{config_dir, reference_rig as rig};

/// The drives (X = node 1, Y = node 2) on a fresh SLCAN pseudo-terminal.
pub fn emulator(rig: &SharedRig, clock: Clock) -> SlcanPty {
    let set = DriveSet::new(rig.clone(), &DriveSetConfig::xy(X_NODE, Y_NODE, clock), 0.0).unwrap();
    let set: SharedSet = Arc::new(Mutex::new(set));
    SlcanPty::spawn(set, None).expect("pseudo-terminal")
}

/// The axes as the gateway would configure them for the simulated C5 stage.
pub fn axes() -> Vec<AxisConfig> {
    let a = |axis, node, travel| AxisConfig {
        axis,
        node,
        counts_per_mm: 2000.0,
        min_mm: 0.0,
        max_mm: travel,
        max_feed_mm_min: 6000.0,
        accel_mm_s2: 800.0,
        homing_method: 17,
    };
    vec![a(Axis::X, X_NODE, 200.0), a(Axis::Y, Y_NODE, 150.0)]
}

/// Short timeouts: a broken test fails in seconds.
pub fn options() -> CanopenOptions {
    CanopenOptions {
        sdo_timeout: Duration::from_millis(500),
        heartbeat_ms: 50,
        heartbeat_timeout: Duration::from_millis(300),
        state_timeout: Duration::from_secs(1),
        motion_timeout: Duration::from_secs(20),
        homing_timeout: Duration::from_secs(20),
        position_inhibit_100us: 20,
        position_event_ms: 100,
    }
}

pub async fn connect(path: &str, axes: Vec<AxisConfig>) -> (MultiAxisStage, Network) {
    let bus = SlcanBus::open(path, 1_000_000)
        .await
        .expect("open the SLCAN adapter");
    open_stage(Box::new(bus), axes, options())
        .await
        .expect("bring up the drives")
}

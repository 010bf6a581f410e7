//! Shared set-up of the Modbus system tests: a simulated rig, the drive emulator on a
//! TCP port of the loopback interface or on a real pseudo-terminal, and the driver.

// Not every test binary that includes this module uses all of it.
#![allow(dead_code, unused_imports)]

use drivers::modbus::{Endpoint, ModbusAxis, ModbusAxisConfig, ModbusBus, ModbusOptions, Parity};
use drivers::Axis;
use emulators::modbus::{DriveSet, MachineAxis, ModbusDevice, ModbusRtu, ModbusTcp};
use protocol::modbus::DriveProfile;
use std::sync::Arc;
use std::time::Duration;
use world::{Clock, SharedRig};

pub use system_tests::config_dir;

pub use system_tests::reference_rig as rig;

pub use system_tests::runtime;

pub fn profile(name: &str) -> Arc<DriveProfile> {
    Arc::new(DriveProfile::load(&config_dir().join(format!("drives/{name}.toml"))).unwrap())
}

/// The drives `units` (id, axis) of `profile` on the rig, motion unconstrained.
pub fn device(
    rig: &SharedRig,
    profile: &Arc<DriveProfile>,
    units: &[(u8, MachineAxis)],
) -> Arc<ModbusDevice> {
    ModbusDevice::new(DriveSet::new(
        rig.clone(),
        profile.clone(),
        units,
        Clock::Unconstrained,
    ))
}

pub async fn tcp(device: &Arc<ModbusDevice>) -> ModbusTcp {
    ModbusTcp::bind(device.clone(), "127.0.0.1:0".parse().unwrap())
        .await
        .unwrap()
}

pub fn rtu(device: &Arc<ModbusDevice>) -> ModbusRtu {
    ModbusRtu::spawn(device.clone(), None).expect("pseudo-terminal")
}

/// Short deadlines: a broken test fails in seconds, and fault tests stay fast.
pub fn options() -> ModbusOptions {
    ModbusOptions {
        timeout: Duration::from_millis(150),
        retries: 2,
        connect_timeout: Duration::from_secs(2),
        motion_timeout: Duration::from_secs(10),
        poll_interval: Duration::from_millis(1),
        rtu_gap: None,
        rtu_quiet: None,
    }
}

pub fn rtu_endpoint(path: &str) -> Endpoint {
    Endpoint::Rtu {
        path: path.to_string(),
        baud: 115_200,
        parity: Parity::None,
    }
}

pub fn axis_cfg(axis: Axis, unit: u8) -> ModbusAxisConfig {
    let max_mm = if axis == Axis::X { 200.0 } else { 150.0 };
    ModbusAxisConfig {
        axis,
        unit,
        min_mm: 0.0,
        max_mm,
        max_feed_mm_min: None,
    }
}

/// One axis on its own bus.
pub async fn axis(
    endpoint: Endpoint,
    profile: &Arc<DriveProfile>,
    axis: Axis,
    unit: u8,
) -> ModbusAxis {
    let bus = ModbusBus::new(endpoint, options()).shared();
    ModbusAxis::new(bus, profile.clone(), &axis_cfg(axis, unit)).await
}

/// The controller's counts of the simulated machine, in mm.
pub fn machine_mm(rig: &SharedRig) -> [f64; 2] {
    rig.lock().unwrap().machine().position_mm()
}

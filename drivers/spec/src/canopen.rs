//! CANopen CiA 402 drives, and what the driver requires of a drive's object
//! dictionary (so a job can refuse an EDS before any bus is opened).

use crate::axis::Axis;
use protocol::canopen::od::ObjectDictionary;
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

/// An object (sub-index 0) the CiA 402 driver reads, writes or maps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RequiredObject {
    pub index: u16,
    /// Its CiA name, for messages.
    pub name: &'static str,
    /// The driver maps it into a PDO, so the drive must allow that.
    pub pdo_mapped: bool,
}

const fn req(index: u16, name: &'static str, pdo_mapped: bool) -> RequiredObject {
    RequiredObject {
        index,
        name,
        pdo_mapped,
    }
}

/// Objects the driver reads, writes or maps: an EDS without them describes a drive
/// this driver cannot run.
pub const REQUIRED_OBJECTS: [RequiredObject; 10] = [
    req(0x1000, "device type", false),
    req(0x1017, "producer heartbeat time", false),
    req(0x6040, "controlword", true),
    req(0x6041, "statusword", true),
    req(0x6060, "modes of operation", false),
    req(0x6061, "modes of operation display", true),
    req(0x6064, "position actual value", true),
    req(0x607A, "target position", true),
    req(0x6081, "profile velocity", true),
    req(0x6098, "homing method", false),
];

/// Check that a drive's EDS has every [`REQUIRED_OBJECTS`] entry, PDO-mappable where
/// the driver maps it. The error names the EDS (`od.source`) and the first object
/// missing or not mappable.
pub fn check_drive_eds(od: &ObjectDictionary) -> Result<(), String> {
    for RequiredObject {
        index,
        name,
        pdo_mapped,
    } in REQUIRED_OBJECTS
    {
        let v = od
            .variable(index, 0)
            .map_err(|_| format!("{}: no object 0x{index:04X} ({name})", od.source))?;
        if pdo_mapped && !v.pdo_mappable {
            return Err(format!(
                "{}: 0x{index:04X} ({name}) is not PDO-mappable",
                od.source
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::canopen::NodeId;

    /// The drive the emulator serves (emulators' `DRIVE_EDS` is this file).
    const DRIVE_EDS: &str = include_str!("../../../config/canopen/drive.eds");

    fn od(text: &str) -> ObjectDictionary {
        ObjectDictionary::from_eds("drive.eds", text, NodeId::new(1).unwrap()).unwrap()
    }

    /// The EDS text with the section `[name]` (and its keys) removed.
    fn without_section(name: &str) -> String {
        let mut out = String::new();
        let mut skip = false;
        for line in DRIVE_EDS.lines() {
            if line.trim_start().starts_with('[') {
                skip = line.trim() == format!("[{name}]");
            }
            if !skip {
                out.push_str(line);
                out.push('\n');
            }
        }
        out
    }

    #[test]
    fn the_emulated_drive_passes() {
        assert_eq!(check_drive_eds(&od(DRIVE_EDS)), Ok(()));
    }

    #[test]
    fn a_missing_object_is_named() {
        let text = without_section("6081");
        assert_ne!(text, DRIVE_EDS, "the test EDS has a [6081] section");
        assert_eq!(
            check_drive_eds(&od(&text)),
            Err("drive.eds: no object 0x6081 (profile velocity)".into())
        );
    }

    #[test]
    fn an_object_that_cannot_be_mapped_is_named() {
        let mut od = od(DRIVE_EDS);
        let statusword = od
            .objects
            .get_mut(&0x6041)
            .unwrap()
            .subs
            .get_mut(&0)
            .unwrap();
        statusword.pdo_mappable = false;
        assert_eq!(
            check_drive_eds(&od),
            Err("drive.eds: 0x6041 (statusword) is not PDO-mappable".into())
        );
    }

    #[test]
    fn only_objects_the_driver_maps_need_be_mappable() {
        let mut od = od(DRIVE_EDS);
        for v in od.objects.get_mut(&0x6098).unwrap().subs.values_mut() {
            v.pdo_mappable = false;
        }
        assert_eq!(check_drive_eds(&od), Ok(()));
    }
}

//! The `canopen` stage backend of a job: CiA 402 drives, one node per axis, on one CAN
//! bus reached through an SLCAN adapter or a SocketCAN interface; or, for the demo, the
//! CiA 402 drive emulator behind an SLCAN adapter on a real pseudo-terminal, driving
//! the simulated machine the simulated camera looks at. Either way the pipeline talks
//! to the real driver over real CANopen frames.
//!
//! ```toml
//! [stage]
//! driver = "canopen"
//! slcan = "/dev/ttyACM0"              # or: socketcan = "can0"
//! bitrate = 1000000                   # slcan only (the adapter sets it)
//! # emulate = "../machines/c5-stage.toml"  (the demo: drive emulator on a pty)
//! eds = "../canopen/drive.eds"        # optional: objects the driver uses are checked
//! homing_method = 17                  # CiA 402 0x6098
//! heartbeat_ms = 100                  # each node's heartbeat; lost after 3.5 periods
//! sdo_timeout_ms = 500
//! axes = [
//!   { axis = "x", node = 1, counts_per_mm = 2000.0, min_mm = 0.0, max_mm = 200.0 },
//!   { axis = "y", node = 2, counts_per_mm = 2000.0, min_mm = 0.0, max_mm = 150.0 },
//! ]                                   # + max_feed_mm_min (6000), accel_mm_s2 (800)
//! ```

use link_spec::can::BusSpec;
use link_spec::canopen::{check_drive_eds, AxisConfig, CanopenOptions};
use link_spec::Axis;
use protocol::canopen::od::ObjectDictionary;
use protocol::canopen::NodeId;
use protocol::config::{ConfigDoc, ConfigError};
use serde::Deserialize;
use std::time::Duration;
use world::machine::MachineConfig;

/// `[stage]` with `driver = "canopen"`, as written.
#[derive(Deserialize, Debug)]
#[serde(deny_unknown_fields)]
pub struct RawCanopenStage {
    slcan: Option<String>,
    socketcan: Option<String>,
    emulate: Option<String>,
    #[serde(default = "default_bitrate")]
    bitrate: u32,
    eds: Option<String>,
    #[serde(default = "default_homing")]
    homing_method: i8,
    #[serde(default = "default_heartbeat")]
    heartbeat_ms: u16,
    #[serde(default = "default_sdo_timeout")]
    sdo_timeout_ms: u64,
    axes: Vec<RawCanopenAxis>,
}

#[derive(Deserialize, Debug)]
#[serde(deny_unknown_fields)]
struct RawCanopenAxis {
    axis: String,
    node: u8,
    counts_per_mm: f64,
    min_mm: f64,
    max_mm: f64,
    #[serde(default = "default_feed")]
    max_feed_mm_min: f64,
    #[serde(default = "default_accel")]
    accel_mm_s2: f64,
}

fn default_bitrate() -> u32 {
    1_000_000
}
pub(crate) fn default_homing() -> i8 {
    17
}
pub(crate) fn default_heartbeat() -> u16 {
    100
}
pub(crate) fn default_sdo_timeout() -> u64 {
    500
}
fn default_feed() -> f64 {
    6000.0
}
fn default_accel() -> f64 {
    800.0
}

/// Where the drives are.
#[derive(Clone, Debug)]
pub enum CanopenLink {
    Bus(BusSpec),
    /// The drive emulator in-process, behind an SLCAN adapter on a pseudo-terminal,
    /// driving this machine.
    Emulate {
        machine: Box<MachineConfig>,
        /// The EDS the emulated drives describe themselves by (name, text); None: the
        /// emulator's own.
        eds: Option<(String, String)>,
    },
}

/// A resolved, checked CANopen stage.
#[derive(Clone, Debug)]
pub struct CanopenStageSpec {
    pub link: CanopenLink,
    pub axes: Vec<AxisConfig>,
    pub options: CanopenOptions,
}

/// Check a `[stage]` of driver `canopen` (errors name the job file, line and key).
pub fn resolve(doc: &ConfigDoc, raw: RawCanopenStage) -> Result<CanopenStageSpec, ConfigError> {
    let given = [
        raw.slcan.is_some(),
        raw.socketcan.is_some(),
        raw.emulate.is_some(),
    ];
    if given.iter().filter(|g| **g).count() != 1 {
        return Err(doc.invalid(
            "stage.slcan",
            "the canopen stage needs exactly one of `slcan` (an SLCAN adapter's serial port), `socketcan` (an interface such as can0) or `emulate` (a machine file for the drive emulator)",
        ));
    }
    if protocol::slcan::bitrate_code(raw.bitrate).is_none() {
        return Err(doc.invalid(
            "stage.bitrate",
            format!(
                "{} bit/s: SLCAN adapters take {:?}",
                raw.bitrate,
                protocol::slcan::BITRATES
            ),
        ));
    }
    if raw.sdo_timeout_ms == 0 || raw.sdo_timeout_ms > 10_000 {
        return Err(doc.invalid("stage.sdo_timeout_ms", "must be 1..=10000 ms"));
    }
    if raw.heartbeat_ms != 0 && raw.heartbeat_ms < 10 {
        return Err(doc.invalid("stage.heartbeat_ms", "0 (no supervision) or at least 10 ms"));
    }
    if !(raw.homing_method < 0 || (1..=37).contains(&raw.homing_method)) {
        return Err(doc.invalid(
            "stage.homing_method",
            "a CiA 402 homing method is 1..37 (or negative, vendor-specific)",
        ));
    }
    let eds = match &raw.eds {
        Some(rel) => {
            let e = doc.read_relative("stage.eds", rel)?;
            Some((e.name.clone(), e.text.clone()))
        }
        None => None,
    };
    if let Some((name, text)) = &eds {
        let node = NodeId::new(raw.axes.first().map_or(1, |a| a.node))
            .unwrap_or(NodeId::new(1).expect("1 is a node id"));
        let od = ObjectDictionary::from_eds(name, text, node)?;
        check_drive_eds(&od).map_err(|m| doc.invalid("stage.eds", m))?;
    }
    let mut axes: Vec<AxisConfig> = Vec::new();
    for (i, a) in raw.axes.iter().enumerate() {
        let key = |k: &str| format!("stage.axes[{i}].{k}");
        let axis = match a.axis.to_ascii_lowercase().as_str() {
            "x" => Axis::X,
            "y" => Axis::Y,
            "z" => Axis::Z,
            other => {
                return Err(doc.invalid(&key("axis"), format!("`{other}`: expected x, y or z")))
            }
        };
        if NodeId::new(a.node).is_none() {
            return Err(doc.invalid(&key("node"), "a CANopen node id is 1..=127"));
        }
        if axes.iter().any(|o| o.axis == axis) {
            return Err(doc.invalid(&key("axis"), format!("axis {axis} is given twice")));
        }
        if axes.iter().any(|o| o.node == a.node) {
            return Err(doc.invalid(&key("node"), format!("node {} is given twice", a.node)));
        }
        // As the machine file's: at least a count and 1 mm/s² per mm, at most 10^6.
        doc.in_range(
            &key("counts_per_mm"),
            a.counts_per_mm,
            1.0,
            1e6,
            "counts/mm",
        )?;
        doc.in_range(&key("accel_mm_s2"), a.accel_mm_s2, 1.0, 100_000.0, "mm/s²")?;
        crate::bounds::check_axis(doc, &key, a.min_mm, a.max_mm, Some(a.max_feed_mm_min))?;
        axes.push(AxisConfig {
            axis,
            node: a.node,
            counts_per_mm: a.counts_per_mm,
            min_mm: a.min_mm,
            max_mm: a.max_mm,
            max_feed_mm_min: a.max_feed_mm_min,
            accel_mm_s2: a.accel_mm_s2,
            homing_method: raw.homing_method,
        });
    }
    if !(axes.iter().any(|a| a.axis == Axis::X) && axes.iter().any(|a| a.axis == Axis::Y)) {
        return Err(doc.invalid("stage.axes", "needs an x and a y axis"));
    }
    let link = if let Some(port) = raw.slcan {
        CanopenLink::Bus(BusSpec::Slcan {
            port,
            bitrate: raw.bitrate,
        })
    } else if let Some(interface) = raw.socketcan {
        CanopenLink::Bus(BusSpec::SocketCan { interface })
    } else {
        let rel = raw.emulate.unwrap_or_default();
        let machine = MachineConfig::from_doc(&doc.read_relative("stage.emulate", &rel)?)?;
        check_emulated(&machine, &axes).map_err(|m| doc.invalid("stage.axes", m))?;
        CanopenLink::Emulate {
            machine: Box::new(machine),
            eds,
        }
    };
    Ok(CanopenStageSpec {
        link,
        axes,
        options: options(raw.heartbeat_ms, raw.sdo_timeout_ms),
    })
}

pub(crate) fn options(heartbeat_ms: u16, sdo_timeout_ms: u64) -> CanopenOptions {
    CanopenOptions {
        sdo_timeout: Duration::from_millis(sdo_timeout_ms),
        heartbeat_ms,
        heartbeat_timeout: Duration::from_millis(u64::from(heartbeat_ms) * 7 / 2),
        ..Default::default()
    }
}

/// The emulated machine's counts are the drives' position units, and it has X and Y.
fn check_emulated(m: &MachineConfig, axes: &[AxisConfig]) -> Result<(), String> {
    for a in axes {
        let cpm = match a.axis {
            Axis::X => m.axes.x.counts_per_mm,
            Axis::Y => m.axes.y.counts_per_mm,
            other => return Err(format!("the emulated machine has no {other} axis")),
        };
        if (a.counts_per_mm - cpm).abs() > 1e-9 {
            return Err(format!(
                "axis {}: counts_per_mm {} differs from the emulated machine's {cpm}: the drive's position units are the machine's counts",
                a.axis, a.counts_per_mm
            ));
        }
    }
    Ok(())
}

//! The `modbus` stage backend of a job: one Modbus positioning drive per axis over
//! Modbus TCP or RTU, register maps from a drive profile; or, for the demo, the Modbus
//! drive emulator (on a loopback TCP port or a real pseudo-terminal) driving the
//! simulated machine the simulated camera looks at. Either way the pipeline talks to
//! the real driver over real Modbus bytes.
//!
//! ```toml
//! [stage]
//! driver = "modbus"
//! profile = "../drives/generic.toml"
//! tcp = "192.168.0.20:502"            # or: rtu = "/dev/ttyUSB0" (+ baud, parity)
//! # emulate = "../machines/c5-stage.toml" + transport = "tcp" | "rtu" (the demo)
//! axes = [
//!   { axis = "x", unit = 1, min_mm = 0.0, max_mm = 200.0 },
//!   { axis = "y", unit = 2, min_mm = 0.0, max_mm = 150.0 },
//! ]
//! timeout_ms = 500                    # per request; retries = 2
//! ```

use link_spec::modbus::{ModbusAxisConfig, ModbusOptions, Parity};
use link_spec::Axis;
use protocol::config::{ConfigDoc, ConfigError};
use protocol::modbus::DriveProfile;
use serde::Deserialize;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;
use world::machine::MachineConfig;

/// The profile the demo uses, compiled in.
pub(crate) const GENERIC_PROFILE: &str = include_str!("../../../config/drives/generic.toml");

/// `[stage]` with `driver = "modbus"`, as written.
#[derive(Deserialize, Debug)]
#[serde(deny_unknown_fields)]
pub struct RawModbusStage {
    profile: String,
    tcp: Option<String>,
    rtu: Option<String>,
    #[serde(default = "default_rtu_baud")]
    baud: u32,
    #[serde(default = "default_parity")]
    parity: String,
    emulate: Option<String>,
    #[serde(default = "default_transport")]
    transport: String,
    axes: Vec<RawModbusAxis>,
    #[serde(default = "default_timeout_ms")]
    timeout_ms: u64,
    #[serde(default = "default_retries")]
    retries: u32,
}

#[derive(Deserialize, Debug)]
#[serde(deny_unknown_fields)]
struct RawModbusAxis {
    axis: String,
    unit: u8,
    min_mm: f64,
    max_mm: f64,
    max_feed_mm_min: Option<f64>,
}

fn default_rtu_baud() -> u32 {
    19_200
}
fn default_parity() -> String {
    "even".into()
}
fn default_transport() -> String {
    "tcp".into()
}
pub(crate) fn default_timeout_ms() -> u64 {
    500
}
pub(crate) fn default_retries() -> u32 {
    2
}

/// Where the drives are.
#[derive(Clone, Debug)]
pub enum ModbusLink {
    Tcp(SocketAddr),
    Rtu {
        port: String,
        baud: u32,
        parity: Parity,
    },
    /// The drive emulator in-process, on this transport, driving this machine.
    Emulate {
        machine: Box<MachineConfig>,
        rtu: bool,
    },
}

/// A resolved, checked Modbus stage.
#[derive(Clone, Debug)]
pub struct ModbusStageSpec {
    pub profile: Arc<DriveProfile>,
    pub link: ModbusLink,
    pub axes: Vec<ModbusAxisConfig>,
    pub timeout_ms: u64,
    pub retries: u32,
}

impl ModbusStageSpec {
    /// The driver options this stage asks for.
    pub fn options(&self) -> ModbusOptions {
        ModbusOptions {
            timeout: Duration::from_millis(self.timeout_ms),
            retries: self.retries,
            ..Default::default()
        }
    }
}

/// Check a `[stage]` of driver `modbus` (errors name the job file, line and key).
pub fn resolve(doc: &ConfigDoc, raw: RawModbusStage) -> Result<ModbusStageSpec, ConfigError> {
    let pdoc = doc.read_relative("stage.profile", &raw.profile)?;
    let profile = Arc::new(DriveProfile::from_doc(&pdoc)?);
    let given = [raw.tcp.is_some(), raw.rtu.is_some(), raw.emulate.is_some()];
    if given.iter().filter(|g| **g).count() != 1 {
        return Err(doc.invalid(
            "stage.tcp",
            "the modbus stage needs exactly one of `tcp` (address:port), `rtu` (a serial port) or `emulate` (a machine file for the drive emulator)",
        ));
    }
    let parity = match raw.parity.as_str() {
        "none" => Parity::None,
        "even" => Parity::Even,
        "odd" => Parity::Odd,
        other => {
            return Err(doc.invalid(
                "stage.parity",
                format!("`{other}`: expected none, even or odd"),
            ))
        }
    };
    crate::bounds::check_baud(doc, raw.baud)?;
    if raw.timeout_ms == 0 || raw.timeout_ms > 60_000 {
        return Err(doc.invalid("stage.timeout_ms", "must be 1..=60000 ms"));
    }
    if raw.retries > 10 {
        return Err(doc.invalid("stage.retries", "at most 10"));
    }
    let mut axes: Vec<ModbusAxisConfig> = Vec::new();
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
        if !(1..=247).contains(&a.unit) {
            return Err(doc.invalid(&key("unit"), "a unit id is 1..=247"));
        }
        if axes.iter().any(|o| o.axis == axis) {
            return Err(doc.invalid(&key("axis"), format!("axis {axis} is given twice")));
        }
        if axes.iter().any(|o| o.unit == a.unit) {
            return Err(doc.invalid(&key("unit"), format!("unit {} is given twice", a.unit)));
        }
        crate::bounds::check_axis(doc, &key, a.min_mm, a.max_mm, a.max_feed_mm_min)?;
        axes.push(ModbusAxisConfig {
            axis,
            unit: a.unit,
            min_mm: a.min_mm,
            max_mm: a.max_mm,
            max_feed_mm_min: a.max_feed_mm_min,
        });
    }
    if !(axes.iter().any(|a| a.axis == Axis::X) && axes.iter().any(|a| a.axis == Axis::Y)) {
        return Err(doc.invalid("stage.axes", "needs an x and a y axis"));
    }
    let link = if let Some(t) = raw.tcp {
        let addr = t
            .parse::<SocketAddr>()
            .map_err(|e| doc.invalid("stage.tcp", format!("`{t}`: expected address:port ({e})")))?;
        ModbusLink::Tcp(addr)
    } else if let Some(port) = raw.rtu {
        ModbusLink::Rtu {
            port,
            baud: raw.baud,
            parity,
        }
    } else {
        let rel = raw.emulate.unwrap_or_default();
        let machine = MachineConfig::from_doc(&doc.read_relative("stage.emulate", &rel)?)?;
        let rtu = match raw.transport.as_str() {
            "tcp" => false,
            "rtu" => true,
            other => {
                return Err(
                    doc.invalid("stage.transport", format!("`{other}`: expected tcp or rtu"))
                )
            }
        };
        check_emulated(&profile, &machine, &axes).map_err(|m| doc.invalid("stage.profile", m))?;
        ModbusLink::Emulate {
            machine: Box::new(machine),
            rtu,
        }
    };
    Ok(ModbusStageSpec {
        profile,
        link,
        axes,
        timeout_ms: raw.timeout_ms,
        retries: raw.retries,
    })
}

/// The emulated machine must have the profile's resolution (its counts are the
/// drives' counts) and only X and Y.
pub(crate) fn check_emulated(
    profile: &DriveProfile,
    m: &MachineConfig,
    axes: &[ModbusAxisConfig],
) -> Result<(), String> {
    for (name, a) in [("x", &m.axes.x), ("y", &m.axes.y)] {
        if (a.counts_per_mm - profile.counts_per_mm()).abs() > 1e-9 {
            return Err(format!(
                "the emulated machine's {name} axis has {} counts/mm but the profile {} has {}: they must agree",
                a.counts_per_mm,
                profile.file,
                profile.counts_per_mm()
            ));
        }
    }
    if let Some(a) = axes.iter().find(|a| !matches!(a.axis, Axis::X | Axis::Y)) {
        return Err(format!("the emulated machine has no {} axis", a.axis));
    }
    Ok(())
}

//! The `linuxcnc` stage backend of a job: a LinuxCNC machine through its text remote
//! shell `linuxcncrsh` (see `drivers::linuxcnc` and docs/links.md).
//!
//! ```toml
//! [stage]
//! driver = "linuxcnc"
//! host = "192.168.0.30"               # the LinuxCNC computer
//! port = 5007                         # linuxcncrsh's --port (default 5007)
//! connect_password = "EMC"            # linuxcncrsh's --connectpw (default EMC)
//! enable_password = "EMCTOO"          # linuxcncrsh's --enablepw (default EMCTOO)
//! axes = [                            # at most the INI's [AXIS_*] limits
//!   { axis = "x", joint = 0, min_mm = 0.0, max_mm = 200.0, max_feed_mm_min = 6000.0 },
//!   { axis = "y", joint = 1, min_mm = 0.0, max_mm = 150.0, max_feed_mm_min = 6000.0 },
//! ]
//! timeout_ms = 5000                   # one command; motion_timeout_s = 120 for a move
//! # follow = "../machines/c5-stage.toml"  # tests and demos: the simulated stage follows
//! #   LinuxCNC's joint motor commands (LinuxCNC on this computer), the sim camera on it
//! ```

use link_spec::linuxcnc::{LinuxcncAxis, LinuxcncOptions};
use link_spec::Axis;
use protocol::config::{ConfigDoc, ConfigError};
use serde::Deserialize;
use std::time::Duration;
use world::machine::MachineConfig;

/// `[stage]` with `driver = "linuxcnc"`, as written.
#[derive(Deserialize, Debug)]
#[serde(deny_unknown_fields)]
pub struct RawLinuxcncStage {
    host: String,
    #[serde(default = "default_port")]
    port: u16,
    #[serde(default = "default_connect_password")]
    connect_password: String,
    #[serde(default = "default_enable_password")]
    enable_password: String,
    axes: Vec<RawLinuxcncAxis>,
    #[serde(default = "default_timeout_ms")]
    timeout_ms: u64,
    #[serde(default = "default_motion_timeout_s")]
    motion_timeout_s: u64,
    follow: Option<String>,
}

#[derive(Deserialize, Debug)]
#[serde(deny_unknown_fields)]
struct RawLinuxcncAxis {
    axis: String,
    joint: Option<u8>,
    min_mm: f64,
    max_mm: f64,
    max_feed_mm_min: f64,
}

fn default_port() -> u16 {
    5007
}
fn default_connect_password() -> String {
    "EMC".into()
}
fn default_enable_password() -> String {
    "EMCTOO".into()
}
fn default_timeout_ms() -> u64 {
    5000
}
fn default_motion_timeout_s() -> u64 {
    120
}

/// A resolved, checked LinuxCNC stage.
#[derive(Clone, Debug)]
pub struct LinuxcncStageSpec {
    /// `host:port` of linuxcncrsh.
    pub address: String,
    pub options: LinuxcncOptions,
    pub axes: Vec<LinuxcncAxis>,
    /// The simulated machine that follows LinuxCNC's joint motor commands (a test or
    /// demo rig: LinuxCNC runs on this computer), for the simulated camera.
    pub follow: Option<Box<MachineConfig>>,
}

fn password(doc: &ConfigDoc, key: &str, value: &str) -> Result<(), ConfigError> {
    // linuxcncrsh reads a password as one word and compares it in a 16-byte buffer.
    if value.is_empty() || value.len() > 15 || !value.bytes().all(|b| b.is_ascii_graphic()) {
        return Err(doc.invalid(
            key,
            "must be 1 to 15 printable ASCII characters without blanks (linuxcncrsh's limit)",
        ));
    }
    Ok(())
}

/// Check a `[stage]` of driver `linuxcnc` (errors name the job file, line and key).
pub fn resolve(doc: &ConfigDoc, raw: RawLinuxcncStage) -> Result<LinuxcncStageSpec, ConfigError> {
    if raw.host.is_empty() || raw.host.len() > 253 || raw.host.contains(char::is_whitespace) {
        return Err(doc.invalid("stage.host", "must be a host name or address (no blanks)"));
    }
    if raw.port == 0 {
        return Err(doc.invalid("stage.port", "must be a TCP port 1..=65535"));
    }
    password(doc, "stage.connect_password", &raw.connect_password)?;
    password(doc, "stage.enable_password", &raw.enable_password)?;
    if raw.enable_password.eq_ignore_ascii_case("off") {
        return Err(doc.invalid(
            "stage.enable_password",
            "cannot be `off` (linuxcncrsh reads `set enable off` as giving up control)",
        ));
    }
    if !(100..=60_000).contains(&raw.timeout_ms) {
        return Err(doc.invalid("stage.timeout_ms", "must be 100..=60000 ms"));
    }
    if !(1..=3600).contains(&raw.motion_timeout_s) {
        return Err(doc.invalid("stage.motion_timeout_s", "must be 1..=3600 s"));
    }
    let mut axes: Vec<LinuxcncAxis> = Vec::new();
    for (i, a) in raw.axes.iter().enumerate() {
        let key = |k: &str| format!("stage.axes[{i}].{k}");
        let (axis, trivial_joint) = match a.axis.to_ascii_lowercase().as_str() {
            "x" => (Axis::X, 0),
            "y" => (Axis::Y, 1),
            "z" => (Axis::Z, 2),
            other => {
                return Err(doc.invalid(&key("axis"), format!("`{other}`: expected x, y or z")))
            }
        };
        let joint = a.joint.unwrap_or(trivial_joint);
        if joint > 8 {
            return Err(doc.invalid(&key("joint"), "LinuxCNC has joints 0 to 8"));
        }
        if axes.iter().any(|o| o.axis == axis) {
            return Err(doc.invalid(&key("axis"), format!("axis {axis} is given twice")));
        }
        if axes.iter().any(|o| o.joint == joint) {
            return Err(doc.invalid(&key("joint"), format!("joint {joint} is given twice")));
        }
        crate::bounds::check_axis(doc, &key, a.min_mm, a.max_mm, Some(a.max_feed_mm_min))?;
        axes.push(LinuxcncAxis {
            axis,
            joint,
            min_mm: a.min_mm,
            max_mm: a.max_mm,
            max_feed_mm_min: a.max_feed_mm_min,
        });
    }
    if !(axes.iter().any(|a| a.axis == Axis::X) && axes.iter().any(|a| a.axis == Axis::Y)) {
        return Err(doc.invalid("stage.axes", "needs an x and a y axis"));
    }
    let address = if raw.host.contains(':') && !raw.host.starts_with('[') {
        // An IPv6 address is written in brackets before its port.
        format!("[{}]:{}", raw.host, raw.port)
    } else {
        format!("{}:{}", raw.host, raw.port)
    };
    let follow = match &raw.follow {
        Some(rel) => Some(Box::new(MachineConfig::from_doc(
            &doc.read_relative("stage.follow", rel)?,
        )?)),
        None => None,
    };
    Ok(LinuxcncStageSpec {
        follow,
        address,
        options: LinuxcncOptions {
            connect_password: raw.connect_password,
            enable_password: raw.enable_password,
            command_timeout: Duration::from_millis(raw.timeout_ms),
            motion_timeout: Duration::from_secs(raw.motion_timeout_s),
            ..Default::default()
        },
        axes,
    })
}

#[cfg(test)]
mod tests {
    use crate::test_support::with_stage;
    use crate::StageSpec;

    const AXES: &str = "axes = [\n  { axis = \"x\", min_mm = 0.0, max_mm = 200.0, max_feed_mm_min = 6000.0 },\n  { axis = \"y\", joint = 1, min_mm = 0.0, max_mm = 150.0, max_feed_mm_min = 6000.0 },\n]";

    #[test]
    fn a_linuxcnc_stage_is_read_with_its_defaults() {
        let job = with_stage(&format!(
            "driver = \"linuxcnc\"\nhost = \"10.0.0.5\"\n{AXES}"
        ))
        .unwrap();
        let StageSpec::Linuxcnc(spec) = &job.stage else {
            panic!("a linuxcnc stage");
        };
        assert_eq!(spec.address, "10.0.0.5:5007");
        assert_eq!(spec.options.connect_password, "EMC");
        assert_eq!(spec.options.enable_password, "EMCTOO");
        assert_eq!(spec.axes[0].joint, 0);
        assert_eq!(spec.axes[1].max_mm, 150.0);
        assert!(!job.stage.is_simulated());
        let v6 = with_stage(&format!(
            "driver = \"linuxcnc\"\nhost = \"fe80::1\"\nport = 6000\n{AXES}"
        ))
        .unwrap();
        let StageSpec::Linuxcnc(spec) = &v6.stage else {
            panic!("a linuxcnc stage");
        };
        assert_eq!(spec.address, "[fe80::1]:6000");
    }

    #[test]
    fn bad_linuxcnc_settings_are_named() {
        let cases = [
            ("host = \"a b\"", "stage.host"),
            ("host = \"h\"\nport = 0", "stage.port"),
            (
                "host = \"h\"\nconnect_password = \"two words\"",
                "stage.connect_password",
            ),
            (
                "host = \"h\"\nenable_password = \"off\"",
                "stage.enable_password",
            ),
            ("host = \"h\"\ntimeout_ms = 10", "stage.timeout_ms"),
        ];
        for (keys, named) in cases {
            let e = with_stage(&format!("driver = \"linuxcnc\"\n{keys}\n{AXES}")).unwrap_err();
            assert!(e.contains(named), "{keys}: {e}");
        }
        let e = with_stage(
            "driver = \"linuxcnc\"\nhost = \"h\"\naxes = [{ axis = \"x\", min_mm = 0.0, max_mm = 1.0, max_feed_mm_min = 1.0 }]",
        )
        .unwrap_err();
        assert!(e.contains("needs an x and a y axis"), "{e}");
        let e = with_stage(
            "driver = \"linuxcnc\"\nhost = \"h\"\naxes = [{ axis = \"x\", min_mm = 0.0, max_mm = 1.0, max_feed_mm_min = 1.0 }, { axis = \"y\", joint = 0, min_mm = 0.0, max_mm = 1.0, max_feed_mm_min = 1.0 }]",
        )
        .unwrap_err();
        assert!(
            e.contains("stage.axes[1].joint") && e.contains("twice"),
            "{e}"
        );
    }
}

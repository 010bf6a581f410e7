//! The `dnc` stage backend of a job: a closed controller (Fanuc, Haas, ...) reached only
//! through its RS-232 tape port by DNC drip-feed (see `drivers::dnc`, docs/dnc.md and
//! docs/links.md, "Closed controllers").
//!
//! ```toml
//! [stage]
//! driver = "dnc"
//! port = "/dev/ttyUSB0"               # the PC's serial port wired to the tape port
//! baud = 9600                         # as set on the controller (default 9600)
//! end_of_block = "lf"                 # "lf" (Fanuc ISO, default) or "crlf" (Haas S25)
//! leader_nuls = 0                     # NULs before the tape (default 0)
//! chunk = 8                           # characters written before looking for DC3
//! start_timeout_s = 600               # for the operator's CYCLE START (first DC1)
//! resume_timeout_s = 600              # how long a DC3 may last (a dwell, a feed hold)
//! axes = [                            # the travel: the controller does not tell it
//!   { axis = "x", min_mm = 0.0, max_mm = 200.0, max_feed_mm_min = 6000.0 },
//!   { axis = "y", min_mm = 0.0, max_mm = 150.0, max_feed_mm_min = 6000.0 },
//! ]
//! ```

use link_spec::dnc::{DncAxis, DncOptions, EndOfBlock};
use link_spec::Axis;
use protocol::config::{ConfigDoc, ConfigError};
use serde::Deserialize;
use std::time::Duration;

/// `[stage]` with `driver = "dnc"`, as written.
#[derive(Deserialize, Debug)]
#[serde(deny_unknown_fields)]
pub struct RawDncStage {
    port: String,
    #[serde(default = "default_baud")]
    baud: u32,
    #[serde(default = "default_end_of_block")]
    end_of_block: String,
    #[serde(default)]
    leader_nuls: usize,
    #[serde(default = "default_chunk")]
    chunk: usize,
    #[serde(default = "default_timeout_s")]
    start_timeout_s: u64,
    #[serde(default = "default_timeout_s")]
    resume_timeout_s: u64,
    axes: Vec<RawDncAxis>,
}

#[derive(Deserialize, Debug)]
#[serde(deny_unknown_fields)]
struct RawDncAxis {
    axis: String,
    min_mm: f64,
    max_mm: f64,
    max_feed_mm_min: f64,
}

fn default_baud() -> u32 {
    9600
}
fn default_end_of_block() -> String {
    "lf".into()
}
fn default_chunk() -> usize {
    8
}
fn default_timeout_s() -> u64 {
    600
}

/// A resolved, checked tape-port stage.
#[derive(Clone, Debug)]
pub struct DncStageSpec {
    pub port: String,
    pub baud: u32,
    pub options: DncOptions,
    pub axes: Vec<DncAxis>,
}

/// Check a `[stage]` of driver `dnc` (errors name the job file, line and key).
pub fn resolve(doc: &ConfigDoc, raw: RawDncStage) -> Result<DncStageSpec, ConfigError> {
    if raw.port.is_empty() || raw.port.contains(char::is_whitespace) {
        return Err(doc.invalid("stage.port", "must be a serial port (no blanks)"));
    }
    if !(50..=921_600).contains(&raw.baud) {
        return Err(doc.invalid("stage.baud", "must be 50..=921600 baud"));
    }
    let end_of_block = match raw.end_of_block.to_ascii_lowercase().as_str() {
        "lf" => EndOfBlock::Lf,
        "crlf" => EndOfBlock::CrLf,
        other => {
            return Err(doc.invalid(
                "stage.end_of_block",
                format!("`{other}`: expected \"lf\" (Fanuc ISO) or \"crlf\" (Haas setting 25)"),
            ))
        }
    };
    if raw.leader_nuls > 1000 {
        return Err(doc.invalid("stage.leader_nuls", "at most 1000"));
    }
    // The Fanuc reader port takes 10 characters after DC3.
    if !(1..=10).contains(&raw.chunk) {
        return Err(doc.invalid(
            "stage.chunk",
            "must be 1..=10 characters (the controller's overrun allowance after DC3)",
        ));
    }
    for (key, v) in [
        ("stage.start_timeout_s", raw.start_timeout_s),
        ("stage.resume_timeout_s", raw.resume_timeout_s),
    ] {
        if !(1..=86_400).contains(&v) {
            return Err(doc.invalid(key, "must be 1..=86400 s"));
        }
    }
    let mut axes: Vec<DncAxis> = Vec::new();
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
        if axes.iter().any(|o| o.axis == axis) {
            return Err(doc.invalid(&key("axis"), format!("axis {axis} is given twice")));
        }
        crate::bounds::check_axis(doc, &key, a.min_mm, a.max_mm, Some(a.max_feed_mm_min))?;
        axes.push(DncAxis {
            axis,
            min_mm: a.min_mm,
            max_mm: a.max_mm,
            max_feed_mm_min: a.max_feed_mm_min,
        });
    }
    if !(axes.iter().any(|a| a.axis == Axis::X) && axes.iter().any(|a| a.axis == Axis::Y)) {
        return Err(doc.invalid("stage.axes", "needs an x and a y axis"));
    }
    Ok(DncStageSpec {
        port: raw.port,
        baud: raw.baud,
        options: DncOptions {
            start_timeout: Duration::from_secs(raw.start_timeout_s),
            resume_timeout: Duration::from_secs(raw.resume_timeout_s),
            chunk: raw.chunk,
            end_of_block,
            leader_nuls: raw.leader_nuls,
            ..DncOptions::default()
        },
        axes,
    })
}

#[cfg(test)]
mod tests {
    use crate::test_support::with_stage;
    use crate::{Job, StageSpec};

    const AXES: &str = "axes = [\n  { axis = \"x\", min_mm = 0.0, max_mm = 200.0, max_feed_mm_min = 6000.0 },\n  { axis = \"y\", min_mm = 0.0, max_mm = 150.0, max_feed_mm_min = 6000.0 },\n]";

    #[test]
    fn a_dnc_stage_is_read_with_its_defaults_and_bad_keys_are_named() {
        let job = with_stage(&format!(
            "driver = \"dnc\"\nport = \"/dev/ttyUSB0\"\n{AXES}"
        ))
        .unwrap();
        let StageSpec::Dnc(spec) = &job.stage else {
            panic!("a dnc stage");
        };
        assert_eq!(spec.baud, 9600);
        assert_eq!(spec.options.chunk, 8);
        assert_eq!(spec.axes[1].max_mm, 150.0);
        assert!(!job.stage.is_simulated());
        // The shipped example loads.
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/gateway");
        let shop = Job::load(&dir.join("dnc-shop.toml")).unwrap();
        assert!(matches!(shop.stage, StageSpec::Dnc(_)));
        for (keys, named) in [
            ("port = \"a b\"", "stage.port"),
            ("port = \"p\"\nbaud = 0", "stage.baud"),
            ("port = \"p\"\nchunk = 64", "stage.chunk"),
            ("port = \"p\"\nend_of_block = \"cr\"", "stage.end_of_block"),
        ] {
            let e = with_stage(&format!("driver = \"dnc\"\n{keys}\n{AXES}")).unwrap_err();
            assert!(e.contains(named), "{keys}: {e}");
        }
    }
}

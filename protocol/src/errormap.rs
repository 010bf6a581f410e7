//! The error map file: what one scan of a machine measured, so that every later move can
//! be compensated without the camera (JSON, schema [`SCHEMA`]).
//!
//! A map belongs to one machine, controller, board (by its certificate's SHA-256) and
//! camera; a job or a rewrite that names a map of another refuses it. Maps are
//! versioned: [`next_version_path`] gives the next free `NAME.vN.json`, so a new scan
//! never overwrites an older one, and a job names the exact file it uses.
//!
//! Conventions (worked example below):
//! - Positions are machine commands, mm (what the controller is told).
//! - An error is where the camera really looked on the board minus where it should have
//!   looked: `e = observed_board - (command + board_at_machine_zero)`, um, per axis.
//! - `approach` is the direction of the final move onto the point, per axis: `forward`
//!   (from below, +) or `reverse` (from above, -). Backlash makes the two differ.
//! - Yaw is the image rotation at the point relative to the reference point, microradians,
//!   counter-clockwise positive; the tool point, offset from the camera by
//!   `tool_offset_mm`, moves by yaw x offset (Abbe).
//!
//! Worked example: a node at command (100, 50) with forward `ex_um = 12.0`, `ey_um = -3.0`
//! means that after a move onto (100, 50) from below on both axes, the camera saw the
//! board 12 um further in +X and 3 um less in +Y than nominal. To put the camera on
//! nominal (100, 50) the command must be about (99.988, 50.003).

use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The schema this module reads and writes.
pub const SCHEMA: &str = "xy-gateway/error-map/1";

/// Mean and sample dispersion of repeated measurements of one quantity.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Stat {
    pub mean: f64,
    /// Sample standard deviation (n - 1); 0 with a single measurement.
    pub sd: f64,
    pub n: u32,
}

impl Stat {
    /// Mean and sample standard deviation of `values` (None when empty).
    pub fn of(values: &[f64]) -> Option<Self> {
        let n = values.len();
        if n == 0 {
            return None;
        }
        let mean = values.iter().sum::<f64>() / n as f64;
        let sd = if n > 1 {
            (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt()
        } else {
            0.0
        };
        Some(Self {
            mean,
            sd,
            n: n as u32,
        })
    }
}

/// What was measured at one point after approaching it in one direction.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Measured {
    pub ex_um: Stat,
    pub ey_um: Stat,
    pub yaw_urad: Stat,
}

/// One point measured from both directions.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Node {
    pub forward: Measured,
    pub reverse: Measured,
}

/// A rectangular grid of nodes: `nodes[j * xs.len() + i]` is at `(xs[i], ys[j])`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Grid {
    pub xs: Vec<f64>,
    pub ys: Vec<f64>,
    pub nodes: Vec<Node>,
}

/// A dense line of points along one axis (at a fixed position of the other), for the
/// short-period errors (ballscrew pitch error) a coarse grid cannot hold.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Line {
    /// The fixed coordinate of the other axis, mm.
    pub at_mm: f64,
    /// Positions along the axis, increasing, mm.
    pub positions: Vec<f64>,
    pub nodes: Vec<Node>,
}

/// Whose the map is: a map is refused for any other machine, controller, board or camera.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Identity {
    pub machine: String,
    pub controller: String,
    pub board: String,
    /// SHA-256 of the board's certificate (hex), or of its nominal description.
    pub certificate_sha256: String,
    pub camera: String,
}

/// One scan of one machine.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ErrorMap {
    pub schema: String,
    pub version: u32,
    /// When the scan ended (RFC 3339, UTC).
    pub created: String,
    pub identity: Identity,
    /// Tool point minus camera centre, in machine axes, mm.
    pub tool_offset_mm: [f64; 2],
    /// Board coordinate under the camera at machine zero, as the scan's job had it.
    pub board_at_machine_zero_mm: [f64; 2],
    /// The point whose frame after homing re-references the map (see the model).
    pub reference_mm: [f64; 2],
    pub grid: Grid,
    /// Dense lines along X (each at a fixed Y).
    #[serde(default)]
    pub x_lines: Vec<Line>,
    /// Dense lines along Y (each at a fixed X).
    #[serde(default)]
    pub y_lines: Vec<Line>,
    /// Expanded uncertainty (k = 2) of a compensated position from this map, um.
    pub uncertainty_um: f64,
}

#[derive(Debug, thiserror::Error)]
pub enum ErrorMapError {
    #[error("{path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    /// The bounded reader's error, which names the file and its kind.
    #[error("{0}")]
    Read(std::io::Error),
    #[error("{path}: not an error map: {message}")]
    Format { path: String, message: String },
    #[error("{path}: {message}")]
    Invalid { path: String, message: String },
}

impl ErrorMap {
    /// Parse and check a map; `path` names it in errors.
    pub fn from_json(path: &str, text: &str) -> Result<Self, ErrorMapError> {
        let de = &mut serde_json::Deserializer::from_str(text);
        let format = |message| ErrorMapError::Format {
            path: path.to_string(),
            message,
        };
        let map: ErrorMap = serde_path_to_error::deserialize(&mut *de)
            .map_err(|e| format(format!("at `{}`: {}", e.path(), e.inner())))?;
        // One map per file: anything after it (a second map pasted in, a torn copy) is
        // refused, not ignored.
        de.end()
            .map_err(|e| format(format!("after the map: {e}")))?;
        map.check().map_err(|message| ErrorMapError::Invalid {
            path: path.to_string(),
            message,
        })?;
        Ok(map)
    }

    /// Read through the one bounded reader (a regular file of at most
    /// `DataKind::ErrorMap`'s cap, UTF-8, a byte-order mark dropped).
    pub fn load(path: &Path) -> Result<Self, ErrorMapError> {
        let text = crate::config::read_kind(path, crate::config::DataKind::ErrorMap)
            .map_err(ErrorMapError::Read)?;
        Self::from_json(&path.display().to_string(), &text)
    }

    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("an error map serializes")
    }

    /// Write as a new file (never over an existing one).
    pub fn save_new(&self, path: &Path) -> Result<(), ErrorMapError> {
        use std::io::Write;
        let io = |source| ErrorMapError::Io {
            path: path.display().to_string(),
            source,
        };
        let mut f = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(path)
            .map_err(io)?;
        f.write_all(self.to_json().as_bytes()).map_err(io)?;
        f.sync_all().map_err(io)
    }

    /// Everything a reader relies on: the schema, finite numbers, increasing grid
    /// coordinates, one node per grid point, at least 2 x 2 nodes.
    pub fn check(&self) -> Result<(), String> {
        if self.schema != SCHEMA {
            return Err(format!(
                "schema `{}`, this gateway reads `{SCHEMA}`",
                self.schema
            ));
        }
        let finite = |what: &str, v: f64| {
            if v.is_finite() && v.abs() <= MAX_COORDINATE_MM {
                Ok(())
            } else {
                Err(format!(
                    "{what} is {v}: not a position on a machine (at most {MAX_COORDINATE_MM} mm from zero)"
                ))
            }
        };
        for (k, v) in self
            .tool_offset_mm
            .iter()
            .chain(&self.board_at_machine_zero_mm)
            .chain(&self.reference_mm)
            .enumerate()
        {
            finite(&format!("set-up value #{k}"), *v)?;
        }
        if !(self.uncertainty_um.is_finite() && (0.0..=MAX_ERROR_UM).contains(&self.uncertainty_um))
        {
            return Err(format!(
                "uncertainty_um is {}: must be 0..{MAX_ERROR_UM} um",
                self.uncertainty_um
            ));
        }
        check_axis("grid.xs", &self.grid.xs)?;
        check_axis("grid.ys", &self.grid.ys)?;
        if self.grid.xs.len() < 2 || self.grid.ys.len() < 2 {
            return Err("the grid needs at least 2 x 2 nodes".into());
        }
        let want = self.grid.xs.len() * self.grid.ys.len();
        if self.grid.nodes.len() != want {
            return Err(format!(
                "grid.nodes has {} nodes for {} x {} positions",
                self.grid.nodes.len(),
                self.grid.xs.len(),
                self.grid.ys.len()
            ));
        }
        check_nodes("grid.nodes", &self.grid.nodes)?;
        for (name, lines) in [("x_lines", &self.x_lines), ("y_lines", &self.y_lines)] {
            for (k, l) in lines.iter().enumerate() {
                let what = format!("{name}[{k}]");
                finite(&format!("{what}.at_mm"), l.at_mm)?;
                check_axis(&format!("{what}.positions"), &l.positions)?;
                if l.positions.len() < 2 || l.nodes.len() != l.positions.len() {
                    return Err(format!(
                        "{what}: needs at least 2 positions and one node per position"
                    ));
                }
                check_nodes(&format!("{what}.nodes"), &l.nodes)?;
            }
        }
        Ok(())
    }

    /// Whether this map may compensate `who`; the error names the first difference.
    pub fn check_identity(&self, who: &Identity) -> Result<(), String> {
        let i = &self.identity;
        for (what, a, b) in [
            ("machine", &i.machine, &who.machine),
            ("controller", &i.controller, &who.controller),
            ("board", &i.board, &who.board),
            (
                "board certificate",
                &i.certificate_sha256,
                &who.certificate_sha256,
            ),
            ("camera", &i.camera, &who.camera),
        ] {
            if a != b {
                return Err(format!(
                    "the map was measured on {what} `{a}`, this job has `{b}`"
                ));
            }
        }
        Ok(())
    }
}

/// The largest coordinate a map may hold, mm: beyond any machine this gateway serves.
pub const MAX_COORDINATE_MM: f64 = 10_000.0;
/// The largest error (and dispersion) a map node may hold, um: no stage the gateway
/// compensates is 10 mm off (corrections are bounded far below); more is a corrupt file.
pub const MAX_ERROR_UM: f64 = 10_000.0;
/// The largest yaw a map node may hold, urad (0.1 rad, 5.7 degrees).
pub const MAX_YAW_URAD: f64 = 100_000.0;

fn check_axis(what: &str, v: &[f64]) -> Result<(), String> {
    if let Some(x) = v
        .iter()
        .find(|x| !(x.is_finite() && x.abs() <= MAX_COORDINATE_MM))
    {
        return Err(format!(
            "{what} holds {x}: not a position on a machine (at most {MAX_COORDINATE_MM} mm from zero)"
        ));
    }
    if v.windows(2).any(|w| w[1] <= w[0]) {
        return Err(format!("{what} must increase strictly"));
    }
    Ok(())
}

fn check_nodes(what: &str, nodes: &[Node]) -> Result<(), String> {
    for (k, n) in nodes.iter().enumerate() {
        for (dir, m) in [("forward", &n.forward), ("reverse", &n.reverse)] {
            for (field, s, bound) in [
                ("ex_um", &m.ex_um, MAX_ERROR_UM),
                ("ey_um", &m.ey_um, MAX_ERROR_UM),
                ("yaw_urad", &m.yaw_urad, MAX_YAW_URAD),
            ] {
                let inside = |v: f64| v.is_finite() && v.abs() <= bound;
                if !(inside(s.mean) && inside(s.sd) && s.sd >= 0.0) || s.n == 0 {
                    return Err(format!(
                        "{what}[{k}].{dir}.{field}: mean {} sd {} n {}: a mean or dispersion \
                         beyond {bound} (or not a number), or no measurement",
                        s.mean, s.sd, s.n
                    ));
                }
            }
        }
    }
    Ok(())
}

/// The next free versioned path for a map named `stem` in `dir`: `stem.v1.json`,
/// `stem.v2.json`, ... (one above the highest present; gaps are never reused).
pub fn next_version_path(dir: &Path, stem: &str) -> std::io::Result<(u32, PathBuf)> {
    let mut highest = 0;
    if dir.exists() {
        for entry in std::fs::read_dir(dir)? {
            let name = entry?.file_name();
            let Some(name) = name.to_str() else { continue };
            let version = name
                .strip_prefix(stem)
                .and_then(|r| r.strip_prefix(".v"))
                .and_then(|r| r.strip_suffix(".json"))
                .and_then(|v| v.parse::<u32>().ok());
            if let Some(v) = version {
                highest = highest.max(v);
            }
        }
    }
    let v = highest + 1;
    Ok((v, dir.join(format!("{stem}.v{v}.json"))))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn measured(ex: f64, ey: f64) -> Measured {
        let s = |mean| Stat {
            mean,
            sd: 0.1,
            n: 2,
        };
        Measured {
            ex_um: s(ex),
            ey_um: s(ey),
            yaw_urad: s(0.0),
        }
    }

    pub(crate) fn small_map() -> ErrorMap {
        let node = |ex, ey| Node {
            forward: measured(ex, ey),
            reverse: measured(ex + 4.0, ey - 4.0),
        };
        ErrorMap {
            schema: SCHEMA.into(),
            version: 1,
            created: "2026-11-22T21:00:00Z".into(),
            identity: Identity {
                machine: "c5".into(),
                controller: "GRBL 1.1h".into(),
                board: "dot-grid-0.5mm".into(),
                certificate_sha256: "ab".repeat(32),
                camera: "sim mono 1.3 MP".into(),
            },
            tool_offset_mm: [30.0, 0.0],
            board_at_machine_zero_mm: [5.0, 5.0],
            reference_mm: [0.0, 0.0],
            grid: Grid {
                xs: vec![0.0, 100.0],
                ys: vec![0.0, 50.0],
                nodes: vec![
                    node(0.0, 0.0),
                    node(10.0, 0.0),
                    node(0.0, 5.0),
                    node(10.0, 5.0),
                ],
            },
            x_lines: Vec::new(),
            y_lines: Vec::new(),
            uncertainty_um: 0.4,
        }
    }

    #[test]
    fn stat_is_mean_and_sample_sd() {
        let s = Stat::of(&[1.0, 2.0, 3.0]).unwrap();
        assert_eq!((s.mean, s.n), (2.0, 3));
        assert!((s.sd - 1.0).abs() < 1e-12);
        assert_eq!(Stat::of(&[4.0]).unwrap().sd, 0.0);
        assert!(Stat::of(&[]).is_none());
    }

    #[test]
    fn a_second_map_or_anything_after_the_map_is_refused() {
        let text = small_map().to_json();
        assert!(ErrorMap::from_json("m.json", &text).is_ok());
        for tail in ["\n999999\n", "x", "{}"] {
            let e = ErrorMap::from_json("m.json", &format!("{text}{tail}")).unwrap_err();
            assert!(e.to_string().contains("after the map"), "{e}");
        }
        let twice = ErrorMap::from_json("m.json", &text.repeat(2)).unwrap_err();
        assert!(twice.to_string().contains("after the map"), "{twice}");
    }

    #[test]
    fn numbers_beyond_any_machine_are_refused_naming_the_field() {
        let mut m = small_map();
        m.grid.nodes[2].reverse.yaw_urad.mean = 1e308;
        let e = ErrorMap::from_json("m.json", &m.to_json()).unwrap_err();
        assert!(
            e.to_string().contains("grid.nodes[2].reverse.yaw_urad"),
            "{e}"
        );
        let mut m = small_map();
        m.grid.nodes[1].forward.ex_um.sd = 2e4;
        let e = ErrorMap::from_json("m.json", &m.to_json()).unwrap_err();
        assert!(e.to_string().contains("grid.nodes[1].forward.ex_um"), "{e}");
        let mut m = small_map();
        m.uncertainty_um = 1e100;
        let e = ErrorMap::from_json("m.json", &m.to_json()).unwrap_err();
        assert!(e.to_string().contains("uncertainty_um"), "{e}");
        let mut m = small_map();
        m.grid.xs[1] = 1e9;
        let e = ErrorMap::from_json("m.json", &m.to_json()).unwrap_err();
        assert!(e.to_string().contains("grid.xs"), "{e}");
    }

    #[test]
    fn round_trips_and_refuses_what_a_reader_cannot_use() {
        let m = small_map();
        let back = ErrorMap::from_json("m.json", &m.to_json()).unwrap();
        assert_eq!(back, m);
        let bad = |f: fn(&mut ErrorMap)| {
            let mut m = small_map();
            f(&mut m);
            ErrorMap::from_json("m.json", &m.to_json())
                .unwrap_err()
                .to_string()
        };
        assert!(bad(|m| m.schema = "other/1".into()).contains("schema `other/1`"));
        assert!(bad(|m| m.grid.xs = vec![100.0, 0.0]).contains("grid.xs must increase"));
        assert!(bad(|m| {
            m.grid.nodes.pop();
        })
        .contains("3 nodes for 2 x 2"));
        let e = ErrorMap::from_json("m.json", "{\"schema\": 3}").unwrap_err();
        assert!(
            e.to_string()
                .starts_with("m.json: not an error map: at `schema`"),
            "{e}"
        );
    }

    #[test]
    fn a_map_of_another_machine_board_or_camera_is_refused_by_name() {
        let m = small_map();
        let mut who = m.identity.clone();
        assert!(m.check_identity(&who).is_ok());
        who.certificate_sha256 = "cd".repeat(32);
        let e = m.check_identity(&who).unwrap_err();
        assert!(e.contains("board certificate"), "{e}");
        who = m.identity.clone();
        who.camera = "other".into();
        assert!(m
            .check_identity(&who)
            .unwrap_err()
            .contains("camera `sim mono 1.3 MP`"));
    }

    #[test]
    fn new_versions_never_overwrite() {
        let dir = std::env::temp_dir().join(format!("errormap-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (v, p) = next_version_path(&dir, "stage").unwrap();
        assert_eq!(v, 1);
        small_map().save_new(&p).unwrap();
        assert!(
            small_map().save_new(&p).is_err(),
            "never over an existing map"
        );
        std::fs::write(dir.join("stage.v7.json"), "{}").unwrap();
        let (v, p) = next_version_path(&dir, "stage").unwrap();
        assert_eq!(
            (v, p.file_name().unwrap().to_str().unwrap()),
            (8, "stage.v8.json")
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

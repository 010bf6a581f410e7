//! The job configuration: which devices, which board, how to localize and correct, and
//! which targets. Read raw from TOML, then resolved and checked into a [`Job`], with
//! every problem reported as `file:line: key `...`: what is wrong`.
//!
//! ```toml
//! [stage]
//! driver = "sim"                      # the backend; each has its own keys
//! machine = "../machines/c5-stage.toml"
//!
//! [camera]
//! driver = "sim"
//! model = "../cameras/mono-1.3mp.toml"
//! pixel_axes = "+x,-y"                # board directions of image +x and +y
//! um_per_px = 4.0                     # nominal scale, checked against each frame
//!
//! [board]
//! file = "../boards/dot-grid-0.5mm.toml"
//!
//! [setup]
//! board_at_machine_zero_mm = [5.0, 5.0]
//! feed_mm_min = 3000.0
//!
//! [localize]                          # optional, defaults shown in the README
//! [compensation]                      # optional
//! [targets]
//! grid = { x_mm = [10.0, 190.0], y_mm = [10.0, 140.0], nx = 6, ny = 5 }
//! ```

pub mod camera;
pub mod canopen;
pub mod demo;
pub mod modbus;

pub use camera::{CameraSpec, PairingError};
use compensation::correction::CorrectionPolicy;
use compensation::session::Target;
use protocol::config::{ConfigDoc, ConfigError};
use protocol::Board;
use serde::Deserialize;
use std::path::Path;
use vision::localize::{LocalizeSettings, PixelAxes};
use world::machine::MachineConfig;

/// The files of the embedded default job (the demo), compiled in.
pub static EMBEDDED: &[(&str, &str)] = &[
    (
        "config/gateway/demo.toml",
        include_str!("../../../config/gateway/demo.toml"),
    ),
    (
        "config/machines/c5-stage.toml",
        include_str!("../../../config/machines/c5-stage.toml"),
    ),
    (
        "config/cameras/mono-1.3mp.toml",
        include_str!("../../../config/cameras/mono-1.3mp.toml"),
    ),
    (
        "config/boards/dot-grid-0.5mm.toml",
        include_str!("../../../config/boards/dot-grid-0.5mm.toml"),
    ),
    (
        "config/boards/dot-grid-0.5mm.certified.csv",
        include_str!("../../../config/boards/dot-grid-0.5mm.certified.csv"),
    ),
];

pub const DEMO_JOB: &str = "config/gateway/demo.toml";

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawJob {
    stage: RawStage,
    camera: camera::RawCamera,
    board: RawBoard,
    setup: RawSetup,
    #[serde(default)]
    localize: LocalizeSettings,
    #[serde(default)]
    compensation: CorrectionPolicy,
    targets: RawTargets,
}

#[derive(Deserialize)]
#[serde(tag = "driver", rename_all = "kebab-case", deny_unknown_fields)]
enum RawStage {
    /// The in-process simulated machine.
    Sim { machine: String },
    /// A GRBL controller on a serial port (`port`, `baud`), or with `emulate` (a
    /// machine file) the GRBL emulator on a pseudo-terminal driving that machine.
    Grbl {
        port: Option<String>,
        #[serde(default = "default_baud")]
        baud: u32,
        emulate: Option<String>,
    },
    /// Modbus positioning drives, one per axis, over TCP or RTU through a drive
    /// profile; or with `emulate` the drive emulator (see `modbus_stage`).
    Modbus(crate::modbus::RawModbusStage),
    /// CiA 402 drives on CAN (SLCAN adapter or SocketCAN interface), one node per
    /// axis; or with `emulate` the drive emulator (see `canopen_stage`).
    Canopen(crate::canopen::RawCanopenStage),
}

fn default_baud() -> u32 {
    115_200
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawBoard {
    file: String,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSetup {
    board_at_machine_zero_mm: [f64; 2],
    #[serde(default = "default_feed")]
    feed_mm_min: f64,
}

fn default_feed() -> f64 {
    3000.0
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTargets {
    grid: Option<RawGrid>,
    points: Option<Vec<[f64; 2]>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawGrid {
    x_mm: [f64; 2],
    y_mm: [f64; 2],
    nx: u32,
    ny: u32,
}

/// The stage backend and its resolved settings.
#[derive(Clone, Debug)]
pub enum StageSpec {
    Sim {
        machine: MachineConfig,
    },
    /// GRBL over serial: a real port, or the emulator on a pseudo-terminal.
    Grbl {
        link: GrblLink,
        baud: u32,
    },
    /// Modbus drives (TCP, RTU, or the emulator), register maps from a drive profile.
    Modbus(crate::modbus::ModbusStageSpec),
    /// CANopen CiA 402 drives (SLCAN, SocketCAN, or the emulator on an SLCAN pty).
    Canopen(crate::canopen::CanopenStageSpec),
}

/// Where a GRBL controller is.
#[derive(Clone, Debug)]
// Built once per job; boxing the machine would only add noise at every use.
#[allow(clippy::large_enum_variant)]
pub enum GrblLink {
    /// A serial port (`/dev/ttyUSB0`, `/dev/ttyACM0`).
    Port(String),
    /// The GRBL emulator on a pseudo-terminal, driving this simulated machine.
    Emulate(MachineConfig),
}

impl StageSpec {
    /// Whether the machine behind this stage is simulated in this process (directly or
    /// behind an emulator of its bus), so that only a simulated camera can see it.
    pub fn is_simulated(&self) -> bool {
        match self {
            StageSpec::Sim { .. } => true,
            StageSpec::Grbl { link, .. } => matches!(link, GrblLink::Emulate(_)),
            StageSpec::Modbus(spec) => {
                matches!(spec.link, crate::modbus::ModbusLink::Emulate { .. })
            }
            StageSpec::Canopen(spec) => {
                matches!(spec.link, crate::canopen::CanopenLink::Emulate { .. })
            }
        }
    }
}

/// A resolved, checked job.
#[derive(Clone, Debug)]
pub struct Job {
    /// Where it came from (file name), for messages.
    pub source: String,
    pub stage: StageSpec,
    pub camera: CameraSpec,
    pub pixel_axes: PixelAxes,
    pub um_per_px: Option<f64>,
    pub board: Board,
    /// Nominal board coordinate under the camera at machine zero: machine command =
    /// target (board mm) - this.
    pub board_at_machine_zero_mm: [f64; 2],
    pub feed_mm_min: f64,
    pub localize: LocalizeSettings,
    pub policy: CorrectionPolicy,
    /// Targets in board coordinates, mm, in visiting order.
    pub targets: Vec<[f64; 2]>,
}

impl Job {
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        Self::from_doc(&ConfigDoc::read(path)?)
    }

    /// The embedded default job: every device simulated in-process.
    pub fn demo() -> Self {
        let doc = ConfigDoc::embedded(DEMO_JOB, EMBEDDED).expect("demo job is embedded");
        Self::from_doc(&doc).expect("the embedded demo job is valid (checked by a test)")
    }

    pub fn from_doc(doc: &ConfigDoc) -> Result<Self, ConfigError> {
        let raw: RawJob = doc.parse()?;
        let stage = match raw.stage {
            RawStage::Sim { machine } => {
                let m = doc.read_relative("stage.machine", &machine)?;
                StageSpec::Sim {
                    machine: MachineConfig::from_doc(&m)?,
                }
            }
            RawStage::Grbl {
                port,
                baud,
                emulate,
            } => {
                if port.is_some() == emulate.is_some() {
                    return Err(doc.invalid(
                        "stage.port",
                        "the grbl stage needs either `port` (a serial port) or `emulate` (a machine file for the GRBL emulator)",
                    ));
                }
                if baud == 0 {
                    return Err(doc.invalid("stage.baud", "must be a positive baud rate"));
                }
                let link = match (port, emulate) {
                    (Some(port), _) => GrblLink::Port(port),
                    (None, Some(rel)) => GrblLink::Emulate(MachineConfig::from_doc(
                        &doc.read_relative("stage.emulate", &rel)?,
                    )?),
                    (None, None) => unreachable!("checked above"),
                };
                StageSpec::Grbl { link, baud }
            }
            RawStage::Modbus(raw) => StageSpec::Modbus(crate::modbus::resolve(doc, raw)?),
            RawStage::Canopen(raw) => StageSpec::Canopen(crate::canopen::resolve(doc, raw)?),
        };
        let camera = raw.camera.resolve(doc)?;
        let pixel_axes = match &raw.camera.pixel_axes {
            Some(s) => s
                .parse::<PixelAxes>()
                .map_err(|e| doc.invalid("camera.pixel_axes", e.to_string()))?,
            None => PixelAxes::default(),
        };
        if let Some(s) = raw.camera.um_per_px {
            if !(s.is_finite() && s > 0.0) {
                return Err(doc.invalid("camera.um_per_px", "must be a positive number"));
            }
        }
        let board = Board::from_doc(&doc.read_relative("board.file", &raw.board.file)?)?;
        if !raw
            .setup
            .board_at_machine_zero_mm
            .iter()
            .all(|v| v.is_finite())
        {
            return Err(doc.invalid("setup.board_at_machine_zero_mm", "must be finite"));
        }
        if !(raw.setup.feed_mm_min > 0.0 && raw.setup.feed_mm_min.is_finite()) {
            return Err(doc.invalid("setup.feed_mm_min", "must be a positive feed in mm/min"));
        }
        let l = &raw.localize;
        if !(l.hint_tolerance_mm > 0.0 && l.hint_tolerance_mm < board.pitch_mm / 2.0) {
            return Err(doc.invalid(
                "localize.hint_tolerance_mm",
                format!(
                    "must be positive and below half the board pitch ({} mm), or dots could be mistaken for their neighbours",
                    board.pitch_mm / 2.0
                ),
            ));
        }
        if !(l.max_residual_um > 0.0) {
            return Err(doc.invalid("localize.max_residual_um", "must be positive"));
        }
        if l.min_points < 4 {
            return Err(doc.invalid("localize.min_points", "at least 4 points are needed"));
        }
        let p = &raw.compensation;
        if !(p.tolerance_um > 0.0 && p.tolerance_um.is_finite()) {
            return Err(doc.invalid("compensation.tolerance_um", "must be positive"));
        }
        if p.max_iterations > 100 {
            return Err(doc.invalid("compensation.max_iterations", "at most 100"));
        }
        if !(p.max_correction_mm > 0.0 && p.max_correction_mm <= 1.0) {
            return Err(doc.invalid(
                "compensation.max_correction_mm",
                "must be positive and at most 1 mm: it bounds every correction",
            ));
        }
        if !(p.approach_mm >= 0.0 && p.approach_mm < 5.0) {
            return Err(doc.invalid("compensation.approach_mm", "must be 0..5 mm"));
        }
        let targets = resolve_targets(doc, &raw.targets, &board)?;
        Ok(Job {
            source: doc.name.clone(),
            stage,
            camera,
            pixel_axes,
            um_per_px: raw.camera.um_per_px,
            board,
            board_at_machine_zero_mm: raw.setup.board_at_machine_zero_mm,
            feed_mm_min: raw.setup.feed_mm_min,
            localize: raw.localize,
            policy: raw.compensation,
            targets,
        })
    }

    /// The targets as the compensation session takes them: board coordinate and
    /// nominal machine command.
    pub fn session_targets(&self) -> Vec<Target> {
        self.targets
            .iter()
            .map(|&board_mm| Target {
                board_mm,
                command_mm: self.command_for(board_mm),
            })
            .collect()
    }

    /// Whether the camera can see the machine (see [`CameraSpec::check_pairing`]).
    pub fn check_pairing(&self) -> Result<(), PairingError> {
        self.camera.check_pairing(self.stage.is_simulated())
    }

    /// Machine command (mm) of a target given in board coordinates.
    pub fn command_for(&self, target_mm: [f64; 2]) -> [f64; 2] {
        [
            target_mm[0] - self.board_at_machine_zero_mm[0],
            target_mm[1] - self.board_at_machine_zero_mm[1],
        ]
    }
}

fn resolve_targets(
    doc: &ConfigDoc,
    t: &RawTargets,
    board: &Board,
) -> Result<Vec<[f64; 2]>, ConfigError> {
    let mut out = Vec::new();
    let key = if t.grid.is_some() {
        "targets.grid"
    } else {
        "targets.points"
    };
    match (&t.grid, &t.points) {
        (Some(_), Some(_)) => {
            return Err(doc.invalid("targets", "give either `grid` or `points`, not both"))
        }
        (None, None) => return Err(doc.invalid("targets", "give `grid` or `points`")),
        (Some(g), None) => {
            if g.nx < 1 || g.ny < 1 || u64::from(g.nx) * u64::from(g.ny) > 100_000 {
                return Err(doc.invalid(
                    "targets.grid",
                    "nx and ny must be 1.. (at most 100000 targets)",
                ));
            }
            let at = |r: [f64; 2], n: u32, k: u32| {
                if n == 1 {
                    r[0]
                } else {
                    r[0] + (r[1] - r[0]) * k as f64 / (n - 1) as f64
                }
            };
            // Serpentine order: short moves between neighbouring targets.
            for j in 0..g.ny {
                for i in 0..g.nx {
                    let i = if j % 2 == 0 { i } else { g.nx - 1 - i };
                    out.push([at(g.x_mm, g.nx, i), at(g.y_mm, g.ny, j)]);
                }
            }
        }
        (None, Some(p)) => {
            if p.is_empty() {
                return Err(doc.invalid("targets.points", "the list is empty"));
            }
            out.extend_from_slice(p);
        }
    }
    let (lo, hi) = board.extent();
    for (k, t) in out.iter().enumerate() {
        if !(t[0] >= lo[0] && t[0] <= hi[0] && t[1] >= lo[1] && t[1] <= hi[1]) {
            return Err(doc.invalid(
                key,
                format!(
                    "target #{k} ({:.3}, {:.3}) mm is off the board ({:.1}..{:.1} x {:.1}..{:.1} mm)",
                    t[0], t[1], lo[0], hi[0], lo[1], hi[1]
                ),
            ));
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_embedded_demo_job_is_valid_and_spread_over_the_travel() {
        let job = Job::demo();
        assert!(job.targets.len() >= 25);
        assert_eq!(
            job.board.certified_points,
            (job.board.cols * job.board.rows) as usize
        );
        let StageSpec::Sim { machine } = &job.stage else {
            unreachable!("the demo job is simulated")
        };
        let (tx, ty) = (machine.axes.x.travel_mm, machine.axes.y.travel_mm);
        let cmds: Vec<[f64; 2]> = job.targets.iter().map(|t| job.command_for(*t)).collect();
        let span = |k: usize| {
            let v = cmds.iter().map(|c| c[k]);
            v.clone().fold(f64::MIN, f64::max) - v.fold(f64::MAX, f64::min)
        };
        assert!(span(0) > 0.9 * tx && span(1) > 0.9 * ty);
    }

    #[test]
    fn hint_tolerance_must_stay_below_half_the_pitch() {
        let doc = ConfigDoc::embedded(DEMO_JOB, EMBEDDED).unwrap();
        let mut doc = doc.clone();
        doc.text = doc
            .text
            .replace("hint_tolerance_mm = 0.1", "hint_tolerance_mm = 0.3");
        let e = Job::from_doc(&doc).unwrap_err().to_string();
        assert!(
            e.contains("localize.hint_tolerance_mm") && e.contains("half the board pitch"),
            "{e}"
        );
        assert!(e.contains("demo.toml (built in):"), "{e}");
    }
}

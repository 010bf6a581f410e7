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
pub mod dnc;
pub mod linuxcnc;
pub mod modbus;
pub mod rotary;

pub use camera::{CameraSpec, PairingError};
use compensation::correction::CorrectionPolicy;
use compensation::session::Target;
use protocol::config::{ConfigDoc, ConfigError, Xy};
use protocol::Board;
use serde::Deserialize;
use std::path::Path;
use vision::localize::{LocalizeParams, LocalizeSettings, PixelAxes};
use world::machine::MachineConfig;

mod bounds;
use bounds::check_baud;
pub use bounds::{MAX_BAUD, MAX_FEED_MM_MIN, MAX_SETUP_OFFSET_MM, MIN_BAUD, MIN_FEED_MM_MIN};

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

/// The smallest hint tolerance: a hint is where the machine was sent, and no machine
/// lands within less of it (a subnormal tolerance made every frame "unreadable").
pub const MIN_HINT_TOLERANCE_MM: f64 = 0.001;

/// The largest fit residual a job may accept, um.
pub const MAX_RESIDUAL_UM: f64 = 100.0;
/// The smallest fit residual limit, um: a sub-pixel fit is never better than this
/// (a subnormal limit refused every frame).
pub const MIN_RESIDUAL_UM: f64 = 0.01;

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
    /// A LinuxCNC machine through its text remote shell linuxcncrsh (see
    /// module `linuxcnc`).
    Linuxcnc(crate::linuxcnc::RawLinuxcncStage),
    /// A closed controller's tape port (DNC drip-feed; see module `dnc`).
    Dnc(crate::dnc::RawDncStage),
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
    board_at_machine_zero_mm: Xy,
    #[serde(default = "default_feed")]
    feed_mm_min: f64,
    /// Home the stage before the job (default). `false` only on a coded board: the
    /// board gives the absolute position, so the job re-references from its first frame.
    #[serde(default = "default_home")]
    home: bool,
}

fn default_home() -> bool {
    true
}

fn default_feed() -> f64 {
    3000.0
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTargets {
    grid: Option<RawGrid>,
    points: Option<Vec<Xy>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawGrid {
    x_mm: Xy,
    y_mm: Xy,
    nx: u32,
    ny: u32,
}

/// The stage backend and its resolved settings.
// The simulated machine's description is the largest variant; a job holds one spec, so
// boxing it would only complicate every match on it.
#[allow(clippy::large_enum_variant)]
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
    /// A LinuxCNC machine through linuxcncrsh (TCP).
    Linuxcnc(crate::linuxcnc::LinuxcncStageSpec),
    /// A closed controller through its tape port (DNC drip-feed, DC1/DC3).
    Dnc(crate::dnc::DncStageSpec),
}

/// Where a GRBL controller is.
#[derive(Clone, Debug)]
pub enum GrblLink {
    /// A serial port (`/dev/ttyUSB0`, `/dev/ttyACM0`).
    Port(String),
    /// The GRBL emulator on a pseudo-terminal, driving this simulated machine.
    Emulate(Box<MachineConfig>),
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
            StageSpec::Linuxcnc(spec) => spec.follow.is_some(),
            StageSpec::Dnc(_) => false,
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
    /// Home before the job (`[setup] home`, default true; false only on a coded board).
    pub home: bool,
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
                check_baud(doc, baud)?;
                let link = match (port, emulate) {
                    (Some(port), None) => GrblLink::Port(port),
                    (None, Some(rel)) => GrblLink::Emulate(Box::new(MachineConfig::from_doc(
                        &doc.read_relative("stage.emulate", &rel)?,
                    )?)),
                    _ => {
                        return Err(doc.invalid(
                            "stage.port",
                            "the grbl stage needs either `port` (a serial port) or `emulate` (a machine file for the GRBL emulator)",
                        ))
                    }
                };
                StageSpec::Grbl { link, baud }
            }
            RawStage::Modbus(raw) => StageSpec::Modbus(crate::modbus::resolve(doc, raw)?),
            RawStage::Canopen(raw) => StageSpec::Canopen(crate::canopen::resolve(doc, raw)?),
            RawStage::Linuxcnc(raw) => StageSpec::Linuxcnc(crate::linuxcnc::resolve(doc, raw)?),
            RawStage::Dnc(raw) => StageSpec::Dnc(crate::dnc::resolve(doc, raw)?),
        };
        let camera = raw.camera.resolve(doc)?;
        let pixel_axes = match &raw.camera.pixel_axes {
            Some(s) => s
                .parse::<PixelAxes>()
                .map_err(|e| doc.invalid("camera.pixel_axes", e.to_string()))?,
            None => PixelAxes::default(),
        };
        if let Some(s) = raw.camera.um_per_px {
            // From a microscope objective (0.01 um/px) to a wide view (1 mm/px).
            doc.in_range("camera.um_per_px", s, 0.01, 1000.0, "um/px")?;
        }
        let board = Board::from_doc(&doc.read_relative("board.file", &raw.board.file)?)?;
        if !raw.setup.home && board.code.is_none() {
            return Err(doc.invalid(
                "setup.home",
                "a job may skip homing only on a coded board ([board.code]): a plain dot grid gives the position only modulo its pitch",
            ));
        }
        let Xy(board_at_machine_zero_mm) = raw.setup.board_at_machine_zero_mm;
        // Where the board sits when the machine is at zero: on the machine, so within
        // the largest travel any stage here has (10 m), not a number that only fails
        // at the first move.
        if !board_at_machine_zero_mm
            .iter()
            .all(|v| v.is_finite() && v.abs() <= MAX_SETUP_OFFSET_MM)
        {
            return Err(doc.invalid(
                "setup.board_at_machine_zero_mm",
                format!("must be two numbers of at most {MAX_SETUP_OFFSET_MM} mm each"),
            ));
        }
        if !(MIN_FEED_MM_MIN..=MAX_FEED_MM_MIN).contains(&raw.setup.feed_mm_min) {
            return Err(doc.invalid(
                "setup.feed_mm_min",
                format!("must be a feed of {MIN_FEED_MM_MIN} to {MAX_FEED_MM_MIN} mm/min"),
            ));
        }
        let l = &raw.localize;
        if !(l.hint_tolerance_mm >= MIN_HINT_TOLERANCE_MM
            && l.hint_tolerance_mm < board.pitch_mm / 2.0)
        {
            return Err(doc.invalid(
                "localize.hint_tolerance_mm",
                format!(
                    "must be at least {MIN_HINT_TOLERANCE_MM} mm (no machine is placed closer than that to where it was sent) and below half the board pitch ({} mm), or dots could be mistaken for their neighbours",
                    board.pitch_mm / 2.0
                ),
            ));
        }
        if !(l.max_residual_um >= MIN_RESIDUAL_UM && l.max_residual_um <= MAX_RESIDUAL_UM) {
            return Err(doc.invalid(
                "localize.max_residual_um",
                format!("`{}`: must be {MIN_RESIDUAL_UM} to {MAX_RESIDUAL_UM} um (no fit is better than the first; a fit worse than the second is no measurement)", l.max_residual_um),
            ));
        }
        let on_board = board.cols as usize * board.rows as usize;
        let in_view = camera.model().map(|m| {
            let field_mm = |px: u32| f64::from(px) * m.um_per_px / 1000.0;
            let per_axis = |px: u32| (field_mm(px) / board.pitch_mm).floor() as usize + 1;
            per_axis(m.width) * per_axis(m.height)
        });
        let most = in_view.map_or(on_board, |v| v.min(on_board));
        if l.min_points < 4 || l.min_points > most {
            return Err(doc.invalid(
                "localize.min_points",
                format!(
                    "must be 4 to {most} (the dots {} can hold)",
                    if in_view.is_some() {
                        "one frame of this camera"
                    } else {
                        "the board"
                    }
                ),
            ));
        }
        let p = &raw.compensation;
        // The floor is the rewriters' (0.01 um: below it no stage's count converges);
        // past a millimetre every uncorrected target would be declared converged.
        if !(0.01..=1000.0).contains(&p.tolerance_um) {
            return Err(doc.invalid(
                "compensation.tolerance_um",
                "must be 0.01 to 1000 um (the rewriters' floor; a tolerance past a millimetre compensates nothing)",
            ));
        }
        if p.max_iterations > 100 {
            return Err(doc.invalid("compensation.max_iterations", "at most 100"));
        }
        if !(p.max_correction_mm >= 0.0001 && p.max_correction_mm <= 1.0) {
            return Err(doc.invalid(
                "compensation.max_correction_mm",
                "must be 0.0001 to 1 mm: it bounds every correction (below 0.1 um nothing could be corrected)",
            ));
        }
        if !(p.approach_mm >= 0.0 && p.approach_mm < 5.0) {
            return Err(doc.invalid("compensation.approach_mm", "must be 0..5 mm"));
        }
        if !(p.divergence_ratio >= 0.01 && p.divergence_ratio <= 1.0) {
            return Err(doc.invalid(
                "compensation.divergence_ratio",
                "must be 0.01 to 1 (the share of a deviation a correction may leave; below 1 % every correction would count as diverging)",
            ));
        }
        let targets = resolve_targets(doc, &raw.targets, &board)?;
        Ok(Job {
            source: doc.name.clone(),
            stage,
            camera,
            pixel_axes,
            um_per_px: raw.camera.um_per_px,
            board,
            board_at_machine_zero_mm,
            feed_mm_min: raw.setup.feed_mm_min,
            home: raw.setup.home,
            localize: raw.localize,
            policy: raw.compensation,
            targets,
        })
    }

    /// How to localize a frame expected to show board coordinate `hint_mm`: the job's
    /// localization settings, camera orientation and nominal scale.
    pub fn localize_params(&self, hint_mm: [f64; 2]) -> LocalizeParams {
        let mut p = LocalizeParams::with_settings(hint_mm, &self.localize);
        p.pixel_axes = self.pixel_axes;
        p.um_per_px = self.um_per_px;
        p
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
            let (Xy(gx), Xy(gy)) = (g.x_mm, g.y_mm);
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
                    out.push([at(gx, g.nx, i), at(gy, g.ny, j)]);
                }
            }
        }
        (None, Some(p)) => {
            if p.is_empty() {
                return Err(doc.invalid("targets.points", "the list is empty"));
            }
            out.extend(p.iter().map(|&Xy(xy)| xy));
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

/// What the tests of the stage kinds share.
#[cfg(test)]
mod test_support {
    use crate::{Job, DEMO_JOB, EMBEDDED};
    use protocol::config::ConfigDoc;

    /// The demo job with `stage` as its `[stage]` table.
    pub fn with_stage(stage: &str) -> Result<Job, String> {
        let mut doc = ConfigDoc::embedded(DEMO_JOB, EMBEDDED).unwrap();
        let old = "driver = \"sim\"\nmachine = \"../machines/c5-stage.toml\"";
        assert!(doc.text.contains(old));
        doc.text = doc.text.replace(old, stage);
        Job::from_doc(&doc).map_err(|e| e.to_string())
    }
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

    /// Issue 38: every number of a job file has a floor and a ceiling that make
    /// physical sense; subnormal, negative, NaN, inf and absurd values are refused
    /// naming the key (a subnormal residual limit or correction bound, a 1e308 scale,
    /// a drive axis's soft limit of 1e308 were accepted).
    #[test]
    fn every_number_of_a_job_file_is_bounded_and_named() {
        let demo = ConfigDoc::embedded(DEMO_JOB, EMBEDDED).unwrap();
        let with = |from: &str, to: &str| {
            assert!(demo.text.contains(from), "{from}");
            let mut doc = demo.clone();
            doc.text = doc.text.replacen(from, to, 1);
            Job::from_doc(&doc).map(|_| ()).map_err(|e| e.to_string())
        };
        let keys: &[(&str, &str, &str, &[&str])] = &[
            (
                "um_per_px = 4.0",
                "um_per_px",
                "camera.um_per_px",
                &["4e-320", "0.001", "1e308"],
            ),
            (
                "feed_mm_min = 3000.0",
                "feed_mm_min",
                "setup.feed_mm_min",
                &["4e-320", "0.5", "1e6"],
            ),
            (
                "hint_tolerance_mm = 0.1",
                "hint_tolerance_mm",
                "localize.hint_tolerance_mm",
                &["4e-320", "0.3"],
            ),
            (
                "max_residual_um = 2.0",
                "max_residual_um",
                "localize.max_residual_um",
                &["4e-320", "0.001", "1e3"],
            ),
            (
                "tolerance_um = 0.5",
                "tolerance_um",
                "compensation.tolerance_um",
                &["4e-320", "1e308"],
            ),
            (
                "max_correction_mm = 0.15",
                "max_correction_mm",
                "compensation.max_correction_mm",
                &["4e-320", "1e-5", "2.0"],
            ),
            (
                "approach_mm = 0.05",
                "approach_mm",
                "compensation.approach_mm",
                &["-0.05", "5.0", "1e308"],
            ),
            (
                "max_iterations = 5",
                "max_iterations",
                "compensation.max_iterations",
                &["101"],
            ),
            (
                "min_points = 12",
                "min_points",
                "localize.min_points",
                &["3", "100000"],
            ),
        ];
        for (line, name, key, values) in keys {
            let every: Vec<&str> = ["nan", "inf", "-inf", "-1.0"]
                .iter()
                .chain(values.iter())
                .copied()
                .collect();
            for v in every {
                // Integers: TOML refuses a float by its type.
                let integer = *name == "max_iterations" || *name == "min_points";
                if integer && (v.contains('.') || v.contains('n')) {
                    continue;
                }
                let e = with(line, &format!("{name} = {v}"))
                    .map(|()| panic!("{name} = {v} accepted"))
                    .unwrap_err();
                assert!(e.contains(&format!("`{key}`")), "{name} = {v}: {e}");
            }
        }
        let e = with(
            "[compensation]",
            "[compensation]\ndivergence_ratio = 4e-320",
        )
        .unwrap_err();
        assert!(e.contains("compensation.divergence_ratio"), "{e}");
        let e = with(
            "board_at_machine_zero_mm = [5.0, 5.0]",
            "board_at_machine_zero_mm = [1e308, 0.0]",
        )
        .unwrap_err();
        assert!(e.contains("setup.board_at_machine_zero_mm"), "{e}");
        // A drive stage's axis: soft limits within 10 m, a feed of 1 to 100 000 mm/min.
        for (from, to, key) in [
            ("max_mm = 200.0", "max_mm = 1e308", "stage.axes[0].max_mm"),
            ("min_mm = 0.0", "min_mm = -1e5", "stage.axes[0].min_mm"),
            (
                "max_feed_mm_min = 6000.0",
                "max_feed_mm_min = 4e-320",
                "stage.axes[0].max_feed_mm_min",
            ),
            (
                "max_feed_mm_min = 6000.0",
                "max_feed_mm_min = 1e9",
                "stage.axes[0].max_feed_mm_min",
            ),
        ] {
            let stage = "driver = \"linuxcnc\"\nhost = \"10.0.0.5\"\naxes = [\n  { axis = \"x\", min_mm = 0.0, max_mm = 200.0, max_feed_mm_min = 6000.0 },\n  { axis = \"y\", joint = 1, min_mm = 0.0, max_mm = 150.0, max_feed_mm_min = 6000.0 },\n]";
            let e = test_support::with_stage(&stage.replacen(from, to, 1))
                .map(|_| panic!("{to} accepted"))
                .unwrap_err();
            assert!(e.contains(&format!("`{key}`")), "{to}: {e}");
        }
        let e =
            test_support::with_stage("driver = \"grbl\"\nport = \"/dev/ttyUSB0\"\nbaud = 9000000")
                .map(|_| panic!("accepted"))
                .unwrap_err();
        assert!(e.contains("`stage.baud`"), "{e}");
    }

    #[test]
    fn only_a_job_on_a_coded_board_may_skip_homing() {
        let doc = ConfigDoc::embedded(DEMO_JOB, EMBEDDED).unwrap();
        assert!(Job::from_doc(&doc).unwrap().home);
        let mut doc = doc.clone();
        doc.text = doc
            .text
            .replace("feed_mm_min = 3000.0", "feed_mm_min = 3000.0\nhome = false");
        let e = Job::from_doc(&doc).unwrap_err().to_string();
        assert!(e.contains("setup.home") && e.contains("coded board"), "{e}");
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
        // A subnormal tolerance (the bad-input sweep's) is refused where it is read,
        // not as "cannot tell which board points are in view" at the first frame.
        let mut tiny = ConfigDoc::embedded(DEMO_JOB, EMBEDDED).unwrap();
        tiny.text = tiny
            .text
            .replace("hint_tolerance_mm = 0.1", "hint_tolerance_mm = 4e-320");
        let e = Job::from_doc(&tiny).unwrap_err().to_string();
        assert!(
            e.contains("localize.hint_tolerance_mm") && e.contains("at least 0.001 mm"),
            "{e}"
        );
        assert!(e.contains("demo.toml (built in):"), "{e}");
    }

    /// The demo job's text with `from` replaced by `to`, resolved.
    fn demo_with(from: &str, to: &str) -> Result<Job, String> {
        let mut doc = ConfigDoc::embedded(DEMO_JOB, EMBEDDED).unwrap();
        assert!(doc.text.contains(from), "{from}");
        doc.text = doc.text.replace(from, to);
        Job::from_doc(&doc).map_err(|e| e.to_string())
    }

    #[test]
    fn a_third_coordinate_is_refused_not_dropped() {
        let e = demo_with("[5.0, 5.0]", "[5.0, 5.0, 1.0]").unwrap_err();
        assert!(
            e.contains("setup.board_at_machine_zero_mm") && e.contains("two numbers"),
            "{e}"
        );
        let e = demo_with(
            "grid = { x_mm = [12.0, 198.0], y_mm = [12.0, 148.0], nx = 6, ny = 5 }",
            "points = [[12.0, 12.0], [20.0, 20.0, 3.0]]",
        )
        .unwrap_err();
        assert!(
            e.contains("targets.points") && e.contains("two numbers"),
            "{e}"
        );
        let e = demo_with("x_mm = [12.0, 198.0]", "x_mm = [12.0]").unwrap_err();
        assert!(e.contains("targets.grid.x_mm"), "{e}");
    }

    #[test]
    fn a_partial_compensation_section_takes_the_defaults_for_the_rest() {
        let job = demo_with(
            "tolerance_um = 0.5\nmax_iterations = 5\nmax_correction_mm = 0.15\napproach_mm = 0.05",
            "tolerance_um = 0.8",
        )
        .unwrap();
        let d = CorrectionPolicy::default();
        assert_eq!(job.policy.tolerance_um, 0.8);
        assert_eq!(
            (
                job.policy.max_iterations,
                job.policy.max_correction_mm,
                job.policy.approach_mm
            ),
            (d.max_iterations, d.max_correction_mm, d.approach_mm)
        );
        assert!(job.policy.check_orientation);
        let e = demo_with(
            "tolerance_um = 0.5",
            "tolerance_um = 0.5\ndivergence_ratio = 1.5",
        )
        .unwrap_err();
        assert!(e.contains("compensation.divergence_ratio"), "{e}");
    }

    #[test]
    fn values_that_would_fail_only_after_homing_are_refused_at_load() {
        let e = demo_with("max_residual_um = 2.0", "max_residual_um = inf").unwrap_err();
        assert!(e.contains("localize.max_residual_um"), "{e}");
        for offset in ["1e308", "-1e100", "inf"] {
            let e = demo_with(
                "board_at_machine_zero_mm = [5.0, 5.0]",
                &format!("board_at_machine_zero_mm = [5.0, {offset}]"),
            )
            .unwrap_err();
            assert!(
                e.contains("setup.board_at_machine_zero_mm"),
                "{offset}: {e}"
            );
        }
        // A tolerance no stage reaches, or one that calls every target converged.
        for tolerance in ["4e-320", "0.001", "1e308", "nan"] {
            let e = demo_with("tolerance_um = 0.5", &format!("tolerance_um = {tolerance}"))
                .unwrap_err();
            assert!(e.contains("compensation.tolerance_um"), "{tolerance}: {e}");
        }
        let e = demo_with("min_points = 12", "min_points = 1000000").unwrap_err();
        assert!(
            e.contains("localize.min_points") && e.contains("one frame of this camera"),
            "{e}"
        );
        for feed in ["1e-300", "1e300", "0.0", "nan"] {
            let e =
                demo_with("feed_mm_min = 3000.0", &format!("feed_mm_min = {feed}")).unwrap_err();
            assert!(
                e.contains("setup.feed_mm_min") && e.contains("mm/min"),
                "{feed}: {e}"
            );
        }
        let e = demo_with("nx = 6, ny = 5", "nx = 65536, ny = 65536").unwrap_err();
        assert!(
            e.contains("targets.grid") && e.contains("at most 100000"),
            "{e}"
        );
    }
}

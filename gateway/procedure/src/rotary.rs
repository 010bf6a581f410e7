//! The A/C tilting table of source B: the paper's probing cycle through the rotary job's
//! link and the identification of the eight location errors (`measure`), the errors
//! from centres measured elsewhere (`identify`), and a 5-axis program rewritten for them
//! (`rewrite`).

use crate::command_line::{self, FileArg};
use crate::request::RotaryRequest;
use crate::Error;
use crate::{Artifact, Outcome, Sink};
use job::rotary::RotaryJob;
use protocol::config::DataKind;
use rotary::{identify as identify_errors, write_centres, CentreRow, Identification};
use rotary::{LocationErrors, MachineConstants, RotaryMachine};
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::cell::Cell;
use std::future::Future;

pub use crate::context::ErrorsShelf;

/// The errors' report as `errors.json` in a folder, written atomically.
pub struct FolderShelf(pub std::path::PathBuf);

impl ErrorsShelf for FolderShelf {
    fn keep(&mut self, _: &str, report: &Value) -> Result<String, crate::Error> {
        let path = self.0.join("errors.json");
        let text = serde_json::to_string_pretty(report)
            .map_err(|e| crate::Error::Output(e.to_string()))?;
        protocol::config::write_output(&path, text.as_bytes(), &[])
            .map_err(|e| crate::Error::Output(format!("writing {}: {e}", path.display())))?;
        Ok(path.display().to_string())
    }
}

/// The eight location errors under the paper's names (what `gateway rewrite --rotary`
/// and `rotary rewrite` read at the top level of an errors file).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct EightErrors {
    /// X offset of the C axis, mm.
    #[serde(rename = "delta_XC_mm")]
    pub delta_xc_mm: f64,
    /// Y offset of the C axis, mm.
    #[serde(rename = "delta_YC_mm")]
    pub delta_yc_mm: f64,
    /// Tilt of the C axis about X, degrees.
    #[serde(rename = "alpha_XC_deg")]
    pub alpha_xc_deg: f64,
    /// Tilt of the C axis about Y, degrees.
    #[serde(rename = "alpha_YC_deg")]
    pub alpha_yc_deg: f64,
    /// Y offset of the A axis, mm.
    #[serde(rename = "delta_YA_mm")]
    pub delta_ya_mm: f64,
    /// Z offset of the A axis, mm.
    #[serde(rename = "delta_ZA_mm")]
    pub delta_za_mm: f64,
    /// Tilt of the A axis about Y, degrees.
    #[serde(rename = "alpha_YA_deg")]
    pub alpha_ya_deg: f64,
    /// Tilt of the A axis about Z, degrees.
    #[serde(rename = "alpha_ZA_deg")]
    pub alpha_za_deg: f64,
}

impl From<LocationErrors> for EightErrors {
    fn from(e: LocationErrors) -> Self {
        Self {
            delta_xc_mm: e.delta_xc_mm,
            delta_yc_mm: e.delta_yc_mm,
            alpha_xc_deg: e.alpha_xc_deg,
            alpha_yc_deg: e.alpha_yc_deg,
            delta_ya_mm: e.delta_ya_mm,
            delta_za_mm: e.delta_za_mm,
            alpha_ya_deg: e.alpha_ya_deg,
            alpha_za_deg: e.alpha_za_deg,
        }
    }
}

impl From<EightErrors> for LocationErrors {
    fn from(e: EightErrors) -> Self {
        Self {
            delta_xc_mm: e.delta_xc_mm,
            delta_yc_mm: e.delta_yc_mm,
            alpha_xc_deg: e.alpha_xc_deg,
            alpha_yc_deg: e.alpha_yc_deg,
            delta_ya_mm: e.delta_ya_mm,
            delta_za_mm: e.delta_za_mm,
            alpha_ya_deg: e.alpha_ya_deg,
            alpha_za_deg: e.alpha_za_deg,
        }
    }
}

/// A circle fitted to one ball's centres over a sweep.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct FittedCircle {
    /// The swept axis: `A` or `C`.
    pub axis: String,
    /// The ball: 1 or 2.
    pub ball: u8,
    /// The circle's centre (machine frame), mm.
    pub centre_mm: [f64; 3],
    /// Its plane's unit normal.
    pub normal: [f64; 3],
    pub radius_mm: f64,
    /// RMS distance of the centres from the circle's plane, um.
    pub rms_plane_um: f64,
    /// RMS of their in-plane distance from the circle, um.
    pub rms_radial_um: f64,
    /// How many centres it was fitted to.
    pub points: usize,
}

/// One axis's identified line.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct AxisFit {
    /// A point of the line (the mean of the two balls' circle centres), mm.
    pub point: [f64; 3],
    /// Its unit direction.
    pub direction: [f64; 3],
    /// The angle between that direction and the line through the two circle centres.
    pub centre_line_deviation_deg: f64,
    /// How far apart the two circle centres are.
    pub centre_separation_mm: f64,
}

impl From<&rotary::identify::AxisLine> for AxisFit {
    fn from(l: &rotary::identify::AxisLine) -> Self {
        Self {
            point: l.point,
            direction: l.direction,
            centre_line_deviation_deg: l.centre_line_deviation_deg,
            centre_separation_mm: l.centre_separation_mm,
        }
    }
}

/// The identification (`rotary identify`'s result; the errors file): the eight errors
/// at the top level under their paper names, their standard uncertainties (k = 1), the
/// fitted circles and axis lines, and the machine constants.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct RotaryIdentifyResult {
    /// The eight errors.
    #[serde(flatten)]
    #[schema(inline)]
    pub errors: EightErrors,
    /// Their standard uncertainties.
    #[schema(inline)]
    pub uncertainty: EightErrors,
    /// The uncertainties' coverage factor k (1).
    pub coverage_factor: u32,
    /// C ball 1, C ball 2, A ball 1, A ball 2.
    #[schema(inline)]
    pub circles: Vec<FittedCircle>,
    #[schema(inline)]
    pub c_axis: AxisFit,
    #[schema(inline)]
    pub a_axis: AxisFit,
    /// The machine constants the errors belong to.
    #[schema(value_type = Object)]
    pub machine: MachineConstants,
}

impl RotaryIdentifyResult {
    fn new(id: &Identification, constants: &MachineConstants) -> Self {
        Self {
            errors: id.errors.into(),
            uncertainty: id.uncertainty.into(),
            coverage_factor: 1,
            circles: (id.circles.iter())
                .map(|(axis, ball, c)| FittedCircle {
                    axis: axis.to_string(),
                    ball: *ball,
                    centre_mm: c.centre,
                    normal: c.normal,
                    radius_mm: c.radius_mm,
                    rms_plane_um: c.rms_plane_mm * 1e3,
                    rms_radial_um: c.rms_radial_mm * 1e3,
                    points: c.points,
                })
                .collect(),
            c_axis: (&id.c_axis).into(),
            a_axis: (&id.a_axis).into(),
            machine: *constants,
        }
    }
}

/// The C rotation centre found on the rim (machine frame, tool-tip coordinates).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct RimCentre {
    pub x_mm: f64,
    pub y_mm: f64,
    /// The located centre minus the nominal C axis, X and Y.
    pub offset_mm: [f64; 2],
    /// The rim's radius from the fit (stylus radius taken off).
    pub rim_radius_mm: f64,
    /// The stylus centres at the three slow touches, mm.
    pub points: Vec<[f64; 3]>,
}

/// The cycle's figures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct CycleFigures {
    /// Balls measured.
    pub balls: usize,
    /// Probe points (two touches each: fast, then slow).
    pub probe_points: usize,
    pub probe_touches: usize,
    /// The cycle's time on the emulated machine's clock (a simulated link).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub simulated_time_s: Option<f64>,
    /// The cycle's time on the wall clock (a real controller).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub wall_time_s: Option<f64>,
}

/// One error identified against the one the simulated table was given.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct AgainstTruth {
    pub injected: f64,
    pub identified: f64,
    /// Identified minus injected.
    pub difference: f64,
}

/// The eight errors against the truth, under their paper names.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct TruthComparison {
    #[serde(rename = "delta_XC_mm")]
    #[schema(inline)]
    pub delta_xc_mm: AgainstTruth,
    #[serde(rename = "delta_YC_mm")]
    #[schema(inline)]
    pub delta_yc_mm: AgainstTruth,
    #[serde(rename = "alpha_XC_deg")]
    #[schema(inline)]
    pub alpha_xc_deg: AgainstTruth,
    #[serde(rename = "alpha_YC_deg")]
    #[schema(inline)]
    pub alpha_yc_deg: AgainstTruth,
    #[serde(rename = "delta_YA_mm")]
    #[schema(inline)]
    pub delta_ya_mm: AgainstTruth,
    #[serde(rename = "delta_ZA_mm")]
    #[schema(inline)]
    pub delta_za_mm: AgainstTruth,
    #[serde(rename = "alpha_YA_deg")]
    #[schema(inline)]
    pub alpha_ya_deg: AgainstTruth,
    #[serde(rename = "alpha_ZA_deg")]
    #[schema(inline)]
    pub alpha_za_deg: AgainstTruth,
}

impl TruthComparison {
    fn new(injected: LocationErrors, identified: LocationErrors) -> Self {
        let c = |w: f64, g: f64| AgainstTruth {
            injected: w,
            identified: g,
            difference: g - w,
        };
        let (w, g) = (injected, identified);
        Self {
            delta_xc_mm: c(w.delta_xc_mm, g.delta_xc_mm),
            delta_yc_mm: c(w.delta_yc_mm, g.delta_yc_mm),
            alpha_xc_deg: c(w.alpha_xc_deg, g.alpha_xc_deg),
            alpha_yc_deg: c(w.alpha_yc_deg, g.alpha_yc_deg),
            delta_ya_mm: c(w.delta_ya_mm, g.delta_ya_mm),
            delta_za_mm: c(w.delta_za_mm, g.delta_za_mm),
            alpha_ya_deg: c(w.alpha_ya_deg, g.alpha_ya_deg),
            alpha_za_deg: c(w.alpha_za_deg, g.alpha_za_deg),
        }
    }

    /// The eight in the paper's order, with their names.
    pub fn named(&self) -> [(&'static str, AgainstTruth); 8] {
        [
            ("delta_XC_mm", self.delta_xc_mm),
            ("delta_YC_mm", self.delta_yc_mm),
            ("alpha_XC_deg", self.alpha_xc_deg),
            ("alpha_YC_deg", self.alpha_yc_deg),
            ("delta_YA_mm", self.delta_ya_mm),
            ("delta_ZA_mm", self.delta_za_mm),
            ("alpha_YA_deg", self.alpha_ya_deg),
            ("alpha_ZA_deg", self.alpha_za_deg),
        ]
    }
}

/// A 5-axis test program run as programmed and as compensated, against the truth.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct CompensationFigures {
    /// Poses of the program (A 2..90°, C all round).
    pub poses: usize,
    pub tip_max_before_mm: f64,
    pub tip_max_after_mm: f64,
    pub tip_mean_before_mm: f64,
    pub tip_mean_after_mm: f64,
    pub tip_improvement_pct: f64,
    pub direction_max_before_rad: f64,
    pub direction_max_after_rad: f64,
    pub direction_improvement_pct: f64,
}

impl From<runner::rotary::CompensationCheck> for CompensationFigures {
    fn from(c: runner::rotary::CompensationCheck) -> Self {
        Self {
            poses: c.poses,
            tip_max_before_mm: c.tip_max_before_mm,
            tip_max_after_mm: c.tip_max_after_mm,
            tip_mean_before_mm: c.tip_mean_before_mm,
            tip_mean_after_mm: c.tip_mean_after_mm,
            tip_improvement_pct: c.tip_improvement_pct,
            direction_max_before_rad: c.dir_max_before_rad,
            direction_max_after_rad: c.dir_max_after_rad,
            direction_improvement_pct: c.dir_improvement_pct,
        }
    }
}

/// The report of a measured cycle (the `errors.json` the shelf keeps): the
/// identification, the C centre found on the rim, the cycle's figures and, when the
/// truth is known (a simulated table), each error against the injected one and the
/// compensation of a 5-axis program checked against the truth.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct CycleReport {
    #[serde(flatten)]
    #[schema(inline)]
    pub identification: RotaryIdentifyResult,
    /// Absent when the cycle's plan locates no centre on the rim.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(inline)]
    pub c_centre: Option<RimCentre>,
    #[schema(inline)]
    pub cycle: CycleFigures,
    /// A simulated table only.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(inline)]
    pub truth: Option<TruthComparison>,
    /// A simulated table only.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(inline)]
    pub compensation_check: Option<CompensationFigures>,
}

impl CycleReport {
    /// The report of `run`'s measurement `m` identified as `id`.
    pub fn new(
        run: &runner::rotary::CycleRun,
        m: &rotary::measure::Measurement,
        id: &Identification,
        constants: &MachineConstants,
    ) -> Result<Self, runner::rotary::RotaryError> {
        let simulated = run.truth.is_some();
        let (truth, compensation_check) = match &run.truth {
            None => (None, None),
            Some(table) => (
                Some(TruthComparison::new(
                    job::rotary::injected_errors(&table.errors),
                    id.errors,
                )),
                Some(runner::rotary::compensation_check(table, constants, &id.errors)?.into()),
            ),
        };
        Ok(Self {
            identification: RotaryIdentifyResult::new(id, constants),
            c_centre: m.c_centre.as_ref().map(|c| RimCentre {
                x_mm: c.x_mm,
                y_mm: c.y_mm,
                offset_mm: c.offset_mm,
                rim_radius_mm: c.rim_radius_mm,
                points: c.points.clone(),
            }),
            cycle: CycleFigures {
                balls: m.balls.len(),
                probe_points: m.probe_touches / 2,
                probe_touches: m.probe_touches,
                simulated_time_s: simulated.then_some(run.time_s),
                wall_time_s: (!simulated).then_some(run.time_s),
            },
            truth,
            compensation_check,
        })
    }
}

/// `rotary measure`'s result: the report with the profile's name and where it was kept;
/// a stopped cycle gives the name and what it measured instead of the report.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct RotaryMeasureResult {
    /// The rotary profile the errors become a version of.
    pub name: String,
    /// Where the errors were kept (a file, a profile version).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub kept_as: Option<String>,
    /// The report (absent when the cycle stopped).
    #[serde(flatten)]
    #[schema(inline)]
    pub report: Option<CycleReport>,
    /// A stopped cycle: the balls it measured.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub balls_measured: Option<usize>,
    /// A stopped cycle: its probe touches.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub probe_touches: Option<usize>,
}

/// One ball's sphere as it is fitted (a measurement of the cycle).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct BallSphere {
    /// The swept axis: `A` or `C`.
    pub axis: String,
    pub step: u32,
    pub angle_deg: f64,
    pub ball: u8,
    pub centre_mm: [f64; 3],
    pub radius_mm: f64,
    /// RMS of the touches' distances from the sphere, um.
    pub rms_um: f64,
    /// The stylus centres at the slow touches (machine frame), mm.
    pub points: Vec<[f64; 3]>,
}

/// `rotary rewrite`'s result: the rewritten program's figures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct RotaryRewriteResult {
    /// Lines of the program.
    pub lines: usize,
    /// Moves rewritten.
    pub moves: usize,
    /// Pieces added where a move was split to stay within the tolerance.
    pub pieces_added: usize,
    /// The largest change of a point's X Y Z.
    pub max_correction_xyz_mm: f64,
    /// The largest change of a point's A or C.
    pub max_correction_ac_deg: f64,
}

/// The sweep chart (centres and fitted circles, deviations x1000) as SVG and PNG.
fn sweep_chart(rows: &[CentreRow], id: &Identification, sink: &mut dyn Sink) -> Result<(), Error> {
    let chart = rotary::chart::SweepChart {
        rows,
        identification: id,
        magnification: 1000.0,
    };
    let failed = |e| Error::Output(format!("the sweep chart: {e}"));
    let svg = plot::render_svg(&chart, 1000, 460).map_err(failed)?;
    let png = plot::render_png(&chart, 1000, 460).map_err(failed)?;
    sink.artifact(Artifact {
        name: "rotary-sweeps.svg".into(),
        title: Some("Ball centres and fitted circles (deviations x1000)".into()),
        media_type: "image/svg+xml",
        bytes: svg.into_bytes(),
    })?;
    sink.artifact(Artifact {
        name: "rotary-sweeps.png".into(),
        title: None,
        media_type: "image/png",
        bytes: png,
    })
}

/// Every probe point of the cycle (`axis,step,angle_deg,ball,touch,x_mm,y_mm,z_mm`).
fn points_csv(m: &rotary::measure::Measurement) -> String {
    let mut points = String::from("axis,step,angle_deg,ball,touch,x_mm,y_mm,z_mm\n");
    for b in &m.balls {
        for (k, p) in b.points.iter().enumerate() {
            points.push_str(&format!(
                "{},{},{},{},{},{:.6},{:.6},{:.6}\n",
                b.axis,
                b.step,
                b.angle_deg,
                b.ball,
                k + 1,
                p[0],
                p[1],
                p[2]
            ));
        }
    }
    points
}

fn text_artifact(name: &str, media_type: &'static str, text: String) -> Artifact {
    Artifact {
        name: name.into(),
        title: None,
        media_type,
        bytes: text.into_bytes(),
    }
}

/// Runs the paper's probing cycle through the job's link (the simulated table in-process,
/// the GRBL emulator, or a real controller), each ball's sphere a measurement as it is
/// fitted, `centres.csv` and `points.csv` as artifacts (also for a stopped cycle), then
/// identifies the eight errors, keeps them on the shelf and draws the sweep chart. The
/// result is the [`CycleReport`] with `name`, `kept_as`.
pub async fn measure(
    request: &RotaryRequest,
    job: &RotaryJob,
    shelf: &mut dyn ErrorsShelf,
    sink: &mut dyn Sink,
    stop: impl Future<Output = ()>,
) -> Outcome<RotaryMeasureResult> {
    let constants = job.machine.unwrap_or_default();
    let cancelled = Cell::new(false);
    let progress = std::cell::RefCell::new(&mut *sink);
    let run = runner::rotary::run_cycle(
        job,
        |done, of| progress.borrow_mut().progress(done as u64, of as u64),
        async {
            stop.await;
            cancelled.set(true);
        },
    )
    .await;
    let run = match run {
        Ok(run) => run,
        Err(e) => return Outcome::failed(e.to_string()),
    };
    let (m, stopped) = match &run.cycle {
        Ok(m) => (m, None),
        Err(s) => (&s.so_far, Some(s.error.to_string())),
    };
    for b in &m.balls {
        let sphere = BallSphere {
            axis: b.axis.to_string(),
            step: b.step,
            angle_deg: b.angle_deg,
            ball: b.ball,
            centre_mm: b.sphere.centre,
            radius_mm: b.sphere.radius_mm,
            rms_um: b.sphere.rms_mm * 1e3,
            points: b.points.clone(),
        };
        let kept = serde_json::to_value(&sphere)
            .map_err(|e| Error::Output(e.to_string()))
            .and_then(|v| sink.measurement(&v));
        if let Err(e) = kept {
            return Outcome::failed(format!("a ball's sphere was not kept: {e}"));
        }
    }
    let rows = m.centres();
    for a in [
        text_artifact("centres.csv", "text/csv", write_centres(&rows)),
        text_artifact("points.csv", "text/csv", points_csv(m)),
    ] {
        if let Err(e) = sink.artifact(a) {
            return Outcome::failed(e);
        }
    }
    if let Some(error) = stopped {
        let result = RotaryMeasureResult {
            name: request.name.clone(),
            kept_as: None,
            report: None,
            balls_measured: Some(m.balls.len()),
            probe_touches: Some(m.probe_touches),
        };
        let error = format!(
            "the measurement cycle stopped: {error} ({} balls measured, kept in centres.csv and points.csv)",
            m.balls.len()
        );
        return Outcome::stopped(
            cancelled.get(),
            error,
            Some(result),
            Default::default(),
            false,
        );
    }
    let identified = match identify_errors(&rows, &constants) {
        Ok(i) => i,
        Err(e) => return Outcome::failed(format!("identification: {e}")),
    };
    let report = match CycleReport::new(&run, m, &identified, &constants) {
        Ok(r) => r,
        Err(e) => return Outcome::failed(format!("the report: {e}")),
    };
    if let Err(e) = sweep_chart(&rows, &identified, sink) {
        return Outcome::failed(e);
    }
    let kept_as = serde_json::to_value(&report)
        .map_err(|e| Error::Output(e.to_string()))
        .and_then(|v| shelf.keep(&request.name, &v));
    let kept_as = match kept_as {
        Ok(k) => k,
        Err(e) => return Outcome::failed(format!("the errors were identified but not kept: {e}")),
    };
    let mut metrics = serde_json::Map::new();
    for (error, v) in identified.errors.named() {
        metrics.insert(error.into(), v.into());
    }
    metrics.insert("balls".into(), m.balls.len().into());
    let result = RotaryMeasureResult {
        name: request.name.clone(),
        kept_as: Some(kept_as),
        report: Some(report),
        balls_measured: None,
        probe_touches: None,
    };
    Outcome::succeeded(result, metrics)
}

/// The eight errors from ball centres measured elsewhere (a CMM, as in the paper): the
/// centres file's text in, the identification as the result, the sweep chart as
/// artifacts.
pub fn identify(
    centres: &str,
    source: &str,
    constants: &MachineConstants,
    sink: &mut dyn Sink,
) -> Outcome<RotaryIdentifyResult> {
    let rows = match rotary::parse_centres(centres) {
        Ok(r) => r,
        Err(e) => return Outcome::failed(format!("{source}: {e}")),
    };
    let id = match identify_errors(&rows, constants) {
        Ok(i) => i,
        Err(e) => return Outcome::failed(format!("identifying from {source}: {e}")),
    };
    if let Err(e) = sweep_chart(&rows, &id, sink) {
        return Outcome::failed(e);
    }
    Outcome::succeeded(
        RotaryIdentifyResult::new(&id, constants),
        Default::default(),
    )
}

/// A rotary input file's text through the bounded reader (regular files only, its
/// kind's size cap); the error names the kind and the file.
fn read_input(path: &std::path::Path, kind: DataKind) -> Result<String, Error> {
    Ok(protocol::config::read_kind(path, kind)?)
}

/// The centres file at `path` read (bounded, [`DataKind::Centres`]) and parsed: errors
/// name the file, and the line and column where the parser fails.
pub fn read_centres_file(path: &std::path::Path) -> Result<Vec<CentreRow>, Error> {
    let text = read_input(path, DataKind::Centres)?;
    rotary::parse_centres(&text).map_err(|e| Error::input(path.display(), e))
}

/// An errors file (or machine constants) at `path` as text, bounded
/// ([`DataKind::RotaryJson`]).
pub fn read_errors_file(path: &std::path::Path) -> Result<String, Error> {
    read_input(path, DataKind::RotaryJson)
}

/// Machine constants (JSON: `a_axis_y_mm`, ... `tool_length_mm`) from the file at
/// `path`, read bounded, one document, checked; every error names the file.
/// The machine constants file read into the request's `machine`.
fn machine_file(path: &std::path::Path, plan: &mut command_line::Plan) -> Result<(), Error> {
    plan.set("machine", read_machine_file(path)?);
    plan.inputs.push(path.to_path_buf());
    Ok(())
}

pub fn read_machine_file(path: &std::path::Path) -> Result<MachineConstants, Error> {
    let text = read_errors_file(path)?;
    let name = path.display();
    let de = &mut serde_json::Deserializer::from_str(&text);
    let k: MachineConstants = serde_path_to_error::deserialize(&mut *de)
        .map_err(|e| Error::input(&name, format!("{} (at {})", e.inner(), e.path())))?;
    de.end()
        .map_err(|e| Error::input(&name, format!("after the constants: {e}")))?;
    k.check().map_err(|e| Error::input(&name, e))?;
    Ok(k)
}

/// The most bytes a rewritten 5-axis program may have (a split move adds at most 2^10
/// pieces): the rewrite stops, naming the line, when its output passes this.
pub const MAX_REWRITTEN_BYTES: usize = 256 << 20;

/// `gateway rotary rewrite` from files: the program at `program` read as a bounded
/// stream of lines ([`protocol::config::open_lines`]: regular files only, 64 KiB per
/// line) and rewritten line by line, the errors file at `errors` read bounded, its
/// machine constants used as [`rewrite_with_errors_file`] does. Every error names the
/// file (and the line).
pub fn rewrite_files(
    program: &std::path::Path,
    errors: &std::path::Path,
    machine: Option<MachineConstants>,
    force_machine: bool,
    tolerance_um: f64,
    sink: &mut dyn Sink,
) -> Outcome<RotaryRewriteResult> {
    let errors_text = match read_errors_file(errors) {
        Ok(t) => t,
        Err(e) => return Outcome::failed(e),
    };
    let source = program.display().to_string();
    let errors_source = errors.display().to_string();
    let lines = match protocol::config::open_lines(program, DataKind::Program) {
        Ok(l) => l.keep_endings(),
        Err(e) => return Outcome::failed(e.to_string()),
    };
    let mut text = String::new();
    for line in lines {
        match line {
            Ok((_, l)) => text.push_str(&l),
            Err(e) => return Outcome::failed(e.to_string()),
        }
    }
    rewrite_with_errors_file(
        &text,
        &source,
        &errors_text,
        &errors_source,
        machine,
        force_machine,
        tolerance_um,
        sink,
    )
}

/// [`rewrite`] from the errors file's text (`errors_source` names it): the errors and
/// the machine constants it records, which the rewrite uses; `machine` (the operator's
/// `--machine`) must agree with them unless `force_machine` (errors belong to the
/// machine they were measured on), and is used alone for a file that records none.
#[allow(clippy::too_many_arguments)]
pub fn rewrite_with_errors_file(
    program: &str,
    source: &str,
    errors_text: &str,
    errors_source: &str,
    machine: Option<MachineConstants>,
    force_machine: bool,
    tolerance_um: f64,
    sink: &mut dyn Sink,
) -> Outcome<RotaryRewriteResult> {
    let errors = match LocationErrors::from_json(errors_text) {
        Ok(e) => e,
        Err(e) => return Outcome::failed(format!("{errors_source}: {e}")),
    };
    let constants = match MachineConstants::from_errors_json(errors_text)
        .and_then(|stored| MachineConstants::for_errors(stored, machine, force_machine))
    {
        Ok(k) => k,
        Err(e) => return Outcome::failed(format!("{errors_source}: {e}")),
    };
    rewrite(program, source, errors, constants, tolerance_um, sink)
}

/// A 5-axis program (X Y Z A C, absolute, mm) rewritten for the errors: the program's
/// text in, the rewritten program as the artifact `program.nc`, the figures as the
/// result. `tolerance_um` is the largest distance of a piece's middle from the
/// compensated path.
pub fn rewrite(
    program: &str,
    source: &str,
    errors: LocationErrors,
    constants: MachineConstants,
    tolerance_um: f64,
    sink: &mut dyn Sink,
) -> Outcome<RotaryRewriteResult> {
    if !(tolerance_um > 0.0 && tolerance_um.is_finite() && tolerance_um <= 1000.0) {
        return Outcome::failed(format!(
            "tolerance_um: must be a number from 0 (excluded) to 1000, got {tolerance_um}"
        ));
    }
    let model = RotaryMachine::with_errors(constants, errors);
    let opts = rotary::rewrite::RewriteOptions {
        tolerance_mm: tolerance_um / 1000.0,
        ..Default::default()
    };
    let (rewritten, report) = match rotary::rewrite::rewrite_program(program, &model, &opts) {
        Ok(r) => r,
        Err(e) => return Outcome::failed(format!("{source}: {e}")),
    };
    let max_xyz = report
        .points
        .iter()
        .map(|p| {
            let (n, c) = (p.nominal, p.command);
            ((c.x - n.x).powi(2) + (c.y - n.y).powi(2) + (c.z - n.z).powi(2)).sqrt()
        })
        .fold(0.0f64, f64::max);
    let max_ac = report
        .points
        .iter()
        .map(|p| {
            (p.command.a - p.nominal.a)
                .abs()
                .max((p.command.c - p.nominal.c).abs())
        })
        .fold(0.0f64, f64::max);
    if let Err(e) = sink.artifact(text_artifact("program.nc", "text/plain", rewritten)) {
        return Outcome::failed(e);
    }
    Outcome::succeeded(
        RotaryRewriteResult {
            lines: report.lines,
            moves: report.moves,
            pieces_added: report.pieces_added,
            max_correction_xyz_mm: max_xyz,
            max_correction_ac_deg: max_ac,
        },
        Default::default(),
    )
}

/// The probing cycle of the rotary table as a registered procedure.
pub struct RotaryMeasure;

impl crate::registry::Procedure for RotaryMeasure {
    const KIND: &'static str = "rotary";
    const TITLE: &'static str =
        "Rotary table: probe the A/C table and identify its eight location errors";
    const COMMAND: &'static str = "rotary measure";
    const LABEL: &'static str = "Rotary table measurement";
    const HELP: &'static str = "Probes the rotary table's balls and finds its eight errors; they become a new rotary profile version.";
    const FIELD_HELP: &'static [(&'static str, &'static str)] = &[(
        "name",
        "The rotary profile the result becomes a new version of.",
    )];
    const USES: crate::registry::Uses = crate::registry::Uses::ROTARY;
    type Request = RotaryRequest;
    type Result = RotaryMeasureResult;
    const FILES: &'static [FileArg] = &[
        FileArg::required(
            "config",
            "The rotary job (JSON: seed, errors, probe, plan, machine, speeds; all optional, defaults are the paper's table).",
            command_line::rotary_job,
        ),
        FileArg::required(
            "out",
            "Output folder: centres.csv, points.csv, errors.json and the sweep chart.",
            command_line::out_folder,
        ),
    ];
    const STEPS: &'static str = "balls";

    async fn run(
        request: RotaryRequest,
        cx: &mut dyn crate::Context,
    ) -> Outcome<RotaryMeasureResult> {
        let stop = cx.stop();
        let job = crate::or_fail!(cx.rotary_job());
        let mut shelf = crate::or_fail!(cx.errors_shelf());
        measure(&request, &job, shelf.as_mut(), cx.sink(), stop.requested()).await
    }

    fn summary(result: &RotaryMeasureResult) -> String {
        measure_summary(result)
    }
}

/// An identification from ball centres measured elsewhere.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields)]
pub struct RotaryIdentifyRequest {
    /// The centres file (`axis,step,angle_deg,ball,x_mm,y_mm,z_mm`: the C sweep at A = 0
    /// and the A sweep at C = 0, machine coordinates).
    #[schema(format = Binary, max_length = 16777216)]
    #[cfg_attr(feature = "cli", arg(skip))]
    pub centres: String,
    /// How messages name it (its file name).
    #[serde(default = "default_centres_name")]
    #[schema(default = default_centres_name)]
    #[cfg_attr(feature = "cli", arg(skip = default_centres_name()))]
    pub centres_name: String,
    /// The machine constants (`a_axis_y_mm`, `a_axis_z_mm`, `ac_offset_y_mm`,
    /// `ac_offset_z_mm`, `tool_length_mm`); default: the built-in 340A-style mill.
    #[serde(default)]
    #[schema(value_type = Option<Object>)]
    #[cfg_attr(feature = "cli", arg(skip))]
    pub machine: Option<MachineConstants>,
}

fn default_centres_name() -> String {
    "centres.csv".into()
}

impl crate::registry::Checked for RotaryIdentifyRequest {
    fn check(&self) -> Result<(), crate::RequestError> {
        let max = DataKind::Centres.max_bytes();
        if self.centres.len() as u64 > max {
            return Err(crate::RequestError::new(
                "centres",
                format!("at most {max} bytes are accepted"),
            ));
        }
        if let Some(k) = &self.machine {
            k.check()
                .map_err(|e| crate::RequestError::new("machine", e.to_string()))?;
        }
        Ok(())
    }
}

/// The identification from centres as a registered procedure.
pub struct RotaryIdentify;

impl crate::registry::Procedure for RotaryIdentify {
    const KIND: &'static str = "rotary-identify";
    const TITLE: &'static str =
        "Rotary table: the eight location errors from ball centres measured elsewhere";
    const COMMAND: &'static str = "rotary identify";
    const LABEL: &'static str = "Rotary errors from measured centres";
    const HELP: &'static str = "Finds the rotary table's eight location errors from ball centres measured elsewhere (a CMM): the C sweep at A = 0 and the A sweep at C = 0, in machine coordinates. The machine does not move.";
    const FIELD_HELP: &'static [(&'static str, &'static str)] = &[(
        "centres",
        "The centres file: one row per ball centre (axis, step, angle, ball, X, Y, Z in mm).",
    )];
    const USES: crate::registry::Uses = crate::registry::Uses::NOTHING;
    type Request = RotaryIdentifyRequest;
    type Result = RotaryIdentifyResult;
    const FILES: &'static [FileArg] = &[
        FileArg::required("centres", "The centres file.", |path, plan| {
            let text = protocol::config::read_kind(path, protocol::config::DataKind::Centres)?;
            plan.set("centres", text);
            plan.set("centres_name", path.display().to_string());
            plan.inputs.push(path.to_path_buf());
            Ok(())
        }),
        FileArg::flag(
            "machine",
            "The machine constants (JSON: a_axis_y_mm, a_axis_z_mm, ac_offset_y_mm, ac_offset_z_mm, tool_length_mm); default: the built-in 340A-style mill.",
            machine_file,
        ),
        FileArg::flag(
            "plot",
            "Write the chart of centres and fitted circles (rotary-sweeps.svg and .png) into this folder.",
            command_line::artifacts_folder,
        ),
    ];

    async fn run(
        request: RotaryIdentifyRequest,
        cx: &mut dyn crate::Context,
    ) -> Outcome<RotaryIdentifyResult> {
        let constants = request.machine.unwrap_or_default();
        identify(
            &request.centres,
            &request.centres_name,
            &constants,
            cx.sink(),
        )
    }

    fn summary(result: &RotaryIdentifyResult) -> String {
        identification_summary(result, None)
    }
}

fn default_rotary_tolerance() -> f64 {
    0.5
}

/// A 5-axis program rewritten for a rotary table's location errors. On the command
/// line its flags are these fields (the program, errors and machine files are read into
/// them by the front end).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields)]
pub struct RotaryRewriteRequest {
    /// The program (X Y Z A C, absolute, mm).
    #[schema(format = Binary, max_length = 67108864)]
    #[cfg_attr(feature = "cli", arg(skip))]
    pub program: String,
    /// How messages name it (its file name).
    #[serde(default = "default_program_name")]
    #[schema(default = default_program_name)]
    #[cfg_attr(feature = "cli", arg(skip = default_program_name()))]
    pub program_name: String,
    /// The errors (the JSON the identification or the probing cycle writes).
    #[schema(format = Binary, max_length = 16777216)]
    #[cfg_attr(feature = "cli", arg(skip))]
    pub errors: String,
    /// How messages name the errors (their file name).
    #[serde(default = "default_errors_name")]
    #[schema(default = default_errors_name)]
    #[cfg_attr(feature = "cli", arg(skip = default_errors_name()))]
    pub errors_name: String,
    /// The machine constants; default: those recorded with the errors. Refused where
    /// they differ from the recorded ones unless `force_machine`.
    #[serde(default)]
    #[schema(value_type = Option<Object>)]
    #[cfg_attr(feature = "cli", arg(skip))]
    pub machine: Option<MachineConstants>,
    /// Use `machine` even where it differs from the constants recorded with the errors.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, requires = "machine"))]
    pub force_machine: bool,
    /// Largest distance (X Y Z) of a piece's middle from the compensated path, um.
    #[serde(default = "default_rotary_tolerance")]
    #[schema(default = default_rotary_tolerance, minimum = 0.001, maximum = 1000.0)]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_rotary_tolerance()))]
    pub tolerance_um: f64,
}

fn default_program_name() -> String {
    "program.nc".into()
}
fn default_errors_name() -> String {
    "errors.json".into()
}

impl crate::registry::Checked for RotaryRewriteRequest {
    fn check(&self) -> Result<(), crate::RequestError> {
        for (field, text, kind) in [
            ("program", &self.program, DataKind::Program),
            ("errors", &self.errors, DataKind::RotaryJson),
        ] {
            if text.len() as u64 > kind.max_bytes() {
                return Err(crate::RequestError::new(
                    field,
                    format!("at most {} bytes are accepted", kind.max_bytes()),
                ));
            }
        }
        crate::request::number("tolerance_um", self.tolerance_um, 1e-3, 1000.0)?;
        if let Some(k) = &self.machine {
            k.check()
                .map_err(|e| crate::RequestError::new("machine", e.to_string()))?;
        }
        Ok(())
    }
}

/// The 5-axis rewrite as a registered procedure.
pub struct RotaryRewrite;

impl crate::registry::Procedure for RotaryRewrite {
    const KIND: &'static str = "rotary-rewrite";
    const TITLE: &'static str =
        "Rotary table: rewrite a 5-axis program so the tool tip lands where programmed";
    const COMMAND: &'static str = "rotary rewrite";
    const LABEL: &'static str = "5-axis program rewrite";
    const HELP: &'static str = "Rewrites a 5-axis program (X Y Z A C, absolute, mm) for the rotary table's identified errors, so that the tool tip and its direction land where programmed; download the rewritten program and run it on the machine.";
    const USES: crate::registry::Uses = crate::registry::Uses::NOTHING;
    type Request = RotaryRewriteRequest;
    type Result = RotaryRewriteResult;
    const FILES: &'static [FileArg] = &[
        FileArg::positional("input", "The program (never overwritten).", |path, plan| {
            plan.text(path, "program", Some("program_name"), crate::rewrite::read_program)
        }),
        FileArg::required(
            "errors",
            "The errors (the JSON `gateway rotary identify` or `measure` writes).",
            |path, plan| plan.text(path, "errors", Some("errors_name"), read_errors_file),
        ),
        FileArg::required("out", "The rewritten program (never over an input).", |path, plan| {
            plan.artifacts.push(("program.nc".into(), path.to_path_buf()));
            Ok(())
        }),
        FileArg::flag(
            "machine",
            "The machine constants (JSON); default: those recorded in the errors file (else the built-in ones). Refused where they differ from the recorded ones.",
            machine_file,
        ),
    ];

    async fn run(
        r: RotaryRewriteRequest,
        cx: &mut dyn crate::Context,
    ) -> Outcome<RotaryRewriteResult> {
        rewrite_with_errors_file(
            &r.program,
            &r.program_name,
            &r.errors,
            &r.errors_name,
            r.machine,
            r.force_machine,
            r.tolerance_um,
            cx.sink(),
        )
    }

    fn summary(r: &RotaryRewriteResult) -> String {
        format!(
            "{} lines, {} moves rewritten, {} pieces added; largest correction {:.4} mm, {:.5} deg\n",
            r.lines, r.moves, r.pieces_added, r.max_correction_xyz_mm, r.max_correction_ac_deg
        )
    }
}

/// An identification as text (the CLI's output without `--json`): the eight errors and
/// their uncertainties (against the truth when it is known), the circles and the axes.
pub fn identification_summary(r: &RotaryIdentifyResult, truth: Option<&TruthComparison>) -> String {
    use std::fmt::Write;
    let mut t = String::new();
    let values = LocationErrors::from(r.errors).named();
    let uncertainty = LocationErrors::from(r.uncertainty).named();
    match truth {
        None => {
            let _ = writeln!(t, "{:<14} {:>12} {:>12}", "error", "value", "u (k=1)");
            for ((name, v), (_, u)) in values.iter().zip(uncertainty) {
                let _ = writeln!(t, "{name:<14} {v:>12.6} {u:>12.6}");
            }
        }
        Some(truth) => {
            let _ = writeln!(
                t,
                "{:<14} {:>12} {:>12} {:>12} {:>10}",
                "error", "injected", "identified", "difference", "u (k=1)"
            );
            for ((name, c), (_, u)) in truth.named().iter().zip(uncertainty) {
                let _ = writeln!(
                    t,
                    "{name:<14} {:>12.6} {:>12.6} {:>12.6} {u:>10.6}",
                    c.injected, c.identified, c.difference
                );
            }
        }
    }
    for c in &r.circles {
        let _ = writeln!(
            t,
            "circle {} ball {}: radius {:.4} mm, rms {:.3} um radial, {:.3} um out of plane, {} centres",
            c.axis, c.ball, c.radius_mm, c.rms_radial_um, c.rms_plane_um, c.points
        );
    }
    for (name, line) in [("C", &r.c_axis), ("A", &r.a_axis)] {
        let _ = writeln!(
            t,
            "{name} axis: circle centres {:.3} mm apart, their line {:.5} deg from the normals",
            line.centre_separation_mm, line.centre_line_deviation_deg
        );
    }
    t
}

/// A cycle's report as text: the C centre on the rim, the identification, the cycle's
/// figures and the compensation check; a stopped cycle's balls.
pub fn measure_summary(r: &RotaryMeasureResult) -> String {
    use std::fmt::Write;
    let mut t = String::new();
    let Some(report) = &r.report else {
        let _ = writeln!(
            t,
            "{}: stopped after {} balls ({} probe touches)",
            r.name,
            r.balls_measured.unwrap_or(0),
            r.probe_touches.unwrap_or(0)
        );
        return t;
    };
    if let Some(c) = &report.c_centre {
        let _ = writeln!(
            t,
            "C centre on the rim: ({:.4}, {:.4}) mm, ({:+.4}, {:+.4}) mm from the nominal axis, rim radius {:.4} mm",
            c.x_mm, c.y_mm, c.offset_mm[0], c.offset_mm[1], c.rim_radius_mm
        );
    }
    t.push_str(&identification_summary(
        &report.identification,
        report.truth.as_ref(),
    ));
    let cycle = &report.cycle;
    let (clock, time_s) = match cycle.simulated_time_s {
        Some(s) => ("simulated machine time ", s),
        None => ("", cycle.wall_time_s.unwrap_or(f64::NAN)),
    };
    let _ = writeln!(
        t,
        "cycle: {} balls, {} probe points ({} touches), {clock}{:.1} min",
        cycle.balls,
        cycle.probe_points,
        cycle.probe_touches,
        time_s / 60.0
    );
    if let Some(c) = &report.compensation_check {
        let _ = writeln!(
            t,
            "compensated 5-axis program ({} poses, A 2..90°, C all round), against the truth:",
            c.poses
        );
        let _ = writeln!(
            t,
            "  tool tip   max {:.4} mm -> {:.5} mm ({:.1} % better), mean {:.4} -> {:.5}",
            c.tip_max_before_mm,
            c.tip_max_after_mm,
            c.tip_improvement_pct,
            c.tip_mean_before_mm,
            c.tip_mean_after_mm
        );
        let _ = writeln!(
            t,
            "  direction  max {:.6} rad -> {:.7} rad ({:.1} % better)",
            c.direction_max_before_rad, c.direction_max_after_rad, c.direction_improvement_pct
        );
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Collect;

    const PROGRAM: &str = "G21 G90 G94\nG0 X0 Y0 Z-150 A0 C0\nG1 X10 Y-20 Z-190 A30 C45 F500\n";

    /// Every reader of an outside file the procedures offer refuses a FIFO (before
    /// opening it: no writer ever comes, the test would hang otherwise) and `/dev/zero`
    /// (never read), naming the file; a real file of each kind is read.
    #[cfg(unix)]
    #[test]
    fn every_reader_refuses_a_fifo_and_dev_zero_naming_the_file() {
        use std::path::Path;
        let dir = std::env::temp_dir().join(format!("procedure-readers-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let fifo = dir.join("in.fifo");
        assert!(std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success());
        type Reader = fn(&Path) -> Result<(), crate::Error>;
        let readers: [(&str, Reader); 8] = [
            ("centres file", |p| read_centres_file(p).map(|_| ())),
            ("rotary errors or machine file", |p| {
                read_errors_file(p).map(|_| ())
            }),
            ("program", |p| crate::rewrite::read_program(p).map(|_| ())),
            ("`$#` reply", |p| {
                crate::rewrite::read_offsets_file(p).map(|_| ())
            }),
            ("measurements file (ISO 230-2)", |p| {
                crate::iso230::read_measurements_file(p).map(|_| ())
            }),
            ("layout", |p| crate::layout::read_layout_file(p).map(|_| ())),
            ("volumetric file", |p| {
                crate::volumetric::read_file(p).map(|_| ())
            }),
            ("program", |p| {
                let out = rewrite_files(p, p, None, false, 0.5, &mut Collect::default());
                out.error()
                    .map_or(Ok(()), |e| Err(crate::Error::Input(e.to_string())))
            }),
        ];
        for (kind, read) in readers {
            let e = read(&fifo).unwrap_err().to_string();
            assert!(
                e.contains(&format!("{}: not a regular file (a FIFO)", fifo.display())),
                "{kind}: {e}"
            );
            let e = read(Path::new("/dev/zero")).unwrap_err().to_string();
            assert!(
                e.contains("/dev/zero: not a regular file (a character device)"),
                "{kind}: {e}"
            );
            let kind_named = e.contains(kind) || kind == "program";
            assert!(kind_named, "{kind}: {e}");
        }
        // A program streamed from a file is rewritten as from its text.
        let prog = dir.join("p.nc");
        std::fs::write(&prog, PROGRAM).unwrap();
        let errs = dir.join("errors.json");
        std::fs::write(&errs, errors_file(None)).unwrap();
        let mut sink = Collect::default();
        let out = rewrite_files(&prog, &errs, None, false, 0.5, &mut sink);
        let from_file = program_of(&out, &sink);
        let mut sink = Collect::default();
        let out = rewrite(
            PROGRAM,
            "p.nc",
            LocationErrors::paper(),
            MachineConstants::default(),
            0.5,
            &mut sink,
        );
        assert_eq!(from_file, program_of(&out, &sink));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A stopped cycle's result (no report) and a whole one read back as the same type,
    /// so the summary reads what the store keeps.
    #[test]
    fn a_stopped_and_a_whole_cycles_results_read_back() {
        let stopped = RotaryMeasureResult {
            name: "table".into(),
            kept_as: None,
            report: None,
            balls_measured: Some(3),
            probe_touches: Some(31),
        };
        let v = serde_json::to_value(&stopped).unwrap();
        assert_eq!(
            v,
            serde_json::json!({"name": "table", "balls_measured": 3, "probe_touches": 31})
        );
        let back: RotaryMeasureResult = serde_json::from_value(v).unwrap();
        assert_eq!(back, stopped);
        assert!(measure_summary(&back).contains("stopped after 3 balls"));

        let rows = rotary::parse_centres(include_str!(
            "../../../tests/fuzz/corpus/rotary_centres/paper.csv"
        ))
        .unwrap();
        let constants = MachineConstants::default();
        let id = identify_errors(&rows, &constants).unwrap();
        let identification = RotaryIdentifyResult::new(&id, &constants);
        let whole = RotaryMeasureResult {
            name: "table".into(),
            kept_as: Some("errors.json".into()),
            report: Some(CycleReport {
                identification,
                c_centre: None,
                cycle: CycleFigures {
                    balls: 20,
                    probe_points: 103,
                    probe_touches: 206,
                    simulated_time_s: None,
                    wall_time_s: Some(600.0),
                },
                truth: None,
                compensation_check: None,
            }),
            balls_measured: None,
            probe_touches: None,
        };
        let v = serde_json::to_value(&whole).unwrap();
        assert_eq!(v["delta_ZA_mm"], serde_json::json!(id.errors.delta_za_mm));
        assert_eq!(v["cycle"]["wall_time_s"], 600.0);
        let back: RotaryMeasureResult = serde_json::from_value(v).unwrap();
        assert_eq!(back, whole);
        assert!(measure_summary(&back).contains("cycle: 20 balls, 103 probe points"));
    }

    /// The typed results' schemas (rotary, volumetric, layout, cut, export) are whole:
    /// their nested types inlined, no `$ref` to a component nobody carries.
    #[test]
    fn the_typed_results_schemas_are_whole() {
        let typed = [
            "rotary",
            "rotary-identify",
            "rotary-rewrite",
            "volumetric-identify",
            "volumetric-eval",
            "volumetric-contributions",
            "volumetric-campaign",
            "volumetric-export-isg",
            "layout",
            "cut",
            "export",
        ];
        for name in typed {
            let kind = crate::kinds::find(name).unwrap();
            let schema = serde_json::to_string(&kind.result_schema()).unwrap();
            assert!(schema.len() > 100, "{name}: {schema}");
            assert!(!schema.contains("$ref"), "{name}: {schema}");
        }
    }

    fn errors_file(machine: Option<MachineConstants>) -> String {
        let mut v = serde_json::to_value(LocationErrors::paper()).unwrap();
        if let Some(k) = machine {
            v["machine"] = serde_json::to_value(k).unwrap();
        }
        v.to_string()
    }

    fn program_of(out: &Outcome<RotaryRewriteResult>, sink: &Collect) -> String {
        assert!(out.is_success(), "{:?}", out.error());
        String::from_utf8(sink.0[0].bytes.clone()).unwrap()
    }

    /// The constants recorded with the errors are the rewrite's (the built-in ones put
    /// the tool off on another machine); another `--machine` is refused naming the
    /// difference, unless forced.
    #[test]
    fn the_errors_files_machine_constants_are_used() {
        let other = MachineConstants {
            ac_offset_z_mm: 80.0,
            ..MachineConstants::default()
        };
        let run = |machine, force| {
            let mut sink = Collect::default();
            let out = rewrite_with_errors_file(
                PROGRAM,
                "p.nc",
                &errors_file(Some(other)),
                "errors.json",
                machine,
                force,
                0.5,
                &mut sink,
            );
            (out, sink)
        };
        let (out, sink) = run(None, false);
        let stored = program_of(&out, &sink);
        let mut sink = Collect::default();
        let direct = rewrite(
            PROGRAM,
            "p.nc",
            LocationErrors::paper(),
            other,
            0.5,
            &mut sink,
        );
        assert_eq!(stored, program_of(&direct, &sink));
        let mut sink = Collect::default();
        let builtin = rewrite(
            PROGRAM,
            "p.nc",
            LocationErrors::paper(),
            MachineConstants::default(),
            0.5,
            &mut sink,
        );
        let builtin = program_of(&builtin, &sink);
        assert_ne!(stored, builtin);

        let (out, sink) = run(Some(MachineConstants::default()), false);
        let e = out.error().unwrap();
        assert!(
            e.starts_with("errors.json: the errors were identified on other machine constants (ac_offset_z_mm 80 in the errors file, 60 given)"),
            "{e}"
        );
        assert!(sink.0.is_empty());
        let (out, sink) = run(Some(MachineConstants::default()), true);
        assert_eq!(
            program_of(&out, &sink),
            builtin,
            "forced: the given constants"
        );
    }
}

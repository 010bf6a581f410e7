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
use serde_json::{json, Value};
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
/// result is the report (`runner::rotary::cycle_report`) with `name`, `kept_as`.
pub async fn measure(
    request: &RotaryRequest,
    job: &RotaryJob,
    shelf: &mut dyn ErrorsShelf,
    sink: &mut dyn Sink,
    stop: impl Future<Output = ()>,
) -> Outcome {
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
        let v = json!({"axis": b.axis.to_string(), "step": b.step, "angle_deg": b.angle_deg,
            "ball": b.ball, "centre_mm": b.sphere.centre, "radius_mm": b.sphere.radius_mm,
            "rms_um": b.sphere.rms_mm * 1e3, "points": b.points});
        if let Err(e) = sink.measurement(&v) {
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
        let result = json!({"name": request.name, "balls_measured": m.balls.len(), "probe_touches": m.probe_touches});
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
    let mut report = match runner::rotary::cycle_report(&run, m, &identified, &constants) {
        Ok(r) => r,
        Err(e) => return Outcome::failed(format!("the report: {e}")),
    };
    if let Err(e) = sweep_chart(&rows, &identified, sink) {
        return Outcome::failed(e);
    }
    let kept_as = match shelf.keep(&request.name, &report) {
        Ok(k) => k,
        Err(e) => return Outcome::failed(format!("the errors were identified but not kept: {e}")),
    };
    let obj = report.as_object_mut().expect("an object");
    obj.insert("name".into(), json!(request.name));
    obj.insert("kept_as".into(), json!(kept_as));
    let mut metrics = serde_json::Map::new();
    for (error, v) in identified.errors.named() {
        metrics.insert(error.into(), json!(v));
    }
    metrics.insert("balls".into(), json!(m.balls.len()));
    Outcome::succeeded(report, metrics)
}

/// The eight errors from ball centres measured elsewhere (a CMM, as in the paper): the
/// centres file's text in, the identification as the result, the sweep chart as
/// artifacts.
pub fn identify(
    centres: &str,
    source: &str,
    constants: &MachineConstants,
    sink: &mut dyn Sink,
) -> Outcome {
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
        runner::rotary::identification_json(&id, constants),
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
) -> Outcome {
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
) -> Outcome {
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
) -> Outcome {
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
        json!({
            "lines": report.lines,
            "moves": report.moves,
            "pieces_added": report.pieces_added,
            "max_correction_xyz_mm": max_xyz,
            "max_correction_ac_deg": max_ac,
        }),
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
    type Result = Value;
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

    async fn run(request: RotaryRequest, cx: &mut dyn crate::Context) -> Outcome {
        let stop = cx.stop();
        let job = crate::or_fail!(cx.rotary_job());
        let mut shelf = crate::or_fail!(cx.errors_shelf());
        measure(&request, &job, shelf.as_mut(), cx.sink(), stop.requested()).await
    }

    fn summary(result: &Value) -> String {
        summary(result)
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
    type Result = Value;
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

    async fn run(request: RotaryIdentifyRequest, cx: &mut dyn crate::Context) -> Outcome {
        let constants = request.machine.unwrap_or_default();
        identify(
            &request.centres,
            &request.centres_name,
            &constants,
            cx.sink(),
        )
    }

    fn summary(result: &Value) -> String {
        summary(result)
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
    type Result = Value;
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

    async fn run(r: RotaryRewriteRequest, cx: &mut dyn crate::Context) -> Outcome {
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

    fn summary(result: &Value) -> String {
        summary(result)
    }
}

/// An identification or a cycle's report as text (the CLI's output without `--json`).
pub fn summary(r: &Value) -> String {
    use std::fmt::Write;
    let mut t = String::new();
    let n = |v: &Value| v.as_f64().unwrap_or(f64::NAN);
    if let Some(c) = r.get("c_centre") {
        let _ = writeln!(
            t,
            "C centre on the rim: ({:.4}, {:.4}) mm, ({:+.4}, {:+.4}) mm from the nominal axis, rim radius {:.4} mm",
            n(&c["x_mm"]), n(&c["y_mm"]), n(&c["offset_mm"][0]), n(&c["offset_mm"][1]), n(&c["rim_radius_mm"])
        );
    }
    let names: Vec<&str> = LocationErrors::default()
        .named()
        .iter()
        .map(|(name, _)| *name)
        .collect();
    match r.get("truth") {
        None => {
            let _ = writeln!(t, "{:<14} {:>12} {:>12}", "error", "value", "u (k=1)");
            for name in &names {
                let _ = writeln!(
                    t,
                    "{name:<14} {:>12.6} {:>12.6}",
                    n(&r[*name]),
                    n(&r["uncertainty"][*name])
                );
            }
        }
        Some(truth) => {
            let _ = writeln!(
                t,
                "{:<14} {:>12} {:>12} {:>12} {:>10}",
                "error", "injected", "identified", "difference", "u (k=1)"
            );
            for name in &names {
                let c = &truth[*name];
                let _ = writeln!(
                    t,
                    "{name:<14} {:>12.6} {:>12.6} {:>12.6} {:>10.6}",
                    n(&c["injected"]),
                    n(&c["identified"]),
                    n(&c["difference"]),
                    n(&r["uncertainty"][*name])
                );
            }
        }
    }
    for c in r["circles"].as_array().into_iter().flatten() {
        let _ = writeln!(
            t,
            "circle {} ball {}: radius {:.4} mm, rms {:.3} um radial, {:.3} um out of plane, {} centres",
            c["axis"].as_str().unwrap_or("?"), c["ball"], n(&c["radius_mm"]),
            n(&c["rms_radial_um"]), n(&c["rms_plane_um"]), c["points"]
        );
    }
    for (name, key) in [("C", "c_axis"), ("A", "a_axis")] {
        if let Some(line) = r.get(key) {
            let _ = writeln!(
                t,
                "{name} axis: circle centres {:.3} mm apart, their line {:.5} deg from the normals",
                n(&line["centre_separation_mm"]),
                n(&line["centre_line_deviation_deg"])
            );
        }
    }
    if let Some(cycle) = r.get("cycle") {
        let (clock, time_s) = match cycle.get("simulated_time_s") {
            Some(s) => ("simulated machine time ", n(s)),
            None => ("", n(&cycle["wall_time_s"])),
        };
        let _ = writeln!(
            t,
            "cycle: {} balls, {} probe points ({} touches), {clock}{:.1} min",
            cycle["balls"],
            cycle["probe_points"],
            cycle["probe_touches"],
            time_s / 60.0
        );
    }
    if let Some(c) = r.get("compensation_check") {
        let _ = writeln!(
            t,
            "compensated 5-axis program ({} poses, A 2..90°, C all round), against the truth:",
            c["poses"]
        );
        let _ = writeln!(
            t,
            "  tool tip   max {:.4} mm -> {:.5} mm ({:.1} % better), mean {:.4} -> {:.5}",
            n(&c["tip_max_before_mm"]),
            n(&c["tip_max_after_mm"]),
            n(&c["tip_improvement_pct"]),
            n(&c["tip_mean_before_mm"]),
            n(&c["tip_mean_after_mm"])
        );
        let _ = writeln!(
            t,
            "  direction  max {:.6} rad -> {:.7} rad ({:.1} % better)",
            n(&c["direction_max_before_rad"]),
            n(&c["direction_max_after_rad"]),
            n(&c["direction_improvement_pct"])
        );
    }
    if r.get("lines").is_some() {
        let _ = writeln!(
            t,
            "{} lines, {} moves rewritten, {} pieces added; largest correction {:.4} mm, {:.5} deg",
            r["lines"],
            r["moves"],
            r["pieces_added"],
            n(&r["max_correction_xyz_mm"]),
            n(&r["max_correction_ac_deg"])
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

    fn errors_file(machine: Option<MachineConstants>) -> String {
        let mut v = serde_json::to_value(LocationErrors::paper()).unwrap();
        if let Some(k) = machine {
            v["machine"] = serde_json::to_value(k).unwrap();
        }
        v.to_string()
    }

    fn program_of(out: &Outcome, sink: &Collect) -> String {
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

//! The ISO 230-2 positioning test of one axis: the measuring line chosen, the cycle run
//! (compensated by a map when one is given), evaluated, charted and reported; and the
//! evaluation of a measurements file from any instrument.

use crate::command_line::{self, FileArg};
use crate::request::Iso230Request;
use crate::{Artifact, Outcome, Sink};
use devices::Devices;
use errormap::MapModel;
use iso230::plan::{targets, Cycle};
use iso230::report::{html, DeviationChart, Series, Tested};
use iso230::{csv_io, evaluate, AxisFigures, Evaluation, Measurement, Uncertainty};
use job::Job;
use protocol::errormap::ErrorMap;
use runner::iso230::{run_iso230, test_area, Iso230Error, Iso230Spec, AXIS_NAMES};
use runner::JobError;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::cell::{Cell, RefCell};
use std::future::Future;
use std::time::Instant;

/// The measurements file: grown a row at a time while the cycle runs
/// ([`crate::LogRow`]), written whole at its end.
pub const MEASUREMENTS_ARTIFACT: &str = "measurements.csv";

/// A measurements file read through the bounded reader ([`DataKind::Iso230`]) and
/// parsed: errors name the file, and the line and column where the parser fails.
pub fn read_measurements_file(path: &std::path::Path) -> Result<Vec<Measurement>, crate::Error> {
    let text = protocol::config::read_kind(path, protocol::config::DataKind::Iso230)?;
    csv_io::read(&text).map_err(|e| crate::Error::input(path.display(), e))
}

/// Still frames at the reference point for the localization's repeatability.
const STILL_FRAMES: usize = 10;

/// An ISO 230-2 test on the machine: its evaluation, or (stopped) how far it got.
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(untagged)]
pub enum Iso230Result {
    /// The test ran to its end and was evaluated.
    Evaluated(#[schema(inline)] Box<Iso230Report>),
    /// It stopped: the measurements taken are kept.
    Stopped(#[schema(inline)] Iso230Stopped),
}

/// How far a stopped test got.
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Iso230Stopped {
    /// Measurements taken (kept, and in the growing measurements file).
    pub measurements_taken: usize,
    /// Measurements the cycle plans.
    pub measurements_planned: u64,
}

/// An evaluated ISO 230-2 test (also `result.json`): the evaluation, the test on the
/// machine when it was measured here, and the `before` test overlaid.
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Iso230Report {
    #[serde(flatten)]
    #[schema(inline)]
    pub evaluation: Iso230Evaluation,
    /// The test on the machine (absent: measurements from a file evaluated).
    #[serde(flatten)]
    #[schema(inline)]
    pub test: Option<Iso230Test>,
    /// The test before compensation, overlaid on the charts.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(inline)]
    pub before: Option<Box<Iso230Evaluation>>,
}

/// The evaluation of one axis, named as in the standard (um; per target position
/// `i` in order of increasing target).
#[allow(non_snake_case)]
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Iso230Evaluation {
    /// `ISO 230-2`.
    pub standard: String,
    /// The axis name (`X`, `Y`, ...).
    pub axis: String,
    /// Target positions.
    pub positions: usize,
    /// i, from 1.
    pub position_index: Vec<usize>,
    /// P_i, mm.
    pub target_mm: Vec<f64>,
    /// Runs up and down at each position.
    pub runs_up: Vec<usize>,
    pub runs_down: Vec<usize>,
    /// Mean deviation up, down and both ways.
    pub mean_up_um: Vec<f64>,
    pub mean_down_um: Vec<f64>,
    pub mean_um: Vec<f64>,
    /// Standard deviation up and down.
    pub s_up_um: Vec<f64>,
    pub s_down_um: Vec<f64>,
    /// Reversal value B_i.
    pub B_i_um: Vec<f64>,
    /// Repeatability up, down and bidirectional.
    pub R_up_i_um: Vec<f64>,
    pub R_down_i_um: Vec<f64>,
    pub R_i_um: Vec<f64>,
    /// The measuring uncertainty of one deviation (`certificate_um`,
    /// `localization_s_um`, `localization_frames`, `expanded_um`); null: measurements
    /// from a file (their instrument's is not known here).
    #[schema(value_type = Option<Object>)]
    pub uncertainty: Option<Uncertainty>,
    /// The axis figures.
    #[serde(flatten)]
    #[schema(inline)]
    pub figures: Iso230Figures,
}

/// The axis figures, named as in the standard, um.
#[allow(non_snake_case)]
#[derive(Debug, Clone, Copy, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Iso230Figures {
    /// Accuracy A, up and down.
    pub A_um: f64,
    pub A_up_um: f64,
    pub A_down_um: f64,
    /// Largest reversal value B.
    pub B_um: f64,
    /// Mean reversal value.
    pub mean_reversal_um: f64,
    /// Repeatability R, up and down.
    pub R_um: f64,
    pub R_up_um: f64,
    pub R_down_um: f64,
    /// Systematic positioning error E, up and down.
    pub E_um: f64,
    pub E_up_um: f64,
    pub E_down_um: f64,
    /// Mean positioning error M.
    pub M_um: f64,
}

/// How a test was run on the machine.
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Iso230Test {
    /// The error map it ran with (null: without compensation).
    pub map: Option<String>,
    /// The cycle: linear or pilgrim-step.
    pub cycle: String,
    /// Runs in each direction.
    pub runs: usize,
    /// How far past the end targets the axis went, mm.
    pub overrun_mm: f64,
    /// Where the other axis stood, mm.
    pub across_mm: f64,
    /// Measurements taken.
    pub measurements: usize,
    /// The simulated machine's time of the whole run, s (null on a real machine).
    pub machine_time_s: Option<f64>,
    /// The run's wall time, s.
    pub wall_time_s: f64,
}

impl Iso230Evaluation {
    /// `e` (with the uncertainty of its deviations when known) in the standard's names.
    pub fn of(e: &Evaluation, uncertainty: Option<&Uncertainty>) -> Self {
        let p = &e.positions;
        let col = |f: fn(&iso230::PositionFigures) -> f64| p.iter().map(f).collect::<Vec<f64>>();
        Self {
            standard: "ISO 230-2".into(),
            axis: e.axis.clone(),
            positions: p.len(),
            position_index: p.iter().map(|q| q.position_index).collect(),
            target_mm: col(|q| q.target_mm),
            runs_up: p.iter().map(|q| q.runs_up).collect(),
            runs_down: p.iter().map(|q| q.runs_down).collect(),
            mean_up_um: col(|q| q.mean_up_um),
            mean_down_um: col(|q| q.mean_down_um),
            mean_um: col(|q| q.mean_um),
            s_up_um: col(|q| q.s_up_um),
            s_down_um: col(|q| q.s_down_um),
            B_i_um: col(|q| q.reversal_um),
            R_up_i_um: col(|q| q.r_up_um),
            R_down_i_um: col(|q| q.r_down_um),
            R_i_um: col(|q| q.r_um),
            uncertainty: uncertainty.copied(),
            figures: Iso230Figures::of(&e.figures),
        }
    }
}

impl Iso230Figures {
    pub fn of(f: &AxisFigures) -> Self {
        Self {
            A_um: f.a,
            A_up_um: f.a_up,
            A_down_um: f.a_down,
            B_um: f.b,
            mean_reversal_um: f.mean_reversal,
            R_um: f.r,
            R_up_um: f.r_up,
            R_down_um: f.r_down,
            E_um: f.e,
            E_up_um: f.e_up,
            E_down_um: f.e_down,
            M_um: f.m,
        }
    }
}

/// One measurement as the sink gets it (a row of the measurements file).
#[derive(Serialize)]
struct MeasurementRow<'a> {
    axis: &'a str,
    position_index: usize,
    target_mm: f64,
    run: usize,
    /// `+` or `-`.
    direction: &'static str,
    deviation_um: f64,
}

/// An error map given to a test: the map and how messages name it (a file, a profile).
pub struct NamedMap {
    pub map: ErrorMap,
    pub name: String,
}

/// The charts, `result.json` and `report.html` of an evaluation (and of the `before`
/// test overlaid), as artifacts; returns the result object (with `test`, how it ran on
/// the machine when it did).
pub fn outputs(
    evaluation: &Evaluation,
    uncertainty: Option<&Uncertainty>,
    before: Option<&Evaluation>,
    label: &str,
    notes: &[String],
    test: Option<Iso230Test>,
    sink: &mut dyn Sink,
) -> Result<Iso230Report, crate::Error> {
    let result = Iso230Report {
        evaluation: Iso230Evaluation::of(evaluation, uncertainty),
        test,
        before: before.map(|b| Box::new(Iso230Evaluation::of(b, None))),
    };
    let axis = &evaluation.axis;
    let mut charts = vec![(
        format!("deviation_{}", axis.to_lowercase()),
        DeviationChart {
            title: format!("ISO 230-2 axis {axis}: mean deviation and ±2s, {label}"),
            series: vec![Series {
                label: "",
                evaluation,
            }],
        },
    )];
    if let Some(b) = before {
        charts.push((
            format!("before_after_{}", axis.to_lowercase()),
            DeviationChart {
                title: format!("ISO 230-2 axis {axis}: before and {label}"),
                series: vec![
                    Series {
                        label: "before",
                        evaluation: b,
                    },
                    Series { label, evaluation },
                ],
            },
        ));
    }
    let mut svgs = Vec::new();
    for (name, chart) in &charts {
        let failed = |e| crate::Error::Output(format!("{name}: {e}"));
        let svg = plot::render_svg(chart, 900, 520).map_err(failed)?;
        let png = plot::render_png(chart, 900, 520).map_err(failed)?;
        sink.artifact(Artifact {
            name: format!("{name}.svg"),
            title: Some(chart.title.clone()),
            media_type: "image/svg+xml",
            bytes: svg.clone().into_bytes(),
        })?;
        sink.artifact(Artifact {
            name: format!("{name}.png"),
            title: None,
            media_type: "image/png",
            bytes: png,
        })?;
        svgs.push(svg);
    }
    let mut tested = Vec::new();
    if let Some(b) = before {
        tested.push(Tested {
            label: "before",
            evaluation: b,
            uncertainty: None,
        });
    }
    tested.push(Tested {
        label,
        evaluation,
        uncertainty,
    });
    let report = html(
        &format!("ISO 230-2 positioning test, axis {axis}"),
        &tested,
        &svgs,
        notes,
    );
    sink.artifact(Artifact {
        name: "report.html".into(),
        title: None,
        media_type: "text/html",
        bytes: report.into_bytes(),
    })?;
    sink.artifact(Artifact {
        name: "result.json".into(),
        title: None,
        media_type: "application/json",
        bytes: (serde_json::to_string_pretty(&result).unwrap_or_default() + "\n").into_bytes(),
    })?;
    Ok(result)
}

/// Evaluates measurements from any instrument (and a `before` test overlaid).
pub fn evaluate_measurements(
    measurements: &[Measurement],
    before: Option<&[Measurement]>,
    source: &str,
    sink: &mut dyn Sink,
) -> Outcome<Iso230Report> {
    let evaluation = match evaluate(measurements) {
        Ok(e) => e,
        Err(e) => return Outcome::failed(format!("{source}: {e}")),
    };
    let before = match before.map(evaluate).transpose() {
        Ok(b) => b,
        Err(e) => return Outcome::failed(format!("the before test: {e}")),
    };
    let label = if before.is_some() {
        "after"
    } else {
        "measured"
    };
    match outputs(
        &evaluation,
        None,
        before.as_ref(),
        label,
        &[format!("Evaluated from {source}.")],
        None,
        sink,
    ) {
        Ok(result) => {
            let metrics = figures_metrics(&evaluation);
            Outcome::succeeded(result, metrics)
        }
        Err(e) => Outcome::failed(e),
    }
}

fn figures_metrics(e: &Evaluation) -> serde_json::Map<String, Value> {
    let f = &e.figures;
    let mut metrics = serde_json::Map::new();
    metrics.insert("axis".into(), e.axis.clone().into());
    for (k, v) in [
        ("A_um", f.a),
        ("B_um", f.b),
        ("R_um", f.r),
        ("E_um", f.e),
        ("M_um", f.m),
    ] {
        metrics.insert(k.into(), v.into());
    }
    metrics
}

/// Runs the test on the machine. With `map`, every target is commanded through it
/// (refused before any motion if the map was measured on another machine); `before`
/// is a test of the same axis without compensation, overlaid on the charts. Each
/// measurement goes to the sink as it is taken (and as a row of
/// [`MEASUREMENTS_ARTIFACT`]'s log), then the evaluation, charts and report as artifacts.
pub async fn run(
    request: &Iso230Request,
    job: &Job,
    devices: &mut Devices,
    map: Option<NamedMap>,
    before: Option<&[Measurement]>,
    sink: &mut dyn Sink,
    stop: impl Future<Output = ()>,
) -> Outcome<Iso230Result> {
    let started = Instant::now();
    let axis = request.axis.index();
    if request.with_map != map.is_some() {
        return Outcome::failed(if request.with_map {
            "with_map: no error map was given"
        } else {
            "an error map was given but with_map is false"
        });
    }
    let map_name = map.as_ref().map(|m| m.name.clone());
    let model = match map {
        Some(m) => {
            if let Err(e) = crate::check_identity(&m.map, &crate::identity(job, devices), &m.name) {
                return Outcome::failed(e);
            }
            Some(MapModel::new(m.map))
        }
        None => None,
    };
    let before = match before.map(evaluate).transpose() {
        Ok(b) => b,
        Err(e) => return Outcome::failed(format!("the before test: {e}")),
    };
    let limits = match runner::soft_limits(devices.stage.info()) {
        Ok(l) => l,
        Err(e) => return Outcome::failed(e.to_string()),
    };
    let (mut lo, mut hi) = test_area(job, &limits, request.overrun_mm);
    if let Some(m) = &model {
        let (mlo, mhi) = m.extent();
        for k in 0..2 {
            lo[k] = lo[k].max(mlo[k]);
            hi[k] = hi[k].min(mhi[k]);
        }
    }
    let from = request.from_mm.unwrap_or(lo[axis]);
    let to = request.to_mm.unwrap_or(hi[axis]);
    if from < lo[axis] - 1e-9 || to > hi[axis] + 1e-9 {
        return Outcome::failed(format!(
            "{}: the segment {from:.3} .. {to:.3} mm leaves the usable travel of {} ({:.3} .. {:.3} mm: the limits less the overrun, the board{})",
            if request.from_mm.is_some() && from < lo[axis] - 1e-9 { "from_mm" } else { "to_mm" },
            AXIS_NAMES[axis],
            lo[axis],
            hi[axis],
            if model.is_some() { ", the map" } else { "" }
        ));
    }
    // Held where the map has its dense line along the axis (the short-period errors are
    // known best there), else in the middle.
    let map_line = model.as_ref().and_then(|m| {
        let lines = if axis == 0 {
            &m.map().x_lines
        } else {
            &m.map().y_lines
        };
        lines.first().map(|l| l.at_mm)
    });
    let across = request
        .at_mm
        .or(map_line)
        .unwrap_or((lo[1 - axis] + hi[1 - axis]) / 2.0);
    let positions = request.positions.map(|n| n as usize);
    let cycle = match targets(from, to, positions).and_then(|t| {
        Cycle::new(
            t,
            request.runs as usize,
            request.overrun_mm,
            request.cycle.kind(),
        )
    }) {
        Ok(c) => c,
        Err(e) => return Outcome::failed(format!("positions: {e}")),
    };
    let spec = Iso230Spec {
        axis,
        cycle: cycle.clone(),
        across_mm: across,
        still_frames: STILL_FRAMES,
    };
    let total = cycle.measurements() as u64;
    sink.progress(0, total);
    let cancelled = Cell::new(false);
    let mut taken = 0usize;
    let mut sink_error: Option<crate::Error> = None;
    // Measurements and progress both go to the one sink, as they come.
    let shared_sink = RefCell::new(&mut *sink);
    let run = run_iso230(
        job,
        devices,
        &spec,
        model.as_ref(),
        &mut |m: &Measurement| {
            taken += 1;
            let row = MeasurementRow {
                axis: &m.axis,
                position_index: m.position_index,
                target_mm: m.target_mm,
                run: m.run,
                direction: m.direction.sign(),
                deviation_um: m.deviation_um,
            };
            let text = csv_io::write(std::slice::from_ref(m));
            let (header, rows) = text.split_once('\n').unwrap_or((&text, ""));
            let log = crate::LogRow {
                log: MEASUREMENTS_ARTIFACT,
                header: &format!("{header}\n"),
                row: rows,
            };
            let mut sink = shared_sink.borrow_mut();
            let kept = serde_json::to_value(&row)
                .map_err(|e| crate::Error::Output(format!("a measurement: {e}")))
                .and_then(|row| sink.measurement(&row))
                .and_then(|()| sink.log_row(&log));
            if let Err(e) = kept {
                sink_error.get_or_insert(e);
            }
        },
        &mut |done, of| shared_sink.borrow_mut().progress(done as u64, of as u64),
        async {
            stop.await;
            cancelled.set(true);
        },
    )
    .await;
    let run = match run {
        Ok(r) => r,
        Err(e) => {
            let lost = matches!(
                e,
                Iso230Error::Reference(JobError::Driver(_))
                    | Iso230Error::Move(JobError::Driver(_))
                    | Iso230Error::Measure {
                        source: JobError::Driver(_),
                        ..
                    }
            );
            let result = Iso230Result::Stopped(Iso230Stopped {
                measurements_taken: taken,
                measurements_planned: total,
            });
            let error = format!("{e}; the {taken} measurements taken are kept");
            return Outcome::stopped(
                cancelled.get(),
                error,
                Some(result),
                Default::default(),
                lost,
            );
        }
    };
    if let Some(e) = sink_error {
        return Outcome::failed(format!("a measurement was not kept: {e}"));
    }
    let evaluation = match evaluate(&run.measurements) {
        Ok(e) => e,
        Err(e) => return Outcome::failed(format!("evaluation: {e}")),
    };
    let uncertainty = Uncertainty::new(request.certificate_uncertainty_um, &run.still_um);
    let machine_time_s = crate::machine_time_s(devices);
    let label = if model.is_some() {
        "with the map"
    } else {
        "without compensation"
    };
    let mut notes = vec![format!(
        "Machine: {}; camera: {}; board: {} (the length reference). Axis {} from {from:.3} to {to:.3} mm at {} = {across:.3} mm, {} positions, {} runs each direction, {} cycle, overrun {} mm; {label}{}.",
        devices.stage.info().name,
        devices.camera.info().model,
        job.board.name,
        AXIS_NAMES[axis],
        AXIS_NAMES[1 - axis],
        cycle.targets_mm.len(),
        cycle.runs,
        request.cycle.as_str(),
        cycle.overrun_mm,
        map_name.as_ref().map(|p| format!(" ({p})")).unwrap_or_default(),
    )];
    if let Some(t) = machine_time_s {
        notes.push(format!(
            "Simulated machine time of the whole run (homing included): {t:.1} s."
        ));
    }
    let test = Iso230Test {
        map: map_name,
        cycle: request.cycle.as_str().into(),
        runs: cycle.runs,
        overrun_mm: cycle.overrun_mm,
        across_mm: across,
        measurements: run.measurements.len(),
        machine_time_s,
        wall_time_s: started.elapsed().as_secs_f64(),
    };
    let csv = Artifact {
        name: MEASUREMENTS_ARTIFACT.into(),
        title: None,
        media_type: "text/csv",
        bytes: csv_io::write(&run.measurements).into_bytes(),
    };
    if let Err(e) = sink.artifact(csv) {
        return Outcome::failed(e);
    }
    match outputs(
        &evaluation,
        Some(&uncertainty),
        before.as_ref(),
        label,
        &notes,
        Some(test),
        sink,
    ) {
        Ok(result) => Outcome::succeeded(
            Iso230Result::Evaluated(Box::new(result)),
            figures_metrics(&evaluation),
        ),
        Err(e) => Outcome::failed(e),
    }
}

/// A measurements file's text parsed (`what` names it in errors).
fn measurements_of(text: &str, what: &str) -> Result<Vec<Measurement>, crate::Error> {
    if text.len() as u64 > protocol::config::DataKind::Iso230.max_bytes() {
        return Err(crate::Error::Refused(format!(
            "{what}: {} bytes; at most {} are accepted",
            text.len(),
            protocol::config::DataKind::Iso230.max_bytes()
        )));
    }
    csv_io::read(text).map_err(|e| crate::Error::input(what, e))
}

/// The ISO 230-2 test on the machine as a registered procedure (with the map when the
/// request says `with_map`).
pub struct Iso230;

impl crate::registry::Procedure for Iso230 {
    const KIND: &'static str = "iso230";
    const TITLE: &'static str =
        "ISO 230-2 positioning test of one axis, with or without the error map";
    const COMMAND: &'static str = "iso230";
    const LABEL: &'static str = "ISO 230-2 axis test";
    const HELP: &'static str = "Positioning test of one axis to ISO 230-2: accuracy, repeatability and reversal, with the deviation chart.";
    const FIELD_HELP: &'static [(&'static str, &'static str)] = &[
        ("axis", "The axis to test."),
        (
            "positions",
            "Target positions along the axis. Empty: the standard's minimum.",
        ),
        ("runs", "Runs in each direction."),
        ("cycle", "Linear, or pilgrim-step."),
        (
            "overrun_mm",
            "How far past the end targets the axis goes before turning back.",
        ),
        (
            "from_mm",
            "Start of the tested travel, machine coordinates. Empty: the usable travel's start.",
        ),
        (
            "to_mm",
            "End of the tested travel, machine coordinates. Empty: the usable travel's end.",
        ),
        (
            "at_mm",
            "Where the other axis stays, machine coordinates. Empty: chosen for you.",
        ),
        (
            "certificate_uncertainty_um",
            "The board certificate's uncertainty of a dot position.",
        ),
        (
            "with_map",
            "Test with the active error map correcting the moves.",
        ),
    ];
    const USES: crate::registry::Uses = crate::registry::Uses {
        devices: true,
        map: crate::registry::MapUse::WhenAsked,
        rotary: false,
        link: false,
    };
    type Request = Iso230Request;
    type Result = Iso230Result;
    const FILES: &'static [FileArg] = &[
        FileArg::required(
            "config",
            "The job (stage, camera, board) to test.",
            command_line::job,
        ),
        FileArg::flag(
            "map",
            "Test with this error map active (the same test, compensated).",
            |path, plan| {
                plan.set("with_map", true);
                command_line::map(path, plan)
            },
        ),
        FileArg::required(
            "out",
            "Output folder: measurements.csv, result.json, charts (SVG, PNG), report.html.",
            command_line::out_folder,
        ),
        FileArg::flag(
            "before",
            "A measurements file of the same test before compensation, overlaid on the charts.",
            |path, plan| plan.text(path, "before", None, read_measurements),
        ),
    ];
    const STEPS: &'static str = "measurements";

    async fn run(request: Iso230Request, cx: &mut dyn crate::Context) -> Outcome<Iso230Result> {
        let stop = cx.stop();
        let map = match request.with_map {
            false => None,
            true => match cx.map() {
                Ok(m) => Some(NamedMap {
                    map: m.map,
                    name: m.name,
                }),
                Err(e) => return Outcome::failed(format!("with_map: {e}")),
            },
        };
        let before = match request.before.as_deref() {
            Some(text) => match measurements_of(text, "before") {
                Ok(m) => Some(m),
                Err(e) => return Outcome::failed(e),
            },
            None => None,
        };
        let bench = crate::or_fail!(cx.bench().await);
        run(
            &request,
            bench.job,
            bench.devices,
            map,
            before.as_deref(),
            bench.sink,
            stop.requested(),
        )
        .await
    }

    fn summary(result: &Iso230Result) -> String {
        match result {
            Iso230Result::Evaluated(r) => summary(r),
            Iso230Result::Stopped(s) => format!(
                "stopped after {} of {} measurements (kept)\n",
                s.measurements_taken, s.measurements_planned
            ),
        }
    }

    fn uses_map(request: &Iso230Request) -> bool {
        request.with_map
    }
}

/// A measurements file's text, bounded.
fn read_measurements(path: &std::path::Path) -> Result<String, crate::Error> {
    Ok(protocol::config::read_kind(
        path,
        protocol::config::DataKind::Iso230,
    )?)
}

/// An evaluation of measurements from any instrument.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields)]
pub struct Iso230EvaluateRequest {
    /// The measurements file (`axis,position_index,target_mm,run,direction,deviation_um`).
    #[schema(format = Binary, max_length = 16777216)]
    #[cfg_attr(feature = "cli", arg(skip))]
    pub measurements: String,
    /// How messages name it (its file name).
    #[serde(default = "default_measurements_name")]
    #[schema(default = default_measurements_name)]
    #[cfg_attr(feature = "cli", arg(skip = default_measurements_name()))]
    pub measurements_name: String,
    /// A test of the same axis before compensation, overlaid on the charts.
    #[serde(default)]
    #[schema(format = Binary, max_length = 16777216)]
    #[cfg_attr(feature = "cli", arg(skip))]
    pub before: Option<String>,
}

fn default_measurements_name() -> String {
    "measurements.csv".into()
}

impl crate::registry::Checked for Iso230EvaluateRequest {
    fn check(&self) -> Result<(), crate::RequestError> {
        let max = protocol::config::DataKind::Iso230.max_bytes();
        for (field, text) in [
            ("measurements", Some(&self.measurements)),
            ("before", self.before.as_ref()),
        ] {
            if text.is_some_and(|t| t.len() as u64 > max) {
                return Err(crate::RequestError::new(
                    field,
                    format!("at most {max} bytes are accepted"),
                ));
            }
        }
        Ok(())
    }
}

/// The evaluation of a measurements file as a registered procedure.
pub struct Iso230Evaluate;

impl crate::registry::Procedure for Iso230Evaluate {
    const KIND: &'static str = "iso230-evaluate";
    const TITLE: &'static str =
        "ISO 230-2 evaluation of measurements from any instrument (a laser, a probe)";
    const COMMAND: &'static str = "iso230 evaluate";
    const LABEL: &'static str = "ISO 230-2 evaluation of a file";
    const HELP: &'static str = "Evaluates a measurements file from any instrument (a laser, the camera) to ISO 230-2: accuracy, repeatability and reversal in each direction, with the deviation chart and a report. The machine does not move.";
    const FIELD_HELP: &'static [(&'static str, &'static str)] = &[
        ("measurements", "The measurements file: one row per reading (axis, position index, target, run, direction, deviation in µm)."),
        ("before", "The same test before compensation, drawn on the charts for comparison (optional)."),
    ];
    const USES: crate::registry::Uses = crate::registry::Uses::NOTHING;
    type Request = Iso230EvaluateRequest;
    type Result = Iso230Report;
    const FILES: &'static [FileArg] = &[
        FileArg::positional(
            "file",
            "The measurements file (axis,position_index,target_mm,run,direction,deviation_um).",
            |path, plan| {
                plan.text(
                    path,
                    "measurements",
                    Some("measurements_name"),
                    read_measurements,
                )
            },
        ),
        FileArg::flag(
            "out",
            "Write result.json, the charts and report.html here.",
            command_line::artifacts_folder,
        ),
        FileArg::flag(
            "before",
            "A measurements file of the test before compensation, overlaid on the charts.",
            |path, plan| plan.text(path, "before", None, read_measurements),
        ),
    ];

    async fn run(
        request: Iso230EvaluateRequest,
        cx: &mut dyn crate::Context,
    ) -> Outcome<Iso230Report> {
        let name = &request.measurements_name;
        let measurements = match measurements_of(&request.measurements, name) {
            Ok(m) => m,
            Err(e) => return Outcome::failed(e),
        };
        let before = match request.before.as_deref() {
            Some(text) => match measurements_of(text, "before") {
                Ok(m) => Some(m),
                Err(e) => return Outcome::failed(e),
            },
            None => None,
        };
        evaluate_measurements(&measurements, before.as_deref(), name, cx.sink())
    }

    fn summary(result: &Iso230Report) -> String {
        summary(result)
    }
}

/// The figures as text, the before test first (the CLI's output without `--json`).
pub fn summary(r: &Iso230Report) -> String {
    use std::fmt::Write;
    let mut t = String::new();
    let figures = |t: &mut String, e: &Iso230Evaluation, label: &str| {
        let f = &e.figures;
        let _ = writeln!(
            t,
            "axis {} ({label}), {} positions: A {:.3} um (up {:.3}, down {:.3}), B {:.3}, mean reversal {:.3}, R {:.3} (up {:.3}, down {:.3}), E {:.3} (up {:.3}, down {:.3}), M {:.3}",
            e.axis, e.positions,
            f.A_um, f.A_up_um, f.A_down_um, f.B_um, f.mean_reversal_um, f.R_um,
            f.R_up_um, f.R_down_um, f.E_um, f.E_up_um, f.E_down_um, f.M_um
        );
    };
    if let Some(b) = &r.before {
        figures(&mut t, b, "before");
    }
    let label = match (&r.test, r.before.is_some()) {
        (Some(test), _) if test.map.is_some() => "with the map",
        (Some(_), _) => "without compensation",
        (None, true) => "after",
        (None, false) => "measured",
    };
    figures(&mut t, &r.evaluation, label);
    if let Some(test) = &r.test {
        let expanded = (r.evaluation.uncertainty.as_ref()).map_or(f64::NAN, |u| u.expanded_um);
        let _ = writeln!(
            t,
            "uncertainty of one deviation {expanded:.3} um (k = 2); {} measurements{}, {:.1} s",
            test.measurements,
            test.machine_time_s
                .map(|s| format!(", {s:.1} s of machine time"))
                .unwrap_or_default(),
            test.wall_time_s,
        );
    }
    t
}

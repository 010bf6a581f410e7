//! `gateway iso230`: the ISO 230-2 positioning test on a machine (with a progress bar and
//! the measurements written as they come), and `gateway iso230 evaluate` for a
//! measurements file from any instrument. Both write DIR/result.json, the charts as SVG
//! and PNG, and DIR/report.html.

use anyhow::Context;
use devices::open_devices_async;
use errormap::MapModel;
use indicatif::{ProgressBar, ProgressStyle};
use iso230::plan::{targets, Cycle, CycleKind};
use iso230::report::{html, result_json, DeviationChart, Series, Tested};
use iso230::{csv_io, evaluate, Evaluation, Measurement, Uncertainty};
use job::Job;
use protocol::errormap::ErrorMap;
use runner::iso230::{run_iso230, test_area, Iso230Spec, AXIS_NAMES};
use serde_json::json;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

pub struct RunArgs {
    pub config: PathBuf,
    pub axis: String,
    pub map: Option<PathBuf>,
    pub out: PathBuf,
    pub positions: Option<usize>,
    pub runs: usize,
    pub cycle: String,
    pub overrun_mm: f64,
    pub from_mm: Option<f64>,
    pub to_mm: Option<f64>,
    pub at_mm: Option<f64>,
    pub certificate_uncertainty_um: f64,
    pub before: Option<PathBuf>,
    pub json: bool,
}

fn read_measurements(path: &Path) -> anyhow::Result<Vec<Measurement>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    csv_io::read(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// Result JSON, charts and report for `evaluation` (and the `before` test overlaid).
fn write_outputs(
    out: &Path,
    evaluation: &Evaluation,
    uncertainty: Option<&Uncertainty>,
    before: Option<&Evaluation>,
    label: &str,
    notes: &[String],
    extra: serde_json::Value,
) -> anyhow::Result<serde_json::Value> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let mut result = result_json(evaluation, uncertainty);
    if let (Some(o), serde_json::Value::Object(e)) = (result.as_object_mut(), extra) {
        o.extend(e);
    }
    if let (Some(o), Some(b)) = (result.as_object_mut(), before) {
        o.insert("before".into(), result_json(b, None));
    }
    let path = out.join("result.json");
    std::fs::write(&path, serde_json::to_string_pretty(&result)? + "\n")
        .with_context(|| format!("writing {}", path.display()))?;
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
        let svg = plot::render_svg(chart, 900, 520)?;
        let png = plot::render_png(chart, 900, 520)?;
        for (ext, bytes) in [("svg", svg.as_bytes()), ("png", png.as_slice())] {
            let p = out.join(format!("{name}.{ext}"));
            std::fs::write(&p, bytes).with_context(|| format!("writing {}", p.display()))?;
        }
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
    let p = out.join("report.html");
    std::fs::write(&p, report).with_context(|| format!("writing {}", p.display()))?;
    Ok(result)
}

fn print_figures(e: &Evaluation, label: &str) {
    let f = &e.figures;
    println!(
        "axis {} ({label}), {} positions: A {:.3} um (up {:.3}, down {:.3}), B {:.3}, mean reversal {:.3}, R {:.3} (up {:.3}, down {:.3}), E {:.3} (up {:.3}, down {:.3}), M {:.3}",
        e.axis, e.positions.len(), f.a, f.a_up, f.a_down, f.b, f.mean_reversal, f.r, f.r_up, f.r_down, f.e, f.e_up, f.e_down, f.m
    );
}

pub fn evaluate_file(
    file: &Path,
    out: Option<&Path>,
    before: Option<&Path>,
    json_out: bool,
) -> anyhow::Result<ExitCode> {
    let evaluation = evaluate(&read_measurements(file)?)?;
    let before = match before {
        Some(b) => Some(evaluate(&read_measurements(b)?)?),
        None => None,
    };
    let result = match out {
        Some(dir) => write_outputs(
            dir,
            &evaluation,
            None,
            before.as_ref(),
            if before.is_some() {
                "after"
            } else {
                "measured"
            },
            &[format!("Evaluated from {}.", file.display())],
            json!({}),
        )?,
        None => result_json(&evaluation, None),
    };
    if json_out {
        println!("{result}");
    } else {
        if let Some(b) = &before {
            print_figures(b, "before");
        }
        print_figures(
            &evaluation,
            if before.is_some() {
                "after"
            } else {
                "measured"
            },
        );
    }
    Ok(ExitCode::SUCCESS)
}

pub fn run(args: RunArgs) -> anyhow::Result<ExitCode> {
    let started = Instant::now();
    let job = Job::load(&args.config)?;
    let axis = match args.axis.to_ascii_lowercase().as_str() {
        "x" => 0,
        "y" => 1,
        other => anyhow::bail!("--axis `{other}`: expected x or y"),
    };
    let kind: CycleKind = args
        .cycle
        .parse()
        .map_err(|e| anyhow::anyhow!("--cycle {e}"))?;
    if !(args.certificate_uncertainty_um >= 0.0) {
        anyhow::bail!("--certificate-uncertainty-um must be a non-negative number");
    }
    let model = match &args.map {
        Some(path) => {
            let map = ErrorMap::load(path)?;
            // The board and its certificate are the length reference the map was
            // measured against: the test must use the same.
            if map.identity.board != job.board.name
                || map.identity.certificate_sha256 != job.board.fingerprint_sha256()
            {
                anyhow::bail!(
                    "{}: the map was measured with board `{}` (certificate {}), this job uses `{}` ({})",
                    path.display(),
                    map.identity.board,
                    map.identity.certificate_sha256,
                    job.board.name,
                    job.board.fingerprint_sha256()
                );
            }
            Some(MapModel::new(map))
        }
        None => None,
    };
    let before = match &args.before {
        Some(b) => Some(evaluate(&read_measurements(b)?)?),
        None => None,
    };
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    let mut devices = rt.block_on(open_devices_async(&job))?;
    let limits = runner::soft_limits(devices.stage.info())?;
    let (mut lo, mut hi) = test_area(&job, &limits, args.overrun_mm);
    if let Some(m) = &model {
        let (mlo, mhi) = m.extent();
        for k in 0..2 {
            lo[k] = lo[k].max(mlo[k]);
            hi[k] = hi[k].min(mhi[k]);
        }
    }
    let from = args.from_mm.unwrap_or(lo[axis]);
    let to = args.to_mm.unwrap_or(hi[axis]);
    if from < lo[axis] - 1e-9 || to > hi[axis] + 1e-9 {
        anyhow::bail!(
            "the segment {from:.3} .. {to:.3} mm leaves the usable travel of {} ({:.3} .. {:.3} mm: the limits less the overrun, the board{})",
            AXIS_NAMES[axis],
            lo[axis],
            hi[axis],
            if model.is_some() { ", the map" } else { "" }
        );
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
    let across = args
        .at_mm
        .or(map_line)
        .unwrap_or((lo[1 - axis] + hi[1 - axis]) / 2.0);
    let cycle = Cycle::new(
        targets(from, to, args.positions)?,
        args.runs,
        args.overrun_mm,
        kind,
    )?;
    let spec = Iso230Spec {
        axis,
        cycle: cycle.clone(),
        across_mm: across,
        still_frames: 10,
    };
    let csv_path = args.out.join("measurements.csv");
    let mut taken: Vec<Measurement> = Vec::new();
    let total = cycle.measurements();
    let bar = if args.json {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(total as u64)
    };
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} ISO 230-2 [{bar:30}] {pos}/{len} measurements, {elapsed} so far, about {eta} left",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    let interrupted = async {
        if tokio::signal::ctrl_c().await.is_err() {
            std::future::pending::<()>().await;
        }
    };
    let mut csv_error: Option<anyhow::Error> = None;
    let result = rt.block_on(run_iso230(
        &job,
        &mut devices,
        &spec,
        model.as_ref(),
        &mut |m| {
            taken.push(m.clone());
            // Rewritten after each measurement: a stopped cycle leaves its runs so far.
            if let Err(e) = std::fs::write(&csv_path, csv_io::write(&taken)) {
                csv_error.get_or_insert(anyhow::anyhow!("writing {}: {e}", csv_path.display()));
            }
        },
        &mut |done, _| bar.set_position(done as u64),
        interrupted,
    ));
    bar.finish_and_clear();
    if let Some(e) = csv_error {
        return Err(e);
    }
    let run = match result {
        Ok(r) => r,
        Err(e) => anyhow::bail!(
            "{e}; the {} measurements taken are in {}",
            taken.len(),
            csv_path.display()
        ),
    };
    std::fs::write(&csv_path, csv_io::write(&run.measurements))
        .with_context(|| format!("writing {}", csv_path.display()))?;
    let evaluation = evaluate(&run.measurements)?;
    let uncertainty = Uncertainty::new(args.certificate_uncertainty_um, &run.still_um);
    let machine_time_s = devices
        .rig
        .as_ref()
        .map(|rig| world::lock(rig).machine().now_s());
    let label = if model.is_some() {
        "with the map"
    } else {
        "without compensation"
    };
    let stage_name = devices.stage.info().name.clone();
    let mut notes = vec![format!(
        "Machine: {stage_name}; camera: {}; board: {} (the length reference). Axis {} from {from:.3} to {to:.3} mm at {} = {across:.3} mm, {} positions, {} runs each direction, {} cycle, overrun {} mm; {label}{}.",
        devices.camera.info().model,
        job.board.name,
        AXIS_NAMES[axis],
        AXIS_NAMES[1 - axis],
        cycle.targets_mm.len(),
        cycle.runs,
        match kind { CycleKind::Linear => "linear", CycleKind::PilgrimStep => "pilgrim-step" },
        cycle.overrun_mm,
        args.map.as_ref().map(|p| format!(" ({})", p.display())).unwrap_or_default(),
    )];
    if let Some(t) = machine_time_s {
        notes.push(format!(
            "Simulated machine time of the whole run (homing included): {t:.1} s."
        ));
    }
    let result = write_outputs(
        &args.out,
        &evaluation,
        Some(&uncertainty),
        before.as_ref(),
        label,
        &notes,
        json!({
            "map": args.map.as_ref().map(|p| p.display().to_string()),
            "cycle": match kind { CycleKind::Linear => "linear", CycleKind::PilgrimStep => "pilgrim-step" },
            "runs": cycle.runs, "overrun_mm": cycle.overrun_mm, "across_mm": across,
            "machine_time_s": machine_time_s, "wall_time_s": started.elapsed().as_secs_f64(),
        }),
    )?;
    if args.json {
        println!("{result}");
    } else {
        print_figures(&evaluation, label);
        println!(
            "uncertainty of one deviation {:.3} um (k = 2); {} measurements{}, {:.1} s; outputs in {}",
            uncertainty.expanded_um,
            run.measurements.len(),
            machine_time_s
                .map(|t| format!(", {t:.1} s of machine time"))
                .unwrap_or_default(),
            started.elapsed().as_secs_f64(),
            args.out.display()
        );
    }
    std::io::stdout().flush()?;
    Ok(ExitCode::SUCCESS)
}

/// `gateway iso230 --config JOB --axis x|y [--map MAP] --out DIR`, or
/// `gateway iso230 evaluate FILE [--out DIR] [--json]`.
#[derive(clap::Args)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct Iso230Args {
    #[command(subcommand)]
    sub: Option<Iso230Cmd>,
    /// The job (stage, camera, board) to test.
    #[arg(long, required = true)]
    config: Option<PathBuf>,
    /// The axis to test: x or y.
    #[arg(long, required = true)]
    axis: Option<String>,
    /// Test with this error map active (the same test, compensated).
    #[arg(long)]
    map: Option<PathBuf>,
    /// Output folder: measurements.csv, result.json, charts (SVG, PNG), report.html.
    #[arg(long, required = true)]
    out: Option<PathBuf>,
    /// Target positions (default: the standard's minimum, 5 and 5 per metre).
    #[arg(long)]
    positions: Option<usize>,
    /// Runs in each direction (at least 5).
    #[arg(long, default_value_t = 5)]
    runs: usize,
    /// linear or pilgrim-step.
    #[arg(long, default_value = "linear")]
    cycle: String,
    /// How far beyond the end targets the axis goes before reversing, mm.
    #[arg(long, default_value_t = 1.0)]
    overrun_mm: f64,
    /// The measurement travel's start and end on the axis, machine mm (default: all the
    /// usable travel).
    #[arg(long)]
    from_mm: Option<f64>,
    #[arg(long)]
    to_mm: Option<f64>,
    /// Where the other axis is held, machine mm (default: on the map's dense line along
    /// the axis, else the middle).
    #[arg(long)]
    at_mm: Option<f64>,
    /// The board certificate's expanded uncertainty (k = 2) of a dot position, um.
    #[arg(long, default_value_t = 1.0)]
    certificate_uncertainty_um: f64,
    /// A measurements file of the same test before compensation, overlaid on the charts.
    #[arg(long)]
    before: Option<PathBuf>,
    /// Print the result JSON instead of text.
    #[arg(long)]
    json: bool,
}

#[derive(clap::Subcommand)]
enum Iso230Cmd {
    /// Evaluate a measurements file from any instrument
    /// (axis,position_index,target_mm,run,direction,deviation_um).
    Evaluate {
        file: PathBuf,
        /// Write result.json, the charts and report.html here.
        #[arg(long)]
        out: Option<PathBuf>,
        /// A measurements file of the test before compensation, overlaid on the charts.
        #[arg(long)]
        before: Option<PathBuf>,
        #[arg(long)]
        json: bool,
    },
}

impl Iso230Args {
    pub fn json(&self) -> bool {
        match &self.sub {
            Some(Iso230Cmd::Evaluate { json, .. }) => *json,
            None => self.json,
        }
    }
}

pub fn dispatch(a: Iso230Args) -> anyhow::Result<ExitCode> {
    match a.sub {
        Some(Iso230Cmd::Evaluate {
            file,
            out,
            before,
            json,
        }) => evaluate_file(&file, out.as_deref(), before.as_deref(), json),
        None => run(RunArgs {
            config: a.config.context("--config is required")?,
            axis: a.axis.context("--axis is required")?,
            map: a.map,
            out: a.out.context("--out is required")?,
            positions: a.positions,
            runs: a.runs,
            cycle: a.cycle,
            overrun_mm: a.overrun_mm,
            from_mm: a.from_mm,
            to_mm: a.to_mm,
            at_mm: a.at_mm,
            certificate_uncertainty_um: a.certificate_uncertainty_um,
            before: a.before,
            json: a.json,
        }),
    }
}

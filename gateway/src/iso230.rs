//! `gateway iso230`: the ISO 230-2 positioning test on a machine (with a progress bar and
//! the measurements written as they come), and `gateway iso230 evaluate` for a
//! measurements file from any instrument. Both write DIR/result.json, the charts as SVG
//! and PNG, and DIR/report.html (the procedure's artifacts).

use crate::front::CliSink;
use anyhow::Context;
use devices::open_devices_async;
use iso230::{csv_io, Direction, Measurement};
use job::Job;
use procedure::iso230::NamedMap;
use procedure::request::{CycleName, Iso230Request, TestAxis};
use protocol::errormap::ErrorMap;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

fn read_measurements(path: &Path) -> anyhow::Result<Vec<Measurement>> {
    let text = protocol::config::read_data_file(path)
        .with_context(|| format!("reading {}", path.display()))?;
    csv_io::read(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

pub fn evaluate_file(
    file: &Path,
    out: Option<&Path>,
    before: Option<&Path>,
    json_out: bool,
) -> anyhow::Result<ExitCode> {
    let measurements = read_measurements(file)?;
    let before_measurements = before.map(read_measurements).transpose()?;
    let inputs: Vec<&Path> = [Some(file), before].into_iter().flatten().collect();
    let mut sink = CliSink::new("", true).inputs(&inputs);
    if let Some(dir) = out {
        sink = sink.into_folder(dir)?;
    }
    let outcome = procedure::iso230::evaluate_measurements(
        &measurements,
        before_measurements.as_deref(),
        &file.display().to_string(),
        &mut sink,
    );
    crate::front::print(&outcome, json_out, procedure::iso230::summary)
}

pub struct RunArgs {
    pub config: PathBuf,
    pub map: Option<PathBuf>,
    pub out: PathBuf,
    pub before: Option<PathBuf>,
    pub request: Iso230Request,
    pub json: bool,
}

/// A measurement as the procedure hands it to the sink, back as a row of the file.
fn measurement_of(m: &Value) -> Measurement {
    Measurement {
        axis: m["axis"].as_str().unwrap_or("").to_string(),
        position_index: m["position_index"].as_u64().unwrap_or(0) as usize,
        target_mm: m["target_mm"].as_f64().unwrap_or(f64::NAN),
        run: m["run"].as_u64().unwrap_or(0) as usize,
        direction: if m["direction"] == "-" {
            Direction::Down
        } else {
            Direction::Up
        },
        deviation_um: m["deviation_um"].as_f64().unwrap_or(f64::NAN),
    }
}

pub fn run(args: RunArgs) -> anyhow::Result<ExitCode> {
    let request = args.request;
    request.check().map_err(|e| anyhow::anyhow!(e.for_cli()))?;
    let job = Job::load(&args.config)?;
    let map = match &args.map {
        Some(path) => Some(NamedMap {
            map: ErrorMap::load(path)?,
            name: path.display().to_string(),
        }),
        None => None,
    };
    let before = args.before.as_deref().map(read_measurements).transpose()?;
    let rt = crate::front::runtime()?;
    let mut devices = rt.block_on(open_devices_async(&job))?;
    let inputs: Vec<&Path> = [
        Some(args.config.as_path()),
        args.map.as_deref(),
        args.before.as_deref(),
    ]
    .into_iter()
    .flatten()
    .collect();
    // measurements.csv is rewritten after each measurement: a stopped cycle leaves its
    // runs so far.
    let csv_path = args.out.join("measurements.csv");
    let csv_inputs: Vec<PathBuf> = inputs.iter().map(|p| p.to_path_buf()).collect();
    let mut taken: Vec<Measurement> = Vec::new();
    let mut sink = CliSink::new("measurements", args.json)
        .inputs(&inputs)
        .into_folder(&args.out)?
        .on_measurement(move |m| {
            taken.push(measurement_of(m));
            crate::front::write_atomic(&csv_path, csv_io::write(&taken).as_bytes(), &csv_inputs)
                .map_err(|e| format!("{e:#}"))
        });
    let outcome = rt.block_on(procedure::iso230::run(
        &request,
        &job,
        &mut devices,
        map,
        before.as_deref(),
        &mut sink,
        crate::front::ctrl_c(),
    ));
    sink.finish();
    crate::front::print(&outcome, args.json, |r| {
        if outcome.is_success() {
            let out = args.out.display();
            format!("{}outputs in {out}", procedure::iso230::summary(r))
        } else {
            format!(
                "{} measurements taken are in {}",
                r["measurements_taken"],
                args.out.join("measurements.csv").display()
            )
        }
    })
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
        None => {
            let axis = match a
                .axis
                .context("--axis is required")?
                .to_ascii_lowercase()
                .as_str()
            {
                "x" => TestAxis::X,
                "y" => TestAxis::Y,
                other => anyhow::bail!("--axis `{other}`: expected x or y"),
            };
            let cycle = match a.cycle.as_str() {
                "linear" => CycleName::Linear,
                "pilgrim" | "pilgrim-step" => CycleName::PilgrimStep,
                other => anyhow::bail!("--cycle `{other}`: expected linear or pilgrim-step"),
            };
            let request = Iso230Request {
                axis,
                positions: a.positions.map(|n| n as u64),
                runs: a.runs as u64,
                cycle,
                overrun_mm: a.overrun_mm,
                from_mm: a.from_mm,
                to_mm: a.to_mm,
                at_mm: a.at_mm,
                certificate_uncertainty_um: a.certificate_uncertainty_um,
                with_map: a.map.is_some(),
            };
            run(RunArgs {
                config: a.config.context("--config is required")?,
                map: a.map,
                out: a.out.context("--out is required")?,
                before: a.before,
                request,
                json: a.json,
            })
        }
    }
}

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
use procedure::request::Iso230Request;
use protocol::errormap::ErrorMap;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

fn read_measurements(path: &Path) -> anyhow::Result<Vec<Measurement>> {
    procedure::iso230::read_measurements_file(path).map_err(anyhow::Error::msg)
}

pub fn evaluate_file(
    file: &Path,
    out: Option<&Path>,
    before: Option<&Path>,
    json: bool,
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
    crate::front::print(&outcome, json, procedure::iso230::summary)
}

pub struct RunArgs {
    pub config: PathBuf,
    pub map: Option<PathBuf>,
    pub out: PathBuf,
    pub before: Option<PathBuf>,
    pub request: Iso230Request,
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

pub fn run(args: RunArgs, json: bool) -> anyhow::Result<ExitCode> {
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
    let mut sink = CliSink::new("measurements", json)
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
    crate::front::print(&outcome, json, |r| {
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
    /// Test with this error map active (the same test, compensated).
    #[arg(long)]
    map: Option<PathBuf>,
    /// Output folder: measurements.csv, result.json, charts (SVG, PNG), report.html.
    #[arg(long, required = true)]
    out: Option<PathBuf>,
    /// A measurements file of the same test before compensation, overlaid on the charts.
    #[arg(long)]
    before: Option<PathBuf>,
    #[command(flatten)]
    pub(crate) request: Option<Iso230Request>,
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
    },
}

pub fn dispatch(a: Iso230Args, json: bool) -> anyhow::Result<ExitCode> {
    match a.sub {
        Some(Iso230Cmd::Evaluate { file, out, before }) => {
            evaluate_file(&file, out.as_deref(), before.as_deref(), json)
        }
        None => {
            let mut request = a.request.context("--axis is required")?;
            request.with_map = a.map.is_some();
            run(
                RunArgs {
                    config: a.config.context("--config is required")?,
                    map: a.map,
                    out: a.out.context("--out is required")?,
                    before: a.before,
                    request,
                },
                json,
            )
        }
    }
}

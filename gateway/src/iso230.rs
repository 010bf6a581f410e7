//! `gateway iso230`: the ISO 230-2 positioning test on a machine (with a progress bar and
//! the measurements written as they come), and `gateway iso230 evaluate` for a
//! measurements file from any instrument. Both write DIR/result.json, the charts as SVG
//! and PNG, and DIR/report.html (the procedure's artifacts).

use crate::front::CliSink;
use anyhow::Context;
use procedure::request::Iso230Request;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

pub fn evaluate_file(
    file: &Path,
    out: Option<&Path>,
    before: Option<&Path>,
    json: bool,
) -> anyhow::Result<ExitCode> {
    let read = |p: &Path| protocol::config::read_kind(p, protocol::config::DataKind::Iso230);
    let request = procedure::iso230::Iso230EvaluateRequest {
        measurements: read(file)?,
        measurements_name: file.display().to_string(),
        before: before.map(read).transpose()?,
    };
    let inputs: Vec<&Path> = [Some(file), before].into_iter().flatten().collect();
    let mut sink = CliSink::new("", true).inputs(&inputs);
    if let Some(dir) = out {
        sink = sink.into_folder(dir)?;
    }
    crate::front::run_kind("iso230-evaluate", &request, &mut sink, json, |f| f)
}

pub struct RunArgs {
    pub config: PathBuf,
    pub map: Option<PathBuf>,
    pub out: PathBuf,
    pub before: Option<PathBuf>,
    pub request: Iso230Request,
}

pub fn run(args: RunArgs, json: bool) -> anyhow::Result<ExitCode> {
    let mut request = args.request;
    request.with_map = args.map.is_some();
    request.before = args
        .before
        .as_deref()
        .map(|p| protocol::config::read_kind(p, protocol::config::DataKind::Iso230))
        .transpose()?;
    let inputs: Vec<&Path> = [
        Some(args.config.as_path()),
        args.map.as_deref(),
        args.before.as_deref(),
    ]
    .into_iter()
    .flatten()
    .collect();
    let mut sink = CliSink::new("measurements", json)
        .inputs(&inputs)
        .into_folder(&args.out)?;
    let kind = procedure::kinds::kind("iso230").map_err(|e| anyhow::anyhow!("{e}"))?;
    let outcome = crate::front::run_outcome(kind, &request, &mut sink, |f| {
        let f = f.job_file(&args.config);
        match &args.map {
            Some(m) => f.map_file(m),
            None => f,
        }
    })?;
    crate::front::print(&outcome, json, |r| {
        if outcome.is_success() {
            let out = args.out.display();
            format!("{}outputs in {out}", kind.summary(r))
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

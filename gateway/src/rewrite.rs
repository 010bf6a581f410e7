//! `gateway rewrite` (3-axis): flags to `procedure::rewrite`'s request, the program and
//! the `$#` reply read through the bounded reader, the rewritten program written
//! atomically to `--out` (never over an input).

use anyhow::Context;
use procedure::rewrite::{RewriteModel, RewriteRequest, PROGRAM_ARTIFACT};
use protocol::errormap::ErrorMap;
use serde_json::json;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// What the command line gave.
pub struct RewriteArgs {
    pub input: PathBuf,
    pub out: PathBuf,
    pub map: Option<PathBuf>,
    /// The job of the machine the program is for: the map's identity is checked.
    pub config: Option<PathBuf>,
    /// A volumetric model file (`gateway volumetric identify`).
    pub volumetric: Option<PathBuf>,
    pub tolerance_um: f64,
    pub max_correction_um: f64,
    pub offsets: Option<PathBuf>,
    pub start: Option<String>,
    pub limits: Option<String>,
    pub json: bool,
}

fn read(path: &Path) -> anyhow::Result<String> {
    protocol::config::read_data_file(path).with_context(|| format!("reading {}", path.display()))
}

/// `X,Y[,Z]` (mm) as numbers; the count and the bounds are the request's.
fn parse_pose(s: &str) -> anyhow::Result<Vec<f64>> {
    s.split(',')
        .map(|p| p.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| anyhow::anyhow!("--start `{s}`: expected X,Y or X,Y,Z in mm"))
}

/// `XMIN:XMAX,YMIN:YMAX[,ZMIN:ZMAX]` (mm) as ranges; the count and the bounds are the
/// request's.
fn parse_limits(s: &str) -> anyhow::Result<Vec<[f64; 2]>> {
    let bad = || anyhow::anyhow!("--limits `{s}`: expected XMIN:XMAX,YMIN:YMAX[,ZMIN:ZMAX] in mm");
    s.split(',')
        .map(|part| {
            let (a, b) = part.split_once(':').ok_or_else(bad)?;
            Ok([
                a.trim().parse().map_err(|_| bad())?,
                b.trim().parse().map_err(|_| bad())?,
            ])
        })
        .collect()
}

pub fn rewrite(args: RewriteArgs) -> anyhow::Result<ExitCode> {
    let model = match (&args.map, &args.volumetric) {
        (Some(_), Some(_)) => anyhow::bail!("give one compensation: --map or --volumetric"),
        (Some(path), None) => {
            let map = ErrorMap::load(path)?;
            if let Some(config) = &args.config {
                // The one identity check, on the job's devices (opened, asked, closed).
                let job = job::Job::load(config)?;
                let here = crate::front::runtime()?
                    .block_on(procedure::identity_of_job(&job))
                    .map_err(|e| anyhow::anyhow!(e))?;
                procedure::check_identity(&map, &here, &path.display().to_string())
                    .map_err(|e| anyhow::anyhow!(e))?;
            }
            RewriteModel::Map(map)
        }
        (None, Some(path)) => RewriteModel::Volumetric {
            model: crate::volumetric::load_model(path)?,
            name: path.display().to_string(),
        },
        (None, None) => {
            anyhow::bail!("give the compensation to apply: --map MAP or --volumetric MODEL")
        }
    };
    let request = RewriteRequest {
        program: read(&args.input)?,
        tolerance_um: args.tolerance_um,
        max_correction_um: args.max_correction_um,
        offsets: args.offsets.as_deref().map(read).transpose()?,
        start: args.start.as_deref().map(parse_pose).transpose()?,
        limits: args.limits.as_deref().map(parse_limits).transpose()?,
    };
    request.check().map_err(|e| anyhow::anyhow!(e.for_cli()))?;
    let inputs: Vec<&Path> = [
        Some(args.input.as_path()),
        args.map.as_deref(),
        args.config.as_deref(),
        args.volumetric.as_deref(),
        args.offsets.as_deref(),
    ]
    .into_iter()
    .flatten()
    .collect();
    let mut sink = crate::front::CliSink::new("", true)
        .inputs(&inputs)
        .artifact_to(PROGRAM_ARTIFACT, args.out.clone());
    let source = args.input.display().to_string();
    let mut outcome = procedure::rewrite::run(&request, model, &source, &mut sink);
    if let Some(r) = outcome.result.as_mut() {
        r["output"] = json!(args.out.display().to_string());
    }
    crate::front::print(&outcome, args.json, procedure::rewrite::summary)
}

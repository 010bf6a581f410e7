//! `gateway rewrite` (3-axis): flags to `procedure::rewrite`'s request, the program and
//! the `$#` reply read through the bounded reader, the rewritten program written
//! atomically to `--out` (never over an input).

use procedure::rewrite::{RewriteRequest, PROGRAM_ARTIFACT};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct RewriteArgs {
    /// The program to rewrite (never overwritten).
    pub input: PathBuf,
    /// The error map (a version file written by `gateway map`).
    #[arg(long)]
    pub map: Option<PathBuf>,
    /// With --map: the job of the machine the program is for; the map is refused
    /// unless it was measured on that machine, controller, board and camera.
    #[arg(long, requires = "map")]
    pub config: Option<PathBuf>,
    /// A volumetric model file (`gateway volumetric identify`): X, Y and Z corrected.
    #[arg(long, conflicts_with = "rotary")]
    pub volumetric: Option<PathBuf>,
    /// The location errors of an A/C tilting table (`gateway rotary identify` or
    /// `measure`): a 5-axis program (X Y Z A C) rewritten so the tool tip and
    /// direction land where programmed (the same rewrite as `gateway rotary rewrite`).
    #[arg(long, conflicts_with = "map")]
    pub rotary: Option<PathBuf>,
    /// With --rotary: the machine constants (JSON); default: those recorded in the
    /// errors file.
    #[arg(long, requires = "rotary")]
    pub machine: Option<PathBuf>,
    /// With --machine: use it even where it differs from the recorded constants.
    #[arg(long, requires = "machine")]
    pub force_machine: bool,
    #[arg(long)]
    pub out: PathBuf,
    /// The controller's `$#` reply saved to a file: its G54..G59 offsets.
    #[arg(long, conflicts_with = "rotary")]
    pub offsets: Option<PathBuf>,
    #[command(flatten)]
    pub request: RewriteRequest,
}

pub fn rewrite(args: RewriteArgs, json: bool) -> anyhow::Result<ExitCode> {
    let read = |p: &Path| procedure::rewrite::read_program(p).map_err(anyhow::Error::msg);
    if let Some(errors) = args.rotary {
        // The 5-axis rewrite has its own program rules (absolute mm, no arcs); the
        // 3-axis flags conflict with --rotary (clap refuses them).
        return crate::rotary::rewrite(
            &args.input,
            &errors,
            &args.out,
            args.machine.as_deref(),
            args.force_machine,
            args.request.tolerance_um,
            json,
        );
    }
    let mut request = args.request;
    request.program = read(&args.input)?;
    request.program_name = args.input.display().to_string();
    request.offsets = (args.offsets.as_deref())
        .map(procedure::rewrite::read_offsets_file)
        .transpose()
        .map_err(anyhow::Error::msg)?;
    if let Some(path) = &args.volumetric {
        request.volumetric =
            Some(procedure::volumetric::read_file(path).map_err(anyhow::Error::msg)?);
        request.volumetric_name = Some(path.display().to_string());
    }
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
    let kind = procedure::kinds::kind("rewrite")?;
    let mut outcome = match (&args.map, &args.volumetric) {
        (Some(_), Some(_)) => anyhow::bail!("give one compensation: --map or --volumetric"),
        (None, None) => {
            anyhow::bail!("give the compensation to apply: --map MAP or --volumetric MODEL")
        }
        (map, _) => crate::front::run_outcome(kind, &request, &mut sink, |f| {
            let f = f.input(&args.input);
            let f = match map {
                Some(map) => f.map_file(map),
                None => f,
            };
            match &args.config {
                Some(job) => f.job_file(job),
                None => f,
            }
        })?,
    };
    if let Some(r) = outcome.result.as_mut() {
        r["output"] = json!(args.out.display().to_string());
    }
    crate::front::print(&outcome, json, |r| kind.summary(r))
}

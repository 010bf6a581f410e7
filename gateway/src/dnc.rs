//! `gateway dnc`: a Fanuc program (and the controller's stored subprograms) read through
//! the bounded reader into `procedure::dnc`'s request, rewritten with the map and
//! drip-fed to the controller's tape port; `--out` keeps the tape sent (written
//! atomically, never over an input).

use procedure::dnc::{DncRequest, TAPE_ARTIFACT};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct DncArgs {
    /// The program (Fanuc dialect, ISO code; its subprograms after M30); none with
    /// `--from-port` (the program comes from a DNC sender).
    #[arg(required_unless_present = "from_port")]
    pub input: Option<PathBuf>,
    /// The error map (a version file written by `gateway map`).
    #[arg(long, required_unless_present = "uncompensated")]
    pub map: Option<PathBuf>,
    /// The job of the machine: its `[stage] driver = "dnc"` names the tape port, and
    /// the map is refused unless it was measured on that machine.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// The subprograms stored in the controller that the program calls (M98).
    #[arg(long)]
    pub subprograms: Option<PathBuf>,
    /// Write the rewritten tape here (never over an input; not with `--from-port`).
    #[arg(long, conflicts_with = "from_port")]
    pub out: Option<PathBuf>,
    #[command(flatten)]
    pub request: DncRequest,
}

pub fn dnc(args: DncArgs, json: bool) -> anyhow::Result<ExitCode> {
    let read = |p: &Path| procedure::rewrite::read_program(p).map_err(anyhow::Error::msg);
    let mut request = args.request;
    if let Some(input) = &args.input {
        request.program = read(input)?;
        request.program_name = input.display().to_string();
    }
    request.subprograms = args.subprograms.as_deref().map(read).transpose()?;
    let inputs: Vec<&Path> = [
        args.input.as_deref(),
        args.map.as_deref(),
        args.config.as_deref(),
        args.subprograms.as_deref(),
    ]
    .into_iter()
    .flatten()
    .collect();
    let mut sink = crate::front::CliSink::new("tape lines", json).inputs(&inputs);
    if let Some(out) = &args.out {
        sink = sink.artifact_to(TAPE_ARTIFACT, out.clone());
    }
    let kind = procedure::kinds::kind("dnc")?;
    let mut outcome = crate::front::run_outcome(kind, &request, &mut sink, |f| {
        let f = match &args.input {
            Some(input) => f.input(input),
            None => f,
        };
        let f = match &args.map {
            Some(map) => f.map_file(map),
            None => f,
        };
        match &args.config {
            Some(job) => f.job_file(job),
            None => f,
        }
    })?;
    // Where the tape went: the --out file, or only the port (nothing written here).
    if let Some(r) = outcome.result.as_mut() {
        r["output"] = serde_json::json!(match &args.out {
            Some(out) => out.display().to_string(),
            None => "the tape port (the tape is not kept: no --out)".to_string(),
        });
    }
    crate::front::print(&outcome, json, |r| kind.summary(r))
}

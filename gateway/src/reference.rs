//! `gateway reference`: the reference procedure after a homing; the map's current
//! reference written atomically beside it (`NAME.vN.reference.json`).

use procedure::request::ReferenceRequest;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct ReferenceArgs {
    #[arg(long)]
    pub config: PathBuf,
    /// The error map (a version file written by `gateway map`).
    #[arg(long)]
    pub map: PathBuf,
    #[command(flatten)]
    pub request: ReferenceRequest,
}

pub fn reference(args: ReferenceArgs, json: bool) -> anyhow::Result<ExitCode> {
    let mut sink = crate::front::CliSink::new("frames", true);
    crate::front::run_kind("reference", &args.request, &mut sink, json, |f| {
        f.job_file(&args.config).map_file(&args.map)
    })
}

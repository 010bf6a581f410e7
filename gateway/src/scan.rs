//! `gateway map`: the scan procedure with its journal file (a stopped scan resumes from
//! OUT/NAME.scan.jsonl) and the map written as a new version OUT/NAME.vN.json.

use procedure::request::MapRequest;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct MapArgs {
    #[arg(long)]
    pub config: PathBuf,
    /// Folder of the map versions.
    #[arg(long)]
    pub out: PathBuf,
    /// Map name (default: the job file's name).
    #[arg(long)]
    pub name: Option<String>,
    #[command(flatten)]
    pub request: MapRequest,
}

pub fn map(args: MapArgs, json: bool) -> anyhow::Result<ExitCode> {
    let mut request = args.request;
    request.name = args.name.unwrap_or_else(|| {
        args.config
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "map".into())
    });
    let mut sink = crate::front::CliSink::new("frames", json);
    crate::front::run_kind("map", &request, &mut sink, json, |f| {
        f.job_file(&args.config).out_folder(&args.out)
    })
}

//! `gateway map`: the scan procedure with its journal file (a stopped scan resumes from
//! OUT/NAME.scan.jsonl) and the map written as a new version OUT/NAME.vN.json.

use anyhow::Context;
use devices::open_devices_async;
use job::Job;
use procedure::map::{FileJournal, FolderShelf};
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
    let job = Job::load(&args.config)?;
    let mut request = args.request;
    request.name = args.name.unwrap_or_else(|| {
        args.config
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "map".into())
    });
    request.check().map_err(|e| anyhow::anyhow!(e.for_cli()))?;
    let (job, out) = (&job, args.out.as_path());
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let rt = crate::front::runtime()?;
    let mut devices = rt.block_on(open_devices_async(job))?;
    let mut journal = FileJournal::new(out.join(format!("{}.scan.jsonl", request.name)));
    let mut shelf = FolderShelf::new(out);
    let mut sink = crate::front::CliSink::new("frames", json);
    let outcome = rt.block_on(procedure::map::run(
        &request,
        job,
        &mut devices,
        &mut journal,
        &mut shelf,
        &mut sink,
        crate::front::ctrl_c(),
    ));
    sink.finish();
    crate::front::print(&outcome, json, procedure::map::summary)
}

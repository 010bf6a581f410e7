//! `gateway reference`: the reference procedure after a homing; the map's current
//! reference written atomically beside it (`NAME.vN.reference.json`).

use devices::open_devices_async;
use job::Job;
use procedure::reference::{read_record, reference_path, REFERENCE_ARTIFACT};
use procedure::request::ReferenceRequest;
use protocol::errormap::ErrorMap;
use serde_json::json;
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
    args.request
        .check()
        .map_err(|e| anyhow::anyhow!(e.for_cli()))?;
    let job = Job::load(&args.config)?;
    let map = ErrorMap::load(&args.map)?;
    let path = reference_path(&args.map);
    // A damaged record is replaced by a new one, with a word about it.
    let previous = read_record(&path).unwrap_or_else(|e| {
        eprintln!("warning: {e}; a new record replaces it");
        None
    });
    let rt = crate::front::runtime()?;
    let mut devices = rt.block_on(open_devices_async(&job))?;
    let inputs = [args.map.as_path(), args.config.as_path()];
    let mut sink = crate::front::CliSink::new("frames", true)
        .inputs(&inputs)
        // The record replaces the one read above (never a link to another file read).
        .replacing(&path)
        .artifact_to(REFERENCE_ARTIFACT, path.clone());
    let what = args.map.display().to_string();
    let mut outcome = rt.block_on(procedure::reference::run(
        &args.request,
        &job,
        &mut devices,
        &map,
        &what,
        previous.as_ref(),
        &mut sink,
    ));
    if let Some(r) = outcome.result.as_mut() {
        r["written_to"] = json!(path.display().to_string());
    }
    crate::front::print(&outcome, json, procedure::reference::summary)
}

//! `gateway map`: the scan procedure with its journal file (a stopped scan resumes from
//! OUT/NAME.scan.jsonl) and the map written as a new version OUT/NAME.vN.json.

use anyhow::Context;
use devices::open_devices_async;
use job::Job;
use procedure::map::{FileJournal, FolderShelf};
use procedure::request::MapRequest;
use std::path::Path;
use std::process::ExitCode;

pub fn map(job: &Job, request: MapRequest, out: &Path, json: bool) -> anyhow::Result<ExitCode> {
    request.check().map_err(|e| anyhow::anyhow!(e.for_cli()))?;
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

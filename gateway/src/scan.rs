//! `gateway map`: the scan procedure with its journal file (a stopped scan resumes from
//! OUT/NAME.scan.jsonl) and the map written as a new version OUT/NAME.vN.json.

use anyhow::Context;
use devices::open_devices_async;
use errormap::scan::{journal, Sample, ScanPlan};
use job::Job;
use procedure::map::{MapShelf, ScanJournal};
use procedure::request::MapRequest;
use protocol::errormap::{next_version_path, ErrorMap};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// The journal file: a header naming the plan, then one line per sample, flushed as
/// each comes.
struct FileJournal {
    path: PathBuf,
    file: Option<std::fs::File>,
}

impl ScanJournal for FileJournal {
    fn resume(&mut self, plan: &ScanPlan) -> Result<Vec<(usize, Sample)>, String> {
        let shown = self.path.display();
        let samples = if self.path.exists() {
            let text = protocol::config::read_data_file(&self.path)
                .map_err(|e| format!("{shown}: {e}"))?;
            journal::read(plan, &text)
                .map_err(|e| format!("{shown}: {e} (remove it to start a new scan)"))?
        } else {
            std::fs::write(&self.path, journal::header(plan))
                .map_err(|e| format!("writing {shown}: {e}"))?;
            Vec::new()
        };
        let file = std::fs::OpenOptions::new()
            .append(true)
            .open(&self.path)
            .map_err(|e| format!("opening {shown}: {e}"))?;
        self.file = Some(file);
        Ok(samples)
    }

    fn append(&mut self, index: usize, sample: &Sample) -> Result<(), String> {
        let file = self.file.as_mut().ok_or("the journal is not open")?;
        file.write_all(journal::line(index, sample).as_bytes())
            .and_then(|()| file.flush())
            .map_err(|e| format!("{}: {e}", self.path.display()))
    }

    fn close(&mut self) {
        self.file = None;
        std::fs::remove_file(&self.path).ok();
    }
}

/// Versions in a folder, never overwritten.
struct FolderShelf {
    dir: PathBuf,
    next: Option<(u32, PathBuf)>,
}

impl MapShelf for FolderShelf {
    fn next_version(&mut self, name: &str) -> Result<u32, String> {
        let (v, path) = next_version_path(&self.dir, name).map_err(|e| e.to_string())?;
        self.next = Some((v, path));
        Ok(v)
    }

    fn keep(&mut self, _: &str, map: &ErrorMap) -> Result<String, String> {
        let (_, path) = self.next.take().ok_or("no version was reserved")?;
        map.save_new(&path).map_err(|e| e.to_string())?;
        Ok(path.display().to_string())
    }
}

pub fn map(job: &Job, request: MapRequest, out: &Path, json: bool) -> anyhow::Result<ExitCode> {
    request.check().map_err(|e| anyhow::anyhow!(e.for_cli()))?;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let rt = crate::front::runtime()?;
    let mut devices = rt.block_on(open_devices_async(job))?;
    let mut journal = FileJournal {
        path: out.join(format!("{}.scan.jsonl", request.name)),
        file: None,
    };
    let mut shelf = FolderShelf {
        dir: out.to_path_buf(),
        next: None,
    };
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

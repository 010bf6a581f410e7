//! The command line's [`Context`]: files. The job file (`--config`), the error map
//! (`--map`) with its current reference beside it (`NAME.vN.reference.json`), an output
//! folder (`--out`: map versions, the scan journal `NAME.scan.jsonl`, `errors.json`), the
//! rotary job file; devices opened through the drivers' factory on first use. Nothing is
//! ever written over a file the command reads.

use crate::context::{ActiveMap, Bench, Context, ContextError, NamedBoard, Stop};
use crate::map::{FileJournal, FolderShelf, MapShelf, ScanJournal};
use crate::rotary::ErrorsShelf;
use crate::Sink;
use devices::Devices;
use errormap::reference::MapReference;
use job::rotary::RotaryJob;
use job::Job;
use protocol::errormap::{ErrorMap, Identity};
use std::path::{Path, PathBuf};
use std::time::SystemTime;

/// The files a command was given, its sink and its stop signal.
pub struct Files<'a> {
    job_path: Option<PathBuf>,
    map_path: Option<PathBuf>,
    out: Option<PathBuf>,
    rotary_path: Option<PathBuf>,
    board_path: Option<PathBuf>,
    /// Every file the command reads: never written over.
    inputs: Vec<PathBuf>,
    job: Option<Job>,
    devices: Option<Devices>,
    sink: &'a mut dyn Sink,
    stop: Stop,
}

impl<'a> Files<'a> {
    pub fn new(sink: &'a mut dyn Sink, stop: Stop) -> Self {
        Self {
            job_path: None,
            map_path: None,
            out: None,
            rotary_path: None,
            board_path: None,
            inputs: Vec::new(),
            job: None,
            devices: None,
            sink,
            stop,
        }
    }

    /// The job file (`--config`).
    pub fn job_file(mut self, path: &Path) -> Self {
        self.inputs.push(path.to_path_buf());
        self.job_path = Some(path.to_path_buf());
        self
    }

    /// A job built by the command itself (the demo's).
    pub fn job(mut self, job: Job) -> Self {
        self.job = Some(job);
        self
    }

    /// The error map (`--map`).
    pub fn map_file(mut self, path: &Path) -> Self {
        self.inputs.push(path.to_path_buf());
        self.map_path = Some(path.to_path_buf());
        self
    }

    /// The output folder (`--out`).
    pub fn out_folder(mut self, dir: &Path) -> Self {
        self.out = Some(dir.to_path_buf());
        self
    }

    /// The rotary job file.
    pub fn rotary_file(mut self, path: &Path) -> Self {
        self.inputs.push(path.to_path_buf());
        self.rotary_path = Some(path.to_path_buf());
        self
    }

    /// The board file (`board make BOARD`, `localize --board BOARD`).
    pub fn board_file(mut self, path: &Path) -> Self {
        self.inputs.push(path.to_path_buf());
        self.board_path = Some(path.to_path_buf());
        self
    }

    /// Another file the command reads (never written over).
    pub fn input(mut self, path: &Path) -> Self {
        self.inputs.push(path.to_path_buf());
        self
    }

    fn loaded_job(&mut self) -> Result<&Job, ContextError> {
        if self.job.is_none() {
            let path = self
                .job_path
                .as_ref()
                .ok_or_else(|| ContextError::Job("no job file was given (--config JOB)".into()))?;
            let job = Job::load(path).map_err(|e| ContextError::Job(e.to_string()))?;
            self.job = Some(job);
        }
        Ok(self.job.as_ref().expect("loaded"))
    }

    fn out(&self) -> Result<&Path, ContextError> {
        self.out
            .as_deref()
            .ok_or_else(|| ContextError::Files("no output folder was given (--out DIR)".into()))
    }
}

#[async_trait::async_trait(?Send)]
impl Context for Files<'_> {
    fn job(&mut self) -> Result<Job, ContextError> {
        self.loaded_job().cloned()
    }

    async fn bench(&mut self) -> Result<Bench<'_>, ContextError> {
        self.loaded_job()?;
        if self.devices.is_none() {
            let job = self.job.as_ref().expect("loaded");
            let opened = devices::open_devices_async(job)
                .await
                .map_err(|e| ContextError::Devices(e.to_string()))?;
            self.devices = Some(opened);
        }
        Ok(Bench {
            job: self.job.as_ref().expect("loaded"),
            devices: self.devices.as_mut().expect("opened"),
            sink: &mut *self.sink,
        })
    }

    async fn identity(&mut self) -> Result<Option<Identity>, ContextError> {
        if self.job_path.is_none() {
            return Ok(None);
        }
        let job = self.loaded_job()?.clone();
        match &self.devices {
            Some(d) => Ok(Some(crate::identity(&job, d))),
            None => crate::identity_of_job(&job)
                .await
                .map(Some)
                .map_err(|e| ContextError::Devices(e.to_string())),
        }
    }

    fn sink(&mut self) -> &mut dyn Sink {
        &mut *self.sink
    }

    fn stop(&self) -> Stop {
        self.stop.clone()
    }

    fn now(&self) -> SystemTime {
        SystemTime::now()
    }

    fn map(&mut self) -> Result<ActiveMap, ContextError> {
        let path = self
            .map_path
            .as_ref()
            .ok_or_else(|| ContextError::NoMap("no error map was given (--map MAP)".into()))?;
        let map = ErrorMap::load(path).map_err(|e| ContextError::Files(e.to_string()))?;
        let reference = crate::reference::read_record(&crate::reference::reference_path(path));
        Ok(ActiveMap {
            name: path.display().to_string(),
            map,
            reference,
        })
    }

    fn keep_reference(&mut self, record: &MapReference) -> Result<String, ContextError> {
        let map = self
            .map_path
            .as_ref()
            .ok_or_else(|| ContextError::NoMap("no error map was given (--map MAP)".into()))?;
        let path = crate::reference::reference_path(map);
        let inputs: Vec<&Path> = self.inputs.iter().map(PathBuf::as_path).collect();
        let text = crate::reference::record_json(record);
        // The record replaces the one read before (never a link to another file read).
        protocol::config::replace_output(&path, text.as_bytes(), &inputs)
            .map_err(|e| ContextError::Files(format!("writing {}: {e}", path.display())))?;
        Ok(path.display().to_string())
    }

    fn scan_journal(&mut self, name: &str) -> Result<Box<dyn ScanJournal>, ContextError> {
        let dir = self.out()?;
        std::fs::create_dir_all(dir)
            .map_err(|e| ContextError::Files(format!("creating {}: {e}", dir.display())))?;
        Ok(Box::new(FileJournal::new(
            dir.join(format!("{name}.scan.jsonl")),
        )))
    }

    fn map_shelf(&mut self) -> Result<Box<dyn MapShelf>, ContextError> {
        Ok(Box::new(FolderShelf::new(self.out()?)))
    }

    fn rotary_job(&mut self) -> Result<RotaryJob, ContextError> {
        let path = self.rotary_path.as_ref().ok_or_else(|| {
            ContextError::Job("no rotary job file was given (--config JOB)".into())
        })?;
        let text = protocol::config::read_kind(path, protocol::config::DataKind::RotaryJson)
            .map_err(|e| ContextError::Job(e.to_string()))?;
        RotaryJob::from_json(&text)
            .map_err(|e| ContextError::Job(format!("{}: {e}", path.display())))
    }

    fn errors_shelf(&mut self) -> Result<Box<dyn ErrorsShelf>, ContextError> {
        Ok(Box::new(crate::rotary::FolderShelf(
            self.out()?.to_path_buf(),
        )))
    }

    fn board(&mut self) -> Result<NamedBoard, ContextError> {
        let Some(path) = &self.board_path else {
            return Ok(NamedBoard::of_job(self.loaded_job()?.board.clone()));
        };
        let board = protocol::Board::load(path).map_err(|e| ContextError::Files(e.to_string()))?;
        // Artifacts are named after the board file.
        let name = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "board".to_string());
        Ok(NamedBoard { name, board })
    }
}

//! The one port between a procedure and its front end.
//!
//! A procedure asks its [`Context`] for everything outside itself: the job and its
//! devices (opened through the drivers' factory, never by a front end), the error map it
//! applies with the map's current reference record, the scan journal, where maps, records
//! and rotary errors are kept, the sink (progress, measurements, artifacts, frames), the
//! stop signal and the clock. There are exactly two implementations: files for the
//! command line ([`crate::files::Files`]) and the store for the service
//! (`service::context`). Which reference applies, whether a scan resumes, which identity
//! must match: those rules are the procedures', so both front ends behave alike.

use crate::Sink;
use devices::Devices;
use errormap::reference::MapReference;
use errormap::scan::{journal, Sample, ScanPlan};
use job::rotary::RotaryJob;
use job::Job;
use protocol::errormap::{ErrorMap, Identity};
use serde_json::Value;

use std::time::SystemTime;
use tokio::sync::watch;

/// Why a procedure could not get what it asked its context for.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ContextError {
    /// The job file (or the rotary job file) cannot be read.
    #[error("{0}")]
    Job(String),
    /// The devices cannot be opened.
    #[error("{0}")]
    Devices(String),
    /// No error map is given (CLI: `--map`; service: an active `error_map` profile).
    #[error("{0}")]
    NoMap(String),
    /// The map, its reference record or a kept output cannot be read or written.
    #[error("{0}")]
    Files(String),
}

/// The error map a procedure applies, named as the operator knows it (a file, a profile
/// version), with its current reference record as the front end found it: `Ok(None)`
/// when none is recorded, `Err` when one is there but cannot be read (the procedure
/// decides what that means).
#[derive(Debug, Clone)]
pub struct ActiveMap {
    pub name: String,
    pub map: ErrorMap,
    pub reference: Result<Option<MapReference>, crate::Error>,
}

/// The calibration board a procedure works with and the name its artifacts take (a
/// board file's stem on the command line; the board's own name in the service).
#[derive(Debug, Clone)]
pub struct NamedBoard {
    pub name: String,
    pub board: protocol::Board,
}

impl NamedBoard {
    /// A job's board, its artifacts named after the board's name.
    pub fn of_job(board: protocol::Board) -> Self {
        Self {
            name: file_name_of(&board.name),
            board,
        }
    }
}

/// The stop signal: raised once (Ctrl-C, a cancel, the service's shutdown), seen by
/// every clone.
#[derive(Debug, Clone)]
pub struct Stop(watch::Receiver<bool>);

impl Stop {
    /// A stop signal and the handle that raises it.
    pub fn new() -> (watch::Sender<bool>, Stop) {
        let (tx, rx) = watch::channel(false);
        (tx, Stop(rx))
    }

    /// `work` to its end, or `None` when the stop is raised first (the caller stops the
    /// stage: `work`, which held it, is dropped by then).
    pub async fn unless<T>(self, work: impl std::future::Future<Output = T>) -> Option<T> {
        tokio::select! {
            done = work => Some(done),
            _ = self.requested() => None,
        }
    }

    /// Completes once the stop is raised (never, if its sender is gone without it).
    pub async fn requested(mut self) {
        if self.0.wait_for(|s| *s).await.is_err() {
            std::future::pending::<()>().await;
        }
    }
}

/// What a procedure that moves the machine works with, borrowed from its context.
pub struct Bench<'a> {
    pub job: &'a Job,
    pub devices: &'a mut Devices,
    pub sink: &'a mut dyn Sink,
}

/// A procedure's port to its front end (see the module's text).
#[async_trait::async_trait(?Send)]
pub trait Context {
    /// The machine's job file (stage, camera, board, targets).
    fn job(&mut self) -> Result<Job, ContextError>;
    /// The job and its devices, opened through the drivers' factory on first use, with
    /// the sink.
    async fn bench(&mut self) -> Result<Bench<'_>, ContextError>;
    /// Who the machine is (stage, controller, board, camera), read from its devices, or
    /// `None` when the front end was given no machine (a rewrite of a file alone). A
    /// camera that cannot be opened leaves its field empty: a map measured with any
    /// camera then matches, and the procedure that needs the camera finds out itself.
    async fn identity(&mut self) -> Result<Option<Identity>, ContextError>;
    /// The sink alone (procedures without devices).
    fn sink(&mut self) -> &mut dyn Sink;
    /// The stop signal.
    fn stop(&self) -> Stop;
    /// The wall clock (records' times, their age).
    fn now(&self) -> SystemTime;
    /// The error map to apply, with its current reference record.
    fn map(&mut self) -> Result<ActiveMap, ContextError>;
    /// Keeps `record` as the current reference of `map`; returns where it went.
    fn keep_reference(&mut self, record: &MapReference) -> Result<String, ContextError>;
    /// The journal of a scan named `name` (a stopped scan's samples, resumed when its
    /// header matches).
    fn scan_journal(&mut self, name: &str) -> Result<Box<dyn ScanJournal>, ContextError>;
    /// Where finished maps are kept.
    fn map_shelf(&mut self) -> Result<Box<dyn MapShelf>, ContextError>;
    /// The rotary table's job (its link, probe, plan).
    fn rotary_job(&mut self) -> Result<RotaryJob, ContextError>;
    /// Where identified rotary errors are kept.
    fn errors_shelf(&mut self) -> Result<Box<dyn ErrorsShelf>, ContextError>;
    /// The calibration board: the job's (its artifacts named after the board's name:
    /// `dot-grid-0-5-mm-421-x-321-certified`), unless the front end was given a board
    /// file (named after the file).
    fn board(&mut self) -> Result<NamedBoard, ContextError> {
        Ok(NamedBoard::of_job(self.job()?.board))
    }
}

/// A name as a file name: lower-case letters and digits, every other run of characters
/// one `-` (`dot grid 0.5 mm` is `dot-grid-0-5-mm`); `board` when nothing is left.
pub fn file_name_of(name: &str) -> String {
    let mut out = String::new();
    for c in name.chars() {
        if c.is_ascii_alphanumeric() {
            out.push(c.to_ascii_lowercase());
        } else if !out.is_empty() && !out.ends_with('-') {
            out.push('-');
        }
    }
    let out = out.trim_end_matches('-').to_string();
    if out.is_empty() {
        "board".into()
    } else {
        out
    }
}

/// Seconds since 1970 of a time (0 before it).
pub fn unix_s(t: SystemTime) -> u64 {
    t.duration_since(SystemTime::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs())
}

/// Where a scan's samples are kept as they come, and where a stopped scan's are found.
pub trait ScanJournal {
    /// The samples a stopped scan of this job, machine and plan (`header`) kept (empty
    /// for a new scan); an error when what is there belongs to another scan (naming what
    /// differs) or is damaged.
    fn resume(
        &mut self,
        header: &journal::Header,
        plan: &ScanPlan,
    ) -> Result<Vec<(usize, Sample)>, crate::Error>;
    /// Keeps one sample (a failure stops the scan with the stage stopped).
    fn append(&mut self, index: usize, sample: &Sample) -> Result<(), crate::Error>;
    /// The map is kept: the journal has done its job.
    fn close(&mut self);
    /// Where resumed samples came from (the service: the stopped job), for the result.
    fn resumed_from(&self) -> Option<Value> {
        None
    }
}

/// Where the finished map goes.
pub trait MapShelf {
    /// The version the next map of `name` gets.
    fn next_version(&mut self, name: &str) -> Result<u32, crate::Error>;
    /// Keeps the map; returns where it went (a path, a profile), for the result.
    fn keep(&mut self, name: &str, map: &ErrorMap) -> Result<String, crate::Error>;
}

/// Where the identified errors are kept (the CLI: `errors.json` in its folder, written
/// as an artifact; the service: the next version of a rotary profile).
pub trait ErrorsShelf {
    /// Keeps the report; returns where it went, for the result.
    fn keep(&mut self, name: &str, report: &Value) -> Result<String, crate::Error>;
}

/// The value of a context's answer, or the procedure ends failed with the context's
/// error (what it could not give and why).
#[macro_export]
macro_rules! or_fail {
    ($answer:expr) => {
        match $answer {
            Ok(v) => v,
            Err(e) => return $crate::Outcome::failed(e.to_string()),
        }
    };
}

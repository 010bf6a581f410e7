//! One procedure per capability, shared by the command line and the service.
//!
//! Each capability is a [`request`] type (parsed and checked once, fields named), a
//! procedure here that runs it over the device traits (the decisions stay in the pure
//! crates' sessions and plans; the executors are `runner`'s), and one [`Outcome`]: the
//! object the CLI's `--json` prints, the service stores and the page shows. What a front
//! end does with progress, measurements and artifacts goes through a [`Sink`]; the stop
//! signal is a future. The CLI and the service only translate in (flags or JSON to a
//! request) and out (files and a progress bar, or the store and events).

pub mod board;
pub mod command_line;
pub mod compensate;
pub mod context;
pub mod cut;
pub mod demo;
pub mod dnc;
pub mod error;
pub mod export;
pub mod files;
pub mod frame;
pub mod iso230;
pub mod kinds;
pub mod layout;
pub mod localize;
pub mod map;
pub mod proxy;
pub mod reference;
pub mod registry;
pub mod request;
pub mod rewrite;
pub mod rotary;
mod summary;
pub mod verify;
pub mod volumetric;

use devices::Devices;
use job::Job;
use protocol::errormap::{ErrorMap, Identity};
use serde::Serialize;
use serde_json::{Map, Value};

pub use context::{ActiveMap, Bench, Context, ContextError, NamedBoard, Stop};
pub use error::Error;
pub use kinds::{summary, Request, KINDS};
pub use registry::Procedure;
pub use request::RequestError;

/// How a procedure ended.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "state", rename_all = "lowercase")]
pub enum End {
    Succeeded,
    Failed { error: String },
    Cancelled,
}

/// What a procedure gives back, however it ended: its typed result `R` (each kind's
/// [`Procedure::Result`]); the registry hands it on as JSON (`Outcome<Value>`, the
/// default), the object `--json` prints and the store keeps.
#[derive(Debug, Clone, PartialEq)]
pub struct Outcome<R = Value> {
    pub end: End,
    /// The procedure's result object (also when it stopped: what was done so far).
    pub result: Option<R>,
    /// The summary figures the plant gets (numbers and flags taken from `result`).
    pub metrics: Map<String, Value>,
    /// Set when the device link failed: the front end reopens the devices first.
    pub link_lost: Option<String>,
}

impl<R> Outcome<R> {
    pub fn succeeded(result: R, metrics: Map<String, Value>) -> Self {
        Self {
            end: End::Succeeded,
            result: Some(result),
            metrics,
            link_lost: None,
        }
    }

    /// Failed before anything was measured.
    pub fn failed(error: impl Into<String>) -> Self {
        Self {
            end: End::Failed {
                error: error.into(),
            },
            result: None,
            metrics: Map::new(),
            link_lost: None,
        }
    }

    /// Stopped by the operator before anything was kept (the stage told to stop).
    pub fn cancelled(why: &str) -> Self {
        Self::stopped(true, why.into(), None, Map::new(), false)
    }

    /// Stopped by an error (or, when `cancelled`, by the operator) with `result` so far.
    pub fn stopped(
        cancelled: bool,
        error: String,
        result: Option<R>,
        metrics: Map<String, Value>,
        link_lost: bool,
    ) -> Self {
        Self {
            end: if cancelled {
                End::Cancelled
            } else {
                End::Failed {
                    error: error.clone(),
                }
            },
            result,
            metrics,
            link_lost: (link_lost && !cancelled).then_some(error),
        }
    }

    pub fn is_success(&self) -> bool {
        self.end == End::Succeeded
    }

    /// The error message when it failed.
    pub fn error(&self) -> Option<&str> {
        match &self.end {
            End::Failed { error } => Some(error),
            _ => None,
        }
    }

    /// The same outcome with its result turned by `f` (the registry: into JSON).
    pub fn map_result<S>(self, f: impl FnOnce(R) -> S) -> Outcome<S> {
        Outcome {
            end: self.end,
            result: self.result.map(f),
            metrics: self.metrics,
            link_lost: self.link_lost,
        }
    }
}

/// A file-like product of a procedure (a chart, a table, a report).
#[derive(Debug, Clone, PartialEq)]
pub struct Artifact {
    /// A plain file name: `deviation_x.svg`, `measurements.csv`, `report.html`.
    pub name: String,
    /// A caption for a chart.
    pub title: Option<String>,
    pub media_type: &'static str,
    pub bytes: Vec<u8>,
}

/// One row of a growing log ([`Sink::log_row`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LogRow<'a> {
    /// The log's file name (an artifact's name).
    pub log: &'a str,
    /// Its first line, written before the first row (with its line end).
    pub header: &'a str,
    /// The row (with its line end).
    pub row: &'a str,
}

/// What a front end does with what a procedure produces while it runs.
pub trait Sink {
    /// `done` of `total` steps (targets, frames, measurements, balls).
    fn progress(&mut self, done: u64, total: u64);
    /// One measurement as it is taken, kept so nothing measured is lost. An error stops
    /// the procedure (with the stage stopped).
    fn measurement(&mut self, measurement: &Value) -> Result<(), crate::Error>;
    /// A product of the procedure; an error fails it naming the artifact.
    fn artifact(&mut self, artifact: Artifact) -> Result<(), crate::Error>;
    /// A product too large to hold whole (a board's artwork), written by `write` as it is
    /// made. A front that writes files streams it into the file (the command line:
    /// `protocol::config::write_output_with`); by default it is collected and handed to
    /// [`Sink::artifact`].
    fn artifact_streamed(
        &mut self,
        name: String,
        media_type: &'static str,
        write: &mut dyn FnMut(&mut dyn std::io::Write) -> std::io::Result<()>,
    ) -> Result<(), crate::Error> {
        let mut bytes = Vec::new();
        write(&mut bytes).map_err(|e| crate::Error::Output(format!("{name}: {e}")))?;
        self.artifact(Artifact {
            name,
            title: None,
            media_type,
            bytes,
        })
    }
    /// A row appended to a log that grows as the procedure goes (ISO 230-2's
    /// `measurements.csv`), so that a run stopped half-way leaves its rows in a file; the
    /// whole artifact of the same name replaces it at the end. Fronts that keep every
    /// [`Sink::measurement`] anyway (the service's store) need not keep it.
    fn log_row(&mut self, _row: &LogRow) -> Result<(), crate::Error> {
        Ok(())
    }
    /// Whether the artifacts `names` can all be kept, asked before the first is made
    /// when a refusal half-way would leave some written (a front writing files refuses
    /// one that would go over an input).
    fn check_outputs(&mut self, _names: &[String]) -> Result<(), crate::Error> {
        Ok(())
    }
    /// One result of a series as it ends (a repeated check's each check), before the
    /// series' own result: the command line prints it at once.
    fn partial_result(&mut self, _result: &Value) {}
    /// A localized camera frame for a live view (a few a second at most; the runner
    /// skips the others). Kept or dropped at will: nothing depends on it.
    fn frame(&mut self, _frame: &FrameThumb) {}
}

/// A live view's frame ([`frame::thumbnail`]): an 8-bit grey PNG at most
/// [`frame::THUMB_MAX_WIDTH`] wide and its overlay (detected dots and the measured point
/// in the thumbnail's pixels).
#[derive(Debug, Clone, PartialEq)]
pub struct FrameThumb {
    pub png: Vec<u8>,
    pub width: u32,
    pub height: u32,
    pub overlay: Value,
}

/// A sink that keeps nothing (tests, `--json` without files).
#[derive(Debug, Default)]
pub struct Discard;

impl Sink for Discard {
    fn progress(&mut self, _: u64, _: u64) {}
    fn measurement(&mut self, _: &Value) -> Result<(), crate::Error> {
        Ok(())
    }
    fn artifact(&mut self, _: Artifact) -> Result<(), crate::Error> {
        Ok(())
    }
}

/// A sink that keeps every artifact in memory (tests; a front end that hands them on
/// itself).
#[derive(Debug, Default)]
pub struct Collect(pub Vec<Artifact>);

impl Sink for Collect {
    fn progress(&mut self, _: u64, _: u64) {}
    fn measurement(&mut self, _: &Value) -> Result<(), crate::Error> {
        Ok(())
    }
    fn artifact(&mut self, artifact: Artifact) -> Result<(), crate::Error> {
        self.0.push(artifact);
        Ok(())
    }
}

/// Who is being measured or compensated: the stage (its name without the port), the
/// board and its certificate, the camera. A map records this when scanned; whoever
/// applies a map compares it with [`check_identity`].
pub fn identity(job: &Job, devices: &Devices) -> Identity {
    let stage = errormap::scan::without_link(&devices.stage.info().name);
    Identity {
        machine: stage.clone(),
        controller: stage,
        board: job.board.name.clone(),
        certificate_sha256: job.board.fingerprint_sha256(),
        camera: devices.camera.info().model.clone(),
    }
}

/// The one identity check wherever a map is applied (verify, ISO 230-2, the pass-through,
/// a rewrite whose job is known, the service): the map must have been measured on this
/// machine, controller, board certificate and camera; the error names the first field
/// that differs and both values. `what` names the map (a file, a profile).
pub fn check_identity(map: &ErrorMap, here: &Identity, what: &str) -> Result<(), Error> {
    // No camera here (none could be opened): the map's is not compared.
    let mut here = here.clone();
    if here.camera.is_empty() {
        here.camera = map.identity.camera.clone();
    }
    map.check_identity(&here).map_err(|e| {
        Error::Mismatch(format!(
            "{what}: {e}: refused (a map applies only to the machine it was measured on)"
        ))
    })
}

/// The simulated machine's clock, s, when the devices are emulated in-process.
pub fn machine_time_s(devices: &Devices) -> Option<f64> {
    devices
        .rig
        .as_ref()
        .map(|rig| world::lock(rig).machine().now_s())
}

/// The identity of the machine a job describes, read from its devices (opened, asked,
/// closed): for a front end that applies a map without keeping the devices open. The
/// stage is required; a camera that cannot be opened (a machine whose map was measured
/// once, so that programs run without the camera) leaves `camera` empty, and
/// [`check_identity`] then does not compare it.
pub async fn identity_of_job(job: &Job) -> Result<Identity, Error> {
    let (stage, rig) = devices::open_stage_async(job)
        .await
        .map_err(|e| Error::Device(format!("reading the machine's identity: {e}")))?;
    let camera = devices::open_camera(&job.camera, rig.as_ref())
        .await
        .map(|c| c.info().model.clone())
        .unwrap_or_default();
    let name = errormap::scan::without_link(&stage.info().name);
    Ok(Identity {
        machine: name.clone(),
        controller: name,
        board: job.board.name.clone(),
        certificate_sha256: job.board.fingerprint_sha256(),
        camera,
    })
}

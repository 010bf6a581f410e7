//! What the service does with a procedure's output: measurements and progress into the
//! store and out as events, the files it writes kept with the job; a map scan's journal in
//! the store (a stopped scan's samples are the next scan's start) and its map as a
//! profile version.

use crate::state::{lock, now_rfc3339, LastFrame, Shared};
use errormap::scan::{journal, Sample, ScanPlan};
use procedure::map::{sample_of, MapShelf, ScanJournal};
use procedure::{Artifact, FrameThumb, Sink};
use protocol::errormap::ErrorMap;
use serde_json::{json, Value};
use std::sync::Arc;
use store::{JobFilter, JobId, JobState, ProfileKind};

/// One running job's sink.
pub struct StoreSink {
    pub shared: Arc<Shared>,
    pub machine: String,
    pub job: JobId,
    /// The shifted layout of a layout job (its text), also kept in the job's result.
    pub layout: Option<String>,
}

impl StoreSink {
    pub fn new(shared: &Arc<Shared>, machine: &str, job: JobId) -> Self {
        Self {
            shared: shared.clone(),
            machine: machine.to_string(),
            job,
            layout: None,
        }
    }
}

/// What the store could not keep: the procedure stops (with the stage stopped).
fn kept_not(e: impl std::fmt::Display) -> procedure::Error {
    procedure::Error::Output(e.to_string())
}

impl Sink for StoreSink {
    fn progress(&mut self, done: u64, total: u64) {
        // The store's lock is released before the events (they read the store).
        let _ = lock(&self.shared.store).set_progress(self.job, done, total);
        self.shared.emit(json!({"type": "progress", "job_id": self.job, "machine": self.machine, "done": done, "total": total}));
        self.shared.publish_states();
    }

    fn measurement(&mut self, measurement: &Value) -> Result<(), procedure::Error> {
        let row = lock(&self.shared.store)
            .add_measurement(self.job, measurement)
            .map_err(kept_not)?;
        // `row` orders it against a fetch of the measurements (their
        // `X-Last-Measurement-Row`): a page appends only the events after its fetch.
        self.shared.emit(json!({"type": "measurement", "job_id": self.job, "machine": self.machine, "row": row, "measurement": measurement}));
        Ok(())
    }

    /// A partial result (the pass-through's port, a check of a series) is one of the
    /// job's measurements: kept, and sent to the page as it comes.
    fn partial_result(&mut self, result: &Value) {
        let _ = self.measurement(result);
    }

    /// The machine's last frame, in memory only (`/api/v1/machines/{machine}/frame`);
    /// the event says a new one is there, without the image.
    fn frame(&mut self, frame: &FrameThumb) {
        let Some(m) = self.shared.machine(&self.machine) else {
            return;
        };
        let last = Arc::new(LastFrame {
            png: frame.png.clone(),
            overlay: frame.overlay.clone(),
            job: self.job,
            at: now_rfc3339(),
        });
        let at = last.at.clone();
        *m.frame.lock().unwrap_or_else(|p| p.into_inner()) = Some(last);
        self.shared.emit(json!({"type": "frame", "job_id": self.job, "machine": self.machine, "at": at, "sequence": frame.overlay.get("sequence")}));
    }

    /// Every file the procedure writes is kept with the job (charts, tables, reports,
    /// the shifted layout) and served on its own (`/api/v1/jobs/{id}/files`).
    fn artifact(&mut self, artifact: Artifact) -> Result<(), procedure::Error> {
        if artifact.name.starts_with("layout.") {
            self.layout = Some(String::from_utf8_lossy(&artifact.bytes).into_owned());
        }
        lock(&self.shared.store)
            .add_job_file(
                self.job,
                &artifact.name,
                artifact.title.as_deref(),
                artifact.media_type,
                &artifact.bytes,
            )
            .map_err(kept_not)
    }
}

/// How many of a machine's latest jobs a new scan looks through for a stopped one.
const RESUME_WINDOW: usize = 1000;

/// A map job's journal: its measurements. A new scan of a profile name resumes the
/// latest stopped scan of that name on the machine when its plan is the same: the
/// stopped job's samples are copied into the new job (so it can be resumed in turn).
pub struct StoreJournal {
    pub shared: Arc<Shared>,
    pub machine: String,
    pub job: JobId,
    pub name: String,
    /// The job's params (the normalized request): only a scan asked the same way resumes.
    pub params: Value,
    /// Where the resumed samples came from (the job), or why a stopped scan was not
    /// resumed, for the result.
    pub resumed_from: Option<Value>,
}

/// The job file that keeps a scan's journal header: the next scan of the same name and
/// params resumes it only when its own header (job, machine, camera, board, plan) is the
/// same, as the CLI's journal file is checked.
pub const JOURNAL_HEADER_FILE: &str = "scan-journal-header.txt";

impl StoreJournal {
    /// The latest map job of this name on this machine that did not finish (looked for
    /// among the machine's last `RESUME_WINDOW` jobs).
    fn stopped_scan(&self) -> Result<Option<(JobId, Value)>, procedure::Error> {
        let store = lock(&self.shared.store);
        let jobs = store
            .jobs(&JobFilter {
                machine: Some(self.machine.clone()),
                state: None,
                limit: Some(RESUME_WINDOW),
                before_id: Some(self.job),
            })
            .map_err(kept_not)?;
        let latest = jobs.into_iter().find(|j| {
            j.kind == "map"
                && j.params.get("name").and_then(Value::as_str) == Some(self.name.as_str())
        });
        let latest = latest.filter(|j| j.params == self.params);
        Ok(latest
            .filter(|j| {
                matches!(
                    j.state,
                    JobState::Failed | JobState::Cancelled | JobState::Interrupted
                )
            })
            .map(|j| (j.id, j.result.unwrap_or(Value::Null))))
    }
}

impl ScanJournal for StoreJournal {
    fn resume(
        &mut self,
        header: &journal::Header,
        plan: &ScanPlan,
    ) -> Result<Vec<(usize, Sample)>, procedure::Error> {
        // This scan's header first: whoever resumes it checks it.
        lock(&self.shared.store)
            .add_job_file(
                self.job,
                JOURNAL_HEADER_FILE,
                None,
                "text/plain",
                header.line().as_bytes(),
            )
            .map_err(kept_not)?;
        let Some((id, result)) = self.stopped_scan()? else {
            return Ok(Vec::new());
        };
        // The stopped scan's header (job, machine, controller, board, camera, plan) must
        // be this one's: a scan of another camera or board starts anew, saying why.
        let stored = lock(&self.shared.store)
            .job_file(id, JOURNAL_HEADER_FILE)
            .map_err(kept_not)?;
        let differs = match stored {
            Some((_, bytes)) => journal::read(header, plan, &bytes).err(),
            None => Some(format!("job {id} kept no journal header")),
        };
        if let Some(why) = differs {
            self.resumed_from = Some(
                json!({ "not_resumed": format!("job {id}'s stopped scan: {why}: started anew") }),
            );
            return Ok(Vec::new());
        }
        // Only the same plan continues (a job interrupted by a restart has no result:
        // its samples are checked against the plan's points instead).
        if let Some(p) = result.get("plan").and_then(Value::as_str) {
            if p != plan.fingerprint() {
                return Ok(Vec::new());
            }
        }
        let rows = lock(&self.shared.store)
            .measurements(id)
            .map_err(kept_not)?;
        let mut samples = Vec::with_capacity(rows.len());
        for (k, row) in rows.iter().enumerate() {
            match sample_of(row).filter(|(i, _)| *i < plan.points.len()) {
                Some(s) => samples.push(s),
                None => {
                    return Err(procedure::Error::Input(format!(
                        "job {id}'s measurement #{k} is not a sample of this plan: {row}"
                    )))
                }
            }
        }
        let mut store = lock(&self.shared.store);
        for row in &rows {
            store.add_measurement(self.job, row).map_err(kept_not)?;
        }
        self.resumed_from = Some(json!(id));
        Ok(samples)
    }

    fn append(&mut self, _: usize, _: &Sample) -> Result<(), procedure::Error> {
        // The sink keeps every sample as a measurement of the job already.
        Ok(())
    }

    fn close(&mut self) {}

    fn resumed_from(&self) -> Option<Value> {
        self.resumed_from.clone()
    }
}

/// The machine's error_map profiles.
pub struct ProfileShelf {
    pub shared: Arc<Shared>,
    pub machine: String,
    pub job: JobId,
}

impl MapShelf for ProfileShelf {
    fn next_version(&mut self, name: &str) -> Result<u32, procedure::Error> {
        let versions = lock(&self.shared.store)
            .profiles(&self.machine)
            .map_err(kept_not)?;
        Ok(versions
            .iter()
            .filter(|p| p.name == name)
            .map(|p| p.version)
            .max()
            .unwrap_or(0)
            + 1)
    }

    fn keep(&mut self, name: &str, map: &ErrorMap) -> Result<String, procedure::Error> {
        let body: Value = serde_json::from_str(&map.to_json()).map_err(kept_not)?;
        let note = format!("scanned by job {}", self.job);
        let p = lock(&self.shared.store)
            .add_profile(
                &self.machine,
                name,
                ProfileKind::ErrorMap,
                &body,
                Some(self.job),
                Some(&note),
            )
            .map_err(kept_not)?;
        Ok(format!("error_map profile {} v{}", p.name, p.version))
    }
}

/// The machine's rotary profiles: the identified errors' report as the body.
pub struct RotaryShelf {
    pub shared: Arc<Shared>,
    pub machine: String,
    pub job: JobId,
}

impl procedure::rotary::ErrorsShelf for RotaryShelf {
    fn keep(&mut self, name: &str, report: &Value) -> Result<String, procedure::Error> {
        let note = format!("measured by job {}", self.job);
        let p = lock(&self.shared.store)
            .add_profile(
                &self.machine,
                name,
                ProfileKind::Rotary,
                report,
                Some(self.job),
                Some(&note),
            )
            .map_err(kept_not)?;
        Ok(format!("rotary profile {} v{}", p.name, p.version))
    }
}

/// The error map in an `error_map` profile's body (the map file's JSON, perhaps beside
/// drawings of it).
pub fn profile_map(body: &Value) -> Result<ErrorMap, String> {
    let text = body.get("map").unwrap_or(body).to_string();
    ErrorMap::from_json("error_map profile", &text).map_err(|e| e.to_string())
}

//! State shared by the API and the machine workers.

use serde_json::{json, Value};
use std::collections::HashMap;
use std::net::IpAddr;
use std::sync::{Arc, Mutex};
use store::{JobId, JobRecord, Store};
use tokio::sync::{broadcast, watch, Notify};

/// What a machine is doing, as the API shows it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MachineState {
    Opening,
    Idle,
    Busy,
    LinkLost,
    Stopped,
}

impl MachineState {
    pub fn as_str(self) -> &'static str {
        match self {
            MachineState::Opening => "opening",
            MachineState::Idle => "idle",
            MachineState::Busy => "busy",
            MachineState::LinkLost => "link_lost",
            MachineState::Stopped => "stopped",
        }
    }
}

#[derive(Debug, Clone)]
pub struct Status {
    pub state: MachineState,
    pub detail: Option<String>,
    pub job: Option<JobId>,
}

/// One machine: its description, live status and the handles its worker listens to.
pub struct Machine {
    pub id: String,
    pub description: String,
    pub stage: String,
    pub camera: String,
    pub map_profile: String,
    /// The A/C table's measurement link (`"sim"`, `"grbl-emulator"`, `"grbl:<port>"`);
    /// None when the machine has no rotary table (its `rotary` jobs are refused).
    pub rotary: Option<String>,
    pub status: Mutex<Status>,
    /// Woken when a job is queued for this machine.
    pub wake: Notify,
    /// Notified to cancel the job now running (a fresh one per job, so a stale
    /// cancel never stops the next job).
    pub cancel: Mutex<Option<(JobId, Arc<Notify>)>>,
    /// The area a map scan covers (machine mm), known once the devices are open: a map
    /// request whose frames would exceed the bound is refused when queued.
    pub scan_area: Mutex<Option<([f64; 2], [f64; 2])>>,
    /// The camera's last frame a job showed (memory only; none after a restart).
    pub frame: Mutex<Option<Arc<LastFrame>>>,
}

/// A machine's last camera frame: the thumbnail and its overlay, with when and by which
/// job it was taken.
pub struct LastFrame {
    pub png: Vec<u8>,
    pub overlay: serde_json::Value,
    pub job: JobId,
    /// RFC 3339 UTC with milliseconds, as the store's timestamps.
    pub at: String,
}

/// Now as RFC 3339 UTC with milliseconds: `2026-11-23T03:20:01.123Z`.
pub fn now_rfc3339() -> String {
    let d = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap_or_default();
    rfc3339(d.as_secs() as i64, d.subsec_millis())
}

/// Seconds since 1970 and milliseconds as RFC 3339 UTC (chrono's formatting).
fn rfc3339(secs: i64, ms: u32) -> String {
    chrono::DateTime::from_timestamp(secs, ms * 1_000_000)
        .unwrap_or_default()
        .to_rfc3339_opts(chrono::SecondsFormat::Millis, true)
}

pub struct Shared {
    pub store: Arc<Mutex<Store>>,
    pub machines: Vec<Arc<Machine>>,
    /// Events as serialized JSON; a client that falls behind is dropped.
    pub events: broadcast::Sender<Arc<str>>,
    pub token: String,
    pub shutdown: watch::Receiver<bool>,
    /// Wrong-token count and per peer, for the growing delay.
    pub bad_tokens: Mutex<HashMap<IpAddr, u32>>,
    pub bad_token_delay_cap_ms: u64,
    /// Every machine's state for the MQTT northbound (sent on each change).
    pub device_states: watch::Sender<Vec<northbound::DeviceState>>,
    /// Woken when a finished job has put a row in the outbox.
    pub outbox_ready: Arc<Notify>,
}

/// The store's lock; a panic while holding it does not make the data unusable
/// (each store call is its own transaction).
pub fn lock(store: &Mutex<Store>) -> std::sync::MutexGuard<'_, Store> {
    store.lock().unwrap_or_else(|p| p.into_inner())
}

/// How many of a machine's queued jobs its `Machine` object lists (`queue`).
pub const QUEUE_SHOWN: usize = 100;

impl Shared {
    pub fn machine(&self, id: &str) -> Option<&Arc<Machine>> {
        self.machines.iter().find(|m| m.id == id)
    }

    /// The API's `Machine` object.
    pub fn machine_json(&self, m: &Machine) -> Value {
        let status = m.status.lock().unwrap_or_else(|p| p.into_inner()).clone();
        let store = lock(&self.store);
        let job = status
            .job
            .and_then(|id| store.job(id).ok().flatten())
            .map(|j| serde_json::to_value(j).unwrap_or(Value::Null))
            .unwrap_or(Value::Null);
        let queue = store.queued(&m.id).unwrap_or_default();
        // The queue in run order, its first jobs (the page's queue with up/down/cancel).
        let shown: Vec<Value> = queue
            .iter()
            .take(QUEUE_SHOWN)
            .map(|j| json!({"id": j.id, "kind": j.kind, "created_at": j.created_at}))
            .collect();
        json!({
            "id": m.id, "description": m.description, "stage": m.stage, "camera": m.camera,
            "rotary": m.rotary, "state": status.state.as_str(), "state_detail": status.detail,
            "job": job, "queued": queue.len(), "queue": shown,
            // The job kinds this machine runs (a rotary job needs its A/C table).
            "kinds": procedure::KINDS.iter()
                .filter(|k| !k.uses.rotary || m.rotary.is_some())
                .map(|k| k.name)
                .collect::<Vec<_>>(),
        })
    }

    pub fn emit(&self, event: Value) {
        // No receiver is not an error: nobody is watching.
        let _ = self.events.send(Arc::from(event.to_string()));
    }

    /// The job's event; a final one wakes the northbound for the outbox. Reads the
    /// store: never call it while holding the store's lock (it is not re-entrant).
    pub fn emit_job(&self, job: &JobRecord) {
        self.emit(json!({"type": "job", "job": light_job(job)}));
        if job.state.is_final() {
            self.outbox_ready.notify_one();
        }
        self.publish_states();
    }

    /// Every machine's state, job and progress to the northbound's watch (a send with
    /// nothing changed wakes it for nothing and publishes nothing).
    pub fn publish_states(&self) {
        let store = lock(&self.store);
        let states = self
            .machines
            .iter()
            .map(|m| {
                let status = m.status.lock().unwrap_or_else(|p| p.into_inner()).clone();
                let progress = status
                    .job
                    .and_then(|id| store.job(id).ok().flatten())
                    .and_then(|j| j.progress);
                northbound::DeviceState {
                    machine: m.id.clone(),
                    state: status.state.as_str().to_string(),
                    job_id: status.job,
                    progress_done: progress.as_ref().map_or(0, |p| p.done),
                    progress_total: progress.as_ref().map_or(0, |p| p.total),
                }
            })
            .collect::<Vec<_>>();
        drop(store);
        self.device_states.send_if_modified(|old| {
            let changed = *old != states;
            *old = states;
            changed
        });
    }

    pub fn emit_machine(&self, m: &Machine) {
        let machine = self.machine_json(m);
        self.emit(json!({"type": "machine", "machine": machine}));
    }

    pub fn set_status(
        &self,
        m: &Machine,
        state: MachineState,
        detail: Option<String>,
        job: Option<JobId>,
    ) {
        {
            let mut s = m.status.lock().unwrap_or_else(|p| p.into_inner());
            s.state = state;
            s.detail = detail;
            s.job = job;
        }
        self.emit_machine(m);
        self.publish_states();
    }
}

/// A job as lists and events carry it: without its `params` and `result`, which can be
/// megabytes (a layout job carries its file and the shifted layout); `GET
/// /api/v1/jobs/{id}` has them.
pub fn light_job(record: &JobRecord) -> Value {
    let mut v = serde_json::to_value(record).unwrap_or(Value::Null);
    if let Some(o) = v.as_object_mut() {
        o.remove("params");
        o.remove("result");
    }
    v
}

#[cfg(test)]
mod time_tests {
    use super::rfc3339;

    #[test]
    fn unix_seconds_as_rfc3339() {
        assert_eq!(rfc3339(0, 0), "1970-01-01T00:00:00.000Z");
        assert_eq!(rfc3339(951_782_400, 5), "2000-02-29T00:00:00.005Z");
        assert_eq!(rfc3339(1_795_403_001, 123), "2026-11-23T03:03:21.123Z");
        assert_eq!(rfc3339(4_102_444_799, 999), "2099-12-31T23:59:59.999Z");
    }
}

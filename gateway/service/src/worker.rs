//! One machine's worker: owns the machine's devices, runs its queue (oldest first, one
//! job at a time), reopens the devices after a link loss. A job is a checked
//! [`procedure::Request`] (parsed when it was queued); the worker only resolves what the
//! machine holds (its job file, its active map), hands the procedure a sink into the
//! store, and makes sure no job can jam the machine: a panic inside a procedure ends
//! that job as failed with its message (the stage told to stop, what was measured
//! kept) and the queue goes on; a cancel that the procedure does not honour within
//! [`CANCEL_GRACE`] drops it the same way.

use crate::config::MachineConfig;
use crate::context::StoreContext;
use crate::sink::StoreSink;
use crate::state::{lock, Machine, MachineState, Shared};
use crate::supervise::{supervise, Supervised};
use devices::Devices;
use job::{CameraSpec, Job, StageSpec};
use procedure::{End, Request, Stop};
use serde_json::{Map, Value};
use std::sync::Arc;
use std::time::Duration;
use store::{JobRecord, Outcome, ProfileKind, ProfileRef};
use tokio::sync::Notify;
use tracing::{info, info_span, warn, Instrument};

/// A cancelled job's `error` when the service's shutdown stopped it.
pub const SHUTDOWN_REASON: &str = "the service was shut down while it ran (SIGTERM or a restart)";

/// How long a cancelled procedure may take to stop by itself before it is dropped.
pub const CANCEL_GRACE: Duration = Duration::from_secs(5);

/// `"<driver>"` or `"<driver>:<link>"` for the API's `stage` and `camera`.
pub fn describe(job: &Job) -> (String, String) {
    let stage = match &job.stage {
        StageSpec::Sim { .. } => "sim".to_string(),
        StageSpec::Grbl { .. } => "grbl".to_string(),
        StageSpec::Modbus(_) => "modbus".to_string(),
        StageSpec::Canopen(_) => "canopen".to_string(),
        StageSpec::Linuxcnc(spec) => format!("linuxcnc:{}", spec.address),
        StageSpec::Dnc(spec) => format!("dnc:{}", spec.port),
    };
    let camera = match &job.camera {
        CameraSpec::Sim { .. } => "sim".to_string(),
        CameraSpec::EmulatedGige { .. } => "gige-emulator".to_string(),
        CameraSpec::Gige { device, .. } => format!("gige:{device}"),
        CameraSpec::Replay { folder } => format!("replay:{}", folder.display()),
    };
    (stage, camera)
}

/// The API's `rotary` of a machine: the link its A/C table is measured through.
pub fn describe_rotary(job: &job::rotary::RotaryJob) -> String {
    match &job.link {
        None => "sim".into(),
        Some(job::rotary::RotaryLink::GrblEmulator) => "grbl-emulator".into(),
        Some(job::rotary::RotaryLink::Grbl(port)) => format!("grbl:{}", port.port),
    }
}

fn backoff(attempt: u32) -> Duration {
    Duration::from_millis((250u64 << attempt.min(6)).min(10_000))
}

/// The worker of one machine, until the service shuts down.
pub async fn run(shared: Arc<Shared>, machine: Arc<Machine>, config: MachineConfig) {
    let mut shutdown = shared.shutdown.clone();
    let mut devices: Option<Devices> = None;
    let mut attempt = 0u32;
    loop {
        if *shutdown.borrow() {
            break;
        }
        if devices.is_none() {
            shared.set_status(&machine, MachineState::Opening, None, None);
            let opened = match config.job.load() {
                Ok(job) => devices::open_devices_async(&job)
                    .await
                    .map(|d| (job, d))
                    .map_err(|e| e.to_string()),
                Err(e) => Err(e),
            };
            match opened {
                Ok((job, d)) => {
                    info!(machine = %machine.id, "devices opened");
                    // The scan area, so a map request is checked when it is queued.
                    if let Ok(limits) = runner::soft_limits(d.stage.info()) {
                        *machine.scan_area.lock().unwrap_or_else(|p| p.into_inner()) =
                            Some(runner::scan::scan_area(&job, &limits));
                    }
                    devices = Some(d);
                    attempt = 0;
                }
                Err(e) => {
                    warn!(machine = %machine.id, error = %e, "devices not opened; retrying");
                    shared.set_status(&machine, MachineState::LinkLost, Some(e), None);
                    let wait = backoff(attempt);
                    attempt += 1;
                    tokio::select! {
                        _ = tokio::time::sleep(wait) => {}
                        _ = shutdown.changed() => {}
                    }
                    continue;
                }
            }
        }
        let next = lock(&shared.store)
            .queued(&machine.id)
            .ok()
            .and_then(|q| q.into_iter().next());
        let Some(record) = next else {
            shared.set_status(&machine, MachineState::Idle, None, None);
            tokio::select! {
                _ = machine.wake.notified() => {}
                _ = shutdown.changed() => {}
            }
            continue;
        };
        let span =
            info_span!("job", job_id = record.id, machine = %machine.id, kind = %record.kind);
        // A kind that opens the controller's link itself (the pass-through): the devices
        // are closed for it and opened again after.
        if procedure::kinds::find(&record.kind).is_some_and(|k| k.uses.link) {
            devices = None;
        }
        let lost = run_one(&shared, &machine, &config, devices.as_mut(), record)
            .instrument(span)
            .await;
        if let Some(detail) = lost {
            // The link failed mid-job (or a procedure was dropped): reopen first.
            devices = None;
            shared.set_status(&machine, MachineState::LinkLost, Some(detail), None);
            tokio::select! {
                _ = tokio::time::sleep(backoff(0)) => {}
                _ = shutdown.changed() => {}
            }
        }
    }
    shared.set_status(&machine, MachineState::Stopped, None, None);
}

/// The store's outcome of a procedure's, with a layout job's shifted layout (its
/// clients take it from the result).
fn to_store(outcome: procedure::Outcome, sink: StoreSink) -> (Outcome, Option<String>) {
    let mut result = outcome.result;
    if let Some(Value::Object(o)) = &mut result {
        if let Some(layout) = sink.layout {
            o.insert("layout".into(), Value::String(layout));
        }
    }
    let metrics = outcome.metrics;
    let stored = match outcome.end {
        End::Succeeded => Outcome::Succeeded {
            result: result.unwrap_or(Value::Null),
            metrics,
        },
        End::Failed { error } => Outcome::Failed {
            error,
            result,
            metrics,
        },
        End::Cancelled => Outcome::Cancelled {
            reason: None,
            result,
            metrics,
        },
    };
    (stored, outcome.link_lost)
}

/// Runs one queued job to its end; `Some(detail)` when the device link was lost (or
/// the devices' state is unknown after a panic or a dropped procedure).
async fn run_one(
    shared: &Arc<Shared>,
    machine: &Arc<Machine>,
    config: &MachineConfig,
    mut devices: Option<&mut Devices>,
    record: JobRecord,
) -> Option<String> {
    let id = record.id;
    let cancel = Arc::new(Notify::new());
    *machine.cancel.lock().unwrap_or_else(|p| p.into_inner()) = Some((id, cancel.clone()));
    // The request was checked when it was queued; a stored one that no longer parses
    // (a database from an older version) fails here, naming the field.
    let request = Request::parse(&record.kind, &record.params);
    // The map the job uses, resolved before it starts so the record says which.
    let wants_map = request.as_ref().is_ok_and(Request::uses_map);
    let profile = if wants_map {
        lock(&shared.store)
            .active_profile(&machine.id, ProfileKind::ErrorMap)
            .ok()
            .flatten()
    } else {
        None
    };
    let profile_ref = profile.as_ref().map(|(v, _)| ProfileRef {
        name: v.name.clone(),
        version: v.version,
    });
    let started = lock(&shared.store).start(id, profile_ref);
    let started = match started {
        Ok(r) => r,
        Err(e) => {
            // Cancelled between the read and the start: nothing to run.
            warn!(error = %e, "job not started");
            *machine.cancel.lock().unwrap_or_else(|p| p.into_inner()) = None;
            return None;
        }
    };
    info!("job started");
    // Busy before the job's `running` event: a client that reacts to it finds the
    // machine busy (an `if_idle` request then gets its 409).
    shared.set_status(machine, MachineState::Busy, None, Some(id));
    shared.emit_job(&started);

    // The stop signal the procedure sees, and the worker's own watch on it: a procedure
    // that does not end within the grace period after a cancel is dropped.
    let (stop_tx, stop) = Stop::new();
    let mut shutdown = shared.shutdown.clone();
    let stop_requested = async move {
        tokio::select! {
            _ = cancel.notified() => {}
            _ = shutdown.wait_for(|s| *s) => {}
        }
    };
    let mut cx = StoreContext::new(
        shared,
        machine,
        config,
        devices.as_deref_mut(),
        &record,
        profile,
        stop,
    );
    let job_future = async {
        match &request {
            Ok(r) => r.registered().run(r.params(), &mut cx).await,
            Err(e) if e.field == "params" => {
                procedure::Outcome::failed(format!("params: {}", e.message))
            }
            Err(e) => procedure::Outcome::failed(format!("params.{e}")),
        }
    };
    let ended = supervise(job_future, stop_requested, stop_tx, CANCEL_GRACE).await;
    let sink = cx.sink;
    let (outcome, lost) = match ended {
        Supervised::Ended(outcome) => to_store(outcome, sink),
        Supervised::Panicked(message) => {
            warn!(panic = %message, "the job panicked");
            if let Some(d) = devices {
                let _ = d.stage.stop().await;
            }
            (
                Outcome::Failed {
                    error: format!("internal error: {message}; the stage was told to stop, the measurements so far are kept"),
                    result: None,
                    metrics: Map::new(),
                },
                Some(format!("job {id} panicked: {message}")),
            )
        }
        Supervised::Dropped => {
            if let Some(d) = devices {
                let _ = d.stage.stop().await;
            }
            (
                Outcome::Cancelled {
                    reason: None,
                    result: None,
                    metrics: Map::new(),
                },
                Some(format!(
                    "job {id} did not stop within {} s of its cancel and was dropped",
                    CANCEL_GRACE.as_secs()
                )),
            )
        }
    };
    *machine.cancel.lock().unwrap_or_else(|p| p.into_inner()) = None;
    // Stopped by the service's shutdown (SIGTERM), not by a Cancel: the record says so,
    // so the page can say what happened and that a scan can be resumed.
    let mut outcome = outcome;
    if let Outcome::Cancelled { reason, .. } = &mut outcome {
        if reason.is_none() && *shared.shutdown.borrow() {
            *reason = Some(SHUTDOWN_REASON.into());
        }
    }
    let finished = lock(&shared.store).finish(id, outcome);
    match finished {
        Ok(r) => {
            info!(state = %r.state, "job finished");
            shared.emit_job(&r);
        }
        Err(e) => warn!(error = %e, "job result not saved"),
    }
    lost
}

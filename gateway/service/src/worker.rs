//! One tokio task per machine: owns the machine's devices, runs its queue (oldest
//! first, one job at a time), reopens the devices after a link loss.

use crate::config::MachineConfig;
use crate::state::{lock, Machine, MachineState, Shared};
use devices::Devices;
use job::{CameraSpec, Job, StageSpec};
use runner::{Event, JobError, Orchestrator};
use serde_json::{json, Map, Value};
use std::sync::Arc;
use std::time::Duration;
use store::{JobRecord, Outcome};
use tokio::sync::Notify;
use tracing::{info, info_span, warn, Instrument};

/// Job kinds a worker runs; others are refused when queued (422).
pub const KINDS: &[&str] = &["compensate"];

/// `"<driver>"` or `"<driver>:<link>"` for the API's `stage` and `camera`.
pub fn describe(job: &Job) -> (String, String) {
    let stage = match &job.stage {
        StageSpec::Sim { .. } => "sim".to_string(),
        StageSpec::Grbl { .. } => "grbl".to_string(),
        StageSpec::Modbus(_) => "modbus".to_string(),
        StageSpec::Canopen(_) => "canopen".to_string(),
    };
    let camera = match &job.camera {
        CameraSpec::Sim { .. } => "sim".to_string(),
        CameraSpec::EmulatedGige { .. } => "gige-emulator".to_string(),
        CameraSpec::Gige { device, .. } => format!("gige:{device}"),
        CameraSpec::Replay { folder } => format!("replay:{}", folder.display()),
    };
    (stage, camera)
}

/// Checks a job's params at queue time, so a bad request changes nothing.
pub fn check_params(kind: &str, params: &Value) -> Result<(), String> {
    if !KINDS.contains(&kind) {
        return Err(format!(
            "unknown job kind {kind:?}; this service runs: {}",
            KINDS.join(", ")
        ));
    }
    let Some(obj) = params.as_object() else {
        return Err("params must be a JSON object".into());
    };
    for (key, value) in obj {
        match key.as_str() {
            "targets" => match value.as_u64() {
                Some(n) if n >= 1 => {}
                _ => {
                    return Err(format!(
                        "params.targets must be an integer >= 1, got {value}"
                    ))
                }
            },
            other => return Err(format!("params.{other}: unknown parameter of a {kind} job")),
        }
    }
    Ok(())
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
                    .map_err(|e| e.to_string()),
                Err(e) => Err(e),
            };
            match opened {
                Ok(d) => {
                    info!(machine = %machine.id, "devices opened");
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
        let lost = run_one(
            &shared,
            &machine,
            &config,
            devices.as_mut().expect("opened"),
            record,
        )
        .instrument(span)
        .await;
        if let Some(detail) = lost {
            // The link failed mid-job: reopen before the next job.
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

/// Runs one queued job to its end; `Some(detail)` when the device link was lost.
async fn run_one(
    shared: &Arc<Shared>,
    machine: &Arc<Machine>,
    config: &MachineConfig,
    devices: &mut Devices,
    record: JobRecord,
) -> Option<String> {
    let id = record.id;
    let cancel = Arc::new(Notify::new());
    *machine.cancel.lock().unwrap_or_else(|p| p.into_inner()) = Some((id, cancel.clone()));
    let started = lock(&shared.store).start(id, None);
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
    shared.emit_job(&started);
    shared.set_status(machine, MachineState::Busy, None, Some(id));

    let mut shutdown = shared.shutdown.clone();
    let stop = async move {
        tokio::select! {
            _ = cancel.notified() => {}
            _ = shutdown.wait_for(|s| *s) => {}
        }
    };
    let (outcome, lost) = match record.kind.as_str() {
        "compensate" => compensate(shared, &machine.id, config, devices, &record, stop).await,
        other => (
            Outcome::Failed {
                error: format!("job kind {other:?} is not run by this service"),
                result: None,
                metrics: Map::new(),
            },
            None,
        ),
    };
    *machine.cancel.lock().unwrap_or_else(|p| p.into_inner()) = None;
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

/// A compensation run over the machine's job file (optionally its first `targets`).
async fn compensate(
    shared: &Arc<Shared>,
    machine: &str,
    config: &MachineConfig,
    devices: &mut Devices,
    record: &JobRecord,
    stop: impl std::future::Future<Output = ()>,
) -> (Outcome, Option<String>) {
    let mut job = match config.job.load() {
        Ok(j) => j,
        Err(e) => {
            return (
                Outcome::Failed {
                    error: format!("job file: {e}"),
                    result: None,
                    metrics: Map::new(),
                },
                None,
            )
        }
    };
    if let Some(n) = record.params.get("targets").and_then(Value::as_u64) {
        job.targets.truncate(n as usize);
    }
    let id = record.id;
    let total = job.targets.len() as u64;
    let _ = lock(&shared.store).set_progress(id, 0, total);
    let mut cancelled = false;
    let mut on_event = |e: Event| match e {
        Event::Measured {
            target_index,
            measurement,
        } => {
            let m = json!({"target_index": target_index, "measurement": measurement});
            if let Err(e) = lock(&shared.store).add_measurement(id, &m) {
                warn!(error = %e, "measurement not saved");
            }
            shared.emit(
                json!({"type": "measurement", "job_id": id, "machine": machine, "measurement": m}),
            );
        }
        Event::TargetDone { outcome, of } => {
            let done = (outcome.index + 1) as u64;
            let _ = lock(&shared.store).set_progress(id, done, of as u64);
            shared.emit(json!({"type": "progress", "job_id": id, "machine": machine, "done": done, "total": of}));
        }
        Event::Homed => {}
    };
    let mut orch = Orchestrator {
        stage: devices.stage.as_mut(),
        camera: devices.camera.as_mut(),
        job: &job,
    };
    let result = {
        let cancelled_ref = &mut cancelled;
        orch.run_until(&mut on_event, async {
            stop.await;
            *cancelled_ref = true;
        })
        .await
    };
    let (completed, error) = match result {
        Ok(s) => (s.completed, None),
        Err(f) => (f.completed, Some(f.error)),
    };
    let converged = completed.iter().filter(|t| t.converged).count();
    let per_target: Vec<Value> = completed
        .iter()
        .map(|t| {
            json!({"index": t.index, "target_mm": t.target_mm, "converged": t.converged,
                   "stopped": t.stopped, "measurements": t.measurements.len()})
        })
        .collect();
    let mut metrics = Map::new();
    metrics.insert("targets_planned".into(), json!(total));
    metrics.insert("targets_done".into(), json!(completed.len()));
    metrics.insert("targets_converged".into(), json!(converged));
    let result = json!({"targets_planned": total, "targets_done": completed.len(),
                        "converged": converged, "per_target": per_target});
    if cancelled {
        return (
            Outcome::Cancelled {
                result: Some(result),
                metrics,
            },
            None,
        );
    }
    match error {
        None => (Outcome::Succeeded { result, metrics }, None),
        Some(e) => {
            let lost = matches!(e, JobError::Driver(_)).then(|| e.to_string());
            (
                Outcome::Failed {
                    error: e.to_string(),
                    result: Some(result),
                    metrics,
                },
                lost,
            )
        }
    }
}

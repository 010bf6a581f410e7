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
use store::{JobRecord, Outcome, ProfileKind, ProfileRef};
use tokio::sync::Notify;
use tracing::{info, info_span, warn, Instrument};

/// Job kinds a worker runs; others are refused when queued (422).
pub const KINDS: &[&str] = &["compensate", "iso230", "map", "verify", "layout", "rotary"];

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

/// The API's `rotary` of a machine: the link its A/C table is measured through.
pub fn describe_rotary(job: &job::rotary::RotaryJob) -> String {
    match &job.link {
        None => "sim".into(),
        Some(job::rotary::RotaryLink::GrblEmulator) => "grbl-emulator".into(),
        Some(job::rotary::RotaryLink::Grbl(port)) => format!("grbl:{}", port.port),
    }
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
    if kind == "iso230" {
        return check_iso230_params(obj);
    }
    if kind == "map" {
        return check_map_params(obj);
    }
    if kind == "verify" {
        return check_verify_params(obj);
    }
    if kind == "layout" {
        return check_layout_params(obj);
    }
    if kind == "rotary" {
        return check_rotary_params(obj);
    }
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

/// An ISO 230-2 job: `axis` ("X" or "Y", required), `positions` (>= 5; default the
/// standard's minimum for the travel), `runs` (>= 5, default 5), `with_map` (bool: test
/// with the machine's active error map, whose version the job records).
fn check_iso230_params(obj: &Map<String, Value>) -> Result<(), String> {
    match obj.get("axis").and_then(Value::as_str) {
        Some("X" | "Y") => {}
        _ => return Err("params.axis must be \"X\" or \"Y\"".into()),
    }
    for (key, value) in obj {
        match key.as_str() {
            "axis" => {}
            "positions" | "runs" => match value.as_u64() {
                Some(n) if (5..=1000).contains(&n) => {}
                _ => {
                    return Err(format!(
                        "params.{key} must be an integer from 5 to 1000 (ISO 230-2's minimum is 5), got {value}"
                    ))
                }
            },
            "with_map" => {
                if !value.is_boolean() {
                    return Err(format!("params.with_map must be true or false, got {value}"));
                }
            }
            other => return Err(format!("params.{other}: unknown parameter of an iso230 job")),
        }
    }
    Ok(())
}

/// A map scan: `name` (the error_map profile the map becomes a version of, required),
/// `grid_step_mm` (> 0), `line_step_mm` (> 0), `passes` (1..=10); defaults as `gateway map`.
fn check_map_params(obj: &Map<String, Value>) -> Result<(), String> {
    check_profile_name(obj.get("name").unwrap_or(&Value::Null))?;
    for (key, value) in obj {
        match key.as_str() {
            "name" => {}
            "grid_step_mm" | "line_step_mm" => match value.as_f64() {
                Some(v) if v > 0.0 && v.is_finite() => {}
                _ => return Err(format!("params.{key} must be a number > 0, got {value}")),
            },
            "passes" => match value.as_u64() {
                Some(1..=10) => {}
                _ => return Err(format!("params.passes must be 1 to 10, got {value}")),
            },
            other => return Err(format!("params.{other}: unknown parameter of a map job")),
        }
    }
    Ok(())
}

/// A verification with the machine's active error map (the same as `gateway verify`):
/// `points` (1..=1000, default 20), `seed` (default 1), `spot_check` (bool: a drift check
/// against `drift_threshold_um`, default 2.0).
fn check_verify_params(obj: &Map<String, Value>) -> Result<(), String> {
    for (key, value) in obj {
        match key.as_str() {
            "points" => match value.as_u64() {
                Some(1..=1000) => {}
                _ => return Err(format!("params.points must be 1 to 1000, got {value}")),
            },
            "seed" => {
                if value.as_u64().is_none() {
                    return Err(format!("params.seed must be an integer >= 0, got {value}"));
                }
            }
            "spot_check" => {
                if !value.is_boolean() {
                    return Err(format!(
                        "params.spot_check must be true or false, got {value}"
                    ));
                }
            }
            "drift_threshold_um" => match value.as_f64() {
                Some(v) if v > 0.0 && v.is_finite() => {}
                _ => {
                    return Err(format!(
                        "params.drift_threshold_um must be > 0, got {value}"
                    ))
                }
            },
            other => return Err(format!("params.{other}: unknown parameter of a verify job")),
        }
    }
    Ok(())
}

/// `params.name` of a job that makes a profile version: a plain name.
fn check_profile_name(value: &Value) -> Result<(), String> {
    match value.as_str() {
        Some(n) if crate::config::valid_id(n) => Ok(()),
        _ => Err(format!(
            "params.name must name the profile (1 to 64 letters, digits, '-' or '_'), got {value}"
        )),
    }
}

/// A measurement of the machine's A/C table (source B, as `gateway rotary measure` with
/// the machine's rotary job file): `name`, the rotary profile the identified errors
/// become a version of (default "rotary").
fn check_rotary_params(obj: &Map<String, Value>) -> Result<(), String> {
    for (key, value) in obj {
        match key.as_str() {
            "name" => check_profile_name(value)?,
            other => return Err(format!("params.{other}: unknown parameter of a rotary job")),
        }
    }
    Ok(())
}

/// A layout partition (source C, as `gateway layout partition`): `layout` (the layout
/// file's text), `format` ("json", "dxf" or "svg"), `tools` (>= 1), `window_mm`,
/// `gap_mm` (> 0), optional `width_mm`, `clearance_mm`, `widen` (bool), `assign`
/// (["PART=GROUP", ...]).
fn check_layout_params(obj: &Map<String, Value>) -> Result<(), String> {
    for required in ["layout", "format", "tools", "window_mm", "gap_mm"] {
        if !obj.contains_key(required) {
            return Err(format!("params.{required} is required for a layout job"));
        }
    }
    for (key, value) in obj {
        match key.as_str() {
            "layout" => {
                if !value.is_string() {
                    return Err("params.layout must be the layout file's text".into());
                }
            }
            "format" => match value.as_str() {
                Some("json" | "dxf" | "svg") => {}
                _ => {
                    return Err(format!(
                        "params.format must be \"json\", \"dxf\" or \"svg\", got {value}"
                    ))
                }
            },
            "tools" => match value.as_u64() {
                Some(1..=64) => {}
                _ => return Err(format!("params.tools must be 1 to 64, got {value}")),
            },
            "window_mm" | "gap_mm" | "width_mm" | "clearance_mm" => match value.as_f64() {
                Some(v) if v > 0.0 && v.is_finite() => {}
                _ => return Err(format!("params.{key} must be a number > 0, got {value}")),
            },
            "widen" => {
                if !value.is_boolean() {
                    return Err(format!("params.widen must be true or false, got {value}"));
                }
            }
            "assign" => {
                let ok = value.as_array().is_some_and(|a| {
                    a.iter()
                        .all(|v| v.as_str().is_some_and(|t| t.contains('=')))
                });
                if !ok {
                    return Err("params.assign must be a list of \"PART=GROUP\"".into());
                }
            }
            other => return Err(format!("params.{other}: unknown parameter of a layout job")),
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
    // The profile the job uses, resolved before it starts so the record says which.
    let wants_map = record.kind == "verify"
        || (record.kind == "iso230"
            && record.params.get("with_map").and_then(Value::as_bool) == Some(true));
    let profile = if wants_map {
        lock(&shared.store)
            .active_profile(&machine.id, ProfileKind::ErrorMap)
            .ok()
            .flatten()
    } else {
        None
    };
    if wants_map && profile.is_none() {
        // The store's lock is released before the event (emit_job reads the store).
        let started = lock(&shared.store).start(id, None);
        if let Ok(r) = started {
            shared.emit_job(&r);
        }
        let failed = lock(&shared.store).finish(
            id,
            Outcome::Failed {
                error: format!(
                    "{}: machine {} has no active error_map profile; activate one first",
                    if record.kind == "verify" {
                        "verify"
                    } else {
                        "params.with_map"
                    },
                    machine.id
                ),
                result: None,
                metrics: Map::new(),
            },
        );
        if let Ok(r) = failed {
            shared.emit_job(&r);
        }
        *machine.cancel.lock().unwrap_or_else(|p| p.into_inner()) = None;
        return None;
    }
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

    let mut shutdown = shared.shutdown.clone();
    let stop = async move {
        tokio::select! {
            _ = cancel.notified() => {}
            _ = shutdown.wait_for(|s| *s) => {}
        }
    };
    let (outcome, lost) = match record.kind.as_str() {
        "compensate" => compensate(shared, &machine.id, config, devices, &record, stop).await,
        "map" => map_job(shared, &machine.id, config, devices, &record, stop).await,
        "iso230" => {
            let map = profile.map(|(_, body)| body);
            iso230_job(shared, &machine.id, config, devices, &record, map, stop).await
        }
        "verify" => {
            let map = profile.map(|(_, body)| body);
            verify_job(config, devices, &record, map).await
        }
        "layout" => layout_job(&record),
        "rotary" => rotary_job(shared, &machine.id, config, &record, stop).await,
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
            shared.publish_states();
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

fn failed(error: String) -> (Outcome, Option<String>) {
    (
        Outcome::Failed {
            error,
            result: None,
            metrics: Map::new(),
        },
        None,
    )
}

/// An ISO 230-2 positioning test of one axis (the same cycle as `gateway iso230`), its
/// evaluation and deviation chart kept in the result; with `map`, compensated.
async fn iso230_job(
    shared: &Arc<Shared>,
    machine: &str,
    config: &MachineConfig,
    devices: &mut Devices,
    record: &JobRecord,
    map: Option<Value>,
    stop: impl std::future::Future<Output = ()>,
) -> (Outcome, Option<String>) {
    use iso230::plan::{targets, Cycle, CycleKind};
    use runner::iso230::{run_iso230, test_area, Iso230Spec, AXIS_NAMES};
    const OVERRUN_MM: f64 = 1.0;
    let job = match config.job.load() {
        Ok(j) => j,
        Err(e) => return failed(format!("job file: {e}")),
    };
    let p = &record.params;
    let axis = usize::from(p.get("axis").and_then(Value::as_str) == Some("Y"));
    let model = match map {
        None => None,
        Some(body) => {
            // A profile body is the map file's JSON (perhaps beside drawings of it).
            let text = body.get("map").unwrap_or(&body).to_string();
            match protocol::errormap::ErrorMap::from_json("error_map profile", &text) {
                Ok(m) => Some(errormap::MapModel::new(m)),
                Err(e) => return failed(format!("the active error_map profile: {e}")),
            }
        }
    };
    let limits = match runner::soft_limits(devices.stage.info()) {
        Ok(l) => l,
        Err(e) => return failed(e.to_string()),
    };
    let (mut lo, mut hi) = test_area(&job, &limits, OVERRUN_MM);
    if let Some(m) = &model {
        let (mlo, mhi) = m.extent();
        for k in 0..2 {
            lo[k] = lo[k].max(mlo[k]);
            hi[k] = hi[k].min(mhi[k]);
        }
    }
    let positions = p
        .get("positions")
        .and_then(Value::as_u64)
        .map(|n| n as usize);
    let runs = p.get("runs").and_then(Value::as_u64).unwrap_or(5) as usize;
    let cycle = match targets(lo[axis], hi[axis], positions)
        .map_err(|e| e.to_string())
        .and_then(|t| Cycle::new(t, runs, OVERRUN_MM, CycleKind::Linear).map_err(|e| e.to_string()))
    {
        Ok(c) => c,
        Err(e) => return failed(format!("params: {e}")),
    };
    let spec = Iso230Spec {
        axis,
        cycle: cycle.clone(),
        across_mm: (lo[1 - axis] + hi[1 - axis]) / 2.0,
        still_frames: 10,
    };
    let id = record.id;
    let total = cycle.measurements() as u64;
    let _ = lock(&shared.store).set_progress(id, 0, total);
    let mut cancelled = false;
    let run = {
        let cancelled_ref = &mut cancelled;
        run_iso230(
            &job,
            devices,
            &spec,
            model.as_ref(),
            &mut |m| {
                let v = json!({"axis": m.axis, "position_index": m.position_index,
                    "target_mm": m.target_mm, "run": m.run, "direction": m.direction,
                    "deviation_um": m.deviation_um});
                if let Err(e) = lock(&shared.store).add_measurement(id, &v) {
                    warn!(error = %e, "measurement not saved");
                }
                shared.emit(json!({"type": "measurement", "job_id": id, "machine": machine, "measurement": v}));
            },
            &mut |done, of| {
                let _ = lock(&shared.store).set_progress(id, done as u64, of as u64);
                shared.emit(json!({"type": "progress", "job_id": id, "machine": machine, "done": done, "total": of}));
                shared.publish_states();
            },
            async {
                stop.await;
                *cancelled_ref = true;
            },
        )
        .await
    };
    let run = match run {
        Ok(r) => r,
        Err(e) => {
            let lost = matches!(
                e,
                runner::iso230::Iso230Error::Reference(JobError::Driver(_))
            )
            .then(|| e.to_string());
            let taken = lock(&shared.store)
                .measurements(id)
                .map(|m| m.len())
                .unwrap_or(0);
            let result = Some(json!({"measurements_taken": taken}));
            let metrics = Map::new();
            return if cancelled {
                (Outcome::Cancelled { result, metrics }, None)
            } else {
                (
                    Outcome::Failed {
                        error: e.to_string(),
                        result,
                        metrics,
                    },
                    lost,
                )
            };
        }
    };
    let evaluation = match iso230::evaluate(&run.measurements) {
        Ok(e) => e,
        Err(e) => return failed(format!("evaluation: {e}")),
    };
    let uncertainty = iso230::Uncertainty::new(1.0, &run.still_um);
    let mut result = iso230::report::result_json(&evaluation, Some(&uncertainty));
    let label = if model.is_some() {
        "with the map"
    } else {
        "without compensation"
    };
    let chart = iso230::report::DeviationChart {
        title: format!(
            "ISO 230-2 axis {}: mean deviation and ±2s, {label}",
            AXIS_NAMES[axis]
        ),
        series: vec![iso230::report::Series {
            label: "",
            evaluation: &evaluation,
        }],
    };
    let name = format!("deviation_{}", AXIS_NAMES[axis].to_lowercase());
    match plot::render_svg(&chart, 900, 520) {
        Ok(svg) => {
            if let Some(o) = result.as_object_mut() {
                o.insert(
                    "charts".into(),
                    json!({ name: {"title": chart.title, "svg": svg} }),
                );
            }
        }
        Err(e) => warn!(error = %e, "chart not drawn"),
    }
    let f = &evaluation.figures;
    let mut metrics = Map::new();
    metrics.insert("axis".into(), json!(AXIS_NAMES[axis]));
    for (k, v) in [
        ("A_um", f.a),
        ("B_um", f.b),
        ("R_um", f.r),
        ("E_um", f.e),
        ("M_um", f.m),
    ] {
        metrics.insert(k.into(), json!(v));
    }
    (Outcome::Succeeded { result, metrics }, None)
}

/// A scan of the machine into an error map (as `gateway map`), kept as the next version
/// of the error_map profile `params.name` (inactive until activated). Each frame is a
/// measurement of the job, so a stopped scan keeps what it measured.
async fn map_job(
    shared: &Arc<Shared>,
    machine: &str,
    config: &MachineConfig,
    devices: &mut Devices,
    record: &JobRecord,
    stop: impl std::future::Future<Output = ()>,
) -> (Outcome, Option<String>) {
    use errormap::scan::{rfc3339, without_link, MapBuilder, ScanPlan, ScanSpec};
    let job = match config.job.load() {
        Ok(j) => j,
        Err(e) => return failed(format!("job file: {e}")),
    };
    let p = &record.params;
    let name = p
        .get("name")
        .and_then(Value::as_str)
        .unwrap_or("map")
        .to_string();
    let mut spec = ScanSpec::default();
    if let Some(v) = p.get("grid_step_mm").and_then(Value::as_f64) {
        spec.grid_step_mm = v;
    }
    if let Some(v) = p.get("line_step_mm").and_then(Value::as_f64) {
        spec.line_step_mm = v;
    }
    if let Some(v) = p.get("passes").and_then(Value::as_u64) {
        spec.passes = v as u32;
    }
    let limits = match runner::soft_limits(devices.stage.info()) {
        Ok(l) => l,
        Err(e) => return failed(e.to_string()),
    };
    let (lo, hi) = runner::scan::scan_area(&job, &limits);
    let plan = match ScanPlan::new(lo, hi, spec) {
        Ok(p) => p,
        Err(e) => return failed(format!("the scan plan: {e}")),
    };
    let stage_name = without_link(&devices.stage.info().name);
    let identity = protocol::errormap::Identity {
        machine: stage_name.clone(),
        controller: stage_name,
        board: job.board.name.clone(),
        certificate_sha256: job.board.fingerprint_sha256(),
        camera: devices.camera.info().model.clone(),
    };
    let id = record.id;
    let total = plan.points.len() as u64;
    let _ = lock(&shared.store).set_progress(id, 0, total);
    let mut builder = MapBuilder::new();
    let mut cancelled = false;
    let run = {
        let cancelled_ref = &mut cancelled;
        runner::scan::run_scan(
            &job,
            devices,
            &plan,
            &mut builder,
            &mut |index, sample| {
                let v = json!({"index": index, "sample": errormap::scan::journal::line(index, sample).trim_end()});
                lock(&shared.store)
                    .add_measurement(id, &v)
                    .map(|_| ())
                    .map_err(|e| e.to_string())
            },
            &mut |done, of| {
                let _ = lock(&shared.store).set_progress(id, done as u64, of as u64);
                shared.emit(json!({"type": "progress", "job_id": id, "machine": machine, "done": done, "total": of}));
                shared.publish_states();
            },
            async {
                stop.await;
                *cancelled_ref = true;
            },
        )
        .await
    };
    let reference = match run {
        Ok(r) => r,
        Err(e) => {
            let result = Some(json!({"frames_taken": builder.done(), "frames_planned": total}));
            let lost = matches!(e, runner::scan::ScanError::Reference(JobError::Driver(_)))
                .then(|| e.to_string());
            return if cancelled {
                (
                    Outcome::Cancelled {
                        result,
                        metrics: Map::new(),
                    },
                    None,
                )
            } else {
                (
                    Outcome::Failed {
                        error: e.to_string(),
                        result,
                        metrics: Map::new(),
                    },
                    lost,
                )
            };
        }
    };
    let store_version = lock(&shared.store)
        .profiles(machine)
        .map(|v| {
            v.iter()
                .filter(|p| p.name == name)
                .map(|p| p.version)
                .max()
                .unwrap_or(0)
                + 1
        })
        .unwrap_or(1);
    let Some(map) = builder.finish(
        &plan,
        identity,
        store_version,
        rfc3339(std::time::SystemTime::now()),
        [0.0, 0.0],
        job.board_at_machine_zero_mm,
        reference.command_mm,
    ) else {
        return failed("the scan ended without every frame".into());
    };
    let body: Value = match serde_json::from_str(&map.to_json()) {
        Ok(v) => v,
        Err(e) => return failed(format!("the map's JSON: {e}")),
    };
    let note = format!("scanned by job {id}");
    let profile = match lock(&shared.store).add_profile(
        machine,
        &name,
        ProfileKind::ErrorMap,
        &body,
        Some(id),
        Some(&note),
    ) {
        Ok(p) => p,
        Err(e) => return failed(format!("the map was measured but not stored: {e}")),
    };
    let mut metrics = Map::new();
    metrics.insert("frames".into(), json!(total));
    metrics.insert("uncertainty_um".into(), json!(map.uncertainty_um));
    metrics.insert("profile_version".into(), json!(profile.version));
    let result = json!({
        "profile": {"name": profile.name, "version": profile.version},
        "frames": total, "grid": [plan.xs.len(), plan.ys.len()],
        "lines": [plan.x_line.len(), plan.y_line.len()], "passes": spec.passes,
        "uncertainty_um": map.uncertainty_um,
    });
    (Outcome::Succeeded { result, metrics }, None)
}

/// The machine's error map read from a profile body (the map file's JSON, perhaps beside
/// drawings of it).
fn map_model(body: &Value) -> Result<errormap::MapModel, String> {
    let text = body.get("map").unwrap_or(body).to_string();
    protocol::errormap::ErrorMap::from_json("error_map profile", &text)
        .map(errormap::MapModel::new)
        .map_err(|e| format!("the active error_map profile: {e}"))
}

/// A verification with the active map (see [`check_verify_params`]).
async fn verify_job(
    config: &MachineConfig,
    devices: &mut Devices,
    record: &JobRecord,
    map: Option<Value>,
) -> (Outcome, Option<String>) {
    let job = match config.job.load() {
        Ok(j) => j,
        Err(e) => return failed(format!("job file: {e}")),
    };
    let Some(model) = map.as_ref().map(map_model) else {
        return failed("verify: no active error_map profile".into());
    };
    let model = match model {
        Ok(m) => m,
        Err(e) => return failed(e),
    };
    let p = &record.params;
    let spot = p.get("spot_check").and_then(Value::as_bool) == Some(true);
    let n = p
        .get("points")
        .and_then(Value::as_u64)
        .unwrap_or(if spot { 5 } else { 20 }) as usize;
    let seed = p.get("seed").and_then(Value::as_u64).unwrap_or(1);
    let threshold = p
        .get("drift_threshold_um")
        .and_then(Value::as_f64)
        .unwrap_or(2.0);
    let points = runner::verify::check_points(&model, n, seed);
    let (checked, error) = match runner::verify::run_verify(&job, devices, &model, &points).await {
        Ok(v) => (v.points, None),
        Err((e, so_far)) => (so_far, Some(e)),
    };
    let norm = |v: [f64; 2]| v[0].hypot(v[1]);
    let (res_max, res_rms) = runner::verify::max_rms(checked.iter().map(|c| norm(c.residual_um)));
    let (unc_max, unc_rms) =
        runner::verify::max_rms(checked.iter().map(|c| norm(c.uncompensated_um)));
    let rescan = spot && res_max > threshold;
    let result = json!({
        "points": checked.iter().map(|c| json!({
            "x_mm": c.nominal_mm[0], "y_mm": c.nominal_mm[1],
            "command_mm": c.command_mm, "residual_um": c.residual_um,
            "uncompensated_um": c.uncompensated_um,
        })).collect::<Vec<_>>(),
        "residual_um": {"max": res_max, "rms": res_rms},
        "uncompensated_um": {"max": unc_max, "rms": unc_rms},
        "spot_check": spot, "drift_threshold_um": threshold, "rescan": rescan,
    });
    let mut metrics = Map::new();
    metrics.insert("points".into(), json!(checked.len()));
    metrics.insert("residual_max_um".into(), json!(res_max));
    metrics.insert("residual_rms_um".into(), json!(res_rms));
    metrics.insert("uncompensated_max_um".into(), json!(unc_max));
    metrics.insert("rescan".into(), json!(rescan));
    match error {
        None => (Outcome::Succeeded { result, metrics }, None),
        Some(e) => {
            let lost = matches!(
                e,
                runner::verify::VerifyError::Point {
                    source: JobError::Driver(_),
                    ..
                } | runner::verify::VerifyError::Reference(JobError::Driver(_))
            )
            .then(|| e.to_string());
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

/// A measurement of the A/C table through the machine's rotary link (see
/// [`check_rotary_params`]): the paper's probing cycle on a blocking thread (it drives
/// its link move by move), progress per ball, every ball's fitted sphere kept as a
/// measurement (a stopped cycle keeps those it measured), and the identified errors kept
/// as the next version of the rotary profile `params.name` (inactive until activated).
async fn rotary_job(
    shared: &Arc<Shared>,
    machine: &str,
    config: &MachineConfig,
    record: &JobRecord,
    stop: impl std::future::Future<Output = ()>,
) -> (Outcome, Option<String>) {
    use std::sync::atomic::{AtomicBool, Ordering};
    let Some(source) = &config.rotary else {
        return failed(format!("machine {machine} has no rotary job file"));
    };
    let job = match source.load() {
        Ok(j) => j,
        Err(e) => return failed(format!("rotary job file: {e}")),
    };
    let name = record
        .params
        .get("name")
        .and_then(Value::as_str)
        .unwrap_or("rotary")
        .to_string();
    let constants = job.machine.unwrap_or_default();
    let id = record.id;
    let stop_flag = Arc::new(AtomicBool::new(false));
    let cycle = {
        let (shared, flag, machine) = (shared.clone(), stop_flag.clone(), machine.to_string());
        tokio::task::spawn_blocking(move || {
            runner::rotary::run_cycle(
                &job,
                |done, of| {
                    // The store's lock is released before the events (they read it).
                    let _ = lock(&shared.store).set_progress(id, done as u64, of as u64);
                    shared.emit(json!({"type": "progress", "job_id": id, "machine": machine, "done": done, "total": of}));
                    shared.publish_states();
                },
                &flag,
            )
        })
    };
    tokio::pin!(cycle);
    let mut cancelled = false;
    let joined = tokio::select! {
        r = &mut cycle => r,
        _ = stop => {
            // The cycle ends before its next move, keeping what it measured.
            cancelled = true;
            stop_flag.store(true, Ordering::Relaxed);
            cycle.await
        }
    };
    let run = match joined {
        Ok(Ok(run)) => run,
        Ok(Err(e)) => return failed(format!("{e:#}")),
        Err(e) => return failed(format!("the measurement cycle ended abnormally: {e}")),
    };
    let (m, stopped) = match &run.cycle {
        Ok(m) => (m, None),
        Err(s) => (&s.so_far, Some(s.error.to_string())),
    };
    for b in &m.balls {
        let v = json!({"axis": b.axis.to_string(), "step": b.step, "angle_deg": b.angle_deg,
            "ball": b.ball, "centre_mm": b.sphere.centre, "radius_mm": b.sphere.radius_mm,
            "rms_um": b.sphere.rms_mm * 1e3, "points": b.points});
        if let Err(e) = lock(&shared.store).add_measurement(id, &v) {
            warn!(error = %e, "measurement not saved");
        }
    }
    if let Some(error) = stopped {
        let result =
            Some(json!({"balls_measured": m.balls.len(), "probe_touches": m.probe_touches}));
        return if cancelled {
            (
                Outcome::Cancelled {
                    result,
                    metrics: Map::new(),
                },
                None,
            )
        } else {
            (
                Outcome::Failed {
                    error: format!("the measurement cycle stopped: {error}"),
                    result,
                    metrics: Map::new(),
                },
                None,
            )
        };
    }
    let rows = m.centres();
    let identified = match rotary::identify(&rows, &constants) {
        Ok(i) => i,
        Err(e) => return failed(format!("identification: {e}")),
    };
    let mut report = match runner::rotary::cycle_report(&run, m, &identified, &constants) {
        Ok(r) => r,
        Err(e) => return failed(format!("the report: {e:#}")),
    };
    let note = format!("measured by job {id}");
    let profile = match lock(&shared.store).add_profile(
        machine,
        &name,
        ProfileKind::Rotary,
        &report,
        Some(id),
        Some(&note),
    ) {
        Ok(p) => p,
        Err(e) => return failed(format!("the errors were identified but not stored: {e}")),
    };
    let mut metrics = Map::new();
    for (error, v) in identified.errors.named() {
        metrics.insert(error.into(), json!(v));
    }
    metrics.insert("balls".into(), json!(m.balls.len()));
    metrics.insert("profile_version".into(), json!(profile.version));
    let chart = rotary::chart::SweepChart {
        rows: &rows,
        identification: &identified,
        magnification: 1000.0,
    };
    if let Some(obj) = report.as_object_mut() {
        obj.insert(
            "profile".into(),
            json!({"name": profile.name, "version": profile.version}),
        );
        match plot::render_svg(&chart, 1000, 460) {
            Ok(svg) => {
                obj.insert(
                    "charts".into(),
                    json!({"rotary_sweeps": {"title": "Ball centres and fitted circles (deviations x1000)", "svg": svg}}),
                );
            }
            Err(e) => warn!(error = %e, "chart not drawn"),
        }
    }
    (
        Outcome::Succeeded {
            result: report,
            metrics,
        },
        None,
    )
}

/// A layout partition (see [`check_layout_params`]); no device moves.
fn layout_job(record: &JobRecord) -> (Outcome, Option<String>) {
    use layout_io::{Format, Layout, ReadOptions};
    let p = &record.params;
    let format = match p.get("format").and_then(Value::as_str) {
        Some("dxf") => Format::Dxf,
        Some("svg") => Format::Svg,
        _ => Format::Json,
    };
    let text = p.get("layout").and_then(Value::as_str).unwrap_or("");
    let doc = match Layout::read(text.as_bytes(), format, &ReadOptions::default()) {
        Ok(d) => d,
        Err(e) => return failed(format!("params.layout: {e}")),
    };
    let num = |k: &str| p.get(k).and_then(Value::as_f64);
    let params = layout::Params {
        tools: p.get("tools").and_then(Value::as_u64).unwrap_or(1) as usize,
        window_mm: num("window_mm").unwrap_or(0.0),
        gap_mm: num("gap_mm").unwrap_or(0.0),
        width_mm: num("width_mm").or(doc.width_mm),
        clearance_mm: num("clearance_mm"),
    };
    let forced: Vec<(String, usize)> = p
        .get("assign")
        .and_then(Value::as_array)
        .map(|a| {
            a.iter()
                .filter_map(Value::as_str)
                .filter_map(|t| {
                    let (part, group) = t.rsplit_once('=')?;
                    Some((
                        part.to_string(),
                        group.trim().trim_start_matches(['G', 'g']).parse().ok()?,
                    ))
                })
                .collect()
        })
        .unwrap_or_default();
    let outcome = (|| {
        let mut partition = layout::partition(&doc.parts, &params)?;
        let pinned = layout::assign(&doc.parts, &mut partition, &forced)?;
        let resolution = if p.get("widen").and_then(Value::as_bool) == Some(true) {
            layout::resolve_widening(&doc.parts, &mut partition, &pinned)?
        } else {
            layout::resolve(&doc.parts, &mut partition, &pinned)?
        };
        Ok::<_, layout::PartitionError>((partition, resolution))
    })();
    let (partition, resolution) = match outcome {
        Ok(r) => r,
        Err(e) => return failed(e.to_string()),
    };
    let report = layout::report(&doc.parts, &partition, &resolution);
    let shifted = match doc
        .translated(&partition.offsets())
        .and_then(|l| l.write(format))
    {
        Ok(bytes) => String::from_utf8_lossy(&bytes).into_owned(),
        Err(e) => return failed(format!("writing the shifted layout: {e}")),
    };
    let mut metrics = Map::new();
    metrics.insert("parts".into(), json!(report.parts));
    metrics.insert("groups".into(), json!(report.groups.len()));
    metrics.insert("overlaps_found".into(), json!(report.overlaps_resolved));
    metrics.insert("moves".into(), json!(report.moves.len()));
    metrics.insert(
        "length_mm".into(),
        json!(report.figures.partitioned.length_mm),
    );
    metrics.insert(
        "utilisation".into(),
        json!(report.figures.partitioned.utilisation),
    );
    // The CLI's `--json` report, with the shifted layout in the format it was given.
    let mut result = serde_json::to_value(&report).unwrap_or(Value::Null);
    if let Some(o) = result.as_object_mut() {
        o.insert("layout".into(), json!(shifted));
    }
    (Outcome::Succeeded { result, metrics }, None)
}

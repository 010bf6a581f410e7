//! Compensation of the job's targets: the session's loop on the devices, the report.

use crate::command_line::{self, FileArg};
use crate::request::CompensateRequest;
use crate::{Outcome, Sink};
use compensation::report::Report;
use devices::Devices;
use job::Job;
use runner::{Event, JobError};
use serde::{Deserialize, Serialize};
use serde_json::Map;
use std::cell::Cell;
use std::future::Future;

/// A compensation run's result: the compensation report as it is (also what was done
/// when it stopped). Its schema is an object: the report's fields are the pure crate's
/// (`job`, `stage`, `camera`, `method`, `targets`, `targets_planned`, `converged`,
/// `before_um`, `after_um`, `estimate_before_um`, `estimate_after_um` (each `max`,
/// `rms`, `mean`, um), `iterations`, `wall_time_s`, `per_target`, ...), and that crate
/// carries no schema derive.
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(transparent)]
#[schema(value_type = Object)]
pub struct CompensateResult(pub Report);

/// One measurement as the sink gets it: the target's index and the measurement.
#[derive(Serialize)]
struct TargetMeasurement<'a, M> {
    target_index: usize,
    measurement: &'a M,
}

/// Runs the job's targets (the first `targets` of them) and reports them: the result is
/// the compensation report (`compensation::report::Report`), truth figures only on a
/// simulated machine. Each measurement goes to the sink as it is taken.
pub async fn run(
    request: &CompensateRequest,
    job: &Job,
    devices: &mut Devices,
    sink: &mut dyn Sink,
    stop: impl Future<Output = ()>,
) -> Outcome<CompensateResult> {
    let mut job = job.clone();
    if let Some(n) = request.targets {
        job.targets.truncate(n as usize);
    }
    if let Some(m) = request.method {
        job.localize.method = m;
    }
    let total = job.targets.len() as u64;
    sink.progress(0, total);
    let cancelled = Cell::new(false);
    let mut sink_error: Option<crate::Error> = None;
    let mut on_event = |e: &Event| match e {
        Event::Measured {
            target_index,
            measurement,
        } => {
            let m = TargetMeasurement {
                target_index: *target_index,
                measurement: *measurement,
            };
            let sent = serde_json::to_value(&m)
                .map_err(|e| crate::Error::Output(format!("a measurement: {e}")))
                .and_then(|m| sink.measurement(&m));
            if let Err(err) = sent {
                sink_error.get_or_insert(err);
            }
        }
        Event::TargetDone { outcome, of } => sink.progress((outcome.index + 1) as u64, *of as u64),
        Event::Frame(seen) => {
            // A live view's frame: one that cannot be made is skipped, nothing depends
            // on it.
            if let Ok(thumb) = crate::frame::thumbnail(seen) {
                sink.frame(&thumb);
            }
        }
        Event::Homed => {}
    };
    let (report, error) = runner::run_job_events(&job, devices, &mut on_event, async {
        stop.await;
        cancelled.set(true);
    })
    .await;
    let mut metrics = Map::new();
    metrics.insert("targets_planned".into(), report.targets_planned.into());
    metrics.insert("targets_done".into(), report.targets.into());
    metrics.insert("targets_converged".into(), report.converged.into());
    let (targets, converged) = (report.targets, report.converged);
    let result = CompensateResult(report);
    if let Some(e) = sink_error {
        return Outcome::stopped(
            false,
            format!("a measurement was not kept: {e}"),
            Some(result),
            metrics,
            false,
        );
    }
    match error {
        None if converged == targets => Outcome::succeeded(result, metrics),
        None => Outcome::stopped(
            false,
            format!(
                "{} of {targets} targets did not converge",
                targets - converged
            ),
            Some(result),
            metrics,
            false,
        ),
        Some(e) => {
            let lost = matches!(e, JobError::Driver(_));
            Outcome::stopped(cancelled.get(), e.to_string(), Some(result), metrics, lost)
        }
    }
}

/// The compensation job as a registered procedure.
pub struct Compensate;

impl crate::registry::Procedure for Compensate {
    const KIND: &'static str = "compensate";
    const TITLE: &'static str =
        "Compensate: move to each target, measure with the camera, correct until on target";
    const COMMAND: &'static str = "compensate";
    const LABEL: &'static str = "Compensation run";
    const HELP: &'static str = "Visits the job's targets and measures each with the camera: the error before and after compensation.";
    const FIELD_HELP: &'static [(&'static str, &'static str)] = &[
        ("targets", "How many of the job's targets to visit, from the first. Empty: all of them."),
        ("method", "How a position is worked out from the board: fit (all dots) or four-point. Empty: the job's own."),
    ];
    const USES: crate::registry::Uses = crate::registry::Uses::DEVICES;
    type Request = CompensateRequest;
    type Result = CompensateResult;
    const FILES: &'static [FileArg] = &[FileArg::required(
        "config",
        "The job file (stage, camera, board, targets).",
        command_line::job,
    )];
    const STEPS: &'static str = "targets";

    async fn run(
        request: CompensateRequest,
        cx: &mut dyn crate::Context,
    ) -> Outcome<CompensateResult> {
        let stop = cx.stop();
        let bench = crate::or_fail!(cx.bench().await);
        run(
            &request,
            bench.job,
            bench.devices,
            bench.sink,
            stop.requested(),
        )
        .await
    }

    /// The report's text (per target, then the figures).
    fn summary(result: &CompensateResult) -> String {
        result.0.to_text()
    }
}

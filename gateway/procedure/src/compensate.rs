//! Compensation of the job's targets: the session's loop on the devices, the report.

use crate::command_line::{self, FileArg};
use crate::request::CompensateRequest;
use crate::{Outcome, Sink};
use compensation::report::Report;
use devices::Devices;
use job::Job;
use runner::{Event, JobError};
use serde_json::{json, Map};
use std::cell::Cell;
use std::future::Future;

/// Runs the job's targets (the first `targets` of them) and reports them: the result is
/// the compensation report (`compensation::report::Report`), truth figures only on a
/// simulated machine. Each measurement goes to the sink as it is taken.
pub async fn run(
    request: &CompensateRequest,
    job: &Job,
    devices: &mut Devices,
    sink: &mut dyn Sink,
    stop: impl Future<Output = ()>,
) -> Outcome {
    run_with_report(request, job, devices, sink, stop).await.0
}

/// [`run`], with the typed report beside the outcome (the CLI prints it as text).
pub async fn run_with_report(
    request: &CompensateRequest,
    job: &Job,
    devices: &mut Devices,
    sink: &mut dyn Sink,
    stop: impl Future<Output = ()>,
) -> (Outcome, Report) {
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
            let m = json!({"target_index": target_index, "measurement": measurement});
            if let Err(err) = sink.measurement(&m) {
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
    let result = serde_json::to_value(&report).unwrap_or_default();
    let mut metrics = Map::new();
    metrics.insert("targets_planned".into(), json!(report.targets_planned));
    metrics.insert("targets_done".into(), json!(report.targets));
    metrics.insert("targets_converged".into(), json!(report.converged));
    if let Some(e) = sink_error {
        let o = Outcome::stopped(
            false,
            format!("a measurement was not kept: {e}"),
            Some(result),
            metrics,
            false,
        );
        return (o, report);
    }
    let outcome = match error {
        None if report.converged == report.targets => Outcome::succeeded(result, metrics),
        None => Outcome::stopped(
            false,
            format!(
                "{} of {} targets did not converge",
                report.targets - report.converged,
                report.targets
            ),
            Some(result),
            metrics,
            false,
        ),
        Some(e) => {
            let lost = matches!(e, JobError::Driver(_));
            Outcome::stopped(cancelled.get(), e.to_string(), Some(result), metrics, lost)
        }
    };
    (outcome, report)
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
    type Result = serde_json::Value;
    const FILES: &'static [FileArg] = &[FileArg::required(
        "config",
        "The job file (stage, camera, board, targets).",
        command_line::job,
    )];
    const STEPS: &'static str = "targets";

    async fn run(request: CompensateRequest, cx: &mut dyn crate::Context) -> Outcome {
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
    fn summary(result: &serde_json::Value) -> String {
        serde_json::from_value::<Report>(result.clone())
            .map(|r| r.to_text())
            .unwrap_or_else(|_| crate::summary::compensate_summary(result))
    }
}

//! Verification of an error map with the camera: home, re-reference the map at its
//! reference point, move to random points with the map's command, measure.

use crate::command_line::{self, FileArg};
use crate::request::VerifyRequest;
use crate::{Outcome, Sink};
use devices::Devices;
use errormap::reference::MapReference;
use errormap::{Approach, MapModel};
use job::Job;
use protocol::errormap::ErrorMap;
use runner::verify::{check_points, max_rms, run_verify_with, CheckedPoint, VerifyError};
use runner::JobError;
use serde::{Deserialize, Serialize};

/// A map's check: the points checked, the figures, and (a spot check) whether the
/// machine needs a new scan. A series of checks (`repeat`) is its last check with every
/// check in `checks`.
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
pub struct VerifyResult {
    /// Which check of a series, from 1.
    pub round: u64,
    /// The points checked (those done before it stopped, when it did).
    #[schema(inline)]
    pub points: Vec<VerifiedPoint>,
    /// Where the camera was at the map's reference point after homing, um (the map is
    /// shifted by it); null when it stopped before.
    pub reference_um: Option<[f64; 2]>,
    /// The map's recorded reference a spot check applied (null: it homed).
    #[schema(inline)]
    pub recorded_reference: Option<RecordedReference>,
    /// The zero's drift since the recorded reference, um.
    pub drift_since_reference_um: Option<[f64; 2]>,
    /// The residuals' size with the map, um.
    #[schema(inline)]
    pub residual_um: MaxRms,
    /// The error the map predicts without compensation at the points, um.
    #[schema(inline)]
    pub uncompensated_um: MaxRms,
    /// The mean residual on X and Y, um.
    pub drift_um: [f64; 2],
    /// Whether it was a spot check.
    pub spot_check: bool,
    /// A residual beyond this asks for a new scan (spot check), um.
    pub drift_threshold_um: f64,
    /// A new scan is needed (in a series: any check asked it).
    pub rescan: bool,
    /// Why the spot check homed although one was asked without homing (no reference
    /// recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub warning: Option<String>,
    /// In a series: how many checks it has.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub of: Option<u64>,
    /// In a series: every check, in order (the last is this one).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(no_recursion)]
    pub checks: Option<Vec<VerifyResult>>,
}

/// One checked point.
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
pub struct VerifiedPoint {
    /// The point, machine mm.
    pub x_mm: f64,
    pub y_mm: f64,
    /// The approach direction on X and Y: `++`, `+-`, `-+`, `--`.
    pub approach: String,
    /// The command the map gave, mm.
    pub command_x_mm: f64,
    pub command_y_mm: f64,
    /// Where the camera really was minus the point, um.
    pub residual_um: [f64; 2],
    /// The error the map predicts there without compensation, um.
    pub uncompensated_um: [f64; 2],
}

/// The largest and the RMS length of a set of errors, um.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, utoipa::ToSchema)]
pub struct MaxRms {
    pub max: f64,
    pub rms: f64,
}

/// The recorded reference a spot check applied.
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
pub struct RecordedReference {
    /// When it was recorded (RFC 3339).
    pub measured_at: String,
    /// Its age at the check, s.
    pub age_s: u64,
    /// Its number since the scan, from 1.
    pub reference_count: u64,
    /// The zero's shift it recorded, um.
    pub shift_um: [f64; 2],
    /// It in one line (which, when, the shift).
    pub describe: String,
}

impl VerifiedPoint {
    fn of(p: &CheckedPoint) -> Self {
        let side = |a: Approach| if a == Approach::Forward { "+" } else { "-" };
        Self {
            x_mm: p.nominal_mm[0],
            y_mm: p.nominal_mm[1],
            approach: format!("{}{}", side(p.dir.x), side(p.dir.y)),
            command_x_mm: p.command_mm[0],
            command_y_mm: p.command_mm[1],
            residual_um: p.residual_um,
            uncompensated_um: p.uncompensated_um,
        }
    }
}

/// Checks `map` (named `what` in messages) on this machine: refused before any motion
/// when it was measured on another machine, controller, board or camera. `round`
/// (from 0) picks fresh points for a repeated check. With the map's current reference
/// (`gateway reference`'s record) a spot check does not home: it applies the recorded
/// reference, as `rewrite` and `proxy` do, and reports the zero's drift since it
/// (`drift_since_reference_um`, with the record's `recorded_reference`: when, how old,
/// the shift); a record of another map is refused. Otherwise it homes and
/// re-references the map at its reference point. The result: [`VerifyResult`].
#[allow(clippy::too_many_arguments)]
pub async fn check_map(
    request: &VerifyRequest,
    job: &Job,
    devices: &mut Devices,
    map: ErrorMap,
    what: &str,
    reference: Option<&MapReference>,
    now: std::time::SystemTime,
    sink: &mut dyn Sink,
) -> Outcome<VerifyResult> {
    let round = request.round;
    if let Err(e) = crate::check_identity(&map, &crate::identity(job, devices), what) {
        return Outcome::failed(e);
    }
    let reference = reference.filter(|_| request.spot_check);
    if let Some(r) = reference {
        if let Err(e) = r.check_map(&map) {
            return Outcome::failed(format!("{what}: {e}"));
        }
    }
    // A recorded reference's axis scale (issue 39) applies as everywhere else; its shift
    // is applied by the check itself (`run_verify_with`).
    let model = match reference {
        Some(r) => match MapModel::new(map).rescaled(r.scale_ppm()) {
            Ok(m) => m,
            Err(e) => return Outcome::failed(format!("{what}: {e}")),
        },
        None => MapModel::new(map),
    };
    let points = check_points(
        &model,
        request.point_count(),
        request.seed.wrapping_add(round),
    );
    sink.progress(0, points.len() as u64);
    let recorded = reference.map(|r| r.seen_um);
    let verified = run_verify_with(job, devices, &model, &points, recorded).await;
    let (seen, checked, error) = match verified {
        Ok(v) => (Some(v.reference_um), v.points, None),
        Err((e, so_far)) => (None, so_far, Some(e)),
    };
    let checked_points: Vec<VerifiedPoint> = checked.iter().map(VerifiedPoint::of).collect();
    for p in &checked_points {
        if let Ok(m) = serde_json::to_value(p) {
            let _ = sink.measurement(&m);
        }
    }
    sink.progress(checked.len() as u64, points.len() as u64);
    let norm = |v: [f64; 2]| v[0].hypot(v[1]);
    let (res_max, res_rms) = max_rms(checked.iter().map(|p| norm(p.residual_um)));
    let (unc_max, unc_rms) = max_rms(checked.iter().map(|p| norm(p.uncompensated_um)));
    let k = checked.len().max(1) as f64;
    let drift = [
        checked.iter().map(|p| p.residual_um[0]).sum::<f64>() / k,
        checked.iter().map(|p| p.residual_um[1]).sum::<f64>() / k,
    ];
    // The map no longer holds where any point is off by more than the threshold.
    let rescan = request.spot_check && res_max > request.drift_threshold_um;
    let now_s = crate::context::unix_s(now);
    let recorded_reference = reference.map(|r| RecordedReference {
        measured_at: r.measured_at.clone(),
        age_s: r.age_s(now_s),
        reference_count: r.reference_count,
        shift_um: r.shift_um,
        describe: r.describe(now_s),
    });
    let drift_since_reference = reference.zip(seen).map(|(r, s)| r.drift_um(s));
    let result = VerifyResult {
        round: round + 1,
        points: checked_points,
        reference_um: seen,
        recorded_reference,
        drift_since_reference_um: drift_since_reference,
        residual_um: MaxRms {
            max: res_max,
            rms: res_rms,
        },
        uncompensated_um: MaxRms {
            max: unc_max,
            rms: unc_rms,
        },
        drift_um: drift,
        spot_check: request.spot_check,
        drift_threshold_um: request.drift_threshold_um,
        rescan,
        warning: None,
        of: None,
        checks: None,
    };
    let metrics = [
        ("rescan", rescan.into()),
        ("points", checked.len().into()),
        ("residual_max_um", res_max.into()),
        ("residual_rms_um", res_rms.into()),
        ("uncompensated_max_um", unc_max.into()),
    ];
    let metrics = metrics.into_iter().map(|(k, v)| (k.into(), v)).collect();
    match error {
        None => Outcome::succeeded(result, metrics),
        Some(e) => {
            let lost = matches!(
                e,
                VerifyError::Point {
                    source: JobError::Driver(_),
                    ..
                } | VerifyError::Reference(JobError::Driver(_))
            );
            let mut error = format!("{e}; {} points checked before it", checked.len());
            if reference.is_some() && matches!(e, VerifyError::Reference(_)) {
                error += " (a spot check with a recorded reference does not home: home and run \
                          `gateway reference` first, or give --no-reference)";
            }
            Outcome::stopped(false, error, Some(result), metrics, lost)
        }
    }
}

/// The map's check as a registered procedure: a spot check uses the map's recorded
/// reference (no homing) unless the request says `no_reference` or none is recorded
/// (then it homes and re-references, and the result's `warning` says so).
pub struct Verify;

impl crate::registry::Procedure for Verify {
    const KIND: &'static str = "verify";
    const TITLE: &'static str =
        "Verify the map: move to random points with the map and measure with the camera";
    const COMMAND: &'static str = "verify";
    const LABEL: &'static str = "Error map check";
    const HELP: &'static str =
        "Checks random points with the active error map: the error without and with it.";
    const FIELD_HELP: &'static [(&'static str, &'static str)] = &[
        ("points", "How many random points to check. Empty: 20 (5 for a spot check)."),
        ("seed", "Chooses the random points: the same seed checks the same points."),
        ("spot_check", "A quick drift check: it asks for a new scan when a point is off by more than the threshold."),
        ("drift_threshold_um", "Drift that asks for a new scan."),
    ];
    const USES: crate::registry::Uses = crate::registry::Uses::DEVICES_AND_MAP;
    type Request = VerifyRequest;
    type Result = VerifyResult;

    async fn run(request: VerifyRequest, cx: &mut dyn crate::Context) -> Outcome<VerifyResult> {
        let stop = cx.stop();
        let now = cx.now();
        let active = crate::or_fail!(cx.map());
        let reference = match (
            request.spot_check && !request.no_reference,
            active.reference,
        ) {
            (false, _) => None,
            (true, Ok(r)) => r,
            (true, Err(e)) => return Outcome::failed(e),
        };
        let warning =
            (request.spot_check && !request.no_reference && reference.is_none()).then(|| {
                format!(
                    "no reference is recorded for {}: the spot check homes and re-references \
                     (record one after every homing: the reference job)",
                    active.name
                )
            });
        let bench = crate::or_fail!(cx.bench().await);
        // A series of checks (`repeat`), each on fresh points, `every_s` apart; the
        // devices stay open between them.
        let mut rounds: Vec<VerifyResult> = Vec::new();
        let mut outcome = Outcome::cancelled("stopped before the first check");
        for round in 0..request.repeat {
            if round > 0 {
                let pause = std::time::Duration::from_secs_f64(request.every_s);
                if stop
                    .clone()
                    .unless(tokio::time::sleep(pause))
                    .await
                    .is_none()
                {
                    break;
                }
            }
            let this = VerifyRequest {
                round: request.round + round,
                ..request.clone()
            };
            let checked = stop
                .clone()
                .unless(check_map(
                    &this,
                    bench.job,
                    bench.devices,
                    active.map.clone(),
                    &active.name,
                    reference.as_ref(),
                    now,
                    &mut *bench.sink,
                ))
                .await;
            let Some(checked) = checked else {
                let _ = bench.devices.stage.stop().await;
                return Outcome::cancelled("stopped during the check");
            };
            outcome = checked;
            if let Some(r) = outcome.result.as_mut() {
                r.warning.clone_from(&warning);
                if request.repeat > 1 {
                    r.of = Some(request.repeat);
                    if let Ok(v) = serde_json::to_value(&*r) {
                        bench.sink.partial_result(&v);
                    }
                }
                rounds.push(r.clone());
            }
            if !outcome.is_success() {
                break;
            }
        }
        // A series: every check kept, and a re-scan asked when any check asked it.
        if let (Some(r), true) = (outcome.result.as_mut(), request.repeat > 1) {
            r.rescan = rounds.iter().any(|c| c.rescan);
            r.checks = Some(rounds);
        }
        outcome
    }

    const FILES: &'static [FileArg] = command_line::JOB_AND_MAP;

    fn exit_code(result: &VerifyResult) -> u8 {
        if result.rescan {
            2
        } else {
            0
        }
    }

    fn summary(result: &VerifyResult) -> String {
        summary(result)
    }
}

/// The result as text (the CLI's output without `--json`).
pub fn summary(r: &VerifyResult) -> String {
    if let Some(checks) = &r.checks {
        let worst = (checks.iter())
            .map(|c| c.residual_um.max)
            .fold(0.0, f64::max);
        return format!(
            "{} checks: worst residual {worst:.2} um{}",
            checks.len(),
            if r.rescan {
                "; re-scan the machine (gateway map)"
            } else {
                ""
            }
        );
    }
    check_summary(r)
}

/// One check as text.
fn check_summary(r: &VerifyResult) -> String {
    use std::fmt::Write;
    let mut t = String::new();
    if let Some(of) = r.of {
        let _ = writeln!(t, "check {} of {of}:", r.round);
    }
    if let Some(w) = &r.warning {
        let _ = writeln!(t, "warning: {w}");
    }
    if let Some(d) = r.drift_since_reference_um {
        let _ = writeln!(
            t,
            "the map's {}; since it the zero drifted by ({:+.2}, {:+.2}) um (|{:.2}| um)",
            (r.recorded_reference.as_ref()).map_or("reference", |x| x.describe.as_str()),
            d[0],
            d[1],
            d[0].hypot(d[1])
        );
    } else if let Some(reference) = r.reference_um {
        let _ = writeln!(
            t,
            "after homing the camera is ({:+.2}, {:+.2}) um off at the map's reference point: the map is shifted by it",
            reference[0],
            reference[1]
        );
    }
    for p in &r.points {
        let _ = writeln!(
            t,
            "  ({:8.3}, {:8.3}) mm: residual ({:+6.2}, {:+6.2}) um, uncompensated ({:+6.2}, {:+6.2}) um",
            p.x_mm, p.y_mm, p.residual_um[0], p.residual_um[1],
            p.uncompensated_um[0], p.uncompensated_um[1]
        );
    }
    let (res_max, res_rms) = (r.residual_um.max, r.residual_um.rms);
    let _ = writeln!(
        t,
        "{} points: residual max {res_max:.2} um, rms {res_rms:.2} um; without the map max {:.2} um, rms {:.2} um",
        r.points.len(),
        r.uncompensated_um.max,
        r.uncompensated_um.rms
    );
    if r.spot_check {
        let threshold = r.drift_threshold_um;
        let _ = writeln!(
            t,
            "since the scan: mean residual ({:+.2}, {:+.2}) um, worst {res_max:.2} um{}",
            r.drift_um[0],
            r.drift_um[1],
            if r.rescan {
                format!(": beyond {threshold} um, re-scan the machine (gateway map)")
            } else {
                format!(": within {threshold} um")
            }
        );
    }
    t
}

//! Verification of an error map with the camera: home, re-reference the map at its
//! reference point, move to random points with the map's command, measure.

use crate::request::VerifyRequest;
use crate::{Outcome, Sink};
use devices::Devices;
use errormap::{Approach, MapModel};
use job::Job;
use protocol::errormap::ErrorMap;
use runner::verify::{check_points, max_rms, run_verify, CheckedPoint, VerifyError};
use runner::JobError;
use serde_json::{json, Value};

fn point_json(p: &CheckedPoint) -> Value {
    let side = |a: Approach| if a == Approach::Forward { "+" } else { "-" };
    json!({
        "x_mm": p.nominal_mm[0], "y_mm": p.nominal_mm[1],
        "approach": format!("{}{}", side(p.dir.x), side(p.dir.y)),
        "command_x_mm": p.command_mm[0], "command_y_mm": p.command_mm[1],
        "residual_um": p.residual_um, "uncompensated_um": p.uncompensated_um,
    })
}

/// Checks `map` (named `what` in messages) on this machine: refused before any motion
/// when it was measured on another machine, controller, board or camera. `round`
/// (from 0) picks fresh points for a repeated check. The result: `points`, `residual_um`
/// and `uncompensated_um` (max, rms), `reference_um` (the zero's shift since the scan),
/// `drift_um` (mean residual), `spot_check`, `drift_threshold_um`, `rescan`.
pub async fn run(
    request: &VerifyRequest,
    job: &Job,
    devices: &mut Devices,
    map: ErrorMap,
    what: &str,
    round: u64,
    sink: &mut dyn Sink,
) -> Outcome {
    if let Err(e) = crate::check_identity(&map, &crate::identity(job, devices), what) {
        return Outcome::failed(e);
    }
    let model = MapModel::new(map);
    let points = check_points(
        &model,
        request.point_count(),
        request.seed.wrapping_add(round),
    );
    sink.progress(0, points.len() as u64);
    let (reference, checked, error) = match run_verify(job, devices, &model, &points).await {
        Ok(v) => (Some(v.reference_um), v.points, None),
        Err((e, so_far)) => (None, so_far, Some(e)),
    };
    for p in &checked {
        let _ = sink.measurement(&point_json(p));
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
    let result = json!({
        "round": round + 1,
        "points": checked.iter().map(point_json).collect::<Vec<_>>(),
        "reference_um": reference,
        "residual_um": {"max": res_max, "rms": res_rms},
        "uncompensated_um": {"max": unc_max, "rms": unc_rms},
        "drift_um": drift, "spot_check": request.spot_check,
        "drift_threshold_um": request.drift_threshold_um, "rescan": rescan,
    });
    let mut metrics = crate::metrics_from(&result, &["rescan"]);
    metrics.insert("points".into(), json!(checked.len()));
    metrics.insert("residual_max_um".into(), json!(res_max));
    metrics.insert("residual_rms_um".into(), json!(res_rms));
    metrics.insert("uncompensated_max_um".into(), json!(unc_max));
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
            let error = format!("{e}; {} points checked before it", checked.len());
            Outcome::stopped(false, error, Some(result), metrics, lost)
        }
    }
}

/// The result as text (the CLI's output without `--json`).
pub fn summary(r: &Value) -> String {
    use std::fmt::Write;
    let mut t = String::new();
    let f = |v: &Value| v.as_f64().unwrap_or(f64::NAN);
    if let Some(reference) = r["reference_um"].as_array() {
        let _ = writeln!(
            t,
            "after homing the camera is ({:+.2}, {:+.2}) um off at the map's reference point: the map is shifted by it",
            f(&reference[0]),
            f(&reference[1])
        );
    }
    let points = r["points"].as_array().map(Vec::as_slice).unwrap_or(&[]);
    for p in points {
        let _ = writeln!(
            t,
            "  ({:8.3}, {:8.3}) mm: residual ({:+6.2}, {:+6.2}) um, uncompensated ({:+6.2}, {:+6.2}) um",
            f(&p["x_mm"]), f(&p["y_mm"]), f(&p["residual_um"][0]), f(&p["residual_um"][1]),
            f(&p["uncompensated_um"][0]), f(&p["uncompensated_um"][1])
        );
    }
    let (res_max, res_rms) = (f(&r["residual_um"]["max"]), f(&r["residual_um"]["rms"]));
    let _ = writeln!(
        t,
        "{} points: residual max {res_max:.2} um, rms {res_rms:.2} um; without the map max {:.2} um, rms {:.2} um",
        points.len(),
        f(&r["uncompensated_um"]["max"]),
        f(&r["uncompensated_um"]["rms"])
    );
    if r["spot_check"] == true {
        let threshold = f(&r["drift_threshold_um"]);
        let _ = writeln!(
            t,
            "since the scan: mean residual ({:+.2}, {:+.2}) um, worst {res_max:.2} um{}",
            f(&r["drift_um"][0]),
            f(&r["drift_um"][1]),
            if r["rescan"] == true {
                format!(": beyond {threshold} um, re-scan the machine (gateway map)")
            } else {
                format!(": within {threshold} um")
            }
        );
    }
    t
}

//! `gateway verify`: camera spot checks with the map's compensation acting.

use anyhow::Context;
use devices::open_devices_async;
use errormap::scan::without_link;
use errormap::{Approach, Direction, MapModel};
use job::Job;
use protocol::errormap::{ErrorMap, Identity};
use runner::verify::{check_points, max_rms, run_verify, CheckedPoint};
use serde_json::json;
use std::path::PathBuf;
use std::process::ExitCode;

pub struct VerifyArgs {
    pub config: PathBuf,
    pub map: PathBuf,
    pub points: Option<usize>,
    pub seed: u64,
    pub spot_check: bool,
    pub drift_threshold_um: f64,
    /// Spot checks in a row (each on fresh random points, each homing and
    /// re-referencing first), `every_s` seconds apart: a periodic watch for drift.
    pub repeat: usize,
    pub every_s: f64,
    pub json: bool,
}

fn point_json(p: &CheckedPoint) -> serde_json::Value {
    let side = |a: Approach| if a == Approach::Forward { "+" } else { "-" };
    json!({
        "x_mm": p.nominal_mm[0], "y_mm": p.nominal_mm[1],
        "approach": format!("{}{}", side(p.dir.x), side(p.dir.y)),
        "command_x_mm": p.command_mm[0], "command_y_mm": p.command_mm[1],
        "residual_um": p.residual_um, "uncompensated_um": p.uncompensated_um,
    })
}

pub fn verify(args: VerifyArgs) -> anyhow::Result<ExitCode> {
    let job = Job::load(&args.config)?;
    let map = ErrorMap::load(&args.map)?;
    let n = args.points.unwrap_or(if args.spot_check { 5 } else { 20 });
    anyhow::ensure!(n >= 1, "--points must be at least 1");
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    let mut devices = rt.block_on(open_devices_async(&job))?;
    let stage_name = without_link(&devices.stage.info().name);
    let here = Identity {
        machine: stage_name.clone(),
        controller: stage_name,
        board: job.board.name.clone(),
        certificate_sha256: job.board.fingerprint_sha256(),
        camera: devices.camera.info().model.clone(),
    };
    map.check_identity(&here)
        .map_err(|e| anyhow::anyhow!("{}: {e}: refused", args.map.display()))?;
    anyhow::ensure!(args.repeat >= 1, "--repeat must be at least 1");
    anyhow::ensure!(
        args.every_s.is_finite() && args.every_s >= 0.0,
        "--every-s must be a number of seconds >= 0, got {}",
        args.every_s
    );
    let model = MapModel::new(map);
    let mut any_drifted = false;
    for round in 0..args.repeat {
        if round > 0 {
            // The timer must be made inside the runtime (tokio panics otherwise).
            let pause = std::time::Duration::from_secs_f64(args.every_s);
            rt.block_on(async { tokio::time::sleep(pause).await });
        }
        if args.repeat > 1 && !args.json {
            println!("check {} of {}:", round + 1, args.repeat);
        }
        // A fresh set of points each round, still reproducible from --seed.
        let points = check_points(&model, n, args.seed.wrapping_add(round as u64));
        any_drifted |= one_round(&args, &rt, &job, &mut devices, &model, &points, round)?;
    }
    Ok(if any_drifted {
        ExitCode::from(2)
    } else {
        ExitCode::SUCCESS
    })
}

/// One check: homes, re-references, visits `points`, prints; true when drifted.
fn one_round(
    args: &VerifyArgs,
    rt: &tokio::runtime::Runtime,
    job: &Job,
    devices: &mut devices::Devices,
    model: &MapModel,
    points: &[([f64; 2], Direction)],
    round: usize,
) -> anyhow::Result<bool> {
    let result = rt.block_on(run_verify(job, devices, model, points));
    let (checked, error) = match result {
        Ok(v) => {
            if !args.json {
                println!(
                    "after homing the camera is ({:+.2}, {:+.2}) um off at the map's reference point: the map is shifted by it",
                    v.reference_um[0], v.reference_um[1]
                );
            }
            (v.points, None)
        }
        Err((e, so_far)) => (so_far, Some(e.to_string())),
    };
    let norm = |v: [f64; 2]| v[0].hypot(v[1]);
    let (res_max, res_rms) = max_rms(checked.iter().map(|p| norm(p.residual_um)));
    let (unc_max, unc_rms) = max_rms(checked.iter().map(|p| norm(p.uncompensated_um)));
    let k = checked.len().max(1) as f64;
    let drift = [
        checked.iter().map(|p| p.residual_um[0]).sum::<f64>() / k,
        checked.iter().map(|p| p.residual_um[1]).sum::<f64>() / k,
    ];
    // The map no longer holds where any point is off by more than the threshold
    // (thermal growth spreads the residuals around the reference point; a shifted zero
    // moves them all).
    let drifted = args.spot_check && res_max > args.drift_threshold_um;
    if args.json {
        println!(
            "{}",
            json!({
                "round": round + 1,
                "points": checked.iter().map(point_json).collect::<Vec<_>>(),
                "residual_um": { "max": res_max, "rms": res_rms },
                "uncompensated_um": { "max": unc_max, "rms": unc_rms },
                "drift_um": drift, "drift_threshold_um": args.drift_threshold_um,
                "rescan": drifted, "error": error,
            })
        );
    } else {
        for p in &checked {
            println!(
                "  ({:8.3}, {:8.3}) mm: residual ({:+6.2}, {:+6.2}) um, uncompensated ({:+6.2}, {:+6.2}) um",
                p.nominal_mm[0], p.nominal_mm[1], p.residual_um[0], p.residual_um[1],
                p.uncompensated_um[0], p.uncompensated_um[1]
            );
        }
        println!(
            "{} points: residual max {res_max:.2} um, rms {res_rms:.2} um; without the map max {unc_max:.2} um, rms {unc_rms:.2} um",
            checked.len()
        );
        if args.spot_check {
            println!(
                "since the scan: mean residual ({:+.2}, {:+.2}) um, worst {res_max:.2} um{}",
                drift[0],
                drift[1],
                if drifted {
                    format!(
                        ": beyond {} um, re-scan the machine (gateway map)",
                        args.drift_threshold_um
                    )
                } else {
                    format!(": within {} um", args.drift_threshold_um)
                }
            );
        }
    }
    if let Some(e) = error {
        return Err(anyhow::anyhow!(e))
            .context(format!("{} points checked before it", checked.len()));
    }
    Ok(drifted)
}

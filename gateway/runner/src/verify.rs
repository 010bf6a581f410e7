//! `gateway verify`: the map's compensation checked by the camera, so a user sees that
//! it really acts (controllers' own tables are known to load and silently not act).
//!
//! Home, then re-reference: one frame at the map's reference point measures where the
//! camera is after this homing (each homing moves the machine's zero by a few um) and
//! the map is shifted by it ([`MapModel::rereferenced`]). Then each check point is
//! approached from its side and moved to with the map's command for the camera, and the
//! camera says how far from the nominal point it really is: the residual, beside the
//! error the map predicts there without compensation. A spot check is the same with a
//! few points; its mean residual is the drift since the scan.

use crate::scan::approach_point;
use crate::JobError;
use devices::Devices;
use errormap::{Approach, Direction, MapModel};
use job::Job;

/// One checked point.
#[derive(Clone, Debug, PartialEq)]
pub struct CheckedPoint {
    /// Where the camera should be, machine mm.
    pub nominal_mm: [f64; 2],
    pub dir: Direction,
    /// The command the map gave for it.
    pub command_mm: [f64; 2],
    /// Where the camera really was minus the nominal point, um.
    pub residual_um: [f64; 2],
    /// The error the map predicts there without compensation, um.
    pub uncompensated_um: [f64; 2],
}

/// What a verification measured.
#[derive(Clone, Debug, PartialEq)]
pub struct Verification {
    /// The camera's error at the map's reference point after this homing, um: the
    /// shift the map was re-referenced by.
    pub reference_um: [f64; 2],
    pub points: Vec<CheckedPoint>,
}

#[derive(Debug, thiserror::Error)]
pub enum VerifyError {
    #[error("the reference frame: {0}")]
    Reference(JobError),
    #[error("the map: {0}")]
    Map(#[from] errormap::ModelError),
    #[error("check point #{index} ({:.3}, {:.3}) mm: {source}; the stage was stopped", at[0], at[1])]
    Point {
        index: usize,
        at: [f64; 2],
        #[source]
        source: JobError,
    },
    #[error("check point #{index} ({:.3}, {:.3}) mm: {message}; nothing was moved", at[0], at[1])]
    OutOfLimits {
        index: usize,
        at: [f64; 2],
        message: String,
    },
    /// On a tape port (`crate::tape`): the tape or its stops ended the check.
    #[error("the measurement tape: {message} ({measured} points checked and kept)")]
    Tape { measured: usize, message: String },
}

/// The map's command for each point, it and its approach point checked against the
/// limits (before anything moves).
pub(crate) fn commands_within_limits(
    job: &Job,
    model: &MapModel,
    points: &[([f64; 2], Direction)],
    limits: &compensation::correction::SoftLimits,
) -> Result<Vec<[f64; 2]>, VerifyError> {
    let a = job.policy.approach_mm;
    let mut commands = Vec::with_capacity(points.len());
    for (index, &(p, dir)) in points.iter().enumerate() {
        let c = model.camera_command_for(p, dir)?;
        for (what, at) in [
            ("the command", c),
            ("the approach point", approach_point(c, dir, a)),
        ] {
            limits
                .check(what, at)
                .map_err(|e| VerifyError::OutOfLimits {
                    index,
                    at: p,
                    message: e.to_string(),
                })?;
        }
        commands.push(c);
    }
    Ok(commands)
}

/// `n` points spread over the map (1 mm in from its edge), each with a random approach
/// side per axis, from `seed` (xorshift: the same seed gives the same points).
pub fn check_points(model: &MapModel, n: usize, seed: u64) -> Vec<([f64; 2], Direction)> {
    let (lo, hi) = model.extent();
    let mut s = seed.max(1);
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let side = |u: f64| {
        if u < 0.5 {
            Approach::Forward
        } else {
            Approach::Reverse
        }
    };
    (0..n)
        .map(|_| {
            let p = [
                lo[0] + 1.0 + (hi[0] - lo[0] - 2.0) * next(),
                lo[1] + 1.0 + (hi[1] - lo[1] - 2.0) * next(),
            ];
            (
                p,
                Direction {
                    x: side(next()),
                    y: side(next()),
                },
            )
        })
        .collect()
}

/// The largest value and the root mean square of `v` (0 and 0 when empty): the
/// figures a verification reports of its residuals.
pub fn max_rms(v: impl Iterator<Item = f64>) -> (f64, f64) {
    let v: Vec<f64> = v.collect();
    let max = v.iter().cloned().fold(0.0, f64::max);
    let rms = (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
    (max, rms)
}

/// Check `points` (nominal machine mm and approach sides). On an error, the points
/// checked so far come back with it.
pub async fn run_verify(
    job: &Job,
    devices: &mut Devices,
    model: &MapModel,
    points: &[([f64; 2], Direction)],
) -> Result<Verification, (VerifyError, Vec<CheckedPoint>)> {
    run_verify_with(job, devices, model, points, None).await
}

/// [`run_verify`], or with `recorded` (the camera's error at the reference point when
/// the map's current reference was taken, um): no homing, the map shifted by the
/// recorded reference (as `rewrite` and `proxy` apply it), and the frame at the
/// reference point measured only to say how far the zero drifted since
/// ([`Verification::reference_um`] is then that frame's error).
pub async fn run_verify_with(
    job: &Job,
    devices: &mut Devices,
    model: &MapModel,
    points: &[([f64; 2], Direction)],
    recorded: Option<[f64; 2]>,
) -> Result<Verification, (VerifyError, Vec<CheckedPoint>)> {
    let stage = devices.stage.as_mut();
    let camera = devices.camera.as_mut();
    let limits =
        crate::soft_limits(stage.info()).map_err(|e| (VerifyError::Reference(e), vec![]))?;
    if stage.capabilities().tape_only {
        // A closed controller: the points as one tape, the stops found from the frames.
        return verify_by_tape(job, stage, camera, model, points, recorded, &limits).await;
    }
    let a = job.policy.approach_mm;
    let z = job.board_at_machine_zero_mm;
    // Homing, the orientation check and the reference frame (shared with `gateway
    // reference`).
    let reference_mm = model.map().reference_mm;
    let frame = match recorded {
        None => {
            crate::reference::measure_reference(job, &mut *stage, &mut *camera, reference_mm).await
        }
        Some(_) => {
            crate::reference::measure_at_reference(job, &mut *stage, &mut *camera, reference_mm)
                .await
        }
    };
    let reference_um = frame
        .map_err(|e| (VerifyError::Reference(e), vec![]))?
        .seen_um;
    let model = model
        .clone()
        .rereferenced(recorded.unwrap_or(reference_um))
        .map_err(|e| (VerifyError::Map(e), vec![]))?;
    // Every command and approach point inside the limits before anything else moves.
    let commands = commands_within_limits(job, &model, points, &limits).map_err(|e| (e, vec![]))?;
    let mut checked = Vec::with_capacity(points.len());
    for (index, (&(p, dir), &c)) in points.iter().zip(&commands).enumerate() {
        let fail = |source: JobError| VerifyError::Point {
            index,
            at: p,
            source,
        };
        let hint = [p[0] + z[0], p[1] + z[1]];
        let at = crate::measure::At {
            path: &[approach_point(c, dir, a), c],
            target_mm: hint,
            index,
            measurement: 0,
            free_on_coded_board: false,
        };
        let o = match crate::measure::measure_at(job, stage, camera, at).await {
            Ok(seen) => seen.observation,
            Err(e) => return Err((fail(e), checked)),
        };
        let uncompensated_um = model
            .camera_error_um(p, dir)
            .map_err(|e| (VerifyError::Map(e), checked.clone()))?;
        checked.push(CheckedPoint {
            nominal_mm: p,
            dir,
            command_mm: c,
            residual_um: [(o.x_mm - hint[0]) * 1000.0, (o.y_mm - hint[1]) * 1000.0],
            uncompensated_um,
        });
    }
    Ok(Verification {
        reference_um,
        points: checked,
    })
}

/// Verify on a `tape_only` stage ([`run_verify_with`] comes here): the
/// reference point on a tape of its own (the map re-referenced by it, or by `recorded`
/// when given: then the frame only says how far the zero drifted), then every check
/// point on one tape, approached from its side with the map's command. On an error the
/// points checked so far come back with it.
async fn verify_by_tape(
    job: &Job,
    stage: &mut dyn drivers::Stage,
    camera: &mut dyn drivers::Camera,
    model: &MapModel,
    points: &[([f64; 2], Direction)],
    recorded: Option<[f64; 2]>,
    limits: &compensation::correction::SoftLimits,
) -> Result<Verification, (VerifyError, Vec<CheckedPoint>)> {
    use VerifyError as E;
    let tape_error = |measured, message| E::Tape { measured, message };
    let (_, reference_um, _) =
        crate::tape::reference_by_tape(job, stage, camera, model.map().reference_mm, 0)
            .await
            .map_err(|m| (tape_error(0, m), vec![]))?;
    let model = model
        .clone()
        .rereferenced(recorded.unwrap_or(reference_um))
        .map_err(|e| (E::Map(e), vec![]))?;
    let commands = commands_within_limits(job, &model, points, limits).map_err(|e| (e, vec![]))?;
    let a = job.policy.approach_mm;
    let targets: Vec<errormap::tape::TapeTarget> = points
        .iter()
        .zip(&commands)
        .map(|(&(_, dir), &c)| errormap::tape::TapeTarget {
            approach_mm: approach_point(c, dir, a),
            command_mm: c,
        })
        .collect();
    let (tape, stops) = crate::tape::job_specs(job);
    let mut checked = Vec::with_capacity(points.len());
    let mut failed = None;
    let mut on_stop = |s: &crate::tape::TapeStop| -> Result<(), String> {
        let (p, dir) = points[s.index];
        match model.camera_error_um(p, dir) {
            Ok(uncompensated_um) => {
                checked.push(CheckedPoint {
                    nominal_mm: p,
                    dir,
                    command_mm: commands[s.index],
                    residual_um: crate::tape::stop_error_um(job, s, p),
                    uncompensated_um,
                });
                Ok(())
            }
            Err(e) => {
                let message = e.to_string();
                failed = Some(E::Map(e));
                Err(message)
            }
        }
    };
    let run =
        crate::tape::measure_by_tape(job, stage, camera, &targets, &tape, &stops, &mut on_stop)
            .await;
    if let Some(e) = failed {
        return Err((e, checked));
    }
    match run.error {
        None => Ok(Verification {
            reference_um,
            points: checked,
        }),
        Some(message) => Err((tape_error(checked.len(), message), checked)),
    }
}

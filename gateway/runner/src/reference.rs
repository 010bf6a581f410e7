//! The reference frame after a homing: home if the job homes, check the camera's
//! orientation, put the camera over the map's reference point (approached from below on
//! both axes, as the scan did) and measure where it really is. Shared by
//! `gateway reference` (which records it as the map's current reference) and
//! `gateway verify` (which shifts the map by it before checking).
//!
//! On a coded board the frame gives the absolute position without a hint, so the
//! reference works whatever the homing did; on a plain dot grid the commanded point is
//! the hint (the homing must be within the localizer's hint tolerance).

use crate::{JobError, Orchestrator};
use drivers::{Camera, Stage};
use job::Job;

/// What one reference frame measured.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReferenceFrame {
    /// The command that put the camera over the reference point, machine mm.
    pub command_mm: [f64; 2],
    /// Where the camera really was minus where it should have been, um (board
    /// coordinates less the board's offset at machine zero).
    pub seen_um: [f64; 2],
}

/// Homes (when the job homes), checks the orientation and measures the camera's error
/// at `reference_mm` (machine mm): a compensation job of that one target with no
/// correction. The stage stays at the reference point.
pub async fn measure_reference(
    job: &Job,
    stage: &mut dyn Stage,
    camera: &mut dyn Camera,
    reference_mm: [f64; 2],
) -> Result<ReferenceFrame, JobError> {
    let z = job.board_at_machine_zero_mm;
    let mut one = job.clone();
    one.targets = vec![[reference_mm[0] + z[0], reference_mm[1] + z[1]]];
    one.policy.max_iterations = 0;
    let outcome = Orchestrator {
        stage,
        camera,
        job: &one,
    }
    .run(&mut |_| {})
    .await
    .map_err(|f| f.error)?;
    let first = outcome.completed[0].first();
    Ok(ReferenceFrame {
        command_mm: reference_mm,
        seen_um: first.deviation.um(),
    })
}

/// The camera's error at `reference_mm` now, without homing or the orientation check
/// (the machine homed and checked already): approached from below on both axes by the
/// job's approach distance, as the scan and [`measure_reference`] do, the commanded
/// point as the hint (none on a coded board). For a drift check against a recorded
/// reference; every point is checked against the soft limits before anything moves.
pub async fn measure_at_reference(
    job: &Job,
    stage: &mut dyn Stage,
    camera: &mut dyn Camera,
    reference_mm: [f64; 2],
) -> Result<ReferenceFrame, JobError> {
    let limits = crate::soft_limits(stage.info())?;
    let a = job.policy.approach_mm.max(0.0);
    let approach = [reference_mm[0] - a, reference_mm[1] - a];
    let z = job.board_at_machine_zero_mm;
    let target = [reference_mm[0] + z[0], reference_mm[1] + z[1]];
    for (what, at) in [
        ("the approach point", approach),
        ("the command", reference_mm),
    ] {
        limits
            .check(what, at)
            .map_err(|source| JobError::Correction {
                index: 0,
                target_mm: target,
                source,
            })?;
    }
    let seen = crate::measure::measure_at(
        job,
        stage,
        camera,
        crate::measure::At {
            path: &[approach, reference_mm],
            target_mm: target,
            index: 0,
            measurement: 0,
            free_on_coded_board: true,
        },
    )
    .await?;
    Ok(ReferenceFrame {
        command_mm: reference_mm,
        seen_um: seen.error_um(target),
    })
}

/// Frames a reference averages at its reference point and at each scale point, each a
/// new arrival from below (the stage's settling noise, about 0.08 um per arrival on the
/// demo stage, and the camera's average out): the axes' scale is a difference of a few
/// tenths of a micrometre over 100 mm.
pub const FRAMES_PER_POINT: usize = 3;

/// The mean of `frames` (at least one) arrivals at `at_mm` from below on both axes
/// ([`measure_at_reference`] each), the camera's error, um.
pub async fn measure_mean_at(
    job: &Job,
    stage: &mut dyn Stage,
    camera: &mut dyn Camera,
    at_mm: [f64; 2],
    frames: usize,
) -> Result<[f64; 2], JobError> {
    let n = frames.max(1);
    let mut sum = [0.0; 2];
    for _ in 0..n {
        let f = measure_at_reference(job, stage, camera, at_mm).await?;
        sum = [sum[0] + f.seen_um[0], sum[1] + f.seen_um[1]];
    }
    Ok([sum[0] / n as f64, sum[1] / n as f64])
}

/// [`measure_reference`] with `frames` arrivals at the reference point averaged (the
/// first after the homing, the others without homing).
pub async fn measure_reference_mean(
    job: &Job,
    stage: &mut dyn Stage,
    camera: &mut dyn Camera,
    reference_mm: [f64; 2],
    frames: usize,
) -> Result<ReferenceFrame, JobError> {
    let first = measure_reference(job, stage, camera, reference_mm).await?;
    if frames <= 1 {
        return Ok(first);
    }
    let more = measure_mean_at(job, stage, camera, reference_mm, frames - 1).await?;
    let w = 1.0 / frames as f64;
    let mean = |k: usize| w * first.seen_um[k] + (1.0 - w) * more[k];
    Ok(ReferenceFrame {
        command_mm: reference_mm,
        seen_um: [mean(0), mean(1)],
    })
}

/// The camera's error at each axis's scale point (`errormap::reference::scale_points_mm`):
/// X's error at (`at_mm[0]`, the reference's Y), Y's at (the reference's X, `at_mm[1]`),
/// each approached from below on both axes as the reference point is, the mean of
/// `frames` arrivals, without homing (right after [`measure_reference`] or
/// [`measure_at_reference`]). What `MapReference::with_scale` records as each axis's
/// growth since the scan.
pub async fn measure_scale(
    job: &Job,
    stage: &mut dyn Stage,
    camera: &mut dyn Camera,
    reference_mm: [f64; 2],
    at_mm: [f64; 2],
    frames: usize,
) -> Result<[f64; 2], JobError> {
    let x = measure_mean_at(job, stage, camera, [at_mm[0], reference_mm[1]], frames).await?;
    let y = measure_mean_at(job, stage, camera, [reference_mm[0], at_mm[1]], frames).await?;
    Ok([x[0], y[1]])
}

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

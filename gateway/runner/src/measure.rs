//! The one measuring step every camera procedure takes: move through the given points
//! (an approach point, then the command; each move waited for, so the stage has
//! settled), grab a frame, localize the board near the target. Scans, verification,
//! the reference after homing, ISO 230-2 and the pass-through's reference frame all
//! measure with it; the compensation loop's session decides its own moves and uses
//! [`localize_frame`].

use crate::JobError;
use drivers::{AxisValues, Camera, Frame, Stage};
use job::Job;
use vision::localize::{localize, Observation};

/// Where a step measures: `path` is visited in order (machine mm), the board is
/// localized near `target_mm` (board mm); `index` and `measurement` name the step in an
/// error.
#[derive(Clone, Copy, Debug)]
pub struct At<'a> {
    pub path: &'a [[f64; 2]],
    pub target_mm: [f64; 2],
    pub index: usize,
    pub measurement: usize,
    /// On a coded board, localize without the target as a hint (the frame gives the
    /// absolute position: a lost reference is found, not refused).
    pub free_on_coded_board: bool,
}

/// What a step saw: the frame and where the board says the camera is.
pub struct Seen {
    pub frame: Frame,
    pub observation: Observation,
}

impl Seen {
    /// Where the camera is minus `target_mm`, um.
    pub fn error_um(&self, target_mm: [f64; 2]) -> [f64; 2] {
        [
            (self.observation.x_mm - target_mm[0]) * 1000.0,
            (self.observation.y_mm - target_mm[1]) * 1000.0,
        ]
    }
}

/// The measuring step (see the module's text). On any error the stage is told to stop
/// before the error is returned: nothing moves on after a failed step.
pub async fn measure_at(
    job: &Job,
    stage: &mut dyn Stage,
    camera: &mut dyn Camera,
    at: At<'_>,
) -> Result<Seen, JobError> {
    let moved = async {
        for p in at.path {
            stage
                .move_to(AxisValues::xy(p[0], p[1]), job.feed_mm_min)
                .await?;
            stage.wait_idle().await?;
        }
        camera.grab().await
    };
    let frame = match moved.await {
        Ok(f) => f,
        Err(e) => {
            let _ = stage.stop().await;
            return Err(e.into());
        }
    };
    match localize_frame(job, &frame, at) {
        Ok(observation) => Ok(Seen { frame, observation }),
        Err(e) => {
            let _ = stage.stop().await;
            Err(e)
        }
    }
}

/// The board localized in `frame` near `at.target_mm` (off the async threads).
pub fn localize_frame(job: &Job, frame: &Frame, at: At<'_>) -> Result<Observation, JobError> {
    let mut params = job.localize_params(at.target_mm);
    if at.free_on_coded_board && job.board.code.is_some() {
        params.hint_mm = None;
    }
    drivers::blocking(|| localize(&frame.image, &job.board, &params)).map_err(|source| {
        JobError::Localize {
            index: at.index,
            target_mm: at.target_mm,
            measurement: at.measurement,
            source,
        }
    })
}

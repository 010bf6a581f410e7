//! The compensation loop end to end on the simulated machine: the figures the demo
//! promises, and the refusals (no motion on a guess).

use async_trait::async_trait;
use devices::open_devices;
use drivers::{AxisValues, Camera, CameraInfo, DriverError, Frame, Stage, StageInfo, StageStatus};
use job::{CameraSpec, Job, StageSpec};
use protocol::{MonoImage, Pixels};
use runner::{run_job, JobError, Orchestrator};
use std::sync::{Arc, Mutex};
use vision::localize::Method;

fn block_on<F: std::future::Future>(f: F) -> F::Output {
    tokio::runtime::Builder::new_current_thread()
        .build()
        .unwrap()
        .block_on(f)
}

#[test]
fn demo_job_compensates_a_c5_stage_to_within_a_micrometre() {
    let job = Job::demo();
    let mut devices = open_devices(&job).unwrap();
    let report = block_on(run_job(&job, &mut devices, &mut |_, _| {}));
    assert!(report.error.is_none(), "{:?}", report.error);
    assert!(report.targets >= 25, "{} targets", report.targets);
    assert_eq!(report.converged, report.targets, "{}", report.to_text());
    let before = report.before_um.unwrap();
    let after = report.after_um.unwrap();
    assert!(
        before.max >= 20.0,
        "uncompensated max {} um: not an ordinary stage",
        before.max
    );
    assert!(
        after.max <= 1.0,
        "compensated max {} um\n{}",
        after.max,
        report.to_text()
    );
    // The gateway's own estimate agrees with the truth to well under a micrometre.
    for row in &report.per_target {
        let t = row.truth.unwrap();
        let est = row.estimate_before_um;
        let diff = (t.before_um[0] - est[0]).hypot(t.before_um[1] - est[1]);
        assert!(
            diff < 0.3,
            "target {}: estimate {est:?} vs truth {:?}",
            row.index,
            t.before_um
        );
    }
}

/// The patent's four-point formula interpolates board X from pixel X alone, so it is
/// exact only when the camera is square to the board: on an aligned camera it meets the
/// same figure as the fit; on the demo camera (mounted 0.8 deg off) it is biased by
/// several micrometres, and the bias jumps where the image centre crosses from one grid
/// cell to the next (the demo's first target sits on a dot), so the loop can even fail
/// to settle. The fit method has neither problem.
#[test]
fn four_point_method_is_exact_when_aligned_and_biased_when_rotated() {
    let run = |rotation_deg: f64| {
        let mut job = Job::demo();
        job.localize.method = Method::FourPoint;
        job.targets.truncate(4);
        let CameraSpec::Sim { model } = &mut job.camera else {
            unreachable!("the demo job simulates its camera")
        };
        model.rotation_deg = rotation_deg;
        model.distortion_px_at_corner = 0.0;
        let mut devices = open_devices(&job).unwrap();
        let report = block_on(run_job(&job, &mut devices, &mut |_, _| {}));
        assert!(report.error.is_none(), "{:?}", report.error);
        assert_eq!(report.targets, 4);
        report
    };
    let aligned = run(0.0);
    assert_eq!(aligned.converged, 4);
    let after = aligned.after_um.unwrap().max;
    assert!(after <= 1.0, "aligned camera: {after} um");
    let rotated = run(0.8).after_um.unwrap().max;
    assert!(
        rotated > 2.0,
        "a 0.8 deg camera should show the formula's bias: {rotated} um"
    );
}

/// A stage wrapper that records every command sent to the stage.
struct Recording {
    inner: Box<dyn Stage>,
    moves: Arc<Mutex<Vec<[f64; 2]>>>,
}

#[async_trait]
impl Stage for Recording {
    fn info(&self) -> &StageInfo {
        self.inner.info()
    }
    fn capabilities(&self) -> drivers::Capabilities {
        self.inner.capabilities()
    }
    async fn home(&mut self) -> Result<(), DriverError> {
        self.inner.home().await
    }
    async fn move_to(&mut self, target: AxisValues, feed: f64) -> Result<(), DriverError> {
        self.moves.lock().unwrap().push(target.to_xy().unwrap());
        self.inner.move_to(target, feed).await
    }
    async fn position(&mut self) -> Result<AxisValues, DriverError> {
        self.inner.position().await
    }
    async fn wait_idle(&mut self) -> Result<(), DriverError> {
        self.inner.wait_idle().await
    }
    async fn stop(&mut self) -> Result<(), DriverError> {
        self.inner.stop().await
    }
    async fn status(&mut self) -> Result<StageStatus, DriverError> {
        self.inner.status().await
    }
}

/// A camera whose view goes blank (lens cap, board removed) after `good` frames.
struct GoesBlank {
    inner: Box<dyn Camera>,
    good: usize,
    grabbed: usize,
}

#[async_trait]
impl Camera for GoesBlank {
    fn info(&self) -> &CameraInfo {
        self.inner.info()
    }
    async fn grab(&mut self) -> Result<Frame, DriverError> {
        let mut f = self.inner.grab().await?;
        self.grabbed += 1;
        if self.grabbed > self.good {
            let n = (f.image.width * f.image.height) as usize;
            f.image =
                MonoImage::new(f.image.width, f.image.height, Pixels::Mono8(vec![190; n])).unwrap();
        }
        Ok(f)
    }
}

/// Run `job` with a recording stage on the devices of `rig_job` (the simulated plate
/// comes from `rig_job`'s board, so the gateway can be given a different board file).
fn run_recorded_on(
    rig_job: &Job,
    job: &Job,
    blank_after: Option<usize>,
) -> (Result<usize, JobError>, Vec<[f64; 2]>) {
    let devices = open_devices(rig_job).unwrap();
    let moves = Arc::new(Mutex::new(Vec::new()));
    let mut stage = Recording {
        inner: devices.stage,
        moves: moves.clone(),
    };
    let mut camera: Box<dyn Camera> = match blank_after {
        Some(good) => Box::new(GoesBlank {
            inner: devices.camera,
            good,
            grabbed: 0,
        }),
        None => devices.camera,
    };
    let result = block_on(async {
        let mut o = Orchestrator {
            stage: &mut stage,
            camera: camera.as_mut(),
            job,
        };
        o.run(&mut |_| {}).await
    });
    let moves = moves.lock().unwrap().clone();
    (result.map(|v| v.len()).map_err(|f| f.error), moves)
}

fn run_recorded(job: &Job, blank_after: Option<usize>) -> (Result<usize, JobError>, Vec<[f64; 2]>) {
    run_recorded_on(job, job, blank_after)
}

#[test]
fn a_camera_that_sees_no_board_stops_the_job_without_moving() {
    let mut job = Job::demo();
    job.targets.truncate(3);
    let (ok, baseline) = run_recorded(&job, None);
    assert_eq!(ok.unwrap(), 3);
    // Frame 1 is good (first target, first look); every later frame is blank.
    let (err, moves) = run_recorded(&job, Some(1));
    let err = err.unwrap_err();
    assert!(matches!(err, JobError::Localize { .. }), "{err}");
    let msg = err.to_string();
    assert!(msg.contains("target #"), "{msg}");
    // Moves made: only those up to the failing frame; no correction was sent after it.
    let corrections_before_failure = moves.len();
    assert!(corrections_before_failure < baseline.len());
    assert_eq!(
        &baseline[..moves.len()],
        &moves[..],
        "the moves before the failure are the same"
    );
}

#[test]
fn a_board_file_that_does_not_match_the_plate_is_refused() {
    let mut real = Job::demo();
    real.targets.truncate(1);
    // The gateway is told the plate has a 0.6 mm pitch; the camera sees 0.5 mm.
    let mut job = real.clone();
    let b = &job.board;
    job.board = protocol::Board::nominal("wrong", 0.6, 0.3, b.polarity, 360, 270, b.origin_mm);
    let (err, moves) = run_recorded_on(&real, &job, None);
    let err = err.unwrap_err();
    assert!(matches!(err, JobError::Localize { .. }), "{err}");
    // Only the first positioning (approach + target) was commanded.
    assert_eq!(moves.len(), 2, "{moves:?}");
}

#[test]
fn out_of_travel_targets_are_refused_before_any_motion() {
    let mut job = Job::demo();
    // Board coordinate 3 mm is machine -2 mm: outside the 0..200 mm travel.
    job.targets = vec![[3.0, 50.0]];
    let (err, moves) = run_recorded(&job, None);
    let err = err.unwrap_err();
    let msg = err.to_string();
    assert!(matches!(err, JobError::Correction { .. }), "{msg}");
    assert!(
        msg.contains("soft limits") && msg.contains("axis X"),
        "{msg}"
    );
    assert!(moves.is_empty(), "{moves:?}");
}

#[test]
fn a_correction_beyond_the_bound_is_refused() {
    let mut job = Job::demo();
    job.targets.truncate(1);
    // The set-up is off by 80 um (within what localization accepts) but the job allows
    // corrections of only 30 um.
    let StageSpec::Sim { machine } = &mut job.stage else {
        unreachable!("the demo job is simulated")
    };
    machine.machine.board_at_home_mm[0] += 0.08;
    job.policy.max_correction_mm = 0.03;
    let (err, moves) = run_recorded(&job, None);
    let err = err.unwrap_err();
    assert!(matches!(err, JobError::Correction { .. }), "{err}");
    assert!(err.to_string().contains("bound"), "{err}");
    assert_eq!(moves.len(), 2, "only the first positioning: {moves:?}");
}

//! Runs a job: performs the actions of a [`CompensationSession`] on a [`Stage`] and a
//! [`Camera`], localizes each frame, and builds the report.
//!
//! Every decision (where to go, whether to correct, when to stop) is the session's; this
//! crate only does the I/O it asks for. A failed localization, a refused correction or a
//! device error stops the job before any further motion: the stage is told to stop and
//! the targets finished so far are kept.

pub mod cutter;
pub mod iso230;
pub mod measure;
pub mod reference;
pub mod rotary;
pub mod scan;
pub mod tape;
pub mod verify;

use compensation::correction::SoftLimits;
use compensation::correction::{CorrectionError, Positioning};
use compensation::report::{Report, TruthAt};
use compensation::session::{
    Action, CheckStep, CompensationSession, Measurement, OrientationCheck, OrientationResult,
    SessionError, TargetOutcome,
};
use devices::Devices;
use drivers::{Axis, AxisValues, Camera, DriverError, Stage, StageInfo};
use job::Job;
use protocol::MonoImage;
use std::time::Instant;
use vision::localize::{detect_dots, localize, LocalizeError};

/// Progress notifications; the runner's own report uses `Measured` to read the simulated
/// truth at the moment of each measurement.
#[derive(Debug)]
pub enum Event<'a> {
    Homed,
    Measured {
        target_index: usize,
        measurement: &'a Measurement,
    },
    TargetDone {
        outcome: &'a TargetOutcome,
        of: usize,
    },
    /// A localized frame with what was found in it, for a live view: at most one per
    /// [`FRAME_EVERY`] of wall time (the first always), the others skipped, never waited
    /// for.
    Frame(FrameSeen<'a>),
}

/// The least wall time between two [`Event::Frame`]s; the frames between are skipped.
pub const FRAME_EVERY: std::time::Duration = std::time::Duration::from_millis(250);

/// One localized frame: the image, the dot centres detected in it and the measured
/// point (the board coordinate under the image centre).
#[derive(Debug, Clone, Copy)]
pub struct FrameSeen<'a> {
    pub image: &'a MonoImage,
    /// The camera's frame counter.
    pub sequence: u64,
    /// Detected dot centres, pixels (x right, y down).
    pub dots_px: &'a [[f64; 2]],
    /// Board coordinate at the image centre, mm.
    pub centre_mm: [f64; 2],
    /// The target being measured (None during the orientation check).
    pub target_mm: Option<[f64; 2]>,
    pub target_index: Option<usize>,
}

/// Whether a frame is due for the live view (`last`: when the previous one went),
/// updating `last` when it is.
fn frame_due(last: &mut Option<Instant>, now: Instant) -> bool {
    match last {
        Some(t) if now.duration_since(*t) < FRAME_EVERY => false,
        _ => {
            *last = Some(now);
            true
        }
    }
}

#[cfg(test)]
mod frame_tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn one_frame_per_interval_the_first_at_once_the_others_skipped() {
        let t0 = Instant::now();
        let mut last = None;
        let ms = |n| t0 + Duration::from_millis(n);
        let due: Vec<bool> = [0, 1, 100, 249, 250, 260, 499, 500, 2000]
            .into_iter()
            .map(|n| frame_due(&mut last, ms(n)))
            .collect();
        assert_eq!(
            due,
            [true, false, false, false, true, false, false, true, true]
        );
    }
}

/// Hands a localized frame to `on_event` when one is due: the dots are detected again
/// (only for the frames shown, a few ms each) since the localizer keeps its own.
fn send_frame(
    on_event: &mut dyn FnMut(Event),
    last: &mut Option<Instant>,
    image: &MonoImage,
    sequence: u64,
    polarity: protocol::Polarity,
    centre_mm: [f64; 2],
    target: Option<(usize, [f64; 2])>,
) {
    if !frame_due(last, Instant::now()) {
        return;
    }
    let dots: Vec<[f64; 2]> = detect_dots(image, polarity)
        .iter()
        .map(|d| [d.x, d.y])
        .collect();
    on_event(Event::Frame(FrameSeen {
        image,
        sequence,
        dots_px: &dots,
        centre_mm,
        target_mm: target.map(|t| t.1),
        target_index: target.map(|t| t.0),
    }));
}

#[derive(Debug, thiserror::Error)]
pub enum JobError {
    #[error("stage or camera: {0}")]
    Driver(#[from] DriverError),
    #[error("target #{index} ({:.3}, {:.3}) mm, measurement {measurement}: {source}; the stage was not moved on this frame", target_mm[0], target_mm[1])]
    Localize {
        index: usize,
        target_mm: [f64; 2],
        measurement: usize,
        #[source]
        source: LocalizeError,
    },
    #[error("target #{index} ({:.3}, {:.3}) mm: {source}", target_mm[0], target_mm[1])]
    Correction {
        index: usize,
        target_mm: [f64; 2],
        #[source]
        source: CorrectionError,
    },
    #[error("the stage reports no {0} axis; the compensation pipeline needs X and Y")]
    MissingAxis(Axis),
    #[error("orientation check {step}: {source}; the board was not found where a camera mounted as `camera.pixel_axes` says would see it; nothing was corrected")]
    CheckLocalize {
        step: CheckStep,
        #[source]
        source: LocalizeError,
    },
    #[error(transparent)]
    Orientation(SessionError),
    #[error("cancelled by the operator; the stage was told to stop")]
    Cancelled,
    /// GRBL refused a move with error:9 (locked in Alarm, as it is at power-up with
    /// homing enabled) in a job that skips homing.
    #[error("{0}; this job skips homing (`setup.home = false` in the job file), but the controller is locked in Alarm (GRBL locks at power-up when homing is enabled, `$22=1`): home it (`$H`) or unlock it (`$X`) before the job, or set `setup.home = true`")]
    LockedWithoutHoming(DriverError),
    /// On a tape port (`tape::position_by_tape`): the tape or its stop.
    #[error("the positioning tape: {0}")]
    Tape(String),
    /// A bug in this crate: it performed an action the session did not ask for.
    #[error("internal: {0}")]
    Session(SessionError),
}

impl From<SessionError> for JobError {
    fn from(e: SessionError) -> Self {
        match e {
            SessionError::Correction {
                index,
                target_mm,
                source,
            } => JobError::Correction {
                index,
                target_mm,
                source,
            },
            e @ SessionError::Orientation { .. } => JobError::Orientation(e),
            other => JobError::Session(other),
        }
    }
}

/// A job stopped by an error, with every target worked on: the finished ones and the
/// one it stopped on (marked `stopped`, with its measurements so far).
#[derive(Debug)]
pub struct JobFailure {
    pub completed: Vec<TargetOutcome>,
    pub orientation: Option<OrientationResult>,
    pub rereferences: Vec<compensation::session::Rereference>,
    pub error: JobError,
}

/// What a finished job did.
#[derive(Debug)]
pub struct JobSuccess {
    pub completed: Vec<TargetOutcome>,
    pub orientation: Option<OrientationResult>,
    /// Lost references found on a coded board, in order.
    pub rereferences: Vec<compensation::session::Rereference>,
}

/// A GRBL `error:9` (G-code lock) in a job that does not home says what to do: home or
/// unlock the controller, or let the job home.
fn explain_lock(error: JobError, home: bool) -> JobError {
    match error {
        JobError::Driver(DriverError::Refused {
            code: 9,
            message,
            device,
            what,
        }) if !home && message == protocol::grbl::codes::error_text(9) => {
            JobError::LockedWithoutHoming(DriverError::Refused {
                code: 9,
                message,
                device,
                what,
            })
        }
        other => other,
    }
}

/// Soft limits of X and Y from what a stage reports.
pub fn soft_limits(info: &StageInfo) -> Result<SoftLimits, JobError> {
    let x = info.axis(Axis::X).ok_or(JobError::MissingAxis(Axis::X))?;
    let y = info.axis(Axis::Y).ok_or(JobError::MissingAxis(Axis::Y))?;
    Ok(SoftLimits {
        min_mm: [x.min_mm, y.min_mm],
        max_mm: [x.max_mm, y.max_mm],
    })
}

pub struct Orchestrator<'a> {
    pub stage: &'a mut dyn Stage,
    pub camera: &'a mut dyn Camera,
    pub job: &'a Job,
}

impl Orchestrator<'_> {
    /// Soft limits of X and Y from the stage.
    pub fn limits(&self) -> Result<SoftLimits, JobError> {
        soft_limits(self.stage.info())
    }

    /// Home, check the camera's orientation, then compensate every target in order.
    pub async fn run(&mut self, on_event: &mut dyn FnMut(Event)) -> Result<JobSuccess, JobFailure> {
        self.run_until(on_event, std::future::pending()).await
    }

    /// [`Self::run`], stopped (the stage told to stop, every result kept) when `cancel`
    /// completes.
    pub async fn run_until(
        &mut self,
        on_event: &mut dyn FnMut(Event),
        cancel: impl std::future::Future<Output = ()>,
    ) -> Result<JobSuccess, JobFailure> {
        let nothing_done = |error| JobFailure {
            completed: Vec::new(),
            orientation: None,
            rereferences: Vec::new(),
            error,
        };
        let limits = self.limits().map_err(nothing_done)?;
        let check = OrientationCheck::for_pitch(self.job.board.pitch_mm);
        let mut session = CompensationSession::new(
            self.job.session_targets(),
            self.job.policy.clone(),
            limits,
            Some(check),
        )
        .map_err(|e| nothing_done(e.into()))?;
        // A coded board gives absolute positions: lost steps are found and re-referenced.
        if self.job.board.code.is_some() {
            session = session.allow_rereference();
            if !self.job.home {
                // The board says where the machine is: no homing (the job file allows
                // this only on a coded board).
                session.skip_homing().map_err(|e| nothing_done(e.into()))?;
            }
        }
        // Biased: a cancel is seen at the next yield between two actions, every time.
        let result = tokio::select! {
            biased;
            () = cancel => Err(JobError::Cancelled),
            r = self.drive(&mut session, on_event) => r,
        };
        let orientation = session.orientation().copied();
        let rereferences = session.rereferences().to_vec();
        match result {
            Ok(()) => Ok(JobSuccess {
                completed: session.into_completed(),
                orientation,
                rereferences,
            }),
            Err(error) => {
                let error = explain_lock(error, self.job.home);
                // Leave the machine still and safe, then report.
                let _ = self.stage.stop().await;
                Err(JobFailure {
                    completed: session.into_outcomes(),
                    orientation,
                    rereferences,
                    error,
                })
            }
        }
    }

    async fn drive(
        &mut self,
        session: &mut CompensationSession,
        on_event: &mut dyn FnMut(Event),
    ) -> Result<(), JobError> {
        let of = self.job.targets.len();
        let mut last_frame: Option<Instant> = None;
        let mut action = session.next_action();
        loop {
            // Between two device actions: let a cancel (Ctrl-C) be seen even when the
            // devices answer without ever waiting (the in-process simulation).
            tokio::task::yield_now().await;
            action = match action {
                Action::Home => {
                    self.stage.home().await?;
                    self.stage.wait_idle().await?;
                    on_event(Event::Homed);
                    session.homed()?
                }
                Action::Position { positioning, .. }
                | Action::CheckPosition { positioning, .. } => {
                    self.position(&positioning).await?;
                    session.positioned()?
                }
                Action::CheckMeasure {
                    step,
                    hint_mm,
                    hint_tolerance_mm,
                } => {
                    let frame = self.camera.grab().await?;
                    let mut params = self.job.localize_params(hint_mm);
                    params.hint_tolerance_mm = hint_tolerance_mm;
                    if self.job.board.code.is_some() {
                        // The code gives the absolute position: no hint to check.
                        params.hint_mm = None;
                    }
                    let board = &self.job.board;
                    let observation = drivers::blocking(|| localize(&frame.image, board, &params))
                        .map_err(|source| JobError::CheckLocalize { step, source })?;
                    send_frame(
                        on_event,
                        &mut last_frame,
                        &frame.image,
                        frame.meta.sequence,
                        board.polarity,
                        [observation.x_mm, observation.y_mm],
                        None,
                    );
                    session.checked([observation.x_mm, observation.y_mm])?
                }
                Action::Measure {
                    target_index,
                    target_mm,
                    hint_mm,
                    measurement,
                } => {
                    let frame = self.camera.grab().await?;
                    let mut params = self.job.localize_params(hint_mm);
                    if self.job.board.code.is_some() {
                        params.hint_mm = None;
                    }
                    let board = &self.job.board;
                    let observation = drivers::blocking(|| localize(&frame.image, board, &params))
                        .map_err(|source| JobError::Localize {
                            index: target_index,
                            target_mm,
                            measurement,
                            source,
                        })?;
                    send_frame(
                        on_event,
                        &mut last_frame,
                        &frame.image,
                        frame.meta.sequence,
                        board.polarity,
                        [observation.x_mm, observation.y_mm],
                        Some((target_index, target_mm)),
                    );
                    let step = match session.measured(observation, frame.meta.sequence) {
                        Ok(step) => step,
                        Err(e) => {
                            // The measurement is kept (the session recorded it before
                            // refusing the next move): report it like any other.
                            if let Some((_, done)) = session.in_progress() {
                                if let Some(measurement) = done.last() {
                                    on_event(Event::Measured {
                                        target_index,
                                        measurement,
                                    });
                                }
                            }
                            return Err(e.into());
                        }
                    };
                    on_event(Event::Measured {
                        target_index,
                        measurement: &step.measurement,
                    });
                    if let Some(outcome) = &step.finished {
                        on_event(Event::TargetDone { outcome, of });
                    }
                    step.next
                }
                Action::Finished => return Ok(()),
            };
        }
    }

    async fn position(&mut self, p: &Positioning) -> Result<(), JobError> {
        if self.stage.capabilities().tape_only {
            // A closed controller: each move a short tape, its end seen by the camera.
            let limits = self.limits()?;
            return tape::position_by_tape(self.job, self.stage, self.camera, p, &limits)
                .await
                .map_err(JobError::Tape);
        }
        let feed = self.job.feed_mm_min;
        if let Some(a) = p.approach_from_mm {
            // Wait at the approach point: not every controller queues moves, and the
            // final move must start from this side for backlash to be taken up.
            self.stage.move_to(AxisValues::xy(a[0], a[1]), feed).await?;
            self.stage.wait_idle().await?;
        }
        self.stage
            .move_to(AxisValues::xy(p.command_mm[0], p.command_mm[1]), feed)
            .await?;
        self.stage.wait_idle().await?;
        Ok(())
    }
}

/// Progress callback: (targets done, targets planned).
pub type Progress<'a> = &'a mut dyn FnMut(usize, usize);

/// Run a job on opened devices and build its report (also when it stopped early).
pub async fn run_job(job: &Job, devices: &mut Devices, progress: Progress<'_>) -> Report {
    run_job_until(job, devices, progress, std::future::pending()).await
}

/// [`run_job`], stopped when `cancel` completes (the operator's Ctrl-C): the stage is
/// told to stop and the report keeps everything measured.
pub async fn run_job_until(
    job: &Job,
    devices: &mut Devices,
    progress: Progress<'_>,
    cancel: impl std::future::Future<Output = ()>,
) -> Report {
    let mut on_event = |e: &Event| {
        if let Event::TargetDone { outcome, of } = e {
            progress(outcome.index + 1, *of);
        }
    };
    run_job_events(job, devices, &mut on_event, cancel).await.0
}

/// [`run_job_until`] with every event of the run handed on (measurements as they come,
/// targets as they finish) and the error that stopped it, typed (a driver error means
/// the link was lost).
pub async fn run_job_events(
    job: &Job,
    devices: &mut Devices,
    events: &mut dyn FnMut(&Event),
    cancel: impl std::future::Future<Output = ()>,
) -> (Report, Option<JobError>) {
    let started = Instant::now();
    let rig = devices.rig.clone();
    // Truth error (um) at the first and latest measurement of each target.
    let mut truth: Vec<Option<TruthAt>> = Vec::new();
    let mut current: Option<(usize, TruthAt)> = None;
    let mut on_event = |e: Event| match e {
        Event::Measured { target_index, .. } => {
            events(&e);
            if let Some(rig) = &rig {
                let pose = world::lock(rig).truth();
                let t = job.targets[target_index];
                let err = [
                    (pose.centre_mm[0] - t[0]) * 1000.0,
                    (pose.centre_mm[1] - t[1]) * 1000.0,
                ];
                match &mut current {
                    Some((i, at)) if *i == target_index => at.after_um = err,
                    _ => {
                        current = Some((
                            target_index,
                            TruthAt {
                                before_um: err,
                                after_um: err,
                            },
                        ))
                    }
                }
            }
        }
        Event::TargetDone { .. } => {
            truth.push(current.take().map(|(_, at)| at));
            events(&e);
        }
        Event::Homed | Event::Frame(_) => events(&e),
    };
    let stage_name = devices.stage.info().name.clone();
    let camera_name = devices.camera.info().model.clone();
    let mut orch = Orchestrator {
        stage: devices.stage.as_mut(),
        camera: devices.camera.as_mut(),
        job,
    };
    let result = orch.run_until(&mut on_event, cancel).await;
    let (outcomes, orientation, rereferences, error) = match result {
        Ok(o) => (o.completed, o.orientation, o.rereferences, None),
        Err(f) => (f.completed, f.orientation, f.rereferences, Some(f.error)),
    };
    // The target the job stopped on (if any) has its truth still in `current`.
    if let Some((_, at)) = current {
        truth.push(Some(at));
    }
    let mut report = Report::build(
        &job.source,
        &stage_name,
        &camera_name,
        job.localize.method,
        job.targets.len(),
        &outcomes,
        &truth,
        started.elapsed().as_secs_f64(),
        error.as_ref().map(|e| e.to_string()),
    );
    report.orientation = orientation;
    report.rereferences = rereferences;
    (report, error)
}

#[cfg(test)]
mod tests {
    use super::*;
    use job::StageSpec;

    /// The demo job on the coded board, with a stepper Y axis that loses `lost_mm` once
    /// in the middle of the job (its third move longer than the loss), on a machine that
    /// powered on anywhere (no homing).
    fn coded_job(lost_mm: f64) -> Job {
        let mut job = Job::demo();
        // The coded board of config/boards/coded-0.5mm.toml (the same grid, seed 28).
        job.board
            .set_code(protocol::board_code::CodeScheme::Additive, 28, [0.2, 0.3]);
        job.home = false;
        // Inside the travel by more than the largest loss: the controller's own soft
        // limits still bound the re-referenced commands.
        job.targets = vec![
            [30.0, 30.0],
            [90.0, 110.0],
            [150.0, 40.0],
            [60.0, 120.0],
            [120.0, 35.0],
            [170.0, 100.0],
        ];
        let StageSpec::Sim { machine } = &mut job.stage else {
            panic!("the demo is simulated")
        };
        machine.machine.power_on_at_mm = Some([3.2, -1.7]);
        machine.axes.y.stall = Some(world::machine::StallConfig {
            full_steps: (lost_mm / 0.025).round() as u32,
            step_mm: 0.025,
            at_move: 3,
            every: 0,
        });
        job
    }

    /// Issue 38: a coded job with `home = false` over GRBL stopped with "code 9: G-code
    /// lock" and said nothing of the job's key or of `$X`.
    #[test]
    fn a_lock_in_a_job_that_skips_homing_names_the_key_and_the_commands() {
        let lock = || {
            JobError::Driver(DriverError::Refused {
                device: "GRBL on /dev/ttyUSB0".into(),
                what: "G0 X30 Y30".into(),
                code: 9,
                message: protocol::grbl::codes::error_text(9).into(),
            })
        };
        let e = explain_lock(lock(), false).to_string();
        for said in ["code 9", "G-code lock", "setup.home", "$X", "$H"] {
            assert!(e.contains(said), "{said}: {e}");
        }
        // A job that homes first, or another code, is left as it was.
        assert_eq!(explain_lock(lock(), true).to_string(), lock().to_string());
        let other = JobError::Driver(DriverError::Refused {
            device: "GRBL".into(),
            what: "G0 X1".into(),
            code: 20,
            message: protocol::grbl::codes::error_text(20).into(),
        });
        assert!(!explain_lock(other, false)
            .to_string()
            .contains("setup.home"));
    }

    #[test]
    fn a_coded_board_job_ends_on_target_after_lost_steps_without_homing() {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        for lost in [0.3, 2.0, 20.0] {
            let job = coded_job(lost);
            let mut devices = devices::open_devices(&job).unwrap();
            let report = rt.block_on(run_job(&job, &mut devices, &mut |_, _| {}));
            assert!(report.error.is_none(), "{lost} mm: {}", report.to_text());
            assert_eq!(report.converged, 6, "{}", report.to_text());
            let after = report.after_um.as_ref().unwrap();
            assert!(after.max <= 0.5, "{lost} mm: {}", report.to_text());
            // The power-on offset (no homing) and the loss are both found.
            assert!(report.rereferences.len() >= 2, "{}", report.to_text());
            assert!(
                report
                    .rereferences
                    .iter()
                    .any(|r| (r.deviation_mm[1].abs() - lost).abs() < 0.05),
                "{lost} mm: {:?}",
                report.rereferences
            );
            assert!(report.to_text().contains("re-referenced"));
        }
    }
}

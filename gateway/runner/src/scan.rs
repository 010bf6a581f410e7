//! Scanning a machine into an error map (`gateway map`): home, check the camera's
//! orientation and measure the reference point (the compensation session does both,
//! with no correction), then visit every point of the [`ScanPlan`] approached from each
//! side, localize the board, and record the camera's error relative to the reference.
//!
//! Nothing is corrected during a scan: the stage only goes where the plan says, every
//! point and approach point is checked against the soft limits before homing, and any
//! failure stops the stage. Samples go to `on_sample` (the journal) as they come, so a
//! stopped scan resumes where it ended; a sample no stage can have (an error beyond
//! 1 mm, a value that is not finite: a misread board) stops the scan instead of being
//! kept.

use crate::{Event, FrameSeen, JobError, Orchestrator};
use compensation::correction::SoftLimits;
use devices::Devices;
use errormap::scan::{MapBuilder, Sample, ScanPlan};
use errormap::Approach;
use job::Job;

/// What the reference frame of this run saw.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reference {
    /// The reference point, machine mm.
    pub command_mm: [f64; 2],
    /// The camera's error there, um, and its image rotation, degrees.
    pub error_um: [f64; 2],
    pub rotation_deg: f64,
}

#[derive(Debug, thiserror::Error)]
pub enum ScanError {
    #[error("scan point #{index} ({:.3}, {:.3}) mm: {message}; nothing was moved", at[0], at[1])]
    OutOfLimits {
        index: usize,
        at: [f64; 2],
        message: String,
    },
    #[error("scan point #{index} ({:.3}, {:.3}) mm: {source}; the stage was stopped", at[0], at[1])]
    Point {
        index: usize,
        at: [f64; 2],
        #[source]
        source: JobError,
    },
    #[error("the reference frame: {0}")]
    Reference(JobError),
    #[error("scan point #{index} ({:.3}, {:.3}) mm: {message}: not a stage's error (a misread board?); the stage was stopped", at[0], at[1])]
    Impossible {
        index: usize,
        at: [f64; 2],
        message: String,
    },
    #[error("the scan journal: {0}; the stage was stopped")]
    Journal(String),
    #[error("cancelled by the operator; the stage was told to stop")]
    Cancelled,
    /// A scan through a tape port ended early (`crate::tape`): the points measured are
    /// kept.
    #[error("the measurement tape: {message} ({measured} points measured and kept)")]
    Tape { measured: usize, message: String },
}

/// Where the final move onto `p` starts from, for an approach from `a` on each axis.
pub(crate) fn approach_point(p: [f64; 2], dir: errormap::Direction, by_mm: f64) -> [f64; 2] {
    let side = |a: Approach| match a {
        Approach::Forward => -by_mm,
        Approach::Reverse => by_mm,
    };
    [p[0] + side(dir.x), p[1] + side(dir.y)]
}

/// The scan area: the stage's travel less the approach, within the board as the camera
/// sees it (2 mm in from its edge), machine mm.
pub fn scan_area(job: &Job, limits: &SoftLimits) -> ([f64; 2], [f64; 2]) {
    let a = job.policy.approach_mm.max(0.0) + 0.001;
    let (blo, bhi) = job.board.extent();
    let z = job.board_at_machine_zero_mm;
    let lo = [
        (limits.min_mm[0] + a).max(blo[0] - z[0] + 2.0),
        (limits.min_mm[1] + a).max(blo[1] - z[1] + 2.0),
    ];
    let hi = [
        (limits.max_mm[0] - a).min(bhi[0] - z[0] - 2.0),
        (limits.max_mm[1] - a).min(bhi[1] - z[1] - 2.0),
    ];
    (lo, hi)
}

/// Run (or resume) a scan: every plan point not yet in `builder`. Returns the reference
/// this run measured.
pub async fn run_scan(
    job: &Job,
    devices: &mut Devices,
    plan: &ScanPlan,
    builder: &mut MapBuilder,
    on_sample: &mut dyn FnMut(usize, &Sample) -> Result<(), String>,
    progress: &mut dyn FnMut(usize, usize),
    cancel: impl std::future::Future<Output = ()>,
) -> Result<Reference, ScanError> {
    run_scan_frames(
        job,
        devices,
        plan,
        builder,
        on_sample,
        progress,
        &mut |_| {},
        cancel,
    )
    .await
}

/// [`run_scan`], with the localized frames for a live view handed to `on_frame` (the
/// reference frames and the scan's, at most one per [`crate::FRAME_EVERY`] of wall time,
/// the others skipped); `target_index` is the plan point's index.
#[allow(clippy::too_many_arguments)]
pub async fn run_scan_frames(
    job: &Job,
    devices: &mut Devices,
    plan: &ScanPlan,
    builder: &mut MapBuilder,
    on_sample: &mut dyn FnMut(usize, &Sample) -> Result<(), String>,
    progress: &mut dyn FnMut(usize, usize),
    on_frame: &mut dyn FnMut(&FrameSeen),
    cancel: impl std::future::Future<Output = ()>,
) -> Result<Reference, ScanError> {
    let mut on_event = |e: Event| {
        if let Event::Frame(f) = e {
            on_frame(&f);
        }
    };
    let stage = devices.stage.as_mut();
    let camera = devices.camera.as_mut();
    // Every point and its approach inside the limits before anything moves.
    let limits = crate::soft_limits(stage.info()).map_err(ScanError::Reference)?;
    let a = job.policy.approach_mm;
    for (index, p) in plan.points.iter().enumerate() {
        for (what, at) in [
            ("the point", p.command_mm),
            ("the approach point", approach_point(p.command_mm, p.dir, a)),
        ] {
            limits.check(what, at).map_err(|e| ScanError::OutOfLimits {
                index,
                at: p.command_mm,
                message: e.to_string(),
            })?;
        }
    }
    if stage.capabilities().tape_only {
        // A closed controller: the whole scan as one tape, the stops found from frames
        // (`crate::tape`); the reference point first.
        let reference_mm = [plan.y_line_at, plan.x_line_at];
        let forward = errormap::Direction {
            x: Approach::Forward,
            y: Approach::Forward,
        };
        let todo: Vec<usize> = (0..plan.points.len())
            .filter(|&i| !builder.is_done(i))
            .collect();
        let target = |command_mm, dir| errormap::tape::TapeTarget {
            approach_mm: approach_point(command_mm, dir, a),
            command_mm,
        };
        let mut targets = vec![target(reference_mm, forward)];
        targets.extend(
            todo.iter()
                .map(|&i| target(plan.points[i].command_mm, plan.points[i].dir)),
        );
        use crate::tape::TapeScanError as E;
        return crate::tape::scan_by_tape(
            job, stage, camera, plan, builder, &targets, &todo, on_sample, progress, cancel,
        )
        .await
        .map(|(error_um, rotation_deg)| Reference {
            command_mm: reference_mm,
            error_um,
            rotation_deg,
        })
        .map_err(|e| match e {
            E::Cancelled => ScanError::Cancelled,
            E::Record { index, message } => ScanError::Impossible {
                index,
                at: plan.points[index].command_mm,
                message,
            },
            E::Journal(m) => ScanError::Journal(m),
            E::Tape { measured, message } => ScanError::Tape { measured, message },
        });
    }
    // Homing, the orientation check and the reference frame: a compensation job of one
    // target and no correction.
    let reference_mm = [plan.y_line_at, plan.x_line_at];
    let z = job.board_at_machine_zero_mm;
    let mut one = job.clone();
    one.targets = vec![[reference_mm[0] + z[0], reference_mm[1] + z[1]]];
    one.policy.max_iterations = 0;
    let outcome = Orchestrator {
        stage: &mut *stage,
        camera: &mut *camera,
        job: &one,
    }
    .run(&mut on_event)
    .await
    .map_err(|f| ScanError::Reference(f.error))?;
    let mut last_frame = None;
    let first = outcome.completed[0].first().clone();
    let reference = Reference {
        command_mm: reference_mm,
        error_um: first.deviation.um(),
        rotation_deg: first.observation.rotation_deg,
    };
    let total = plan.points.len();
    let scan = async {
        for (index, p) in plan.points.iter().enumerate() {
            if builder.is_done(index) {
                continue;
            }
            tokio::task::yield_now().await;
            let fail = |source| ScanError::Point {
                index,
                at: p.command_mm,
                source,
            };
            let hint = [p.command_mm[0] + z[0], p.command_mm[1] + z[1]];
            let at = crate::measure::At {
                path: &[approach_point(p.command_mm, p.dir, a), p.command_mm],
                target_mm: hint,
                index,
                measurement: 0,
                free_on_coded_board: false,
            };
            let seen = crate::measure::measure_at(job, stage, camera, at)
                .await
                .map_err(fail)?;
            let (frame, o) = (seen.frame, seen.observation);
            crate::send_frame(
                &mut on_event,
                &mut last_frame,
                &frame.image,
                frame.meta.sequence,
                job.board.polarity,
                [o.x_mm, o.y_mm],
                Some((index, hint)),
            );
            let sample = Sample {
                error_um: [
                    (o.x_mm - hint[0]) * 1000.0 - reference.error_um[0],
                    (o.y_mm - hint[1]) * 1000.0 - reference.error_um[1],
                ],
                yaw_urad: (o.rotation_deg - reference.rotation_deg).to_radians() * 1e6,
            };
            // A value no stage can have (beyond 1 mm, not finite) is never kept: the
            // journal would refuse it on resume.
            builder
                .record(plan, index, sample)
                .map_err(|e| ScanError::Impossible {
                    index,
                    at: p.command_mm,
                    message: e.to_string(),
                })?;
            on_sample(index, &sample).map_err(ScanError::Journal)?;
            progress(builder.done(), total);
        }
        Ok(())
    };
    // Biased: a cancel is seen at the next yield between two points, every time.
    let result = tokio::select! {
        biased;
        () = cancel => Err(ScanError::Cancelled),
        r = scan => r,
    };
    match result {
        Ok(()) => Ok(reference),
        Err(e) => {
            let _ = devices.stage.stop().await;
            Err(e)
        }
    }
}

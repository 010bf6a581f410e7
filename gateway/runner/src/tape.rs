//! Measuring through a tape port with the camera as the only sensor (issue 40, item
//! 3): the targets go to the controller as one measurement tape
//! ([`errormap::tape::measurement_tape`]) streamed by the stage (a `tape_only` stage:
//! nothing comes back), while the camera grabs without pause; each frame is localized
//! and [`errormap::tape::StopFinder`] finds the stops (still for a third of the dwell,
//! at the next target). A target missed, out of order or never stopping ends the run
//! with the stops found so far. Time is the frames' (the machine's clock for a
//! simulated one).
//!
//! [`measure_by_tape`] is the one step every job measuring through a tape takes: the map
//! scan ([`scan_by_tape`]), ISO 230-2 (`crate::iso230`), verify (`crate::verify`) and
//! each positioning of the compensation loop ([`position_by_tape`]) only say which
//! targets, in which order, and what a stop means to them. The reference point is
//! measured first on a tape of its own ([`reference_by_tape`]) where the later commands
//! depend on it (a map re-referenced to this reference return), and the camera's
//! orientation is not checked by moves (a tape cannot wait for a frame): on a coded
//! board every frame gives the absolute position.

use drivers::{Camera, Stage};
use errormap::tape::{
    machine_time_s, measurement_tape, Seen, StopFinder, StopSpec, TapeSpec, TapeTarget,
};
use errormap::Approach;
use job::Job;
use vision::localize::{localize, Observation};

/// One target stopped at: where the board says the camera is, and when.
#[derive(Clone, Debug)]
pub struct TapeStop {
    pub index: usize,
    /// The controller's command there (rounded to its increment), machine mm.
    pub command_mm: [f64; 2],
    pub observation: Observation,
    pub t_s: f64,
}

/// What a tape measured.
#[derive(Clone, Debug, Default)]
pub struct TapeRun {
    pub stops: Vec<TapeStop>,
    /// Frames grabbed, and of them localized.
    pub frames: u64,
    pub localized: u64,
    /// Machine time from the first frame to the last stop, s.
    pub machine_time_s: f64,
    /// Why it ended early (the stops before are kept).
    pub error: Option<String>,
}

/// Streams the measurement tape of `targets` and finds each stop from the frames
/// (module text). `on_stop` is told each stop as it is found.
pub async fn measure_by_tape(
    job: &Job,
    stage: &mut dyn Stage,
    camera: &mut dyn Camera,
    targets: &[TapeTarget],
    tape_spec: &TapeSpec,
    stop_spec: &StopSpec,
    on_stop: &mut dyn FnMut(&TapeStop) -> Result<(), String>,
) -> TapeRun {
    let mut run = TapeRun::default();
    if !stage.capabilities().tape_only {
        run.error = Some("the stage is not a tape port (capability tape_only)".into());
        return run;
    }
    let (tape, commands) = match measurement_tape(targets, tape_spec) {
        Ok(t) => t,
        Err(e) => {
            run.error = Some(e.to_string());
            return run;
        }
    };
    let z = job.board_at_machine_zero_mm;
    let expected: Vec<[f64; 2]> = commands
        .iter()
        .map(|c| [c[0] + z[0], c[1] + z[1]])
        .collect();
    // A rest is one stop: two targets in a row where the camera sees nearly the same
    // position (within the bound) would be one rest if it missed the short trip between
    // them.
    if let Some(k) = expected
        .windows(2)
        .position(|w| (w[0][0] - w[1][0]).hypot(w[0][1] - w[1][1]) < stop_spec.bound_mm)
    {
        run.error = Some(format!(
            "targets #{k} and #{} are within {} mm of each other: the camera could not tell their stops apart (put another target between them)",
            k + 1,
            stop_spec.bound_mm
        ));
        return run;
    }
    let mut finder = StopFinder::new(expected.clone(), stop_spec.clone());
    // How long the stops may take: the tape's time at its feed, twice, and a minute.
    let start = targets.first().map_or([0.0; 2], |t| t.approach_mm);
    let budget_s = 2.0 * machine_time_s(start, targets, tape_spec) + 60.0;
    let options = drivers::StreamOptions::default();
    let mut sent = |_: protocol::grbl::stream::StreamProgress| {};
    let mut stream_done = false;
    let ended: Result<(), String> = {
        let streaming = stage.stream_program(&tape, &options, &mut sent);
        tokio::pin!(streaming);
        let grabbing = async {
            let mut t0 = None;
            loop {
                // The tape is streamed in the same task: let it run between frames.
                tokio::task::yield_now().await;
                let frame = camera.grab().await.map_err(|e| e.to_string())?;
                run.frames += 1;
                let t = frame.meta.timestamp_ns as f64 * 1e-9;
                let t0 = *t0.get_or_insert(t);
                if t - t0 > budget_s {
                    return finder.finish().map_err(|e| e.to_string());
                }
                let next = expected.get(finder.measured()).copied().unwrap_or([0.0; 2]);
                let mut params = job.localize_params(next);
                if job.board.code.is_some() {
                    params.hint_mm = None;
                }
                // A frame of a moving machine may not localize: it is not a stop.
                let Ok(o) = drivers::blocking(|| localize(&frame.image, &job.board, &params))
                else {
                    continue;
                };
                run.localized += 1;
                match finder
                    .push(t, [o.x_mm, o.y_mm])
                    .map_err(|e| e.to_string())?
                {
                    Seen::Stop { index, .. } => {
                        let stop = TapeStop {
                            index,
                            command_mm: commands[index],
                            observation: o,
                            t_s: t,
                        };
                        on_stop(&stop)?;
                        run.machine_time_s = t - t0;
                        run.stops.push(stop);
                        if finder.done() {
                            return Ok(());
                        }
                    }
                    Seen::Moving | Seen::Still => {}
                }
            }
        };
        tokio::pin!(grabbing);
        let grabbed = loop {
            tokio::select! {
                r = &mut streaming, if !stream_done => match r {
                    Ok(_) => stream_done = true,
                    Err(e) => break Err(format!("the tape: {e}")),
                },
                g = &mut grabbing => break g,
            }
        };
        // Every stop found: the rest of the tape (the last dwell, M30, `%`) is sent, so
        // the controller is ready for the next tape.
        match grabbed {
            Ok(()) if !stream_done => streaming
                .await
                .map(|_| ())
                .map_err(|e| format!("the tape's end: {e}")),
            other => other,
        }
    };
    if let Err(e) = ended {
        run.error = Some(e);
    }
    run
}

/// Why a scan through the tape ended early (the points measured are kept).
#[derive(Debug)]
pub enum TapeScanError {
    Cancelled,
    /// The builder refused a sample of plan point `index` (not a stage's error).
    Record {
        index: usize,
        message: String,
    },
    Journal(String),
    /// The tape or the stops ended it: `measured` plan points were measured.
    Tape {
        measured: usize,
        message: String,
    },
}

/// The map scan on a `tape_only` stage (`crate::scan::run_scan` comes here with the
/// targets: the reference point first, then the plan points `todo` not measured yet,
/// each with its approach): one measurement tape, each target dwelt at
/// ([`SCAN_DWELL_S`]), the stops found from the frames. The operator has done the
/// reference return (the stage cannot home) and the camera's orientation is not checked
/// by moves (the tape cannot wait for a frame): on a coded board every frame gives the
/// absolute position. Returns the reference frame's error (um) and rotation (degrees).
#[allow(clippy::too_many_arguments)]
pub(crate) async fn scan_by_tape(
    job: &Job,
    stage: &mut dyn Stage,
    camera: &mut dyn Camera,
    plan: &errormap::scan::ScanPlan,
    builder: &mut errormap::scan::MapBuilder,
    targets: &[TapeTarget],
    todo: &[usize],
    on_sample: &mut dyn FnMut(usize, &errormap::scan::Sample) -> Result<(), String>,
    progress: &mut dyn FnMut(usize, usize),
    cancel: impl std::future::Future<Output = ()>,
) -> Result<([f64; 2], f64), TapeScanError> {
    // The plan visits each point from both sides in a row: one rest to a camera that
    // misses the 0.1 mm trip between them. The tape visits every point approached from
    // below first, then from above (each pass in turn), in the plan's order.
    let mut order: Vec<usize> = (0..todo.len()).collect();
    order.sort_by_key(|&k| {
        let p = &plan.points[todo[k]];
        (
            p.pass,
            p.dir.x != Approach::Forward,
            p.dir.y != Approach::Forward,
        )
    });
    let todo: Vec<usize> = order.iter().map(|&k| todo[k]).collect();
    let targets: Vec<TapeTarget> = targets[..1]
        .iter()
        .chain(order.iter().map(|&k| &targets[k + 1]))
        .copied()
        .collect();
    let (tape, stops) = job_specs(job);
    let z = job.board_at_machine_zero_mm;
    let total = plan.points.len();
    let mut reference: Option<([f64; 2], f64)> = None;
    let mut failed: Option<TapeScanError> = None;
    let mut on_stop = |s: &TapeStop| -> Result<(), String> {
        let hint = [s.command_mm[0] + z[0], s.command_mm[1] + z[1]];
        let o = &s.observation;
        let error_um = [(o.x_mm - hint[0]) * 1000.0, (o.y_mm - hint[1]) * 1000.0];
        let Some((r_um, r_deg)) = reference else {
            reference = Some((error_um, o.rotation_deg));
            return Ok(());
        };
        let index = todo[s.index - 1];
        let sample = errormap::scan::Sample {
            error_um: [error_um[0] - r_um[0], error_um[1] - r_um[1]],
            yaw_urad: (o.rotation_deg - r_deg).to_radians() * 1e6,
        };
        if let Err(e) = builder.record(plan, index, sample) {
            let message = e.to_string();
            failed = Some(TapeScanError::Record {
                index,
                message: message.clone(),
            });
            return Err(message);
        }
        if let Err(e) = on_sample(index, &sample) {
            failed = Some(TapeScanError::Journal(e.clone()));
            return Err(e);
        }
        progress(builder.done(), total);
        Ok(())
    };
    let run = tokio::select! {
        biased;
        () = cancel => None,
        r = measure_by_tape(job, stage, camera, &targets, &tape, &stops, &mut on_stop) => Some(r),
    };
    let Some(run) = run else {
        return Err(TapeScanError::Cancelled);
    };
    if let Some(e) = failed {
        return Err(e);
    }
    match (run.error, reference) {
        (None, Some(r)) => Ok(r),
        (error, _) => Err(TapeScanError::Tape {
            measured: run.stops.len().saturating_sub(1),
            message: error.unwrap_or_else(|| "the reference point was not measured".into()),
        }),
    }
}

/// The dwell at each target of a measuring tape, s (the camera needs frames spanning a
/// third of it while the machine is still).
pub const SCAN_DWELL_S: f64 = 3.0;

/// How a job's measuring tapes are written and their stops found (map, ISO 230-2,
/// verify alike): the job's feed, [`SCAN_DWELL_S`] at each target, IS-B; still within
/// 2 um for a third of the dwell, within the job's largest correction (at least 0.05 mm)
/// of the next target.
pub fn job_specs(job: &Job) -> (TapeSpec, StopSpec) {
    (
        TapeSpec {
            feed_mm_min: job.feed_mm_min,
            dwell_s: SCAN_DWELL_S,
            increment_mm: 0.001,
        },
        StopSpec {
            still_mm: 0.002,
            min_still_s: SCAN_DWELL_S / 3.0,
            bound_mm: job.policy.max_correction_mm.max(0.05),
        },
    )
}

/// The measured stops' errors from their commands, um: where the board says the camera
/// is minus the command's board position.
pub(crate) fn stop_error_um(job: &Job, s: &TapeStop, nominal_mm: [f64; 2]) -> [f64; 2] {
    let z = job.board_at_machine_zero_mm;
    [
        (s.observation.x_mm - nominal_mm[0] - z[0]) * 1000.0,
        (s.observation.y_mm - nominal_mm[1] - z[1]) * 1000.0,
    ]
}

/// The reference point measured through a tape of its own (approached from below on
/// both axes, as a scan's reference is; the operator has done the reference return):
/// the stop, its error from the point (um), and `still_frames` more frames of the
/// machine resting there after the tape's end (board mm), for the localization's
/// repeatability.
pub async fn reference_by_tape(
    job: &Job,
    stage: &mut dyn Stage,
    camera: &mut dyn Camera,
    reference_mm: [f64; 2],
    still_frames: usize,
) -> Result<(TapeStop, [f64; 2], Vec<[f64; 2]>), String> {
    let (tape, stops) = job_specs(job);
    let a = job.policy.approach_mm;
    let target = TapeTarget {
        approach_mm: [reference_mm[0] - a, reference_mm[1] - a],
        command_mm: reference_mm,
    };
    let run = measure_by_tape(
        job,
        stage,
        camera,
        &[target],
        &tape,
        &stops,
        &mut |_| Ok(()),
    )
    .await;
    if let Some(e) = run.error {
        return Err(format!("the reference point's tape: {e}"));
    }
    let stop = run
        .stops
        .into_iter()
        .next()
        .ok_or("the reference point's tape ended without a stop")?;
    let error_um = stop_error_um(job, &stop, reference_mm);
    let z = job.board_at_machine_zero_mm;
    let hint = [reference_mm[0] + z[0], reference_mm[1] + z[1]];
    let mut still = Vec::with_capacity(still_frames);
    for frame_no in 0..still_frames {
        let frame = camera.grab().await.map_err(|e| e.to_string())?;
        let params = job.localize_params(hint);
        let o = drivers::blocking(|| localize(&frame.image, &job.board, &params))
            .map_err(|e| format!("still frame {frame_no} at the reference point: {e}"))?;
        still.push([o.x_mm, o.y_mm]);
    }
    Ok((stop, error_um, still))
}

/// One positioning of the compensation loop on a `tape_only` stage (each corrective move
/// a short tape of its own), returning once the camera has seen the machine stop there,
/// so the frame grabbed next is of the machine at rest. A correction may be a fraction of
/// a micrometre, which no camera sees as a move, and the trip to the approach point
/// 0.05 mm away is too short to be sure a frame falls in it; so the tape first goes to a
/// point twice the stops' bound away on both axes (below, or above where the travel
/// ends), dwells there (a stop of its own, not the target's), then the approach point
/// (0.05 mm below when the policy gives none), the command, the dwell.
pub async fn position_by_tape(
    job: &Job,
    stage: &mut dyn Stage,
    camera: &mut dyn Camera,
    positioning: &compensation::correction::Positioning,
    limits: &compensation::correction::SoftLimits,
) -> Result<(), String> {
    let (tape, stops) = job_specs(job);
    let c = positioning.command_mm;
    let away = 2.0 * stops.bound_mm;
    let far = [0, 1].map(|k| {
        if c[k] - away >= limits.min_mm[k] {
            c[k] - away
        } else {
            c[k] + away
        }
    });
    let targets = [
        TapeTarget {
            approach_mm: far,
            command_mm: far,
        },
        TapeTarget {
            approach_mm: positioning
                .approach_from_mm
                .unwrap_or([c[0] - 0.05, c[1] - 0.05]),
            command_mm: c,
        },
    ];
    let run = measure_by_tape(job, stage, camera, &targets, &tape, &stops, &mut |_| Ok(())).await;
    match run.error {
        None => Ok(()),
        Some(e) => Err(e),
    }
}

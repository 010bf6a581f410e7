//! An ISO 230-2 positioning test through any stage driver, measured by the camera on the
//! board (`gateway iso230`): home, check the camera's orientation and measure the
//! reference point (the compensation session does both, with no correction), take a
//! few still frames there for the localization's repeatability, then run the cycle of
//! [`iso230::plan::Cycle`] along one axis with the other held, measuring each target's
//! deviation along the axis as the camera sees it on the certified board.
//!
//! Deviation convention: x_ij = (board position the camera sees - nominal target) along
//! the tested axis, um, in the board's (certified) frame; a constant offset (the homing
//! error, the board's placement) shifts every deviation alike and changes no figure.
//!
//! With a map, each target is commanded where the map says the camera lands on it
//! (`MapModel::camera_command_for`, approached from the run's side on the tested axis and
//! from below on the held one), after re-referencing the map to this homing; overrun
//! points are commanded as they are. The camera measures its own point, so the test
//! commands the camera onto the targets: with the map's tool offset zero (as `gateway
//! map` scans by default) that is `command_for`'s command, the tool's; with an offset,
//! the tool differs from the camera by the yaw times the offset (the map's Abbe term). Nothing else is corrected. A frame that does not localize
//! stops the cycle (the stage is told to stop); every measurement taken before it has
//! already gone to `on_measurement`.

use crate::{JobError, Orchestrator};
use compensation::correction::SoftLimits;
use devices::Devices;
use drivers::AxisValues;
use errormap::{Approach, Direction as MapDirection, MapModel, ModelError};
use iso230::plan::{Cycle, Step};
use iso230::{Direction, Measurement};
use job::Job;

/// What to test.
#[derive(Clone, Debug)]
pub struct Iso230Spec {
    /// 0 for X, 1 for Y.
    pub axis: usize,
    pub cycle: Cycle,
    /// The held axis's position, machine mm.
    pub across_mm: f64,
    /// Still frames at the reference point for the localization's repeatability.
    pub still_frames: usize,
}

/// A finished cycle.
#[derive(Clone, Debug)]
pub struct Iso230Run {
    pub measurements: Vec<Measurement>,
    /// The tested axis's coordinate in each still frame, um (for the uncertainty).
    pub still_um: Vec<f64>,
}

#[derive(Debug, thiserror::Error)]
pub enum Iso230Error {
    #[error("{what} ({:.3}, {:.3}) mm: {message}; nothing was moved", at[0], at[1])]
    OutOfLimits {
        what: String,
        at: [f64; 2],
        message: String,
    },
    #[error("the map: {0}; nothing was moved")]
    Map(ModelError),
    #[error("the reference frame: {0}")]
    Reference(JobError),
    #[error("position {position_index} ({target_mm:.3} mm), run {run}, direction {}: {source}; the stage was stopped", direction.sign())]
    Measure {
        position_index: usize,
        target_mm: f64,
        run: usize,
        direction: Direction,
        #[source]
        source: JobError,
    },
    #[error("a move of the cycle: {0}; the stage was stopped")]
    Move(JobError),
    #[error("cancelled by the operator; the stage was told to stop")]
    Cancelled,
    /// On a tape port (`crate::tape`): the tape or its stops ended the cycle; the
    /// measurements taken before went to `on_measurement`.
    #[error("the measurement tape: {message} ({measured} measurements taken and kept)")]
    Tape { measured: usize, message: String },
}

pub const AXIS_NAMES: [&str; 2] = ["X", "Y"];

/// The travel a test can use along each axis: the stage's limits less the overrun,
/// within the board as the camera sees it (2 mm in from its edge), machine mm.
pub fn test_area(job: &Job, limits: &SoftLimits, overrun_mm: f64) -> ([f64; 2], [f64; 2]) {
    let a = overrun_mm.max(0.0) + 0.001;
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

pub(crate) fn point(axis: usize, along: f64, across: f64) -> [f64; 2] {
    if axis == 0 {
        [along, across]
    } else {
        [across, along]
    }
}

pub(crate) fn map_direction(axis: usize, d: Direction) -> MapDirection {
    let along = match d {
        Direction::Up => Approach::Forward,
        Direction::Down => Approach::Reverse,
    };
    if axis == 0 {
        MapDirection {
            x: along,
            y: Approach::Forward,
        }
    } else {
        MapDirection {
            x: Approach::Forward,
            y: along,
        }
    }
}

/// Run the test. `on_measurement` gets each measurement as it is taken; `progress`
/// (measurements done, planned).
pub async fn run_iso230(
    job: &Job,
    devices: &mut Devices,
    spec: &Iso230Spec,
    map: Option<&MapModel>,
    on_measurement: &mut dyn FnMut(&Measurement),
    progress: &mut dyn FnMut(usize, usize),
    cancel: impl std::future::Future<Output = ()>,
) -> Result<Iso230Run, Iso230Error> {
    let stage = devices.stage.as_mut();
    let camera = devices.camera.as_mut();
    let axis = spec.axis;
    let limits = crate::soft_limits(stage.info()).map_err(Iso230Error::Reference)?;
    let steps = spec.cycle.steps();
    // Every point inside the limits (and the map) before anything moves; a compensated
    // command is within a few um of its target, checked again when it is computed.
    let (below, above) = spec.cycle.span_mm();
    for (what, along) in [
        ("the lower overrun point", below),
        ("the upper overrun point", above),
    ] {
        let at = point(axis, along, spec.across_mm);
        limits
            .check(what, at)
            .map_err(|e| Iso230Error::OutOfLimits {
                what: what.into(),
                at,
                message: e.to_string(),
            })?;
    }
    if let Some(model) = map {
        for &t in &spec.cycle.targets_mm {
            model
                .camera_command_for(point(axis, t, spec.across_mm), MapDirection::FORWARD)
                .map_err(Iso230Error::Map)?;
        }
    }
    if stage.capabilities().tape_only {
        // A closed controller: the cycle as one tape, the stops found from the frames.
        let cycle = iso230_by_tape(
            job,
            stage,
            camera,
            spec,
            map,
            &limits,
            on_measurement,
            progress,
        );
        let result = tokio::select! {
            biased;
            () = cancel => Err(Iso230Error::Cancelled),
            r = cycle => r,
        };
        if result.is_err() {
            let _ = devices.stage.stop().await;
        }
        return result;
    }
    // Homing, the orientation check and the reference frame: a compensation job of one
    // target and no correction (the map's reference point, else the first target).
    let z = job.board_at_machine_zero_mm;
    let reference_mm = match map {
        Some(m) => m.map().reference_mm,
        None => point(axis, spec.cycle.targets_mm[0], spec.across_mm),
    };
    let mut one = job.clone();
    one.targets = vec![[reference_mm[0] + z[0], reference_mm[1] + z[1]]];
    one.policy.max_iterations = 0;
    let outcome = Orchestrator {
        stage: &mut *stage,
        camera: &mut *camera,
        job: &one,
    }
    .run(&mut |_| {})
    .await
    .map_err(|f| Iso230Error::Reference(f.error))?;
    let seen_um = outcome.completed[0].first().deviation.um();
    let model = match map {
        Some(m) => Some(m.clone().rereferenced(seen_um).map_err(Iso230Error::Map)?),
        None => None,
    };
    let total = steps
        .iter()
        .filter(|s| matches!(s, Step::Measure { .. }))
        .count();
    let feed = job.feed_mm_min;
    let mut measurements = Vec::with_capacity(total);
    let mut still_um = Vec::new();
    let run = async {
        // The localization's repeatability: still frames at the reference point.
        let hint = one.targets[0];
        for frame_no in 0..spec.still_frames {
            let at = crate::measure::At {
                path: &[],
                target_mm: hint,
                index: 0,
                measurement: frame_no,
                free_on_coded_board: false,
            };
            let o = crate::measure::measure_at(job, stage, camera, at)
                .await
                .map_err(Iso230Error::Reference)?
                .observation;
            still_um.push([o.x_mm, o.y_mm][axis] * 1000.0);
        }
        // The held axis approached from below, then the cycle.
        let start = point(axis, below, spec.across_mm - spec.cycle.overrun_mm);
        stage
            .move_to(AxisValues::xy(start[0], start[1]), feed)
            .await
            .map_err(|e| Iso230Error::Move(e.into()))?;
        stage
            .wait_idle()
            .await
            .map_err(|e| Iso230Error::Move(e.into()))?;
        let mut across_cmd = spec.across_mm;
        for step in &steps {
            tokio::task::yield_now().await;
            match *step {
                Step::Travel { at_mm } => {
                    let c = point(axis, at_mm, across_cmd);
                    stage
                        .move_to(AxisValues::xy(c[0], c[1]), feed)
                        .await
                        .map_err(|e| Iso230Error::Move(e.into()))?;
                    stage
                        .wait_idle()
                        .await
                        .map_err(|e| Iso230Error::Move(e.into()))?;
                }
                Step::Measure {
                    position,
                    run,
                    direction,
                    at_mm,
                } => {
                    let fail = |source| Iso230Error::Measure {
                        position_index: position + 1,
                        target_mm: at_mm,
                        run,
                        direction,
                        source,
                    };
                    let nominal = point(axis, at_mm, spec.across_mm);
                    let c = match &model {
                        Some(m) => m
                            .camera_command_for(nominal, map_direction(axis, direction))
                            .map_err(Iso230Error::Map)?,
                        None => nominal,
                    };
                    across_cmd = c[1 - axis];
                    limits.check("a compensated target", c).map_err(|e| {
                        Iso230Error::OutOfLimits {
                            what: format!("position {} compensated", position + 1),
                            at: c,
                            message: e.to_string(),
                        }
                    })?;
                    let hint = [nominal[0] + z[0], nominal[1] + z[1]];
                    let at = crate::measure::At {
                        path: &[c],
                        target_mm: hint,
                        index: position,
                        measurement: run,
                        free_on_coded_board: false,
                    };
                    let o = crate::measure::measure_at(job, stage, camera, at)
                        .await
                        .map_err(fail)?
                        .observation;
                    let seen = [o.x_mm, o.y_mm][axis];
                    let m = Measurement {
                        axis: AXIS_NAMES[axis].into(),
                        position_index: position + 1,
                        target_mm: at_mm,
                        run,
                        direction,
                        deviation_um: (seen - hint[axis]) * 1000.0,
                    };
                    on_measurement(&m);
                    measurements.push(m);
                    progress(measurements.len(), total);
                }
            }
        }
        Ok(())
    };
    // Biased: a cancel is seen at the next yield between two steps, every time.
    let result = tokio::select! {
        biased;
        () = cancel => Err(Iso230Error::Cancelled),
        r = run => r,
    };
    match result {
        Ok(()) => Ok(Iso230Run {
            measurements,
            still_um,
        }),
        Err(e) => {
            let _ = devices.stage.stop().await;
            Err(e)
        }
    }
}

/// ISO 230-2 on a `tape_only` stage ([`run_iso230`] comes here; its checks
/// of the limits and the map are done): the reference point on a tape of its own (the
/// map re-referenced by it, the still frames taken there), then the whole cycle as one
/// tape: the held axis approached from below, then every step, each target approached
/// from the step before it. Every point of the cycle is dwelt at, the overrun points
/// too (their stops are not measurements): a target measured twice in a row on the way
/// back (the last of a run up, the first of the run down) would otherwise be one rest to
/// a camera that missed the short trip to the overrun point between them.
#[allow(clippy::too_many_arguments)]
async fn iso230_by_tape(
    job: &Job,
    stage: &mut dyn drivers::Stage,
    camera: &mut dyn drivers::Camera,
    spec: &Iso230Spec,
    map: Option<&errormap::MapModel>,
    limits: &compensation::correction::SoftLimits,
    on_measurement: &mut dyn FnMut(&iso230::Measurement),
    progress: &mut dyn FnMut(usize, usize),
) -> Result<Iso230Run, Iso230Error> {
    use iso230::plan::Step;
    use Iso230Error as E;
    let axis = spec.axis;
    let (_, stops) = crate::tape::job_specs(job);
    let (below, _) = spec.cycle.span_mm();
    if spec.cycle.overrun_mm <= 2.0 * stops.bound_mm {
        return Err(E::Tape {
            measured: 0,
            message: format!(
                "the overrun ({} mm) must be more than twice the stops' bound ({} mm): a stop at an overrun point would read as its target's",
                spec.cycle.overrun_mm, stops.bound_mm
            ),
        });
    }
    let reference_mm = match map {
        Some(m) => m.map().reference_mm,
        None => point(axis, spec.cycle.targets_mm[0], spec.across_mm),
    };
    let (_, seen_um, still) =
        crate::tape::reference_by_tape(job, stage, camera, reference_mm, spec.still_frames)
            .await
            .map_err(|message| E::Tape {
                measured: 0,
                message,
            })?;
    let model = match map {
        Some(m) => Some(m.clone().rereferenced(seen_um).map_err(E::Map)?),
        None => None,
    };
    // Every command of the cycle, checked against the limits before the tape goes.
    let start = point(axis, below, spec.across_mm - spec.cycle.overrun_mm);
    let mut at = start;
    let mut across_cmd = spec.across_mm;
    let mut targets = Vec::new();
    // Per target: the measurement it is (position, run, direction, nominal), or none.
    let mut legs = Vec::new();
    for step in spec.cycle.steps() {
        let (c, leg) = match step {
            Step::Travel { at_mm } => (point(axis, at_mm, across_cmd), None),
            Step::Measure {
                position,
                run,
                direction,
                at_mm,
            } => {
                let nominal = point(axis, at_mm, spec.across_mm);
                let c = match &model {
                    Some(m) => m
                        .camera_command_for(nominal, map_direction(axis, direction))
                        .map_err(E::Map)?,
                    None => nominal,
                };
                limits
                    .check("a compensated target", c)
                    .map_err(|e| E::OutOfLimits {
                        what: format!("position {} compensated", position + 1),
                        at: c,
                        message: e.to_string(),
                    })?;
                across_cmd = c[1 - axis];
                (c, Some((position, run, direction, at_mm, nominal)))
            }
        };
        targets.push(errormap::tape::TapeTarget {
            approach_mm: at,
            command_mm: c,
        });
        legs.push(leg);
        at = c;
    }
    let total = legs.iter().flatten().count();
    let z = job.board_at_machine_zero_mm;
    let (tape, stop_spec) = crate::tape::job_specs(job);
    let mut measurements = Vec::with_capacity(total);
    let mut on_stop = |s: &crate::tape::TapeStop| -> Result<(), String> {
        let Some((position, run, direction, at_mm, nominal)) = legs[s.index] else {
            return Ok(());
        };
        let seen = [s.observation.x_mm, s.observation.y_mm][axis];
        let m = iso230::Measurement {
            axis: AXIS_NAMES[axis].into(),
            position_index: position + 1,
            target_mm: at_mm,
            run,
            direction,
            deviation_um: (seen - (nominal[axis] + z[axis])) * 1000.0,
        };
        on_measurement(&m);
        measurements.push(m);
        progress(measurements.len(), total);
        Ok(())
    };
    let run = crate::tape::measure_by_tape(
        job,
        stage,
        camera,
        &targets,
        &tape,
        &stop_spec,
        &mut on_stop,
    )
    .await;
    match run.error {
        None => Ok(Iso230Run {
            measurements,
            still_um: still.iter().map(|p| p[axis] * 1000.0).collect(),
        }),
        Some(message) => Err(E::Tape {
            measured: measurements.len(),
            message,
        }),
    }
}

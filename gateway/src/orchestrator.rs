//! The orchestrator: runs the compensation pipeline through the driver traits.
//!
//! For each target (board coordinates): position the stage at the nominal command
//! (approaching from one side to take up backlash), grab a frame, localize the board,
//! compute D, and correct until |D| is within tolerance or the iterations run out.
//! This is the only module that does I/O; every decision is made by the pure functions
//! of `localize` and `correction`. A failed localization or a refused correction stops
//! the job before any further motion, and the results gathered so far are kept.

use crate::config::Job;
use crate::correction::{
    deviation, next_step, plan_positioning, CorrectionError, Deviation, NextStep, Positioning,
    SoftLimits,
};
use crate::localize::{localize, LocalizeError, LocalizeParams, Observation};
use drivers::{Axis, AxisValues, Camera, DriverError, Stage};
use serde::Serialize;

/// One measurement at one command.
#[derive(Clone, Debug, Serialize)]
pub struct Measurement {
    /// Machine command the stage was at, mm.
    pub command_mm: [f64; 2],
    pub observation: Observation,
    pub deviation: Deviation,
    /// The camera's frame counter, to tie the measurement to a frame.
    pub frame_sequence: u64,
}

/// What happened at one target.
#[derive(Clone, Debug, Serialize)]
pub struct TargetOutcome {
    pub index: usize,
    pub target_mm: [f64; 2],
    /// Measurements in order: the first is the uncompensated positioning.
    pub measurements: Vec<Measurement>,
    pub converged: bool,
}

impl TargetOutcome {
    pub fn first(&self) -> &Measurement {
        &self.measurements[0]
    }

    pub fn last(&self) -> &Measurement {
        self.measurements
            .last()
            .expect("an outcome has at least one measurement")
    }

    /// Corrective moves made after the first positioning.
    pub fn corrections(&self) -> usize {
        self.measurements.len() - 1
    }
}

/// Progress notifications; the demo also uses `Measured` to read the simulated truth at
/// the moment of each measurement.
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
}

/// A job stopped by an error, with everything measured before it.
#[derive(Debug)]
pub struct JobFailure {
    pub completed: Vec<TargetOutcome>,
    pub error: JobError,
}

pub struct Orchestrator<'a> {
    pub stage: &'a mut dyn Stage,
    pub camera: &'a mut dyn Camera,
    pub job: &'a Job,
}

impl Orchestrator<'_> {
    /// Soft limits of X and Y from the stage.
    pub fn limits(&self) -> Result<SoftLimits, JobError> {
        let info = self.stage.info();
        let x = info.axis(Axis::X).ok_or(JobError::MissingAxis(Axis::X))?;
        let y = info.axis(Axis::Y).ok_or(JobError::MissingAxis(Axis::Y))?;
        Ok(SoftLimits {
            min_mm: [x.min_mm, y.min_mm],
            max_mm: [x.max_mm, y.max_mm],
        })
    }

    /// Home, then compensate every target of the job in order.
    pub async fn run(
        &mut self,
        on_event: &mut dyn FnMut(Event),
    ) -> Result<Vec<TargetOutcome>, JobFailure> {
        let mut completed = Vec::new();
        let fail = |completed: Vec<TargetOutcome>, error: JobError| JobFailure { completed, error };
        if let Err(e) = self.stage.home().await {
            return Err(fail(completed, e.into()));
        }
        if let Err(e) = self.stage.wait_idle().await {
            return Err(fail(completed, e.into()));
        }
        on_event(Event::Homed);
        let n = self.job.targets.len();
        for (index, &target) in self.job.targets.iter().enumerate() {
            match self.compensate(index, target, on_event).await {
                Ok(outcome) => {
                    on_event(Event::TargetDone {
                        outcome: &outcome,
                        of: n,
                    });
                    completed.push(outcome);
                }
                Err(error) => {
                    // Leave the machine still and safe, then report.
                    let _ = self.stage.stop().await;
                    return Err(fail(completed, error));
                }
            }
        }
        Ok(completed)
    }

    /// Position at one target and correct until within tolerance.
    pub async fn compensate(
        &mut self,
        index: usize,
        target_mm: [f64; 2],
        on_event: &mut dyn FnMut(Event),
    ) -> Result<TargetOutcome, JobError> {
        let limits = self.limits()?;
        let policy = &self.job.policy;
        let nominal = self.job.command_for(target_mm);
        let correction_err = |source| JobError::Correction {
            index,
            target_mm,
            source,
        };
        let mut positioning = plan_positioning(nominal, policy, &limits).map_err(correction_err)?;
        let mut measurements: Vec<Measurement> = Vec::new();
        loop {
            self.position(&positioning).await?;
            let frame = self.camera.grab().await?;
            let params = self.localize_params(target_mm);
            let board = &self.job.board;
            let observation = drivers::blocking(|| localize(&frame.image, board, &params))
                .map_err(|source| JobError::Localize {
                    index,
                    target_mm,
                    measurement: measurements.len(),
                    source,
                })?;
            let d = deviation([observation.x_mm, observation.y_mm], target_mm);
            let m = Measurement {
                command_mm: positioning.command_mm,
                observation,
                deviation: d,
                frame_sequence: frame.meta.sequence,
            };
            on_event(Event::Measured {
                target_index: index,
                measurement: &m,
            });
            measurements.push(m);
            let done = (measurements.len() - 1) as u32;
            match next_step(nominal, positioning.command_mm, d, done, policy, &limits)
                .map_err(correction_err)?
            {
                NextStep::Converged => {
                    return Ok(TargetOutcome {
                        index,
                        target_mm,
                        measurements,
                        converged: true,
                    })
                }
                NextStep::Exhausted => {
                    return Ok(TargetOutcome {
                        index,
                        target_mm,
                        measurements,
                        converged: false,
                    })
                }
                NextStep::Correct(next) => positioning = next,
            }
        }
    }

    async fn position(&mut self, p: &Positioning) -> Result<(), JobError> {
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

    fn localize_params(&self, hint_mm: [f64; 2]) -> LocalizeParams {
        let l = &self.job.localize;
        let mut p = LocalizeParams::new(hint_mm);
        p.method = l.method;
        p.pixel_axes = self.job.pixel_axes;
        p.um_per_px = self.job.um_per_px;
        p.hint_tolerance_mm = l.hint_tolerance_mm;
        p.max_residual_um = l.max_residual_um;
        p.min_points = l.min_points;
        p
    }
}

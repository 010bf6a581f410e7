//! The compensation loop as a sans-IO state machine: observations in, the next action
//! out. Whoever owns the devices (the runner today; the service, ISO 230-2 runs and map
//! scans later) performs each [`Action`] and reports back; every decision (where to
//! go, whether to correct, when to stop) is made here, before anything moves.
//!
//! ```text
//! new ─► Home ─homed()─► [orientation check] ─► Position(t0) ─positioned()─► Measure(t0)
//!                                                 ▲                              │
//!                                                 │                         measured()
//!                          Position(t0 corrected) or Position(t1) … ◄────────────┘
//!                                                                   … Finished
//! orientation check: CheckPosition(base) ─positioned()─► CheckMeasure(base) ─checked()─►
//!   CheckPosition(base + s·X) … CheckMeasure ─► CheckPosition(base + s·Y) … CheckMeasure
//! ```
//!
//! Nothing is corrected before the orientation check has passed: it moves the stage by
//! a known step `s` along X, then along Y (each approached from the same side, so
//! backlash cancels), and compares how far the board moved in the image with the
//! commanded step. A camera mounted turned or mirrored against the job's `pixel_axes`,
//! or a wrong scale, fails here, before the first corrective move (see
//! [`OrientationCheck`]). Every corrective move is then judged against the model: one
//! that leaves more than `divergence_ratio` of the deviation it was to cancel stops the
//! loop (`CorrectionError::NotConverging`).
//!
//! Worked example (policy: tolerance 0.5 um, approach 0.05 mm): a target at board
//! (50, 30) mm with the board at (5, 5) mm under machine zero has the nominal command
//! (45, 25). The session asks to position at (45, 25) from (44.95, 24.95); the frame
//! localizes at board (50.012, 29.993), so D = (+12, -7) um and the next action is a
//! positioning at (44.988, 25.007), approached from (44.938, 24.957).

use crate::correction::{
    deviation, next_step, plan_positioning, CorrectionError, CorrectionPolicy, Deviation, NextStep,
    Positioning, SoftLimits,
};
use serde::Serialize;
use vision::localize::Observation;

/// One target of a session: where it is on the board, and the nominal machine command
/// that should put the camera there on a perfect machine.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Target {
    pub board_mm: [f64; 2],
    pub command_mm: [f64; 2],
}

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
    /// The job stopped while working on this target (its measurements so far are kept).
    pub stopped: bool,
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

/// What the device owner must do next.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Action {
    /// Home the stage and wait until it is idle, then call [`CompensationSession::homed`].
    Home,
    /// Move to `positioning.approach_from_mm` (if any) and wait, then to
    /// `positioning.command_mm` and wait; then call [`CompensationSession::positioned`].
    Position {
        target_index: usize,
        positioning: Positioning,
    },
    /// Grab a frame, localize it with `hint_mm` as the expected board coordinate, then
    /// call [`CompensationSession::measured`]. `measurement` counts from 0 per target.
    Measure {
        target_index: usize,
        target_mm: [f64; 2],
        hint_mm: [f64; 2],
        measurement: usize,
    },
    /// Every target is done.
    Finished,
    /// Orientation check: move to `positioning.approach_from_mm` (if any) and wait, then
    /// to `positioning.command_mm` and wait; then call [`CompensationSession::positioned`].
    CheckPosition {
        step: CheckStep,
        positioning: Positioning,
    },
    /// Orientation check: grab a frame, localize it with `hint_mm` and this hint
    /// tolerance (wider than a target's: the check is what finds a wrong set-up), then
    /// call [`CompensationSession::checked`].
    CheckMeasure {
        step: CheckStep,
        hint_mm: [f64; 2],
        hint_tolerance_mm: f64,
    },
}

/// The three positions of the orientation check.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum CheckStep {
    /// The first target's command.
    Base,
    /// The base plus the step along machine X.
    AlongX,
    /// The base plus the step along machine Y.
    AlongY,
}

impl std::fmt::Display for CheckStep {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            CheckStep::Base => "at the start position",
            CheckStep::AlongX => "after the step along X",
            CheckStep::AlongY => "after the step along Y",
        })
    }
}

/// How the orientation check moves: a step that is not a multiple of the board's pitch
/// (otherwise a camera turned by 90 degrees would see the same dots and pass), and the
/// hint tolerance to find the board after it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct OrientationCheck {
    pub step_mm: f64,
    pub hint_tolerance_mm: f64,
    /// Largest accepted |observed - commanded| board displacement, as a fraction of the
    /// step.
    pub tolerance: f64,
}

impl OrientationCheck {
    /// For a board of this pitch: a step of 0.2 pitch, found within 0.45 pitch (under
    /// half a pitch, so the dot lattice stays unambiguous), accepted within 20 % of the
    /// step (20 um for a 0.5 mm pitch: far above the stage's error over 0.1 mm, far
    /// below what a turned (141 %) or mirrored (200 %) camera gives). The step is small
    /// enough that a reversed or turned displacement is still the nearest lattice
    /// position to the expected one, so the check names what is wrong (at 0.3 pitch a
    /// mirrored axis would read as +0.7 pitch, a wrong scale).
    pub fn for_pitch(pitch_mm: f64) -> Self {
        Self {
            step_mm: 0.2 * pitch_mm,
            hint_tolerance_mm: 0.45 * pitch_mm,
            tolerance: 0.2,
        }
    }
}

/// What the orientation check measured: how the board moved in the image for each
/// commanded machine step, mm.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct OrientationResult {
    pub step_mm: f64,
    pub moved_for_x_mm: [f64; 2],
    pub moved_for_y_mm: [f64; 2],
    /// Rotation of the image axes against the machine's, degrees (0 when right).
    pub rotation_deg: f64,
    /// Measured / commanded step length (1 when right).
    pub scale: f64,
    /// The image is mirrored against the machine (one axis reversed).
    pub mirrored: bool,
}

impl OrientationResult {
    fn of(step_mm: f64, x: [f64; 2], y: [f64; 2]) -> Self {
        let rot_x = x[1].atan2(x[0]);
        let rot_y = (-y[0]).atan2(y[1]);
        let mean = (rot_x.sin() + rot_y.sin()).atan2(rot_x.cos() + rot_y.cos());
        Self {
            step_mm,
            moved_for_x_mm: x,
            moved_for_y_mm: y,
            rotation_deg: mean.to_degrees(),
            scale: (x[0].hypot(x[1]) + y[0].hypot(y[1])) / (2.0 * step_mm),
            mirrored: x[0] * y[1] - x[1] * y[0] < 0.0,
        }
    }

    /// The larger miss of the two steps, as a fraction of the step.
    pub fn miss(&self) -> f64 {
        let s = self.step_mm;
        let mx = (self.moved_for_x_mm[0] - s).hypot(self.moved_for_x_mm[1]);
        let my = self.moved_for_y_mm[0].hypot(self.moved_for_y_mm[1] - s);
        mx.max(my) / s
    }
}

impl std::fmt::Display for OrientationResult {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let [a, b] = self.moved_for_x_mm;
        let [c, d] = self.moved_for_y_mm;
        write!(
            f,
            "a {s:.3} mm step along machine X moved the board ({a:+.3}, {b:+.3}) mm in the image and one along Y ({c:+.3}, {d:+.3}) mm: the image is turned by {r:.1} degrees{m}, scale {k:.3}",
            s = self.step_mm,
            r = self.rotation_deg,
            m = if self.mirrored { " and mirrored" } else { "" },
            k = self.scale,
        )
    }
}

impl Action {
    fn name(&self) -> &'static str {
        match self {
            Action::Home => "homing",
            Action::Position { .. } => "a positioning",
            Action::Measure { .. } => "a measurement",
            Action::Finished => "nothing (the session is finished)",
            Action::CheckPosition { .. } => "a positioning of the orientation check",
            Action::CheckMeasure { .. } => "a measurement of the orientation check",
        }
    }
}

/// The result of one measurement: what was measured, the target it finished (if it
/// did), and the next action.
#[derive(Clone, Debug)]
pub struct Step {
    pub measurement: Measurement,
    pub finished: Option<TargetOutcome>,
    pub next: Action,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SessionError {
    /// A target cannot be reached or corrected safely; nothing was moved for it.
    #[error("target #{index} ({:.3}, {:.3}) mm: {source}", target_mm[0], target_mm[1])]
    Correction {
        index: usize,
        target_mm: [f64; 2],
        #[source]
        source: CorrectionError,
    },
    /// The camera does not see the machine's moves as the job's `pixel_axes` and scale
    /// say; nothing was corrected.
    #[error("orientation check: {result}; check the job's `camera.pixel_axes` and `camera.um_per_px` against how the camera is mounted; nothing was corrected")]
    Orientation { result: OrientationResult },
    /// The device owner reported something the session did not ask for.
    #[error("the compensation session asked for {expected}, but was told of {got}")]
    OutOfOrder {
        expected: &'static str,
        got: &'static str,
    },
}

/// The target being worked on.
#[derive(Clone, Debug)]
struct InProgress {
    index: usize,
    positioning: Positioning,
    measurements: Vec<Measurement>,
}

/// The orientation check under way: where it started and what it saw so far.
#[derive(Clone, Debug)]
struct CheckInProgress {
    plan: OrientationCheck,
    base_mm: [f64; 2],
    /// Signed step per axis (negative where the positive step would leave the limits).
    step_mm: [f64; 2],
    seen: Vec<[f64; 2]>,
}

/// The compensation of a list of targets, one after the other.
#[derive(Clone, Debug)]
pub struct CompensationSession {
    targets: Vec<Target>,
    policy: CorrectionPolicy,
    limits: SoftLimits,
    next: Action,
    current: Option<InProgress>,
    completed: Vec<TargetOutcome>,
    check: Option<CheckInProgress>,
    orientation: Option<OrientationResult>,
    /// On a coded board (absolute positions): re-reference the machine when a
    /// measurement is further off than any correction (lost steps, no homing).
    rereference: bool,
    /// Machine coordinate offset found by re-referencing, mm: commands are the targets'
    /// plus this.
    offset_mm: [f64; 2],
    rereferences: Vec<Rereference>,
}

/// A re-referencing: a measurement on a coded board further from its target than any
/// correction may move, taken as the machine having lost its reference (lost steps, a
/// machine that was never homed); the commands of this and every later target shift
/// by the deviation.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Rereference {
    pub target_index: usize,
    /// Observed minus target at the measurement, mm: what the machine had lost.
    pub deviation_mm: [f64; 2],
    /// The machine offset from then on (target + offset = command), mm.
    pub offset_mm: [f64; 2],
}

impl CompensationSession {
    /// A session that starts by homing. Every target's positioning is planned here, so
    /// a target outside the soft limits is refused before anything moves.
    /// `orientation`: the check to run before the first target (when the policy asks
    /// for it); None skips it.
    pub fn new(
        targets: Vec<Target>,
        policy: CorrectionPolicy,
        limits: SoftLimits,
        orientation: Option<OrientationCheck>,
    ) -> Result<Self, SessionError> {
        for (index, t) in targets.iter().enumerate() {
            plan_positioning(t.command_mm, &policy, &limits).map_err(|source| {
                SessionError::Correction {
                    index,
                    target_mm: t.board_mm,
                    source,
                }
            })?;
        }
        let check = match (orientation, targets.first()) {
            (Some(plan), Some(first)) if policy.check_orientation => {
                let base_mm = first.command_mm;
                let mut step_mm = [plan.step_mm; 2];
                for k in 0..2 {
                    let mut p = base_mm;
                    p[k] += plan.step_mm;
                    if plan_positioning(p, &policy, &limits).is_err() {
                        step_mm[k] = -plan.step_mm;
                    }
                }
                Some(CheckInProgress {
                    plan,
                    base_mm,
                    step_mm,
                    seen: Vec::new(),
                })
            }
            _ => None,
        };
        Ok(Self {
            targets,
            policy,
            limits,
            next: Action::Home,
            current: None,
            completed: Vec::new(),
            check,
            orientation: None,
            rereference: false,
            offset_mm: [0.0, 0.0],
            rereferences: Vec::new(),
        })
    }

    /// What the orientation check measured, once it has passed or failed.
    pub fn orientation(&self) -> Option<&OrientationResult> {
        self.orientation.as_ref()
    }

    /// The action the session waits for.
    pub fn next_action(&self) -> Action {
        self.next
    }

    /// Targets finished so far (converged or out of iterations), in order.
    pub fn completed(&self) -> &[TargetOutcome] {
        &self.completed
    }

    /// The target being worked on and its measurements so far.
    pub fn in_progress(&self) -> Option<(usize, &[Measurement])> {
        self.current
            .as_ref()
            .map(|c| (c.index, c.measurements.as_slice()))
    }

    /// The finished targets, consuming the session.
    pub fn into_completed(self) -> Vec<TargetOutcome> {
        self.completed
    }

    /// Every target worked on: the finished ones, then (when the session stopped in the
    /// middle of one) the target under way with its measurements so far, marked
    /// `stopped`. What a report shows after a failure.
    pub fn into_outcomes(mut self) -> Vec<TargetOutcome> {
        if let Some(c) = self.current.take() {
            if !c.measurements.is_empty() {
                self.completed.push(TargetOutcome {
                    index: c.index,
                    target_mm: self.targets[c.index].board_mm,
                    measurements: c.measurements,
                    converged: false,
                    stopped: true,
                });
            }
        }
        self.completed
    }

    /// On a coded board: take a deviation beyond `max_correction_mm` as a lost reference
    /// and re-reference (see [`Rereference`]) instead of refusing.
    pub fn allow_rereference(mut self) -> Self {
        self.rereference = true;
        self
    }

    /// Start without homing (a coded board: the first frame re-references the machine):
    /// the session begins where [`CompensationSession::homed`] would have led.
    pub fn skip_homing(&mut self) -> Result<Action, SessionError> {
        self.homed()
    }

    /// The re-referencings so far.
    pub fn rereferences(&self) -> &[Rereference] {
        &self.rereferences
    }

    /// The stage is homed and idle.
    pub fn homed(&mut self) -> Result<Action, SessionError> {
        self.expect(matches!(self.next, Action::Home), "homing")?;
        if self.check.is_some() {
            return self.next_check_position();
        }
        self.start_target(0)
    }

    /// The orientation check's next positioning (base, then along X, then along Y).
    fn next_check_position(&mut self) -> Result<Action, SessionError> {
        let check = self.check.as_ref().expect("a check is under way");
        let (step, at) = match check.seen.len() {
            0 => (CheckStep::Base, check.base_mm),
            1 => (
                CheckStep::AlongX,
                [check.base_mm[0] + check.step_mm[0], check.base_mm[1]],
            ),
            _ => (
                CheckStep::AlongY,
                [check.base_mm[0], check.base_mm[1] + check.step_mm[1]],
            ),
        };
        let positioning = plan_positioning(at, &self.policy, &self.limits)
            .map_err(|source| self.correction_error(0, source))?;
        self.next = Action::CheckPosition { step, positioning };
        Ok(self.next)
    }

    /// A frame of the orientation check was localized (board coordinate at the image
    /// centre, mm).
    pub fn checked(&mut self, observed_mm: [f64; 2]) -> Result<Action, SessionError> {
        let Action::CheckMeasure { .. } = self.next else {
            return Err(self.out_of_order("a measurement of the orientation check"));
        };
        let check = self.check.as_mut().expect("a check is under way");
        check.seen.push(observed_mm);
        if check.seen.len() < 3 {
            return self.next_check_position();
        }
        let check = self.check.take().expect("checked above");
        let [base, x, y] = [check.seen[0], check.seen[1], check.seen[2]];
        // Per unit of positive step, so a step taken backwards near a limit compares
        // the same way.
        let sx = check.step_mm[0].signum();
        let sy = check.step_mm[1].signum();
        let result = OrientationResult::of(
            check.plan.step_mm,
            [(x[0] - base[0]) * sx, (x[1] - base[1]) * sx],
            [(y[0] - base[0]) * sy, (y[1] - base[1]) * sy],
        );
        self.orientation = Some(result);
        if result.miss() > check.plan.tolerance {
            self.next = Action::Finished;
            return Err(SessionError::Orientation { result });
        }
        self.start_target(0)
    }

    /// The stage is at the commanded position and idle.
    pub fn positioned(&mut self) -> Result<Action, SessionError> {
        if let Action::CheckPosition { step, .. } = self.next {
            let check = self.check.as_ref().expect("a check is under way");
            let target = self.targets[0].board_mm;
            // Where the board should be seen: at the base, the first target; after a
            // step, the base as seen plus the step (the stage's own error over the
            // step is microns; a wrong set-up shows as tenths of a millimetre).
            let hint_mm = match step {
                CheckStep::Base => target,
                CheckStep::AlongX => [check.seen[0][0] + check.step_mm[0], check.seen[0][1]],
                CheckStep::AlongY => [check.seen[0][0], check.seen[0][1] + check.step_mm[1]],
            };
            self.next = Action::CheckMeasure {
                step,
                hint_mm,
                hint_tolerance_mm: check.plan.hint_tolerance_mm,
            };
            return Ok(self.next);
        }
        let Action::Position { target_index, .. } = self.next else {
            return Err(self.out_of_order("a positioning"));
        };
        let current = self.current.as_ref().expect("a positioning has a target");
        let target_mm = self.targets[target_index].board_mm;
        self.next = Action::Measure {
            target_index,
            target_mm,
            hint_mm: target_mm,
            measurement: current.measurements.len(),
        };
        Ok(self.next)
    }

    /// A frame taken at the positioning was localized.
    pub fn measured(
        &mut self,
        observation: Observation,
        frame_sequence: u64,
    ) -> Result<Step, SessionError> {
        let Action::Measure { target_index, .. } = self.next else {
            return Err(self.out_of_order("a measurement"));
        };
        let target = self.targets[target_index];
        let current = self.current.as_mut().expect("a measurement has a target");
        let d = deviation([observation.x_mm, observation.y_mm], target.board_mm);
        let previous = current.measurements.last().map(|m| m.deviation);
        let measurement = Measurement {
            command_mm: current.positioning.command_mm,
            observation,
            deviation: d,
            frame_sequence,
        };
        current.measurements.push(measurement.clone());
        let done = (current.measurements.len() - 1) as u32;
        let beyond = d.dx_mm.abs().max(d.dy_mm.abs()) > self.policy.max_correction_mm;
        if self.rereference && beyond && done < self.policy.max_iterations {
            // Lost steps: the machine is where the code says, not where it believes.
            let command = [
                current.positioning.command_mm[0] - d.dx_mm,
                current.positioning.command_mm[1] - d.dy_mm,
            ];
            self.offset_mm = [
                command[0] - target.command_mm[0],
                command[1] - target.command_mm[1],
            ];
            self.rereferences.push(Rereference {
                target_index,
                deviation_mm: [d.dx_mm, d.dy_mm],
                offset_mm: self.offset_mm,
            });
            let positioning =
                plan_positioning(command, &self.policy, &self.limits).map_err(|source| {
                    SessionError::Correction {
                        index: target_index,
                        target_mm: target.board_mm,
                        source,
                    }
                })?;
            current.positioning = positioning;
            self.next = Action::Position {
                target_index,
                positioning,
            };
            return Ok(Step {
                measurement,
                finished: None,
                next: self.next,
            });
        }
        let nominal = [
            target.command_mm[0] + self.offset_mm[0],
            target.command_mm[1] + self.offset_mm[1],
        ];
        let decision = next_step(
            nominal,
            current.positioning.command_mm,
            d,
            previous,
            done,
            &self.policy,
            &self.limits,
        )
        .map_err(|source| SessionError::Correction {
            index: target_index,
            target_mm: target.board_mm,
            source,
        })?;
        let converged = match decision {
            NextStep::Correct(positioning) => {
                current.positioning = positioning;
                self.next = Action::Position {
                    target_index,
                    positioning,
                };
                return Ok(Step {
                    measurement,
                    finished: None,
                    next: self.next,
                });
            }
            NextStep::Converged => true,
            NextStep::Exhausted => false,
        };
        let current = self.current.take().expect("checked above");
        let outcome = TargetOutcome {
            index: current.index,
            target_mm: target.board_mm,
            measurements: current.measurements,
            converged,
            stopped: false,
        };
        self.completed.push(outcome.clone());
        let next = self.start_target(target_index + 1)?;
        Ok(Step {
            measurement,
            finished: Some(outcome),
            next,
        })
    }

    /// Plan the first positioning of target `index`, or finish.
    fn start_target(&mut self, index: usize) -> Result<Action, SessionError> {
        let Some(target) = self.targets.get(index).copied() else {
            self.next = Action::Finished;
            return Ok(self.next);
        };
        let command = [
            target.command_mm[0] + self.offset_mm[0],
            target.command_mm[1] + self.offset_mm[1],
        ];
        let positioning = plan_positioning(command, &self.policy, &self.limits)
            .map_err(|source| self.correction_error(index, source))?;
        self.current = Some(InProgress {
            index,
            positioning,
            measurements: Vec::new(),
        });
        self.next = Action::Position {
            target_index: index,
            positioning,
        };
        Ok(self.next)
    }

    fn correction_error(&self, index: usize, source: CorrectionError) -> SessionError {
        SessionError::Correction {
            index,
            target_mm: self.targets[index].board_mm,
            source,
        }
    }

    fn expect(&self, ok: bool, got: &'static str) -> Result<(), SessionError> {
        if ok {
            Ok(())
        } else {
            Err(self.out_of_order(got))
        }
    }

    fn out_of_order(&self, got: &'static str) -> SessionError {
        SessionError::OutOfOrder {
            expected: self.next.name(),
            got,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use vision::localize::Method;

    const LIMITS: SoftLimits = SoftLimits {
        min_mm: [0.0, 0.0],
        max_mm: [200.0, 150.0],
    };

    fn seen_at(x_mm: f64, y_mm: f64) -> Observation {
        Observation {
            x_mm,
            y_mm,
            points: 100,
            residual_rms_um: 0.1,
            um_per_px: 4.0,
            rotation_deg: 0.0,
            rejected: 0,
            method: Method::Fit,
            code: None,
        }
    }

    /// A stage that has lost `lost` mm (the carriage is that far short of the command)
    /// on a coded board: the session re-references and every target ends on target.
    fn lost_steps_run(lost: [f64; 2]) -> CompensationSession {
        let targets = vec![
            target([50.0, 30.0]),
            target([120.0, 90.0]),
            target([60.0, 140.0]),
        ];
        let mut s = session(targets.clone()).allow_rereference();
        let mut action = s.homed().unwrap();
        let mut seq = 0;
        let mut command = [0.0, 0.0];
        // The loss happens during the move to the second target (index 1).
        let mut lost_now = [0.0, 0.0];
        loop {
            action = match action {
                Action::Position {
                    target_index,
                    positioning,
                } => {
                    if target_index == 1 {
                        lost_now = lost;
                    }
                    command = positioning.command_mm;
                    s.positioned().unwrap()
                }
                Action::Measure { .. } => {
                    seq += 1;
                    // Machine zero at board (5, 5), a 7 um machine error, the loss.
                    let seen = [
                        command[0] + 5.0 + 0.007 - lost_now[0],
                        command[1] + 5.0 - 0.004 - lost_now[1],
                    ];
                    s.measured(seen_at(seen[0], seen[1]), seq).unwrap().next
                }
                Action::Finished => break,
                other => panic!("{other:?}"),
            };
        }
        s
    }

    #[test]
    fn lost_steps_on_a_coded_board_are_found_and_every_target_ends_on_target() {
        for lost in [[0.3, 0.0], [0.0, 2.0], [20.0, -20.0]] {
            let s = lost_steps_run(lost);
            let r = s.rereferences();
            assert_eq!(r.len(), 1, "{lost:?}: {r:?}");
            assert_eq!(r[0].target_index, 1);
            assert!(
                (r[0].deviation_mm[0] + lost[0]).abs() < 0.01
                    && (r[0].deviation_mm[1] + lost[1]).abs() < 0.01,
                "{r:?}"
            );
            let done = s.completed();
            assert_eq!(done.len(), 3);
            for o in done {
                assert!(o.converged, "{lost:?}: {o:?}");
                assert!(o.last().deviation.magnitude_um() <= 0.5, "{o:?}");
            }
        }
        // Without re-referencing (a plain grid) a 2 mm loss stops the job.
        let targets = vec![target([50.0, 30.0])];
        let mut s = session(targets);
        let Action::Position { positioning, .. } = s.homed().unwrap() else {
            panic!()
        };
        s.positioned().unwrap();
        let c = positioning.command_mm;
        assert!(s
            .measured(seen_at(c[0] + 5.0, c[1] + 5.0 - 2.0), 1)
            .is_err());
    }

    fn target(board: [f64; 2]) -> Target {
        Target {
            board_mm: board,
            command_mm: [board[0] - 5.0, board[1] - 5.0],
        }
    }

    fn session(targets: Vec<Target>) -> CompensationSession {
        CompensationSession::new(targets, CorrectionPolicy::default(), LIMITS, None).unwrap()
    }

    #[test]
    fn the_worked_example_corrects_then_converges_then_finishes() {
        let mut s = session(vec![target([50.0, 30.0])]);
        assert_eq!(s.next_action(), Action::Home);
        let Action::Position { positioning, .. } = s.homed().unwrap() else {
            panic!("{:?}", s.next_action())
        };
        assert_eq!(positioning.command_mm, [45.0, 25.0]);
        assert_eq!(positioning.approach_from_mm, Some([44.95, 24.95]));
        let Action::Measure {
            hint_mm,
            measurement,
            ..
        } = s.positioned().unwrap()
        else {
            panic!()
        };
        assert_eq!((hint_mm, measurement), ([50.0, 30.0], 0));
        let step = s.measured(seen_at(50.012, 29.993), 7).unwrap();
        assert!(step.finished.is_none());
        let Action::Position { positioning, .. } = step.next else {
            panic!("{:?}", step.next)
        };
        assert!((positioning.command_mm[0] - 44.988).abs() < 1e-9);
        assert!((positioning.command_mm[1] - 25.007).abs() < 1e-9);
        assert_eq!(s.in_progress().map(|(i, m)| (i, m.len())), Some((0, 1)));
        s.positioned().unwrap();
        let step = s.measured(seen_at(50.0001, 30.0002), 8).unwrap();
        let outcome = step.finished.expect("converged");
        assert!(outcome.converged && !outcome.stopped);
        assert_eq!(outcome.corrections(), 1);
        assert_eq!(outcome.last().frame_sequence, 8);
        assert_eq!(step.next, Action::Finished);
        assert_eq!(s.completed().len(), 1);
        assert!(s.in_progress().is_none());
    }

    #[test]
    fn a_target_out_of_reach_is_refused_before_anything_moves() {
        let e = CompensationSession::new(
            vec![target([50.0, 30.0]), target([260.0, 30.0])],
            CorrectionPolicy::default(),
            LIMITS,
            None,
        )
        .unwrap_err();
        assert!(
            matches!(e, SessionError::Correction { index: 1, .. }),
            "{e}"
        );
        assert!(
            e.to_string().contains("target #1 (260.000, 30.000) mm"),
            "{e}"
        );
    }

    #[test]
    fn a_stop_mid_target_keeps_its_measurements() {
        let mut s = session(vec![target([50.0, 30.0]), target([60.0, 30.0])]);
        s.homed().unwrap();
        s.positioned().unwrap();
        s.measured(seen_at(50.0, 30.0), 1).unwrap();
        s.positioned().unwrap();
        s.measured(seen_at(60.012, 30.0), 2).unwrap();
        s.positioned().unwrap();
        // The correction made it worse (12 um -> 20 um): the loop stops, and the second
        // target's two measurements stay in the outcomes.
        let e = s.measured(seen_at(60.0, 30.020), 3).unwrap_err();
        assert!(
            matches!(
                e,
                SessionError::Correction {
                    index: 1,
                    source: CorrectionError::NotConverging { .. },
                    ..
                }
            ),
            "{e}"
        );
        let outcomes = s.into_outcomes();
        assert_eq!(outcomes.len(), 2);
        assert!(outcomes[0].converged && !outcomes[0].stopped);
        assert!(outcomes[1].stopped && !outcomes[1].converged);
        assert_eq!(outcomes[1].measurements.len(), 2);
    }

    #[test]
    fn reports_out_of_order_calls_without_changing_state() {
        let mut s = session(vec![target([50.0, 30.0])]);
        let e = s.measured(seen_at(50.0, 30.0), 0).unwrap_err();
        assert_eq!(
            e,
            SessionError::OutOfOrder {
                expected: "homing",
                got: "a measurement"
            }
        );
        assert!(s.positioned().is_err());
        assert_eq!(s.next_action(), Action::Home);
    }

    #[test]
    fn an_empty_session_finishes_after_homing() {
        let mut s = session(Vec::new());
        assert_eq!(s.homed().unwrap(), Action::Finished);
        assert!(s.into_completed().is_empty());
    }

    /// Run the orientation check with a camera whose image axes map machine moves by
    /// `m` (board displacement seen = m * machine displacement).
    fn check_with(
        m: [[f64; 2]; 2],
        first: [f64; 2],
    ) -> (CompensationSession, Result<Action, SessionError>) {
        let mut s = CompensationSession::new(
            vec![target(first)],
            CorrectionPolicy::default(),
            LIMITS,
            Some(OrientationCheck::for_pitch(0.5)),
        )
        .unwrap();
        // The board seen at the base is 40 um off the target (a wrong mapping also
        // puts the first frame off).
        let base_seen = [first[0] + 0.04, first[1]];
        let mut action = s.homed().unwrap();
        let mut base_cmd = None;
        loop {
            let Action::CheckPosition { positioning, .. } = action else {
                return (s, Ok(action));
            };
            let cmd = positioning.command_mm;
            let b = *base_cmd.get_or_insert(cmd);
            assert!(
                positioning.approach_from_mm.is_some(),
                "approached like a target"
            );
            let Action::CheckMeasure {
                hint_tolerance_mm, ..
            } = s.positioned().unwrap()
            else {
                panic!()
            };
            assert_eq!(hint_tolerance_mm, 0.225);
            let d = [cmd[0] - b[0], cmd[1] - b[1]];
            let seen = [
                base_seen[0] + m[0][0] * d[0] + m[0][1] * d[1],
                base_seen[1] + m[1][0] * d[0] + m[1][1] * d[1],
            ];
            match s.checked(seen) {
                Ok(a) => action = a,
                Err(e) => return (s, Err(e)),
            }
        }
    }

    #[test]
    fn the_orientation_check_passes_a_right_camera_and_then_works_on_targets() {
        let (s, next) = check_with([[1.0, 0.0], [0.0, 1.0]], [50.0, 30.0]);
        let Ok(Action::Position {
            target_index: 0,
            positioning,
        }) = next
        else {
            panic!("{next:?}")
        };
        assert_eq!(positioning.command_mm, [45.0, 25.0]);
        let r = s.orientation().unwrap();
        assert!(r.rotation_deg.abs() < 1e-6 && (r.scale - 1.0).abs() < 1e-9 && !r.mirrored);
        assert!((r.moved_for_x_mm[0] - 0.1).abs() < 1e-9 && r.moved_for_x_mm[1].abs() < 1e-9);
    }

    #[test]
    fn a_turned_or_mirrored_camera_fails_the_check_before_any_correction() {
        let turned = check_with([[0.0, -1.0], [1.0, 0.0]], [50.0, 30.0])
            .1
            .unwrap_err();
        let SessionError::Orientation { result } = &turned else {
            panic!("{turned}")
        };
        assert!(
            (result.rotation_deg - 90.0).abs() < 1e-6 && !result.mirrored,
            "{turned}"
        );
        assert!(
            turned.to_string().contains("turned by 90.0 degrees"),
            "{turned}"
        );
        assert!(turned.to_string().contains("pixel_axes"), "{turned}");
        let mirrored = check_with([[-1.0, 0.0], [0.0, 1.0]], [50.0, 30.0])
            .1
            .unwrap_err();
        assert!(mirrored.to_string().contains("mirrored"), "{mirrored}");
        let scaled = check_with([[1.3, 0.0], [0.0, 1.3]], [50.0, 30.0])
            .1
            .unwrap_err();
        assert!(scaled.to_string().contains("scale 1.300"), "{scaled}");
    }

    #[test]
    fn the_check_steps_backwards_at_the_far_limit() {
        // The first target sits at the far corner of the travel: the steps go to -X/-Y
        // and the result is still judged per positive step.
        let (s, next) = check_with([[1.0, 0.0], [0.0, 1.0]], [205.0, 155.0]);
        assert!(matches!(next, Ok(Action::Position { .. })), "{next:?}");
        let r = s.orientation().unwrap();
        assert!((r.moved_for_x_mm[0] - 0.1).abs() < 1e-9, "{r:?}");
    }
}

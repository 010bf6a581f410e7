//! The compensation loop as a sans-IO state machine: observations in, the next action
//! out. Whoever owns the devices (the runner today; the service, ISO 230-2 runs and map
//! scans later) performs each [`Action`] and reports back; every decision (where to
//! go, whether to correct, when to stop) is made here, before anything moves.
//!
//! ```text
//! new ─► Home ─homed()─► Position(t0) ─positioned()─► Measure(t0) ─measured()─┐
//!                          ▲                                                 │
//!                          └── Position(t0 corrected) or Position(t1) … ◄────┘
//!                                                         … Finished
//! ```
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
}

impl Action {
    fn name(&self) -> &'static str {
        match self {
            Action::Home => "homing",
            Action::Position { .. } => "a positioning",
            Action::Measure { .. } => "a measurement",
            Action::Finished => "nothing (the session is finished)",
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

/// The compensation of a list of targets, one after the other.
#[derive(Clone, Debug)]
pub struct CompensationSession {
    targets: Vec<Target>,
    policy: CorrectionPolicy,
    limits: SoftLimits,
    next: Action,
    current: Option<InProgress>,
    completed: Vec<TargetOutcome>,
}

impl CompensationSession {
    /// A session that starts by homing.
    pub fn new(targets: Vec<Target>, policy: CorrectionPolicy, limits: SoftLimits) -> Self {
        Self {
            targets,
            policy,
            limits,
            next: Action::Home,
            current: None,
            completed: Vec::new(),
        }
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

    /// The stage is homed and idle.
    pub fn homed(&mut self) -> Result<Action, SessionError> {
        self.expect(matches!(self.next, Action::Home), "homing")?;
        self.start_target(0)
    }

    /// The stage is at the commanded position and idle.
    pub fn positioned(&mut self) -> Result<Action, SessionError> {
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
        let measurement = Measurement {
            command_mm: current.positioning.command_mm,
            observation,
            deviation: d,
            frame_sequence,
        };
        current.measurements.push(measurement.clone());
        let done = (current.measurements.len() - 1) as u32;
        let decision = next_step(
            target.command_mm,
            current.positioning.command_mm,
            d,
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
        let positioning = plan_positioning(target.command_mm, &self.policy, &self.limits)
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
        }
    }

    fn target(board: [f64; 2]) -> Target {
        Target {
            board_mm: board,
            command_mm: [board[0] - 5.0, board[1] - 5.0],
        }
    }

    #[test]
    fn the_worked_example_corrects_then_converges_then_finishes() {
        let mut s = CompensationSession::new(
            vec![target([50.0, 30.0])],
            CorrectionPolicy::default(),
            LIMITS,
        );
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
        assert!(outcome.converged);
        assert_eq!(outcome.corrections(), 1);
        assert_eq!(outcome.last().frame_sequence, 8);
        assert_eq!(step.next, Action::Finished);
        assert_eq!(s.completed().len(), 1);
        assert!(s.in_progress().is_none());
    }

    #[test]
    fn a_target_out_of_reach_is_refused_before_any_move_and_keeps_earlier_targets() {
        let mut s = CompensationSession::new(
            vec![target([50.0, 30.0]), target([260.0, 30.0])],
            CorrectionPolicy::default(),
            LIMITS,
        );
        s.homed().unwrap();
        s.positioned().unwrap();
        let e = s.measured(seen_at(50.0, 30.0), 0).unwrap_err();
        assert!(
            matches!(e, SessionError::Correction { index: 1, .. }),
            "{e}"
        );
        assert!(
            e.to_string().contains("target #1 (260.000, 30.000) mm"),
            "{e}"
        );
        assert_eq!(s.completed().len(), 1);
    }

    #[test]
    fn reports_out_of_order_calls_without_changing_state() {
        let mut s = CompensationSession::new(
            vec![target([50.0, 30.0])],
            CorrectionPolicy::default(),
            LIMITS,
        );
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
        let mut s = CompensationSession::new(Vec::new(), CorrectionPolicy::default(), LIMITS);
        assert_eq!(s.homed().unwrap(), Action::Finished);
        assert!(s.into_completed().is_empty());
    }
}

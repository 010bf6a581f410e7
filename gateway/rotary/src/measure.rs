//! The measurement cycle on the machine with a touch probe (the paper's plan, executed
//! through whatever drives the machine): the C rotation centre first, from a circle
//! through 3 points touched on the table's rim at A = C = 0 (the balls are then looked
//! for around it); C in 12 steps of 30° at A = 0, A in 6 steps of
//! 15° at C = 0; at each step 6 points on each ball, each approached along the sphere's
//! normal, touched fast, backed off and touched again slowly; a sphere fitted per ball
//! and step (radius free, checked against the certified radius plus the stylus); the
//! centres then go to [`crate::identify`].
//!
//! The cycle is sans-IO: a [`MeasureSession`] says what the machine is to do next
//! ([`Action`]: a positioning move, a probing move, or finished) and is told how it went
//! ([`MeasureSession::moved`], [`MeasureSession::probed`], [`MeasureSession::failed`]),
//! so whoever owns the machine (a synchronous [`ProbingMachine`] through [`measure`], an
//! async driver in the runner) drives the same cycle move for move. A stop
//! ([`MeasureSession::stop`]) ends it before its next move, keeping what it measured.

use crate::centres::{Axis, CentreRow};
use crate::design::{optimal_design, Design};
use crate::identify::{check_sphere, fit_sphere, FitError, SphereFit};
use crate::machine::{Axes, RotaryMachine};
use crate::{Artifact, MachineConstants};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// What the cycle needs from the machine: positioning moves and probing moves of the
/// spindle gauge point (machine X, Y, Z in mm, A and C in degrees).
pub trait ProbingMachine {
    /// A positioning move (rapid) to all five axes.
    fn move_to(&mut self, target: &Axes) -> Result<(), String>;
    /// A probing move (G38.3-like: no alarm on a miss) of X, Y, Z from where the machine
    /// is to `to` at `feed_mm_min`, the rotary axes staying: the gauge point where the
    /// probe triggered, or `None` if it reached `to` without contact. The machine stops
    /// at the trigger point (or at `to`).
    fn probe_towards(&mut self, to: [f64; 3], feed_mm_min: f64)
        -> Result<Option<[f64; 3]>, String>;
}

/// The cycle's settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeasurePlan {
    /// The nominal artifact (where the balls should be; a few tenths of a millimetre
    /// off is fine, the approach distance covers it).
    pub artifact: Artifact,
    /// The stylus ball's effective radius (its radius less the pre-travel, as
    /// calibrated on a reference).
    pub stylus_radius_mm: f64,
    /// Free distance before the expected contact where each touch starts.
    pub approach_mm: f64,
    /// How far the probe may go past the expected contact before the ball counts as
    /// not found.
    pub overtravel_mm: f64,
    /// Back-off after the fast touch, before the slow one.
    pub backoff_mm: f64,
    pub fast_feed_mm_min: f64,
    pub slow_feed_mm_min: f64,
    /// Angle from the ball's top (machine +Z) of the five touches around it; the sixth
    /// is the top.
    pub cone_deg: f64,
    /// Sphere acceptance: fitted radius within this of certified + stylus ...
    pub radius_tolerance_mm: f64,
    /// ... and RMS residual at most this.
    pub residual_limit_mm: f64,
    /// Height of the gauge point for moves between balls and steps (machine Z).
    pub safe_z_mm: f64,
    /// Locating the C centre on the table's rim first (absent in a plan file: the
    /// defaults).
    #[serde(default)]
    pub rim: RimPlan,
    /// Which table positions are measured (absent: the optimal design of the default
    /// plan).
    #[serde(default = "default_design")]
    pub design: PlanDesign,
    /// Touches per ball: the top and the others around it at `cone_deg` (at least 5, so
    /// that the sphere's residual says something; absent: 5).
    #[serde(default = "default_touches_per_ball")]
    pub touches_per_ball: usize,
    /// Where the probe goes between two touches of one ball (absent: over the ball).
    #[serde(default = "default_retract")]
    pub retract: Retract,
}

/// Which table positions the cycle measures: C positions at A = 0, A positions at C = 0.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum PlanDesign {
    /// The paper's: C in 12 steps of 30°, A in 6 steps of 15° (19 positions).
    Paper,
    /// The Ds-optimal `c_positions` and `a_positions` among the paper's for the eight
    /// errors ([`crate::design::optimal_design`]).
    Optimal {
        c_positions: usize,
        a_positions: usize,
    },
}

/// Where the probe goes between two touches of one ball.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Retract {
    /// Up to the safe height after every touch (the paper's plan).
    SafeHeight,
    /// Up only to `approach_mm` above the ball's top, then across to over the next
    /// start point: the stylus stays outside the ball grown by the approach distance
    /// (a start point at `cone_deg` is further than that from the ball's vertical axis,
    /// so the way up from it is clear, and the way across is above the ball). The safe
    /// height is kept between balls and to turn the table.
    OverBall,
}

fn default_design() -> PlanDesign {
    PlanDesign::Optimal {
        c_positions: 5,
        a_positions: 5,
    }
}

fn default_touches_per_ball() -> usize {
    5
}

fn default_retract() -> Retract {
    Retract::OverBall
}

/// Where and how the C rotation centre is found: 3 touches on the table's cylindrical rim,
/// horizontally towards the nominal C axis, at A = C = 0.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RimPlan {
    /// The rim's radius as drawn (NCTLT-125: 62.5 mm).
    pub radius_mm: f64,
    /// Height of the touches below the table face.
    pub depth_mm: f64,
    /// Directions of the touches from the C axis, degrees from machine +X (the plate
    /// lies along X: the default touches at 90°, 210° and 330° stay clear of it).
    pub angles_deg: [f64; 3],
    /// The fitted radius (less the stylus) must be within this of `radius_mm`.
    pub radius_tolerance_mm: f64,
    /// The located centre may be at most this far from the nominal C axis (X, Y); more
    /// and the constants are wrong for this machine: the cycle stops before looking for
    /// the balls where they are not.
    pub max_offset_mm: f64,
    /// How far above the touch's height the probing descent beside the rim starts: the
    /// probe comes down rapidly from the safe height to there, then probes its way down
    /// (25 mm: from 15 mm above the table face; absent in a plan file: 25). None: the
    /// whole way down from the safe height is a probing move (the paper's plan as first
    /// run, about 36 s a touch at 300 mm/min).
    #[serde(default = "default_protected_descent")]
    pub protected_descent_mm: Option<f64>,
}

fn default_protected_descent() -> Option<f64> {
    Some(25.0)
}

impl Default for RimPlan {
    fn default() -> Self {
        Self {
            radius_mm: 62.5,
            depth_mm: 10.0,
            angles_deg: [90.0, 210.0, 330.0],
            radius_tolerance_mm: 0.05,
            max_offset_mm: 1.0,
            protected_descent_mm: default_protected_descent(),
        }
    }
}

/// The C rotation centre found on the rim (machine frame, tool-tip coordinates, mm).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CCentre {
    pub x_mm: f64,
    pub y_mm: f64,
    /// The located centre minus the nominal C axis (the machine constants'), X and Y.
    pub offset_mm: [f64; 2],
    /// The rim's radius from the fit (stylus radius taken off).
    pub rim_radius_mm: f64,
    /// The stylus centres at the three slow touches.
    pub points: Vec<[f64; 3]>,
}

impl Default for MeasurePlan {
    /// The cycle of issue 39: the optimal 5 + 5 positions, 5 touches per ball, the probe
    /// kept over the balls between their touches, the rim's probing descent from 15 mm
    /// above the face, the slow touch at 50 mm/min (see `docs/rotary.md` for its figures
    /// beside the paper's plan).
    fn default() -> Self {
        Self {
            design: default_design(),
            touches_per_ball: default_touches_per_ball(),
            retract: default_retract(),
            rim: RimPlan::default(),
            // The slow touch at 50 mm/min (0.83 mm/s): GRBL latches the probe position
            // in its step interrupt (`probe_state_monitor`, stepper.c), so the feed
            // adds only the probe's own trigger-delay scatter times the speed; a probe
            // whose datasheet states its repeatability at a lower speed sets this lower.
            slow_feed_mm_min: 50.0,
            ..Self::paper()
        }
    }
}

impl MeasurePlan {
    /// The paper's plan as this project first ran it: 19 positions, 6 touches per ball,
    /// the probe up to the safe height after every touch.
    pub fn paper() -> Self {
        Self {
            artifact: Artifact::default(),
            stylus_radius_mm: 1.4992,
            approach_mm: 3.0,
            overtravel_mm: 2.0,
            backoff_mm: 0.5,
            fast_feed_mm_min: 300.0,
            slow_feed_mm_min: 20.0,
            cone_deg: 80.0,
            radius_tolerance_mm: 0.005,
            residual_limit_mm: 0.002,
            safe_z_mm: -20.0,
            rim: RimPlan {
                protected_descent_mm: None,
                ..RimPlan::default()
            },
            design: PlanDesign::Paper,
            touches_per_ball: 6,
            retract: Retract::SafeHeight,
        }
    }

    /// The table positions this plan measures, or why it cannot.
    pub fn positions(&self, constants: &MachineConstants) -> Result<Design, String> {
        if self.touches_per_ball < 5 {
            return Err(format!(
                "plan.touches_per_ball: {}, at least 5 (a sphere through 4 points has no residual to check)",
                self.touches_per_ball
            ));
        }
        match self.design {
            PlanDesign::Paper => Ok(Design::paper()),
            PlanDesign::Optimal {
                c_positions,
                a_positions,
            } => optimal_design(constants, &self.artifact, c_positions, a_positions)
                .map_err(|e| format!("plan.design: {e}")),
        }
    }
}

/// One ball at one step: the touched points and the sphere through them.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BallMeasurement {
    pub axis: Axis,
    pub step: u32,
    pub angle_deg: f64,
    pub ball: u8,
    /// Stylus centres at the slow touches (machine frame, mm).
    pub points: Vec<[f64; 3]>,
    pub sphere: SphereFit,
}

/// The cycle's result.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Measurement {
    /// The C centre located on the rim before the balls (None if the cycle stopped there).
    pub c_centre: Option<CCentre>,
    pub balls: Vec<BallMeasurement>,
    pub probe_touches: usize,
}

impl Measurement {
    /// The centres file rows.
    pub fn centres(&self) -> Vec<CentreRow> {
        self.balls
            .iter()
            .map(|b| CentreRow {
                axis: b.axis,
                step: b.step,
                angle_deg: b.angle_deg,
                ball: b.ball,
                x_mm: b.sphere.centre[0],
                y_mm: b.sphere.centre[1],
                z_mm: b.sphere.centre[2],
            })
            .collect()
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MeasureError {
    #[error("axis {axis} step {step} ball {ball}, touch {touch}: no contact within {overtravel_mm} mm past where the ball should be; stopped")]
    BallNotFound {
        axis: Axis,
        step: u32,
        ball: u8,
        touch: usize,
        overtravel_mm: f64,
    },
    #[error("axis {axis} step {step} ball {ball}: {source}; the point set is rejected")]
    Sphere {
        axis: Axis,
        step: u32,
        ball: u8,
        source: FitError,
    },
    #[error("the machine: {0}")]
    Machine(String),
    #[error("table rim, touch {touch} at {angle_deg}°: no contact within {overtravel_mm} mm past where the rim should be; stopped")]
    RimNotFound {
        touch: usize,
        angle_deg: f64,
        overtravel_mm: f64,
    },
    #[error("table rim: {0}; stopped before the balls")]
    Rim(String),
    #[error("the plan: {0}; nothing moved")]
    Plan(String),
    /// Stopped from outside ([`MeasureSession::stop`]) before the next move.
    #[error("{STOPPED_ON_REQUEST}")]
    StopRequested,
    /// The session ended ([`MeasureSession::finish`]) before its last move.
    #[error("the cycle ended before its last move")]
    Unfinished,
}

/// What a stopped cycle's error says when it was stopped on request.
pub const STOPPED_ON_REQUEST: &str = "stopped on request";

/// A stopped cycle: why, and what was measured until then (to be saved).
#[derive(Debug, Clone, PartialEq)]
pub struct Stopped {
    pub error: MeasureError,
    pub so_far: Measurement,
}

/// What the machine is to do next (machine X, Y, Z of the spindle gauge point in mm, A
/// and C in degrees).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Action {
    /// A positioning move (rapid) of all five axes, run to its end; answer
    /// [`MeasureSession::moved`].
    MoveTo(Axes),
    /// A probing move (G38.3-like: no alarm on a miss) of X, Y, Z from where the machine
    /// is to `to` at `feed_mm_min`, the rotary axes staying, stopping at the trigger
    /// point (or at `to`); answer [`MeasureSession::probed`] with the gauge point where
    /// the probe triggered, or `None`.
    ProbeTowards { to: [f64; 3], feed_mm_min: f64 },
    /// Nothing more to do: [`MeasureSession::finish`] gives the result.
    Finished,
}

/// The moves of one touch, on the rim or on a ball, in their order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Leg {
    /// Over the start point at the safe height.
    Above,
    /// Beside the rim: rapidly down to where the probing descent starts.
    Lower,
    /// Down to the start point (beside the rim: a probing move, so a table that is not
    /// where the constants put it stops the machine instead of crashing it).
    Descend,
    /// The fast touch.
    Fast,
    /// Back off from the fast touch point along the normal.
    BackOff,
    /// The slow touch.
    Slow,
    /// Back out to the start point.
    Retract,
    /// Up to the safe height.
    Up,
}

/// Where the cycle is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Cursor {
    /// Over the nominal C axis at the safe height.
    RimStart,
    /// Rim touch `touch` (0-based).
    Rim { touch: usize, leg: Leg },
    /// Turning the table for `step` of sweep `sweep` (0: C, 1: A), the probe up.
    Turn { sweep: usize, step: usize },
    /// Touch `touch` on ball `ball` (0-based) at a step.
    Ball {
        sweep: usize,
        step: usize,
        ball: usize,
        touch: usize,
        leg: Leg,
    },
    /// Every move done, or stopped.
    Done,
}

const SWEEPS: [Axis; 2] = [Axis::C, Axis::A];

/// One rim touch's geometry.
struct RimTouch {
    /// Outwards from the C axis, horizontal.
    u: Vector3<f64>,
    /// The start point (gauge point, A = C = 0).
    over: Axes,
    /// Where the probing moves go (gauge point).
    end: [f64; 3],
}

/// One ball touch's geometry.
struct BallTouch {
    axis: Axis,
    a: f64,
    c: f64,
    /// Outwards from the ball's centre.
    d: Vector3<f64>,
    /// The start point (gauge point).
    start: [f64; 3],
    /// Where the probing moves go (gauge point).
    end: [f64; 3],
    /// Certified radius plus the stylus's.
    reach: f64,
    /// The gauge point's height `approach_mm` over the ball's top, and over every
    /// ball's top at this position.
    over_z: f64,
    over_all_z: f64,
    /// The ball (0-based).
    ball: usize,
}

/// Where one ball should be at one step, worked out once for its touches.
#[derive(Clone, Debug)]
struct BallPlace {
    /// Sweep, step, ball.
    key: (usize, usize, usize),
    axis: Axis,
    a: f64,
    c: f64,
    centre: Vector3<f64>,
    /// Certified radius plus the stylus's.
    reach: f64,
    /// Outwards from the centre, one per touch.
    directions: Vec<Vector3<f64>>,
    /// The height `approach_mm` over the highest ball's top at this position (stylus
    /// centre, machine Z).
    over_all_z: f64,
}

/// The measurement cycle as a state machine: [`next_action`](Self::next_action) says
/// what the machine is to do, and the answer ([`moved`](Self::moved),
/// [`probed`](Self::probed) or [`failed`](Self::failed)) moves the cycle on. The
/// result is [`finish`](Self::finish)'s; what was measured so far is readable any time
/// ([`measurement`](Self::measurement), [`progress`](Self::progress)).
#[derive(Clone, Debug)]
pub struct MeasureSession {
    plan: MeasurePlan,
    nominal: RotaryMachine,
    tool_length_mm: f64,
    result: Measurement,
    cursor: Cursor,
    /// What `cursor` asks of the machine (computed when the cursor moves).
    action: Action,
    error: Option<MeasureError>,
    /// The rim's slow touches (stylus centres).
    rim_points: Vec<[f64; 3]>,
    /// The current ball's slow touches (stylus centres).
    ball_points: Vec<[f64; 3]>,
    /// The last fast touch (gauge point).
    fast: [f64; 3],
    /// The located C centre less the nominal axis (X, Y, 0), once the rim is done.
    offset: Vector3<f64>,
    /// The current ball's place.
    place: Option<BallPlace>,
    total: usize,
    /// The table positions measured.
    design: Design,
}

impl MeasureSession {
    /// The cycle for a machine with these nominal constants, to this plan; nothing has
    /// moved yet.
    pub fn new(constants: &MachineConstants, plan: &MeasurePlan) -> Self {
        let (design, refused) = match plan.positions(constants) {
            Ok(d) => (d, None),
            Err(e) => (Design::paper(), Some(e)),
        };
        let mut s = Self {
            plan: *plan,
            nominal: RotaryMachine::nominal(*constants),
            tool_length_mm: constants.tool_length_mm,
            result: Measurement {
                c_centre: None,
                balls: Vec::new(),
                probe_touches: 0,
            },
            cursor: Cursor::Done,
            action: Action::Finished,
            error: None,
            rim_points: Vec::new(),
            ball_points: Vec::new(),
            fast: [0.0; 3],
            offset: Vector3::zeros(),
            place: None,
            total: SWEEPS
                .iter()
                .map(|&axis| design.sweep(axis).len() * plan.artifact.balls.len())
                .sum(),
            design,
        };
        match refused {
            None => s.enter(Cursor::RimStart),
            Some(e) => s.stop_with(MeasureError::Plan(e)),
        }
        s
    }

    /// The table positions this cycle measures.
    pub fn design(&self) -> &Design {
        &self.design
    }

    /// What the machine is to do now (the same until it is answered).
    pub fn next_action(&self) -> Action {
        self.action
    }

    /// The positioning move of [`Action::MoveTo`] ended where it was sent.
    pub fn moved(&mut self) {
        if !matches!(self.action, Action::MoveTo(_)) {
            return self.misuse("a positioning move ended");
        }
        let next = match self.cursor {
            Cursor::RimStart => Cursor::Rim {
                touch: 0,
                leg: Leg::Above,
            },
            Cursor::Rim { touch, leg } => match leg {
                Leg::Above if self.plan.rim.protected_descent_mm.is_some() => Cursor::Rim {
                    touch,
                    leg: Leg::Lower,
                },
                Leg::Above | Leg::Lower => Cursor::Rim {
                    touch,
                    leg: Leg::Descend,
                },
                Leg::BackOff => Cursor::Rim {
                    touch,
                    leg: Leg::Slow,
                },
                Leg::Retract => Cursor::Rim {
                    touch,
                    leg: Leg::Up,
                },
                Leg::Up if touch + 1 < self.plan.rim.angles_deg.len() => Cursor::Rim {
                    touch: touch + 1,
                    leg: Leg::Above,
                },
                Leg::Up => match self.rim_done() {
                    Ok(()) => Cursor::Turn { sweep: 0, step: 0 },
                    Err(e) => return self.stop_with(e),
                },
                Leg::Descend | Leg::Fast | Leg::Slow => unreachable!("probing legs"),
            },
            Cursor::Turn { sweep, step } => Cursor::Ball {
                sweep,
                step,
                ball: 0,
                touch: 0,
                leg: Leg::Above,
            },
            Cursor::Ball {
                sweep,
                step,
                ball,
                touch,
                leg,
            } => {
                let at = |touch, leg| Cursor::Ball {
                    sweep,
                    step,
                    ball,
                    touch,
                    leg,
                };
                match leg {
                    Leg::Above => at(touch, Leg::Descend),
                    Leg::Descend => at(touch, Leg::Fast),
                    Leg::BackOff => at(touch, Leg::Slow),
                    Leg::Retract => at(touch, Leg::Up),
                    Leg::Up if touch + 1 < self.plan.touches_per_ball => at(touch + 1, Leg::Above),
                    Leg::Up => match self.ball_done(step, ball) {
                        Ok(()) => self.after_ball(sweep, step, ball),
                        Err(e) => return self.stop_with(e),
                    },
                    Leg::Fast | Leg::Slow => unreachable!("probing legs"),
                    Leg::Lower => unreachable!("beside the rim only"),
                }
            }
            Cursor::Done => unreachable!("no move is asked once done"),
        };
        self.enter(next);
    }

    /// The probing move of [`Action::ProbeTowards`] ended: `hit` is the gauge point
    /// where the probe triggered, `None` if it reached its target without contact.
    pub fn probed(&mut self, hit: Option<[f64; 3]>) {
        if !matches!(self.action, Action::ProbeTowards { .. }) {
            return self.misuse("a probing move ended");
        }
        let l = self.tool_length_mm;
        let next = match self.cursor {
            Cursor::Rim { touch, leg } => {
                let angle_deg = self.plan.rim.angles_deg[touch];
                let not_found = MeasureError::RimNotFound {
                    touch: touch + 1,
                    angle_deg,
                    overtravel_mm: self.plan.overtravel_mm,
                };
                match (leg, hit) {
                    (Leg::Descend, Some(p)) => {
                        return self.stop_with(MeasureError::Rim(format!(
                            "touch {} at {angle_deg}°: contact at ({:.3}, {:.3}, {:.3}) mm on \
                             the way down beside the rim; the table is not where the machine \
                             constants put it",
                            touch + 1,
                            p[0],
                            p[1],
                            p[2]
                        )))
                    }
                    (Leg::Descend, None) => Cursor::Rim {
                        touch,
                        leg: Leg::Fast,
                    },
                    (Leg::Fast | Leg::Slow, None) => return self.stop_with(not_found),
                    (Leg::Fast, Some(p)) => {
                        self.fast = p;
                        Cursor::Rim {
                            touch,
                            leg: Leg::BackOff,
                        }
                    }
                    (Leg::Slow, Some(p)) => {
                        self.rim_points.push([p[0], p[1], p[2] - l]);
                        Cursor::Rim {
                            touch,
                            leg: Leg::Retract,
                        }
                    }
                    _ => unreachable!("positioning legs"),
                }
            }
            Cursor::Ball {
                sweep,
                step,
                ball,
                touch,
                leg,
            } => {
                // A ball's touches count once the machine answered.
                self.result.probe_touches += 1;
                let Some(p) = hit else {
                    return self.stop_with(MeasureError::BallNotFound {
                        axis: SWEEPS[sweep],
                        step: step as u32,
                        ball: ball as u8 + 1,
                        touch: touch + 1,
                        overtravel_mm: self.plan.overtravel_mm,
                    });
                };
                let at = |leg| Cursor::Ball {
                    sweep,
                    step,
                    ball,
                    touch,
                    leg,
                };
                match leg {
                    Leg::Fast => {
                        self.fast = p;
                        at(Leg::BackOff)
                    }
                    Leg::Slow => {
                        self.ball_points.push([p[0], p[1], p[2] - l]);
                        at(Leg::Retract)
                    }
                    _ => unreachable!("positioning legs"),
                }
            }
            Cursor::RimStart | Cursor::Turn { .. } | Cursor::Done => {
                unreachable!("no probing move asked")
            }
        };
        self.enter(next);
    }

    /// The machine could not do what [`next_action`](Self::next_action) asked
    /// (`message`: its words): the cycle stops, keeping what it measured.
    pub fn failed(&mut self, message: impl Into<String>) {
        if self.cursor != Cursor::Done {
            self.stop_with(MeasureError::Machine(message.into()));
        }
    }

    /// Stop before the next move, keeping what was measured (the error is
    /// [`MeasureError::StopRequested`]). Nothing changes once the cycle is finished.
    pub fn stop(&mut self) {
        if self.cursor != Cursor::Done {
            self.stop_with(MeasureError::StopRequested);
        }
    }

    /// Balls measured so far and balls in the whole cycle.
    pub fn progress(&self) -> (usize, usize) {
        (self.result.balls.len(), self.total)
    }

    /// What was measured so far.
    pub fn measurement(&self) -> &Measurement {
        &self.result
    }

    /// Why the cycle stopped, once it did.
    pub fn error(&self) -> Option<&MeasureError> {
        self.error.as_ref()
    }

    /// No more moves: finished or stopped.
    pub fn is_finished(&self) -> bool {
        self.cursor == Cursor::Done
    }

    /// The measurement, or why the cycle stopped with what it measured until then. A
    /// session ended before [`Action::Finished`] is stopped ([`MeasureError::Unfinished`]).
    pub fn finish(self) -> Result<Measurement, Box<Stopped>> {
        let error = match (self.error, self.cursor) {
            (Some(error), _) => error,
            (None, Cursor::Done) => return Ok(self.result),
            (None, _) => MeasureError::Unfinished,
        };
        Err(Box::new(Stopped {
            error,
            so_far: self.result,
        }))
    }

    fn misuse(&mut self, what: &str) {
        if self.cursor != Cursor::Done {
            let asked = match self.action {
                Action::MoveTo(_) => "a positioning move",
                Action::ProbeTowards { .. } => "a probing move",
                Action::Finished => "nothing",
            };
            self.stop_with(MeasureError::Machine(format!(
                "the cycle was told {what} while it had asked for {asked}"
            )));
        }
    }

    fn stop_with(&mut self, error: MeasureError) {
        self.error = Some(error);
        self.enter(Cursor::Done);
    }

    /// Moves to `cursor` and works out what it asks of the machine. A rim touch counts
    /// when it is asked for (a ball's when answered): the figures of a stopped cycle are
    /// the same as they always were.
    fn enter(&mut self, cursor: Cursor) {
        self.cursor = cursor;
        if let Cursor::Ball {
            sweep, step, ball, ..
        } = cursor
        {
            if self.place.as_ref().map(|p| p.key) != Some((sweep, step, ball)) {
                self.place = Some(self.ball_place(sweep, step, ball));
            }
        }
        if let Cursor::Rim {
            leg: Leg::Fast | Leg::Slow,
            ..
        } = cursor
        {
            self.result.probe_touches += 1;
        }
        self.action = self.action_at(cursor);
    }

    fn action_at(&self, cursor: Cursor) -> Action {
        let plan = &self.plan;
        let safe = plan.safe_z_mm;
        let probe = |to: [f64; 3], feed_mm_min: f64| Action::ProbeTowards { to, feed_mm_min };
        match cursor {
            Cursor::RimStart => {
                let axis = self.c_axis();
                Action::MoveTo(Axes::new(axis.x, axis.y, safe, 0.0, 0.0))
            }
            Cursor::Rim { touch, leg } => {
                let t = self.rim_touch(touch);
                let over = t.over;
                let above = Axes::new(over.x, over.y, safe.max(over.z), 0.0, 0.0);
                match leg {
                    Leg::Above | Leg::Up => Action::MoveTo(above),
                    Leg::Lower => {
                        let low = over.z + plan.rim.protected_descent_mm.unwrap_or(f64::INFINITY);
                        Action::MoveTo(Axes::new(over.x, over.y, low.min(above.z), 0.0, 0.0))
                    }
                    Leg::Descend => probe([over.x, over.y, over.z], plan.fast_feed_mm_min),
                    Leg::Fast => probe(t.end, plan.fast_feed_mm_min),
                    Leg::BackOff => {
                        let back = Vector3::from(self.fast) + t.u * plan.backoff_mm;
                        Action::MoveTo(Axes::new(back.x, back.y, back.z, 0.0, 0.0))
                    }
                    Leg::Slow => probe(t.end, plan.slow_feed_mm_min),
                    Leg::Retract => Action::MoveTo(over),
                }
            }
            Cursor::Turn { sweep: k, step } => {
                let (a, c) = self.design.sweep(SWEEPS[k])[step];
                Action::MoveTo(Axes::new(0.0, 0.0, safe, a, c))
            }
            Cursor::Ball { touch, leg, .. } => {
                let t = self.ball_touch(touch);
                let (a, c, s) = (t.a, t.c, t.start);
                let above = Axes::new(s[0], s[1], safe.max(s[2]), a, c);
                // Between two touches of the ball: over it (see `Retract::OverBall`).
                let over = Axes::new(s[0], s[1], t.over_z.max(s[2]), a, c);
                // Between two balls of one position: over both.
                let over_all = Axes::new(s[0], s[1], t.over_all_z.max(s[2]), a, c);
                let last = touch + 1 == plan.touches_per_ball;
                let hop = plan.retract == Retract::OverBall;
                let (first_ball, last_ball) =
                    (t.ball == 0, t.ball + 1 == plan.artifact.balls.len());
                let start = Axes::new(s[0], s[1], s[2], a, c);
                match leg {
                    Leg::Above if hop && touch > 0 => Action::MoveTo(over),
                    Leg::Up if hop && !last => Action::MoveTo(over),
                    Leg::Above if hop && !first_ball => Action::MoveTo(over_all),
                    Leg::Up if hop && !last_ball => Action::MoveTo(over_all),
                    Leg::Above | Leg::Up => Action::MoveTo(above),
                    Leg::Descend | Leg::Retract => Action::MoveTo(start),
                    Leg::Fast => probe(t.end, plan.fast_feed_mm_min),
                    Leg::BackOff => {
                        let back = Vector3::from(self.fast) + t.d * plan.backoff_mm;
                        Action::MoveTo(Axes::new(back.x, back.y, back.z, a, c))
                    }
                    Leg::Slow => probe(t.end, plan.slow_feed_mm_min),
                    Leg::Lower => unreachable!("beside the rim only"),
                }
            }
            Cursor::Done => Action::Finished,
        }
    }

    /// The nominal C axis at the table face, A = C = 0 (machine frame, tool tip).
    fn c_axis(&self) -> Vector3<f64> {
        kinematics::transform_point(&self.nominal.table(0.0, 0.0), &Vector3::zeros())
    }

    /// Rim touch `k`: from outside, horizontally towards the nominal axis (see
    /// [`RimPlan`]).
    fn rim_touch(&self, k: usize) -> RimTouch {
        let (plan, rim, l) = (&self.plan, &self.plan.rim, self.tool_length_mm);
        let axis = self.c_axis();
        let z = axis.z - rim.depth_mm;
        let reach = rim.radius_mm + plan.stylus_radius_mm;
        let angle_deg = rim.angles_deg[k];
        let u = Vector3::new(
            angle_deg.to_radians().cos(),
            angle_deg.to_radians().sin(),
            0.0,
        );
        let start = Vector3::new(axis.x, axis.y, z) + u * (reach + plan.approach_mm);
        let end = Vector3::new(axis.x, axis.y, z) + u * (reach - plan.overtravel_mm);
        RimTouch {
            u,
            over: Axes::new(start.x, start.y, start.z + l, 0.0, 0.0),
            end: [end.x, end.y, end.z + l],
        }
    }

    /// The circle through the rim's three touches: the C centre, checked (the rim's
    /// radius, the centre's distance from the nominal axis).
    fn rim_done(&mut self) -> Result<(), MeasureError> {
        let (plan, rim) = (&self.plan, &self.plan.rim);
        let axis = self.c_axis();
        let points = std::mem::take(&mut self.rim_points);
        let (cx, cy, r) = circle_through(&points)
            .ok_or_else(|| MeasureError::Rim("the three touches lie on one line".into()))?;
        let rim_radius_mm = r - plan.stylus_radius_mm;
        if (rim_radius_mm - rim.radius_mm).abs() > rim.radius_tolerance_mm {
            return Err(MeasureError::Rim(format!(
                "fitted radius {rim_radius_mm:.4} mm, drawn {:.4} mm (tolerance {} mm)",
                rim.radius_mm, rim.radius_tolerance_mm
            )));
        }
        let offset_mm = [cx - axis.x, cy - axis.y];
        if offset_mm[0].hypot(offset_mm[1]) > rim.max_offset_mm {
            return Err(MeasureError::Rim(format!(
                "the C centre is at ({cx:.4}, {cy:.4}) mm, ({:.4}, {:.4}) mm from the nominal \
                 axis: more than {} mm, the machine constants do not describe this machine",
                offset_mm[0], offset_mm[1], rim.max_offset_mm
            )));
        }
        self.offset = Vector3::new(offset_mm[0], offset_mm[1], 0.0);
        self.result.c_centre = Some(CCentre {
            x_mm: cx,
            y_mm: cy,
            offset_mm,
            rim_radius_mm,
            points,
        });
        Ok(())
    }

    /// Where ball `ball` should be at `step` of sweep `sweep`, and the directions of its
    /// touches.
    fn ball_place(&self, sweep_no: usize, step: usize, ball: usize) -> BallPlace {
        let plan = &self.plan;
        let axis = SWEEPS[sweep_no];
        let (a, c) = self.design.sweep(axis)[step];
        let table = self.nominal.table(a, c);
        let b = &plan.artifact.balls[ball];
        // Where the ball should be, with the table where the rim says it is (the offset
        // at A = 0 turned with A).
        let centre = kinematics::transform_point(&table, &Vector3::from(b.centre_mm))
            + self.nominal.table(a, 0.0).fixed_view::<3, 3>(0, 0) * self.offset;
        // Around machine +Z: the probe comes from above; the points at `cone_deg` from
        // the top reach down near the equator, so the centre's height is not left to the
        // radius (a cap of 40° would make it 4 times noisier than the touches). The stem
        // (below the ball on the table normal) is at least 90° - (90° - cone) away at any
        // A up to 90°.
        let over_all_z = plan
            .artifact
            .balls
            .iter()
            .map(|other| {
                let at = kinematics::transform_point(&table, &Vector3::from(other.centre_mm))
                    + self.nominal.table(a, 0.0).fixed_view::<3, 3>(0, 0) * self.offset;
                at.z + other.radius_mm + plan.stylus_radius_mm + plan.approach_mm
            })
            .fold(f64::NEG_INFINITY, f64::max);
        BallPlace {
            over_all_z,
            key: (sweep_no, step, ball),
            axis,
            a,
            c,
            centre,
            reach: b.radius_mm + plan.stylus_radius_mm,
            directions: directions(&Vector3::z(), plan.cone_deg, plan.touches_per_ball),
        }
    }

    /// Touch `touch` on the current ball (see `enter`).
    fn ball_touch(&self, touch: usize) -> BallTouch {
        let (plan, l) = (&self.plan, self.tool_length_mm);
        let place = self
            .place
            .as_ref()
            .expect("the ball's place is worked out on entry");
        let (centre, reach) = (place.centre, place.reach);
        let d = place.directions[touch];
        let start = centre + d * (reach + plan.approach_mm);
        let end = centre + d * (reach - plan.overtravel_mm);
        let gauge = |p: Vector3<f64>| [p.x, p.y, p.z + l];
        BallTouch {
            axis: place.axis,
            a: place.a,
            c: place.c,
            d,
            start: gauge(start),
            end: gauge(end),
            reach,
            over_z: centre.z + reach + plan.approach_mm + l,
            over_all_z: place.over_all_z + l,
            ball: place.key.2,
        }
    }

    /// The sphere through a ball's six touches, checked, added to the result.
    fn ball_done(&mut self, step: usize, ball: usize) -> Result<(), MeasureError> {
        let t = self.ball_touch(0);
        let (axis, step) = (t.axis, step as u32);
        let ball_no = ball as u8 + 1;
        let points = std::mem::take(&mut self.ball_points);
        let what = format!("axis {axis} step {step} ball {ball_no}");
        let pts: Vec<Vector3<f64>> = points.iter().map(|p| Vector3::from(*p)).collect();
        let sphere_error = |source| MeasureError::Sphere {
            axis,
            step,
            ball: ball_no,
            source,
        };
        let sphere = fit_sphere(&what, &pts).map_err(sphere_error)?;
        check_sphere(
            &what,
            &sphere,
            t.reach,
            self.plan.radius_tolerance_mm,
            self.plan.residual_limit_mm,
        )
        .map_err(sphere_error)?;
        self.result.balls.push(BallMeasurement {
            axis,
            step,
            angle_deg: if axis == Axis::C { t.c } else { t.a },
            ball: ball_no,
            points,
            sphere,
        });
        Ok(())
    }

    /// Where the cycle goes after a ball: the next ball, the next step, the next sweep,
    /// or the end.
    fn after_ball(&self, sweep_no: usize, step: usize, ball: usize) -> Cursor {
        if ball + 1 < self.plan.artifact.balls.len() {
            Cursor::Ball {
                sweep: sweep_no,
                step,
                ball: ball + 1,
                touch: 0,
                leg: Leg::Above,
            }
        } else if step + 1 < self.design.sweep(SWEEPS[sweep_no]).len() {
            Cursor::Turn {
                sweep: sweep_no,
                step: step + 1,
            }
        } else if sweep_no + 1 < SWEEPS.len() {
            Cursor::Turn {
                sweep: sweep_no + 1,
                step: 0,
            }
        } else {
            Cursor::Done
        }
    }
}

/// The circle (centre X, Y and radius) through three points' X, Y; None when they are on
/// one line.
fn circle_through(p: &[[f64; 3]]) -> Option<(f64, f64, f64)> {
    let [a, b, c] = [p[0], p[1], p[2]];
    // Relative to `a`, for conditioning.
    let (bx, by) = (b[0] - a[0], b[1] - a[1]);
    let (cx, cy) = (c[0] - a[0], c[1] - a[1]);
    let d = 2.0 * (bx * cy - by * cx);
    if d.abs() < 1e-12 * (bx.hypot(by) * cx.hypot(cy)).max(1e-300) {
        return None;
    }
    let (b2, c2) = (bx * bx + by * by, cx * cx + cy * cy);
    let ux = (cy * b2 - by * c2) / d;
    let uy = (bx * c2 - cx * b2) / d;
    Some((a[0] + ux, a[1] + uy, ux.hypot(uy)))
}

/// The `count` approach directions (unit vectors from the ball's centre outwards,
/// machine frame): the pole `n` and `count - 1` around it at `cone_deg`, evenly apart;
/// with an even number around, turned by half a step so that none points along ±Y
/// (where the stem lies when A turns the table by 90°): 4 around at 45°, 135°, 225°,
/// 315° from +Y; 5 around (the paper's plan) from +Y, 72° apart.
fn directions(n: &Vector3<f64>, cone_deg: f64, count: usize) -> Vec<Vector3<f64>> {
    let helper = if n.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let e1 = n.cross(&helper).normalize();
    let e2 = n.cross(&e1);
    let (s, c) = cone_deg.to_radians().sin_cos();
    let mut out = vec![*n];
    let around = count.saturating_sub(1);
    let step = 360.0 / around.max(1) as f64;
    let turn = if around.is_multiple_of(2) {
        step / 2.0
    } else {
        0.0
    };
    for k in 0..around {
        let t = (turn + step * k as f64).to_radians();
        out.push((n * c + (e1 * t.cos() + e2 * t.sin()) * s).normalize());
    }
    out
}

/// Runs the cycle on a synchronous machine, move by move through a [`MeasureSession`].
/// `progress(done, total)` is called after each ball.
pub fn measure(
    machine: &mut impl ProbingMachine,
    constants: &MachineConstants,
    plan: &MeasurePlan,
    mut progress: impl FnMut(usize, usize),
) -> Result<Measurement, Box<Stopped>> {
    let mut session = MeasureSession::new(constants, plan);
    loop {
        let done = session.progress().0;
        match session.next_action() {
            Action::Finished => break,
            Action::MoveTo(target) => match machine.move_to(&target) {
                Ok(()) => session.moved(),
                Err(e) => session.failed(e),
            },
            Action::ProbeTowards { to, feed_mm_min } => {
                match machine.probe_towards(to, feed_mm_min) {
                    Ok(hit) => session.probed(hit),
                    Err(e) => session.failed(e),
                }
            }
        }
        let (now, total) = session.progress();
        if now != done {
            progress(now, total);
        }
    }
    session.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A perfect machine for the session: the nominal table, the balls exactly where
    /// the artifact puts them (unless shifted or shrunk), the table a solid disk of the
    /// rim's radius about the nominal C axis (at A = 0), a stylus of the plan's radius
    /// without pre-travel.
    #[derive(Clone)]
    struct PerfectTable {
        nominal: RotaryMachine,
        tool_length_mm: f64,
        plan: MeasurePlan,
        position: Axes,
        /// Ball 2 this much further out along the workpiece's X than the artifact says.
        shift_mm: [f64; 2],
        /// Ball 2 this much smaller.
        shrink_mm: f64,
        log: Vec<Action>,
    }

    impl PerfectTable {
        fn new() -> Self {
            let constants = MachineConstants::default();
            Self {
                nominal: RotaryMachine::nominal(constants),
                tool_length_mm: constants.tool_length_mm,
                plan: MeasurePlan::default(),
                position: Axes::new(0.0, 0.0, 0.0, 0.0, 0.0),
                shift_mm: [0.0, 0.0],
                shrink_mm: 0.0,
                log: Vec::new(),
            }
        }

        /// The first t in [0, 1] where `from + t (to - from)` is `radius` from `centre`
        /// (in the first `dims` coordinates), starting outside.
        fn first_contact(
            from: Vector3<f64>,
            to: Vector3<f64>,
            centre: Vector3<f64>,
            radius: f64,
            dims: usize,
        ) -> Option<f64> {
            let (d, f) = (to - from, from - centre);
            let (d, f) = (d.rows(0, dims), f.rows(0, dims));
            let (a, b, c) = (d.dot(&d), 2.0 * f.dot(&d), f.dot(&f) - radius * radius);
            let disc = b * b - 4.0 * a * c;
            if c <= 0.0 || a == 0.0 || disc < 0.0 {
                return None;
            }
            let t = (-b - disc.sqrt()) / (2.0 * a);
            (0.0..=1.0).contains(&t).then_some(t)
        }

        /// Where the stylus centre moving `from` -> `to` meets the table (a disk of
        /// `radius` about `axis`, its face at `axis.z`, the stylus's radius added).
        fn table_contact(
            &self,
            from: Vector3<f64>,
            to: Vector3<f64>,
            axis: Vector3<f64>,
        ) -> Option<f64> {
            let r = self.plan.stylus_radius_mm;
            let (radius, top) = (self.plan.rim.radius_mm + r, axis.z + r);
            let inside = |p: Vector3<f64>| (p - axis).xy().norm() <= radius;
            let through_top = (from.z > top && to.z <= top)
                .then(|| (top - from.z) / (to.z - from.z))
                .filter(|&t| inside(from + (to - from) * t));
            let side = Self::first_contact(from, to, axis, radius, 2)
                .filter(|&t| (from + (to - from) * t).z <= top);
            match (through_top, side) {
                (Some(a), Some(b)) => Some(a.min(b)),
                (a, b) => a.or(b),
            }
        }
    }

    impl ProbingMachine for PerfectTable {
        fn move_to(&mut self, target: &Axes) -> Result<(), String> {
            self.log.push(Action::MoveTo(*target));
            self.position = *target;
            Ok(())
        }

        fn probe_towards(
            &mut self,
            to: [f64; 3],
            feed_mm_min: f64,
        ) -> Result<Option<[f64; 3]>, String> {
            self.log.push(Action::ProbeTowards { to, feed_mm_min });
            let (a, c, l) = (self.position.a, self.position.c, self.tool_length_mm);
            let tip = |p: [f64; 3]| Vector3::new(p[0], p[1], p[2] - l);
            let from = tip([self.position.x, self.position.y, self.position.z]);
            let end = tip(to);
            let r = self.plan.stylus_radius_mm;
            let table = self.nominal.table(a, c);
            let mut hits: Vec<f64> = self
                .plan
                .artifact
                .balls
                .iter()
                .enumerate()
                .filter_map(|(k, b)| {
                    let mut at = Vector3::from(b.centre_mm);
                    at.x += self.shift_mm[k].copysign(at.x);
                    let radius = b.radius_mm - if k == 1 { self.shrink_mm } else { 0.0 };
                    let centre = kinematics::transform_point(&table, &at);
                    Self::first_contact(from, end, centre, radius + r, 3)
                })
                .collect();
            if a == 0.0 {
                let axis = kinematics::transform_point(&table, &Vector3::zeros());
                hits.extend(self.table_contact(from, end, axis));
            }
            let stop = hits
                .into_iter()
                .fold(None, |m: Option<f64>, t| Some(m.map_or(t, |m| m.min(t))))
                .map(|t| from + (end - from) * t);
            let at = stop.unwrap_or(end);
            self.position.x = at.x;
            self.position.y = at.y;
            self.position.z = at.z + l;
            Ok(stop.map(|p| [p.x, p.y, p.z + l]))
        }
    }

    fn session() -> MeasureSession {
        MeasureSession::new(&MachineConstants::default(), &MeasurePlan::default())
    }

    /// Answers the session's next action on `machine`; false once finished.
    fn step(s: &mut MeasureSession, machine: &mut impl ProbingMachine) -> bool {
        match s.next_action() {
            Action::Finished => return false,
            Action::MoveTo(t) => match machine.move_to(&t) {
                Ok(()) => s.moved(),
                Err(e) => s.failed(e),
            },
            Action::ProbeTowards { to, feed_mm_min } => {
                match machine.probe_towards(to, feed_mm_min) {
                    Ok(hit) => s.probed(hit),
                    Err(e) => s.failed(e),
                }
            }
        }
        true
    }

    /// The default plan: the optimal positions, 5 touches per ball, over the ball
    /// between them; every move of a touch is clear of the ball grown by the stylus
    /// (the perfect table would report a contact on a positioning move's way as a
    /// crash: checked below on every move's straight line).
    #[test]
    fn the_default_cycle_measures_the_optimal_positions_over_the_balls() {
        let mut table = PerfectTable::new();
        let plan = MeasurePlan::default();
        let constants = MachineConstants::default();
        let design = plan.positions(&constants).unwrap();
        let m = measure(&mut table, &constants, &plan, |_, _| {})
            .unwrap_or_else(|s| panic!("{}", s.error));
        let positions = design.c_steps_deg.len() + design.a_steps_deg.len();
        assert_eq!(positions, 10);
        assert_eq!(m.balls.len(), 2 * positions);
        assert_eq!(m.probe_touches, (3 + m.balls.len() * 5) * 2);
        let angles: Vec<f64> = m.balls.iter().map(|b| b.angle_deg).collect();
        let want: Vec<f64> = design
            .c_steps_deg
            .iter()
            .chain(&design.a_steps_deg)
            .flat_map(|&a| [a, a])
            .collect();
        assert_eq!(angles, want);
        // Positioning moves: between two touches of a ball only over it (never up to
        // the safe height), and no positioning move passes through a ball.
        let nominal = RotaryMachine::nominal(constants);
        let mut from: Option<Axes> = None;
        let mut safe_moves = 0;
        for action in &table.log {
            if let Action::MoveTo(to) = action {
                if to.z == plan.safe_z_mm {
                    safe_moves += 1;
                }
                if let Some(f) = from.filter(|f| f.a == to.a && f.c == to.c) {
                    let table_at = nominal.table(to.a, to.c);
                    for ball in &plan.artifact.balls {
                        let centre =
                            kinematics::transform_point(&table_at, &Vector3::from(ball.centre_mm));
                        let l = constants.tool_length_mm;
                        let (p, q) = (
                            Vector3::new(f.x, f.y, f.z - l),
                            Vector3::new(to.x, to.y, to.z - l),
                        );
                        let reach = ball.radius_mm + plan.stylus_radius_mm;
                        assert!(
                            PerfectTable::first_contact(p, q, centre, reach, 3).is_none(),
                            "a move from {f:?} to {to:?} passes through a ball"
                        );
                    }
                }
                from = Some(*to);
            } else if let Action::ProbeTowards { to, .. } = action {
                if let Some(f) = from.as_mut() {
                    (f.x, f.y, f.z) = (to[0], to[1], to[2]);
                }
            }
        }
        // Over the C axis, per rim touch over it and back up, per position the turn,
        // over the first ball's first start and up from the last ball's last touch.
        assert_eq!(safe_moves, 1 + 3 * 2 + positions * 3);
    }

    #[test]
    fn the_whole_cycle_on_a_perfect_table_finds_every_ball_where_it_is() {
        let mut table = PerfectTable::new();
        let mut calls = Vec::new();
        let m = measure(
            &mut table,
            &MachineConstants::default(),
            &MeasurePlan::paper(),
            |done, total| calls.push((done, total)),
        )
        .unwrap_or_else(|s| panic!("{}", s.error));
        let balls = 2 * (12 + 7);
        assert_eq!(m.balls.len(), balls);
        assert_eq!(calls, (1..=balls).map(|k| (k, balls)).collect::<Vec<_>>());
        // 3 rim points and 6 per ball, each touched fast then slow; the 3 protected
        // descents beside the rim are not touches.
        assert_eq!(m.probe_touches, (3 + balls * 6) * 2);
        let probes = table
            .log
            .iter()
            .filter(|a| matches!(a, Action::ProbeTowards { .. }))
            .count();
        assert_eq!(probes, m.probe_touches + 3);
        // Moves: 1 over the axis, 4 per rim touch; per step 1 turn and 5 per ball touch.
        assert_eq!(
            table.log.len() - probes,
            1 + 3 * 4 + (12 + 7) + balls * 6 * 5
        );
        let c = m.c_centre.as_ref().expect("located");
        assert!(c.offset_mm[0].abs() < 1e-9 && c.offset_mm[1].abs() < 1e-9);
        let nominal = crate::centres_of(
            &RotaryMachine::nominal(MachineConstants::default()),
            &Artifact::default(),
        );
        for (got, want) in m.centres().iter().zip(&nominal) {
            assert_eq!(
                (got.axis, got.step, got.ball),
                (want.axis, want.step, want.ball)
            );
            let d = (got.x_mm - want.x_mm)
                .hypot(got.y_mm - want.y_mm)
                .hypot(got.z_mm - want.z_mm);
            assert!(d < 1e-9, "{got:?} vs {want:?}");
        }
    }

    #[test]
    fn the_first_move_is_over_the_c_axis_and_stays_until_answered() {
        let mut s = session();
        let constants = MachineConstants::default();
        let axis = kinematics::transform_point(
            &RotaryMachine::nominal(constants).table(0.0, 0.0),
            &Vector3::zeros(),
        );
        let first = Action::MoveTo(Axes::new(axis.x, axis.y, -20.0, 0.0, 0.0));
        assert_eq!(s.next_action(), first);
        assert_eq!(s.next_action(), first);
        // 2 balls at the optimal 5 + 5 positions.
        assert_eq!(s.progress(), (0, 20));
        s.moved();
        // Over the first rim touch, rapidly down to 15 mm above the face, then the
        // protected descent beside the rim.
        assert!(matches!(s.next_action(), Action::MoveTo(_)));
        s.moved();
        let face = axis.z + MachineConstants::default().tool_length_mm;
        assert!(matches!(
            s.next_action(),
            Action::MoveTo(to) if (to.z - (face + 15.0)).abs() < 1e-9
        ));
        s.moved();
        assert!(matches!(
            s.next_action(),
            Action::ProbeTowards { feed_mm_min, .. } if feed_mm_min == 300.0
        ));
        assert!(!s.is_finished() && s.error().is_none());
    }

    #[test]
    fn a_plan_that_cannot_be_run_stops_before_any_move() {
        for (plan, says) in [
            (
                MeasurePlan {
                    touches_per_ball: 4,
                    ..MeasurePlan::default()
                },
                "plan.touches_per_ball: 4, at least 5",
            ),
            (
                MeasurePlan {
                    design: PlanDesign::Optimal {
                        c_positions: 3,
                        a_positions: 4,
                    },
                    ..MeasurePlan::default()
                },
                "plan.design: an optimal design needs 4 to 12 C positions",
            ),
        ] {
            let s = MeasureSession::new(&MachineConstants::default(), &plan);
            assert_eq!(s.next_action(), Action::Finished);
            let e = s.finish().expect_err("refused").error.to_string();
            assert!(e.starts_with("the plan: ") && e.contains(says), "{e}");
        }
    }

    #[test]
    fn a_stop_after_n_balls_keeps_n_balls() {
        for n in [0, 1, 5, 14] {
            let mut table = PerfectTable::new();
            let mut s = session();
            while s.progress().0 < n && step(&mut s, &mut table) {}
            let moves = table.log.len();
            s.stop();
            assert_eq!(s.next_action(), Action::Finished);
            assert!(!step(&mut s, &mut table));
            assert_eq!(table.log.len(), moves, "nothing moves after a stop");
            // A second stop, a late answer: nothing changes.
            s.stop();
            s.moved();
            let stopped = s.finish().expect_err("stopped");
            assert_eq!(stopped.error, MeasureError::StopRequested);
            assert_eq!(stopped.error.to_string(), STOPPED_ON_REQUEST);
            assert_eq!(stopped.so_far.balls.len(), n);
            assert_eq!(stopped.so_far.c_centre.is_some(), n > 0);
        }
    }

    #[test]
    fn a_failed_move_stops_the_cycle_with_the_machines_words() {
        let mut table = PerfectTable::new();
        let mut s = session();
        while s.progress().0 < 3 && step(&mut s, &mut table) {}
        s.failed("link lost");
        assert_eq!(s.next_action(), Action::Finished);
        let stopped = s.finish().expect_err("stopped");
        assert_eq!(stopped.error.to_string(), "the machine: link lost");
        assert_eq!(stopped.so_far.balls.len(), 3);
    }

    #[test]
    fn a_probe_that_never_touches_stops_at_the_first_rim_touch() {
        let mut s = session();
        // Over the axis, over the first touch, rapidly down to 15 mm above the face,
        // probing down beside the rim (no contact: good), then the fast touch finds
        // nothing.
        s.moved();
        s.moved();
        s.moved();
        s.probed(None);
        s.probed(None);
        let stopped = s.finish().expect_err("stopped");
        assert!(
            matches!(stopped.error, MeasureError::RimNotFound { touch: 1, .. }),
            "{}",
            stopped.error
        );
        // The rim touch counts as asked, as it always did.
        assert_eq!(stopped.so_far.probe_touches, 1);
        assert!(stopped.so_far.c_centre.is_none());
    }

    #[test]
    fn an_answer_to_a_question_not_asked_stops_the_cycle() {
        let mut s = session();
        s.probed(Some([0.0; 3]));
        assert_eq!(s.next_action(), Action::Finished);
        let e = s.finish().expect_err("stopped").error.to_string();
        assert!(
            e.contains("told a probing move ended while it had asked for a positioning move"),
            "{e}"
        );
    }

    #[test]
    fn a_session_finished_early_is_unfinished() {
        let mut s = session();
        s.moved();
        let stopped = s.finish().expect_err("not finished");
        assert_eq!(stopped.error, MeasureError::Unfinished);
    }

    /// The cycle as it was written before the session (a loop calling the machine),
    /// frozen: the session must drive any machine move for move as it did.
    mod frozen {
        use super::super::*;
        use crate::sweep;

        fn reference_locate_c_centre(
            machine: &mut impl ProbingMachine,
            nominal: &RotaryMachine,
            tool_length_mm: f64,
            plan: &MeasurePlan,
            touches: &mut usize,
        ) -> Result<CCentre, MeasureError> {
            let rim = &plan.rim;
            let axis = kinematics::transform_point(&nominal.table(0.0, 0.0), &Vector3::zeros());
            let z = axis.z - rim.depth_mm;
            let reach = rim.radius_mm + plan.stylus_radius_mm;
            let machine_error = MeasureError::Machine;
            let at = |p: Vector3<f64>| Axes::new(p.x, p.y, p.z + tool_length_mm, 0.0, 0.0);
            machine
                .move_to(&Axes::new(axis.x, axis.y, plan.safe_z_mm, 0.0, 0.0))
                .map_err(machine_error)?;
            let mut points = Vec::new();
            for (k, &angle_deg) in rim.angles_deg.iter().enumerate() {
                let u = Vector3::new(
                    angle_deg.to_radians().cos(),
                    angle_deg.to_radians().sin(),
                    0.0,
                );
                let start = Vector3::new(axis.x, axis.y, z) + u * (reach + plan.approach_mm);
                let end = Vector3::new(axis.x, axis.y, z) + u * (reach - plan.overtravel_mm);
                let over = at(start);
                machine
                    .move_to(&Axes::new(
                        over.x,
                        over.y,
                        plan.safe_z_mm.max(over.z),
                        0.0,
                        0.0,
                    ))
                    .map_err(machine_error)?;
                // Down beside the rim as a probing move: if the table is not where the constants
                // put it the stylus meets it here, and the machine stops instead of crashing.
                if let Some(p) = machine
                    .probe_towards([over.x, over.y, over.z], plan.fast_feed_mm_min)
                    .map_err(machine_error)?
                {
                    return Err(MeasureError::Rim(format!(
                        "touch {} at {angle_deg}°: contact at ({:.3}, {:.3}, {:.3}) mm on the way down \
                         beside the rim; the table is not where the machine constants put it",
                        k + 1,
                        p[0],
                        p[1],
                        p[2]
                    )));
                }
                let not_found = MeasureError::RimNotFound {
                    touch: k + 1,
                    angle_deg,
                    overtravel_mm: plan.overtravel_mm,
                };
                let gauge = |p: Vector3<f64>| [p.x, p.y, p.z + tool_length_mm];
                *touches += 1;
                let fast = machine
                    .probe_towards(gauge(end), plan.fast_feed_mm_min)
                    .map_err(machine_error)?
                    .ok_or_else(|| not_found.clone())?;
                let back = Vector3::from(fast) + u * plan.backoff_mm;
                machine
                    .move_to(&Axes::new(back.x, back.y, back.z, 0.0, 0.0))
                    .map_err(machine_error)?;
                *touches += 1;
                let slow = machine
                    .probe_towards(gauge(end), plan.slow_feed_mm_min)
                    .map_err(machine_error)?
                    .ok_or(not_found)?;
                points.push([slow[0], slow[1], slow[2] - tool_length_mm]);
                machine.move_to(&over).map_err(machine_error)?;
                machine
                    .move_to(&Axes::new(
                        over.x,
                        over.y,
                        plan.safe_z_mm.max(over.z),
                        0.0,
                        0.0,
                    ))
                    .map_err(machine_error)?;
            }
            let (cx, cy, r) = circle_through(&points)
                .ok_or_else(|| MeasureError::Rim("the three touches lie on one line".into()))?;
            let rim_radius_mm = r - plan.stylus_radius_mm;
            if (rim_radius_mm - rim.radius_mm).abs() > rim.radius_tolerance_mm {
                return Err(MeasureError::Rim(format!(
                    "fitted radius {rim_radius_mm:.4} mm, drawn {:.4} mm (tolerance {} mm)",
                    rim.radius_mm, rim.radius_tolerance_mm
                )));
            }
            let offset_mm = [cx - axis.x, cy - axis.y];
            if offset_mm[0].hypot(offset_mm[1]) > rim.max_offset_mm {
                return Err(MeasureError::Rim(format!(
                    "the C centre is at ({cx:.4}, {cy:.4}) mm, ({:.4}, {:.4}) mm from the nominal axis: \
                     more than {} mm, the machine constants do not describe this machine",
                    offset_mm[0], offset_mm[1], rim.max_offset_mm
                )));
            }
            Ok(CCentre {
                x_mm: cx,
                y_mm: cy,
                offset_mm,
                rim_radius_mm,
                points,
            })
        }

        pub(super) fn reference_measure(
            machine: &mut impl ProbingMachine,
            constants: &MachineConstants,
            plan: &MeasurePlan,
            mut progress: impl FnMut(usize, usize),
        ) -> Result<Measurement, Box<Stopped>> {
            let nominal = RotaryMachine::nominal(*constants);
            let l = constants.tool_length_mm;
            let mut result = Measurement {
                c_centre: None,
                balls: Vec::new(),
                probe_touches: 0,
            };
            let total = 2 * (sweep(Axis::C).len() + sweep(Axis::A).len());
            let stop = |error: MeasureError, so_far: &Measurement| {
                Box::new(Stopped {
                    error,
                    so_far: so_far.clone(),
                })
            };
            let located =
                reference_locate_c_centre(machine, &nominal, l, plan, &mut result.probe_touches)
                    .map_err(|e| stop(e, &result))?;
            let offset = Vector3::new(located.offset_mm[0], located.offset_mm[1], 0.0);
            result.c_centre = Some(located);
            for axis in [Axis::C, Axis::A] {
                for (step, (a, c)) in sweep(axis).into_iter().enumerate() {
                    let step = step as u32;
                    let table = nominal.table(a, c);
                    // Turn the table with the probe up at the safe height.
                    let here = Axes::new(0.0, 0.0, plan.safe_z_mm, a, c);
                    machine
                        .move_to(&here)
                        .map_err(|e| stop(MeasureError::Machine(e), &result))?;
                    for (b, ball) in plan.artifact.balls.iter().enumerate() {
                        let ball_no = b as u8 + 1;
                        // Where the ball should be, with the table where the rim says it is (the
                        // offset at A = 0 turned with A).
                        let centre =
                            kinematics::transform_point(&table, &Vector3::from(ball.centre_mm))
                                + nominal.table(a, 0.0).fixed_view::<3, 3>(0, 0) * offset;
                        // Around machine +Z: the probe comes from above; the points at
                        // `cone_deg` from the top reach down near the equator, so the centre's
                        // height is not left to the radius (a cap of 40° would make it 4 times
                        // noisier than the touches). The stem (below the ball on the table
                        // normal) is at least 90° - (90° - cone) away at any A up to 90°.
                        let pole = Vector3::z();
                        let reach = ball.radius_mm + plan.stylus_radius_mm;
                        let mut points = Vec::new();
                        for (touch, d) in
                            directions(&pole, plan.cone_deg, 6).into_iter().enumerate()
                        {
                            let start = centre + d * (reach + plan.approach_mm);
                            let end = centre + d * (reach - plan.overtravel_mm);
                            let gauge = |p: Vector3<f64>| [p.x, p.y, p.z + l];
                            let s = gauge(start);
                            // Over the start point at the safe height, then down to it.
                            for target in [
                                Axes::new(s[0], s[1], plan.safe_z_mm.max(s[2]), a, c),
                                Axes::new(s[0], s[1], s[2], a, c),
                            ] {
                                machine
                                    .move_to(&target)
                                    .map_err(|e| stop(MeasureError::Machine(e), &result))?;
                            }
                            let not_found = MeasureError::BallNotFound {
                                axis,
                                step,
                                ball: ball_no,
                                touch: touch + 1,
                                overtravel_mm: plan.overtravel_mm,
                            };
                            let fast = machine
                                .probe_towards(gauge(end), plan.fast_feed_mm_min)
                                .map_err(|e| stop(MeasureError::Machine(e), &result))?;
                            result.probe_touches += 1;
                            let Some(fast) = fast else {
                                return Err(stop(not_found, &result));
                            };
                            let back = Vector3::from(fast) + d * plan.backoff_mm;
                            machine
                                .move_to(&Axes::new(back.x, back.y, back.z, a, c))
                                .map_err(|e| stop(MeasureError::Machine(e), &result))?;
                            let slow = machine
                                .probe_towards(gauge(end), plan.slow_feed_mm_min)
                                .map_err(|e| stop(MeasureError::Machine(e), &result))?;
                            result.probe_touches += 1;
                            let Some(slow) = slow else {
                                return Err(stop(not_found, &result));
                            };
                            points.push([slow[0], slow[1], slow[2] - l]);
                            // Back out along the normal, then up.
                            machine
                                .move_to(&Axes::new(s[0], s[1], s[2], a, c))
                                .map_err(|e| stop(MeasureError::Machine(e), &result))?;
                            machine
                                .move_to(&Axes::new(s[0], s[1], plan.safe_z_mm.max(s[2]), a, c))
                                .map_err(|e| stop(MeasureError::Machine(e), &result))?;
                        }
                        let what = format!("axis {axis} step {step} ball {ball_no}");
                        let pts: Vec<Vector3<f64>> =
                            points.iter().map(|p| Vector3::from(*p)).collect();
                        let sphere_error = |source| MeasureError::Sphere {
                            axis,
                            step,
                            ball: ball_no,
                            source,
                        };
                        let sphere =
                            fit_sphere(&what, &pts).map_err(|e| stop(sphere_error(e), &result))?;
                        check_sphere(
                            &what,
                            &sphere,
                            reach,
                            plan.radius_tolerance_mm,
                            plan.residual_limit_mm,
                        )
                        .map_err(|e| stop(sphere_error(e), &result))?;
                        result.balls.push(BallMeasurement {
                            axis,
                            step,
                            angle_deg: if axis == Axis::C { c } else { a },
                            ball: ball_no,
                            points,
                            sphere,
                        });
                        progress(result.balls.len(), total);
                    }
                }
            }
            Ok(result)
        }
    }

    /// One machine call as the machine saw it (numbers as bits), and its answer.
    #[derive(Debug, PartialEq)]
    enum Call {
        Move([u64; 5]),
        Probe([u64; 3], u64, Result<Option<[u64; 3]>, String>),
    }

    /// Logs every call to `inner`; call number `fail_at` (1-based) fails instead.
    struct Recorder<M> {
        inner: M,
        log: Vec<Call>,
        fail_at: Option<usize>,
    }

    impl<M: ProbingMachine> ProbingMachine for Recorder<M> {
        fn move_to(&mut self, t: &Axes) -> Result<(), String> {
            self.log
                .push(Call::Move([t.x, t.y, t.z, t.a, t.c].map(f64::to_bits)));
            if Some(self.log.len()) == self.fail_at {
                return Err("link lost".into());
            }
            self.inner.move_to(t)
        }

        fn probe_towards(
            &mut self,
            to: [f64; 3],
            feed_mm_min: f64,
        ) -> Result<Option<[f64; 3]>, String> {
            let r = if Some(self.log.len() + 1) == self.fail_at {
                Err("link lost".to_string())
            } else {
                self.inner.probe_towards(to, feed_mm_min)
            };
            self.log.push(Call::Probe(
                to.map(f64::to_bits),
                feed_mm_min.to_bits(),
                r.clone().map(|h| h.map(|p| p.map(f64::to_bits))),
            ));
            r
        }
    }

    /// The session-driven cycle and the frozen one on two copies of `table`: the same
    /// calls, answers, progress and result.
    fn same_as_frozen(
        table: PerfectTable,
        constants: &MachineConstants,
        fail_at: Option<usize>,
    ) -> Result<Measurement, Box<Stopped>> {
        let plan = MeasurePlan::paper();
        let mut ours = Recorder {
            inner: table.clone(),
            log: Vec::new(),
            fail_at,
        };
        let mut theirs = Recorder {
            inner: table,
            log: Vec::new(),
            fail_at,
        };
        let (mut p1, mut p2) = (Vec::new(), Vec::new());
        let r1 = measure(&mut ours, constants, &plan, |d, n| p1.push((d, n)));
        let r2 = frozen::reference_measure(&mut theirs, constants, &plan, |d, n| p2.push((d, n)));
        assert_eq!(ours.log.len(), theirs.log.len(), "fail at {fail_at:?}");
        assert!(
            ours.log == theirs.log,
            "fail at {fail_at:?}: the calls differ"
        );
        assert_eq!(p1, p2);
        assert_eq!(r1, r2, "fail at {fail_at:?}");
        r1
    }

    #[test]
    fn the_session_drives_the_machine_move_for_move_as_the_frozen_cycle() {
        let constants = MachineConstants::default();
        let m = same_as_frozen(PerfectTable::new(), &constants, None).expect("measured");
        assert_eq!(m.balls.len(), 38);
        // A failure at every call of the rim and of the first ball, and later ones.
        for n in (1..=70).chain([200, 203, 204, 205, 206, 900, 1637]) {
            let stopped = same_as_frozen(PerfectTable::new(), &constants, Some(n))
                .expect_err("the machine failed");
            assert_eq!(stopped.error.to_string(), "the machine: link lost");
        }
    }

    #[test]
    fn the_session_stops_where_the_frozen_cycle_did() {
        let stop = |table, dy: f64| {
            let constants = MachineConstants {
                a_axis_y_mm: MachineConstants::default().a_axis_y_mm + dy,
                ..MachineConstants::default()
            };
            let stopped = same_as_frozen(table, &constants, None).expect_err("stopped");
            (stopped.error, stopped.so_far)
        };
        // Ball 2 6 mm further out than planned: one of its touches finds nothing.
        let mut moved = PerfectTable::new();
        moved.shift_mm = [0.0, 6.0];
        let (e, m) = stop(moved, 0.0);
        assert!(
            matches!(
                e,
                MeasureError::BallNotFound {
                    ball: 2,
                    step: 0,
                    ..
                }
            ),
            "{e}"
        );
        assert_eq!(m.balls.len(), 1);
        // Ball 2 10 um smaller: its sphere is rejected.
        let mut small = PerfectTable::new();
        small.shrink_mm = 0.01;
        let (e, _) = stop(small, 0.0);
        assert!(matches!(e, MeasureError::Sphere { ball: 2, .. }), "{e}");
        // Constants off the table: stopped at the rim (1.5 mm: the centre too far from
        // the nominal axis; -5 mm: contact on the way down; +5 mm: no rim within reach).
        let (e, _) = stop(PerfectTable::new(), 1.5);
        assert!(e.to_string().contains("from the nominal axis"), "{e}");
        let (e, m) = stop(PerfectTable::new(), -5.0);
        assert!(e.to_string().contains("on the way down"), "{e}");
        assert_eq!(m.probe_touches, 0);
        let (e, _) = stop(PerfectTable::new(), 5.0);
        assert!(
            matches!(e, MeasureError::RimNotFound { touch: 1, .. }),
            "{e}"
        );
    }
}

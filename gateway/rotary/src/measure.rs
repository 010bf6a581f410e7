//! The measurement cycle on the machine with a touch probe (the paper's plan, executed
//! through whatever drives the machine): C in 12 steps of 30° at A = 0, A in 6 steps of
//! 15° at C = 0; at each step 6 points on each ball, each approached along the sphere's
//! normal, touched fast, backed off and touched again slowly; a sphere fitted per ball
//! and step (radius free, checked against the certified radius plus the stylus); the
//! centres then go to [`crate::identify`].

use crate::centres::{Axis, CentreRow};
use crate::identify::{check_sphere, fit_sphere, FitError, SphereFit};
use crate::machine::{Axes, RotaryMachine};
use crate::{sweep, Artifact, MachineConstants};
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
}

impl Default for MeasurePlan {
    fn default() -> Self {
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
}

/// A stopped cycle: why, and what was measured until then (to be saved).
#[derive(Debug, Clone, PartialEq)]
pub struct Stopped {
    pub error: MeasureError,
    pub so_far: Measurement,
}

/// The six approach directions (unit vectors from the ball's centre outwards, machine
/// frame): the pole `n` and five around it at `cone_deg`, 72° apart.
fn directions(n: &Vector3<f64>, cone_deg: f64) -> Vec<Vector3<f64>> {
    let helper = if n.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let e1 = n.cross(&helper).normalize();
    let e2 = n.cross(&e1);
    let (s, c) = cone_deg.to_radians().sin_cos();
    let mut out = vec![*n];
    for k in 0..5 {
        let t = (72.0 * k as f64).to_radians();
        out.push((n * c + (e1 * t.cos() + e2 * t.sin()) * s).normalize());
    }
    out
}

/// Runs the cycle. `progress(done, total)` is called after each ball.
pub fn measure(
    machine: &mut impl ProbingMachine,
    constants: &MachineConstants,
    plan: &MeasurePlan,
    mut progress: impl FnMut(usize, usize),
) -> Result<Measurement, Box<Stopped>> {
    let nominal = RotaryMachine::nominal(*constants);
    let l = constants.tool_length_mm;
    let mut result = Measurement {
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
                let centre = kinematics::transform_point(&table, &Vector3::from(ball.centre_mm));
                // Around machine +Z: the probe comes from above; the points at
                // `cone_deg` from the top reach down near the equator, so the centre's
                // height is not left to the radius (a cap of 40° would make it 4 times
                // noisier than the touches). The stem (below the ball on the table
                // normal) is at least 90° - (90° - cone) away at any A up to 90°.
                let pole = Vector3::z();
                let reach = ball.radius_mm + plan.stylus_radius_mm;
                let mut points = Vec::new();
                for (touch, d) in directions(&pole, plan.cone_deg).into_iter().enumerate() {
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
                let pts: Vec<Vector3<f64>> = points.iter().map(|p| Vector3::from(*p)).collect();
                let sphere_error = |source| MeasureError::Sphere {
                    axis,
                    step,
                    ball: ball_no,
                    source,
                };
                let sphere = fit_sphere(&what, &pts).map_err(|e| stop(sphere_error(e), &result))?;
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

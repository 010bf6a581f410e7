//! The measurement cycle on the machine with a touch probe (the paper's plan, executed
//! through whatever drives the machine): the C rotation centre first, from a circle
//! through 3 points touched on the table's rim at A = C = 0 (the balls are then looked
//! for around it); C in 12 steps of 30° at A = 0, A in 6 steps of
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
    /// Locating the C centre on the table's rim first (absent in a plan file: the
    /// defaults).
    #[serde(default)]
    pub rim: RimPlan,
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
}

impl Default for RimPlan {
    fn default() -> Self {
        Self {
            radius_mm: 62.5,
            depth_mm: 10.0,
            angles_deg: [90.0, 210.0, 330.0],
            radius_tolerance_mm: 0.05,
            max_offset_mm: 1.0,
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
            rim: RimPlan::default(),
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
}

/// A stopped cycle: why, and what was measured until then (to be saved).
#[derive(Debug, Clone, PartialEq)]
pub struct Stopped {
    pub error: MeasureError,
    pub so_far: Measurement,
}

/// The C rotation centre from three touches on the table's rim (see [`RimPlan`]): each
/// touch from outside, horizontally towards the nominal axis, fast then slow after a
/// back-off; the circle through the three stylus centres.
fn locate_c_centre(
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
    let located = locate_c_centre(machine, &nominal, l, plan, &mut result.probe_touches)
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
                let centre = kinematics::transform_point(&table, &Vector3::from(ball.centre_mm))
                    + nominal.table(a, 0.0).fixed_view::<3, 3>(0, 0) * offset;
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

//! The A/C tilting rotary table of source B (SPEC B): an XYZ mill carrying, on its
//! table, an A axis (about X) that carries a C axis (about Z); the chain with the eight
//! location errors; the command that puts the tool back on the programmed tip point and
//! direction; the identification of the errors from measured ball centres.
//!
//! # Frames and signs
//! - Machine (reference) frame `r`: the machine's X, Y, Z, right-handed, Z up; X, Y, Z
//!   are the positions of the spindle gauge point (mm). The linear axes are modelled on
//!   the tool side (ISO 841: the tool's motion relative to the work).
//! - Tool frame `t`: at the tool tip, `tool_length_mm` below the gauge point; its Z axis
//!   points from the tip up the tool.
//! - Workpiece frame `w`: fixed to the C table, origin where the nominal C axis meets the
//!   table face, parallel to the machine frame at A = C = 0.
//! - A and C in degrees, right-handed about +X and +Z of the frame that carries them
//!   (the table turns, so positive A tips the tool direction, seen in the workpiece,
//!   towards +Y: the nominal direction is `(sin A sin C, sin A cos C, cos A)`, the
//!   paper's). LinuxCNC's xyzac-trt uses the same table rotation (its forward map is
//!   `Rz(-C) Rx(-A)` on the joint position; checked in the tests).
//! - Chain: `rT_w = T(0, a_axis_y, a_axis_z) · E_A Rx(A) E_A⁻¹ · T(0, ac_offset_y,
//!   ac_offset_z) · E_C Rz(C) E_C⁻¹` and `rT_t = T(X, Y, Z - tool_length)`; the tool in
//!   the workpiece is `wT_t = (rT_w)⁻¹ rT_t`. `E_A`, `E_C` are the small-angle error
//!   HTMs of [`LocationErrors`] (kinematics::small_angle_error).
//!
//! # Worked example (default constants, the paper's errors)
//! Nominal command X 0, Y 0, Z -190, A 30°, C 45°: the tool tip is at machine Z -290,
//! 60 mm above the A axis; turned back by A then C it is, in the workpiece,
//! Rz(-45°)·(0, 60 sin 30°, 60 cos 30° - 60) = (21.2132, 21.2132, -8.0385) mm, with
//! direction (0.35355, 0.35355, 0.86603). The machine with the paper's errors puts the
//! tip 0.2027 mm away (mostly `delta_ZA` = -0.3924 mm turned by A) and the direction
//! 0.000185 rad off; [`RotaryMachine::command_for`] gives X -0.00171, Y -0.20068,
//! Z -190.03825, A 30.00187°, C 44.97918°, which puts both back (the test
//! `worked_example_of_the_crate_docs`).

pub mod centres;
pub mod chart;
pub mod design;
pub mod identify;
pub mod machine;
pub mod measure;
pub mod rewrite;

pub use centres::{parse_centres, write_centres, Axis, CentreRow, CentresError};
pub use identify::{
    check_sphere, fit_circle, fit_sphere, identify, CircleFit, FitError, Identification,
    IdentifyError, SphereFit,
};
pub use machine::{
    Axes, AxisLimits, LocationErrors, MachineConstants, RotaryError, RotaryMachine, ToolPose,
};

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// One precision ball of the artifact: its certified radius and its centre in the
/// workpiece frame (mm).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ball {
    pub radius_mm: f64,
    pub centre_mm: [f64; 3],
}

/// The artifact of the paper: a 150 mm plate on the C table with two balls, 26 mm and
/// 41 mm, as far from the C axis as the plate allows: the 26 mm ball's centre 60 mm
/// out, the 41 mm ball's 52 mm out on the other side, both reaching 73 mm of the 75 mm
/// plate radius, on stems putting their centres 30 and 45 mm above the table face
/// (their placement is this project's choice; the paper shows it only in a figure).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Artifact {
    pub balls: [Ball; 2],
}

impl Default for Artifact {
    fn default() -> Self {
        Self {
            balls: [
                Ball {
                    radius_mm: 13.0,
                    centre_mm: [-60.0, 0.0, 30.0],
                },
                Ball {
                    radius_mm: 20.5,
                    centre_mm: [52.0, 0.0, 45.0],
                },
            ],
        }
    }
}

/// The paper's sweeps: C in 12 steps of 30° at A = 0, A in 6 steps of 15° (7 positions,
/// 0 to 90°) at C = 0. Returns (A, C) in degrees per step.
pub fn sweep(axis: Axis) -> Vec<(f64, f64)> {
    match axis {
        Axis::C => (0..12).map(|k| (0.0, 30.0 * k as f64)).collect(),
        Axis::A => (0..7).map(|k| (15.0 * k as f64, 0.0)).collect(),
    }
}

/// Where the balls' centres are in the machine frame over both sweeps, for a machine
/// (with or without errors): the centres a perfect measurement would give.
pub fn centres_of(machine: &RotaryMachine, artifact: &Artifact) -> Vec<CentreRow> {
    let mut rows = Vec::new();
    for axis in [Axis::C, Axis::A] {
        for (step, (a, c)) in sweep(axis).into_iter().enumerate() {
            let table = machine.table(a, c);
            for (b, ball) in artifact.balls.iter().enumerate() {
                let p = kinematics::transform_point(&table, &Vector3::from(ball.centre_mm));
                rows.push(CentreRow {
                    axis,
                    step: step as u32,
                    angle_deg: if axis == Axis::C { c } else { a },
                    ball: b as u8 + 1,
                    x_mm: p.x,
                    y_mm: p.y,
                    z_mm: p.z,
                });
            }
        }
    }
    rows
}

#[cfg(test)]
mod tests;

//! The simulated 5-axis machine of source B: a 340A-style mill with an NCTLT-125-style
//! A/C tilting table carrying a plate with two precision balls, and a touch probe in the
//! spindle. The truth for tests; its chain is its own code (exact rotations about the
//! actual axis lines), not the `rotary` crate's.
//!
//! Frames as in the `rotary` crate: machine X, Y, Z of the spindle gauge point (mm),
//! the linear axes on the tool side; the workpiece frame on the table with its origin on
//! the nominal C axis at the table face; A about X, C about Z, right-handed, degrees.

use crate::rng::Rng;
use nalgebra::{Rotation3, Unit, Vector3};
use serde::{Deserialize, Serialize};

/// The machine's nominal geometry (mm), as its maker states it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Geometry {
    pub a_axis_y_mm: f64,
    pub a_axis_z_mm: f64,
    pub ac_offset_y_mm: f64,
    pub ac_offset_z_mm: f64,
    pub tool_length_mm: f64,
}

impl Default for Geometry {
    fn default() -> Self {
        Self {
            a_axis_y_mm: 0.0,
            a_axis_z_mm: -350.0,
            ac_offset_y_mm: 0.0,
            ac_offset_z_mm: 60.0,
            tool_length_mm: 100.0,
        }
    }
}

/// The eight location errors of the simulated table (mm and degrees), the paper's names.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TableErrors {
    pub delta_xc_mm: f64,
    pub delta_yc_mm: f64,
    pub alpha_xc_deg: f64,
    pub alpha_yc_deg: f64,
    pub delta_ya_mm: f64,
    pub delta_za_mm: f64,
    pub alpha_ya_deg: f64,
    pub alpha_za_deg: f64,
}

impl Default for TableErrors {
    /// The values the paper measured on its NCTLT-125 table.
    fn default() -> Self {
        Self {
            delta_xc_mm: -0.0015,
            delta_yc_mm: 0.0009,
            alpha_xc_deg: -0.003,
            alpha_yc_deg: -0.0014,
            delta_ya_mm: -0.0293,
            delta_za_mm: -0.3924,
            alpha_ya_deg: 0.0232,
            alpha_za_deg: -0.03,
        }
    }
}

/// A ball on the plate: radius and true centre in the workpiece frame (mm).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrueBall {
    pub radius_mm: f64,
    pub centre_mm: [f64; 3],
}

/// The touch probe: a stylus ball on the tool's axis at the tool length, a trigger that
/// fires after `pre_travel_mm` of deflection, with a normal scatter of `noise_mm`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TouchProbe {
    pub stylus_radius_mm: f64,
    pub pre_travel_mm: f64,
    pub noise_mm: f64,
}

impl Default for TouchProbe {
    fn default() -> Self {
        Self {
            stylus_radius_mm: 1.5,
            pre_travel_mm: 0.0008,
            noise_mm: 0.0003,
        }
    }
}

/// The table's cylindrical rim (NCTLT-125: a 125 mm face), turning with C: the probe
/// finds the C rotation centre on it. Its centre is the actual C axis at the table face
/// plus a run-out of a micrometre or two (rims are ground concentric to the bearing).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TableRim {
    pub radius_mm: f64,
    /// How far the rim reaches below the table face.
    pub depth_mm: f64,
    /// The rim's centre off the actual C axis (workpiece frame X, Y), mm.
    pub runout_mm: [f64; 2],
}

impl Default for TableRim {
    fn default() -> Self {
        Self {
            radius_mm: 62.5,
            depth_mm: 20.0,
            runout_mm: [0.0012, -0.0008],
        }
    }
}

/// The simulated machine.
#[derive(Clone, Debug)]
pub struct RotaryMachineSim {
    pub geometry: Geometry,
    pub errors: TableErrors,
    /// The plate's balls where they really are: a few hundredths of a millimetre from
    /// where the drawing puts them (26 mm at (-60, 0, 30), 41 mm at (52, 0, 45)).
    pub balls: [TrueBall; 2],
    pub rim: TableRim,
    pub probe: TouchProbe,
    rng: Rng,
}

impl RotaryMachineSim {
    pub fn new(geometry: Geometry, errors: TableErrors, probe: TouchProbe, seed: u64) -> Self {
        Self {
            geometry,
            errors,
            balls: [
                TrueBall {
                    radius_mm: 13.0,
                    centre_mm: [-59.972, 0.018, 30.011],
                },
                TrueBall {
                    radius_mm: 20.5,
                    centre_mm: [52.025, -0.031, 44.992],
                },
            ],
            rim: TableRim::default(),
            probe,
            rng: Rng::new(seed),
        }
    }

    /// The paper's table with a default probe.
    pub fn paper(seed: u64) -> Self {
        Self::new(
            Geometry::default(),
            TableErrors::default(),
            TouchProbe::default(),
            seed,
        )
    }

    /// The actual C axis at A = 0 (machine frame): a point and a unit direction.
    fn c_line(&self) -> (Vector3<f64>, Unit<Vector3<f64>>) {
        let g = &self.geometry;
        let e = &self.errors;
        let point = Vector3::new(
            e.delta_xc_mm,
            g.a_axis_y_mm + g.ac_offset_y_mm + e.delta_yc_mm,
            g.a_axis_z_mm + g.ac_offset_z_mm,
        );
        let dir = Vector3::new(
            e.alpha_yc_deg.to_radians().tan(),
            -e.alpha_xc_deg.to_radians().tan(),
            1.0,
        );
        (point, Unit::new_normalize(dir))
    }

    /// The actual A axis (machine frame).
    fn a_line(&self) -> (Vector3<f64>, Unit<Vector3<f64>>) {
        let g = &self.geometry;
        let e = &self.errors;
        let point = Vector3::new(
            0.0,
            g.a_axis_y_mm + e.delta_ya_mm,
            g.a_axis_z_mm + e.delta_za_mm,
        );
        let dir = Vector3::new(
            1.0,
            e.alpha_za_deg.to_radians().tan(),
            -e.alpha_ya_deg.to_radians().tan(),
        );
        (point, Unit::new_normalize(dir))
    }

    fn table_origin(&self) -> Vector3<f64> {
        let g = &self.geometry;
        Vector3::new(
            0.0,
            g.a_axis_y_mm + g.ac_offset_y_mm,
            g.a_axis_z_mm + g.ac_offset_z_mm,
        )
    }

    /// A point of the table (workpiece frame) in the machine frame at A, C (degrees):
    /// turned by C about the actual C line, then by A about the actual A line.
    pub fn table_point(&self, p_w: &Vector3<f64>, a_deg: f64, c_deg: f64) -> Vector3<f64> {
        let (qc, uc) = self.c_line();
        let (qa, ua) = self.a_line();
        let p = p_w + self.table_origin();
        let p = qc + Rotation3::from_axis_angle(&uc, c_deg.to_radians()) * (p - qc);
        qa + Rotation3::from_axis_angle(&ua, a_deg.to_radians()) * (p - qa)
    }

    /// The true tool tip and direction in the workpiece frame for a command (X, Y, Z of
    /// the gauge point, A, C): the trace the tests compare programs against.
    pub fn tool_in_workpiece(&self, cmd: [f64; 5]) -> (Vector3<f64>, Vector3<f64>) {
        let [x, y, z, a, c] = cmd;
        let (qc, uc) = self.c_line();
        let (qa, ua) = self.a_line();
        let ra = Rotation3::from_axis_angle(&ua, a.to_radians());
        let rc = Rotation3::from_axis_angle(&uc, c.to_radians());
        let tip = Vector3::new(x, y, z - self.geometry.tool_length_mm);
        // Undo A, then C, then the table origin.
        let p = qa + ra.inverse() * (tip - qa);
        let p = qc + rc.inverse() * (p - qc);
        let dir = rc.inverse() * (ra.inverse() * Vector3::z());
        (p - self.table_origin(), dir)
    }

    /// A machine-frame point in the workpiece frame with the table at A, C (the inverse of
    /// [`Self::table_point`]).
    fn to_table(&self, m: &Vector3<f64>, a_deg: f64, c_deg: f64) -> Vector3<f64> {
        let (qc, uc) = self.c_line();
        let (qa, ua) = self.a_line();
        let p = qa + Rotation3::from_axis_angle(&ua, a_deg.to_radians()).inverse() * (m - qa);
        let p = qc + Rotation3::from_axis_angle(&uc, c_deg.to_radians()).inverse() * (p - qc);
        p - self.table_origin()
    }

    /// The rim's centre in the workpiece frame (X, Y) at C = 0: the actual C axis where
    /// it crosses the table face, plus the run-out.
    pub fn rim_centre(&self) -> [f64; 2] {
        let (qc, uc) = self.c_line();
        // The C line at the face's height (workpiece z = 0).
        let o = self.table_origin();
        let t = (o.z - qc.z) / uc.z;
        let at_face = qc + uc.into_inner() * t - o;
        [
            at_face.x + self.rim.runout_mm[0],
            at_face.y + self.rim.runout_mm[1],
        ]
    }

    /// Where along a straight stylus path (workpiece frame, from `start` in unit
    /// direction `dir`, `length` long) the stylus ball first meets the rim, if it does:
    /// its centre comes within the rim's radius plus the stylus radius of the rim's axis,
    /// at a height on the rim.
    fn rim_contact(&self, start: &Vector3<f64>, dir: &Vector3<f64>, length: f64) -> Option<f64> {
        let c = self.rim_centre();
        let r = self.probe.stylus_radius_mm;
        let reach = self.rim.radius_mm + r;
        let within = |p: Vector3<f64>, radius: f64| (p.x - c[0]).hypot(p.y - c[1]) <= radius;
        // The face, from above: the stylus centre comes down to one stylus radius over
        // it inside the rim.
        let top = (dir.z < 0.0 && start.z > r)
            .then(|| (r - start.z) / dir.z)
            .filter(|&s| s <= length && within(start + dir * s, self.rim.radius_mm));
        // The cylinder, from outside.
        let (mx, my) = (start.x - c[0], start.y - c[1]);
        let a = dir.x * dir.x + dir.y * dir.y;
        let b = mx * dir.x + my * dir.y;
        let cq = mx * mx + my * my - reach * reach;
        let disc = b * b - a * cq;
        let side = (a > 1e-18 && disc >= 0.0 && cq > 0.0)
            .then(|| (-b - disc.sqrt()) / a)
            .filter(|&s| {
                let z = start.z + dir.z * s;
                s >= 0.0 && s <= length && z <= 0.0 && z >= -self.rim.depth_mm
            });
        match (top, side) {
            (Some(t), Some(s)) => Some(t.min(s)),
            (t, s) => t.or(s),
        }
    }

    /// The true centre of ball `ball` (0 or 1) in the machine frame at A, C.
    pub fn ball_centre(&self, ball: usize, a_deg: f64, c_deg: f64) -> Vector3<f64> {
        self.table_point(&Vector3::from(self.balls[ball].centre_mm), a_deg, c_deg)
    }

    /// A probing move of the gauge point from `from` to `to` (machine X, Y, Z) with the
    /// table at A, C: the gauge point where the probe triggers, or `None` when the
    /// stylus reaches `to` without touching a ball. The stylus centre is the tool tip;
    /// it touches a ball when its distance to the ball's centre falls to the sum of the
    /// radii, and the trigger fires `pre_travel_mm` further along the move, scattered by
    /// the trigger noise.
    pub fn probe_move(
        &mut self,
        from: [f64; 3],
        to: [f64; 3],
        a_deg: f64,
        c_deg: f64,
    ) -> Option<[f64; 3]> {
        let l = self.geometry.tool_length_mm;
        let start = Vector3::new(from[0], from[1], from[2] - l);
        let end = Vector3::new(to[0], to[1], to[2] - l);
        let travel = end - start;
        let length = travel.norm();
        if !(length > 0.0) {
            return None;
        }
        let dir = travel / length;
        let mut first: Option<f64> = None;
        for b in 0..2 {
            let centre = self.ball_centre(b, a_deg, c_deg);
            let reach = self.balls[b].radius_mm + self.probe.stylus_radius_mm;
            // |start + s dir - centre| = reach, the smaller root s >= 0.
            let m = start - centre;
            let bq = m.dot(&dir);
            let cq = m.norm_squared() - reach * reach;
            let disc = bq * bq - cq;
            if disc < 0.0 {
                continue;
            }
            let s = -bq - disc.sqrt();
            let s = if cq <= 0.0 { 0.0 } else { s };
            if s >= 0.0 && s <= length && first.is_none_or(|f| s < f) {
                first = Some(s);
            }
        }
        // The rim, in the workpiece frame (a rigid motion keeps the path's length).
        let from_t = self.to_table(&start, a_deg, c_deg);
        let to_t = self.to_table(&end, a_deg, c_deg);
        if let Some(s) = self.rim_contact(&from_t, &((to_t - from_t) / length), length) {
            if first.is_none_or(|f| s < f) {
                first = Some(s);
            }
        }
        let s = first? + self.probe.pre_travel_mm + self.probe.noise_mm * self.rng.normal();
        let p = start + dir * s.min(length);
        Some([p.x, p.y, p.z + l])
    }
}

/// The rotary machine behind an N-axis controller: six axis slots X Y Z A B C as
/// grblHAL orders them (a 5-axis X Y Z A C machine is a six-axis build whose B has no
/// travel), the touch probe against the plate's balls.
pub struct RotaryWorkpiece {
    pub sim: RotaryMachineSim,
}

impl RotaryWorkpiece {
    /// Travels: X, Y -250..250 mm, Z -400..200 mm (gauge point; the table face is near -260), A -120..120 deg, B
    /// fixed at 0, C -3600..3600 deg (ten turns).
    pub const LIMITS: [(f64, f64, f64); 6] = [
        (-250.0, 250.0, 3000.0),
        (-250.0, 250.0, 3000.0),
        (-400.0, 200.0, 3000.0),
        (-120.0, 120.0, 5400.0),
        (0.0, 0.0, 5400.0),
        (-3600.0, 3600.0, 5400.0),
    ];

    /// The true tool tip and direction in the workpiece frame with the axes at `at`.
    pub fn tool(&self, at: &crate::axes::AxesPosition) -> (Vector3<f64>, Vector3<f64>) {
        self.sim
            .tool_in_workpiece([at[0], at[1], at[2], at[3], at[5]])
    }
}

impl crate::axes::Workpiece for RotaryWorkpiece {
    fn axes(&self) -> usize {
        6
    }

    fn limits(&self, axis: usize) -> crate::axes::AxisLimits {
        let (min, max, max_rate) = Self::LIMITS[axis.min(5)];
        crate::axes::AxisLimits { min, max, max_rate }
    }

    /// Probing moves with the table still (A and C the same at both ends); a move that
    /// turns the table does not probe (no contact).
    fn probe_contact(
        &mut self,
        from: &crate::axes::AxesPosition,
        to: &crate::axes::AxesPosition,
    ) -> Option<crate::axes::AxesPosition> {
        if from[3] != to[3] || from[5] != to[5] {
            return None;
        }
        let p = self.sim.probe_move(
            [from[0], from[1], from[2]],
            [to[0], to[1], to[2]],
            to[3],
            to[5],
        )?;
        let mut at = *to;
        at[..3].copy_from_slice(&p);
        Some(at)
    }

    fn probe_touching(&self, at: &crate::axes::AxesPosition) -> bool {
        let tip = Vector3::new(at[0], at[1], at[2] - self.sim.geometry.tool_length_mm);
        let on_rim = {
            let t = self.sim.to_table(&tip, at[3], at[5]);
            let c = self.sim.rim_centre();
            let reach = self.sim.rim.radius_mm + self.sim.probe.stylus_radius_mm;
            (t.x - c[0]).hypot(t.y - c[1]) <= reach && t.z <= 0.0 && t.z >= -self.sim.rim.depth_mm
        };
        on_rim
            || (0..2).any(|b| {
                let reach = self.sim.balls[b].radius_mm + self.sim.probe.stylus_radius_mm;
                (tip - self.sim.ball_centre(b, at[3], at[5])).norm() <= reach
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nominal_table_turns_as_the_paper_says() {
        let mut m = RotaryMachineSim::paper(1);
        m.errors = TableErrors {
            delta_xc_mm: 0.0,
            delta_yc_mm: 0.0,
            alpha_xc_deg: 0.0,
            alpha_yc_deg: 0.0,
            delta_ya_mm: 0.0,
            delta_za_mm: 0.0,
            alpha_ya_deg: 0.0,
            alpha_za_deg: 0.0,
        };
        // Tool straight down over the table origin at A 90: the table stands up, the
        // tool looks along workpiece +Y ((sin A sin C, sin A cos C, cos A) at C = 0).
        let (p, d) = m.tool_in_workpiece([0.0, 0.0, -190.0, 90.0, 0.0]);
        assert!((d - Vector3::new(0.0, 1.0, 0.0)).norm() < 1e-12);
        // The tip is 60 mm above the A axis, i.e. 60 mm along workpiece +Y from the A
        // axis, which sits 60 mm below the table face: (0, 60, -60).
        assert!((p - Vector3::new(0.0, 60.0, -60.0)).norm() < 1e-9, "{p}");
    }

    #[test]
    fn delta_za_moves_a_table_point_about_the_lowered_axis() {
        let mut m = RotaryMachineSim::paper(1);
        m.errors = TableErrors {
            delta_xc_mm: 0.0,
            delta_yc_mm: 0.0,
            alpha_xc_deg: 0.0,
            alpha_yc_deg: 0.0,
            delta_ya_mm: 0.0,
            delta_za_mm: 0.02,
            alpha_ya_deg: 0.0,
            alpha_za_deg: 0.0,
        };
        let p = m.table_point(&Vector3::zeros(), 90.0, 0.0);
        // Nominal: A point (0, 0, -350) + Rx(90)(0, 0, 60) = (0, -60, -350); the axis
        // 0.02 higher moves it by (0, 0.02, 0.02).
        assert!(
            (p - Vector3::new(0.0, -59.98, -349.98)).norm() < 1e-12,
            "{p}"
        );
    }

    #[test]
    fn probe_triggers_on_the_ball_and_misses_beside_it() {
        let mut m = RotaryMachineSim::paper(3);
        m.probe.noise_mm = 0.0;
        let c = m.ball_centre(0, 0.0, 0.0);
        let l = m.geometry.tool_length_mm;
        // Straight down onto the top of ball 1.
        let from = [c.x, c.y, c.z + l + 30.0];
        let to = [c.x, c.y, c.z + l];
        let hit = m.probe_move(from, to, 0.0, 0.0).unwrap();
        let expect = c.z + l + 13.0 + 1.5 - m.probe.pre_travel_mm;
        assert!((hit[2] - expect).abs() < 1e-12, "{hit:?}");
        // 20 mm to the side: nothing to touch.
        let miss = m.probe_move(
            [c.x + 20.0, c.y, c.z + l + 30.0],
            [c.x + 20.0, c.y, c.z + l],
            0.0,
            0.0,
        );
        assert_eq!(miss, None);
    }
}

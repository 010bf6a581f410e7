//! The error map as a model of the machine: where the camera (and the tool) really is
//! for a command, approached from a given side, and the command that puts the tool on a
//! nominal point. Pure and fast: no I/O, a few microseconds per evaluation.
//!
//! The map (`protocol::errormap`) holds a coarse grid over the travel, for the smooth
//! errors and the cross terms (squareness, straightness, yaw), and optional dense lines
//! along each axis for the short-period ones (the ballscrew's pitch error, whose period
//! is the lead): the grid alone cannot hold a 5 mm period without a dense 2-D grid. The
//! model is the grid's smooth interpolation plus, along each axis, what a dense line saw
//! beyond the grid at the same place:
//!
//! ```text
//! e(x, y, dir) = G(x, y, dir) + [Lx(x, dir) - G(x, y_Lx, dir)] + [Ly(y, dir) - G(x_Ly, y, dir)]
//! ```
//!
//! where G is a piecewise-cubic Hermite interpolation of the grid (C1: no kinks at the
//! nodes), Lx the dense line along X measured at y = y_Lx (interpolated between lines
//! when there are several), Ly likewise along Y. The X line's detail adds to both error
//! components (pitch error in ex, short-period straightness in ey).
//!
//! Direction: `Approach` per axis selects the forward (from below) or reverse (from
//! above) measurements for that axis's error component (backlash of the X screw shows in
//! ex, of the Y screw in ey); yaw is taken from the X approach.
//!
//! Tool point (Abbe): the tool sits at `tool_offset_mm` from the camera in machine axes;
//! a yaw theta (rad, counter-clockwise) moves it by theta x (-oy, ox) relative to the
//! camera. Worked example: offset (30, 0) mm and yaw +10 urad: the tool is 0.30 um
//! further in +Y than the camera's error says.
//!
//! Inverse: the command c that puts the tool on nominal p solves c + e_tool(c) = p; it is
//! found by fixed-point iteration c <- p - e_tool(c), which converges in two or three
//! steps because the error changes by far less than a micrometre per micrometre.
//!
//! Outside the map's extent nothing is extrapolated: every call refuses it.

mod compensation;
pub mod diff;
pub mod export;
pub mod heatmap;
pub mod reference;
pub mod scan;
pub mod tape;

use protocol::errormap::{ErrorMap, Measured, Node};

/// The side the final move onto a point came from, per axis (the rewriter's type, so a
/// map plugs into it without conversion).
pub use rewrite::Approach;

/// The largest machine-zero shift a reference accepts, um. Homing moves the zero by a
/// few um; more than half a millimetre is not a homing error but the wrong lattice
/// point, a moved board or a crash.
pub const MAX_SHIFT_UM: f64 = 500.0;

/// The largest growth of an axis a model applies, parts per million of the distance
/// from the reference point: 200 ppm is 20 um per 100 mm, a steel screw 17 K warmer
/// than at the scan. More is not thermal growth but a wrong measurement.
pub const MAX_SCALE_PPM: f64 = 200.0;

/// Micrometres as messages print them: `+6.27`, and never hundreds of digits for an
/// absurd value (`+1.000e308`).
pub fn um_text(v: f64) -> String {
    if v.abs() < 1e6 || !v.is_finite() {
        format!("{v:+.2}")
    } else {
        format!("{v:+.3e}")
    }
}

/// Approach per axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Direction {
    pub x: Approach,
    pub y: Approach,
}

impl Direction {
    pub const FORWARD: Direction = Direction {
        x: Approach::Forward,
        y: Approach::Forward,
    };
    pub const REVERSE: Direction = Direction {
        x: Approach::Reverse,
        y: Approach::Reverse,
    };

    /// The direction of a move from `from` to `to` (an axis that does not move keeps
    /// `previous`).
    pub fn of_move(from: [f64; 2], to: [f64; 2], previous: Direction) -> Direction {
        let side = |a: f64, b: f64, prev: Approach| {
            if b > a {
                Approach::Forward
            } else if b < a {
                Approach::Reverse
            } else {
                prev
            }
        };
        Direction {
            x: side(from[0], to[0], previous.x),
            y: side(from[1], to[1], previous.y),
        }
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ModelError {
    #[error("({:.3}, {:.3}) mm is outside the map ({:.3}..{:.3} x {:.3}..{:.3} mm): nothing is extrapolated", p[0], p[1], lo[0], hi[0], lo[1], hi[1])]
    Outside {
        p: [f64; 2],
        lo: [f64; 2],
        hi: [f64; 2],
    },
    #[error("the inverse did not settle at ({:.3}, {:.3}) mm (the map's errors change too fast to invert)", p[0], p[1])]
    NoInverse { p: [f64; 2] },
    #[error("the machine's zero would be shifted by ({}, {}) um, more than the {bound_um} um a homing can move it: not applied", um_text(shift_um[0]), um_text(shift_um[1]))]
    ShiftTooLarge { shift_um: [f64; 2], bound_um: f64 },
    #[error("the axes would be scaled by ({}, {}) ppm, more than the {bound_ppm} ppm thermal growth can: not applied", um_text(ppm[0]), um_text(ppm[1]))]
    ScaleTooLarge { ppm: [f64; 2], bound_ppm: f64 },
}

/// The three measured quantities of a node, each from the side its axis came from:
/// ex from X's approach, ey from Y's, yaw from X's (as the scan records it).
fn pick3(n: &Node, dir: Direction) -> [f64; 3] {
    let side = |a: Approach| -> &Measured {
        match a {
            Approach::Forward => &n.forward,
            Approach::Reverse => &n.reverse,
        }
    };
    let (mx, my) = (side(dir.x), side(dir.y));
    [mx.ex_um.mean, my.ey_um.mean, mx.yaw_urad.mean]
}

/// Weights of a piecewise-cubic Hermite interpolation at `x` over increasing `xs`, with
/// central-difference slopes (one-sided at the ends): the value is `sum w * f(i)` over
/// the four (index, weight) pairs, nodes k-1 .. k+2 around `x` (clamped at the ends). C1, exact on straight lines. Computing the weights once
/// per axis lets one pass interpolate every quantity of a node and a grid's rows.
fn hermite_weights(xs: &[f64], x: f64) -> [(usize, f64); 4] {
    let n = xs.len();
    debug_assert!(n >= 2);
    let k = match xs.partition_point(|&v| v <= x) {
        0 => 0,
        p if p >= n => n - 2,
        p => p - 1,
    };
    let h = xs[k + 1] - xs[k];
    let t = (x - xs[k]) / h;
    let (t2, t3) = (t * t, t * t * t);
    let h00 = 2.0 * t3 - 3.0 * t2 + 1.0;
    let h10 = t3 - 2.0 * t2 + t;
    let h01 = -2.0 * t3 + 3.0 * t2;
    let h11 = t3 - t2;
    // slope(i) = (f(b) - f(a)) / (xs[b] - xs[a]) with a = i - 1, b = i + 1, clamped
    // to the ends; the slopes' terms are folded into the four nodes k-1 .. k+2.
    let (a0, b1) = (k.saturating_sub(1), (k + 2).min(n - 1));
    let s0 = h10 * h / (xs[k + 1] - xs[a0]);
    let s1 = h11 * h / (xs[b1] - xs[k]);
    let mut w = [0.0; 4];
    w[if k >= 1 { 0 } else { 1 }] -= s0;
    w[1] += h00 - s1;
    w[2] += h01 + s0;
    w[if k + 2 < n { 3 } else { 2 }] += s1;
    [(a0, w[0]), (k, w[1]), (k + 1, w[2]), (b1, w[3])]
}

/// Piecewise-cubic Hermite interpolation at `x` of values `f` at increasing `xs`.
#[cfg(test)]
fn hermite(xs: &[f64], f: impl Fn(usize) -> f64, x: f64) -> f64 {
    hermite_weights(xs, x).iter().map(|&(i, w)| w * f(i)).sum()
}

fn add_scaled(acc: &mut [f64; 3], w: f64, v: [f64; 3]) {
    acc[0] += w * v[0];
    acc[1] += w * v[1];
    acc[2] += w * v[2];
}

/// An error map ready to evaluate.
#[derive(Clone, Debug)]
pub struct MapModel {
    /// The map, its lines sorted by their position across the axis.
    map: ErrorMap,
    /// Added to every camera error (re-reference after homing), um.
    offset_um: [f64; 2],
    /// Each axis's growth since the scan about the reference point, ppm (a reference
    /// that measured it): X's error grows by `scale_ppm[0] * (x - x_ref)`, Y's likewise.
    scale_ppm: [f64; 2],
    /// Yaw at the reference point (forward), urad: the zero of the Abbe term.
    reference_yaw_urad: f64,
    /// The grid interpolated across to each dense line, per direction: for a line along
    /// X at y = a, the grid's values at (xs[i], a) for every i (for a line along Y, at
    /// (a, ys[j])). The grid under a line is then a one-axis interpolation of these,
    /// exactly as the full tensor product gives it, at a quarter of the work.
    x_line_rows: Vec<[Vec<[f64; 3]>; 4]>,
    y_line_rows: Vec<[Vec<[f64; 3]>; 4]>,
}

/// The four approach combinations, indexed as [`dir_index`] does.
const DIRECTIONS: [Direction; 4] = [
    Direction {
        x: Approach::Forward,
        y: Approach::Forward,
    },
    Direction {
        x: Approach::Reverse,
        y: Approach::Forward,
    },
    Direction {
        x: Approach::Forward,
        y: Approach::Reverse,
    },
    Direction {
        x: Approach::Reverse,
        y: Approach::Reverse,
    },
];

fn dir_index(dir: Direction) -> usize {
    usize::from(dir.x == Approach::Reverse) + 2 * usize::from(dir.y == Approach::Reverse)
}

impl MapModel {
    pub fn new(mut map: ErrorMap) -> Self {
        map.x_lines.sort_by(|a, b| a.at_mm.total_cmp(&b.at_mm));
        map.y_lines.sort_by(|a, b| a.at_mm.total_cmp(&b.at_mm));
        let mut model = Self {
            map,
            offset_um: [0.0; 2],
            scale_ppm: [0.0; 2],
            reference_yaw_urad: 0.0,
            x_line_rows: Vec::new(),
            y_line_rows: Vec::new(),
        };
        model.x_line_rows = model.line_rows(true);
        model.y_line_rows = model.line_rows(false);
        model.reference_yaw_urad = model.values(Direction::FORWARD, model.map.reference_mm)[2];
        model
    }

    fn line_rows(&self, along_x: bool) -> Vec<[Vec<[f64; 3]>; 4]> {
        let g = &self.map.grid;
        let (lines, along, across) = if along_x {
            (&self.map.x_lines, &g.xs, &g.ys)
        } else {
            (&self.map.y_lines, &g.ys, &g.xs)
        };
        lines
            .iter()
            .map(|l| {
                let w_across = hermite_weights(across, l.at_mm);
                DIRECTIONS.map(|dir| {
                    (0..along.len())
                        .map(|i| {
                            let mut w_along = [(0, 0.0); 4];
                            w_along[0] = (i, 1.0);
                            if along_x {
                                self.grid(dir, &w_along, &w_across)
                            } else {
                                self.grid(dir, &w_across, &w_along)
                            }
                        })
                        .collect()
                })
            })
            .collect()
    }

    pub fn map(&self) -> &ErrorMap {
        &self.map
    }

    /// The extent the map covers, machine mm: (min, max).
    pub fn extent(&self) -> ([f64; 2], [f64; 2]) {
        let g = &self.map.grid;
        (
            [g.xs[0], g.ys[0]],
            [g.xs[g.xs.len() - 1], g.ys[g.ys.len() - 1]],
        )
    }

    /// The same map shifted by what the camera saw at the reference point after a new
    /// homing (each homing moves the machine's zero by a few um): `seen_um` is the error
    /// measured there now, approached forward. The shift this applies is bounded here,
    /// where it is applied, whoever measured or recorded it: more than
    /// [`MAX_SHIFT_UM`] (or not finite) is refused. An axis scale ([`Self::rescaled`])
    /// stays: it is zero at the reference point, and a homing does not cool a screw.
    pub fn rereferenced(mut self, seen_um: [f64; 2]) -> Result<Self, ModelError> {
        self.offset_um = [0.0; 2];
        let r = self.map.reference_mm;
        let mapped = self.camera_error_um(r, Direction::FORWARD)?;
        let shift_um = [seen_um[0] - mapped[0], seen_um[1] - mapped[1]];
        let bound_um = MAX_SHIFT_UM;
        if !(shift_um[0].hypot(shift_um[1]) <= bound_um) {
            return Err(ModelError::ShiftTooLarge { shift_um, bound_um });
        }
        self.offset_um = shift_um;
        Ok(self)
    }

    pub fn offset_um(&self) -> [f64; 2] {
        self.offset_um
    }

    /// The same map with each axis grown by `ppm` since the scan (thermal growth of the
    /// screws, measured by a reference along each axis), about the reference point: a
    /// command at `x` lands `ppm[0] * (x - x_ref) / 1000` um further than the map says
    /// (ppm x mm = nm). Worked example: +3 ppm on X, reference at X 105: at X 205 the
    /// camera is +0.30 um further in X, at X 5 -0.30 um. Keeps the shift (the growth is
    /// zero at the reference point); replaces an earlier scale. Bounded here, where it
    /// is applied: more than [`MAX_SCALE_PPM`] (or not finite) is refused.
    pub fn rescaled(mut self, ppm: [f64; 2]) -> Result<Self, ModelError> {
        let bound_ppm = MAX_SCALE_PPM;
        if !ppm.iter().all(|v| v.abs() <= bound_ppm) {
            return Err(ModelError::ScaleTooLarge { ppm, bound_ppm });
        }
        self.scale_ppm = ppm;
        Ok(self)
    }

    pub fn scale_ppm(&self) -> [f64; 2] {
        self.scale_ppm
    }

    /// The shift plus the axes' growth at `p`, um.
    fn correction_um(&self, p: [f64; 2]) -> [f64; 2] {
        let r = self.map.reference_mm;
        [
            self.offset_um[0] + self.scale_ppm[0] * (p[0] - r[0]) / 1000.0,
            self.offset_um[1] + self.scale_ppm[1] * (p[1] - r[1]) / 1000.0,
        ]
    }

    pub(crate) fn inside(&self, p: [f64; 2]) -> Result<(), ModelError> {
        let (lo, hi) = self.extent();
        // A nanometre of slack for points computed onto the edge.
        let eps = 1e-6;
        if p[0] >= lo[0] - eps && p[0] <= hi[0] + eps && p[1] >= lo[1] - eps && p[1] <= hi[1] + eps
        {
            Ok(())
        } else {
            Err(ModelError::Outside { p, lo, hi })
        }
    }

    /// The grid's smooth values at `p`: tensor product of the two axes' weights.
    fn grid(&self, dir: Direction, wx: &[(usize, f64); 4], wy: &[(usize, f64); 4]) -> [f64; 3] {
        let g = &self.map.grid;
        let nx = g.xs.len();
        let mut v = [0.0; 3];
        for &(j, w_row) in wy {
            if w_row == 0.0 {
                continue;
            }
            for &(i, w) in wx {
                add_scaled(&mut v, w_row * w, pick3(&g.nodes[j * nx + i], dir));
            }
        }
        v
    }

    /// What the dense lines along one axis saw beyond the grid, at position `s` along
    /// the axis and `t` across it (interpolated linearly between lines by their `at_mm`).
    fn line_detail(&self, along_x: bool, dir: Direction, p: [f64; 2]) -> [f64; 3] {
        let (lines, rows, along) = if along_x {
            (&self.map.x_lines, &self.x_line_rows, &self.map.grid.xs)
        } else {
            (&self.map.y_lines, &self.y_line_rows, &self.map.grid.ys)
        };
        if lines.is_empty() {
            return [0.0; 3];
        }
        let (s, t) = if along_x { (p[0], p[1]) } else { (p[1], p[0]) };
        let d = dir_index(dir);
        let detail = |k: usize| {
            let l = &lines[k];
            let s = s.clamp(l.positions[0], l.positions[l.positions.len() - 1]);
            let mut v = [0.0; 3];
            for (i, w) in hermite_weights(&l.positions, s) {
                add_scaled(&mut v, w, pick3(&l.nodes[i], dir));
            }
            for (i, w) in hermite_weights(along, s) {
                add_scaled(&mut v, -w, rows[k][d][i]);
            }
            v
        };
        if lines.len() == 1 {
            return detail(0);
        }
        // Lines are sorted by position across (`new`); linear between the two around t.
        let last = lines.len() - 1;
        if t <= lines[0].at_mm {
            return detail(0);
        }
        if t >= lines[last].at_mm {
            return detail(last);
        }
        let k = lines.windows(2).position(|w| t <= w[1].at_mm).unwrap_or(0);
        let w = (t - lines[k].at_mm) / (lines[k + 1].at_mm - lines[k].at_mm);
        let mut v = [0.0; 3];
        add_scaled(&mut v, 1.0 - w, detail(k));
        add_scaled(&mut v, w, detail(k + 1));
        v
    }

    /// (ex um, ey um, yaw urad) at `p` approached from `dir`, without the re-reference
    /// offset.
    fn values(&self, dir: Direction, p: [f64; 2]) -> [f64; 3] {
        let g = &self.map.grid;
        let mut v = self.grid(
            dir,
            &hermite_weights(&g.xs, p[0]),
            &hermite_weights(&g.ys, p[1]),
        );
        add_scaled(&mut v, 1.0, self.line_detail(true, dir, p));
        add_scaled(&mut v, 1.0, self.line_detail(false, dir, p));
        v
    }

    /// The map's own camera error at `p` (as scanned: no shift, no scale), um.
    pub(crate) fn scanned_error_um(
        &self,
        p: [f64; 2],
        dir: Direction,
    ) -> Result<[f64; 2], ModelError> {
        self.inside(p)?;
        let v = self.values(dir, p);
        Ok([v[0], v[1]])
    }

    /// Where the camera really looks minus where it should, um, after a move onto
    /// command `p` (mm) approached from `dir`.
    pub fn camera_error_um(&self, p: [f64; 2], dir: Direction) -> Result<[f64; 2], ModelError> {
        self.inside(p)?;
        let v = self.values(dir, p);
        let c = self.correction_um(p);
        Ok([v[0] + c[0], v[1] + c[1]])
    }

    /// Yaw at `p` relative to the reference, microradians.
    pub fn yaw_urad(&self, p: [f64; 2], dir: Direction) -> Result<f64, ModelError> {
        self.inside(p)?;
        Ok(self.values(dir, p)[2])
    }

    /// The tool point's error, um: the camera's plus the yaw acting on the tool offset.
    pub fn tool_error_um(&self, p: [f64; 2], dir: Direction) -> Result<[f64; 2], ModelError> {
        self.inside(p)?;
        let v = self.values(dir, p);
        let c = self.correction_um(p);
        let e = [v[0] + c[0], v[1] + c[1]];
        let theta_urad = v[2] - self.reference_yaw_urad;
        let [ox, oy] = self.map.tool_offset_mm;
        // urad x mm = nm: / 1000 for um.
        Ok([
            e[0] - theta_urad * oy / 1000.0,
            e[1] + theta_urad * ox / 1000.0,
        ])
    }

    /// The command that puts the tool on nominal `p` (mm) when approached from `dir`.
    pub fn command_for(&self, p: [f64; 2], dir: Direction) -> Result<[f64; 2], ModelError> {
        self.command_from(p, dir, p)
    }

    /// The command that puts the camera (not the tool) on nominal `p`: what a camera
    /// check of the compensation needs (`gateway verify`).
    pub fn camera_command_for(&self, p: [f64; 2], dir: Direction) -> Result<[f64; 2], ModelError> {
        self.invert(p, p, |at| self.camera_error_um(at, dir))
    }

    /// The same, iterating from `guess` (a command close to the answer saves a step).
    pub fn command_from(
        &self,
        p: [f64; 2],
        dir: Direction,
        guess: [f64; 2],
    ) -> Result<[f64; 2], ModelError> {
        self.invert(p, guess, |at| self.tool_error_um(at, dir))
    }

    /// Fixed point c <- p - e(c) from `guess`: each step shrinks the distance to the
    /// answer by the error's slope (about 0.003 um per um on a C5 screw), so once a step
    /// moves the command by less than 10 nm the answer is within a fraction of a
    /// nanometre.
    fn invert(
        &self,
        p: [f64; 2],
        guess: [f64; 2],
        error_um: impl Fn([f64; 2]) -> Result<[f64; 2], ModelError>,
    ) -> Result<[f64; 2], ModelError> {
        self.inside(p)?;
        let (lo, hi) = self.extent();
        let mut c = guess;
        for _ in 0..8 {
            // Clamp into the map: a point on the edge needs a command just outside it.
            let at = [c[0].clamp(lo[0], hi[0]), c[1].clamp(lo[1], hi[1])];
            let e = error_um(at)?;
            let next = [p[0] - e[0] / 1000.0, p[1] - e[1] / 1000.0];
            let moved = (next[0] - c[0]).hypot(next[1] - c[1]);
            c = next;
            if moved < 1e-5 {
                return Ok(c);
            }
        }
        Err(ModelError::NoInverse { p })
    }
}

#[cfg(test)]
mod tests;

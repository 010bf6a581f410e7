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

pub mod scan;

use protocol::errormap::{ErrorMap, Line, Measured, Node};

/// The side the final move onto a point came from, per axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Approach {
    /// From below (the last move was in +).
    Forward,
    /// From above (the last move was in -).
    Reverse,
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
}

/// Which measured quantity of a node.
#[derive(Clone, Copy)]
enum Quantity {
    Ex,
    Ey,
    Yaw,
}

fn pick(n: &Node, q: Quantity, a: Approach) -> f64 {
    let m: &Measured = match a {
        Approach::Forward => &n.forward,
        Approach::Reverse => &n.reverse,
    };
    match q {
        Quantity::Ex => m.ex_um.mean,
        Quantity::Ey => m.ey_um.mean,
        Quantity::Yaw => m.yaw_urad.mean,
    }
}

/// Piecewise-cubic Hermite interpolation at `x` of values `f` at increasing `xs`, with
/// central-difference slopes (one-sided at the ends): C1, exact on straight lines.
fn hermite(xs: &[f64], f: impl Fn(usize) -> f64, x: f64) -> f64 {
    let n = xs.len();
    debug_assert!(n >= 2);
    let k = match xs.partition_point(|&v| v <= x) {
        0 => 0,
        p if p >= n => n - 2,
        p => p - 1,
    };
    let slope = |i: usize| {
        let (a, b) = (i.saturating_sub(1), (i + 1).min(n - 1));
        (f(b) - f(a)) / (xs[b] - xs[a])
    };
    let h = xs[k + 1] - xs[k];
    let t = (x - xs[k]) / h;
    let (t2, t3) = (t * t, t * t * t);
    let h00 = 2.0 * t3 - 3.0 * t2 + 1.0;
    let h10 = t3 - 2.0 * t2 + t;
    let h01 = -2.0 * t3 + 3.0 * t2;
    let h11 = t3 - t2;
    h00 * f(k) + h10 * h * slope(k) + h01 * f(k + 1) + h11 * h * slope(k + 1)
}

/// An error map ready to evaluate.
#[derive(Clone, Debug)]
pub struct MapModel {
    /// The map, its lines sorted by their position across the axis.
    map: ErrorMap,
    /// Added to every camera error (re-reference after homing), um.
    offset_um: [f64; 2],
    /// Yaw at the reference point (forward), urad: the zero of the Abbe term.
    reference_yaw_urad: f64,
}

impl MapModel {
    pub fn new(mut map: ErrorMap) -> Self {
        map.x_lines.sort_by(|a, b| a.at_mm.total_cmp(&b.at_mm));
        map.y_lines.sort_by(|a, b| a.at_mm.total_cmp(&b.at_mm));
        let mut model = Self {
            map,
            offset_um: [0.0; 2],
            reference_yaw_urad: 0.0,
        };
        model.reference_yaw_urad =
            model.value(Quantity::Yaw, Approach::Forward, model.map.reference_mm);
        model
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
    /// measured there now, approached forward.
    pub fn rereferenced(mut self, seen_um: [f64; 2]) -> Result<Self, ModelError> {
        self.offset_um = [0.0; 2];
        let r = self.map.reference_mm;
        let mapped = self.camera_error_um(r, Direction::FORWARD)?;
        self.offset_um = [seen_um[0] - mapped[0], seen_um[1] - mapped[1]];
        Ok(self)
    }

    pub fn offset_um(&self) -> [f64; 2] {
        self.offset_um
    }

    fn inside(&self, p: [f64; 2]) -> Result<(), ModelError> {
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

    /// The grid's smooth value of `q` at `p`.
    fn grid(&self, q: Quantity, a: Approach, p: [f64; 2]) -> f64 {
        let g = &self.map.grid;
        let nx = g.xs.len();
        let row = |j: usize| hermite(&g.xs, |i| pick(&g.nodes[j * nx + i], q, a), p[0]);
        hermite(&g.ys, row, p[1])
    }

    /// What the dense lines along one axis saw beyond the grid, at position `s` along
    /// the axis and `t` across it (interpolated linearly between lines by their `at_mm`).
    fn line_detail(
        &self,
        lines: &[Line],
        along_x: bool,
        q: Quantity,
        a: Approach,
        p: [f64; 2],
    ) -> f64 {
        if lines.is_empty() {
            return 0.0;
        }
        let (s, t) = if along_x { (p[0], p[1]) } else { (p[1], p[0]) };
        let detail = |l: &Line| {
            let s = s.clamp(l.positions[0], l.positions[l.positions.len() - 1]);
            let on_line = hermite(&l.positions, |i| pick(&l.nodes[i], q, a), s);
            let at = if along_x { [s, l.at_mm] } else { [l.at_mm, s] };
            on_line - self.grid(q, a, at)
        };
        if lines.len() == 1 {
            return detail(&lines[0]);
        }
        // Lines are sorted by position across (`new`); linear between the two around t.
        let (first, last) = (&lines[0], &lines[lines.len() - 1]);
        if t <= first.at_mm {
            return detail(first);
        }
        if t >= last.at_mm {
            return detail(last);
        }
        let k = lines.windows(2).position(|w| t <= w[1].at_mm).unwrap_or(0);
        let (l0, l1) = (&lines[k], &lines[k + 1]);
        let w = (t - l0.at_mm) / (l1.at_mm - l0.at_mm);
        (1.0 - w) * detail(l0) + w * detail(l1)
    }

    fn value(&self, q: Quantity, a: Approach, p: [f64; 2]) -> f64 {
        self.grid(q, a, p)
            + self.line_detail(&self.map.x_lines, true, q, a, p)
            + self.line_detail(&self.map.y_lines, false, q, a, p)
    }

    /// Where the camera really looks minus where it should, um, after a move onto
    /// command `p` (mm) approached from `dir`.
    pub fn camera_error_um(&self, p: [f64; 2], dir: Direction) -> Result<[f64; 2], ModelError> {
        self.inside(p)?;
        Ok([
            self.value(Quantity::Ex, dir.x, p) + self.offset_um[0],
            self.value(Quantity::Ey, dir.y, p) + self.offset_um[1],
        ])
    }

    /// Yaw at `p` relative to the reference, microradians.
    pub fn yaw_urad(&self, p: [f64; 2], dir: Direction) -> Result<f64, ModelError> {
        self.inside(p)?;
        Ok(self.value(Quantity::Yaw, dir.x, p))
    }

    /// The tool point's error, um: the camera's plus the yaw acting on the tool offset.
    pub fn tool_error_um(&self, p: [f64; 2], dir: Direction) -> Result<[f64; 2], ModelError> {
        let e = self.camera_error_um(p, dir)?;
        let theta_urad = self.yaw_urad(p, dir)? - self.reference_yaw_urad;
        let [ox, oy] = self.map.tool_offset_mm;
        // urad x mm = nm: / 1000 for um.
        Ok([
            e[0] - theta_urad * oy / 1000.0,
            e[1] + theta_urad * ox / 1000.0,
        ])
    }

    /// The command that puts the tool on nominal `p` (mm) when approached from `dir`.
    pub fn command_for(&self, p: [f64; 2], dir: Direction) -> Result<[f64; 2], ModelError> {
        self.inside(p)?;
        let mut c = p;
        for _ in 0..8 {
            // Clamp into the map: a point on the edge needs a command just outside it.
            let (lo, hi) = self.extent();
            let at = [c[0].clamp(lo[0], hi[0]), c[1].clamp(lo[1], hi[1])];
            let e = self.tool_error_um(at, dir)?;
            let next = [p[0] - e[0] / 1000.0, p[1] - e[1] / 1000.0];
            let moved = (next[0] - c[0]).hypot(next[1] - c[1]);
            c = next;
            if moved < 1e-7 {
                return Ok(c);
            }
        }
        Err(ModelError::NoInverse { p })
    }
}

#[cfg(test)]
mod tests;

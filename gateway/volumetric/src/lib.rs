//! The 21-error volumetric model of a 3-axis machine (SPEC D).
//!
//! # Frames, signs and reference points
//!
//! - The reference frame R is fixed to the machine frame F, its axes along the nominal
//!   X, Y, Z, its origin where every axis reads 0. Lengths in mm, angles in rad.
//! - A command `(x, y, z)` moves the tool by `+x, +y, +z` relative to the workpiece
//!   (ISO 841): an axis that carries the workpiece (a letter before F in the structure
//!   name) moves its carriage by `-q`, an axis that carries the tool by `+q`.
//! - Each carriage frame coincides with R when every axis reads 0; its HTM relative to the
//!   part it rides on is `translation(±q · u) · exact_error(E_X?, E_Y?, E_Z?, E_A?, E_B?, E_C?)`
//!   with `u` the axis direction (squareness below). The six error motions of an axis are
//!   those of its carriage, expressed in the carriage frame at the carriage origin (the
//!   reference point), ISO 230-1 names: for X: E_XX positioning, E_YX and E_ZX
//!   straightness, E_AX roll, E_BX pitch, E_CX yaw; likewise `E_?Y` and `E_?Z`. All
//!   error motions are zero at position 0 (the instruments are zeroed there).
//! - Squareness: X is the reference direction. Y moves along `rot_z(E_C0Y) · (0, 1, 0)`,
//!   Z along `rot_x(E_A0Z) · rot_y(E_B0Z) · (0, 0, 1)`; to first order Y's direction is
//!   `(-E_C0Y, 1, 0)` and Z's `(E_B0Z, -E_A0Z, 1)`.
//! - Chains, read from the frame outwards: FXYZ: tool on Z on Y on X; XFYZ: workpiece on X,
//!   tool on Z on Y; XYFZ: workpiece on X on Y, tool on Z; XYZF: workpiece on X on Y on Z.
//!   The tool point is at `tool_offset` in the last tool carriage's frame (or R), the
//!   workpiece reference point at `work_offset` in the last workpiece carriage's frame.
//! - The volumetric error at a command `q` is `position((T_work)^-1 · T_tool) - (q +
//!   tool_offset - work_offset)`: where the tool point really is in the workpiece frame,
//!   minus where it should be.
//!
//! # First-order closed form
//!
//! With `ε_i` an axis's rotation vector `(E_A, E_B, E_C)`, `δ_i` its translation vector and
//! `P = Σ_tool q_j e_j + t` the nominal tool point in R:
//!
//! ```text
//! e(q) = Σ_tool i [ δ_i + ε_i × r_i ] − Σ_work k [ δ_k + ε_k × s_k ] + S(q)
//! r_i = Σ_{tool j after i} q_j e_j + t          (arm from carriage i to the tool point)
//! s_k = P + Σ_{work l up to and including k} q_l e_l   (arm from carriage k's origin,
//!                                                        which sits at −Σ q_l e_l)
//! S(q) = (−E_C0Y·y + E_B0Z·z,  −E_A0Z·z,  0)
//! ```
//!
//! Written out for XYFZ with zero offsets (tool on Z; workpiece on X on Y):
//!
//! ```text
//! ex = E_XZ − E_XX − E_XY − z(E_BX + E_BY) + y(E_CX + E_CY) − E_C0Y·y + E_B0Z·z
//! ey = E_YZ − E_YX − E_YY + z(E_AX + E_AY) − x·E_CX − E_A0Z·z
//! ez = E_ZZ − E_ZX − E_ZY − y·E_AX + x·E_BX
//! ```
//!
//! (products of two errors dropped; the test `first_order_matches_exact` checks it against
//! the full HTM product within 0.1 µm.)

pub mod ballbar;
pub mod camera;
mod compensation;
pub mod contributions;
pub mod identify;

use kinematics::{exact_error, position, rigid_inverse, translation, Htm};
use nalgebra::Vector3;
pub use protocol::volumetric::{AxisTable, Structure, VolumetricFile};

/// The 21 errors' ISO 230-1 names, in the order [`Model::terms`] returns them.
pub const NAMES: [&str; 21] = [
    "E_XX", "E_YX", "E_ZX", "E_AX", "E_BX", "E_CX", //
    "E_XY", "E_YY", "E_ZY", "E_AY", "E_BY", "E_CY", //
    "E_XZ", "E_YZ", "E_ZZ", "E_AZ", "E_BZ", "E_CZ", //
    "E_C0Y", "E_B0Z", "E_A0Z",
];

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum VolError {
    #[error("axis {axis} at {position_mm} mm is outside the measured travel {min_mm}..{max_mm} mm (no extrapolation)")]
    OutsideTravel {
        axis: char,
        position_mm: f64,
        min_mm: f64,
        max_mm: f64,
    },
    #[error("the inverse did not converge at ({0}, {1}, {2}) mm")]
    NoConvergence(f64, f64, f64),
    #[error("axis {axis} table: {message}")]
    BadTable { axis: char, message: String },
}

/// The model: error tables of X, Y, Z, squareness, structure and offsets.
#[derive(Debug, Clone, PartialEq)]
pub struct Model {
    pub file: VolumetricFile,
}

const AXES: [char; 3] = ['X', 'Y', 'Z'];

fn unit(a: usize) -> Vector3<f64> {
    let mut v = Vector3::zeros();
    v[a] = 1.0;
    v
}

impl Model {
    /// Checks the tables (>= 2 rows, strictly increasing finite positions, finite values).
    pub fn new(file: VolumetricFile) -> Result<Model, VolError> {
        for (a, t) in file.tables.iter().enumerate() {
            let bad = |m: &str| VolError::BadTable {
                axis: AXES[a],
                message: m.to_string(),
            };
            if t.positions_mm.len() < 2 || t.positions_mm.len() != t.errors.len() {
                return Err(bad("needs at least two rows, one error row per position"));
            }
            if t.positions_mm.windows(2).any(|w| !(w[1] > w[0])) {
                return Err(bad("positions must be strictly increasing"));
            }
            if t.positions_mm.iter().any(|p| !p.is_finite())
                || t.errors.iter().flatten().any(|v| !v.is_finite())
            {
                return Err(bad("values must be finite"));
            }
        }
        Ok(Model { file })
    }

    /// A model with every error zero over the given travels (for tests and examples).
    pub fn zero(structure: Structure, travel_mm: [f64; 3]) -> Model {
        let t = |l: f64| AxisTable {
            positions_mm: vec![0.0, l],
            errors: vec![[0.0; 6]; 2],
        };
        Model {
            file: VolumetricFile {
                structure,
                tool_offset_mm: [0.0; 3],
                work_offset_mm: [0.0; 3],
                squareness_rad: [0.0; 3],
                fit: true,
                tables: [t(travel_mm[0]), t(travel_mm[1]), t(travel_mm[2])],
            },
        }
    }

    /// The measured travel of each axis, mm.
    pub fn travel(&self) -> [(f64, f64); 3] {
        std::array::from_fn(|a| {
            let p = &self.file.tables[a].positions_mm;
            (p[0], p[p.len() - 1])
        })
    }

    /// The six error motions of axis `a` at `q` (linear interpolation; refused outside).
    pub fn axis_errors(&self, a: usize, q: f64) -> Result<[f64; 6], VolError> {
        let t = &self.file.tables[a];
        let p = &t.positions_mm;
        let (lo, hi) = (p[0], p[p.len() - 1]);
        if !(q >= lo && q <= hi) {
            return Err(VolError::OutsideTravel {
                axis: AXES[a],
                position_mm: q,
                min_mm: lo,
                max_mm: hi,
            });
        }
        let i = p.partition_point(|&x| x <= q).clamp(1, p.len() - 1);
        let w = (q - p[i - 1]) / (p[i] - p[i - 1]);
        let (e0, e1) = (&t.errors[i - 1], &t.errors[i]);
        Ok(std::array::from_fn(|k| e0[k] + w * (e1[k] - e0[k])))
    }

    fn all_errors(&self, q: [f64; 3]) -> Result<[[f64; 6]; 3], VolError> {
        Ok([
            self.axis_errors(0, q[0])?,
            self.axis_errors(1, q[1])?,
            self.axis_errors(2, q[2])?,
        ])
    }

    /// Each axis's true direction (squareness), exactly.
    fn directions(&self) -> [Vector3<f64>; 3] {
        let [c0y, b0z, a0z] = self.file.squareness_rad;
        let y = Vector3::new(-c0y.sin(), c0y.cos(), 0.0);
        let z = Vector3::new(b0z.sin(), -a0z.sin() * b0z.cos(), a0z.cos() * b0z.cos());
        [Vector3::x(), y, z]
    }

    /// `(T_work)^-1 · T_tool` with full HTMs (rigid error transforms), at command `q`.
    pub fn relative_htm(&self, q: [f64; 3]) -> Result<Htm, VolError> {
        let e = self.all_errors(q)?;
        let u = self.directions();
        let s = self.file.structure;
        let carriage = |a: usize, sign: f64| {
            let d = u[a] * (sign * q[a]);
            let v = &e[a];
            translation(d.x, d.y, d.z) * exact_error(v[0], v[1], v[2], v[3], v[4], v[5])
        };
        let mut tool = Htm::identity();
        for &a in s.tool_chain() {
            tool *= carriage(a, 1.0);
        }
        let t = self.file.tool_offset_mm;
        tool *= translation(t[0], t[1], t[2]);
        let mut work = Htm::identity();
        for &a in s.work_chain() {
            work *= carriage(a, -1.0);
        }
        let w = self.file.work_offset_mm;
        work *= translation(w[0], w[1], w[2]);
        Ok(rigid_inverse(&work) * tool)
    }

    fn nominal(&self, q: [f64; 3]) -> Vector3<f64> {
        let t = self.file.tool_offset_mm;
        let w = self.file.work_offset_mm;
        Vector3::new(q[0] + t[0] - w[0], q[1] + t[1] - w[1], q[2] + t[2] - w[2])
    }

    /// The volumetric error at command `q` (mm), from the full HTM product.
    pub fn error_exact(&self, q: [f64; 3]) -> Result<[f64; 3], VolError> {
        let p = position(&self.relative_htm(q)?) - self.nominal(q);
        Ok([p.x, p.y, p.z])
    }

    /// Each of the 21 errors' first-order contribution to the volumetric error at `q`
    /// (mm), in [`NAMES`] order; their sum is [`Model::error_first_order`].
    pub fn terms(&self, q: [f64; 3]) -> Result<[[f64; 3]; 21], VolError> {
        let e = self.all_errors(q)?;
        let s = self.file.structure;
        let t = self.file.tool_offset_mm;
        let t = Vector3::new(t[0], t[1], t[2]);
        let mut out = [[0.0; 3]; 21];
        let mut put = |a: usize, sign: f64, arm: Vector3<f64>| {
            for c in 0..3 {
                let mut v = [0.0; 3];
                v[c] = sign * e[a][c];
                out[a * 6 + c] = v;
                let r = unit(c).cross(&arm) * (sign * e[a][3 + c]);
                out[a * 6 + 3 + c] = [r.x, r.y, r.z];
            }
        };
        let tool = s.tool_chain();
        for (i, &a) in tool.iter().enumerate() {
            let arm = tool[i + 1..].iter().fold(t, |acc, &j| acc + unit(j) * q[j]);
            put(a, 1.0, arm);
        }
        let p = tool.iter().fold(t, |acc, &j| acc + unit(j) * q[j]);
        let mut arm = p;
        for &a in s.work_chain() {
            arm += unit(a) * q[a];
            put(a, -1.0, arm);
        }
        let [c0y, b0z, a0z] = self.file.squareness_rad;
        out[18] = [-c0y * q[1], 0.0, 0.0];
        out[19] = [b0z * q[2], 0.0, 0.0];
        out[20] = [0.0, -a0z * q[2], 0.0];
        Ok(out)
    }

    /// The volumetric error at command `q` (mm), from the first-order closed form: the
    /// sum of [`Model::terms`], computed directly (no per-term vectors).
    pub fn error_first_order(&self, q: [f64; 3]) -> Result<[f64; 3], VolError> {
        let e = self.all_errors(q)?;
        let s = self.file.structure;
        let t = self.file.tool_offset_mm;
        let mut sum = Vector3::zeros();
        let mut add = |a: usize, sign: f64, arm: Vector3<f64>| {
            let v = &e[a];
            let d = Vector3::new(v[0], v[1], v[2]);
            let r = Vector3::new(v[3], v[4], v[5]);
            sum += (d + r.cross(&arm)) * sign;
        };
        let tool = s.tool_chain();
        let mut p = Vector3::new(t[0], t[1], t[2]);
        // Walk the tool chain from the tool inwards so each arm grows by one axis.
        for &a in tool.iter().rev() {
            add(a, 1.0, p);
            p[a] += q[a];
        }
        let mut arm = p;
        for &a in s.work_chain() {
            arm[a] += q[a];
            add(a, -1.0, arm);
        }
        let [c0y, b0z, a0z] = self.file.squareness_rad;
        Ok([sum.x - c0y * q[1] + b0z * q[2], sum.y - a0z * q[2], sum.z])
    }

    /// The volumetric error (mm), exact or first order.
    pub fn error(&self, q: [f64; 3], first_order: bool) -> Result<[f64; 3], VolError> {
        if first_order {
            self.error_first_order(q)
        } else {
            self.error_exact(q)
        }
    }

    /// The command that puts the tool point on the nominal point of `target` (the axis
    /// positions an error-free machine would use): solves `c + e(c) = target` by
    /// fixed-point iteration from `c = target`. Refuses targets and commands outside the
    /// measured travel.
    pub fn command_for(&self, target: [f64; 3]) -> Result<[f64; 3], VolError> {
        self.command_from(target, target)
    }

    /// [`Model::command_for`] from a first guess of the command (a neighbouring one):
    /// iterates on the cheap first-order error until it settles, then takes one step with
    /// the exact error (the map `c -> target - e(c)` contracts by the errors' slope, about
    /// 1e-4, so that step leaves under 1e-9 mm of the exact model's residual).
    pub fn command_from(&self, target: [f64; 3], guess: [f64; 3]) -> Result<[f64; 3], VolError> {
        for (a, (lo, hi)) in self.travel().into_iter().enumerate() {
            if !(target[a] >= lo && target[a] <= hi) {
                return Err(VolError::OutsideTravel {
                    axis: AXES[a],
                    position_mm: target[a],
                    min_mm: lo,
                    max_mm: hi,
                });
            }
        }
        let mut c = guess;
        let mut settled = false;
        for _ in 0..50 {
            let e = self.error_first_order(c)?;
            let next: [f64; 3] = std::array::from_fn(|k| target[k] - e[k]);
            let step = (0..3).map(|k| (next[k] - c[k]).abs()).fold(0.0, f64::max);
            c = next;
            if step < 1e-10 {
                settled = true;
                break;
            }
        }
        if !settled {
            return Err(VolError::NoConvergence(target[0], target[1], target[2]));
        }
        // One exact step moves c by the (second-order) exact-minus-first-order difference,
        // under 0.01 µm; what remains is that times the errors' slope: below 1e-9 mm.
        let e = self.error_exact(c)?;
        c = std::array::from_fn(|k| target[k] - e[k]);
        // The final command must itself be inside the tables.
        self.error_first_order(c)?;
        Ok(c)
    }
}

#[cfg(test)]
mod tests;

//! The kinematic chain of the XYZ machine carrying the A/C table, nominal and with the
//! eight location errors, forward and inverse.

use kinematics::{
    position, rot_x, rot_z, small_angle_error, transform_point, translation, z_direction, Htm,
};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// The machine constants the chain needs (mm). The paper names its constants (d1..d6,
/// Y_AC, tool length) but prints no values; these defaults describe a 340A-style mill
/// with an NCTLT-125-style table and are this project's choice.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MachineConstants {
    /// Where the nominal A axis (parallel to X) crosses the machine's YZ plane: its Y.
    pub a_axis_y_mm: f64,
    /// ... and its Z, in the coordinates of the spindle gauge point.
    pub a_axis_z_mm: f64,
    /// The A-C offset along Y: the nominal C axis is this far from the A axis at A = 0.
    pub ac_offset_y_mm: f64,
    /// The height of the C table face (the workpiece origin) above the A axis at A = 0.
    pub ac_offset_z_mm: f64,
    /// Tool length: the tool tip is this far below the spindle gauge point.
    pub tool_length_mm: f64,
}

impl Default for MachineConstants {
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

impl MachineConstants {
    /// The point where the nominal C axis meets the table face at A = 0, in machine
    /// coordinates (the workpiece origin at A = C = 0).
    pub fn table_origin(&self) -> Vector3<f64> {
        Vector3::new(
            0.0,
            self.a_axis_y_mm + self.ac_offset_y_mm,
            self.a_axis_z_mm + self.ac_offset_z_mm,
        )
    }

    /// The point where the nominal A axis crosses X = 0, in machine coordinates.
    pub fn a_axis_point(&self) -> Vector3<f64> {
        Vector3::new(0.0, self.a_axis_y_mm, self.a_axis_z_mm)
    }

    /// Refuses constants that are not finite numbers.
    pub fn check(&self) -> Result<(), String> {
        let all = [
            ("a_axis_y_mm", self.a_axis_y_mm),
            ("a_axis_z_mm", self.a_axis_z_mm),
            ("ac_offset_y_mm", self.ac_offset_y_mm),
            ("ac_offset_z_mm", self.ac_offset_z_mm),
            ("tool_length_mm", self.tool_length_mm),
        ];
        for (name, v) in all {
            if !v.is_finite() {
                return Err(format!("machine constant {name} is not a finite number"));
            }
            if v.abs() > crate::centres::MAX_COORDINATE_MM {
                return Err(format!(
                    "machine constant {name} = {v} mm is beyond any machine (at most {} mm)",
                    crate::centres::MAX_COORDINATE_MM
                ));
            }
        }
        Ok(())
    }

    /// The constants an errors file records (its `machine` object, which `gateway rotary
    /// identify` and `measure` write): `None` for a file without one (written by hand or
    /// by an older version). A `machine` object that is not five finite constants is an
    /// error naming the field.
    pub fn from_errors_json(text: &str) -> Result<Option<Self>, String> {
        #[derive(Deserialize)]
        struct Stored {
            machine: Option<serde_json::Value>,
        }
        let stored: Stored = serde_json::from_str(text).map_err(|e| e.to_string())?;
        let Some(value) = stored.machine else {
            return Ok(None);
        };
        let k: Self = serde_json::from_value(value).map_err(|e| format!("machine: {e}"))?;
        k.check().map_err(|e| format!("machine: {e}"))?;
        Ok(Some(k))
    }

    /// The constants a rewrite (or the pass-through) uses with errors identified on
    /// `stored` (from [`Self::from_errors_json`]): errors belong to the machine they were
    /// measured on, so `given` (the operator's `--machine`) must agree with `stored`
    /// (within 1 nm) unless `force`; with no `given`, `stored`; with neither, the
    /// built-in constants. A disagreement is refused naming every constant that
    /// differs (the built-in constants on another machine put the tool 37.7 um off).
    pub fn for_errors(
        stored: Option<Self>,
        given: Option<Self>,
        force: bool,
    ) -> Result<Self, String> {
        match (stored, given) {
            (None, None) => Ok(Self::default()),
            (Some(k), None) | (None, Some(k)) => Ok(k),
            (Some(s), Some(g)) => {
                let named = |k: &Self| {
                    [
                        ("a_axis_y_mm", k.a_axis_y_mm),
                        ("a_axis_z_mm", k.a_axis_z_mm),
                        ("ac_offset_y_mm", k.ac_offset_y_mm),
                        ("ac_offset_z_mm", k.ac_offset_z_mm),
                        ("tool_length_mm", k.tool_length_mm),
                    ]
                };
                let differ: Vec<String> = named(&s)
                    .into_iter()
                    .zip(named(&g))
                    .filter(|((_, a), (_, b))| (a - b).abs() > 1e-6)
                    .map(|((name, a), (_, b))| format!("{name} {a} in the errors file, {b} given"))
                    .collect();
                if differ.is_empty() || force {
                    Ok(g)
                } else {
                    Err(format!(
                        "the errors were identified on other machine constants ({}): errors belong to the machine they were measured on (force the given constants to use them anyway)",
                        differ.join(", ")
                    ))
                }
            }
        }
    }
}

/// The eight location errors (ISO 230-7 sense) as the paper names them, in the units of
/// the output JSON: positions in mm, angles in degrees.
///
/// - `delta_XC`, `delta_YC`: where the actual C axis meets the table-face plane, minus
///   the nominal point ([`MachineConstants::table_origin`]), along X and Y, at A = 0.
/// - `alpha_XC`, `alpha_YC`: the actual C axis turned about X and about Y (right hand);
///   its direction is `(alpha_YC, -alpha_XC, 1)` to first order.
/// - `delta_YA`, `delta_ZA`: where the actual A axis crosses X = 0, minus the nominal
///   point ([`MachineConstants::a_axis_point`]), along Y and Z.
/// - `alpha_YA`, `alpha_ZA`: the actual A axis turned about Y and about Z; its direction
///   is `(1, alpha_ZA, -alpha_YA)` to first order.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LocationErrors {
    #[serde(rename = "delta_XC_mm")]
    pub delta_xc_mm: f64,
    #[serde(rename = "delta_YC_mm")]
    pub delta_yc_mm: f64,
    #[serde(rename = "alpha_XC_deg")]
    pub alpha_xc_deg: f64,
    #[serde(rename = "alpha_YC_deg")]
    pub alpha_yc_deg: f64,
    #[serde(rename = "delta_YA_mm")]
    pub delta_ya_mm: f64,
    #[serde(rename = "delta_ZA_mm")]
    pub delta_za_mm: f64,
    #[serde(rename = "alpha_YA_deg")]
    pub alpha_ya_deg: f64,
    #[serde(rename = "alpha_ZA_deg")]
    pub alpha_za_deg: f64,
}

impl LocationErrors {
    /// The values the paper measured on its NCTLT-125 table (SPEC B).
    pub fn paper() -> Self {
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

    /// Reads the errors from JSON text: an object with the eight fields at its top level
    /// (what `gateway rotary identify --json` writes; other fields are ignored), each a
    /// number, checked with [`LocationErrors::check`].
    pub fn from_json(text: &str) -> Result<Self, String> {
        #[derive(Deserialize)]
        struct Fields {
            #[serde(rename = "delta_XC_mm")]
            delta_xc_mm: f64,
            #[serde(rename = "delta_YC_mm")]
            delta_yc_mm: f64,
            #[serde(rename = "alpha_XC_deg")]
            alpha_xc_deg: f64,
            #[serde(rename = "alpha_YC_deg")]
            alpha_yc_deg: f64,
            #[serde(rename = "delta_YA_mm")]
            delta_ya_mm: f64,
            #[serde(rename = "delta_ZA_mm")]
            delta_za_mm: f64,
            #[serde(rename = "alpha_YA_deg")]
            alpha_ya_deg: f64,
            #[serde(rename = "alpha_ZA_deg")]
            alpha_za_deg: f64,
        }
        let f: Fields = serde_json::from_str(text).map_err(|e| e.to_string())?;
        let e = LocationErrors {
            delta_xc_mm: f.delta_xc_mm,
            delta_yc_mm: f.delta_yc_mm,
            alpha_xc_deg: f.alpha_xc_deg,
            alpha_yc_deg: f.alpha_yc_deg,
            delta_ya_mm: f.delta_ya_mm,
            delta_za_mm: f.delta_za_mm,
            alpha_ya_deg: f.alpha_ya_deg,
            alpha_za_deg: f.alpha_za_deg,
        };
        e.check()?;
        Ok(e)
    }

    /// The eight values with their JSON names, in the paper's order.
    pub fn named(&self) -> [(&'static str, f64); 8] {
        [
            ("delta_XC_mm", self.delta_xc_mm),
            ("delta_YC_mm", self.delta_yc_mm),
            ("alpha_XC_deg", self.alpha_xc_deg),
            ("alpha_YC_deg", self.alpha_yc_deg),
            ("delta_YA_mm", self.delta_ya_mm),
            ("delta_ZA_mm", self.delta_za_mm),
            ("alpha_YA_deg", self.alpha_ya_deg),
            ("alpha_ZA_deg", self.alpha_za_deg),
        ]
    }

    /// Refuses values that are not finite or too large for a small-angle model (an
    /// angle past 1 degree or an offset past 5 mm is a set-up mistake, not an error).
    pub fn check(&self) -> Result<(), String> {
        for (name, v) in self.named() {
            let limit = if name.ends_with("_deg") { 1.0 } else { 5.0 };
            if !v.is_finite() || v.abs() > limit {
                return Err(format!(
                    "{name} = {v}: not a location error (|value| must be below {limit})"
                ));
            }
        }
        Ok(())
    }

    /// The C axis error HTM, in the frame of the C axis at the table face.
    pub fn c_axis_htm(&self) -> Htm {
        small_angle_error(
            self.delta_xc_mm,
            self.delta_yc_mm,
            0.0,
            self.alpha_xc_deg.to_radians(),
            self.alpha_yc_deg.to_radians(),
            0.0,
        )
    }

    /// The A axis error HTM, in the frame of the A axis at X = 0.
    pub fn a_axis_htm(&self) -> Htm {
        small_angle_error(
            0.0,
            self.delta_ya_mm,
            self.delta_za_mm,
            0.0,
            self.alpha_ya_deg.to_radians(),
            self.alpha_za_deg.to_radians(),
        )
    }
}

/// A command or programmed position of the five axes: X Y Z of the spindle gauge point
/// in mm (machine coordinates), A and C in degrees.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Axes {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub a: f64,
    pub c: f64,
}

impl Axes {
    pub fn new(x: f64, y: f64, z: f64, a: f64, c: f64) -> Self {
        Self { x, y, z, a, c }
    }
}

/// The tool in the workpiece frame: tip position (mm) and direction (unit vector from
/// the tip up the tool, `(sin A sin C, sin A cos C, cos A)` nominally).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ToolPose {
    pub position: Vector3<f64>,
    pub direction: Vector3<f64>,
}

/// Travel limits of the five axes (mm, degrees), inclusive.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisLimits {
    pub x: [f64; 2],
    pub y: [f64; 2],
    pub z: [f64; 2],
    pub a: [f64; 2],
    pub c: [f64; 2],
}

impl Default for AxisLimits {
    /// A 340A-style mill's travel around the table and the NCTLT-125-style tilt range.
    fn default() -> Self {
        Self {
            x: [-250.0, 250.0],
            y: [-200.0, 200.0],
            z: [-250.0, 0.0],
            a: [-30.0, 110.0],
            c: [-100000.0, 100000.0],
        }
    }
}

impl AxisLimits {
    /// The first axis outside its limits, named.
    pub fn check(&self, cmd: &Axes) -> Result<(), RotaryError> {
        let axes = [
            ('X', cmd.x, self.x),
            ('Y', cmd.y, self.y),
            ('Z', cmd.z, self.z),
            ('A', cmd.a, self.a),
            ('C', cmd.c, self.c),
        ];
        for (axis, v, [lo, hi]) in axes {
            if !v.is_finite() {
                return Err(RotaryError::NotFinite { axis });
            }
            if v < lo || v > hi {
                return Err(RotaryError::OutOfLimits {
                    axis,
                    value: v,
                    min: lo,
                    max: hi,
                });
            }
        }
        Ok(())
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RotaryError {
    #[error("axis {axis}: {value:.4} is outside its limits [{min}, {max}]")]
    OutOfLimits {
        axis: char,
        value: f64,
        min: f64,
        max: f64,
    },
    #[error("axis {axis}: not a finite number")]
    NotFinite { axis: char },
    #[error("the corrected rotary axes did not converge (direction still {residual:e} off)")]
    NoConvergence { residual: f64 },
    #[error("{0}")]
    Invalid(String),
}

/// The machine: constants, location errors (zero for the nominal machine) and limits.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RotaryMachine {
    pub constants: MachineConstants,
    pub errors: LocationErrors,
    pub limits: AxisLimits,
}

/// Below this |sin A| (A within 0.57° of 0 or 180°) the tool direction hardly tells C
/// (the tool is nearly along the C axis) and correcting a tilt error through C would
/// swing the table round; the inverse keeps the programmed C there and corrects A only.
const C_SINGULAR_SIN_A: f64 = 0.01;

impl RotaryMachine {
    /// The nominal machine (no location errors).
    pub fn nominal(constants: MachineConstants) -> Self {
        Self {
            constants,
            ..Self::default()
        }
    }

    pub fn with_errors(constants: MachineConstants, errors: LocationErrors) -> Self {
        Self {
            constants,
            errors,
            ..Self::default()
        }
    }

    /// `rT_w`: the workpiece frame (origin on the C axis at the table face) in the
    /// reference (machine) frame, at rotary positions `a_deg`, `c_deg`.
    ///
    /// `T(A axis point) · E_A Rx(A) E_A⁻¹ · T(A-C offset) · E_C Rz(C) E_C⁻¹`: each axis
    /// turns the body it carries about its actual line (the error HTM moves and tilts the
    /// axis, the rotation happens there, and the inverse brings the body back to where
    /// it is mounted at angle 0: zero-angle errors are neglected, as in the paper).
    pub fn table(&self, a_deg: f64, c_deg: f64) -> Htm {
        let k = &self.constants;
        let ea = self.errors.a_axis_htm();
        let ec = self.errors.c_axis_htm();
        let ea_inv = ea.try_inverse().unwrap_or_else(Htm::identity);
        let ec_inv = ec.try_inverse().unwrap_or_else(Htm::identity);
        translation(0.0, k.a_axis_y_mm, k.a_axis_z_mm)
            * ea
            * rot_x(a_deg.to_radians())
            * ea_inv
            * translation(0.0, k.ac_offset_y_mm, k.ac_offset_z_mm)
            * ec
            * rot_z(c_deg.to_radians())
            * ec_inv
    }

    /// `rT_t`: the tool tip frame in the machine frame. The three linear axes are taken
    /// on the tool side: what matters is the tool relative to the table, and a table
    /// moving -X is the tool moving +X (ISO 841).
    pub fn tool(&self, x: f64, y: f64, z: f64) -> Htm {
        translation(x, y, z - self.constants.tool_length_mm)
    }

    /// Forward kinematics: `wT_t = (rT_w)⁻¹ rT_t`, the tool in the workpiece frame.
    pub fn forward(&self, cmd: &Axes) -> ToolPose {
        let rtw = self.table(cmd.a, cmd.c);
        let wtr = rtw.try_inverse().unwrap_or_else(Htm::identity);
        let wtt = wtr * self.tool(cmd.x, cmd.y, cmd.z);
        let d = z_direction(&wtt);
        ToolPose {
            position: position(&wtt),
            direction: d / d.norm(),
        }
    }

    /// The tool direction only (in the workpiece frame) at rotary positions A, C.
    fn direction_at(&self, a_deg: f64, c_deg: f64) -> Vector3<f64> {
        let rtw = self.table(a_deg, c_deg);
        let r = rtw.fixed_view::<3, 3>(0, 0).into_owned();
        let inv = r.try_inverse().unwrap_or_else(nalgebra::Matrix3::identity);
        let d = inv * Vector3::z();
        d / d.norm()
    }

    /// Inverse kinematics: the command giving the tool `pose` in the workpiece frame,
    /// rotary axes starting from `near` (A, C in degrees: the programmed ones).
    ///
    /// Rotary axes first, from the direction alone, by the paper's correction applied
    /// until it converges: `A += acos(k) - acos(k')`, `C += atan2(i, j) - atan2(i', j')`
    /// with (i, j, k) the wanted and (i', j', k') the actual direction. Where the tool
    /// is nearly along the C axis (|sin A| below 0.01) C is kept as given and A alone
    /// brings the direction as close as it can. Then X, Y, Z exactly:
    /// the tip must be at `rT_w · p_w`, and the gauge point is the tool length above it.
    pub fn inverse(&self, pose: &ToolPose, near: (f64, f64)) -> Result<Axes, RotaryError> {
        let want = pose.direction / pose.direction.norm();
        let (mut a, mut c) = near;
        let want_a = want.z.clamp(-1.0, 1.0).acos().to_degrees();
        let use_c = want_a.to_radians().sin().abs() > C_SINGULAR_SIN_A;
        let mut residual = f64::INFINITY;
        for _ in 0..50 {
            let got = self.direction_at(a, c);
            residual = (got - want).norm();
            if residual < 1e-13 {
                break;
            }
            if use_c {
                let got_a = got.z.clamp(-1.0, 1.0).acos().to_degrees();
                // The near command may be the negative-A twin of the wanted direction:
                // acos only gives A >= 0, so compare like with like.
                let sign = if a < 0.0 { -1.0 } else { 1.0 };
                a += sign * (want_a - got_a);
                let got_c = (sign * got.x).atan2(sign * got.y).to_degrees();
                let wc = (sign * want.x).atan2(sign * want.y).to_degrees();
                c += wrap_deg(wc - got_c);
            } else {
                // C keeps its value; A alone brings the direction as close as it can
                // (one-dimensional Gauss-Newton).
                let h = 1e-6;
                let da = (self.direction_at(a + h, c) - self.direction_at(a - h, c)) / (2.0 * h);
                let step = -(got - want).dot(&da) / da.norm_squared();
                a += step;
                if step.abs() < 1e-12 {
                    break;
                }
            }
        }
        if !(residual < 1e-9) && use_c {
            return Err(RotaryError::NoConvergence { residual });
        }
        let tip = transform_point(&self.table(a, c), &pose.position);
        Ok(Axes {
            x: tip.x,
            y: tip.y,
            z: tip.z + self.constants.tool_length_mm,
            a,
            c,
        })
    }

    /// The command that puts the tool of this (erroneous) machine where the nominal
    /// machine would put it for `nominal`: same tip point, same direction, in the
    /// workpiece frame. Refuses a command past the axis limits, naming the axis.
    pub fn command_for(&self, nominal: &Axes) -> Result<Axes, RotaryError> {
        self.limits.check(nominal)?;
        let ideal = RotaryMachine::nominal(self.constants).forward(nominal);
        let cmd = self.inverse(&ideal, (nominal.a, nominal.c))?;
        self.limits.check(&cmd)?;
        Ok(cmd)
    }
}

/// An angle difference brought into (-180, 180] degrees.
pub fn wrap_deg(d: f64) -> f64 {
    let r = d.rem_euclid(360.0);
    if r > 180.0 {
        r - 360.0
    } else {
        r
    }
}

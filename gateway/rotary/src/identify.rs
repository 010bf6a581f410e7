//! Identification of the eight location errors from measured ball centres: sphere fits
//! (probe points -> centres), circle fits in 3D (centres of one ball over one axis's
//! sweep), the actual axis lines, and the errors with their standard uncertainty.

use crate::centres::{Axis, CentreRow, MAX_COORDINATE_MM};
use crate::machine::{LocationErrors, MachineConstants, RotaryMachine};
use nalgebra::{DMatrix, DVector, Matrix3, SymmetricEigen, Vector3};
use serde::Serialize;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FitError {
    #[error("{what}: {n} points, at least {min} needed")]
    TooFewPoints { what: String, n: usize, min: usize },
    #[error("{what}: the points are degenerate ({why})")]
    Degenerate { what: String, why: String },
    #[error("{what}: fitted radius {radius:.4} mm is off the certified {certified:.4} mm by more than {tolerance} mm")]
    RadiusOff {
        what: String,
        radius: f64,
        certified: f64,
        tolerance: f64,
    },
    #[error("{what}: fit residual {rms_um:.3} um (RMS) is above the limit {limit_um} um")]
    ResidualOff {
        what: String,
        rms_um: f64,
        limit_um: f64,
    },
}

fn check_points(what: &str, points: &[Vector3<f64>]) -> Result<(), FitError> {
    for (k, p) in points.iter().enumerate() {
        if !p
            .iter()
            .all(|v| v.is_finite() && v.abs() <= MAX_COORDINATE_MM)
        {
            return Err(FitError::Degenerate {
                what: what.into(),
                why: format!(
                    "point {} ({}, {}, {}) is not within {MAX_COORDINATE_MM} mm of the origin on each axis",
                    k + 1,
                    p.x,
                    p.y,
                    p.z
                ),
            });
        }
    }
    Ok(())
}

/// A least-squares sphere: the centre and radius minimising the sum of squared
/// distances of the points from the surface (radius free).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SphereFit {
    pub centre: [f64; 3],
    pub radius_mm: f64,
    /// Root mean square of the points' distances from the fitted surface.
    pub rms_mm: f64,
    pub points: usize,
}

/// Fits a sphere to at least 4 points that are not on one plane: the algebraic
/// (linear) solution first, then Gauss-Newton on the geometric distances.
pub fn fit_sphere(what: &str, points: &[Vector3<f64>]) -> Result<SphereFit, FitError> {
    if points.len() < 4 {
        return Err(FitError::TooFewPoints {
            what: what.into(),
            n: points.len(),
            min: 4,
        });
    }
    check_points(what, points)?;
    let mean = points.iter().sum::<Vector3<f64>>() / points.len() as f64;
    // |p|² = 2 p·c + (r² - |c|²), points taken about their mean for conditioning.
    let a = DMatrix::from_fn(points.len(), 4, |i, j| {
        let q = points[i] - mean;
        if j < 3 {
            2.0 * q[j]
        } else {
            1.0
        }
    });
    let b = DVector::from_fn(points.len(), |i, _| (points[i] - mean).norm_squared());
    let svd = a.svd(true, true);
    let smallest = svd.singular_values.min();
    let largest = svd.singular_values.max();
    if !(smallest > 1e-9 * largest) {
        return Err(FitError::Degenerate {
            what: what.into(),
            why: "all on one plane or circle".into(),
        });
    }
    let sol = svd.solve(&b, 1e-12).map_err(|e| FitError::Degenerate {
        what: what.into(),
        why: e.into(),
    })?;
    let mut c = Vector3::new(sol[0], sol[1], sol[2]);
    let mut r = (sol[3] + c.norm_squared()).max(0.0).sqrt();
    for _ in 0..20 {
        // Residual d_i = |q_i - c| - r; Jacobian rows [-(q_i - c)/|q_i - c|, -1].
        let mut jtj = nalgebra::Matrix4::<f64>::zeros();
        let mut jtr = nalgebra::Vector4::<f64>::zeros();
        for p in points {
            let v = p - mean - c;
            let n = v.norm();
            if n == 0.0 {
                continue;
            }
            let row = nalgebra::Vector4::new(-v.x / n, -v.y / n, -v.z / n, -1.0);
            jtj += row * row.transpose();
            jtr += row * (n - r);
        }
        let Some(step) = jtj.lu().solve(&(-jtr)) else {
            break;
        };
        c += Vector3::new(step[0], step[1], step[2]);
        r += step[3];
        if step.norm() < 1e-13 {
            break;
        }
    }
    let ss: f64 = points
        .iter()
        .map(|p| ((p - mean - c).norm() - r).powi(2))
        .sum();
    let centre = c + mean;
    Ok(SphereFit {
        centre: [centre.x, centre.y, centre.z],
        radius_mm: r,
        rms_mm: (ss / points.len() as f64).sqrt(),
        points: points.len(),
    })
}

/// The certificate check of a sphere fit: radius within `radius_tol_mm` of the
/// certified one and RMS residual at most `residual_limit_mm`; a fit that fails is not
/// to be used (a dirty ball, a false trigger, the wrong ball).
pub fn check_sphere(
    what: &str,
    fit: &SphereFit,
    certified_radius_mm: f64,
    radius_tol_mm: f64,
    residual_limit_mm: f64,
) -> Result<(), FitError> {
    if !((fit.radius_mm - certified_radius_mm).abs() <= radius_tol_mm) {
        return Err(FitError::RadiusOff {
            what: what.into(),
            radius: fit.radius_mm,
            certified: certified_radius_mm,
            tolerance: radius_tol_mm,
        });
    }
    if !(fit.rms_mm <= residual_limit_mm) {
        return Err(FitError::ResidualOff {
            what: what.into(),
            rms_um: fit.rms_mm * 1e3,
            limit_um: residual_limit_mm * 1e3,
        });
    }
    Ok(())
}

/// A circle in space fitted to points: centre, unit normal of its plane, radius, and the
/// covariance of the parameters (centre x y z, two tilts of the normal, radius).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CircleFit {
    pub centre: [f64; 3],
    pub normal: [f64; 3],
    pub radius_mm: f64,
    /// RMS distance of the points from the circle's plane.
    pub rms_plane_mm: f64,
    /// RMS of the in-plane distance from the circle.
    pub rms_radial_mm: f64,
    pub points: usize,
    #[serde(skip)]
    pub covariance: nalgebra::Matrix6<f64>,
    /// The two directions the normal's tilts in `covariance` are taken along.
    #[serde(skip)]
    pub tilt_basis: [Vector3<f64>; 2],
}

impl CircleFit {
    pub fn centre_v(&self) -> Vector3<f64> {
        Vector3::from(self.centre)
    }
    pub fn normal_v(&self) -> Vector3<f64> {
        Vector3::from(self.normal)
    }
}

fn perpendicular_basis(n: &Vector3<f64>) -> [Vector3<f64>; 2] {
    let helper = if n.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let e1 = n.cross(&helper).normalize();
    let e2 = n.cross(&e1);
    [e1, e2]
}

/// Residuals of points against a circle: per point the distance from the plane and the
/// in-plane distance from the circle.
fn circle_residuals(
    points: &[Vector3<f64>],
    c: &Vector3<f64>,
    n: &Vector3<f64>,
    r: f64,
) -> DVector<f64> {
    let mut res = DVector::zeros(2 * points.len());
    for (i, p) in points.iter().enumerate() {
        let v = p - c;
        let h = v.dot(n);
        res[2 * i] = h;
        res[2 * i + 1] = (v - n * h).norm() - r;
    }
    res
}

fn circle_params(
    theta: &[f64; 6],
    base_n: &Vector3<f64>,
    basis: &[Vector3<f64>; 2],
) -> (Vector3<f64>, Vector3<f64>, f64) {
    let c = Vector3::new(theta[0], theta[1], theta[2]);
    let n = (base_n + basis[0] * theta[3] + basis[1] * theta[4]).normalize();
    (c, n, theta[5])
}

/// Fits a circle in space to at least 4 points (the centres of one ball over a sweep):
/// the plane by principal components, an algebraic circle in it, then Gauss-Newton on
/// the geometric residuals (out of plane, in plane). The covariance is
/// `s² (JᵀJ)⁻¹` with `s²` the residual sum of squares over its degrees of freedom.
pub fn fit_circle(what: &str, points: &[Vector3<f64>]) -> Result<CircleFit, FitError> {
    let n_pts = points.len();
    if n_pts < 4 {
        return Err(FitError::TooFewPoints {
            what: what.into(),
            n: n_pts,
            min: 4,
        });
    }
    check_points(what, points)?;
    let mean = points.iter().sum::<Vector3<f64>>() / n_pts as f64;
    let mut scatter = Matrix3::zeros();
    for p in points {
        let q = p - mean;
        scatter += q * q.transpose();
    }
    let eig = SymmetricEigen::new(scatter);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
    let spread = eig.eigenvalues[order[1]];
    if !(spread > 1e-12 * eig.eigenvalues[order[2]].max(1e-300)) || !(spread > 1e-16) {
        return Err(FitError::Degenerate {
            what: what.into(),
            why: "the points lie on a line".into(),
        });
    }
    let normal = eig.eigenvectors.column(order[0]).into_owned().normalize();
    let [u, v] = perpendicular_basis(&normal);
    // Algebraic circle in the plane: u² + v² = 2 a u + 2 b v + k.
    let a = DMatrix::from_fn(n_pts, 3, |i, j| {
        let q = points[i] - mean;
        match j {
            0 => 2.0 * q.dot(&u),
            1 => 2.0 * q.dot(&v),
            _ => 1.0,
        }
    });
    let b = DVector::from_fn(n_pts, |i, _| {
        let q = points[i] - mean;
        q.dot(&u).powi(2) + q.dot(&v).powi(2)
    });
    let sol = a
        .svd(true, true)
        .solve(&b, 1e-12)
        .map_err(|e| FitError::Degenerate {
            what: what.into(),
            why: e.into(),
        })?;
    let mut c = mean + u * sol[0] + v * sol[1];
    let mut r = (sol[2] + sol[0] * sol[0] + sol[1] * sol[1]).max(0.0).sqrt();
    let mut n = normal;
    let jacobian = |c: &Vector3<f64>, n: &Vector3<f64>, r: f64, basis: &[Vector3<f64>; 2]| {
        let theta0 = [c.x, c.y, c.z, 0.0, 0.0, r];
        let scale = c.norm().max(r).max(1.0);
        let mut j = DMatrix::zeros(2 * n_pts, 6);
        for k in 0..6 {
            let h = if k == 3 || k == 4 { 1e-7 } else { 1e-7 * scale };
            let mut tp = theta0;
            let mut tm = theta0;
            tp[k] += h;
            tm[k] -= h;
            let (cp, np, rp) = circle_params(&tp, n, basis);
            let (cm, nm, rm) = circle_params(&tm, n, basis);
            let d = (circle_residuals(points, &cp, &np, rp)
                - circle_residuals(points, &cm, &nm, rm))
                / (2.0 * h);
            j.set_column(k, &d);
        }
        j
    };
    for _ in 0..30 {
        let basis = perpendicular_basis(&n);
        let res = circle_residuals(points, &c, &n, r);
        let j = jacobian(&c, &n, r, &basis);
        let Some(step) = (j.transpose() * &j).lu().solve(&(-(j.transpose() * res))) else {
            break;
        };
        let theta = [
            c.x + step[0],
            c.y + step[1],
            c.z + step[2],
            step[3],
            step[4],
            r + step[5],
        ];
        let (c2, n2, r2) = circle_params(&theta, &n, &basis);
        c = c2;
        n = n2;
        r = r2;
        if step.norm() < 1e-12 * r.max(1.0) {
            break;
        }
    }
    let basis = perpendicular_basis(&n);
    let res = circle_residuals(points, &c, &n, r);
    let j = jacobian(&c, &n, r, &basis);
    let dof = (2 * n_pts).saturating_sub(6).max(1) as f64;
    let s2 = res.norm_squared() / dof;
    let jtj = j.transpose() * &j;
    let inv = jtj.try_inverse().ok_or_else(|| FitError::Degenerate {
        what: what.into(),
        why: "the circle's parameters are not determined".into(),
    })?;
    let covariance = nalgebra::Matrix6::from_fn(|i, k| inv[(i, k)] * s2);
    let plane_ss: f64 = (0..n_pts).map(|i| res[2 * i].powi(2)).sum();
    let radial_ss: f64 = (0..n_pts).map(|i| res[2 * i + 1].powi(2)).sum();
    Ok(CircleFit {
        centre: [c.x, c.y, c.z],
        normal: [n.x, n.y, n.z],
        radius_mm: r,
        rms_plane_mm: (plane_ss / n_pts as f64).sqrt(),
        rms_radial_mm: (radial_ss / n_pts as f64).sqrt(),
        points: n_pts,
        covariance,
        tilt_basis: basis,
    })
}

/// One axis's identified line.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct AxisLine {
    /// A point of the line: the mean of the two balls' circle centres.
    pub point: [f64; 3],
    /// Its direction: the mean of the two circles' normals (oriented +Z for C, +X for A).
    pub direction: [f64; 3],
    /// The angle between that direction and the line through the two circle centres
    /// (degrees): a consistency check, see [`identify`].
    pub centre_line_deviation_deg: f64,
    /// How far apart the two circle centres are (mm).
    pub centre_separation_mm: f64,
}

/// The result of an identification.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Identification {
    /// The identified errors (see [`identify`]: the joint fit, or the circles' estimate
    /// when it fails).
    pub errors: LocationErrors,
    /// Their standard uncertainties (k = 1).
    pub uncertainty: LocationErrors,
    /// The paper's estimate: from the circles and axis lines alone.
    pub circle_errors: LocationErrors,
    /// Its standard uncertainties (k = 1), the circle fits' covariances carried through.
    pub circle_uncertainty: LocationErrors,
    /// The joint fit's estimate of all eight, and its uncertainties (NaN if it failed).
    pub joint_errors: LocationErrors,
    pub joint_uncertainty: LocationErrors,
    /// RMS of the joint fit's residuals over every centre coordinate (mm).
    pub refined_rms_mm: f64,
    /// The balls' centres in the workpiece frame, from the refined fit (mm).
    pub ball_centres_mm: [[f64; 3]; 2],
    /// Circle fits: C ball 1, C ball 2, A ball 1, A ball 2.
    pub circles: Vec<(Axis, u8, CircleFit)>,
    pub c_axis: AxisLine,
    pub a_axis: AxisLine,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum IdentifyError {
    #[error("no centres of ball {ball} on axis {axis}")]
    Missing { axis: Axis, ball: u8 },
    #[error(transparent)]
    Fit(#[from] FitError),
}

fn oriented(n: Vector3<f64>, towards: &Vector3<f64>) -> Vector3<f64> {
    if n.dot(towards) < 0.0 {
        -n
    } else {
        n
    }
}

/// The eight errors from the four circles (C ball 1, C ball 2, A ball 1, A ball 2),
/// each given as centre and normal.
fn errors_from_circles(
    circles: &[(Vector3<f64>, Vector3<f64>); 4],
    k: &MachineConstants,
) -> (LocationErrors, AxisLine, AxisLine) {
    let line = |a: &(Vector3<f64>, Vector3<f64>),
                b: &(Vector3<f64>, Vector3<f64>),
                towards: Vector3<f64>| {
        let point = (a.0 + b.0) / 2.0;
        let dir = (oriented(a.1, &towards) + oriented(b.1, &towards)).normalize();
        let sep = b.0 - a.0;
        let deviation = if sep.norm() > 0.0 {
            oriented(sep.normalize(), &towards)
                .dot(&dir)
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees()
        } else {
            0.0
        };
        AxisLine {
            point: point.into(),
            direction: dir.into(),
            centre_line_deviation_deg: deviation,
            centre_separation_mm: sep.norm(),
        }
    };
    let c_line = line(&circles[0], &circles[1], Vector3::z());
    let a_line = line(&circles[2], &circles[3], Vector3::x());
    let origin = k.table_origin();
    let (cp, cu) = (Vector3::from(c_line.point), Vector3::from(c_line.direction));
    let at_face = cp + cu * ((origin.z - cp.z) / cu.z);
    let a0 = k.a_axis_point();
    let (ap, au) = (Vector3::from(a_line.point), Vector3::from(a_line.direction));
    let at_x0 = ap + au * ((a0.x - ap.x) / au.x);
    let errors = LocationErrors {
        delta_xc_mm: at_face.x - origin.x,
        delta_yc_mm: at_face.y - origin.y,
        alpha_xc_deg: (-cu.y).atan2(cu.z).to_degrees(),
        alpha_yc_deg: cu.x.atan2(cu.z).to_degrees(),
        delta_ya_mm: at_x0.y - a0.y,
        delta_za_mm: at_x0.z - a0.z,
        alpha_ya_deg: (-au.z).atan2(au.x).to_degrees(),
        alpha_za_deg: au.y.atan2(au.x).to_degrees(),
    };
    (errors, c_line, a_line)
}

/// Identifies the eight location errors from ball centres measured at A = 0 over the C
/// sweep and at C = 0 over the A sweep (machine coordinates, mm).
///
/// Per axis and ball a circle is fitted to the centres; both balls' circles have their
/// centres on the actual axis, and their normals along it. The axis line is taken
/// through the mean of the two circle centres, with the mean of the two normals as its
/// direction. The paper takes the direction of the line through the two centres; on a
/// plate the balls' C circles are only the difference of their heights apart (15 mm
/// here), which turns a 0.1 um centre noise into 0.0004 degrees, while each circle's
/// normal rests on its full radius; the angle between the two is reported
/// ([`AxisLine::centre_line_deviation_deg`]) as a check.
///
/// C errors: where the line meets the table-face plane (`z = table_origin.z`) minus the
/// nominal point, and its tilts `alpha_XC = atan2(-u_y, u_z)`, `alpha_YC = atan2(u_x,
/// u_z)`. A errors: where the line crosses X = 0 minus the nominal A axis point, and
/// `alpha_YA = atan2(-u_z, u_x)`, `alpha_ZA = atan2(u_y, u_x)`. Uncertainties: the
/// circles' parameter covariances carried through these formulas (numerical Jacobian).
/// This is the paper's estimate ([`Identification::circle_errors`]).
///
/// Then the whole chain is fitted to every centre at once, starting from it: the eight
/// errors and the balls' positions on the table (14 unknowns) by Gauss-Newton on the
/// centres' coordinates, each row at its own `angle_deg`, uncertainties from its
/// covariance `s² (JᵀJ)⁻¹`. The circles of the A sweep span only 90°, so their centres
/// (and with them `delta_YA`, `delta_ZA`) are several times noisier than the points;
/// the joint fit knows where the balls sit on the table from the C sweep. On the
/// simulated probing cycle (0.3 um trigger noise, 40 seeds) the largest deviations
/// were, circles: `delta_ZA` 1.3 um, angles 0.00048°; joint fit: positions 0.41 um,
/// angles 0.00023°. So [`Identification::errors`] is the joint fit's estimate; the
/// circles' (the paper's method) is kept beside it, and stands alone if the joint fit
/// fails (too few rows, no convergence).
pub fn identify(
    rows: &[CentreRow],
    constants: &MachineConstants,
) -> Result<Identification, IdentifyError> {
    let mut fits = Vec::new();
    for axis in [Axis::C, Axis::A] {
        for ball in [1u8, 2] {
            let pts: Vec<Vector3<f64>> = rows
                .iter()
                .filter(|r| r.axis == axis && r.ball == ball)
                .map(|r| Vector3::new(r.x_mm, r.y_mm, r.z_mm))
                .collect();
            if pts.is_empty() {
                return Err(IdentifyError::Missing { axis, ball });
            }
            let fit = fit_circle(&format!("axis {axis} ball {ball}"), &pts)?;
            fits.push((axis, ball, fit));
        }
    }
    let as_pairs = |theta: &DVector<f64>| -> [(Vector3<f64>, Vector3<f64>); 4] {
        std::array::from_fn(|i| {
            let f = &fits[i].2;
            let o = 6 * i;
            let c = Vector3::new(theta[o], theta[o + 1], theta[o + 2]);
            let n =
                (f.normal_v() + f.tilt_basis[0] * theta[o + 3] + f.tilt_basis[1] * theta[o + 4])
                    .normalize();
            (c, n)
        })
    };
    let mut theta = DVector::zeros(24);
    for (i, (_, _, f)) in fits.iter().enumerate() {
        for k in 0..3 {
            theta[6 * i + k] = f.centre[k];
        }
        theta[6 * i + 5] = f.radius_mm;
    }
    let (errors, c_axis, a_axis) = errors_from_circles(&as_pairs(&theta), constants);
    let values = |e: &LocationErrors| e.named().map(|(_, v)| v);
    let mut var = [0.0; 8];
    for (i, (_, _, f)) in fits.iter().enumerate() {
        // Jacobian of the eight errors by this circle's six parameters.
        let mut jac = nalgebra::SMatrix::<f64, 8, 6>::zeros();
        for k in 0..6 {
            let h = if k == 3 || k == 4 { 1e-7 } else { 1e-5 };
            let mut tp = theta.clone();
            let mut tm = theta.clone();
            tp[6 * i + k] += h;
            tm[6 * i + k] -= h;
            let ep = values(&errors_from_circles(&as_pairs(&tp), constants).0);
            let em = values(&errors_from_circles(&as_pairs(&tm), constants).0);
            for e in 0..8 {
                jac[(e, k)] = (ep[e] - em[e]) / (2.0 * h);
            }
        }
        let cov = jac * f.covariance * jac.transpose();
        for e in 0..8 {
            var[e] += cov[(e, e)].max(0.0);
        }
    }
    let u = var.map(f64::sqrt);
    let uncertainty = LocationErrors {
        delta_xc_mm: u[0],
        delta_yc_mm: u[1],
        alpha_xc_deg: u[2],
        alpha_yc_deg: u[3],
        delta_ya_mm: u[4],
        delta_za_mm: u[5],
        alpha_ya_deg: u[6],
        alpha_za_deg: u[7],
    };
    let refined = refine(rows, constants, &errors);
    let nan = LocationErrors {
        delta_xc_mm: f64::NAN,
        delta_yc_mm: f64::NAN,
        alpha_xc_deg: f64::NAN,
        alpha_yc_deg: f64::NAN,
        delta_ya_mm: f64::NAN,
        delta_za_mm: f64::NAN,
        alpha_ya_deg: f64::NAN,
        alpha_za_deg: f64::NAN,
    };
    let (joint_errors, joint_uncertainty) = match &refined {
        Some((e, u, _, _)) => (*e, *u),
        None => (nan, nan),
    };
    let (final_errors, final_u, rms, balls) = match refined {
        Some(joint) => joint,
        None => (errors, uncertainty, f64::NAN, [[f64::NAN; 3]; 2]),
    };
    Ok(Identification {
        errors: final_errors,
        uncertainty: final_u,
        circle_errors: errors,
        circle_uncertainty: uncertainty,
        joint_errors,
        joint_uncertainty,
        refined_rms_mm: rms,
        ball_centres_mm: balls,
        circles: fits,
        c_axis,
        a_axis,
    })
}

fn errors_from_slice(v: &[f64]) -> LocationErrors {
    LocationErrors {
        delta_xc_mm: v[0],
        delta_yc_mm: v[1],
        alpha_xc_deg: v[2],
        alpha_yc_deg: v[3],
        delta_ya_mm: v[4],
        delta_za_mm: v[5],
        alpha_ya_deg: v[6],
        alpha_za_deg: v[7],
    }
}

/// Where each centre row should be for parameters `theta` (8 errors, then the two balls'
/// centres in the workpiece frame).
pub(crate) fn predicted(
    rows: &[CentreRow],
    constants: &MachineConstants,
    theta: &[f64],
) -> DVector<f64> {
    let m = RotaryMachine::with_errors(*constants, errors_from_slice(&theta[..8]));
    let mut out = DVector::zeros(3 * rows.len());
    for (i, r) in rows.iter().enumerate() {
        let (a, c) = match r.axis {
            Axis::C => (0.0, r.angle_deg),
            Axis::A => (r.angle_deg, 0.0),
        };
        let o = 8 + 3 * (r.ball as usize - 1);
        let b = Vector3::new(theta[o], theta[o + 1], theta[o + 2]);
        let p = kinematics::transform_point(&m.table(a, c), &b);
        out[3 * i] = p.x;
        out[3 * i + 1] = p.y;
        out[3 * i + 2] = p.z;
    }
    out
}

/// The whole chain fitted to every centre at once (Gauss-Newton from the circles'
/// estimate): the eight errors and the two balls' positions on the table, 14 unknowns.
/// Both sweeps then share what they have in common (the balls sit where the C sweep
/// saw them when the A sweep turns them), which the separate circles ignore: a 90°
/// arc leaves a circle's centre several times noisier than its points.
fn refine(
    rows: &[CentreRow],
    constants: &MachineConstants,
    start: &LocationErrors,
) -> Option<(LocationErrors, LocationErrors, f64, [[f64; 3]; 2])> {
    let n = rows.len();
    if 3 * n <= 14 {
        return None;
    }
    let mut theta: Vec<f64> = start.named().iter().map(|(_, v)| *v).collect();
    // First guess of each ball: its measured centres brought back into the workpiece
    // frame with the first guess of the errors, averaged.
    let m = RotaryMachine::with_errors(*constants, *start);
    for ball in [1u8, 2] {
        let mut sum = Vector3::zeros();
        let mut k = 0.0;
        for r in rows.iter().filter(|r| r.ball == ball) {
            let (a, c) = match r.axis {
                Axis::C => (0.0, r.angle_deg),
                Axis::A => (r.angle_deg, 0.0),
            };
            let inv = m.table(a, c).try_inverse()?;
            sum += kinematics::transform_point(&inv, &Vector3::new(r.x_mm, r.y_mm, r.z_mm));
            k += 1.0;
        }
        let b = sum / k;
        theta.extend_from_slice(&[b.x, b.y, b.z]);
    }
    let measured =
        DVector::from_iterator(3 * n, rows.iter().flat_map(|r| [r.x_mm, r.y_mm, r.z_mm]));
    let jacobian = |theta: &[f64]| {
        let mut j = DMatrix::zeros(3 * n, 14);
        for k in 0..14 {
            let h = 1e-6;
            let mut tp = theta.to_vec();
            let mut tm = theta.to_vec();
            tp[k] += h;
            tm[k] -= h;
            let d = (predicted(rows, constants, &tp) - predicted(rows, constants, &tm)) / (2.0 * h);
            j.set_column(k, &d);
        }
        j
    };
    for _ in 0..10 {
        let res = predicted(rows, constants, &theta) - &measured;
        let j = jacobian(&theta);
        let step = (j.transpose() * &j).lu().solve(&(-(j.transpose() * res)))?;
        for k in 0..14 {
            theta[k] += step[k];
        }
        if !theta.iter().all(|v| v.is_finite()) {
            return None;
        }
        if step.norm() < 1e-12 {
            break;
        }
    }
    let res = predicted(rows, constants, &theta) - &measured;
    let j = jacobian(&theta);
    let s2 = res.norm_squared() / (3 * n - 14) as f64;
    let cov = (j.transpose() * &j).try_inverse()? * s2;
    let u: Vec<f64> = (0..8).map(|k| cov[(k, k)].max(0.0).sqrt()).collect();
    let errors = errors_from_slice(&theta[..8]);
    errors.check().ok()?;
    Some((
        errors,
        errors_from_slice(&u),
        (res.norm_squared() / (3 * n) as f64).sqrt(),
        [
            [theta[8], theta[9], theta[10]],
            [theta[11], theta[12], theta[13]],
        ],
    ))
}

//! The camera campaign: in-plane errors seen at several heights of Z, from which the
//! Abbe effect of the X and Y axes' angles about X and Y is separated.
//!
//! # Set-up
//!
//! A camera at the spindle (its focal point is the tool point) looks down at a dot board
//! on the table. The board is laid on risers of several heights `z_k` (the first height
//! is the reference, usually the bare table) and Z is commanded so the focal point sits
//! on the board's surface; at each height the camera visits the same grid of X, Y
//! commands. The localizer reports the board coordinates of the image centre:
//! `b = R(−θ_k) (p_xy − o_k)` with `p` the real tool point in the workpiece frame and
//! `(o_k, θ_k)` the board's unknown placement on riser k (laid against a fence: tenths of
//! a mm, below 0.2 mrad).
//!
//! # Why the height separates the angles
//!
//! In the first-order form (crate docs) the part of the in-plane error that depends on
//! both the height and the X, Y position comes only from the X and Y carriages' angles
//! about X and Y acting over the vertical arm: an axis carrying the tool with Z after it
//! adds `+ε_i × (z e_z)`, an axis carrying the workpiece `−ε_i × (z e_z)` (its arm to the
//! tool point holds the height); with `ε × (z e_z) = (ε_B z, −ε_A z, 0)`:
//!
//! ```text
//! e_xy(x, y, z) = g(x, y) + h(z) + z·( s_X E_BX(x) + s_Y E_BY(y),  −s_X E_AX(x) − s_Y E_AY(y) )
//! s_i = +1 if axis i carries the tool, −1 if it carries the workpiece
//! ```
//!
//! `g` gathers what depends on X, Y alone (positioning, straightness, yaw, squareness of
//! Y), `h` what depends on Z alone (Z's own errors, the squareness of Z; for XYZF also
//! Z's yaw, which turns the XY plane like a board rotation). Subtracting the reference
//! height's reading at the same X, Y removes `g` and the reference board placement:
//!
//! ```text
//! d_k(x, y) = b_k(x, y) − b_0(x, y)
//!           = Δz_k (s_X E_BX(x) + s_Y E_BY(y)) + c_k,x + φ_k y
//!             −Δz_k (s_X E_AX(x) + s_Y E_AY(y)) + c_k,y − φ_k x      (second row: y)
//! ```
//!
//! with `Δz_k = z_k − z_0`, `c_k` the change of board offset (plus `h`) and `φ_k` the
//! change of board rotation (plus Z's yaw) between the risers; products of errors and
//! `φ²·|p|` (< 0.02 µm for 0.2 mrad over the travel) dropped. Worked example (XYFZ, both
//! X and Y carry the workpiece, `s = −1`): `E_BX(250) = 20 µrad`, the board raised by
//! 300 mm, placement unchanged: `d_x(250, y) = 300 · (−1) · 20e−6 mm = −6 µm` (the world
//! test `the_camera_sees_the_pitch_of_a_table_axis_grow_with_height` checks this
//! against the exact chain).
//!
//! # Identification, combined with the interferometer campaign
//!
//! Unknowns: `E_AX, E_BX` at the laser's X positions and `E_AY, E_BY` at its Y positions
//! (the camera's grid points interpolate linearly between them), and `c_k, φ_k` per
//! raised height. Some combinations are invisible to the camera: a constant added to
//! one of the four errors is a change of board offset (`c_k` takes it; the instruments
//! are zeroed at position 0, which fixes it), and equal slopes of the two rolls
//! `E_AX(x) = αx`, `E_BY(y) = αy` (with `s_X = s_Y`) give `Δz α (s y, −s x)`, a pure
//! rotation that `φ_k` takes. So the camera is combined with the instruments: every table
//! value identified from the laser and level enters as a prior with its standard
//! uncertainty, each camera difference as an observation with `√2 U / √runs` (U the
//! camera's stated uncertainty). The weighted least-squares solution replaces those four
//! errors' tables; the inverse normal matrix gives each value's standard uncertainty.
//! Reported: the camera fit's residual RMS, the largest change from the instruments'
//! values and the uncertainties before and after.

use crate::NAMES;
use nalgebra::{DMatrix, DVector};
use protocol::volumetric::{InstrumentFile, Structure};

/// The columns (after `run`) of `camera.csv`.
pub const CAMERA_COLUMNS: [&str; 6] = ["point", "x_mm", "y_mm", "z_mm", "board_x_mm", "board_y_mm"];

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CameraError {
    #[error("camera.csv: header key `uncertainty_um` missing or not a positive number")]
    Uncertainty,
    #[error("camera.csv: run {run}, point {point}: command differs from the first run's")]
    RunMismatch { run: usize, point: usize },
    #[error("camera.csv: needs at least two heights of Z, found {0}")]
    OneHeight(usize),
    #[error(
        "camera.csv: point {point} at ({x}, {y}, {z}) mm has no reading at the reference height {z0} mm at the same X, Y"
    )]
    NoReference {
        point: usize,
        x: f64,
        y: f64,
        z: f64,
        z0: f64,
    },
    #[error("camera.csv: point {point}: {axis} = {value} mm is outside the laser's travel {min}..{max} mm")]
    Outside {
        point: usize,
        axis: char,
        value: f64,
        min: f64,
        max: f64,
    },
    #[error("camera campaign: the combined normal equations are singular")]
    Singular,
}

/// The instruments' identification of one axis's angles about X and Y, in the model's
/// sign (ε), at the laser positions, with one standard uncertainty per error.
#[derive(Debug, Clone, PartialEq)]
pub struct AnglePrior {
    pub positions_mm: Vec<f64>,
    /// `[E_A?, E_B?]` at each position, rad.
    pub values: [Vec<f64>; 2],
    /// Standard uncertainty of `[E_A?, E_B?]`, rad.
    pub sigma: [f64; 2],
}

/// The result of combining the camera with the instruments.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraFit {
    /// `[X, Y][A, B]`: the combined values at the laser positions, rad.
    pub values: [[Vec<f64>; 2]; 2],
    /// Their standard uncertainties, rad.
    pub sigma: [[Vec<f64>; 2]; 2],
    /// Largest change from the instruments' value, rad, per `[X, Y][A, B]`.
    pub change: [[f64; 2]; 2],
    /// Names of the four errors in `[X, Y][A, B]` order.
    pub names: [[&'static str; 2]; 2],
    /// Heights of Z (mm), the reference first.
    pub heights_mm: Vec<f64>,
    /// Board rotation change per raised height (rad).
    pub board_rotation_rad: Vec<f64>,
    /// RMS of the fitted camera differences' residuals (mm) and its stated bound
    /// (`√2 U`, mm): the camera is consistent with the model when the first is below.
    pub residual_rms_mm: f64,
    pub stated_mm: f64,
    /// RMS of the runs about their mean (mm).
    pub repeatability_mm: f64,
    pub points: usize,
}

impl CameraFit {
    pub fn fit(&self) -> bool {
        self.residual_rms_mm <= self.stated_mm && self.repeatability_mm <= self.stated_mm
    }
}

/// Linear interpolation weights of `q` among `positions` (index of the left node, its
/// weight), or `None` outside.
fn weights(positions: &[f64], q: f64) -> Option<(usize, f64)> {
    let n = positions.len();
    if !(q >= positions[0] && q <= positions[n - 1]) {
        return None;
    }
    let i = positions.partition_point(|&p| p <= q).clamp(1, n - 1);
    let w = (q - positions[i - 1]) / (positions[i] - positions[i - 1]);
    Some((i - 1, 1.0 - w))
}

/// Combines the camera campaign with the instruments' angle priors for X and Y.
pub fn combine(
    structure: Structure,
    camera: &InstrumentFile,
    priors: [&AnglePrior; 2],
) -> Result<CameraFit, CameraError> {
    let u = camera
        .meta("uncertainty_um")
        .and_then(|v| v.parse::<f64>().ok())
        .filter(|v| *v > 0.0 && v.is_finite())
        .ok_or(CameraError::Uncertainty)?
        * 1e-3;
    let runs = camera.runs.len();
    let first = &camera.runs[0];
    for (r, run) in camera.runs.iter().enumerate().skip(1) {
        for (i, row) in run.iter().enumerate() {
            if row[1..4] != first[i][1..4] {
                return Err(CameraError::RunMismatch {
                    run: r + 1,
                    point: row[0] as usize,
                });
            }
        }
    }
    // Mean reading per point and the runs' scatter.
    let mut mean = Vec::with_capacity(first.len());
    let mut ss = 0.0;
    for i in 0..first.len() {
        let m: [f64; 2] = std::array::from_fn(|c| {
            camera.runs.iter().map(|r| r[i][4 + c]).sum::<f64>() / runs as f64
        });
        for r in &camera.runs {
            ss += (r[i][4] - m[0]).powi(2) + (r[i][5] - m[1]).powi(2);
        }
        mean.push(m);
    }
    let repeatability_mm = (ss / (2.0 * (runs * first.len()) as f64)).sqrt();
    let z0 = first[0][3];
    let mut heights = vec![z0];
    for row in first {
        if !heights.contains(&row[3]) {
            heights.push(row[3]);
        }
    }
    if heights.len() < 2 {
        return Err(CameraError::OneHeight(heights.len()));
    }
    let [px, py] = [&priors[0].positions_mm, &priors[1].positions_mm];
    let (nx, ny) = (px.len(), py.len());
    // Unknown layout: X: A then B (nx each), Y: A then B (ny each), then (cx, cy, φ)
    // per raised height.
    let col_x = |c: usize, i: usize| c * nx + i;
    let col_y = |c: usize, j: usize| 2 * nx + c * ny + j;
    let col_h = |k: usize, c: usize| 2 * nx + 2 * ny + 3 * (k - 1) + c;
    let n = 2 * nx + 2 * ny + 3 * (heights.len() - 1);
    let sign = |a: usize| if structure.moves_work(a) { -1.0 } else { 1.0 };
    let (sx, sy) = (sign(0), sign(1));
    let sigma_d = u * (2.0 / runs as f64).sqrt();
    let mut rows: Vec<(Vec<(usize, f64)>, f64)> = Vec::new();
    for (p, row) in first.iter().enumerate() {
        let (x, y, z) = (row[1], row[2], row[3]);
        if z == z0 {
            continue;
        }
        let reference = first
            .iter()
            .position(|r| r[3] == z0 && r[1] == x && r[2] == y)
            .ok_or(CameraError::NoReference {
                point: row[0] as usize,
                x,
                y,
                z,
                z0,
            })?;
        let outside = |axis: char, value: f64, pos: &[f64]| CameraError::Outside {
            point: row[0] as usize,
            axis,
            value,
            min: pos[0],
            max: pos[pos.len() - 1],
        };
        let (ix, wx) = weights(px, x).ok_or_else(|| outside('X', x, px))?;
        let (iy, wy) = weights(py, y).ok_or_else(|| outside('Y', y, py))?;
        let k = heights.iter().position(|&h| h == z).unwrap_or(0);
        let dz = z - z0;
        let d = [
            mean[p][0] - mean[reference][0],
            mean[p][1] - mean[reference][1],
        ];
        // Row x: B terms; row y: A terms with the opposite sign.
        for (c, comp, f) in [(0, 1, 1.0), (1, 0, -1.0)] {
            let mut a = vec![
                (col_x(comp, ix), f * dz * sx * wx),
                (col_x(comp, (ix + 1).min(nx - 1)), f * dz * sx * (1.0 - wx)),
                (col_y(comp, iy), f * dz * sy * wy),
                (col_y(comp, (iy + 1).min(ny - 1)), f * dz * sy * (1.0 - wy)),
                (col_h(k, c), 1.0),
            ];
            a.push((col_h(k, 2), if c == 0 { y } else { -x }));
            rows.push((a, d[c]));
        }
    }
    let mut normal = DMatrix::<f64>::zeros(n, n);
    let mut rhs = DVector::<f64>::zeros(n);
    let w = 1.0 / (sigma_d * sigma_d);
    for (a, b) in &rows {
        for &(i, ai) in a {
            rhs[i] += w * ai * b;
            for &(j, aj) in a {
                normal[(i, j)] += w * ai * aj;
            }
        }
    }
    for (axis, prior) in priors.iter().enumerate() {
        for comp in 0..2 {
            let wp = 1.0 / prior.sigma[comp].powi(2);
            for (i, v) in prior.values[comp].iter().enumerate() {
                let col = if axis == 0 {
                    col_x(comp, i)
                } else {
                    col_y(comp, i)
                };
                normal[(col, col)] += wp;
                rhs[col] += wp * v;
            }
        }
    }
    let chol = normal.cholesky().ok_or(CameraError::Singular)?;
    let sol = chol.solve(&rhs);
    let cov = chol.inverse();
    let mut ss = 0.0;
    for (a, b) in &rows {
        let pred: f64 = a.iter().map(|&(i, ai)| ai * sol[i]).sum();
        ss += (pred - b).powi(2);
    }
    let residual_rms_mm = (ss / rows.len().max(1) as f64).sqrt();
    let mut values: [[Vec<f64>; 2]; 2] = Default::default();
    let mut sigma: [[Vec<f64>; 2]; 2] = Default::default();
    let mut change = [[0.0; 2]; 2];
    for (axis, prior) in priors.iter().enumerate() {
        for comp in 0..2 {
            for (i, v) in prior.values[comp].iter().enumerate() {
                let col = if axis == 0 {
                    col_x(comp, i)
                } else {
                    col_y(comp, i)
                };
                values[axis][comp].push(sol[col]);
                sigma[axis][comp].push(cov[(col, col)].max(0.0).sqrt());
                change[axis][comp] = f64::max(change[axis][comp], (sol[col] - v).abs());
            }
        }
    }
    let board_rotation_rad = (1..heights.len()).map(|k| sol[col_h(k, 2)]).collect();
    Ok(CameraFit {
        values,
        sigma,
        change,
        names: [[NAMES[3], NAMES[4]], [NAMES[9], NAMES[10]]],
        heights_mm: heights,
        board_rotation_rad,
        residual_rms_mm,
        stated_mm: u * 2f64.sqrt(),
        repeatability_mm,
        points: first.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::volumetric::parse_instrument;

    fn prior(l: f64) -> AnglePrior {
        AnglePrior {
            positions_mm: vec![0.0, l / 2.0, l],
            values: [vec![0.0; 3], vec![0.0; 3]],
            sigma: [1e-6, 1e-6],
        }
    }

    fn file(rows: &str) -> InstrumentFile {
        let text = format!(
            "# uncertainty_um: 0.2\nrun,point,x_mm,y_mm,z_mm,board_x_mm,board_y_mm\n{rows}"
        );
        parse_instrument(&text, &CAMERA_COLUMNS).unwrap()
    }

    #[test]
    fn a_pitch_seen_at_two_heights_is_recovered() {
        // XYFZ (s = −1): E_BX = 20 µrad at x = 500 (linear), E_BY = 0; raised 300 mm:
        // d_x = −300 · E_BX(x), so −6 µm at x = 250 and −12 µm at x = 500. Loose priors
        // (100 µrad): the camera decides.
        let mut rows = String::new();
        let mut p = 0;
        for (z, dz) in [(0.0, 0.0), (300.0, 300.0)] {
            for y in [0.0, 200.0, 400.0] {
                for x in [0.0, 250.0, 500.0] {
                    let bx = x - dz * 40e-6 * x / 500.0;
                    rows += &format!("1,{p},{x},{y},{z},{bx},{y}\n");
                    p += 1;
                }
            }
        }
        let mut px = prior(500.0);
        let mut py = prior(400.0);
        px.sigma = [100e-6; 2];
        py.sigma = [100e-6; 2];
        let fit = combine(Structure::Xyfz, &file(&rows), [&px, &py]).unwrap();
        // A constant in E_BX is a change of board offset to the camera: with loose
        // priors only the values relative to position 0 are the camera's.
        let ebx = &fit.values[0][1];
        assert!((ebx[1] - ebx[0] - 20e-6).abs() < 0.01e-6, "{ebx:?}");
        assert!((ebx[2] - ebx[0] - 40e-6).abs() < 0.01e-6, "{ebx:?}");
        assert!(fit.residual_rms_mm < 1e-6, "{}", fit.residual_rms_mm);
        assert!(fit.fit());
    }

    #[test]
    fn refusals_name_what_is_wrong() {
        let (px, py) = (prior(500.0), prior(400.0));
        let one = file("1,0,0,0,0,0,0\n1,1,500,0,0,500,0\n");
        assert_eq!(
            combine(Structure::Xyfz, &one, [&px, &py]),
            Err(CameraError::OneHeight(1))
        );
        let orphan = file("1,0,0,0,0,0,0\n1,1,500,0,100,500,0\n");
        let e = combine(Structure::Xyfz, &orphan, [&px, &py]).unwrap_err();
        assert!(e.to_string().contains("point 1 at (500, 0, 100) mm"), "{e}");
        let outside = file("1,0,0,0,0,0,0\n1,1,600,0,0,600,0\n1,2,600,0,100,600,0\n");
        let e = combine(Structure::Xyfz, &outside, [&px, &py]).unwrap_err();
        assert!(e.to_string().contains("X = 600 mm is outside"), "{e}");
        let runs = file("1,0,0,0,0,0,0\n1,1,0,0,100,0,0\n2,0,0,0,0,0,0\n2,1,0,0,120,0,0\n");
        assert_eq!(
            combine(Structure::Xyfz, &runs, [&px, &py]),
            Err(CameraError::RunMismatch { run: 2, point: 1 })
        );
    }
}

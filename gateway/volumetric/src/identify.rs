//! Identification: the model from a measurement campaign (file grammar in
//! `protocol::volumetric`; reading the files is the CLI's job).
//!
//! Each axis is measured alone, the others at 0, along the line through the reference
//! point. The instruments read the tool's error relative to the workpiece, so (first
//! order, see the crate docs) for an axis carrying the tool the reading is `δ + S(q)` and
//! `ε`; for an axis carrying the workpiece it is `−δ − ε × (q e_a) + S(q)` and `−ε`, the
//! `ε × (q e_a)` being the Abbe effect of the carriage's own angles over the arm from its
//! origin (which moves with it) to the tool point. Identification inverts these with the
//! measured angles and squareness: `δ = m − S` (tool side), `δ = −m − ε × (q e_a) + S`
//! (workpiece side).
//!
//! Per error: the identified value at each position is the mean over the runs; its
//! residual is the RMS of (run − mean) over all runs and positions; its standard
//! uncertainty is `sqrt(U² + σ²/n)` (U the instrument's stated uncertainty, σ the runs'
//! standard deviation, n runs), the largest over the positions. A model whose residual
//! exceeds the stated uncertainty for any error is marked unfit for compensation.

use crate::{Model, NAMES};
use nalgebra::Vector3;
use protocol::volumetric::{AxisTable, InstrumentFile, Structure, VolumetricFile};

const AXES: [char; 3] = ['X', 'Y', 'Z'];
const COMP: [char; 6] = ['X', 'Y', 'Z', 'A', 'B', 'C'];

/// The campaign as parsed files: per axis the laser and level file, and the squareness
/// results ((value, uncertainty) rad, E_C0Y, E_B0Z, E_A0Z).
#[derive(Debug, Clone)]
pub struct Campaign {
    pub laser: [InstrumentFile; 3],
    pub level: [InstrumentFile; 3],
    pub squareness: [(f64, f64); 3],
}

/// The columns (after `run`) of `laser_<axis>.csv`.
pub fn laser_columns(axis: usize) -> Vec<String> {
    let a = AXES[axis];
    let mut c = vec!["position_mm".to_string()];
    for k in 0..3 {
        c.push(format!("E_{}{a}_um", COMP[k]));
    }
    for k in (3..6).filter(|&k| k != 3 + axis) {
        c.push(format!("E_{}{a}_urad", COMP[k]));
    }
    c
}

/// The columns (after `run`) of `level_<axis>.csv`.
pub fn level_columns(axis: usize) -> Vec<String> {
    vec![
        "position_mm".to_string(),
        format!("E_{}{}_urad", COMP[3 + axis], AXES[axis]),
    ]
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum IdentifyError {
    #[error("{file}: header key `{key}` missing or not a positive number")]
    Meta { file: String, key: String },
    #[error("{file}: positions differ from laser_{axis}.csv's")]
    Positions { file: String, axis: char },
    #[error("identified model: {0}")]
    Model(#[from] crate::VolError),
}

/// How well one of the 21 errors is known.
#[derive(Debug, Clone, PartialEq)]
pub struct ErrorQuality {
    pub name: &'static str,
    /// RMS of (run − mean), in mm for translations, rad for angles.
    pub residual: f64,
    /// Largest standard uncertainty of the identified value (same unit).
    pub uncertainty: f64,
    /// The instrument's stated uncertainty (same unit).
    pub stated: f64,
}

impl ErrorQuality {
    pub fn fit(&self) -> bool {
        self.residual <= self.stated
    }
}

#[derive(Debug, Clone)]
pub struct Identification {
    pub model: Model,
    /// In [`NAMES`] order.
    pub quality: Vec<ErrorQuality>,
}

fn stated(f: &InstrumentFile, file: &str, key: &str) -> Result<f64, IdentifyError> {
    f.meta(key)
        .and_then(|v| v.parse::<f64>().ok())
        .filter(|v| *v > 0.0 && v.is_finite())
        .ok_or_else(|| IdentifyError::Meta {
            file: file.to_string(),
            key: key.to_string(),
        })
}

/// Mean per position, residual RMS and largest uncertainty of column `col` (values
/// scaled by `scale`, stated uncertainty `u` in the scaled unit).
fn channel(f: &InstrumentFile, col: usize, scale: f64, u: f64) -> (Vec<f64>, f64, f64) {
    let runs = f.runs.len() as f64;
    let n = f.runs[0].len();
    let mut means = Vec::with_capacity(n);
    let mut ss = 0.0;
    let mut worst_u: f64 = 0.0;
    for i in 0..n {
        let vals: Vec<f64> = f.runs.iter().map(|r| r[i][col] * scale).collect();
        let mean = vals.iter().sum::<f64>() / runs;
        let dev: f64 = vals.iter().map(|v| (v - mean).powi(2)).sum();
        ss += dev;
        let sigma2 = if runs > 1.0 { dev / (runs - 1.0) } else { 0.0 };
        worst_u = worst_u.max((u * u + sigma2 / runs).sqrt());
        means.push(mean);
    }
    let rms = (ss / (runs * n as f64)).sqrt();
    (means, rms, worst_u)
}

/// Builds the model of a machine of `structure` from the campaign.
pub fn identify(structure: Structure, c: &Campaign) -> Result<Identification, IdentifyError> {
    let [(c0y, uc), (b0z, ub), (a0z, ua)] = c.squareness;
    let mut tables: [AxisTable; 3] = Default::default();
    let mut quality: Vec<Option<ErrorQuality>> = vec![None; 21];
    for a in 0..3 {
        let laser_name = format!("laser_{}.csv", AXES[a]);
        let level_name = format!("level_{}.csv", AXES[a]);
        let laser = &c.laser[a];
        let level = &c.level[a];
        let u_len = stated(laser, &laser_name, "uncertainty_um")? * 1e-3;
        let u_ang = stated(laser, &laser_name, "uncertainty_urad")? * 1e-6;
        let u_roll = stated(level, &level_name, "uncertainty_urad")? * 1e-6;
        let positions: Vec<f64> = laser.runs[0].iter().map(|r| r[0]).collect();
        let level_positions: Vec<f64> = level.runs[0].iter().map(|r| r[0]).collect();
        if positions != level_positions {
            return Err(IdentifyError::Positions {
                file: level_name,
                axis: AXES[a],
            });
        }
        // Channels in component order X, Y, Z, A, B, C.
        let mut means: [Vec<f64>; 6] = Default::default();
        let mut laser_col = 1;
        for k in 0..6 {
            let (m, rms, unc, st) = if k == 3 + a {
                let (m, r, u) = channel(level, 1, 1e-6, u_roll);
                (m, r, u, u_roll)
            } else {
                let (scale, st) = if k < 3 { (1e-3, u_len) } else { (1e-6, u_ang) };
                let (m, r, u) = channel(laser, laser_col, scale, st);
                laser_col += 1;
                (m, r, u, st)
            };
            means[k] = m;
            quality[a * 6 + k] = Some(ErrorQuality {
                name: NAMES[a * 6 + k],
                residual: rms,
                uncertainty: unc,
                stated: st,
            });
        }
        let work_side = structure.moves_work(a);
        let mut errors = Vec::with_capacity(positions.len());
        for (i, &q) in positions.iter().enumerate() {
            let m = Vector3::new(means[0][i], means[1][i], means[2][i]);
            let meas_angle = Vector3::new(means[3][i], means[4][i], means[5][i]);
            let sq = match a {
                1 => Vector3::new(-c0y * q, 0.0, 0.0),
                2 => Vector3::new(b0z * q, -a0z * q, 0.0),
                _ => Vector3::zeros(),
            };
            let (delta, eps) = if work_side {
                let eps = -meas_angle;
                let mut arm = Vector3::zeros();
                arm[a] = q;
                (-m - eps.cross(&arm) + sq, eps)
            } else {
                (m - sq, meas_angle)
            };
            errors.push([delta.x, delta.y, delta.z, eps.x, eps.y, eps.z]);
        }
        tables[a] = AxisTable {
            positions_mm: positions,
            errors,
        };
    }
    for (k, u) in [uc, ub, ua].into_iter().enumerate() {
        // One ball-bar result per constant: no run-to-run residual, the stated uncertainty.
        quality[18 + k] = Some(ErrorQuality {
            name: NAMES[18 + k],
            residual: 0.0,
            uncertainty: u,
            stated: u,
        });
    }
    let quality: Vec<ErrorQuality> = quality.into_iter().flatten().collect();
    let fit = quality.iter().all(ErrorQuality::fit);
    let model = Model::new(VolumetricFile {
        structure,
        tool_offset_mm: [0.0; 3],
        work_offset_mm: [0.0; 3],
        squareness_rad: [c0y, b0z, a0z],
        fit,
        tables,
    })?;
    Ok(Identification { model, quality })
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::volumetric::{parse_instrument, parse_squareness};
    use world::volumetric::VolumetricMachine;

    pub(crate) fn campaign_of(files: &[(String, String)]) -> Campaign {
        let get = |n: String| &files.iter().find(|f| f.0 == n).unwrap().1;
        let parse = |n: String, cols: Vec<String>| {
            let cols: Vec<&str> = cols.iter().map(String::as_str).collect();
            parse_instrument(get(n), &cols).unwrap()
        };
        Campaign {
            laser: std::array::from_fn(|a| {
                parse(format!("laser_{}.csv", AXES[a]), laser_columns(a))
            }),
            level: std::array::from_fn(|a| {
                parse(format!("level_{}.csv", AXES[a]), level_columns(a))
            }),
            squareness: parse_squareness(get("squareness.csv".into())).unwrap(),
        }
    }

    #[test]
    fn identified_model_predicts_the_emulated_machine() {
        for s in Structure::ALL {
            let machine = VolumetricMachine::new(s, 11);
            let id = identify(s, &campaign_of(&machine.campaign(5))).unwrap();
            assert!(id.model.file.fit, "{s}");
            assert_eq!(id.quality.len(), 21);
            let mut before: f64 = 0.0;
            let mut after: f64 = 0.0;
            for i in 0..200 {
                let t = i as f64 / 200.0;
                let q = [
                    500.0 * t,
                    400.0 * (t * 7.0).fract(),
                    400.0 * (t * 13.0).fract(),
                ];
                let truth = machine.true_error(q);
                let model = id.model.error_exact(q).unwrap();
                for k in 0..3 {
                    before = before.max(truth[k].abs());
                    after = after.max((truth[k] - model[k]).abs());
                }
            }
            assert!(after <= 0.1 * before, "{s}: {after} of {before}");
        }
    }

    #[test]
    fn noisy_runs_mark_the_model_unfit() {
        let machine = VolumetricMachine::new(Structure::Xyfz, 2);
        let mut files = machine.campaign(3);
        // Run 2 of the X laser file drifts by 5 µm in positioning.
        let laser = &mut files[0].1;
        *laser = laser
            .lines()
            .map(|l| {
                let mut f: Vec<String> = l.split(',').map(str::to_string).collect();
                if f[0] == "2" {
                    let v: f64 = f[2].parse().unwrap();
                    f[2] = format!("{}", v + 5.0);
                }
                f.join(",") + "\n"
            })
            .collect();
        let id = identify(Structure::Xyfz, &campaign_of(&files)).unwrap();
        assert!(!id.model.file.fit);
        let bad: Vec<&str> = id
            .quality
            .iter()
            .filter(|q| !q.fit())
            .map(|q| q.name)
            .collect();
        assert_eq!(bad, ["E_XX"]);
    }
}

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

use crate::ballbar::{circle, squareness, CircleResult, BALLBAR_COLUMNS, PLANES};
use crate::camera::{combine, AnglePrior, CameraFit, CAMERA_COLUMNS};
use crate::{Model, NAMES};
use nalgebra::Vector3;
use protocol::volumetric::{
    parse_instrument, parse_squareness, AxisTable, InstrumentFile, Structure, VolumetricFile,
};

const AXES: [char; 3] = ['X', 'Y', 'Z'];
const COMP: [char; 6] = ['X', 'Y', 'Z', 'A', 'B', 'C'];

/// Where the squareness constants come from.
#[derive(Debug, Clone)]
pub enum SquarenessSource {
    /// Results of a diagonal or ball-bar test as numbers ((value, uncertainty) rad,
    /// E_C0Y, E_B0Z, E_A0Z: `squareness.csv`), for straightness readings that keep
    /// their slope.
    Values([(f64, f64); 3]),
    /// The ball-bar files of the XY, XZ and YZ circles (file name, parsed file), in
    /// that order: squareness fitted against the model (see [`crate::ballbar`]).
    Ballbar(Box<[(String, InstrumentFile); 3]>),
}

/// The campaign as parsed files: per axis the laser and level file, and the squareness
/// source.
#[derive(Debug, Clone)]
pub struct Campaign {
    pub laser: [InstrumentFile; 3],
    pub level: [InstrumentFile; 3],
    pub squareness: SquarenessSource,
    /// `camera.csv` (columns [`crate::camera::CAMERA_COLUMNS`]), if measured.
    pub camera: Option<InstrumentFile>,
}

impl Campaign {
    /// The campaign from its files' (name, text): `laser_<axis>.csv` and `level_<axis>.csv`
    /// for X, Y, Z; squareness from `ballbar_XY.csv`, `ballbar_XZ.csv`, `ballbar_YZ.csv`
    /// or else `squareness.csv`; `camera.csv` if present. Errors name the file (and
    /// line and column).
    pub fn from_files(files: &[(String, String)]) -> Result<Campaign, String> {
        let get = |n: &str| files.iter().find(|f| f.0 == n).map(|f| f.1.as_str());
        let parse = |n: String, cols: &[&str]| -> Result<InstrumentFile, String> {
            let text = get(&n).ok_or_else(|| format!("{n}: missing from the campaign"))?;
            let f = parse_instrument(text, cols).map_err(|e| format!("{n}: {e}"))?;
            check_readings(&n, text)?;
            Ok(f)
        };
        let axis = |a: usize, laser: bool| -> Result<InstrumentFile, String> {
            let (name, cols) = if laser {
                (format!("laser_{}.csv", AXES[a]), laser_columns(a))
            } else {
                (format!("level_{}.csv", AXES[a]), level_columns(a))
            };
            let cols: Vec<&str> = cols.iter().map(String::as_str).collect();
            parse(name, &cols)
        };
        let ballbar_names: [String; 3] =
            std::array::from_fn(|k| format!("ballbar_{}.csv", PLANES[k].0));
        let squareness = if ballbar_names.iter().any(|n| get(n).is_some()) {
            let mut v = Vec::new();
            for n in ballbar_names {
                let f = parse(n.clone(), &BALLBAR_COLUMNS)?;
                v.push((n, f));
            }
            SquarenessSource::Ballbar(Box::new(
                v.try_into().map_err(|_| "three circles".to_string())?,
            ))
        } else {
            let text = get("squareness.csv").ok_or(
                "squareness: neither ballbar_XY.csv, ballbar_XZ.csv, ballbar_YZ.csv nor squareness.csv in the campaign",
            )?;
            SquarenessSource::Values(
                parse_squareness(text).map_err(|e| format!("squareness.csv: {e}"))?,
            )
        };
        let camera = match get("camera.csv") {
            Some(_) => Some(parse("camera.csv".into(), &CAMERA_COLUMNS)?),
            None => None,
        };
        Ok(Campaign {
            laser: [axis(0, true)?, axis(1, true)?, axis(2, true)?],
            level: [axis(0, false)?, axis(1, false)?, axis(2, false)?],
            squareness,
            camera,
        })
    }
}

/// The largest magnitude a campaign file's number may have, in its column's unit (um,
/// urad, mm, deg): far beyond any instrument's range. A reading past it (1e308) is a
/// corrupted file, and would otherwise be fitted into a model written as merely unfit.
pub const MAX_READING: f64 = 1e6;

/// Refuses a number beyond [`MAX_READING`] in an instrument file's data rows, naming the
/// file, the line and the column.
fn check_readings(name: &str, text: &str) -> Result<(), String> {
    let mut header: Option<Vec<&str>> = None;
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let Some(cols) = &header else {
            header = Some(fields);
            continue;
        };
        for (k, f) in fields.iter().enumerate().skip(1) {
            if let Ok(v) = f.parse::<f64>() {
                if !(v.abs() <= MAX_READING) {
                    return Err(format!(
                        "{name}: line {}, column {}: `{f}` is beyond any instrument's reading (at most {MAX_READING:e} in the column's unit)",
                        i + 1,
                        cols.get(k).copied().unwrap_or("?")
                    ));
                }
            }
        }
    }
    Ok(())
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
    #[error(transparent)]
    Camera(#[from] crate::camera::CameraError),
    #[error(transparent)]
    Ballbar(#[from] crate::ballbar::BallbarError),
    #[error("{file}: header `plane` must be {want} for this file")]
    Plane { file: String, want: &'static str },
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
    /// The camera campaign's combination, when there was one.
    pub camera: Option<CameraFit>,
    /// The ball-bar circles' readings (XY, XZ, YZ), when squareness came from them.
    pub ballbar: Vec<CircleResult>,
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

/// Builds the model of a machine of `structure` from the campaign (with the camera
/// campaign when there is one: see [`crate::camera`]).
pub fn identify(structure: Structure, c: &Campaign) -> Result<Identification, IdentifyError> {
    // With the ball-bar, the tables are built without squareness and the constants
    // fitted afterwards against them.
    let [(c0y, _), (b0z, _), (a0z, _)] = match &c.squareness {
        SquarenessSource::Values(v) => *v,
        SquarenessSource::Ballbar(_) => [(0.0, 0.0); 3],
    };
    let mut tables: [AxisTable; 3] = Default::default();
    let mut quality: Vec<Option<ErrorQuality>> = vec![None; 21];
    // Per axis: positions and the mean readings in component order X, Y, Z, A, B, C.
    let mut axes: Vec<(Vec<f64>, [Vec<f64>; 6])> = Vec::with_capacity(3);
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
        axes.push((positions, means));
    }
    // The camera's heights sharpen the X and Y angles about X and Y (model sign ε:
    // the reading for a tool-side axis, minus it for a workpiece-side one).
    let sign = |a: usize| if structure.moves_work(a) { -1.0 } else { 1.0 };
    let camera = match &c.camera {
        None => None,
        Some(file) => {
            let priors: [AnglePrior; 2] = std::array::from_fn(|a| AnglePrior {
                positions_mm: axes[a].0.clone(),
                values: std::array::from_fn(|k| {
                    axes[a].1[3 + k].iter().map(|v| sign(a) * v).collect()
                }),
                sigma: std::array::from_fn(|k| {
                    quality[a * 6 + 3 + k]
                        .as_ref()
                        .map_or(0.0, |q| q.uncertainty)
                }),
            });
            let fit = combine(structure, file, [&priors[0], &priors[1]])?;
            for a in 0..2 {
                for k in 0..2 {
                    axes[a].1[3 + k] = fit.values[a][k].iter().map(|v| sign(a) * v).collect();
                    if let Some(q) = quality[a * 6 + 3 + k].as_mut() {
                        q.uncertainty = fit.sigma[a][k].iter().fold(0.0, |m, v| m.max(*v));
                    }
                }
            }
            Some(fit)
        }
    };
    for (a, (positions, means)) in axes.iter().enumerate() {
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
            positions_mm: positions.clone(),
            errors,
        };
    }
    let mut ballbar = Vec::new();
    let squareness_rad = match &c.squareness {
        SquarenessSource::Values(v) => {
            for (k, (_, u)) in v.iter().enumerate() {
                // One result per constant: no run-to-run residual, the stated uncertainty.
                quality[18 + k] = Some(ErrorQuality {
                    name: NAMES[18 + k],
                    residual: 0.0,
                    uncertainty: *u,
                    stated: *u,
                });
            }
            [v[0].0, v[1].0, v[2].0]
        }
        SquarenessSource::Ballbar(files) => {
            let base = Model::new(VolumetricFile {
                structure,
                tool_offset_mm: [0.0; 3],
                work_offset_mm: [0.0; 3],
                squareness_rad: [0.0; 3],
                fit: true,
                tables: tables.clone(),
            })?;
            let mut sq = [0.0; 3];
            for (k, (name, f)) in files.iter().enumerate() {
                let circle = circle(name, f)?;
                if circle.plane != k {
                    return Err(IdentifyError::Plane {
                        file: name.clone(),
                        want: PLANES[k].0,
                    });
                }
                let r = squareness(name, &base, &circle)?;
                sq[k] = r.squareness_rad;
                // The circle must also agree with the model within the bar's stated
                // uncertainty; if not, the squareness is not to be trusted.
                let agrees = r.model_residual_rms_mm <= circle.uncertainty_mm;
                quality[18 + k] = Some(ErrorQuality {
                    name: NAMES[18 + k],
                    residual: if agrees {
                        r.residual_rad
                    } else {
                        f64::INFINITY
                    },
                    uncertainty: r.uncertainty_rad,
                    stated: r.uncertainty_rad,
                });
                ballbar.push(r);
            }
            sq
        }
    };
    let quality: Vec<ErrorQuality> = quality.into_iter().flatten().collect();
    let fit = quality.iter().all(ErrorQuality::fit) && camera.as_ref().is_none_or(CameraFit::fit);
    let model = Model::new(VolumetricFile {
        structure,
        tool_offset_mm: [0.0; 3],
        work_offset_mm: [0.0; 3],
        squareness_rad,
        fit,
        tables,
    })?;
    Ok(Identification {
        model,
        quality,
        camera,
        ballbar,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::CAMERA_COLUMNS;
    use world::volumetric::{CameraPlan, VolumetricMachine};

    pub(crate) fn campaign_of(files: &[(String, String)]) -> Campaign {
        Campaign::from_files(files).unwrap()
    }

    /// A reading no instrument gives (1e308) is refused naming file, line and column,
    /// rather than fitted into a model written as merely unfit.
    #[test]
    fn an_absurd_reading_is_refused_naming_file_line_and_column() {
        let machine = VolumetricMachine::new(Structure::Xyfz, 11);
        let mut files = machine.campaign(5);
        let laser = files.iter_mut().find(|f| f.0 == "laser_X.csv").unwrap();
        let mut lines: Vec<String> = laser.1.lines().map(String::from).collect();
        let k = lines
            .iter()
            .position(|l| l.starts_with("1,") && !l.starts_with("1,0,"))
            .unwrap();
        let mut fields: Vec<String> = lines[k].split(',').map(String::from).collect();
        fields[2] = "1e308".into();
        lines[k] = fields.join(",");
        laser.1 = lines.join("\n");
        let e = Campaign::from_files(&files).unwrap_err();
        assert_eq!(
            e,
            format!(
                "laser_X.csv: line {}, column E_XX_um: `1e308` is beyond any instrument's reading (at most 1e6 in the column's unit)",
                k + 1
            )
        );
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
    fn ballbar_circles_give_the_true_squareness() {
        // The laser's straightness has its slope removed, so squareness comes only from
        // the circles; the truth's straightness is about the mean lines (ISO 230-1), so
        // the machine's constants are what the circles must give back.
        for s in Structure::ALL {
            let machine = VolumetricMachine::new(s, 21);
            let id = identify(s, &campaign_of(&machine.campaign(8))).unwrap();
            assert_eq!(id.ballbar.len(), 3);
            for k in 0..3 {
                let got = id.model.file.squareness_rad[k];
                let want = machine.squareness_rad[k];
                let q = &id.quality[18 + k];
                eprintln!(
                    "{s} {}: {:.3} vs {:.3} urad, u {:.3}, G {:.2} um, iso {:.2} urad",
                    q.name,
                    got * 1e6,
                    want * 1e6,
                    q.uncertainty * 1e6,
                    id.ballbar[k].circular_deviation_mm * 1e3,
                    id.ballbar[k].iso_squareness_rad * 1e6
                );
                // Within 2 µrad: the circles' 0.35 µrad standard uncertainty plus the
                // tables' linear interpolation between 25 mm rows (a tenth of a µm of
                // ellipse on a 150 mm circle is 1.3 µrad).
                assert!(
                    (got - want).abs() <= 2e-6,
                    "{s} {}: {got} vs {want}",
                    q.name
                );
            }
        }
    }

    /// Largest |identified − truth| of E_AX, E_BX, E_AY, E_BY over the laser positions,
    /// and its ratio to the reported standard uncertainty.
    fn angle_errors(id: &Identification, machine: &VolumetricMachine) -> (f64, f64) {
        let mut worst: f64 = 0.0;
        let mut ratio: f64 = 0.0;
        for a in 0..2 {
            let t = &id.model.file.tables[a];
            for k in 3..5 {
                let u = id.quality[a * 6 + k].uncertainty;
                for (p, e) in t.positions_mm.iter().zip(&t.errors) {
                    let d = (e[k] - machine.error_motion(a, k, *p)).abs();
                    worst = worst.max(d);
                    ratio = ratio.max(d / u);
                }
            }
        }
        (worst, ratio)
    }

    #[test]
    fn camera_heights_identify_the_table_angles_within_their_uncertainty() {
        for s in Structure::ALL {
            let machine = VolumetricMachine::new(s, 11);
            let mut c = campaign_of(&machine.campaign(5));
            let (plain_worst, _) = angle_errors(&identify(s, &c).unwrap(), &machine);
            let plan = CameraPlan::default_for(machine.travel_mm);
            let (file, _) = machine.camera_campaign(&plan, 6);
            c.camera = Some(parse_instrument(&file, &CAMERA_COLUMNS).unwrap());
            let id = identify(s, &c).unwrap();
            let cam = id.camera.as_ref().unwrap();
            assert!(cam.fit(), "{s}: {cam:?}");
            assert!(id.model.file.fit);
            let (worst, ratio) = angle_errors(&id, &machine);
            eprintln!(
                "{s}: without camera {:.3} urad, with {:.3} urad, {ratio:.2} sigma, residual {:.4} um, sigma max {:?}",
                plain_worst * 1e6,
                worst * 1e6,
                cam.residual_rms_mm * 1e3,
                cam.sigma
                    .iter()
                    .flatten()
                    .map(|v| v.iter().fold(0.0f64, |m, x| m.max(*x)) * 1e6)
                    .collect::<Vec<_>>()
            );
            // Injected (truth) angles recovered within 3 standard uncertainties, and
            // the camera at least halves the worst error of the instruments alone.
            assert!(ratio <= 3.0, "{s}: {ratio}");
            assert!(worst <= 0.5 * plain_worst, "{s}: {worst} vs {plain_worst}");
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

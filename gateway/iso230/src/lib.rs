//! ISO 230-2 positioning tests of a numerically controlled axis, pure: the target
//! positions and the test cycle ([`plan`]), the evaluation with every figure of the
//! standard (this file), the measurements CSV ([`csv_io`]), and the result JSON, plots
//! and HTML report ([`report`]).
//!
//! Notation (ISO 230-2, clause 3): target positions P_i, i = 1..m; runs j = 1..n in each
//! direction; ↑ is the approach in the positive direction of the axis, ↓ in the
//! negative. The positional deviation x_ij = P_ij - P_i is where the axis really is minus
//! where it was told to go, micrometres. Per position and direction:
//!
//! ```text
//! x̄_i↑ = (1/n) Σ_j x_ij↑                       mean unidirectional positional deviation
//! s_i↑ = sqrt( Σ_j (x_ij↑ - x̄_i↑)² / (n - 1) )  estimator of the unidirectional repeatability
//! R_i↑ = 4 s_i↑                                 unidirectional repeatability
//! x̄_i  = (x̄_i↑ + x̄_i↓) / 2                      mean bidirectional positional deviation
//! B_i  = x̄_i↑ - x̄_i↓                           reversal value
//! R_i  = max(2 s_i↑ + 2 s_i↓ + |B_i|, R_i↑, R_i↓) bidirectional repeatability
//! ```
//!
//! and per axis:
//!
//! ```text
//! B  = max |B_i|            B̄ = (1/m) Σ_i B_i (mean reversal value)
//! R↑ = max R_i↑   R↓ = max R_i↓   R = max R_i
//! E↑ = max x̄_i↑ - min x̄_i↑   E↓ likewise
//! E  = max(x̄_i↑, x̄_i↓) - min(x̄_i↑, x̄_i↓)   (over both directions together)
//! M  = max x̄_i - min x̄_i
//! A↑ = max(x̄_i↑ + 2 s_i↑) - min(x̄_i↑ - 2 s_i↑)   A↓ likewise
//! A  = max(x̄_i↑ + 2 s_i↑, x̄_i↓ + 2 s_i↓) - min(x̄_i↑ - 2 s_i↑, x̄_i↓ - 2 s_i↓)
//! ```
//!
//! Each mean divides by the number of runs at that position and direction (never by the
//! number of positions), and each direction keeps its own runs: a position with 6 runs
//! up and 5 down is evaluated with n = 6 and n = 5. E and A take the extremes over both
//! directions at once, so E ≥ max(E↑, E↓) and A ≥ max(A↑, A↓) always.
//!
//! Worked example (one position, runs up 1, 2, 3, 4, 5 um, down -1, 0, 1, 2, 3 um):
//! x̄↑ = 3, x̄↓ = 1, s↑ = s↓ = sqrt(10/4) = 1.5811, B_i = 2, R_i↑ = R_i↓ = 6.3246,
//! R_i = 2·1.5811 + 2·1.5811 + 2 = 8.3246, x̄_i = 2.

pub mod csv_io;
pub mod plan;
pub mod report;

use serde::{Deserialize, Serialize};

/// The direction of approach: ↑ (`+` in files) or ↓ (`-`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum Direction {
    #[serde(rename = "+")]
    Up,
    #[serde(rename = "-")]
    Down,
}

impl Direction {
    pub fn sign(self) -> &'static str {
        match self {
            Direction::Up => "+",
            Direction::Down => "-",
        }
    }
}

/// One measured positional deviation.
#[derive(Clone, Debug, PartialEq)]
pub struct Measurement {
    /// The axis name as the file gives it (`X`, `Y`, ...).
    pub axis: String,
    /// i, 1-based, in order of increasing target.
    pub position_index: usize,
    /// P_i, mm.
    pub target_mm: f64,
    /// j, 1-based.
    pub run: usize,
    pub direction: Direction,
    /// x_ij = P_ij - P_i, um.
    pub deviation_um: f64,
}

/// The standard's minimum: 5 runs in each direction, 5 target positions.
pub const MIN_RUNS: usize = 5;
pub const MIN_POSITIONS: usize = 5;

/// What a set of measurements lacks for an evaluation.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EvalError {
    #[error("no measurements")]
    Empty,
    #[error("{found} target positions; ISO 230-2 needs at least {MIN_POSITIONS}")]
    TooFewPositions { found: usize },
    #[error("position {position_index} ({target_mm} mm) has no runs in the {} direction", direction.sign())]
    MissingDirection {
        position_index: usize,
        target_mm: f64,
        direction: Direction,
    },
    #[error("position {position_index} ({target_mm} mm), direction {}: {found} runs; ISO 230-2 needs at least {MIN_RUNS}", direction.sign())]
    TooFewRuns {
        position_index: usize,
        target_mm: f64,
        direction: Direction,
        found: usize,
    },
    #[error("measurements of axes `{0}` and `{1}` together: evaluate one axis at a time")]
    MixedAxes(String, String),
}

/// Every per-position figure, um (targets mm).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PositionFigures {
    pub position_index: usize,
    pub target_mm: f64,
    pub runs_up: usize,
    pub runs_down: usize,
    /// x̄_i↑, x̄_i↓, x̄_i.
    pub mean_up_um: f64,
    pub mean_down_um: f64,
    pub mean_um: f64,
    /// s_i↑, s_i↓ (n - 1).
    pub s_up_um: f64,
    pub s_down_um: f64,
    /// B_i.
    pub reversal_um: f64,
    /// R_i↑ = 4 s_i↑, R_i↓, R_i.
    pub r_up_um: f64,
    pub r_down_um: f64,
    pub r_um: f64,
}

/// The axis figures, named as in the standard, um.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AxisFigures {
    #[serde(rename = "A_um")]
    pub a: f64,
    #[serde(rename = "A_up_um")]
    pub a_up: f64,
    #[serde(rename = "A_down_um")]
    pub a_down: f64,
    #[serde(rename = "B_um")]
    pub b: f64,
    #[serde(rename = "mean_reversal_um")]
    pub mean_reversal: f64,
    #[serde(rename = "R_um")]
    pub r: f64,
    #[serde(rename = "R_up_um")]
    pub r_up: f64,
    #[serde(rename = "R_down_um")]
    pub r_down: f64,
    #[serde(rename = "E_um")]
    pub e: f64,
    #[serde(rename = "E_up_um")]
    pub e_up: f64,
    #[serde(rename = "E_down_um")]
    pub e_down: f64,
    #[serde(rename = "M_um")]
    pub m: f64,
}

/// An evaluated axis.
#[derive(Clone, Debug, PartialEq)]
pub struct Evaluation {
    pub axis: String,
    /// In order of increasing target.
    pub positions: Vec<PositionFigures>,
    pub figures: AxisFigures,
}

/// Mean and sample standard deviation (n - 1) of `v` (n >= 2).
fn mean_s(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let ss = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>();
    (mean, (ss / (n - 1.0)).sqrt())
}

fn max_of(it: impl Iterator<Item = f64>) -> f64 {
    it.fold(f64::NEG_INFINITY, f64::max)
}

fn min_of(it: impl Iterator<Item = f64>) -> f64 {
    it.fold(f64::INFINITY, f64::min)
}

/// Evaluate one axis. Positions are grouped by `position_index` (the first measurement
/// of an index gives its target) and sorted by target; runs are taken as they come, so
/// run numbers only identify (the CSV reader refuses duplicates).
pub fn evaluate(measurements: &[Measurement]) -> Result<Evaluation, EvalError> {
    let first = measurements.first().ok_or(EvalError::Empty)?;
    if let Some(other) = measurements.iter().find(|m| m.axis != first.axis) {
        return Err(EvalError::MixedAxes(first.axis.clone(), other.axis.clone()));
    }
    // position_index -> (target, up deviations, down deviations)
    let mut groups: std::collections::BTreeMap<usize, (f64, Vec<f64>, Vec<f64>)> =
        Default::default();
    for m in measurements {
        let g = groups
            .entry(m.position_index)
            .or_insert_with(|| (m.target_mm, Vec::new(), Vec::new()));
        match m.direction {
            Direction::Up => g.1.push(m.deviation_um),
            Direction::Down => g.2.push(m.deviation_um),
        }
    }
    if groups.len() < MIN_POSITIONS {
        return Err(EvalError::TooFewPositions {
            found: groups.len(),
        });
    }
    let mut positions = Vec::with_capacity(groups.len());
    for (&position_index, (target_mm, up, down)) in &groups {
        for (direction, v) in [(Direction::Up, up), (Direction::Down, down)] {
            if v.is_empty() {
                return Err(EvalError::MissingDirection {
                    position_index,
                    target_mm: *target_mm,
                    direction,
                });
            }
            if v.len() < MIN_RUNS {
                return Err(EvalError::TooFewRuns {
                    position_index,
                    target_mm: *target_mm,
                    direction,
                    found: v.len(),
                });
            }
        }
        let (mean_up_um, s_up_um) = mean_s(up);
        let (mean_down_um, s_down_um) = mean_s(down);
        let reversal_um = mean_up_um - mean_down_um;
        let (r_up_um, r_down_um) = (4.0 * s_up_um, 4.0 * s_down_um);
        let r_um = (2.0 * s_up_um + 2.0 * s_down_um + reversal_um.abs())
            .max(r_up_um)
            .max(r_down_um);
        positions.push(PositionFigures {
            position_index,
            target_mm: *target_mm,
            runs_up: up.len(),
            runs_down: down.len(),
            mean_up_um,
            mean_down_um,
            mean_um: (mean_up_um + mean_down_um) / 2.0,
            s_up_um,
            s_down_um,
            reversal_um,
            r_up_um,
            r_down_um,
            r_um,
        });
    }
    positions.sort_by(|a, b| a.target_mm.total_cmp(&b.target_mm));
    let figures = axis_figures(&positions);
    Ok(Evaluation {
        axis: first.axis.clone(),
        positions,
        figures,
    })
}

/// The axis figures from the per-position ones (at least one position).
pub fn axis_figures(p: &[PositionFigures]) -> AxisFigures {
    let up = || p.iter().map(|q| q.mean_up_um);
    let down = || p.iter().map(|q| q.mean_down_um);
    let both = || up().chain(down());
    let hi_up = || p.iter().map(|q| q.mean_up_um + 2.0 * q.s_up_um);
    let lo_up = || p.iter().map(|q| q.mean_up_um - 2.0 * q.s_up_um);
    let hi_down = || p.iter().map(|q| q.mean_down_um + 2.0 * q.s_down_um);
    let lo_down = || p.iter().map(|q| q.mean_down_um - 2.0 * q.s_down_um);
    AxisFigures {
        a: max_of(hi_up().chain(hi_down())) - min_of(lo_up().chain(lo_down())),
        a_up: max_of(hi_up()) - min_of(lo_up()),
        a_down: max_of(hi_down()) - min_of(lo_down()),
        b: max_of(p.iter().map(|q| q.reversal_um.abs())),
        mean_reversal: p.iter().map(|q| q.reversal_um).sum::<f64>() / p.len() as f64,
        r: max_of(p.iter().map(|q| q.r_um)),
        r_up: max_of(p.iter().map(|q| q.r_up_um)),
        r_down: max_of(p.iter().map(|q| q.r_down_um)),
        e: max_of(both()) - min_of(both()),
        e_up: max_of(up()) - min_of(up()),
        e_down: max_of(down()) - min_of(down()),
        m: max_of(p.iter().map(|q| q.mean_um)) - min_of(p.iter().map(|q| q.mean_um)),
    }
}

/// The measurement uncertainty of one positional deviation measured by the camera on
/// the board, expanded with k = 2 (ISO/TR 230-9 style budget of two contributions):
/// the board certificate (the length reference: the expanded uncertainty the calibration
/// lab states for a dot position) and the localization's repeatability (the standard
/// deviation of repeated localizations of one still frame position, n - 1).
///
/// `U = 2 · sqrt((U_cert / 2)² + s_loc²)`. Worked example: certificate 1.0 um (k = 2),
/// s_loc = 0.2 um: U = 2 · sqrt(0.25 + 0.04) = 1.077 um.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Uncertainty {
    /// The certificate's expanded uncertainty (k = 2), um.
    pub certificate_um: f64,
    /// Repeatability of the localization, one standard deviation, um.
    pub localization_s_um: f64,
    /// How many still frames gave `localization_s_um`.
    pub localization_frames: usize,
    /// Expanded (k = 2) uncertainty of one deviation, um.
    pub expanded_um: f64,
}

impl Uncertainty {
    pub fn new(certificate_um: f64, localization_samples_um: &[f64]) -> Self {
        let s = if localization_samples_um.len() >= 2 {
            mean_s(localization_samples_um).1
        } else {
            0.0
        };
        Uncertainty {
            certificate_um,
            localization_s_um: s,
            localization_frames: localization_samples_um.len(),
            expanded_um: 2.0 * ((certificate_um / 2.0).powi(2) + s * s).sqrt(),
        }
    }
}

#[cfg(test)]
mod tests;

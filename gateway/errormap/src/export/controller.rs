//! What the industrial controllers' tables share: the map sampled into per-axis
//! profiles, the tables as the controller applies them (`Term`s: a curve of one input
//! axis added to one output axis), and the residual of a set of terms against the map.
//!
//! Sign: a term's value is the error it cancels (where the tool really is minus where it
//! was commanded, as the map says); each writer turns it into its format's sign.

use super::ExportError;
use crate::{Approach, Direction, MapModel, ModelError};

/// How a controller goes from one table point to the next.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shape {
    /// Linear between points; the end values held beyond the first and last.
    Linear,
    /// Point k's value holds over the section (k-1, k] (the section ending at it).
    StepEnding,
    /// Point k's value holds over the section [k, k+1) (the section starting at it).
    StepStarting,
}

/// One table: values at increasing positions of its input axis, mm.
#[derive(Debug, Clone, PartialEq)]
pub struct Curve {
    pub input: usize,
    pub positions: Vec<f64>,
    pub values_mm: Vec<f64>,
    pub shape: Shape,
}

impl Curve {
    /// The value at `s` (ends held).
    pub fn at(&self, s: f64) -> f64 {
        let (p, v) = (&self.positions, &self.values_mm);
        let n = p.len();
        if s <= p[0] {
            return v[0];
        }
        if s >= p[n - 1] {
            return v[n - 1];
        }
        let k = p.partition_point(|&q| q < s).clamp(1, n - 1);
        match self.shape {
            Shape::Linear => {
                let t = (s - p[k - 1]) / (p[k] - p[k - 1]);
                v[k - 1] + (v[k] - v[k - 1]) * t
            }
            Shape::StepEnding => v[k],
            Shape::StepStarting => {
                if s >= p[k] {
                    v[k]
                } else {
                    v[k - 1]
                }
            }
        }
    }
}

/// A table as the controller applies it: `curve` (times `times` when set) added to the
/// `output` axis, only when the input axis's last move went the way of `only`.
#[derive(Debug, Clone, PartialEq)]
pub struct Term {
    pub output: usize,
    pub curve: Curve,
    pub only: Option<Approach>,
    pub times: Option<Curve>,
}

impl Term {
    pub fn plain(output: usize, curve: Curve) -> Self {
        Self {
            output,
            curve,
            only: None,
            times: None,
        }
    }
}

fn side(dir: Direction, axis: usize) -> Approach {
    if axis == 0 {
        dir.x
    } else {
        dir.y
    }
}

/// The error the terms cancel at command `p` approached from `dir`, um.
pub fn applied_um(terms: &[Term], p: [f64; 2], dir: Direction) -> [f64; 2] {
    let mut out = [0.0; 2];
    for t in terms {
        if let Some(only) = t.only {
            if side(dir, t.curve.input) != only {
                continue;
            }
        }
        let mut v = t.curve.at(p[t.curve.input]);
        if let Some(m) = &t.times {
            v *= m.at(p[m.input]);
        }
        out[t.output] += v * 1000.0;
    }
    out
}

/// A set of tables against the map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fit {
    /// The map's error itself over the same points (what no table leaves), um.
    pub map_max_um: f64,
    pub map_rms_um: f64,
    /// What the tables leave of it, um.
    pub max_um: f64,
    pub rms_um: f64,
    /// The share of the map's error (sum of squares) the tables express: 1 - r^2 / e^2.
    pub share: f64,
    pub worst_at_mm: [f64; 2],
}

/// Sample positions across `lo..hi`: `n` cell centres (never a table's own point on a
/// regular table, where interpolation is exact).
pub fn centres(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    (0..n)
        .map(|k| lo + (hi - lo) * (k as f64 + 0.5) / n as f64)
        .collect()
}

/// The terms (plus `zero_um`, the constant a controller's zero cannot hold, see
/// [`Fit`]) against the map's tool error at the centres of a grid about 0.8 mm apart,
/// approached forward and reverse on both axes.
pub fn fit(model: &MapModel, terms: &[Term], zero_um: [f64; 2]) -> Result<Fit, ModelError> {
    let (lo, hi) = model.extent();
    let n = |k: usize| (((hi[k] - lo[k]) / 0.8).ceil() as usize).clamp(2, 2000);
    let (xs, ys) = (centres(lo[0], hi[0], n(0)), centres(lo[1], hi[1], n(1)));
    let (mut e2, mut r2, mut count) = (0.0, 0.0, 0usize);
    let (mut emax, mut rmax, mut worst) = (0.0f64, 0.0f64, lo);
    for &y in &ys {
        for &x in &xs {
            for dir in [Direction::FORWARD, Direction::REVERSE] {
                let e = model.tool_error_um([x, y], dir)?;
                let a = applied_um(terms, [x, y], dir);
                for k in 0..2 {
                    let r = e[k] - zero_um[k] - a[k];
                    e2 += e[k] * e[k];
                    r2 += r * r;
                    count += 1;
                    emax = emax.max(e[k].abs());
                    if r.abs() > rmax {
                        (rmax, worst) = (r.abs(), [x, y]);
                    }
                }
            }
        }
    }
    let count = count as f64;
    Ok(Fit {
        map_max_um: emax,
        map_rms_um: (e2 / count).sqrt(),
        max_um: rmax,
        rms_um: (r2 / count).sqrt(),
        share: if e2 > 0.0 { 1.0 - r2 / e2 } else { 1.0 },
        worst_at_mm: worst,
    })
}

/// The map's error of `axis`'s component, as a function of the position along `input`,
/// averaged over the other axis (the least-squares part of the error a table of `input`
/// holds), mm, per approach of the input axis (the component's own axis takes the same
/// approach, as a move along the input axis leaves it).
pub struct Profiles {
    lo: [f64; 2],
    hi: [f64; 2],
    across: [Vec<f64>; 2],
}

impl Profiles {
    pub fn new(model: &MapModel) -> Self {
        let (lo, hi) = model.extent();
        Self {
            lo,
            hi,
            across: [centres(lo[0], hi[0], 24), centres(lo[1], hi[1], 24)],
        }
    }

    /// Mean over the other axis of component `component` at `s` along `input`, mm,
    /// approached from `a` on both axes (`None`: the mean of both approaches).
    pub fn mean(
        &self,
        model: &MapModel,
        component: usize,
        input: usize,
        s: f64,
        a: Option<Approach>,
    ) -> Result<f64, ModelError> {
        let s = s.clamp(self.lo[input], self.hi[input]);
        let other = 1 - input;
        let dirs: &[Direction] = match a {
            Some(Approach::Forward) => &[Direction::FORWARD],
            Some(Approach::Reverse) => &[Direction::REVERSE],
            None => &[Direction::FORWARD, Direction::REVERSE],
        };
        let mut sum = 0.0;
        for &t in &self.across[other] {
            let mut p = [0.0; 2];
            p[input] = s;
            p[other] = t;
            for &d in dirs {
                sum += model.tool_error_um(p, d)?[component];
            }
        }
        Ok(sum / (self.across[other].len() * dirs.len()) as f64 / 1000.0)
    }

    /// The same over all of the map (both axes), mm.
    pub fn overall(&self, model: &MapModel, component: usize) -> Result<f64, ModelError> {
        let mut sum = 0.0;
        for &s in &self.across[0] {
            sum += self.mean(model, component, 0, s, None)?;
        }
        Ok(sum / self.across[0].len() as f64)
    }
}

/// A regular table over `lo..hi` of at most `max_points` points: the step rounded up to
/// a whole micrometre, so the written step, minimum and maximum agree exactly with the
/// point count ((MAX - MIN) / STEP + 1); the last point at or below `hi` (beyond it the
/// controller holds the last value).
pub fn regular(
    format: &str,
    lo: f64,
    hi: f64,
    max_points: usize,
) -> Result<(f64, usize), ExportError> {
    if max_points < 2 {
        return Err(ExportError::Options(format!(
            "{format}: {max_points} points per table: at least 2"
        )));
    }
    let step_um = ((hi - lo) * 1000.0 / (max_points - 1) as f64)
        .ceil()
        .max(1.0);
    let step = step_um / 1000.0;
    let n = (((hi - lo) * 1000.0 + 1e-6) / step_um).floor() as usize + 1;
    Ok((step, n.min(max_points)))
}

/// `count` positions from `lo`, `step` apart.
pub fn positions(lo: f64, step: f64, count: usize) -> Vec<f64> {
    (0..count).map(|k| lo + step * k as f64).collect()
}

/// What the engineer must know: the map's identity line for a header.
pub fn identity_line(model: &MapModel) -> String {
    let m = model.map();
    format!(
        "machine {}, map version {} of {}",
        m.identity.machine, m.version, m.created
    )
}

/// The sign a format writes its values in, where the manuals leave it open.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ValueSign {
    /// Minus the error: what the controller adds to the command.
    #[default]
    Correction,
    /// The error itself (where the axis really is minus where it was commanded).
    Error,
}

impl ValueSign {
    pub fn apply(self, error: f64) -> f64 {
        match self {
            ValueSign::Correction => -error,
            ValueSign::Error => error,
        }
    }

    pub fn as_str(self) -> &'static str {
        match self {
            ValueSign::Correction => "correction",
            ValueSign::Error => "error",
        }
    }
}

impl std::str::FromStr for ValueSign {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "correction" => Ok(ValueSign::Correction),
            "error" => Ok(ValueSign::Error),
            other => Err(format!("`{other}`: correction or error")),
        }
    }
}

/// A written table: its file's text beside what the command's output must say.
#[derive(Debug, Clone, PartialEq)]
pub struct ControllerTables {
    /// (file suffix as the procedure names it, text), in order.
    pub files: Vec<(String, String)>,
    /// What to set on the controller (also in the files' header where comments exist).
    pub settings: Vec<String>,
    /// The tables against the map.
    pub fit: Fit,
    /// A constant per axis the controller's zero cannot hold (its reference sets it), um.
    pub zero_not_held_um: [f64; 2],
    /// The tables chosen, one line each.
    pub tables: Vec<String>,
}

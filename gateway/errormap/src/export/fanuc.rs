//! Fanuc pitch error compensation (16i/18i/0i, parameters 3620-3624), written as the
//! parameter file the controller punches and reads over RS-232: ISO code, `%` at both
//! ends, EOB LF, axis-type records `N03620A1P..A2P..`, and one record per compensation
//! point. The file holds no comments: what to set is returned for the command's output.
//!
//! What the manuals leave open, and the option that decides it (see docs/error-map.md):
//! * the unit of values and of the interval 3624: `unit_um` (default 1 um, the detection
//!   unit of an IS-B machine);
//! * the sign: `sign` (default [`ValueSign::Correction`]: a value is what the control adds);
//! * which section a point's value covers and how it is applied: `section` (default
//!   [`FanucSection::StepEnding`]: point n's running sum holds over the section ending at
//!   point n, as the parameter manual numbers the reference point's section);
//! * the range of one value: `max_increment` (default 127) and of 3623: `magnification`
//!   (default 1);
//! * the line form of pitch data: `record_base` (default 10000: point n is `N1nnnnP..`);
//! * the TV check: `tv_check` (default: each block's characters without its EOB padded
//!   to an even count with a space, as DNC senders do).
//!
//! Values are incremental from the negative end: the absolute correction at point k is
//! the running sum of the values after the reference point up to k (minus the values
//! from k + 1 up to the reference point below it), zero at the reference position
//! (machine zero). Worked example: 3620 = 40, interval 50 mm, values of 41..44 = +2 +1
//! -1 0: +2, +3, +2, +2 units at +50 .. +200 mm.

use super::controller::{fit, ControllerTables, Curve, Profiles, Shape, Term, ValueSign};
use super::ExportError;
use crate::MapModel;

/// Which section a compensation point covers and how the control applies it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FanucSection {
    /// The running sum at point n holds over the section ending at point n.
    #[default]
    StepEnding,
    /// The running sum at point n holds over the section starting at point n.
    StepStarting,
    /// Linear between the running sums at the points.
    Ramp,
}

impl FanucSection {
    pub fn shape(self) -> Shape {
        match self {
            Self::StepEnding => Shape::StepEnding,
            Self::StepStarting => Shape::StepStarting,
            Self::Ramp => Shape::Linear,
        }
    }
    pub fn as_str(self) -> &'static str {
        match self {
            Self::StepEnding => "step-ending",
            Self::StepStarting => "step-starting",
            Self::Ramp => "ramp",
        }
    }
}

impl std::str::FromStr for FanucSection {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "step-ending" => Ok(Self::StepEnding),
            "step-starting" => Ok(Self::StepStarting),
            "ramp" => Ok(Self::Ramp),
            other => Err(format!("`{other}`: step-ending, step-starting or ramp")),
        }
    }
}

/// Whether and how blocks are padded for the TV check (alarm 002 on an odd count).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TvCheck {
    /// No padding (the check is disabled on the control).
    Off,
    /// The characters of a block, its EOB not counted, made even.
    #[default]
    WithoutEob,
    /// The characters of a block with its EOB made even.
    WithEob,
}

impl TvCheck {
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Off => "off",
            Self::WithoutEob => "without-eob",
            Self::WithEob => "with-eob",
        }
    }
}

impl std::str::FromStr for TvCheck {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "off" => Ok(Self::Off),
            "without-eob" => Ok(Self::WithoutEob),
            "with-eob" => Ok(Self::WithEob),
            other => Err(format!("`{other}`: off, without-eob or with-eob")),
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct FanucOptions {
    pub unit_um: f64,
    pub sign: ValueSign,
    pub section: FanucSection,
    pub magnification: u32,
    pub max_increment: u32,
    /// Compensation points per axis the control holds (a secondary source names 128).
    pub points: usize,
    pub record_base: u32,
    pub tv_check: TvCheck,
}

impl Default for FanucOptions {
    fn default() -> Self {
        Self {
            unit_um: 1.0,
            sign: ValueSign::Correction,
            section: FanucSection::StepEnding,
            magnification: 1,
            max_increment: 127,
            points: 128,
            record_base: 10000,
            tv_check: TvCheck::WithoutEob,
        }
    }
}

/// One axis's points: numbers `first..=first + values.len() - 1`, the reference number,
/// values in units.
struct Axis {
    first: usize,
    reference: usize,
    values: Vec<i64>,
}

/// A block padded for the TV check.
fn block(text: &str, tv: TvCheck) -> String {
    let count = text.chars().count()
        + match tv {
            TvCheck::WithEob => 1,
            _ => 0,
        };
    if tv != TvCheck::Off && count % 2 == 1 {
        format!("{text} \n")
    } else {
        format!("{text}\n")
    }
}

pub fn fanuc_pitch(model: &MapModel, o: &FanucOptions) -> Result<ControllerTables, ExportError> {
    if !(o.unit_um.is_finite() && (0.001..=100.0).contains(&o.unit_um)) {
        return Err(ExportError::Options(format!(
            "Fanuc unit {} um: 0.001 to 100 um",
            o.unit_um
        )));
    }
    if o.magnification == 0 || o.max_increment == 0 || o.points < 2 {
        return Err(ExportError::Options(
            "Fanuc: magnification, range and points must be at least 1, 1 and 2".into(),
        ));
    }
    let (lo, hi) = model.extent();
    let profiles = Profiles::new(model);
    // A unit of a value, mm.
    let q = o.unit_um * o.magnification as f64 / 1000.0;
    let shape = o.section.shape();
    let mut axes = Vec::new();
    let mut terms = Vec::new();
    let mut zero = [0.0; 2];
    let mut interval_units = [0u64; 2];
    let mut next = 0usize;
    for k in 0..2 {
        // Whole units of interval; sections from the reference position (machine zero).
        let span = hi[k] - lo[k];
        let per = o.points.saturating_sub(2).max(1) as f64;
        let units = ((span / per) * 1000.0 / o.unit_um).ceil().max(1.0) as u64;
        let interval = units as f64 * o.unit_um / 1000.0;
        // The reference position (machine zero) is always one of the points.
        let (kmin, kmax) = (
            ((lo[k] / interval).floor() as i64).min(0),
            ((hi[k] / interval).ceil() as i64).max(0),
        );
        let count = (kmax - kmin + 1) as usize;
        if count > o.points {
            return Err(ExportError::Options(format!(
                "Fanuc axis {}: {count} compensation points over {:.3}..{:.3} mm at {interval} mm; the control holds {} (--points)",
                k + 1, lo[k], hi[k], o.points
            )));
        }
        // The error each section should hold (in error sign, mm), clamped into the map.
        let target = |j: i64| -> Result<f64, ExportError> {
            let at = match o.section {
                FanucSection::Ramp => j as f64 * interval,
                FanucSection::StepEnding => (j as f64 - 0.5) * interval,
                FanucSection::StepStarting => (j as f64 + 0.5) * interval,
            };
            Ok(profiles.mean(model, k, k, at, None)?)
        };
        let c = target(0)?;
        zero[k] = c * 1000.0;
        // Running sums in units, rounded once each so rounding never accumulates.
        let sums: Vec<i64> = (kmin..=kmax)
            .map(|j| Ok((o.sign.apply(target(j)? - c) / q).round() as i64))
            .collect::<Result<_, ExportError>>()?;
        let zero_index = (-kmin) as usize;
        let mut values = Vec::with_capacity(count);
        for (i, s) in sums.iter().enumerate() {
            let v = if i == 0 { 0 } else { s - sums[i - 1] };
            if v.unsigned_abs() > o.max_increment as u64 {
                return Err(ExportError::Options(format!(
                    "Fanuc axis {}: point {} needs {v} units of {} um, past the {} a point holds (--fanuc-max-increment); raise --fanuc-magnification (3623)",
                    k + 1, next + i, o.unit_um * o.magnification as f64, o.max_increment
                )));
            }
            values.push(v);
        }
        // The controller's correction, as the error it cancels: the running sums.
        terms.push(Term::plain(
            k,
            Curve {
                input: k,
                positions: (kmin..=kmax).map(|j| j as f64 * interval).collect(),
                values_mm: sums.iter().map(|&s| o.sign.apply(s as f64 * q)).collect(),
                shape,
            },
        ));
        interval_units[k] = units;
        axes.push(Axis {
            first: next,
            reference: next + zero_index,
            values,
        });
        next += count;
    }
    let fit = fit(model, &terms, zero)?;
    let mut text = String::from("%\n");
    let pair = |n: u32, f: &dyn Fn(usize) -> String| -> String {
        format!("N{n:05}A1P{}A2P{}", f(0), f(1))
    };
    let records = [
        pair(3620, &|k| axes[k].reference.to_string()),
        pair(3621, &|k| axes[k].first.to_string()),
        pair(3622, &|k| {
            (axes[k].first + axes[k].values.len() - 1).to_string()
        }),
        pair(3623, &|_| o.magnification.to_string()),
        pair(3624, &|k| interval_units[k].to_string()),
    ];
    for r in &records {
        text.push_str(&block(r, o.tv_check));
    }
    for a in &axes {
        for (i, v) in a.values.iter().enumerate() {
            let r = format!("N{}P{v}", o.record_base as usize + a.first + i);
            text.push_str(&block(&r, o.tv_check));
        }
    }
    text.push_str("%\n");
    let unit = o.unit_um;
    let settings = vec![
        "3605#0 (bidirectional pitch error compensation) = 0 on axes 1 (X) and 2 (Y): one table for both directions; the backlash stays with parameter 1851".to_string(),
        format!("3620-3624 as in the file (reference point {} and {}, interval {} and {} units of {unit} um, magnification {})", axes[0].reference, axes[1].reference, interval_units[0], interval_units[1], o.magnification),
        format!("values: {} in units of {} um, section {} (the manuals leave unit, sign and section open: confirm with one point)", o.sign.as_str(), unit * o.magnification as f64, o.section.as_str()),
        "switch the power off and on after loading 3620-3627, then return to the reference position".to_string(),
        format!("the correction is zero at the reference position: the map's {:.2} um (X) and {:.2} um (Y) there belong to the reference (grid shift 1850 or the work offset)", zero[0], zero[1]),
    ];
    let tables = (0..2)
        .map(|k| {
            format!(
                "axis {}: points {}..{} (reference {}), interval {} units",
                k + 1,
                axes[k].first,
                axes[k].first + axes[k].values.len() - 1,
                axes[k].reference,
                interval_units[k]
            )
        })
        .collect();
    Ok(ControllerTables {
        files: vec![(String::new(), text)],
        settings,
        fit,
        zero_not_held_um: zero,
        tables,
    })
}

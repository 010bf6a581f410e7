//! SINUMERIK 840D/828D: leadscrew/encoder error compensation (EEC) per axis and cross
//! error compensation (CEC), each loaded as an `_INI` part program of assignments
//! (Function Manual K3; `../shared/notes/legacy-controllers.md` section 3).
//!
//! * EEC: `$AA_ENC_COMP[0,N,AX]` for N = 0 .. (MAX - MIN) / STEP with `_STEP`, `_MIN`,
//!   `_MAX`, `_IS_MODULO` (measuring system 0). Linear between points, the first value
//!   held below MIN and the last above MAX. A positive value moves the axis negative: the
//!   table holds the error (actual minus commanded, mm).
//! * CEC: table t `$AN_CEC[t,N]` with `_INPUT_AXIS` (its setpoint is the input),
//!   `_OUTPUT_AXIS`, `_STEP`, `_MIN`, `_MAX`, `_DIRECTION` (0 both, 1 positive only, -1
//!   negative only), `_MULT_BY_TABLE` (k: times table k - 1), `_IS_MODULO`; the tables
//!   of an axis add up. Sign as EEC.
//!
//! From a 2-D map: each axis's EEC holds its error as a function of its own position
//! (the mean over the other axis: the least-squares part of the map one table holds);
//! within the CEC budget (the 828D: 8 tables of 200 points), in this order: the cross
//! terms (X's error as a function of Y: squareness; Y's as a function of X:
//! straightness), the direction-dependent part of each axis (half the forward/reverse
//! difference, a table per direction: what EEC, one table for both directions, cannot
//! hold), then, with a multiplier mode chosen, products of two tables (a rank-one fit of
//! what is left). The share of the map the set expresses is reported.

use super::controller::{
    fit, identity_line, positions, regular, ControllerTables, Curve, Profiles, Shape, Term,
};
use super::ExportError;
use crate::{Approach, MapModel};
use std::fmt::Write;

/// What the manual leaves open about `$AN_CEC_MULT_BY_TABLE`: whether the table used
/// only as a multiplier also adds its own output.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CecMultiplier {
    /// No products (the default: the manuals leave both details open).
    #[default]
    Off,
    /// Products, the multiplier table's own output also added (the writer cancels it in
    /// the EEC of that axis).
    OwnOutputAdded,
    /// Products, the multiplier table adds nothing of its own.
    OwnOutputNotAdded,
}

impl std::str::FromStr for CecMultiplier {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "off" => Ok(Self::Off),
            "own-output-added" => Ok(Self::OwnOutputAdded),
            "own-output-not-added" => Ok(Self::OwnOutputNotAdded),
            other => Err(format!(
                "`{other}`: off, own-output-added or own-output-not-added"
            )),
        }
    }
}

impl CecMultiplier {
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Off => "off",
            Self::OwnOutputAdded => "own-output-added",
            Self::OwnOutputNotAdded => "own-output-not-added",
        }
    }
}

/// The products' fit holds the map's residual at every pair of X and Y table points
/// (8 bytes each): at most 32 MB.
pub const MAX_PRODUCT_PAIRS: usize = 4_000_000;

#[derive(Debug, Clone, PartialEq)]
pub struct SiemensOptions {
    /// Machine axis names of X and Y (`X1`, `Y1`; `AX1`, `AX2` on some machines).
    pub axes: [String; 2],
    /// Points per table: MD38000 `MM_ENC_COMP_MAX_POINTS` (EEC) and MD18342
    /// `MM_CEC_MAX_POINTS` (CEC) as set on the machine (828D: 200).
    pub points: usize,
    /// CEC tables available (828D: 8); 0 writes none.
    pub cec_tables: usize,
    pub multiplier: CecMultiplier,
}

impl Default for SiemensOptions {
    fn default() -> Self {
        Self {
            axes: ["X1".into(), "Y1".into()],
            points: 200,
            cec_tables: 8,
            multiplier: CecMultiplier::Off,
        }
    }
}

/// An axis name the control accepts in a system variable: a letter, then letters or
/// digits, at most 8.
fn check_axis(name: &str) -> Result<(), ExportError> {
    let ok = (1..=8).contains(&name.len())
        && name.as_bytes()[0].is_ascii_uppercase()
        && name
            .bytes()
            .all(|b| b.is_ascii_uppercase() || b.is_ascii_digit());
    if ok {
        Ok(())
    } else {
        Err(ExportError::Options(format!(
            "Siemens axis name {name:?}: a capital letter then capitals or digits, at most 8 (X1, AX1)"
        )))
    }
}

/// One table's points.
struct Table {
    curve: Curve,
    step: f64,
}

impl Table {
    fn min(&self) -> f64 {
        self.curve.positions[0]
    }
    fn max(&self) -> f64 {
        self.curve.positions[self.curve.positions.len() - 1]
    }
}

struct Cec {
    table: Table,
    output: usize,
    direction: i8,
    /// Index of the table it is multiplied by.
    times: Option<usize>,
    /// Serves as another table's multiplier.
    multiplier: bool,
    what: String,
}

/// The EEC tables (and, with `cec`, the CEC set) of the map.
pub fn siemens(
    model: &MapModel,
    options: &SiemensOptions,
    cec: bool,
) -> Result<ControllerTables, ExportError> {
    for a in &options.axes {
        check_axis(a)?;
    }
    let (lo, hi) = model.extent();
    let profiles = Profiles::new(model);
    let mut geometry = [(0.0, 0), (0.0, 0)];
    for k in 0..2 {
        geometry[k] = regular("Siemens", lo[k], hi[k], options.points)?;
    }
    let grid = |k: usize| positions(lo[k], geometry[k].0, geometry[k].1);
    let table = |input: usize, values: Vec<f64>| Table {
        curve: Curve {
            input,
            positions: grid(input),
            values_mm: values,
            shape: Shape::Linear,
        },
        step: geometry[input].0,
    };
    let profile =
        |component: usize, input: usize, a: Option<Approach>| -> Result<Vec<f64>, ExportError> {
            grid(input)
                .iter()
                .map(|&s| Ok(profiles.mean(model, component, input, s, a)?))
                .collect()
        };
    // EEC: each axis's error along itself.
    let mut eec = [
        table(0, profile(0, 0, None)?),
        table(1, profile(1, 1, None)?),
    ];
    let mut cecs: Vec<Cec> = Vec::new();
    if cec {
        let budget = options.cec_tables;
        let names = ["X", "Y"];
        // Cross terms: the component's mean along the other axis, less its overall mean
        // (which the EEC holds).
        for (output, input) in [(0usize, 1usize), (1, 0)] {
            if cecs.len() >= budget {
                break;
            }
            let overall = profiles.overall(model, output)?;
            let values = profile(output, input, None)?
                .into_iter()
                .map(|v| v - overall)
                .collect();
            cecs.push(Cec {
                table: table(input, values),
                output,
                direction: 0,
                times: None,
                multiplier: false,
                what: format!(
                    "{}'s error as a function of {} (squareness, straightness)",
                    names[output], names[input]
                ),
            });
        }
        // Direction: forward and reverse less the mean the EEC holds.
        for axis in 0..2 {
            for (direction, a) in [(1i8, Approach::Forward), (-1, Approach::Reverse)] {
                if cecs.len() >= budget {
                    break;
                }
                let side = profile(axis, axis, Some(a))?;
                let values = side
                    .iter()
                    .zip(&eec[axis].curve.values_mm)
                    .map(|(s, m)| s - m)
                    .collect();
                cecs.push(Cec {
                    table: table(axis, values),
                    output: axis,
                    direction,
                    times: None,
                    multiplier: false,
                    what: format!(
                        "{}'s error moving {} less the EEC's mean (backlash)",
                        names[axis],
                        if direction > 0 { "in +" } else { "in -" }
                    ),
                });
            }
        }
        if options.multiplier != CecMultiplier::Off {
            let pairs = geometry[0].1 * geometry[1].1;
            if pairs > MAX_PRODUCT_PAIRS {
                return Err(ExportError::Options(format!(
                    "Siemens CEC products fit the map at every pair of X and Y points: {} x {} = {pairs}, at most {MAX_PRODUCT_PAIRS} (fewer points per table)",
                    geometry[0].1, geometry[1].1
                )));
            }
            products(model, options, &mut eec, &mut cecs, &grid, &table)?;
        }
    }
    // What the set holds.
    let mut terms: Vec<Term> = eec
        .iter()
        .enumerate()
        .map(|(axis, t)| Term::plain(axis, t.curve.clone()))
        .collect();
    for c in &cecs {
        let only = match c.direction {
            1 => Some(Approach::Forward),
            -1 => Some(Approach::Reverse),
            _ => None,
        };
        if c.multiplier {
            // A multiplier: adds itself only in that mode.
            if options.multiplier == CecMultiplier::OwnOutputAdded {
                terms.push(Term::plain(c.output, c.table.curve.clone()));
            }
            continue;
        }
        terms.push(Term {
            output: c.output,
            curve: c.table.curve.clone(),
            only,
            times: c.times.map(|k| cecs[k].table.curve.clone()),
        });
    }
    let fit = fit(model, &terms, [0.0; 2])?;
    // The files.
    let ax = &options.axes;
    let mut settings = Vec::new();
    let mut files = Vec::new();
    for (axis, t) in eec.iter().enumerate() {
        let name = &ax[axis];
        let n = t.curve.positions.len();
        let lines = vec![
            format!("MD38000 MM_ENC_COMP_MAX_POINTS[0] of {name} >= {n} (a change reformats the compensation memory at the next POWER ON: load the table after it)"),
            format!("MD32700 ENC_COMP_ENABLE[0] of {name} = 0 while loading, then 1; POWER ON and reference {name}: the table acts once the axis is referenced"),
        ];
        let mut text = String::new();
        let _ = writeln!(text, "%_N_{name}_EEC_INI");
        let _ = writeln!(
            text,
            "; EEC of machine axis {name} from the gateway's error map ({})",
            identity_line(model)
        );
        let _ = writeln!(text, "; values: the axis's error in mm (actual - commanded); the control moves the axis by minus the value");
        let _ = writeln!(
            text,
            "; linear between points, the first value held below MIN and the last above MAX"
        );
        for l in &lines {
            let _ = writeln!(text, "; set: {l}");
        }
        let _ = writeln!(text, "CHANDATA(1)");
        for (i, v) in t.curve.values_mm.iter().enumerate() {
            let _ = writeln!(text, "$AA_ENC_COMP[0,{i},{name}]={v:.6}");
        }
        let _ = writeln!(text, "$AA_ENC_COMP_STEP[0,{name}]={:.3}", t.step);
        let _ = writeln!(text, "$AA_ENC_COMP_MIN[0,{name}]={:.3}", t.min());
        let _ = writeln!(text, "$AA_ENC_COMP_MAX[0,{name}]={:.3}", t.max());
        let _ = writeln!(text, "$AA_ENC_COMP_IS_MODULO[0,{name}]=0");
        let _ = writeln!(text, "M17");
        files.push((["x", "y"][axis].to_string(), text));
        settings.extend(lines);
    }
    let mut tables: Vec<String> = eec
        .iter()
        .enumerate()
        .map(|(axis, t)| {
            format!(
                "EEC {}: {} points every {:.3} mm from {:.3} to {:.3} mm",
                ax[axis],
                t.curve.positions.len(),
                t.step,
                t.min(),
                t.max()
            )
        })
        .collect();
    if cec {
        let count = cecs.len();
        let max_n = cecs
            .iter()
            .map(|c| c.table.curve.positions.len())
            .max()
            .unwrap_or(0);
        let lines = vec![
            format!("MD18342 MM_CEC_MAX_POINTS[t] >= {max_n} for t = 0..{} (the 828D has 8 tables of 200 points, fixed)", count.saturating_sub(1)),
            format!("MD32710 CEC_ENABLE of {} and {} = 0 while loading, then 1", ax[0], ax[1]),
            format!("SD41300 CEC_TABLE_ENABLE[t] = 1 for t = 0..{}", count.saturating_sub(1)),
            "POWER ON and reference the axes: the tables act once stored, enabled and referenced".to_string(),
        ];
        let mut text = String::new();
        let _ = writeln!(text, "%_N_NC_CEC_INI");
        let _ = writeln!(
            text,
            "; CEC tables from the gateway's error map ({})",
            identity_line(model)
        );
        let _ = writeln!(text, "; values: the output axis's error in mm; the control moves it by minus the sum of its tables");
        for l in &lines {
            let _ = writeln!(text, "; set: {l}");
        }
        for (t, c) in cecs.iter().enumerate() {
            let _ = writeln!(text, "; table {t}: {}", c.what);
        }
        let _ = writeln!(text, "CHANDATA(1)");
        for (t, c) in cecs.iter().enumerate() {
            for (i, v) in c.table.curve.values_mm.iter().enumerate() {
                let _ = writeln!(text, "$AN_CEC[{t},{i}]={v:.6}");
            }
            let _ = writeln!(
                text,
                "$AN_CEC_INPUT_AXIS[{t}]=({})",
                ax[c.table.curve.input]
            );
            let _ = writeln!(text, "$AN_CEC_OUTPUT_AXIS[{t}]=({})", ax[c.output]);
            let _ = writeln!(text, "$AN_CEC_STEP[{t}]={:.3}", c.table.step);
            let _ = writeln!(text, "$AN_CEC_MIN[{t}]={:.3}", c.table.min());
            let _ = writeln!(text, "$AN_CEC_MAX[{t}]={:.3}", c.table.max());
            let _ = writeln!(text, "$AN_CEC_DIRECTION[{t}]={}", c.direction);
            let _ = writeln!(
                text,
                "$AN_CEC_MULT_BY_TABLE[{t}]={}",
                c.times.map_or(0, |k| k + 1)
            );
            let _ = writeln!(text, "$AN_CEC_IS_MODULO[{t}]=0");
        }
        let _ = writeln!(text, "M17");
        files.push(("cec".to_string(), text));
        settings.extend(lines);
        for (t, c) in cecs.iter().enumerate() {
            tables.push(format!(
                "CEC {t}: {} -> {}, {} points, direction {}{}: {}",
                ax[c.table.curve.input],
                ax[c.output],
                c.table.curve.positions.len(),
                c.direction,
                c.times
                    .map_or(String::new(), |k| format!(", times table {k}")),
                c.what
            ));
        }
    }
    Ok(ControllerTables {
        files,
        settings,
        fit,
        zero_not_held_um: [0.0; 2],
        tables,
    })
}

/// Products of two tables for what the EEC and CEC tables so far leave, each a rank-one
/// fit (power iteration) of the larger component's residual on the tables' points: table
/// A (input the other axis) times table B (input the component's own axis, scaled to at
/// most 1 in size); two tables each, while the budget lasts.
fn products(
    model: &MapModel,
    options: &SiemensOptions,
    eec: &mut [Table; 2],
    cecs: &mut Vec<Cec>,
    grid: &dyn Fn(usize) -> Vec<f64>,
    table: &dyn Fn(usize, Vec<f64>) -> Table,
) -> Result<(), ExportError> {
    let names = ["X", "Y"];
    while cecs.len() + 2 <= options.cec_tables {
        // The residual of each component on the tables' points (mean of both directions).
        let mut best: Option<(f64, usize, Vec<Vec<f64>>)> = None;
        for o in 0..2 {
            let (own, other) = (grid(o), grid(1 - o));
            let mut r = vec![vec![0.0; own.len()]; other.len()];
            let mut norm = 0.0;
            for (j, &t) in other.iter().enumerate() {
                for (i, &s) in own.iter().enumerate() {
                    let mut p = [0.0; 2];
                    p[o] = s;
                    p[1 - o] = t;
                    let e = (model.tool_error_um(p, crate::Direction::FORWARD)?[o]
                        + model.tool_error_um(p, crate::Direction::REVERSE)?[o])
                        / 2000.0;
                    let mut held = eec[o].curve.at(s);
                    // Both directions' tables cancel in the mean; a multiplier's own
                    // output is cancelled in the EEC (or not added at all).
                    for c in cecs
                        .iter()
                        .filter(|c| c.output == o && c.direction == 0 && !c.multiplier)
                    {
                        let mut v = c.table.curve.at(p[c.table.curve.input]);
                        if let Some(k) = c.times {
                            v *= cecs[k].table.curve.at(p[cecs[k].table.curve.input]);
                        }
                        held += v;
                    }
                    r[j][i] = e - held;
                    norm += r[j][i] * r[j][i];
                }
            }
            if best.as_ref().is_none_or(|b| norm > b.0) {
                best = Some((norm, o, r));
            }
        }
        let Some((norm, o, r)) = best else { break };
        if norm <= 0.0 {
            break;
        }
        // r[j][i] ~ f[j] g[i].
        let mut g = vec![1.0; r[0].len()];
        let mut f = vec![0.0; r.len()];
        for _ in 0..50 {
            let gg: f64 = g.iter().map(|v| v * v).sum();
            for (j, row) in r.iter().enumerate() {
                f[j] = row.iter().zip(&g).map(|(a, b)| a * b).sum::<f64>() / gg;
            }
            let ff: f64 = f.iter().map(|v| v * v).sum();
            if ff == 0.0 {
                break;
            }
            for (i, gi) in g.iter_mut().enumerate() {
                *gi = r.iter().zip(&f).map(|(row, fj)| row[i] * fj).sum::<f64>() / ff;
            }
        }
        let gmax = g.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if gmax == 0.0 {
            break;
        }
        g.iter_mut().for_each(|v| *v /= gmax);
        f.iter_mut().for_each(|v| *v *= gmax);
        if options.multiplier == CecMultiplier::OwnOutputAdded {
            for (v, gi) in eec[o].curve.values_mm.iter_mut().zip(&g) {
                *v -= gi;
            }
        }
        let b = cecs.len();
        cecs.push(Cec {
            table: table(o, g),
            output: o,
            direction: 0,
            times: None,
            multiplier: true,
            what: format!(
                "factor of {}'s product term, a function of {} (at most 1)",
                names[o], names[o]
            ),
        });
        cecs.push(Cec {
            table: table(1 - o, f),
            output: o,
            direction: 0,
            times: Some(b),
            multiplier: false,
            what: format!(
                "{}'s error left by the tables above, as a function of {} times table {b}",
                names[o],
                names[1 - o]
            ),
        });
    }
    Ok(())
}

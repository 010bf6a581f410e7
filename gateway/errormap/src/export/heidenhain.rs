//! Heidenhain nonlinear axis error compensation, two generations:
//!
//! * TNC 4xx/6xx: a `.CMA` file assigns `.COM` tables to axes; a `.COM` assigned under
//!   an axis's column of the `.CMA` holds, per entry (at most 256), the position of that
//!   axis (`AXISPOS`, from the machine datum) and one column per compensated axis:
//!   [column axis] = F([`.CMA` axis]), linear between entries, and a `BACKLASH` column of
//!   negative-direction values. Written here: `NAME_x.com` (X = F(X) with its BACKLASH,
//!   Y = F(X): X's straightness), `NAME_y.com` (X = F(Y): the squareness, Y = F(Y) with
//!   its BACKLASH) and `NAME.cma` with one active line assigning them.
//!   The literal layout is not published: it follows the TNC's `.TAB` tables
//!   (`BEGIN name MM`, a header line of columns, `NR` per entry, `[END]`); BACKLASH is
//!   read as the value added to the axis's own column while the axis moves in - (so the
//!   axis column holds the + direction). Both are our reading: confirm on the control.
//! * TNC 306/360 (64 values): per axis one dependency `X=F(X)`, a datum (distance from
//!   the machine datum) where the value must be 0, a spacing of 2^SETUP um (SETUP at most
//!   23), adjacent values at most spacing / 64 apart, linear between values. The map's
//!   error at the datum is therefore not held (the reference holds it).
//!
//! Neither format takes comments: what to set is returned for the command's output. The
//! values' sign is open in the manuals: `sign` (default [`ValueSign::Correction`]).

use super::controller::{
    fit, positions, regular, ControllerTables, Curve, Profiles, Shape, Term, ValueSign,
};
use super::ExportError;
use crate::{Approach, MapModel};
use std::fmt::Write;

/// Entries of a `.COM` table.
pub const HEIDENHAIN_COM_MAX_ENTRIES: usize = 256;
/// Values of a TNC 306/360 table.
pub const HEIDENHAIN_OLD_VALUES: usize = 64;
/// The largest spacing exponent of a TNC 306/360 table (2^23 um).
pub const HEIDENHAIN_OLD_MAX_EXPONENT: u32 = 23;

/// The files of a `.COM`/`.CMA` set, as the `.CMA` names them: `STEM_X.COM`,
/// `STEM_Y.COM`, `STEM.CMA` (upper case, as the TNC lists its files).
pub fn com_file_names(stem: &str) -> [String; 3] {
    let s = stem.to_uppercase();
    [
        format!("{s}_X.COM"),
        format!("{s}_Y.COM"),
        format!("{s}.CMA"),
    ]
}

/// The `.COM`/`.CMA` files of the map, named by [`com_file_names`].
pub fn heidenhain_com(
    model: &MapModel,
    stem: &str,
    entries: usize,
    sign: ValueSign,
) -> Result<ControllerTables, ExportError> {
    if stem.is_empty()
        || stem.len() > 16
        || !stem.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_')
    {
        return Err(ExportError::Options(format!(
            "Heidenhain file name {stem:?}: 1 to 16 letters, digits or _"
        )));
    }
    if !(2..=HEIDENHAIN_COM_MAX_ENTRIES).contains(&entries) {
        return Err(ExportError::Options(format!(
            "Heidenhain .COM: {entries} entries; a table holds 2 to {HEIDENHAIN_COM_MAX_ENTRIES}"
        )));
    }
    let (lo, hi) = model.extent();
    let profiles = Profiles::new(model);
    let names = ["X", "Y"];
    let mut files = Vec::new();
    let mut terms = Vec::new();
    let mut tables = Vec::new();
    let [x_com, y_com, cma_name] = com_file_names(stem);
    let com_names = [x_com, y_com];
    for input in 0..2 {
        let (step, n) = regular("Heidenhain .COM", lo[input], hi[input], entries)?;
        let at = positions(lo[input], step, n);
        // Columns, as errors (mm): the input axis's own (+ direction) and its BACKLASH
        // (- minus +), the other axis's mean less its overall mean (the own table of the
        // other axis holds that).
        let mut own = Vec::with_capacity(n);
        let mut backlash = Vec::with_capacity(n);
        let mut cross = Vec::with_capacity(n);
        let other = 1 - input;
        let overall = profiles.overall(model, other)?;
        for &s in &at {
            let f = profiles.mean(model, input, input, s, Some(Approach::Forward))?;
            let r = profiles.mean(model, input, input, s, Some(Approach::Reverse))?;
            own.push(round4(f));
            backlash.push(round4(r) - round4(f));
            cross.push(round4(
                profiles.mean(model, other, input, s, None)? - overall,
            ));
        }
        let curve = |values: Vec<f64>| Curve {
            input,
            positions: at.clone(),
            values_mm: values,
            shape: Shape::Linear,
        };
        terms.push(Term::plain(input, curve(own.clone())));
        terms.push(Term {
            output: input,
            curve: curve(backlash.clone()),
            only: Some(Approach::Reverse),
            times: None,
        });
        terms.push(Term::plain(other, curve(cross.clone())));
        let mut text = String::new();
        let _ = writeln!(text, "BEGIN {} MM", com_names[input]);
        let _ = writeln!(
            text,
            "{:<6}{:<14}{:<14}{:<14}BACKLASH",
            "NR", "AXISPOS", "X", "Y"
        );
        for i in 0..n {
            let (x, y) = if input == 0 {
                (own[i], cross[i])
            } else {
                (cross[i], own[i])
            };
            let _ = writeln!(
                text,
                "{:<6}{:<14}{:<14}{:<14}{}",
                i,
                format!("{:+.4}", at[i]),
                signed4(sign.apply(x)),
                signed4(sign.apply(y)),
                signed4(sign.apply(backlash[i])),
            );
        }
        let _ = writeln!(text, "[END]");
        files.push((com_names[input].clone(), text));
        tables.push(format!(
            "{}: {n} entries every {step:.3} mm from {:.3}: X = F({n0}), Y = F({n0}), BACKLASH of {n0}",
            com_names[input],
            lo[input],
            n0 = names[input]
        ));
    }
    let mut cma = String::new();
    let _ = writeln!(cma, "BEGIN {cma_name}");
    let _ = writeln!(cma, "{:<6}{:<24}{:<24}ACTIVE", "NR", "X", "Y");
    // Line 0, active.
    let _ = writeln!(cma, "{:<6}{:<24}{:<24}*", 0, com_names[0], com_names[1]);
    let _ = writeln!(cma, "[END]");
    files.push((cma_name, cma));
    let fit = fit(model, &terms, [0.0; 2])?;
    let settings = vec![
        format!("copy {}, {} and {} to the control (PLC-programming mode's data interface on a TNC 4xx, where they travel as .S/.V)", com_names[0], com_names[1], files[2].0),
        "nonlinear compensation on for X and Y (TNC 4xx: MP730; TNC 6xx: the axis compensation configuration), then activate line 0 of the .CMA (soft key, or PLC module 9095)".to_string(),
        format!("values: {} in mm (the manuals leave the sign open: confirm with one point); BACKLASH read as added while the axis moves in -", sign.as_str()),
    ];
    Ok(ControllerTables {
        files,
        settings,
        fit,
        zero_not_held_um: [0.0; 2],
        tables,
    })
}

fn round4(mm: f64) -> f64 {
    (mm * 10_000.0).round() / 10_000.0
}

/// `+0.0012`, never `-0.0000`.
fn signed4(mm: f64) -> String {
    format!("{:+.4}", round4(mm) + 0.0)
}

/// The TNC 306/360 tables, `X=F(X)` and `Y=F(Y)` (file suffixes `x`, `y`).
pub fn heidenhain_64(model: &MapModel, sign: ValueSign) -> Result<ControllerTables, ExportError> {
    let (lo, hi) = model.extent();
    let profiles = Profiles::new(model);
    let mut files = Vec::new();
    let mut terms = Vec::new();
    let mut zero = [0.0; 2];
    let mut tables = Vec::new();
    for k in 0..2 {
        let name = ["X", "Y"][k];
        let span_um = (hi[k] - lo[k]) * 1000.0;
        let Some(exponent) = (0..=HEIDENHAIN_OLD_MAX_EXPONENT)
            .find(|&e| (HEIDENHAIN_OLD_VALUES - 1) as f64 * f64::from(1u32 << e) >= span_um)
        else {
            return Err(ExportError::Options(format!(
                "Heidenhain 64-value table of {name}: {:.1} mm do not fit 63 spacings of at most 2^{HEIDENHAIN_OLD_MAX_EXPONENT} um",
                span_um / 1000.0
            )));
        };
        let spacing = f64::from(1u32 << exponent) / 1000.0;
        let count = ((hi[k] - lo[k]) / spacing).ceil() as usize + 1;
        let at = positions(lo[k], spacing, count.min(HEIDENHAIN_OLD_VALUES));
        let datum = profiles.mean(model, k, k, lo[k], None)?;
        zero[k] = datum * 1000.0;
        let errors: Vec<f64> = at
            .iter()
            .map(|&s| Ok(round4(profiles.mean(model, k, k, s, None)? - datum)))
            .collect::<Result<_, ExportError>>()?;
        let limit = spacing / 64.0;
        for (i, w) in errors.windows(2).enumerate() {
            if (w[1] - w[0]).abs() > limit + 1e-9 {
                return Err(ExportError::Options(format!(
                    "Heidenhain 64-value table of {name}: values {i} and {} differ by {:.4} mm, more than the spacing / 64 = {limit:.4} mm the control accepts",
                    i + 1,
                    (w[1] - w[0]).abs()
                )));
            }
        }
        terms.push(Term::plain(
            k,
            Curve {
                input: k,
                positions: at.clone(),
                values_mm: errors.clone(),
                shape: Shape::Linear,
            },
        ));
        let mut text = String::new();
        let _ = writeln!(text, "{name}=F({name})");
        let _ = writeln!(text, "DATUM POINT {name}{:+.3}", lo[k]);
        let _ = writeln!(text, "SETUP {exponent}");
        for (i, (s, e)) in at.iter().zip(&errors).enumerate() {
            let _ = writeln!(
                text,
                "{i} {name}{:+.3} {name}{:+.4}",
                s - lo[k],
                sign.apply(*e)
            );
        }
        files.push((["x", "y"][k].to_string(), text));
        tables.push(format!(
            "{name}=F({name}): {} values every 2^{exponent} um = {spacing} mm from the datum {:.3} mm",
            at.len(),
            lo[k]
        ));
    }
    let fit = fit(model, &terms, zero)?;
    let settings = vec![
        "enter each table on the control's compensation page (TNC 306/360: one dependency per axis, X=F(X) and Y=F(Y))".to_string(),
        format!("values: {} in mm, positions from the datum point (the manuals leave the sign open: confirm with one point)", sign.as_str()),
        format!("the value at the datum is 0: the map's {:.2} um (X) and {:.2} um (Y) there belong to the reference", zero[0], zero[1]),
    ];
    Ok(ControllerTables {
        files,
        settings,
        fit,
        zero_not_held_um: zero,
        tables,
    })
}

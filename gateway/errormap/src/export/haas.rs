//! Haas lead screw compensation: per axis a value every 0.5 in of machine coordinate, in
//! inches at 0.0001 in, entry 0 at machine zero and the entries at increasingly negative
//! positions (Haas machine coordinates are negative over the travel); the control
//! interpolates them into its own 256-entry table spaced by Parameter 58, within +-127
//! encoder steps (the inch limit follows the steps per inch, Parameters 5, 19, 33).
//!
//! No transfer format for these values is published: the writer makes the listing the
//! engineer keys in on the control's lead screw compensation page, one file per axis.
//! Haas machine zero is taken at the map's upper end of each axis (the axis pointing the
//! same way), so entry k is at the map's upper end less k x 12.7 mm. The sign is open:
//! `sign` (default [`ValueSign::Correction`]).

use super::controller::{fit, ControllerTables, Curve, Profiles, Shape, Term, ValueSign};
use super::ExportError;
use crate::MapModel;
use std::fmt::Write;

/// Inches between entries.
pub const HAAS_SPACING_IN: f64 = 0.5;
/// The largest value in encoder steps.
pub const HAAS_MAX_STEPS: f64 = 127.0;
const MM_PER_IN: f64 = 25.4;

/// `steps_per_inch` per axis (Parameters 5 and 19) checks the +-127 steps; without it
/// the limit is reported as not checked.
pub fn haas(
    model: &MapModel,
    sign: ValueSign,
    steps_per_inch: Option<[f64; 2]>,
) -> Result<ControllerTables, ExportError> {
    let (lo, hi) = model.extent();
    let profiles = Profiles::new(model);
    let mut files = Vec::new();
    let mut terms = Vec::new();
    let mut tables = Vec::new();
    for k in 0..2 {
        let name = ["X", "Y"][k];
        let spacing = HAAS_SPACING_IN * MM_PER_IN;
        let count = ((hi[k] - lo[k]) / spacing).ceil() as usize + 1;
        let mut text = String::new();
        let _ = writeln!(
            text,
            "HAAS LEAD SCREW COMPENSATION {name}: key in on the control's lead screw compensation page"
        );
        let _ = writeln!(
            text,
            "machine zero = map {name} {:.3} mm; values: {} in inches",
            hi[k],
            sign.as_str()
        );
        let _ = writeln!(text, "ENTRY  MACHINE_IN  VALUE_IN");
        let mut at = Vec::with_capacity(count);
        let mut errors = Vec::with_capacity(count);
        for i in 0..count {
            // + 0.0: entry 0 is at 0, not -0.
            let machine_in = -(i as f64 * HAAS_SPACING_IN) + 0.0;
            let s = hi[k] + machine_in * MM_PER_IN;
            let e_in = profiles.mean(model, k, k, s, None)? / MM_PER_IN;
            // + 0.0: never -0.0000.
            let written = (sign.apply(e_in) * 10_000.0).round() / 10_000.0 + 0.0;
            if let Some(steps) = steps_per_inch {
                let limit = HAAS_MAX_STEPS / steps[k];
                if written.abs() > limit {
                    return Err(ExportError::Options(format!(
                        "Haas {name}: entry {i} needs {written:+.4} in, past the +-127 encoder steps ({limit:.4} in at {} steps per inch)",
                        steps[k]
                    )));
                }
            }
            let _ = writeln!(text, "{i:<7}{machine_in:<12.4}{written:+.4}");
            at.push(s);
            errors.push(sign.apply(written) * MM_PER_IN);
        }
        // Increasing positions for the interpolation.
        at.reverse();
        errors.reverse();
        terms.push(Term::plain(
            k,
            Curve {
                input: k,
                positions: at,
                values_mm: errors,
                shape: Shape::Linear,
            },
        ));
        files.push((["x", "y"][k].to_string(), text));
        tables.push(format!(
            "{name}: {count} entries, 0 to -{:.1} in from machine zero at map {name} = {:.3} mm",
            (count - 1) as f64 * HAAS_SPACING_IN,
            hi[k]
        ));
    }
    let fit = fit(model, &terms, [0.0; 2])?;
    let settings = vec![
        "key the values of each axis in on the lead screw compensation page (no transfer format for them is published)".to_string(),
        match steps_per_inch {
            Some(s) => format!("checked against +-127 encoder steps at {} (X) and {} (Y) steps per inch (Parameters 5 and 19)", s[0], s[1]),
            None => "+-127 encoder steps NOT checked: give the steps per inch of X and Y (Parameters 5 and 19)".to_string(),
        },
        "the control spreads the values into its 256-entry table spaced by Parameter 58: the travel must fit 256 x Parameter 58".to_string(),
        format!("values: {} in inches (the manuals leave the sign open: confirm with one point)", sign.as_str()),
    ];
    Ok(ControllerTables {
        files,
        settings,
        fit,
        zero_not_held_um: [0.0; 2],
        tables,
    })
}

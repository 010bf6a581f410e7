//! A job's result as a person reads it, by its kind (the service's page shows it).

use serde_json::Value;

/// The text a person reads of a job kind's result: the CLI's summary, shown by the
/// service's page above the result's numbers.
pub fn summary(kind: &str, result: &Value) -> Option<String> {
    Some(match kind {
        "compensate" => compensate_summary(result),
        "map" => crate::map::summary(result),
        "verify" => crate::verify::summary(result),
        "iso230" => crate::iso230::summary(result),
        "layout" => crate::layout::summary(result),
        "rotary" => crate::rotary::summary(result),
        _ => return None,
    })
}

/// A compensation's result in a few lines (the CLI prints its full per-target table).
fn compensate_summary(r: &Value) -> String {
    let um = |v: &Value| v.as_f64().map_or("-".to_string(), |x| format!("{x:.3}"));
    let figures = |key: &str| {
        let f = &r[key];
        format!(
            "mean {} um, rms {} um, max {} um",
            um(&f["mean"]),
            um(&f["rms"]),
            um(&f["max"])
        )
    };
    format!(
        "{} targets, {} converged; method {}\nerror before compensation: {}\nerror after compensation:  {}\n",
        r["targets"],
        r["converged"],
        r["method"].as_str().unwrap_or("-"),
        figures("before_um"),
        figures("after_um"),
    )
}

//! The compensation's result in a few lines (the other kinds' summaries live with their procedures).

use serde_json::Value;

/// A compensation's result in a few lines (the CLI prints its full per-target table).
pub(crate) fn compensate_summary(r: &Value) -> String {
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

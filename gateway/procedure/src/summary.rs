//! The compensation's result in a few lines (the other kinds' summaries live with their
//! procedures), and what several summaries share.

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

/// The files a result names (`files`), comma-separated.
pub(crate) fn files(r: &Value) -> String {
    let names: Vec<&str> = r["files"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(Value::as_str)
        .collect();
    names.join(", ")
}

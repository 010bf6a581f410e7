//! What several summaries share (each kind's summary lives with its procedure and reads
//! its typed result).

use serde_json::Value;

/// The files a result names (`files`), comma-separated. Only `volumetric` reads its
/// result as JSON still; a typed result joins its own `files`.
pub(crate) fn files(r: &Value) -> String {
    let names: Vec<&str> = r["files"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(Value::as_str)
        .collect();
    names.join(", ")
}

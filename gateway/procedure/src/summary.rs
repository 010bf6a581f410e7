//! What several summaries share (each kind's summary lives with its procedure and reads
//! its typed result).

use serde::Deserialize;
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

/// For a field that is absent, null or a value (`Option<Option<T>>` with
/// `skip_serializing_if = "Option::is_none"`): a null read back is `Some(None)`, not
/// absent.
pub(crate) fn present<'de, D, T>(d: D) -> Result<Option<Option<T>>, D::Error>
where
    D: serde::Deserializer<'de>,
    T: serde::Deserialize<'de>,
{
    Option::<T>::deserialize(d).map(Some)
}

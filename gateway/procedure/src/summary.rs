//! What several summaries share (each kind's summary lives with its procedure and reads
//! its typed result).

use serde::Deserialize;

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

#[cfg(test)]
mod tests {
    use crate::kinds::find;
    use serde_json::{json, Value};

    fn schema(kind: &str) -> Value {
        serde_json::to_value(find(kind).unwrap().result_schema()).unwrap()
    }

    /// The typed results' schemas name their fields (the API's documentation of each
    /// kind's result).
    #[test]
    fn the_result_schemas_name_their_fields() {
        for (kind, fields) in [
            ("board-make", &["board", "dots", "coded", "files"][..]),
            ("localize", &["x_mm", "y_mm", "points", "image", "code"]),
            ("map", &["frames", "grid", "version", "machine_time_s"]),
            ("verify", &["points", "residual_um", "rescan", "checks"]),
            ("reference", &["shift_um", "scale", "record", "written_to"]),
            ("rewrite", &["moves_compensated", "notes", "reference"]),
            ("dnc", &["sent_lines", "port", "tape_lines"]),
        ] {
            let s = schema(kind);
            // A flattened part makes it `allOf` its parts.
            let parts = match s["allOf"].as_array() {
                Some(parts) => parts.clone(),
                None => vec![s.clone()],
            };
            for f in fields {
                assert!(
                    parts.iter().any(|p| p["properties"][f].is_object()),
                    "{kind}.{f}: {s}"
                );
            }
        }
        // One of several shapes: a stopped test, or a session and the partial results.
        assert_eq!(schema("iso230")["oneOf"].as_array().map(Vec::len), Some(2));
        assert_eq!(schema("proxy")["oneOf"].as_array().map(Vec::len), Some(3));
        assert_eq!(schema("compensate")["type"], "object");
        // Whole: no reference to a schema it does not carry (a series of checks names
        // its own kind's).
        for kind in [
            "board-make",
            "localize",
            "map",
            "verify",
            "reference",
            "rewrite",
            "dnc",
            "iso230",
            "iso230-evaluate",
            "proxy",
        ] {
            let text = schema(kind).to_string();
            let refs = text.matches("\"$ref\"").count();
            let own = text.matches("#/components/schemas/VerifyResult").count();
            assert_eq!(refs, own, "{kind}: {text}");
        }
    }

    /// A result read back as its kind's type gives the summary (a stored record, the
    /// command line's text): a stopped run's partial result too.
    #[test]
    fn stopped_results_read_back_for_their_summaries() {
        let map = find("map").unwrap();
        let stopped = json!({"name": "m", "plan": "p", "frames": 40, "resumed_frames": 0,
            "grid": [2, 2], "lines": [3, 3], "passes": 2, "frames_taken": 12});
        assert_eq!(
            map.summary(&stopped),
            "12 of 40 frames are kept for the next scan of this plan\n"
        );
        let iso = find("iso230").unwrap();
        let stopped = json!({"measurements_taken": 7, "measurements_planned": 50});
        assert_eq!(
            iso.summary(&stopped),
            "stopped after 7 of 50 measurements (kept)\n"
        );
    }
}

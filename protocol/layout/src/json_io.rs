//! The JSON form of a layout:
//!
//! ```json
//! { "units": "mm", "width_mm": 1600,
//!   "parts": [ { "id": "front", "layer": "1", "attributes": { "size": "M" },
//!                "contours": [ [[0,0],[100,0],[100,50],[0,50]], [[10,10],[20,10],[20,20]] ] } ] }
//! ```
//!
//! The first contour of a part is its outer contour, the others its holes; a contour
//! does not repeat its first point. `units` may be left out; when present it must be
//! `"mm"`. `width_mm` (optional) is the material's width.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::model::{LayoutError, Part, Point};

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct JsonLayout {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    units: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    width_mm: Option<f64>,
    parts: Vec<JsonPart>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct JsonPart {
    id: String,
    #[serde(default, skip_serializing_if = "String::is_empty")]
    layer: String,
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    attributes: BTreeMap<String, String>,
    contours: Vec<Vec<Point>>,
}

/// The parts and the material width.
pub(crate) fn read(bytes: &[u8]) -> Result<(Vec<Part>, Option<f64>), LayoutError> {
    let syntax = |message: String| LayoutError::Syntax {
        format: "JSON",
        message,
    };
    let mut de = serde_json::Deserializer::from_slice(bytes);
    let doc: JsonLayout = serde_path_to_error::deserialize(&mut de).map_err(|e| {
        let path = e.path().to_string();
        syntax(format!("at `{path}`: {}", e.into_inner()))
    })?;
    // One layout per file: a second document pasted in is refused, not ignored.
    de.end()
        .map_err(|e| syntax(format!("after the layout: {e}")))?;
    if let Some(u) = &doc.units {
        if u != "mm" {
            return Err(syntax(format!("units `{u}`: only \"mm\" is accepted")));
        }
    }
    if let Some(w) = doc.width_mm {
        if !(w > 0.0 && w <= crate::model::MAX_COORDINATE_MM) {
            return Err(syntax(format!(
                "width_mm {w} must be a positive number of at most {} mm",
                crate::model::MAX_COORDINATE_MM
            )));
        }
    }
    let mut parts = Vec::with_capacity(doc.parts.len());
    for p in doc.parts {
        let mut contours = p.contours.into_iter();
        let outer = contours.next().ok_or_else(|| LayoutError::Part {
            part: p.id.clone(),
            message: "has no contour".into(),
        })?;
        parts.push(Part {
            id: p.id,
            outer,
            holes: contours.collect(),
            layer: p.layer,
            attributes: p.attributes,
        });
    }
    Ok((parts, doc.width_mm))
}

pub(crate) fn write(parts: &[Part], width_mm: Option<f64>) -> Result<Vec<u8>, LayoutError> {
    let doc = JsonLayout {
        units: Some("mm".into()),
        width_mm,
        parts: parts
            .iter()
            .map(|p| JsonPart {
                id: p.id.clone(),
                layer: p.layer.clone(),
                attributes: p.attributes.clone(),
                contours: std::iter::once(p.outer.clone())
                    .chain(p.holes.iter().cloned())
                    .collect(),
            })
            .collect(),
    };
    serde_json::to_vec_pretty(&doc).map_err(|e| LayoutError::Write {
        format: "JSON",
        message: e.to_string(),
    })
}

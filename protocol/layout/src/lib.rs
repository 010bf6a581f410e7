//! Cutting layouts as files: DXF, SVG paths and a JSON form, read and written sans-IO.
//!
//! A layout is a list of [`Part`]s; each keeps its id, its outer contour and its holes
//! (polygons in millimetres, X along the material's feed, Y across it), its layer and its
//! attributes. Curves are flattened on reading within a chord tolerance
//! ([`ReadOptions::chord_tolerance_mm`], 0.01 mm by default: no point of a chord is
//! farther than that from the true arc or spline).
//!
//! Writing moves parts, nothing else: [`Layout::translated`] shifts every part by its own
//! offset and [`Layout::write`] writes the layout in a [`Format`]. A DXF layout written
//! as DXF keeps its drawing (entities, blocks, layers, header) with only the parts'
//! coordinates changed; other combinations write the parts' flattened contours.

mod dxf_io;
mod flatten;
mod json_io;
mod svg_io;

use std::collections::BTreeMap;

use geo::{Coord, LineString, Polygon, Validation};
use serde::{Deserialize, Serialize};

pub use flatten::{arc_points, bulge_points, nurbs_points};

/// A point in millimetres: `[x, y]`, X along the feed, Y across the material.
pub type Point = [f64; 2];

/// One part of a layout.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Part {
    /// The part's name: a DXF block name (apparel CAD exports a piece as a block), the
    /// handle of a top-level DXF contour, an SVG element's `id`, or the JSON `id`.
    pub id: String,
    /// Outer contour, counter-clockwise or not (orientation is not used), without the
    /// closing point repeated.
    pub outer: Vec<Point>,
    /// Holes inside the outer contour.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub holes: Vec<Vec<Point>>,
    /// DXF layer or SVG class; empty when none.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub layer: String,
    /// Other attributes kept for writing back (SVG attributes, JSON `attributes`).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub attributes: BTreeMap<String, String>,
}

impl Part {
    /// The part as a `geo` polygon.
    pub fn polygon(&self) -> Polygon<f64> {
        fn ring(points: &[Point]) -> LineString<f64> {
            LineString::from(
                points
                    .iter()
                    .map(|p| Coord { x: p[0], y: p[1] })
                    .collect::<Vec<_>>(),
            )
        }
        Polygon::new(
            ring(&self.outer),
            self.holes.iter().map(|h| ring(h)).collect(),
        )
    }

    /// `[xmin, ymin, xmax, ymax]` of the outer contour.
    pub fn bounds(&self) -> [f64; 4] {
        let mut b = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        for p in &self.outer {
            b[0] = b[0].min(p[0]);
            b[1] = b[1].min(p[1]);
            b[2] = b[2].max(p[0]);
            b[3] = b[3].max(p[1]);
        }
        b
    }

    fn translate(&mut self, d: Point) {
        for p in self.outer.iter_mut().chain(self.holes.iter_mut().flatten()) {
            p[0] += d[0];
            p[1] += d[1];
        }
    }
}

/// The file formats a layout is read from and written to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    Dxf,
    Svg,
    Json,
}

impl Format {
    /// The format named by a file name's extension (`.dxf`, `.svg`, `.json`, any case).
    pub fn from_path(path: &str) -> Option<Format> {
        let ext = path.rsplit_once('.')?.1.to_ascii_lowercase();
        match ext.as_str() {
            "dxf" => Some(Format::Dxf),
            "svg" => Some(Format::Svg),
            "json" => Some(Format::Json),
            _ => None,
        }
    }
}

/// How curves are flattened on reading.
#[derive(Debug, Clone, Copy)]
pub struct ReadOptions {
    /// Largest distance between a chord and the arc or spline it replaces, in mm.
    pub chord_tolerance_mm: f64,
    /// Largest gap between the ends of LINE/ARC/open polyline pieces joined into one
    /// contour, in mm.
    pub join_tolerance_mm: f64,
}

impl Default for ReadOptions {
    fn default() -> Self {
        ReadOptions {
            chord_tolerance_mm: 0.01,
            join_tolerance_mm: 0.01,
        }
    }
}

/// Why a layout could not be read or written.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum LayoutError {
    #[error("{format}: {message}")]
    Syntax {
        format: &'static str,
        message: String,
    },
    #[error(
        "DXF: $INSUNITS is missing or unitless (0): the drawing's unit must be stated (4 = mm)"
    )]
    MissingUnits,
    #[error(
        "DXF: $INSUNITS = {0} is not a length unit this reader knows (1 in, 2 ft, 4 mm, 5 cm, 6 m)"
    )]
    UnsupportedUnits(String),
    #[error("{place}: {message}")]
    Entity { place: String, message: String },
    #[error("part `{part}`: {message}")]
    Part { part: String, message: String },
    #[error("the layout has no parts")]
    Empty,
    #[error("duplicate part id `{0}`")]
    DuplicateId(String),
    #[error("{0} offsets given for {1} parts")]
    OffsetCount(usize, usize),
    #[error("writing {format}: {message}")]
    Write {
        format: &'static str,
        message: String,
    },
}

/// Where a layout came from, so it can be written back the same way.
#[derive(Debug, Clone)]
enum Source {
    Parts,
    Dxf(Box<dxf_io::DxfSource>),
}

/// A cutting layout: its parts, and (for DXF) the drawing they came from.
#[derive(Debug, Clone)]
pub struct Layout {
    pub parts: Vec<Part>,
    /// Material width stated by the file (JSON `width_mm`), if any.
    pub width_mm: Option<f64>,
    source: Source,
}

impl Layout {
    /// A layout of these parts, checked like a file's.
    pub fn from_parts(parts: Vec<Part>, width_mm: Option<f64>) -> Result<Layout, LayoutError> {
        let layout = Layout {
            parts,
            width_mm,
            source: Source::Parts,
        };
        layout.check()?;
        Ok(layout)
    }

    /// Reads a layout of the given format.
    pub fn read(
        bytes: &[u8],
        format: Format,
        options: &ReadOptions,
    ) -> Result<Layout, LayoutError> {
        if !(options.chord_tolerance_mm > 0.0) || !(options.join_tolerance_mm >= 0.0) {
            return Err(LayoutError::Syntax {
                format: "options",
                message: "the chord tolerance must be > 0 and the join tolerance >= 0".into(),
            });
        }
        let layout = match format {
            Format::Json => json_io::read(bytes)?,
            Format::Svg => svg_io::read(bytes, options)?,
            Format::Dxf => dxf_io::read(bytes, options)?,
        };
        layout.check()?;
        Ok(layout)
    }

    /// Writes the layout in `format`.
    pub fn write(&self, format: Format) -> Result<Vec<u8>, LayoutError> {
        match format {
            Format::Json => json_io::write(self),
            Format::Svg => Ok(svg_io::write(self).into_bytes()),
            Format::Dxf => match &self.source {
                Source::Dxf(src) => src.write(),
                Source::Parts => dxf_io::write_parts(&self.parts),
            },
        }
    }

    /// The same layout with part `i` moved by `offsets[i]` (mm); for a DXF layout every
    /// entity of the part (or its INSERT) moves with it.
    pub fn translated(&self, offsets: &[Point]) -> Result<Layout, LayoutError> {
        if offsets.len() != self.parts.len() {
            return Err(LayoutError::OffsetCount(offsets.len(), self.parts.len()));
        }
        let mut out = self.clone();
        for (part, d) in out.parts.iter_mut().zip(offsets) {
            part.translate(*d);
        }
        if let Source::Dxf(src) = &mut out.source {
            src.translate(offsets);
        }
        Ok(out)
    }

    /// Every part is a closed, simple polygon with its holes inside, and ids are unique.
    fn check(&self) -> Result<(), LayoutError> {
        if self.parts.is_empty() {
            return Err(LayoutError::Empty);
        }
        let mut seen = std::collections::HashSet::new();
        for part in &self.parts {
            if !seen.insert(part.id.as_str()) {
                return Err(LayoutError::DuplicateId(part.id.clone()));
            }
            check_part(part)?;
        }
        Ok(())
    }
}

/// A part's contours: finite, at least 3 distinct points, no self-intersection, holes
/// inside the outer contour and apart from each other (`geo`'s OGC validity rules).
pub fn check_part(part: &Part) -> Result<(), LayoutError> {
    let bad = |message: String| LayoutError::Part {
        part: part.id.clone(),
        message,
    };
    for ring in std::iter::once(&part.outer).chain(&part.holes) {
        if ring.iter().any(|p| !p[0].is_finite() || !p[1].is_finite()) {
            return Err(bad("a coordinate is not a finite number".into()));
        }
    }
    let polygon = part.polygon();
    if let Some(problem) = polygon.validation_errors().into_iter().next() {
        return Err(bad(problem.to_string()));
    }
    Ok(())
}

#[cfg(test)]
mod tests;

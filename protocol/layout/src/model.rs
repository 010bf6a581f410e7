//! The layout's parts, formats, reading options and errors.

use std::collections::BTreeMap;

use geo::{Coord, LineString, Polygon};
use serde::{Deserialize, Serialize};

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

    pub(crate) fn translate(&mut self, d: Point) {
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

/// The largest coordinate of a part, mm: a kilometre, beyond any cutting table.
pub const MAX_COORDINATE_MM: f64 = 1e6;

/// The smallest width and height of a part, mm: a micrometre. Smaller contours are
/// rounding noise (a viewBox of 5e14 units on 200 mm makes parts of 1e-11 mm), not parts.
pub const MIN_SIZE_MM: f64 = 1e-3;

/// The first vertex where a closed ring reverses its direction (the edges before and after
/// it run back along one line). Such a spike has no width to cut; whether a validity
/// check sees it as a self-intersection depends on the last bits of the coordinates, so
/// the same part moved by a millimetre could be accepted once and refused the next time.
fn turns_back(ring: &[[f64; 2]]) -> Option<[f64; 2]> {
    // Distinct consecutive points, the closing point dropped.
    let mut pts: Vec<[f64; 2]> = Vec::with_capacity(ring.len());
    for &p in ring {
        if pts.last() != Some(&p) {
            pts.push(p);
        }
    }
    while pts.len() > 1 && pts.first() == pts.last() {
        pts.pop();
    }
    let n = pts.len();
    if n < 3 {
        return None;
    }
    (0..n).find_map(|i| {
        let (a, b, c) = (pts[(i + n - 1) % n], pts[i], pts[(i + 1) % n]);
        let u = [b[0] - a[0], b[1] - a[1]];
        let v = [c[0] - b[0], c[1] - b[1]];
        let cross = u[0] * v[1] - u[1] * v[0];
        let dot = u[0] * v[0] + u[1] * v[1];
        let lengths = u[0].hypot(u[1]) * v[0].hypot(v[1]);
        // Reversal within about a nanoradian: only rounding separates it from a spike.
        (dot < 0.0 && cross.abs() <= 1e-9 * lengths).then_some(b)
    })
}

/// A part's contours: finite, within a kilometre of the origin, at least a micrometre
/// across, at least 3 distinct points, no self-intersection and no zero-width spike, holes inside the outer contour and apart from each other (`geo`'s OGC validity rules).
pub fn check_part(part: &Part) -> Result<(), LayoutError> {
    let bad = |message: String| LayoutError::Part {
        part: part.id.clone(),
        message,
    };
    for ring in std::iter::once(&part.outer).chain(&part.holes) {
        if ring.iter().any(|p| !p[0].is_finite() || !p[1].is_finite()) {
            return Err(bad("a coordinate is not a finite number".into()));
        }
        if let Some(p) = ring
            .iter()
            .find(|p| !(p[0].abs() <= MAX_COORDINATE_MM && p[1].abs() <= MAX_COORDINATE_MM))
        {
            return Err(bad(format!(
                "the point ({}, {}) mm is more than {MAX_COORDINATE_MM} mm (1 km) from the origin",
                p[0], p[1]
            )));
        }
    }
    if part.outer.len() < 3 || part.holes.iter().any(|h| h.len() < 3) {
        return Err(bad("a contour has fewer than 3 points".into()));
    }
    for ring in std::iter::once(&part.outer).chain(&part.holes) {
        if let Some(at) = turns_back(ring) {
            return Err(bad(format!(
                "the contour turns back on itself at ({:.6}, {:.6}) mm (a zero-width spike)",
                at[0], at[1]
            )));
        }
    }
    let (lo, hi) = part.outer.iter().fold(
        ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]),
        |(lo, hi), p| {
            (
                [lo[0].min(p[0]), lo[1].min(p[1])],
                [hi[0].max(p[0]), hi[1].max(p[1])],
            )
        },
    );
    let (w, h) = (hi[0] - lo[0], hi[1] - lo[1]);
    if w < MIN_SIZE_MM || h < MIN_SIZE_MM {
        return Err(bad(format!(
            "the part is {w:.3e} x {h:.3e} mm, less than {MIN_SIZE_MM} mm across: nothing a cutter can cut"
        )));
    }
    crate::validity::check_polygon(&part.polygon()).map_err(bad)?;
    Ok(())
}

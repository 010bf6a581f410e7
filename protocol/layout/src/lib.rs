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
mod dxf_tidy;
mod flatten;
mod json_io;
mod layout;
mod model;
mod svg_io;
mod validity;

pub use flatten::{arc_points, bulge_points, nurbs_points};
pub use layout::Layout;
pub use model::{check_part, Format, LayoutError, Part, Point, ReadOptions};
pub use svg_io::MAX_ATTRIBUTES as MAX_SVG_ATTRIBUTES;

#[cfg(test)]
mod tests;

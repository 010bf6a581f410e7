//! A layout with where it came from, read, moved and written.

use crate::dxf_io::{self, DxfSource};
use crate::model::{check_part, Format, LayoutError, Part, Point, ReadOptions};
use crate::{json_io, svg_io};

/// Where a layout came from, so it can be written back the same way.
#[derive(Debug, Clone)]
enum Source {
    Parts,
    Dxf(Box<DxfSource>),
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
            Format::Json => {
                let (parts, width_mm) = json_io::read(bytes)?;
                Layout {
                    parts,
                    width_mm,
                    source: Source::Parts,
                }
            }
            Format::Svg => Layout {
                parts: svg_io::read(bytes, options)?,
                width_mm: None,
                source: Source::Parts,
            },
            Format::Dxf => {
                let (parts, src) = dxf_io::read(bytes, options)?;
                Layout {
                    parts,
                    width_mm: None,
                    source: Source::Dxf(Box::new(src)),
                }
            }
        };
        layout.check()?;
        Ok(layout)
    }

    /// Writes the layout in `format`.
    pub fn write(&self, format: Format) -> Result<Vec<u8>, LayoutError> {
        match format {
            Format::Json => json_io::write(&self.parts, self.width_mm),
            Format::Svg => Ok(svg_io::write(&self.parts).into_bytes()),
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

//! Cutting layouts (`layout-io`): DXF, SVG and JSON files as a user hands them over.

use layout_io::{check_part, Format, Layout, ReadOptions};

/// Reads `data` as `format`; an accepted layout has valid parts with unique ids, and is
/// written back (moved by 1 mm in X and Y) and read again: the same parts, the same ids.
fn read_write_read(data: &[u8], format: Format, exact: bool) {
    let Ok(layout) = Layout::read(data, format, &ReadOptions::default()) else {
        return;
    };
    assert!(!layout.parts.is_empty());
    for p in &layout.parts {
        check_part(p).expect("accepted parts are valid");
    }
    let moved = layout
        .translated(&vec![[1.0, 1.0]; layout.parts.len()])
        .expect("one offset per part");
    // A part moved past the largest coordinate is no longer a valid part.
    if moved.parts.iter().any(|p| check_part(p).is_err()) {
        return;
    }
    let written = moved.write(format).expect("an accepted layout is written");
    let Ok(again) = Layout::read(&written, format, &ReadOptions::default()) else {
        // Moving may bring a DXF contour's pieces within or out of the join tolerance of
        // another's only through rounding; the formats we write ourselves must read back.
        assert_eq!(
            format,
            Format::Dxf,
            "a written {format:?} layout reads back"
        );
        return;
    };
    if exact {
        assert_eq!(again.parts, moved.parts);
    } else if format == Format::Svg {
        let ids = |l: &Layout| l.parts.iter().map(|p| p.id.clone()).collect::<Vec<_>>();
        assert_eq!(ids(&again), ids(&moved));
    }
}

/// Any bytes as a DXF drawing (through the `dxf` crate, then our contour reading).
pub fn layout_dxf(data: &[u8]) {
    read_write_read(data, Format::Dxf, false);
}

/// Any bytes as an SVG layout.
pub fn layout_svg(data: &[u8]) {
    read_write_read(data, Format::Svg, false);
}

/// Any bytes as the layout JSON form: written back exactly.
pub fn layout_json(data: &[u8]) {
    read_write_read(data, Format::Json, true);
}

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

/// Any bytes as a layout JSON that a user partitions and cuts (`gateway layout cut`, the
/// service's layout job): 2 tools, a window 1.5 times the longest part, a gap of a
/// hundredth of the width, overlaps resolved with widening, then the cutter's stops. An
/// accepted partition leaves no overlap (the exhaustive check agrees), and a plan cuts
/// every group with parts exactly once, at conveyor stops that never go back.
pub fn layout_cut(data: &[u8]) {
    let Ok(doc) = Layout::read(data, Format::Json, &ReadOptions::default()) else {
        return;
    };
    let boxes: Vec<[f64; 4]> = doc.parts.iter().map(|p| p.bounds()).collect();
    let longest = boxes.iter().map(|b| b[2] - b[0]).fold(0.0f64, f64::max);
    let ymin = boxes.iter().map(|b| b[1]).fold(f64::INFINITY, f64::min);
    let ymax = boxes.iter().map(|b| b[3]).fold(f64::NEG_INFINITY, f64::max);
    let params = layout::Params {
        tools: 2,
        window_mm: 1.5 * longest,
        gap_mm: (ymax - ymin) / 100.0,
        width_mm: doc.width_mm,
        clearance_mm: None,
    };
    let Ok(mut partition) = layout::partition(&doc.parts, &params) else {
        return;
    };
    if layout::resolve_widening(&doc.parts, &mut partition, &[]).is_err() {
        return;
    }
    assert!(layout::detect_exhaustive(&doc.parts, &partition).is_empty());
    let cutter = layout::cut::CutterSpec::for_partition(&doc.parts, &partition);
    let Ok(stops) = layout::cut::plan(&doc.parts, &partition, &cutter) else {
        return;
    };
    let mut cut: Vec<usize> = stops
        .iter()
        .flat_map(|s| s.jobs.iter().map(|j| j.group))
        .collect();
    cut.sort_unstable();
    let mut want: Vec<usize> = partition
        .groups
        .iter()
        .filter(|g| !g.parts.is_empty())
        .map(|g| g.id)
        .collect();
    want.sort_unstable();
    assert_eq!(cut, want, "every group cut once");
    assert!(stops
        .windows(2)
        .all(|w| w[0].conveyor_mm <= w[1].conveyor_mm));
}

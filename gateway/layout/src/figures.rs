//! Material used by a layout: as nested (no gaps), as partitioned (gaps between groups),
//! and with a gap around every part.
//!
//! Lengths are along X from the layout's first Xmin, widths across from the lanes' lower
//! edge y0; a material's width is at least W. Area used = length x width; utilisation =
//! the parts' own area (holes taken out) / area used.
//!
//! The gap-around-every-part reference keeps the nest and puts one gap between every
//! two neighbouring parts along any line: a line along X that crosses n parts needs
//! n - 1 gaps, so the length grows by `gap x (nX - 1)` with nX the most parts any line
//! along X crosses (a part crosses the line y when its box's open Y interval holds y),
//! and the width by `gap x (nY - 1)` likewise. Example: three 10 x 10 mm squares side
//! by side along X, gap 5 mm: nX = 3, the length grows from 30 to 40 mm.

use geo::Area;
use layout_io::Part;
use serde::{Deserialize, Serialize};

use crate::Partition;

/// One way of laying the parts on the material.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Material {
    pub length_mm: f64,
    pub width_mm: f64,
    pub area_mm2: f64,
    pub utilisation: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Figures {
    pub parts_area_mm2: f64,
    pub no_gap: Material,
    pub partitioned: Material,
    pub gap_every_part: Material,
    pub added_length_partitioned_mm: f64,
    pub added_length_every_part_mm: f64,
    /// Width the partition adds to the nest as given (its lanes' DY), mm.
    pub added_width_partitioned_mm: f64,
    /// Added length of the partition / added length of a gap around every part (None
    /// when the latter is 0: a single part along every line).
    pub added_length_fraction: Option<f64>,
    /// Most parts a line along X (across Y) crosses.
    pub crossings_along_x: usize,
    pub crossings_along_y: usize,
    /// Per tool: how many groups (windows) it cuts.
    pub groups_per_tool: Vec<usize>,
}

/// The most open intervals `(lo, hi)` holding one point.
fn max_crossing(mut intervals: Vec<(f64, f64)>) -> usize {
    let mut events: Vec<(f64, i32)> = Vec::with_capacity(intervals.len() * 2);
    for (lo, hi) in intervals.drain(..) {
        if hi > lo {
            events.push((lo, 1));
            events.push((hi, -1));
        }
    }
    // Ends before starts at the same coordinate: open intervals that only touch do not cross.
    events.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let (mut n, mut best) = (0i32, 0i32);
    for (_, e) in events {
        n += e;
        best = best.max(n);
    }
    best as usize
}

fn material(length: f64, width: f64, parts_area: f64) -> Material {
    let area = length * width;
    Material {
        length_mm: length,
        width_mm: width,
        area_mm2: area,
        utilisation: if area > 0.0 { parts_area / area } else { 0.0 },
    }
}

pub fn figures(parts: &[Part], partition: &Partition) -> Figures {
    let boxes: Vec<[f64; 4]> = parts.iter().map(Part::bounds).collect();
    let offsets = partition.offsets();
    let parts_area: f64 = parts.iter().map(|p| p.polygon().unsigned_area()).sum();
    let x0 = boxes.iter().map(|b| b[0]).fold(f64::INFINITY, f64::min);
    let y0 = partition.y0_mm;
    let w = partition.width_mm;
    let x1 = boxes.iter().map(|b| b[2]).fold(f64::NEG_INFINITY, f64::max);
    let y1 = boxes.iter().map(|b| b[3]).fold(f64::NEG_INFINITY, f64::max);
    let sx1 = boxes
        .iter()
        .zip(&offsets)
        .map(|(b, d)| b[2] + d[0])
        .fold(f64::NEG_INFINITY, f64::max);
    let sy1 = boxes
        .iter()
        .zip(&offsets)
        .map(|(b, d)| b[3] + d[1])
        .fold(f64::NEG_INFINITY, f64::max);
    let gap = partition.gap_mm;
    let nx = max_crossing(boxes.iter().map(|b| (b[1], b[3])).collect());
    let ny = max_crossing(boxes.iter().map(|b| (b[0], b[2])).collect());
    let l0 = x1 - x0;
    let add_every = gap * nx.saturating_sub(1) as f64;
    let no_gap = material(l0, w.max(y1 - y0), parts_area);
    let partitioned = material(sx1 - x0, w.max(sy1 - y0), parts_area);
    let every = material(
        l0 + add_every,
        w.max(y1 - y0 + gap * ny.saturating_sub(1) as f64),
        parts_area,
    );
    let mut groups_per_tool = vec![0; partition.tools];
    for g in partition.groups.iter().filter(|g| !g.parts.is_empty()) {
        groups_per_tool[g.tool] += 1;
    }
    let added = partitioned.length_mm - l0;
    Figures {
        parts_area_mm2: parts_area,
        no_gap,
        partitioned,
        gap_every_part: every,
        added_length_partitioned_mm: added,
        added_length_every_part_mm: add_every,
        added_width_partitioned_mm: partitioned.width_mm - no_gap.width_mm,
        added_length_fraction: (add_every > 0.0).then(|| added / add_every),
        crossings_along_x: nx,
        crossings_along_y: ny,
        groups_per_tool,
    }
}

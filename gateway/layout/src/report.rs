//! The partition's result as the CLI's `--json` and the service's layout job give it:
//! parts named by their ids, groups, moves, overlaps, widenings and the material figures.

use crate::{Figures, Partition, Resolution, Widening};
use layout_io::Part;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Report {
    pub parts: usize,
    pub tools: usize,
    pub window_mm: f64,
    pub gap_mm: f64,
    pub clearance_mm: f64,
    pub width_mm: f64,
    pub y0_mm: f64,
    /// Groups with parts, in id order.
    pub groups: Vec<GroupReport>,
    pub moves: Vec<MoveReport>,
    /// Every overlap after S8 (all resolved: an unresolved one is an error instead).
    pub overlaps_found: Vec<OverlapReport>,
    pub overlaps_resolved: usize,
    pub overlaps_left: usize,
    pub widenings: Vec<Widening>,
    pub figures: Figures,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GroupReport {
    pub id: usize,
    pub tool: usize,
    pub window: usize,
    pub dx_mm: f64,
    pub dy_mm: f64,
    pub parts: Vec<String>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MoveReport {
    pub part: String,
    pub from_group: usize,
    pub to_group: usize,
    pub because_of: Option<String>,
    /// Distance to `because_of` before the move, mm.
    pub distance_mm: f64,
    /// Parts of other groups the moved part was too close to, before and after.
    pub overlaps_before: usize,
    pub overlaps_after: usize,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OverlapReport {
    pub a: String,
    pub b: String,
    pub group_a: usize,
    pub group_b: usize,
    pub distance_mm: f64,
}

/// The report of `partition` after `resolution`, parts named by their ids.
pub fn report(parts: &[Part], partition: &Partition, resolution: &Resolution) -> Report {
    let id = |i: usize| parts[i].id.clone();
    Report {
        parts: parts.len(),
        tools: partition.tools,
        window_mm: partition.window_mm,
        gap_mm: partition.gap_mm,
        clearance_mm: partition.clearance_mm,
        width_mm: partition.width_mm,
        y0_mm: partition.y0_mm,
        groups: partition
            .groups
            .iter()
            .filter(|g| !g.parts.is_empty())
            .map(|g| GroupReport {
                id: g.id,
                tool: g.tool,
                window: g.window,
                dx_mm: g.dx_mm,
                dy_mm: g.dy_mm,
                parts: g.parts.iter().map(|&p| id(p)).collect(),
            })
            .collect(),
        moves: resolution
            .moves
            .iter()
            .map(|m| MoveReport {
                part: id(m.part),
                from_group: m.from_group,
                to_group: m.to_group,
                because_of: m.because_of.map(id),
                distance_mm: m.distance_mm,
                overlaps_before: m.overlaps_before,
                overlaps_after: m.overlaps_after,
            })
            .collect(),
        overlaps_found: resolution
            .found
            .iter()
            .map(|o| OverlapReport {
                a: id(o.a),
                b: id(o.b),
                group_a: o.group_a,
                group_b: o.group_b,
                distance_mm: o.distance_mm,
            })
            .collect(),
        overlaps_resolved: resolution.found.len(),
        overlaps_left: 0,
        widenings: resolution.widenings.clone(),
        figures: crate::figures(parts, partition),
    }
}

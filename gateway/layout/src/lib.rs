//! Source C: a cutting layout partitioned into groups for a conveyor cutter with `k` tools
//! and a cutting window of length L', gaps only between groups, and the overlaps that
//! irregular shapes leave between groups found and resolved.
//!
//! Frame: X along the material's feed, Y across it, millimetres, as the layout file has
//! them. The steps follow the source document (`SPEC.md` C):
//!
//! - **S1** every part's bounding box B-i; parts taken in increasing Xmin (ties in file
//!   order).
//! - **S2** the material width W is cut into k equal lanes, lane 0 at the smallest Y; a
//!   part goes to the tool whose lane holds its box centre Yc:
//!   `tool = floor((Yc - y0) / (W / k))` (Yc on the far edge counts in the last lane).
//! - **S3-S7** the cutting windows span the whole width and are shared by every tool
//!   (the source's Fig. 4: G-1 and G-3 of tool O-1 and G-2 and G-4 of tool O-2 in the
//!   same two windows F-1 and F-2); window `w` starts at X `windows_mm[w]`, the Xmin of
//!   the part that opened it, and is L' long. If the part's tool has a group in the
//!   current (last opened) window, L is the length along X of the rectangle H bounding
//!   the window's start, the group's parts and this part (for the tool that opened the
//!   window, the source's rectangle of the group's parts); if L < L' the part joins the
//!   group (S5). Otherwise (S6-S7) the tool opens a new group: in the current window if
//!   it has none there and the part fits it (`Xmax - start < L'`), else in a new window
//!   F-i+1 starting at the part's Xmin. Groups are numbered 1, 2, ... in the order they
//!   open (G-1, G-2, ...). Parts come in increasing Xmin, so a part's window never
//!   comes before that of a part taken earlier.
//! - **S8** every part of a group moves by the group's common shift
//!   `DX = window x gap`, `DY = tool x gap`: the first group none, a same-window group of
//!   the next lane DY only, the next window of the same lane DX only, the diagonal both.
//!   Windows grow with Xmin and lanes with Yc, so two parts whose boxes are at least the
//!   gap apart stay at least the gap apart (a part lying wholly before another along X
//!   or Y never moves further than it that way); parts whose boxes overlap can come
//!   closer along slanted edges, which the overlap detection then finds.
//!
//! Worked example (gap 5 mm, 2 tools, W = 100 mm, L' = 300 mm): a part with box
//! x 0..100, y 10..40 (Yc = 25, lane 0) opens G-1 and window 0 at X 0 (tool 0, shift
//! (0, 0)); a part x 50..150, y 60..90 (Yc = 75, lane 1) opens G-2 in window 0 (tool 1,
//! shift (0, 5)); a part x 120..380, y 0..45 in lane 0 would make G-1 380 mm long
//! (>= 300), so it opens window 1 at X 120 and G-3 (tool 0, shift (5, 0)).
//!
//! Then [`resolve`] finds every pair of parts of different groups whose shifted contours
//! intersect or come closer than the gap, and moves parts to neighbouring groups until
//! none is left (see its documentation).

pub mod cut;
mod figures;
mod near;
mod overlap;
mod picture;
mod report;

use layout_io::Part;
use serde::Serialize;

pub use figures::{figures, Figures, Material};
pub use overlap::{
    detect, detect_exhaustive, resolve, resolve_widening, Move, Overlap, Resolution, Widening,
};
pub use picture::Picture;
pub use report::{report, GroupReport, MoveReport, OverlapReport, Report};

/// What the cutter is and how far apart groups go.
#[derive(Debug, Clone, Copy)]
pub struct Params {
    /// Number of tools k (lanes across the width).
    pub tools: usize,
    /// Cutting window length L' along X, mm.
    pub window_mm: f64,
    /// Gap between groups, mm.
    pub gap_mm: f64,
    /// Material width W, mm, with the material's edge at Y = 0. None: the layout's own
    /// extent across (from its smallest to its largest Y).
    pub width_mm: Option<f64>,
    /// Parts of different groups closer than this after S8 are overlaps, mm. None: the
    /// gap (the source's rule). A smaller clearance (down to a micrometre) accepts parts
    /// of neighbouring groups that end up nearer than the gap along slanted edges, and
    /// still catches every intersection.
    pub clearance_mm: Option<f64>,
}

/// A group of parts cut by one tool in one window.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Group {
    /// 1, 2, ... in the order groups opened (G-1, G-2, ...).
    pub id: usize,
    /// Tool and lane index, 0 at the smallest Y.
    pub tool: usize,
    /// Window index, shared by every tool (window 0 first along X).
    pub window: usize,
    pub dx_mm: f64,
    pub dy_mm: f64,
    /// Indices of the group's parts in the layout.
    pub parts: Vec<usize>,
}

/// Why a layout cannot be partitioned.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PartitionError {
    #[error("{0}")]
    Params(String),
    #[error("part `{part}` is {width:.3} mm wide across, wider than a lane ({lane:.3} mm = W {w:.3} / {k} tools)")]
    WiderThanLane {
        part: String,
        width: f64,
        lane: f64,
        w: f64,
        k: usize,
    },
    #[error("part `{part}` is {length:.3} mm long, not shorter than the window ({window:.3} mm)")]
    LongerThanWindow {
        part: String,
        length: f64,
        window: f64,
    },
    #[error(
        "part `{part}` lies at Y {ymin:.3}..{ymax:.3} mm, outside the material (0..{w:.3} mm)"
    )]
    OutsideWidth {
        part: String,
        ymin: f64,
        ymax: f64,
        w: f64,
    },
    #[error("{count} part(s) do not fit the {material:.3} mm material (Y {y0:.3}..{y1:.3} mm) after the shifts, the partitioned layout needs {needed:.3} mm: {list} (--material-width-mm states the material's width)", y1 = y0 + material)]
    OutsideMaterial {
        count: usize,
        material: f64,
        y0: f64,
        needed: f64,
        /// Each part that does not fit: its id, group and Y extent after the shifts.
        list: String,
    },
    #[error("--assign {part}={group}: {message}")]
    Assign {
        part: String,
        group: String,
        message: String,
    },
    #[error("overlap that no neighbouring group resolves: {0}")]
    Unresolvable(String),
}

/// The partition: groups, each part's group, and the lanes.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Partition {
    pub groups: Vec<Group>,
    /// Index into `groups` of each part's group.
    #[serde(skip)]
    pub group_of: Vec<usize>,
    /// Y of lane 0's lower edge, and the material width W.
    pub y0_mm: f64,
    pub width_mm: f64,
    pub gap_mm: f64,
    /// Distance below which parts of different groups overlap (see [`Params`]).
    pub clearance_mm: f64,
    pub window_mm: f64,
    /// Where each window starts along X, before any shift (window `w` spans
    /// `windows_mm[w] .. windows_mm[w] + window_mm` across the whole width).
    pub windows_mm: Vec<f64>,
    pub tools: usize,
}

impl Partition {
    /// The shift of every part: its group's (DX, DY).
    pub fn offsets(&self) -> Vec<[f64; 2]> {
        self.group_of
            .iter()
            .map(|&g| [self.groups[g].dx_mm, self.groups[g].dy_mm])
            .collect()
    }

    /// Lane width W / k.
    pub fn lane_mm(&self) -> f64 {
        self.width_mm / self.tools as f64
    }

    /// Moves part `p` to group index `g` (keeps `groups[..].parts` sorted).
    pub(crate) fn reassign(&mut self, p: usize, g: usize) {
        let from = self.group_of[p];
        self.groups[from].parts.retain(|&q| q != p);
        let parts = &mut self.groups[g].parts;
        let at = parts.partition_point(|&q| q < p);
        parts.insert(at, p);
        self.group_of[p] = g;
    }

    /// Whether group `g` with part `extra` still fits its window: the rectangle bounding
    /// the window's start and the group's parts (unshifted) shorter than L' (S5's
    /// `L < L'`); otherwise why not.
    pub(crate) fn fits_window(
        &self,
        boxes: &[[f64; 4]],
        g: usize,
        extra: Option<usize>,
    ) -> Result<(), String> {
        if self.window_fits(boxes, g, extra) {
            return Ok(());
        }
        let ext = self.extent_with(boxes, g, extra);
        let w = self.groups[g].window;
        let start = self.windows_mm.get(w).copied().unwrap_or(ext[0]);
        let from = ext[0].min(start);
        Err(format!(
            "the group with window {w}'s start would span X {from:.3}..{:.3} mm, {:.3} mm: not shorter than the window ({:.3} mm)",
            ext[1],
            ext[1] - from,
            self.window_mm
        ))
    }

    /// [`Self::fits_window`] without saying why (what the resolution asks for every
    /// candidate move, where the message would be thrown away).
    pub(crate) fn window_fits(&self, boxes: &[[f64; 4]], g: usize, extra: Option<usize>) -> bool {
        self.window_fits_extent(g, self.extent_with(boxes, g, extra))
    }

    /// Whether group `g` spanning X `ext` (its parts' and a newcomer's, unshifted) fits
    /// its window.
    pub(crate) fn window_fits_extent(&self, g: usize, ext: [f64; 2]) -> bool {
        let w = self.groups[g].window;
        let start = self.windows_mm.get(w).copied().unwrap_or(ext[0]);
        ext[1] - ext[0].min(start) < self.window_mm
    }

    /// X extent `[xmin, xmax]` of group `g`'s unshifted parts plus part `extra`.
    pub(crate) fn extent_with(
        &self,
        boxes: &[[f64; 4]],
        g: usize,
        extra: Option<usize>,
    ) -> [f64; 2] {
        self.groups[g]
            .parts
            .iter()
            .copied()
            .chain(extra)
            .fold([f64::INFINITY, f64::NEG_INFINITY], |e, p| {
                [e[0].min(boxes[p][0]), e[1].max(boxes[p][2])]
            })
    }
}

fn check_params(p: &Params) -> Result<(), PartitionError> {
    let bad = |m: &str| Err(PartitionError::Params(m.into()));
    if p.tools == 0 {
        return bad("--tools must be at least 1");
    }
    if !(p.window_mm > 0.0) || !p.window_mm.is_finite() {
        return bad("--window-mm must be a positive length");
    }
    if !(p.gap_mm > 0.0) || !p.gap_mm.is_finite() {
        return bad("--gap-mm must be a positive length");
    }
    if let Some(c) = p.clearance_mm {
        if !(c >= 1e-3) || !(c <= p.gap_mm) {
            return bad("--clearance-mm must be between 0.001 mm and the gap");
        }
    }
    if let Some(w) = p.width_mm {
        if !(w > 0.0) || !w.is_finite() {
            return bad("--width-mm must be a positive length");
        }
    }
    Ok(())
}

/// Steps S1-S8 (see the crate's documentation).
pub fn partition(parts: &[Part], params: &Params) -> Result<Partition, PartitionError> {
    check_params(params)?;
    if parts.is_empty() {
        return Err(PartitionError::Params("the layout has no parts".into()));
    }
    // S1: bounding boxes, parts in increasing Xmin.
    let boxes: Vec<[f64; 4]> = parts.iter().map(Part::bounds).collect();
    let (y0, width) = match params.width_mm {
        Some(w) => {
            for (p, b) in parts.iter().zip(&boxes) {
                if b[1] < 0.0 || b[3] > w {
                    return Err(PartitionError::OutsideWidth {
                        part: p.id.clone(),
                        ymin: b[1],
                        ymax: b[3],
                        w,
                    });
                }
            }
            (0.0, w)
        }
        None => {
            let lo = boxes.iter().map(|b| b[1]).fold(f64::INFINITY, f64::min);
            let hi = boxes.iter().map(|b| b[3]).fold(f64::NEG_INFINITY, f64::max);
            (lo, (hi - lo).max(f64::MIN_POSITIVE))
        }
    };
    let k = params.tools;
    let lane = width / k as f64;
    for (p, b) in parts.iter().zip(&boxes) {
        if b[3] - b[1] > lane {
            return Err(PartitionError::WiderThanLane {
                part: p.id.clone(),
                width: b[3] - b[1],
                lane,
                w: width,
                k,
            });
        }
        if b[2] - b[0] >= params.window_mm {
            return Err(PartitionError::LongerThanWindow {
                part: p.id.clone(),
                length: b[2] - b[0],
                window: params.window_mm,
            });
        }
    }
    let mut order: Vec<usize> = (0..parts.len()).collect();
    order.sort_by(|&a, &b| boxes[a][0].total_cmp(&boxes[b][0]).then(a.cmp(&b)));

    let mut groups: Vec<Group> = Vec::new();
    let mut group_of = vec![0usize; parts.len()];
    // The windows, shared by every tool and spanning the whole width: window w starts at
    // X `windows[w]` (the Xmin of the part that opened it) and is L' long. Per tool: its
    // current group (index into `groups`) and that group's window.
    let mut windows: Vec<f64> = Vec::new();
    let mut current: Vec<Option<(usize, usize)>> = vec![None; k];
    // Per group: the largest Xmax of its parts.
    let mut group_end: Vec<f64> = Vec::new();
    for &i in &order {
        let b = boxes[i];
        // S2: the lane holding the box centre Yc.
        let yc = (b[1] + b[3]) / 2.0;
        let tool = (((yc - y0) / lane).floor().max(0.0) as usize).min(k - 1);
        // The window being cut: the last one opened (parts come in increasing Xmin, so
        // it starts at or before this part).
        let last = windows.len().checked_sub(1);
        // S3-S5: the tool's group in the current window takes the part while the
        // rectangle H of the window's start, the group's parts and this one stays
        // shorter than L' (`L < L'`; for the tool that opened the window, H is the
        // source's rectangle of the group's parts).
        if let (Some((g, w)), Some(last)) = (current[tool], last) {
            if w == last && group_end[g].max(b[2]) - windows[w] < params.window_mm {
                group_end[g] = group_end[g].max(b[2]);
                groups[g].parts.push(i);
                group_of[i] = g;
                continue;
            }
        }
        // S6-S7: a new group for this tool, in the current window if the tool has no
        // group there yet and the part fits it, otherwise in a new window starting at
        // the part (F-i+1, shifted forward along X).
        let window = match (last, current[tool]) {
            (Some(last), c)
                if c.is_none_or(|(_, w)| w < last) && b[2] - windows[last] < params.window_mm =>
            {
                last
            }
            _ => {
                windows.push(b[0]);
                windows.len() - 1
            }
        };
        let g = groups.len();
        groups.push(Group {
            id: g + 1,
            tool,
            window,
            // S8: the group's common shift.
            dx_mm: window as f64 * params.gap_mm,
            dy_mm: tool as f64 * params.gap_mm,
            parts: vec![i],
        });
        group_end.push(b[2]);
        group_of[i] = g;
        current[tool] = Some((g, window));
    }
    for g in &mut groups {
        g.parts.sort_unstable();
    }
    Ok(Partition {
        groups,
        group_of,
        y0_mm: y0,
        width_mm: width,
        gap_mm: params.gap_mm,
        clearance_mm: params.clearance_mm.unwrap_or(params.gap_mm),
        window_mm: params.window_mm,
        windows_mm: windows,
        tools: k,
    })
}

/// The material a partition is written on: its width and the partitioned layout's.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MaterialFit {
    /// The material's width, mm, from the lanes' lower edge `y0_mm`.
    pub material_width_mm: f64,
    /// The partitioned layout's width across, mm: at least W, and as far as the shifted
    /// parts reach from `y0_mm`.
    pub partitioned_width_mm: f64,
}

/// Checks that every shifted part lies on the material (Y from the lanes' lower edge to
/// that plus `material_width_mm`; None: the partition's width W); a part that does not
/// is named with its group and where it reaches.
pub fn fit_material(
    parts: &[Part],
    partition: &Partition,
    material_width_mm: Option<f64>,
) -> Result<MaterialFit, PartitionError> {
    let material = material_width_mm.unwrap_or(partition.width_mm);
    if !(material > 0.0) || !material.is_finite() {
        return Err(PartitionError::Params(
            "--material-width-mm must be a positive length".into(),
        ));
    }
    let y0 = partition.y0_mm;
    let offsets = partition.offsets();
    let mut top = y0 + partition.width_mm;
    let mut outside = Vec::new();
    for (i, (part, d)) in parts.iter().zip(&offsets).enumerate() {
        let b = part.bounds();
        let (lo, hi) = (b[1] + d[1], b[3] + d[1]);
        top = top.max(hi);
        // A nanometre of slack: a part on the edge fits.
        if lo < y0 - 1e-6 || hi > y0 + material + 1e-6 {
            outside.push((i, lo, hi));
        }
    }
    if outside.is_empty() {
        return Ok(MaterialFit {
            material_width_mm: material,
            partitioned_width_mm: top - y0,
        });
    }
    let shown: Vec<String> = outside
        .iter()
        .take(20)
        .map(|&(i, lo, hi)| {
            let g = &partition.groups[partition.group_of[i]];
            format!(
                "`{}` (group {}, DY {:.3}) at Y {lo:.3}..{hi:.3}",
                parts[i].id, g.id, g.dy_mm
            )
        })
        .collect();
    let more = outside.len().saturating_sub(shown.len());
    Err(PartitionError::OutsideMaterial {
        count: outside.len(),
        material,
        y0,
        needed: top - y0,
        list: shown.join("; ")
            + &if more > 0 {
                format!("; and {more} more")
            } else {
                String::new()
            },
    })
}

/// Applies the operator's forced assignments `(part id, group id)`: each part joins the
/// group (and its shift). Refused when the part or group does not exist, or when the
/// group would no longer lie in its window (see `fits_window`).
pub fn assign(
    parts: &[Part],
    partition: &mut Partition,
    forced: &[(String, usize)],
) -> Result<Vec<usize>, PartitionError> {
    let boxes: Vec<[f64; 4]> = parts.iter().map(Part::bounds).collect();
    let mut pinned = Vec::new();
    for (part, group) in forced {
        let err = |m: String| PartitionError::Assign {
            part: part.clone(),
            group: group.to_string(),
            message: m,
        };
        let p = parts
            .iter()
            .position(|q| &q.id == part)
            .ok_or_else(|| err("no part has this id".into()))?;
        let g = partition
            .groups
            .iter()
            .position(|q| q.id == *group)
            .ok_or_else(|| {
                err(format!(
                    "no such group (groups are 1..={})",
                    partition.groups.len()
                ))
            })?;
        partition.fits_window(&boxes, g, Some(p)).map_err(err)?;
        partition.reassign(p, g);
        pinned.push(p);
    }
    Ok(pinned)
}

#[cfg(test)]
mod tests;

//! Overlaps between groups after S8, found with an R*-tree and exact polygon distances
//! (`near.rs`),
//! and resolved by moving parts to neighbouring groups.

use geo::{Polygon, Translate};
use layout_io::Part;
use rstar::primitives::{GeomWithData, Rectangle};
use rstar::{RTree, AABB};
use serde::Serialize;

use crate::{Partition, PartitionError};

/// Two parts of different groups closer than the clearance (the gap unless set;
/// distance 0: they touch or intersect). A pair counts when its distance is below the
/// clearance by more than [`SLACK_MM`], so parts that S8 puts exactly one gap apart are
/// not reported for rounding.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Overlap {
    /// Part indices, `a < b`.
    pub a: usize,
    pub b: usize,
    pub group_a: usize,
    pub group_b: usize,
    pub distance_mm: f64,
}

/// 1 nm: how far below the clearance a distance must be to count.
pub const SLACK_MM: f64 = 1e-6;

/// One automatic or forced move of a part between groups (group ids, 1-based).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Move {
    pub part: usize,
    pub from_group: usize,
    pub to_group: usize,
    /// The part it was too close to (None for an operator's `--assign`).
    pub because_of: Option<usize>,
    /// Why: the distance to that part before the move, mm, and how many parts of other
    /// groups the moved part was too close to before and after it.
    pub distance_mm: f64,
    pub overlaps_before: usize,
    pub overlaps_after: usize,
}

/// What [`resolve`] did.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Resolution {
    /// Overlaps after S8 (and the operator's assignments), before any automatic move.
    pub found: Vec<Overlap>,
    pub moves: Vec<Move>,
    /// Where the groups' shifts were widened beyond S8's because no move resolved an
    /// overlap (empty when moves sufficed or widening was not allowed).
    pub widenings: Vec<Widening>,
}

/// Extra shift added to every group from a window (or lane) on, beyond S8's
/// `window x gap` (`tool x gap`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Widening {
    /// "window": DX of every group of window index >= `from` grows by `extra_mm`;
    /// "lane": DY of every group of tool index >= `from`.
    pub between: &'static str,
    pub from: usize,
    pub extra_mm: f64,
}

/// How many times one part may move (it never goes back to a group it left, and has at
/// most eight neighbouring groups, so this is never reached; a bound all the same).
const MAX_MOVES_PER_PART: usize = 8;

/// How many widening rounds before giving up (each round widens by at least an eighth
/// of the clearance; a layout a kilometre long needs far fewer).
const MAX_WIDENING_ROUNDS: usize = 10_000;

type Entry = GeomWithData<Rectangle<[f64; 2]>, usize>;

/// The parts' shifted polygons, their boxes, and an R*-tree of the boxes.
struct Placed<'a> {
    /// The parts' polygons as given (made once per resolution, not once per round).
    polygons: std::borrow::Cow<'a, [Polygon<f64>]>,
    shifted: Vec<Polygon<f64>>,
    boxes: Vec<[f64; 4]>,
    tree: RTree<Entry>,
}

fn rect(b: [f64; 4]) -> Rectangle<[f64; 2]> {
    Rectangle::from_corners([b[0], b[1]], [b[2], b[3]])
}

impl<'a> Placed<'a> {
    fn new(parts: &[Part], partition: &Partition) -> Placed<'static> {
        let polygons: Vec<Polygon<f64>> = parts.iter().map(Part::polygon).collect();
        Placed::with_polygons(parts, partition, std::borrow::Cow::Owned(polygons))
    }

    fn with_polygons(
        parts: &[Part],
        partition: &Partition,
        polygons: std::borrow::Cow<'a, [Polygon<f64>]>,
    ) -> Placed<'a> {
        let offsets = partition.offsets();
        let shifted: Vec<Polygon<f64>> = polygons
            .iter()
            .zip(&offsets)
            .map(|(p, d)| p.translate(d[0], d[1]))
            .collect();
        let boxes: Vec<[f64; 4]> = parts
            .iter()
            .zip(&offsets)
            .map(|(p, d)| {
                let b = p.bounds();
                [b[0] + d[0], b[1] + d[1], b[2] + d[0], b[3] + d[1]]
            })
            .collect();
        let tree = RTree::bulk_load(
            boxes
                .iter()
                .enumerate()
                .map(|(i, b)| Entry::new(rect(*b), i))
                .collect(),
        );
        Placed {
            polygons,
            shifted,
            boxes,
            tree,
        }
    }

    /// Parts whose box comes within `gap` of box `b` (a superset of those within `gap`
    /// of the polygon: two shapes are never closer than their boxes).
    fn near(&self, b: [f64; 4], gap: f64) -> impl Iterator<Item = usize> + '_ {
        let env = AABB::from_corners([b[0] - gap, b[1] - gap], [b[2] + gap, b[3] + gap]);
        self.tree
            .locate_in_envelope_intersecting(&env)
            .map(|e| e.data)
    }

    /// The distance between parts `a` and `b` as placed, if below `limit`.
    fn distance_below(&self, a: usize, b: usize, limit: f64) -> Option<f64> {
        crate::near::distance_below(
            &self.shifted[a],
            self.boxes[a],
            &self.shifted[b],
            self.boxes[b],
            limit,
        )
    }

    fn place(&mut self, p: usize, d: [f64; 2], bounds: [f64; 4]) {
        let old = self.boxes[p];
        self.tree.remove(&Entry::new(rect(old), p));
        self.shifted[p] = self.polygons[p].translate(d[0], d[1]);
        self.boxes[p] = [
            bounds[0] + d[0],
            bounds[1] + d[1],
            bounds[2] + d[0],
            bounds[3] + d[1],
        ];
        self.tree.insert(Entry::new(rect(self.boxes[p]), p));
    }
}

/// Distance between two boxes (0 when they meet): a lower bound of their shapes'.
fn box_distance(a: [f64; 4], b: [f64; 4]) -> f64 {
    let dx = (a[0] - b[2]).max(b[0] - a[2]).max(0.0);
    let dy = (a[1] - b[3]).max(b[1] - a[3]).max(0.0);
    dx.hypot(dy)
}

fn overlap(
    partition: &Partition,
    placed: &Placed,
    a: usize,
    b: usize,
    gap: f64,
) -> Option<Overlap> {
    let (ga, gb) = (partition.group_of[a], partition.group_of[b]);
    if ga == gb {
        return None;
    }
    let d = placed.distance_below(a, b, gap - SLACK_MM)?;
    Some(Overlap {
        a: a.min(b),
        b: a.max(b),
        group_a: partition.groups[partition.group_of[a.min(b)]].id,
        group_b: partition.groups[partition.group_of[a.max(b)]].id,
        distance_mm: d,
    })
}

fn detect_placed(partition: &Partition, placed: &Placed) -> Vec<Overlap> {
    detect_remembering(partition, placed, &mut Apart::new())
}

/// Pairs of parts found not close, with the translation of the second relative to the
/// first they were measured at: the same polygons at the same relative translation are
/// as far apart again, so a widening round measures only the pairs whose groups' shifts
/// changed relative to each other.
type Apart = std::collections::HashMap<(usize, usize), [f64; 2]>;

/// [`detect_placed`], skipping the pairs `apart` holds at their relative translation and
/// adding those it finds apart.
fn detect_remembering(partition: &Partition, placed: &Placed, apart: &mut Apart) -> Vec<Overlap> {
    let gap = partition.clearance_mm;
    let offsets = partition.offsets();
    let mut out = Vec::new();
    for a in 0..placed.boxes.len() {
        let mut near: Vec<usize> = placed
            .near(placed.boxes[a], gap)
            .filter(|&b| b > a && partition.group_of[a] != partition.group_of[b])
            .collect();
        near.sort_unstable();
        for b in near {
            let rel = [offsets[b][0] - offsets[a][0], offsets[b][1] - offsets[a][1]];
            if apart.get(&(a, b)) == Some(&rel) {
                continue;
            }
            match overlap(partition, placed, a, b, gap) {
                Some(o) => out.push(o),
                None => {
                    apart.insert((a, b), rel);
                }
            }
        }
    }
    out
}

/// Every pair of parts of different groups, after their groups' shifts, whose contours
/// intersect or are closer than the clearance (exact polygon distance, `geo`), candidates
/// from an R*-tree of the shifted boxes (`rstar`). Sorted by (a, b).
pub fn detect(parts: &[Part], partition: &Partition) -> Vec<Overlap> {
    detect_placed(partition, &Placed::new(parts, partition))
}

/// The same as [`detect`] by checking every pair: the reference for tests and benchmarks.
pub fn detect_exhaustive(parts: &[Part], partition: &Partition) -> Vec<Overlap> {
    let placed = Placed::new(parts, partition);
    let gap = partition.clearance_mm;
    let mut out = Vec::new();
    for a in 0..parts.len() {
        for b in a + 1..parts.len() {
            out.extend(overlap(partition, &placed, a, b, gap));
        }
    }
    out
}

/// Groups next to group index `g`: tool and window each within one of `g`'s, not `g`.
fn neighbours(partition: &Partition, g: usize) -> Vec<usize> {
    let (t, w) = (partition.groups[g].tool, partition.groups[g].window);
    (0..partition.groups.len())
        .filter(|&h| {
            let o = &partition.groups[h];
            h != g && o.tool.abs_diff(t) <= 1 && o.window.abs_diff(w) <= 1
        })
        .collect()
}

/// Like [`resolve`], then, for what moves leave, widens the shifts beyond S8's (the
/// operator's `--widen`): the output is always cuttable, at the cost of material.
///
/// Widening: for each overlap left, its two groups are in different windows (the later
/// window's groups, and every window after, move along X) or in the same window and
/// different lanes (the upper lane's groups, and every lane above, move along Y). The
/// extra shift at each such boundary is the largest shortfall `clearance - distance` of
/// its pairs (a translation by e changes a distance by at most e, so less cannot do),
/// at least an eighth of the clearance; then moves are tried again. Shifts only grow and
/// parts of windows (lanes) far enough apart cannot be close, so this ends, with no pair
/// below the clearance. Every widening is reported; groups' `dx_mm`/`dy_mm` include it.
pub fn resolve_widening(
    parts: &[Part],
    partition: &mut Partition,
    pinned: &[usize],
) -> Result<Resolution, PartitionError> {
    resolve_with(parts, partition, pinned, true)
}

/// Finds the overlaps and resolves them by moving parts between neighbouring groups
/// until none is left, keeping S8's shifts (the patent leaves this to the operator);
/// an overlap no move resolves is an error naming every pair left.
///
/// A candidate move takes one part of an overlapping pair into a neighbouring group
/// (tool and window each within one of its own): part b into a's group and part a into
/// b's group when the two groups are neighbours, then b into each other group next to
/// its own, then a likewise. A candidate is allowed when (1) the part is not pinned by
/// `--assign`, (2) the part never was in that group (a part never goes back to a group it
/// left, and moves at most [`MAX_MOVES_PER_PART`] times) and (3) the target group still
/// fits its window with the part (`Partition::fits_window`). Each move is reported with
/// why: the partner, their distance, and the part's overlaps before and after. The parts of one group share one shift, so a part
/// joining a group sits beside its new group mates exactly as in the given layout: no
/// new contact inside the group is possible. Its score is the number of overlaps
/// the part has after the move minus before (a part taken into its partner's group is
/// back beside it as nested, but may now be too close to its former group mates).
///
/// Repeatedly, for the first overlap (in order of (a, b)) that has a candidate of
/// negative score, the best such candidate (lowest score, first in the order above on
/// ties) is applied. Every move lowers the number of overlaps, so this ends: with none
/// left, or with overlaps that no move reduces (densely nested layouts, whose parts touch
/// their neighbours, often leave some: a part moved only trades one contact for
/// another; [`resolve_widening`] then ends them).
pub fn resolve(
    parts: &[Part],
    partition: &mut Partition,
    pinned: &[usize],
) -> Result<Resolution, PartitionError> {
    resolve_with(parts, partition, pinned, false)
}

fn resolve_with(
    parts: &[Part],
    partition: &mut Partition,
    pinned: &[usize],
    widen: bool,
) -> Result<Resolution, PartitionError> {
    let bounds: Vec<[f64; 4]> = parts.iter().map(Part::bounds).collect();
    let found = detect(parts, partition);
    let mut moves = Vec::new();
    let mut widenings: Vec<Widening> = Vec::new();
    let mut rounds = 0;
    let mut memory = Memory {
        left_groups: vec![Vec::new(); parts.len()],
        polygons: parts.iter().map(Part::polygon).collect(),
        apart: Apart::new(),
    };
    loop {
        let left = move_parts(partition, &bounds, pinned, parts, &mut moves, &mut memory);
        if left.is_empty() {
            return Ok(Resolution {
                found,
                moves,
                widenings,
            });
        }
        rounds += 1;
        if !widen || rounds > MAX_WIDENING_ROUNDS {
            let gap = partition.clearance_mm;
            let list: Vec<String> = left
                .iter()
                .map(|o| {
                    format!(
                        "`{}` (group {}) and `{}` (group {}) {:.3} mm apart",
                        parts[o.a].id, o.group_a, parts[o.b].id, o.group_b, o.distance_mm
                    )
                })
                .collect();
            return Err(PartitionError::Unresolvable(format!(
                "{} pair(s) below the {gap:.3} mm clearance: {}{}",
                list.len(),
                list.join("; "),
                if widen {
                    ""
                } else {
                    " (--widen moves later windows or lanes further apart instead)"
                }
            )));
        }
        widen_once(partition, &left, &mut widenings);
    }
}

/// Widens the shifts once for the overlaps `left` (see [`resolve_widening`]).
fn widen_once(partition: &mut Partition, left: &[Overlap], widenings: &mut Vec<Widening>) {
    let clearance = partition.clearance_mm;
    let minimum = clearance / 8.0;
    // (between, from) -> extra
    let mut extra: std::collections::BTreeMap<(&'static str, usize), f64> = Default::default();
    for o in left {
        let (ga, gb) = (
            &partition.groups[partition.group_of[o.a]],
            &partition.groups[partition.group_of[o.b]],
        );
        let key = if ga.window != gb.window {
            ("window", ga.window.max(gb.window))
        } else {
            ("lane", ga.tool.max(gb.tool))
        };
        let need = (clearance - o.distance_mm).max(minimum);
        let e = extra.entry(key).or_insert(0.0);
        *e = e.max(need);
    }
    for ((between, from), extra_mm) in extra {
        for g in &mut partition.groups {
            match between {
                "window" if g.window >= from => g.dx_mm += extra_mm,
                "lane" if g.tool >= from => g.dy_mm += extra_mm,
                _ => {}
            }
        }
        match widenings
            .iter_mut()
            .find(|w| w.between == between && w.from == from)
        {
            Some(w) => w.extra_mm += extra_mm,
            None => widenings.push(Widening {
                between,
                from,
                extra_mm,
            }),
        }
    }
    widenings.sort_by(|a, b| (a.between, a.from).cmp(&(b.between, b.from)));
}

/// What one resolution keeps from round to round: per part the groups it left (it never
/// goes back to one), the parts' polygons, and the pairs found apart.
struct Memory {
    left_groups: Vec<Vec<usize>>,
    polygons: Vec<Polygon<f64>>,
    apart: Apart,
}

/// Moves parts as [`resolve`] describes; returns the overlaps no move reduces.
fn move_parts(
    partition: &mut Partition,
    bounds: &[[f64; 4]],
    pinned: &[usize],
    parts: &[Part],
    moves: &mut Vec<Move>,
    memory: &mut Memory,
) -> Vec<Overlap> {
    let Memory {
        left_groups,
        polygons,
        apart,
    } = memory;
    let gap = partition.clearance_mm;
    let mut placed =
        Placed::with_polygons(parts, partition, std::borrow::Cow::Borrowed(&polygons[..]));
    let mut current: std::collections::BTreeSet<(usize, usize)> =
        detect_remembering(partition, &placed, apart)
            .iter()
            .map(|o| (o.a, o.b))
            .collect();
    // Where each candidate (part, group) would leave the part, kept while no move can
    // change it.
    let mut cache: std::collections::HashMap<(usize, usize), Option<Vec<usize>>> =
        std::collections::HashMap::new();
    'search: while !current.is_empty() {
        for &(a, b) in &current {
            let (ga, gb) = (partition.group_of[a], partition.group_of[b]);
            // The partner's group first, when it is a neighbour (tool and window each
            // within one), then the other neighbours.
            let adjacent = |g: usize, h: usize| {
                let (x, y) = (&partition.groups[g], &partition.groups[h]);
                x.tool.abs_diff(y.tool) <= 1 && x.window.abs_diff(y.window) <= 1
            };
            let mut candidates = Vec::new();
            if adjacent(ga, gb) {
                candidates.extend([(b, ga), (a, gb)]);
            }
            candidates.extend(
                neighbours(partition, gb)
                    .into_iter()
                    .filter(|&h| h != ga)
                    .map(|h| (b, h)),
            );
            candidates.extend(
                neighbours(partition, ga)
                    .into_iter()
                    .filter(|&h| h != gb)
                    .map(|h| (a, h)),
            );
            let mut best: Option<(i64, usize, usize, Vec<usize>)> = None;
            for (p, g) in candidates {
                // Pinned parts stay; a part never goes back to a group it left, and
                // moves a bounded number of times.
                if pinned.contains(&p)
                    || left_groups[p].contains(&g)
                    || left_groups[p].len() >= MAX_MOVES_PER_PART
                {
                    continue;
                }
                let Some(after) = cache
                    .entry((p, g))
                    .or_insert_with(|| overlaps_if_moved(partition, bounds, &placed, p, g))
                    .clone()
                else {
                    continue;
                };
                let before = current.iter().filter(|&&(x, y)| x == p || y == p).count() as i64;
                let score = after.len() as i64 - before;
                if score < 0 && best.as_ref().is_none_or(|b| score < b.0) {
                    best = Some((score, p, g, after));
                }
            }
            if let Some((_, p, g, after)) = best {
                let from = partition.group_of[p];
                let other = if p == a { b } else { a };
                let distance_mm = placed
                    .distance_below(p, other, f64::INFINITY)
                    .unwrap_or(0.0);
                let overlaps_before = current.iter().filter(|&&(x, y)| x == p || y == p).count();
                let overlaps_after = after.len();
                left_groups[p].push(from);
                let old_box = placed.boxes[p];
                partition.reassign(p, g);
                placed.place(
                    p,
                    [partition.groups[g].dx_mm, partition.groups[g].dy_mm],
                    bounds[p],
                );
                // A candidate's outcome depends on its target group's extent and on the
                // parts near where it would go: keep those the move cannot touch.
                let new_box = placed.boxes[p];
                cache.retain(|&(q, h), _| {
                    let grp = &partition.groups[h];
                    let b = bounds[q];
                    let at = [
                        b[0] + grp.dx_mm,
                        b[1] + grp.dy_mm,
                        b[2] + grp.dx_mm,
                        b[3] + grp.dy_mm,
                    ];
                    q != p
                        && h != from
                        && h != g
                        && box_distance(at, old_box) >= gap
                        && box_distance(at, new_box) >= gap
                });
                current.retain(|&(x, y)| x != p && y != p);
                current.extend(after.into_iter().map(|q| (p.min(q), p.max(q))));
                moves.push(Move {
                    part: p,
                    from_group: partition.groups[from].id,
                    to_group: partition.groups[g].id,
                    because_of: Some(other),
                    distance_mm,
                    overlaps_before,
                    overlaps_after,
                });
                continue 'search;
            }
        }
        return current
            .iter()
            .filter_map(|&(a, b)| overlap(partition, &placed, a, b, gap))
            .collect();
    }
    Vec::new()
}

/// The parts of other groups part `p` would be too close to in group index `g`, or None
/// when it may not go there (the group would be too long for its window).
fn overlaps_if_moved(
    partition: &Partition,
    bounds: &[[f64; 4]],
    placed: &Placed,
    p: usize,
    g: usize,
) -> Option<Vec<usize>> {
    partition.fits_window(bounds, g, Some(p)).ok()?;
    let grp = &partition.groups[g];
    let moved = placed.polygons[p].translate(grp.dx_mm, grp.dy_mm);
    let b = bounds[p];
    let bx = [
        b[0] + grp.dx_mm,
        b[1] + grp.dy_mm,
        b[2] + grp.dx_mm,
        b[3] + grp.dy_mm,
    ];
    let gap = partition.clearance_mm;
    let mut close = Vec::new();
    for q in placed.near(bx, gap).filter(|&q| q != p) {
        // Group mates keep their nested positions (the same shift): no check needed.
        if partition.group_of[q] != g
            && crate::near::distance_below(
                &moved,
                bx,
                &placed.shifted[q],
                placed.boxes[q],
                gap - SLACK_MM,
            )
            .is_some()
        {
            close.push(q);
        }
    }
    Some(close)
}

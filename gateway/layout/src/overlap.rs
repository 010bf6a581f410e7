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

fn rect(b: [f64; 4]) -> Rectangle<[f64; 2]> {
    Rectangle::from_corners([b[0], b[1]], [b[2], b[3]])
}

/// `b` moved by `d`.
fn shifted_box(b: [f64; 4], d: [f64; 2]) -> [f64; 4] {
    [b[0] + d[0], b[1] + d[1], b[2] + d[0], b[3] + d[1]]
}

/// The parts where their groups put them, found through one R*-tree per group of the
/// parts' boxes as given: a group's parts share its shift, so its tree never changes
/// when shifts grow (widening) and changes by one entry when a part moves. Pairs are
/// looked for only between groups whose boxes come within the clearance, and there only
/// among the parts near the other group's box; each part's polygon is translated when a
/// distance needs it at a shift it was not translated to yet. Positions, boxes and
/// distances are computed exactly as a polygon translated by its group's shift gives
/// them, so every result is the same as with one tree of all shifted boxes.
struct Placed<'a> {
    /// The parts' polygons and boxes as given.
    polygons: &'a [Polygon<f64>],
    bounds: &'a [[f64; 4]],
    /// Per group: an R*-tree of its parts' boxes as given, and their union.
    trees: Vec<RTree<Entry>>,
    group_boxes: Vec<[f64; 4]>,
    /// Per part: the shift it was last translated by and the polygon so translated.
    shifted: Vec<Option<([f64; 2], Polygon<f64>)>>,
}

const EMPTY_BOX: [f64; 4] = [
    f64::INFINITY,
    f64::INFINITY,
    f64::NEG_INFINITY,
    f64::NEG_INFINITY,
];

fn union(a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
    [
        a[0].min(b[0]),
        a[1].min(b[1]),
        a[2].max(b[2]),
        a[3].max(b[3]),
    ]
}

/// Whether boxes `a` and `b`, `b` grown by `gap` on every side, meet (touching counts):
/// the R*-tree's envelope test.
fn within(a: [f64; 4], b: [f64; 4], gap: f64) -> bool {
    a[0] <= b[2] + gap && b[0] - gap <= a[2] && a[1] <= b[3] + gap && b[1] - gap <= a[3]
}

impl<'a> Placed<'a> {
    fn new(
        polygons: &'a [Polygon<f64>],
        bounds: &'a [[f64; 4]],
        partition: &Partition,
    ) -> Placed<'a> {
        let trees: Vec<RTree<Entry>> = partition
            .groups
            .iter()
            .map(|g| {
                RTree::bulk_load(
                    g.parts
                        .iter()
                        .map(|&p| Entry::new(rect(bounds[p]), p))
                        .collect(),
                )
            })
            .collect();
        let group_boxes = partition
            .groups
            .iter()
            .map(|g| g.parts.iter().fold(EMPTY_BOX, |u, &p| union(u, bounds[p])))
            .collect();
        Placed {
            polygons,
            bounds,
            trees,
            group_boxes,
            shifted: vec![None; polygons.len()],
        }
    }

    fn shift(partition: &Partition, p: usize) -> [f64; 2] {
        let g = &partition.groups[partition.group_of[p]];
        [g.dx_mm, g.dy_mm]
    }

    /// Part `p`'s box where its group puts it.
    fn placed_box(&self, partition: &Partition, p: usize) -> [f64; 4] {
        shifted_box(self.bounds[p], Self::shift(partition, p))
    }

    /// Parts whose placed box comes within `gap` of box `b` (a superset of those within
    /// `gap` of the polygon: two shapes are never closer than their boxes), in no
    /// particular order.
    fn near(&self, partition: &Partition, b: [f64; 4], gap: f64) -> Vec<usize> {
        let mut out = Vec::new();
        for (h, grp) in partition.groups.iter().enumerate() {
            let d = [grp.dx_mm, grp.dy_mm];
            if grp.parts.is_empty() || !within(shifted_box(self.group_boxes[h], d), b, gap) {
                continue;
            }
            // `b` grown by `gap`, in the group's unshifted frame: the parts whose placed
            // box meets it.
            let env = AABB::from_corners(
                [b[0] - gap - d[0], b[1] - gap - d[1]],
                [b[2] + gap - d[0], b[3] + gap - d[1]],
            );
            out.extend(
                self.trees[h]
                    .locate_in_envelope_intersecting(&env)
                    .map(|e| e.data)
                    .filter(|&q| within(self.placed_box(partition, q), b, gap)),
            );
        }
        out
    }

    /// Every pair `a < b` of parts of different groups whose placed boxes come within
    /// `gap` of each other.
    fn candidate_pairs(&self, partition: &Partition, gap: f64) -> Vec<(usize, usize)> {
        let mut out = Vec::new();
        let groups = &partition.groups;
        for (g, gg) in groups.iter().enumerate() {
            let dg = [gg.dx_mm, gg.dy_mm];
            if gg.parts.is_empty() {
                continue;
            }
            let gbox = shifted_box(self.group_boxes[g], dg);
            for (h, hg) in groups.iter().enumerate() {
                let dh = [hg.dx_mm, hg.dy_mm];
                if h == g || hg.parts.is_empty() {
                    continue;
                }
                let hbox = shifted_box(self.group_boxes[h], dh);
                if !within(gbox, hbox, gap) {
                    continue;
                }
                // The parts of g near h's box, then h's parts near each.
                let env = AABB::from_corners(
                    [hbox[0] - gap - dg[0], hbox[1] - gap - dg[1]],
                    [hbox[2] + gap - dg[0], hbox[3] + gap - dg[1]],
                );
                for a in self.trees[g].locate_in_envelope_intersecting(&env) {
                    let a = a.data;
                    let abox = shifted_box(self.bounds[a], dg);
                    let env = AABB::from_corners(
                        [abox[0] - gap - dh[0], abox[1] - gap - dh[1]],
                        [abox[2] + gap - dh[0], abox[3] + gap - dh[1]],
                    );
                    out.extend(
                        self.trees[h]
                            .locate_in_envelope_intersecting(&env)
                            .map(|e| e.data)
                            .filter(|&b| {
                                a < b && within(shifted_box(self.bounds[b], dh), abox, gap)
                            })
                            .map(|b| (a, b)),
                    );
                }
            }
        }
        out.sort_unstable();
        out
    }

    /// Translates part `p`'s polygon by its group's shift unless it already is.
    fn translate(&mut self, partition: &Partition, p: usize) {
        let d = Self::shift(partition, p);
        if self.shifted[p].as_ref().is_none_or(|(at, _)| *at != d) {
            self.shifted[p] = Some((d, self.polygons[p].translate(d[0], d[1])));
        }
    }

    /// Part `p`'s polygon where its group puts it (after [`Self::translate`]).
    fn polygon(&self, p: usize) -> &Polygon<f64> {
        &self.shifted[p].as_ref().expect("translated").1
    }

    /// The distance between parts `a` and `b` as placed, if below `limit`.
    fn distance_below(
        &mut self,
        partition: &Partition,
        a: usize,
        b: usize,
        limit: f64,
    ) -> Option<f64> {
        self.translate(partition, a);
        self.translate(partition, b);
        crate::near::distance_below(
            self.polygon(a),
            self.placed_box(partition, a),
            self.polygon(b),
            self.placed_box(partition, b),
            limit,
        )
    }

    /// Part `p` moved from group index `from` to `to` (the partition already says so).
    fn moved(&mut self, p: usize, from: usize, to: usize, partition: &Partition) {
        self.trees[from].remove(&Entry::new(rect(self.bounds[p]), p));
        self.trees[to].insert(Entry::new(rect(self.bounds[p]), p));
        for g in [from, to] {
            self.group_boxes[g] = partition.groups[g]
                .parts
                .iter()
                .fold(EMPTY_BOX, |u, &q| union(u, self.bounds[q]));
        }
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
    placed: &mut Placed,
    a: usize,
    b: usize,
    gap: f64,
) -> Option<Overlap> {
    let (ga, gb) = (partition.group_of[a], partition.group_of[b]);
    if ga == gb {
        return None;
    }
    let d = placed.distance_below(partition, a, b, gap - SLACK_MM)?;
    Some(Overlap {
        a: a.min(b),
        b: a.max(b),
        group_a: partition.groups[partition.group_of[a.min(b)]].id,
        group_b: partition.groups[partition.group_of[a.max(b)]].id,
        distance_mm: d,
    })
}

/// Pairs of parts found not close, with the translation of the second relative to the
/// first they were measured at: the same polygons at the same relative translation are
/// as far apart again, so a widening round measures only the pairs whose groups' shifts
/// changed relative to each other.
type Apart = std::collections::HashMap<(usize, usize), [f64; 2]>;

/// The overlaps as placed, sorted by (a, b), skipping the pairs `apart` holds at their
/// relative translation and adding those it finds apart.
fn detect_remembering(
    partition: &Partition,
    placed: &mut Placed,
    apart: &mut Apart,
) -> Vec<Overlap> {
    let gap = partition.clearance_mm;
    let mut out = Vec::new();
    for (a, b) in placed.candidate_pairs(partition, gap) {
        let (da, db) = (Placed::shift(partition, a), Placed::shift(partition, b));
        let rel = [db[0] - da[0], db[1] - da[1]];
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
    out
}

/// The parts' polygons and boxes as given.
fn shapes(parts: &[Part]) -> (Vec<Polygon<f64>>, Vec<[f64; 4]>) {
    (
        parts.iter().map(Part::polygon).collect(),
        parts.iter().map(Part::bounds).collect(),
    )
}

/// Every pair of parts of different groups, after their groups' shifts, whose contours
/// intersect or are closer than the clearance (exact polygon distance, `near.rs`, the
/// same as `geo`'s), candidates from R*-trees of the boxes (`rstar`, one per group).
/// Sorted by (a, b).
pub fn detect(parts: &[Part], partition: &Partition) -> Vec<Overlap> {
    let (polygons, bounds) = shapes(parts);
    let mut placed = Placed::new(&polygons, &bounds, partition);
    detect_remembering(partition, &mut placed, &mut Apart::new())
}

/// The same as [`detect`] by checking every pair: the reference for tests and benchmarks.
pub fn detect_exhaustive(parts: &[Part], partition: &Partition) -> Vec<Overlap> {
    let (polygons, bounds) = shapes(parts);
    let mut placed = Placed::new(&polygons, &bounds, partition);
    let gap = partition.clearance_mm;
    let mut out = Vec::new();
    for a in 0..parts.len() {
        for b in a + 1..parts.len() {
            out.extend(overlap(partition, &mut placed, a, b, gap));
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
    let (polygons, bounds) = shapes(parts);
    // The groups' trees, kept from round to round: a widening changes only shifts.
    let mut placed = Placed::new(&polygons, &bounds, partition);
    let found = detect_remembering(partition, &mut placed, &mut Apart::new());
    let mut moves = Vec::new();
    let mut widenings: Vec<Widening> = Vec::new();
    let mut rounds = 0;
    let mut memory = Memory {
        left_groups: vec![Vec::new(); parts.len()],
        apart: Apart::new(),
    };
    loop {
        let left = move_parts(
            partition,
            &bounds,
            pinned,
            &mut placed,
            &mut moves,
            &mut memory,
        );
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

/// A widening read back (a stored report); `between` is `window` or `lane`.
impl<'de> serde::Deserialize<'de> for Widening {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        use serde::de::Error;
        #[derive(serde::Deserialize)]
        struct Stored {
            between: String,
            from: usize,
            extra_mm: f64,
        }
        let s = Stored::deserialize(d)?;
        let between = ["window", "lane"]
            .into_iter()
            .find(|b| *b == s.between)
            .ok_or_else(|| D::Error::unknown_variant(&s.between, &["window", "lane"]))?;
        Ok(Widening {
            between,
            from: s.from,
            extra_mm: s.extra_mm,
        })
    }
}

/// What one resolution keeps from round to round: per part the groups it left (it never
/// goes back to one), and the pairs found apart.
struct Memory {
    left_groups: Vec<Vec<usize>>,
    apart: Apart,
}

/// Moves parts as [`resolve`] describes; returns the overlaps no move reduces.
fn move_parts(
    partition: &mut Partition,
    bounds: &[[f64; 4]],
    pinned: &[usize],
    placed: &mut Placed,
    moves: &mut Vec<Move>,
    memory: &mut Memory,
) -> Vec<Overlap> {
    let Memory { left_groups, apart } = memory;
    let gap = partition.clearance_mm;
    let mut current: std::collections::BTreeSet<(usize, usize)> =
        detect_remembering(partition, placed, apart)
            .iter()
            .map(|o| (o.a, o.b))
            .collect();
    // Where each candidate (part, group) would leave the part, kept while no move can
    // change it.
    let mut cache: std::collections::HashMap<(usize, usize), Option<Vec<usize>>> =
        std::collections::HashMap::new();
    // Each group's X extent (its parts' as given), for the window check of a candidate.
    let extent = |partition: &Partition, g: usize| partition.extent_with(bounds, g, None);
    let mut extents: Vec<[f64; 2]> = (0..partition.groups.len())
        .map(|g| extent(partition, g))
        .collect();
    'search: while !current.is_empty() {
        // How many overlaps each part has (the score's "before"; `current` changes only
        // by a move, which starts the search again).
        let mut count: std::collections::HashMap<usize, usize> = Default::default();
        for &(x, y) in &current {
            *count.entry(x).or_default() += 1;
            *count.entry(y).or_default() += 1;
        }
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
                    .or_insert_with(|| overlaps_if_moved(partition, bounds, placed, &extents, p, g))
                    .clone()
                else {
                    continue;
                };
                let before = count.get(&p).copied().unwrap_or(0) as i64;
                let score = after.len() as i64 - before;
                if score < 0 && best.as_ref().is_none_or(|b| score < b.0) {
                    best = Some((score, p, g, after));
                }
            }
            if let Some((_, p, g, after)) = best {
                let from = partition.group_of[p];
                let other = if p == a { b } else { a };
                let distance_mm = placed
                    .distance_below(partition, p, other, f64::INFINITY)
                    .unwrap_or(0.0);
                let overlaps_before = count.get(&p).copied().unwrap_or(0);
                let overlaps_after = after.len();
                left_groups[p].push(from);
                let old_box = placed.placed_box(partition, p);
                partition.reassign(p, g);
                placed.moved(p, from, g, partition);
                extents[from] = extent(partition, from);
                extents[g] = extent(partition, g);
                // A candidate's outcome depends on its target group's extent and on the
                // parts near where it would go: keep those the move cannot touch.
                let new_box = placed.placed_box(partition, p);
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
            .filter_map(|&(a, b)| overlap(partition, placed, a, b, gap))
            .collect();
    }
    Vec::new()
}

/// The parts of other groups part `p` would be too close to in group index `g`, or None
/// when it may not go there (the group would be too long for its window).
fn overlaps_if_moved(
    partition: &Partition,
    bounds: &[[f64; 4]],
    placed: &mut Placed,
    extents: &[[f64; 2]],
    p: usize,
    g: usize,
) -> Option<Vec<usize>> {
    // The group's X extent with the part (min and max: the same as over its parts).
    let ext = [
        extents[g][0].min(bounds[p][0]),
        extents[g][1].max(bounds[p][2]),
    ];
    if !partition.window_fits_extent(g, ext) {
        return None;
    }
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
    for q in placed.near(partition, bx, gap) {
        // Group mates keep their nested positions (the same shift): no check needed.
        if q == p || partition.group_of[q] == g {
            continue;
        }
        placed.translate(partition, q);
        if crate::near::distance_below(
            &moved,
            bx,
            placed.polygon(q),
            placed.placed_box(partition, q),
            gap - SLACK_MM,
        )
        .is_some()
        {
            close.push(q);
        }
    }
    Some(close)
}

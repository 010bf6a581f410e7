//! A part's polygon checked by the rules of `geo`'s `Validation` for polygons, with the
//! self-intersection test indexed.
//!
//! `geo` 0.33 tests a ring for self-intersection by comparing every segment with every
//! other one: a contour of 8 000 points (a curve flattened finely, or one fuzzed input
//! with a control point 800 m away) costs 64 million segment tests, most of a second per
//! reading. Here the candidate pairs come from an R-tree of the segments' bounding boxes
//! (two segments can only meet if their boxes do), and each candidate is decided by the
//! same predicate as `geo`'s (`Line::intersects`, pairs that share a vertex as neighbours
//! do excused), so the verdicts are the same and a ring costs O(n log n). The checks
//! between rings are `geo`'s own, through its public `PreparedGeometry` relate.

use geo::algorithm::validation::{InvalidPolygon, RingRole};
use geo::coordinate_position::CoordPos;
use geo::dimensions::Dimensions;
use geo::{Intersects, Line, LineString, Polygon, PreparedGeometry, Relate, RemoveRepeatedPoints};
use rstar::primitives::GeomWithData;
use rstar::{RTree, AABB};

/// The first rule the polygon breaks, worded as `geo` words it (with the place of a
/// self-intersection added), or `Ok`.
pub(crate) fn check_polygon(polygon: &Polygon<f64>) -> Result<(), String> {
    for (index, ring) in std::iter::once(polygon.exterior())
        .chain(polygon.interiors())
        .enumerate()
    {
        let role = if index == 0 {
            RingRole::Exterior
        } else {
            RingRole::Interior(index - 1)
        };
        if ring.remove_repeated_points().0.len() < 4 {
            return Err(InvalidPolygon::TooFewPointsInRing(role).to_string());
        }
        if let Some(at) = self_intersection(ring) {
            return Err(format!(
                "{} near ({:.6}, {:.6}) mm",
                InvalidPolygon::SelfIntersection(role),
                at.x,
                at.y
            ));
        }
    }
    if polygon.interiors().is_empty() {
        return Ok(());
    }
    // As geo's `Validation` does: each hole inside the exterior and touching it at points
    // only; no two holes overlapping or touching along a line.
    let exterior = Polygon::new(polygon.exterior().clone(), vec![]);
    let exterior = PreparedGeometry::from(&exterior);
    let holes: Vec<Polygon<f64>> = polygon
        .interiors()
        .iter()
        .map(|ring| Polygon::new(ring.clone(), vec![]))
        .collect();
    for (i, hole) in holes.iter().enumerate() {
        let prepared = PreparedGeometry::from(hole);
        let relation = exterior.relate(&prepared);
        if !relation.is_contains() {
            return Err(InvalidPolygon::InteriorRingNotContainedInExteriorRing(
                RingRole::Interior(i),
            )
            .to_string());
        }
        if relation.get(CoordPos::OnBoundary, CoordPos::OnBoundary) == Dimensions::OneDimensional {
            return Err(InvalidPolygon::IntersectingRingsOnALine(
                RingRole::Exterior,
                RingRole::Interior(i),
            )
            .to_string());
        }
        for (j, other) in holes.iter().enumerate().skip(i + 1) {
            let relation = prepared.relate(other);
            if relation.get(CoordPos::Inside, CoordPos::Inside) == Dimensions::TwoDimensional {
                return Err(InvalidPolygon::IntersectingRingsOnAnArea(
                    RingRole::Interior(i),
                    RingRole::Interior(j),
                )
                .to_string());
            }
            if relation.get(CoordPos::OnBoundary, CoordPos::OnBoundary)
                == Dimensions::OneDimensional
            {
                return Err(InvalidPolygon::IntersectingRingsOnALine(
                    RingRole::Interior(i),
                    RingRole::Interior(j),
                )
                .to_string());
            }
        }
    }
    Ok(())
}

/// A point where two segments of the ring meet other than as neighbours, if any.
/// The predicate is `geo`'s: segments `a` and `b` (not the same one) intersect and
/// neither `a` ends where `b` starts nor `b` ends where `a` starts.
fn self_intersection(ring: &LineString<f64>) -> Option<geo::Coord<f64>> {
    let segments: Vec<GeomWithData<rstar::primitives::Rectangle<[f64; 2]>, usize>> = ring
        .lines()
        .enumerate()
        .map(|(i, line)| {
            let (a, b) = (line.start, line.end);
            let envelope = rstar::primitives::Rectangle::from_corners(
                [a.x.min(b.x), a.y.min(b.y)],
                [a.x.max(b.x), a.y.max(b.y)],
            );
            GeomWithData::new(envelope, i)
        })
        .collect();
    let lines: Vec<Line<f64>> = ring.lines().collect();
    let tree = RTree::bulk_load(segments);
    for (i, a) in lines.iter().enumerate() {
        let envelope = AABB::from_corners(
            [a.start.x.min(a.end.x), a.start.y.min(a.end.y)],
            [a.start.x.max(a.end.x), a.start.y.max(a.end.y)],
        );
        for candidate in tree.locate_in_envelope_intersecting(&envelope) {
            let j = candidate.data;
            // Each unordered pair once; the predicate is symmetric.
            if j <= i {
                continue;
            }
            let b = &lines[j];
            if a.intersects(b) && a.start != b.end && a.end != b.start {
                return Some(meeting_point(a, b));
            }
        }
    }
    None
}

/// Where two intersecting segments meet (the first common point for collinear ones).
fn meeting_point(a: &Line<f64>, b: &Line<f64>) -> geo::Coord<f64> {
    match geo::line_intersection::line_intersection(*a, *b) {
        Some(geo::line_intersection::LineIntersection::SinglePoint { intersection, .. }) => {
            intersection
        }
        Some(geo::line_intersection::LineIntersection::Collinear { intersection }) => {
            intersection.start
        }
        None => a.start,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use geo::Validation;

    fn ring(points: &[(f64, f64)]) -> LineString<f64> {
        LineString::from(points.to_vec())
    }

    /// The same verdict as geo's quadratic check on rings that are simple, cross, touch at
    /// a vertex, run back along themselves, or repeat a point.
    #[test]
    fn agrees_with_geo_on_simple_and_broken_rings() {
        type Ring = Vec<(f64, f64)>;
        let cases: Vec<(Ring, Vec<Ring>)> = vec![
            (
                vec![(0., 0.), (10., 0.), (10., 10.), (0., 10.), (0., 0.)],
                vec![],
            ),
            // A bow tie.
            (
                vec![(0., 0.), (10., 10.), (10., 0.), (0., 10.), (0., 0.)],
                vec![],
            ),
            // A ring touching itself at a vertex (an inverted hole).
            (
                vec![
                    (0., 0.),
                    (10., 0.),
                    (10., 10.),
                    (5., 0.),
                    (0., 10.),
                    (0., 0.),
                ],
                vec![],
            ),
            // A repeated point.
            (
                vec![(0., 0.), (10., 0.), (10., 0.), (10., 10.), (0., 0.)],
                vec![],
            ),
            // Too few distinct points.
            (vec![(0., 0.), (10., 0.), (10., 0.), (0., 0.)], vec![]),
            // A hole inside, a hole crossing the outline, two overlapping holes.
            (
                vec![(0., 0.), (10., 0.), (10., 10.), (0., 10.), (0., 0.)],
                vec![vec![(2., 2.), (4., 2.), (4., 4.), (2., 2.)]],
            ),
            (
                vec![(0., 0.), (10., 0.), (10., 10.), (0., 10.), (0., 0.)],
                vec![vec![(8., 2.), (12., 2.), (12., 4.), (8., 2.)]],
            ),
            (
                vec![(0., 0.), (10., 0.), (10., 10.), (0., 10.), (0., 0.)],
                vec![
                    vec![(2., 2.), (6., 2.), (6., 6.), (2., 6.), (2., 2.)],
                    vec![(4., 4.), (8., 4.), (8., 8.), (4., 8.), (4., 4.)],
                ],
            ),
        ];
        for (outer, holes) in cases {
            let polygon = Polygon::new(ring(&outer), holes.iter().map(|h| ring(h)).collect());
            let ours = check_polygon(&polygon);
            let geos = polygon.check_validation();
            assert_eq!(
                ours.is_ok(),
                geos.is_ok(),
                "{outer:?} {holes:?}: {ours:?} vs {geos:?}"
            );
        }
    }

    /// A crossing is named with its place.
    #[test]
    fn names_where_a_ring_crosses_itself() {
        let polygon = Polygon::new(
            ring(&[(0., 0.), (10., 10.), (10., 0.), (0., 10.), (0., 0.)]),
            vec![],
        );
        let message = check_polygon(&polygon).unwrap_err();
        assert!(
            message.contains("exterior ring has a self-intersection"),
            "{message}"
        );
        assert!(message.contains("(5.000000, 5.000000)"), "{message}");
    }

    /// Random star-shaped rings, some with a vertex pulled across: same verdicts as geo.
    #[test]
    fn agrees_with_geo_on_random_rings() {
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut broken = 0;
        for case in 0..300 {
            let n = 5 + (case % 40);
            let mut points: Vec<(f64, f64)> = (0..n)
                .map(|k| {
                    let angle = std::f64::consts::TAU * k as f64 / n as f64;
                    let r = 5.0 + 5.0 * next();
                    (r * angle.cos(), r * angle.sin())
                })
                .collect();
            if case % 3 == 0 {
                let k = (next() * n as f64) as usize % n;
                points[k] = (20.0 * next() - 10.0, 20.0 * next() - 10.0);
            }
            points.push(points[0]);
            let polygon = Polygon::new(ring(&points), vec![]);
            let ours = check_polygon(&polygon);
            broken += usize::from(ours.is_err());
            assert_eq!(
                ours.is_ok(),
                polygon.check_validation().is_ok(),
                "{points:?}"
            );
        }
        // The pulled vertices break some rings: the comparison covers both verdicts.
        assert!(broken > 10, "{broken}");
    }
}

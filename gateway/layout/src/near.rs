//! The distance between two parts' polygons when it is below a limit: what overlap
//! detection asks millions of times. geo's `Euclidean` polygon distance compares every
//! edge with every edge; two parts of a nest are close along a short stretch only, so
//! only the edges within the limit of the other polygon's box can give a distance below
//! it (the closest pair of points lies on such edges), and the rest are skipped. The
//! value is the same as geo's (tests compare them on random polygons).

use geo::{Intersects, Polygon};

type Segment = [[f64; 2]; 2];

fn box_gap(a: [f64; 4], b: [f64; 4]) -> f64 {
    let dx = (a[0] - b[2]).max(b[0] - a[2]).max(0.0);
    let dy = (a[1] - b[3]).max(b[1] - a[3]).max(0.0);
    dx.hypot(dy)
}

/// Every ring's edges of `p` whose box comes within `limit` of box `other`, each with
/// its box.
fn edges_near(p: &Polygon<f64>, other: [f64; 4], limit: f64) -> Vec<(Segment, [f64; 4])> {
    let limit2 = limit * limit;
    // A quick and safe rejection first: both ends past the other box grown by a little
    // more than the limit on one side (the exact test below decides the rest, so the
    // edges kept are the same).
    let margin = limit * (1.0 + 1e-6) + 1e-9;
    let (lo_x, lo_y, hi_x, hi_y) = (
        other[0] - margin,
        other[1] - margin,
        other[2] + margin,
        other[3] + margin,
    );
    let mut out = Vec::with_capacity(16);
    for ring in std::iter::once(p.exterior()).chain(p.interiors()) {
        for w in ring.0.windows(2) {
            let (a, b) = (w[0], w[1]);
            if (a.x > hi_x && b.x > hi_x)
                || (a.x < lo_x && b.x < lo_x)
                || (a.y > hi_y && b.y > hi_y)
                || (a.y < lo_y && b.y < lo_y)
            {
                continue;
            }
            let s = [[a.x, a.y], [b.x, b.y]];
            let b = [
                s[0][0].min(s[1][0]),
                s[0][1].min(s[1][1]),
                s[0][0].max(s[1][0]),
                s[0][1].max(s[1][1]),
            ];
            // Squared (no square root per edge).
            let dx = (b[0] - other[2]).max(other[0] - b[2]).max(0.0);
            let dy = (b[1] - other[3]).max(other[1] - b[3]).max(0.0);
            if dx * dx + dy * dy < limit2 {
                out.push((s, b));
            }
        }
    }
    out
}

/// The squared distance from point `p` to segment `s` (squares: no square root in the
/// inner loop, one at the end).
fn point_segment(p: [f64; 2], s: Segment) -> f64 {
    let (dx, dy) = (s[1][0] - s[0][0], s[1][1] - s[0][1]);
    let len2 = dx * dx + dy * dy;
    let t = if len2 > 0.0 {
        (((p[0] - s[0][0]) * dx + (p[1] - s[0][1]) * dy) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let (ex, ey) = (p[0] - s[0][0] - t * dx, p[1] - s[0][1] - t * dy);
    ex * ex + ey * ey
}

fn cross(o: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
}

/// Squared distance between two segments: 0 when they cross, else the least of the four
/// endpoint-to-segment distances.
fn segment_segment(a: Segment, b: Segment) -> f64 {
    let (d1, d2) = (cross(a[0], a[1], b[0]), cross(a[0], a[1], b[1]));
    let (d3, d4) = (cross(b[0], b[1], a[0]), cross(b[0], b[1], a[1]));
    if ((d1 > 0.0 && d2 < 0.0) || (d1 < 0.0 && d2 > 0.0))
        && ((d3 > 0.0 && d4 < 0.0) || (d3 < 0.0 && d4 > 0.0))
    {
        return 0.0;
    }
    point_segment(a[0], b)
        .min(point_segment(a[1], b))
        .min(point_segment(b[0], a))
        .min(point_segment(b[1], a))
}

/// The distance between polygons `a` and `b` (boxes `ab`, `bb`) if it is below `limit`,
/// else None. 0 when they intersect, one lies inside the other, or they touch.
pub(crate) fn distance_below(
    a: &Polygon<f64>,
    ab: [f64; 4],
    b: &Polygon<f64>,
    bb: [f64; 4],
    limit: f64,
) -> Option<f64> {
    if box_gap(ab, bb) >= limit {
        return None;
    }
    // One inside the other (outside its holes) with no edges near: distance 0.
    // (A point outside the other's box is outside it: the ring test is skipped.)
    let inside = |p: &Polygon<f64>, q: &Polygon<f64>, qb: [f64; 4]| {
        p.exterior().0.first().is_some_and(|c| {
            c.x >= qb[0] && c.x <= qb[2] && c.y >= qb[1] && c.y <= qb[3] && q.intersects(c)
        })
    };
    if inside(a, b, bb) || inside(b, a, ab) {
        return Some(0.0);
    }
    let ea = edges_near(a, bb, limit);
    let eb = edges_near(b, ab, limit);
    // Squared distances; a pair of edges whose boxes are already as far apart as the
    // best so far cannot improve it.
    let mut best = limit * limit;
    let mut found = false;
    for (s, sb) in &ea {
        for (t, tb) in &eb {
            let dx = (sb[0] - tb[2]).max(tb[0] - sb[2]).max(0.0);
            let dy = (sb[1] - tb[3]).max(tb[1] - sb[3]).max(0.0);
            if dx * dx + dy * dy >= best {
                continue;
            }
            let d = segment_segment(*s, *t);
            if d < best {
                best = d;
                found = true;
                if d == 0.0 {
                    return Some(0.0);
                }
            }
        }
    }
    found.then(|| best.sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;
    use geo::{BoundingRect, Distance, Euclidean, LineString};

    fn bounds(p: &Polygon<f64>) -> [f64; 4] {
        let r = p.bounding_rect().unwrap();
        [r.min().x, r.min().y, r.max().x, r.max().y]
    }

    /// A star-ish polygon around (cx, cy) from a small deterministic generator.
    fn blob(seed: &mut u64, cx: f64, cy: f64, holes: bool) -> Polygon<f64> {
        let mut next = || {
            *seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((*seed >> 11) as f64) / ((1u64 << 53) as f64)
        };
        let n = 5 + (next() * 30.0) as usize;
        let ring: Vec<(f64, f64)> = (0..n)
            .map(|k| {
                let a = k as f64 / n as f64 * std::f64::consts::TAU;
                let r = 4.0 + 6.0 * next();
                (cx + r * a.cos(), cy + r * a.sin())
            })
            .collect();
        let interiors = if holes {
            vec![LineString::from(vec![
                (cx - 1.0, cy - 1.0),
                (cx + 1.0, cy - 1.0),
                (cx + 1.0, cy + 1.0),
                (cx - 1.0, cy + 1.0),
            ])]
        } else {
            vec![]
        };
        Polygon::new(LineString::from(ring), interiors)
    }

    /// The same distance as geo's below the limit, None exactly when geo's is not
    /// below it: 2 000 random pairs, near and far, crossing, nested, in holes.
    #[test]
    fn agrees_with_geo_on_random_polygons() {
        let mut seed = 7u64;
        let mut below = 0;
        for i in 0..2000 {
            let a = blob(&mut seed, 0.0, 0.0, i % 3 == 0);
            let off = (i % 40) as f64 * 0.6;
            let b = blob(&mut seed, off, (i % 7) as f64 * 0.5, false);
            let limit = 0.5 + (i % 5) as f64;
            let want = Euclidean.distance(&a, &b);
            let got = distance_below(&a, bounds(&a), &b, bounds(&b), limit);
            match got {
                Some(d) => {
                    below += 1;
                    assert!((d - want).abs() < 1e-9, "pair {i}: {d} vs geo {want}");
                    assert!(want < limit);
                }
                None => assert!(want >= limit - 1e-12, "pair {i}: geo {want} < {limit}"),
            }
        }
        assert!(
            below > 200 && below < 1900,
            "{below} pairs below: both cases tested"
        );
    }

    /// A small square in a big one's hole is as far as the hole's edge.
    #[test]
    fn a_part_in_a_hole_is_as_far_as_the_hole() {
        let big = Polygon::new(
            LineString::from(vec![(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0)]),
            vec![LineString::from(vec![
                (2.0, 2.0),
                (8.0, 2.0),
                (8.0, 8.0),
                (2.0, 8.0),
            ])],
        );
        let small = Polygon::new(
            LineString::from(vec![(4.0, 4.0), (6.0, 4.0), (6.0, 6.0), (4.0, 6.0)]),
            vec![],
        );
        let d = distance_below(&big, bounds(&big), &small, bounds(&small), 5.0);
        assert_eq!(d, Some(2.0));
        assert_eq!(
            distance_below(&big, bounds(&big), &small, bounds(&small), 2.0),
            None
        );
    }
}

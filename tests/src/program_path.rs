//! The programmed path of a G-code program and how far a traced tool point strayed
//! from it: the measure the pass-through and retrofit tests hold the true trace to.

use protocol::grbl::gcode::{filter_line, Action, Interpreter};

/// The XY points GRBL's interpreter plans for `program` (arcs as fine chords), from the
/// first one at `start` on (where the feed moves begin).
pub fn programmed_path(program: &str, start: [f64; 2]) -> Vec<[f64; 2]> {
    let mut interp = Interpreter::new();
    interp.arc_tolerance = 1e-6;
    let mut path = Vec::new();
    for line in program.lines() {
        let f = filter_line(line).unwrap();
        if f.is_empty() {
            continue;
        }
        for a in interp.execute(&f, false).unwrap() {
            if let Action::Move { target, .. } = a {
                path.push([target[0], target[1]]);
            }
        }
    }
    let at = path
        .iter()
        .position(|p| *p == start)
        .expect("the program passes through its start");
    path.split_off(at)
}

/// The squared distance of `q` from the segment `a`-`b` (squared: the search compares
/// them and takes one root at the end; this runs for every row against hundreds of
/// segments in an unoptimized test build).
fn distance2_to_segment(q: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let (qx, qy) = (q[0] - a[0], q[1] - a[1]);
    let len2 = dx * dx + dy * dy;
    let t = if len2 == 0.0 {
        0.0
    } else {
        ((qx * dx + qy * dy) / len2).clamp(0.0, 1.0)
    };
    let (ex, ey) = (qx - t * dx, qy - t * dy);
    ex * ex + ey * ey
}

/// Largest distance of the points from the path, both in travel order: each point is
/// matched within a window of segments around the last match (the tool moves along the
/// path), which keeps the check linear in the number of rows. `PATH_DEBUG` in the
/// environment prints each new worst point.
pub fn worst_distance(points: impl Iterator<Item = [f64; 2]>, path: &[[f64; 2]]) -> f64 {
    let mut at: usize = 0;
    let mut worst: f64 = 0.0;
    for q in points {
        // A window both ways: near a corner the next element (an arc leaving the corner
        // along the same line) can be as close as the current one.
        let (begin, end) = (at.saturating_sub(400), (at + 400).min(path.len() - 1));
        let (mut k, mut d2) = (at, f64::INFINITY);
        for j in begin..end {
            let e2 = distance2_to_segment(q, path[j], path[j + 1]);
            if e2 < d2 {
                (k, d2) = (j, e2);
            }
        }
        let d = d2.sqrt();
        at = k;
        if d > worst && std::env::var_os("PATH_DEBUG").is_some() {
            eprintln!(
                "worst so far {:.3} um at {q:?}, segment {k} {:?} -> {:?}",
                d * 1e3,
                path[k],
                path[k + 1]
            );
        }
        worst = worst.max(d);
    }
    worst
}

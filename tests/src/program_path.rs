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

/// Segments per block of the search: a block whose bounding box is farther from the
/// point than a distance already found holds no nearer segment and is skipped.
const BLOCK: usize = 32;

/// The bounding box (`[min x, min y, max x, max y]`) of each `BLOCK` segments of `path`.
fn block_boxes(path: &[[f64; 2]]) -> Vec<[f64; 4]> {
    let segments = path.len().saturating_sub(1);
    (0..segments.div_ceil(BLOCK))
        .map(|b| {
            let last = (b * BLOCK + BLOCK).min(segments);
            path[b * BLOCK..=last].iter().fold(
                [
                    f64::INFINITY,
                    f64::INFINITY,
                    f64::NEG_INFINITY,
                    f64::NEG_INFINITY,
                ],
                |r, p| {
                    [
                        r[0].min(p[0]),
                        r[1].min(p[1]),
                        r[2].max(p[0]),
                        r[3].max(p[1]),
                    ]
                },
            )
        })
        .collect()
}

/// The squared distance of `q` from the box `b`: no segment inside it is nearer.
fn distance2_to_box(q: [f64; 2], b: &[f64; 4]) -> f64 {
    let dx = (b[0] - q[0]).max(q[0] - b[2]).max(0.0);
    let dy = (b[1] - q[1]).max(q[1] - b[3]).max(0.0);
    dx * dx + dy * dy
}

/// Largest distance of the points from the path, both in travel order: each point is
/// matched within a window of segments around the last match (the tool moves along the
/// path), which keeps the check linear in the number of rows. Within the window, blocks
/// of segments whose bounding box is farther than the last match's segment are skipped
/// (they cannot hold the nearest one, so the result is that of the full window; it runs
/// for every traced row in an unoptimized test build). `PATH_DEBUG` in the environment
/// prints each new worst point.
pub fn worst_distance(points: impl Iterator<Item = [f64; 2]>, path: &[[f64; 2]]) -> f64 {
    let boxes = block_boxes(path);
    let mut at: usize = 0;
    let mut worst: f64 = 0.0;
    for q in points {
        let (k, d2) = nearest_in_window(q, path, &boxes, at);
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

/// The nearest segment to `q` (the first one of the least distance) within the window
/// around the last match `at`, and its squared distance.
fn nearest_in_window(
    q: [f64; 2],
    path: &[[f64; 2]],
    boxes: &[[f64; 4]],
    at: usize,
) -> (usize, f64) {
    // A window both ways: near a corner the next element (an arc leaving the corner
    // along the same line) can be as close as the current one.
    let (begin, end) = (at.saturating_sub(400), (at + 400).min(path.len() - 1));
    let (mut k, mut d2) = (at, f64::INFINITY);
    if begin < end {
        // The last match's segment bounds the nearest distance from above (with a
        // margin for rounding, so a block is skipped only when clearly farther).
        let j = at.clamp(begin, end - 1);
        let bound = distance2_to_segment(q, path[j], path[j + 1]) * (1.0 + 1e-9) + 1e-24;
        for b in begin / BLOCK..=(end - 1) / BLOCK {
            if distance2_to_box(q, &boxes[b]) > bound {
                continue;
            }
            for j in (b * BLOCK).max(begin)..(b * BLOCK + BLOCK).min(end) {
                let e2 = distance2_to_segment(q, path[j], path[j + 1]);
                if e2 < d2 {
                    (k, d2) = (j, e2);
                }
            }
        }
    }
    (k, d2)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The window search without the skipped blocks: every segment of the window.
    fn nearest_unpruned(q: [f64; 2], path: &[[f64; 2]], at: usize) -> (usize, f64) {
        let (begin, end) = (at.saturating_sub(400), (at + 400).min(path.len() - 1));
        let (mut k, mut d2) = (at, f64::INFINITY);
        for j in begin..end {
            let e2 = distance2_to_segment(q, path[j], path[j + 1]);
            if e2 < d2 {
                (k, d2) = (j, e2);
            }
        }
        (k, d2)
    }

    #[test]
    fn skipping_far_blocks_finds_what_the_whole_window_finds() {
        let program = "G21 G90 G17\nG0 X20 Y20\nG1 X150 Y20 F3000\nG2 X110 Y20 I-20 J0\n\
                       G1 X20 Y30\nG3 X60 Y60 I20 J15\nG1 X180 Y130\nG1 X20.001 Y20\n\
                       G1 X150 Y20.002\n";
        let path = programmed_path(program, [20.0, 20.0]);
        assert!(path.len() > 1000, "{} points", path.len());
        // Points along the path, off it by up to 50 um, and a few far off (a tool that
        // strays), from a fixed linear congruential sequence.
        let mut state: u64 = 42;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut points = Vec::new();
        for w in path.windows(2) {
            let t = next();
            let far = if next() < 0.01 { 5.0 } else { 0.05 };
            points.push([
                w[0][0] + t * (w[1][0] - w[0][0]) + far * (next() - 0.5),
                w[0][1] + t * (w[1][1] - w[0][1]) + far * (next() - 0.5),
            ]);
        }
        let boxes = block_boxes(&path);
        let mut at = 0;
        for (i, &q) in points.iter().enumerate() {
            let pruned = nearest_in_window(q, &path, &boxes, at);
            let full = nearest_unpruned(q, &path, at);
            assert_eq!(pruned.0, full.0, "point {i}: segment");
            assert_eq!(pruned.1.to_bits(), full.1.to_bits(), "point {i}: distance");
            at = full.0;
        }
    }
}

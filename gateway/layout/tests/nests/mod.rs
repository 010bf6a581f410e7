//! The layouts the benchmark measures and the same-results test checks (shared by
//! `examples/layout_bench.rs` and `tests/same_results.rs` through `#[path]`): every
//! `data/esicup/*.json` with the benchmark's parameters, and generated 10 000-part nests.

#![allow(dead_code)]

use layout::Params;
use layout_io::{Format, Layout, Part, ReadOptions};

/// A layout and the parameters it is partitioned with.
pub struct Case {
    pub name: String,
    pub parts: Vec<Part>,
    pub params: Params,
}

/// Every layout of data/esicup, by name, read (or why it could not be).
pub fn esicup() -> Vec<(String, Result<Layout, String>)> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/esicup");
    let mut out: Vec<(String, Result<Layout, String>)> = std::fs::read_dir(&dir)
        .expect("data/esicup")
        .filter_map(|e| {
            let path = e.ok()?.path();
            (path.extension()? == "json").then(|| {
                let name = path.file_stem().unwrap().to_string_lossy().into_owned();
                let text = std::fs::read_to_string(&path).expect("layout");
                let doc = Layout::read(text.as_bytes(), Format::Json, &ReadOptions::default())
                    .map_err(|e| e.to_string());
                (name, doc)
            })
        })
        .collect();
    out.sort_by(|a, b| a.0.cmp(&b.0));
    out
}

/// The benchmark's parameters for an ESICUP layout of strip width `w`: 2 tools (1 where
/// a part is wider than W / 2), L' = 0.8 W (1.1 times the longest part where that is
/// longer), gap W / 80, clearance the gap times `clearance` (1 or 0.5).
pub fn esicup_params(doc: &Layout, clearance: f64) -> Params {
    let w = doc.width_mm.expect("width");
    let widest = doc
        .parts
        .iter()
        .map(|p| p.bounds()[3] - p.bounds()[1])
        .fold(0.0, f64::max);
    let longest = doc
        .parts
        .iter()
        .map(|p| p.bounds()[2] - p.bounds()[0])
        .fold(0.0, f64::max);
    Params {
        tools: if widest <= w / 2.0 { 2 } else { 1 },
        window_mm: (0.8 * w).max(1.1 * longest),
        gap_mm: w / 80.0,
        width_mm: Some(w),
        clearance_mm: Some(w / 80.0 * clearance),
    }
}

fn lcg(seed: u64) -> impl FnMut() -> f64 {
    let mut state = seed;
    move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Star-shaped parts (5 to 10 points at radius 6 to 10 mm) in columns of 50 on a grid of
/// `pitch` mm: at 20 mm neighbours touch or nearly touch, at 20.5 mm every two parts are
/// at least 0.5 mm apart, at 22.5 mm at least 2.5 mm.
pub fn stars(n: usize, seed: u64, pitch: f64) -> Vec<Part> {
    let mut next = lcg(seed);
    let rows = 50;
    (0..n)
        .map(|i| {
            let (cx, cy) = (
                (i / rows) as f64 * pitch + 10.0,
                (i % rows) as f64 * pitch + 10.0,
            );
            let k = 5 + (next() * 6.0) as usize;
            let outer = (0..k)
                .map(|j| {
                    let a = std::f64::consts::TAU * j as f64 / k as f64;
                    let r = 6.0 + next() * 4.0;
                    [cx + r * a.cos(), cy + r * a.sin()]
                })
                .collect();
            part(i, outer)
        })
        .collect()
}

/// Diamonds (squares turned 45°, 20 mm corner to corner less the gap) nested in a
/// checkerboard, every neighbour exactly `gap` mm away along a slanted edge, 50 across:
/// a shift of G along X or Y moves a 45° edge only G / sqrt 2 away, so with a gap of
/// 0.5 mm and G = 2 every pair across a window or lane boundary stays closer than G
/// after S8 (the nest that needs widening).
pub fn diamonds(n: usize, gap: f64) -> Vec<Part> {
    let pitch = 10.0;
    let half = pitch - gap / std::f64::consts::SQRT_2;
    let rows = 50;
    (0..n)
        .map(|i| {
            let (col, row) = (i / rows, i % rows);
            // Checkerboard: the centres of one column sit half a pitch off the next's.
            let cx = col as f64 * pitch + 10.0;
            let cy = (2 * row + col % 2) as f64 * pitch + 10.0;
            let outer = vec![
                [cx - half, cy],
                [cx, cy - half],
                [cx + half, cy],
                [cx, cy + half],
            ];
            part(i, outer)
        })
        .collect()
}

/// A jittered grid cut into quadrilaterals (corners 20 mm apart, each moved up to
/// `jitter` mm along X and Y), each cell shrunk by half of `gap` on every edge, 50 across:
/// every neighbour exactly `gap` mm away along edges at random slants, as a nest of
/// irregular pieces cut with a kerf.
pub fn quads(n: usize, seed: u64, gap: f64, jitter: f64) -> Vec<Part> {
    let mut next = lcg(seed);
    let (rows, pitch) = (50usize, 20.0);
    let cols = n.div_ceil(rows);
    // Corner (c, r) for c in 0..=cols, r in 0..=rows; the border stays straight.
    let corners: Vec<Vec<[f64; 2]>> = (0..=cols)
        .map(|c| {
            (0..=rows)
                .map(|r| {
                    let mut j = || (next() * 2.0 - 1.0) * jitter;
                    let (jx, jy) = (j(), j());
                    let jx = if c == 0 || c == cols { 0.0 } else { jx };
                    let jy = if r == 0 || r == rows { 0.0 } else { jy };
                    [c as f64 * pitch + jx, r as f64 * pitch + jy]
                })
                .collect()
        })
        .collect();
    (0..n)
        .map(|i| {
            let (c, r) = (i / rows, i % rows);
            let quad = [
                corners[c][r],
                corners[c + 1][r],
                corners[c + 1][r + 1],
                corners[c][r + 1],
            ];
            part(i, inset(&quad, gap / 2.0))
        })
        .collect()
}

/// A convex counter-clockwise polygon with every edge moved `d` inwards.
fn inset(p: &[[f64; 2]], d: f64) -> Vec<[f64; 2]> {
    let k = p.len();
    // Each edge as a point moved inwards and its direction.
    let edges: Vec<([f64; 2], [f64; 2])> = (0..k)
        .map(|i| {
            let (a, b) = (p[i], p[(i + 1) % k]);
            let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
            let len = dx.hypot(dy);
            // Inwards of a counter-clockwise ring: the left normal.
            let (nx, ny) = (-dy / len, dx / len);
            ([a[0] + d * nx, a[1] + d * ny], [dx, dy])
        })
        .collect();
    (0..k)
        .map(|i| {
            let (p1, d1) = edges[(i + k - 1) % k];
            let (p2, d2) = edges[i];
            // p1 + t d1 = p2 + s d2
            let det = d1[0] * (-d2[1]) - d1[1] * (-d2[0]);
            let (rx, ry) = (p2[0] - p1[0], p2[1] - p1[1]);
            let t = (rx * (-d2[1]) - ry * (-d2[0])) / det;
            [p1[0] + t * d1[0], p1[1] + t * d1[1]]
        })
        .collect()
}

fn part(i: usize, outer: Vec<[f64; 2]>) -> Part {
    Part {
        id: format!("p{i}"),
        outer,
        holes: vec![],
        layer: String::new(),
        attributes: Default::default(),
    }
}

/// The generated nests: 4 tools, L' 300 mm, G 2 mm, W the nest's width.
pub fn generated(n: usize) -> Vec<Case> {
    let params = |w: f64| Params {
        tools: 4,
        window_mm: 300.0,
        gap_mm: 2.0,
        width_mm: Some(w),
        clearance_mm: None,
    };
    vec![
        Case {
            name: "stars 20 mm pitch (dense)".into(),
            parts: stars(n, 7, 20.0),
            params: params(50.0 * 20.0),
        },
        Case {
            name: "stars 20.5 mm pitch (0.5 mm apart)".into(),
            parts: stars(n, 7, 20.5),
            params: params(50.0 * 20.5),
        },
        Case {
            name: "stars 22.5 mm pitch (spaced 2.5 mm)".into(),
            parts: stars(n, 7, 22.5),
            params: params(50.0 * 22.5),
        },
        Case {
            name: "quads 0.5 mm apart".into(),
            parts: quads(n, 7, 0.5, 4.0),
            params: params(50.0 * 20.0),
        },
        Case {
            name: "diamonds 0.5 mm apart".into(),
            parts: diamonds(n, 0.5),
            params: params(100.0 * 10.0 + 20.0),
        },
    ]
}

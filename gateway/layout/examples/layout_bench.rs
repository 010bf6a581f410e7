//! Speed and material figures of the partition on public nesting layouts and on a
//! generated 10 000-part layout. Run with
//! `cargo run --release -p layout --example layout_bench` (one thread; figures in README).
//!
//! Layouts: the best known solutions of the ESICUP instances shirts (99 parts), trousers
//! (64) and swim (48) published by sparrow (data/esicup/README.md), in the instances'
//! own units read as mm. Parameters per layout, from its strip width W: 2 tools,
//! window L' = 0.8 W, gap W / 80, clearance the gap and half the gap.

use std::time::Instant;

use layout::{detect, detect_exhaustive, figures, partition, resolve, Params, Partition};
use layout_io::{Format, Layout, Part, ReadOptions};

const LAYOUTS: [(&str, &str); 3] = [
    ("shirts", include_str!("../data/esicup/shirts.json")),
    ("trousers", include_str!("../data/esicup/trousers.json")),
    ("swim", include_str!("../data/esicup/swim.json")),
];

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Partition + overlap resolution, timed (median of `runs`); the partition after S8
/// (for the figures) and the outcome of the resolution.
fn run(parts: &[Part], params: &Params, runs: usize) -> (f64, Partition, Result<usize, String>) {
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..runs {
        let t = Instant::now();
        let mut p = partition(parts, params).expect("partition");
        let s8 = p.clone();
        let r = resolve(parts, &mut p, &[]);
        times.push(t.elapsed().as_secs_f64() * 1e3);
        last = Some((s8, r.map(|r| r.moves.len()).map_err(|e| e.to_string())));
    }
    let (s8, r) = last.expect("one run");
    (median(times), s8, r)
}

/// Star-shaped parts on a jittered 20 mm grid, touching or interlocking their neighbours.
fn generated(n: usize, seed: u64) -> Vec<Part> {
    let mut state = seed;
    let mut next = || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let rows = 50;
    (0..n)
        .map(|i| {
            let (cx, cy) = (
                (i / rows) as f64 * 20.0 + 10.0,
                (i % rows) as f64 * 20.0 + 10.0,
            );
            let k = 5 + (next() * 6.0) as usize;
            let outer = (0..k)
                .map(|j| {
                    let a = std::f64::consts::TAU * j as f64 / k as f64;
                    let r = 6.0 + next() * 4.0;
                    [cx + r * a.cos(), cy + r * a.sin()]
                })
                .collect();
            Part {
                id: format!("p{i}"),
                outer,
                holes: vec![],
                layer: String::new(),
                attributes: Default::default(),
            }
        })
        .collect()
}

fn main() {
    println!("| layout | parts | W | L' | gap | clearance | overlaps after S8 | resolution | time ms (median) | detection ms | L no gap | L partitioned | L gap every part | added / every part | indexed = exhaustive |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for (name, text) in LAYOUTS {
        let doc =
            Layout::read(text.as_bytes(), Format::Json, &ReadOptions::default()).expect("layout");
        let w = doc.width_mm.expect("width");
        for clearance in [1.0, 0.5] {
            let params = Params {
                tools: 2,
                window_mm: 0.8 * w,
                gap_mm: w / 80.0,
                width_mm: Some(w),
                clearance_mm: Some(w / 80.0 * clearance),
            };
            let (ms, s8, outcome) = run(&doc.parts, &params, 51);
            let t = Instant::now();
            let found = detect(&doc.parts, &s8);
            let detect_ms = t.elapsed().as_secs_f64() * 1e3;
            let same = found == detect_exhaustive(&doc.parts, &s8);
            let f = figures(&doc.parts, &s8);
            let outcome = match outcome {
                Ok(moves) => format!("{moves} moves, none left"),
                Err(e) => format!("unresolved: {}", e.split(':').nth(1).unwrap_or("").trim()),
            };
            println!(
                "| {name} | {} | {w} | {:.1} | {:.3} | {:.3} | {} | {outcome} | {ms:.3} | {detect_ms:.3} | {:.2} | {:.2} | {:.2} | {:.1} % | {same} |",
                doc.parts.len(),
                params.window_mm,
                params.gap_mm,
                params.clearance_mm.unwrap_or(params.gap_mm),
                found.len(),
                f.no_gap.length_mm,
                f.partitioned.length_mm,
                f.gap_every_part.length_mm,
                f.added_length_fraction.unwrap_or(f64::NAN) * 100.0,
            );
        }
    }
    let parts = generated(10_000, 7);
    let params = Params {
        tools: 4,
        window_mm: 300.0,
        gap_mm: 2.0,
        width_mm: Some(1000.0),
        clearance_mm: None,
    };
    let (ms, s8, outcome) = run(&parts, &params, 5);
    let f = figures(&parts, &s8);
    let t = Instant::now();
    let found = detect(&parts, &s8);
    let detect_ms = t.elapsed().as_secs_f64() * 1e3;
    println!(
        "\ngenerated: {} parts, 4 tools, L' 300 mm, gap 2 mm: partition + resolution {ms:.1} ms (median of 5), detection alone {detect_ms:.1} ms, {} overlaps after S8, {}; length {:.1} -> {:.1} mm (gap every part {:.1} mm, {:.1} %)",
        parts.len(),
        found.len(),
        match outcome {
            Ok(m) => format!("{m} moves, none left"),
            Err(e) => format!("unresolved ({})", e.split(" pair").next().unwrap_or("")),
        },
        f.no_gap.length_mm,
        f.partitioned.length_mm,
        f.gap_every_part.length_mm,
        f.added_length_fraction.unwrap_or(f64::NAN) * 100.0
    );
    let t = Instant::now();
    let same = found == detect_exhaustive(&parts, &s8);
    println!(
        "exhaustive pairwise check on the generated layout: identical = {same} ({:.0} ms)",
        t.elapsed().as_secs_f64() * 1e3
    );
}

//! Speed and material figures of the partition on public nesting layouts and on a
//! generated 10 000-part layout. Run with
//! `cargo run --release -p layout --example layout_bench` (one thread; figures in README).
//!
//! Layouts: the best known solutions of the ESICUP instances shirts (99 parts), trousers
//! (64) and swim (48) published by sparrow (data/esicup/README.md), in the instances'
//! own units read as mm. Parameters per layout, from its strip width W: 2 tools,
//! window L' = 0.8 W, gap W / 80, clearance the gap and half the gap.

use std::time::Instant;

use layout::{
    detect, detect_exhaustive, figures, partition, resolve, resolve_widening, Params, Partition,
};
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

/// What one layout's partition and resolution gave.
struct Run {
    /// Median time of partition + resolution, ms.
    ms: f64,
    /// The partition after S8, before any move.
    s8: Partition,
    /// After the resolution.
    resolved: Partition,
    /// "N moves, widened ..." or the error.
    outcome: String,
}

/// Partition + overlap resolution (`widen`: with widening), timed (median of `runs`).
fn run(parts: &[Part], params: &Params, runs: usize, widen: bool) -> Run {
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..runs {
        let t = Instant::now();
        let mut p = partition(parts, params).expect("partition");
        let s8 = p.clone();
        let r = if widen {
            resolve_widening(parts, &mut p, &[])
        } else {
            resolve(parts, &mut p, &[])
        };
        times.push(t.elapsed().as_secs_f64() * 1e3);
        let outcome = match r {
            Ok(r) => {
                let widened: Vec<String> = r
                    .widenings
                    .iter()
                    .map(|w| format!("{} {} +{:.3}", w.between, w.from, w.extra_mm))
                    .collect();
                if widened.is_empty() {
                    format!("{} moves", r.moves.len())
                } else {
                    format!("{} moves, widened {}", r.moves.len(), widened.join(", "))
                }
            }
            Err(e) => format!(
                "unresolved: {}",
                e.to_string().split(':').nth(1).unwrap_or("").trim()
            ),
        };
        last = Some((s8, p, outcome));
    }
    let (s8, resolved, outcome) = last.expect("one run");
    Run {
        ms: median(times),
        s8,
        resolved,
        outcome,
    }
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
    println!("| layout | parts | W | L' | gap | clearance | overlaps after S8 | resolution | left (exhaustive) | time ms (median) | detection ms | L no gap | L S8 | L resolved | L gap every part | added / every part | indexed = exhaustive |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
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
            for widen in [false, true] {
                let r = run(&doc.parts, &params, 51, widen);
                let t = Instant::now();
                let found = detect(&doc.parts, &r.s8);
                let detect_ms = t.elapsed().as_secs_f64() * 1e3;
                let same = found == detect_exhaustive(&doc.parts, &r.s8);
                let left = detect_exhaustive(&doc.parts, &r.resolved).len();
                let f8 = figures(&doc.parts, &r.s8);
                let f = figures(&doc.parts, &r.resolved);
                println!(
                "| {name}{} | {} | {w} | {:.1} | {:.3} | {:.3} | {} | {} | {left} | {:.3} | {detect_ms:.3} | {:.2} | {:.2} | {:.2} | {:.2} | {:.1} % | {same} |",
                if widen { " --widen" } else { "" },
                doc.parts.len(),
                params.window_mm,
                params.gap_mm,
                params.clearance_mm.unwrap_or(params.gap_mm),
                found.len(),
                r.outcome,
                r.ms,
                f.no_gap.length_mm,
                f8.partitioned.length_mm,
                f.partitioned.length_mm,
                f.gap_every_part.length_mm,
                f.added_length_fraction.unwrap_or(f64::NAN) * 100.0,
            );
            }
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
    let r = run(&parts, &params, 5, false);
    let (ms, s8) = (r.ms, &r.s8);
    let f = figures(&parts, &r.resolved);
    let t = Instant::now();
    let found = detect(&parts, s8);
    let detect_ms = t.elapsed().as_secs_f64() * 1e3;
    println!(
        "\ngenerated: {} parts, 4 tools, L' 300 mm, gap 2 mm: partition + resolution {ms:.1} ms (median of 5), detection alone {detect_ms:.1} ms, {} overlaps after S8, {}; length {:.1} -> {:.1} mm (gap every part {:.1} mm, {:.1} %)",
        parts.len(),
        found.len(),
        r.outcome,
        f.no_gap.length_mm,
        f.partitioned.length_mm,
        f.gap_every_part.length_mm,
        f.added_length_fraction.unwrap_or(f64::NAN) * 100.0
    );
    let t = Instant::now();
    let same = found == detect_exhaustive(&parts, s8);
    println!(
        "exhaustive pairwise check on the generated layout: identical = {same} ({:.0} ms); pairs left after the resolution: {}",
        t.elapsed().as_secs_f64() * 1e3,
        detect_exhaustive(&parts, &r.resolved).len()
    );
}

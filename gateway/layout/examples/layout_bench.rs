//! Speed and material figures of the partition on public nesting layouts and on
//! generated 10 000-part layouts. Run with
//! `cargo run --release -p layout --example layout_bench` (one thread; figures in
//! docs/layout.md and docs/performance.md).
//!
//! Layouts: every `data/esicup/*.json`, the best known solutions of ESICUP and Gardeyn
//! instances published by sparrow (data/esicup/README.md), in the instances' own units
//! read as mm. Parameters per layout, from its strip width W: 2 tools (1 where a part is
//! wider than W / 2), window L' = 0.8 W (1.1 times the longest part where that is
//! longer), gap W / 80, clearance the gap and half the gap. The first argument is the
//! number of runs each median is taken over (51); a second, a name prefix: only those
//! layouts (`layout_bench 51 gardeyn7`).
//!
//! Generated: 10 000 star-shaped parts on a 20 mm grid (`generated`), touching their
//! neighbours (`dense`), and the same spread so that every two parts are at least the
//! gap apart (`spaced`): S8 must add no pair closer than the gap to those.

use std::time::Instant;

use layout::{
    detect, detect_exhaustive, figures, partition, resolve, resolve_widening, Params, Partition,
};
use layout_io::Part;

#[path = "../tests/nests/mod.rs"]
mod nests;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// What one layout's partition and resolution gave.
struct Run {
    /// Fastest and median wall time of partition + resolution, ms (on a shared machine
    /// the fastest run is the one least disturbed by other processes).
    ms: f64,
    min_ms: f64,
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
        min_ms: times.iter().copied().fold(f64::INFINITY, f64::min),
        ms: median(times),
        s8,
        resolved,
        outcome,
    }
}

fn main() {
    let runs: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(51);
    println!("| layout | parts | tools | W | L' | gap | clearance | overlaps after S8 | resolution | left (exhaustive) | ms fastest / median | detection ms | L no gap | L S8 | L resolved | L gap every part | added / every part | indexed = exhaustive |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    // The second argument, if any: only the layouts whose name starts with it.
    let only = std::env::args().nth(2);
    for (name, doc) in nests::esicup() {
        if only.as_ref().is_some_and(|o| !name.starts_with(o.as_str())) {
            continue;
        }
        let doc = match doc {
            Ok(d) => d,
            Err(e) => {
                println!("| {name} | refused: {e} |");
                continue;
            }
        };
        let w = doc.width_mm.expect("width");
        for clearance in [1.0, 0.5] {
            let params = nests::esicup_params(&doc, clearance);
            let tools = params.tools;
            for widen in [false, true] {
                let Ok(_) = partition(&doc.parts, &params) else {
                    println!(
                        "| {name} | {} | {w} | refused: {} |",
                        doc.parts.len(),
                        partition(&doc.parts, &params).unwrap_err()
                    );
                    break;
                };
                let r = run(&doc.parts, &params, runs, widen);
                let t = Instant::now();
                let found = detect(&doc.parts, &r.s8);
                let detect_ms = t.elapsed().as_secs_f64() * 1e3;
                let same = found == detect_exhaustive(&doc.parts, &r.s8);
                let left = detect_exhaustive(&doc.parts, &r.resolved).len();
                let f8 = figures(&doc.parts, &r.s8);
                let f = figures(&doc.parts, &r.resolved);
                println!(
                "| {name}{} | {} | {tools} | {w} | {:.1} | {:.3} | {:.3} | {} | {} | {left} | {:.3} / {:.3} | {detect_ms:.3} | {:.2} | {:.2} | {:.2} | {:.2} | {:.1} % | {same} |",
                if widen { " --widen" } else { "" },
                doc.parts.len(),
                params.window_mm,
                params.gap_mm,
                params.clearance_mm.unwrap_or(params.gap_mm),
                found.len(),
                r.outcome,
                r.min_ms,
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
    // Generated nests: `layout_bench RUNS generated` runs only these, `layout_bench RUNS
    // diamonds` (or another generated name's start) only that one.
    let generated_only = only
        .as_deref()
        .map(|o| o.strip_prefix("generated").unwrap_or(o).trim().to_string());
    for case in nests::generated(10_000) {
        if generated_only
            .as_ref()
            .is_some_and(|o| !case.name.starts_with(o.as_str()))
        {
            continue;
        }
        for widen in [false, true] {
            let (what, parts, params) = (&case.name, &case.parts, case.params);
            let parts = &parts[..];
            let r = run(parts, &params, 5, widen);
            let (ms, s8) = (r.ms, &r.s8);
            let f = figures(parts, &r.resolved);
            let t = Instant::now();
            let found = detect(parts, s8);
            let detect_ms = t.elapsed().as_secs_f64() * 1e3;
            // Pairs closer than the gap before S8 (every part its own group: each pair).
            let mut alone = s8.clone();
            alone.groups = (0..parts.len())
                .map(|i| layout::Group {
                    id: i + 1,
                    tool: 0,
                    window: 0,
                    dx_mm: 0.0,
                    dy_mm: 0.0,
                    parts: vec![i],
                })
                .collect();
            alone.group_of = (0..parts.len()).collect();
            let before = detect(parts, &alone);
            let close_before: std::collections::HashSet<(usize, usize)> =
                before.iter().map(|o| (o.a, o.b)).collect();
            let new = found
                .iter()
                .filter(|o| !close_before.contains(&(o.a, o.b)))
                .count();
            println!(
            "\ngenerated {what}: {} parts, 4 tools, L' 300 mm, gap 2 mm{}: partition + resolution {:.1} ms fastest, {ms:.1} ms median of 5, detection alone {detect_ms:.1} ms; {} pairs closer than the gap before S8, {} after S8 of which {new} new; {}; length {:.1} -> {:.1} mm (gap every part {:.1} mm, {:.1} %)",
            parts.len(),
            if widen { ", --widen" } else { "" },
            r.min_ms,
            before.len(),
            found.len(),
            r.outcome,
            f.no_gap.length_mm,
            f.partitioned.length_mm,
            f.gap_every_part.length_mm,
            f.added_length_fraction.unwrap_or(f64::NAN) * 100.0
        );
            if !widen {
                let t = Instant::now();
                let same = found == detect_exhaustive(parts, s8);
                println!(
                "exhaustive pairwise check: identical = {same} ({:.0} ms); pairs left after the resolution: {}",
                t.elapsed().as_secs_f64() * 1e3,
                detect_exhaustive(parts, &r.resolved).len()
            );
            }
        }
    }
}

//! A real nesting layout (ESICUP trousers, 64 parts) partitioned for two tools and cut on
//! the emulated conveyor cutter (a GRBL controller for the conveyor and one per head,
//! on pseudo-terminals, driven by our GRBL driver). Everything is checked on the
//! cutter's own log of knife strokes, against the shifted layout (not the plan): every
//! edge of every part cut exactly once and nothing else, each part by its group's head,
//! at one conveyor stop, inside the cutting area and (unless the overlap resolution moved
//! it to a neighbouring group) its lane, never while the material
//! moved; and no part cut while a part of another group closer than the gap had already
//! been cut (the source's reason for the groups). No wall time: the emulators run on
//! their unconstrained clocks and every wait is for the controllers' replies.

use drivers::grbl::{GrblOptions, StreamOptions};
use layout::cut::{plan, CutSettings, CutterSpec};
use layout_io::{Format, Layout, ReadOptions};
use std::time::Duration;
use world::cutter::CutLog;

/// Coordinates go through G-code with 3 decimals.
const TOL_MM: f64 = 2e-3;

fn trousers() -> Layout {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../gateway/layout/data/esicup/trousers.json"
    );
    let bytes = std::fs::read(path).expect("the trousers layout");
    Layout::read(&bytes, Format::Json, &ReadOptions::default()).expect("reads")
}

fn dist_point_segment(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len2 = dx * dx + dy * dy;
    let t = if len2 == 0.0 {
        0.0
    } else {
        (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / len2).clamp(0.0, 1.0)
    };
    ((p[0] - a[0] - t * dx).powi(2) + (p[1] - a[1] - t * dy).powi(2)).sqrt()
}

fn cross(o: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
}

/// Distance between two segments (0 when they cross).
fn dist_segments(a: [[f64; 2]; 2], b: [[f64; 2]; 2]) -> f64 {
    let d1 = cross(a[0], a[1], b[0]);
    let d2 = cross(a[0], a[1], b[1]);
    let d3 = cross(b[0], b[1], a[0]);
    let d4 = cross(b[0], b[1], a[1]);
    if d1 * d2 < 0.0 && d3 * d4 < 0.0 {
        return 0.0;
    }
    dist_point_segment(a[0], b[0], b[1])
        .min(dist_point_segment(a[1], b[0], b[1]))
        .min(dist_point_segment(b[0], a[0], a[1]))
        .min(dist_point_segment(b[1], a[0], a[1]))
}

fn close(p: [f64; 2], q: [f64; 2]) -> bool {
    (p[0] - q[0]).abs() <= TOL_MM && (p[1] - q[1]).abs() <= TOL_MM
}

#[test]
fn a_partitioned_layout_is_cut_window_by_window_each_part_once_never_beside_a_cut_neighbour() {
    let doc = trousers();
    let w = doc.width_mm.expect("the layout's width");
    let params = layout::Params {
        tools: 2,
        window_mm: 0.8 * w,
        gap_mm: w / 80.0,
        width_mm: Some(w),
        clearance_mm: None,
    };
    let mut partition = layout::partition(&doc.parts, &params).unwrap();
    let resolution = layout::resolve_widening(&doc.parts, &mut partition, &[]).unwrap();
    let moved: Vec<usize> = resolution.moves.iter().map(|m| m.part).collect();
    let cutter = CutterSpec::for_partition(&doc.parts, &partition);
    let stops = plan(&doc.parts, &partition, &cutter).unwrap();
    let geometry = runner::cutter::emulated_geometry(&cutter, &stops);

    let rt = system_tests::runtime();
    let (log, run) = rt.block_on(async {
        let emulated = emulators::cutter::CutterPty::spawn(&geometry).expect("pseudo-terminals");
        let opts = GrblOptions {
            poll_interval: Duration::from_millis(2),
            ..GrblOptions::default()
        };
        let mut links = devices::open_cutter(
            emulated.conveyor.path(),
            &emulated.head_paths(),
            115_200,
            &opts,
        )
        .await
        .expect("the cutter's controllers answer");
        let stream = StreamOptions {
            status_interval: Duration::from_millis(2),
            ..StreamOptions::default()
        };
        let run = runner::cutter::run_cut(
            &stops,
            links.conveyor.as_mut(),
            &mut links.heads,
            &CutSettings::default(),
            &stream,
            |_, _| {},
        )
        .await
        .unwrap_or_else(|e| panic!("{e}"));
        (emulated.log(), run)
    });
    check_log(&doc, &partition, &cutter, &moved, &log);
    assert_eq!(run.stops, stops.len());
    assert_eq!(log.feeds.len(), stops.len(), "one feed per stop");
    let groups: usize = run.heads.iter().map(|h| h.groups).sum();
    assert_eq!(
        groups,
        partition
            .groups
            .iter()
            .filter(|g| !g.parts.is_empty())
            .count()
    );
    // The figures the README quotes (printed with --nocapture).
    let stroke_mm: f64 = log
        .strokes
        .iter()
        .map(|s| ((s.to_mm[0] - s.from_mm[0]).powi(2) + (s.to_mm[1] - s.from_mm[1]).powi(2)).sqrt())
        .sum();
    let planned: f64 = run.heads.iter().map(|h| h.cut_length_mm).sum();
    assert!(
        (stroke_mm - planned).abs() < 0.01 * planned,
        "{stroke_mm} vs {planned}"
    );
    println!(
        "trousers: {} parts, {} groups, {} stops, cut length per head {:?} mm, machine time {:.1} s",
        doc.parts.len(),
        groups,
        run.stops,
        run.heads.iter().map(|h| (h.cut_length_mm * 10.0).round() / 10.0).collect::<Vec<_>>(),
        log.machine_time_s()
    );
}

/// The checks of the test's doc comment, on the log alone and the shifted layout.
fn check_log(
    doc: &Layout,
    partition: &layout::Partition,
    cutter: &CutterSpec,
    moved: &[usize],
    log: &CutLog,
) {
    assert!(
        log.strokes.iter().all(|s| !s.conveyor_moving),
        "a knife cut while the material moved"
    );
    let offsets = partition.offsets();
    // Every edge of every ring of every part, shifted: (part, from, to).
    let mut edges = Vec::new();
    for (p, part) in doc.parts.iter().enumerate() {
        let [dx, dy] = offsets[p];
        for ring in std::iter::once(&part.outer).chain(part.holes.iter()) {
            for k in 0..ring.len() {
                let a = ring[k];
                let b = ring[(k + 1) % ring.len()];
                edges.push((p, [a[0] + dx, a[1] + dy], [b[0] + dx, b[1] + dy]));
            }
        }
    }
    // Each stroke matches exactly one edge not matched before.
    let mut cut_by: Vec<Option<usize>> = vec![None; edges.len()];
    let mut part_strokes: Vec<Vec<usize>> = vec![Vec::new(); doc.parts.len()];
    for (si, s) in log.strokes.iter().enumerate() {
        let e = edges
            .iter()
            .enumerate()
            .find(|(ei, (_, a, b))| {
                cut_by[*ei].is_none() && close(s.from_mm, *a) && close(s.to_mm, *b)
            })
            .map(|(ei, _)| ei)
            .unwrap_or_else(|| panic!("stroke {si} {s:?} cuts no uncut edge of the layout"));
        cut_by[e] = Some(si);
        part_strokes[edges[e].0].push(si);
    }
    for (ei, c) in cut_by.iter().enumerate() {
        assert!(
            c.is_some(),
            "edge {ei} of part `{}` never cut",
            doc.parts[edges[ei].0].id
        );
    }
    // Per part: its group's head, one stop, inside the area, and (unless the overlap
    // resolution moved it to a neighbouring group) its centre in the head's lane.
    let lane = partition.lane_mm();
    let mut stop_of = vec![0u64; doc.parts.len()];
    for (p, strokes) in part_strokes.iter().enumerate() {
        let id = &doc.parts[p].id;
        let g = &partition.groups[partition.group_of[p]];
        let first = &log.strokes[strokes[0]];
        stop_of[p] = first.feeds_before;
        for &si in strokes {
            let s = &log.strokes[si];
            assert_eq!(
                s.head, g.tool,
                "part `{id}` cut by head {}, its group G-{} is tool {}",
                s.head, g.id, g.tool
            );
            assert_eq!(
                s.feeds_before, first.feeds_before,
                "part `{id}` cut across two stops"
            );
            for q in [s.from_mm, s.to_mm] {
                assert!(
                    q[0] >= s.conveyor_mm - TOL_MM
                        && q[0] <= s.conveyor_mm + cutter.window_mm + TOL_MM,
                    "part `{id}` point {q:?} outside the cutting area at conveyor {}",
                    s.conveyor_mm
                );
            }
        }
        if moved.contains(&p) {
            continue;
        }
        let b = doc.parts[p].bounds();
        let yc = (b[1] + b[3]) / 2.0 + g.dy_mm;
        let lo = partition.y0_mm + g.tool as f64 * lane + g.dy_mm;
        assert!(
            yc >= lo - TOL_MM && yc <= lo + lane + TOL_MM,
            "part `{id}` centre Y {yc} outside lane {} ({lo}..{})",
            g.tool,
            lo + lane
        );
    }
    // Hold-down: a part's cut comes after (or with) the cut of a part of another group
    // closer than the gap: never.
    // Each part's strokes as segments, and their box, once.
    let segments: Vec<Vec<[[f64; 2]; 2]>> = part_strokes
        .iter()
        .map(|strokes| {
            strokes
                .iter()
                .map(|&si| [log.strokes[si].from_mm, log.strokes[si].to_mm])
                .collect()
        })
        .collect();
    let boxes: Vec<[f64; 4]> = segments
        .iter()
        .map(|segs| {
            segs.iter().flatten().fold(
                [
                    f64::INFINITY,
                    f64::INFINITY,
                    f64::NEG_INFINITY,
                    f64::NEG_INFINITY,
                ],
                |b, q| {
                    [
                        b[0].min(q[0]),
                        b[1].min(q[1]),
                        b[2].max(q[0]),
                        b[3].max(q[1]),
                    ]
                },
            )
        })
        .collect();
    let gap = partition.gap_mm;
    let mut pairs_checked = 0;
    for p in 0..doc.parts.len() {
        for q in 0..doc.parts.len() {
            if partition.group_of[p] == partition.group_of[q] || stop_of[q] > stop_of[p] {
                continue;
            }
            let (a, b) = (boxes[p], boxes[q]);
            if a[0] - b[2] >= gap || b[0] - a[2] >= gap || a[1] - b[3] >= gap || b[1] - a[3] >= gap
            {
                continue;
            }
            pairs_checked += 1;
            let d = segments[p]
                .iter()
                .flat_map(|s| segments[q].iter().map(move |t| dist_segments(*s, *t)))
                .fold(f64::INFINITY, f64::min);
            assert!(
                d >= gap - TOL_MM,
                "part `{}` was cut {d:.4} mm from part `{}` of another group, cut before or with it (gap {gap})",
                doc.parts[p].id,
                doc.parts[q].id
            );
        }
    }
    assert!(
        pairs_checked > 0,
        "no neighbours near the gap: the check checked nothing"
    );
}

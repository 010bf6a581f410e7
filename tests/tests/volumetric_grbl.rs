//! A 3-axis program on the emulated volumetric machine, as GRBL executes it: the program
//! is interpreted by GRBL's own G-code interpreter (`protocol::grbl::gcode::Interpreter`,
//! modal state, arcs as chords), each straight move traced in command space as GRBL's
//! planner does, and the tool point taken from the machine's truth. Run as written and
//! after the volumetric rewrite (`gateway rewrite --volumetric`, the same library call):
//! the tool point's error at the program's points and its distance from the programmed
//! path, before and after.
//!
//! And the same through the whole stack: the machine behind the GRBL emulator
//! (`GrblDevice::with_axes` over `world::volumetric::VolumetricWorkpiece`) on a real
//! pseudo-terminal, the program streamed by the GRBL driver, the truth taken where the
//! emulated axes really ended each move.

use protocol::grbl::gcode::{filter_line, Action, Interpreter, Rate};
use protocol::volumetric::Structure;
use rewrite::{rewrite_program, Options};
use volumetric::identify::{identify, Campaign};
use world::volumetric::{CameraPlan, VolumetricMachine};

type P = [f64; 3];

/// The program: rectangles, a full circle (G2) and a diagonal at three heights.
fn program() -> String {
    let mut p = String::from("G21 G90 G17 G54 F1500\nG0 X20 Y20 Z390\n");
    for z in [350.0, 200.0, 50.0] {
        p += &format!("G1 Z{z}\nG1 X480\nG1 Y380\nG1 X20\nG1 Y20\n");
        p += "G0 X350 Y200\nG2 X350 Y200 I-100 J0\n";
        p += &format!("G1 X480 Y380 Z{}\nG0 X20 Y20 Z{z}\n", z + 30.0);
    }
    p += "G0 Z390\nM2\n";
    p
}

/// The move targets GRBL's interpreter makes of `text` (machine coordinates, mm), each
/// with whether it cuts (a feed move, not a G0 rapid).
fn moves(text: &str) -> Vec<(P, bool)> {
    moves_and_points(text).0
}

/// The move targets, and the program's own points (each line's last target: an arc's
/// end, not its chords).
fn moves_and_points(text: &str) -> (Vec<(P, bool)>, Vec<P>) {
    let mut points = Vec::new();
    let mut g = Interpreter::new();
    let mut out = Vec::new();
    for raw in text.lines() {
        // What GRBL's serial reader keeps of the line (upper case, no blanks).
        let line = filter_line(raw).unwrap_or_else(|e| panic!("`{raw}`: {e:?}"));
        if line.is_empty() {
            continue;
        }
        let actions = g
            .execute(&line, false)
            .unwrap_or_else(|code| panic!("GRBL refuses `{line}`: error {code}"));
        let mut last = None;
        for a in actions {
            if let Action::Move { target, rate, .. } = a {
                out.push((target, matches!(rate, Rate::Feed(_))));
                last = Some(target);
            }
        }
        points.extend(last);
    }
    (out, points)
}

fn dist(a: P, b: P) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// Distance from `p` to the segment `a`-`b`.
fn to_segment(p: P, a: P, b: P) -> f64 {
    let d: P = std::array::from_fn(|k| b[k] - a[k]);
    let l2 = d.iter().map(|v| v * v).sum::<f64>();
    let t = if l2 > 0.0 {
        ((0..3).map(|k| (p[k] - a[k]) * d[k]).sum::<f64>() / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    dist(p, std::array::from_fn(|k| a[k] + t * d[k]))
}

/// Segments per block of the nearest-segment search.
const BLOCK: usize = 16;

/// A polyline with the bounding box of each `BLOCK` segments: the distance from a
/// point to the polyline skips the blocks whose box is farther than a segment already
/// measured (they hold no nearer one, so the distance is the minimum over every
/// segment; it runs for every sampled point in an unoptimized test build).
struct Polyline<'a> {
    path: &'a [P],
    boxes: Vec<(P, P)>,
}

impl<'a> Polyline<'a> {
    fn new(path: &'a [P]) -> Polyline<'a> {
        let segments = path.len().saturating_sub(1);
        let boxes = (0..segments.div_ceil(BLOCK))
            .map(|b| {
                let last = (b * BLOCK + BLOCK).min(segments);
                let mut lo = [f64::INFINITY; 3];
                let mut hi = [f64::NEG_INFINITY; 3];
                for q in &path[b * BLOCK..=last] {
                    for k in 0..3 {
                        lo[k] = lo[k].min(q[k]);
                        hi[k] = hi[k].max(q[k]);
                    }
                }
                (lo, hi)
            })
            .collect();
        Polyline { path, boxes }
    }

    /// Distance from `p` to the polyline; `hint` is a segment likely near (the previous
    /// point's nearest), updated to this point's nearest.
    fn distance(&self, p: P, hint: &mut usize) -> f64 {
        let segments = self.path.len().saturating_sub(1);
        if segments == 0 {
            return f64::INFINITY;
        }
        let h = (*hint).min(segments - 1);
        // The hint's distance bounds the nearest from above (a margin for rounding: a
        // block is skipped only when clearly farther).
        let bound = to_segment(p, self.path[h], self.path[h + 1]) * (1.0 + 1e-9) + 1e-12;
        let mut best = f64::INFINITY;
        for (b, (lo, hi)) in self.boxes.iter().enumerate() {
            let out: P = std::array::from_fn(|k| (lo[k] - p[k]).max(p[k] - hi[k]).max(0.0));
            if dist(out, [0.0; 3]) > bound {
                continue;
            }
            for j in b * BLOCK..(b * BLOCK + BLOCK).min(segments) {
                let d = to_segment(p, self.path[j], self.path[j + 1]);
                if d < best {
                    best = d;
                    *hint = j;
                }
            }
        }
        best
    }
}

struct Figures {
    point_rms: f64,
    point_max: f64,
    path_rms: f64,
    path_max: f64,
}

/// Runs `commands` (from the origin) on `machine`: the error at the program's `points`
/// (the nearest real end point to each) and the real path's distance from the nominal
/// path (every cutting move sampled at 8 points; rapids are not cuts, and the rewriter
/// corrects their end points only).
fn run(
    machine: &VolumetricMachine,
    commands: &[(P, bool)],
    nominal: &[P],
    points: &[P],
) -> Figures {
    let real_ends: Vec<P> = commands
        .iter()
        .map(|&(c, _)| machine.tool_in_work(c))
        .collect();
    let (mut pss, mut pmax) = (0.0, 0.0f64);
    for &v in points {
        let e = real_ends
            .iter()
            .map(|&r| dist(r, v))
            .fold(f64::INFINITY, f64::min);
        pss += e * e;
        pmax = pmax.max(e);
    }
    let (mut dss, mut dmax, mut n) = (0.0, 0.0f64, 0);
    let path = Polyline::new(nominal);
    let mut near = 0;
    let mut from = [0.0; 3];
    for &(to, cuts) in commands {
        if !cuts {
            from = to;
            continue;
        }
        for s in 1..=8 {
            let t = s as f64 / 8.0;
            let c: P = std::array::from_fn(|k| from[k] + t * (to[k] - from[k]));
            let d = path.distance(machine.tool_in_work(c), &mut near);
            dss += d * d;
            dmax = dmax.max(d);
            n += 1;
        }
        from = to;
    }
    Figures {
        point_rms: (pss / points.len() as f64).sqrt(),
        point_max: pmax,
        path_rms: (dss / n as f64).sqrt(),
        path_max: dmax,
    }
}

#[test]
fn a_program_run_by_grbl_lands_on_the_nominal_path_after_the_volumetric_rewrite() {
    let machine = VolumetricMachine::new(Structure::Xyfz, 1);
    let mut files = machine.campaign(101);
    let plan = CameraPlan::default_for(machine.travel_mm);
    files.push(("camera.csv".into(), machine.camera_campaign(&plan, 1).0));
    let model = identify(Structure::Xyfz, &Campaign::from_files(&files).unwrap())
        .unwrap()
        .model;
    let text = program();
    let (rewritten, report) = rewrite_program(
        &text,
        &model,
        Options {
            start: Some([0.0; 3]),
            ..Options::default()
        },
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let (program_moves, points) = moves_and_points(&text);
    let mut nominal = vec![[0.0; 3]];
    nominal.extend(program_moves.iter().map(|m| m.0));
    let before = run(&machine, &program_moves, &nominal, &points);
    let after = run(&machine, &moves(&rewritten), &nominal, &points);
    eprintln!(
        "{} lines -> {} ({} moves corrected); points RMS {:.2} -> {:.3} µm, max {:.2} -> {:.3} µm; path RMS {:.2} -> {:.3} µm, max {:.2} -> {:.3} µm",
        report.input_lines,
        report.output_lines,
        report.moves_compensated,
        before.point_rms * 1e3,
        after.point_rms * 1e3,
        before.point_max * 1e3,
        after.point_max * 1e3,
        before.path_rms * 1e3,
        after.path_rms * 1e3,
        before.path_max * 1e3,
        after.path_max * 1e3
    );
    assert!(before.point_rms > 0.005, "the machine has errors to remove");
    // The goal: at least 90 % of the tool point's error removed.
    assert!(after.point_rms <= 0.1 * before.point_rms);
    assert!(after.point_max <= 0.1 * before.point_max);
    assert!(after.path_rms <= 0.1 * before.path_rms);
    assert!(after.path_max <= 0.1 * before.path_max);
}

/// Streams `program` through the GRBL driver to the emulator serving `machine` on a
/// pseudo-terminal; returns where the axes ended each move (machine X, Y, Z).
fn stream_through_grbl(machine: &VolumetricMachine, program: &str) -> Vec<P> {
    use drivers::grbl::{GrblOptions, GrblStage, StreamOptions};
    use drivers::Stage;
    use emulators::grbl::{GrblConfig, GrblDevice, GrblPty};
    use world::axes::{lock_axes, AxesMachine};
    let rt = system_tests::runtime();
    let axes = AxesMachine::new(Box::new(world::volumetric::VolumetricWorkpiece(
        machine.clone(),
    )))
    .shared();
    lock_axes(&axes).record_move_ends();
    rt.block_on(async {
        let pty = GrblPty::spawn(
            GrblDevice::with_axes(axes.clone(), GrblConfig::default()),
            None,
        )
        .expect("pseudo-terminal");
        let opts = GrblOptions {
            poll_interval: std::time::Duration::from_millis(2),
            ..GrblOptions::default()
        };
        let mut stage = GrblStage::open(pty.path(), 115_200, opts)
            .await
            .expect("connect to the emulator");
        let report = stage
            .stream_program(program, &StreamOptions::default(), &mut |_| {})
            .await
            .unwrap_or_else(|e| panic!("{e}"));
        stage.wait_idle().await.expect("idle at the end");
        assert_eq!(report.progress.acknowledged, report.progress.total);
        drop(pty);
    });
    let ends = lock_axes(&axes).take_move_ends();
    ends.iter().map(|e| [e[0], e[1], e[2]]).collect()
}

#[test]
fn a_program_streamed_to_the_emulated_machine_lands_on_the_nominal_path_after_the_rewrite() {
    let machine = VolumetricMachine::new(Structure::Xyfz, 1);
    let files = machine.campaign(101);
    let model = identify(Structure::Xyfz, &Campaign::from_files(&files).unwrap())
        .unwrap()
        .model;
    let text = program();
    let (rewritten, _) = rewrite_program(
        &text,
        &model,
        Options {
            start: Some([0.0; 3]),
            ..Options::default()
        },
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let (program_moves, points) = moves_and_points(&text);
    let mut nominal = vec![[0.0; 3]];
    nominal.extend(program_moves.iter().map(|m| m.0));
    // The emulator's move ends, as commands (cutting or not does not matter for the
    // points; every segment is sampled for the path, rapids included, so the path
    // figures are looser than the interpreter-only test's).
    let as_run =
        |ends: Vec<P>| -> Vec<(P, bool)> { ends.into_iter().map(|e| (e, false)).collect() };
    let plain = stream_through_grbl(&machine, &text);
    let fixed = stream_through_grbl(&machine, &rewritten);
    // GRBL moved the axes to exactly the interpreter's targets (arcs as the same chords).
    let interpreted: Vec<P> = program_moves.iter().map(|m| m.0).collect();
    assert_eq!(
        plain.len(),
        interpreted.len(),
        "one move end per interpreted move"
    );
    for (a, b) in plain.iter().zip(&interpreted) {
        assert!(dist(*a, *b) < 1e-4, "{a:?} vs {b:?}");
    }
    let before = run(&machine, &as_run(plain), &nominal, &points);
    let after = run(&machine, &as_run(fixed), &nominal, &points);
    eprintln!(
        "through the emulator: points RMS {:.2} -> {:.3} um, max {:.2} -> {:.3} um",
        before.point_rms * 1e3,
        after.point_rms * 1e3,
        before.point_max * 1e3,
        after.point_max * 1e3
    );
    assert!(before.point_rms > 0.005, "the machine has errors to remove");
    assert!(after.point_rms <= 0.1 * before.point_rms);
    assert!(after.point_max <= 0.1 * before.point_max);
}

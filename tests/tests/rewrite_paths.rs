//! The rewriter against the GRBL emulator's trace of the TRUE tool point: random programs
//! (lines short and long, arcs G2/G3 in G17/G18/G19, G91 sections, G20, G54-G59 and G92,
//! feed changes, rapids) rewritten with the demo stage's error map, streamed piece by
//! piece into the emulated controller (in-process, unconstrained clock) on the simulated
//! stage (backlash, screw errors, straightness, squareness, yaw), and every trace row of
//! a feed move compared with the programmed path of its line. The map is made from the
//! simulator's truth at the scan's plan (`system_tests::truth_map`): a camera scan takes
//! minutes in a debug build. The figures for the docs come from the ignored benchmark at
//! the end (`cargo test --release -p system-tests --test system rewrite_paths:: -- --ignored
//! --nocapture`), which can also scan the map with the camera (`SCAN=1`).

use emulators::grbl::{GrblConfig, GrblDevice};
use errormap::MapModel;
use job::{Job, StageSpec};
use protocol::grbl::gcode::{filter_line, Action, Interpreter, Rate};
use rewrite::programs::{random_program, Program, ProgramSpec};
use rewrite::{Compensation, Options, Pose, Rewriter, N_AXIS};
use system_tests::truth_map::{demo_machine, map_from_truth, sim_identity as identity};
use world::machine::{MachineConfig, TraceRow};
use world::{lock, Clock, SharedRig};

/// The GRBL emulator on a fresh copy of the machine, homed once (as the map's machine
/// was), recording the trace.
struct Emulator {
    dev: GrblDevice,
    rig: SharedRig,
}

impl Emulator {
    fn new(machine: &MachineConfig) -> Self {
        let d = system_tests::config_dir();
        let camera = world::camera::CameraModel::load(&d.join("cameras/mono-1.3mp.toml"))
            .expect("the camera file loads");
        let board = protocol::Board::load(&d.join("boards/dot-grid-0.5mm.toml"))
            .expect("the board file loads");
        let rig = world::shared_rig(machine.clone(), board, camera);
        let dev = GrblDevice::new(
            rig.clone(),
            GrblConfig {
                clock: Clock::Unconstrained,
                ..Default::default()
            },
        );
        let mut e = Self { dev, rig };
        e.dev.power_on(0.0);
        e.dev.take_output();
        e.send("$H");
        lock(&e.rig).machine_mut().start_trace();
        e
    }

    /// One line, answered `ok` (anything else fails the test).
    fn send(&mut self, line: &str) {
        self.dev.receive(format!("{line}\n").as_bytes(), 0.0);
        let mut got = String::new();
        for _ in 0..10_000 {
            got.push_str(&String::from_utf8_lossy(&self.dev.take_output()));
            if got.lines().any(|l| l == "ok" || l.starts_with("error:")) {
                break;
            }
            self.dev.poll(0.0);
        }
        assert!(
            got.lines().any(|l| l == "ok") && !got.contains("error:") && !got.contains("ALARM"),
            "`{line}` answered `{got}`"
        );
    }

    /// One line run to its end: the trace rows of its motion.
    fn run(&mut self, line: &str) -> Vec<TraceRow> {
        self.send(line);
        // A status request completes every queued move on the unconstrained clock (the
        // report shows the moment it was asked: the next one is Idle).
        let mut got = String::new();
        for _ in 0..10 {
            self.dev.receive(b"?", 0.0);
            got.clear();
            for _ in 0..10_000 {
                got.push_str(&String::from_utf8_lossy(&self.dev.take_output()));
                if got.contains('>') {
                    break;
                }
                self.dev.poll(0.0);
            }
            if got.contains("<Idle") {
                break;
            }
        }
        assert!(got.contains("<Idle"), "after `{line}`: {got}");
        lock(&self.rig).machine_mut().take_trace()
    }
}

fn interpreter(offsets: &[Pose; 6]) -> Interpreter {
    let mut i = Interpreter::new();
    for (k, o) in offsets.iter().enumerate() {
        i.stored[k] = *o;
    }
    i.coord_system = offsets[0];
    i
}

/// The moves a controller makes for one line: (end, feed move?).
fn moves_of(interp: &mut Interpreter, line: &str) -> Vec<(Pose, bool)> {
    let f = filter_line(line).expect("the line passes GRBL's filter");
    if f.is_empty() {
        return Vec::new();
    }
    interp
        .execute(&f, false)
        .expect("GRBL executes the line")
        .into_iter()
        .filter_map(|a| match a {
            Action::Move { target, rate, .. } => Some((target, !matches!(rate, Rate::Rapid))),
            _ => None,
        })
        .collect()
}

fn distance(a: &Pose, b: &Pose) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f64>()
        .sqrt()
}

fn distance_to_segment(q: [f64; 2], a: &Pose, b: &Pose) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len2 = dx * dx + dy * dy;
    let t = if len2 == 0.0 {
        0.0
    } else {
        (((q[0] - a[0]) * dx + (q[1] - a[1]) * dy) / len2).clamp(0.0, 1.0)
    };
    (q[0] - a[0] - t * dx).hypot(q[1] - a[1] - t * dy)
}

/// What one program gave on the emulator.
#[derive(Default)]
struct Run {
    /// Largest distance of the true tool point from the programmed feed path, mm.
    worst: f64,
    sum2: f64,
    rows: usize,
    /// Largest distance of the true tool point from the command (the stage's own error
    /// where the program went), mm.
    stage_worst: f64,
    /// Where each rapid ended: distance of the resting tool from its programmed end, mm.
    rapid_ends: Vec<f64>,
    report: rewrite::Report,
    where_worst: String,
}

/// Rewrites `program` with `model` line by line, runs every piece on a fresh emulator,
/// and compares the true tool point along every feed piece with the programmed path of
/// its line (arcs as chords within 10 nm), matched around the same progress along the
/// line (a ZX arc goes back and forth in X-Y).
fn run_program(machine: &MachineConfig, model: &dyn Compensation, program: &Program) -> Run {
    let mut emulator = Emulator::new(machine);
    for line in program.setup_lines() {
        emulator.send(&line);
    }
    let options = Options {
        work_offsets: program.work_offsets,
        ..Options::default()
    };
    let mut rewriter = Rewriter::new(model, options).expect("options are valid");
    let mut nominal = interpreter(&program.work_offsets);
    nominal.arc_tolerance = 1e-5;
    let mut commands = interpreter(&program.work_offsets);
    let mut run = Run::default();
    for (k, line) in program.text.lines().enumerate() {
        let pieces = rewriter
            .line(line, k + 1)
            .unwrap_or_else(|e| panic!("{e}\n{}", program.text));
        let mut path = vec![nominal.position];
        path.extend(moves_of(&mut nominal, line).into_iter().map(|m| m.0));
        let mut cum = vec![0.0];
        for w in path.windows(2) {
            cum.push(cum.last().unwrap() + distance(&w[0], &w[1]));
        }
        let mut progress = 0.0;
        for piece in pieces {
            let from = commands.position;
            let moves = moves_of(&mut commands, &piece);
            let rows = emulator.run(&piece);
            let Some(&(to, feed)) = moves.last() else {
                continue;
            };
            assert_eq!(moves.len(), 1, "one move per piece: {piece}");
            for r in &rows {
                run.stage_worst = run
                    .stage_worst
                    .max((r.true_mm[0] - r.cmd_mm[0]).hypot(r.true_mm[1] - r.cmd_mm[1]));
            }
            let length = distance(&from, &to);
            if !feed {
                if let Some(last) = rows.last() {
                    let end = path.last().unwrap();
                    run.rapid_ends
                        .push((last.true_mm[0] - end[0]).hypot(last.true_mm[1] - end[1]));
                }
                progress += length;
                continue;
            }
            if path.len() < 2 {
                continue;
            }
            let (dx, dy) = (to[0] - from[0], to[1] - from[1]);
            let len2 = dx * dx + dy * dy;
            for r in &rows {
                // How far along this piece the command is (a piece is straight).
                let f = if len2 < 1e-12 {
                    1.0
                } else {
                    (((r.cmd_mm[0] - from[0]) * dx + (r.cmd_mm[1] - from[1]) * dy) / len2)
                        .clamp(0.0, 1.0)
                };
                let p = progress + f * length;
                let lo = cum
                    .partition_point(|&c| c < p - 0.5)
                    .saturating_sub(1)
                    .min(path.len() - 2);
                let hi = cum
                    .partition_point(|&c| c <= p + 0.5)
                    .clamp(lo + 1, path.len() - 1);
                let d = (lo..hi)
                    .map(|j| distance_to_segment(r.true_mm, &path[j], &path[j + 1]))
                    .fold(f64::INFINITY, f64::min);
                if d > run.worst {
                    run.worst = d;
                    run.where_worst = format!(
                        "line {}: `{line}`, piece `{piece}`, true {:?}",
                        k + 1,
                        r.true_mm
                    );
                }
                run.sum2 += d * d;
                run.rows += 1;
            }
            progress += length;
        }
    }
    run.report = rewriter.into_report();
    run
}

fn spec(seed: u64, items: usize) -> ProgramSpec {
    // Inside the map's inner cells (the map covers 0..200 x 0..150 mm on a 10 mm grid;
    // in its corner cells, extrapolated from one side, the map itself is off by up to
    // 2.1 um at (5, 5), wherever the path is); Z inside the emulated controller's soft
    // limits.
    ProgramSpec {
        lo: [10.0, 10.0, -45.0],
        hi: [190.0, 140.0, -2.0],
        items,
        seed,
        // `NO_G92=1`: programs without G92 (the rewriter before G92 was corrected).
        g92: std::env::var_os("NO_G92").is_none(),
    }
}

fn truth_model() -> (MachineConfig, MapModel) {
    let (job, machine) = demo_machine();
    let map = map_from_truth(&machine, identity(&job));
    (machine, MapModel::new(map))
}

#[test]
fn the_long_move_whose_y_correction_creeps_up_and_back_stays_on_the_path() {
    let (machine, model) = truth_model();
    let program = Program {
        text: "G21 G90\nG0 X17.5 Y12.25\nG1 X172.5 Y12.25 F2400\n".into(),
        work_offsets: [[0.0; N_AXIS]; 6],
    };
    let run = run_program(&machine, &model, &program);
    eprintln!(
        "long move: true path within {:.3} um of the program (rms {:.3} um, stage error up to {:.2} um), {} backlash take-ups, {} pieces",
        run.worst * 1e3,
        (run.sum2 / run.rows as f64).sqrt() * 1e3,
        run.stage_worst * 1e3,
        run.report.backlash_takeups,
        run.report.segments_added + 1
    );
    assert!(run.rows > 3000, "{} rows", run.rows);
    assert!(run.stage_worst > 0.015, "the stage alone is off");
    assert!(run.report.backlash_takeups >= 1, "the Y creep turns");
    assert!(
        run.worst < 0.0009,
        "true path {:.3} um from the program ({})",
        run.worst * 1e3,
        run.where_worst
    );
}

#[test]
fn random_programs_stay_within_1_5_um_of_the_programmed_path() {
    let (machine, model) = truth_model();
    let (mut worst, mut sum2, mut rows) = (0.0f64, 0.0, 0usize);
    for seed in 1..=3 {
        let program = random_program(&spec(seed, 40));
        let run = run_program(&machine, &model, &program);
        assert!(
            run.worst <= 0.0015,
            "seed {seed}: true path {:.3} um from the program ({})\n{}",
            run.worst * 1e3,
            run.where_worst,
            program.text
        );
        worst = worst.max(run.worst);
        sum2 += run.sum2;
        rows += run.rows;
    }
    eprintln!(
        "3 random programs: true path within {:.3} um, rms {:.3} um ({rows} trace rows)",
        worst * 1e3,
        (sum2 / rows as f64).sqrt() * 1e3
    );
}

#[test]
fn more_random_programs_stay_within_1_5_um_of_the_programmed_path() {
    let (machine, model) = truth_model();
    for seed in 4..=9 {
        let program = random_program(&spec(seed, 60));
        let run = run_program(&machine, &model, &program);
        assert!(
            run.worst <= 0.0015,
            "seed {seed}: true path {:.3} um from the program ({})\n{}",
            run.worst * 1e3,
            run.where_worst,
            program.text
        );
        // Rapids are corrected at their end: the tool rests where programmed.
        for (k, e) in run.rapid_ends.iter().enumerate() {
            assert!(
                *e <= 0.0015,
                "seed {seed}: rapid {k} ends {:.3} um off",
                e * 1e3
            );
        }
    }
}

/// The map the benchmark uses: from the truth, or (`SCAN=1`) scanned with the camera by
/// the same procedure as `gateway map` (release build: about 40 s), re-referenced at the
/// scan's reference point.
fn bench_model(job: &Job, machine: &MachineConfig) -> (MapModel, &'static str) {
    if std::env::var_os("SCAN").is_none() {
        return (
            MapModel::new(map_from_truth(machine, identity(job))),
            "map from the simulator's truth",
        );
    }
    use errormap::scan::{MapBuilder, ScanPlan, ScanSpec};
    let mut job = job.clone();
    if let StageSpec::Sim { machine: m } = &mut job.stage {
        *m = machine.clone();
    }
    let rt = system_tests::runtime();
    let mut devices = devices::open_devices(&job).expect("the demo devices open");
    let limits = runner::soft_limits(devices.stage.info()).expect("soft limits");
    let (lo, hi) = runner::scan::scan_area(&job, &limits);
    let plan = ScanPlan::new(lo, hi, ScanSpec::default()).expect("the default plan");
    let mut builder = MapBuilder::new();
    let reference = rt
        .block_on(runner::scan::run_scan(
            &job,
            &mut devices,
            &plan,
            &mut builder,
            &mut |_, _| Ok(()),
            &mut |_, _| {},
            std::future::pending(),
        ))
        .expect("the scan runs");
    let map = builder
        .finish(
            &plan,
            identity(&job),
            1,
            "now".into(),
            [0.0; 2],
            job.board_at_machine_zero_mm,
            reference.command_mm,
        )
        .expect("the map is built");
    let model = MapModel::new(map)
        .rereferenced(reference.error_um)
        .expect("re-referenced");
    (model, "map scanned with the camera (gateway map's plan)")
}

/// The figures for docs/compensation.md: `cargo test --release -p system-tests --test
/// rewrite_paths -- --ignored --nocapture` (`PROGRAMS=N`, default 30; `SCAN=1` scans
/// the map with the camera first; `MAP_OUT=FILE` writes the map used).
#[test]
#[ignore = "a benchmark: run in release with --ignored --nocapture"]
fn benchmark_path_deviation_pieces_and_speed() {
    let (job, machine) = demo_machine();
    let (model, which) = bench_model(&job, &machine);
    if let Some(path) = std::env::var_os("MAP_OUT") {
        // For `cargo run --release -p gateway --example rewrite_speed -- MAP`.
        std::fs::write(&path, model.map().to_json()).expect("the map is written");
    }
    let programs: u64 = std::env::var("PROGRAMS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(30);
    let (mut worst, mut sum2, mut rows, mut stage) = (0.0f64, 0.0, 0usize, 0.0f64);
    let (mut added, mut blocks, mut takeups, mut lines_in) = (0usize, 0usize, 0usize, 0usize);
    let mut rapid_ends = Vec::new();
    let mut where_worst = String::new();
    for seed in 1..=programs {
        let program = random_program(&spec(seed, 100));
        let run = run_program(&machine, &model, &program);
        if run.worst > worst {
            worst = run.worst;
            where_worst = format!("seed {seed}, {}", run.where_worst);
        }
        sum2 += run.sum2;
        rows += run.rows;
        stage = stage.max(run.stage_worst);
        added += run.report.segments_added;
        blocks += run.report.moves_compensated;
        takeups += run.report.backlash_takeups;
        lines_in += run.report.input_lines;
        rapid_ends.extend(run.rapid_ends);
    }
    println!("{which}");
    println!(
        "{programs} random programs ({lines_in} lines: lines, arcs in G17/G18/G19, G91, G20, G54-G59, G92, feeds): feed path max {:.3} um, rms {:.3} um from the programmed path over {rows} trace rows (stage alone up to {:.2} um); worst at {where_worst}",
        worst * 1e3,
        (sum2 / rows as f64).sqrt() * 1e3,
        stage * 1e3
    );
    println!(
        "pieces added per corrected block {:.2} (arcs included), backlash take-ups per block {:.3}",
        added as f64 / blocks as f64,
        takeups as f64 / blocks as f64
    );
    // 1000 random points, each reached by a rapid from the previous one (so from a
    // random side), the resting tool against the programmed point.
    let mut rng = rewrite::programs::Rng::new(77);
    let mut text = String::from("G21 G90\n");
    for _ in 0..1000 {
        text.push_str(&format!(
            "G0 X{:.4} Y{:.4}\n",
            rng.range(10.0, 190.0),
            rng.range(10.0, 140.0)
        ));
    }
    let points = Program {
        text,
        work_offsets: [[0.0; N_AXIS]; 6],
    };
    let run = run_program(&machine, &model, &points);
    let n = run.rapid_ends.len();
    let max = run.rapid_ends.iter().fold(0.0f64, |a, &b| a.max(b));
    let rms = (run.rapid_ends.iter().map(|e| e * e).sum::<f64>() / n as f64).sqrt();
    println!(
        "{n} random points by rapids from random sides: max {:.3} um, rms {:.3} um (the rapids of the programs: max {:.3} um over {})",
        max * 1e3,
        rms * 1e3,
        rapid_ends.iter().fold(0.0f64, |a, &b| a.max(b)) * 1e3,
        rapid_ends.len()
    );
    // The long move of the issue.
    let long = Program {
        text: "G21 G90\nG0 X17.5 Y12.25\nG1 X172.5 Y12.25 F2400\n".into(),
        work_offsets: [[0.0; N_AXIS]; 6],
    };
    let run = run_program(&machine, &model, &long);
    println!(
        "the long move G0 X17.5 Y12.25, G1 X172.5 Y12.25: max {:.3} um, rms {:.3} um, {} pieces, {} take-ups",
        run.worst * 1e3,
        (run.sum2 / run.rows as f64).sqrt() * 1e3,
        run.report.segments_added + 1,
        run.report.backlash_takeups
    );
    // Rewrite speed alone (no emulator), one thread.
    let big = random_program(&spec(1000, 20_000));
    let options = Options {
        work_offsets: big.work_offsets,
        ..Options::default()
    };
    let started = std::time::Instant::now();
    let (_, report) =
        rewrite::rewrite_program(&big.text, &model, options).expect("the program rewrites");
    let secs = started.elapsed().as_secs_f64();
    println!(
        "rewrite speed: {} lines in, {} out in {secs:.3} s: {:.0} lines/s in, {:.0} lines/s out",
        report.input_lines,
        report.output_lines,
        report.input_lines as f64 / secs,
        report.output_lines as f64 / secs
    );
}

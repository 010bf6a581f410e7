//! Measuring through the tape port with the camera as the only sensor (issue 40, item
//! 3): `runner::tape::measure_by_tape` streams a measurement tape to `emulators dnc` on
//! a pseudo-terminal (the demo's C5 stage) while the simulated camera on the same stage
//! grabs; every stop is found from the frames alone (no status, no position) and what
//! the camera measured there is compared with the stage's true error (the simulator's
//! static error model at each command). The same step under the map scan, ISO 230-2 and
//! verify on a `tape_only` stage. The machine's time is paced by the camera's frames
//! (`system_tests::dnc_rig`), so the camera sees as many frames in each dwell on a
//! loaded machine as on an idle one.

use emulators::dnc::DncPty;
use errormap::tape::{StopSpec, TapeSpec, TapeTarget};
use job::Job;
use std::time::Duration;
use system_tests::dnc_rig::{coded_rig, paced_camera, tape_stage};
use system_tests::runtime_two_workers;
use world::lock;
use world::machine::MachineConfig;

/// A safety bound (never reached by a passing run).
const BOUND: Duration = Duration::from_secs(900);

#[test]
fn a_grid_is_measured_through_the_tape_with_the_stops_found_from_the_frames() {
    let (job, machine, rig, dev) = coded_rig();
    lock(&rig).machine_mut().start_trace();
    runtime_two_workers().block_on(async {
        let pty = DncPty::spawn(dev, None).expect("a pseudo-terminal");
        let mut stage = tape_stage(&pty);
        let mut camera = paced_camera(&pty, &rig);
        let mut targets = Vec::new();
        for y in [25.0, 75.0, 125.0] {
            for x in [25.0, 100.0, 175.0] {
                targets.push(TapeTarget {
                    approach_mm: [x - 0.05, y - 0.05],
                    command_mm: [x, y],
                });
            }
        }
        let tape = TapeSpec {
            feed_mm_min: 3000.0,
            dwell_s: 3.0,
            increment_mm: 0.001,
        };
        let stops = StopSpec {
            still_mm: 0.002,
            min_still_s: 1.0,
            bound_mm: 0.2,
        };
        // Two targets in a row within the bound (one point from both sides): refused
        // before the tape goes, nothing grabbed.
        let twice = [
            targets[0],
            TapeTarget {
                approach_mm: [25.05, 25.05],
                command_mm: [25.0, 25.0],
            },
        ];
        let refused = runner::tape::measure_by_tape(
            &job,
            &mut stage,
            &mut camera,
            &twice,
            &tape,
            &stops,
            &mut |_| Ok(()),
        )
        .await;
        let e = refused.error.expect("refused");
        assert!(e.contains("targets #0 and #1"), "{e}");
        assert_eq!(refused.frames, 0);
        let run = tokio::time::timeout(
            BOUND,
            runner::tape::measure_by_tape(
                &job,
                &mut stage,
                &mut camera,
                &targets,
                &tape,
                &stops,
                &mut |_| Ok(()),
            ),
        )
        .await
        .expect("the run ends within the bound");
        assert_eq!(run.error, None, "{} stops", run.stops.len());
        assert_eq!(run.stops.len(), targets.len());
        // The truth at each stop: the stage's error there, approached from below as
        // the tape does (the simulator's static error model, noise aside), where the
        // board's position under the camera is the command plus the board at home.
        let home = machine.machine.board_at_home_mm;
        let (mut worst, mut largest) = (0.0f64, 0.0f64);
        for (k, s) in run.stops.iter().enumerate() {
            assert_eq!(s.index, k, "in order");
            let c = s.command_mm;
            let e = lock(&rig).machine().static_error_um(c);
            let truth = [home[0] + c[0] + e[0] / 1e3, home[1] + c[1] + e[1] / 1e3];
            worst = worst.max((s.observation.x_mm - truth[0]).hypot(s.observation.y_mm - truth[1]));
            largest = largest.max(e[0].hypot(e[1]) / 1e3);
        }
        eprintln!(
            "{} targets through the tape: machine time {:.1} s, {} frames ({} localized); the camera at the stops within {:.3} um of the truth (the stage's own error up to {:.1} um)",
            run.stops.len(),
            run.machine_time_s,
            run.frames,
            run.localized,
            worst * 1e3,
            largest * 1e3
        );
        assert!(largest > 0.005, "the stage is off by more than the bound");
        assert!(worst < 0.0015, "{:.3} um", worst * 1e3);
    });
}

/// The map procedure's scan (`runner::scan::run_scan`) on a `tape_only` stage: a small
/// plan (20 mm grid and lines over 40 x 30 mm, both approach sides) as one measurement
/// tape, every point found from the frames; the samples taken from below in X and Y
/// against the stage's true error relative to the reference point.
#[test]
fn the_map_scan_runs_through_the_tape_on_a_tape_only_stage() {
    use errormap::scan::{MapBuilder, ScanPlan, ScanSpec};
    use errormap::Approach;
    let (job, _, rig, dev) = coded_rig();
    let plan = ScanPlan::new(
        [60.0, 40.0],
        [100.0, 70.0],
        ScanSpec {
            grid_step_mm: 20.0,
            line_step_mm: 20.0,
            passes: 1,
        },
    )
    .expect("the plan");
    runtime_two_workers().block_on(async {
        let pty = DncPty::spawn(dev, None).expect("a pseudo-terminal");
        let stage = tape_stage(&pty);
        let mut devices = devices::Devices {
            stage: Box::new(stage),
            camera: Box::new(paced_camera(&pty, &rig)),
            rig: Some(rig.clone()),
        };
        let mut builder = MapBuilder::new();
        let mut samples = Vec::new();
        let reference = tokio::time::timeout(
            BOUND,
            runner::scan::run_scan(
                &job,
                &mut devices,
                &plan,
                &mut builder,
                &mut |i, s| {
                    samples.push((i, *s));
                    Ok(())
                },
                &mut |_, _| {},
                std::future::pending(),
            ),
        )
        .await
        .expect("the scan ends within the bound")
        .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(builder.done(), plan.points.len());
        let m = lock(&rig).machine().clone();
        let e0 = m.static_error_um(reference.command_mm);
        let mut worst = 0.0f64;
        let mut compared = 0;
        for (i, s) in &samples {
            let p = &plan.points[*i];
            if p.dir.x != Approach::Forward || p.dir.y != Approach::Forward {
                continue;
            }
            let e = m.static_error_um(p.command_mm);
            let d = (s.error_um[0] - (e[0] - e0[0])).hypot(s.error_um[1] - (e[1] - e0[1]));
            worst = worst.max(d);
            compared += 1;
        }
        eprintln!(
            "map scan through the tape: {} points, the {compared} approached from below within {worst:.3} um of the truth",
            plan.points.len()
        );
        assert!(compared > 3);
        assert!(worst < 1.5, "{worst:.3} um");
    });
}

/// The map of the demo stage from the simulator's truth (as a perfect scan would make
/// it), for the jobs that apply one.
fn truth_model(job: &Job, machine: &MachineConfig) -> errormap::MapModel {
    let id = system_tests::truth_map::sim_identity(job);
    errormap::MapModel::new(system_tests::truth_map::map_from_truth(machine, id))
}

/// ISO 230-2 through the tape (`runner::iso230::run_iso230` on a `tape_only` stage):
/// the cycle of tests/tests/iso230.rs (X 22 .. 48 mm, 5 positions, 5 runs each way,
/// 1 mm overrun) without a map and with the stage's map; the figures must improve as
/// much as they do over GRBL.
#[test]
fn iso230_runs_through_the_tape_and_the_map_improves_every_figure() {
    use iso230::plan::{targets, Cycle, CycleKind};
    use runner::iso230::{run_iso230, Iso230Spec};
    let cycle = || {
        Cycle::new(
            targets(22.0, 48.0, None).unwrap(),
            5,
            1.0,
            CycleKind::Linear,
        )
        .unwrap()
    };
    let test = |map: Option<&errormap::MapModel>| {
        let (job, _, rig, dev) = coded_rig();
        runtime_two_workers().block_on(async {
            let pty = DncPty::spawn(dev, None).expect("a pseudo-terminal");
            let mut devices = devices::Devices {
                stage: Box::new(tape_stage(&pty)),
                camera: Box::new(paced_camera(&pty, &rig)),
                rig: Some(rig.clone()),
            };
            let spec = Iso230Spec {
                axis: 0,
                cycle: cycle(),
                across_mm: 45.0,
                still_frames: 3,
            };
            let mut seen = 0;
            let run = tokio::time::timeout(
                BOUND,
                run_iso230(
                    &job,
                    &mut devices,
                    &spec,
                    map,
                    &mut |_| seen += 1,
                    &mut |_, _| {},
                    std::future::pending(),
                ),
            )
            .await
            .expect("the cycle ends within the bound")
            .unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(run.measurements.len(), 50);
            assert_eq!(seen, 50);
            assert_eq!(run.still_um.len(), 3);
            iso230::evaluate(&run.measurements).unwrap()
        })
    };
    let (job, machine, _, _) = coded_rig();
    let model = truth_model(&job, &machine);
    let (b, a) = (test(None).figures, test(Some(&model)).figures);
    eprintln!("ISO 230-2 through the tape: before {b:?}\nafter  {a:?}");
    // The same bounds as over GRBL (tests/tests/iso230.rs).
    assert!(b.a > 5.0 && b.b > 2.0, "{b:?}");
    assert!(a.a < 0.2 * b.a, "A {} -> {}", b.a, a.a);
    assert!(a.b < 0.2 * b.b, "B {} -> {}", b.b, a.b);
    assert!(a.e < 0.2 * b.e, "E {} -> {}", b.e, a.e);
    assert!(a.m < b.m, "M {} -> {}", b.m, a.m);
    assert!(a.r < b.r, "R {} -> {}", b.r, a.r);
}

/// Verify through the tape (`runner::verify::run_verify` on a `tape_only` stage): the
/// six points of tests/tests/errormap_verify.rs, each approached from its side with the
/// map's command; the camera finds the residual far below the stage's error, as over
/// GRBL.
#[test]
fn verify_runs_through_the_tape_and_the_residual_is_far_below_the_error() {
    use errormap::{Approach, Direction};
    let (job, machine, rig, dev) = coded_rig();
    let model = truth_model(&job, &machine);
    let d = |x, y| Direction { x, y };
    use Approach::{Forward as F, Reverse as R};
    let points = vec![
        ([20.5, 15.25], d(F, F)),
        ([150.0, 30.0], d(R, F)),
        ([95.3, 120.7], d(F, R)),
        ([180.2, 140.1], d(R, R)),
        ([42.0, 88.8], d(F, R)),
        ([121.9, 64.4], d(R, F)),
    ];
    let v = runtime_two_workers().block_on(async {
        let pty = DncPty::spawn(dev, None).expect("a pseudo-terminal");
        let mut devices = devices::Devices {
            stage: Box::new(tape_stage(&pty)),
            camera: Box::new(paced_camera(&pty, &rig)),
            rig: Some(rig.clone()),
        };
        tokio::time::timeout(
            BOUND,
            runner::verify::run_verify(&job, &mut devices, &model, &points),
        )
        .await
        .expect("the check ends within the bound")
        .unwrap_or_else(|(e, _)| panic!("{e}"))
    });
    assert_eq!(v.points.len(), points.len());
    let norm = |p: [f64; 2]| p[0].hypot(p[1]);
    let worst = v
        .points
        .iter()
        .map(|p| norm(p.residual_um))
        .fold(0.0, f64::max);
    let raw = v
        .points
        .iter()
        .map(|p| norm(p.uncompensated_um))
        .fold(0.0, f64::max);
    eprintln!(
        "verify through the tape: residual max {worst:.2} um, uncompensated max {raw:.2} um, reference {:?} um",
        v.reference_um
    );
    // The same bounds as over GRBL (tests/tests/errormap_verify.rs).
    assert!(raw > 10.0, "the stage's own error: {raw} um");
    assert!(worst < 1.5, "residual {worst} um");
}

/// The compensation loop through the tape (`runner::run_job` on a `tape_only` stage):
/// every positioning, the first and each correction, is a short tape of its own whose
/// end the camera sees; the first six targets of the coded job (no homing: the coded
/// board says where the machine is) end on target as over GRBL.
#[test]
fn compensate_runs_each_move_as_a_short_tape_and_ends_on_target() {
    let (mut job, _, rig, dev) = coded_rig();
    job.targets.truncate(6);
    let report = runtime_two_workers().block_on(async {
        let pty = DncPty::spawn(dev, None).expect("a pseudo-terminal");
        let mut devices = devices::Devices {
            stage: Box::new(tape_stage(&pty)),
            camera: Box::new(paced_camera(&pty, &rig)),
            rig: Some(rig.clone()),
        };
        tokio::time::timeout(BOUND, runner::run_job(&job, &mut devices, &mut |_, _| {}))
            .await
            .expect("the job ends within the bound")
    });
    eprintln!("compensate through the tape:\n{}", report.to_text());
    // The demo's figure over GRBL (tests/tests/compensation.rs): every target converged,
    // within 1 um of the truth, on a stage off by more than 10 um there.
    system_tests::assert_demo_figure(&report, 10.0);
}

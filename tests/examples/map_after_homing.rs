//! The map's accuracy after a homing, end to end, as an independent check measures it:
//!
//! ```text
//! nice -n 10 cargo run --release -p system-tests --example map_after_homing [POINTS] [CONFIG]
//! ```
//!
//! (defaults: 1000 points, `config/gateway/grbl-demo.toml`). A map is scanned by the
//! camera through the job's stage (the GRBL emulator on a pseudo-terminal, driving the
//! simulated C5 stage, thermal drift on), as `gateway map` does; then the machine is
//! homed again and the map's reference point measured, as `gateway reference` does
//! (`runner::reference::measure_reference`, the map shifted by what it saw); then
//! `POINTS` random nominal points inside the map are each approached from a random side
//! per axis (the job's approach distance) with the map's command, through the same
//! GRBL link, and where the camera really is comes from the simulator's truth (which the
//! gateway never reads). Prints the scan's frames and machine time, and the error left
//! (max, rms) beside the uncompensated error and beside an ideal touch-off (the map
//! shifted by the truth at the reference point instead of the measured reference).
//!
//! Environment: `GRID_MM`, `LINE_MM`, `PASSES` override the scan plan's defaults;
//! `NO_SNAP=1` plans positions off the stage's steps (as before issue 39);
//! `NO_THERMAL=1` switches the stage's thermal drift off.

use drivers::AxisValues;
use errormap::scan::{MapBuilder, ScanPlan, ScanSpec};
use errormap::{Approach, Direction, MapModel};
use job::Job;
use protocol::errormap::Identity;
use runner::scan::{run_scan, scan_area};
use std::path::PathBuf;
use std::time::Instant;

fn env_f64(name: &str) -> Option<f64> {
    std::env::var(name).ok().and_then(|s| s.parse().ok())
}

fn main() {
    let mut args = std::env::args().skip(1);
    let n: usize = args.next().and_then(|s| s.parse().ok()).unwrap_or(1000);
    let config = args.next().map(PathBuf::from).unwrap_or_else(|| {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/gateway/grbl-demo.toml")
    });
    let mut job = Job::load(&config).expect("the job's config");
    if std::env::var_os("NO_THERMAL").is_some() {
        match &mut job.stage {
            job::StageSpec::Sim { machine } => machine.thermal = None,
            job::StageSpec::Grbl {
                link: job::GrblLink::Emulate(machine),
                ..
            } => machine.thermal = None,
            _ => panic!("NO_THERMAL: not an emulated stage"),
        }
    }
    let defaults = ScanSpec::default();
    let spec = ScanSpec {
        grid_step_mm: env_f64("GRID_MM").unwrap_or(defaults.grid_step_mm),
        line_step_mm: env_f64("LINE_MM").unwrap_or(defaults.line_step_mm),
        passes: env_f64("PASSES").map_or(defaults.passes, |p| p as u32),
    };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .unwrap();
    let mut devices = rt
        .block_on(devices::open_devices_async(&job))
        .expect("the job's devices");
    let rig = devices
        .rig
        .clone()
        .expect("a simulated machine behind the stage");
    let limits = runner::soft_limits(devices.stage.info()).unwrap();
    let (lo, hi) = scan_area(&job, &limits);
    // On the stage's own steps, as `gateway map` plans it (`NO_SNAP=1`: anywhere).
    let info = devices.stage.info();
    let steps =
        [drivers::Axis::X, drivers::Axis::Y].map(|a| info.axis(a).map_or(0.0, |i| i.resolution_mm));
    let steps = if std::env::var_os("NO_SNAP").is_some() {
        [0.0; 2]
    } else {
        steps
    };
    let plan = ScanPlan::on_steps(lo, hi, spec, steps).unwrap();
    let mut builder = MapBuilder::new();
    let started = Instant::now();
    let t0 = world::lock(&rig).machine().now_s();
    let reference = rt
        .block_on(run_scan(
            &job,
            &mut devices,
            &plan,
            &mut builder,
            &mut |_, _| Ok(()),
            &mut |_, _| {},
            std::future::pending(),
        ))
        .unwrap();
    let scan_wall_s = started.elapsed().as_secs_f64();
    let scan_machine_s = world::lock(&rig).machine().now_s() - t0;
    let id = Identity {
        machine: "sim".into(),
        controller: devices.stage.info().name.clone(),
        board: job.board.name.clone(),
        certificate_sha256: job.board.fingerprint_sha256(),
        camera: "sim".into(),
    };
    let map = builder
        .finish(
            &plan,
            id,
            1,
            "now".into(),
            [0.0; 2],
            job.board_at_machine_zero_mm,
            reference.command_mm,
        )
        .unwrap();
    let uncertainty = map.uncertainty_um;
    let reference_mm = map.reference_mm;
    let base = MapModel::new(map);

    // Home again and measure the reference point, as `gateway reference` does.
    let homings = world::lock(&rig).machine().homings();
    let frame = rt
        .block_on(runner::reference::measure_reference(
            &job,
            devices.stage.as_mut(),
            devices.camera.as_mut(),
            reference_mm,
        ))
        .expect("the reference after homing");
    assert!(
        world::lock(&rig).machine().homings() > homings,
        "the job did not home again"
    );
    let z = job.board_at_machine_zero_mm;
    let truth_error_um = || {
        let pose = world::lock(&rig).truth();
        pose.centre_mm
    };
    // The truth where the reference frame was taken: an ideal touch-off.
    let at_reference = truth_error_um();
    let ideal_seen = [
        (at_reference[0] - reference_mm[0] - z[0]) * 1000.0,
        (at_reference[1] - reference_mm[1] - z[1]) * 1000.0,
    ];
    let model = base.clone().rereferenced(frame.seen_um).unwrap();
    let ideal = base.rereferenced(ideal_seen).unwrap();

    let mut s = 0x2545_F491_4F6C_DD1Du64;
    let mut next = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let approach = job.policy.approach_mm;
    let (mlo, mhi) = model.extent();
    let mut error_at = |cmd: [f64; 2], dir: Direction, nominal: [f64; 2]| -> [f64; 2] {
        let side = |a: Approach| {
            if a == Approach::Forward {
                -approach
            } else {
                approach
            }
        };
        rt.block_on(async {
            for at in [[cmd[0] + side(dir.x), cmd[1] + side(dir.y)], cmd] {
                devices
                    .stage
                    .move_to(AxisValues::xy(at[0], at[1]), job.feed_mm_min)
                    .await
                    .unwrap();
                devices.stage.wait_idle().await.unwrap();
            }
        });
        let c = truth_error_um();
        [
            (c[0] - nominal[0] - z[0]) * 1000.0,
            (c[1] - nominal[1] - z[1]) * 1000.0,
        ]
    };
    use system_tests::truth_map::ErrorStat;
    let (mut raw, mut left, mut left_ideal) = (
        ErrorStat::default(),
        ErrorStat::default(),
        ErrorStat::default(),
    );
    let (mut left_x, mut left_y) = (ErrorStat::default(), ErrorStat::default());
    let check_t0 = world::lock(&rig).machine().now_s();
    // The first fifth of the check separately: the thermal drift since the reference
    // grows with the check's own machine time.
    let mut early = ErrorStat::default();
    for point in 0..n {
        let p = [
            mlo[0] + (mhi[0] - mlo[0]) * next(),
            mlo[1] + (mhi[1] - mlo[1]) * next(),
        ];
        let side = |u: f64| {
            if u < 0.5 {
                Approach::Forward
            } else {
                Approach::Reverse
            }
        };
        let dir = Direction {
            x: side(next()),
            y: side(next()),
        };
        // Uncompensated: what the map says the stage does there (no extra move, so the
        // check's machine time, and the drift during it, is one move per point).
        let u = model.camera_error_um(p, dir).unwrap();
        raw.add(u[0].hypot(u[1]));
        let e = error_at(model.camera_command_for(p, dir).unwrap(), dir, p);
        left.add(e[0].hypot(e[1]));
        if point < n.div_ceil(5) {
            early.add(e[0].hypot(e[1]));
        }
        left_x.add(e[0].abs());
        left_y.add(e[1].abs());
        // The ideal touch-off's map differs by a constant shift: its command lands the
        // difference further (the error's slope is far below 0.01 um per um).
        let (a, b) = (model.offset_um(), ideal.offset_um());
        let ei = [e[0] + a[0] - b[0], e[1] + a[1] - b[1]];
        left_ideal.add(ei[0].hypot(ei[1]));
    }
    let check_machine_s = world::lock(&rig).machine().now_s() - check_t0;
    println!(
        "scan: {} frames, {:.1} s of machine time, {:.1} s wall; map uncertainty {:.3} um (k = 2); plan {}",
        plan.points.len(),
        scan_machine_s,
        scan_wall_s,
        uncertainty,
        plan.fingerprint()
    );
    println!(
        "homed again, reference measured: seen ({:+.3}, {:+.3}) um, truth ({:+.3}, {:+.3}) um",
        frame.seen_um[0], frame.seen_um[1], ideal_seen[0], ideal_seen[1]
    );
    println!("{n} random points, random approach side per axis ({check_machine_s:.0} s of machine time for the check):");
    println!("  uncompensated (the map's own figure): {}", raw.text());
    println!("  with the map and its reference: {}", left.text());
    println!("    per axis: X {}; Y {}", left_x.text(), left_y.text());
    println!("  with an ideal touch-off:        {}", left_ideal.text());
    println!(
        "  the first {} points only (the drift since the reference smaller): {}",
        early.n,
        early.text()
    );
}

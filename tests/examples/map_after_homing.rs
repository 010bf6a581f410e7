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
//! `NO_THERMAL=1` switches the stage's thermal drift off; `NO_SCALE=1` measures the
//! reference point alone (as before issue 39: no axis scale); `REREF_S=S` re-references
//! in use every S s of machine time (no homing: the reference point and the scale
//! points; `RATE=1` predicts the scale between them with the rate since the previous
//! reference, as `MapReference::predicted_scale_ppm` does).

use drivers::AxisValues;
use errormap::reference::{scale_points_mm, Circumstances, MapReference};
use errormap::scan::{MapBuilder, ScanPlan, ScanSpec};
use errormap::{Approach, Direction, MapModel, MAX_SHIFT_UM};
use job::Job;
use protocol::errormap::ErrorMap;
use runner::scan::{run_scan, scan_area};
use std::path::PathBuf;
use std::time::{Duration, Instant, UNIX_EPOCH};

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
    let map = system_tests::truth_map::finish_sim_map(
        &builder,
        &plan,
        &job,
        &devices.stage.info().name,
        reference.command_mm,
    );
    let uncertainty = map.uncertainty_um;
    let reference_mm = map.reference_mm;
    let base = MapModel::new(map);
    let scale_at = if std::env::var_os("NO_SCALE").is_some() {
        None
    } else {
        scale_points_mm(base.map())
    };
    let reref_s = env_f64("REREF_S").unwrap_or(0.0);
    let with_rate = std::env::var_os("RATE").is_some();
    let machine_s = || world::lock(&rig).machine().now_s();
    // The records' clock: the simulated machine's time on a fixed epoch (the check runs
    // faster than real time; the prediction needs the machine's time).
    let clock = |t: f64| EPOCH_S + t as u64;

    // Home again and measure the reference point (and the scale points), as `gateway
    // reference` does.
    let homings = world::lock(&rig).machine().homings();
    let t_ref = machine_s();
    let (frame, mut record) = rt.block_on(take_reference(
        &job,
        &mut devices,
        base.map(),
        true,
        scale_at,
        None,
        clock(t_ref),
    ));
    let reference_machine_s = machine_s() - t_ref;
    assert!(
        world::lock(&rig).machine().homings() > homings,
        "the job did not home again"
    );
    let z = job.board_at_machine_zero_mm;
    let truth_error_um = || {
        let pose = world::lock(&rig).truth();
        pose.centre_mm
    };
    // The truth where the reference frame was taken: an ideal touch-off. (With the
    // scale points measured the stage is elsewhere now: the truth at the reference
    // point is read by going back there, outside the check's clock.)
    let ideal_seen = {
        rt.block_on(goto(&job, &mut devices, reference_mm, Direction::FORWARD));
        let c = truth_error_um();
        [
            (c[0] - reference_mm[0] - z[0]) * 1000.0,
            (c[1] - reference_mm[1] - z[1]) * 1000.0,
        ]
    };
    let first_record = record.clone();
    let mut model = record.apply(base.clone(), clock(machine_s())).unwrap();
    let ideal = base
        .clone()
        .rereferenced(ideal_seen)
        .unwrap()
        .rescaled(model.scale_ppm())
        .unwrap();

    let mut s = 0x2545_F491_4F6C_DD1Du64;
    let mut next = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let (mlo, mhi) = model.extent();
    use system_tests::truth_map::ErrorStat;
    let (mut raw, mut left, mut left_ideal) = (
        ErrorStat::default(),
        ErrorStat::default(),
        ErrorStat::default(),
    );
    let (mut left_x, mut left_y) = (ErrorStat::default(), ErrorStat::default());
    let check_t0 = machine_s();
    let (mut last_ref_s, mut rerefs, mut reref_machine_s) = (check_t0, 0u32, 0.0);
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
        // In use, a re-reference every REREF_S of machine time (no homing: the zero's
        // drift and the axes' growth since the scan, the rate since the previous one).
        if reref_s > 0.0 && machine_s() - last_ref_s >= reref_s {
            let t = machine_s();
            record = rt
                .block_on(take_reference(
                    &job,
                    &mut devices,
                    base.map(),
                    false,
                    scale_at,
                    Some(&record),
                    clock(t),
                ))
                .1;
            model = record.apply(base.clone(), clock(machine_s())).unwrap();
            last_ref_s = machine_s();
            reref_machine_s += last_ref_s - t;
            rerefs += 1;
        }
        // RATE=1: the scale as the record's rate predicts it now (the gateway applies
        // the measured scale).
        if with_rate {
            model = model
                .rescaled(record.predicted_scale_ppm(clock(machine_s())))
                .unwrap();
        }
        // Uncompensated: what the map says the stage does there (no extra move, so the
        // check's machine time, and the drift during it, is one move per point).
        let u = model.camera_error_um(p, dir).unwrap();
        raw.add(u[0].hypot(u[1]));
        let c = model.camera_command_for(p, dir).unwrap();
        rt.block_on(goto(&job, &mut devices, c, dir));
        let t = truth_error_um();
        let e = [(t[0] - p[0] - z[0]) * 1000.0, (t[1] - p[1] - z[1]) * 1000.0];
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
    let check_machine_s = machine_s() - check_t0;
    println!(
        "scan: {} frames, {:.1} s of machine time, {:.1} s wall; map uncertainty {:.3} um (k = 2); plan {}",
        plan.points.len(),
        scan_machine_s,
        scan_wall_s,
        uncertainty,
        plan.fingerprint()
    );
    println!(
        "homed again, reference measured in {reference_machine_s:.1} s of machine time: seen ({:+.3}, {:+.3}) um, truth ({:+.3}, {:+.3}) um",
        frame.seen_um[0], frame.seen_um[1], ideal_seen[0], ideal_seen[1]
    );
    match &first_record.scale {
        Some(sc) => println!(
            "  axes' scale since the scan: ({:+.3}, {:+.3}) ppm, measured at X {:.3}, Y {:.3} mm",
            sc.ppm[0], sc.ppm[1], sc.at_mm[0], sc.at_mm[1]
        ),
        None => println!("  no scale measured (NO_SCALE, or the map is too short)"),
    }
    if rerefs > 0 {
        let sc = record.scale.as_ref();
        println!(
            "  re-referenced {rerefs} times in use, every {reref_s:.0} s: {reref_machine_s:.1} s of machine time; the last: scale {:?} ppm, rate {:?} ppm/h",
            sc.map(|s| s.ppm),
            sc.and_then(|s| s.ppm_per_h)
        );
    }
    println!("{n} random points, random approach side per axis ({check_machine_s:.0} s of machine time for the check):");
    println!("  uncompensated (the map's own figure): {}", raw.text());
    println!("  with the map and its reference: {}", left.text());
    println!("    per axis: X {}; Y {}", left_x.text(), left_y.text());
    if rerefs == 0 {
        println!("  with an ideal touch-off:        {}", left_ideal.text());
    }
    println!(
        "  the first {} points only (the drift since the reference smaller): {}",
        early.n,
        early.text()
    );
}

/// 2026-11-27T13:00:00Z: the records' epoch, the machine's time added to it.
const EPOCH_S: u64 = 1_795_784_400;

/// Moves onto `cmd` approached from `dir`'s side by the job's approach distance.
async fn goto(job: &Job, devices: &mut devices::Devices, cmd: [f64; 2], dir: Direction) {
    let a = job.policy.approach_mm;
    let side = |s: Approach| if s == Approach::Forward { -a } else { a };
    for at in [[cmd[0] + side(dir.x), cmd[1] + side(dir.y)], cmd] {
        devices
            .stage
            .move_to(AxisValues::xy(at[0], at[1]), job.feed_mm_min)
            .await
            .unwrap();
        devices.stage.wait_idle().await.unwrap();
    }
}

/// A reference as `gateway reference` takes it (`home`: homing first), or in use
/// without homing: the frame at the reference point, then each axis's scale point when
/// `scale_at` names them, recorded with `previous` (its count and rate go on).
async fn take_reference(
    job: &Job,
    devices: &mut devices::Devices,
    map: &ErrorMap,
    home: bool,
    scale_at: Option<[f64; 2]>,
    previous: Option<&MapReference>,
    now_s: u64,
) -> (runner::reference::ReferenceFrame, MapReference) {
    let (stage, camera) = (devices.stage.as_mut(), devices.camera.as_mut());
    let r = map.reference_mm;
    // FRAMES: arrivals averaged per point (the gateway's default with a scale).
    let frames = match (scale_at, env_f64("FRAMES")) {
        (None, _) => 1,
        (Some(_), Some(f)) => f as usize,
        (Some(_), None) => runner::reference::FRAMES_PER_POINT,
    };
    let frame = if home {
        runner::reference::measure_reference_mean(job, stage, camera, r, frames).await
    } else {
        let seen = runner::reference::measure_mean_at(job, stage, camera, r, frames).await;
        seen.map(|seen_um| runner::reference::ReferenceFrame {
            command_mm: r,
            seen_um,
        })
    }
    .expect("the reference frame");
    let at = Circumstances {
        measured_at: errormap::scan::rfc3339(UNIX_EPOCH + Duration::from_secs(now_s)),
        measured_unix_s: now_s,
        previous_count: previous.map_or(0, |p| p.reference_count),
        ..Circumstances::default()
    };
    let mut record = MapReference::new(map, frame.seen_um, MAX_SHIFT_UM, at).unwrap();
    if let Some(at_mm) = scale_at {
        let seen = runner::reference::measure_scale(job, stage, camera, r, at_mm, frames)
            .await
            .expect("the scale frames");
        record = record.with_scale(map, at_mm, seen, previous).unwrap();
    }
    (frame, record)
}

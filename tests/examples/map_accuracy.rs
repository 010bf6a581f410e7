//! How well an error map measured by the camera compensates the demo stage with no camera
//! in the loop: `cargo run --release -p system-tests --example map_accuracy [POINTS]`.
//!
//! Scans the demo job's simulated stage with the default plan (as `gateway map` does),
//! then, on the same machine (thermal drift running on), moves to random nominal points
//! approached from random sides with the map's command, and reads where the camera
//! really is from the simulator's truth. Prints the uncompensated and compensated error
//! (max, RMS) and the scan's cost.

use devices::open_devices;
use drivers::AxisValues;
use errormap::scan::{MapBuilder, ScanPlan, ScanSpec};
use errormap::{Approach, Direction, MapModel};
use job::Job;
use runner::scan::{run_scan, scan_area};
use std::time::Instant;

fn main() {
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(1000);
    let mut job = Job::demo();
    if std::env::var_os("NO_THERMAL").is_some() {
        // The map's spatial model alone (drift is for re-referencing and spot checks).
        if let job::StageSpec::Sim { machine } = &mut job.stage {
            machine.thermal = None;
        }
    }
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let mut devices = open_devices(&job).unwrap();
    let limits = runner::soft_limits(devices.stage.info()).unwrap();
    let (lo, hi) = scan_area(&job, &limits);
    let plan = ScanPlan::new(lo, hi, ScanSpec::default()).unwrap();
    let mut builder = MapBuilder::new();
    let started = Instant::now();
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
    let scan_s = started.elapsed().as_secs_f64();
    let rig = devices.rig.clone().unwrap();
    let machine_s = world::lock(&rig).machine().now_s();
    let map =
        system_tests::truth_map::finish_sim_map(&builder, &plan, &job, "sim", reference.command_mm);
    let uncertainty = map.uncertainty_um;
    // The map is relative to the reference frame; this run's reference re-references it.
    let model = MapModel::new(map).rereferenced(reference.error_um).unwrap();
    let z = job.board_at_machine_zero_mm;
    let mut s = 0x2545_F491_4F6C_DD1Du64;
    let mut next = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let (mut raw_max, mut raw2, mut max, mut sum2) = (0.0f64, 0.0, 0.0f64, 0.0);
    let mut error_at = |cmd: [f64; 2], dir: Direction, nominal: [f64; 2]| {
        let side = |a: Approach| if a == Approach::Forward { -0.05 } else { 0.05 };
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
        let pose = world::lock(&rig).truth();
        let e = [
            (pose.centre_mm[0] - nominal[0] - z[0]) * 1000.0,
            (pose.centre_mm[1] - nominal[1] - z[1]) * 1000.0,
        ];
        e[0].hypot(e[1])
    };
    for _ in 0..n {
        let p = [
            lo[0] + 0.2 + (hi[0] - lo[0] - 0.4) * next(),
            lo[1] + 0.2 + (hi[1] - lo[1] - 0.4) * next(),
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
        let raw = error_at(p, dir, p);
        raw_max = raw_max.max(raw);
        raw2 += raw * raw;
        let c = model.command_for(p, dir).unwrap();
        let left = error_at(c, dir, p);
        max = max.max(left);
        sum2 += left * left;
    }
    let rms = |s2: f64| (s2 / n as f64).sqrt();
    println!(
        "scan: {} frames, {:.0} s of machine time, {:.1} s wall; map uncertainty {:.3} um (k = 2)",
        plan.points.len(),
        machine_s,
        scan_s,
        uncertainty
    );
    println!(
        "{n} random points, random approach sides: uncompensated max {raw_max:.2} um, rms {:.2} um; with the map max {max:.3} um, rms {:.3} um",
        rms(raw2),
        rms(sum2)
    );
}

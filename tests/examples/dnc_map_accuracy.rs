//! The accuracy of a map scanned through the tape port only (issue 40: no status, no
//! position, the camera as the only sensor), as an independent check measures it:
//!
//! ```text
//! nice -n 10 cargo run -p system-tests --example dnc_map_accuracy [POINTS]
//! ```
//!
//! (default 1000 points). The demo's C5 stage (thermal drift off) under the coded board
//! is driven by `emulators dnc` on a pseudo-terminal, its clock paced by the simulated
//! camera's frames (`system_tests::dnc_rig`: the figures do not depend on the build or
//! the load, only the wall time does; the renderer and the localizer are optimized in a
//! debug build too). The map is scanned over the travel with the default plan (10 mm
//! grid, 1 mm lines, both sides) as `gateway map` does on a `tape_only` stage: one
//! measurement tape, every stop found from the frames; the map is re-referenced by the
//! scan's own reference frame (a tape port cannot home again). Then `POINTS` random
//! nominal points inside the map, each approached from a random side per axis (the
//! job's approach distance) with the map's command, are run on a fresh machine with the
//! same first homing (the emulator homes at power-on) and where the camera really is
//! comes from the simulator's truth, which the gateway never reads. Prints the scan's
//! machine time and frames, and the error left (max, rms) beside the uncompensated
//! error. `GRID_MM`, `LINE_MM` override the plan.

use errormap::scan::{MapBuilder, ScanPlan, ScanSpec};
use errormap::{Approach, Direction, MapModel};
use runner::scan::{run_scan, scan_area};
use std::time::Instant;
use system_tests::dnc_rig::{coded_rig, paced_camera, tape_stage};
use world::lock;

fn env_f64(name: &str) -> Option<f64> {
    std::env::var(name).ok().and_then(|s| s.parse().ok())
}

use system_tests::truth_map::ErrorStat;

fn main() {
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(1000);
    let defaults = ScanSpec::default();
    let spec = ScanSpec {
        grid_step_mm: env_f64("GRID_MM").unwrap_or(defaults.grid_step_mm),
        line_step_mm: env_f64("LINE_MM").unwrap_or(defaults.line_step_mm),
        passes: 1,
    };
    let (job, machine, rig, dev) = coded_rig();
    let rt = system_tests::runtime_two_workers();
    let started = Instant::now();
    let (plan, builder, reference, machine_s, frames) = rt.block_on(async {
        let pty = emulators::dnc::DncPty::spawn(dev, None).expect("a pseudo-terminal");
        let mut devices = devices::Devices {
            stage: Box::new(tape_stage(&pty)),
            camera: Box::new(paced_camera(&pty, &rig)),
            rig: Some(rig.clone()),
        };
        let limits = runner::soft_limits(devices.stage.info()).unwrap();
        let (lo, hi) = scan_area(&job, &limits);
        let plan = ScanPlan::new(lo, hi, spec).unwrap();
        eprintln!("{}: {} points", plan.fingerprint(), plan.points.len());
        let mut builder = MapBuilder::new();
        let (t0, f0) = {
            let r = lock(&rig);
            (r.machine().now_s(), r.frames())
        };
        let total = plan.points.len();
        let reference = run_scan(
            &job,
            &mut devices,
            &plan,
            &mut builder,
            &mut |_, _| Ok(()),
            &mut |done, _| {
                if done % 100 == 0 {
                    eprintln!("  {done} of {total}");
                }
            },
            std::future::pending(),
        )
        .await
        .unwrap_or_else(|e| panic!("the scan: {e}"));
        let r = lock(&rig);
        let machine_s = r.machine().now_s() - t0;
        (plan, builder, reference, machine_s, r.frames() - f0)
    });
    let scan_wall_s = started.elapsed().as_secs_f64();
    let map =
        system_tests::truth_map::finish_sim_map(&builder, &plan, &job, "dnc", reference.command_mm);
    let uncertainty = map.uncertainty_um;
    let model = MapModel::new(map).rereferenced(reference.error_um).unwrap();

    // The check: a fresh machine with the same first homing, moved in-process.
    let truth = devices::new_rig(&job, &machine);
    lock(&truth).machine_mut().home();
    let z = job.board_at_machine_zero_mm;
    let approach = job.policy.approach_mm;
    let error_at = |cmd: [f64; 2], dir: Direction, nominal: [f64; 2]| -> f64 {
        let side = |a: Approach| {
            if a == Approach::Forward {
                -approach
            } else {
                approach
            }
        };
        let mut r = lock(&truth);
        for at in [[cmd[0] + side(dir.x), cmd[1] + side(dir.y)], cmd] {
            r.machine_mut()
                .start_move(at, job.feed_mm_min)
                .expect("inside the travel");
            r.machine_mut().finish_motion();
        }
        let c = r.truth().centre_mm;
        ((c[0] - nominal[0] - z[0]) * 1000.0).hypot((c[1] - nominal[1] - z[1]) * 1000.0)
    };
    let mut s = 0x2545_F491_4F6C_DD1Du64;
    let mut next = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let (mlo, mhi) = model.extent();
    let (mut compensated, mut raw) = (ErrorStat::default(), ErrorStat::default());
    for _ in 0..n {
        let p = [
            mlo[0] + 1.0 + (mhi[0] - mlo[0] - 2.0) * next(),
            mlo[1] + 1.0 + (mhi[1] - mlo[1] - 2.0) * next(),
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
        let c = model.camera_command_for(p, dir).expect("inside the map");
        compensated.add(error_at(c, dir, p));
        raw.add(error_at(p, dir, p));
    }
    println!(
        "scan through the tape: {} points, machine time {:.0} s ({:.1} h), {} frames, {:.0} s wall; map uncertainty {:.3} um",
        plan.points.len(),
        machine_s,
        machine_s / 3600.0,
        frames,
        scan_wall_s,
        uncertainty
    );
    println!("{n} random points, random side per axis:");
    println!("  with the map:    {}", compensated.text());
    println!("  without the map: {}", raw.text());
}

//! The ISO 230-2 test on the simulated demo stage through the device traits (the same
//! path as `gateway iso230`): a short X segment (5 positions, 5 runs each way, the
//! standard's minimum) before and after an error map scanned over the same region; the
//! figures must improve. A small camera window and a small map keep the debug build fast.

use devices::open_devices;
use errormap::scan::{MapBuilder, ScanPlan, ScanSpec};
use errormap::MapModel;
use iso230::plan::{targets, Cycle, CycleKind};
use iso230::{evaluate, Evaluation};
use job::{CameraSpec, Job, StageSpec};
use protocol::errormap::Identity;
use runner::iso230::{run_iso230, Iso230Error, Iso230Spec};
use runner::scan::run_scan;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use system_tests::runtime;

fn small_job() -> Job {
    let mut job = Job::demo();
    let CameraSpec::Sim { model } = &mut job.camera else {
        unreachable!("the demo job simulates its camera")
    };
    model.width = 480;
    model.height = 384;
    job.localize.min_points = 8;
    let StageSpec::Sim { machine } = &mut job.stage else {
        unreachable!("the demo job is simulated")
    };
    // The map's spatial model only: drift is what re-referencing is for.
    machine.thermal = None;
    job
}

fn scan_map(job: &Job) -> (MapModel, f64) {
    let mut devices = open_devices(job).unwrap();
    // A map over x 20 .. 50, y 35 .. 55 mm: 10 mm grid, 1 mm lines (the screw's 5 mm
    // pitch error needs them).
    let spec = ScanSpec {
        grid_step_mm: 10.0,
        line_step_mm: 1.0,
        passes: 1,
    };
    let plan = ScanPlan::new([20.0, 35.0], [50.0, 55.0], spec).unwrap();
    let mut builder = MapBuilder::new();
    let reference = runtime()
        .block_on(run_scan(
            job,
            &mut devices,
            &plan,
            &mut builder,
            &mut |_, _| Ok(()),
            &mut |_, _| {},
            std::future::pending(),
        ))
        .unwrap();
    let id = Identity {
        machine: "sim".into(),
        controller: "sim".into(),
        board: job.board.name.clone(),
        certificate_sha256: job.board.fingerprint_sha256(),
        camera: "c".into(),
    };
    let map = builder
        .finish(
            &plan,
            id,
            1,
            "t".into(),
            [0.0; 2],
            job.board_at_machine_zero_mm,
            reference.command_mm,
        )
        .unwrap();
    (MapModel::new(map), plan.x_line_at)
}

fn cycle() -> Cycle {
    Cycle::new(
        targets(22.0, 48.0, None).unwrap(),
        5,
        1.0,
        CycleKind::Linear,
    )
    .unwrap()
}

fn test(job: &Job, map: Option<&MapModel>, across_mm: f64) -> Evaluation {
    let mut devices = open_devices(job).unwrap();
    let spec = Iso230Spec {
        axis: 0,
        cycle: cycle(),
        across_mm,
        still_frames: 3,
    };
    let mut seen = 0;
    let run = runtime()
        .block_on(run_iso230(
            job,
            &mut devices,
            &spec,
            map,
            &mut |_| seen += 1,
            &mut |_, _| {},
            std::future::pending(),
        ))
        .unwrap();
    assert_eq!(run.measurements.len(), 50);
    assert_eq!(seen, 50);
    assert_eq!(run.still_um.len(), 3);
    evaluate(&run.measurements).unwrap()
}

#[test]
fn the_map_improves_every_iso230_figure_on_the_demo_stage() {
    let job = small_job();
    let (model, across) = scan_map(&job);
    let before = test(&job, None, across);
    let after = test(&job, Some(&model), across);
    let (b, a) = (before.figures, after.figures);
    eprintln!("before {b:?}\nafter  {a:?}");
    // The demo stage's backlash and screw error: several um before.
    assert!(b.a > 5.0 && b.b > 2.0, "{b:?}");
    // The map takes out the systematic part (measured: A 12.2 -> 1.2 um, B 8.0 -> 0.6,
    // E 11.9 -> 1.0): A, B and E to a fifth at most; R falls with B (it holds |B_i|).
    assert!(a.a < 0.2 * b.a, "A {} -> {}", b.a, a.a);
    assert!(a.b < 0.2 * b.b, "B {} -> {}", b.b, a.b);
    assert!(a.e < 0.2 * b.e, "E {} -> {}", b.e, a.e);
    assert!(a.m < b.m, "M {} -> {}", b.m, a.m);
    assert!(a.r < b.r, "R {} -> {}", b.r, a.r);
}

/// The camera as it is until `capped` is set; then a lens cap (a flat grey frame, which
/// does not localize).
struct Cappable {
    inner: Box<dyn drivers::Camera>,
    capped: Arc<AtomicBool>,
}

#[async_trait::async_trait]
impl drivers::Camera for Cappable {
    fn info(&self) -> &drivers::CameraInfo {
        self.inner.info()
    }
    async fn grab(&mut self) -> Result<drivers::Frame, drivers::DriverError> {
        let mut f = self.inner.grab().await?;
        if self.capped.load(Ordering::SeqCst) {
            let n = (f.image.width * f.image.height) as usize;
            f.image.pixels = protocol::image::Pixels::Mono8(vec![128; n]);
        }
        Ok(f)
    }
}

#[test]
fn a_frame_that_does_not_localize_stops_the_cycle_with_the_runs_so_far() {
    let job = small_job();
    let mut devices = open_devices(&job).unwrap();
    let capped = Arc::new(AtomicBool::new(false));
    let inner = std::mem::replace(&mut devices.camera, Box::new(NoCamera));
    devices.camera = Box::new(Cappable {
        inner,
        capped: capped.clone(),
    });
    let spec = Iso230Spec {
        axis: 0,
        cycle: cycle(),
        across_mm: 45.0,
        still_frames: 2,
    };
    let mut taken = Vec::new();
    let r = runtime().block_on(run_iso230(
        &job,
        &mut devices,
        &spec,
        None,
        &mut |m| {
            taken.push(m.clone());
            // The lens cap goes on after one full run and 3 targets of the second.
            if taken.len() == 13 {
                capped.store(true, Ordering::SeqCst);
            }
        },
        &mut |_, _| {},
        std::future::pending(),
    ));
    match r {
        Err(Iso230Error::Measure {
            position_index,
            run,
            direction,
            ..
        }) => {
            // Run 2 going up: positions 1..3 measured, position 4 failed.
            assert_eq!(
                (position_index, run, direction),
                (4, 2, iso230::Direction::Up)
            );
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(taken.len(), 13);
    assert!(taken[..10].iter().all(|m| m.run == 1));
}

/// Stands in for the camera while it is moved into the wrapper.
struct NoCamera;

#[async_trait::async_trait]
impl drivers::Camera for NoCamera {
    fn info(&self) -> &drivers::CameraInfo {
        unreachable!("replaced before use")
    }
    async fn grab(&mut self) -> Result<drivers::Frame, drivers::DriverError> {
        unreachable!("replaced before use")
    }
}

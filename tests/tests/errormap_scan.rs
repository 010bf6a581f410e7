//! Scanning the simulated stage into an error map through the device traits (the same
//! path as `gateway map`), then checking the map against the truth, and resuming a
//! stopped scan after a new homing, from a journal file whose last line the stop tore.
//! A small camera window and a coarse plan keep the debug build fast; `gateway map` on
//! the demo runs the full plan (figures in docs/error-map.md).

use devices::open_devices;
use errormap::scan::{journal, MapBuilder, Sample, ScanPlan, ScanSpec};
use errormap::{Direction, MapModel};
use job::{CameraSpec, Job, StageSpec};
use procedure::map::{FileJournal, ScanJournal};
use protocol::errormap::Identity;
use runner::scan::{run_scan, scan_area, Reference};
use system_tests::runtime;

fn small_job() -> Job {
    let mut job = Job::demo();
    let CameraSpec::Sim { model } = &mut job.camera else {
        unreachable!("the demo job simulates its camera")
    };
    // 1.92 x 1.54 mm of board: about 4 x 3 pitches, 7 times fewer pixels to render.
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

const SPEC: ScanSpec = ScanSpec {
    grid_step_mm: 50.0,
    line_step_mm: 10.0,
    passes: 1,
};

fn id() -> Identity {
    Identity {
        machine: "sim".into(),
        controller: "sim".into(),
        board: "b".into(),
        certificate_sha256: String::new(),
        camera: "c".into(),
    }
}

/// Scan with fresh devices; `stop_after`: cancel once that many samples are in; each
/// sample goes to `file` when there is one.
fn scan(
    job: &Job,
    builder: &mut MapBuilder,
    stop_after: Option<usize>,
    extra_homings: usize,
    mut file: Option<&mut FileJournal>,
) -> (
    Result<Reference, runner::scan::ScanError>,
    ScanPlan,
    devices::Devices,
) {
    let mut devices = open_devices(job).unwrap();
    // Each homing draws a new homing error: the scan's own homing then lands elsewhere.
    for _ in 0..extra_homings {
        runtime().block_on(devices.stage.home()).unwrap();
    }
    let limits = runner::soft_limits(devices.stage.info()).unwrap();
    let (lo, hi) = scan_area(job, &limits);
    let plan = ScanPlan::new(lo, hi, SPEC).unwrap();
    let (tx, rx) = tokio::sync::watch::channel(false);
    let cancel = async move {
        let mut rx = rx;
        let _ = rx.wait_for(|c| *c).await;
    };
    let mut journal = Vec::new();
    let r = runtime().block_on(run_scan(
        job,
        &mut devices,
        &plan,
        builder,
        &mut |i, s: &Sample| {
            if let Some(f) = file.as_mut() {
                f.append(i, s)?;
            }
            journal.push(i);
            if Some(journal.len()) == stop_after {
                tx.send_replace(true);
            }
            Ok(())
        },
        &mut |_, _| {},
        cancel,
    ));
    (r, plan, devices)
}

#[test]
fn a_scanned_map_predicts_the_stage_and_a_stopped_scan_resumes_after_homing() {
    let job = small_job();
    // One scan straight through.
    let mut whole = MapBuilder::new();
    let (r, plan, mut devices) = scan(&job, &mut whole, None, 0, None);
    let reference = r.unwrap();
    let map = whole
        .finish(
            &plan,
            id(),
            1,
            "t".into(),
            [0.0; 2],
            job.board_at_machine_zero_mm,
            reference.command_mm,
        )
        .expect("complete");
    map.check().unwrap();
    let model = MapModel::new(map.clone());
    // The map against the truth at points between its nodes, each approached from below
    // (the machine was homed once; the map is relative to the reference frame).
    let rig = devices.rig.clone().unwrap();
    let z = job.board_at_machine_zero_mm;
    let (mut raw2, mut left2, n) = (0.0, 0.0, 40);
    for k in 0..n {
        let p = [
            plan.xs[0] + (k as f64 * 37.3) % (plan.xs[plan.xs.len() - 1] - plan.xs[0]),
            plan.ys[0] + (k as f64 * 23.9) % (plan.ys[plan.ys.len() - 1] - plan.ys[0]),
        ];
        runtime().block_on(async {
            for at in [[p[0] - 0.05, p[1] - 0.05], p] {
                devices
                    .stage
                    .move_to(drivers::AxisValues::xy(at[0], at[1]), 3000.0)
                    .await
                    .unwrap();
                devices.stage.wait_idle().await.unwrap();
            }
        });
        let pose = world::lock(&rig).truth();
        let truth = [
            (pose.centre_mm[0] - p[0] - z[0]) * 1000.0,
            (pose.centre_mm[1] - p[1] - z[1]) * 1000.0,
        ];
        let e = model.camera_error_um(p, Direction::FORWARD).unwrap();
        let predicted = [e[0] + reference.error_um[0], e[1] + reference.error_um[1]];
        raw2 += truth[0].powi(2) + truth[1].powi(2);
        left2 += (truth[0] - predicted[0]).powi(2) + (truth[1] - predicted[1]).powi(2);
    }
    let (raw, left) = ((raw2 / n as f64).sqrt(), (left2 / n as f64).sqrt());
    // A coarse plan (50 mm grid, 10 mm lines) cannot hold the 5 mm pitch error; it still
    // takes out most of the error.
    assert!(
        raw > 10.0 && left < 0.3 * raw,
        "rms {raw:.2} um -> {left:.2} um with the map"
    );

    // Stopped after 40 samples with its journal's last line torn (the process died as it
    // wrote it), then resumed from the journal on freshly opened (re-homed) devices: the
    // torn line is cut off and measured again, and the map is the same within the
    // measurement noise.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("scan.scan.jsonl");
    let header = journal::Header::new("demo.toml", id(), &plan);
    let mut file = FileJournal::new(path.clone());
    assert!(file.resume(&header, &plan).unwrap().is_empty());
    let mut stopped = MapBuilder::new();
    let (r, _, _) = scan(&job, &mut stopped, Some(40), 0, Some(&mut file));
    assert!(
        matches!(r, Err(runner::scan::ScanError::Cancelled)),
        "{r:?}"
    );
    assert_eq!(stopped.done(), 40);
    drop(file);
    let text = std::fs::read(&path).unwrap();
    std::fs::write(&path, &text[..text.len() - 25]).unwrap();
    let mut file = FileJournal::new(path.clone());
    let kept = file.resume(&header, &plan).unwrap();
    assert_eq!(kept.len(), 39);
    let mut resumed = MapBuilder::new();
    for (i, s) in &kept {
        resumed.record(&plan, *i, *s).unwrap();
    }
    // A different homing error on the second run: the reference frame absorbs it.
    let (r, plan2, _) = scan(&job, &mut resumed, None, 1, Some(&mut file));
    let reference2 = r.unwrap();
    assert_eq!(plan2, plan);
    let moved = (reference2.error_um[0] - reference.error_um[0])
        .hypot(reference2.error_um[1] - reference.error_um[1]);
    assert!(
        moved > 0.5,
        "the second homing moved the zero by {moved:.2} um"
    );
    let map2 = resumed
        .finish(
            &plan,
            id(),
            2,
            "t".into(),
            [0.0; 2],
            z,
            reference2.command_mm,
        )
        .expect("complete after the resume");
    // The journal holds every frame once, each line whole.
    let read = journal::read(&header, &plan, &std::fs::read(&path).unwrap()).unwrap();
    assert_eq!(
        (read.samples.len(), read.torn_bytes),
        (plan.points.len(), 0)
    );
    let worst = map
        .grid
        .nodes
        .iter()
        .zip(&map2.grid.nodes)
        .map(|(a, b)| {
            (a.forward.ex_um.mean - b.forward.ex_um.mean)
                .abs()
                .max((a.forward.ey_um.mean - b.forward.ey_um.mean).abs())
        })
        .fold(0.0, f64::max);
    assert!(worst < 0.6, "resumed map differs by up to {worst:.3} um");
}

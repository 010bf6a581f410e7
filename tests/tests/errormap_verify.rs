//! `gateway verify` through the device traits: the map's compensation checked by the
//! camera after a new homing and a re-reference, and the spot check's drift figure when
//! the stage has warmed up since the scan.

use devices::open_devices;
use errormap::{Approach, Direction, MapModel};
use job::{CameraSpec, Job, StageSpec};
use protocol::errormap::Identity;
use runner::verify::run_verify;
use system_tests::runtime;
use system_tests::truth_map::map_from_truth;

/// The demo job with a small camera window (fast in a debug build).
fn small_job(thermal: bool) -> Job {
    let mut job = Job::demo();
    let CameraSpec::Sim { model } = &mut job.camera else {
        unreachable!("the demo job simulates its camera")
    };
    model.width = 480;
    model.height = 384;
    job.localize.min_points = 6;
    let StageSpec::Sim { machine } = &mut job.stage else {
        unreachable!("the demo job is simulated")
    };
    if !thermal {
        machine.thermal = None;
    }
    job
}

fn model_of(job: &Job) -> MapModel {
    let StageSpec::Sim { machine } = &job.stage else {
        unreachable!()
    };
    // The map of the cold machine: thermal drift is what the spot check is to see.
    let mut cold = machine.clone();
    cold.thermal = None;
    let id = Identity {
        machine: "sim".into(),
        controller: "sim".into(),
        board: job.board.name.clone(),
        certificate_sha256: job.board.fingerprint_sha256(),
        camera: "sim".into(),
    };
    MapModel::new(map_from_truth(&cold, id))
}

fn points() -> Vec<([f64; 2], Direction)> {
    let d = |x, y| Direction { x, y };
    use Approach::{Forward as F, Reverse as R};
    vec![
        ([20.5, 15.25], d(F, F)),
        ([150.0, 30.0], d(R, F)),
        ([95.3, 120.7], d(F, R)),
        ([180.2, 140.1], d(R, R)),
        ([42.0, 88.8], d(F, R)),
        ([121.9, 64.4], d(R, F)),
    ]
}

#[test]
fn the_compensation_acts_the_camera_sees_the_residual_far_below_the_error() {
    let job = small_job(false);
    let model = model_of(&job);
    let mut devices = open_devices(&job).unwrap();
    let v = runtime()
        .block_on(run_verify(&job, &mut devices, &model, &points()))
        .unwrap_or_else(|(e, _)| panic!("{e}"));
    assert_eq!(v.points.len(), points().len());
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
        "verify: residual max {worst:.2} um, uncompensated max {raw:.2} um, reference shift {:?}",
        v.reference_um
    );
    assert!(raw > 10.0, "the stage's own error: {raw} um");
    assert!(worst < 1.5, "residual {worst} um");
}

#[test]
fn a_spot_check_on_a_warm_stage_reports_the_drift() {
    let job = small_job(true);
    let model = model_of(&job);
    let mut devices = open_devices(&job).unwrap();
    // Two hours of running since the (cold) scan: the screws have grown by about 2 K x
    // 11.7 um/m/K, +-1.9 um over +-80 mm from the reference point.
    world::lock(devices.rig.as_ref().unwrap())
        .machine_mut()
        .advance(7200.0);
    let v = runtime()
        .block_on(run_verify(&job, &mut devices, &model, &points()))
        .unwrap_or_else(|(e, _)| panic!("{e}"));
    let k = v.points.len() as f64;
    let mean_x = v.points.iter().map(|p| p.residual_um[0]).sum::<f64>() / k;
    let spread_x = v
        .points
        .iter()
        .map(|p| (p.residual_um[0] - mean_x).abs())
        .fold(0.0, f64::max);
    eprintln!(
        "spot check on a warm stage: mean X residual {mean_x:.2} um, spread {spread_x:.2} um"
    );
    // Thermal growth is proportional to the distance from the reference point: the
    // residuals spread along X well beyond the cold check's (about 0.5 um), which is
    // what tells the user to scan again.
    assert!(spread_x > 1.5, "spread {spread_x} um");
}

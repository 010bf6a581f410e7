//! An error map made from the simulator's truth, as a perfect scan would measure it:
//! for tests of what uses a map (the rewriter, the pass-through, exports) without the
//! minutes a camera scan takes in a debug build. The same plan as the default scan: a
//! 10 mm grid over the travel, 1 mm lines along each axis through the middle, every node
//! approached from both sides.

use job::{Job, StageSpec};
use protocol::errormap::{ErrorMap, Grid, Identity, Line, Measured, Node, Stat, SCHEMA};
use world::machine::{MachineConfig, SimMachine};
use world::rig::SimRig;

/// The demo job and its stage, thermal drift off (the map's spatial model alone).
pub fn demo_machine() -> (Job, MachineConfig) {
    let mut job = Job::demo();
    let StageSpec::Sim { machine } = &mut job.stage else {
        unreachable!("the demo job simulates its stage")
    };
    machine.thermal = None;
    let machine = machine.clone();
    (job, machine)
}

/// The identity of the demo job's simulated machine (what a scan of it records).
pub fn sim_identity(job: &Job) -> Identity {
    Identity {
        machine: "sim".into(),
        controller: "sim".into(),
        board: job.board.name.clone(),
        certificate_sha256: job.board.fingerprint_sha256(),
        camera: "sim".into(),
    }
}

fn stat(mean: f64) -> Stat {
    Stat {
        mean,
        sd: 0.0,
        n: 1,
    }
}

fn steps(from: f64, to: f64, step: f64) -> Vec<f64> {
    let n = ((to - from) / step).round() as usize;
    (0..=n)
        .map(|k| from + (to - from) * k as f64 / n as f64)
        .collect()
}

/// The map of `machine` (its first homing, as a fresh machine with the same seed has
/// it), identity as given.
/// The GRBL demo job (`config/gateway/grbl-demo.toml`, its controller emulated) and a map
/// of its simulated stage from the truth, with the identity the gateway reads of it: the
/// map a scan of that machine would make, for the pass-through's tests.
pub async fn grbl_demo_map() -> (std::path::PathBuf, ErrorMap) {
    let path = crate::config_dir().join("gateway/grbl-demo.toml");
    let job = Job::load(&path).expect("config/gateway/grbl-demo.toml loads");
    let StageSpec::Grbl {
        link: job::GrblLink::Emulate(machine),
        ..
    } = &job.stage
    else {
        unreachable!("the GRBL demo job emulates its controller")
    };
    let here = procedure::identity_of_job(&job)
        .await
        .expect("its identity");
    (path.clone(), map_from_truth(machine, here))
}

/// The map a benchmark's scan of the simulated machine made (`builder` over `plan`, its
/// reference frame commanded at `reference_mm`), named as a simulated machine's: the
/// `controller` the scan ran through, version 1. Panics when a point has no sample.
pub fn finish_sim_map(
    builder: &errormap::scan::MapBuilder,
    plan: &errormap::scan::ScanPlan,
    job: &Job,
    controller: &str,
    reference_mm: [f64; 2],
) -> ErrorMap {
    let identity = Identity {
        machine: "sim".into(),
        controller: controller.into(),
        board: job.board.name.clone(),
        certificate_sha256: job.board.fingerprint_sha256(),
        camera: "sim".into(),
    };
    builder
        .finish(
            plan,
            identity,
            1,
            "now".into(),
            [0.0; 2],
            job.board_at_machine_zero_mm,
            reference_mm,
        )
        .expect("every point of the plan has a sample")
}

pub fn map_from_truth(machine: &MachineConfig, identity: Identity) -> ErrorMap {
    let d = crate::config_dir();
    let camera = world::camera::CameraModel::load(&d.join("cameras/mono-1.3mp.toml"))
        .expect("config/cameras/mono-1.3mp.toml loads");
    let board = protocol::Board::load(&d.join("boards/dot-grid-0.5mm.toml"))
        .expect("config/boards/dot-grid-0.5mm.toml loads");
    let zero = machine.machine.board_at_home_mm;
    let mut rig = SimRig::new(SimMachine::new(machine.clone()), board, camera);
    rig.machine_mut().home();
    let (tx, ty) = (machine.axes.x.travel_mm, machine.axes.y.travel_mm);
    let approach = 0.05;
    let mut visit = |p: [f64; 2], forward: bool| {
        let side = if forward { -approach } else { approach };
        let from = [(p[0] + side).clamp(0.0, tx), (p[1] + side).clamp(0.0, ty)];
        for q in [from, p] {
            rig.machine_mut()
                .start_move(q, 3000.0)
                .expect("inside the travel");
            rig.machine_mut().finish_motion();
        }
        let pose = rig.truth();
        Measured {
            ex_um: stat((pose.centre_mm[0] - p[0] - zero[0]) * 1000.0),
            ey_um: stat((pose.centre_mm[1] - p[1] - zero[1]) * 1000.0),
            yaw_urad: stat(pose.rotation_rad * 1e6),
        }
    };
    let mut node = |x: f64, y: f64| Node {
        forward: visit([x, y], true),
        reverse: visit([x, y], false),
    };
    let (xs, ys) = (steps(0.0, tx, 10.0), steps(0.0, ty, 10.0));
    let nodes = ys
        .iter()
        .flat_map(|&y| xs.iter().map(move |&x| (x, y)))
        .collect::<Vec<_>>()
        .into_iter()
        .map(|(x, y)| node(x, y))
        .collect();
    let (xline, yline) = (steps(0.0, tx, 1.0), steps(0.0, ty, 1.0));
    let (at_y, at_x) = (ty / 2.0, tx / 2.0);
    let x_nodes = xline.iter().map(|&x| node(x, at_y)).collect();
    let y_nodes = yline.iter().map(|&y| node(at_x, y)).collect();
    let map = ErrorMap {
        schema: SCHEMA.into(),
        version: 1,
        created: "2026-11-23T00:00:00Z".into(),
        identity,
        // The operator gives the tool's offset from the camera, as to `gateway map`.
        tool_offset_mm: machine.machine.tool_offset_mm,
        board_at_machine_zero_mm: machine.machine.board_at_home_mm,
        // The middle, where a scan takes its reference frame.
        reference_mm: [at_x, at_y],
        grid: Grid { xs, ys, nodes },
        x_lines: vec![Line {
            at_mm: at_y,
            positions: xline,
            nodes: x_nodes,
        }],
        y_lines: vec![Line {
            at_mm: at_x,
            positions: yline,
            nodes: y_nodes,
        }],
        uncertainty_um: 0.0,
    };
    map.check().expect("a map from the truth is well formed");
    map
}

/// The largest and the rms of errors (um) as a check adds them, for the accuracy
/// examples' reports.
#[derive(Debug, Default)]
pub struct ErrorStat {
    pub max: f64,
    sum2: f64,
    pub n: usize,
}

impl ErrorStat {
    pub fn add(&mut self, e: f64) {
        self.max = self.max.max(e);
        self.sum2 += e * e;
        self.n += 1;
    }

    pub fn rms(&self) -> f64 {
        (self.sum2 / self.n.max(1) as f64).sqrt()
    }

    /// `max 0.825 um, rms 0.340 um`.
    pub fn text(&self) -> String {
        format!("max {:.3} um, rms {:.3} um", self.max, self.rms())
    }
}

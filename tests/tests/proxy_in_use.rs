//! The pass-through re-referencing a warming machine in use (issue 39): the GRBL
//! emulator on the demo stage with its thermal drift on (the screws grow with time since
//! power-on), a map of the cold machine, and a sender of our own. After the sender's
//! homing the gateway measures the reference and each axis's scale; an hour of dwell
//! later the screws have grown, and the map's compensation misses at the far end of the
//! travel. While the tool is down (machine Z below the clear height) the due
//! re-reference waits and says so; once the sender raises the tool it runs by itself
//! (XY rapids only), and the same point is hit again within a fraction of the miss. The
//! truth is read only to check, never by what compensates.
//!
//! The emulator's clock is unconstrained: a dwell lets the machine's hour pass at once,
//! and the test waits on the gateway's answers, never on the wall clock.

use devices::spawn_grbl_emulator;
use drivers::open_grbl_line as open_controller;
use errormap::MapModel;
use job::{CameraSpec, Job, StageSpec};
use procedure::proxy::{map_rereference, CameraFrames, SharedMap};
use proxy::{AfterHoming, Ending, InUse, Proxy, SenderPort};
use rewrite::{Options, Rewriter};
use std::cell::RefCell;
use std::path::Path;
use std::time::Duration;
use system_tests::runtime;
use system_tests::truth_map::{map_from_truth, sim_identity};
use world::{lock, Clock, SharedRig};

/// Machine Z at or above which the tool is clear (the sender lowers the tool to Z -20).
const CLEAR_Z_MM: f64 = -5.0;

/// The far end of the map from the home switches, where the screws' growth shows most.
const FAR: [f64; 2] = [180.0, 130.0];

/// A sender of our own on the gateway's port: a line and its answer, and the gateway's
/// messages as they come.
struct Sender {
    port: tokio_serial::SerialStream,
    got: String,
}

impl Sender {
    fn open(link: &Path) -> Sender {
        use tokio_serial::SerialPortBuilderExt;
        let port = tokio_serial::new(link.to_string_lossy(), 115_200)
            .open_native_async()
            .expect("open the gateway's port");
        Sender {
            port,
            got: String::new(),
        }
    }

    /// Reads until `done` holds for what came since `from`.
    async fn read_until(&mut self, from: usize, done: impl Fn(&str) -> bool) {
        use tokio::io::AsyncReadExt;
        let mut buf = [0u8; 1024];
        while !done(&self.got[from..]) {
            let k = self.port.read(&mut buf).await.unwrap();
            assert!(k > 0, "the gateway closed the port");
            self.got
                .push_str(&String::from_utf8_lossy(&buf[..k]).replace('\r', ""));
        }
    }

    /// Sends `line` and waits for its `ok` (an `error:` fails the test).
    async fn send(&mut self, line: &str) {
        use tokio::io::AsyncWriteExt;
        let from = self.got.len();
        self.port
            .write_all(format!("{line}\n").as_bytes())
            .await
            .unwrap();
        self.read_until(from, |s| {
            s.lines().any(|l| l == "ok" || l.starts_with("error:"))
        })
        .await;
        let answer = &self.got[from..];
        assert!(!answer.contains("error:"), "{line}: {answer}");
    }

    /// Waits for a line of the gateway's containing `text`, after `from`.
    async fn wait_for(&mut self, from: usize, text: &str) {
        self.read_until(from, |s| s.contains(text)).await;
    }

    /// To `p` from below on both axes at the tool's height, then a sync (`G4 P0` is
    /// answered once the planner is empty).
    async fn visit(&mut self, p: [f64; 2]) {
        self.send(&format!("G1 X{:.3} Y{:.3} F3000", p[0] - 1.0, p[1] - 1.0))
            .await;
        self.send(&format!("G1 X{:.3} Y{:.3}", p[0], p[1])).await;
        self.send("G4 P0").await;
    }
}

/// The camera's true error where the tool stands at nominal `p`, um.
fn true_error_um(rig: &SharedRig, job: &Job, p: [f64; 2]) -> f64 {
    let pose = lock(rig).truth();
    let zero = job.board_at_machine_zero_mm;
    let e = [
        pose.centre_mm[0] - p[0] - zero[0],
        pose.centre_mm[1] - p[1] - zero[1],
    ];
    e[0].hypot(e[1]) * 1000.0
}

#[test]
fn in_use_the_pass_through_re_references_the_warming_machine_once_the_tool_is_clear() {
    let mut job = Job::demo();
    let CameraSpec::Sim { model } = &mut job.camera else {
        unreachable!("the demo job simulates its camera")
    };
    model.width = 600;
    model.height = 480;
    job.localize.min_points = 8;
    let StageSpec::Sim { machine } = &job.stage else {
        unreachable!("the demo job is simulated")
    };
    let machine = machine.clone();
    assert!(machine.thermal.is_some(), "the demo stage warms");
    // The map of the machine cold, as a scan right after power-on would see it.
    let mut cold = machine.clone();
    cold.thermal = None;
    let map = map_from_truth(&cold, sim_identity(&job));
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("ttyINUSE");
    let rt = runtime();
    rt.block_on(async {
        let (emulator, rig) = spawn_grbl_emulator(&job, &machine, Clock::Unconstrained).unwrap();
        let (mut controller, _) = open_controller(emulator.path(), 115_200, Duration::ZERO)
            .await
            .unwrap();
        let mut sender_port = SenderPort::create(Some(&link)).unwrap();
        let shared = SharedMap::new(MapModel::new(map.clone()));
        let previous = RefCell::new(None);
        let records = RefCell::new(Vec::new());
        let mut proxy = Proxy::new(Rewriter::new(&shared, Options::default()).unwrap(), &shared);
        // Due at once whenever the sender is quiet: the tool's height alone decides here.
        proxy.after_homing(AfterHoming::Reference(map_rereference(
            &map,
            &shared,
            job.policy.approach_mm,
            procedure::reference::shift_bound_um(&job, errormap::reference::MAX_SHIFT_UM),
            Some(InUse {
                every_s: 0.0,
                clear_z_mm: CLEAR_Z_MM,
                first_due_s: 0.0,
            }),
            &previous,
            |record, _| {
                records.borrow_mut().push(record.clone());
                Ok(())
            },
        )));
        proxy.start();
        let mut frames = CameraFrames {
            camera: Box::new(drivers::sim::SimCamera::new(rig.clone())),
            job: &job,
        };
        let session = proxy::serve_with_camera(
            &mut proxy,
            &mut sender_port,
            &mut controller,
            std::future::pending(),
            Some(&mut frames),
        );
        let sender = async {
            let mut s = Sender::open(&link);
            s.send("$H").await;
            s.wait_for(0, "referenced: ").await;
            // The tool down, an hour of the machine warming, then the far point.
            s.send("G21 G90 G0 Z-20").await;
            s.send("G4 P3600").await;
            s.visit(FAR).await;
            let stale = true_error_um(&rig, &job, FAR);
            let from = s.got.len();
            s.wait_for(
                from,
                "it waits for the tool at or above machine Z -5.000 (now -20.000)",
            )
            .await;
            let homed_and_stale = records.borrow().len();
            // The tool up: the due re-reference runs by itself, then the tool goes back
            // down and to the same point.
            let from = s.got.len();
            s.send("G0 Z0").await;
            s.wait_for(from, "referenced: ").await;
            s.send("G0 Z-20").await;
            s.visit(FAR).await;
            let fresh = true_error_um(&rig, &job, FAR);
            (s.got, stale, fresh, homed_and_stale)
        };
        let (ending, (got, stale, fresh, homed_and_stale)) = tokio::join!(session, sender);
        assert!(matches!(ending, Ending::SenderLeft(_)), "{ending:?}");
        let records = records.borrow();
        eprintln!(
            "in use on the warming demo stage: at X{} Y{} the tool missed by {stale:.3} um an \
             hour after the homing's reference, {fresh:.3} um after the re-reference in use \
             (scale measured: {:?} ppm)",
            FAR[0],
            FAR[1],
            records.last().and_then(|r| r.scale.as_ref()).map(|s| s.ppm)
        );
        // The homing's reference, and none while the tool was down.
        assert_eq!(homed_and_stale, 1, "{got}");
        assert!(records.len() >= 2, "{got}");
        for line in got.lines().filter(|l| l.contains("re-referencing in use")) {
            let z: f64 = line
                .split("at Z ")
                .nth(1)
                .and_then(|r| r.split_whitespace().next())
                .and_then(|z| z.parse().ok())
                .unwrap_or_else(|| panic!("{line}"));
            assert!(z >= CLEAR_Z_MM, "{line}");
        }
        let scale = records.last().unwrap().scale.as_ref().expect("a scale");
        assert!(scale.ppm.iter().all(|p| *p > 5.0), "{scale:?}");
        assert!(stale > 1.0, "the warming shows: {stale} um");
        // What is left is the map's own residual there (about 0.4 um before any warming)
        // and the scale's noise.
        assert!(fresh < 1.0 && fresh < stale / 4.0, "{stale} -> {fresh} um");
    });
}

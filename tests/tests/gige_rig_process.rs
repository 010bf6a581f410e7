//! The whole loop over real links against a separate emulator process: `emulators gige
//! --stage grbl` hosts the GRBL controller (on a pseudo-terminal) and the GigE Vision
//! camera (on a loopback UDP port) on ONE simulated machine; the gateway opens a job
//! naming the port and the camera address, as it would a real machine, and compensates.
//! There is no truth on this side of the links: the test checks convergence and the
//! gateway's own estimate.

use gateway::camera_link::CameraLink;
use gateway::config::Job;
use gateway::run::{open_devices_async, run_job};
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The `emulators` binary next to this test's executable, built if missing.
fn emulators_binary() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let dir = exe.parent().and_then(Path::parent).unwrap().to_path_buf();
    let bin = dir.join("emulators");
    if !bin.exists() {
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
        let status = Command::new(cargo)
            .args(["build", "-p", "emulators", "--bin", "emulators"])
            .current_dir(workspace())
            .status()
            .expect("cargo build");
        assert!(status.success(), "building the emulators binary failed");
    }
    bin
}

struct Kill(Child);
impl Drop for Kill {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[test]
fn gateway_compensates_over_grbl_and_gige_against_an_emulator_process() {
    let mut child = Command::new(emulators_binary())
        .args([
            "gige",
            "--bind",
            "127.0.0.1:0",
            "--stage",
            "grbl",
            "--time-scale",
            "unconstrained",
        ])
        .current_dir(workspace())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("spawn emulators");
    let out = child.stdout.take().unwrap();
    let child = Kill(child);
    // The process prints its addresses, then serves: read lines until both are known
    // (the read ends at EOF if the process dies).
    let (mut gige, mut grbl) = (None, None);
    for line in BufReader::new(out).lines() {
        let line = line.unwrap();
        if let Some(a) = line.strip_prefix("gige: ") {
            gige = Some(a.trim().to_string());
        }
        if let Some(p) = line.strip_prefix("grbl: ") {
            grbl = Some(p.trim().to_string());
        }
        if gige.is_some() && grbl.is_some() {
            break;
        }
    }
    let (gige, grbl) = (
        gige.expect("gige address printed"),
        grbl.expect("grbl port printed"),
    );
    let dir = workspace().join("config/gateway");
    let text = std::fs::read_to_string(dir.join("gige-demo.toml"))
        .unwrap()
        .replace(
            "emulate = \"../machines/c5-stage.toml\"",
            &format!("port = \"{grbl}\""),
        )
        .replace(
            "model = \"../cameras/mono-1.3mp.toml\"",
            &format!("camera = \"{gige}\""),
        )
        .replace("nx = 6, ny = 5", "nx = 2, ny = 2");
    let doc = protocol::config::ConfigDoc::from_text("rig-process.toml", &text, &dir);
    let job = Job::from_doc(&doc).unwrap();
    assert!(matches!(
        job.camera_link,
        CameraLink::Gige {
            camera: Some(_),
            ..
        }
    ));
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let report = rt.block_on(async {
        let mut devices = tokio::time::timeout(Duration::from_secs(30), open_devices_async(&job))
            .await
            .expect("devices open in time")
            .unwrap();
        assert!(devices.rig.is_none(), "no in-process machine on this side");
        assert_eq!(devices.camera.info().model, "XYGateway SimMono");
        run_job(&job, &mut devices, &mut |_, _| {}).await
    });
    drop(child);
    assert!(report.error.is_none(), "{:?}", report.error);
    assert_eq!(report.targets, 4);
    assert_eq!(report.converged, report.targets, "{}", report.to_text());
    assert!(report.before_um.is_none(), "no truth over real links");
}

//! The whole loop over real links against a separate emulator process: `emulators gige
//! --stage grbl|modbus|canopen` hosts the GRBL controller (on a pseudo-terminal), Modbus
//! drives (on TCP) or CiA 402 drives (behind SLCAN on a pseudo-terminal) and the GigE
//! Vision camera (on a loopback UDP port) on ONE simulated machine; the gateway opens a
//! job naming the port and the camera address, as it would a real machine, and
//! compensates. There is no truth on this side of the links: the test checks convergence
//! and the gateway's own estimate.

use devices::open_devices_async;
use job::{CameraSpec, Job};
use runner::run_job;
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;
use system_tests::{emulators_binary, workspace, Kill};

/// Starts `emulators gige --bind 127.0.0.1:0 --stage STAGE` and returns it with the
/// camera address and the stage's port or address (as printed).
fn rig_process(stage: &str, stage_prefix: &str) -> (Kill, String, String) {
    let mut child = Command::new(emulators_binary())
        .args([
            "gige",
            "--bind",
            "127.0.0.1:0",
            "--stage",
            stage,
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
    let (mut gige, mut port) = (None, None);
    let mut lines = BufReader::new(out).lines();
    while gige.is_none() || port.is_none() {
        let Some(line) = lines.next() else { break };
        let line = line.unwrap();
        if let Some(a) = line.strip_prefix("gige: ") {
            gige = Some(a.trim().to_string());
        }
        if let Some(p) = line.strip_prefix(stage_prefix) {
            port = Some(p.split_whitespace().next().unwrap().to_string());
        }
    }
    (
        child,
        gige.expect("gige address printed"),
        port.expect("stage port printed"),
    )
}

fn run(text: &str) -> compensation::report::Report {
    let dir = workspace().join("config/gateway");
    let doc = protocol::config::ConfigDoc::from_text("rig-process.toml", text, &dir);
    let job = Job::from_doc(&doc).unwrap();
    assert!(matches!(job.camera, CameraSpec::Gige { .. }));
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let mut devices = tokio::time::timeout(Duration::from_secs(30), open_devices_async(&job))
            .await
            .expect("devices open in time")
            .unwrap();
        assert!(devices.rig.is_none(), "no in-process machine on this side");
        assert_eq!(devices.camera.info().model, "XYGateway SimMono");
        run_job(&job, &mut devices, &mut |_, _| {}).await
    })
}

fn demo_text(gige: &str) -> String {
    std::fs::read_to_string(workspace().join("config/gateway/gige-demo.toml"))
        .unwrap()
        .replace(
            "model = \"../cameras/mono-1.3mp.toml\"",
            &format!("camera = \"{gige}\""),
        )
        .replace("nx = 6, ny = 5", "nx = 2, ny = 2")
}

fn check(report: &compensation::report::Report) {
    assert!(report.error.is_none(), "{:?}", report.error);
    assert_eq!(report.targets, 4);
    assert_eq!(report.converged, report.targets, "{}", report.to_text());
    assert!(report.before_um.is_none(), "no truth over real links");
}

#[test]
fn gateway_compensates_over_grbl_and_gige_against_an_emulator_process() {
    let (child, gige, grbl) = rig_process("grbl", "grbl: ");
    let text = demo_text(&gige).replace(
        "emulate = \"../machines/c5-stage.toml\"",
        &format!("port = \"{grbl}\""),
    );
    let report = run(&text);
    drop(child);
    check(&report);
}

#[test]
fn gateway_compensates_over_modbus_tcp_and_gige_against_an_emulator_process() {
    let (child, gige, tcp) = rig_process("modbus", "modbus tcp: ");
    let stage = format!(
        r#"[stage]
driver = "modbus"
profile = "../drives/generic.toml"
tcp = "{tcp}"
axes = [
    {{ axis = "x", unit = 1, min_mm = 0.0, max_mm = 200.0 }},
    {{ axis = "y", unit = 2, min_mm = 0.0, max_mm = 150.0 }},
]
"#
    );
    let text = demo_text(&gige).replace(
        "[stage]\ndriver = \"grbl\"\nemulate = \"../machines/c5-stage.toml\"\n",
        &stage,
    );
    assert!(text.contains("driver = \"modbus\""), "{text}");
    let report = run(&text);
    drop(child);
    check(&report);
}

#[test]
fn gateway_compensates_over_canopen_slcan_and_gige_against_an_emulator_process() {
    let (child, gige, slcan) = rig_process("canopen", "slcan: ");
    let stage = format!(
        r#"[stage]
driver = "canopen"
slcan = "{slcan}"
bitrate = 1000000
axes = [
  {{ axis = "x", node = 1, counts_per_mm = 2000.0, min_mm = 0.0, max_mm = 200.0 }},
  {{ axis = "y", node = 2, counts_per_mm = 2000.0, min_mm = 0.0, max_mm = 150.0 }},
]
"#
    );
    let text = demo_text(&gige).replace(
        "[stage]\ndriver = \"grbl\"\nemulate = \"../machines/c5-stage.toml\"\n",
        &stage,
    );
    assert!(text.contains("driver = \"canopen\""), "{text}");
    let report = run(&text);
    drop(child);
    check(&report);
}

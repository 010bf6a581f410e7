//! GigE Vision interop with Aravis 0.8 (Debian packages aravis-tools, aravis-tools-cli):
//! Aravis's `arv-tool-0.8` discovers our emulator and reads its features,
//! `arv-camera-test-0.8` streams complete frames from it, and our driver grabs frames
//! from Aravis's own `arv-fake-gv-camera-0.8`. Aravis talks to GVCP port 3956 only, so
//! each test runs in a private network namespace whose 127.0.0.1:3956 nothing else on
//! the machine can hold (a stand-alone emulator, another test process); where none can
//! be made, it says so and takes a lock shared across processes instead
//! (`system_tests::netns`). A missing tool is reported and the test skips; it never
//! fails for absence.

use crate::gige_common;

use drivers::Camera;
use emulators::gige::{GigeCameraServer, GigeConfig, GigeServerOptions};
use gige_common::*;
use std::process::{Command, Stdio};
use std::sync::Mutex;
use std::time::Duration;
use system_tests::netns::on_private_loopback;

/// GVCP, the only port Aravis talks to.
const GVCP: u16 = 3956;

/// One test at a time in this binary, as before the namespaces. Not for the port (each
/// test has its own), but for timing: with two of these tests at once on a 2-core
/// machine, Aravis timed out a frame of the packet-resend test in 4 of 8 runs (0 of 8
/// one at a time, 0 of 6 beside two busy loops).
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

/// Runs the test `name` (whole body) where 127.0.0.1:3956 is its own: in a private
/// network namespace, or else under a lock shared by all test processes (see
/// `system_tests::netns`).
fn on_own_gvcp_port(name: &str, body: impl FnOnce()) {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|p| p.into_inner());
    // The harness's full name: this module's path in the test binary, then the test.
    let module = module_path!().split_once("::").map_or("", |(_, m)| m);
    on_private_loopback(&format!("{module}::{name}"), GVCP, body)
}

/// An Aravis tool this test drives; a missing one fails the test naming the install
/// step (a test never passes without having run).
fn require_tool(name: &str) {
    let found = Command::new("sh")
        .args(["-c", &format!("command -v {name}")])
        .stdout(Stdio::null())
        .status()
        .map(|s| s.success())
        .unwrap_or(false);
    assert!(
        found,
        "a peer of this test is missing (install every test peer with tests/install-peers.sh, \
         README: Set-up): `{name}` is not installed (Debian: aravis-tools aravis-tools-cli)"
    );
}

async fn emulator_on_3956(rig: &SharedRig) -> GigeCameraServer {
    lossy_emulator_on_3956(rig, None).await
}

async fn lossy_emulator_on_3956(rig: &SharedRig, drop_every: Option<u32>) -> GigeCameraServer {
    emulator_on_3956_with(
        rig,
        GigeConfig {
            drop_every,
            ..Default::default()
        },
    )
    .await
}

async fn emulator_on_3956_with(rig: &SharedRig, config: GigeConfig) -> GigeCameraServer {
    GigeCameraServer::spawn(
        rig.clone(),
        GigeServerOptions {
            bind: "127.0.0.1:3956".parse().unwrap(),
            broadcast: true,
            config: GigeConfig {
                serial: "INTEROP1".into(),
                frame_rate_hz: 20.0,
                ..config
            },
        },
    )
    .await
    .expect("127.0.0.1:3956 is free (another GigE Vision device or emulator is running?)")
}

/// Runs a command with a bounded wait; returns (status ok, stdout + stderr).
fn run(cmd: &mut Command, limit: Duration) -> (bool, String) {
    let child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn");
    let pid = child.id();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(child.wait_with_output());
    });
    match rx.recv_timeout(limit) {
        Ok(Ok(o)) => (
            o.status.success(),
            String::from_utf8_lossy(&o.stdout).to_string() + &String::from_utf8_lossy(&o.stderr),
        ),
        _ => {
            let _ = Command::new("kill").arg(pid.to_string()).status();
            panic!("{cmd:?} did not finish within {limit:?}");
        }
    }
}

#[test]
fn arv_tool_discovers_our_emulator_and_reads_its_features() {
    on_own_gvcp_port(
        "arv_tool_discovers_our_emulator_and_reads_its_features",
        || {
            require_tool("arv-tool-0.8");
            let rt = runtime();
            let rig = rig(Some((320, 240)), None);
            let _emu = rt.block_on(emulator_on_3956(&rig));
            // Discovery (broadcast on every interface, loopback included).
            let (ok, out) = run(&mut Command::new("arv-tool-0.8"), Duration::from_secs(20));
            assert!(ok, "{out}");
            assert!(out.contains("XYGateway-SimMono-INTEROP1"), "{out}");
            // By address (no discovery): features through our GenICam XML.
            let (ok, out) = run(
                Command::new("arv-tool-0.8").args([
                    "-a",
                    "127.0.0.1",
                    "control",
                    "Width",
                    "Height",
                    "PixelFormat",
                    "PayloadSize",
                    "DeviceVendorName",
                    "TriggerMode",
                ]),
                Duration::from_secs(20),
            );
            assert!(ok, "{out}");
            for want in [
                "Width = 320",
                "Height = 240",
                "PixelFormat = Mono8",
                "PayloadSize = 76800",
                "DeviceVendorName = XYGateway",
                "TriggerMode = Off",
            ] {
                assert!(out.contains(want), "`{want}` missing in:\n{out}");
            }
        },
    );
}

/// Runs `arv-camera-test-0.8 -n 127.0.0.1` against our emulator until it has streamed 5
/// frames, stops it with SIGINT and returns its stream statistics.
fn arv_camera_test(drop_every: Option<u32>) -> (String, impl Fn(&str) -> u64) {
    require_tool("arv-camera-test-0.8");
    require_tool("stdbuf");
    let rt = runtime();
    let rig = rig(Some((320, 240)), None);
    let emu = rt.block_on(lossy_emulator_on_3956(&rig, drop_every));
    let child = Command::new("stdbuf")
        .args(["-o0", "arv-camera-test-0.8", "-n", "127.0.0.1"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn arv-camera-test-0.8");
    let pid = child.id();
    // Let it receive a few frames (the emulator counts what it streamed), then stop it
    // the way a user does (SIGINT), which makes it print its stream statistics.
    let mut frames = emu.frames_watch();
    let got = rt.block_on(async {
        tokio::time::timeout(Duration::from_secs(30), frames.wait_for(|n| *n >= 5))
            .await
            .is_ok()
    });
    let _ = Command::new("kill")
        .args(["-INT", &pid.to_string()])
        .status();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(child.wait_with_output());
    });
    let out = match rx.recv_timeout(Duration::from_secs(20)) {
        Ok(Ok(o)) => {
            String::from_utf8_lossy(&o.stdout).to_string() + &String::from_utf8_lossy(&o.stderr)
        }
        _ => {
            let _ = Command::new("kill").arg(pid.to_string()).status();
            panic!("arv-camera-test-0.8 did not stop after SIGINT");
        }
    };
    assert!(
        got,
        "the emulator streamed fewer than 5 frames to Aravis:\n{out}"
    );
    let text = out.clone();
    let stat = move |key: &str| -> u64 {
        out.lines()
            .find(|l| l.trim_start().starts_with(key))
            .and_then(|l| l.split('=').nth(1))
            .and_then(|v| v.trim().parse().ok())
            .unwrap_or_else(|| panic!("`{key}` missing in:\n{out}"))
    };
    (text, stat)
}

#[test]
fn arv_camera_test_streams_complete_frames_from_our_emulator() {
    on_own_gvcp_port(
        "arv_camera_test_streams_complete_frames_from_our_emulator",
        || {
            let (out, stat) = arv_camera_test(None);
            assert!(stat("n_completed_buffers") >= 3, "{out}");
            assert_eq!(stat("n_failures"), 0, "{out}");
            assert_eq!(stat("n_missing_packets"), 0, "{out}");
            assert_eq!(stat("n_size_mismatch_errors"), 0, "{out}");
            assert!(out.contains("image width            = 320"), "{out}");
        },
    );
}

#[test]
fn aravis_recovers_lost_packets_from_our_emulator_by_packetresend() {
    on_own_gvcp_port(
        "aravis_recovers_lost_packets_from_our_emulator_by_packetresend",
        || {
            let (out, stat) = arv_camera_test(Some(10));
            assert!(stat("n_completed_buffers") >= 3, "{out}");
            assert_eq!(stat("n_failures"), 0, "{out}");
            assert!(stat("n_resend_requests") > 0, "{out}");
            // Requests still in flight when the tool is stopped may go unanswered.
            assert!(stat("n_resent_packets") > 0, "{out}");
        },
    );
}

#[test]
fn our_driver_grabs_from_arv_fake_gv_camera() {
    on_own_gvcp_port("our_driver_grabs_from_arv_fake_gv_camera", || {
        require_tool("arv-fake-gv-camera-0.8");
        let mut fake = Command::new("arv-fake-gv-camera-0.8")
            .args(["-i", "127.0.0.1"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("spawn arv-fake-gv-camera-0.8");
        let rt = runtime();
        let r = rt.block_on(async {
            // The fake camera needs a moment to bind: open retries on "no answer" only,
            // each attempt bounded by the GVCP timeouts.
            let mut last = None;
            for _ in 0..10 {
                match drivers::gige::GigeCamera::open("127.0.0.1", options()).await {
                    Ok(c) => return Ok(c),
                    Err(e @ drivers::DriverError::Timeout { .. }) => last = Some(e),
                    Err(e) => return Err(e),
                }
            }
            Err(last.expect("attempted"))
        });
        let result = (|| {
            let mut cam = r.map_err(|e| format!("open: {e}"))?;
            let info = cam.info().clone();
            if info.bit_depth != 8 || info.width == 0 {
                return Err(format!("unexpected camera {info:?}"));
            }
            let mut seqs = Vec::new();
            for _ in 0..3 {
                let f = rt.block_on(cam.grab()).map_err(|e| format!("grab: {e}"))?;
                if (f.image.width, f.image.height) != (info.width, info.height) {
                    return Err(format!("frame {}x{}", f.image.width, f.image.height));
                }
                let protocol::Pixels::Mono8(p) = &f.image.pixels else {
                    return Err("not Mono8".into());
                };
                // The fake camera draws a moving diagonal pattern: not a constant frame.
                if p.iter().all(|v| *v == p[0]) {
                    return Err("constant frame".into());
                }
                seqs.push(f.meta.sequence);
            }
            Ok((info, seqs))
        })();
        let _ = fake.kill();
        let _ = fake.wait();
        let (info, seqs) = result.unwrap();
        assert_eq!(info.model, "Aravis Fake");
        assert_eq!(seqs, vec![0, 1, 2]);
    });
}

#[test]
fn our_driver_finds_our_emulator_by_device_name() {
    on_own_gvcp_port("our_driver_finds_our_emulator_by_device_name", || {
        // No Aravis here: discovery is ours on both sides, but it needs port 3956.
        let rt = runtime();
        let rig = rig(Some((160, 120)), None);
        rt.block_on(async {
            let _emu = emulator_on_3956(&rig).await;
            let mut cam = drivers::gige::GigeCamera::open("XYGateway-SimMono-INTEROP1", options())
                .await
                .unwrap();
            assert_eq!(cam.info().serial, "INTEROP1");
            cam.grab().await.unwrap();
            drop(cam);
            let e = drivers::gige::GigeCamera::open("NoSuch-Camera-0", options())
                .await
                .err()
                .expect("unknown name");
            let m = e.to_string();
            assert!(
                m.contains("no GigE Vision camera named `NoSuch-Camera-0`")
                    && m.contains("XYGateway-SimMono-INTEROP1 at 127.0.0.1:3956"),
                "{m}"
            );
        });
    });
}

#[test]
fn our_driver_refuses_incomplete_frames_from_a_lossy_arv_fake_gv_camera() {
    on_own_gvcp_port(
        "our_driver_refuses_incomplete_frames_from_a_lossy_arv_fake_gv_camera",
        || {
            require_tool("arv-fake-gv-camera-0.8");
            // 10 % of the stream packets lost; the fake camera does not offer PACKETRESEND, so
            // a 512 x 512 frame (180 packets of 1464 bytes) cannot arrive whole (P < 1e-8).
            let mut fake = Command::new("arv-fake-gv-camera-0.8")
                .args(["-i", "127.0.0.1", "-r", "100"])
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .expect("spawn arv-fake-gv-camera-0.8");
            let rt = runtime();
            let errors = rt.block_on(async {
                let mut opts = options();
                opts.packet_size = 1500;
                opts.packet_timeout = Duration::from_millis(50);
                let mut cam = None;
                for _ in 0..10 {
                    match drivers::gige::GigeCamera::open("127.0.0.1", opts.clone()).await {
                        Ok(c) => {
                            cam = Some(c);
                            break;
                        }
                        Err(drivers::DriverError::Timeout { .. }) => {}
                        Err(e) => return Err(format!("open: {e}")),
                    }
                }
                let mut cam = cam.ok_or("the fake camera never answered")?;
                let mut errors = Vec::new();
                for _ in 0..3 {
                    match cam.grab().await {
                        Ok(_) => return Err("a frame arrived whole through 10 % loss".to_string()),
                        Err(e) => errors.push(e.to_string()),
                    }
                }
                Ok(errors)
            });
            let _ = fake.kill();
            let _ = fake.wait();
            for m in errors.unwrap() {
                assert!(
                    m.contains("incomplete frame")
                        && m.contains("the camera cannot resend")
                        && m.contains("frame refused"),
                    "{m}"
                );
            }
        },
    );
}

#[test]
fn arv_tool_reads_our_zipped_genicam_xml() {
    on_own_gvcp_port("arv_tool_reads_our_zipped_genicam_xml", || {
        require_tool("arv-tool-0.8");
        let rt = runtime();
        let rig = rig(Some((320, 240)), None);
        let _emu = rt.block_on(emulator_on_3956_with(
            &rig,
            GigeConfig {
                zip_xml: true,
                ..Default::default()
            },
        ));
        let (ok, out) = run(
            Command::new("arv-tool-0.8").args([
                "-a",
                "127.0.0.1",
                "control",
                "Width",
                "PixelFormat",
            ]),
            Duration::from_secs(20),
        );
        assert!(ok, "{out}");
        assert!(
            out.contains("Width = 320") && out.contains("PixelFormat = Mono8"),
            "{out}"
        );
    });
}

//! `gateway proxy --config JOB --map MAP` on a machine whose camera is not there (a map
//! is measured once so that programs run without the camera): it starts, checks the
//! map against the controller it reaches, says that motion after a homing waits for a
//! reference, and after the sender's `$H` refuses motion with `error:9` (GRBL's "locked
//! out") while `$` commands still pass. The controller is the GRBL emulator on a real
//! pseudo-terminal, named in the job by its port as a real controller would be; the
//! job's simulated camera cannot be opened without the emulator's rig, as on a real
//! machine whose camera is unplugged.
//!
//! The same on the real GRBL 1.1h firmware (grbl-sim, `system_tests::firmware`), whose
//! harness has limit switches (tests/firmware/grbl-sim-limit-switches.py): homing on
//! (`$22=1`), it powers up in `Alarm`; the sender's `$X` and `$H` pass through, the
//! firmware homes, and motion is then refused by the gateway. A missing firmware or
//! socat fails the test naming `tests/install-peers.sh`.

use errormap::scan::without_link;
use job::{Job, StageSpec};
use protocol::errormap::Identity;
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::Duration;
use system_tests::firmware::{Firmware, INSTALL_STEP};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_serial::SerialPortBuilderExt;
use world::machine::MachineConfig;
use world::Clock;

use crate::common;

use common::{scratch, workspace};

/// Reads from the sender's port until `n` answers (`ok` / `error:N`) have come.
async fn answers(port: &mut tokio_serial::SerialStream, got: &mut String, n: usize) {
    let count = |s: &str| {
        s.lines()
            .filter(|l| *l == "ok" || l.starts_with("error:"))
            .count()
    };
    let mut buf = [0u8; 512];
    while count(got) < n {
        let k = port.read(&mut buf).await.expect("read the sender's port");
        assert!(k > 0, "the pass-through closed the port: {got}");
        got.push_str(&String::from_utf8_lossy(&buf[..k]).replace('\r', ""));
    }
}

/// The job at `job_path` as the pass-through reads it, and a map measured on its
/// machine (the truth of `machine`) whose identity is what the gateway reads of the
/// job's controller, saved at `dir/map.v1.json`.
async fn map_for(job_path: &Path, machine: &MachineConfig, dir: &Path) -> std::path::PathBuf {
    let job = Job::load(job_path).unwrap();
    // What the gateway reads of this machine: the controller, no camera.
    let here = procedure::identity_of_job(&job).await.unwrap();
    assert_eq!(here.camera, "", "no camera can be opened: {here:?}");
    let machine_name = without_link(&here.machine);
    let identity = Identity {
        camera: "the camera of the scan".into(),
        machine: machine_name.clone(),
        controller: machine_name,
        ..here
    };
    let map = system_tests::truth_map::map_from_truth(machine, identity);
    let map_path = dir.join("map.v1.json");
    map.save_new(&map_path).unwrap();
    map_path
}

/// `gateway proxy --once` on the job and map, its sender's port at `link`, once it has
/// said what follows a homing (returned with everything it said before).
async fn start_proxy(job_path: &Path, map_path: &Path, link: &Path) -> (Child, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_gateway"))
        .args(["proxy", "--config"])
        .arg(job_path)
        .arg("--map")
        .arg(map_path)
        .arg("--link")
        .arg(link)
        .arg("--once")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("gateway runs");
    let stdout = child.stdout.take().unwrap();
    let said = tokio::task::spawn_blocking(move || {
        let mut said = String::new();
        for line in BufReader::new(stdout).lines() {
            let line = line.unwrap();
            said.push_str(&line);
            said.push('\n');
            if line.contains("after the sender's homing") {
                return said;
            }
        }
        said
    })
    .await
    .unwrap();
    assert!(
        said.contains("no camera") && said.contains("error:9"),
        "the pass-through says motion after a homing waits for a reference: {said}"
    );
    (child, said)
}

#[test]
fn the_pass_through_starts_without_a_camera_and_locks_motion_after_a_homing() {
    let dir = scratch("proxy-no-camera", "run");
    let demo = Job::load(&workspace().join("config/gateway/grbl-demo.toml")).unwrap();
    let StageSpec::Grbl { link, .. } = &demo.stage else {
        unreachable!("the grbl demo job")
    };
    let job::GrblLink::Emulate(machine) = link else {
        unreachable!("an emulated controller")
    };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let (emulator, _rig) =
            devices::spawn_grbl_emulator(&demo, machine, Clock::Unconstrained).unwrap();
        // The same job, its controller named by its port (a real controller's job).
        let job_text = std::fs::read_to_string(workspace().join("config/gateway/grbl-demo.toml"))
            .unwrap()
            .replace(
                "emulate = \"../machines/c5-stage.toml\"",
                &format!("port = \"{}\"", emulator.path()),
            )
            .replace("../", &format!("{}/config/", workspace().display()));
        let job_path = dir.join("job.toml");
        std::fs::write(&job_path, job_text).unwrap();
        let map_path = map_for(&job_path, machine, &dir).await;
        let link = dir.join("ttyGATEWAY");
        let (mut child, _) = start_proxy(&job_path, &map_path, &link).await;
        let mut port = tokio_serial::new(link.to_string_lossy(), 115_200)
            .open_native_async()
            .expect("the sender's port");
        let mut got = String::new();
        port.write_all(b"$H\n").await.unwrap();
        answers(&mut port, &mut got, 1).await;
        assert!(
            got.starts_with("ok\n") && got.contains("error:9"),
            "the homing is passed on, and the sender told what follows: {got}"
        );
        port.write_all(b"G0 X20 Y20\n").await.unwrap();
        answers(&mut port, &mut got, 2).await;
        assert!(
            got.ends_with("error:9\n") && got.matches("[MSG:").count() >= 2,
            "motion after the homing is locked out, saying why: {got}"
        );
        port.write_all(b"$$\n").await.unwrap();
        answers(&mut port, &mut got, 3).await;
        assert!(got.contains("$100="), "`$` commands still pass: {got}");
        drop(port);
        let _ = child.kill();
        let _ = child.wait();
    });
}

/// The answers of the sender's port (`ok` / `error:N`) come within this bound; it only
/// ends a broken test (a homing on a busy machine takes tens of seconds).
const ANSWERS_WITHIN: Duration = Duration::from_secs(300);

#[test]
fn the_pass_through_on_real_grbl_11h_passes_its_homing_then_locks_motion() {
    let dir = scratch("proxy-no-camera", "real-grbl");
    let start = |started: Result<system_tests::firmware::RunningFirmware, String>| {
        started.unwrap_or_else(|e| panic!("real GRBL 1.1h: {e} ({INSTALL_STEP})"))
    };
    // The machine's set-up: homing on ($22=1) and quick (the harness's switches are
    // 5 mm from power-up; locate at 200 mm/min, seek at 1000, 10 ms debounce,
    // 100 mm/s²), stored in its EEPROM at a first power-up.
    let mut fw = start(Firmware::Grbl11h.start());
    {
        let mut c = fw.open().unwrap();
        c.read_through_line(ANSWERS_WITHIN, |l| l.starts_with("Grbl 1.1h"))
            .unwrap();
        for setting in [
            "$22=1", "$24=200", "$25=1000", "$26=10", "$120=100", "$121=100", "$122=100",
        ] {
            c.send(format!("{setting}\n").as_bytes());
            let a = c.read_through_line(ANSWERS_WITHIN, |l| l == "ok" || l.starts_with("error:"));
            assert_eq!(a.as_deref(), Ok("ok\r\n"), "{setting}");
        }
    }
    let workdir = fw.keep_workdir();
    drop(fw);
    // Powered up again: unhomed, in Alarm; its port kept open so that the gateway's
    // identity check and its sessions each open and close it without ending the link.
    let fw = start(Firmware::Grbl11h.start_in(&workdir));
    let powered = fw.hold().unwrap();

    let demo = Job::load(&workspace().join("config/gateway/grbl-demo.toml")).unwrap();
    let StageSpec::Grbl {
        link: job::GrblLink::Emulate(machine),
        ..
    } = &demo.stage
    else {
        unreachable!("the grbl demo job's emulated controller")
    };
    let job_text = std::fs::read_to_string(workspace().join("config/gateway/grbl-demo.toml"))
        .unwrap()
        .replace(
            "emulate = \"../machines/c5-stage.toml\"",
            &format!("port = \"{}\"", fw.path()),
        )
        .replace("../", &format!("{}/config/", workspace().display()));
    let job_path = dir.join("job.toml");
    std::fs::write(&job_path, job_text).unwrap();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let map_path = map_for(&job_path, machine, &dir).await;
        let link = dir.join("ttyGATEWAY");
        let (mut child, _) = start_proxy(&job_path, &map_path, &link).await;
        let mut port = tokio_serial::new(link.to_string_lossy(), 115_200)
            .open_native_async()
            .expect("the sender's port");
        let mut got = String::new();
        let mut answer = async |line: &str, n: usize, got: &mut String| {
            port.write_all(format!("{line}\n").as_bytes())
                .await
                .unwrap();
            tokio::time::timeout(ANSWERS_WITHIN, answers(&mut port, got, n))
                .await
                .unwrap_or_else(|_| panic!("no answer to {line}: {got}"));
        };
        // The firmware's own answers: locked at power-up, unlocked, homed.
        answer("$X", 1, &mut got).await;
        assert!(
            got.ends_with("[MSG:Caution: Unlocked]\nok\n"),
            "`$X` reaches the firmware: {got}"
        );
        let unlocked = got.len();
        answer("$H", 2, &mut got).await;
        assert!(
            got[unlocked..].starts_with("ok\n"),
            "the homing is passed on and the firmware completes it: {got}"
        );
        answer("G0 X20 Y20", 3, &mut got).await;
        assert!(
            got.ends_with("error:9\n") && got[unlocked..].matches("[MSG:gateway:").count() >= 2,
            "motion after the homing is locked out, saying why: {got}"
        );
        answer("$$", 4, &mut got).await;
        assert!(
            got.contains("$22=1") && got.contains("$100=250.000"),
            "`$$` still passes: {got}"
        );
        drop(port);
        let _ = child.kill();
        let _ = child.wait();
    });
    // The firmware's record: it homed (Z first: its seek towards +1.5 x $132 = 300 mm
    // at $25), pulled off to -1 mm ($27), and planned nothing else (no X20 Y20).
    let blocks: Vec<Vec<f64>> = fw
        .blocks()
        .lines()
        .map(|l| l.split(',').map(|f| f.trim().parse().unwrap()).collect())
        .collect();
    assert_eq!(
        blocks.first().map(|b| (b[2], b[3])),
        Some((75_000.0, 1000.0)),
        "{blocks:?}"
    );
    assert!(
        blocks.iter().all(|b| b[0] != 5000.0 && b[1] != 5000.0),
        "{blocks:?}"
    );
    // Read while the port is still held (the last close would end the link).
    let mut c = fw.open().unwrap();
    drop(powered);
    c.send(b"?");
    let status = c
        .read_through_line(ANSWERS_WITHIN, |l| l.starts_with('<'))
        .unwrap();
    assert!(
        status.contains("<Idle|MPos:-1.000,-1.000,-1.000|"),
        "homed, pulled off: {status}"
    );
    drop(c);
    drop(fw);
    let _ = std::fs::remove_dir_all(&workdir);
    let _ = std::fs::remove_dir_all(&dir);
}

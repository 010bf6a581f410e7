//! `gateway proxy --config JOB --map MAP` on a machine whose camera is not there (a map
//! is measured once so that programs run without the camera): it starts, checks the
//! map against the controller it reaches, says that motion after a homing waits for a
//! reference, and after the sender's `$H` refuses motion with `error:9` (GRBL's "locked
//! out") while `$` commands still pass. The controller is the GRBL emulator on a real
//! pseudo-terminal, named in the job by its port as a real controller would be; the
//! job's simulated camera cannot be opened without the emulator's rig, as on a real
//! machine whose camera is unplugged.

use errormap::scan::without_link;
use job::{Job, StageSpec};
use protocol::errormap::Identity;
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_serial::SerialPortBuilderExt;
use world::Clock;

mod common;

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
        let job = Job::load(&job_path).unwrap();
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
        let link = dir.join("ttyGATEWAY");

        let mut child = Command::new(env!("CARGO_BIN_EXE_gateway"))
            .args(["proxy", "--config"])
            .arg(&job_path)
            .arg("--map")
            .arg(&map_path)
            .arg("--link")
            .arg(&link)
            .arg("--once")
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("gateway runs");
        // Ready once it has said where the sender's port is and what follows a homing.
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

//! Interoperation with an independent Modbus implementation (pymodbus, from the package
//! registry): its client drives the stand-alone `emulators modbus` over TCP and over
//! RTU on the emulator's pseudo-terminal; our driver drives a pymodbus server built
//! from a drive profile's register map. Fails, naming the missing peer and the install
//! step (`tests/install-peers.sh`), when python3 or pymodbus is missing.

use crate::modbus_common;

use drivers::modbus::{open_stage, Endpoint};
use drivers::{Axis, AxisValues, Stage};
use modbus_common::*;
use std::io::{BufRead, BufReader, Read};
use std::process::{Command, Stdio};
use system_tests::{emulators_binary, python_missing, workspace, Kill};

/// pymodbus is here, or the test fails naming it and the install step.
fn require_pymodbus() {
    if let Some(why) = python_missing("pymodbus, serial", "pymodbus pyserial") {
        panic!("a peer of this test is missing (install every test peer with tests/install-peers.sh, README: Set-up): {why}");
    }
}

fn run_client(args: &[&str]) -> serde_json::Value {
    let out = Command::new("python3")
        .arg(workspace().join("tests/interop/modbus_client.py"))
        .args(args)
        .args(["--profile", "config/drives/generic.toml", "--units", "1,2"])
        .current_dir(workspace())
        .output()
        .expect("run the pymodbus client");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "client failed: {stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_str(stdout.trim()).unwrap_or_else(|e| panic!("{e}: {stdout}"))
}

#[test]
fn pymodbus_client_drives_the_emulator_over_tcp_and_rtu() {
    require_pymodbus();
    let child = Command::new(emulators_binary())
        .args([
            "modbus",
            "--tcp",
            "127.0.0.1:0",
            "--rtu",
            "--time-scale",
            "unconstrained",
        ])
        .args(["--unit", "1=x", "--unit", "2=y"])
        .current_dir(workspace())
        .stdout(Stdio::piped())
        .spawn()
        .expect("start the emulator");
    let mut child = Kill(child);
    let mut out = BufReader::new(child.0.stdout.take().unwrap());
    let mut line = |prefix: &str| {
        let mut l = String::new();
        out.read_line(&mut l).unwrap();
        l.trim()
            .strip_prefix(prefix)
            .unwrap_or_else(|| panic!("emulator printed {l:?}"))
            .to_string()
    };
    let tcp = line("modbus tcp: ");
    let pts = line("modbus rtu: ");
    assert!(pts.starts_with("/dev/pts/"), "{pts}");
    for args in [["--tcp", tcp.as_str()], ["--rtu", pts.as_str()]] {
        let v = run_client(&args);
        for u in ["1", "2"] {
            assert_eq!(
                v["units"][u]["actual_counts"], v["units"][u]["target_counts"],
                "{args:?}: {v}"
            );
        }
        assert_eq!(v["units"]["1"]["target_counts"], 50_000, "{v}");
        assert!(
            v["home_polls"].as_u64().unwrap() >= 2,
            "homing reported busy first: {v}"
        );
        assert_eq!(v["unmapped_read"], 2, "illegal data address: {v}");
        assert_eq!(v["read_coils"], 1, "illegal function: {v}");
        assert_eq!(v["bad_trigger"], 3, "illegal data value: {v}");
    }
}

#[test]
fn our_driver_drives_a_pymodbus_server_built_from_the_oriental_profile() {
    require_pymodbus();
    let child = Command::new("python3")
        .arg(workspace().join("tests/interop/modbus_server.py"))
        .args([
            "--profile",
            "config/drives/oriental-az.toml",
            "--units",
            "1,2",
        ])
        .current_dir(workspace())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start the pymodbus server");
    let mut child = Kill(child);
    let mut l = String::new();
    BufReader::new(child.0.stdout.as_mut().unwrap())
        .read_line(&mut l)
        .unwrap();
    let port: u16 = l
        .trim()
        .strip_prefix("listening ")
        .and_then(|p| p.parse().ok())
        .unwrap_or_else(|| panic!("server printed {l:?}"));
    runtime().block_on(async {
        let ep = Endpoint::Tcp(format!("127.0.0.1:{port}").parse().unwrap());
        let axes = [axis_cfg(Axis::X, 1), axis_cfg(Axis::Y, 2)];
        let mut stage = open_stage(ep, options(), profile("oriental-az"), &axes)
            .await
            .unwrap();
        stage.home().await.unwrap();
        for (x, y) in [(12.5, 100.0), (180.0, 3.25)] {
            stage.move_to(AxisValues::xy(x, y), 2000.0).await.unwrap();
            stage.wait_idle().await.unwrap();
            let p = stage.position().await.unwrap();
            assert_eq!((p.get(Axis::X).unwrap(), p.get(Axis::Y).unwrap()), (x, y));
        }
    });
    let _ = child.0.kill();
    let _ = child.0.wait();
    let mut err = String::new();
    child
        .0
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    let triggers: Vec<&str> = err.lines().filter(|l| l.starts_with("trigger ")).collect();
    assert_eq!(
        triggers,
        ["trigger 1 1", "trigger 2 1", "trigger 1 2", "trigger 2 2"],
        "{err}"
    );
}

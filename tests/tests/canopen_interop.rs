//! Interoperation with an independent CANopen stack: the python `canopen` package
//! (BaseNode402) over python-can's `slcan` interface, as master of the stand-alone
//! `emulators canopen` drive over its pseudo-terminal: NMT, heartbeat, SDO reads of the
//! PDO records and 0x6502, the power state machine, homing, a profile-position move,
//! a fault with its EMCY and a fault reset. Fails, naming the missing peer and the
//! install step (`tests/install-peers.sh`), when python3 or the packages are missing.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use system_tests::{emulators_binary, python_missing, workspace, Kill};

#[test]
fn python_canopen_master_runs_our_emulated_cia402_drive_over_slcan() {
    if let Some(why) = python_missing("canopen, can, serial", "canopen python-can pyserial") {
        panic!("a peer of this test is missing (install every test peer with tests/install-peers.sh, README: Set-up): {why}");
    }
    let child = Command::new(emulators_binary())
        .args(["canopen", "--time-scale", "unconstrained"])
        .current_dir(workspace())
        .stdout(Stdio::piped())
        .spawn()
        .expect("start the emulator");
    let mut child = Kill(child);
    let mut first = String::new();
    BufReader::new(child.0.stdout.as_mut().unwrap())
        .read_line(&mut first)
        .unwrap();
    let pts = first
        .trim()
        .strip_prefix("slcan: ")
        .unwrap_or_else(|| panic!("emulator printed {first:?}"));
    assert!(pts.starts_with("/dev/pts/"), "{pts}");

    let script = workspace().join("tests/interop/canopen_master.py");
    let eds = workspace().join("config/canopen/drive.eds");
    let out = Command::new("python3")
        .arg(&script)
        .arg(pts)
        .arg(&eds)
        .output()
        .expect("run the master");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "master failed: {stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value =
        serde_json::from_str(stdout.trim()).unwrap_or_else(|e| panic!("{e}: {stdout}"));
    assert_eq!(v["ok"], true, "{v}");
    assert_eq!(v["heartbeat_state"], "PRE-OPERATIONAL");
    assert_eq!(v["device_type"], 0x0002_0192);
    assert_eq!(v["name"], "CiA 402 drive emulator");
    assert_eq!(v["supported_modes"], 0x21);
    assert_eq!(
        v["write_ro"], 0x0601_0002,
        "writing the statusword is refused with its abort code"
    );
    assert_eq!(v["tpdo1"], serde_json::json!(["6041", "6061"]));
    assert_eq!(v["tpdo2"], serde_json::json!(["6041", "6064"]));
    assert_eq!(v["rpdo1"], serde_json::json!(["6040", "6060"]));
    assert_eq!(v["rpdo2"], serde_json::json!(["6040", "607A"]));
    assert_eq!(v["state"], "OPERATION ENABLED");
    assert_eq!(v["homed"], true);
    assert_eq!(v["op_mode"], "PROFILED POSITION");
    assert_eq!(v["position"], 20000);
    assert_eq!(
        v["statusword_after_move"].as_u64().unwrap() & 0x046F,
        0x0427,
        "{v}"
    );
    assert_eq!(v["fault_emcy"], 0x8612);
    assert_eq!(v["error_code"], 0x8612);
    assert_eq!(v["after_reset"], "OPERATION ENABLED");
    assert_eq!(v["reset_emcy"], 0);
}

//! Interoperation with an independent GRBL client: a pyserial script written against
//! GRBL's public interface (what UGS and CNCjs do at connect, then character-counting
//! streaming) talks to the stand-alone `emulators grbl` binary over its pseudo-terminal.
//! Fails, naming the missing peer and the install step (`tests/install-peers.sh`), when
//! python3 or pyserial is missing.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use system_tests::{emulators_binary, python_missing, workspace, Kill};

#[test]
fn pyserial_sender_connects_like_ugs_and_streams_by_character_counting() {
    if let Some(why) = python_missing("serial", "pyserial") {
        panic!("a peer of this test is missing (install every test peer with tests/install-peers.sh, README: Set-up): {why}");
    }
    let dir = std::env::temp_dir().join(format!("grbl-interop-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let link = dir.join("ttyGRBL");
    let child = Command::new(emulators_binary())
        .args(["grbl", "--time-scale", "unconstrained", "--link"])
        .arg(&link)
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
        .strip_prefix("grbl: ")
        .unwrap_or_else(|| panic!("emulator printed {first:?}"));
    assert!(pts.starts_with("/dev/pts/"), "{pts}");

    // A 1500-line program (comments, blank lines, an arc) within the travel.
    let mut prog = String::from("(interop test)\nG21 G90 G17\nG0 X5 Y5\n\n");
    for i in 0..1500 {
        prog.push_str(&format!(
            "G1 X{:.3} Y{:.3} F4000 ; {i}\n",
            5.0 + (i % 60) as f64 * 0.8,
            5.0 + (i / 60) as f64 * 0.8
        ));
    }
    prog.push_str("G0 X5 Y5\nG2 X20 Y5 I7.5 J0 F2000\nG4 P0.1\nM2\n");
    let file = dir.join("prog.nc");
    std::fs::write(&file, &prog).unwrap();

    let out = system_tests::grbl_sender(&link, &file)
        .output()
        .expect("run the sender");
    let v = system_tests::sender_json(&out);
    let n = prog.lines().count() as u64;
    assert_eq!(v["streamed"], n);
    assert_eq!(v["acknowledged"], n);
    assert_eq!(v["errors"].as_array().unwrap().len(), 0, "{v}");
    assert_eq!(
        v["first_state"], "Alarm",
        "boots locked with homing enabled"
    );
    assert_eq!(v["rx_buffer"], 128);
    assert_eq!(v["steps_per_mm_x"], 2000.0);
    assert!(
        v["version"].as_str().unwrap().starts_with("[VER:1.1h."),
        "{v}"
    );
    assert!(
        v["final_status"]
            .as_str()
            .unwrap()
            .starts_with("<Idle|MPos:20.000,5.000,"),
        "{v}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

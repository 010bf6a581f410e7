//! `gateway layout partition` through the binary: files in, files and JSON out.

use std::path::PathBuf;
use std::process::{Command, Output};

fn gateway(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_gateway"))
        .args(args)
        .output()
        .expect("gateway runs")
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("layout-cli-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("scratch folder");
    dir
}

/// A1, A2 (tool 0, window 0), B 2 mm above A2 once shifted (tool 0, window 1), C (tool
/// 1, window 0), D (tool 1, window 1); gap 5, L' 150, W 100 (in the file).
const CROSSING: &str = r#"{"units":"mm","width_mm":100,"parts":[
{"id":"A1","contours":[[[0,0],[35,0],[35,20],[0,20]]]},
{"id":"A2","contours":[[[40,0],[140,0],[140,20],[40,20]]]},
{"id":"B","layer":"cut","contours":[[[110,22],[200,22],[200,45],[110,45]]]},
{"id":"C","contours":[[[0,60],[100,60],[100,80],[0,80]]]},
{"id":"D","contours":[[[150,60],[200,60],[200,80],[150,80]]]}]}"#;

#[test]
fn partition_writes_the_shifted_layout_and_reports_groups_and_moves() {
    let dir = scratch("ok");
    let input = dir.join("crossing.json");
    std::fs::write(&input, CROSSING).unwrap();
    let out = dir.join("shifted.dxf");
    let pic = dir.join("groups.png");
    let o = gateway(&[
        "layout",
        "partition",
        input.to_str().unwrap(),
        "--tools",
        "2",
        "--window-mm",
        "150",
        "--gap-mm",
        "5",
        "--out",
        out.to_str().unwrap(),
        "--picture",
        pic.to_str().unwrap(),
        "--json",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let groups = v["groups"].as_array().unwrap();
    assert_eq!(groups.len(), 3);
    assert_eq!(groups[2]["id"], 4);
    assert_eq!(groups[2]["parts"], serde_json::json!(["B", "D"]));
    assert_eq!(
        (groups[2]["dx_mm"].as_f64(), groups[2]["dy_mm"].as_f64()),
        (Some(5.0), Some(5.0))
    );
    assert_eq!(v["moves"][0]["part"], "B");
    assert_eq!(v["moves"][0]["to_group"], 4);
    assert_eq!(v["overlaps_found"][0]["distance_mm"], 2.0);
    assert_eq!(v["figures"]["partitioned"]["length_mm"], 205.0);
    assert!(std::fs::read(&pic).unwrap().starts_with(b"\x89PNG"));
    // The written DXF reads back with B moved by (5, 5).
    let back = dir.join("again.json");
    let o = gateway(&[
        "layout",
        "partition",
        out.to_str().unwrap(),
        "--tools",
        "1",
        "--window-mm",
        "1000",
        "--gap-mm",
        "1",
        "--out",
        back.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let again: serde_json::Value = serde_json::from_slice(&std::fs::read(&back).unwrap()).unwrap();
    let b = again["parts"]
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["id"] == "B")
        .unwrap();
    assert_eq!(b["contours"][0][0], serde_json::json!([115.0, 27.0]));
    assert_eq!(b["layer"], "cut");
}

#[test]
fn an_unresolvable_overlap_is_reported_and_nothing_is_written() {
    let dir = scratch("refused");
    let input = dir.join("crossing.json");
    // Without D, B has no group to go to.
    let text = CROSSING.replace(
        ",\n{\"id\":\"D\",\"contours\":[[[150,60],[200,60],[200,80],[150,80]]]}",
        "",
    );
    assert!(!text.contains("\"D\""));
    std::fs::write(&input, text).unwrap();
    let out = dir.join("shifted.svg");
    let o = gateway(&[
        "layout",
        "partition",
        input.to_str().unwrap(),
        "--tools",
        "2",
        "--window-mm",
        "150",
        "--gap-mm",
        "5",
        "--out",
        out.to_str().unwrap(),
        "--json",
    ]);
    assert!(!o.status.success());
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let e = v["error"].as_str().unwrap();
    assert!(
        e.contains("`A2` (group 1)") && e.contains("`B` (group 3)"),
        "{e}"
    );
    assert!(!out.exists());
    // Bad parameters and files are named.
    let o = gateway(&[
        "layout",
        "partition",
        input.to_str().unwrap(),
        "--tools",
        "0",
        "--window-mm",
        "150",
        "--gap-mm",
        "5",
        "--out",
        out.to_str().unwrap(),
    ]);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        e.contains("--tools: must be an integer from 1 to 64, got 0"),
        "{e}"
    );
    let o = gateway(&[
        "layout",
        "partition",
        input.to_str().unwrap(),
        "--tools",
        "2",
        "--window-mm",
        "150",
        "--gap-mm",
        "5",
        "--out",
        dir.join("x.txt").to_str().unwrap(),
    ]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("must be .dxf, .svg or .json"));
}

/// `layout cut` on the emulated cutter: the crossing layout's groups cut stop by stop,
/// the stroke log written (every part's outline once: 4 strokes per rectangle), and a
/// head too short for its parts refused before anything moves, naming the part.
#[test]
fn cut_runs_the_layout_on_the_emulated_cutter_and_writes_its_log() {
    let dir = scratch("cut");
    let input = dir.join("crossing.json");
    std::fs::write(&input, CROSSING).unwrap();
    let log = dir.join("strokes.jsonl");
    let base = [
        "layout",
        "cut",
        input.to_str().unwrap(),
        "--tools",
        "2",
        "--window-mm",
        "150",
        "--gap-mm",
        "5",
    ];
    let mut args = base.to_vec();
    args.extend(["--log", log.to_str().unwrap(), "--json"]);
    let o = gateway(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["parts"], 5);
    assert_eq!(v["strokes"], 20, "{v}");
    let groups: u64 = v["heads"]
        .as_array()
        .unwrap()
        .iter()
        .map(|h| h["groups"].as_u64().unwrap())
        .sum();
    assert_eq!(groups, v["groups"].as_u64().unwrap());
    let lines: Vec<serde_json::Value> = std::fs::read_to_string(&log)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 21, "20 strokes and the summary");
    assert!(lines[..20]
        .iter()
        .all(|l| l["stroke"]["conveyor_moving"] == false));
    assert_eq!(
        lines[20]["feeds"].as_array().unwrap().len(),
        v["stops"].as_array().unwrap().len()
    );

    let mut args = base.to_vec();
    args.extend(["--head-reach", "0:40", "--head-reach", "50:40"]);
    let refused = gateway(&args);
    assert!(!refused.status.success());
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(
        err.contains("part `B`") && err.contains("head 1's reach"),
        "{err}"
    );
    let mut args = base.to_vec();
    args.extend(["--head-reach", "0-40", "--head-reach", "50:40"]);
    let err = gateway(&args);
    assert!(String::from_utf8_lossy(&err.stderr).contains("ORIGIN:REACH"));
}

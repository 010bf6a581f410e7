//! `gateway volumetric ...` through the binary: campaign -> model -> eval/contributions,
//! and a bad campaign file refused with its path, line and column.

use std::path::PathBuf;
use std::process::{Command, Output};

fn gateway(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_gateway"))
        .args(args)
        .output()
        .expect("the gateway binary runs")
}

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("gateway-vol-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn campaign_identify_eval_contributions() {
    let d = dir("flow");
    let camp = d.join("camp");
    let model = d.join("m.vol.csv");
    let s = |p: &PathBuf| p.to_str().unwrap().to_string();
    let out = gateway(&[
        "volumetric",
        "simulate-campaign",
        "--out",
        &s(&camp),
        "--structure",
        "XFYZ",
        "--seed",
        "9",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = gateway(&[
        "volumetric",
        "identify",
        "--campaign",
        &s(&camp),
        "--structure",
        "XFYZ",
        "--out",
        &s(&model),
        "--json",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["fit_for_compensation"], true);
    assert_eq!(v["errors"].as_array().unwrap().len(), 21);
    // Squareness from the three ball-bar circles, angles sharpened by the camera.
    assert_eq!(v["ballbar"].as_array().unwrap().len(), 3);
    assert_eq!(v["ballbar"][1]["plane"], "XZ");
    assert_eq!(v["camera"]["fit"], true);
    assert_eq!(v["camera"]["heights_mm"][2], 300.0);
    let isg = d.join("isg");
    let out = gateway(&[
        "volumetric",
        "export-isg",
        "--model",
        &s(&model),
        "--out",
        &s(&isg),
    ]);
    assert!(out.status.success());
    let csv = std::fs::read_to_string(isg.join("volcomp.csv")).unwrap();
    let headers: Vec<&str> = csv
        .lines()
        .filter(|l| l.chars().next().is_some_and(|c| c.is_ascii_alphabetic()))
        .collect();
    assert_eq!(
        headers,
        [
            "C0Y B0Z A0Z P0X P0Y P0Z",
            "X EXX EYX EZX EAX EBX ECX",
            "Y EXY EYY EZY EAY EBY ECY",
            "Z EXZ EYZ EZZ EAZ EBZ ECZ"
        ]
    );
    let lis = std::fs::read_to_string(isg.join("volcomp.lis")).unwrap();
    assert!(lis.contains("workpiece_axes           1\n"), "{lis}");
    let points = d.join("p.csv");
    std::fs::write(&points, "x_mm,y_mm,z_mm\n0,0,0\n250,200,100\n").unwrap();
    let eval = |first: bool| {
        let mut a = vec!["volumetric", "eval", "--model"];
        let (m, p) = (s(&model), s(&points));
        a.push(&m);
        a.push("--points");
        a.push(&p);
        a.push("--json");
        if first {
            a.push("--first-order");
        }
        let out = gateway(&a);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        serde_json::from_slice::<serde_json::Value>(&out.stdout).unwrap()
    };
    let (exact, first) = (eval(false), eval(true));
    let pts = exact["points"].as_array().unwrap();
    assert_eq!(pts.len(), 2);
    for k in ["ex_um", "ey_um", "ez_um"] {
        let a = pts[1][k].as_f64().unwrap();
        let b = first["points"][1][k].as_f64().unwrap();
        assert!((a - b).abs() <= 0.1, "{k}: {a} vs {b}");
        // At the origin the errors are those of position 0: zero up to the noise.
        assert!(pts[0][k].as_f64().unwrap().abs() < 1.5);
    }
    let contrib = d.join("contrib");
    let out = gateway(&[
        "volumetric",
        "contributions",
        "--model",
        &s(&model),
        "--out",
        &s(&contrib),
        "--grid",
        "5",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for f in [
        "contributions.csv",
        "contributions.svg",
        "map_XY.svg",
        "map_XZ.csv",
        "map_YZ.svg",
    ] {
        assert!(contrib.join(f).is_file(), "{f}");
    }
    let csv = std::fs::read_to_string(contrib.join("contributions.csv")).unwrap();
    assert_eq!(csv.lines().count(), 22);
}

#[test]
fn a_bad_campaign_file_is_named_with_line_and_column() {
    let d = dir("bad");
    let camp = d.join("camp");
    let c = camp.to_str().unwrap();
    assert!(gateway(&["volumetric", "simulate-campaign", "--out", c])
        .status
        .success());
    let level = camp.join("level_Y.csv");
    let text = std::fs::read_to_string(&level).unwrap();
    // The second data row's position goes back to 0: duplicated within run 1.
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    lines[5] = "1,0,0.5".to_string();
    std::fs::write(&level, lines.join("\n")).unwrap();
    let m = d.join("m.csv");
    let out = gateway(&[
        "volumetric",
        "identify",
        "--campaign",
        c,
        "--structure",
        "XYFZ",
        "--out",
        m.to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("level_Y.csv: line 6, column 3: position 0 duplicated"),
        "{err}"
    );
    let out = gateway(&[
        "volumetric",
        "simulate-campaign",
        "--out",
        c,
        "--structure",
        "XZFY",
    ]);
    assert!(String::from_utf8_lossy(&out.stderr).contains("--structure: `XZFY`"));
}

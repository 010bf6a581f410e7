//! `gateway iso230 evaluate` through the binary: a file evaluated to the hand-computed
//! figures with every output written, and a bad row refused by line.

use std::process::Command;

fn scratch(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("gateway-iso230-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Up runs 1..5 um at every target, down 0 um except -2 um at the third: x̄↑ = 3,
/// s↑ = sqrt(2.5); B_i = 3 (5 at the third); E = 3 - (-2) = 5; M = 1.5 - 0.5 = 1;
/// R = 2 sqrt(2.5) + 5; A = 3 + 2 sqrt(2.5) - (-2).
fn csv() -> String {
    let mut s = String::from("axis,position_index,target_mm,run,direction,deviation_um\n");
    for i in 1..=5 {
        let t = 10.0 * i as f64 + 0.37 * (i * i) as f64;
        for j in 1..=5 {
            s += &format!("X,{i},{t},{j},+,{j}\n");
            s += &format!("X,{i},{t},{j},-,{}\n", if i == 3 { -2 } else { 0 });
        }
    }
    s
}

#[test]
fn evaluate_writes_the_figures_charts_and_report() {
    let dir = scratch("ok");
    let file = dir.join("measurements.csv");
    std::fs::write(&file, csv()).unwrap();
    let out = dir.join("out");
    let o = Command::new(env!("CARGO_BIN_EXE_gateway"))
        .args([
            "iso230",
            "evaluate",
            file.to_str().unwrap(),
            "--json",
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let s = 2.5f64.sqrt();
    for (k, want) in [
        ("E_um", 5.0),
        ("E_up_um", 0.0),
        ("E_down_um", 2.0),
        ("M_um", 1.0),
        ("B_um", 5.0),
        ("mean_reversal_um", 3.4),
        ("R_um", 2.0 * s + 5.0),
        ("R_up_um", 4.0 * s),
        ("A_um", 5.0 + 2.0 * s),
    ] {
        let got = v[k].as_f64().unwrap();
        assert!((got - want).abs() < 1e-9, "{k}: {got} != {want}");
    }
    for f in [
        "result.json",
        "deviation_x.svg",
        "deviation_x.png",
        "report.html",
    ] {
        assert!(out.join(f).is_file(), "{f}");
    }
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(html.contains("<svg"));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn evaluate_names_the_bad_line() {
    let dir = scratch("bad");
    let file = dir.join("m.csv");
    let mut text = csv();
    text = text.replacen("X,2,", "X,2x,", 1);
    std::fs::write(&file, text).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_gateway"))
        .args(["iso230", "evaluate", file.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    // Position 2's first row is line 12 (header, then 10 rows of position 1).
    assert!(
        err.contains("line 12, column position_index: `2x`"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

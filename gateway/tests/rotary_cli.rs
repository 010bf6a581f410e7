//! `gateway rotary` as a user runs it: the probing cycle on the simulated machine, then
//! the identification from the centres file it wrote, and a bad file refused.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn gateway(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_gateway"))
        .args(args)
        .output()
        .expect("gateway runs")
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .unwrap()
        .to_path_buf()
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("gateway-rotary-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

const NAMES: [&str; 8] = [
    "delta_XC_mm",
    "delta_YC_mm",
    "alpha_XC_deg",
    "alpha_YC_deg",
    "delta_YA_mm",
    "delta_ZA_mm",
    "alpha_YA_deg",
    "alpha_ZA_deg",
];

#[test]
fn measure_then_identify_from_its_centres() {
    let out = scratch("measure");
    let config = repo().join("config/rotary/sim-table.json");
    let run = gateway(&[
        "rotary",
        "measure",
        "--config",
        config.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--json",
    ]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    for name in NAMES {
        let d = v["truth"][name]["difference"].as_f64().unwrap();
        let tol = if name.ends_with("_deg") {
            0.0005
        } else {
            0.001
        };
        assert!(d.abs() <= tol, "{name}: {d}");
        assert!(v["uncertainty"][name].as_f64().unwrap() > 0.0);
    }
    assert_eq!(v["cycle"]["probe_points"], 103);
    assert!(
        v["compensation_check"]["tip_improvement_pct"]
            .as_f64()
            .unwrap()
            >= 95.0
    );
    assert!(
        v["compensation_check"]["direction_improvement_pct"]
            .as_f64()
            .unwrap()
            >= 95.0
    );
    for f in [
        "centres.csv",
        "points.csv",
        "errors.json",
        "rotary-sweeps.svg",
        "rotary-sweeps.png",
    ] {
        assert!(out.join(f).is_file(), "{f} written");
    }
    // The same identification from the centres file alone.
    let centres = out.join("centres.csv");
    let id = gateway(&[
        "rotary",
        "identify",
        "--centres",
        centres.to_str().unwrap(),
        "--json",
    ]);
    assert!(
        id.status.success(),
        "{}",
        String::from_utf8_lossy(&id.stderr)
    );
    let w: serde_json::Value = serde_json::from_slice(&id.stdout).unwrap();
    for name in NAMES {
        let a = v[name].as_f64().unwrap();
        let b = w[name].as_f64().unwrap();
        // The file keeps 6 decimals (1 nm).
        assert!((a - b).abs() < 1e-5, "{name}: {a} vs {b}");
    }
    // The errors file it wrote is what the rewriter reads.
    let text = std::fs::read_to_string(out.join("errors.json")).unwrap();
    rotary::LocationErrors::from_json(&text).unwrap();

    // `gateway rewrite --rotary` is the same 5-axis rewrite as `gateway rotary rewrite`.
    let program = out.join("five-axis.nc");
    std::fs::write(
        &program,
        "G21 G90 G94\nG0 X10 Y5 Z-30 A0 C0\nG1 X12 Y6 Z-35 A15 C30 F500\nG1 X-8 Y4 Z-40 A-30 C120\n",
    )
    .unwrap();
    let errors = out.join("errors.json");
    let through_rewrite = out.join("via-rewrite.nc");
    let through_rotary = out.join("via-rotary.nc");
    let a = gateway(&[
        "rewrite",
        program.to_str().unwrap(),
        "--rotary",
        errors.to_str().unwrap(),
        "--out",
        through_rewrite.to_str().unwrap(),
        "--json",
    ]);
    assert!(a.status.success(), "{}", String::from_utf8_lossy(&a.stderr));
    let b = gateway(&[
        "rotary",
        "rewrite",
        program.to_str().unwrap(),
        "--errors",
        errors.to_str().unwrap(),
        "--out",
        through_rotary.to_str().unwrap(),
    ]);
    assert!(b.status.success(), "{}", String::from_utf8_lossy(&b.stderr));
    let rewritten = std::fs::read_to_string(&through_rewrite).unwrap();
    assert_eq!(rewritten, std::fs::read_to_string(&through_rotary).unwrap());
    assert_ne!(rewritten, std::fs::read_to_string(&program).unwrap());
    // A 3-axis option beside --rotary is refused, naming it; nothing is written.
    let refused_out = out.join("refused.nc");
    let c = gateway(&[
        "rewrite",
        program.to_str().unwrap(),
        "--rotary",
        errors.to_str().unwrap(),
        "--start",
        "0,0,0",
        "--out",
        refused_out.to_str().unwrap(),
    ]);
    assert!(!c.status.success());
    assert!(String::from_utf8_lossy(&c.stderr).contains("--start"));
    assert!(!refused_out.exists());
}

#[test]
fn a_bad_centres_file_is_refused_naming_line_and_column() {
    let dir = scratch("bad");
    let path = dir.join("centres.csv");
    std::fs::write(
        &path,
        "axis,step,angle_deg,ball,x_mm,y_mm,z_mm\nC,0,0,1,-60,0,-260\nC,1,30,1,oops,0,-260\n",
    )
    .unwrap();
    let run = gateway(&["rotary", "identify", "--centres", path.to_str().unwrap()]);
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("line 3, column 5 (x_mm): `oops`"), "{err}");
}

/// The cycle run by the `gateway` process against a controller on a serial port it knows
/// only by its path: here the GRBL emulator (six axes, the paper's table with its
/// default errors behind it) on a pseudo-terminal served by this test process. The
/// identified errors are compared with the ones the emulated table carries.
#[test]
fn measure_through_a_controller_on_a_serial_port() {
    use emulators::grbl::{GrblConfig, GrblDevice, GrblPty};
    use world::axes::AxesMachine;
    let job = job::rotary::RotaryJob::default();
    let truth = job.simulated().sim.errors;
    let sim = job.simulated().sim;
    let (path_tx, path_rx) = std::sync::mpsc::channel();
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let controller = std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        let axes = AxesMachine::new(Box::new(world::rotary::RotaryWorkpiece { sim })).shared();
        let pty = {
            let _enter = rt.enter();
            GrblPty::spawn(GrblDevice::with_axes(axes, GrblConfig::default()), None).unwrap()
        };
        path_tx.send(pty.path().to_string()).unwrap();
        rt.block_on(async {
            let _ = stop_rx.await;
        });
        drop(pty);
    });
    let port = path_rx.recv().unwrap();
    let out = scratch("serial");
    let config = out.join("job.json");
    std::fs::write(
        &config,
        serde_json::json!({"link": {"grbl": {"port": port, "poll_ms": 2}}}).to_string(),
    )
    .unwrap();
    let run = gateway(&[
        "rotary",
        "measure",
        "--config",
        config.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--json",
    ]);
    let _ = stop_tx.send(());
    controller.join().unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    // A real controller's truth is unknown to the gateway: no comparison in its report.
    assert!(v.get("truth").is_none() && v.get("compensation_check").is_none());
    assert_eq!(v["cycle"]["probe_points"], 103);
    // The C centre from the rim: the actual axis (delta_XC, delta_YC off the nominal)
    // within the rim's run-out (1.2 and 0.8 um) and the probe's scatter.
    let offset = &v["c_centre"]["offset_mm"];
    assert!(
        (offset[0].as_f64().unwrap() - truth.delta_xc_mm).abs() < 0.003,
        "{offset}"
    );
    assert!(
        (offset[1].as_f64().unwrap() - truth.delta_yc_mm).abs() < 0.003,
        "{offset}"
    );
    let injected = [
        truth.delta_xc_mm,
        truth.delta_yc_mm,
        truth.alpha_xc_deg,
        truth.alpha_yc_deg,
        truth.delta_ya_mm,
        truth.delta_za_mm,
        truth.alpha_ya_deg,
        truth.alpha_za_deg,
    ];
    for (name, want) in NAMES.iter().zip(injected) {
        let got = v[name].as_f64().unwrap();
        let tol = if name.ends_with("_deg") {
            0.0005
        } else {
            0.001
        };
        assert!((got - want).abs() <= tol, "{name}: {got} vs {want}");
    }
    assert!(out.join("errors.json").is_file());
}

/// Simulation settings beside a real port are refused: they would describe a machine
/// that is not there.
#[test]
fn a_real_port_job_refuses_simulation_settings() {
    let out = scratch("serial-refused");
    let config = out.join("job.json");
    std::fs::write(
        &config,
        r#"{"seed": 3, "link": {"grbl": {"port": "/dev/ttyUSB7"}}}"#,
    )
    .unwrap();
    let run = gateway(&[
        "rotary",
        "measure",
        "--config",
        config.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(
        err.contains("`seed`") && err.contains("/dev/ttyUSB7"),
        "{err}"
    );
}

/// `gateway proxy --rotary`: a sender streams a 5-axis program to the gateway's port; the
/// gateway rewrites it for the table's errors and streams it to the controller on a
/// pseudo-terminal (the GRBL emulator with the paper's table, served by this test). Every
/// line is acknowledged, the moves were split, and the sender's status shows the
/// programmed position while the controller's differs by the correction.
#[test]
fn the_pass_through_rewrites_a_five_axis_program_for_the_table() {
    use emulators::grbl::{GrblConfig, GrblDevice, GrblPty};
    use std::io::{BufRead, BufReader};
    use tokio::io::{AsyncBufReadExt, AsyncWriteExt};
    use world::axes::{lock_axes, AxesMachine};
    let out = scratch("proxy");
    let errors = out.join("errors.json");
    let truth = job::rotary::RotaryJob::default().simulated().sim;
    let t = truth.errors;
    std::fs::write(
        &errors,
        serde_json::json!({
            "delta_XC_mm": t.delta_xc_mm, "delta_YC_mm": t.delta_yc_mm,
            "alpha_XC_deg": t.alpha_xc_deg, "alpha_YC_deg": t.alpha_yc_deg,
            "delta_YA_mm": t.delta_ya_mm, "delta_ZA_mm": t.delta_za_mm,
            "alpha_YA_deg": t.alpha_ya_deg, "alpha_ZA_deg": t.alpha_za_deg,
        })
        .to_string(),
    )
    .unwrap();
    let (path_tx, path_rx) = std::sync::mpsc::channel();
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let controller = std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        let axes =
            AxesMachine::new(Box::new(world::rotary::RotaryWorkpiece { sim: truth })).shared();
        let pty = {
            let _enter = rt.enter();
            GrblPty::spawn(
                GrblDevice::with_axes(axes.clone(), GrblConfig::default()),
                None,
            )
            .unwrap()
        };
        path_tx.send(pty.path().to_string()).unwrap();
        rt.block_on(async {
            let _ = stop_rx.await;
        });
        let at = lock_axes(&axes).position();
        drop(pty);
        at
    });
    let port = path_rx.recv().unwrap();
    let mut gateway = Command::new(env!("CARGO_BIN_EXE_gateway"))
        .args([
            "proxy",
            "--rotary",
            errors.to_str().unwrap(),
            "--controller",
            &port,
            "--once",
            "--json",
        ])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdout = BufReader::new(gateway.stdout.take().unwrap());
    let mut first = String::new();
    stdout.read_line(&mut first).unwrap();
    let hello: serde_json::Value =
        serde_json::from_str(&first).unwrap_or_else(|e| panic!("{e}: {first:?}"));
    let sender_port = hello["sender_port"].as_str().unwrap().to_string();
    let program = "G21 G90 G94\nG0 X10 Y5 Z-170 A0 C0\nG1 X12 Y6 Z-175 A15 C30 F800\n\
                   G1 X-8 Y4 Z-180 A40 C160\nG0 X0 Y0 Z-150 A10 C10\n";
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let (answers, status) = rt.block_on(async {
        use tokio_serial::SerialPortBuilderExt;
        let port = tokio_serial::new(&sender_port, 115_200)
            .open_native_async()
            .unwrap();
        let (read, mut write) = tokio::io::split(port);
        let mut lines = tokio::io::BufReader::new(read).lines();
        let mut answers = Vec::new();
        for line in program.lines() {
            write
                .write_all(format!("{line}\n").as_bytes())
                .await
                .unwrap();
            loop {
                let got =
                    tokio::time::timeout(std::time::Duration::from_secs(30), lines.next_line())
                        .await
                        .expect("an answer")
                        .unwrap()
                        .unwrap();
                let got = got.trim().to_string();
                if got == "ok" || got.starts_with("error:") {
                    answers.push(got);
                    break;
                }
            }
        }
        let status = loop {
            write.write_all(b"?").await.unwrap();
            let got = tokio::time::timeout(std::time::Duration::from_secs(30), lines.next_line())
                .await
                .expect("a report")
                .unwrap()
                .unwrap();
            if got.starts_with("<Idle") {
                break got;
            }
        };
        (answers, status)
    });
    let status_code = gateway.wait().unwrap();
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut stdout, &mut rest).unwrap();
    let _ = stop_tx.send(());
    let at = controller.join().unwrap();
    assert!(status_code.success(), "{rest}");
    assert!(answers.iter().all(|a| a == "ok"), "{answers:?}");
    let session: serde_json::Value = serde_json::from_str(rest.trim()).unwrap();
    assert_eq!(session["ending"], "sender left");
    assert_eq!(session["lines"]["refused"], "none");
    assert!(session["segments_added"].as_u64().unwrap() > 0, "{session}");
    let mpos: Vec<f64> = status
        .split('|')
        .find_map(|f| f.strip_prefix("MPos:"))
        .unwrap()
        .split(',')
        .map(|v| v.parse().unwrap())
        .collect();
    for (got, want) in [mpos[0], mpos[1], mpos[2], mpos[3], mpos[5]]
        .iter()
        .zip([0.0, 0.0, -150.0, 10.0, 10.0])
    {
        assert!((got - want).abs() <= 0.0015, "{status}");
    }
    // The controller's axes are where the correction put them, not on the program.
    assert!(
        (at[0] - 0.0).abs() + (at[1] - 0.0).abs() + (at[2] + 150.0).abs() > 0.05,
        "{at:?}"
    );
}

//! The `gateway` binary as a user runs it: real files in, exit codes and output checked.

use protocol::config::ConfigDoc;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use world::camera::{CameraModel, CameraPose};
use world::render::render;

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
    let dir = std::env::temp_dir().join(format!("gateway-cli-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn camera() -> CameraModel {
    let doc = ConfigDoc::read(&repo().join("config/cameras/mono-1.3mp.toml")).unwrap();
    CameraModel::from_doc(&doc).unwrap()
}

/// Render a frame of the default board at a known pose and save it as PNG.
fn frame_at(dir: &Path, centre_mm: [f64; 2], sixteen_bit: bool) -> PathBuf {
    let board = protocol::Board::load(&repo().join("config/boards/dot-grid-0.5mm.toml")).unwrap();
    let mut cam = camera();
    if sixteen_bit {
        cam.bit_depth = 16;
        cam.noise_sigma *= 257.0;
    }
    let f = render(
        &board,
        &cam,
        &CameraPose {
            centre_mm,
            rotation_rad: 0.0,
        },
        3,
    );
    let path = dir.join(if sixteen_bit {
        "frame16.png"
    } else {
        "frame8.png"
    });
    vision::image_io::save_png(&f.image, &path).unwrap();
    path
}

fn json(out: &Output) -> serde_json::Value {
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "not JSON ({e}): {}\n{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        )
    })
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).to_string()
}

#[test]
fn localize_a_png_frame_8_and_16_bit() {
    let dir = scratch("loc");
    let board = repo().join("config/boards/dot-grid-0.5mm.toml");
    let truth = [52.1234, 40.0567];
    for sixteen in [false, true] {
        let png = frame_at(&dir, truth, sixteen);
        for method in ["fit", "four-point"] {
            let out = gateway(&[
                "localize",
                png.to_str().unwrap(),
                "--board",
                board.to_str().unwrap(),
                "--near",
                "52.1,40.1",
                "--method",
                method,
                "--um-per-px",
                "4",
                "--json",
            ]);
            assert!(out.status.success(), "{}", stderr(&out));
            let v = json(&out);
            let (x, y) = (v["x_mm"].as_f64().unwrap(), v["y_mm"].as_f64().unwrap());
            // The four-point formula has a rotation bias (0.8 deg camera): allow it more.
            let tol_um = if method == "fit" { 0.1 } else { 3.0 };
            assert!(((x - truth[0]) * 1000.0).abs() < tol_um, "{method}: x {x}");
            assert!(((y - truth[1]) * 1000.0).abs() < tol_um, "{method}: y {y}");
            assert!(v["points"].as_u64().unwrap() >= 4);
            assert_eq!(v["method"], method);
            assert!(v["elapsed_ms"].as_f64().unwrap() > 0.0);
        }
    }
}

#[test]
fn localize_refuses_bad_input_with_clear_errors() {
    let dir = scratch("bad");
    let board = repo().join("config/boards/dot-grid-0.5mm.toml");
    let b = board.to_str().unwrap();
    // Not an image.
    let junk = dir.join("junk.png");
    std::fs::write(&junk, b"this is not a png").unwrap();
    let out = gateway(&[
        "localize",
        junk.to_str().unwrap(),
        "--board",
        b,
        "--near",
        "1,1",
    ]);
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("junk.png") && err.contains("not a readable image"),
        "{err}"
    );
    // Missing file.
    let out = gateway(&[
        "localize",
        "/nonexistent/f.png",
        "--board",
        b,
        "--near",
        "1,1",
    ]);
    assert!(stderr(&out).contains("/nonexistent/f.png"));
    // Colour image.
    let rgb = dir.join("rgb.png");
    image::RgbImage::new(64, 64).save(&rgb).unwrap();
    let out = gateway(&[
        "localize",
        rgb.to_str().unwrap(),
        "--board",
        b,
        "--near",
        "1,1",
    ]);
    let err = stderr(&out);
    assert!(err.contains("greyscale") && err.contains("Rgb8"), "{err}");
    // A hint that is not a coordinate.
    let png = frame_at(&dir, [30.0, 30.0], false);
    let out = gateway(&[
        "localize",
        png.to_str().unwrap(),
        "--board",
        b,
        "--near",
        "thirty",
    ]);
    let err = stderr(&out);
    assert!(
        err.contains("--near") && err.contains("`thirty`: expected X,Y in mm"),
        "{err}"
    );
    // A hint 0.15 mm from the truth: beyond the 0.1 mm tolerance, so the dots cannot be
    // identified safely. (A hint off by whole pitches cannot be told apart on a plain
    // grid: that is why the tolerance must stay below half the pitch.)
    let out = gateway(&[
        "localize",
        png.to_str().unwrap(),
        "--board",
        b,
        "--near",
        "30.15,30.0",
        "--json",
    ]);
    assert!(!out.status.success());
    let v = json(&out);
    assert!(v["error"].as_str().unwrap().contains("hint"), "{v}");
    // A blank frame: no board in view.
    let blank = dir.join("blank.png");
    image::GrayImage::from_pixel(640, 512, image::Luma([200u8]))
        .save(&blank)
        .unwrap();
    let out = gateway(&[
        "localize",
        blank.to_str().unwrap(),
        "--board",
        b,
        "--near",
        "30,30",
    ]);
    assert!(!out.status.success());
    assert!(stderr(&out).contains("blank.png"));
}

fn write_job(dir: &Path, body: &str) -> PathBuf {
    let cfg = repo().join("config");
    let text = body.replace("@CONFIG@", cfg.to_str().unwrap());
    let p = dir.join("job.toml");
    std::fs::write(&p, text).unwrap();
    p
}

const SMALL_JOB: &str = r#"
[stage]
driver = "sim"
machine = "@CONFIG@/machines/c5-stage.toml"

[camera]
driver = "sim"
model = "@CONFIG@/cameras/mono-1.3mp.toml"
um_per_px = 4.0

[board]
file = "@CONFIG@/boards/dot-grid-0.5mm.toml"

[setup]
board_at_machine_zero_mm = [5.0, 5.0]

[targets]
points = [[20.0, 30.0], [150.5, 100.25]]
"#;

#[test]
fn compensate_from_a_config_file_prints_the_json_report() {
    let dir = scratch("job");
    let job = write_job(&dir, SMALL_JOB);
    let out = gateway(&["compensate", "--config", job.to_str().unwrap(), "--json"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let v = json(&out);
    assert_eq!(v["targets"], 2);
    assert_eq!(v["method"], "fit");
    assert!(v["after_um"]["max"].as_f64().unwrap() <= 1.0, "{v}");
    assert!(v["before_um"]["max"].as_f64().unwrap() > v["after_um"]["max"].as_f64().unwrap());
    assert!(v["before_um"]["rms"].is_number() && v["after_um"]["rms"].is_number());
    assert_eq!(v["per_target"].as_array().unwrap().len(), 2);
}

#[test]
fn malformed_job_files_name_file_line_and_key() {
    let dir = scratch("badjob");
    let cases = [
        (
            "um_per_px = 4.0",
            "um_per_px = \"four\"",
            "camera.um_per_px",
        ),
        ("[targets]", "[targets]\nspeed = 3", "speed"),
        (
            "board_at_machine_zero_mm = [5.0, 5.0]",
            "board_at_machine_zero_mm = [5.0]",
            "setup.board_at_machine_zero_mm",
        ),
        (
            "driver = \"sim\"\nmodel",
            "driver = \"usb-webcam\"\nmodel",
            "camera.driver",
        ),
    ];
    for (from, to, key) in cases {
        assert!(SMALL_JOB.contains(from), "{from}");
        let job = write_job(&dir, &SMALL_JOB.replacen(from, to, 1));
        let out = gateway(&["compensate", "--config", job.to_str().unwrap()]);
        assert!(!out.status.success());
        let err = stderr(&out);
        assert!(err.contains("job.toml:"), "{err}");
        assert!(err.contains(key), "{key}: {err}");
    }
    // A target off the board, and a referenced file that is missing.
    let job = write_job(
        &dir,
        &SMALL_JOB.replace("[150.5, 100.25]", "[150.5, 400.0]"),
    );
    let err = stderr(&gateway(&["compensate", "--config", job.to_str().unwrap()]));
    assert!(
        err.contains("targets.points") && err.contains("off the board"),
        "{err}"
    );
    let job = write_job(&dir, &SMALL_JOB.replace("c5-stage.toml", "missing.toml"));
    let err = stderr(&gateway(&["compensate", "--config", job.to_str().unwrap()]));
    assert!(
        err.contains("stage.machine") && err.contains("missing.toml"),
        "{err}"
    );
}

//! The localizer on frames from an independent renderer (tests/interop/render_board.py:
//! numpy supersampling, a plane homography with perspective, its own blur, noise and PNG
//! writer), so that it is not tuned to the project's own renderer. The frames go through
//! the `gateway localize` command exactly as a user's camera images would.
//!
//! Perspective: a tilted camera images a disc as an ellipse whose centroid is displaced
//! from the image of the disc's centre by about r^2 * h31 (r the dot radius in pixels,
//! h31 the projective term per pixel). The first case has a strong tilt (2e-5/px, ~18 deg
//! at a 100 mm working distance) with small dots; the second a realistic one (5e-6/px,
//! ~5 deg) with large dots. A large tilt with large dots is outside what the centroid
//! localizer claims.

use std::path::{Path, PathBuf};
use std::process::Command;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .unwrap()
        .to_path_buf()
}

/// Why the Python renderer cannot run here, if it cannot.
fn python_missing() -> Option<String> {
    match Command::new("python3")
        .args(["-c", "import numpy"])
        .output()
    {
        Err(e) => Some(format!("python3 is not runnable: {e}")),
        Ok(o) if !o.status.success() => Some(format!(
            "numpy is not installed for python3 (pip install numpy): {}",
            String::from_utf8_lossy(&o.stderr).trim()
        )),
        Ok(_) => None,
    }
}

fn num(v: &str, key: &str) -> f64 {
    let start = v
        .find(&format!("\"{key}\":"))
        .unwrap_or_else(|| panic!("{key} in {v}"))
        + key.len()
        + 3;
    let rest = &v[start..];
    let end = rest.find([',', '}']).unwrap();
    rest[..end].trim().parse().unwrap()
}

struct Case {
    name: &'static str,
    render_args: &'static [&'static str],
    board: &'static str,
    near: &'static str,
    um_per_px: &'static str,
}

#[test]
fn localizes_frames_from_an_independent_renderer() {
    if let Some(why) = python_missing() {
        panic!("a peer of this test is missing (install every test peer with tests/install-peers.sh, README: Set-up): {why}");
    }
    let dir = std::env::temp_dir().join(format!("foreign-frames-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cases = [
        Case {
            name: "bright dots, 0.4 mm pitch, 3.5 um/px, 1.5 deg, perspective",
            render_args: &[],
            board: "pitch_mm = 0.4\ndot_diameter_mm = 0.15\npolarity = \"bright-on-dark\"",
            near: "20.1,10.1",
            um_per_px: "3.5",
        },
        Case {
            name: "dark dots, 1 mm pitch, 6 um/px, -4 deg, other tilt, more blur",
            render_args: &[
                "--pitch-mm",
                "1.0",
                "--dot-mm",
                "0.5",
                "--polarity",
                "dark-on-light",
                "--um-per-px",
                "6.0",
                "--rotation-deg=-4.0",
                "--tilt-x=-5e-6",
                "--tilt-y=3e-6",
                "--blur",
                "2.0",
                "--noise",
                "4.0",
                "--width",
                "800",
                "--height",
                "600",
                "--x-mm",
                "55.377",
                "--y-mm",
                "31.9021",
                "--seed",
                "5",
            ],
            board: "pitch_mm = 1.0\ndot_diameter_mm = 0.5\npolarity = \"dark-on-light\"",
            near: "55.4,31.85",
            um_per_px: "6.0",
        },
    ];
    for (k, case) in cases.iter().enumerate() {
        let png = dir.join(format!("frame{k}.png"));
        let out = Command::new("python3")
            .arg(repo().join("tests/interop/render_board.py"))
            .arg(&png)
            .args(case.render_args)
            .arg("--json")
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "renderer: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let truth = String::from_utf8(out.stdout).unwrap();
        let board = dir.join(format!("board{k}.toml"));
        std::fs::write(
            &board,
            format!(
                "[board]\n{}\ncols = 200\nrows = 200\norigin_mm = [0.0, 0.0]\n",
                case.board
            ),
        )
        .unwrap();
        let out = Command::new(env!("CARGO_BIN_EXE_gateway"))
            .args([
                "localize",
                png.to_str().unwrap(),
                "--board",
                board.to_str().unwrap(),
            ])
            .args(["--near", case.near, "--um-per-px", case.um_per_px, "--json"])
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}: {}",
            case.name,
            String::from_utf8_lossy(&out.stderr)
        );
        let got = String::from_utf8(out.stdout).unwrap();
        let ex = (num(&got, "x_mm") - num(&truth, "x_mm")) * 1000.0;
        let ey = (num(&got, "y_mm") - num(&truth, "y_mm")) * 1000.0;
        eprintln!("{}: error ({ex:.4}, {ey:.4}) um", case.name);
        // 0.1 um is 0.02-0.03 px here; supersampled coverage is itself only that exact.
        assert!(
            ex.hypot(ey) < 0.1,
            "{}: error ({ex}, {ey}) um\n{got}",
            case.name
        );
    }
}

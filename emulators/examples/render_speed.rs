//! Renderer speed check: milliseconds per frame at the two demo sensor sizes, with blur,
//! noise, illumination and distortion all on (the expensive case).
//!
//! Run with `cargo run --release -p emulators --example render_speed [frames]`.

use protocol::{Board, Polarity};
use std::time::Instant;
use world::camera::{CameraModel, CameraPose};
use world::render::render;

fn camera(width: u32, height: u32, bit_depth: u8) -> CameraModel {
    CameraModel {
        model: "speed".into(),
        width,
        height,
        bit_depth,
        um_per_px: 4.0,
        rotation_deg: 1.5,
        mirrored: false,
        distortion_px_at_corner: 1.6,
        blur_sigma_px: 1.5,
        noise_sigma: 2.0,
        background_level: 0.8,
        dot_level: 0.15,
        illumination_gradient: 0.1,
        illumination_angle_deg: 20.0,
        vignetting: 0.05,
    }
}

fn main() {
    let frames: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(30);
    // 420 x 320 points: a realistic 134k-point plate, so the index-window logic is exercised.
    let board = Board::nominal(
        "speed",
        0.5,
        0.25,
        Polarity::DarkOnLight,
        420,
        320,
        [0.0, 0.0],
    );
    for (w, h, depth, what) in [
        (1280, 1024, 8, "all effects"),
        (1280, 1024, 8, "no noise"),
        (1280, 1024, 8, "no blur"),
        (2448, 2048, 8, "all effects"),
        (2448, 2048, 16, "all effects"),
    ] {
        let mut cam = camera(w, h, depth);
        match what {
            "no noise" => cam.noise_sigma = 0.0,
            "no blur" => cam.blur_sigma_px = 0.0,
            _ => {}
        }
        let mut dots = 0;
        let start = Instant::now();
        for n in 0..frames {
            let pose = CameraPose {
                centre_mm: [50.0 + 0.137 * n as f64, 40.0 + 0.071 * n as f64],
                rotation_rad: 1e-4 * n as f64,
            };
            dots += render(&board, &cam, &pose, n as u64).dots.len();
        }
        let ms = start.elapsed().as_secs_f64() * 1000.0 / frames as f64;
        println!(
            "{w}x{h} {depth}-bit, {what}: {ms:.1} ms/frame over {frames} frames ({} dots/frame)",
            dots / frames
        );
    }
}

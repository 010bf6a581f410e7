//! Test helpers: simulated cameras, boards and frames (from `emulators`, test-only).

use super::Dot;
use protocol::{Board, Polarity};
use world::camera::{CameraModel, CameraPose};
use world::render::{render, RenderedFrame};

/// The acceptance-criteria camera: 4 um/px, 8-bit, with the given size, rotation, blur,
/// noise and distortion, illumination gradient 0.15 and vignetting 0.05.
pub fn camera(w: u32, h: u32, rot_deg: f64, blur: f64, noise: f64, dist_px: f64) -> CameraModel {
    CameraModel {
        model: "test".into(),
        width: w,
        height: h,
        bit_depth: 8,
        um_per_px: 4.0,
        rotation_deg: rot_deg,
        mirrored: false,
        distortion_px_at_corner: dist_px,
        blur_sigma_px: blur,
        noise_sigma: noise,
        background_level: 0.78,
        dot_level: 0.12,
        illumination_gradient: 0.15,
        illumination_angle_deg: 30.0,
        vignetting: 0.05,
    }
}

/// A 0.5 mm pitch, 0.25 mm dot board, 200 x 160 points, with a few points certified
/// away from nominal by a few micrometres (so using the certificate matters).
pub fn board(polarity: Polarity) -> Board {
    let mut b = Board::nominal("test", 0.5, 0.25, polarity, 200, 160, [0.0, 0.0]);
    for (k, (i, j)) in [
        (40u32, 40u32),
        (41, 40),
        (40, 41),
        (41, 41),
        (42, 39),
        (39, 42),
        (60, 50),
    ]
    .iter()
    .enumerate()
    {
        let n = b.nominal_xy(*i as i64, *j as i64);
        let d = 0.001 * (1.0 + k as f64);
        b.set_true_xy(*i, *j, [n[0] + d, n[1] - 0.7 * d]);
    }
    b
}

pub fn frame(board: &Board, cam: &CameraModel, centre_mm: [f64; 2], seed: u64) -> RenderedFrame {
    render(
        board,
        cam,
        &CameraPose {
            centre_mm,
            rotation_rad: 0.0,
        },
        seed,
    )
}

/// Centre errors of detected dots against the renderer's true centres: (RMS of the 2-D
/// error, largest error, number matched). Only listed dots (centre inside the frame) are
/// compared; a detected dot matches the true dot within 2 px.
pub fn dot_errors(f: &RenderedFrame, dots: &[Dot]) -> (f64, f64, usize) {
    let (mut s2, mut mx, mut n) = (0.0, 0.0f64, 0usize);
    for d in dots {
        let best = f
            .dots
            .iter()
            .map(|t| (t.centre_px[0] - d.x).hypot(t.centre_px[1] - d.y))
            .fold(f64::INFINITY, f64::min);
        if best < 2.0 {
            s2 += best * best;
            mx = mx.max(best);
            n += 1;
        }
    }
    ((s2 / n.max(1) as f64).sqrt(), mx, n)
}

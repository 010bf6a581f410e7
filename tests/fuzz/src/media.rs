//! Frames: PNG files as the localizer reads them, and localization on any pixels.

use protocol::{Board, MonoImage, Pixels, Polarity};
use vision::image_io::load_png;
use vision::localize::{localize as locate, LocalizeParams};

/// A PNG file (written to a temporary file of this process: the reader takes a path):
/// a frame that loads is 8- or 16-bit greyscale with as many pixels as it says.
pub fn png_load(data: &[u8]) {
    thread_local! {
        static PATH: std::path::PathBuf = std::env::temp_dir().join(format!(
            "fuzz-png-{}-{:?}.png",
            std::process::id(),
            std::thread::current().id()
        ));
    }
    PATH.with(|path| {
        std::fs::write(path, data).expect("temporary file");
        let loaded = load_png(path);
        let _ = std::fs::remove_file(path);
        match loaded {
            Ok(img) => {
                let n = img.width as usize * img.height as usize;
                let len = match &img.pixels {
                    Pixels::Mono8(p) => p.len(),
                    Pixels::Mono16(p) => p.len(),
                };
                assert_eq!(len, n);
                assert!(matches!(img.bit_depth(), 8 | 16));
            }
            Err(e) => {
                let _ = e.to_string();
            }
        }
    });
}

/// Any pixels: a frame of 8 to 71 pixels each way (two bytes), 8 or 16 bits (the
/// third), the rest of the bytes as its pixels (repeated to fill it), localized on a
/// nominal 0.5 mm board with the default settings, the scale known or not (the fourth
/// byte). The answer is an observation with finite numbers, or a refusal.
pub fn localize(data: &[u8]) {
    let [w, h, depth, scale, pixels @ ..] = data else {
        return;
    };
    let (w, h) = (u32::from(w % 64) + 8, u32::from(h % 64) + 8);
    let n = (w * h) as usize;
    let byte = |k: usize| pixels.get(k % pixels.len().max(1)).copied().unwrap_or(0);
    let img_pixels = if depth % 2 == 0 {
        Pixels::Mono8((0..n).map(byte).collect())
    } else {
        Pixels::Mono16(
            (0..n)
                .map(|k| u16::from_le_bytes([byte(2 * k), byte(2 * k + 1)]))
                .collect(),
        )
    };
    let img = MonoImage::new(w, h, img_pixels).expect("sized above");
    let polarity = if depth & 2 == 0 {
        Polarity::DarkOnLight
    } else {
        Polarity::BrightOnDark
    };
    let board = Board::nominal("fuzz", 0.5, 0.25, polarity, 40, 40, [0.0, 0.0]);
    let mut params = LocalizeParams::new([5.0, 5.0]);
    params.um_per_px = match scale % 3 {
        0 => None,
        1 => Some(50.0),
        _ => Some(f64::from(*scale) + 0.5),
    };
    if let Ok(obs) = locate(&img, &board, &params) {
        for v in [
            obs.x_mm,
            obs.y_mm,
            obs.residual_rms_um,
            obs.um_per_px,
            obs.rotation_deg,
        ] {
            assert!(v.is_finite(), "{obs:?}");
        }
        assert!(obs.points >= 4, "{obs:?}");
    }
}

//! The live view's frame: a localized camera frame made into a small 8-bit grey PNG and
//! a JSON overlay (the detected dots and the measured point in the thumbnail's pixels).

use crate::FrameThumb;
use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::{ExtendedColorType, ImageEncoder};
use protocol::{MonoImage, Pixels};
use runner::FrameSeen;
use serde_json::json;

/// The thumbnail's largest width, pixels.
pub const THUMB_MAX_WIDTH: u32 = 320;

/// The thumbnail of a localized frame: the image reduced by a whole factor (the mean of
/// each k x k block; 16-bit frames scaled so the brightest pixel is 255) to at most
/// [`THUMB_MAX_WIDTH`] wide, and the overlay: `width`, `height`, `source_width`,
/// `source_height`, `factor`, `dots` (each detected centre in thumbnail pixels, pixel
/// centres at integers as in the frame), `centre_px` (the measured point: the image
/// centre), `centre_mm` (its board coordinate), `target_mm`, `target_index`,
/// `deviation_um` (measured minus target) and `sequence`.
pub fn thumbnail(seen: &FrameSeen<'_>) -> Result<FrameThumb, crate::Error> {
    let img = seen.image;
    let k = img.width.div_ceil(THUMB_MAX_WIDTH).max(1);
    let (w, h) = ((img.width / k).max(1), (img.height / k).max(1));
    let grey = reduce(img, k, w, h);
    let mut png = Vec::with_capacity((w * h) as usize / 2);
    PngEncoder::new_with_quality(&mut png, CompressionType::Fast, FilterType::Sub)
        .write_image(&grey, w, h, ExtendedColorType::L8)
        .map_err(|e| crate::Error::Output(format!("frame thumbnail: {e}")))?;
    let to_thumb = |p: f64| (p + 0.5) / k as f64 - 0.5;
    let round = |v: f64| (v * 100.0).round() / 100.0;
    let dots: Vec<[f64; 2]> = seen
        .dots_px
        .iter()
        .map(|d| [round(to_thumb(d[0])), round(to_thumb(d[1]))])
        .collect();
    let centre = [
        (img.width as f64 - 1.0) / 2.0,
        (img.height as f64 - 1.0) / 2.0,
    ];
    let deviation_um = seen.target_mm.map(|t| {
        [
            round((seen.centre_mm[0] - t[0]) * 1000.0),
            round((seen.centre_mm[1] - t[1]) * 1000.0),
        ]
    });
    let overlay = json!({
        "width": w,
        "height": h,
        "source_width": img.width,
        "source_height": img.height,
        "factor": k,
        "dots": dots,
        "centre_px": [round(to_thumb(centre[0])), round(to_thumb(centre[1]))],
        "centre_mm": seen.centre_mm,
        "target_mm": seen.target_mm,
        "target_index": seen.target_index,
        "deviation_um": deviation_um,
        "sequence": seen.sequence,
    });
    Ok(FrameThumb {
        png,
        width: w,
        height: h,
        overlay,
    })
}

/// The mean of each k x k block, 8-bit.
fn reduce(img: &MonoImage, k: u32, w: u32, h: u32) -> Vec<u8> {
    let (sw, k) = (img.width as usize, k as usize);
    let n = (k * k) as u64;
    let mut out = Vec::with_capacity((w * h) as usize);
    let max16 = match &img.pixels {
        Pixels::Mono16(p) => u64::from(p.iter().copied().max().unwrap_or(0).max(1)),
        Pixels::Mono8(_) => 255,
    };
    for ty in 0..h as usize {
        for tx in 0..w as usize {
            let mut sum = 0u64;
            for y in ty * k..ty * k + k {
                let row = y * sw + tx * k;
                sum += match &img.pixels {
                    Pixels::Mono8(p) => p[row..row + k].iter().map(|&v| u64::from(v)).sum::<u64>(),
                    Pixels::Mono16(p) => p[row..row + k].iter().map(|&v| u64::from(v)).sum::<u64>(),
                };
            }
            out.push(((sum * 255 + n * max16 / 2) / (n * max16)).min(255) as u8);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thumbnail_downscales_and_scales_the_dots() {
        // 1280 x 960, dark square at (640..660, 480..500): factor 4, 320 x 240.
        let (w, h) = (1280u32, 960u32);
        let mut p = vec![200u8; (w * h) as usize];
        for y in 480..500 {
            for x in 640..660 {
                p[y * w as usize + x] = 0;
            }
        }
        let img = MonoImage {
            width: w,
            height: h,
            pixels: Pixels::Mono8(p),
        };
        let dots = [[649.5, 489.5], [0.0, 0.0], [1279.0, 959.0]];
        let seen = FrameSeen {
            image: &img,
            sequence: 7,
            dots_px: &dots,
            centre_mm: [10.001, 20.0],
            target_mm: Some([10.0, 20.0]),
            target_index: Some(0),
        };
        let t = thumbnail(&seen).unwrap();
        assert_eq!((t.width, t.height), (320, 240));
        let o = &t.overlay;
        assert_eq!(o["factor"], 4);
        assert_eq!(o["dots"][0], json!([162.0, 122.0]));
        assert_eq!(o["dots"][1], json!([-0.38, -0.38]));
        assert_eq!(o["dots"][2], json!([319.38, 239.38]));
        assert_eq!(o["centre_px"], json!([159.5, 119.5]));
        assert_eq!(o["deviation_um"], json!([1.0, 0.0]));
        assert_eq!(o["sequence"], 7);
        // The PNG decodes to the thumbnail: 8-bit grey, the square dark, the rest 200.
        let back = image::load_from_memory(&t.png).unwrap();
        assert_eq!(back.color(), image::ColorType::L8);
        let g = back.to_luma8();
        assert_eq!((g.width(), g.height()), (320, 240));
        assert_eq!(g.get_pixel(162, 122).0[0], 0);
        assert_eq!(g.get_pixel(10, 10).0[0], 200);
        assert!(t.png.len() < 20_000, "{} bytes", t.png.len());
    }
}

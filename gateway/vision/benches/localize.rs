//! Localizer benchmark: speed on one core and accuracy over a sweep of camera conditions.
//!
//! `cargo bench -p vision --bench localize`
//!
//! Frames are rendered once (by `world::render`, which also gives the true dot
//! centres and the true position), then `localize()` is timed on the decoded frame, many
//! times, and reported as median, 90th percentile and minimum. A plain pass over the
//! same frame (summing every pixel) is timed in the same loop, interleaved, so the ratio
//! says how many "frame reads" the localizer costs independent of the machine and of
//! load from other processes. The machine may be shared: medians, not means.
//!
//! Environment:
//! * `LOCALIZE_BENCH_RUNS`: timed runs (default 101, at least 50 for the speed table);
//! * `LOCALIZE_BENCH_ONLY=speed` or `=accuracy`: run one half;
//! * `LOCALIZE_BENCH_ONLY=loop`: only call `localize()` `LOCALIZE_BENCH_RUNS` times on one
//!   frame (camera file `LOCALIZE_BENCH_CAMERA`, default `mono-5mp.toml`), for profilers
//!   such as `perf record` or `valgrind --tool=cachegrind`.

use protocol::{Board, MonoImage, Pixels, Polarity};
use std::hint::black_box;
use std::path::Path;
use std::time::Instant;
use vision::localize::{detect_dots, localize, LocalizeParams, Method};
use world::camera::{CameraModel, CameraPose};
use world::plate::{manufacture, PlateErrors};
use world::render::{render, RenderedFrame};

fn board() -> Board {
    let mut b = Board::nominal(
        "bench",
        0.5,
        0.25,
        Polarity::DarkOnLight,
        200,
        160,
        [0.0, 0.0],
    );
    manufacture(&mut b, PlateErrors::default(), 11);
    b
}

fn load_camera(file: &str) -> CameraModel {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../config/cameras")
        .join(file);
    match CameraModel::load(&path) {
        Ok(c) => c,
        Err(e) => panic!("cannot load {}: {e}", path.display()),
    }
}

/// Sum of all pixels: the cheapest thing that reads the whole frame once (u32 partial
/// sums per chunk so that the compiler vectorises it; a u64 running sum would make this
/// "plain pass" several times slower than it needs to be and flatter the ratio).
fn plain_pass(img: &MonoImage) -> u64 {
    match &img.pixels {
        Pixels::Mono8(p) => p
            .chunks(1 << 16)
            .map(|c| c.iter().map(|&v| v as u32).sum::<u32>() as u64)
            .sum(),
        Pixels::Mono16(p) => p
            .chunks(1 << 15)
            .map(|c| c.iter().map(|&v| v as u32).sum::<u32>() as u64)
            .sum(),
    }
}

/// Median, 90th percentile and minimum of timings (ms).
fn stats(mut t: Vec<f64>) -> (f64, f64, f64) {
    t.sort_by(|a, b| a.total_cmp(b));
    (t[t.len() / 2], t[(t.len() * 9 / 10).min(t.len() - 1)], t[0])
}

fn time_once(f: &mut impl FnMut()) -> f64 {
    let s = Instant::now();
    f();
    s.elapsed().as_secs_f64() * 1e3
}

fn speed(runs: usize) {
    println!(
        "== speed (one core, release, frame already decoded; {runs} runs each, interleaved) =="
    );
    println!(
        "   times in ms as median / p90 / min; the machine may be shared, so medians, not means"
    );
    let b = board();
    let cams = [
        ("mono-1.3mp.toml", None),
        ("mono-5mp.toml", None),
        ("mono-5mp.toml", Some(8u8)),
    ];
    for (file, bits) in cams {
        let mut cam = load_camera(file);
        if let Some(bits) = bits {
            cam.bit_depth = bits;
            cam.noise_sigma = 2.3;
        }
        let truth = [40.1234, 30.5678];
        let f = render(
            &b,
            &cam,
            &CameraPose {
                centre_mm: truth,
                rotation_rad: 0.0,
            },
            5,
        );
        let mut p = LocalizeParams::new([truth[0] + 0.02, truth[1] - 0.03]);
        p.um_per_px = Some(cam.um_per_px);
        let o = match localize(&f.image, &b, &p) {
            Ok(o) => o,
            Err(e) => {
                println!("{file}: localize failed: {e}");
                continue;
            }
        };
        let err = (o.x_mm - truth[0]).hypot(o.y_mm - truth[1]) * 1e3;
        let p_none = LocalizeParams {
            um_per_px: None,
            ..p.clone()
        };
        let mut loc = || {
            black_box(localize(black_box(&f.image), &b, &p).ok());
        };
        let mut loc_none = || {
            black_box(localize(black_box(&f.image), &b, &p_none).ok());
        };
        let mut det = || {
            black_box(detect_dots(black_box(&f.image), Polarity::DarkOnLight));
        };
        let mut plain = || {
            black_box(plain_pass(black_box(&f.image)));
        };
        // Warm up, then interleave so that load from other processes hits all alike.
        loc();
        plain();
        let (mut t_loc, mut t_none, mut t_det, mut t_plain) = (vec![], vec![], vec![], vec![]);
        for _ in 0..runs {
            t_loc.push(time_once(&mut loc));
            t_plain.push(time_once(&mut plain));
            t_none.push(time_once(&mut loc_none));
            t_det.push(time_once(&mut det));
        }
        let (l, lp, lm) = stats(t_loc);
        let (n, np, nm) = stats(t_none);
        let (d, dp, dm) = stats(t_det);
        let (s, sp, sm) = stats(t_plain);
        println!(
            "{}x{} {:>2}-bit, {} dots used, error {:.4} um:",
            cam.width,
            cam.height,
            f.image.bit_depth(),
            o.points,
            err
        );
        println!("   localize (nominal scale given) {l:.3} / {lp:.3} / {lm:.3}");
        println!("   localize (scale unknown)       {n:.3} / {np:.3} / {nm:.3}");
        println!("   detect_dots alone (no scale)   {d:.3} / {dp:.3} / {dm:.3}");
        println!("   plain pass (sum of pixels)     {s:.3} / {sp:.3} / {sm:.3}");
        println!(
            "   ratio localize / plain pass    {:.1} (medians), {:.1} (minima)",
            l / s,
            lm / sm
        );
    }
}

/// Dot-centre errors (px) of one frame against the renderer's true centres.
fn dot_errors(f: &RenderedFrame) -> Vec<f64> {
    let dots = detect_dots(&f.image, Polarity::DarkOnLight);
    dots.iter()
        .filter_map(|d| {
            let e = f
                .dots
                .iter()
                .map(|t| (t.centre_px[0] - d.x).hypot(t.centre_px[1] - d.y))
                .fold(f64::INFINITY, f64::min);
            (e < 2.0).then_some(e)
        })
        .collect()
}

#[derive(Default)]
struct Stats {
    dot_sq: f64,
    dots: usize,
    fit: Vec<f64>,
    four: Vec<f64>,
    refused: usize,
}

impl Stats {
    fn add(&mut self, o: &Stats) {
        self.dot_sq += o.dot_sq;
        self.dots += o.dots;
        self.fit.extend(&o.fit);
        self.four.extend(&o.four);
        self.refused += o.refused;
    }
    fn dot_rms(&self) -> f64 {
        (self.dot_sq / self.dots.max(1) as f64).sqrt()
    }
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

fn max(v: &[f64]) -> f64 {
    v.iter().copied().fold(0.0, f64::max)
}

fn accuracy() {
    println!();
    println!("== accuracy: 1280x1024 8-bit, 4 um/px, pitch 0.5 mm, dots 0.25 mm, gradient 0.15, vignetting 0.05, certified plate ==");
    println!("   errors against the renderer's truth; centre errors are the 2-D distance, um; 3 sub-pixel poses per row");
    let b = board();
    let poses = [[40.1234, 30.5678], [40.3101, 30.4417], [40.0625, 30.1876]];
    println!(
        "{:>7} {:>5} {:>6} {:>5} | {:>12} | {:>9} {:>9} | {:>9} {:>9}",
        "rot_deg",
        "blur",
        "noise",
        "dist",
        "dot_rms_px",
        "fit_mean",
        "fit_max",
        "4pt_mean",
        "4pt_max"
    );
    let mut all = Stats::default();
    let mut by_rot: Vec<(f64, Stats)> = Vec::new();
    for rot in [0.0, 0.5, 1.0, 2.0] {
        let mut rs = Stats::default();
        for blur in [0.7, 1.5] {
            for noise in [2.0, 4.0] {
                for dist in [0.0, 1.6] {
                    let mut cam = load_camera("mono-1.3mp.toml");
                    cam.rotation_deg = rot;
                    cam.blur_sigma_px = blur;
                    cam.noise_sigma = noise;
                    cam.distortion_px_at_corner = dist;
                    cam.illumination_gradient = 0.15;
                    cam.vignetting = 0.05;
                    let mut s = Stats::default();
                    for (k, truth) in poses.iter().enumerate() {
                        let f = render(
                            &b,
                            &cam,
                            &CameraPose {
                                centre_mm: *truth,
                                rotation_rad: 0.0,
                            },
                            100 + k as u64,
                        );
                        for e in dot_errors(&f) {
                            s.dot_sq += e * e;
                            s.dots += 1;
                        }
                        let hint = [truth[0] - 0.04, truth[1] + 0.05];
                        let mut p = LocalizeParams::new(hint);
                        p.um_per_px = Some(4.0);
                        match localize(&f.image, &b, &p) {
                            Ok(o) => s
                                .fit
                                .push((o.x_mm - truth[0]).hypot(o.y_mm - truth[1]) * 1e3),
                            Err(e) => {
                                println!("   refused (fit): {e}");
                                s.refused += 1;
                            }
                        }
                        p.method = Method::FourPoint;
                        match localize(&f.image, &b, &p) {
                            Ok(o) => s
                                .four
                                .push((o.x_mm - truth[0]).hypot(o.y_mm - truth[1]) * 1e3),
                            Err(e) => {
                                println!("   refused (four-point): {e}");
                                s.refused += 1;
                            }
                        }
                    }
                    println!(
                        "{:>7.1} {:>5.1} {:>6.1} {:>5.1} | {:>12.4} | {:>9.4} {:>9.4} | {:>9.3} {:>9.3}",
                        rot,
                        blur,
                        noise,
                        dist,
                        s.dot_rms(),
                        mean(&s.fit),
                        max(&s.fit),
                        mean(&s.four),
                        max(&s.four)
                    );
                    rs.add(&s);
                }
            }
        }
        all.add(&rs);
        by_rot.push((rot, rs));
    }
    println!();
    println!("per rotation (four-point bias grows with rotation; the fit does not):");
    for (rot, s) in &by_rot {
        println!(
            "  rotation {rot:.1} deg: dot RMS {:.4} px | fit mean {:.4} um, max {:.4} um | four-point mean {:.3} um, max {:.3} um",
            s.dot_rms(),
            mean(&s.fit),
            max(&s.fit),
            mean(&s.four),
            max(&s.four)
        );
    }
    println!(
        "overall ({} frames, {} dots): dot RMS {:.4} px (2-D; per axis {:.4} px) | fit mean {:.4} um, max {:.4} um | four-point mean {:.3} um, max {:.3} um | refused {}",
        all.fit.len(),
        all.dots,
        all.dot_rms(),
        all.dot_rms() / std::f64::consts::SQRT_2,
        mean(&all.fit),
        max(&all.fit),
        mean(&all.four),
        max(&all.four),
        all.refused
    );
}

fn main() {
    // `cargo bench` passes `--bench`: harness-style arguments are ignored.
    let runs: usize = std::env::var("LOCALIZE_BENCH_RUNS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(101);
    let only = std::env::var("LOCALIZE_BENCH_ONLY").unwrap_or_default();
    if only == "loop" {
        // For `perf stat`: localize the 5 MP 16-bit frame `runs` times, nothing else.
        let b = board();
        let cam =
            load_camera(&std::env::var("LOCALIZE_BENCH_CAMERA").unwrap_or("mono-5mp.toml".into()));
        let truth = [40.1234, 30.5678];
        let f = render(
            &b,
            &cam,
            &CameraPose {
                centre_mm: truth,
                rotation_rad: 0.0,
            },
            5,
        );
        let mut p = LocalizeParams::new(truth);
        p.um_per_px = Some(cam.um_per_px);
        let t = Instant::now();
        for _ in 0..runs {
            black_box(localize(black_box(&f.image), &b, &p).ok());
        }
        println!(
            "loop: {:.3} ms per call (wall)",
            t.elapsed().as_secs_f64() * 1e3 / runs as f64
        );
        return;
    }
    if only != "accuracy" {
        speed(runs.max(50));
    }
    if only != "speed" {
        accuracy();
    }
}

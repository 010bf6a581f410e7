//! GigE Vision benchmark: frames per second and latency from the software trigger to a
//! received frame and to a localized observation, at 1.3 MP (1280 x 1024) and 5 MP
//! (2448 x 2048), Mono8.
//!
//! `cargo bench -p gateway --bench gige` (env `GIGE_BENCH_FRAMES`, default 20 per size)
//!
//! Set-up: the demo job's simulated machine, its camera served by the GigE Vision
//! emulator on a loopback UDP port (8192-byte packets), read by the pure-Rust `gige`
//! driver — the same path as `gateway demo --camera gige`. Each frame: TriggerSoftware
//! (WRITEREG), the emulator renders the board at the machine's pose at that moment and
//! streams it (GVSP), the driver reassembles it, then `localize()` runs on it. The
//! rendering is the emulator's (a real camera exposes instead), so the table also gives
//! the render time alone and the difference (the GigE link: protocol, copies, sockets).
//! Medians and 90th percentiles: the machine may be shared.

use devices::open_devices_async;
use job::demo::over_gige;
use job::{CameraSpec, Job};
use std::path::Path;
use std::time::Instant;
use vision::localize::localize;

fn pct(v: &mut [f64], p: f64) -> f64 {
    v.sort_by(|a, b| a.partial_cmp(b).unwrap());
    v[((v.len() - 1) as f64 * p).round() as usize]
}

fn main() {
    let frames: usize = std::env::var("GIGE_BENCH_FRAMES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(20)
        .max(3);
    let cams = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/cameras");
    println!("GigE Vision loop, {frames} frames per size, Mono8, 8192-byte packets on loopback");
    println!(
        "{:>11} | {:>7} | {:>16} | {:>16} | {:>16} | {:>16}",
        "size", "fps", "render p50/p90", "trigger->frame", "link only p50", "->observation"
    );
    for (file, w, h) in [
        ("mono-1.3mp.toml", 1280, 1024),
        ("mono-5mp.toml", 2448, 2048),
    ] {
        let mut model = world::camera::CameraModel::load(&cams.join(file)).unwrap();
        assert_eq!((model.width, model.height), (w, h));
        if model.bit_depth == 16 {
            model.bit_depth = 8;
            model.noise_sigma /= 257.0;
        }
        let mut job = Job::demo();
        job.um_per_px = Some(model.um_per_px);
        job.camera = CameraSpec::Sim {
            model: model.clone(),
        };
        over_gige(&mut job).expect("the demo job runs over GigE");
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .unwrap();
        let (mut render, mut grab, mut obs, total) = rt.block_on(async {
            let mut dev = open_devices_async(&job).await.expect("open");
            dev.stage.home().await.unwrap();
            let target = [60.0, 50.0];
            let z = job.board_at_machine_zero_mm;
            dev.stage
                .move_to(
                    drivers::AxisValues::xy(target[0] - z[0], target[1] - z[1]),
                    job.feed_mm_min,
                )
                .await
                .unwrap();
            dev.stage.wait_idle().await.unwrap();
            let rig = dev.rig.clone().unwrap();
            let p = job.localize_params(target);
            let (mut render, mut grab, mut obs) = (Vec::new(), Vec::new(), Vec::new());
            // One warm-up frame.
            dev.camera.grab().await.unwrap();
            let all = Instant::now();
            for _ in 0..frames {
                let t = Instant::now();
                let f = dev.camera.grab().await.unwrap();
                let t_frame = t.elapsed().as_secs_f64() * 1e3;
                let o = localize(&f.image, &job.board, &p).expect("localized");
                std::hint::black_box(o);
                obs.push(t.elapsed().as_secs_f64() * 1e3);
                grab.push(t_frame);
            }
            let total = all.elapsed().as_secs_f64();
            // The render alone, on a copy of the rig in the same state.
            for _ in 0..frames.min(10) {
                let mut r = world::lock(&rig).clone();
                let t = Instant::now();
                std::hint::black_box(r.grab());
                render.push(t.elapsed().as_secs_f64() * 1e3);
            }
            (render, grab, obs, total)
        });
        let r50 = pct(&mut render, 0.5);
        let g50 = pct(&mut grab, 0.5);
        println!(
            "{:>4}x{:<6} | {:>7.1} | {:>7.1}/{:>5.1} ms | {:>7.1}/{:>5.1} ms | {:>11.1} ms | {:>7.1}/{:>5.1} ms",
            w,
            h,
            frames as f64 / total,
            r50,
            pct(&mut render, 0.9),
            g50,
            pct(&mut grab, 0.9),
            g50 - r50,
            pct(&mut obs, 0.5),
            pct(&mut obs, 0.9),
        );
    }
}

//! Streaming throughput and command latency through the GRBL driver and the GRBL
//! emulator over a real pseudo-terminal, with the motion clock unconstrained (so the
//! figures measure the protocol path: driver, pty, emulator), compared with what a
//! 115200-baud serial line allows for the same bytes.
//!
//! Run: `cargo bench -p drivers --bench grbl_stream`

use drivers::grbl::{GrblOptions, GrblStage, StreamOptions};
use drivers::Stage;
use emulators::grbl::{GrblConfig, GrblDevice, GrblPty};
use protocol::grbl::gcode::filter_line;
use protocol::grbl::Command;
use protocol::Board;
use std::path::Path;
use std::time::{Duration, Instant};
use world::camera::CameraModel;
use world::machine::MachineConfig;
use world::Clock;

/// 115200 baud, 8N1: 10 bits per byte.
const BAUD_BYTES_PER_S: f64 = 115_200.0 / 10.0;

fn percentile(sorted: &[f64], p: f64) -> f64 {
    let i = ((sorted.len() as f64 - 1.0) * p).round() as usize;
    sorted[i]
}

fn main() {
    let cfg = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config");
    let m = MachineConfig::load(&cfg.join("machines/c5-stage.toml")).unwrap();
    let c = CameraModel::load(&cfg.join("cameras/mono-1.3mp.toml")).unwrap();
    let b = Board::load(&cfg.join("boards/dot-grid-0.5mm.toml")).unwrap();
    let rig = world::shared_rig(m, b, c);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async move {
        let dev = GrblDevice::new(rig, GrblConfig { clock: Clock::Unconstrained, ..Default::default() });
        let emu = GrblPty::spawn(dev, None).unwrap();
        let opts = GrblOptions { poll_interval: Duration::from_millis(1), ..Default::default() };
        let mut g = GrblStage::open(emu.path(), 115_200, opts).await.unwrap();
        g.home().await.unwrap();
        g.command(&Command::WriteSetting(10, 3.0)).await.unwrap();

        // Streaming: a 20 000-line program of short moves.
        let n = 20_000;
        let mut prog = String::new();
        for i in 0..n {
            let x = 10.0 + (i % 200) as f64 * 0.25;
            let y = 10.0 + ((i / 200) % 100) as f64 * 0.25;
            prog.push_str(&format!("G1X{x:.3}Y{y:.3}F3000\n"));
        }
        let bytes: usize = prog.lines().map(|l| filter_line(l).unwrap().len() + 1).sum();
        let sopts = StreamOptions {
            preflight: false,
            wait_until_executed: false,
            status_interval: Duration::from_millis(20),
            ..Default::default()
        };
        let t = Instant::now();
        let report = g.stream_program(&prog, &sopts, &mut |_| {}).await.unwrap();
        let dt = t.elapsed().as_secs_f64();
        assert_eq!(report.progress.acknowledged, n);
        let lines_s = n as f64 / dt;
        let avg = bytes as f64 / n as f64;
        let baud_lines_s = BAUD_BYTES_PER_S / avg;
        println!("streaming: {n} lines, {bytes} bytes ({avg:.1} bytes/line) in {dt:.3} s");
        println!("  {lines_s:.0} lines/s, {:.0} bytes/s; planner min free blocks {:?}, max in flight {} bytes",
            bytes as f64 / dt, report.min_free_blocks, report.max_in_flight_bytes);
        println!("  a 115200-baud line carries {BAUD_BYTES_PER_S:.0} bytes/s = {baud_lines_s:.0} lines/s of these lines");
        println!("  ratio pty / 115200 baud: {:.1}x", lines_s / baud_lines_s);
        g.wait_idle().await.unwrap();

        // Round trips: a send-response line GRBL executes without motion, and `?`.
        for (name, k) in [("send-response `G90`", 0), ("status `?`", 1)] {
            let mut v = Vec::new();
            for _ in 0..2000 {
                let t = Instant::now();
                if k == 0 {
                    g.command(&Command::Gcode("G90".into())).await.unwrap();
                } else {
                    g.status_report().await.unwrap();
                }
                v.push(t.elapsed().as_secs_f64() * 1e6);
            }
            v.sort_by(|a, b| a.partial_cmp(b).unwrap());
            let wire = if k == 0 { 4.0 + 4.0 } else { 1.0 + 60.0 };
            println!(
                "round trip {name}: median {:.0} us, p90 {:.0} us (on a 115200-baud line the bytes alone take {:.0} us)",
                percentile(&v, 0.5),
                percentile(&v, 0.9),
                wire / BAUD_BYTES_PER_S * 1e6
            );
        }
        drop(emu);
    });
}

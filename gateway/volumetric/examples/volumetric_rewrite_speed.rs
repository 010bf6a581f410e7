//! Rewrite speed with the volumetric model:
//! `cargo run --release -p volumetric --example volumetric_rewrite_speed -- [LINES] [T_UM]`.
//!
//! Identifies the model of the emulated XYFZ machine from its simulated campaign, then
//! rewrites a generated 3-axis program of LINES lines (default 100 000: short feed moves
//! of 0.2 to 2 mm wandering through the volume, a long diagonal every 500 lines) at
//! tolerance T_UM (default 0.5 µm) on one thread, and prints the time.

use protocol::volumetric::Structure;
use rewrite::{rewrite_program, Options};
use std::fmt::Write;
use std::time::Instant;
use volumetric::identify::{identify, Campaign};
use world::volumetric::VolumetricMachine;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let lines: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(100_000);
    let t_um: f64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(0.5);
    let machine = VolumetricMachine::new(Structure::Xyfz, 1);
    let files = machine.campaign(1);
    let campaign = Campaign::from_files(&files).expect("campaign parses");
    let model = identify(Structure::Xyfz, &campaign)
        .expect("identifies")
        .model;

    let mut rng = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        (rng >> 11) as f64 / (1u64 << 53) as f64
    };
    let (lo, hi) = ([5.0, 5.0, 5.0], [495.0, 395.0, 395.0]);
    let mut p = [250.0, 200.0, 200.0];
    let (mut heading, mut climb): (f64, f64) = (0.0, 0.0);
    let mut program = String::from("G21 G90\nG0 X250 Y200 Z200\nG1 F1200\n");
    for n in 3..lines {
        if n % 500 == 0 {
            p = std::array::from_fn(|a| lo[a] + next() * (hi[a] - lo[a]));
        } else {
            heading += (next() - 0.5) * 0.6;
            climb = (climb + (next() - 0.5) * 0.2).clamp(-0.5, 0.5);
            let step = 0.2 + 1.8 * next();
            let d = [heading.cos() * step, heading.sin() * step, climb * step];
            for a in 0..3 {
                p[a] += d[a];
                if p[a] < lo[a] || p[a] > hi[a] {
                    p[a] -= 2.0 * d[a];
                    if a < 2 {
                        heading += std::f64::consts::PI / 2.0;
                    } else {
                        climb = -climb;
                    }
                }
            }
        }
        writeln!(program, "X{:.3} Y{:.3} Z{:.3}", p[0], p[1], p[2]).unwrap();
    }
    let options = Options {
        tolerance_mm: t_um / 1000.0,
        ..Options::default()
    };
    let started = Instant::now();
    let (out, report) = rewrite_program(&program, &model, options).expect("rewrite");
    let secs = started.elapsed().as_secs_f64();
    println!(
        "{} lines in, {} out ({} segments added, {} moves corrected), largest correction {:.2} um, T = {t_um} um: {secs:.3} s ({:.0} lines/s), {} bytes out",
        report.input_lines,
        report.output_lines,
        report.segments_added,
        report.moves_compensated,
        report.largest_correction_um,
        report.input_lines as f64 / secs,
        out.len()
    );
}

//! Benchmark: exact vs first-order volumetric error (largest difference over a grid), and
//! evaluation speed on one core. Run with
//! `cargo run --release -p volumetric --example volumetric_speed`.

use protocol::volumetric::{AxisTable, Structure};
use std::hint::black_box;
use std::time::Instant;
use volumetric::Model;

/// A model of realistic size (30 µm positioning, 10 µm straightness, 30 µrad angles,
/// 30 µrad squareness), tables every 25 mm.
fn model(structure: Structure) -> Model {
    let travel = [500.0, 400.0, 400.0];
    let mut m = Model::zero(structure, travel);
    m.file.tool_offset_mm = [0.0, 0.0, 150.0];
    m.file.squareness_rad = [30e-6, -25e-6, 20e-6];
    for a in 0..3 {
        let n = (travel[a] / 25.0) as usize + 1;
        let positions: Vec<f64> = (0..n).map(|i| 25.0 * i as f64).collect();
        let errors = positions
            .iter()
            .map(|&q| {
                let u = q / travel[a];
                let w = |k: f64| (std::f64::consts::TAU * k * u).sin();
                [
                    0.03 * u,
                    0.01 * w(1.0),
                    -0.008 * w(1.5),
                    25e-6 * w(1.0),
                    -30e-6 * w(0.8),
                    28e-6 * w(1.2),
                ]
            })
            .collect();
        m.file.tables[a] = AxisTable {
            positions_mm: positions,
            errors,
        };
    }
    m
}

fn main() {
    for s in Structure::ALL {
        let m = model(s);
        let mut worst: f64 = 0.0;
        for i in 0..=50 {
            for j in 0..=40 {
                for k in 0..=40 {
                    let q = [10.0 * i as f64, 10.0 * j as f64, 10.0 * k as f64];
                    let a = m.error_exact(q).unwrap();
                    let b = m.error_first_order(q).unwrap();
                    for c in 0..3 {
                        worst = worst.max((a[c] - b[c]).abs());
                    }
                }
            }
        }
        println!(
            "{s}: exact vs first order, largest difference over 51x41x41 points: {:.5} µm",
            worst * 1e3
        );
    }
    let m = model(Structure::Xyfz);
    let n = 2_000_000;
    let pts: Vec<[f64; 3]> = (0..n)
        .map(|i| {
            let t = i as f64 / n as f64;
            [
                500.0 * t,
                400.0 * (t * 7.3).fract(),
                400.0 * (t * 13.7).fract(),
            ]
        })
        .collect();
    for (name, first) in [("first order", true), ("exact", false)] {
        let start = Instant::now();
        let mut acc = 0.0;
        for q in &pts {
            acc += m.error(black_box(*q), first).unwrap()[0];
        }
        let dt = start.elapsed().as_secs_f64();
        black_box(acc);
        println!(
            "{name}: {:.2} million points/s on one core",
            n as f64 / dt / 1e6
        );
    }
    let start = Instant::now();
    for q in pts.iter().take(200_000) {
        black_box(m.command_for(*q).ok());
    }
    println!(
        "inverse (command_for): {:.0} thousand points/s",
        200_000.0 / start.elapsed().as_secs_f64() / 1e3
    );
}

//! The coded board's figures (issue 28, `docs/coded-board.md`): decoding over a sweep of
//! the whole 200 x 150 mm travel at the default optics, clean and with 5 % of the dots
//! damaged, the centre error on rendered frames, and what decoding costs.
//!
//! `cargo run --release -p vision --example coded_sweep`
//!
//! Environment: `CODED_SWEEP_STEP_MM` (grid step of the sweep, default 5 mm: 41 x 31
//! frames), `CODED_SWEEP_DAMAGE` (fraction of damaged dots, default 0.05),
//! `CODED_SWEEP_RUNS` (timed runs per board, default 41), `CODED_SWEEP_SPEED_ONLY` (set:
//! the speed line alone).
//!
//! Frames come from `world::render` with the camera file `config/cameras/mono-1.3mp.toml`
//! and the board files `config/boards/coded-0.5mm.toml` (certified) and
//! `dot-grid-0.5mm.toml`; positions are the image centre on the board, machine zero at
//! board (5, 5) as in `config/gateway/demo.toml`, with a sub-pitch offset drawn for
//! each frame so every phase of the grid is seen.

use protocol::Board;
use std::path::Path;
use std::time::Instant;
use vision::localize::code::{decode, decode_exhaustive, ORIENTATIONS};
use vision::localize::{localize, LocalizeError, LocalizeParams};
use world::camera::{CameraModel, CameraPose};
use world::plate::damage;
use world::render::{render_damaged, Damage};

fn env(name: &str, default: f64) -> f64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn config(rel: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../config")
        .join(rel)
}

/// A deterministic sub-pitch jitter for frame k.
fn jitter(k: u64) -> [f64; 2] {
    let h = protocol::board_code::splitmix64(k ^ 0x5EED);
    [
        (h & 0xFFFF) as f64 / 65536.0 * 0.5,
        ((h >> 16) & 0xFFFF) as f64 / 65536.0 * 0.5,
    ]
}

struct Tally {
    frames: usize,
    decoded: usize,
    wrong: usize,
    refused: Vec<String>,
    errs_um: Vec<f64>,
    min_margin: usize,
    bit_errors: usize,
    ms: Vec<f64>,
}

fn sweep(board: &Board, cam: &CameraModel, dmg: &Damage, step: f64, hint: bool) -> Tally {
    let mut t = Tally {
        frames: 0,
        decoded: 0,
        wrong: 0,
        refused: Vec::new(),
        errs_um: Vec::new(),
        min_margin: usize::MAX,
        bit_errors: 0,
        ms: Vec::new(),
    };
    let (nx, ny) = (
        (200.0 / step).round() as usize + 1,
        (150.0 / step).round() as usize + 1,
    );
    for iy in 0..ny {
        for ix in 0..nx {
            let k = (iy * nx + ix) as u64;
            let j = jitter(k);
            // Inside the travel: image centre from board (5, 5) to (205, 155).
            let truth = [
                (5.0 + ix as f64 * step + j[0]).min(205.0),
                (5.0 + iy as f64 * step + j[1]).min(155.0),
            ];
            let pose = CameraPose {
                centre_mm: truth,
                rotation_rad: 0.0,
            };
            let f = render_damaged(board, cam, &pose, k, dmg);
            let mut p = LocalizeParams::new(truth);
            if !hint {
                p.hint_mm = None;
            }
            p.um_per_px = Some(cam.um_per_px);
            let s = Instant::now();
            let r = localize(&f.image, board, &p);
            t.ms.push(s.elapsed().as_secs_f64() * 1e3);
            t.frames += 1;
            match r {
                Ok(o) => {
                    let e = (o.x_mm - truth[0]).hypot(o.y_mm - truth[1]) * 1e3;
                    if e > 100.0 {
                        t.wrong += 1;
                        println!("WRONG at {truth:?}: {o:?}");
                    } else {
                        t.decoded += 1;
                        t.errs_um.push(e);
                    }
                    if let Some(c) = &o.code {
                        t.min_margin = t.min_margin.min(c.second - c.errors);
                        t.bit_errors += c.errors;
                    }
                }
                Err(e) => {
                    let short = match &e {
                        LocalizeError::CodeUnreadable { .. } => "code unreadable",
                        LocalizeError::TooFewPoints { .. } => "too few points",
                        LocalizeError::ResidualTooLarge { .. } => "residual too large",
                        _ => "other",
                    };
                    t.refused.push(format!("{short}: at {truth:?}: {e}"));
                }
            }
        }
    }
    t
}

fn report(name: &str, t: &Tally) {
    let n = t.errs_um.len().max(1) as f64;
    let mean = t.errs_um.iter().sum::<f64>() / n;
    let max = t.errs_um.iter().copied().fold(0.0, f64::max);
    let mut ms = t.ms.clone();
    ms.sort_by(f64::total_cmp);
    println!(
        "{name}: {} frames, {} decoded ({:.2} %), {} wrong, {} refused; centre error mean {:.4} um, worst {:.4} um; localize median {:.1} ms{}",
        t.frames,
        t.decoded,
        100.0 * t.decoded as f64 / t.frames as f64,
        t.wrong,
        t.refused.len(),
        mean,
        max,
        ms[ms.len() / 2],
        if t.min_margin < usize::MAX {
            format!(
                "; smallest margin {} dots, {} misread dots outvoted",
                t.min_margin, t.bit_errors
            )
        } else {
            String::new()
        }
    );
    for r in t.refused.iter().take(5) {
        println!("   refused {r}");
    }
}

/// The code alone: the guaranteed 9 x 7 view at every `stride`-th dot of the travel, with
/// `flips` dots misread (size read wrong) at drawn places; the index decoder checked
/// against the exhaustive one on every 64th view.
fn code_sweep(board: &Board, stride: usize, flips: usize) {
    let code = board.code.as_ref().expect("a coded board");
    let axes = ORIENTATIONS[0];
    let (mut right, mut wrong, mut refused, mut checked, mut disagree) = (0, 0, 0, 0, 0);
    let mut k = 0u64;
    // Image centres over the travel: board (5, 5) to (205, 155) mm = dots 10..410, 10..310.
    for j in (10..=310).step_by(stride) {
        for i in (10..=410).step_by(stride) {
            k += 1;
            let mut obs = Vec::new();
            for b in -3..=3i64 {
                for a in -4..=4i64 {
                    let ij = [
                        i + a * axes[0][0] + b * axes[1][0],
                        j + a * axes[0][1] + b * axes[1][1],
                    ];
                    obs.push(([a, b], code.bit(ij[0], ij[1]).expect("on the board")));
                }
            }
            let mut h = k;
            for _ in 0..flips {
                h = protocol::board_code::splitmix64(h);
                let n = (h % obs.len() as u64) as usize;
                obs[n].1 = !obs[n].1;
            }
            let d = decode(code, &obs);
            match &d {
                Ok(d) if d.ij0 == [i, j] && d.axes == axes => right += 1,
                Ok(d) => {
                    wrong += 1;
                    println!("WRONG: view at ({i},{j}) read at {:?}", d.ij0);
                }
                Err(_) => refused += 1,
            }
            if k.is_multiple_of(64) {
                checked += 1;
                let e = decode_exhaustive(code, &obs);
                let same = match (&d, &e) {
                    (Ok(a), Ok(b)) => (a.ij0, a.axes) == (b.ij0, b.axes),
                    (Err(_), Err(_)) => true,
                    _ => false,
                };
                if !same {
                    disagree += 1;
                }
            }
        }
    }
    let n = right + wrong + refused;
    println!(
        "code only, 9 x 7 view, {flips} misread dots: {n} views, {right} right ({:.2} %), {wrong} wrong, {refused} refused; index vs exhaustive search: {disagree} of {checked} differ",
        100.0 * right as f64 / n as f64
    );
}

fn main() {
    let step = env("CODED_SWEEP_STEP_MM", 5.0);
    let fraction = env("CODED_SWEEP_DAMAGE", 0.05);
    let runs = env("CODED_SWEEP_RUNS", 41.0) as usize;
    let cam = CameraModel::load(&config("cameras/mono-1.3mp.toml")).expect("camera file");
    let coded = Board::load(&config("boards/coded-0.5mm.toml")).expect("coded board file");
    let plain = Board::load(&config("boards/dot-grid-0.5mm.toml")).expect("plain board file");

    // Speed first (quiet machine), interleaved, same positions on both boards.
    let mut t_plain = Vec::new();
    let mut t_coded = Vec::new();
    for k in 0..runs {
        let truth = [
            10.0 + (3.1 * k as f64) % 190.0,
            10.0 + (2.3 * k as f64) % 140.0,
        ];
        let pose = CameraPose {
            centre_mm: truth,
            rotation_rad: 0.0,
        };
        let fp = render_damaged(&plain, &cam, &pose, k as u64, &Damage::default());
        let fc = render_damaged(&coded, &cam, &pose, k as u64, &Damage::default());
        let mut pp = LocalizeParams::new(truth);
        pp.um_per_px = Some(cam.um_per_px);
        let mut pc = pp.clone();
        pc.hint_mm = None;
        let s = Instant::now();
        localize(&fp.image, &plain, &pp).expect("plain frame");
        t_plain.push(s.elapsed().as_secs_f64() * 1e3);
        let s = Instant::now();
        localize(&fc.image, &coded, &pc).expect("coded frame");
        t_coded.push(s.elapsed().as_secs_f64() * 1e3);
    }
    t_plain.sort_by(f64::total_cmp);
    t_coded.sort_by(f64::total_cmp);
    let (mp, mc) = (t_plain[runs / 2], t_coded[runs / 2]);
    println!(
        "speed ({runs} frames each, release, one core): plain grid with hint median {mp:.2} ms, coded board without hint median {mc:.2} ms: decoding adds {:.1} %",
        100.0 * (mc / mp - 1.0)
    );

    if std::env::var_os("CODED_SWEEP_SPEED_ONLY").is_some() {
        return;
    }
    for flips in [0, 1, 2, 3, 4, 5] {
        code_sweep(&coded, 4, flips);
    }

    let clean = sweep(&coded, &cam, &Damage::default(), step, false);
    report("coded, clean", &clean);
    let dmg = damage(&coded, fraction, 2028);
    let damaged = sweep(&coded, &cam, &dmg, step, false);
    report(
        &format!("coded, {:.0} % of dots damaged", 100.0 * fraction),
        &damaged,
    );
}

//! Rewrite speed: `cargo run --release -p gateway --example rewrite_speed -- MAP [LINES] [T_UM]`.
//!
//! Generates a program of LINES lines (default 100 000) inside the map's extent, as CAM
//! output looks: short feed moves (0.2 to 2 mm) along a wandering contour, an arc every
//! 50 lines and a long diagonal every 500, then rewrites it with the map at tolerance
//! T_UM (default 0.5 um) on one thread and prints the time, lines in and out, segments
//! added and the largest correction.

use errormap::MapModel;
use protocol::errormap::ErrorMap;
use rewrite::{rewrite_program, Compensation, Options};
use std::fmt::Write;
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let map_path = args
        .get(1)
        .expect("usage: rewrite_speed MAP [LINES] [T_UM]");
    let lines: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(100_000);
    let t_um: f64 = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(0.5);
    let model = MapModel::new(ErrorMap::load(std::path::Path::new(map_path)).expect("map"));
    let (lo, hi) = model.extent();
    let margin = 5.0;
    let (x0, x1, y0, y1) = (
        lo[0] + margin,
        hi[0] - margin,
        lo[1] + margin,
        hi[1] - margin,
    );
    let mut rng = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        (rng >> 11) as f64 / (1u64 << 53) as f64
    };
    let (mut x, mut y) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
    let mut heading: f64 = 0.0;
    let mut after_arc = false;
    let mut program = String::new();
    writeln!(program, "G21 G90 G17").unwrap();
    writeln!(program, "G0 X{x:.3} Y{y:.3}").unwrap();
    writeln!(program, "G1 F1200").unwrap();
    let mut written = 3;
    while written < lines {
        if written % 500 == 0 {
            let (tx, ty) = (x0 + next() * (x1 - x0), y0 + next() * (y1 - y0));
            writeln!(program, "G1 X{tx:.3} Y{ty:.3}").unwrap();
            after_arc = false;
            (x, y) = (tx, ty);
        } else if written % 50 == 0 {
            // A quarter circle of radius 2-6 mm, kept inside.
            let r = 2.0 + 4.0 * next();
            let (cx, cy) = (x + r, y);
            if cx + r < x1 && cy + r < y1 && cx - r > x0 && cy - r > y0 {
                let (tx, ty) = (cx, cy + r);
                writeln!(program, "G2 X{tx:.3} Y{ty:.3} I{r:.3} J0").unwrap();
                after_arc = true;
                (x, y) = (tx, ty);
            } else {
                writeln!(
                    program,
                    "G1 X{:.3} Y{:.3}",
                    (x0 + x1) / 2.0,
                    (y0 + y1) / 2.0
                )
                .unwrap();
                after_arc = false;
                (x, y) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
            }
        } else {
            heading += (next() - 0.5) * 0.6;
            let step = 0.2 + 1.8 * next();
            let (mut tx, mut ty) = (x + step * heading.cos(), y + step * heading.sin());
            if !(x0..x1).contains(&tx) || !(y0..y1).contains(&ty) {
                heading += std::f64::consts::PI;
                (tx, ty) = (x + step * heading.cos(), y + step * heading.sin());
            }
            // Modal G1 as CAM output writes it; after an arc the motion mode is G2.
            let g1 = if after_arc { "G1 " } else { "" };
            after_arc = false;
            writeln!(program, "{g1}X{tx:.3} Y{ty:.3}").unwrap();
            (x, y) = (tx, ty);
        }
        written += 1;
    }
    let options = Options {
        tolerance_mm: t_um / 1000.0,
        ..Options::default()
    };
    let counting = Counting {
        model: &model,
        calls: std::cell::Cell::new(0),
    };
    let started = Instant::now();
    let (out, report) = match rewrite_program(&program, &counting, options) {
        Ok(r) => r,
        Err(e) => {
            let line = program.lines().nth(e.line.saturating_sub(1)).unwrap_or("");
            panic!("rewrite refused: {e}: `{line}`");
        }
    };
    let secs = started.elapsed().as_secs_f64();
    println!(
        "{} lines in, {} out ({} segments added, {} moves corrected), largest correction {:.2} um, T = {t_um} um: {secs:.3} s ({:.0} lines/s), {} -> {} bytes",
        report.input_lines,
        report.output_lines,
        report.segments_added,
        report.moves_compensated,
        report.largest_correction_um,
        report.input_lines as f64 / secs,
        program.len(),
        out.len()
    );
    println!(
        "{} model inversions ({:.1} per input line, {:.2} us each)",
        counting.calls.get(),
        counting.calls.get() as f64 / report.input_lines as f64,
        secs * 1e6 / counting.calls.get() as f64
    );
}

/// The map, counting how often the rewriter asks it for a command.
struct Counting<'a> {
    model: &'a MapModel,
    calls: std::cell::Cell<u64>,
}

impl rewrite::Compensation for Counting<'_> {
    fn describe(&self) -> String {
        self.model.describe()
    }
    fn axes(&self) -> &[usize] {
        self.model.axes()
    }
    fn feature_length_mm(&self) -> f64 {
        self.model.feature_length_mm()
    }
    fn command_for(
        &self,
        nominal: &rewrite::Pose,
        approach: &[rewrite::Approach; rewrite::N_AXIS],
    ) -> Result<rewrite::Pose, String> {
        self.calls.set(self.calls.get() + 1);
        Compensation::command_for(self.model, nominal, approach)
    }
    fn command_near(
        &self,
        nominal: &rewrite::Pose,
        approach: &[rewrite::Approach; rewrite::N_AXIS],
        guess: &rewrite::Pose,
    ) -> Result<rewrite::Pose, String> {
        self.calls.set(self.calls.get() + 1);
        self.model.command_near(nominal, approach, guess)
    }
}

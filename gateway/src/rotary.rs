//! `gateway rotary`: the A/C tilting table of source B: identification of its eight
//! location errors from measured ball centres, and the probing cycle on the simulated
//! 5-axis machine.

use anyhow::Context;
use clap::Subcommand;
use indicatif::{ProgressBar, ProgressStyle};
use job::rotary::RotaryJob;
use rotary::{
    identify, parse_centres, write_centres, Identification, LocationErrors, MachineConstants,
    RotaryMachine,
};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Subcommand)]
pub enum RotaryCmd {
    /// Identify the eight location errors from ball centres measured elsewhere (a CMM,
    /// as in the paper): a CSV `axis,step,angle_deg,ball,x_mm,y_mm,z_mm` of the C sweep
    /// (at A = 0) and the A sweep (at C = 0), machine coordinates.
    Identify {
        /// The centres file.
        #[arg(long)]
        centres: PathBuf,
        /// The machine constants (JSON: a_axis_y_mm, a_axis_z_mm, ac_offset_y_mm,
        /// ac_offset_z_mm, tool_length_mm); default: the built-in 340A-style mill.
        #[arg(long)]
        machine: Option<PathBuf>,
        /// Write the chart of centres and fitted circles (rotary-sweeps.svg and .png)
        /// into this folder.
        #[arg(long)]
        plot: Option<PathBuf>,
        /// Print one JSON object instead of the table.
        #[arg(long)]
        json: bool,
    },
    /// Rewrite a 5-axis program (X Y Z A C, absolute, mm) for the identified errors:
    /// every programmed point replaced by the command that puts the tool tip and
    /// direction back on it, feed moves split where the commands bend. Refuses (naming
    /// the line) arcs, inches, incremental moves, unknown axes and commands past the
    /// limits.
    Rewrite {
        /// The program (never overwritten).
        input: PathBuf,
        /// The errors (the JSON `gateway rotary identify` or `measure` writes).
        #[arg(long)]
        errors: PathBuf,
        #[arg(long)]
        out: PathBuf,
        /// The machine constants (JSON), default the built-in ones.
        #[arg(long)]
        machine: Option<PathBuf>,
        /// Largest distance (X Y Z) of a piece's middle from the compensated path, um.
        #[arg(long, default_value_t = 0.5)]
        tolerance_um: f64,
        #[arg(long)]
        json: bool,
    },
    /// Run the paper's measurement cycle with the touch probe on the simulated 5-axis
    /// machine (C in 12 steps of 30°, A in 6 steps of 15°, 6 points per ball, each
    /// touched fast, backed off and touched slowly), identify the errors, and check them
    /// and a compensated 5-axis program against the simulation's truth. Writes
    /// OUT/centres.csv, OUT/points.csv, OUT/errors.json and the sweep chart; a stopped
    /// cycle still writes what it measured.
    Measure {
        /// The rotary job (JSON: seed, errors, probe, plan, machine, speeds; all
        /// optional, defaults are the paper's table).
        #[arg(long)]
        config: PathBuf,
        #[arg(long)]
        out: PathBuf,
        #[arg(long)]
        json: bool,
    },
}

impl RotaryCmd {
    pub fn json(&self) -> bool {
        match self {
            RotaryCmd::Identify { json, .. }
            | RotaryCmd::Measure { json, .. }
            | RotaryCmd::Rewrite { json, .. } => *json,
        }
    }
}

pub fn run(cmd: RotaryCmd) -> anyhow::Result<ExitCode> {
    match cmd {
        RotaryCmd::Identify {
            centres,
            machine,
            plot,
            json,
        } => {
            let constants = load_constants(machine.as_deref())?;
            let text = std::fs::read_to_string(&centres)
                .with_context(|| format!("reading {}", centres.display()))?;
            let rows = parse_centres(&text).with_context(|| format!("{}", centres.display()))?;
            let id = identify(&rows, &constants)
                .with_context(|| format!("identifying from {}", centres.display()))?;
            let plot_files = match &plot {
                Some(dir) => Some(write_plot(dir, &rows, &id)?),
                None => None,
            };
            if json {
                let mut report = runner::rotary::identification_json(&id, &constants);
                if let (Some(obj), Some((svg, png))) = (report.as_object_mut(), &plot_files) {
                    obj.insert(
                        "plot".into(),
                        json!({ "svg": svg.display().to_string(), "png": png.display().to_string() }),
                    );
                }
                println!("{report}");
            } else {
                print_table(&id);
                if let Some((svg, png)) = plot_files {
                    println!("chart: {} and {}", svg.display(), png.display());
                }
            }
            Ok(ExitCode::SUCCESS)
        }
        RotaryCmd::Measure { config, out, json } => measure_cmd(&config, &out, json),
        RotaryCmd::Rewrite {
            input,
            errors,
            out,
            machine,
            tolerance_um,
            json,
        } => {
            if !(tolerance_um > 0.0 && tolerance_um.is_finite()) {
                anyhow::bail!("--tolerance-um {tolerance_um}: must be a positive number");
            }
            if out == input {
                anyhow::bail!("--out is the input file: the program is never overwritten");
            }
            let constants = load_constants(machine.as_deref())?;
            let e_text = std::fs::read_to_string(&errors)
                .with_context(|| format!("reading {}", errors.display()))?;
            let e = LocationErrors::from_json(&e_text)
                .map_err(|err| anyhow::anyhow!("{}: {err}", errors.display()))?;
            let model = RotaryMachine::with_errors(constants, e);
            let text = std::fs::read_to_string(&input)
                .with_context(|| format!("reading {}", input.display()))?;
            let opts = rotary::rewrite::RewriteOptions {
                tolerance_mm: tolerance_um / 1000.0,
                ..Default::default()
            };
            let (rewritten, report) = rotary::rewrite::rewrite_program(&text, &model, &opts)
                .with_context(|| format!("{}", input.display()))?;
            std::fs::write(&out, rewritten)
                .with_context(|| format!("writing {}", out.display()))?;
            let max_xyz = report
                .points
                .iter()
                .map(|p| {
                    let (n, c) = (p.nominal, p.command);
                    ((c.x - n.x).powi(2) + (c.y - n.y).powi(2) + (c.z - n.z).powi(2)).sqrt()
                })
                .fold(0.0f64, f64::max);
            let max_ac = report
                .points
                .iter()
                .map(|p| {
                    (p.command.a - p.nominal.a)
                        .abs()
                        .max((p.command.c - p.nominal.c).abs())
                })
                .fold(0.0f64, f64::max);
            if json {
                println!(
                    "{}",
                    json!({
                        "lines": report.lines,
                        "moves": report.moves,
                        "pieces_added": report.pieces_added,
                        "max_correction_xyz_mm": max_xyz,
                        "max_correction_ac_deg": max_ac,
                        "out": out.display().to_string(),
                    })
                );
            } else {
                println!(
                    "{} lines, {} moves rewritten, {} pieces added; largest correction {:.4} mm, {:.5} deg; wrote {}",
                    report.lines,
                    report.moves,
                    report.pieces_added,
                    max_xyz,
                    max_ac,
                    out.display()
                );
            }
            Ok(ExitCode::SUCCESS)
        }
    }
}

fn measure_cmd(config: &Path, out: &Path, json: bool) -> anyhow::Result<ExitCode> {
    use runner::rotary::{cycle_report, run_cycle};
    let text =
        std::fs::read_to_string(config).with_context(|| format!("reading {}", config.display()))?;
    let job =
        RotaryJob::from_json(&text).map_err(|e| anyhow::anyhow!("{}: {e}", config.display()))?;
    let constants = job.machine.unwrap_or_default();
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let bar = if json {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(0)
    };
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} balls {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let progress = |done: usize, total: usize| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    };
    // Nothing stops the command's cycle but a failure (Ctrl-C ends the process).
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let run = rt.block_on(run_cycle(&job, progress, std::future::pending()))?;
    bar.finish_and_clear();
    let (m, stopped) = match &run.cycle {
        Ok(m) => (m, None),
        Err(stop) => (&stop.so_far, Some(&stop.error)),
    };
    let centres_path = out.join("centres.csv");
    std::fs::write(&centres_path, write_centres(&m.centres()))
        .with_context(|| format!("writing {}", centres_path.display()))?;
    let points_path = out.join("points.csv");
    std::fs::write(&points_path, points_csv(m))
        .with_context(|| format!("writing {}", points_path.display()))?;
    if let Some(error) = stopped {
        anyhow::bail!(
            "{error} ({} balls measured, saved in {} and {})",
            m.balls.len(),
            centres_path.display(),
            points_path.display()
        );
    }
    let rows = m.centres();
    let id = identify(&rows, &constants)?;
    let (svg, png) = write_plot(out, &rows, &id)?;
    let mut report = cycle_report(&run, m, &id, &constants)?;
    if let Some(obj) = report.as_object_mut() {
        obj.insert(
            "plot".into(),
            json!({ "svg": svg.display().to_string(), "png": png.display().to_string() }),
        );
    }
    let errors_path = out.join("errors.json");
    std::fs::write(&errors_path, serde_json::to_string_pretty(&report)?)
        .with_context(|| format!("writing {}", errors_path.display()))?;
    if json {
        println!("{report}");
        return Ok(ExitCode::SUCCESS);
    }
    if let Some(c) = &m.c_centre {
        println!(
            "C centre on the rim: ({:.4}, {:.4}) mm, ({:+.4}, {:+.4}) mm from the nominal axis, rim radius {:.4} mm",
            c.x_mm, c.y_mm, c.offset_mm[0], c.offset_mm[1], c.rim_radius_mm
        );
    }
    let touches = m.probe_touches;
    match &run.truth {
        // A real controller: its truth is unknown, its time the wall clock's.
        None => {
            print_table(&id);
            println!(
                "cycle: {} balls, {} probe points ({} touches), {:.1} min",
                m.balls.len(),
                touches / 2,
                touches,
                run.time_s / 60.0
            );
        }
        // The simulation knows the truth: compare.
        Some(truth) => {
            let t = truth.errors;
            let injected = job::rotary::injected_errors(&t);
            println!(
                "{:<14} {:>12} {:>12} {:>12} {:>10}",
                "error", "injected", "identified", "difference", "u (k=1)"
            );
            for (((name, w), (_, g)), (_, u)) in injected
                .named()
                .iter()
                .zip(id.errors.named())
                .zip(id.uncertainty.named())
            {
                println!("{name:<14} {w:>12.6} {g:>12.6} {:>12.6} {u:>10.6}", g - w);
            }
            println!(
                "cycle: {} balls, {} probe points ({} touches), simulated machine time {:.1} min",
                m.balls.len(),
                touches / 2,
                touches,
                run.time_s / 60.0
            );
            let check = runner::rotary::compensation_check(truth, &constants, &id.errors)?;
            println!(
                "compensated 5-axis program ({} poses, A 2..90°, C all round), against the truth:",
                check.poses
            );
            println!(
                "  tool tip   max {:.4} mm -> {:.5} mm ({:.1} % better), mean {:.4} -> {:.5}",
                check.tip_max_before_mm,
                check.tip_max_after_mm,
                check.tip_improvement_pct,
                check.tip_mean_before_mm,
                check.tip_mean_after_mm
            );
            println!(
                "  direction  max {:.6} rad -> {:.7} rad ({:.1} % better)",
                check.dir_max_before_rad, check.dir_max_after_rad, check.dir_improvement_pct
            );
        }
    }
    println!(
        "wrote {}, {}, {}",
        centres_path.display(),
        points_path.display(),
        errors_path.display()
    );
    Ok(ExitCode::SUCCESS)
}

/// Every probe point of the cycle (`axis,step,angle_deg,ball,touch,x_mm,y_mm,z_mm`).
fn points_csv(m: &rotary::measure::Measurement) -> String {
    let mut points = String::from("axis,step,angle_deg,ball,touch,x_mm,y_mm,z_mm\n");
    for b in &m.balls {
        for (k, p) in b.points.iter().enumerate() {
            points.push_str(&format!(
                "{},{},{},{},{},{:.6},{:.6},{:.6}\n",
                b.axis,
                b.step,
                b.angle_deg,
                b.ball,
                k + 1,
                p[0],
                p[1],
                p[2]
            ));
        }
    }
    points
}

/// The machine constants from a JSON file, or the defaults.
pub fn load_constants(path: Option<&Path>) -> anyhow::Result<MachineConstants> {
    let Some(path) = path else {
        return Ok(MachineConstants::default());
    };
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let de = &mut serde_json::Deserializer::from_str(&text);
    let k: MachineConstants = serde_path_to_error::deserialize(de)
        .map_err(|e| anyhow::anyhow!("{}: {} (at {})", path.display(), e.inner(), e.path()))?;
    k.check()
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    Ok(k)
}

fn write_plot(
    dir: &Path,
    rows: &[rotary::CentreRow],
    id: &Identification,
) -> anyhow::Result<(PathBuf, PathBuf)> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let chart = rotary::chart::SweepChart {
        rows,
        identification: id,
        magnification: 1000.0,
    };
    let svg = dir.join("rotary-sweeps.svg");
    let png = dir.join("rotary-sweeps.png");
    std::fs::write(&svg, plot::render_svg(&chart, 1000, 460)?)
        .with_context(|| format!("writing {}", svg.display()))?;
    std::fs::write(&png, plot::render_png(&chart, 1000, 460)?)
        .with_context(|| format!("writing {}", png.display()))?;
    Ok((svg, png))
}

fn print_table(id: &Identification) {
    println!("{:<14} {:>12} {:>12}", "error", "value", "u (k=1)");
    for ((name, v), (_, u)) in id.errors.named().iter().zip(id.uncertainty.named()) {
        println!("{name:<14} {v:>12.6} {u:>12.6}");
    }
    for (axis, ball, c) in &id.circles {
        println!(
            "circle {axis} ball {ball}: radius {:.4} mm, rms {:.3} um radial, {:.3} um out of plane, {} centres",
            c.radius_mm,
            c.rms_radial_mm * 1e3,
            c.rms_plane_mm * 1e3,
            c.points
        );
    }
    for (name, line) in [("C", &id.c_axis), ("A", &id.a_axis)] {
        println!(
            "{name} axis: circle centres {:.3} mm apart, their line {:.5} deg from the normals",
            line.centre_separation_mm, line.centre_line_deviation_deg
        );
    }
}

//! `gateway rotary`: the A/C tilting table of source B: identification of its eight
//! location errors from measured ball centres, and the probing cycle on the simulated
//! 5-axis machine.

use anyhow::Context;
use clap::Subcommand;
use indicatif::{ProgressBar, ProgressStyle};
use job::rotary::{RotaryJob, RotaryLink};
use rotary::measure::measure;
use rotary::{
    identify, parse_centres, write_centres, Axes, Identification, LocationErrors, MachineConstants,
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
                println!("{}", identification_json(&id, &constants, plot_files));
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
    let text =
        std::fs::read_to_string(config).with_context(|| format!("reading {}", config.display()))?;
    let job =
        RotaryJob::from_json(&text).map_err(|e| anyhow::anyhow!("{}: {e}", config.display()))?;
    let constants = job.machine.unwrap_or_default();
    let plan = job.plan.unwrap_or_default();
    let mut machine = job.simulated();
    let link = job.link;
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
    // The real controller's truth is unknown: no comparison then, and its time is the
    // wall clock's.
    let (result, link_time_s, truth_known) = match &link {
        None => (
            measure(&mut machine, &constants, &plan, progress),
            None,
            true,
        ),
        Some(RotaryLink::GrblEmulator) => {
            let (r, t) = measure_through_grbl_emulator(&machine.sim, &constants, &plan, progress)?;
            (r, Some(t), true)
        }
        Some(RotaryLink::Grbl(port)) => {
            let (r, t) = measure_through_grbl_port(port, &constants, &plan, progress)?;
            (r, Some(t), false)
        }
    };
    bar.finish_and_clear();
    let (m, stopped) = match result {
        Ok(m) => (m, None),
        Err(stop) => (stop.so_far, Some(stop.error)),
    };
    let centres_path = out.join("centres.csv");
    std::fs::write(&centres_path, write_centres(&m.centres()))
        .with_context(|| format!("writing {}", centres_path.display()))?;
    let points_path = out.join("points.csv");
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
    std::fs::write(&points_path, points)
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
    let plot_files = write_plot(out, &rows, &id)?;
    let mut report = identification_json(&id, &constants, Some(plot_files));
    let errors_path = out.join("errors.json");
    std::fs::write(&errors_path, serde_json::to_string_pretty(&report)?)
        .with_context(|| format!("writing {}", errors_path.display()))?;
    let touches = m.probe_touches;
    if let (Some(obj), Some(c)) = (report.as_object_mut(), &m.c_centre) {
        obj.insert("c_centre".into(), serde_json::to_value(c)?);
    }
    if !json {
        if let Some(c) = &m.c_centre {
            println!(
                "C centre on the rim: ({:.4}, {:.4}) mm, ({:+.4}, {:+.4}) mm from the nominal axis, rim radius {:.4} mm",
                c.x_mm, c.y_mm, c.offset_mm[0], c.offset_mm[1], c.rim_radius_mm
            );
        }
    }
    if !truth_known {
        let time_s = link_time_s.unwrap_or(0.0);
        if json {
            let obj = report.as_object_mut().expect("an object");
            obj.insert(
                "cycle".into(),
                json!({
                    "balls": m.balls.len(),
                    "probe_points": touches / 2,
                    "probe_touches": touches,
                    "wall_time_s": time_s,
                }),
            );
            println!("{report}");
        } else {
            print_table(&id);
            println!(
                "cycle: {} balls, {} probe points ({} touches), {:.1} min",
                m.balls.len(),
                touches / 2,
                touches,
                time_s / 60.0
            );
            println!(
                "wrote {}, {}, {}",
                centres_path.display(),
                points_path.display(),
                errors_path.display()
            );
        }
        return Ok(ExitCode::SUCCESS);
    }
    // The simulation knows the truth: compare.
    let t = machine.sim.errors;
    let injected = LocationErrors {
        delta_xc_mm: t.delta_xc_mm,
        delta_yc_mm: t.delta_yc_mm,
        alpha_xc_deg: t.alpha_xc_deg,
        alpha_yc_deg: t.alpha_yc_deg,
        delta_ya_mm: t.delta_ya_mm,
        delta_za_mm: t.delta_za_mm,
        alpha_ya_deg: t.alpha_ya_deg,
        alpha_za_deg: t.alpha_za_deg,
    };
    let check = compensation_check(&machine.sim, &constants, &id.errors)?;
    let time_s = link_time_s.unwrap_or(machine.time_s);
    if json {
        let obj = report.as_object_mut().expect("an object");
        let mut truth = serde_json::Map::new();
        for ((name, w), (_, g)) in injected.named().iter().zip(id.errors.named()) {
            truth.insert(
                (*name).into(),
                json!({ "injected": w, "identified": g, "difference": g - w }),
            );
        }
        obj.insert("truth".into(), serde_json::Value::Object(truth));
        obj.insert(
            "cycle".into(),
            json!({
                "balls": m.balls.len(),
                "probe_points": touches / 2,
                "probe_touches": touches,
                "simulated_time_s": time_s,
            }),
        );
        obj.insert(
            "compensation_check".into(),
            json!({
                "poses": check.poses,
                "tip_max_before_mm": check.tip_max_before_mm,
                "tip_max_after_mm": check.tip_max_after_mm,
                "tip_mean_before_mm": check.tip_mean_before_mm,
                "tip_mean_after_mm": check.tip_mean_after_mm,
                "tip_improvement_pct": check.tip_improvement_pct,
                "direction_max_before_rad": check.dir_max_before_rad,
                "direction_max_after_rad": check.dir_max_after_rad,
                "direction_improvement_pct": check.dir_improvement_pct,
            }),
        );
        println!("{report}");
    } else {
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
            time_s / 60.0
        );
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
        println!(
            "wrote {}, {}, {}",
            centres_path.display(),
            points_path.display(),
            errors_path.display()
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// The cycle through a controller link: the GRBL emulator with `sim` behind it (six
/// axes X Y Z A B C, B fixed) on a pseudo-terminal, the GRBL driver moving the axes and
/// probing with G38.3. Returns the result and the emulated machine time (s).
fn measure_through_grbl_emulator(
    sim: &world::rotary::RotaryMachineSim,
    constants: &MachineConstants,
    plan: &rotary::measure::MeasurePlan,
    progress: impl FnMut(usize, usize),
) -> anyhow::Result<(Cycle, f64)> {
    use emulators::grbl::{GrblConfig, GrblDevice, GrblPty};
    use world::axes::{lock_axes, AxesMachine};
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let axes = AxesMachine::new(Box::new(world::rotary::RotaryWorkpiece {
        sim: sim.clone(),
    }))
    .shared();
    let pty = {
        let _enter = rt.enter();
        GrblPty::spawn(
            GrblDevice::with_axes(axes.clone(), GrblConfig::default()),
            None,
        )
        .context("starting the GRBL emulator on a pseudo-terminal")?
    };
    let result = measure_over_grbl(&rt, pty.path(), 115_200, Some(2), constants, plan, progress)?;
    let time_s = lock_axes(&axes).now_s();
    Ok((result, time_s))
}

/// The cycle through a real controller on a serial port. Returns the result and the
/// wall time of the cycle (s).
fn measure_through_grbl_port(
    port: &job::rotary::GrblPort,
    constants: &MachineConstants,
    plan: &rotary::measure::MeasurePlan,
    progress: impl FnMut(usize, usize),
) -> anyhow::Result<(Cycle, f64)> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let started = std::time::Instant::now();
    let result = measure_over_grbl(
        &rt,
        &port.port,
        port.baud,
        port.poll_ms,
        constants,
        plan,
        progress,
    )?;
    Ok((result, started.elapsed().as_secs_f64()))
}

/// What the cycle gave: the measurement, or where it stopped with what it had.
type Cycle = Result<rotary::measure::Measurement, Box<rotary::measure::Stopped>>;

/// Connects to the GRBL controller at `path`, checks that it has the A and C axes and a
/// probe input (before any motion), and runs the cycle through it.
fn measure_over_grbl(
    rt: &tokio::runtime::Runtime,
    path: &str,
    baud: u32,
    poll_ms: Option<u64>,
    constants: &MachineConstants,
    plan: &rotary::measure::MeasurePlan,
    progress: impl FnMut(usize, usize),
) -> anyhow::Result<Cycle> {
    use drivers::grbl::{GrblOptions, GrblStage};
    use drivers::{Axis, Stage};
    let mut opts = GrblOptions::default();
    if let Some(ms) = poll_ms {
        opts.poll_interval = std::time::Duration::from_millis(ms);
    }
    let stage = rt
        .block_on(GrblStage::open(path, baud, opts))
        .with_context(|| format!("connecting to the GRBL controller on {path}"))?;
    let caps = stage.capabilities();
    for axis in [Axis::A, Axis::C] {
        anyhow::ensure!(
            caps.rotary_axes.contains(&axis),
            "the controller on {path} has no {axis:?} axis (its axes: {:?}); the cycle needs A and C",
            caps.rotary_axes
        );
    }
    anyhow::ensure!(
        caps.probing,
        "the controller on {path} reports no probe input; the cycle probes the balls"
    );
    let mut prober = LinkProber { rt, stage };
    Ok(measure(&mut prober, constants, plan, progress))
}

/// The measurement cycle's machine behind a GRBL link: each move and probing move is a
/// driver call run to its end (moves at 3000 units/min, probing with G38.3 so a miss is
/// the cycle's own "ball not found").
struct LinkProber<'a> {
    rt: &'a tokio::runtime::Runtime,
    stage: drivers::grbl::GrblStage,
}

impl rotary::measure::ProbingMachine for LinkProber<'_> {
    fn move_to(&mut self, t: &Axes) -> Result<(), String> {
        use drivers::{Axis, AxisValues, Stage};
        let target = AxisValues::default()
            .with(Axis::X, t.x)
            .with(Axis::Y, t.y)
            .with(Axis::Z, t.z)
            .with(Axis::A, t.a)
            .with(Axis::C, t.c);
        self.rt
            .block_on(async {
                self.stage.move_to(target, 3000.0).await?;
                self.stage.wait_idle().await
            })
            .map_err(|e| e.to_string())
    }

    fn probe_towards(&mut self, to: [f64; 3], feed: f64) -> Result<Option<[f64; 3]>, String> {
        use drivers::{Axis, AxisValues, ProbeMode, Stage};
        let target = AxisValues::default()
            .with(Axis::X, to[0])
            .with(Axis::Y, to[1])
            .with(Axis::Z, to[2]);
        let mode = ProbeMode {
            toward: true,
            must_trigger: false,
        };
        let hit = self
            .rt
            .block_on(self.stage.probe(target, feed, mode))
            .map_err(|e| e.to_string())?;
        let p = |a| hit.position.get(a).unwrap_or(f64::NAN);
        Ok(hit.touched.then(|| [p(Axis::X), p(Axis::Y), p(Axis::Z)]))
    }
}

/// The compensation of a 5-axis test program checked against the simulation's truth.
struct CompensationCheck {
    poses: usize,
    tip_max_before_mm: f64,
    tip_max_after_mm: f64,
    tip_mean_before_mm: f64,
    tip_mean_after_mm: f64,
    tip_improvement_pct: f64,
    dir_max_before_rad: f64,
    dir_max_after_rad: f64,
    dir_improvement_pct: f64,
}

/// A 5-axis test program (A from 2° to 90°, C all round, tips spread over the part)
/// run as programmed and as compensated with `errors`, each pose's true tool tip and
/// direction compared with the programmed ones.
fn compensation_check(
    truth: &world::rotary::RotaryMachineSim,
    constants: &MachineConstants,
    errors: &LocationErrors,
) -> anyhow::Result<CompensationCheck> {
    let model = RotaryMachine::with_errors(*constants, *errors);
    let ideal_m = RotaryMachine::nominal(*constants);
    let mut before = Vec::new();
    let mut after = Vec::new();
    for (i, a) in [2.0, 10.0, 25.0, 40.0, 55.0, 70.0, 85.0, 90.0]
        .iter()
        .enumerate()
    {
        for (j, c) in [0.0, 45.0, 135.0, 200.0, 290.0].iter().enumerate() {
            let nominal = Axes::new(
                -40.0 + 11.0 * i as f64,
                30.0 - 13.0 * j as f64,
                -180.0 - 3.0 * i as f64,
                *a,
                *c,
            );
            let ideal = ideal_m.forward(&nominal);
            let cmd = model
                .command_for(&nominal)
                .with_context(|| format!("compensating {nominal:?}"))?;
            for (list, cmd) in [(&mut before, nominal), (&mut after, cmd)] {
                let (p, d) = truth.tool_in_workpiece([cmd.x, cmd.y, cmd.z, cmd.a, cmd.c]);
                let dir = d.dot(&ideal.direction).clamp(-1.0, 1.0).acos();
                list.push(((p - ideal.position).norm(), dir));
            }
        }
    }
    let max = |v: &[(f64, f64)], k: usize| {
        v.iter()
            .map(|p| if k == 0 { p.0 } else { p.1 })
            .fold(0.0f64, f64::max)
    };
    let mean = |v: &[(f64, f64)]| v.iter().map(|p| p.0).sum::<f64>() / v.len() as f64;
    let pct = |b: f64, a: f64| 100.0 * (1.0 - a / b);
    Ok(CompensationCheck {
        poses: before.len(),
        tip_max_before_mm: max(&before, 0),
        tip_max_after_mm: max(&after, 0),
        tip_mean_before_mm: mean(&before),
        tip_mean_after_mm: mean(&after),
        tip_improvement_pct: pct(max(&before, 0), max(&after, 0)),
        dir_max_before_rad: max(&before, 1),
        dir_max_after_rad: max(&after, 1),
        dir_improvement_pct: pct(max(&before, 1), max(&after, 1)),
    })
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

/// The output JSON: the eight errors at the top level under their paper names, their
/// standard uncertainties (k = 1) under `uncertainty`, and the fits.
pub fn identification_json(
    id: &Identification,
    constants: &MachineConstants,
    plot: Option<(PathBuf, PathBuf)>,
) -> serde_json::Value {
    let mut out = serde_json::Map::new();
    for (name, v) in id.errors.named() {
        out.insert(name.into(), json!(v));
    }
    let mut u = serde_json::Map::new();
    for (name, v) in id.uncertainty.named() {
        u.insert(name.into(), json!(v));
    }
    out.insert("uncertainty".into(), serde_json::Value::Object(u));
    out.insert("coverage_factor".into(), json!(1));
    let circles: Vec<serde_json::Value> = id
        .circles
        .iter()
        .map(|(axis, ball, c)| {
            json!({
                "axis": axis.to_string(),
                "ball": ball,
                "centre_mm": c.centre,
                "normal": c.normal,
                "radius_mm": c.radius_mm,
                "rms_plane_um": c.rms_plane_mm * 1e3,
                "rms_radial_um": c.rms_radial_mm * 1e3,
                "points": c.points,
            })
        })
        .collect();
    out.insert("circles".into(), json!(circles));
    out.insert("c_axis".into(), json!(id.c_axis));
    out.insert("a_axis".into(), json!(id.a_axis));
    out.insert("machine".into(), json!(constants));
    if let Some((svg, png)) = plot {
        out.insert(
            "plot".into(),
            json!({ "svg": svg.display().to_string(), "png": png.display().to_string() }),
        );
    }
    serde_json::Value::Object(out)
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

//! The rotary table's probing cycle (source B) run through a rotary job's link, and its
//! report: shared by `gateway rotary measure` and the service's `rotary` job.
//!
//! The link is the simulated table in-process (no `link`), the same table behind the
//! GRBL emulator on a pseudo-terminal (`"grbl_emulator"`), or a real GRBL-family
//! controller on a serial port (`{"grbl": {..}}`), whose truth nobody knows. The cycle
//! itself is synchronous (`rotary::measure::measure` calls the machine move by move), so
//! each link runs on a private single-thread runtime: callers inside a runtime call
//! [`run_cycle`] from a blocking thread (`tokio::task::spawn_blocking`).

use anyhow::Context;
use job::rotary::{GrblPort, RotaryJob, RotaryLink};
use rotary::measure::{measure, MeasurePlan, Measurement, ProbingMachine, Stopped};
use rotary::{Axes, Identification, LocationErrors, MachineConstants, RotaryMachine};
use serde_json::{json, Value};
use std::sync::atomic::{AtomicBool, Ordering};
use world::rotary::RotaryMachineSim;

/// What the cycle gave: the measurement, or where it stopped with what it had.
pub type Cycle = Result<Measurement, Box<Stopped>>;

/// A cycle run through the job's link.
pub struct CycleRun {
    pub cycle: Cycle,
    /// The cycle's time, s: the emulated machine's clock on a simulated link, the wall
    /// clock's on a real controller.
    pub time_s: f64,
    /// The simulated table when the link is simulated (its truth known), else None.
    pub truth: Option<RotaryMachineSim>,
}

/// Runs the job's measurement cycle through its link. `progress(done, total)` counts
/// balls; once `stop` is set, the next move is refused and the cycle ends as stopped
/// with what it measured. Errors are what kept the cycle from starting (the emulator,
/// the port, a controller without A, C or a probe input), before any motion.
pub fn run_cycle(
    job: &RotaryJob,
    progress: impl FnMut(usize, usize),
    stop: &AtomicBool,
) -> anyhow::Result<CycleRun> {
    let constants = job.machine.unwrap_or_default();
    let plan = job.plan.unwrap_or_default();
    match &job.link {
        None => {
            let mut table = job.simulated();
            let cycle = measure(
                &mut Stoppable {
                    inner: &mut table,
                    stop,
                },
                &constants,
                &plan,
                progress,
            );
            Ok(CycleRun {
                cycle,
                time_s: table.time_s,
                truth: Some(table.sim),
            })
        }
        Some(RotaryLink::GrblEmulator) => {
            let sim = job.simulated().sim;
            let (cycle, time_s) = through_grbl_emulator(&sim, &constants, &plan, progress, stop)?;
            Ok(CycleRun {
                cycle,
                time_s,
                truth: Some(sim),
            })
        }
        Some(RotaryLink::Grbl(port)) => {
            let (cycle, time_s) = through_grbl_port(port, &constants, &plan, progress, stop)?;
            Ok(CycleRun {
                cycle,
                time_s,
                truth: None,
            })
        }
    }
}

/// The cycle through the GRBL emulator with `sim` behind it (six axes X Y Z A B C, B
/// fixed) on a pseudo-terminal, the GRBL driver moving the axes and probing with G38.3.
/// Returns the result and the emulated machine time (s).
fn through_grbl_emulator(
    sim: &RotaryMachineSim,
    constants: &MachineConstants,
    plan: &MeasurePlan,
    progress: impl FnMut(usize, usize),
    stop: &AtomicBool,
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
    let result = over_grbl(
        &rt,
        pty.path(),
        115_200,
        Some(2),
        constants,
        plan,
        progress,
        stop,
    )?;
    let time_s = lock_axes(&axes).now_s();
    Ok((result, time_s))
}

/// The cycle through a real controller on a serial port. Returns the result and the
/// wall time of the cycle (s).
fn through_grbl_port(
    port: &GrblPort,
    constants: &MachineConstants,
    plan: &MeasurePlan,
    progress: impl FnMut(usize, usize),
    stop: &AtomicBool,
) -> anyhow::Result<(Cycle, f64)> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let started = std::time::Instant::now();
    let result = over_grbl(
        &rt,
        &port.port,
        port.baud,
        port.poll_ms,
        constants,
        plan,
        progress,
        stop,
    )?;
    Ok((result, started.elapsed().as_secs_f64()))
}

/// Connects to the GRBL controller at `path`, checks that it has the A and C axes and a
/// probe input (before any motion), and runs the cycle through it.
#[allow(clippy::too_many_arguments)]
fn over_grbl(
    rt: &tokio::runtime::Runtime,
    path: &str,
    baud: u32,
    poll_ms: Option<u64>,
    constants: &MachineConstants,
    plan: &MeasurePlan,
    progress: impl FnMut(usize, usize),
    stop: &AtomicBool,
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
    Ok(measure(
        &mut Stoppable {
            inner: &mut prober,
            stop,
        },
        constants,
        plan,
        progress,
    ))
}

/// The measurement cycle's machine behind a GRBL link: each move and probing move is a
/// driver call run to its end (moves at 3000 units/min, probing with G38.3 so a miss is
/// the cycle's own "ball not found").
struct LinkProber<'a> {
    rt: &'a tokio::runtime::Runtime,
    stage: drivers::grbl::GrblStage,
}

impl ProbingMachine for LinkProber<'_> {
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

/// A machine whose next move is refused once `stop` is set: a cancelled cycle ends
/// between two moves (never in the middle of a probing move), keeping what it measured.
struct Stoppable<'a, M> {
    inner: &'a mut M,
    stop: &'a AtomicBool,
}

/// The error a stopped cycle names.
pub const STOPPED_ON_REQUEST: &str = "stopped on request";

impl<M: ProbingMachine> ProbingMachine for Stoppable<'_, M> {
    fn move_to(&mut self, t: &Axes) -> Result<(), String> {
        if self.stop.load(Ordering::Relaxed) {
            return Err(STOPPED_ON_REQUEST.into());
        }
        self.inner.move_to(t)
    }

    fn probe_towards(&mut self, to: [f64; 3], feed: f64) -> Result<Option<[f64; 3]>, String> {
        if self.stop.load(Ordering::Relaxed) {
            return Err(STOPPED_ON_REQUEST.into());
        }
        self.inner.probe_towards(to, feed)
    }
}

/// The compensation of a 5-axis test program checked against the simulation's truth.
pub struct CompensationCheck {
    pub poses: usize,
    pub tip_max_before_mm: f64,
    pub tip_max_after_mm: f64,
    pub tip_mean_before_mm: f64,
    pub tip_mean_after_mm: f64,
    pub tip_improvement_pct: f64,
    pub dir_max_before_rad: f64,
    pub dir_max_after_rad: f64,
    pub dir_improvement_pct: f64,
}

/// A 5-axis test program (A from 2° to 90°, C all round, tips spread over the part)
/// run as programmed and as compensated with `errors`, each pose's true tool tip and
/// direction compared with the programmed ones.
pub fn compensation_check(
    truth: &RotaryMachineSim,
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

/// The identification's JSON: the eight errors at the top level under their paper names
/// (what `gateway rewrite --rotary` reads), their standard uncertainties (k = 1) under
/// `uncertainty`, the fitted circles and axis lines, and the machine constants.
pub fn identification_json(id: &Identification, constants: &MachineConstants) -> Value {
    let mut out = serde_json::Map::new();
    for (name, v) in id.errors.named() {
        out.insert(name.into(), json!(v));
    }
    let mut u = serde_json::Map::new();
    for (name, v) in id.uncertainty.named() {
        u.insert(name.into(), json!(v));
    }
    out.insert("uncertainty".into(), Value::Object(u));
    out.insert("coverage_factor".into(), json!(1));
    let circles: Vec<Value> = id
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
    Value::Object(out)
}

/// The full report of a measured cycle: [`identification_json`], the C centre found on
/// the rim, the cycle's figures (`simulated_time_s` on a simulated link, `wall_time_s`
/// on a real one) and, when the truth is known, each error against the injected one and
/// the compensation of a 5-axis program checked against the truth.
pub fn cycle_report(
    run: &CycleRun,
    m: &Measurement,
    id: &Identification,
    constants: &MachineConstants,
) -> anyhow::Result<Value> {
    let mut report = identification_json(id, constants);
    let obj = report.as_object_mut().expect("an object");
    if let Some(c) = &m.c_centre {
        obj.insert("c_centre".into(), serde_json::to_value(c)?);
    }
    let clock = if run.truth.is_some() {
        "simulated_time_s"
    } else {
        "wall_time_s"
    };
    obj.insert(
        "cycle".into(),
        json!({
            "balls": m.balls.len(),
            "probe_points": m.probe_touches / 2,
            "probe_touches": m.probe_touches,
            clock: run.time_s,
        }),
    );
    let Some(truth) = &run.truth else {
        return Ok(report);
    };
    let t = truth.errors;
    let injected = job::rotary::injected_errors(&t);
    let mut comparison = serde_json::Map::new();
    for ((name, w), (_, g)) in injected.named().iter().zip(id.errors.named()) {
        comparison.insert(
            (*name).into(),
            json!({ "injected": w, "identified": g, "difference": g - w }),
        );
    }
    obj.insert("truth".into(), Value::Object(comparison));
    let check = compensation_check(truth, constants, &id.errors)?;
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
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A stop asked for while the cycle runs ends it before its next move, keeping the
    /// balls measured so far (the service's cancel).
    #[test]
    fn a_stop_ends_the_cycle_keeping_what_it_measured() {
        let stop = AtomicBool::new(false);
        let job = RotaryJob::default();
        let run = run_cycle(
            &job,
            |done, _| {
                if done == 2 {
                    stop.store(true, Ordering::Relaxed);
                }
            },
            &stop,
        )
        .unwrap();
        let stopped = run.cycle.expect_err("the cycle stops");
        assert_eq!(stopped.so_far.balls.len(), 2);
        assert!(
            stopped.error.to_string().contains(STOPPED_ON_REQUEST),
            "{}",
            stopped.error
        );
        assert!(run.truth.is_some());
    }

    /// Without a stop the in-process cycle measures every ball and identifies the
    /// injected errors (the paper's table, default plan).
    #[test]
    fn the_in_process_cycle_identifies_the_injected_errors() {
        let job = RotaryJob::default();
        let run = run_cycle(&job, |_, _| {}, &AtomicBool::new(false)).unwrap();
        let m = run.cycle.as_ref().expect("the cycle ends");
        let constants = MachineConstants::default();
        let id = rotary::identify(&m.centres(), &constants).unwrap();
        let report = cycle_report(&run, m, &id, &constants).unwrap();
        assert!(
            report["truth"]["delta_XC_mm"]["difference"]
                .as_f64()
                .unwrap()
                .abs()
                < 1e-3
        );
        assert!(report["cycle"]["simulated_time_s"].as_f64().unwrap() > 0.0);
        assert!(report.get("wall_time_s").is_none());
    }
}

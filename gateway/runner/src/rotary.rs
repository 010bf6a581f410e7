//! The rotary table's probing cycle (source B) run through a rotary job's link, and the
//! compensation check of its report against a simulated table's truth: shared by
//! `gateway rotary measure` and the service's `rotary` job (the report itself is
//! `procedure::rotary::CycleReport`).
//!
//! The link is the simulated table in-process (no `link`), the same table behind the
//! GRBL emulator on a pseudo-terminal (`"grbl_emulator"`), or a real GRBL-family
//! controller on a serial port (`{"grbl": {..}}`), whose truth nobody knows; `devices`
//! opens it ([`devices::open_rotary`], links through the drivers' factory). The cycle is
//! the sans-IO [`MeasureSession`], driven here move by move through a
//! [`drivers::Prober`] on the caller's runtime: the controller's, or the in-process
//! table's behind an adapter (it computes each move at once and yields between moves).

use devices::{open_rotary, RotaryOpenError, RotaryTable};
use drivers::{Axis, AxisValues, DriverError, Prober};
use futures_util::FutureExt;
use job::rotary::{RotaryJob, SimulatedTable};
use rotary::measure::{Action, MeasureSession, Measurement, ProbingMachine, Stopped};
use rotary::{Axes, LocationErrors, MachineConstants, RotaryMachine};
use std::future::Future;
use std::pin::Pin;
use world::rotary::RotaryMachineSim;

pub use rotary::measure::STOPPED_ON_REQUEST;

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

/// What kept a cycle from starting, or a report from being made.
#[derive(Debug, thiserror::Error)]
pub enum RotaryError {
    /// The job's machine could not be opened (the emulator, the port, a controller
    /// without A, C or a probe input); nothing moved.
    #[error(transparent)]
    Open(#[from] RotaryOpenError),
    /// A pose of the compensation check has no compensated command.
    #[error("compensating {nominal:?}: {error}")]
    Compensation {
        nominal: Axes,
        error: rotary::RotaryError,
    },
}

/// Runs the job's measurement cycle through its link, on the caller's runtime.
/// `progress(done, total)` counts balls; once `stop` completes, the cycle ends before
/// its next move (never in the middle of one) as stopped, with what it measured. Errors
/// are what kept the cycle from starting (the emulator, the port, a controller without
/// A, C or a probe input), before any motion.
pub async fn run_cycle(
    job: &RotaryJob,
    mut progress: impl FnMut(usize, usize),
    stop: impl Future<Output = ()>,
) -> Result<CycleRun, RotaryError> {
    let constants = job.machine.unwrap_or_default();
    let plan = job.plan.unwrap_or_default();
    let session = MeasureSession::new(&constants, &plan);
    let mut stop = std::pin::pin!(stop);
    let started = std::time::Instant::now();
    match open_rotary(job).await? {
        RotaryTable::InProcess(mut table) => {
            let cycle = drive(
                &mut InProcess(&mut table),
                session,
                &mut progress,
                stop.as_mut(),
            )
            .await;
            Ok(CycleRun {
                cycle,
                time_s: table.time_s,
                truth: Some(table.sim),
            })
        }
        RotaryTable::Linked(mut linked) => {
            let cycle = drive(
                linked.prober.as_mut(),
                session,
                &mut progress,
                stop.as_mut(),
            )
            .await;
            let time_s = linked
                .machine_time_s()
                .unwrap_or_else(|| started.elapsed().as_secs_f64());
            Ok(CycleRun {
                cycle,
                time_s,
                truth: linked.truth().cloned(),
            })
        }
    }
}

/// The session loop: each action of the session done by `machine` and answered, the
/// stop looked at before each (a stopped cycle keeps what it measured).
async fn drive<S: Future<Output = ()>>(
    machine: &mut dyn Prober,
    mut session: MeasureSession,
    progress: &mut impl FnMut(usize, usize),
    mut stop: Pin<&mut S>,
) -> Cycle {
    loop {
        let action = session.next_action();
        if action == Action::Finished {
            break;
        }
        if stop.as_mut().now_or_never().is_some() {
            session.stop();
            break;
        }
        let done = session.progress().0;
        match action {
            Action::MoveTo(t) => match machine.move_to(five_axes(&t)).await {
                Ok(()) => session.moved(),
                Err(e) => session.failed(e.to_string()),
            },
            Action::ProbeTowards { to, feed_mm_min } => {
                match machine.probe_towards(xyz(to), feed_mm_min).await {
                    Ok(None) => session.probed(None),
                    Ok(Some(hit)) => match gauge_point(&hit) {
                        Some(p) => session.probed(Some(p)),
                        None => session.failed(format!(
                            "{}: the probing move's report has no X, Y and Z ({hit:?})",
                            machine.name()
                        )),
                    },
                    Err(e) => session.failed(e.to_string()),
                }
            }
            Action::Finished => unreachable!("handled above"),
        }
        let (now, total) = session.progress();
        if now != done {
            progress(now, total);
        }
    }
    session.finish()
}

fn five_axes(t: &Axes) -> AxisValues {
    AxisValues::default()
        .with(Axis::X, t.x)
        .with(Axis::Y, t.y)
        .with(Axis::Z, t.z)
        .with(Axis::A, t.a)
        .with(Axis::C, t.c)
}

fn xyz(p: [f64; 3]) -> AxisValues {
    AxisValues::default()
        .with(Axis::X, p[0])
        .with(Axis::Y, p[1])
        .with(Axis::Z, p[2])
}

fn gauge_point(v: &AxisValues) -> Option<[f64; 3]> {
    Some([v.get(Axis::X)?, v.get(Axis::Y)?, v.get(Axis::Z)?])
}

/// The in-process simulated table (the synchronous [`ProbingMachine`] of the `job`
/// crate) as a [`Prober`]: each move is computed at once on the table's clock, the task
/// yielding first so the runtime's other tasks (the one that stops the cycle) run.
/// Axes a move leaves out stay where the table is.
struct InProcess<'a>(&'a mut SimulatedTable);

impl InProcess<'_> {
    const NAME: &'static str = "the simulated table";

    fn refused(message: String) -> DriverError {
        DriverError::Unsupported {
            device: Self::NAME.into(),
            message,
        }
    }
}

#[async_trait::async_trait]
impl Prober for InProcess<'_> {
    fn name(&self) -> &str {
        Self::NAME
    }

    async fn move_to(&mut self, target: AxisValues) -> Result<(), DriverError> {
        tokio::task::yield_now().await;
        let [x, y, z, a, c] = self.0.position();
        let v = |axis, here| target.get(axis).unwrap_or(here);
        let t = Axes::new(
            v(Axis::X, x),
            v(Axis::Y, y),
            v(Axis::Z, z),
            v(Axis::A, a),
            v(Axis::C, c),
        );
        self.0.move_to(&t).map_err(Self::refused)
    }

    async fn probe_towards(
        &mut self,
        to: AxisValues,
        feed_mm_min: f64,
    ) -> Result<Option<AxisValues>, DriverError> {
        tokio::task::yield_now().await;
        let [x, y, z, a, c] = self.0.position();
        let v = |axis, here| to.get(axis).unwrap_or(here);
        let hit = self
            .0
            .probe_towards([v(Axis::X, x), v(Axis::Y, y), v(Axis::Z, z)], feed_mm_min)
            .map_err(Self::refused)?;
        Ok(hit.map(|p| xyz(p).with(Axis::A, a).with(Axis::C, c)))
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
) -> Result<CompensationCheck, RotaryError> {
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
                .map_err(|error| RotaryError::Compensation { nominal, error })?;
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

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicBool, Ordering};

    fn runtime() -> tokio::runtime::Runtime {
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap()
    }

    /// Completes once `flag` is set (looked at each time it is polled).
    async fn set(flag: &AtomicBool) {
        std::future::poll_fn(|_| match flag.load(Ordering::Relaxed) {
            true => std::task::Poll::Ready(()),
            false => std::task::Poll::Pending,
        })
        .await
    }

    /// A stop asked for while the cycle runs ends it before its next move, keeping the
    /// balls measured so far (the service's cancel).
    #[test]
    fn a_stop_ends_the_cycle_keeping_what_it_measured() {
        let stop = AtomicBool::new(false);
        let job = RotaryJob::default();
        let run = runtime()
            .block_on(run_cycle(
                &job,
                |done, _| {
                    if done == 2 {
                        stop.store(true, Ordering::Relaxed);
                    }
                },
                set(&stop),
            ))
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

    /// A stop from another task of the runtime reaches the in-process cycle (it yields
    /// between moves), which ends with what it measured.
    #[test]
    fn a_stop_from_another_task_reaches_the_in_process_cycle() {
        runtime().block_on(async {
            let (tx, rx) = tokio::sync::oneshot::channel::<()>();
            let stopper = tokio::spawn(async move {
                tokio::task::yield_now().await;
                let _ = tx.send(());
            });
            let run = run_cycle(&RotaryJob::default(), |_, _| {}, async {
                let _ = rx.await;
            })
            .await
            .unwrap();
            stopper.await.unwrap();
            let stopped = run.cycle.expect_err("stopped");
            assert!(stopped.so_far.balls.len() < 20);
            assert_eq!(stopped.error.to_string(), STOPPED_ON_REQUEST);
        });
    }

    /// Without a stop the in-process cycle measures every ball and identifies the
    /// injected errors (the paper's table, default plan).
    #[test]
    fn the_in_process_cycle_identifies_the_injected_errors() {
        let job = RotaryJob::default();
        let mut calls = 0;
        let run = runtime()
            .block_on(run_cycle(&job, |_, _| calls += 1, std::future::pending()))
            .unwrap();
        let m = run.cycle.as_ref().expect("the cycle ends");
        assert_eq!(calls, m.balls.len());
        let constants = MachineConstants::default();
        let id = rotary::identify(&m.centres(), &constants).unwrap();
        let truth = run.truth.as_ref().expect("the simulated table");
        let injected = job::rotary::injected_errors(&truth.errors);
        assert!((id.errors.delta_xc_mm - injected.delta_xc_mm).abs() < 1e-3);
        assert!(run.time_s > 0.0);
        // Compensated with the identified errors, the tool tip lands closer.
        let check = compensation_check(truth, &constants, &id.errors).unwrap();
        assert!(check.tip_max_after_mm < check.tip_max_before_mm / 10.0);
    }

    /// The in-process cycle through the adapter is the synchronous one, figure for
    /// figure (the same session, the same table).
    #[test]
    fn the_in_process_cycle_is_the_synchronous_one() {
        let job = RotaryJob {
            seed: 3,
            ..RotaryJob::default()
        };
        let run = runtime()
            .block_on(run_cycle(&job, |_, _| {}, std::future::pending()))
            .unwrap();
        let mut table = job.simulated();
        let sync = rotary::measure::measure(
            &mut table,
            &job.machine.unwrap_or_default(),
            &job.plan.unwrap_or_default(),
            |_, _| {},
        );
        assert_eq!(run.cycle, sync);
        assert_eq!(run.time_s.to_bits(), table.time_s.to_bits());
    }

    /// The cycle's future can go to a multi-thread runtime's task (the service's).
    #[test]
    fn the_cycle_is_send() {
        fn send<T: Send>(_: T) {}
        let job = RotaryJob::default();
        send(run_cycle(&job, |_, _| {}, std::future::pending()));
    }

    /// The cycle through the GRBL emulator, opened by `devices` through the factory,
    /// on the test's runtime: the same table behind the link gives the injected errors.
    #[test]
    fn the_cycle_through_the_grbl_emulator_identifies_the_injected_errors() {
        let job = RotaryJob {
            link: Some(job::rotary::RotaryLink::GrblEmulator),
            seed: 3,
            ..RotaryJob::default()
        };
        let run = runtime()
            .block_on(run_cycle(&job, |_, _| {}, std::future::pending()))
            .unwrap();
        let m = run.cycle.as_ref().unwrap_or_else(|s| panic!("{}", s.error));
        assert_eq!(m.balls.len(), 20);
        assert_eq!(m.probe_touches, 206);
        let constants = MachineConstants::default();
        let id = rotary::identify(&m.centres(), &constants).unwrap();
        let injected = job::rotary::injected_errors(&run.truth.as_ref().unwrap().errors);
        for ((name, g), (_, w)) in id.errors.named().iter().zip(injected.named()) {
            let d = g - w;
            let tol = if name.ends_with("_deg") {
                0.0005
            } else {
                0.001
            };
            assert!(d.abs() <= tol, "{name}: {d}");
        }
        assert!(run.time_s > 0.0);
    }

    #[test]
    fn a_controller_that_is_not_there_is_an_error_before_the_cycle() {
        let job = RotaryJob {
            link: Some(job::rotary::RotaryLink::Grbl(job::rotary::GrblPort {
                port: "/dev/does-not-exist-rotary-runner".into(),
                baud: 115_200,
                poll_ms: None,
            })),
            ..RotaryJob::default()
        };
        let e = runtime()
            .block_on(run_cycle(&job, |_, _| {}, std::future::pending()))
            .err()
            .expect("refused");
        assert!(
            e.to_string().starts_with(
                "connecting to the GRBL controller on /dev/does-not-exist-rotary-runner: "
            ),
            "{e}"
        );
    }
}

//! Opening the machine of a rotary measurement job (source B, `job::rotary::RotaryJob`):
//! the simulated table in-process (no link), the same table behind the GRBL emulator on
//! a pseudo-terminal (`"grbl_emulator"`), or a real GRBL-family controller on a serial
//! port (`{"grbl": {..}}`). A link is opened only through the drivers' factory
//! (`drivers::open_prober`), which refuses, before any motion, a controller without the
//! A and C axes or a probe input.

use drivers::grbl::GrblOptions;
use drivers::{Axis, DriverError, Prober, ProberError, StageLink};
use emulators::grbl::{GrblConfig, GrblDevice, GrblPty};
use job::rotary::{RotaryJob, RotaryLink, SimulatedTable};
use std::time::Duration;
use world::axes::{lock_axes, AxesMachine, SharedAxes};
use world::rotary::{RotaryMachineSim, RotaryWorkpiece};

/// The rotary axes the measurement cycle turns.
pub const CYCLE_AXES: [Axis; 2] = [Axis::A, Axis::C];

/// The machine of a rotary job, open.
pub enum RotaryTable {
    /// The simulated table in this process, driven directly (no link), on its own clock
    /// of simulated machine time (`SimulatedTable::time_s`).
    InProcess(SimulatedTable),
    /// A controller behind a link.
    Linked(LinkedTable),
}

/// A controller behind a link, as a prober; with the GRBL emulator, the emulator and
/// the simulated table behind it, kept alive as long as the link.
pub struct LinkedTable {
    /// The controller (dropped before the emulator it talks to).
    pub prober: Box<dyn Prober>,
    /// Its serial port (the emulator's pseudo-terminal).
    pub port: String,
    emulated: Option<EmulatedTable>,
}

struct EmulatedTable {
    sim: RotaryMachineSim,
    axes: SharedAxes,
    _pty: GrblPty,
}

impl LinkedTable {
    /// The simulated table behind the emulator (its truth known); None for a real
    /// controller.
    pub fn truth(&self) -> Option<&RotaryMachineSim> {
        self.emulated.as_ref().map(|e| &e.sim)
    }

    /// The emulated machine's clock (s); None for a real controller.
    pub fn machine_time_s(&self) -> Option<f64> {
        self.emulated.as_ref().map(|e| lock_axes(&e.axes).now_s())
    }
}

/// Why a rotary job's machine could not be opened; nothing has moved.
#[derive(Debug, thiserror::Error)]
pub enum RotaryOpenError {
    #[error("starting the GRBL emulator on a pseudo-terminal: {error}")]
    Emulator { error: std::io::Error },
    #[error("connecting to the GRBL controller on {port}: {error}")]
    Connect { port: String, error: DriverError },
    #[error(
        "the controller on {port} has no {axis:?} axis (its axes: {axes:?}); the cycle needs A and C"
    )]
    MissingAxis {
        port: String,
        axis: Axis,
        /// Its rotary axes.
        axes: Vec<Axis>,
    },
    #[error("the controller on {port} reports no probe input; the cycle probes the balls")]
    NoProbeInput { port: String },
}

/// Opens the job's machine. Call from inside the tokio runtime that will run the cycle
/// (the emulator serves its pseudo-terminal from a task of that runtime).
pub async fn open_rotary(job: &RotaryJob) -> Result<RotaryTable, RotaryOpenError> {
    match &job.link {
        None => Ok(RotaryTable::InProcess(job.simulated())),
        Some(RotaryLink::GrblEmulator) => {
            // Six axes X Y Z A B C (B without travel), the table's balls and rim under
            // the probe; motion on the unconstrained clock.
            let sim = job.simulated().sim;
            let axes = AxesMachine::new(Box::new(RotaryWorkpiece { sim: sim.clone() })).shared();
            let pty = GrblPty::spawn(
                GrblDevice::with_axes(axes.clone(), GrblConfig::default()),
                None,
            )
            .map_err(|error| RotaryOpenError::Emulator { error })?;
            let port = pty.path().to_string();
            let options = GrblOptions {
                poll_interval: Duration::from_millis(2),
                ..GrblOptions::default()
            };
            let prober = open_prober(&port, 115_200, options).await?;
            Ok(RotaryTable::Linked(LinkedTable {
                prober,
                port,
                emulated: Some(EmulatedTable {
                    sim,
                    axes,
                    _pty: pty,
                }),
            }))
        }
        Some(RotaryLink::Grbl(port)) => {
            let mut options = GrblOptions::default();
            if let Some(ms) = port.poll_ms {
                options.poll_interval = Duration::from_millis(ms);
            }
            let prober = open_prober(&port.port, port.baud, options).await?;
            Ok(RotaryTable::Linked(LinkedTable {
                prober,
                port: port.port.clone(),
                emulated: None,
            }))
        }
    }
}

/// The GRBL controller at `port` as a prober with the cycle's axes, through the
/// factory.
async fn open_prober(
    port: &str,
    baud: u32,
    options: GrblOptions,
) -> Result<Box<dyn Prober>, RotaryOpenError> {
    let link = StageLink::Grbl {
        port: port.to_string(),
        baud,
        options,
    };
    let port = port.to_string();
    drivers::open_prober(&link, &CYCLE_AXES)
        .await
        .map_err(|e| match e {
            ProberError::Open(error) => RotaryOpenError::Connect { port, error },
            ProberError::MissingAxis {
                axis, rotary_axes, ..
            } => RotaryOpenError::MissingAxis {
                port,
                axis,
                axes: rotary_axes,
            },
            ProberError::NoProbing { .. } => RotaryOpenError::NoProbeInput { port },
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rt() -> tokio::runtime::Runtime {
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap()
    }

    #[test]
    fn no_link_is_the_simulated_table_in_process() {
        let table = rt().block_on(open_rotary(&RotaryJob::default())).unwrap();
        assert!(matches!(table, RotaryTable::InProcess(t) if t.moves == 0));
    }

    /// The emulator's table behind the factory's prober: five axes and a probe, its
    /// truth and clock known.
    #[test]
    fn the_emulator_is_opened_through_the_factory_with_its_truth() {
        rt().block_on(async {
            let job = RotaryJob {
                link: Some(RotaryLink::GrblEmulator),
                ..RotaryJob::default()
            };
            let RotaryTable::Linked(mut table) = open_rotary(&job).await.unwrap() else {
                panic!("a link");
            };
            assert!(table.port.starts_with("/dev/"), "{}", table.port);
            assert!(table.prober.name().starts_with("GRBL"));
            let truth = table.truth().expect("the emulated table's truth");
            assert_eq!(truth.errors, job.simulated().sim.errors);
            let before = table.machine_time_s().unwrap();
            let up = drivers::AxisValues::default()
                .with(Axis::Z, -20.0)
                .with(Axis::C, 30.0);
            table.prober.move_to(up).await.unwrap();
            assert!(table.machine_time_s().unwrap() > before);
        });
    }

    /// Four axes X Y Z A, no probe.
    struct NoC;

    impl world::axes::Workpiece for NoC {
        fn axes(&self) -> usize {
            4
        }
        fn limits(&self, _: usize) -> world::axes::AxisLimits {
            world::axes::AxisLimits {
                min: -100.0,
                max: 100.0,
                max_rate: 1000.0,
            }
        }
        fn probe_contact(
            &mut self,
            _: &world::axes::AxesPosition,
            _: &world::axes::AxesPosition,
        ) -> Option<world::axes::AxesPosition> {
            None
        }
        fn probe_touching(&self, _: &world::axes::AxesPosition) -> bool {
            false
        }
    }

    /// A controller with A but no C is refused with the cycle's words before any motion.
    #[test]
    fn a_controller_without_c_is_refused_before_motion() {
        rt().block_on(async {
            let axes = AxesMachine::new(Box::new(NoC)).shared();
            let pty = GrblPty::spawn(
                GrblDevice::with_axes(axes.clone(), GrblConfig::default()),
                None,
            )
            .unwrap();
            let job = RotaryJob {
                link: Some(RotaryLink::Grbl(job::rotary::GrblPort {
                    port: pty.path().to_string(),
                    baud: 115_200,
                    poll_ms: Some(2),
                })),
                ..RotaryJob::default()
            };
            let e = open_rotary(&job).await.err().expect("refused");
            assert_eq!(
                e.to_string(),
                format!(
                    "the controller on {} has no C axis (its axes: [A]); the cycle needs A and C",
                    pty.path()
                )
            );
            assert_eq!(lock_axes(&axes).now_s(), 0.0, "nothing moved");
        });
    }

    #[test]
    fn a_missing_port_names_it() {
        let job = RotaryJob {
            link: Some(RotaryLink::Grbl(job::rotary::GrblPort {
                port: "/dev/does-not-exist-rotary".into(),
                baud: 115_200,
                poll_ms: None,
            })),
            ..RotaryJob::default()
        };
        let e = rt().block_on(open_rotary(&job)).err().expect("refused");
        let msg = e.to_string();
        assert!(
            msg.starts_with("connecting to the GRBL controller on /dev/does-not-exist-rotary: "),
            "{msg}"
        );
    }
}

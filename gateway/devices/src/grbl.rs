//! Opening a `grbl` stage: the controller on its serial port, or the GRBL emulator on a
//! pseudo-terminal driving a new simulated machine.

use crate::{new_rig, EmulatedStage, OpenedStage};
use drivers::grbl::{GrblOptions, GrblStage};
use drivers::DriverError;
use emulators::grbl::{GrblConfig, GrblDevice, GrblPty};
use job::Job;
use std::time::Duration;
use world::machine::MachineConfig;
use world::Clock;

/// Open a job's `grbl` stage: the controller on its serial port, or the emulator on a
/// pseudo-terminal driving a new simulated machine (returned as the rig). Must run
/// inside the tokio runtime that will run the job (the emulator serves its
/// pseudo-terminal from a task of that runtime).
pub(crate) async fn open(
    job: &Job,
    port: Option<&str>,
    baud: u32,
    emulate: Option<&MachineConfig>,
) -> Result<OpenedStage, DriverError> {
    match (emulate, port) {
        (Some(machine), _) => {
            let rig = new_rig(job, machine);
            // The motion clock is unconstrained: moves end as soon as the driver polls.
            let dev = GrblDevice::new(
                rig.clone(),
                GrblConfig {
                    clock: Clock::Unconstrained,
                    ..Default::default()
                },
            );
            let emulator = GrblPty::spawn(dev, None).map_err(|e| DriverError::Transport {
                device: "GRBL emulator".into(),
                message: format!("cannot create a pseudo-terminal: {e}"),
            })?;
            let opts = GrblOptions {
                poll_interval: Duration::from_millis(1),
                ..Default::default()
            };
            let stage = GrblStage::open(emulator.path(), baud, opts).await?;
            Ok((Box::new(EmulatedStage::new(stage, emulator)), Some(rig)))
        }
        (None, Some(port)) => {
            let stage = GrblStage::open(port, baud, GrblOptions::default()).await?;
            Ok((Box::new(stage), None))
        }
        (None, None) => Err(DriverError::Unsupported {
            device: "grbl stage".into(),
            message: "needs `port` (a serial port) or `emulate` (a machine file)".into(),
        }),
    }
}

//! The `grbl` stage backend of a job: a GRBL controller on a serial port, or, for the
//! demo, the GRBL emulator on a real pseudo-terminal driving the simulated machine that
//! the simulated camera looks at. Either way the pipeline talks to [`GrblStage`] over
//! real GRBL protocol bytes.

use crate::config::{Job, StageSpec};
use crate::run::{new_rig, EmulatedStage, OpenedStage};
use drivers::grbl::{GrblOptions, GrblStage};
use drivers::DriverError;
use emulators::grbl::{GrblConfig, GrblDevice, GrblPty};
use std::time::Duration;
use world::Clock;

/// Replace a simulated job's stage by the same machine behind the GRBL emulator
/// (`gateway demo --stage grbl`).
pub fn over_grbl(job: &mut Job) -> Result<(), DriverError> {
    match &job.stage {
        StageSpec::Sim { machine } => {
            job.stage = StageSpec::Grbl {
                port: None,
                baud: 115_200,
                emulate: Some(machine.clone()),
            };
            Ok(())
        }
        StageSpec::Grbl { .. } => Ok(()),
        StageSpec::Modbus(_) | StageSpec::Canopen(_) => Err(DriverError::Unsupported {
            device: "job".into(),
            message: "--stage grbl replaces the simulated stage of the demo job".into(),
        }),
    }
}

/// Open a job's `grbl` stage: the controller on its serial port, or the emulator on a
/// pseudo-terminal driving a new simulated machine (returned as the rig). Must run
/// inside the tokio runtime that will run the job (the emulator serves its
/// pseudo-terminal from a task of that runtime).
pub async fn open(job: &Job) -> Result<OpenedStage, DriverError> {
    let StageSpec::Grbl {
        port,
        baud,
        emulate,
    } = &job.stage
    else {
        return Err(DriverError::Unsupported {
            device: "job".into(),
            message: "not a grbl stage".into(),
        });
    };
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
            let stage = GrblStage::open(emulator.path(), *baud, opts).await?;
            Ok((Box::new(EmulatedStage::new(stage, emulator)), Some(rig)))
        }
        (None, Some(port)) => {
            let stage = GrblStage::open(port, *baud, GrblOptions::default()).await?;
            Ok((Box::new(stage), None))
        }
        (None, None) => Err(DriverError::Unsupported {
            device: "grbl stage".into(),
            message: "needs `port` (a serial port) or `emulate` (a machine file)".into(),
        }),
    }
}

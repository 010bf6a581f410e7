//! Opening a `grbl` stage: the controller on its serial port, or the GRBL emulator on a
//! pseudo-terminal driving a new simulated machine.

use crate::emulated::{new_rig, EmulatedStage, OpenedStage};
use crate::error::OpenError;
use drivers::grbl::GrblOptions;
use drivers::StageLink;
use emulators::grbl::{GrblConfig, GrblDevice, GrblPty};
use job::{GrblLink, Job};
use std::time::Duration;
use world::Clock;

/// Open a job's `grbl` stage: the controller on its serial port, or the emulator on a
/// pseudo-terminal driving a new simulated machine (returned as the rig). Must run
/// inside the tokio runtime that will run the job (the emulator serves its
/// pseudo-terminal from a task of that runtime).
pub(crate) async fn open(job: &Job, link: &GrblLink, baud: u32) -> Result<OpenedStage, OpenError> {
    match link {
        GrblLink::Port(port) => {
            let link = StageLink::Grbl {
                port: port.clone(),
                baud,
                options: GrblOptions::default(),
            };
            Ok((drivers::open_stage(&link).await?, None))
        }
        GrblLink::Emulate(machine) => {
            let rig = new_rig(job, machine);
            // The motion clock is unconstrained: moves end as soon as the driver polls.
            let dev = GrblDevice::new(
                rig.clone(),
                GrblConfig {
                    clock: Clock::Unconstrained,
                    ..Default::default()
                },
            );
            let emulator = GrblPty::spawn(dev, None).map_err(|e| OpenError::Emulator {
                what: "GRBL emulator",
                message: format!("cannot create a pseudo-terminal: {e}"),
            })?;
            let link = StageLink::Grbl {
                port: emulator.path().to_string(),
                baud,
                options: GrblOptions {
                    poll_interval: Duration::from_millis(1),
                    ..Default::default()
                },
            };
            let stage = drivers::open_stage(&link).await?;
            Ok((Box::new(EmulatedStage::new(stage, emulator)), Some(rig)))
        }
    }
}

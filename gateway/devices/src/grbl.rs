//! Opening a `grbl` stage: the controller on its serial port, or the GRBL emulator on a
//! pseudo-terminal driving a new simulated machine.

use crate::emulated::{new_rig, EmulatedStage, OpenedStage};
use crate::error::OpenError;
use drivers::grbl::GrblOptions;
use drivers::StageLink;
use emulators::grbl::{GrblConfig, GrblDevice, GrblPty};
use job::{GrblLink, Job};
use std::time::Duration;
use world::machine::MachineConfig;
use world::{Clock, SharedRig};

/// The GRBL emulator of an `emulate` link on a new pseudo-terminal, driving a new
/// simulated machine (returned as the rig) on `clock`: for what talks to the controller
/// itself rather than through the stage driver (the live pass-through). Must run inside
/// a tokio runtime.
pub fn spawn_grbl_emulator(
    job: &Job,
    machine: &MachineConfig,
    clock: Clock,
) -> Result<(GrblPty, SharedRig), OpenError> {
    let rig = new_rig(job, machine);
    let dev = GrblDevice::new(
        rig.clone(),
        GrblConfig {
            clock,
            ..Default::default()
        },
    );
    let emulator = GrblPty::spawn(dev, None).map_err(|e| OpenError::Emulator {
        what: "GRBL emulator",
        message: format!("cannot create a pseudo-terminal: {e}"),
    })?;
    Ok((emulator, rig))
}

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
            // The motion clock is unconstrained: moves end as soon as the driver polls.
            let (emulator, rig) = spawn_grbl_emulator(job, machine, Clock::Unconstrained)?;
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

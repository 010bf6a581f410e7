//! The `grbl` stage backend of a job: a GRBL controller on a serial port, or, for the
//! demo, the GRBL emulator on a real pseudo-terminal driving the simulated machine that
//! the simulated camera looks at. Either way the pipeline talks to [`GrblStage`] over
//! real GRBL protocol bytes.

use crate::config::{CameraSpec, Job, StageSpec};
use crate::run::Devices;
use async_trait::async_trait;
use drivers::grbl::{GrblOptions, GrblStage};
use drivers::sim::{SharedRig, SimCamera};
use drivers::{AxisValues, DriverError, Stage, StageInfo, StageStatus};
use emulators::grbl::{Clock, GrblConfig, GrblDevice, GrblPty};
use emulators::machine::SimMachine;
use emulators::rig::SimRig;
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// A GRBL stage whose controller is the in-process emulator: the emulator lives as
/// long as the stage.
pub struct EmulatedGrblStage {
    stage: GrblStage,
    _emulator: GrblPty,
}

#[async_trait]
impl Stage for EmulatedGrblStage {
    fn info(&self) -> &StageInfo {
        self.stage.info()
    }
    async fn home(&mut self) -> Result<(), DriverError> {
        self.stage.home().await
    }
    async fn move_to(&mut self, target: AxisValues, feed_mm_min: f64) -> Result<(), DriverError> {
        self.stage.move_to(target, feed_mm_min).await
    }
    async fn move_by(&mut self, delta: AxisValues, feed_mm_min: f64) -> Result<(), DriverError> {
        self.stage.move_by(delta, feed_mm_min).await
    }
    async fn position(&mut self) -> Result<AxisValues, DriverError> {
        self.stage.position().await
    }
    async fn wait_idle(&mut self) -> Result<(), DriverError> {
        self.stage.wait_idle().await
    }
    async fn stop(&mut self) -> Result<(), DriverError> {
        self.stage.stop().await
    }
    async fn status(&mut self) -> Result<StageStatus, DriverError> {
        self.stage.status().await
    }
}

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

/// Open a job whose stage is `grbl`. Must run inside the tokio runtime that will run
/// the job (the emulator serves its pseudo-terminal from a task of that runtime).
pub async fn open(job: &Job) -> Result<Devices, DriverError> {
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
    match (emulate, port, &job.camera) {
        (Some(machine), _, CameraSpec::Sim { model }) => {
            let rig = SimRig::new(SimMachine::new(machine.clone()), job.board.clone(), model.clone());
            let rig: SharedRig = Arc::new(Mutex::new(rig));
            // The motion clock is unconstrained: moves end as soon as the driver polls.
            let dev = GrblDevice::new(rig.clone(), GrblConfig { clock: Clock::Unconstrained, ..Default::default() });
            let emulator = GrblPty::spawn(dev, None).map_err(|e| DriverError::Transport {
                device: "GRBL emulator".into(),
                message: format!("cannot create a pseudo-terminal: {e}"),
            })?;
            let opts = GrblOptions { poll_interval: Duration::from_millis(1), ..Default::default() };
            let stage = GrblStage::open(emulator.path(), *baud, opts).await?;
            Ok(Devices {
                stage: Box::new(EmulatedGrblStage { stage, _emulator: emulator }),
                camera: Box::new(SimCamera::new(rig.clone())),
                rig: Some(rig),
            })
        }
        (None, Some(_), CameraSpec::Sim { .. }) => Err(DriverError::NotAvailable {
            backend: "grbl + sim camera".into(),
            reason: "a simulated camera cannot see a real machine: use `emulate` for the demo, or a real camera".into(),
        }),
        (None, None, _) => Err(DriverError::Unsupported {
            device: "grbl stage".into(),
            message: "needs `port` (a serial port) or `emulate` (a machine file)".into(),
        }),
    }
}

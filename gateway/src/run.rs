//! Opening the devices a job names, and running the job to a report.

use crate::camera_link::CameraLink;
use crate::config::{CameraSpec, Job, StageSpec};
use crate::orchestrator::{Event, Orchestrator};
use crate::report::{Report, TruthAt};
use async_trait::async_trait;
use drivers::sim::{SimCamera, SimStage};
use drivers::{AxisValues, Camera, DriverError, Stage, StageInfo, StageStatus};
use std::any::Any;
use std::time::Instant;
use world::machine::MachineConfig;
use world::SharedRig;

/// The devices of a job. `rig` is set when the machine is simulated: it is how reports
/// learn the truth; the pipeline never receives it.
pub struct Devices {
    pub stage: Box<dyn Stage>,
    pub camera: Box<dyn Camera>,
    pub rig: Option<SharedRig>,
}

/// A stage whose controller or drives are emulated in this process: the emulator (a
/// pseudo-terminal, a server) is kept alive exactly as long as the stage.
pub struct EmulatedStage {
    stage: Box<dyn Stage>,
    _emulator: Box<dyn Any + Send>,
}

impl EmulatedStage {
    pub fn new(stage: impl Stage + 'static, emulator: impl Any + Send) -> Self {
        Self {
            stage: Box::new(stage),
            _emulator: Box::new(emulator),
        }
    }
}

#[async_trait]
impl Stage for EmulatedStage {
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

/// What a stage backend opens: the stage, and the rig when the machine is simulated.
pub type OpenedStage = (Box<dyn Stage>, Option<SharedRig>);

/// The simulated machine of a job: `machine` with the job's board, seen by the job's
/// camera optics.
pub fn new_rig(job: &Job, machine: &MachineConfig) -> SharedRig {
    let CameraSpec::Sim { model } = &job.camera;
    world::shared_rig(machine.clone(), job.board.clone(), model.clone())
}

/// Open the devices of a fully in-process job (simulated stage and camera) without an
/// async runtime. Jobs with real or emulated links use [`open_devices_async`].
pub fn open_devices(job: &Job) -> Result<Devices, DriverError> {
    match (&job.stage, &job.camera_link) {
        (StageSpec::Sim { machine }, CameraLink::Direct) => {
            let rig = new_rig(job, machine);
            Ok(Devices {
                stage: Box::new(SimStage::new(rig.clone())),
                camera: Box::new(SimCamera::new(rig.clone())),
                rig: Some(rig),
            })
        }
        _ => Err(DriverError::NotAvailable {
            backend: "devices over real links".into(),
            reason: "this job's stage or camera connects over a link (serial, CAN, Modbus, GigE Vision), which is opened inside the async runtime: use run::open_devices_async".into(),
        }),
    }
}

/// Open the devices of any job. Call from inside the runtime that will run the job
/// (emulators in-process and bus tasks are tasks of that runtime).
pub async fn open_devices_async(job: &Job) -> Result<Devices, DriverError> {
    crate::camera_link::check_pairing(&job.camera_link, job.stage.is_simulated())?;
    let (stage, rig): OpenedStage = match &job.stage {
        StageSpec::Sim { machine } => {
            let rig = new_rig(job, machine);
            (Box::new(SimStage::new(rig.clone())), Some(rig))
        }
        StageSpec::Grbl { .. } => crate::grbl_stage::open(job).await?,
        StageSpec::Modbus(_) => crate::modbus_stage::open(job).await?,
        StageSpec::Canopen(_) => crate::canopen_stage::open(job).await?,
    };
    let camera = crate::camera_link::open(&job.camera_link, rig.as_ref()).await?;
    Ok(Devices { stage, camera, rig })
}

/// Progress callback: (targets done, targets planned).
pub type Progress<'a> = &'a mut dyn FnMut(usize, usize);

/// Run a job on opened devices and build its report (also when it stopped early).
pub async fn run_job(job: &Job, devices: &mut Devices, progress: Progress<'_>) -> Report {
    let started = Instant::now();
    let rig = devices.rig.clone();
    // Truth error (um) at the first and latest measurement of each target.
    let mut truth: Vec<Option<TruthAt>> = Vec::new();
    let mut current: Option<(usize, TruthAt)> = None;
    let mut on_event = |e: Event| match e {
        Event::Measured { target_index, .. } => {
            if let Some(rig) = &rig {
                let pose = rig.lock().unwrap_or_else(|p| p.into_inner()).truth();
                let t = job.targets[target_index];
                let err = [
                    (pose.centre_mm[0] - t[0]) * 1000.0,
                    (pose.centre_mm[1] - t[1]) * 1000.0,
                ];
                match &mut current {
                    Some((i, at)) if *i == target_index => at.after_um = err,
                    _ => {
                        current = Some((
                            target_index,
                            TruthAt {
                                before_um: err,
                                after_um: err,
                            },
                        ))
                    }
                }
            }
        }
        Event::TargetDone { outcome, of } => {
            truth.push(current.take().map(|(_, at)| at));
            progress(outcome.index + 1, of);
        }
        Event::Homed => {}
    };
    let stage_name = devices.stage.info().name.clone();
    let camera_name = devices.camera.info().model.clone();
    let mut orch = Orchestrator {
        stage: devices.stage.as_mut(),
        camera: devices.camera.as_mut(),
        job,
    };
    let result = orch.run(&mut on_event).await;
    let (outcomes, error) = match result {
        Ok(o) => (o, None),
        Err(f) => (f.completed, Some(f.error.to_string())),
    };
    Report::build(
        &job.source,
        &stage_name,
        &camera_name,
        job.localize.method,
        job.targets.len(),
        &outcomes,
        &truth,
        started.elapsed().as_secs_f64(),
        error,
    )
}

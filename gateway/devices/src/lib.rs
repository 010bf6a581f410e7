//! Opening the devices a job names: spec -> boxed [`Stage`] and [`Camera`], over real
//! links through the drivers, or over in-process emulators of the same buses driving a
//! simulated machine (whose rig is returned so that reports can learn the truth).
//!
//! The only crate besides the runner that touches both drivers and emulators; the
//! pipeline crates (vision, compensation) never see what it opens, only frames and
//! positions through the traits.

mod camera;
mod canopen;
mod grbl;
mod modbus;

pub use camera::{open_camera, EmulatedGige, ReplayCamera};

use async_trait::async_trait;
use drivers::sim::{SimCamera, SimStage};
use drivers::{AxisValues, Camera, Capabilities, DriverError, Stage, StageInfo, StageStatus};
use job::{CameraSpec, Job, PairingError, StageSpec};
use protocol::config::ConfigDoc;
use std::any::Any;
use std::path::Path;
use world::camera::CameraModel;
use world::machine::MachineConfig;
use world::SharedRig;

/// Why the devices of a job could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    /// The camera cannot see the machine; nothing was opened.
    #[error(transparent)]
    Pairing(#[from] PairingError),
    /// A device, its link or an in-process emulator failed.
    #[error(transparent)]
    Driver(#[from] DriverError),
    /// An emulator this process was to run could not start (no pseudo-terminal, no
    /// loopback port, a drive description it cannot serve).
    #[error("cannot start the {what}: {message}")]
    Emulator { what: &'static str, message: String },
    /// [`open_devices`] was asked for links that open inside an async runtime.
    #[error("this job's stage or camera connects over a link (serial, CAN, Modbus, GigE Vision), which is opened inside the async runtime: use devices::open_devices_async")]
    NeedsRuntime,
}

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
    pub fn new(stage: Box<dyn Stage>, emulator: impl Any + Send) -> Self {
        Self {
            stage,
            _emulator: Box::new(emulator),
        }
    }
}

#[async_trait]
impl Stage for EmulatedStage {
    fn info(&self) -> &StageInfo {
        self.stage.info()
    }
    fn capabilities(&self) -> Capabilities {
        self.stage.capabilities()
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
    let model = match &job.camera {
        CameraSpec::Sim { model } | CameraSpec::EmulatedGige { model, .. } => model.clone(),
        // Replayed frames on a simulated machine: the rig still needs optics; they are
        // never rendered.
        CameraSpec::Gige { .. } | CameraSpec::Replay { .. } => reference_camera(),
    };
    world::shared_rig(machine.clone(), job.board.clone(), model)
}

fn reference_camera() -> CameraModel {
    let (name, text) = job::EMBEDDED
        .iter()
        .find(|(name, _)| name.ends_with("mono-1.3mp.toml"))
        .expect("the reference camera is embedded");
    let doc = ConfigDoc::from_text(name, text, Path::new("config/cameras"));
    CameraModel::from_doc(&doc).expect("the embedded reference camera is valid")
}

/// Open the devices of a fully in-process job (simulated stage and camera) without an
/// async runtime. Jobs with real or emulated links use [`open_devices_async`].
pub fn open_devices(job: &Job) -> Result<Devices, OpenError> {
    match (&job.stage, &job.camera) {
        (StageSpec::Sim { machine }, CameraSpec::Sim { .. }) => {
            let rig = new_rig(job, machine);
            Ok(Devices {
                stage: Box::new(SimStage::new(rig.clone())),
                camera: Box::new(SimCamera::new(rig.clone())),
                rig: Some(rig),
            })
        }
        _ => Err(OpenError::NeedsRuntime),
    }
}

/// Open the devices of any job. Call from inside the runtime that will run the job
/// (emulators in-process and bus tasks are tasks of that runtime).
pub async fn open_devices_async(job: &Job) -> Result<Devices, OpenError> {
    job.check_pairing()?;
    let (stage, rig): OpenedStage = match &job.stage {
        StageSpec::Sim { machine } => {
            let rig = new_rig(job, machine);
            (Box::new(SimStage::new(rig.clone())), Some(rig))
        }
        StageSpec::Grbl { link, baud } => grbl::open(job, link, *baud).await?,
        StageSpec::Modbus(spec) => modbus::open(job, spec).await?,
        StageSpec::Canopen(spec) => canopen::open(job, spec).await?,
    };
    let camera = open_camera(&job.camera, rig.as_ref()).await?;
    Ok(Devices { stage, camera, rig })
}

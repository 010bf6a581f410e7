//! Opening the devices a job names: spec -> boxed [`Stage`] and [`Camera`], over real
//! links through the drivers, or over in-process emulators of the same buses driving a
//! simulated machine (whose rig is returned so that reports can learn the truth). The
//! rotary table's probing cycle ([`open_rotary`]: a `drivers::Prober`) and the conveyor
//! cutter ([`open_cutter`], [`open_emulated_cutter`]) are opened here too.
//!
//! The only crate besides the runner that touches both drivers and emulators; the
//! pipeline crates (vision, compensation) never see what it opens, only frames and
//! positions through the traits.

mod camera;
mod canopen;
mod cutter;
mod emulated;
mod error;
mod grbl;
mod linuxcnc;
mod modbus;
mod rotary;

pub use camera::{open_camera, EmulatedGige, ReplayCamera};
pub use cutter::{open_cutter, open_emulated_cutter, Cutter};
pub use emulated::{new_rig, EmulatedStage, OpenedStage};
pub use error::OpenError;
pub use grbl::spawn_grbl_emulator;
pub use linuxcnc::{open_followed, FollowedLinuxcnc};
pub use rotary::{open_rotary, LinkedTable, RotaryOpenError, RotaryTable, CYCLE_AXES};

use drivers::sim::{SimCamera, SimStage};
use drivers::{Camera, Stage};
use job::{CameraSpec, Job, StageSpec};
use world::SharedRig;

/// The devices of a job. `rig` is set when the machine is simulated: it is how reports
/// learn the truth; the pipeline never receives it.
pub struct Devices {
    pub stage: Box<dyn Stage>,
    pub camera: Box<dyn Camera>,
    pub rig: Option<SharedRig>,
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
    let (stage, rig) = open_stage_async(job).await?;
    let camera = open_camera(&job.camera, rig.as_ref()).await?;
    Ok(Devices { stage, camera, rig })
}

/// Open the stage of a job alone (with the simulated machine's rig when it is one):
/// for a front end that needs the controller but may have no camera (the pass-through
/// after a map was measured).
/// The camera's pairing with the stage is not checked: no camera is opened here.
pub async fn open_stage_async(job: &Job) -> Result<OpenedStage, OpenError> {
    Ok(match &job.stage {
        StageSpec::Sim { machine } => {
            let rig = new_rig(job, machine);
            (Box::new(SimStage::new(rig.clone())), Some(rig))
        }
        StageSpec::Grbl { link, baud } => grbl::open(job, link, *baud).await?,
        StageSpec::Modbus(spec) => modbus::open(job, spec).await?,
        StageSpec::Canopen(spec) => canopen::open(job, spec).await?,
        StageSpec::Linuxcnc(spec) => linuxcnc::open(job, spec).await?,
        StageSpec::Dnc(spec) => (drivers::open_stage(&dnc_link(spec)).await?, None),
    })
}

/// The factory's link of a job's tape-port (DNC) stage.
pub fn dnc_link(spec: &job::dnc::DncStageSpec) -> drivers::StageLink {
    drivers::StageLink::Dnc {
        port: spec.port.clone(),
        baud: spec.baud,
        options: spec.options.clone(),
        axes: spec.axes.clone(),
    }
}

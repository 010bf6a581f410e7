//! Opening a `linuxcnc` stage: the driver on linuxcncrsh, and with `follow` the rig's
//! simulated stage slaved to LinuxCNC's joint motor commands (`emulators::linuxcnc`),
//! so the simulated camera sees what the real controller commands. The rig follows
//! continuously while LinuxCNC moves (every servo period, through LinuxCNC's `sampler`
//! in its HAL; see `emulators::linuxcnc`), and settles
//! on LinuxCNC's final command when each move, homing or program has ended.

use crate::emulated::{new_rig, OpenedStage};
use crate::error::OpenError;
use async_trait::async_trait;
use drivers::linuxcnc::LinuxcncStage;
use drivers::{
    Axis, AxisValues, Capabilities, DriverError, Stage, StageInfo, StageLink, StageStatus,
};
use emulators::linuxcnc::LinuxcncFollower;
use job::linuxcnc::LinuxcncStageSpec;
use job::Job;
use world::SharedRig;

/// The feed the simulated stage follows at (it moves on its own clock; the figure only
/// sets its simulated time).
const FOLLOW_FEED_MM_MIN: f64 = 3000.0;

pub(crate) async fn open(job: &Job, spec: &LinuxcncStageSpec) -> Result<OpenedStage, OpenError> {
    let Some(machine) = &spec.follow else {
        let stage = drivers::open_stage(&StageLink::Linuxcnc {
            address: spec.address.clone(),
            options: spec.options.clone(),
            axes: spec.axes.clone(),
        })
        .await?;
        return Ok((stage, None));
    };
    let rig = new_rig(job, machine);
    let stage = open_followed(spec, rig.clone()).await?;
    Ok((Box::new(stage), Some(rig)))
}

/// The LinuxCNC stage of `spec` with `rig`'s simulated stage following it (a rig of
/// the caller's, so that one simulated machine outlives several sessions, as a real
/// machine does).
pub async fn open_followed(
    spec: &LinuxcncStageSpec,
    rig: SharedRig,
) -> Result<FollowedLinuxcnc, OpenError> {
    let joint = |a: Axis| spec.axes.iter().find(|c| c.axis == a).map(|c| c.joint);
    let (Some(jx), Some(jy)) = (joint(Axis::X), joint(Axis::Y)) else {
        return Err(OpenError::Emulator {
            what: "LinuxCNC follower",
            message: "the stage needs an x and a y axis".into(),
        });
    };
    let stage = LinuxcncStage::open(&spec.address, spec.options.clone(), spec.axes.clone()).await?;
    let follower = LinuxcncFollower::new(rig, [jx, jy], FOLLOW_FEED_MM_MIN).map_err(|e| {
        OpenError::Emulator {
            what: "LinuxCNC follower",
            message: e.to_string(),
        }
    })?;
    Ok(FollowedLinuxcnc { stage, follower })
}

/// A LinuxCNC stage whose motion the rig's simulated stage follows.
pub struct FollowedLinuxcnc {
    stage: LinuxcncStage,
    follower: LinuxcncFollower,
}

fn follow_error(e: std::io::Error) -> DriverError {
    DriverError::Transport {
        device: "the rig following LinuxCNC".into(),
        message: e.to_string(),
    }
}

impl FollowedLinuxcnc {
    fn start(&mut self) -> Result<(), DriverError> {
        self.follower.start().map_err(follow_error)
    }

    /// LinuxCNC's motion has ended (or homing, with `homed`): the rig settles on its
    /// final command.
    fn settle(&mut self, homed: bool) -> Result<(), DriverError> {
        let follower = &mut self.follower;
        drivers::blocking(|| {
            if homed {
                follower.homed()
            } else {
                follower.settle()
            }
        })
        .map(|_| ())
        .map_err(follow_error)
    }

    /// The follower (to record the points of LinuxCNC's path it put the rig on).
    pub fn follower(&mut self) -> &mut LinuxcncFollower {
        &mut self.follower
    }

    /// Run a program file on the LinuxCNC machine in auto mode (`set mode auto`,
    /// `set open`, `set run`, until the interpreter is idle), the rig following.
    pub async fn run_program(&mut self, path: &str) -> Result<(), DriverError> {
        self.start()?;
        let ran = self.stage.run_program(path).await;
        self.settle(false)?;
        ran
    }
}

#[async_trait]
impl Stage for FollowedLinuxcnc {
    fn info(&self) -> &StageInfo {
        self.stage.info()
    }
    fn capabilities(&self) -> Capabilities {
        self.stage.capabilities()
    }
    async fn home(&mut self) -> Result<(), DriverError> {
        self.stage.home().await?;
        self.settle(true)
    }
    async fn move_to(&mut self, target: AxisValues, feed_mm_min: f64) -> Result<(), DriverError> {
        self.start()?;
        let moved = self.stage.move_to(target, feed_mm_min).await;
        // Settle also after a refused move: LinuxCNC may have moved part of the way.
        self.settle(false)?;
        moved
    }
    async fn position(&mut self) -> Result<AxisValues, DriverError> {
        self.stage.position().await
    }
    async fn wait_idle(&mut self) -> Result<(), DriverError> {
        self.stage.wait_idle().await?;
        self.settle(false)
    }
    async fn stop(&mut self) -> Result<(), DriverError> {
        self.stage.stop().await?;
        self.settle(false)
    }
    async fn status(&mut self) -> Result<StageStatus, DriverError> {
        self.stage.status().await
    }
}

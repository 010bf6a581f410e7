//! Opening a `linuxcnc` stage: the driver on linuxcncrsh, and with `follow` the rig's
//! simulated stage slaved to LinuxCNC's joint motor commands (`emulators::linuxcnc`),
//! so the simulated camera sees what the real controller commands.

use crate::emulated::{new_rig, OpenedStage};
use crate::error::OpenError;
use async_trait::async_trait;
use drivers::{
    Axis, AxisValues, Capabilities, DriverError, Stage, StageInfo, StageLink, StageStatus,
};
use emulators::linuxcnc::LinuxcncFollower;
use job::linuxcnc::LinuxcncStageSpec;
use job::Job;

/// The feed the simulated stage follows at (it moves on its own clock; the figure only
/// sets its simulated time).
const FOLLOW_FEED_MM_MIN: f64 = 3000.0;

pub(crate) async fn open(job: &Job, spec: &LinuxcncStageSpec) -> Result<OpenedStage, OpenError> {
    let stage = drivers::open_stage(&StageLink::Linuxcnc {
        address: spec.address.clone(),
        options: spec.options.clone(),
        axes: spec.axes.clone(),
    })
    .await?;
    let Some(machine) = &spec.follow else {
        return Ok((stage, None));
    };
    let joint = |a: Axis| spec.axes.iter().find(|c| c.axis == a).map(|c| c.joint);
    let (Some(jx), Some(jy)) = (joint(Axis::X), joint(Axis::Y)) else {
        return Err(OpenError::Emulator {
            what: "LinuxCNC follower",
            message: "the stage needs an x and a y axis".into(),
        });
    };
    let rig = new_rig(job, machine);
    let follower =
        LinuxcncFollower::new(rig.clone(), [jx, jy]).map_err(|e| OpenError::Emulator {
            what: "LinuxCNC follower",
            message: e.to_string(),
        })?;
    Ok((Box::new(FollowedStage { stage, follower }), Some(rig)))
}

/// A LinuxCNC stage whose moves the rig's simulated stage follows.
struct FollowedStage {
    stage: Box<dyn Stage>,
    follower: LinuxcncFollower,
}

impl FollowedStage {
    fn follow(&mut self, homed: bool) -> Result<(), DriverError> {
        let follower = &mut self.follower;
        drivers::blocking(|| {
            if homed {
                follower.homed(FOLLOW_FEED_MM_MIN)
            } else {
                follower.follow(FOLLOW_FEED_MM_MIN)
            }
        })
        .map(|_| ())
        .map_err(|e| DriverError::Transport {
            device: "the rig following LinuxCNC".into(),
            message: e.to_string(),
        })
    }
}

#[async_trait]
impl Stage for FollowedStage {
    fn info(&self) -> &StageInfo {
        self.stage.info()
    }
    fn capabilities(&self) -> Capabilities {
        self.stage.capabilities()
    }
    async fn home(&mut self) -> Result<(), DriverError> {
        self.stage.home().await?;
        self.follow(true)
    }
    async fn move_to(&mut self, target: AxisValues, feed_mm_min: f64) -> Result<(), DriverError> {
        let moved = self.stage.move_to(target, feed_mm_min).await;
        // Follow also after a refused move: LinuxCNC may have moved part of the way.
        self.follow(false)?;
        moved
    }
    async fn position(&mut self) -> Result<AxisValues, DriverError> {
        self.stage.position().await
    }
    async fn wait_idle(&mut self) -> Result<(), DriverError> {
        self.stage.wait_idle().await?;
        self.follow(false)
    }
    async fn stop(&mut self) -> Result<(), DriverError> {
        self.stage.stop().await?;
        self.follow(false)
    }
    async fn status(&mut self) -> Result<StageStatus, DriverError> {
        self.stage.status().await
    }
}

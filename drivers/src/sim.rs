//! The `sim` backend: a stage controller and a camera attached to an in-process
//! [`SimRig`]. They see what a real controller and camera would: encoder counts and
//! rendered frames; never the rig's truth.

use crate::camera::{Camera, CameraInfo, Frame, FrameMeta};
use crate::error::DriverError;
use crate::stage::{
    check_feed, Axis, AxisInfo, AxisValues, Capabilities, Stage, StageInfo, StageState, StageStatus,
};
use async_trait::async_trait;
use world::machine::MachineRefusal;
use world::{lock, SharedRig};

const DEVICE: &str = "sim stage";

pub struct SimStage {
    rig: SharedRig,
    info: StageInfo,
}

impl SimStage {
    pub fn new(rig: SharedRig) -> Self {
        let info = {
            let r = lock(&rig);
            let c = r.machine().config();
            let axis = |axis, a: &world::machine::AxisConfig| AxisInfo {
                axis,
                min_mm: 0.0,
                max_mm: a.travel_mm,
                resolution_mm: 1.0 / a.counts_per_mm,
                max_feed_mm_min: a.max_feed_mm_min,
            };
            StageInfo {
                name: format!("sim stage ({})", c.machine.name),
                axes: vec![axis(Axis::X, &c.axes.x), axis(Axis::Y, &c.axes.y)],
            }
        };
        Self { rig, info }
    }
}

fn refusal(e: MachineRefusal) -> DriverError {
    match e {
        MachineRefusal::NotHomed => DriverError::InvalidState {
            device: DEVICE.into(),
            message: "not homed: home the stage before moving".into(),
        },
        other => DriverError::Refused {
            device: DEVICE.into(),
            what: "move".into(),
            code: 0,
            message: other.to_string(),
        },
    }
}

#[async_trait]
impl Stage for SimStage {
    fn info(&self) -> &StageInfo {
        &self.info
    }

    /// Point-to-point moves of X and Y only.
    fn capabilities(&self) -> Capabilities {
        Capabilities::default()
    }

    async fn home(&mut self) -> Result<(), DriverError> {
        lock(&self.rig).machine_mut().home();
        Ok(())
    }

    async fn move_to(&mut self, target: AxisValues, feed_mm_min: f64) -> Result<(), DriverError> {
        self.info.check_limits(&target)?;
        check_feed(DEVICE, feed_mm_min)?;
        let mut r = lock(&self.rig);
        let here = r.machine().position_mm();
        let to = [
            target.get(Axis::X).unwrap_or(here[0]),
            target.get(Axis::Y).unwrap_or(here[1]),
        ];
        r.machine_mut()
            .start_move(to, feed_mm_min)
            .map(|_| ())
            .map_err(refusal)
    }

    async fn position(&mut self) -> Result<AxisValues, DriverError> {
        let p = lock(&self.rig).machine().position_mm();
        Ok(AxisValues::xy(p[0], p[1]))
    }

    async fn wait_idle(&mut self) -> Result<(), DriverError> {
        // Simulated time: the move runs to its end at once.
        lock(&self.rig).machine_mut().finish_motion();
        Ok(())
    }

    async fn stop(&mut self) -> Result<(), DriverError> {
        lock(&self.rig).machine_mut().stop();
        Ok(())
    }

    async fn status(&mut self) -> Result<StageStatus, DriverError> {
        let r = lock(&self.rig);
        let p = r.machine().position_mm();
        let state = if !r.machine().is_homed() {
            StageState::NotHomed
        } else if r.machine().is_moving() {
            StageState::Moving
        } else {
            StageState::Idle
        };
        Ok(StageStatus {
            state,
            position: AxisValues::xy(p[0], p[1]),
        })
    }
}

pub struct SimCamera {
    rig: SharedRig,
    info: CameraInfo,
}

impl SimCamera {
    pub fn new(rig: SharedRig) -> Self {
        let info = {
            let r = lock(&rig);
            CameraInfo {
                model: r.camera().model.clone(),
                serial: "SIM-0001".into(),
                width: r.camera().width,
                height: r.camera().height,
                bit_depth: r.camera().bit_depth,
            }
        };
        Self { rig, info }
    }
}

#[async_trait]
impl Camera for SimCamera {
    fn info(&self) -> &CameraInfo {
        &self.info
    }

    async fn grab(&mut self) -> Result<Frame, DriverError> {
        let (image, info) = crate::blocking(|| lock(&self.rig).grab());
        Ok(Frame {
            image,
            meta: FrameMeta {
                sequence: info.sequence,
                timestamp_ns: (info.time_s * 1e9) as u64,
                exposure_us: 5000.0,
                gain_db: 0.0,
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::config::ConfigDoc;
    use std::path::Path;

    #[tokio::test]
    async fn a_feed_that_is_not_a_positive_number_is_refused() {
        let doc = |name: &str, text: &str| ConfigDoc::from_text(name, text, Path::new("."));
        let machine = world::machine::MachineConfig::from_doc(&doc(
            "m.toml",
            include_str!("../../config/machines/c5-stage.toml"),
        ))
        .unwrap();
        let camera = world::camera::CameraModel::from_doc(&doc(
            "c.toml",
            include_str!("../../config/cameras/mono-1.3mp.toml"),
        ))
        .unwrap();
        let board = protocol::Board::nominal(
            "b",
            0.5,
            0.25,
            protocol::Polarity::DarkOnLight,
            10,
            10,
            [0.0; 2],
        );
        let rig = world::shared_rig(machine, board, camera);
        let mut s = SimStage::new(rig.clone());
        s.home().await.unwrap();
        for feed in [f64::NAN, 0.0, -1.0, f64::INFINITY] {
            let e = s
                .move_to(AxisValues::xy(10.0, 10.0), feed)
                .await
                .unwrap_err();
            assert!(
                matches!(e, DriverError::Unsupported { .. }) && e.to_string().contains("feed"),
                "{feed}: {e}"
            );
        }
        s.move_to(AxisValues::xy(10.0, 10.0), 1000.0).await.unwrap();
    }
}

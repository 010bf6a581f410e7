//! Independently driven axes (one drive per axis: CANopen nodes, Modbus units) made into
//! one [`Stage`].

use crate::error::DriverError;
use crate::stage::{
    check_feed, Axis, AxisInfo, AxisValues, Capabilities, Stage, StageInfo, StageState, StageStatus,
};
use async_trait::async_trait;

#[derive(Clone, Debug, PartialEq)]
pub struct AxisStatus {
    pub moving: bool,
    pub homed: bool,
    /// Fault or alarm in the drive's own words.
    pub fault: Option<String>,
    pub position_mm: f64,
}

/// One axis behind its own drive.
#[async_trait]
pub trait AxisDrive: Send {
    fn info(&self) -> &AxisInfo;
    /// Identity for messages (bus, node id / unit id).
    fn device(&self) -> &str;
    async fn home(&mut self) -> Result<(), DriverError>;
    /// Start an absolute move; returns once the drive has accepted it.
    async fn start_move(&mut self, position_mm: f64, speed_mm_min: f64) -> Result<(), DriverError>;
    async fn position(&mut self) -> Result<f64, DriverError>;
    async fn status(&mut self) -> Result<AxisStatus, DriverError>;
    async fn wait_idle(&mut self) -> Result<(), DriverError>;
    async fn stop(&mut self) -> Result<(), DriverError>;
}

/// A stage made of independent axis drives. Moves start every axis with a speed scaled
/// to its share of the path so that the axes arrive together (a straight line when the
/// drives' profiles match).
pub struct MultiAxisStage {
    info: StageInfo,
    drives: Vec<Box<dyn AxisDrive>>,
}

impl MultiAxisStage {
    pub fn new(name: &str, drives: Vec<Box<dyn AxisDrive>>) -> Result<Self, DriverError> {
        let mut axes: Vec<AxisInfo> = Vec::new();
        for d in &drives {
            if axes.iter().any(|a| a.axis == d.info().axis) {
                return Err(DriverError::Unsupported {
                    device: name.to_string(),
                    message: format!("two drives are configured for axis {}", d.info().axis),
                });
            }
            axes.push(d.info().clone());
        }
        Ok(Self {
            info: StageInfo {
                name: name.to_string(),
                axes,
            },
            drives,
        })
    }

    fn drive_mut(&mut self, a: Axis) -> Option<&mut Box<dyn AxisDrive>> {
        self.drives.iter_mut().find(|d| d.info().axis == a)
    }
}

#[async_trait]
impl Stage for MultiAxisStage {
    fn info(&self) -> &StageInfo {
        &self.info
    }

    /// Positioning drives take one target at a time: no program, no table, no probing;
    /// any A, B or C drive is a rotary axis.
    fn capabilities(&self) -> Capabilities {
        Capabilities {
            rotary_axes: Capabilities::rotary_among(self.info.axes.iter().map(|a| a.axis)),
            ..Capabilities::default()
        }
    }

    async fn home(&mut self) -> Result<(), DriverError> {
        for d in &mut self.drives {
            d.home().await?;
        }
        Ok(())
    }

    async fn move_to(&mut self, target: AxisValues, feed_mm_min: f64) -> Result<(), DriverError> {
        self.info.check_limits(&target)?;
        check_feed(&self.info.name, feed_mm_min)?;
        let here = self.position().await?;
        let deltas: Vec<(Axis, f64, f64)> = target
            .iter()
            .map(|(a, v)| (a, v, (v - here.get(a).unwrap_or(v)).abs()))
            .collect();
        let length = deltas.iter().map(|(_, _, d)| d * d).sum::<f64>().sqrt();
        for (a, v, d) in deltas {
            // Each axis gets its share of the path feed (at least a small floor so a
            // zero-length axis move is still a valid command).
            let speed = if length > 0.0 {
                (feed_mm_min * d / length).max(1.0)
            } else {
                feed_mm_min
            };
            let drive = self.drive_mut(a).ok_or_else(|| DriverError::Unsupported {
                device: "stage".into(),
                message: format!("no drive for axis {a}"),
            })?;
            let speed = speed.min(drive.info().max_feed_mm_min);
            drive.start_move(v, speed).await?;
        }
        Ok(())
    }

    async fn position(&mut self) -> Result<AxisValues, DriverError> {
        let mut v = AxisValues::default();
        for d in &mut self.drives {
            let p = d.position().await?;
            v.set(d.info().axis, p);
        }
        Ok(v)
    }

    async fn wait_idle(&mut self) -> Result<(), DriverError> {
        for d in &mut self.drives {
            d.wait_idle().await?;
        }
        Ok(())
    }

    async fn stop(&mut self) -> Result<(), DriverError> {
        // Stop every axis even if one fails, then report the first failure.
        let mut first = None;
        for d in &mut self.drives {
            if let Err(e) = d.stop().await {
                first.get_or_insert(e);
            }
        }
        first.map_or(Ok(()), Err)
    }

    async fn status(&mut self) -> Result<StageStatus, DriverError> {
        let mut position = AxisValues::default();
        let mut state = StageState::Idle;
        for d in &mut self.drives {
            let s = d.status().await?;
            position.set(d.info().axis, s.position_mm);
            state = match (state, &s) {
                (StageState::Alarm(m), _) => StageState::Alarm(m),
                (_, AxisStatus { fault: Some(f), .. }) => {
                    StageState::Alarm(format!("{}: {f}", d.device()))
                }
                (_, AxisStatus { homed: false, .. }) => StageState::NotHomed,
                (StageState::NotHomed, _) => StageState::NotHomed,
                (_, AxisStatus { moving: true, .. }) => StageState::Moving,
                (s, _) => s,
            };
        }
        Ok(StageStatus { state, position })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::{Arc, Mutex};

    /// A drive that records what it is told.
    struct Recorder {
        info: AxisInfo,
        told: Arc<Mutex<Vec<(f64, f64)>>>,
    }

    #[async_trait]
    impl AxisDrive for Recorder {
        fn info(&self) -> &AxisInfo {
            &self.info
        }
        fn device(&self) -> &str {
            "recorder"
        }
        async fn home(&mut self) -> Result<(), DriverError> {
            Ok(())
        }
        async fn start_move(&mut self, p: f64, s: f64) -> Result<(), DriverError> {
            self.told.lock().unwrap().push((p, s));
            Ok(())
        }
        async fn position(&mut self) -> Result<f64, DriverError> {
            Ok(0.0)
        }
        async fn status(&mut self) -> Result<AxisStatus, DriverError> {
            Ok(AxisStatus {
                moving: false,
                homed: true,
                fault: None,
                position_mm: 0.0,
            })
        }
        async fn wait_idle(&mut self) -> Result<(), DriverError> {
            Ok(())
        }
        async fn stop(&mut self) -> Result<(), DriverError> {
            Ok(())
        }
    }

    #[tokio::test]
    async fn a_feed_that_is_not_a_positive_number_is_refused_before_any_drive_is_told() {
        let told = Arc::new(Mutex::new(Vec::new()));
        let drive = |axis| -> Box<dyn AxisDrive> {
            Box::new(Recorder {
                info: AxisInfo {
                    axis,
                    min_mm: 0.0,
                    max_mm: 100.0,
                    resolution_mm: 0.001,
                    max_feed_mm_min: 6000.0,
                },
                told: told.clone(),
            })
        };
        let mut s = MultiAxisStage::new("t", vec![drive(Axis::X), drive(Axis::Y)]).unwrap();
        for feed in [f64::NAN, 0.0, -100.0, f64::INFINITY] {
            let e = s
                .move_to(AxisValues::xy(10.0, 20.0), feed)
                .await
                .unwrap_err();
            assert!(
                matches!(e, DriverError::Unsupported { .. }) && e.to_string().contains("feed"),
                "{feed}: {e}"
            );
        }
        assert!(told.lock().unwrap().is_empty());
        s.move_to(AxisValues::xy(10.0, 20.0), 1000.0).await.unwrap();
        assert_eq!(told.lock().unwrap().len(), 2);
    }
}

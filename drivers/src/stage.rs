//! The motion stage trait and its value types.

use crate::error::DriverError;
use crate::program::{StreamError, StreamOptions, StreamReport};
use async_trait::async_trait;
pub use link_spec::Capabilities;
use protocol::grbl::stream::StreamProgress;
use serde::Serialize;

pub use link_spec::Axis;

/// A value per axis; axes not mentioned are `None` (a move leaves them where they are).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AxisValues([Option<f64>; 6]);

impl AxisValues {
    pub fn xy(x: f64, y: f64) -> Self {
        let mut v = Self::default();
        v.set(Axis::X, x);
        v.set(Axis::Y, y);
        v
    }

    pub fn get(&self, a: Axis) -> Option<f64> {
        self.0[a.index()]
    }

    pub fn set(&mut self, a: Axis, value: f64) {
        self.0[a.index()] = Some(value);
    }

    pub fn with(mut self, a: Axis, value: f64) -> Self {
        self.set(a, value);
        self
    }

    /// The axes that have a value, in X..C order.
    pub fn iter(&self) -> impl Iterator<Item = (Axis, f64)> + '_ {
        Axis::ALL
            .into_iter()
            .filter_map(|a| self.get(a).map(|v| (a, v)))
    }

    pub fn is_empty(&self) -> bool {
        self.0.iter().all(Option::is_none)
    }

    /// X and Y, or None if either is missing.
    pub fn to_xy(&self) -> Option<[f64; 2]> {
        Some([self.get(Axis::X)?, self.get(Axis::Y)?])
    }
}

/// Refuse a feed (or speed) that is not a positive finite number of mm/min before
/// anything is sent: `NaN.min(max)` is `max`, so without this a NaN feed would silently
/// become the axis's fastest.
pub fn check_feed(device: &str, feed_mm_min: f64) -> Result<(), DriverError> {
    if feed_mm_min.is_finite() && feed_mm_min > 0.0 {
        return Ok(());
    }
    Err(DriverError::Unsupported {
        device: device.to_string(),
        message: format!(
            "feed {feed_mm_min} mm/min is not a positive finite number: nothing was sent"
        ),
    })
}

/// Check an axis's configured limits and maximum feed (`what` names the axis for the
/// message) before a device is opened.
pub fn check_axis_config(
    device: &str,
    what: &str,
    min_mm: f64,
    max_mm: f64,
    max_feed_mm_min: Option<f64>,
) -> Result<(), DriverError> {
    let bad = |message: String| DriverError::Unsupported {
        device: device.to_string(),
        message: format!("{what}: {message}"),
    };
    if !(min_mm.is_finite() && max_mm.is_finite() && min_mm < max_mm) {
        return Err(bad(format!(
            "soft limits {min_mm}..{max_mm} mm: need finite numbers with min_mm < max_mm"
        )));
    }
    if let Some(f) = max_feed_mm_min {
        if !(f.is_finite() && f > 0.0) {
            return Err(bad(format!(
                "max_feed_mm_min = {f}: must be a positive finite number of mm/min"
            )));
        }
    }
    Ok(())
}

/// What a stage tells about one of its axes.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct AxisInfo {
    pub axis: Axis,
    /// Soft limits in machine coordinates, mm.
    pub min_mm: f64,
    pub max_mm: f64,
    /// Smallest commandable step, mm (encoder count or microstep).
    pub resolution_mm: f64,
    pub max_feed_mm_min: f64,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StageInfo {
    /// Human-readable identity (controller type, firmware, port).
    pub name: String,
    pub axes: Vec<AxisInfo>,
}

impl StageInfo {
    pub fn axis(&self, a: Axis) -> Option<&AxisInfo> {
        self.axes.iter().find(|i| i.axis == a)
    }

    /// Check a target against every axis's soft limits before anything is sent.
    pub fn check_limits(&self, target: &AxisValues) -> Result<(), DriverError> {
        for (a, v) in target.iter() {
            let info = self.axis(a).ok_or_else(|| DriverError::Unsupported {
                device: self.name.clone(),
                message: format!("this stage has no {a} axis"),
            })?;
            if !(v >= info.min_mm && v <= info.max_mm) {
                return Err(DriverError::OutOfLimits {
                    axis: a,
                    value_mm: v,
                    min_mm: info.min_mm,
                    max_mm: info.max_mm,
                });
            }
        }
        Ok(())
    }
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub enum StageState {
    Idle,
    Moving,
    Homing,
    Hold,
    /// Alarm or fault, with the device's own words; motion is stopped.
    Alarm(String),
    /// Powered but not homed / not referenced.
    NotHomed,
}

#[derive(Clone, Debug, PartialEq)]
pub struct StageStatus {
    pub state: StageState,
    /// Controller position (what the controller believes), mm.
    pub position: AxisValues,
}

/// What a probing move looks for (G38.2 to G38.5).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ProbeMode {
    /// Toward the work until contact (G38.2/G38.3), else away until contact is lost
    /// (G38.4/G38.5).
    pub toward: bool,
    /// Reaching the target without a trigger is an error (G38.2/G38.4: the controller
    /// raises its probe alarm), else it is a result with `touched` false.
    pub must_trigger: bool,
}

/// Where a probing move ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ProbeHit {
    /// Machine position where the probe triggered (or where the move ended), per axis
    /// the controller reports (mm, degrees for A B C).
    pub position: AxisValues,
    pub touched: bool,
}

/// A motion stage made of axes, driven through its controller.
///
/// Moves are absolute in machine coordinates (mm). `move_to` returns once the
/// controller has accepted the move; `wait_idle` returns when motion has ended. Every
/// implementation checks targets against [`StageInfo::check_limits`] before sending.
#[async_trait]
pub trait Stage: Send {
    fn info(&self) -> &StageInfo;
    /// What the controller can do beyond point-to-point moves.
    fn capabilities(&self) -> Capabilities;
    async fn home(&mut self) -> Result<(), DriverError>;
    async fn move_to(&mut self, target: AxisValues, feed_mm_min: f64) -> Result<(), DriverError>;
    /// Relative move: the default reads the controller position and moves to the sum.
    async fn move_by(&mut self, delta: AxisValues, feed_mm_min: f64) -> Result<(), DriverError> {
        let here = self.position().await?;
        let mut target = AxisValues::default();
        for (a, d) in delta.iter() {
            let p = here.get(a).ok_or_else(|| DriverError::Unsupported {
                device: self.info().name.clone(),
                message: format!("no position reported for axis {a}"),
            })?;
            target.set(a, p + d);
        }
        self.move_to(target, feed_mm_min).await
    }
    /// The controller's own position (not the truth), mm.
    async fn position(&mut self) -> Result<AxisValues, DriverError>;
    async fn wait_idle(&mut self) -> Result<(), DriverError>;
    async fn stop(&mut self) -> Result<(), DriverError>;
    async fn status(&mut self) -> Result<StageStatus, DriverError>;
    /// A probing move to `target` (machine coordinates) at `feed` (units/min) that stops
    /// where the probe triggers. Only controllers whose [`Capabilities::probing`] is
    /// true implement it; the default refuses.
    async fn probe(
        &mut self,
        target: AxisValues,
        feed: f64,
        mode: ProbeMode,
    ) -> Result<ProbeHit, DriverError> {
        let _ = (target, feed, mode);
        Err(DriverError::Unsupported {
            device: self.info().name.clone(),
            message: "this controller has no probing moves (capability `probing` is false)".into(),
        })
    }
    /// Run a G-code program streamed line by line; `progress` is told whenever lines
    /// are acknowledged or known executed. Only controllers whose
    /// [`Capabilities::program_streaming`] is true implement it; the default refuses
    /// before anything is sent.
    async fn stream_program(
        &mut self,
        program: &str,
        opts: &StreamOptions,
        progress: &mut (dyn FnMut(StreamProgress) + Send),
    ) -> Result<StreamReport, StreamError> {
        let _ = (program, opts, progress);
        Err(StreamError {
            cause: DriverError::Unsupported {
                device: self.info().name.clone(),
                message: "this controller does not run streamed programs (capability \
                          `program_streaming` is false)"
                    .into(),
            },
            line: None,
            text: None,
            progress: StreamProgress::default(),
            acknowledged_after: Vec::new(),
        })
    }
}

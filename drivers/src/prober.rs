//! A machine that positions a touch probe and probes with it (the rotary table's
//! measurement cycle, SPEC B): positioning moves of X Y Z A C run to their end, and
//! probing moves that stop where the probe triggers (G38.3: a miss is an answer, not an
//! alarm).
//!
//! [`StageProber`] makes any [`Stage`] whose [`Capabilities`] have probing and the
//! rotary axes asked for into a [`Prober`], refusing before any motion one that lacks
//! them; the factory's [`open_prober`](crate::open_prober) opens a link that way. The
//! GRBL stage is one (`G38.3`, the `[PRB:...]` report).

use crate::error::DriverError;
use crate::stage::{Axis, AxisValues, Capabilities, ProbeMode, Stage};
use async_trait::async_trait;

/// Positioning and probing moves of a touch probe on a machine.
#[async_trait]
pub trait Prober: Send {
    /// The controller's name (for messages).
    fn name(&self) -> &str;
    /// A positioning move of the axes in `target` (X Y Z in mm, A B C in degrees, axes
    /// not given stay where they are), returning once the motion has ended.
    async fn move_to(&mut self, target: AxisValues) -> Result<(), DriverError>;
    /// A probing move (G38.3: towards the work, no alarm on a miss) of the axes in `to`
    /// from where the machine is, at `feed_mm_min`, the other axes staying: the machine
    /// position (every axis the controller reports) where the probe triggered, or
    /// `None` if it reached `to` without contact. The machine stops there.
    async fn probe_towards(
        &mut self,
        to: AxisValues,
        feed_mm_min: f64,
    ) -> Result<Option<AxisValues>, DriverError>;
}

/// Why a device cannot be used as a [`Prober`]; nothing has moved.
#[derive(Debug, thiserror::Error)]
pub enum ProberError {
    /// The device could not be opened (its link, its handshake).
    #[error(transparent)]
    Open(#[from] DriverError),
    /// It lacks a rotary axis that was asked for.
    #[error("{device} has no {axis:?} axis (its rotary axes: {rotary_axes:?})")]
    MissingAxis {
        device: String,
        axis: Axis,
        /// The rotary axes it has.
        rotary_axes: Vec<Axis>,
    },
    /// It has no probing moves (no probe input).
    #[error("{device} reports no probe input")]
    NoProbing { device: String },
}

impl ProberError {
    /// Checks `caps` of `device` for probing and every axis of `rotary_axes` (the axes
    /// in the order asked, then probing).
    pub fn check(device: &str, caps: &Capabilities, rotary_axes: &[Axis]) -> Result<(), Self> {
        if let Some(&axis) = rotary_axes.iter().find(|a| !caps.rotary_axes.contains(a)) {
            return Err(ProberError::MissingAxis {
                device: device.to_string(),
                axis,
                rotary_axes: caps.rotary_axes.clone(),
            });
        }
        if !caps.probing {
            return Err(ProberError::NoProbing {
                device: device.to_string(),
            });
        }
        Ok(())
    }
}

/// A [`Stage`] with probing moves as a [`Prober`]: a positioning move is
/// [`Stage::move_to`] at [`positioning_feed`](Self::with_positioning_feed) then
/// [`Stage::wait_idle`]; a probing move is [`Stage::probe`] toward the work without
/// `must_trigger` (G38.3).
pub struct StageProber {
    stage: Box<dyn Stage>,
    feed_mm_min: f64,
}

impl StageProber {
    /// The positioning moves' feed unless set (units/min: mm/min for X Y Z, degrees/min
    /// for the rotary axes).
    pub const POSITIONING_FEED_MM_MIN: f64 = 3000.0;

    /// The stage as a prober, if its capabilities have probing and every axis of
    /// `rotary_axes`; refused otherwise, before anything moves.
    pub fn new(stage: Box<dyn Stage>, rotary_axes: &[Axis]) -> Result<Self, ProberError> {
        ProberError::check(&stage.info().name, &stage.capabilities(), rotary_axes)?;
        Ok(Self {
            stage,
            feed_mm_min: Self::POSITIONING_FEED_MM_MIN,
        })
    }

    /// Positioning moves at `feed_mm_min` instead.
    pub fn with_positioning_feed(mut self, feed_mm_min: f64) -> Self {
        self.feed_mm_min = feed_mm_min;
        self
    }

    /// The stage, for what a prober does not do (status, homing).
    pub fn stage_mut(&mut self) -> &mut dyn Stage {
        self.stage.as_mut()
    }

    pub fn into_stage(self) -> Box<dyn Stage> {
        self.stage
    }
}

#[async_trait]
impl Prober for StageProber {
    fn name(&self) -> &str {
        &self.stage.info().name
    }

    async fn move_to(&mut self, target: AxisValues) -> Result<(), DriverError> {
        self.stage.move_to(target, self.feed_mm_min).await?;
        self.stage.wait_idle().await
    }

    async fn probe_towards(
        &mut self,
        to: AxisValues,
        feed_mm_min: f64,
    ) -> Result<Option<AxisValues>, DriverError> {
        let mode = ProbeMode {
            toward: true,
            must_trigger: false,
        };
        let hit = self.stage.probe(to, feed_mm_min, mode).await?;
        Ok(hit.touched.then_some(hit.position))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn caps(probing: bool, rotary_axes: Vec<Axis>) -> Capabilities {
        Capabilities {
            probing,
            rotary_axes,
            ..Capabilities::default()
        }
    }

    #[test]
    fn a_controller_without_the_axes_or_a_probe_is_refused_naming_what_it_lacks() {
        let ac = [Axis::A, Axis::C];
        assert!(ProberError::check("d", &caps(true, vec![Axis::A, Axis::B, Axis::C]), &ac).is_ok());
        let e = ProberError::check("d", &caps(true, vec![Axis::C]), &ac).unwrap_err();
        assert_eq!(e.to_string(), "d has no A axis (its rotary axes: [C])");
        let e = ProberError::check("d", &caps(false, vec![Axis::A]), &ac).unwrap_err();
        assert!(
            matches!(e, ProberError::MissingAxis { axis: Axis::C, .. }),
            "{e}"
        );
        let e = ProberError::check("d", &caps(false, vec![Axis::A, Axis::C]), &ac).unwrap_err();
        assert_eq!(e.to_string(), "d reports no probe input");
        assert!(ProberError::check("d", &caps(true, vec![]), &[]).is_ok());
    }
}

//! A machine of up to six independent axes (X Y Z, then A B C, grblHAL's order) for an
//! N-axis controller emulator to drive: the 5-axis rotary machine of [`crate::rotary`]
//! now, other machines (the 3-axis volumetric one) by implementing [`Workpiece`].
//!
//! Motion is a straight interpolation of all axes at a constant rate: the controller
//! asks for a feed in units per minute over the Euclidean length of the move in axis
//! units (mm and degrees together, as GRBL's planner measures it), and the axes reach
//! the target after `length / feed` minutes. No acceleration is modelled: the N-axis
//! machine serves geometry (where the tool tip is, where the probe triggers), not
//! dynamics. Example: from all zeros to X 30, A 40 at F 600: length 50, 5 s.

use std::sync::{Arc, Mutex, MutexGuard, PoisonError};

/// Most axes a controller drives.
pub const MAX_AXES: usize = 6;
/// A position of every axis slot, X Y Z A B C (mm, degrees); slots beyond the
/// machine's axes stay 0.
pub type AxesPosition = [f64; MAX_AXES];

/// One axis: travel in machine coordinates and maximum rate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisLimits {
    pub min: f64,
    pub max: f64,
    /// mm/min or deg/min.
    pub max_rate: f64,
}

/// What sits on the machine and can be touched by a probe.
pub trait Workpiece: Send {
    /// Axes the machine has (3..=6), X Y Z A B C in that order.
    fn axes(&self) -> usize;
    fn limits(&self, axis: usize) -> AxisLimits;
    /// A probing move of the axes from `from` to `to`: where the probe triggers, if it
    /// does (the caller stops the axes there).
    fn probe_contact(&mut self, from: &AxesPosition, to: &AxesPosition) -> Option<AxesPosition>;
    /// Whether the probe touches something with the axes at `at` (the `Pn:P` pin).
    fn probe_touching(&self, at: &AxesPosition) -> bool;
    /// A move of the axes ended, reached or stopped short: the straight path `from` ->
    /// `to` run from `start_s` to `end_s` on the machine's clock. What a tool does to the
    /// work happens here (a knife's cut); by default nothing.
    fn moved(&mut self, from: &AxesPosition, to: &AxesPosition, start_s: f64, end_s: f64) {
        let _ = (from, to, start_s, end_s);
    }
}

/// Why the machine refuses a move.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum AxesRefusal {
    #[error("axis {axis} target {target} outside its travel")]
    OutOfTravel { axis: usize, target: f64 },
}

#[derive(Clone, Copy, Debug)]
struct Motion {
    from: AxesPosition,
    to: AxesPosition,
    duration_s: f64,
    elapsed_s: f64,
    /// Units per minute.
    rate: f64,
    /// The machine's clock when the move began.
    start_s: f64,
}

/// The axes of a machine and what they carry.
pub struct AxesMachine {
    workpiece: Box<dyn Workpiece>,
    position: AxesPosition,
    motion: Option<Motion>,
    /// The probe fired during the last probing move.
    triggered: bool,
    now_s: f64,
    /// Where each move ended, while a test asks for them (see [`Self::record_move_ends`]).
    move_ends: Option<Vec<AxesPosition>>,
}

/// The machine shared between a controller emulator and tests.
pub type SharedAxes = Arc<Mutex<AxesMachine>>;

/// Lock a shared axes machine (a poisoned lock still holds a usable machine).
pub fn lock_axes(shared: &SharedAxes) -> MutexGuard<'_, AxesMachine> {
    shared.lock().unwrap_or_else(PoisonError::into_inner)
}

impl AxesMachine {
    pub fn new(workpiece: Box<dyn Workpiece>) -> Self {
        Self {
            workpiece,
            position: [0.0; MAX_AXES],
            motion: None,
            triggered: false,
            now_s: 0.0,
            move_ends: None,
        }
    }

    /// From now on, keep the position where every move ends (reached, not stopped
    /// short): the trace a test compares with the truth.
    pub fn record_move_ends(&mut self) {
        self.move_ends.get_or_insert_with(Vec::new);
    }

    /// The move ends kept since the last call (recording goes on).
    pub fn take_move_ends(&mut self) -> Vec<AxesPosition> {
        self.move_ends
            .as_mut()
            .map(std::mem::take)
            .unwrap_or_default()
    }

    fn reached(&mut self, at: AxesPosition) {
        self.position = at;
        if let Some(ends) = &mut self.move_ends {
            ends.push(at);
        }
    }

    pub fn shared(self) -> SharedAxes {
        Arc::new(Mutex::new(self))
    }

    pub fn axes(&self) -> usize {
        self.workpiece.axes().clamp(3, MAX_AXES)
    }

    pub fn limits(&self, axis: usize) -> AxisLimits {
        self.workpiece.limits(axis)
    }

    pub fn workpiece(&self) -> &dyn Workpiece {
        self.workpiece.as_ref()
    }

    pub fn position(&self) -> AxesPosition {
        self.position
    }

    /// Simulated seconds the axes have run.
    pub fn now_s(&self) -> f64 {
        self.now_s
    }

    pub fn is_moving(&self) -> bool {
        self.motion.is_some()
    }

    /// Current rate (units/min), 0 at rest.
    pub fn rate(&self) -> f64 {
        self.motion.map_or(0.0, |m| m.rate)
    }

    pub fn probe_triggered(&self) -> bool {
        self.triggered
    }

    pub fn probe_touching(&self) -> bool {
        self.workpiece.probe_touching(&self.position)
    }

    fn check_travel(&self, target: &AxesPosition) -> Result<(), AxesRefusal> {
        for (axis, &t) in target.iter().enumerate().take(self.axes()) {
            let l = self.workpiece.limits(axis);
            if !(l.min..=l.max).contains(&t) {
                return Err(AxesRefusal::OutOfTravel { axis, target: t });
            }
        }
        Ok(())
    }

    /// Start a straight move at `rate` units/min; returns its duration in seconds.
    pub fn start_move(&mut self, target: AxesPosition, rate: f64) -> Result<f64, AxesRefusal> {
        self.check_travel(&target)?;
        self.triggered = false;
        Ok(self.begin(target, rate))
    }

    /// Start a probing move: it ends where the probe triggers, or at `target`. Toward
    /// the work (G38.2/G38.3) the trigger is the first contact; away from it (G38.4/
    /// G38.5) the point where contact is lost (found by bisection to 1 nm).
    pub fn start_probe(
        &mut self,
        target: AxesPosition,
        rate: f64,
        toward: bool,
    ) -> Result<f64, AxesRefusal> {
        self.check_travel(&target)?;
        let contact = if toward {
            self.workpiece.probe_contact(&self.position, &target)
        } else {
            self.contact_lost(&target)
        };
        self.triggered = contact.is_some();
        Ok(self.begin(contact.unwrap_or(target), rate))
    }

    fn contact_lost(&self, target: &AxesPosition) -> Option<AxesPosition> {
        let at = |k: f64| -> AxesPosition {
            std::array::from_fn(|i| self.position[i] + (target[i] - self.position[i]) * k)
        };
        if !self.workpiece.probe_touching(&self.position) || self.workpiece.probe_touching(target) {
            return None;
        }
        let length = (0..MAX_AXES)
            .map(|i| (target[i] - self.position[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        let (mut lo, mut hi) = (0.0, 1.0);
        while (hi - lo) * length > 1e-6 {
            let mid = 0.5 * (lo + hi);
            if self.workpiece.probe_touching(&at(mid)) {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        Some(at(hi))
    }

    fn begin(&mut self, to: AxesPosition, rate: f64) -> f64 {
        let length = (0..MAX_AXES)
            .map(|i| (to[i] - self.position[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        let rate = rate.max(1e-9);
        let duration_s = length / rate * 60.0;
        if duration_s > 0.0 {
            self.motion = Some(Motion {
                from: self.position,
                to,
                duration_s,
                elapsed_s: 0.0,
                rate,
                start_s: self.now_s,
            });
        } else {
            let from = self.position;
            self.reached(to);
            self.workpiece.moved(&from, &to, self.now_s, self.now_s);
        }
        duration_s
    }

    /// Let `dt` simulated seconds pass.
    pub fn advance(&mut self, dt: f64) {
        self.now_s += dt;
        let Some(mut m) = self.motion else {
            return;
        };
        m.elapsed_s += dt;
        if m.elapsed_s >= m.duration_s {
            self.motion = None;
            self.reached(m.to);
            self.workpiece
                .moved(&m.from, &m.to, m.start_s, m.start_s + m.duration_s);
            return;
        }
        let k = m.elapsed_s / m.duration_s;
        for i in 0..MAX_AXES {
            self.position[i] = m.from[i] + (m.to[i] - m.from[i]) * k;
        }
        self.motion = Some(m);
    }

    /// Complete the current move at once (the controller decided it has ended).
    pub fn finish_motion(&mut self) {
        if let Some(m) = self.motion.take() {
            self.now_s += (m.duration_s - m.elapsed_s).max(0.0);
            self.reached(m.to);
            self.workpiece.moved(&m.from, &m.to, m.start_s, self.now_s);
        }
    }

    /// Stop where the axes are.
    pub fn stop(&mut self) {
        if let Some(m) = self.motion.take() {
            self.workpiece
                .moved(&m.from, &self.position, m.start_s, self.now_s);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Free;
    impl Workpiece for Free {
        fn axes(&self) -> usize {
            4
        }
        fn limits(&self, _: usize) -> AxisLimits {
            AxisLimits {
                min: -100.0,
                max: 100.0,
                max_rate: 1000.0,
            }
        }
        fn probe_contact(&mut self, _: &AxesPosition, _: &AxesPosition) -> Option<AxesPosition> {
            None
        }
        fn probe_touching(&self, _: &AxesPosition) -> bool {
            false
        }
    }

    #[test]
    fn moves_take_length_over_feed_and_interpolate_every_axis() {
        // X 30, A 40 at F 600: length 50, 5 s; halfway at 2.5 s.
        let mut m = AxesMachine::new(Box::new(Free));
        let d = m
            .start_move([30.0, 0.0, 0.0, 40.0, 0.0, 0.0], 600.0)
            .unwrap();
        assert!((d - 5.0).abs() < 1e-12);
        m.advance(2.5);
        assert_eq!(m.position(), [15.0, 0.0, 0.0, 20.0, 0.0, 0.0]);
        m.advance(2.5);
        assert!(!m.is_moving());
        assert_eq!(m.position()[3], 40.0);
        assert_eq!(
            m.start_move([0.0, 0.0, 0.0, 101.0, 0.0, 0.0], 600.0),
            Err(AxesRefusal::OutOfTravel {
                axis: 3,
                target: 101.0
            })
        );
    }
}

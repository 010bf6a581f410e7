//! A conveyor cutter for sheet material (source C): a vacuum conveyor that feeds the
//! material along X, and k knife heads above a cutting area of length L', each on its
//! own X/Y gantry over its lane, the knife lowered by the head's Z axis. Every knife
//! stroke is written to a [`CutLog`] with the time and where it ran on the material, so
//! a test can tell which part was cut when, where, and beside what.
//!
//! Frames (mm). The material frame is the layout's: X along the feed, Y across. The
//! conveyor's axis position `c` is the material X under the cutting area's start edge.
//! Head `t`'s machine frame has its origin on that edge at material Y `origin_y[t]`, X
//! along the feed (0..=L'), Y across (0..=reach[t]), Z up (the knife cuts while Z < 0).
//! So a head at machine (x, y) with the knife down cuts material point
//! `(c + x, origin_y[t] + y)`. Worked example: the conveyor at 300 (the material's first
//! 300 mm have passed under the area's start), head 1 with origin_y 45 at machine
//! (20, 10), knife at Z -1: it cuts the material at (320, 55).
//!
//! The knife is modelled as a point and the heads as not colliding with each other (a
//! real head's body needs its own clearance, which the layout's lanes give it).

use crate::axes::{AxesPosition, AxisLimits, SharedAxes, Workpiece};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};

/// The cutter's geometry.
#[derive(Clone, Debug, PartialEq)]
pub struct CutterGeometry {
    /// Cutting area length L' along X (each head's X travel), mm.
    pub window_mm: f64,
    /// Per head: material Y of its machine Y 0, and its Y travel (mm).
    pub heads: Vec<HeadGeometry>,
    /// The conveyor axis's travel (material X under the area's start edge), mm.
    pub conveyor_min_mm: f64,
    pub conveyor_max_mm: f64,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeadGeometry {
    pub origin_y_mm: f64,
    pub reach_y_mm: f64,
}

/// Knife travel: Z from this depth (below the material's top at 0) to this height, mm.
pub const KNIFE_DEPTH_MM: f64 = -2.0;
pub const KNIFE_CLEAR_MM: f64 = 10.0;
/// Rates of the simulated axes, mm/min.
pub const HEAD_MAX_RATE: f64 = 60_000.0;
pub const CONVEYOR_MAX_RATE: f64 = 30_000.0;

/// One knife stroke: a straight move of a head with its knife below the material's top.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Stroke {
    pub head: usize,
    /// On the head's clock, s.
    pub start_s: f64,
    pub end_s: f64,
    /// Where it ran on the material (material frame, mm).
    pub from_mm: [f64; 2],
    pub to_mm: [f64; 2],
    /// The conveyor's position while it ran, and whether the conveyor was moving (the
    /// knife then drags the material: a defect the gateway must never cause).
    pub conveyor_mm: f64,
    pub conveyor_moving: bool,
    /// How many conveyor moves had ended before the stroke: strokes with a smaller count
    /// came before this one on the material.
    pub feeds_before: u64,
}

/// Everything the cutter did, in the order it happened on each head.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct CutLog {
    pub strokes: Vec<Stroke>,
    /// Conveyor moves ended so far, and where each ended (mm).
    pub feeds: Vec<f64>,
    /// Seconds the conveyor moved.
    pub conveyor_s: f64,
    /// Seconds each head moved (travel, plunges and strokes) between two feeds:
    /// `(feeds_before, head, seconds)`, one entry per pair that moved.
    pub head_busy: Vec<(u64, usize, f64)>,
}

impl CutLog {
    /// The cutter's machine time when the feeds wait for every head and the heads work
    /// at once between feeds: the conveyor's moves plus, between each two feeds, the
    /// busiest head's time, s.
    pub fn machine_time_s(&self) -> f64 {
        let mut busiest: std::collections::BTreeMap<u64, f64> = Default::default();
        for &(feeds, _, s) in &self.head_busy {
            let b = busiest.entry(feeds).or_default();
            *b = b.max(s);
        }
        self.conveyor_s + busiest.values().sum::<f64>()
    }
}

pub type SharedCutLog = Arc<Mutex<CutLog>>;

/// Lock the log (a poisoned lock still holds a usable log).
pub fn lock_log(log: &SharedCutLog) -> MutexGuard<'_, CutLog> {
    log.lock().unwrap_or_else(PoisonError::into_inner)
}

/// The conveyor: X is the feed; Y and Z have no travel.
pub struct Conveyor {
    min_mm: f64,
    max_mm: f64,
    log: SharedCutLog,
}

impl Conveyor {
    pub fn new(geometry: &CutterGeometry, log: SharedCutLog) -> Self {
        Self {
            min_mm: geometry.conveyor_min_mm,
            max_mm: geometry.conveyor_max_mm,
            log,
        }
    }
}

impl Workpiece for Conveyor {
    fn axes(&self) -> usize {
        3
    }

    fn limits(&self, axis: usize) -> AxisLimits {
        match axis {
            0 => AxisLimits {
                min: self.min_mm,
                max: self.max_mm,
                max_rate: CONVEYOR_MAX_RATE,
            },
            _ => AxisLimits {
                min: 0.0,
                max: 0.0,
                max_rate: CONVEYOR_MAX_RATE,
            },
        }
    }

    fn probe_contact(&mut self, _: &AxesPosition, _: &AxesPosition) -> Option<AxesPosition> {
        None
    }

    fn probe_touching(&self, _: &AxesPosition) -> bool {
        false
    }

    fn moved(&mut self, _from: &AxesPosition, to: &AxesPosition, start_s: f64, end_s: f64) {
        let mut log = lock_log(&self.log);
        log.feeds.push(to[0]);
        log.conveyor_s += end_s - start_s;
    }
}

/// One knife head: X (along the feed, over the cutting area), Y (across, over its
/// reach), Z (the knife).
pub struct Head {
    index: usize,
    window_mm: f64,
    geometry: HeadGeometry,
    conveyor: SharedAxes,
    log: SharedCutLog,
}

impl Head {
    pub fn new(
        index: usize,
        cutter: &CutterGeometry,
        conveyor: SharedAxes,
        log: SharedCutLog,
    ) -> Self {
        Self {
            index,
            window_mm: cutter.window_mm,
            geometry: cutter.heads[index],
            conveyor,
            log,
        }
    }
}

impl Workpiece for Head {
    fn axes(&self) -> usize {
        3
    }

    fn limits(&self, axis: usize) -> AxisLimits {
        let (min, max) = match axis {
            0 => (0.0, self.window_mm),
            1 => (0.0, self.geometry.reach_y_mm),
            _ => (KNIFE_DEPTH_MM, KNIFE_CLEAR_MM),
        };
        AxisLimits {
            min,
            max,
            max_rate: HEAD_MAX_RATE,
        }
    }

    fn probe_contact(&mut self, _: &AxesPosition, _: &AxesPosition) -> Option<AxesPosition> {
        None
    }

    fn probe_touching(&self, _: &AxesPosition) -> bool {
        false
    }

    fn moved(&mut self, from: &AxesPosition, to: &AxesPosition, start_s: f64, end_s: f64) {
        let (conveyor_mm, conveyor_moving) = {
            let c = crate::axes::lock_axes(&self.conveyor);
            (c.position()[0], c.is_moving())
        };
        let mut log = lock_log(&self.log);
        let feeds_before = log.feeds.len() as u64;
        let busy = end_s - start_s;
        match log
            .head_busy
            .iter_mut()
            .rev()
            .find(|(f, h, _)| *f == feeds_before && *h == self.index)
        {
            Some((_, _, s)) => *s += busy,
            None => log.head_busy.push((feeds_before, self.index, busy)),
        }
        // A stroke is an X/Y move with the knife in the material all along (a plunge or
        // a lift changes Z only).
        let knife_in = from[2] < 0.0 && to[2] < 0.0;
        if !knife_in || (from[0] == to[0] && from[1] == to[1]) {
            return;
        }
        let at = |p: &AxesPosition| [conveyor_mm + p[0], self.geometry.origin_y_mm + p[1]];
        log.strokes.push(Stroke {
            head: self.index,
            start_s,
            end_s,
            from_mm: at(from),
            to_mm: at(to),
            conveyor_mm,
            conveyor_moving,
            feeds_before,
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::axes::{lock_axes, AxesMachine};

    fn cutter() -> (SharedAxes, SharedAxes, SharedCutLog) {
        let geometry = CutterGeometry {
            window_mm: 300.0,
            heads: vec![
                HeadGeometry {
                    origin_y_mm: 0.0,
                    reach_y_mm: 50.0,
                },
                HeadGeometry {
                    origin_y_mm: 45.0,
                    reach_y_mm: 50.0,
                },
            ],
            conveyor_min_mm: 0.0,
            conveyor_max_mm: 10_000.0,
        };
        let log = SharedCutLog::default();
        let conveyor = AxesMachine::new(Box::new(Conveyor::new(&geometry, log.clone()))).shared();
        let head = AxesMachine::new(Box::new(Head::new(
            1,
            &geometry,
            conveyor.clone(),
            log.clone(),
        )))
        .shared();
        (conveyor, head, log)
    }

    /// The module's worked example: conveyor at 300, head 1 (origin 45) at (20, 10) with
    /// the knife down cuts material (320, 55).
    #[test]
    fn a_stroke_is_logged_on_the_material() {
        let (conveyor, head, log) = cutter();
        let mut c = lock_axes(&conveyor);
        c.start_move([300.0, 0.0, 0.0, 0.0, 0.0, 0.0], 30_000.0)
            .unwrap();
        c.finish_motion();
        drop(c);
        let mut h = lock_axes(&head);
        h.start_move([20.0, 10.0, 5.0, 0.0, 0.0, 0.0], 6000.0)
            .unwrap();
        h.finish_motion();
        h.start_move([20.0, 10.0, -1.0, 0.0, 0.0, 0.0], 600.0)
            .unwrap();
        h.finish_motion();
        assert!(
            lock_log(&log).strokes.is_empty(),
            "travel and plunge are no strokes"
        );
        h.start_move([30.0, 10.0, -1.0, 0.0, 0.0, 0.0], 600.0)
            .unwrap();
        h.finish_motion();
        let log = lock_log(&log);
        assert_eq!(log.feeds, vec![300.0]);
        let s = &log.strokes[0];
        assert_eq!(
            (s.head, s.from_mm, s.to_mm),
            (1, [320.0, 55.0], [330.0, 55.0])
        );
        assert_eq!((s.conveyor_moving, s.feeds_before), (false, 1));
        assert!(
            (s.end_s - s.start_s - 1.0).abs() < 1e-12,
            "10 mm at 600 mm/min"
        );
        // The conveyor's 300 mm at 30 m/min, then the head's travel, plunge and stroke.
        let travel = (20f64.powi(2) + 10f64.powi(2) + 5f64.powi(2)).sqrt() / 6000.0 * 60.0;
        let want = 0.6 + travel + 0.6 + 1.0;
        assert!(
            (log.machine_time_s() - want).abs() < 1e-9,
            "{}",
            log.machine_time_s()
        );
    }

    /// A stroke while the conveyor still moves is logged as such.
    #[test]
    fn a_stroke_while_the_material_moves_is_flagged() {
        let (conveyor, head, log) = cutter();
        lock_axes(&conveyor)
            .start_move([300.0, 0.0, 0.0, 0.0, 0.0, 0.0], 30_000.0)
            .unwrap();
        let mut h = lock_axes(&head);
        h.start_move([0.0, 0.0, -1.0, 0.0, 0.0, 0.0], 600.0)
            .unwrap();
        h.finish_motion();
        h.start_move([5.0, 0.0, -1.0, 0.0, 0.0, 0.0], 600.0)
            .unwrap();
        h.finish_motion();
        let log = lock_log(&log);
        assert!(log.strokes[0].conveyor_moving);
        assert_eq!(log.strokes[0].feeds_before, 0);
    }
}

//! Target positions and the test cycle (ISO 230-2, clause 5).
//!
//! Targets: m positions over the measurement travel [lo, hi], at least 5 and at least 5
//! per metre (m = max(5, ceil(5 · L / 1000 mm)) unless more are asked for), spaced
//! irregularly so that a periodic error (a ballscrew's pitch error, an encoder's scale
//! period) is not sampled at the same phase everywhere: P_i = lo + (i - 1) · p + r_i with
//! p = L / (m - 1) and r_i = p · 0.6 · (frac(i² · 0.618034) - 0.5), a different value at
//! each inner position within ±0.3 p (a quadratic golden-ratio sequence: neither the
//! offsets nor the gaps repeat with a period), r = 0 at
//! the two ends so the whole travel is covered. Targets are rounded to 1 um.
//! Worked example: lo = 10, hi = 90 mm, m = 5: p = 20 mm, r_2 = 20 · 0.6 · (0.472136 -
//! 0.5) = -0.334 mm, so P = 10, 29.666, 50.748, 74.663, 90 mm (r_3 = +0.748, r_4 = +4.663).
//!
//! Cycles (each run measures every target once in each direction; an overrun beyond
//! the end target before each reversal, so every target of a direction is approached
//! from the same side like a normal move):
//! - linear: run j goes to P_1 - overrun, then P_1, P_2, .., P_m (↑), then P_m + overrun,
//!   then P_m, .., P_1 (↓); n runs in a row.
//! - pilgrim step: at each target in turn (P_1 .. P_m), n times: to P_i - overrun, then
//!   P_i (↑); then at each target from P_m down to P_1, n times: to P_i + overrun, then
//!   P_i (↓). The runs of one position follow each other, so slow drift weighs less on s.

use crate::{Direction, MIN_POSITIONS, MIN_RUNS};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CycleKind {
    Linear,
    PilgrimStep,
}

impl std::str::FromStr for CycleKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "linear" => Ok(CycleKind::Linear),
            "pilgrim" | "pilgrim-step" => Ok(CycleKind::PilgrimStep),
            other => Err(format!("`{other}`: expected linear or pilgrim-step")),
        }
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlanError {
    #[error("the measurement travel {lo} .. {hi} mm is empty")]
    EmptyTravel { lo: f64, hi: f64 },
    #[error("{asked} target positions over {length_mm:.1} mm: ISO 230-2 needs at least {needed} (5, and 5 per metre)")]
    TooFewPositions {
        asked: usize,
        needed: usize,
        length_mm: f64,
    },
    #[error("{0} runs: ISO 230-2 needs at least {MIN_RUNS} in each direction")]
    TooFewRuns(usize),
    #[error("overrun {0} mm: must be a positive number")]
    Overrun(f64),
}

/// The fewest targets the standard allows over `length_mm`.
pub fn min_positions(length_mm: f64) -> usize {
    MIN_POSITIONS.max((5.0 * length_mm / 1000.0).ceil() as usize)
}

/// Target positions over [lo, hi] mm, `count` of them (None: the minimum).
pub fn targets(lo: f64, hi: f64, count: Option<usize>) -> Result<Vec<f64>, PlanError> {
    if !(hi > lo) || !lo.is_finite() || !hi.is_finite() {
        return Err(PlanError::EmptyTravel { lo, hi });
    }
    let length_mm = hi - lo;
    let needed = min_positions(length_mm);
    let m = count.unwrap_or(needed);
    if m < needed {
        return Err(PlanError::TooFewPositions {
            asked: m,
            needed,
            length_mm,
        });
    }
    let p = length_mm / (m - 1) as f64;
    Ok((1..=m)
        .map(|i| {
            let r = if i == 1 || i == m {
                0.0
            } else {
                p * 0.6 * (((i * i) as f64 * 0.618_034).fract() - 0.5)
            };
            let t = lo + (i - 1) as f64 * p + r;
            (t * 1000.0).round() / 1000.0
        })
        .collect())
}

/// One step of a cycle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Step {
    /// Move to this position (an overrun point) without measuring.
    Travel { at_mm: f64 },
    /// Move onto target `position` (0-based) and measure run `run` (1-based).
    Measure {
        position: usize,
        run: usize,
        direction: Direction,
        at_mm: f64,
    },
}

/// A test cycle over given targets.
#[derive(Clone, Debug, PartialEq)]
pub struct Cycle {
    pub targets_mm: Vec<f64>,
    pub runs: usize,
    pub overrun_mm: f64,
    pub kind: CycleKind,
}

impl Cycle {
    pub fn new(
        targets_mm: Vec<f64>,
        runs: usize,
        overrun_mm: f64,
        kind: CycleKind,
    ) -> Result<Self, PlanError> {
        if targets_mm.len() < MIN_POSITIONS {
            return Err(PlanError::TooFewPositions {
                asked: targets_mm.len(),
                needed: MIN_POSITIONS,
                length_mm: targets_mm.last().unwrap_or(&0.0) - targets_mm.first().unwrap_or(&0.0),
            });
        }
        if runs < MIN_RUNS {
            return Err(PlanError::TooFewRuns(runs));
        }
        if !(overrun_mm > 0.0 && overrun_mm.is_finite()) {
            return Err(PlanError::Overrun(overrun_mm));
        }
        Ok(Cycle {
            targets_mm,
            runs,
            overrun_mm,
            kind,
        })
    }

    /// The lowest and highest position the cycle visits (the overrun points), mm.
    pub fn span_mm(&self) -> (f64, f64) {
        let t = &self.targets_mm;
        (t[0] - self.overrun_mm, t[t.len() - 1] + self.overrun_mm)
    }

    /// How many measurements the cycle takes.
    pub fn measurements(&self) -> usize {
        2 * self.runs * self.targets_mm.len()
    }

    /// Every step in order.
    pub fn steps(&self) -> Vec<Step> {
        let t = &self.targets_mm;
        let m = t.len();
        let (below, above) = self.span_mm();
        let measure = |position: usize, run: usize, direction| Step::Measure {
            position,
            run,
            direction,
            at_mm: t[position],
        };
        let mut steps = Vec::new();
        match self.kind {
            CycleKind::Linear => {
                for run in 1..=self.runs {
                    steps.push(Step::Travel { at_mm: below });
                    steps.extend((0..m).map(|i| measure(i, run, Direction::Up)));
                    steps.push(Step::Travel { at_mm: above });
                    steps.extend((0..m).rev().map(|i| measure(i, run, Direction::Down)));
                }
            }
            CycleKind::PilgrimStep => {
                for i in 0..m {
                    for run in 1..=self.runs {
                        steps.push(Step::Travel {
                            at_mm: t[i] - self.overrun_mm,
                        });
                        steps.push(measure(i, run, Direction::Up));
                    }
                }
                for i in (0..m).rev() {
                    for run in 1..=self.runs {
                        steps.push(Step::Travel {
                            at_mm: t[i] + self.overrun_mm,
                        });
                        steps.push(measure(i, run, Direction::Down));
                    }
                }
            }
        }
        steps
    }
}

//! Deviation and corrective moves (SPEC A, claims 6-7), as pure functions.
//!
//! Dx = Xmm - Xmm0, Dy = Ymm - Ymm0: the measured true position minus the target, both
//! in board coordinates. The corrective command cancels it: command' = command - D.
//! Safety is decided here, before anything moves: a correction may never take the
//! command farther than `max_correction_mm` from the nominal command, and every command
//! (including the backlash approach point) must lie inside the soft limits.

use serde::{Deserialize, Serialize};

/// D = observed - target, mm.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Deviation {
    pub dx_mm: f64,
    pub dy_mm: f64,
}

impl Deviation {
    pub fn magnitude_um(&self) -> f64 {
        (self.dx_mm * self.dx_mm + self.dy_mm * self.dy_mm).sqrt() * 1000.0
    }

    pub fn um(&self) -> [f64; 2] {
        [self.dx_mm * 1000.0, self.dy_mm * 1000.0]
    }
}

pub fn deviation(observed_mm: [f64; 2], target_mm: [f64; 2]) -> Deviation {
    Deviation {
        dx_mm: observed_mm[0] - target_mm[0],
        dy_mm: observed_mm[1] - target_mm[1],
    }
}

/// How the loop corrects. Every key of a job's `[compensation]` section is optional
/// and defaults to the value below.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CorrectionPolicy {
    /// Stop correcting once |D| is at most this.
    pub tolerance_um: f64,
    /// Corrective moves allowed per target after the first positioning.
    pub max_iterations: u32,
    /// Largest total correction from the nominal command (either axis), mm.
    pub max_correction_mm: f64,
    /// Every positioning ends with a move from this far on the negative side of both
    /// axes, so backlash is always taken up the same way. 0 disables it.
    pub approach_mm: f64,
    /// A corrective move must leave at most this fraction of the deviation it was to
    /// cancel (the model predicts none is left); a loop that does worse, while above
    /// [`Self::noise_floor_um`], is stopped before its next move.
    pub divergence_ratio: f64,
    /// Before the first target, check the camera's orientation and scale against the
    /// machine: three small moves, no correction (see the session).
    pub check_orientation: bool,
}

impl CorrectionPolicy {
    /// Deviations below this are noise to the divergence check: three times the
    /// tolerance.
    pub fn noise_floor_um(&self) -> f64 {
        3.0 * self.tolerance_um
    }
}

impl Default for CorrectionPolicy {
    fn default() -> Self {
        Self {
            tolerance_um: 0.5,
            max_iterations: 5,
            max_correction_mm: 0.15,
            approach_mm: 0.05,
            divergence_ratio: 0.7,
            check_orientation: true,
        }
    }
}

/// Soft limits of the X and Y axes in machine coordinates, mm.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SoftLimits {
    pub min_mm: [f64; 2],
    pub max_mm: [f64; 2],
}

impl SoftLimits {
    pub fn check(&self, what: &'static str, p: [f64; 2]) -> Result<(), CorrectionError> {
        for k in 0..2 {
            if !(p[k] >= self.min_mm[k] && p[k] <= self.max_mm[k]) {
                return Err(CorrectionError::OutOfLimits {
                    what,
                    axis: ['X', 'Y'][k],
                    value_mm: p[k],
                    min_mm: self.min_mm[k],
                    max_mm: self.max_mm[k],
                });
            }
        }
        Ok(())
    }
}

#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum CorrectionError {
    #[error("{what} on axis {axis} would be {value_mm:.4} mm, outside the soft limits {min_mm}..{max_mm} mm; nothing was moved")]
    OutOfLimits {
        what: &'static str,
        axis: char,
        value_mm: f64,
        min_mm: f64,
        max_mm: f64,
    },
    #[error("the correction would total {correction_um:.1} um on axis {axis}, more than the bound of {bound_um:.1} um; nothing was moved (a wrong set-up or a lost position, not a stage error)")]
    ExceedsBound {
        axis: char,
        correction_um: f64,
        bound_um: f64,
    },
    #[error("the corrective move left {after_um:.2} um of the {before_um:.2} um it was to cancel (more than {:.0} %): the camera's orientation or scale, or the stage, does not behave as the correction assumes; stopped before another move", ratio * 100.0)]
    NotConverging {
        before_um: f64,
        after_um: f64,
        ratio: f64,
    },
}

/// One positioning: where to go, and where to start the final approach from.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Positioning {
    pub command_mm: [f64; 2],
    pub approach_from_mm: Option<[f64; 2]>,
}

/// Plan a positioning to `command`, with the backlash take-up approach, inside limits.
pub fn plan_positioning(
    command_mm: [f64; 2],
    policy: &CorrectionPolicy,
    limits: &SoftLimits,
) -> Result<Positioning, CorrectionError> {
    limits.check("the command", command_mm)?;
    let approach_from_mm = if policy.approach_mm > 0.0 {
        let a = [
            command_mm[0] - policy.approach_mm,
            command_mm[1] - policy.approach_mm,
        ];
        limits.check("the backlash approach point", a)?;
        Some(a)
    } else {
        None
    };
    Ok(Positioning {
        command_mm,
        approach_from_mm,
    })
}

/// What to do after a measurement.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub enum NextStep {
    /// |D| is within tolerance.
    Converged,
    /// Move again to cancel D.
    Correct(Positioning),
    /// Out of iterations with |D| still above tolerance.
    Exhausted,
}

/// Decide the next step for a target.
///
/// `nominal_mm` is the uncorrected command for the target, `current_mm` the command the
/// measurement was taken at, `previous` the deviation measured before the corrective
/// move that led here (None after the first positioning), `corrections_done` how many
/// corrective moves were made.
pub fn next_step(
    nominal_mm: [f64; 2],
    current_mm: [f64; 2],
    d: Deviation,
    previous: Option<Deviation>,
    corrections_done: u32,
    policy: &CorrectionPolicy,
    limits: &SoftLimits,
) -> Result<NextStep, CorrectionError> {
    if d.magnitude_um() <= policy.tolerance_um {
        return Ok(NextStep::Converged);
    }
    if let Some(before) = previous {
        let (before_um, after_um) = (before.magnitude_um(), d.magnitude_um());
        if after_um > policy.noise_floor_um() && after_um > policy.divergence_ratio * before_um {
            return Err(CorrectionError::NotConverging {
                before_um,
                after_um,
                ratio: policy.divergence_ratio,
            });
        }
    }
    if corrections_done >= policy.max_iterations {
        return Ok(NextStep::Exhausted);
    }
    let next = [current_mm[0] - d.dx_mm, current_mm[1] - d.dy_mm];
    for k in 0..2 {
        let total = next[k] - nominal_mm[k];
        if total.abs() > policy.max_correction_mm {
            return Err(CorrectionError::ExceedsBound {
                axis: ['X', 'Y'][k],
                correction_um: total * 1000.0,
                bound_um: policy.max_correction_mm * 1000.0,
            });
        }
    }
    Ok(NextStep::Correct(plan_positioning(next, policy, limits)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    const LIMITS: SoftLimits = SoftLimits {
        min_mm: [0.0, 0.0],
        max_mm: [200.0, 150.0],
    };

    #[test]
    fn deviation_is_observed_minus_target() {
        let d = deviation([302.0, 216.07], [302.02, 216.0]);
        assert!((d.dx_mm + 0.02).abs() < 1e-12 && (d.dy_mm - 0.07).abs() < 1e-12);
        assert!((d.magnitude_um() - (20.0f64.hypot(70.0))).abs() < 1e-6);
    }

    #[test]
    fn correction_cancels_the_deviation_and_keeps_the_approach() {
        let p = CorrectionPolicy::default();
        let d = deviation([50.012, 30.0], [50.0, 30.007]);
        let step = next_step([45.0, 25.0], [45.0, 25.0], d, None, 0, &p, &LIMITS).unwrap();
        let NextStep::Correct(pos) = step else {
            panic!("{step:?}")
        };
        assert!((pos.command_mm[0] - 44.988).abs() < 1e-9);
        assert!((pos.command_mm[1] - 25.007).abs() < 1e-9);
        let a = pos.approach_from_mm.unwrap();
        assert!((a[0] - (44.988 - 0.05)).abs() < 1e-9 && (a[1] - (25.007 - 0.05)).abs() < 1e-9);
    }

    #[test]
    fn converges_and_exhausts() {
        let p = CorrectionPolicy::default();
        let small = deviation([10.0003, 10.0], [10.0, 10.0]);
        assert_eq!(
            next_step([5.0; 2], [5.0; 2], small, None, 0, &p, &LIMITS),
            Ok(NextStep::Converged)
        );
        let big = deviation([10.003, 10.0], [10.0, 10.0]);
        assert_eq!(
            next_step([5.0; 2], [5.0; 2], big, None, p.max_iterations, &p, &LIMITS),
            Ok(NextStep::Exhausted)
        );
    }

    #[test]
    fn refuses_oversized_corrections_and_limit_violations() {
        let p = CorrectionPolicy::default();
        // Total correction counts from the nominal command, not from the last step.
        let d = deviation([10.1, 10.0], [10.0, 10.0]);
        let e = next_step([5.0; 2], [4.94, 5.0], d, None, 1, &p, &LIMITS).unwrap_err();
        assert!(
            matches!(e, CorrectionError::ExceedsBound { axis: 'X', .. }),
            "{e}"
        );
        let d = deviation([10.0, 10.01], [10.0, 10.0]);
        let e = next_step([0.0, 149.999], [0.0, 149.995], d, None, 0, &p, &LIMITS).unwrap_err();
        assert!(
            e.to_string().contains("axis X") && e.to_string().contains("approach"),
            "{e}"
        );
        let e = plan_positioning([201.0, 3.0], &p, &LIMITS).unwrap_err();
        assert!(e.to_string().contains("201.0000"), "{e}");
    }

    #[test]
    fn a_correction_that_does_not_shrink_the_deviation_stops_the_loop() {
        let p = CorrectionPolicy::default();
        let before = deviation([10.012, 10.0], [10.0, 10.0]);
        // A camera turned by 90 degrees: the move cancelled X, the error reappears in Y.
        let after = deviation([10.0, 10.012], [10.0, 10.0]);
        let e = next_step([5.0; 2], [4.988, 5.0], after, Some(before), 1, &p, &LIMITS).unwrap_err();
        assert!(
            matches!(e, CorrectionError::NotConverging { .. })
                && e.to_string().contains("12.00 um"),
            "{e}"
        );
        // Halving it is progress; noise below the floor is never judged.
        let half = deviation([10.006, 10.0], [10.0, 10.0]);
        assert!(next_step([5.0; 2], [4.988, 5.0], half, Some(before), 1, &p, &LIMITS).is_ok());
        let tiny = deviation([10.0012, 10.0], [10.0, 10.0]);
        let tinier = deviation([10.0011, 10.0], [10.0, 10.0]);
        assert!(next_step([5.0; 2], [5.0; 2], tinier, Some(tiny), 2, &p, &LIMITS).is_ok());
    }
}

//! Where to probe: the table positions of the measurement cycle chosen for the eight
//! location errors (an optimal experimental design) instead of the paper's 19.
//!
//! The identification ([`crate::identify`]) fits 14 unknowns (the eight errors and the
//! two balls' centres on the table) to the measured centres; the covariance of its
//! estimate is `s² (JᵀJ)⁻¹`, `J` the Jacobian of the centres by the unknowns. A table
//! position adds its two balls' rows to `J`, so every choice of positions has an
//! information matrix `M = Σ JᵢᵀJᵢ`; the choice made here is the one that maximises the
//! information on the eight errors with the balls' positions as nuisance parameters
//! (Ds-optimality: `det M / det M_balls`, the determinant of the Schur complement,
//! i.e. the smallest joint confidence region of the eight errors for the same number of
//! centres). Candidates are the paper's (C every 30° at A = 0, A every 15° from 0 to 90°
//! at C = 0), so the centres file and the circles of the paper's estimate keep their
//! meaning; every subset of the requested sizes is scored (495 x 35 for 4 and 4), from
//! the machine constants and the artifact alone: no measurement is needed to plan.
//!
//! Worked example (default constants and artifact): the best 4 + 4 positions are C 90°,
//! 120°, 210°, 270° and A 0°, 60°, 75°, 90° (not the evenly spread C 0°, 90°, 180°,
//! 270° and A 0°, 30°, 60°, 90°, which score lower); the default plan's 5 + 5 are C 90°,
//! 120°, 180°, 240°, 270° and A 0°, 15°, 60°, 75°, 90°. Per unit of centre noise the
//! standard deviations of the eight errors are 0.31-0.45 for these 10 positions against
//! 0.23-0.37 for the paper's 19: half the positions for 1.2 to 1.4 times the scatter.

use crate::centres::{Axis, CentreRow};
use crate::{Artifact, MachineConstants};
use nalgebra::{DMatrix, SMatrix};

/// The table positions of one cycle: C angles at A = 0 and A angles at C = 0 (degrees).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Design {
    pub c_steps_deg: Vec<f64>,
    pub a_steps_deg: Vec<f64>,
}

impl Design {
    /// The paper's positions: C in 12 steps of 30°, A in 6 steps of 15° (7 positions).
    pub fn paper() -> Self {
        Self {
            c_steps_deg: (0..12).map(|k| 30.0 * k as f64).collect(),
            a_steps_deg: (0..7).map(|k| 15.0 * k as f64).collect(),
        }
    }

    /// (A, C) of every step of a sweep, in the cycle's order.
    pub fn sweep(&self, axis: Axis) -> Vec<(f64, f64)> {
        match axis {
            Axis::C => self.c_steps_deg.iter().map(|&c| (0.0, c)).collect(),
            Axis::A => self.a_steps_deg.iter().map(|&a| (a, 0.0)).collect(),
        }
    }

    /// The Ds criterion of this design: `log det` of the information on the eight errors
    /// (per unit variance of a centre coordinate; errors in mm and degrees).
    pub fn log_information(&self, constants: &MachineConstants, artifact: &Artifact) -> f64 {
        let blocks = |axis, steps: &[f64]| -> Vec<Info> {
            steps
                .iter()
                .map(|&s| position_information(constants, artifact, axis, s))
                .collect()
        };
        let all: Vec<Info> = blocks(Axis::C, &self.c_steps_deg)
            .into_iter()
            .chain(blocks(Axis::A, &self.a_steps_deg))
            .collect();
        ds_criterion(&all.iter().sum())
    }
}

type Info = SMatrix<f64, 14, 14>;

/// `JᵀJ` of one table position's two centres (6 rows) by the 14 unknowns, at the
/// nominal machine and the artifact's drawn ball positions.
fn position_information(
    constants: &MachineConstants,
    artifact: &Artifact,
    axis: Axis,
    angle_deg: f64,
) -> Info {
    let rows: Vec<CentreRow> = (1..=2u8)
        .map(|ball| CentreRow {
            axis,
            step: 0,
            angle_deg,
            ball,
            x_mm: 0.0,
            y_mm: 0.0,
            z_mm: 0.0,
        })
        .collect();
    let mut theta = vec![0.0; 8];
    for b in &artifact.balls {
        theta.extend_from_slice(&b.centre_mm);
    }
    let mut j = DMatrix::zeros(6, 14);
    for k in 0..14 {
        let h = 1e-6;
        let (mut tp, mut tm) = (theta.clone(), theta.clone());
        tp[k] += h;
        tm[k] -= h;
        let d = (crate::identify::predicted(&rows, constants, &tp)
            - crate::identify::predicted(&rows, constants, &tm))
            / (2.0 * h);
        j.set_column(k, &d);
    }
    let m = j.transpose() * j;
    Info::from_fn(|r, c| m[(r, c)])
}

/// `log det` of the Schur complement of the balls' block: the information on the eight
/// errors once the balls' positions are fitted too (-inf when they are not all
/// identifiable).
fn ds_criterion(m: &Info) -> f64 {
    let a = m.fixed_view::<8, 8>(0, 0);
    let b = m.fixed_view::<8, 6>(0, 8);
    let d = m.fixed_view::<6, 6>(8, 8);
    let Some(d_inv) = d.into_owned().try_inverse() else {
        return f64::NEG_INFINITY;
    };
    let schur = a - b * d_inv * b.transpose();
    match schur.cholesky() {
        Some(ch) => 2.0 * ch.l().diagonal().iter().map(|v| v.ln()).sum::<f64>(),
        None => f64::NEG_INFINITY,
    }
}

/// Every `k`-subset of `0..n`, in lexicographic order.
fn subsets(n: usize, k: usize) -> Vec<Vec<usize>> {
    let mut out = Vec::new();
    let mut pick: Vec<usize> = (0..k).collect();
    if k > n {
        return out;
    }
    loop {
        out.push(pick.clone());
        // The rightmost index that can still move right.
        let Some(i) = (0..k).rev().find(|&i| pick[i] < n - k + i) else {
            return out;
        };
        pick[i] += 1;
        for j in i + 1..k {
            pick[j] = pick[j - 1] + 1;
        }
    }
}

/// The Ds-optimal `c_count` C positions and `a_count` A positions among the paper's
/// candidates (see the module's documentation); ties go to the first subset in
/// lexicographic order, so the design is the same on every run. Each sweep needs at
/// least 4 positions (its circles are fitted to at least 4 centres).
pub fn optimal_design(
    constants: &MachineConstants,
    artifact: &Artifact,
    c_count: usize,
    a_count: usize,
) -> Result<Design, String> {
    let paper = Design::paper();
    if !(4..=paper.c_steps_deg.len()).contains(&c_count)
        || !(4..=paper.a_steps_deg.len()).contains(&a_count)
    {
        return Err(format!(
            "an optimal design needs 4 to {} C positions and 4 to {} A positions, not {c_count} and {a_count}",
            paper.c_steps_deg.len(),
            paper.a_steps_deg.len()
        ));
    }
    let c_info: Vec<Info> = paper
        .c_steps_deg
        .iter()
        .map(|&c| position_information(constants, artifact, Axis::C, c))
        .collect();
    let a_info: Vec<Info> = paper
        .a_steps_deg
        .iter()
        .map(|&a| position_information(constants, artifact, Axis::A, a))
        .collect();
    let c_sets = subsets(c_info.len(), c_count);
    let a_sets: Vec<(Vec<usize>, Info)> = subsets(a_info.len(), a_count)
        .into_iter()
        .map(|s| {
            let m = s.iter().map(|&i| a_info[i]).sum();
            (s, m)
        })
        .collect();
    let mut best: Option<(f64, &[usize], &[usize])> = None;
    for cs in &c_sets {
        let mc: Info = cs.iter().map(|&i| c_info[i]).sum();
        for (as_, ma) in &a_sets {
            let score = ds_criterion(&(mc + ma));
            // Strictly better only (ties keep the first), with a relative margin so that
            // rounding between mirror-image sets does not decide.
            if best.is_none_or(|(b, _, _)| score > b + 1e-9 * b.abs().max(1.0)) {
                best = Some((score, cs, as_));
            }
        }
    }
    let (_, cs, as_) = best.ok_or("no design scores")?;
    Ok(Design {
        c_steps_deg: cs.iter().map(|&i| paper.c_steps_deg[i]).collect(),
        a_steps_deg: as_.iter().map(|&i| paper.a_steps_deg[i]).collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn subsets_are_every_choice_once() {
        assert_eq!(subsets(12, 4).len(), 495);
        assert_eq!(subsets(7, 4).len(), 35);
        assert_eq!(
            subsets(4, 2),
            [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]]
        );
    }

    /// The chosen design scores at least as well as every other of its size (checked
    /// against the evenly spread ones) and has all eight errors identifiable.
    #[test]
    fn the_optimal_design_beats_evenly_spread_positions() {
        let (k, art) = (MachineConstants::default(), Artifact::default());
        let best = optimal_design(&k, &art, 4, 4).unwrap();
        assert_eq!(best.c_steps_deg, [90.0, 120.0, 210.0, 270.0]);
        assert_eq!(best.a_steps_deg, [0.0, 60.0, 75.0, 90.0]);
        let score = best.log_information(&k, &art);
        assert!(score.is_finite());
        let even = Design {
            c_steps_deg: vec![0.0, 90.0, 180.0, 270.0],
            a_steps_deg: vec![0.0, 30.0, 60.0, 90.0],
        };
        assert!(score >= even.log_information(&k, &art));
        // The paper's 19 positions hold more information (more centres) but per centre
        // less: D-efficiency per position.
        let paper = Design::paper();
        let per = |d: &Design| {
            let n = (d.c_steps_deg.len() + d.a_steps_deg.len()) as f64;
            (d.log_information(&k, &art) / 8.0).exp() / n
        };
        println!("per position: optimal {} paper {}", per(&best), per(&paper));
        assert!(per(&best) > per(&paper));
    }

    #[test]
    fn too_few_positions_are_refused() {
        let (k, art) = (MachineConstants::default(), Artifact::default());
        let e = optimal_design(&k, &art, 3, 4).unwrap_err();
        assert!(e.contains("4 to 12 C positions"), "{e}");
    }
}

//! Adaptive splitting of one straight nominal move.
//!
//! The controller interpolates a straight line between two commands; the commands that
//! keep the tool on the nominal line follow a curve (the machine's errors change along
//! the way). A piece is accepted when the straight line between its end commands stays
//! within 85 % of the tolerance of the model's command at interior probe points; else it
//! is cut in half. Probes: the middle, and on a piece longer than half the model's
//! feature length (the shortest distance over which its errors can turn, e.g. the node
//! spacing of a map) more, no further apart than half that length, so that an error
//! whose period divides the piece evenly cannot hide between the probes (a 5 mm screw
//! error on a 50 mm move is zero at every quarter point). [`MAX_DEPTH`] bounds a
//! pathological model at 2^16 pieces per move.
//!
//! Before that, [`turns`] finds where any axis's command turns back along the move (the
//! rewriter then takes up that axis's backlash on the spot and splits each stretch on
//! its own side).

use crate::{Approach, Pose, N_AXIS};

/// Halvings of one move at most.
pub const MAX_DEPTH: u32 = 16;

/// The pieces of the nominal move `p0 -> p1`: each piece's nominal end and its command,
/// the last one ending exactly on `p1`. `c0` is the command at `p0`; `command` gives the
/// command for a nominal point, from a first guess; `tolerance` and `feature` (the model's feature length)
/// are in the units of the poses (mm).
pub fn split<E>(
    p0: &Pose,
    c0: &Pose,
    p1: &Pose,
    tolerance: f64,
    feature: f64,
    command: &mut impl FnMut(&Pose, &Pose) -> Result<Pose, E>,
) -> Result<Vec<(Pose, Pose)>, E> {
    // The correction changes little along a move: the start's is a good first guess.
    let mut guess = *p1;
    for i in 0..guess.len() {
        guess[i] += c0[i] - p0[i];
    }
    let c1 = command(p1, &guess)?;
    let mut out = Vec::new();
    let limits = Limits { tolerance, feature };
    piece(p0, c0, p1, &c1, &limits, 0, command, &mut out)?;
    Ok(out)
}

struct Limits {
    tolerance: f64,
    feature: f64,
}

#[allow(clippy::too_many_arguments)]
fn piece<E>(
    p0: &Pose,
    c0: &Pose,
    p1: &Pose,
    c1: &Pose,
    limits: &Limits,
    depth: u32,
    command: &mut impl FnMut(&Pose, &Pose) -> Result<Pose, E>,
    out: &mut Vec<(Pose, Pose)>,
) -> Result<(), E> {
    if depth < MAX_DEPTH {
        let pm = lerp(p0, p1, 0.5);
        let cm = command(&pm, &lerp(c0, c1, 0.5))?;
        // Accepted below 85 % of the tolerance: a cubic's largest distance from its chord
        // can lie off the probes by up to about 20 % of what the probes see.
        let accept = 0.85 * limits.tolerance;
        let mut bent = distance(&lerp(c0, c1, 0.5), &cm) > accept;
        if !bent {
            // Further probes at t = k/n, no more than half a feature length apart (n even,
            // so the middle, already probed, is among them): none on a piece shorter than
            // half a feature, the quarter points up to a whole one.
            let length = distance(p0, p1);
            let halves = (2.0 * length / limits.feature).ceil().clamp(1.0, 1024.0) as usize;
            let n = 2 * halves;
            for k in (1..n).filter(|&k| 2 * k != n) {
                let t = k as f64 / n as f64;
                let ct = command(&lerp(p0, p1, t), &lerp(c0, c1, t))?;
                if distance(&lerp(c0, c1, t), &ct) > accept {
                    bent = true;
                    break;
                }
            }
        }
        if bent {
            piece(p0, c0, &pm, &cm, limits, depth + 1, command, out)?;
            return piece(&pm, &cm, p1, c1, limits, depth + 1, command, out);
        }
    }
    out.push((*p1, *c1));
    Ok(())
}

pub fn lerp(a: &Pose, b: &Pose, t: f64) -> Pose {
    let mut p = *a;
    for i in 0..p.len() {
        p[i] = a[i] + (b[i] - a[i]) * t;
    }
    p
}

pub fn distance(a: &Pose, b: &Pose) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f64>()
        .sqrt()
}

/// Samples of one move for [`turns`] at most (a 200 mm move on a 1 mm map: 800).
pub const MAX_SAMPLES: usize = 4096;

/// The share of the tolerance below which a retreat of an axis's command is not
/// followed (see [`turns`]).
pub const REVERSAL_SHARE: f64 = 0.5;

/// Where the commands of one move change direction, axis by axis, and the approach side
/// each stretch of the move needs.
#[derive(Clone, Debug, PartialEq)]
pub struct Turns {
    /// Stretches of the move: where each starts (0..1 along the move) and the side each
    /// axis arrives from on it. The first starts at 0; its sides may differ from those the
    /// move started with (an axis that reverses at the very start).
    pub runs: Vec<(f64, [Approach; N_AXIS])>,
    /// How far (mm, >= 0) each axis's command has retreated at the end of the move from
    /// the furthest point it reached on its side, not yet followed: carried into the next
    /// move, so creeping back in many short moves is seen as one retreat.
    pub retreat: Pose,
}

/// The turning points of the commands along the straight nominal move `p0 -> p1`.
///
/// The controller moves each axis's nut with its command; when an axis's command turns
/// back, the nut must cross the backlash before the carriage follows, so the model's
/// command for the other side applies from there on. The move is sampled every quarter
/// of the model's feature length (at its ends only on a move shorter than that, where a
/// turn inside is taken at the next move's start; at most [`MAX_SAMPLES`]),
/// each axis's command is followed with the sides the move starts with, and a turn is
/// taken where the command has come back by more than `threshold` from its furthest
/// point on its side: the new stretch starts at that furthest point. A retreat within
/// `threshold` is not followed (the axis stays in its backlash by at most that much);
/// `retreat` carries what was left of it in the previous moves. Only `axes` are looked
/// at. `command` gives the command for a nominal point from a first guess, on `sides`.
///
/// Bound: at most one turn per axis per sample, and at most (the command's total travel
/// back and forth along the move) / `threshold` turns per axis.
#[allow(clippy::too_many_arguments)]
pub fn turns<E>(
    p0: &Pose,
    c0: &Pose,
    p1: &Pose,
    sides: &[Approach; N_AXIS],
    retreat: &Pose,
    axes: &[bool; N_AXIS],
    threshold: f64,
    feature: f64,
    samples_at_most: usize,
    command: &mut impl FnMut(&Pose, &Pose) -> Result<Pose, E>,
) -> Result<Turns, E> {
    let length = distance(p0, p1);
    let wanted = (4.0 * length / feature).ceil();
    let n = if wanted.is_finite() {
        (wanted as usize).clamp(1, MAX_SAMPLES)
    } else {
        2
    }
    .min(samples_at_most.max(1));
    // The command at every sample, from the start's correction as a first guess.
    let mut values = Vec::with_capacity(n + 1);
    let mut guess = *c0;
    for k in 0..=n {
        let p = if k == n {
            *p1
        } else {
            lerp(p0, p1, k as f64 / n as f64)
        };
        if k > 0 {
            let previous: &Pose = &values[k - 1];
            let q = lerp(p0, p1, (k - 1) as f64 / n as f64);
            for i in 0..N_AXIS {
                guess[i] = previous[i] + p[i] - q[i];
            }
        }
        // The start's command is the one the machine was given there.
        let c = if k == 0 { *c0 } else { command(&p, &guess)? };
        values.push(c);
    }
    // Per axis: its turns (sample index of the furthest point, new side).
    let mut changes: Vec<(usize, usize, Approach)> = Vec::new();
    let mut left = [0.0; N_AXIS];
    for i in (0..N_AXIS).filter(|&i| axes[i]) {
        let sign = |a: Approach| if a == Approach::Forward { 1.0 } else { -1.0 };
        let mut side = sides[i];
        let mut furthest = values[0][i] + sign(side) * retreat[i].max(0.0);
        let mut at = 0;
        for (k, v) in values.iter().enumerate().skip(1) {
            let ahead = (v[i] - furthest) * sign(side);
            if ahead > 0.0 {
                furthest = v[i];
                at = k;
            } else if -ahead > threshold {
                side = match side {
                    Approach::Forward => Approach::Reverse,
                    Approach::Reverse => Approach::Forward,
                };
                changes.push((at, i, side));
                furthest = v[i];
                at = k;
            }
        }
        left[i] = (furthest - values[n][i]) * sign(side);
    }
    changes.sort_by_key(|&(k, i, _)| (k, i));
    let mut runs = vec![(0.0, *sides)];
    for (k, i, side) in changes {
        let t = k as f64 / n as f64;
        let last = runs.last_mut().expect("one run at least");
        if last.0 == t {
            last.1[i] = side;
        } else {
            let mut s = last.1;
            s[i] = side;
            runs.push((t, s));
        }
    }
    Ok(Turns {
        runs,
        retreat: left,
    })
}

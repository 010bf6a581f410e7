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

use crate::Pose;

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

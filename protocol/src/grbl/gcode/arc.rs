//! GRBL's arc segmentation (`mc_arc`): an arc becomes chords within the arc tolerance.

use std::f64::consts::PI;

const ARC_ANGULAR_TRAVEL_EPSILON: f64 = 5e-7;
/// Most chords of one arc: GRBL's `mc_arc` counts them in a `uint16_t`.
pub(super) const MAX_SEGMENTS: u16 = u16::MAX;

/// Chord end points of an arc (GRBL's `mc_arc`): as many segments as keep the chord
/// within the arc tolerance; the last point is exactly the target.
pub(super) fn arc_points<const N: usize>(
    position: [f64; N],
    target: [f64; N],
    offset: [f64; N],
    (a0, a1, _lin): (usize, usize, usize),
    clockwise: bool,
    tolerance: f64,
) -> Vec<[f64; N]> {
    let c0 = position[a0] + offset[a0];
    let c1 = position[a1] + offset[a1];
    let r0 = -offset[a0];
    let r1 = -offset[a1];
    let rt0 = target[a0] - c0;
    let rt1 = target[a1] - c1;
    let radius = r0.hypot(r1);
    let mut travel = (r0 * rt1 - r1 * rt0).atan2(r0 * rt0 + r1 * rt1);
    if clockwise {
        if travel >= -ARC_ANGULAR_TRAVEL_EPSILON {
            travel -= 2.0 * PI;
        }
    } else if travel <= ARC_ANGULAR_TRAVEL_EPSILON {
        travel += 2.0 * PI;
    }
    let tol = tolerance.max(1e-6);
    let segments =
        ((0.5 * travel * radius).abs() / (tol * (2.0 * radius - tol)).max(1e-12).sqrt()).floor();
    // GRBL keeps the count in a uint16_t: an absurd radius (or NaN) cannot ask for
    // more chords than that, and nothing is reserved from the count.
    let segments = if segments.is_nan() {
        0
    } else {
        segments.min(MAX_SEGMENTS as f64) as usize
    };
    let mut pts = Vec::new();
    for k in 1..segments.max(1) {
        if segments <= 1 {
            break;
        }
        let a = travel * k as f64 / segments as f64;
        let (s, c) = a.sin_cos();
        let mut p = position;
        p[a0] = c0 + r0 * c - r1 * s;
        p[a1] = c1 + r0 * s + r1 * c;
        // The linear axis and any rotary axis move in proportion (grblHAL's `mc_arc`).
        for axis in (0..N).filter(|&i| i != a0 && i != a1) {
            p[axis] = position[axis] + (target[axis] - position[axis]) * k as f64 / segments as f64;
        }
        pts.push(p);
    }
    pts.push(target);
    pts
}

//! Manufacturing errors of a calibration plate, as a metrology lab would certify them.
//!
//! A chrome-on-glass dot plate is not a perfect grid: the writer has a small scale
//! error, a slow bow over the plate and per-dot placement noise. The lab measures every
//! point; the certificate (protocol::board certificate CSV) records the true positions.
//! The simulated rig places dots at those certified positions, so a gateway that uses
//! the certificate is exact and one that assumes a nominal grid is not.

use crate::rng::Rng;
use protocol::Board;

#[derive(Clone, Copy, Debug)]
pub struct PlateErrors {
    /// Scale error of the writer, parts per million.
    pub scale_ppm: f64,
    /// Peak of the slow bow over the plate, micrometres.
    pub bow_um: f64,
    /// Per-dot placement noise (sigma), micrometres.
    pub dot_sigma_um: f64,
}

impl Default for PlateErrors {
    fn default() -> Self {
        Self {
            scale_ppm: 2.0,
            bow_um: 0.6,
            dot_sigma_um: 0.15,
        }
    }
}

/// Apply drawn manufacturing errors to every point of `board`.
pub fn manufacture(board: &mut Board, errors: PlateErrors, seed: u64) {
    let mut rng = Rng::new(seed);
    let (lo, hi) = board.extent();
    let span = [(hi[0] - lo[0]).max(1e-9), (hi[1] - lo[1]).max(1e-9)];
    let phase: [f64; 4] = std::array::from_fn(|_| rng.range(0.0, std::f64::consts::TAU));
    let um = 1e-3;
    for j in 0..board.rows {
        for i in 0..board.cols {
            let n = board.nominal_xy(i as i64, j as i64);
            let u = [(n[0] - lo[0]) / span[0], (n[1] - lo[1]) / span[1]];
            let bow_x =
                (std::f64::consts::PI * u[1] + phase[0]).sin() * (2.1 * u[0] + phase[1]).cos();
            let bow_y =
                (std::f64::consts::PI * u[0] + phase[2]).sin() * (1.7 * u[1] + phase[3]).cos();
            let dx = errors.scale_ppm * 1e-6 * (n[0] - lo[0])
                + errors.bow_um * um * bow_x
                + errors.dot_sigma_um * um * rng.normal();
            let dy = errors.scale_ppm * 1e-6 * (n[1] - lo[1])
                + errors.bow_um * um * bow_y
                + errors.dot_sigma_um * um * rng.normal();
            board.set_true_xy(i, j, [n[0] + dx, n[1] + dy]);
        }
    }
}

/// Damage `fraction` of the dots of `board` (0..1), drawn from `seed`, in three equal
/// shares: missing dots, dots merged with a neighbour by a bridge of dot material, and
/// dirt blobs (0.05 to 0.2 mm) near a dot, on it or beside it.
pub fn damage(board: &Board, fraction: f64, seed: u64) -> crate::render::Damage {
    let mut rng = Rng::new(seed);
    let mut out = crate::render::Damage::default();
    let pitch = board.pitch_mm;
    for j in 0..board.rows as i64 {
        for i in 0..board.cols as i64 {
            if rng.uniform() >= fraction {
                continue;
            }
            let Some(xy) = board.true_xy(i, j) else {
                continue;
            };
            match rng.next_u64() % 3 {
                0 => {
                    out.missing.insert((i, j));
                }
                1 => {
                    // A bridge to the +x or +y neighbour, wide enough to join both.
                    let (di, dj) = if rng.uniform() < 0.5 { (1, 0) } else { (0, 1) };
                    let Some(n) = board.true_xy(i + di, j + dj) else {
                        continue;
                    };
                    let mid = [0.5 * (xy[0] + n[0]), 0.5 * (xy[1] + n[1])];
                    out.blobs.push((mid, 0.7 * pitch));
                }
                _ => {
                    let d = rng.range(0.05, 0.2);
                    let r = rng.range(0.0, 0.3 * pitch);
                    let a = rng.range(0.0, std::f64::consts::TAU);
                    out.blobs
                        .push(([xy[0] + r * a.cos(), xy[1] + r * a.sin()], d));
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::Polarity;

    #[test]
    fn errors_are_small_deterministic_and_round_trip_through_a_certificate() {
        let mut a = Board::nominal("t", 0.5, 0.25, Polarity::DarkOnLight, 40, 30, [0.0, 0.0]);
        let mut b = a.clone();
        manufacture(&mut a, PlateErrors::default(), 5);
        manufacture(&mut b, PlateErrors::default(), 5);
        assert_eq!(a, b);
        let mut worst: f64 = 0.0;
        for j in 0..30 {
            for i in 0..40 {
                let t = a.true_xy(i, j).unwrap();
                let n = a.nominal_xy(i, j);
                worst = worst.max((t[0] - n[0]).abs()).max((t[1] - n[1]).abs());
            }
        }
        assert!(
            worst > 0.0002 && worst < 0.002,
            "worst plate error {worst} mm"
        );
        let mut c = Board::nominal("t", 0.5, 0.25, Polarity::DarkOnLight, 40, 30, [0.0, 0.0]);
        c.apply_certificate("cert", &a.certificate_csv()).unwrap();
        for (i, j) in [(0, 0), (17, 11), (39, 29)] {
            let (p, q) = (a.true_xy(i, j).unwrap(), c.true_xy(i, j).unwrap());
            assert!((p[0] - q[0]).abs() < 1e-6 && (p[1] - q[1]).abs() < 1e-6);
        }
    }
}

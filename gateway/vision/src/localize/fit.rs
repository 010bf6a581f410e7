//! The pixel -> board model: a plane homography after one radial distortion term about
//! the image centre, `p_u = c + (p - c)(1 + k1 r²)`, fitted to the certified coordinates
//! of every identified dot.
//!
//! Why this model: the board is a plane, so any pinhole camera maps it by a homography;
//! lens distortion is mostly radial and its first term dominates for machine-vision
//! lenses. Perspective, scale, rotation, shear and distortion are all estimated, so
//! nothing is assumed about the camera beyond that.
//!
//! Fitting: normalised DLT for a start, then Gauss-Newton on all nine parameters. One
//! bad dot (dirt, a mis-measured centre) must not move the result, so points further
//! than 4 robust sigmas (from the median residual) are dropped and the model refitted
//! until the inlier set is stable.

use nalgebra::{DMatrix, DVector};

/// One identified point: measured pixel centre and certified board coordinate.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Corr {
    pub px: [f64; 2],
    pub mm: [f64; 2],
}

/// The fitted model, in normalised coordinates (pixels relative to the image centre
/// divided by `sp`; board relative to `bm` divided by `sb`) for conditioning.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Model {
    c: [f64; 2],
    sp: f64,
    bm: [f64; 2],
    sb: f64,
    /// Homography, row-major, h[8] = 1.
    h: [f64; 8],
    /// Radial distortion in normalised pixel units.
    k: f64,
}

impl Model {
    /// Board coordinate (mm) of pixel `p`.
    pub(crate) fn map(&self, p: [f64; 2]) -> [f64; 2] {
        let q = [(p[0] - self.c[0]) / self.sp, (p[1] - self.c[1]) / self.sp];
        let b = self.map_norm(q);
        [self.bm[0] + self.sb * b[0], self.bm[1] + self.sb * b[1]]
    }

    fn map_norm(&self, q: [f64; 2]) -> [f64; 2] {
        let h = &self.h;
        let f = 1.0 + self.k * (q[0] * q[0] + q[1] * q[1]);
        let (ux, uy) = (q[0] * f, q[1] * f);
        let den = h[6] * ux + h[7] * uy + 1.0;
        [
            (h[0] * ux + h[1] * uy + h[2]) / den,
            (h[3] * ux + h[4] * uy + h[5]) / den,
        ]
    }

    /// d(board mm)/d(pixel) at pixel `p`, as columns: [d/dx, d/dy].
    pub(crate) fn jacobian(&self, p: [f64; 2]) -> [[f64; 2]; 2] {
        let e = 1e-3;
        let a = self.map([p[0] + e, p[1]]);
        let b = self.map([p[0] - e, p[1]]);
        let c = self.map([p[0], p[1] + e]);
        let d = self.map([p[0], p[1] - e]);
        [
            [(a[0] - b[0]) / (2.0 * e), (a[1] - b[1]) / (2.0 * e)],
            [(c[0] - d[0]) / (2.0 * e), (c[1] - d[1]) / (2.0 * e)],
        ]
    }
}

/// Result of a robust fit.
#[derive(Clone, Debug)]
pub(crate) struct FitOut {
    pub model: Model,
    pub inlier: Vec<bool>,
    pub n_inliers: usize,
    /// RMS of the inliers' residual vectors, mm.
    pub rms_mm: f64,
}

/// Smallest robust sigma used for rejection (mm): below this, residuals are at the
/// level of the certificate's own precision and nothing is an outlier.
const SIGMA_FLOOR_MM: f64 = 2e-5;

/// Fit the model to `corr` (at least 4 points). None if the points are degenerate
/// (collinear) or the iteration fails.
pub(crate) fn fit(corr: &[Corr], centre: [f64; 2]) -> Option<FitOut> {
    let n = corr.len();
    if n < 4 {
        return None;
    }
    let sp = (corr
        .iter()
        .map(|c| (c.px[0] - centre[0]).powi(2) + (c.px[1] - centre[1]).powi(2))
        .sum::<f64>()
        / n as f64)
        .sqrt()
        .max(1.0);
    let bm = [
        corr.iter().map(|c| c.mm[0]).sum::<f64>() / n as f64,
        corr.iter().map(|c| c.mm[1]).sum::<f64>() / n as f64,
    ];
    let sb = (corr
        .iter()
        .map(|c| (c.mm[0] - bm[0]).powi(2) + (c.mm[1] - bm[1]).powi(2))
        .sum::<f64>()
        / n as f64)
        .sqrt();
    if !(sb > 0.0) {
        return None;
    }
    let q: Vec<[f64; 2]> = corr
        .iter()
        .map(|c| [(c.px[0] - centre[0]) / sp, (c.px[1] - centre[1]) / sp])
        .collect();
    let b: Vec<[f64; 2]> = corr
        .iter()
        .map(|c| [(c.mm[0] - bm[0]) / sb, (c.mm[1] - bm[1]) / sb])
        .collect();
    let mut model = Model {
        c: centre,
        sp,
        bm,
        sb,
        h: [0.0; 8],
        k: 0.0,
    };
    let mut inlier = vec![true; n];
    model.h = dlt(&q, &b, &inlier)?;

    let mut rms = 0.0;
    for _round in 0..5 {
        // k1 only with enough points to tell it from scale and perspective.
        let with_k1 = inlier.iter().filter(|&&x| x).count() >= 12;
        gauss_newton(&mut model, &q, &b, &inlier, with_k1)?;
        // Residuals of every point (mm), robust sigma from the inliers' median.
        let res: Vec<f64> = q
            .iter()
            .zip(&b)
            .map(|(qi, bi)| {
                let r = model.map_norm(*qi);
                sb * ((r[0] - bi[0]).powi(2) + (r[1] - bi[1]).powi(2)).sqrt()
            })
            .collect();
        let mut inl: Vec<f64> = res
            .iter()
            .zip(&inlier)
            .filter(|(_, &k)| k)
            .map(|(r, _)| *r)
            .collect();
        rms = (inl.iter().map(|r| r * r).sum::<f64>() / inl.len().max(1) as f64).sqrt();
        // Median of a 2-D Gaussian residual's length is 1.1774 sigma.
        let sigma = (super::detect::median(&mut inl).unwrap_or(0.0) / 1.1774).max(SIGMA_FLOOR_MM);
        let new: Vec<bool> = res.iter().map(|&r| r <= 4.0 * sigma).collect();
        let count = new.iter().filter(|&&x| x).count();
        if new == inlier || count < 4 {
            break;
        }
        inlier = new;
    }
    let n_inliers = inlier.iter().filter(|&&x| x).count();
    Some(FitOut {
        model,
        inlier,
        n_inliers,
        rms_mm: rms,
    })
}

/// Linear DLT with h[8] = 1 (safe: normalised pixel coordinates are centred on the
/// image centre, where the homography's denominator is close to 1).
fn dlt(q: &[[f64; 2]], b: &[[f64; 2]], use_pt: &[bool]) -> Option<[f64; 8]> {
    let mut ata = DMatrix::<f64>::zeros(8, 8);
    let mut atb = DVector::<f64>::zeros(8);
    for ((qi, bi), &u) in q.iter().zip(b).zip(use_pt) {
        if !u {
            continue;
        }
        let (x, y) = (qi[0], qi[1]);
        let rows = [
            ([x, y, 1.0, 0.0, 0.0, 0.0, -x * bi[0], -y * bi[0]], bi[0]),
            ([0.0, 0.0, 0.0, x, y, 1.0, -x * bi[1], -y * bi[1]], bi[1]),
        ];
        for (r, rhs) in rows {
            for i in 0..8 {
                atb[i] += r[i] * rhs;
                for j in 0..8 {
                    ata[(i, j)] += r[i] * r[j];
                }
            }
        }
    }
    let sol = ata.lu().solve(&atb)?;
    let mut h = [0.0; 8];
    for i in 0..8 {
        h[i] = sol[i];
    }
    h.iter().all(|v| v.is_finite()).then_some(h)
}

/// Gauss-Newton on (h0..h7, k) over the inliers. None if the normal equations are
/// singular.
fn gauss_newton(
    m: &mut Model,
    q: &[[f64; 2]],
    b: &[[f64; 2]],
    use_pt: &[bool],
    with_k: bool,
) -> Option<()> {
    let np = if with_k { 9 } else { 8 };
    if !with_k {
        m.k = 0.0;
    }
    for _ in 0..8 {
        let mut jtj = DMatrix::<f64>::zeros(np, np);
        let mut jtr = DVector::<f64>::zeros(np);
        for ((qi, bi), &u) in q.iter().zip(b).zip(use_pt) {
            if !u {
                continue;
            }
            let h = &m.h;
            let r2 = qi[0] * qi[0] + qi[1] * qi[1];
            let f = 1.0 + m.k * r2;
            let (ux, uy) = (qi[0] * f, qi[1] * f);
            let den = h[6] * ux + h[7] * uy + 1.0;
            let xx = (h[0] * ux + h[1] * uy + h[2]) / den;
            let yy = (h[3] * ux + h[4] * uy + h[5]) / den;
            let mut jx = [0.0; 9];
            let mut jy = [0.0; 9];
            jx[0] = ux / den;
            jx[1] = uy / den;
            jx[2] = 1.0 / den;
            jx[6] = -xx * ux / den;
            jx[7] = -xx * uy / den;
            jy[3] = ux / den;
            jy[4] = uy / den;
            jy[5] = 1.0 / den;
            jy[6] = -yy * ux / den;
            jy[7] = -yy * uy / den;
            jx[8] = ((h[0] - h[6] * xx) * qi[0] + (h[1] - h[7] * xx) * qi[1]) * r2 / den;
            jy[8] = ((h[3] - h[6] * yy) * qi[0] + (h[4] - h[7] * yy) * qi[1]) * r2 / den;
            let (ex, ey) = (bi[0] - xx, bi[1] - yy);
            for i in 0..np {
                jtr[i] += jx[i] * ex + jy[i] * ey;
                for j in i..np {
                    jtj[(i, j)] += jx[i] * jx[j] + jy[i] * jy[j];
                }
            }
        }
        for i in 0..np {
            for j in 0..i {
                jtj[(i, j)] = jtj[(j, i)];
            }
        }
        let step = jtj.cholesky()?.solve(&jtr);
        for i in 0..8 {
            m.h[i] += step[i];
        }
        if with_k {
            m.k += step[8];
        }
        if step.norm() < 1e-12 {
            break;
        }
    }
    (m.h.iter().all(|v| v.is_finite()) && m.k.is_finite()).then_some(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A synthetic camera: rotation, scale, mild perspective and radial distortion.
    fn project(b: [f64; 2]) -> [f64; 2] {
        // Board -> undistorted pixel by a homography, then distort.
        let (s, t) = (250.0, 0.02f64);
        let (x, y) = (b[0] - 10.0, b[1] - 20.0);
        let den = 1.0 + 0.002 * x - 0.001 * y;
        let u = [
            (s * (t.cos() * x - t.sin() * y)) / den,
            (s * (-t.sin() * x - t.cos() * y)) / den,
        ];
        let k = 3e-9;
        let f = 1.0 + k * (u[0] * u[0] + u[1] * u[1]);
        [639.5 + u[0] * f, 511.5 + u[1] * f]
    }

    fn corrs() -> Vec<Corr> {
        let mut v = Vec::new();
        for j in -4..=4 {
            for i in -5..=5 {
                let mm = [10.0 + 0.5 * i as f64, 20.0 + 0.5 * j as f64];
                v.push(Corr {
                    px: project(mm),
                    mm,
                });
            }
        }
        v
    }

    #[test]
    fn recovers_centre_of_a_distorted_perspective_view() {
        let c = corrs();
        let f = fit(&c, [639.5, 511.5]).unwrap();
        let p = f.model.map([639.5, 511.5]);
        assert!(
            (p[0] - 10.0).abs() < 1e-7 && (p[1] - 20.0).abs() < 1e-7,
            "{p:?}"
        );
        assert_eq!(f.n_inliers, c.len());
        // The model inverts the distortion only to first order: nanometres here.
        assert!(f.rms_mm < 5e-6, "{}", f.rms_mm);
    }

    #[test]
    fn one_bad_point_is_rejected_and_does_not_move_the_centre() {
        let mut c = corrs();
        // Small realistic scatter, then one grossly wrong point.
        for (k, p) in c.iter_mut().enumerate() {
            p.mm[0] += 1e-4 * ((k * 7 % 11) as f64 / 11.0 - 0.5);
            p.mm[1] += 1e-4 * ((k * 5 % 13) as f64 / 13.0 - 0.5);
        }
        c[40].px[0] += 3.0;
        let f = fit(&c, [639.5, 511.5]).unwrap();
        assert!(!f.inlier[40]);
        assert_eq!(f.n_inliers, c.len() - 1);
        let p = f.model.map([639.5, 511.5]);
        assert!(
            (p[0] - 10.0).abs() < 3e-5 && (p[1] - 20.0).abs() < 3e-5,
            "{p:?}"
        );
    }
}

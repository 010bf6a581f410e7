//! The patent's four-point formula (SPEC.md section A, claims 3-5), implemented exactly
//! as written so that its results can be compared with the fit.
//!
//! The 4 points of the grid cell around the image centre are paired along the cell's
//! two diagonals (each pair must differ in both x and y): point 1 = (i, j) with
//! point 2 = (i+1, j+1), point 3 = (i+1, j) with point 4 = (i, j+1). Per axis, the true
//! coordinate is interpolated linearly in the pixel coordinate along each diagonal, and
//! the two estimates averaged:
//!
//! ```text
//! Xmm11 = Xmm1 + (Xc - X1)(Xmm2 - Xmm1)/(X2 - X1)     Ymm11 likewise with Y
//! Xmm22 = Xmm3 + (Xc - X3)(Xmm4 - Xmm3)/(X4 - X3)     Ymm22 likewise with Y
//! Xmm = (Xmm11 + Xmm22)/2,  Ymm = (Ymm11 + Ymm22)/2
//! ```
//!
//! Pixel coordinates are taken in board-aligned pixel axes (the nominal `PixelAxes`
//! sign/swap applied, so pixel X runs along board x). Each axis is interpolated from
//! its own pixel coordinate only, so a camera rotated by θ from nominal gives an error
//! that grows with θ and with the centre's offset inside the cell. That bias is the
//! method's, and is deliberately not corrected: it is what we report against the fit.

/// One cell corner: board-aligned pixel coordinate and certified board coordinate.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Corner {
    pub px: [f64; 2],
    pub mm: [f64; 2],
}

/// The formula. `p` = [point1 (i,j), point2 (i+1,j+1), point3 (i+1,j), point4 (i,j+1)],
/// `c` = the image centre in the same board-aligned pixel axes. None if a diagonal has
/// no extent along an axis (cannot happen for a real cell).
pub(crate) fn four_point(p: &[Corner; 4], c: [f64; 2]) -> Option<[f64; 2]> {
    let interp = |a: &Corner, b: &Corner, axis: usize| -> Option<f64> {
        let den = b.px[axis] - a.px[axis];
        if den.abs() < 1e-9 {
            return None;
        }
        Some(a.mm[axis] + (c[axis] - a.px[axis]) * (b.mm[axis] - a.mm[axis]) / den)
    };
    let xmm11 = interp(&p[0], &p[1], 0)?;
    let ymm11 = interp(&p[0], &p[1], 1)?;
    let xmm22 = interp(&p[2], &p[3], 0)?;
    let ymm22 = interp(&p[2], &p[3], 1)?;
    Some([0.5 * (xmm11 + xmm22), 0.5 * (ymm11 + ymm22)])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cell(theta: f64, centre_mm: [f64; 2]) -> ([Corner; 4], [f64; 2]) {
        // 125 px per 0.5 mm cell, camera rotated by theta; board-aligned pixel axes.
        let s = 250.0;
        let to_px = |m: [f64; 2]| {
            let d = [m[0] - centre_mm[0], m[1] - centre_mm[1]];
            let (sn, cs) = theta.sin_cos();
            [s * (cs * d[0] + sn * d[1]), s * (-sn * d[0] + cs * d[1])]
        };
        let pts = [[0.0, 0.0], [0.5, 0.5], [0.5, 0.0], [0.0, 0.5]];
        let corners = pts.map(|m| Corner {
            px: to_px(m),
            mm: m,
        });
        (corners, [0.0, 0.0])
    }

    #[test]
    fn exact_without_rotation_and_biased_with_it() {
        let (p, c) = cell(0.0, [0.2, 0.35]);
        let r = four_point(&p, c).unwrap();
        assert!(
            (r[0] - 0.2).abs() < 1e-12 && (r[1] - 0.35).abs() < 1e-12,
            "{r:?}"
        );
        // 2 degrees: a bias of micrometres, which the method does not correct.
        let (p, c) = cell(2f64.to_radians(), [0.2, 0.35]);
        let r = four_point(&p, c).unwrap();
        let err_um = ((r[0] - 0.2).hypot(r[1] - 0.35)) * 1000.0;
        assert!(err_um > 0.5 && err_um < 50.0, "{err_um}");
        // At the cell centre the two diagonals' errors cancel by symmetry.
        let (p, c) = cell(2f64.to_radians(), [0.25, 0.25]);
        let r = four_point(&p, c).unwrap();
        assert!(
            (r[0] - 0.25).abs() < 1e-9 && (r[1] - 0.25).abs() < 1e-9,
            "{r:?}"
        );
    }
}

//! Identification: which board point is each dot.
//!
//! The dots alone give a lattice up to an integer offset. The lattice (two basis
//! vectors) comes from nearest-neighbour differences; integer lattice indices are grown
//! outwards from the dot nearest the image centre through each dot's near neighbours,
//! and checked against one affine lattice-to-pixel model so that a dot off the lattice
//! (dirt, a noise blob) or a wrong step cannot keep an index. The integer offset on the
//! board is chosen later, from the hint (see `super::choose_offset`).

use super::detect::{median, SpatialGrid};

/// Two lattice basis vectors in pixels: `u` is the one nearest image +x, `v` the one
/// nearest image +y.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Lattice {
    pub u: [f64; 2],
    pub v: [f64; 2],
    /// Angle of `u` from image +x, radians, in image coordinates (y down).
    pub theta: f64,
}

/// Affine model `pixel = t + a U + b V` of lattice index (a, b).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Affine {
    pub t: [f64; 2],
    pub u: [f64; 2],
    pub v: [f64; 2],
}

impl Affine {
    /// Real lattice coordinates of a pixel position.
    pub(crate) fn inverse(&self, p: [f64; 2]) -> Option<[f64; 2]> {
        let det = self.u[0] * self.v[1] - self.u[1] * self.v[0];
        if det.abs() < 1e-12 {
            return None;
        }
        let d = [p[0] - self.t[0], p[1] - self.t[1]];
        Some([
            (d[0] * self.v[1] - d[1] * self.v[0]) / det,
            (self.u[0] * d[1] - self.u[1] * d[0]) / det,
        ])
    }

    fn apply(&self, a: f64, b: f64) -> [f64; 2] {
        [
            self.t[0] + a * self.u[0] + b * self.v[0],
            self.t[1] + a * self.u[1] + b * self.v[1],
        ]
    }
}

/// Neighbour lists shared by lattice estimation and indexing.
pub(crate) struct Neighbours {
    pub lists: Vec<Vec<(f64, usize)>>,
}

pub(crate) fn neighbours(pts: &[[f64; 2]], cell: f64) -> Neighbours {
    let grid = SpatialGrid::new(pts, cell);
    Neighbours {
        lists: (0..pts.len())
            .map(|i| grid.knn(pts, i, 8, f64::MAX))
            .collect(),
    }
}

/// Estimate the lattice basis. Err explains why the dots do not form a square grid.
pub(crate) fn estimate_lattice(pts: &[[f64; 2]], nb: &Neighbours) -> Result<Lattice, String> {
    let mut first: Vec<f64> = nb
        .lists
        .iter()
        .filter_map(|l| l.first().map(|e| e.0))
        .collect();
    let nn = median(&mut first).ok_or_else(|| "fewer than two dots".to_string())?;
    // Axis neighbours are at one pitch, diagonal ones at 1.41 pitch.
    let reach = 1.25 * nn;
    let mut vecs: Vec<[f64; 2]> = Vec::new();
    let (mut c4, mut s4) = (0.0, 0.0);
    for (i, l) in nb.lists.iter().enumerate() {
        for &(d, j) in l {
            if d <= reach && d > 0.0 {
                let dv = [pts[j][0] - pts[i][0], pts[j][1] - pts[i][1]];
                let phi = dv[1].atan2(dv[0]);
                c4 += (4.0 * phi).cos();
                s4 += (4.0 * phi).sin();
                vecs.push(dv);
            }
        }
    }
    if vecs.len() < 4 {
        return Err(format!(
            "only {} neighbour pairs among {} dots",
            vecs.len() / 2,
            pts.len()
        ));
    }
    // The square lattice is 90° symmetric: average 4φ to get its orientation.
    let coherence = (c4 * c4 + s4 * s4).sqrt() / vecs.len() as f64;
    if coherence < 0.7 {
        return Err(format!(
            "the {} dots do not form a square grid (neighbour directions agree only {:.0} %)",
            pts.len(),
            coherence * 100.0
        ));
    }
    let theta = s4.atan2(c4) / 4.0;
    let (u0, v0) = ([theta.cos(), theta.sin()], [-theta.sin(), theta.cos()]);
    let (mut su, mut sv, mut nu, mut nv) = ([0.0; 2], [0.0; 2], 0.0, 0.0);
    for d in &vecs {
        let pu = d[0] * u0[0] + d[1] * u0[1];
        let pv = d[0] * v0[0] + d[1] * v0[1];
        if pu.abs() >= pv.abs() {
            let sg = pu.signum();
            su = [su[0] + sg * d[0], su[1] + sg * d[1]];
            nu += 1.0;
        } else {
            let sg = pv.signum();
            sv = [sv[0] + sg * d[0], sv[1] + sg * d[1]];
            nv += 1.0;
        }
    }
    if nu < 1.0 || nv < 1.0 {
        return Err(format!("the {} dots form a line, not a grid", pts.len()));
    }
    let u = [su[0] / nu, su[1] / nu];
    let v = [sv[0] / nv, sv[1] / nv];
    let (lu, lv) = (u[0].hypot(u[1]), v[0].hypot(v[1]));
    if (lu / lv - 1.0).abs() > 0.15 {
        return Err(format!(
            "the dot spacing differs between the two grid directions ({lu:.1} px and {lv:.1} px): not a square grid"
        ));
    }
    Ok(Lattice { u, v, theta })
}

/// Dots tried as the start of the indexing, nearest the centre first.
const MAX_STARTS: usize = 8;

/// Lattice indices grown from `start` (index (0, 0)) through neighbour steps of up to
/// two pitches; a dot reached with two different indices gets none.
fn grow(pts: &[[f64; 2]], nb: &Neighbours, lat: &Lattice, start: usize) -> Vec<Option<[i64; 2]>> {
    let n = pts.len();
    let aff0 = Affine {
        t: pts[start],
        u: lat.u,
        v: lat.v,
    };
    let mut idx: Vec<Option<[i64; 2]>> = vec![None; n];
    let mut conflict = vec![false; n];
    idx[start] = Some([0, 0]);
    let mut queue = std::collections::VecDeque::from([start]);
    while let Some(i) = queue.pop_front() {
        let Some(ii) = idx[i] else { continue };
        for &(_, j) in &nb.lists[i] {
            let rel = Affine { t: pts[i], ..aff0 };
            let Some(ab) = rel.inverse(pts[j]) else {
                continue;
            };
            let (ra, rb) = (ab[0].round(), ab[1].round());
            // Steps of up to two pitches (so a missing dot does not cut the growth),
            // landing within 0.3 pitch of a lattice node.
            if (ab[0] - ra).abs() > 0.3
                || (ab[1] - rb).abs() > 0.3
                || ra.abs() > 2.0
                || rb.abs() > 2.0
            {
                continue;
            }
            let want = [ii[0] + ra as i64, ii[1] + rb as i64];
            match idx[j] {
                None => {
                    idx[j] = Some(want);
                    queue.push_back(j);
                }
                Some(have) if have != want => conflict[j] = true,
                _ => {}
            }
        }
    }
    for k in 0..n {
        if conflict[k] {
            idx[k] = None;
        }
    }
    idx
}

/// Lattice index of every dot (None when not on the lattice), relative to the start dot
/// (index (0, 0): the dot nearest `centre` from which the lattice grows), plus the
/// affine lattice model fitted to them.
pub(crate) fn index_dots(
    pts: &[[f64; 2]],
    nb: &Neighbours,
    lat: &Lattice,
    centre: [f64; 2],
) -> Option<(Vec<Option<[i64; 2]>>, Affine)> {
    let n = pts.len();
    // The growth starts at the dot nearest the centre; when that is no lattice dot (a
    // dirt blob between dots reaches none of its neighbours a whole step away, issue
    // 38), at the next nearest, keeping the growth that reached the most dots.
    let mut order: Vec<usize> = (0..n).collect();
    let dist = |k: usize| (pts[k][0] - centre[0]).powi(2) + (pts[k][1] - centre[1]).powi(2);
    order.sort_by(|&a, &b| dist(a).total_cmp(&dist(b)));
    let mut idx: Vec<Option<[i64; 2]>> = Vec::new();
    let mut reached = 0;
    for &start in order.iter().take(MAX_STARTS) {
        let grown = grow(pts, nb, lat, start);
        let count = grown.iter().filter(|i| i.is_some()).count();
        if count > reached {
            (idx, reached) = (grown, count);
        }
        if 2 * reached >= n {
            break;
        }
    }
    if idx.is_empty() {
        return None;
    }

    // One affine model for all indexed dots; a dot whose position does not round back
    // to its own index is not on the lattice. Two passes: the second without the
    // rejected dots.
    for _ in 0..2 {
        let aff = fit_affine(pts, &idx)?;
        let tol = 0.25;
        for k in 0..n {
            if let Some(ab) = idx[k] {
                let q = aff.inverse(pts[k])?;
                if (q[0] - ab[0] as f64).abs() > tol || (q[1] - ab[1] as f64).abs() > tol {
                    idx[k] = None;
                }
            }
        }
    }
    // Two dots on one index: neither can be trusted.
    let mut seen: std::collections::HashMap<[i64; 2], usize> = std::collections::HashMap::new();
    let mut dup = vec![false; n];
    for k in 0..n {
        if let Some(ab) = idx[k] {
            if let Some(&other) = seen.get(&ab) {
                dup[k] = true;
                dup[other] = true;
            } else {
                seen.insert(ab, k);
            }
        }
    }
    for k in 0..n {
        if dup[k] {
            idx[k] = None;
        }
    }
    let aff = fit_affine(pts, &idx)?;
    Some((idx, aff))
}

/// Least-squares affine lattice model over the indexed dots.
fn fit_affine(pts: &[[f64; 2]], idx: &[Option<[i64; 2]>]) -> Option<Affine> {
    let mut ata = nalgebra::Matrix3::<f64>::zeros();
    let mut atx = nalgebra::Vector3::<f64>::zeros();
    let mut aty = nalgebra::Vector3::<f64>::zeros();
    let mut count = 0;
    for (p, ab) in pts.iter().zip(idx) {
        if let Some(ab) = ab {
            let r = nalgebra::Vector3::new(1.0, ab[0] as f64, ab[1] as f64);
            ata += r * r.transpose();
            atx += r * p[0];
            aty += r * p[1];
            count += 1;
        }
    }
    if count < 3 {
        return None;
    }
    let inv = ata.try_inverse()?;
    let cx = inv * atx;
    let cy = inv * aty;
    let aff = Affine {
        t: [cx[0], cy[0]],
        u: [cx[1], cy[1]],
        v: [cx[2], cy[2]],
    };
    // Degenerate (all dots on one line) shows up as a vanishing determinant.
    aff.inverse(aff.apply(0.0, 0.0))?;
    Some(aff)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A rotated, slightly distorted lattice with holes and strays.
    fn scene() -> (Vec<[f64; 2]>, Vec<Option<[i64; 2]>>) {
        let (s, t) = (125.0, 3f64.to_radians());
        let mut pts = Vec::new();
        let mut truth = Vec::new();
        for b in -4..=4 {
            for a in -5..=5 {
                if (a, b) == (2, 1) || (a, b) == (-3, -2) {
                    continue; // missing dots
                }
                let (x, y) = (a as f64 * s, b as f64 * s);
                let f = 1.0 + 2e-9 * (x * x + y * y);
                pts.push([
                    640.0 + 30.0 + f * (t.cos() * x - t.sin() * y),
                    512.0 - 20.0 + f * (t.sin() * x + t.cos() * y),
                ]);
                truth.push(Some([a, b]));
            }
        }
        // Strays between lattice nodes.
        pts.push([640.0 + 30.0 + 0.5 * s, 512.0 - 20.0 + 0.45 * s]);
        truth.push(None);
        pts.push([100.0, 980.0]);
        truth.push(None);
        (pts, truth)
    }

    #[test]
    fn indexes_a_rotated_lattice_with_holes_and_rejects_strays() {
        let (pts, truth) = scene();
        let nb = neighbours(&pts, 250.0);
        let lat = estimate_lattice(&pts, &nb).unwrap();
        assert!((lat.theta.to_degrees() - 3.0).abs() < 0.1, "{lat:?}");
        let (idx, aff) = index_dots(&pts, &nb, &lat, [639.5, 511.5]).unwrap();
        // Index (0, 0) is the dot nearest the centre; compare up to that offset.
        let r = truth[idx.iter().position(|i| *i == Some([0, 0])).unwrap()].unwrap();
        for (got, want) in idx.iter().zip(&truth) {
            assert_eq!(*got, want.map(|w| [w[0] - r[0], w[1] - r[1]]));
        }
        let c = aff.inverse([639.5, 511.5]).unwrap();
        assert!(
            (c[0] + r[0] as f64 + 0.24).abs() < 0.02 && (c[1] + r[1] as f64 - 0.16).abs() < 0.02,
            "{c:?}"
        );
    }

    #[test]
    fn refuses_dots_that_are_not_a_square_grid() {
        let pts: Vec<[f64; 2]> = (0..40)
            .map(|k| [(k * 37 % 400) as f64 * 3.1, (k * 91 % 300) as f64 * 2.7])
            .collect();
        let nb = neighbours(&pts, 100.0);
        assert!(estimate_lattice(&pts, &nb).is_err());
        let stretched: Vec<[f64; 2]> = (0..30)
            .map(|k| [(k % 6) as f64 * 100.0, (k / 6) as f64 * 120.0])
            .collect();
        let e = estimate_lattice(&stretched, &neighbours(&stretched, 200.0)).unwrap_err();
        assert!(e.contains("spacing differs"), "{e}");
    }
}

//! Arcs and splines turned into chords no farther than a tolerance from the curve.

use crate::model::Point;

/// No curve is cut into more chords than this (a guard against absurd radii or
/// tolerances in outside input).
const MAX_CHORDS: usize = 200_000;

/// Chords of an arc of centre `c`, radius `r`, from angle `start` sweeping `sweep`
/// (radians, positive counter-clockwise). Returns the points after the start point, up
/// to and including the end point. The chord count is the smallest `n` with
/// `r (1 - cos(sweep / 2n)) <= tol` (the sagitta of each chord within the tolerance).
///
/// Example: r = 10 mm, a quarter turn, tol = 0.01 mm: the largest chord angle is
/// 2 acos(1 - 0.001) = 0.0894 rad, so n = ceil(1.5708 / 0.0894) = 18 chords.
pub fn arc_points(
    c: Point,
    r: f64,
    start: f64,
    sweep: f64,
    tol: f64,
) -> Result<Vec<Point>, String> {
    if !(r > 0.0) || !r.is_finite() || !sweep.is_finite() || !start.is_finite() {
        return Err(format!(
            "arc of radius {r} and sweep {sweep} rad is not drawable"
        ));
    }
    let max_angle = if tol >= r {
        std::f64::consts::FRAC_PI_2
    } else {
        2.0 * (1.0 - tol / r).acos()
    };
    let n = (sweep.abs() / max_angle).ceil().max(1.0);
    if n > MAX_CHORDS as f64 {
        return Err(format!(
            "arc of radius {r} mm needs more than {MAX_CHORDS} chords at {tol} mm"
        ));
    }
    let n = n as usize;
    Ok((1..=n)
        .map(|i| {
            let a = start + sweep * i as f64 / n as f64;
            [c[0] + r * a.cos(), c[1] + r * a.sin()]
        })
        .collect())
}

/// Chords of a polyline segment from `p0` to `p1` with DXF bulge `b` (the tangent of a
/// quarter of the included angle, positive counter-clockwise). Returns the points after
/// `p0`, ending with `p1` exactly. A bulge of 1 is a half circle: from (0,0) to (2,0) it
/// passes through (1,-1) (counter-clockwise from p0 to p1 bends to the right of the chord).
pub fn bulge_points(p0: Point, p1: Point, b: f64, tol: f64) -> Result<Vec<Point>, String> {
    let chord = ((p1[0] - p0[0]).powi(2) + (p1[1] - p0[1]).powi(2)).sqrt();
    if b == 0.0 || chord == 0.0 {
        return Ok(vec![p1]);
    }
    if !b.is_finite() {
        return Err(format!("bulge {b} is not a number"));
    }
    let sweep = 4.0 * b.atan();
    let r = chord / (2.0 * (sweep / 2.0).sin().abs());
    // Centre: from the chord's midpoint, along the chord's left normal by the signed
    // distance r cos(sweep/2) (sagitta side opposite the bulge's sign).
    let mid = [(p0[0] + p1[0]) / 2.0, (p0[1] + p1[1]) / 2.0];
    let n = [-(p1[1] - p0[1]) / chord, (p1[0] - p0[0]) / chord];
    let h = r * (sweep / 2.0).cos() * sweep.signum();
    let c = [mid[0] + n[0] * h, mid[1] + n[1] * h];
    let start = (p0[1] - c[1]).atan2(p0[0] - c[0]);
    let mut pts = arc_points(c, r, start, sweep, tol)?;
    if let Some(last) = pts.last_mut() {
        *last = p1;
    }
    Ok(pts)
}

/// Point of a NURBS curve at parameter `u` (de Boor's algorithm on homogeneous points).
fn nurbs_at(degree: usize, knots: &[f64], ctrl: &[[f64; 3]], u: f64) -> Point {
    let n = ctrl.len();
    // The span k with knots[k] <= u < knots[k+1], inside [degree, n-1].
    let mut k = degree;
    while k + 1 < n && knots[k + 1] <= u {
        k += 1;
    }
    let mut d: Vec<[f64; 3]> = (0..=degree).map(|j| ctrl[j + k - degree]).collect();
    for r in 1..=degree {
        for j in (r..=degree).rev() {
            let i = j + k - degree;
            let den = knots[i + degree + 1 - r] - knots[i];
            let a = if den == 0.0 {
                0.0
            } else {
                (u - knots[i]) / den
            };
            for c in 0..3 {
                d[j][c] = (1.0 - a) * d[j - 1][c] + a * d[j][c];
            }
        }
    }
    let w = d[degree][2];
    [d[degree][0] / w, d[degree][1] / w]
}

fn deviation(a: Point, b: Point, p: Point) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len = (dx * dx + dy * dy).sqrt();
    if len == 0.0 {
        return ((p[0] - a[0]).powi(2) + (p[1] - a[1]).powi(2)).sqrt();
    }
    ((p[0] - a[0]) * dy - (p[1] - a[1]) * dx).abs() / len
}

/// Points of a (rational) B-spline of `degree` with `knots`, control points `ctrl` and
/// `weights` (empty = all 1), from its first to its last point. Each knot span is cut in
/// 4, then every piece is halved while the curve's points at 1/4, 1/2 and 3/4 of it lie
/// farther than `tol` from its chord (at most 2^16 pieces per span).
pub fn nurbs_points(
    degree: usize,
    knots: &[f64],
    ctrl: &[Point],
    weights: &[f64],
    tol: f64,
) -> Result<Vec<Point>, String> {
    let n = ctrl.len();
    if degree < 1 || n < degree + 1 {
        return Err(format!("spline of degree {degree} has {n} control points"));
    }
    if knots.len() != n + degree + 1 {
        return Err(format!(
            "spline of degree {degree} with {n} control points needs {} knots, has {}",
            n + degree + 1,
            knots.len()
        ));
    }
    if knots.windows(2).any(|w| !(w[1] >= w[0])) || knots.iter().any(|k| !k.is_finite()) {
        return Err("spline knots are not a non-decreasing sequence of numbers".into());
    }
    if !weights.is_empty()
        && (weights.len() != n || weights.iter().any(|w| !(*w > 0.0) || !w.is_finite()))
    {
        return Err("spline weights must be one positive number per control point".into());
    }
    let h: Vec<[f64; 3]> = ctrl
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let w = weights.get(i).copied().unwrap_or(1.0);
            [p[0] * w, p[1] * w, w]
        })
        .collect();
    let (u0, u1) = (knots[degree], knots[n]);
    if !(u1 > u0) {
        return Err("spline has an empty parameter range".into());
    }
    let mut pts = vec![nurbs_at(degree, knots, &h, u0)];
    let mut chords = 0usize;
    for s in degree..n {
        let (a, b) = (knots[s], knots[s + 1]);
        if !(b > a) {
            continue;
        }
        for q in 0..4 {
            let (ua, ub) = (
                a + (b - a) * q as f64 / 4.0,
                a + (b - a) * (q + 1) as f64 / 4.0,
            );
            // At u = knots[n] the evaluation stays in the last span: the curve's end.
            let pb = nurbs_at(degree, knots, &h, ub);
            subdivide(
                degree,
                knots,
                &h,
                (ua, *pts.last().unwrap_or(&pb)),
                (ub, pb),
                tol,
                0,
                &mut pts,
                &mut chords,
            )?;
        }
    }
    Ok(pts)
}

#[allow(clippy::too_many_arguments)]
fn subdivide(
    degree: usize,
    knots: &[f64],
    h: &[[f64; 3]],
    (ua, pa): (f64, Point),
    (ub, pb): (f64, Point),
    tol: f64,
    depth: u32,
    out: &mut Vec<Point>,
    chords: &mut usize,
) -> Result<(), String> {
    let probe = |t: f64| nurbs_at(degree, knots, h, ua + (ub - ua) * t);
    let mid = probe(0.5);
    let far = [probe(0.25), mid, probe(0.75)]
        .iter()
        .any(|p| deviation(pa, pb, *p) > tol);
    if far && depth < 16 {
        let um = (ua + ub) / 2.0;
        subdivide(
            degree,
            knots,
            h,
            (ua, pa),
            (um, mid),
            tol,
            depth + 1,
            out,
            chords,
        )?;
        subdivide(
            degree,
            knots,
            h,
            (um, mid),
            (ub, pb),
            tol,
            depth + 1,
            out,
            chords,
        )
    } else {
        *chords += 1;
        if *chords > MAX_CHORDS {
            return Err(format!(
                "spline needs more than {MAX_CHORDS} chords at {tol} mm"
            ));
        }
        out.push(pb);
        Ok(())
    }
}

//! Contribution analysis: each of the 21 errors' share of the volumetric error over the
//! working volume (first-order terms, which add up exactly to the first-order error), and
//! the volumetric error map over a grid, with plots drawn through the `plot` crate.

use crate::{Model, VolError, NAMES};
use plot::plotters::coord::Shift;
use plot::plotters::prelude::*;
use plot::Chart;

/// One error's share over the grid: the largest and the RMS length of its term (µm).
#[derive(Debug, Clone, PartialEq)]
pub struct Contribution {
    pub name: &'static str,
    pub max_um: f64,
    pub rms_um: f64,
}

/// The grid points: `n` per axis over each measured travel (n >= 2).
pub fn grid(model: &Model, n: usize) -> Vec<[f64; 3]> {
    let n = n.max(2);
    let t = model.travel();
    let at = |a: usize, i: usize| t[a].0 + (t[a].1 - t[a].0) * i as f64 / (n - 1) as f64;
    let mut out = Vec::with_capacity(n * n * n);
    for i in 0..n {
        for j in 0..n {
            for k in 0..n {
                out.push([at(0, i), at(1, j), at(2, k)]);
            }
        }
    }
    out
}

/// The 21 contributions over an `n`³ grid, ranked by RMS (largest first); the total
/// (the first-order volumetric error) is returned alongside as (max, RMS) µm.
pub fn contributions(model: &Model, n: usize) -> Result<(Vec<Contribution>, f64, f64), VolError> {
    let pts = grid(model, n);
    let mut max = [0.0f64; 21];
    let mut ss = [0.0f64; 21];
    let (mut tmax, mut tss) = (0.0f64, 0.0);
    for q in &pts {
        let terms = model.terms(*q)?;
        let mut sum = [0.0; 3];
        for (k, v) in terms.iter().enumerate() {
            let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt() * 1e3;
            max[k] = max[k].max(len);
            ss[k] += len * len;
            for c in 0..3 {
                sum[c] += v[c];
            }
        }
        let len = (sum[0] * sum[0] + sum[1] * sum[1] + sum[2] * sum[2]).sqrt() * 1e3;
        tmax = tmax.max(len);
        tss += len * len;
    }
    let count = pts.len() as f64;
    let mut out: Vec<Contribution> = (0..21)
        .map(|k| Contribution {
            name: NAMES[k],
            max_um: max[k],
            rms_um: (ss[k] / count).sqrt(),
        })
        .collect();
    out.sort_by(|a, b| b.rms_um.total_cmp(&a.rms_um));
    Ok((out, tmax, (tss / count).sqrt()))
}

/// Ranked bars: RMS and max of each error's contribution.
pub struct ContributionChart<'a>(pub &'a [Contribution]);

impl Chart for ContributionChart<'_> {
    fn draw<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        area.fill(&WHITE)?;
        let n = self.0.len();
        let top = self.0.iter().map(|c| c.max_um).fold(1e-9, f64::max) * 1.1;
        let mut chart = ChartBuilder::on(area)
            .caption(
                "Contribution of each error (max and RMS over the volume)",
                (plot::FONT, 18),
            )
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(plot::safe_range(0.0, top, 1e-9), -0.5..n as f64 - 0.5)?;
        let names: Vec<&str> = self.0.iter().map(|c| c.name).collect();
        chart
            .configure_mesh()
            .disable_y_mesh()
            .y_labels(n)
            .y_label_formatter(&|v| {
                let i = n as f64 - 1.0 - v.round();
                if i >= 0.0 && (i as usize) < n && (v - v.round()).abs() < 0.01 {
                    names[i as usize].to_string()
                } else {
                    String::new()
                }
            })
            .x_desc("µm")
            .label_style((plot::FONT, 12))
            .draw()?;
        chart
            .draw_series(self.0.iter().enumerate().map(|(i, c)| {
                let y = (n - 1 - i) as f64;
                Rectangle::new(
                    [(0.0, y - 0.35), (c.max_um, y + 0.35)],
                    RGBColor(180, 200, 230).filled(),
                )
            }))?
            .label("max")
            .legend(|(x, y)| {
                Rectangle::new(
                    [(x, y - 5), (x + 10, y + 5)],
                    RGBColor(180, 200, 230).filled(),
                )
            });
        chart
            .draw_series(self.0.iter().enumerate().map(|(i, c)| {
                let y = (n - 1 - i) as f64;
                Rectangle::new(
                    [(0.0, y - 0.2), (c.rms_um, y + 0.2)],
                    RGBColor(30, 80, 160).filled(),
                )
            }))?
            .label("RMS")
            .legend(|(x, y)| {
                Rectangle::new(
                    [(x, y - 5), (x + 10, y + 5)],
                    RGBColor(30, 80, 160).filled(),
                )
            });
        chart
            .configure_series_labels()
            .background_style(WHITE)
            .border_style(BLACK)
            .label_font((plot::FONT, 12))
            .draw()?;
        Ok(())
    }
}

/// The plane of a map: which two axes vary, the third held at `at_mm`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Plane {
    Xy,
    Xz,
    Yz,
}

impl Plane {
    pub fn axes(self) -> (usize, usize, usize) {
        match self {
            Plane::Xy => (0, 1, 2),
            Plane::Xz => (0, 2, 1),
            Plane::Yz => (1, 2, 0),
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            Plane::Xy => "XY",
            Plane::Xz => "XZ",
            Plane::Yz => "YZ",
        }
    }
}

/// The volumetric error over one plane: grid cells with their error vector (µm).
pub struct PlaneMap {
    pub plane: Plane,
    pub at_mm: f64,
    pub u: Vec<f64>,
    pub v: Vec<f64>,
    /// `errors[i][j]` at (u[i], v[j]): (ex, ey, ez) µm.
    pub errors: Vec<Vec<[f64; 3]>>,
}

/// The map of `plane` through the middle of the third axis, `n` x `n` points, exact.
pub fn plane_map(model: &Model, plane: Plane, n: usize) -> Result<PlaneMap, VolError> {
    let n = n.max(2);
    let t = model.travel();
    let (a, b, c) = plane.axes();
    let lin = |ax: usize| -> Vec<f64> {
        (0..n)
            .map(|i| t[ax].0 + (t[ax].1 - t[ax].0) * i as f64 / (n - 1) as f64)
            .collect()
    };
    let (u, v) = (lin(a), lin(b));
    let at_mm = 0.5 * (t[c].0 + t[c].1);
    let mut errors = Vec::with_capacity(n);
    for &pu in &u {
        let mut row = Vec::with_capacity(n);
        for &pv in &v {
            let mut q = [0.0; 3];
            q[a] = pu;
            q[b] = pv;
            q[c] = at_mm;
            let e = model.error_exact(q)?;
            row.push([e[0] * 1e3, e[1] * 1e3, e[2] * 1e3]);
        }
        errors.push(row);
    }
    Ok(PlaneMap {
        plane,
        at_mm,
        u,
        v,
        errors,
    })
}

impl Chart for PlaneMap {
    fn draw<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        area.fill(&WHITE)?;
        let (a, b, c) = self.plane.axes();
        let names = ['X', 'Y', 'Z'];
        let len = |e: &[f64; 3]| (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt();
        let top = self.errors.iter().flatten().map(len).fold(1e-9, f64::max);
        let (u0, u1) = (self.u[0], self.u[self.u.len() - 1]);
        let (v0, v1) = (self.v[0], self.v[self.v.len() - 1]);
        let mut chart = ChartBuilder::on(area)
            .caption(
                format!(
                    "Volumetric error, {} plane at {} = {:.0} mm (colour |e|, max {:.1} µm; arrows in-plane)",
                    self.plane.name(),
                    names[c],
                    self.at_mm,
                    top
                ),
                (plot::FONT, 15),
            )
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(45)
            .build_cartesian_2d(
                plot::safe_range(u0, u1, 1e-6),
                plot::safe_range(v0, v1, 1e-6),
            )?;
        chart
            .configure_mesh()
            .x_desc(format!("{} mm", names[a]))
            .y_desc(format!("{} mm", names[b]))
            .label_style((plot::FONT, 12))
            .draw()?;
        let du = (u1 - u0) / (self.u.len() - 1) as f64;
        let dv = (v1 - v0) / (self.v.len() - 1) as f64;
        chart.draw_series(self.u.iter().enumerate().flat_map(|(i, &pu)| {
            self.v.iter().enumerate().map(move |(j, &pv)| {
                let t = len(&self.errors[i][j]) / top;
                let colour = RGBColor(
                    (255.0 * t) as u8,
                    (80.0 + 100.0 * (1.0 - t)) as u8,
                    (255.0 * (1.0 - t)) as u8,
                );
                Rectangle::new(
                    [
                        ((pu - du / 2.0).max(u0), (pv - dv / 2.0).max(v0)),
                        ((pu + du / 2.0).min(u1), (pv + dv / 2.0).min(v1)),
                    ],
                    colour.filled(),
                )
            })
        }))?;
        // Arrows of the in-plane error, scaled so the largest spans 0.8 cell.
        let scale = 0.8 * du.min(dv) / top;
        chart.draw_series(self.u.iter().enumerate().flat_map(|(i, &pu)| {
            self.v.iter().enumerate().map(move |(j, &pv)| {
                let e = self.errors[i][j];
                PathElement::new(
                    vec![(pu, pv), (pu + e[a] * scale, pv + e[b] * scale)],
                    BLACK.stroke_width(1),
                )
            })
        }))?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tests::worked_example;
    use protocol::volumetric::Structure;

    #[test]
    fn a_single_error_owns_the_whole_error() {
        // Only E_XX (linear 0..10 µm over X): its contribution is the total.
        let mut m = Model::zero(Structure::Xyfz, [500.0, 400.0, 400.0]);
        m.file.tables[0].errors[1][0] = 0.010;
        let (c, tmax, trms) = contributions(&m, 5).unwrap();
        assert_eq!(c[0].name, "E_XX");
        assert!((c[0].max_um - 10.0).abs() < 1e-9);
        // RMS of 0, 2.5, 5, 7.5, 10 µm.
        let rms = ((0.0 + 6.25 + 25.0 + 56.25 + 100.0) / 5.0f64).sqrt();
        assert!((c[0].rms_um - rms).abs() < 1e-9 && (trms - rms).abs() < 1e-9);
        assert!((tmax - 10.0).abs() < 1e-9);
        assert!(c[1..].iter().all(|x| x.max_um == 0.0));
    }

    #[test]
    fn ranking_and_plots_render() {
        let m = worked_example(Structure::Xyfz);
        let (c, _, _) = contributions(&m, 5).unwrap();
        assert!(c.windows(2).all(|w| w[0].rms_um >= w[1].rms_um));
        let svg = plot::render_svg(&ContributionChart(&c), 800, 600).unwrap();
        assert!(svg.contains("E_XX"));
        let map = plane_map(&m, Plane::Xy, 6).unwrap();
        // At the centre Z = 200: the X axis's positioning reaches -10 µm at X = 500.
        assert!(
            (map.errors[5][0][0] + 10.0).abs() < 0.5,
            "{:?}",
            map.errors[5][0]
        );
        let svg = plot::render_svg(&map, 600, 500).unwrap();
        assert!(svg.contains("XY plane"));
    }
}

//! The measured centres and the fitted circles, drawn with the `plot` crate: the C sweep
//! seen from above (X, Y) and the A sweep seen along X (Y, Z). Each circle is drawn
//! with its radial misfit magnified, so micrometre residuals are visible on a circle of
//! tens of millimetres.

use crate::centres::{Axis, CentreRow};
use crate::identify::{CircleFit, Identification};
use nalgebra::Vector3;
use plot::plotters::coord::Shift;
use plot::plotters::prelude::*;

/// The chart: measured centres (dots) and fitted circles (lines) of both sweeps.
pub struct SweepChart<'a> {
    pub rows: &'a [CentreRow],
    pub identification: &'a Identification,
    /// How much the radial and out-of-plane misfits are magnified (1000: 1 um shows as
    /// 1 mm).
    pub magnification: f64,
}

fn circle_frame(f: &CircleFit) -> (Vector3<f64>, Vector3<f64>, Vector3<f64>) {
    let n = f.normal_v();
    let helper = if n.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let e1 = n.cross(&helper).normalize();
    let e2 = n.cross(&e1);
    (f.centre_v(), e1, e2)
}

impl SweepChart<'_> {
    /// A measured centre moved so its misfit from the circle is magnified.
    fn magnified(&self, f: &CircleFit, p: &Vector3<f64>) -> Vector3<f64> {
        let c = f.centre_v();
        let n = f.normal_v();
        let v = p - c;
        let h = v.dot(&n);
        let inplane = v - n * h;
        let r = inplane.norm();
        if r == 0.0 {
            return *p;
        }
        let radial = inplane / r * (f.radius_mm + (r - f.radius_mm) * self.magnification);
        c + radial + n * h * self.magnification
    }

    fn panel<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
        axis: Axis,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        // Which machine coordinates the panel shows.
        let (i, j, names) = match axis {
            Axis::C => (0, 1, ("X (mm)", "Y (mm)")),
            Axis::A => (1, 2, ("Y (mm)", "Z (mm)")),
        };
        let fits: Vec<&(Axis, u8, CircleFit)> = self
            .identification
            .circles
            .iter()
            .filter(|(a, _, _)| *a == axis)
            .collect();
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for (_, _, f) in &fits {
            let c = f.centre_v();
            for (k, idx) in [i, j].into_iter().enumerate() {
                lo[k] = lo[k].min(c[idx] - f.radius_mm * 1.15);
                hi[k] = hi[k].max(c[idx] + f.radius_mm * 1.15);
            }
        }
        if !lo.iter().chain(hi.iter()).all(|v| v.is_finite()) {
            lo = [-1.0, -1.0];
            hi = [1.0, 1.0];
        }
        let mut chart = ChartBuilder::on(area)
            .caption(
                format!(
                    "{axis} sweep: centres and fitted circles (misfit x{})",
                    self.magnification
                ),
                (plot::FONT, 15),
            )
            .margin(8)
            .x_label_area_size(32)
            .y_label_area_size(48)
            .build_cartesian_2d(
                plot::safe_range(lo[0], hi[0], 1e-6),
                plot::safe_range(lo[1], hi[1], 1e-6),
            )?;
        chart
            .configure_mesh()
            .x_desc(names.0)
            .y_desc(names.1)
            .label_style((plot::FONT, 11))
            .draw()?;
        let colours = [BLUE, RED];
        for (_, ball, f) in &fits {
            let colour = colours[(*ball as usize).saturating_sub(1).min(1)];
            let (c, e1, e2) = circle_frame(f);
            let curve: Vec<(f64, f64)> = (0..=360)
                .map(|d| {
                    let t = (d as f64).to_radians();
                    let p = c + (e1 * t.cos() + e2 * t.sin()) * f.radius_mm;
                    (p[i], p[j])
                })
                .collect();
            chart
                .draw_series(LineSeries::new(curve, colour.stroke_width(1)))?
                .label(format!(
                    "ball {ball}: r {:.3} mm, rms {:.2} um",
                    f.radius_mm,
                    f.rms_radial_mm.hypot(f.rms_plane_mm) * 1e3
                ))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], colour));
            let dots: Vec<(f64, f64)> = self
                .rows
                .iter()
                .filter(|r| r.axis == axis && r.ball == *ball)
                .map(|r| {
                    let p = self.magnified(f, &Vector3::new(r.x_mm, r.y_mm, r.z_mm));
                    (p[i], p[j])
                })
                .collect();
            chart.draw_series(dots.into_iter().map(|p| Circle::new(p, 3, colour.filled())))?;
        }
        chart
            .configure_series_labels()
            .label_font((plot::FONT, 11))
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
        Ok(())
    }
}

impl plot::Chart for SweepChart<'_> {
    fn draw<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        area.fill(&WHITE)?;
        let halves = area.split_evenly((1, 2));
        self.panel(&halves[0], Axis::C)?;
        self.panel(&halves[1], Axis::A)?;
        Ok(())
    }
}

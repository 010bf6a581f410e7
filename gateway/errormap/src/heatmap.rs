//! The error map as a heat map: each grid node's in-plane error (the mean of its two
//! approach directions) as a coloured cell, blue for none up to red for the largest.

use plot::plotters::coord::Shift;
use plot::plotters::prelude::*;
use plot::Chart;
use protocol::errormap::ErrorMap;

pub struct HeatMap<'a> {
    pub map: &'a ErrorMap,
    pub title: String,
}

impl HeatMap<'_> {
    /// |e| in um at grid node (i, j): the mean of the forward and reverse approach.
    pub fn error_um(&self, i: usize, j: usize) -> f64 {
        let g = &self.map.grid;
        let n = &g.nodes[j * g.xs.len() + i];
        let ex = (n.forward.ex_um.mean + n.reverse.ex_um.mean) / 2.0;
        let ey = (n.forward.ey_um.mean + n.reverse.ey_um.mean) / 2.0;
        ex.hypot(ey)
    }
}

impl Chart for HeatMap<'_> {
    fn draw<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        area.fill(&WHITE)?;
        let g = &self.map.grid;
        let (nx, ny) = (g.xs.len(), g.ys.len());
        if nx < 2 || ny < 2 || g.nodes.len() != nx * ny {
            return Ok(());
        }
        let top = (0..nx)
            .flat_map(|i| (0..ny).map(move |j| (i, j)))
            .map(|(i, j)| self.error_um(i, j))
            .filter(|e| e.is_finite())
            .fold(1e-9, f64::max);
        let (x0, x1) = (g.xs[0], g.xs[nx - 1]);
        let (y0, y1) = (g.ys[0], g.ys[ny - 1]);
        let mut chart = ChartBuilder::on(area)
            .caption(
                format!("{} (colour |e|, max {top:.2} µm)", self.title),
                (plot::FONT, 15),
            )
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(45)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        chart
            .configure_mesh()
            .x_desc("X mm")
            .y_desc("Y mm")
            .label_style((plot::FONT, 12))
            .draw()?;
        // Each node's cell reaches halfway to its neighbours.
        let edge = |v: &[f64], k: usize, lo: bool| -> f64 {
            if lo {
                if k == 0 {
                    v[0]
                } else {
                    (v[k - 1] + v[k]) / 2.0
                }
            } else if k + 1 == v.len() {
                v[k]
            } else {
                (v[k] + v[k + 1]) / 2.0
            }
        };
        chart.draw_series((0..nx).flat_map(|i| {
            (0..ny).map(move |j| {
                let e = self.error_um(i, j);
                let t = if e.is_finite() {
                    (e / top).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                let colour = RGBColor(
                    (255.0 * t) as u8,
                    (80.0 + 100.0 * (1.0 - t)) as u8,
                    (255.0 * (1.0 - t)) as u8,
                );
                Rectangle::new(
                    [
                        (edge(&g.xs, i, true), edge(&g.ys, j, true)),
                        (edge(&g.xs, i, false), edge(&g.ys, j, false)),
                    ],
                    colour.filled(),
                )
            })
        }))?;
        Ok(())
    }
}

//! The error map as a heat map: each grid node's in-plane error (the mean of its two
//! approach directions) as a coloured cell, blue for none up to red for the largest,
//! with the colour scale beside it in µm, and an arrow at each node showing the error's
//! direction (where the machine really went, relative to the target; the longest arrow
//! is the largest error).

use plot::plotters::coord::Shift;
use plot::plotters::prelude::*;
use plot::Chart;
use protocol::errormap::ErrorMap;

pub struct HeatMap<'a> {
    pub map: &'a ErrorMap,
    pub title: String,
}

impl HeatMap<'_> {
    /// The in-plane error (ex, ey) in um at grid node (i, j): the mean of the forward
    /// and reverse approach.
    pub fn error_xy_um(&self, i: usize, j: usize) -> (f64, f64) {
        let g = &self.map.grid;
        let n = &g.nodes[j * g.xs.len() + i];
        let ex = (n.forward.ex_um.mean + n.reverse.ex_um.mean) / 2.0;
        let ey = (n.forward.ey_um.mean + n.reverse.ey_um.mean) / 2.0;
        (ex, ey)
    }

    /// |e| in um at grid node (i, j).
    pub fn error_um(&self, i: usize, j: usize) -> f64 {
        let (ex, ey) = self.error_xy_um(i, j);
        ex.hypot(ey)
    }
}

/// The scale's colour at `t` in 0..=1 (blue, none, to red, the largest).
fn colour(t: f64) -> RGBColor {
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    RGBColor(
        (255.0 * t) as u8,
        (80.0 + 100.0 * (1.0 - t)) as u8,
        (255.0 * (1.0 - t)) as u8,
    )
}

/// The arrows' colour (near-black, told apart from the axes' black).
pub const ARROW: RGBColor = RGBColor(20, 20, 20);

/// Pixels kept on the right for the colour scale.
const SCALE_PX: u32 = 90;

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
        let (width, _) = area.dim_in_pixel();
        let (area, scale_area) = area.split_horizontally(width.saturating_sub(SCALE_PX));
        let top = (0..nx)
            .flat_map(|i| (0..ny).map(move |j| (i, j)))
            .map(|(i, j)| self.error_um(i, j))
            .filter(|e| e.is_finite())
            .fold(1e-9, f64::max);
        let (x0, x1) = (g.xs[0], g.xs[nx - 1]);
        let (y0, y1) = (g.ys[0], g.ys[ny - 1]);
        let mut chart = ChartBuilder::on(&area)
            .caption(
                format!("{} (colour |e|, arrows its direction)", self.title),
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
                Rectangle::new(
                    [
                        (edge(&g.xs, i, true), edge(&g.ys, j, true)),
                        (edge(&g.xs, i, false), edge(&g.ys, j, false)),
                    ],
                    colour(self.error_um(i, j) / top).filled(),
                )
            })
        }))?;
        // Arrows: the largest error is 80 % of the smallest grid step long.
        let step = |v: &[f64]| {
            v.windows(2)
                .map(|w| (w[1] - w[0]).abs())
                .fold(f64::INFINITY, f64::min)
        };
        let mm_per_um = 0.8 * step(&g.xs).min(step(&g.ys)) / top;
        let arrows = (0..nx).flat_map(|i| (0..ny).map(move |j| (i, j)));
        for (i, j) in arrows {
            let (ex, ey) = self.error_xy_um(i, j);
            if !(ex.is_finite() && ey.is_finite()) || ex.hypot(ey) < 1e-3 * top {
                continue;
            }
            let (x, y) = (g.xs[i], g.ys[j]);
            let (dx, dy) = (ex * mm_per_um, ey * mm_per_um);
            let tip = (x + dx, y + dy);
            // A head of two strokes, a quarter of the arrow long, 25 degrees off.
            let head = |turn: f64| {
                let (c, s) = (turn.cos(), turn.sin());
                (
                    tip.0 - 0.25 * (c * dx - s * dy),
                    tip.1 - 0.25 * (s * dx + c * dy),
                )
            };
            let style = ARROW.stroke_width(1);
            chart.draw_series(std::iter::once(PathElement::new(vec![(x, y), tip], style)))?;
            chart.draw_series(std::iter::once(PathElement::new(
                vec![head(0.44), tip, head(-0.44)],
                style,
            )))?;
        }
        // The colour scale: 0 at the bottom to the largest error at the top, in µm.
        let mut scale = ChartBuilder::on(&scale_area)
            .margin_top(40)
            .margin_bottom(45)
            .margin_right(10)
            .y_label_area_size(50)
            .build_cartesian_2d(0.0..1.0, 0.0..top)?;
        scale
            .configure_mesh()
            .disable_x_mesh()
            .disable_x_axis()
            .y_desc("|e| µm")
            .y_labels(5)
            .label_style((plot::FONT, 11))
            .draw()?;
        let bands = 50;
        scale.draw_series((0..bands).map(|k| {
            let (lo, hi) = (k as f64 / bands as f64, (k + 1) as f64 / bands as f64);
            Rectangle::new(
                [(0.0, lo * top), (1.0, hi * top)],
                colour((lo + hi) / 2.0).filled(),
            )
        }))?;
        Ok(())
    }
}

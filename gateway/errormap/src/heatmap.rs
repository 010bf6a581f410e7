//! The error map as a heat map: each grid node's in-plane error (the mean of its two
//! approach directions) as a coloured cell, blue for none up to red for the largest,
//! with the colour scale beside it in µm, and an arrow at each node showing the error's
//! direction (where the machine really went, relative to the target; the longest arrow
//! is the largest error). The axes are machine positions (the commands, mm, as the map
//! holds them); each node's cell reaches halfway to its neighbours (as far past the
//! grid's edge nodes), and the longest arrow is 90 % of the smaller half step, so every
//! arrow stays in its node's cell, inside the plot; under the colour scale an arrow of a round length says how many µm an
//! arrow's length is, and the scale has its value written at both ends (0 and the
//! largest error).

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
        let y0 = g.ys[0];
        // Each node's cell reaches halfway to its neighbours, and as far past the edge
        // nodes; the largest error's arrow is 90 % of the smallest half step long, so
        // every arrow stays inside its cell.
        let edge = |v: &[f64], k: usize, lo: bool| -> f64 {
            let n = v.len();
            match (lo, k) {
                (true, 0) => v[0] - (v[1] - v[0]) / 2.0,
                (true, k) => (v[k - 1] + v[k]) / 2.0,
                (false, k) if k + 1 == n => v[k] + (v[k] - v[k - 1]) / 2.0,
                (false, k) => (v[k] + v[k + 1]) / 2.0,
            }
        };
        let step = |v: &[f64]| {
            v.windows(2)
                .map(|w| (w[1] - w[0]).abs())
                .fold(f64::INFINITY, f64::min)
        };
        let mm_per_um = 0.45 * step(&g.xs).min(step(&g.ys)) / top;
        let mut chart = ChartBuilder::on(&area)
            .caption(
                format!("{} (colour |e|, arrows its direction)", self.title),
                (plot::FONT, 15),
            )
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(55)
            .build_cartesian_2d(
                plot::safe_range(edge(&g.xs, 0, true), edge(&g.xs, nx - 1, false), 1e-6),
                plot::safe_range(edge(&g.ys, 0, true), edge(&g.ys, ny - 1, false), 1e-6),
            )?;
        chart
            .configure_mesh()
            .x_desc("X, machine position (mm)")
            .y_desc("Y, machine position (mm)")
            .label_style((plot::FONT, 12))
            .axis_desc_style((plot::FONT, 13))
            .draw()?;
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
        let arrows = (0..nx).flat_map(|i| (0..ny).map(move |j| (i, j)));
        for (i, j) in arrows {
            let (ex, ey) = self.error_xy_um(i, j);
            if !(ex.is_finite() && ey.is_finite()) || ex.hypot(ey) < 1e-3 * top {
                continue;
            }
            let (x, y) = (g.xs[i], g.ys[j]);
            let (dx, dy) = (ex * mm_per_um, ey * mm_per_um);
            for path in arrow((x, y), (dx, dy)) {
                chart.draw_series(std::iter::once(PathElement::new(
                    path,
                    ARROW.stroke_width(1),
                )))?;
            }
        }
        // The arrows' scale: a round length of error (1, 2 or 5 x 10^n µm) that fits
        // under the colour scale, drawn as the arrows are, with its value.
        let px_per_mm = {
            let (a, b) = (
                chart.backend_coord(&(x0, y0)),
                chart.backend_coord(&(x1, y0)),
            );
            f64::from(b.0 - a.0) / (x1 - x0)
        };
        let room_px = f64::from(SCALE_PX) - 30.0;
        let um_per_px = 1.0 / (mm_per_um * px_per_mm);
        let sample_um = round_down(top.min(room_px * um_per_px));
        let (_, scale_h) = scale_area.dim_in_pixel();
        let text = |size| TextStyle::from((plot::FONT, size).into_font());
        if sample_um.is_finite() && sample_um > 0.0 {
            let len_px = sample_um / um_per_px;
            let y = scale_h as f64 - 22.0;
            for path in arrow((8.0, y), (len_px, 0.0)) {
                let px: Vec<(i32, i32)> = path.iter().map(|p| (p.0 as i32, p.1 as i32)).collect();
                scale_area.draw(&PathElement::new(px, ARROW.stroke_width(1)))?;
            }
            scale_area.draw(&Text::new(
                format!("arrow {} µm", label(sample_um)),
                (4, (y + 6.0) as i32),
                text(11),
            ))?;
        }
        // The colour scale: 0 at the bottom to the largest error at the top, in µm,
        // written at both ends.
        let mut scale = ChartBuilder::on(&scale_area)
            .margin_top(40)
            .margin_bottom(70)
            .margin_right(45)
            .margin_left(10)
            .build_cartesian_2d(0.0..1.0, 0.0..top)?;
        let (bar_top, bar_bottom) = (
            scale.backend_coord(&(1.0, top)),
            scale.backend_coord(&(1.0, 0.0)),
        );
        let base = scale_area.get_base_pixel();
        for (at, value) in [(bar_top, top), (bar_bottom, 0.0)] {
            scale_area.draw(&Text::new(
                label(value),
                (at.0 - base.0 + 4, at.1 - base.1 - 6),
                text(11),
            ))?;
        }
        let bar_left = scale.backend_coord(&(0.0, top)).0;
        scale_area.draw(&Text::new(
            "|e|, µm",
            (bar_left - base.0, bar_top.1 - base.1 - 24),
            text(12),
        ))?;
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

/// An arrow from `from` by `by` (in the same units): its shaft, then a head of two
/// strokes a quarter of its length, 25 degrees off.
fn arrow(from: (f64, f64), by: (f64, f64)) -> [Vec<(f64, f64)>; 2] {
    let tip = (from.0 + by.0, from.1 + by.1);
    let head = |turn: f64| {
        let (c, s) = (f64::cos(turn), f64::sin(turn));
        (
            tip.0 - 0.25 * (c * by.0 - s * by.1),
            tip.1 - 0.25 * (s * by.0 + c * by.1),
        )
    };
    [vec![from, tip], vec![head(0.44), tip, head(-0.44)]]
}

/// The largest of 1, 2 or 5 x 10^n at most `v`.
fn round_down(v: f64) -> f64 {
    if !(v.is_finite() && v > 0.0) {
        return f64::NAN;
    }
    let unit = 10f64.powf(v.log10().floor());
    [5.0, 2.0, 1.0]
        .into_iter()
        .map(|m| m * unit)
        .find(|&r| r <= v)
        .unwrap_or(unit)
}

/// A value in µm as the scale writes it: 3 significant digits, no exponent, no
/// trailing zeros (`10`, `2.5`, `0.123`).
fn label(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return "0".into();
    }
    let digits = (2 - v.abs().log10().floor() as i32).clamp(0, 6) as usize;
    let text = format!("{v:.digits$}");
    if text.contains('.') {
        text.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        text
    }
}

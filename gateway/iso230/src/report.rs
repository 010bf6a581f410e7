//! Outputs of an evaluation: the result JSON (the standard's names), the plots (like the
//! standard's figures: the mean deviation per direction against the target position,
//! with its ±2s band), and a one-file HTML report with the plots inline as SVG.

use crate::{Evaluation, Uncertainty};
use plot::plotters::coord::Shift;
use plot::plotters::prelude::*;
use serde_json::{json, Value};

/// The result JSON: the axis figures under the standard's names (`A_um`, `B_um`, ...,
/// `M_um`), then one array per per-position figure, index k for the k-th target in
/// increasing order (`B_i_um` is the reversal value B_i, `R_i_um` the bidirectional
/// repeatability R_i).
pub fn result_json(e: &Evaluation, uncertainty: Option<&Uncertainty>) -> Value {
    let p = &e.positions;
    let col = |f: fn(&crate::PositionFigures) -> f64| p.iter().map(f).collect::<Vec<f64>>();
    let mut v = json!({
        "standard": "ISO 230-2",
        "axis": e.axis,
        "positions": p.len(),
        "position_index": p.iter().map(|q| q.position_index).collect::<Vec<_>>(),
        "target_mm": col(|q| q.target_mm),
        "runs_up": p.iter().map(|q| q.runs_up).collect::<Vec<_>>(),
        "runs_down": p.iter().map(|q| q.runs_down).collect::<Vec<_>>(),
        "mean_up_um": col(|q| q.mean_up_um),
        "mean_down_um": col(|q| q.mean_down_um),
        "mean_um": col(|q| q.mean_um),
        "s_up_um": col(|q| q.s_up_um),
        "s_down_um": col(|q| q.s_down_um),
        "B_i_um": col(|q| q.reversal_um),
        "R_up_i_um": col(|q| q.r_up_um),
        "R_down_i_um": col(|q| q.r_down_um),
        "R_i_um": col(|q| q.r_um),
        "uncertainty": uncertainty,
    });
    if let (Value::Object(o), Ok(Value::Object(f))) = (&mut v, serde_json::to_value(e.figures)) {
        o.extend(f);
    }
    v
}

/// One evaluated test drawn on a deviation chart.
pub struct Series<'a> {
    pub label: &'a str,
    pub evaluation: &'a Evaluation,
}

/// Mean deviation ↑ and ↓ against position, each with its x̄ ± 2s band (thin lines);
/// several tests overlaid (before/after) in their own colours. The legend is a strip
/// under the plot, never over the data.
pub struct DeviationChart<'a> {
    pub title: String,
    pub series: Vec<Series<'a>>,
}

const COLOURS: [(RGBColor, RGBColor); 3] = [
    (RGBColor(200, 30, 30), RGBColor(30, 60, 200)),
    (RGBColor(230, 140, 0), RGBColor(0, 150, 140)),
    (RGBColor(140, 0, 160), RGBColor(90, 90, 90)),
];

impl plot::Chart for DeviationChart<'_> {
    fn draw<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        area.fill(&WHITE)?;
        // The legend's strip: a row per test (its two directions), then the bands' row.
        let (_, height) = area.dim_in_pixel();
        let legend_h = LEGEND_ROW_PX * (self.series.len() as u32 + 1) + 8;
        let (area, legend) = area.split_vertically(height.saturating_sub(legend_h));
        let all = || self.series.iter().flat_map(|s| &s.evaluation.positions);
        let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        for q in all() {
            x0 = x0.min(q.target_mm);
            x1 = x1.max(q.target_mm);
            y0 = y0
                .min(q.mean_up_um - 2.0 * q.s_up_um)
                .min(q.mean_down_um - 2.0 * q.s_down_um);
            y1 = y1
                .max(q.mean_up_um + 2.0 * q.s_up_um)
                .max(q.mean_down_um + 2.0 * q.s_down_um);
        }
        if x0 > x1 {
            (x0, x1, y0, y1) = (0.0, 1.0, -1.0, 1.0);
        }
        // Clamped first: a deviation of 1e308 um made the padding infinite and the tick
        // code loop.
        let std::ops::Range { start: x0, end: x1 } = plot::safe_range(x0, x1, 0.0);
        let std::ops::Range { start: y0, end: y1 } = plot::safe_range(y0, y1, 0.0);
        let xpad = ((x1 - x0) * 0.03).max(0.5);
        let ypad = ((y1 - y0) * 0.1).max(0.5);
        let mut chart = ChartBuilder::on(&area)
            .caption(&self.title, (plot::FONT, 18))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(
                plot::safe_range(x0 - xpad, x1 + xpad, 1.0),
                plot::safe_range(y0 - ypad, y1 + ypad, 1.0),
            )?;
        chart
            .configure_mesh()
            .x_desc("target position, machine axis (mm)")
            .y_desc("positional deviation (µm)")
            .label_style((plot::FONT, 12))
            .axis_desc_style((plot::FONT, 14))
            .draw()?;
        for (k, s) in self.series.iter().enumerate() {
            let (c_up, c_down) = COLOURS[k % COLOURS.len()];
            let p = &s.evaluation.positions;
            type Pick = fn(&crate::PositionFigures) -> (f64, f64);
            let dirs: [(&str, RGBColor, Pick); 2] = [
                ("up (+)", c_up, |q| (q.mean_up_um, q.s_up_um)),
                ("down (-)", c_down, |q| (q.mean_down_um, q.s_down_um)),
            ];
            let row = LEGEND_ROW_PX as i32 * k as i32 + 4;
            for (d, (name, colour, pick)) in dirs.into_iter().enumerate() {
                let label = if s.label.is_empty() {
                    format!("mean {name}")
                } else {
                    format!("{}: mean {name}", s.label)
                };
                legend_entry(&legend, (70 + 260 * d as i32, row), colour, 2, &label)?;
                chart.draw_series(LineSeries::new(
                    p.iter().map(|q| (q.target_mm, pick(q).0)),
                    colour.stroke_width(2),
                ))?;
                chart.draw_series(
                    p.iter()
                        .map(|q| Circle::new((q.target_mm, pick(q).0), 3, colour.filled())),
                )?;
                for sign in [2.0, -2.0] {
                    chart.draw_series(LineSeries::new(
                        p.iter().map(|q| {
                            let (m, sd) = pick(q);
                            (q.target_mm, m + sign * sd)
                        }),
                        colour.mix(0.6).stroke_width(1),
                    ))?;
                }
            }
        }
        let row = LEGEND_ROW_PX as i32 * self.series.len() as i32 + 4;
        legend_entry(
            &legend,
            (70, row),
            RGBColor(90, 90, 90).mix(0.6),
            1,
            "thin lines: mean ± 2s (each direction, its colour)",
        )?;
        Ok(())
    }
}

/// Height of a legend row, px.
const LEGEND_ROW_PX: u32 = 18;

/// One legend entry at `at` (px in the legend's strip): a 20 px line sample and its text.
fn legend_entry<DB: DrawingBackend, C: Color>(
    legend: &DrawingArea<DB, Shift>,
    at: (i32, i32),
    colour: C,
    width: u32,
    text: &str,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let (x, y) = (at.0, at.1 + LEGEND_ROW_PX as i32 / 2);
    legend.draw(&PathElement::new(
        [(x, y), (x + 20, y)],
        colour.stroke_width(width),
    ))?;
    let style = TextStyle::from((plot::FONT, 12).into_font()).pos(
        plot::plotters::style::text_anchor::Pos::new(
            plot::plotters::style::text_anchor::HPos::Left,
            plot::plotters::style::text_anchor::VPos::Center,
        ),
    );
    legend.draw(&Text::new(text.to_string(), (x + 26, y), style))
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// One test in the report: a name (before / after) and its evaluation.
pub struct Tested<'a> {
    pub label: &'a str,
    pub evaluation: &'a Evaluation,
    pub uncertainty: Option<&'a Uncertainty>,
}

/// A one-file HTML report: the axis figures of each test side by side, the
/// per-position table of each, the charts inline (SVG), the uncertainty statement and
/// `notes` (set-up, machine time), as given.
pub fn html(title: &str, tests: &[Tested<'_>], charts_svg: &[String], notes: &[String]) -> String {
    let mut h = String::new();
    h.push_str(&format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{t}</title>\n<style>body{{font-family:sans-serif;max-width:1000px;margin:2em auto;color:#222}}table{{border-collapse:collapse;margin:1em 0}}td,th{{border:1px solid #bbb;padding:3px 8px;text-align:right}}th{{background:#eee}}td:first-child,th:first-child{{text-align:left}}</style></head><body>\n<h1>{t}</h1>\n<p>Positioning accuracy and repeatability per ISO 230-2: target positions P_i, 5 or more runs approaching each in the positive (↑, +) and the negative (↓, -) direction; deviation = actual - target, micrometres. A: accuracy, B: reversal value (max |B_i|), B̄: mean reversal value, R: repeatability (4 s, bidirectional by max(2s↑ + 2s↓ + |B_i|, R_i↑, R_i↓)), E: systematic positional deviation (range of the directional means), M: mean bidirectional positional deviation (range of (x̄↑ + x̄↓) / 2).</p>\n",
        t = escape(title)
    ));
    for n in notes {
        h.push_str(&format!("<p>{}</p>\n", escape(n)));
    }
    h.push_str("<h2>Axis figures (um)</h2>\n<table><tr><th>figure</th>");
    for t in tests {
        h.push_str(&format!(
            "<th>{} (axis {})</th>",
            escape(t.label),
            escape(&t.evaluation.axis)
        ));
    }
    h.push_str("</tr>\n");
    type Get = fn(&crate::AxisFigures) -> f64;
    let rows: [(&str, Get); 12] = [
        ("A (bidirectional accuracy)", |f| f.a),
        ("A↑", |f| f.a_up),
        ("A↓", |f| f.a_down),
        ("B (reversal value)", |f| f.b),
        ("B̄ (mean reversal value)", |f| f.mean_reversal),
        ("R (bidirectional repeatability)", |f| f.r),
        ("R↑", |f| f.r_up),
        ("R↓", |f| f.r_down),
        ("E (bidirectional systematic deviation)", |f| f.e),
        ("E↑", |f| f.e_up),
        ("E↓", |f| f.e_down),
        ("M (mean bidirectional deviation)", |f| f.m),
    ];
    for (name, get) in rows {
        h.push_str(&format!("<tr><td>{name}</td>"));
        for t in tests {
            h.push_str(&format!("<td>{:.3}</td>", get(&t.evaluation.figures)));
        }
        h.push_str("</tr>\n");
    }
    h.push_str("</table>\n");
    for t in tests {
        if let Some(u) = t.uncertainty {
            h.push_str(&format!(
                "<p>{}: measurement uncertainty of one deviation U = {:.3} um (k = 2), from the board certificate ({:.3} um, k = 2) and the localization repeatability (s = {:.3} um over {} still frames).</p>\n",
                escape(t.label), u.expanded_um, u.certificate_um, u.localization_s_um, u.localization_frames
            ));
        }
    }
    h.push_str("<h2>Charts</h2>\n");
    for svg in charts_svg {
        // The SVG documents come from our own renderer: inline as they are.
        h.push_str("<div>");
        h.push_str(svg);
        h.push_str("</div>\n");
    }
    for t in tests {
        h.push_str(&format!(
            "<h2>Per position: {}</h2>\n<table><tr><th>i</th><th>P_i (mm)</th><th>n↑</th><th>n↓</th><th>x̄↑</th><th>x̄↓</th><th>x̄</th><th>s↑</th><th>s↓</th><th>B_i</th><th>R_i↑</th><th>R_i↓</th><th>R_i</th></tr>\n",
            escape(t.label)
        ));
        for q in &t.evaluation.positions {
            h.push_str(&format!(
                "<tr><td>{}</td><td>{:.3}</td><td>{}</td><td>{}</td><td>{:.3}</td><td>{:.3}</td><td>{:.3}</td><td>{:.3}</td><td>{:.3}</td><td>{:.3}</td><td>{:.3}</td><td>{:.3}</td><td>{:.3}</td></tr>\n",
                q.position_index, q.target_mm, q.runs_up, q.runs_down, q.mean_up_um, q.mean_down_um,
                q.mean_um, q.s_up_um, q.s_down_um, q.reversal_um, q.r_up_um, q.r_down_um, q.r_um
            ));
        }
        h.push_str("</table>\n");
    }
    h.push_str("</body></html>\n");
    h
}

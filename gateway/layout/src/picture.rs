//! The partitioned layout drawn with `plot`: parts filled in their group's colour,
//! each group's window (from the group's first X, L' long, over its lane, shifted with
//! the group) as a dashed frame, lane edges as grey lines, and parts moved to resolve an
//! overlap outlined in red.

use layout_io::Part;
use plot::plotters::coord::Shift;
use plot::plotters::prelude::*;

use crate::{Move, Partition};

pub struct Picture<'a> {
    pub parts: &'a [Part],
    pub partition: &'a Partition,
    pub moves: &'a [Move],
}

impl Picture<'_> {
    /// `[xmin, ymin, xmax, ymax]` of everything drawn (shifted parts and windows).
    pub fn extent(&self) -> [f64; 4] {
        let offsets = self.partition.offsets();
        let mut e = [
            f64::INFINITY,
            self.partition.y0_mm,
            f64::NEG_INFINITY,
            self.partition.y0_mm + self.partition.width_mm,
        ];
        for (p, d) in self.parts.iter().zip(&offsets) {
            let b = p.bounds();
            e = [
                e[0].min(b[0] + d[0]),
                e[1].min(b[1] + d[1]),
                e[2].max(b[2] + d[0]),
                e[3].max(b[3] + d[1]),
            ];
        }
        for w in self.windows() {
            e = [
                e[0].min(w[0]),
                e[1].min(w[1]),
                e[2].max(w[2]),
                e[3].max(w[3]),
            ];
        }
        e
    }

    /// Each non-empty group's window rectangle.
    fn windows(&self) -> Vec<[f64; 4]> {
        let boxes: Vec<[f64; 4]> = self.parts.iter().map(Part::bounds).collect();
        let lane = self.partition.lane_mm();
        (0..self.partition.groups.len())
            .filter(|&g| !self.partition.groups[g].parts.is_empty())
            .map(|g| {
                let grp = &self.partition.groups[g];
                let ext = self.partition.extent_with(&boxes, g, None);
                let y = self.partition.y0_mm + grp.tool as f64 * lane + grp.dy_mm;
                // The lane, grown to hold parts moved in from a neighbouring lane.
                let (lo, hi) = grp.parts.iter().fold((y, y + lane), |(lo, hi), &p| {
                    (
                        lo.min(boxes[p][1] + grp.dy_mm),
                        hi.max(boxes[p][3] + grp.dy_mm),
                    )
                });
                [
                    ext[0] + grp.dx_mm,
                    lo,
                    ext[0] + grp.dx_mm + self.partition.window_mm,
                    hi,
                ]
            })
            .collect()
    }

    /// A picture size in pixels keeping the layout's proportions, `long` pixels on its longer side.
    pub fn size(&self, long: u32) -> (u32, u32) {
        let e = self.extent();
        let (w, h) = ((e[2] - e[0]).max(1e-9), (e[3] - e[1]).max(1e-9));
        let margin = 60;
        if w >= h {
            (long, ((long - margin) as f64 * h / w) as u32 + margin)
        } else {
            (((long - margin) as f64 * w / h) as u32 + margin, long)
        }
    }
}

impl plot::Chart for Picture<'_> {
    fn draw<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        area.fill(&WHITE)?;
        let e = self.extent();
        let mut chart = ChartBuilder::on(area)
            .margin(10)
            .x_label_area_size(30)
            .y_label_area_size(40)
            .caption(
                format!(
                    "{} parts, {} groups, {} tools, window {} mm, gap {} mm, {} moves",
                    self.parts.len(),
                    self.partition
                        .groups
                        .iter()
                        .filter(|g| !g.parts.is_empty())
                        .count(),
                    self.partition.tools,
                    self.partition.window_mm,
                    self.partition.gap_mm,
                    self.moves.len()
                ),
                (plot::FONT, 14),
            )
            .build_cartesian_2d(
                plot::safe_range(e[0], e[2], 1e-6),
                plot::safe_range(e[1], e[3], 1e-6),
            )?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc("X (feed), mm")
            .y_desc("Y, mm")
            .label_style((plot::FONT, 11))
            .draw()?;
        let lane = self.partition.lane_mm();
        for j in 0..=self.partition.tools {
            let y = self.partition.y0_mm + j as f64 * lane;
            chart.draw_series(std::iter::once(PathElement::new(
                vec![(e[0], y), (e[2], y)],
                RGBColor(170, 170, 170),
            )))?;
        }
        let offsets = self.partition.offsets();
        for (i, (p, d)) in self.parts.iter().zip(&offsets).enumerate() {
            let g = self.partition.group_of[i];
            let colour = Palette99::pick(g);
            let pts: Vec<(f64, f64)> = p.outer.iter().map(|q| (q[0] + d[0], q[1] + d[1])).collect();
            chart.draw_series(std::iter::once(Polygon::new(
                pts.clone(),
                colour.mix(0.55).filled(),
            )))?;
            for h in &p.holes {
                let hp: Vec<(f64, f64)> = h.iter().map(|q| (q[0] + d[0], q[1] + d[1])).collect();
                chart.draw_series(std::iter::once(Polygon::new(hp, WHITE.filled())))?;
            }
            let moved = self.moves.iter().any(|m| m.part == i);
            let mut outline = pts;
            outline.push(outline[0]);
            let style = if moved {
                RED.stroke_width(3)
            } else {
                BLACK.stroke_width(1)
            };
            chart.draw_series(std::iter::once(PathElement::new(outline, style)))?;
        }
        for (w, g) in self
            .windows()
            .into_iter()
            .zip(self.partition.groups.iter().filter(|g| !g.parts.is_empty()))
        {
            let colour = Palette99::pick(
                self.partition
                    .groups
                    .iter()
                    .position(|h| h.id == g.id)
                    .unwrap_or(0),
            );
            let corners = [
                (w[0], w[1]),
                (w[2], w[1]),
                (w[2], w[3]),
                (w[0], w[3]),
                (w[0], w[1]),
            ];
            for s in corners.windows(2) {
                chart.draw_series(DashedLineSeries::new(
                    s.iter().copied(),
                    6,
                    4,
                    colour.stroke_width(2),
                ))?;
            }
            chart.draw_series(std::iter::once(Text::new(
                format!("G{}", g.id),
                (w[0], w[3]),
                (plot::FONT, 12).into_font().color(&BLACK),
            )))?;
        }
        Ok(())
    }
}

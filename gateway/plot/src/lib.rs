//! Charts rendered in memory: one drawing routine gives both an SVG (for pages and
//! reports) and a PNG (for files and the web page), through plotters.
//!
//! A chart implements [`Chart`] once, generically over the plotters backend; the
//! renderers call it with an SVG or a bitmap backend. Text uses the embedded DejaVu Sans
//! under the family name [`FONT`], so no system font library is needed and a PNG looks
//! the same on the gateway box and in CI.
//!
//! ```
//! use plot::plotters::prelude::*;
//! struct Line;
//! impl plot::Chart for Line {
//!     fn draw<DB: DrawingBackend>(
//!         &self,
//!         area: &DrawingArea<DB, plot::plotters::coord::Shift>,
//!     ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
//!         area.fill(&WHITE)?;
//!         let mut chart = ChartBuilder::on(area)
//!             .caption("y = x", (plot::FONT, 16))
//!             .x_label_area_size(30)
//!             .y_label_area_size(30)
//!             .build_cartesian_2d(0.0..1.0, 0.0..1.0)?;
//!         chart.configure_mesh().label_style((plot::FONT, 12)).draw()?;
//!         chart.draw_series(LineSeries::new([(0.0, 0.0), (1.0, 1.0)], &BLUE))?;
//!         Ok(())
//!     }
//! }
//! let svg = plot::render_svg(&Line, 320, 240).unwrap();
//! assert!(svg.starts_with("<svg"));
//! let png = plot::render_png(&Line, 320, 240).unwrap();
//! assert_eq!(&png[1..4], b"PNG");
//! ```

use plotters::coord::Shift;
use plotters::prelude::*;
use std::sync::Once;

pub use plotters;

/// The font family every chart should name in its text styles.
pub const FONT: &str = "sans-serif";

static DEJAVU_SANS: &[u8] = include_bytes!("../fonts/DejaVuSans.ttf");

/// A chart drawn the same way on any plotters backend.
pub trait Chart {
    fn draw<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>>;
}

#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    #[error("drawing the chart failed: {0}")]
    Draw(String),
    #[error("encoding the PNG failed: {0}")]
    Encode(String),
    #[error("a chart of {width} x {height} pixels cannot be drawn (each side 1 to 16384)")]
    Size { width: u32, height: u32 },
}

fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        for style in [FontStyle::Normal, FontStyle::Bold, FontStyle::Italic] {
            // The font is compiled in and known to parse; a failure here is a broken build.
            if plotters::style::register_font(FONT, style, DEJAVU_SANS).is_err() {
                panic!("the embedded DejaVu Sans does not parse");
            }
        }
    });
}

fn check_size(width: u32, height: u32) -> Result<(), PlotError> {
    if (1..=16384).contains(&width) && (1..=16384).contains(&height) {
        Ok(())
    } else {
        Err(PlotError::Size { width, height })
    }
}

/// The largest magnitude a chart's axis may reach: far beyond any physical figure in mm
/// or um, small enough that the axis arithmetic (tick steps, labels) stays exact.
pub const MAX_AXIS: f64 = 1e12;

/// An axis range a chart can draw, whatever the data: `lo..hi` with non-finite ends
/// replaced, both ends clamped to [`MAX_AXIS`] in magnitude, ordered, and at least
/// `min_span` wide. Every chart builds its axes through here, so a data value such as
/// 1e308 (or NaN) gives a chart with its point off the scale instead of tick
/// arithmetic that never ends.
pub fn safe_range(lo: f64, hi: f64, min_span: f64) -> std::ops::Range<f64> {
    let clamp = |v: f64, fallback: f64| {
        if v.is_nan() {
            fallback
        } else {
            v.clamp(-MAX_AXIS, MAX_AXIS)
        }
    };
    let (mut lo, mut hi) = (clamp(lo, 0.0), clamp(hi, 1.0));
    if lo > hi {
        std::mem::swap(&mut lo, &mut hi);
    }
    let min_span = if min_span.is_finite() && min_span > 0.0 {
        min_span.min(MAX_AXIS)
    } else {
        1e-9
    };
    if hi - lo < min_span {
        let mid = lo / 2.0 + hi / 2.0;
        lo = mid - min_span / 2.0;
        hi = mid + min_span / 2.0;
    }
    lo..hi
}

/// The chart as an SVG document.
pub fn render_svg(chart: &impl Chart, width: u32, height: u32) -> Result<String, PlotError> {
    check_size(width, height)?;
    register_font();
    let mut svg = String::new();
    {
        let area = SVGBackend::with_string(&mut svg, (width, height)).into_drawing_area();
        chart
            .draw(&area)
            .map_err(|e| PlotError::Draw(e.to_string()))?;
        area.present().map_err(|e| PlotError::Draw(e.to_string()))?;
    }
    Ok(svg)
}

/// The chart as a PNG file's bytes (8-bit RGB).
pub fn render_png(chart: &impl Chart, width: u32, height: u32) -> Result<Vec<u8>, PlotError> {
    check_size(width, height)?;
    register_font();
    let mut rgb = vec![0u8; width as usize * height as usize * 3];
    {
        let area = BitMapBackend::with_buffer(&mut rgb, (width, height)).into_drawing_area();
        chart
            .draw(&area)
            .map_err(|e| PlotError::Draw(e.to_string()))?;
        area.present().map_err(|e| PlotError::Draw(e.to_string()))?;
    }
    let img = image::RgbImage::from_raw(width, height, rgb)
        .ok_or_else(|| PlotError::Encode("buffer size does not match the picture".into()))?;
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(|e| PlotError::Encode(e.to_string()))?;
    Ok(png)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A square with a caption: dark pixels where the square is, text in the SVG.
    struct Square;
    impl Chart for Square {
        fn draw<DB: DrawingBackend>(
            &self,
            area: &DrawingArea<DB, Shift>,
        ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
            area.fill(&WHITE)?;
            area.draw(&Rectangle::new([(10, 10), (30, 30)], BLACK.filled()))?;
            area.draw(&Text::new("axis X", (40, 40), (FONT, 14)))?;
            Ok(())
        }
    }

    #[test]
    fn svg_holds_the_shapes_and_the_text() {
        let svg = render_svg(&Square, 100, 80).unwrap();
        assert!(svg.contains("<rect"), "{svg}");
        assert!(svg.contains("axis X"), "{svg}");
    }

    #[test]
    fn png_decodes_with_the_square_black_and_the_rest_white() {
        let png = render_png(&Square, 100, 80).unwrap();
        let img = image::load_from_memory(&png).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (100, 80));
        assert_eq!(img.get_pixel(20, 20).0, [0, 0, 0]);
        assert_eq!(img.get_pixel(90, 5).0, [255, 255, 255]);
        // The text was rasterised with the embedded font: some dark pixels near it.
        let inked = (40..100)
            .flat_map(|x| (40..60).map(move |y| (x, y)))
            .filter(|&(x, y)| img.get_pixel(x, y).0[0] < 128)
            .count();
        assert!(inked > 10, "no text drawn ({inked} dark pixels)");
    }

    /// Axes from absurd data: a chart's range stays finite, ordered and drawable, and
    /// drawing a point at 1e308 on it ends (it looped in the tick code before).
    #[test]
    fn ranges_from_absurd_data_are_drawable() {
        for (lo, hi) in [
            (0.0, 1e308),
            (-1e308, 1e308),
            (f64::NAN, 3.0),
            (f64::NEG_INFINITY, f64::INFINITY),
            (5.0, 5.0),
            (2.0, -2.0),
        ] {
            let r = safe_range(lo, hi, 1.0);
            assert!(r.start.is_finite() && r.end.is_finite(), "{lo} {hi}: {r:?}");
            assert!(r.end - r.start >= 1.0 - 1e-9, "{lo} {hi}: {r:?}");
            assert!(r.start.abs() <= MAX_AXIS && r.end.abs() <= MAX_AXIS);
        }
        struct Far;
        impl Chart for Far {
            fn draw<DB: DrawingBackend>(
                &self,
                area: &DrawingArea<DB, Shift>,
            ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
                let y = safe_range(-1.0, 1e308, 1.0);
                let mut chart = ChartBuilder::on(area)
                    .x_label_area_size(30)
                    .y_label_area_size(30)
                    .build_cartesian_2d(0.0..1.0, y)?;
                chart.configure_mesh().label_style((FONT, 12)).draw()?;
                chart.draw_series(LineSeries::new([(0.0, 0.0), (1.0, 1e308)], &BLUE))?;
                Ok(())
            }
        }
        assert!(render_svg(&Far, 200, 150).unwrap().starts_with("<svg"));
        assert_eq!(&render_png(&Far, 200, 150).unwrap()[1..4], b"PNG");
    }

    #[test]
    fn refuses_an_empty_or_huge_picture() {
        assert!(matches!(
            render_png(&Square, 0, 10),
            Err(PlotError::Size { .. })
        ));
        assert!(matches!(
            render_svg(&Square, 10, 20000),
            Err(PlotError::Size { .. })
        ));
    }
}

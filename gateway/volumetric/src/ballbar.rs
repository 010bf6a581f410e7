//! The ball-bar test (ISO 230-4): squareness from circles traced in XY, XZ and YZ.
//!
//! # What the bar reads
//!
//! A telescoping bar of nominal length R links a ball at the tool point to a pivot ball
//! fixed on the table; the machine traces a circle of radius R about the pivot's
//! command `c` in one plane, the angle θ running from the plane's first axis towards its
//! second (XY: +X towards +Y; XZ: +X towards +Z; YZ: +Y towards +Z). The bar reads its
//! length minus R. With `u(θ)` the radial direction, to first order
//!
//! ```text
//! Δr(θ) = (e(c + R u(θ)) − e(c)) · u(θ) + (pivot setting) · u(θ) + (bar length offset)
//! ```
//!
//! # The standard reading
//!
//! The readings of both runs are fitted by least squares with
//! `a0 + a1 cos θ + b1 sin θ + a2 cos 2θ + b2 sin 2θ`: `a0` is the bar's length offset,
//! `(a1, b1)` the pivot's setting error (the least-squares centre), and the second
//! harmonic the ellipse. ISO 230-4's circular deviation G is the radial span of the
//! readings about the least-squares centre (max − min of `Δr − a1 cos θ − b1 sin θ`).
//! An out-of-square plane stretches the circle along one diagonal: the diameter along
//! 45° grows by `2 b2` and along 135° shrinks by `2 b2`, so the angle between the two
//! axes' lines of motion departs from 90° by `(D135 − D45) / (2R) = −2 b2 / R`; that is
//! the test's raw squareness reading (reported as `iso_squareness`, positive when the
//! angle between the plane's axes exceeds 90°).
//!
//! # Squareness for the model
//!
//! The raw reading also holds the straightness slopes and any angle's Abbe effect that
//! the other instruments already measured. So the model's constant is fitted against
//! the model itself: with the tables identified from the laser and the level and the
//! squareness set to zero, the model predicts every reading; the measured `b2` minus the
//! predicted one, divided by `b2`'s sensitivity to the plane's squareness constant
//! (`∂b2/∂E_C0Y = −R/2` in XY, `∂b2/∂E_B0Z = +R/2` in XZ, `∂b2/∂E_A0Z = −R/2` in YZ, from
//! `S(q) = (−E_C0Y·y + E_B0Z·z, −E_A0Z·z, 0)`; computed here from the model), is the
//! constant. Worked example (XY, R = 150 mm, everything else zero): `E_C0Y = 20 µrad`
//! gives `Δr = −E_C0Y R sin θ cos θ`, `b2 = −1.5 µm`, the 45° diameter 3 µm short, the
//! 135° one 3 µm long: `−2 b2 / R = 20 µrad`.
//!
//! Uncertainty: `b2`'s standard deviation `U √(2/N)` (U the bar's stated uncertainty,
//! N readings) over the sensitivity; the run-to-run residual is half the difference of
//! the runs' own estimates.

use crate::{Model, VolError};
use nalgebra::{DMatrix, DVector};
use protocol::volumetric::InstrumentFile;

/// The planes in the order of the squareness constants (E_C0Y, E_B0Z, E_A0Z), with
/// their two axes.
pub const PLANES: [(&str, usize, usize); 3] = [("XY", 0, 1), ("XZ", 0, 2), ("YZ", 1, 2)];

/// The columns (after `run`) of `ballbar_<plane>.csv`.
pub const BALLBAR_COLUMNS: [&str; 2] = ["angle_deg", "deviation_um"];

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BallbarError {
    #[error("{file}: header key `{key}` missing or malformed ({want})")]
    Meta {
        file: String,
        key: &'static str,
        want: &'static str,
    },
    #[error(
        "{file}: the circle covers {span:.0} degrees; a squareness reading needs the full 360"
    )]
    Span { file: String, span: f64 },
    #[error("{file}: circle leaves the model's travel: {source}")]
    Travel { file: String, source: VolError },
}

/// One circle's file, read.
#[derive(Debug, Clone, PartialEq)]
pub struct Circle {
    pub plane: usize,
    pub radius_mm: f64,
    pub centre_mm: [f64; 3],
    pub uncertainty_mm: f64,
    /// Every reading of every run: (angle rad, deviation mm).
    pub readings: Vec<(f64, f64)>,
    /// The same per run.
    pub runs: Vec<Vec<(f64, f64)>>,
}

/// The standard reading and the model's squareness for one plane.
#[derive(Debug, Clone, PartialEq)]
pub struct CircleResult {
    pub plane: &'static str,
    /// `[a0, a1, b1, a2, b2]`, mm.
    pub harmonics: [f64; 5],
    /// ISO 230-4 circular deviation G about the least-squares centre, mm.
    pub circular_deviation_mm: f64,
    /// `−2 b2 / R`, rad: the raw squareness reading of the test.
    pub iso_squareness_rad: f64,
    /// The model's squareness constant, its standard uncertainty and the run-to-run
    /// residual, rad.
    pub squareness_rad: f64,
    pub uncertainty_rad: f64,
    pub residual_rad: f64,
    /// RMS of the readings minus the fitted model's prediction (with the fitted
    /// squareness and the fitted offset and centre), mm.
    pub model_residual_rms_mm: f64,
    /// Per reading: angle (rad), the reading less the bar offset and the pivot setting
    /// (mm), and the fitted model's prediction less the same (mm): the plotted traces.
    pub trace: Vec<(f64, f64, f64)>,
}

/// The ball-bar plot: the nominal circle, the measured trace and the model's, the
/// deviations magnified, with the 45° and 135° diagonals the squareness is read along.
pub struct BallbarChart<'a>(pub &'a CircleResult);

impl plot::Chart for BallbarChart<'_> {
    fn draw<DB: plot::plotters::prelude::DrawingBackend>(
        &self,
        area: &plot::plotters::prelude::DrawingArea<DB, plot::plotters::coord::Shift>,
    ) -> Result<(), plot::plotters::prelude::DrawingAreaErrorKind<DB::ErrorType>> {
        use plot::plotters::prelude::*;
        let r = self.0;
        area.fill(&WHITE)?;
        let span = r
            .trace
            .iter()
            .map(|t| t.1.abs().max(t.2.abs()))
            .fold(1e-6, f64::max);
        // The largest deviation is drawn as 40 % of the nominal radius.
        let k = 0.4 / span;
        let at = |t: f64, d: f64| ((1.0 + k * d) * t.cos(), (1.0 + k * d) * t.sin());
        let (a, b) = (&r.plane[0..1], &r.plane[1..2]);
        let mut chart = ChartBuilder::on(area)
            .caption(
                format!(
                    "Ball bar {}: G {:.2} µm, squareness reading {:.1} µrad, model {:.1} ± {:.1} µrad (1 div = {:.1} µm)",
                    r.plane,
                    r.circular_deviation_mm * 1e3,
                    r.iso_squareness_rad * 1e6,
                    r.squareness_rad * 1e6,
                    r.uncertainty_rad * 1e6,
                    span * 1e3 / 2.0
                ),
                (plot::FONT, 15),
            )
            .margin(10)
            .x_label_area_size(30)
            .y_label_area_size(30)
            .build_cartesian_2d(-1.6..1.6, -1.6..1.6)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc(format!("+{a}"))
            .y_desc(format!("+{b}"))
            .x_label_formatter(&|_| String::new())
            .y_label_formatter(&|_| String::new())
            .label_style((plot::FONT, 12))
            .draw()?;
        let ring = |f: f64| (0..=360).map(move |i| at((i as f64).to_radians(), f / k));
        for f in [-0.4, -0.2, 0.2, 0.4] {
            chart.draw_series(LineSeries::new(ring(f), RGBColor(225, 225, 225)))?;
        }
        chart.draw_series(LineSeries::new(ring(0.0), RGBColor(150, 150, 150)))?;
        for deg in [45.0f64, 135.0] {
            let (s, c) = deg.to_radians().sin_cos();
            chart.draw_series(LineSeries::new(
                [(-1.5 * c, -1.5 * s), (1.5 * c, 1.5 * s)],
                RGBColor(200, 200, 200),
            ))?;
        }
        let mut model: Vec<(f64, f64)> = r.trace.iter().map(|t| at(t.0, t.2)).collect();
        model.push(model[0]);
        chart
            .draw_series(LineSeries::new(
                model,
                RGBColor(230, 120, 30).stroke_width(2),
            ))?
            .label("model (fitted squareness)")
            .legend(|(x, y)| PathElement::new([(x, y), (x + 15, y)], RGBColor(230, 120, 30)));
        chart
            .draw_series(
                r.trace
                    .iter()
                    .map(|t| Circle::new(at(t.0, t.1), 1, RGBColor(30, 80, 180).filled())),
            )?
            .label("measured")
            .legend(|(x, y)| Circle::new((x + 7, y), 3, RGBColor(30, 80, 180).filled()));
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .label_font((plot::FONT, 12))
            .draw()?;
        Ok(())
    }
}

/// Reads a parsed `ballbar_<plane>.csv` (header keys `plane`, `radius_mm`, `centre_mm`
/// as three numbers, `uncertainty_um`).
pub fn circle(file: &str, f: &InstrumentFile) -> Result<Circle, BallbarError> {
    let meta = |key: &'static str, want: &'static str| {
        f.meta(key).ok_or(BallbarError::Meta {
            file: file.to_string(),
            key,
            want,
        })
    };
    let bad = |key: &'static str, want: &'static str| BallbarError::Meta {
        file: file.to_string(),
        key,
        want,
    };
    let plane_name = meta("plane", "XY, XZ or YZ")?.trim();
    let plane = PLANES
        .iter()
        .position(|p| p.0 == plane_name)
        .ok_or_else(|| bad("plane", "XY, XZ or YZ"))?;
    let positive = |key: &'static str, want: &'static str| -> Result<f64, BallbarError> {
        meta(key, want)?
            .trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite() && *v > 0.0)
            .ok_or_else(|| bad(key, want))
    };
    let radius_mm = positive("radius_mm", "a positive length in mm")?;
    let uncertainty_mm = positive("uncertainty_um", "a positive number of µm")? * 1e-3;
    let centre: Vec<f64> = meta("centre_mm", "three numbers in mm")?
        .split_whitespace()
        .map(|v| v.parse::<f64>().ok().filter(|v| v.is_finite()))
        .collect::<Option<Vec<f64>>>()
        .filter(|v| v.len() == 3)
        .ok_or_else(|| bad("centre_mm", "three numbers in mm"))?;
    let runs: Vec<Vec<(f64, f64)>> = f
        .runs
        .iter()
        .map(|r| {
            r.iter()
                .map(|row| (row[0].to_radians(), row[1] * 1e-3))
                .collect()
        })
        .collect();
    let first = &f.runs[0];
    let span = first[first.len() - 1][0] - first[0][0];
    if span < 350.0 {
        return Err(BallbarError::Span {
            file: file.to_string(),
            span,
        });
    }
    Ok(Circle {
        plane,
        radius_mm,
        centre_mm: [centre[0], centre[1], centre[2]],
        uncertainty_mm,
        readings: runs.iter().flatten().copied().collect(),
        runs,
    })
}

/// Least-squares `[a0, a1, b1, a2, b2]` of `readings`.
pub fn harmonics(readings: &[(f64, f64)]) -> [f64; 5] {
    let basis = |t: f64| [1.0, t.cos(), t.sin(), (2.0 * t).cos(), (2.0 * t).sin()];
    let a = DMatrix::from_fn(readings.len(), 5, |i, j| basis(readings[i].0)[j]);
    let b = DVector::from_iterator(readings.len(), readings.iter().map(|r| r.1));
    let n = a.transpose() * &a;
    let rhs = a.transpose() * b;
    let x = n
        .cholesky()
        .map(|c| c.solve(&rhs))
        .unwrap_or_else(|| DVector::zeros(5));
    std::array::from_fn(|k| x[k])
}

fn command(c: &Circle, t: f64) -> [f64; 3] {
    let (_, i, j) = PLANES[c.plane];
    let mut q = c.centre_mm;
    q[i] += c.radius_mm * t.cos();
    q[j] += c.radius_mm * t.sin();
    q
}

/// What `model` predicts the bar reads at angle `t` (perfect pivot and bar).
fn predicted(model: &Model, c: &Circle, t: f64) -> Result<f64, VolError> {
    let e0 = model.error_exact(c.centre_mm)?;
    let e = model.error_exact(command(c, t))?;
    let (_, i, j) = PLANES[c.plane];
    Ok((e[i] - e0[i]) * t.cos() + (e[j] - e0[j]) * t.sin())
}

fn predicted_b2(model: &Model, c: &Circle, angles: &[f64]) -> Result<f64, VolError> {
    let p: Vec<(f64, f64)> = angles
        .iter()
        .map(|&t| predicted(model, c, t).map(|v| (t, v)))
        .collect::<Result<_, _>>()?;
    Ok(harmonics(&p)[4])
}

/// The standard reading of `c` and its squareness constant for `base` (the model from
/// the other instruments; its squareness constants are ignored and set to zero).
pub fn squareness(file: &str, base: &Model, c: &Circle) -> Result<CircleResult, BallbarError> {
    let travel = |source| BallbarError::Travel {
        file: file.to_string(),
        source,
    };
    let mut zero = base.clone();
    zero.file.squareness_rad = [0.0; 3];
    let mut unit = zero.clone();
    let step = 1e-5;
    unit.file.squareness_rad[c.plane] = step;
    let angles: Vec<f64> = c.runs[0].iter().map(|r| r.0).collect();
    let b2_zero = predicted_b2(&zero, c, &angles).map_err(travel)?;
    let sensitivity = (predicted_b2(&unit, c, &angles).map_err(travel)? - b2_zero) / step;
    let h = harmonics(&c.readings);
    let value = (h[4] - b2_zero) / sensitivity;
    let per_run: Vec<f64> = c
        .runs
        .iter()
        .map(|r| (harmonics(r)[4] - b2_zero) / sensitivity)
        .collect();
    let residual_rad = if per_run.len() > 1 {
        let m = per_run.iter().sum::<f64>() / per_run.len() as f64;
        (per_run.iter().map(|v| (v - m).powi(2)).sum::<f64>() / per_run.len() as f64).sqrt()
    } else {
        0.0
    };
    let n = c.readings.len() as f64;
    let uncertainty_rad = c.uncertainty_mm * (2.0 / n).sqrt() / sensitivity.abs();
    let span = c
        .readings
        .iter()
        .map(|&(t, d)| d - h[1] * t.cos() - h[2] * t.sin());
    let (lo, hi) = span.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    });
    let mut fitted = zero.clone();
    fitted.file.squareness_rad[c.plane] = value;
    // Readings minus the prediction, less the bar offset and the pivot setting fitted
    // to that difference.
    let diff: Vec<(f64, f64)> = c
        .readings
        .iter()
        .map(|&(t, d)| predicted(&fitted, c, t).map(|p| (t, d - p)))
        .collect::<Result<_, _>>()
        .map_err(travel)?;
    let g = harmonics(&diff);
    let ss: f64 = diff
        .iter()
        .map(|&(t, r)| (r - g[0] - g[1] * t.cos() - g[2] * t.sin()).powi(2))
        .sum();
    let trace = c
        .readings
        .iter()
        .zip(&diff)
        .map(|(&(t, d), &(_, r))| {
            let setting = h[0] + h[1] * t.cos() + h[2] * t.sin();
            // The model's trace shares the measured one's offset and centre.
            (
                t,
                d - setting,
                d - setting - (r - g[0] - g[1] * t.cos() - g[2] * t.sin()),
            )
        })
        .collect();
    Ok(CircleResult {
        plane: PLANES[c.plane].0,
        harmonics: h,
        circular_deviation_mm: hi - lo,
        iso_squareness_rad: -2.0 * h[4] / c.radius_mm,
        squareness_rad: value,
        uncertainty_rad,
        residual_rad,
        model_residual_rms_mm: (ss / n).sqrt(),
        trace,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::volumetric::{parse_instrument, Structure};

    fn file(plane: &str, dev: impl Fn(f64) -> f64) -> InstrumentFile {
        let mut s = format!(
            "# plane: {plane}\n# radius_mm: 150\n# centre_mm: 250 200 200\n# uncertainty_um: 0.5\nrun,angle_deg,deviation_um\n"
        );
        for k in 0..360 {
            s += &format!("1,{k},{}\n", dev((k as f64).to_radians()));
        }
        parse_instrument(&s, &BALLBAR_COLUMNS).unwrap()
    }

    #[test]
    fn worked_example_xy_squareness_from_the_diagonals() {
        // E_C0Y = 20 µrad alone: Δr = −E_C0Y R sin θ cos θ (µm), plus a pivot set 2 µm
        // off along X and a bar 1 µm long: both absorbed by a0, a1.
        let c0y = 20e-6;
        let f = file("XY", |t| {
            (-c0y * 150.0 * t.sin() * t.cos() + 0.002 * t.cos() + 0.001) * 1e3
        });
        let c = circle("ballbar_XY.csv", &f).unwrap();
        let base = Model::zero(Structure::Xyfz, [500.0, 400.0, 400.0]);
        let r = squareness("ballbar_XY.csv", &base, &c).unwrap();
        assert!((r.harmonics[4] + 0.0015).abs() < 1e-9, "{:?}", r.harmonics);
        assert!((r.iso_squareness_rad - 20e-6).abs() < 1e-11);
        assert!(
            (r.squareness_rad - 20e-6).abs() < 1e-9,
            "{}",
            r.squareness_rad
        );
        assert!((r.harmonics[0] - 0.001).abs() < 1e-9 && (r.harmonics[1] - 0.002).abs() < 1e-9);
        // G: the ellipse's span, 2 |b2| = 3 µm.
        assert!((r.circular_deviation_mm - 0.003).abs() < 1e-6);
        assert!(
            r.model_residual_rms_mm < 1e-7,
            "{}",
            r.model_residual_rms_mm
        );
    }

    #[test]
    fn signs_per_plane_follow_the_squareness_terms() {
        // XZ: ex = +E_B0Z z → Δr = +E_B0Z R sin cos; YZ: ey = −E_A0Z z → −E_A0Z R sin cos.
        let base = Model::zero(Structure::Xyfz, [500.0, 400.0, 400.0]);
        for (plane, sign) in [("XZ", 1.0), ("YZ", -1.0)] {
            let f = file(plane, |t| sign * 10e-6 * 150.0 * t.sin() * t.cos() * 1e3);
            let c = circle("b.csv", &f).unwrap();
            let r = squareness("b.csv", &base, &c).unwrap();
            assert!(
                (r.squareness_rad - 10e-6).abs() < 1e-9,
                "{plane}: {}",
                r.squareness_rad
            );
        }
    }

    #[test]
    fn refuses_bad_headers_and_partial_circles() {
        let good = file("XY", |_| 0.0);
        let mut f = good.clone();
        f.meta.retain(|m| m.0 != "radius_mm");
        assert!(matches!(
            circle("b.csv", &f),
            Err(BallbarError::Meta {
                key: "radius_mm",
                ..
            })
        ));
        let mut f = good.clone();
        f.meta.push(("centre_mm".into(), "1 2".into()));
        f.meta.retain(|m| m.0 != "centre_mm" || m.1 == "1 2");
        assert!(matches!(
            circle("b.csv", &f),
            Err(BallbarError::Meta {
                key: "centre_mm",
                ..
            })
        ));
        let mut f = good;
        f.runs[0].truncate(180);
        let e = circle("b.csv", &f).unwrap_err();
        assert!(e.to_string().contains("179 degrees"), "{e}");
    }
}

//! Behaviour of the whole localizer on rendered frames (`world::render`, whose dot
//! centres and pose are the truth). Frames are few and mostly small so the suite stays
//! fast in debug builds: two 1280x1024 frames for the accuracy figures, the rest
//! 640x512 or smaller.

use super::testkit::{board, camera, dot_errors, frame};
use super::*;
use protocol::{Pixels, Polarity};

fn err_um(o: &Observation, truth: [f64; 2]) -> f64 {
    (o.x_mm - truth[0]).hypot(o.y_mm - truth[1]) * 1000.0
}

/// A small frame (640x512, 20 dots) at the default conditions.
fn small_frame(truth: [f64; 2]) -> world::render::RenderedFrame {
    frame(
        &board(Polarity::DarkOnLight),
        &camera(640, 512, 0.8, 1.0, 2.0, 0.4),
        truth,
        11,
    )
}

const TRUTH: [f64; 2] = [20.1234, 20.3171];

#[test]
fn accuracy_figures_on_worst_and_mild_frames() {
    let b = board(Polarity::DarkOnLight);
    // Worst case of the acceptance conditions, then a mild unrotated one.
    let cases = [
        (2.0, 1.5, 4.0, 1.6, [20.1234, 20.3171]),
        (0.0, 0.7, 2.0, 0.0, [20.0871, 20.2093]),
    ];
    for (k, (rot, blur, noise, dist, truth)) in cases.into_iter().enumerate() {
        let f = frame(
            &b,
            &camera(1280, 1024, rot, blur, noise, dist),
            truth,
            7 + k as u64,
        );
        let dots = detect_dots(&f.image, Polarity::DarkOnLight);
        let (rms, max, n) = dot_errors(&f, &dots);
        assert!(
            n >= 70 && n == dots.len(),
            "frame {k}: {n} of {} dots matched",
            dots.len()
        );
        assert!(
            rms <= 0.012,
            "frame {k}: dot centre RMS {rms:.4} px (max {max:.4})"
        );

        let mut p = LocalizeParams::new([truth[0] + 0.03, truth[1] - 0.05]);
        p.um_per_px = Some(4.0);
        let o = localize(&f.image, &b, &p).unwrap();
        assert!(
            err_um(&o, truth) <= 0.03,
            "frame {k}: fit error {:.4} um",
            err_um(&o, truth)
        );
        assert!(o.points >= 70 && o.rejected == 0, "{o:?}");
        assert!((o.rotation_deg - rot).abs() < 0.01, "{o:?}");
        assert!((o.um_per_px - 4.0).abs() < 0.004, "{o:?}");
        assert!(o.residual_rms_um < 0.3, "{o:?}");

        // The patent's formula on the same frame: exact enough without rotation, biased
        // by micrometres with it (reported, not corrected).
        p.method = Method::FourPoint;
        let o4 = localize(&f.image, &b, &p).unwrap();
        assert_eq!((o4.method, o4.points), (Method::FourPoint, 4));
        let e4 = err_um(&o4, truth);
        if rot == 0.0 {
            assert!(e4 < 0.1, "four-point at 0 deg: {e4:.4} um");
        } else {
            assert!(e4 > 1.0 && e4 < 20.0, "four-point at {rot} deg: {e4:.4} um");
        }
    }
}

#[test]
fn bright_dots_on_a_16_bit_frame() {
    let b = board(Polarity::BrightOnDark);
    let mut cam = camera(800, 600, -1.0, 1.2, 0.0, 0.8);
    cam.bit_depth = 16;
    cam.noise_sigma = 3.0 * 257.0;
    let f = frame(&b, &cam, TRUTH, 5);
    assert!(matches!(f.image.pixels, Pixels::Mono16(_)));
    let dots = detect_dots(&f.image, Polarity::BrightOnDark);
    let (rms, _, n) = dot_errors(&f, &dots);
    assert!(n >= 20 && rms < 0.015, "{n} dots, RMS {rms:.4} px");
    // Looking for dark dots finds nothing sensible on this board.
    assert!(detect_dots(&f.image, Polarity::DarkOnLight).len() < 3);
    let o = localize(&f.image, &b, &LocalizeParams::new(TRUTH)).unwrap();
    assert!(err_um(&o, TRUTH) < 0.05, "{o:?}");
}

#[test]
fn turned_and_mirrored_mounts_with_matching_pixel_axes() {
    let b = board(Polarity::DarkOnLight);
    // (mount rotation, mirrored, pixel axes): image +x along board +y and image +y along
    // board +x for a mount turned by 90 degrees; a camera below the board is mirrored.
    for (rot, mirrored, axes) in [
        (90.5, false, "+y,+x"),
        (-0.7, true, "+x,+y"),
        (180.3, false, "-x,+y"),
    ] {
        let mut cam = camera(640, 512, rot, 1.0, 2.0, 0.4);
        cam.mirrored = mirrored;
        let f = frame(&b, &cam, TRUTH, 3);
        let mut p = LocalizeParams::new(TRUTH);
        p.pixel_axes = axes.parse().unwrap();
        let o = localize(&f.image, &b, &p).unwrap();
        assert!(err_um(&o, TRUTH) < 0.05, "{axes}: {o:?}");
        // Rotation is reported against the nominal axes.
        let nominal = (rot / 90.0).round() * 90.0;
        assert!(
            (o.rotation_deg - (rot - nominal)).abs() < 0.02,
            "{axes}: {o:?}"
        );
        p.method = Method::FourPoint;
        assert!(err_um(&localize(&f.image, &b, &p).unwrap(), TRUTH) < 5.0);
    }
}

#[test]
fn rotation_is_accepted_up_to_ten_degrees() {
    let b = board(Polarity::DarkOnLight);
    let f = frame(&b, &camera(640, 512, 9.5, 1.0, 2.0, 0.0), TRUTH, 6);
    let o = localize(&f.image, &b, &LocalizeParams::new(TRUTH)).unwrap();
    assert!(
        err_um(&o, TRUTH) < 0.05 && (o.rotation_deg - 9.5).abs() < 0.02,
        "{o:?}"
    );
    let f = frame(&b, &camera(640, 512, -12.0, 1.0, 2.0, 0.0), TRUTH, 6);
    let e = localize(&f.image, &b, &LocalizeParams::new(TRUTH)).unwrap_err();
    assert!(matches!(e, LocalizeError::RotationOutOfRange { .. }), "{e}");
    assert!(e.to_string().contains("rotated -12.0"), "{e}");
}

#[test]
fn hint_errors_up_to_the_tolerance_give_the_same_answer() {
    let b = board(Polarity::DarkOnLight);
    let f = small_frame(TRUTH);
    let reference = localize(&f.image, &b, &LocalizeParams::new(TRUTH)).unwrap();
    assert!(err_um(&reference, TRUTH) < 0.05, "{reference:?}");
    for k in 0..8 {
        let a = k as f64 * std::f64::consts::FRAC_PI_4;
        let hint = [TRUTH[0] + 0.095 * a.cos(), TRUTH[1] + 0.095 * a.sin()];
        let o = localize(&f.image, &b, &LocalizeParams::new(hint)).unwrap();
        assert_eq!(
            (o.x_mm, o.y_mm),
            (reference.x_mm, reference.y_mm),
            "hint {hint:?}"
        );
    }
    // A wider (legal) tolerance admits a hint off by most of half a pitch.
    let mut p = LocalizeParams::new([TRUTH[0] - 0.2, TRUTH[1] + 0.05]);
    p.hint_tolerance_mm = 0.24;
    assert_eq!(localize(&f.image, &b, &p).unwrap().x_mm, reference.x_mm);
}

#[test]
fn refuses_an_ambiguous_or_contradicted_hint() {
    let b = board(Polarity::DarkOnLight);
    let f = small_frame(TRUTH);
    // Further off than the tolerance: the stage is not where it was told to go.
    let e = localize(
        &f.image,
        &b,
        &LocalizeParams::new([TRUTH[0] + 0.15, TRUTH[1]]),
    )
    .unwrap_err();
    assert!(matches!(e, LocalizeError::Ambiguous { .. }), "{e}");
    assert!(e.to_string().contains("beyond the tolerance"), "{e}");
    // Half a pitch or more: two grid offsets always fit.
    let mut p = LocalizeParams::new(TRUTH);
    p.hint_tolerance_mm = 0.25;
    let e = localize(&f.image, &b, &p).unwrap_err();
    assert!(e.to_string().contains("ambiguous by construction"), "{e}");
}

#[test]
fn refuses_frames_without_a_usable_board() {
    let b = board(Polarity::DarkOnLight);
    // Blank (uniform grey plus noise).
    let mut rng = world::rng::Rng::new(1);
    let px: Vec<u8> = (0..640 * 512)
        .map(|_| (180.0 + 3.0 * rng.normal()) as u8)
        .collect();
    let blank = MonoImage::new(640, 512, Pixels::Mono8(px)).unwrap();
    let e = localize(&blank, &b, &LocalizeParams::new(TRUTH)).unwrap_err();
    assert!(matches!(e, LocalizeError::NoBoard { .. }), "{e}");
    assert!(detect_dots(&blank, Polarity::DarkOnLight).is_empty());
    // Camera beyond the board's edge: nothing in view.
    let far = [-5.0, -5.0];
    let e = localize(&small_frame(far).image, &b, &LocalizeParams::new(far)).unwrap_err();
    assert!(matches!(e, LocalizeError::NoBoard { .. }), "{e}");

    let f = small_frame(TRUTH);
    // Too few points for the configured minimum.
    let mut p = LocalizeParams::new(TRUTH);
    p.min_points = 50;
    let e = localize(&f.image, &b, &p).unwrap_err();
    assert!(
        matches!(e, LocalizeError::TooFewPoints { need: 50, .. }),
        "{e}"
    );
    // The view is on another part of the plate than this (small) board covers.
    let small = Board::nominal(
        "small",
        0.5,
        0.25,
        Polarity::DarkOnLight,
        10,
        10,
        [0.0, 0.0],
    );
    let e = localize(&f.image, &small, &LocalizeParams::new(TRUTH)).unwrap_err();
    assert!(matches!(e, LocalizeError::OffBoard { .. }), "{e}");
    assert!(e.to_string().contains("10 x 10"), "{e}");
    // Nominal scale 5 um/px for a 4 um/px camera.
    p = LocalizeParams::new(TRUTH);
    p.um_per_px = Some(5.0);
    let e = localize(&f.image, &b, &p).unwrap_err();
    assert!(matches!(e, LocalizeError::ScaleMismatch { .. }), "{e}");
    assert!(e.to_string().contains("nominal 5 um/px by -20."), "{e}");
    // A board file with twice the dot size.
    let fat = Board::nominal("fat", 0.5, 0.4, Polarity::DarkOnLight, 200, 160, [0.0, 0.0]);
    let e = localize(&f.image, &fat, &LocalizeParams::new(TRUTH)).unwrap_err();
    assert!(matches!(e, LocalizeError::DotSizeMismatch { .. }), "{e}");
    // Bad parameters.
    p = LocalizeParams::new(TRUTH);
    p.min_points = 3;
    assert!(matches!(
        localize(&f.image, &b, &p),
        Err(LocalizeError::BadParams(_))
    ));
}

#[test]
fn points_off_the_board_are_ignored() {
    // The board ends at x = 20.0 mm (i = 40); the view spans about 18.8..21.4 mm.
    let full = Board::nominal(
        "full",
        0.5,
        0.25,
        Polarity::DarkOnLight,
        200,
        160,
        [0.0, 0.0],
    );
    let cut = Board::nominal("cut", 0.5, 0.25, Polarity::DarkOnLight, 41, 160, [0.0, 0.0]);
    let f = frame(&full, &camera(640, 512, 0.8, 1.0, 2.0, 0.4), TRUTH, 4);
    let all = localize(&f.image, &full, &LocalizeParams::new(TRUTH)).unwrap();
    let part = localize(&f.image, &cut, &LocalizeParams::new(TRUTH)).unwrap();
    assert!(part.points < all.points, "{part:?} vs {all:?}");
    assert!(err_um(&part, TRUTH) < 0.1, "{part:?}");
}

#[test]
fn certificate_errors_are_caught_by_the_robust_fit() {
    let b = board(Polarity::DarkOnLight);
    let f = small_frame(TRUTH);
    // One in-view point certified 3 um away from where it really is: rejected.
    let mut wrong = b.clone();
    let t = b.true_xy(40, 41).unwrap();
    wrong.set_true_xy(40, 41, [t[0] + 0.003, t[1]]);
    let o = localize(&f.image, &wrong, &LocalizeParams::new(TRUTH)).unwrap();
    assert_eq!(o.rejected, 1, "{o:?}");
    assert!(err_um(&o, TRUTH) < 0.05, "{o:?}");
    // The four-point method cannot use a rejected corner.
    let mut p = LocalizeParams::new(TRUTH);
    p.method = Method::FourPoint;
    let e = localize(&f.image, &wrong, &p).unwrap_err();
    assert!(matches!(e, LocalizeError::CellIncomplete { .. }), "{e}");
    assert!(e.to_string().contains("(40,41) rejected"), "{e}");

    // Every point off by a few micrometres: not a board this certificate describes.
    let mut rng = world::rng::Rng::new(9);
    let mut noisy = b.clone();
    for j in 35..46 {
        for i in 35..46 {
            let t = b.true_xy(i, j).unwrap();
            noisy.set_true_xy(
                i as u32,
                j as u32,
                [t[0] + 0.004 * rng.normal(), t[1] + 0.004 * rng.normal()],
            );
        }
    }
    let e = localize(&f.image, &noisy, &LocalizeParams::new(TRUTH)).unwrap_err();
    assert!(
        matches!(e, LocalizeError::ResidualTooLarge { limit_um: 2.0, .. }),
        "{e}"
    );
}

#[test]
fn a_dirty_dot_in_the_centre_cell() {
    let b = board(Polarity::DarkOnLight);
    let mut f = small_frame(TRUTH);
    // Wipe the dot nearest the image centre with background from the middle of a cell
    // (0.36 mm diagonally away, where no dot is).
    let c = f.image.centre();
    let d = f
        .dots
        .iter()
        .min_by(|a, b| {
            let da = (a.centre_px[0] - c[0]).hypot(a.centre_px[1] - c[1]);
            let db = (b.centre_px[0] - c[0]).hypot(b.centre_px[1] - c[1]);
            da.total_cmp(&db)
        })
        .unwrap()
        .centre_px;
    let w = f.image.width as i64;
    if let Pixels::Mono8(px) = &mut f.image.pixels {
        let (x0, y0) = (d[0].round() as i64, d[1].round() as i64);
        for dy in -36..=36 {
            for dx in -36..=36 {
                let src = (y0 + dy + 62) * w + x0 + dx + 62;
                px[((y0 + dy) * w + x0 + dx) as usize] = px[src as usize];
            }
        }
    }
    let o = localize(&f.image, &b, &LocalizeParams::new(TRUTH)).unwrap();
    assert!(err_um(&o, TRUTH) < 0.06, "{o:?}");
    let mut p = LocalizeParams::new(TRUTH);
    p.method = Method::FourPoint;
    let e = localize(&f.image, &b, &p).unwrap_err();
    assert!(matches!(e, LocalizeError::CellIncomplete { .. }), "{e}");
    assert!(e.to_string().contains("not identified"), "{e}");
}

#[test]
fn dots_from_8_to_150_pixels_without_knowing_the_scale() {
    // (um per pixel, frame): 0.25 mm dots of 8 px and of 150 px.
    for (um, w, h, max_rms) in [(31.25, 320, 256, 0.04), (1.6667, 960, 768, 0.01)] {
        let b = board(Polarity::DarkOnLight);
        let mut cam = camera(w, h, 1.0, 1.0, 3.0, 0.0);
        cam.um_per_px = um;
        let f = frame(&b, &cam, TRUTH, 2);
        let dots = detect_dots(&f.image, Polarity::DarkOnLight);
        let (rms, _, n) = dot_errors(&f, &dots);
        // Dots whose window (dot, edge band and a pixel) fits in the frame.
        let complete = f
            .dots
            .iter()
            .filter(|d| {
                let r = 125.0 / um + 4.0;
                d.centre_px[0] > r
                    && d.centre_px[1] > r
                    && d.centre_px[0] < w as f64 - r
                    && d.centre_px[1] < h as f64 - r
            })
            .count();
        assert!(
            n == dots.len() && n >= complete,
            "{um} um/px: {n} matched of {} found, {complete} complete",
            dots.len()
        );
        assert!(rms < max_rms, "{um} um/px: RMS {rms:.4} px");
        // Only 6 whole 150 px dots fit in the frame.
        let mut p = LocalizeParams::new(TRUTH);
        p.min_points = 6;
        let o = localize(&f.image, &b, &p).unwrap();
        assert!(err_um(&o, TRUTH) < 0.1, "{um} um/px: {o:?}");
        assert!((o.um_per_px / um - 1.0).abs() < 1e-3, "{o:?}");
    }
}

#[test]
fn settings_parse_print_and_serialise() {
    let a: PixelAxes = " +Y, -x ".parse().unwrap();
    assert_eq!(a.to_string(), "+y,-x");
    assert_eq!(a.to_board_aligned([1.0, 2.0]), [-2.0, 1.0]);
    assert_eq!(PixelAxes::default().to_string(), "+x,-y");
    assert!("+x,+x"
        .parse::<PixelAxes>()
        .unwrap_err()
        .contains("not perpendicular"));
    assert!("up,down".parse::<PixelAxes>().is_err());
    assert_eq!(serde_json::to_string(&a).unwrap(), "\"+y,-x\"");
    assert_eq!(
        serde_json::from_str::<PixelAxes>("\"-x,+y\"")
            .unwrap()
            .to_string(),
        "-x,+y"
    );
    assert_eq!(
        serde_json::to_string(&Method::FourPoint).unwrap(),
        "\"four-point\""
    );
    assert_eq!("four-point".parse::<Method>().unwrap(), Method::FourPoint);
    assert_eq!(Method::default(), Method::Fit);
    let p = LocalizeParams::new([1.0, 2.0]);
    assert_eq!(
        (
            p.method,
            p.um_per_px,
            p.hint_tolerance_mm,
            p.max_residual_um,
            p.min_points
        ),
        (Method::Fit, None, 0.1, 2.0, 8)
    );
}

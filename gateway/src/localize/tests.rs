//! Behaviour of the whole localizer on rendered frames.

use super::testkit::{board, camera, dot_errors, frame};
use super::*;
use protocol::Polarity;

fn err_um(o: &Observation, truth: [f64; 2]) -> f64 {
    (o.x_mm - truth[0]).hypot(o.y_mm - truth[1]) * 1000.0
}

#[test]
fn worst_case_frames_meet_the_accuracy_figures() {
    let b = board(Polarity::DarkOnLight);
    let cam = camera(1280, 1024, 2.0, 1.5, 4.0, 1.6);
    let truth = [20.1234, 20.3171];
    let f = frame(&b, &cam, truth, 7);
    let dots = detect_dots(&f.image, Polarity::DarkOnLight);
    let (rms, max, n) = dot_errors(&f, &dots);
    eprintln!("dots {} matched {n} rms {rms:.4} max {max:.4}", dots.len());
    let mut p = LocalizeParams::new([truth[0] + 0.03, truth[1] - 0.05]);
    p.um_per_px = Some(4.0);
    let o = localize(&f.image, &b, &p).unwrap();
    eprintln!("{o:?} err {:.4} um", err_um(&o, truth));
    p.method = Method::FourPoint;
    let o4 = localize(&f.image, &b, &p).unwrap();
    eprintln!("{o4:?} err {:.4} um", err_um(&o4, truth));
}

#[test]
#[ignore]
fn explore() {
    let b = board(Polarity::DarkOnLight);
    for (rot, blur, noise, dist, grad) in [
        (0.0, 1.5, 0.0, 0.0, 0.0),
        (2.0, 1.5, 0.0, 0.0, 0.0),
        (2.0, 1.5, 0.0, 1.6, 0.0),
        (2.0, 1.5, 0.0, 1.6, 0.15),
        (2.0, 0.7, 0.0, 1.6, 0.15),
        (2.0, 1.5, 4.0, 1.6, 0.15),
        (2.0, 0.7, 4.0, 1.6, 0.15),
        (2.0, 0.7, 2.0, 1.6, 0.15),
    ] {
        let mut cam = camera(1280, 1024, rot, blur, noise, dist);
        cam.illumination_gradient = grad;
        cam.vignetting = grad / 3.0;
        for seed in 0..2 {
            let truth = [20.1234 + 0.0013 * seed as f64, 20.3171];
            let f = frame(&b, &cam, truth, seed);
            let dots = detect_dots(&f.image, Polarity::DarkOnLight);
            let (rms, max, n) = dot_errors(&f, &dots);
            // mean signed error
            let (mut mx, mut my) = (0.0, 0.0);
            for d in &dots {
                if let Some(t) = f
                    .dots
                    .iter()
                    .find(|t| (t.centre_px[0] - d.x).hypot(t.centre_px[1] - d.y) < 2.0)
                {
                    mx += d.x - t.centre_px[0];
                    my += d.y - t.centre_px[1];
                }
            }
            let p = LocalizeParams::new(truth);
            let o = localize(&f.image, &b, &p).unwrap();
            eprintln!(
                "rot {rot} blur {blur} noise {noise} dist {dist} grad {grad}: n {n}/{} rms {rms:.4} max {max:.4} mean ({:.4},{:.4}) fit err {:.4} um",
                f.dots.len(),
                mx / n as f64,
                my / n as f64,
                err_um(&o, truth)
            );
        }
    }
}

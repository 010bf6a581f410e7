//! Volumetric model files and campaign instrument files (read from disk by the gateway).

use protocol::volumetric::{parse_instrument, parse_model, write_model, Structure};
use volumetric::ballbar::{circle, squareness, BALLBAR_COLUMNS};
use volumetric::camera::{combine, AnglePrior, CAMERA_COLUMNS};

/// The text as a ball-bar file (its header read, its circle fitted against an error-free
/// model) and as a camera file (combined with flat priors): refused or finite.
fn campaign_files(text: &str) {
    if let Ok(f) = parse_instrument(text, &BALLBAR_COLUMNS) {
        if let Ok(c) = circle("ballbar.csv", &f) {
            let base = volumetric::Model::zero(Structure::Xyfz, [500.0, 400.0, 400.0]);
            if let Ok(r) = squareness("ballbar.csv", &base, &c) {
                assert!(r
                    .harmonics
                    .iter()
                    .all(|v| v.is_finite() || !c.readings.iter().all(|x| x.1.is_finite())));
            }
        }
    }
    if let Ok(f) = parse_instrument(text, &CAMERA_COLUMNS) {
        let prior = |l: f64| AnglePrior {
            positions_mm: vec![0.0, l / 2.0, l],
            values: [vec![0.0; 3], vec![0.0; 3]],
            sigma: [1e-6, 1e-6],
        };
        let (px, py) = (prior(500.0), prior(400.0));
        if let Ok(fit) = combine(Structure::Xyfz, &f, [&px, &py]) {
            assert!(
                fit.values.iter().flatten().flatten().all(|v| v.is_finite())
                    || !fit.residual_rms_mm.is_finite()
            );
        }
    }
}

/// Any text as a volumetric model, instrument, squareness, points, ball-bar or camera
/// file: refused with a
/// line/column error or accepted; an accepted model is written back and read to the same
/// model, and a model that checks answers at its travel's corners and centre (exact,
/// first order, inverse) without panicking.
pub fn volumetric_model(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    protocol::volumetric::fuzz_parse(&text);
    campaign_files(&text);
    let Ok(file) = parse_model(&text) else {
        return;
    };
    let again = parse_model(&write_model(&file)).expect("written models read back");
    assert_eq!(again, file);
    let Ok(model) = volumetric::Model::new(file) else {
        return;
    };
    let t = model.travel();
    for q in [
        [t[0].0, t[1].0, t[2].0],
        [t[0].1, t[1].1, t[2].1],
        std::array::from_fn(|a| (t[a].0 + t[a].1) / 2.0),
    ] {
        let _ = model.error_exact(q);
        let _ = model.error_first_order(q);
        let _ = model.command_for(q);
    }
}

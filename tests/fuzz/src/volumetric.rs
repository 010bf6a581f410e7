//! Volumetric model files and campaign instrument files (read from disk by the gateway).

use protocol::volumetric::{parse_model, write_model};

/// Any text as a volumetric model, instrument, squareness or points file: refused with a
/// line/column error or accepted; an accepted model is written back and read to the same
/// model, and a model that checks answers at its travel's corners and centre (exact,
/// first order, inverse) without panicking.
pub fn volumetric_model(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    protocol::volumetric::fuzz_parse(&text);
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

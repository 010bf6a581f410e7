//! The ISO 230-2 measurements CSV (`gateway iso230 evaluate`).

use iso230::csv_io::{read, write};
use iso230::evaluate;

/// `iso230::csv_io::read`: a file that reads is evaluated (the reader has checked all
/// the standard asks, so the evaluation succeeds, every figure finite when the
/// deviations are of a sane size), and written back reads to the same measurements.
pub fn iso230_csv(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    let Ok(measurements) = read(&text) else {
        return;
    };
    let e = evaluate(&measurements).expect("a file that reads can be evaluated");
    assert!(e.positions.len() >= iso230::MIN_POSITIONS);
    let sane = measurements
        .iter()
        .all(|m| m.deviation_um.abs() < 1e12 && m.target_mm.abs() < 1e12);
    if sane {
        let f = e.figures;
        for v in [f.a, f.b, f.r, f.e, f.m, f.mean_reversal] {
            assert!(v.is_finite(), "{f:?}");
        }
        assert!(f.e >= f.e_up.max(f.e_down) && f.a >= f.a_up.max(f.a_down));
        // Written at 1 nm and 0.1 um: read back, the same positions and runs.
        let again = read(&write(&measurements)).expect("written files read back");
        assert_eq!(again.len(), measurements.len());
        for (a, b) in again.iter().zip(&measurements) {
            assert_eq!(
                (a.position_index, a.run, a.direction, &a.axis),
                (b.position_index, b.run, b.direction, &b.axis)
            );
            assert!(
                (a.deviation_um - b.deviation_um).abs() <= 0.0005 + 1e-9 * b.deviation_um.abs()
            );
        }
    }
}

//! The rotary table's centres file.

use rotary::{identify, parse_centres, write_centres, MachineConstants};

/// Any text as a centres file: rows or an error naming the line; rows read are written
/// again and read back the same (to the 6 decimals written), and identification from
/// them answers or refuses without panicking, with finite errors when it answers.
pub fn rotary_centres(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    let Ok(rows) = parse_centres(&text) else {
        return;
    };
    let again = parse_centres(&write_centres(&rows)).expect("written centres read back");
    assert_eq!(again.len(), rows.len());
    for (a, b) in rows.iter().zip(&again) {
        assert_eq!((a.axis, a.step, a.ball), (b.axis, b.step, b.ball));
        for (x, y) in [(a.x_mm, b.x_mm), (a.y_mm, b.y_mm), (a.z_mm, b.z_mm)] {
            assert!((x - y).abs() <= 5e-7 * x.abs().max(1.0), "{x} -> {y}");
        }
    }
    if let Ok(id) = identify(&rows, &MachineConstants::default()) {
        for (_, v) in id.errors.named() {
            assert!(!v.is_infinite(), "an infinite error from finite centres");
        }
    }
}

//! The bounds a job file's numbers share across its stage kinds (feeds, offsets,
//! serial rates, a drive axis's soft limits): one place, so each kind refuses the same
//! values naming its own key.

use protocol::config::{ConfigDoc, ConfigError};

/// Feeds a job may ask for, mm/min: below, a move of a millimetre takes over ten
/// minutes; above, no stage of this class moves.
pub const MIN_FEED_MM_MIN: f64 = 1.0;
pub const MAX_FEED_MM_MIN: f64 = 100_000.0;
/// The largest board offset from machine zero, mm.
pub const MAX_SETUP_OFFSET_MM: f64 = 10_000.0;
/// Serial rates a job may ask for, baud (termios' lowest to the fastest USB adapters').
pub const MIN_BAUD: u32 = 50;
pub const MAX_BAUD: u32 = 4_000_000;

/// A serial stage's `stage.baud`, named when outside [`MIN_BAUD`]..=[`MAX_BAUD`].
pub(crate) fn check_baud(doc: &ConfigDoc, baud: u32) -> Result<(), ConfigError> {
    if !(MIN_BAUD..=MAX_BAUD).contains(&baud) {
        return Err(doc.invalid(
            "stage.baud",
            format!("{baud}: must be {MIN_BAUD}..={MAX_BAUD} baud"),
        ));
    }
    Ok(())
}

/// An axis of a drive stage (Modbus, CANopen, LinuxCNC, DNC): its soft limits each
/// within [`MAX_SETUP_OFFSET_MM`] of zero and apart (`min_mm < max_mm`), its feed (when
/// given) [`MIN_FEED_MM_MIN`] to [`MAX_FEED_MM_MIN`]; `key` makes the axis's dotted key.
pub(crate) fn check_axis(
    doc: &ConfigDoc,
    key: &dyn Fn(&str) -> String,
    min_mm: f64,
    max_mm: f64,
    max_feed_mm_min: Option<f64>,
) -> Result<(), ConfigError> {
    for (k, v) in [("min_mm", min_mm), ("max_mm", max_mm)] {
        doc.in_range(&key(k), v, -MAX_SETUP_OFFSET_MM, MAX_SETUP_OFFSET_MM, "mm")?;
    }
    if !(min_mm < max_mm) {
        return Err(doc.invalid(&key("max_mm"), "soft limits need min_mm < max_mm"));
    }
    if let Some(f) = max_feed_mm_min {
        doc.in_range(
            &key("max_feed_mm_min"),
            f,
            MIN_FEED_MM_MIN,
            MAX_FEED_MM_MIN,
            "mm/min",
        )?;
    }
    Ok(())
}

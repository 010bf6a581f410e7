//! How numbers are written when a word is edited.

/// `value` with exactly `decimals` decimals, never in exponent notation (controllers
/// do not read `1e-5`) and never as `-0` (some read it as a sign error, and it is not
/// what a user would write). `None` for a value that has no G-code form (NaN, ±∞).
pub fn format_number(value: f64, decimals: usize) -> Option<String> {
    if !value.is_finite() {
        return None;
    }
    let text = format!("{value:.decimals$}");
    let is_zero = text.bytes().all(|b| matches!(b, b'-' | b'0' | b'.'));
    Some(match text.strip_prefix('-') {
        Some(unsigned) if is_zero => unsigned.to_string(),
        _ => text,
    })
}

/// Length of the number at the start of `s`, RS-274 syntax: an optional sign, digits
/// with at most one decimal point, at least one digit. `0` when there is none.
pub(crate) fn number_len(s: &[u8]) -> usize {
    let mut i = usize::from(matches!(s.first(), Some(b'+' | b'-')));
    let (mut digits, mut point) = (0, false);
    while let Some(&c) = s.get(i) {
        match c {
            b'0'..=b'9' => digits += 1,
            b'.' if !point => point = true,
            _ => break,
        }
        i += 1;
    }
    if digits == 0 {
        0
    } else {
        i
    }
}

/// The value of a number [`number_len`] accepted (`1.`, `.5`, `+2`, `-.5` included).
pub(crate) fn number_value(text: &str) -> f64 {
    text.parse()
        .or_else(|_| format!("{text}0").parse())
        .unwrap_or(f64::NAN)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fixed_decimals_without_exponent_or_negative_zero() {
        assert_eq!(format_number(1.5, 3).as_deref(), Some("1.500"));
        assert_eq!(format_number(2.0, 0).as_deref(), Some("2"));
        assert_eq!(format_number(-0.0, 3).as_deref(), Some("0.000"));
        assert_eq!(format_number(-0.0004, 3).as_deref(), Some("0.000"));
        assert_eq!(format_number(-0.4, 0).as_deref(), Some("0"));
        assert_eq!(format_number(-0.0006, 3).as_deref(), Some("-0.001"));
        assert_eq!(format_number(1e-7, 4).as_deref(), Some("0.0000"));
        assert_eq!(
            format_number(1e20, 1).as_deref(),
            Some("100000000000000000000.0")
        );
        assert_eq!(format_number(f64::NAN, 3), None);
        assert_eq!(format_number(f64::INFINITY, 3), None);
    }

    #[test]
    fn numbers_are_read_as_rs274_writes_them() {
        for (text, len, value) in [
            ("1.", 2, 1.0),
            (".5", 2, 0.5),
            ("-.5", 3, -0.5),
            ("+2", 2, 2.0),
            ("007", 3, 7.0),
            ("1.2.3", 3, 1.2),
        ] {
            assert_eq!(number_len(text.as_bytes()), len, "{text}");
            assert_eq!(number_value(&text[..len]), value, "{text}");
        }
        for text in [".", "-", "+", "-.", "", "--1", "e5"] {
            assert_eq!(number_len(text.as_bytes()), 0, "{text}");
        }
    }
}

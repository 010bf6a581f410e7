//! Showing text that came from outside (a device, a data file) in a message.
//!
//! One wording everywhere: printable ASCII is shown as is, every other byte as `\xNN`
//! (a tab, carriage return or line feed as `\t`, `\r`, `\n`), and long input is cut with
//! the total count, so raw binary garbage from a device or a stray control character in
//! a file can neither garble a terminal nor hide in an invisible character.

/// How many characters of escaped text [`escape_bytes`] shows before cutting.
pub const SHOWN_CHARS: usize = 80;

/// `bytes` escaped and, past [`SHOWN_CHARS`] characters, truncated with
/// `… (N bytes)` where N is the length of the whole input.
pub fn escape_bytes(bytes: &[u8]) -> String {
    escape_bytes_max(bytes, SHOWN_CHARS)
}

/// [`escape_bytes`] with a chosen limit on the shown characters.
pub fn escape_bytes_max(bytes: &[u8], max_chars: usize) -> String {
    let mut out = String::new();
    for &b in bytes {
        let piece = escape_byte(b);
        if out.len() + piece.len() > max_chars {
            out.push_str(&format!("… ({} bytes)", bytes.len()));
            return out;
        }
        out.push_str(&piece);
    }
    out
}

/// How many bytes [`hex_bytes`] shows before cutting.
pub const SHOWN_HEX_BYTES: usize = 16;

/// Binary device bytes (a Modbus RTU frame, a CAN payload) as hex, `01 83 02 C0 F1`;
/// past [`SHOWN_HEX_BYTES`] bytes cut with `… (N bytes)` as [`escape_bytes`] does.
pub fn hex_bytes(bytes: &[u8]) -> String {
    let shown: Vec<String> = bytes
        .iter()
        .take(SHOWN_HEX_BYTES)
        .map(|b| format!("{b:02X}"))
        .collect();
    let mut out = shown.join(" ");
    if bytes.len() > SHOWN_HEX_BYTES {
        out.push_str(&format!(" … ({} bytes)", bytes.len()));
    }
    out
}

/// A text with its non-printable characters escaped (`\xNN` for ASCII controls,
/// `\u{XXXX}` for invisible or control Unicode characters such as a byte-order mark),
/// not truncated: for names and values from files, whose length the file bounds.
pub fn escape_text(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        if c.is_ascii() {
            out.push_str(&escape_byte(c as u8));
        } else if c.is_control() || is_invisible(c) {
            out.push_str(&format!("\\u{{{:04X}}}", c as u32));
        } else {
            out.push(c);
        }
    }
    out
}

fn is_invisible(c: char) -> bool {
    matches!(c,
        '\u{00A0}' | '\u{00AD}' | '\u{034F}' | '\u{061C}' | '\u{115F}' | '\u{1160}'
        | '\u{17B4}' | '\u{17B5}' | '\u{180B}'..='\u{180E}' | '\u{2000}'..='\u{200F}'
        | '\u{2028}'..='\u{202F}' | '\u{205F}'..='\u{206F}' | '\u{3000}' | '\u{3164}'
        | '\u{FE00}'..='\u{FE0F}' | '\u{FEFF}' | '\u{FFA0}' | '\u{FFF0}'..='\u{FFFB}')
}

fn escape_byte(b: u8) -> String {
    match b {
        b'\t' => "\\t".to_string(),
        b'\r' => "\\r".to_string(),
        b'\n' => "\\n".to_string(),
        b'\\' => "\\\\".to_string(),
        0x20..=0x7E => (b as char).to_string(),
        _ => format!("\\x{b:02X}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn printable_ascii_is_shown_as_is_and_the_rest_escaped() {
        assert_eq!(escape_bytes(b"ok"), "ok");
        assert_eq!(
            escape_bytes(b"<Idle|\x00\xFF>\r\n"),
            "<Idle|\\x00\\xFF>\\r\\n"
        );
        assert_eq!(escape_bytes(b"a\\b"), "a\\\\b");
    }

    #[test]
    fn long_input_is_cut_with_the_total_count() {
        let garbage: Vec<u8> = (0..=255u8).cycle().take(1000).collect();
        let s = escape_bytes(&garbage);
        assert!(s.ends_with("… (1000 bytes)"), "{s}");
        assert!(
            s.chars().count() <= SHOWN_CHARS + "… (1000 bytes)".len(),
            "{s}"
        );
        // Never cut inside an escape.
        let head = s.trim_end_matches("… (1000 bytes)");
        assert!(!head.ends_with('\\') && head.len() <= SHOWN_CHARS, "{s}");
        // Exactly at the limit: shown whole.
        let exact = vec![b'a'; SHOWN_CHARS];
        assert_eq!(escape_bytes(&exact), "a".repeat(SHOWN_CHARS));
    }

    #[test]
    fn binary_bytes_are_shown_in_hex_and_cut_with_the_count() {
        assert_eq!(hex_bytes(&[0x01, 0x83, 0x02, 0xC0, 0xF1]), "01 83 02 C0 F1");
        assert_eq!(hex_bytes(&[]), "");
        let long: Vec<u8> = (0..40).collect();
        let s = hex_bytes(&long);
        assert!(
            s.starts_with("00 01 02") && s.ends_with("0F … (40 bytes)"),
            "{s}"
        );
    }

    #[test]
    fn invisible_characters_in_text_are_made_visible() {
        assert_eq!(escape_text("\u{FEFF}i,j"), "\\u{FEFF}i,j");
        assert_eq!(escape_text("x\u{7}y"), "x\\x07y");
        assert_eq!(escape_text("Größe µm"), "Größe µm");
    }
}

//! The dialect-neutral NC layer: lexer and program.

use protocol::nc::{lex, Program};

/// Any text: the lexer's tokens cover each line exactly; a program that parses is
/// written back byte for byte and parses again to the same program.
pub fn nc_program(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    for (n, line) in text.split(['\n', '\r']).enumerate().take(200) {
        let mut covered = String::new();
        let mut failed = false;
        for token in lex(line, n + 1) {
            match token {
                Ok(t) => covered.push_str(t.text),
                Err(_) => failed = true,
            }
        }
        if failed {
            assert!(line.starts_with(&covered), "tokens {covered:?} of {line:?}");
        } else {
            assert_eq!(covered, line, "the tokens must cover the line");
        }
    }
    if let Ok(program) = Program::parse(&text) {
        let written = program.to_string();
        assert_eq!(
            written, text,
            "a parsed program must be written back as read"
        );
        assert_eq!(Program::parse(&written).ok().as_ref(), Some(&program));
    }
}

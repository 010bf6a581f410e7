//! The controller's dialect, one check for every rewrite: the 3-axis rewriter
//! ([`crate::Rewriter`]) and the 5-axis rotary rewrite (`rotary::rewrite`, on a grblHAL
//! six-axis build) read each line here, so both refuse exactly what GRBL would refuse,
//! naming the line: what its line filter cannot take (overflow, real-time characters,
//! non-ASCII), then GRBL's own interpreter ([`Interpreter`], generic over 3 to 6 axes):
//! unknown or repeated words, numbers GRBL cannot read (`X1e308`), modal group clashes,
//! a feed motion without a feed (`F0`, or a G93 block without its own F), and the rest
//! of `gc_execute_line`'s checks, in GRBL's order.
//!
//! A rewrite that splits a move into pieces cannot keep inverse-time feed (G93): each
//! piece would need its own F, the duration of its part of the move; such moves are
//! refused with [`RewriteErrorKind::InverseTime`] by both rewriters.

use crate::{RewriteError, RewriteErrorKind};
use protocol::grbl::gcode::{filter_line, Action, Interpreter, Motion, Plane};
use protocol::nc::Block;

/// What the controller makes of one line (its text without the line ending, `line_no`
/// from 1): the parsed block and what the interpreter does for it, or `None` for a line
/// GRBL's filter leaves empty (blank, only comments, an unclosed `(`), which goes as
/// written. On an error the interpreter is unchanged (GRBL's rule: a refused block
/// changes nothing).
///
/// The line is read as GRBL 1.1h reads it (protocol.c, checked on the firmware): its
/// filter first drops spaces, `/` anywhere and comments (a `(` without `)` runs to the
/// end of the line), so `X6 0` is `X60`; what is left goes to the interpreter, which
/// refuses `%` (a program delimiter GRBL does not support) with error:1. The block
/// keeps the line as written (comments, spaces) when the dialect-neutral reader sees the
/// same words there; otherwise it is the filtered text GRBL executes.
pub fn read_line<const N: usize>(
    interpreter: &mut Interpreter<N>,
    text: &str,
    line_no: usize,
) -> Result<Option<(Block, Vec<Action<N>>)>, RewriteError> {
    let fail = |kind| RewriteError {
        line: line_no,
        kind,
    };
    let filtered = filter_line(text).map_err(|e| fail(RewriteErrorKind::Filter(e)))?;
    if filtered.is_empty() {
        return Ok(None);
    }
    let actions = interpreter
        .execute(&filtered, false)
        .map_err(|code| fail(RewriteErrorKind::Refused { code }))?;
    // The interpreter read the filtered text with the same lexer, so it parses.
    let executed =
        Block::parse(&filtered, line_no).map_err(|e| fail(RewriteErrorKind::Syntax(e)))?;
    let block = match Block::parse(text, line_no) {
        Ok(written) if same_words(&written, &executed) => written,
        _ => executed,
    };
    Ok(Some((block, actions)))
}

/// The same words (letters and values) in the same order.
fn same_words(a: &Block, b: &Block) -> bool {
    a.words()
        .map(|w| (w.letter(), w.value()))
        .eq(b.words().map(|w| (w.letter(), w.value())))
}

/// Takes the controller's modal state from its `$G` reply (the words inside `[GC:...]`,
/// e.g. `G1 G54 G17 G21 G90 G94 M5 M9 T0 F500 S0`): motion, coordinate system, plane,
/// units, distance and feed modes, and the feed. `Err` names a word that is not a
/// number after its letter; nothing changes then.
pub fn sync_modal<const N: usize>(
    interpreter: &mut Interpreter<N>,
    gc_words: &str,
) -> Result<(), String> {
    let bad = |w: &str| format!("`{w}` in the $G reply `{gc_words}`");
    let mut modal = interpreter.modal;
    let mut feed = interpreter.feed_rate;
    for w in gc_words.split_whitespace() {
        // Split after the first character, not the first byte: a corrupted reply may
        // hold any bytes.
        let mut chars = w.chars();
        let letter = chars.next().map(String::from).unwrap_or_default();
        let (letter, number) = (letter.as_str(), chars.as_str());
        let value: f64 = number.parse().map_err(|_| bad(w))?;
        match (letter, number) {
            ("G", "0") => modal.motion = Motion::Rapid,
            ("G", "1") => modal.motion = Motion::Linear,
            ("G", "2") => modal.motion = Motion::ArcCw,
            ("G", "3") => modal.motion = Motion::ArcCcw,
            ("G", "80") => modal.motion = Motion::None,
            ("G", n) if n.starts_with("38.") => {
                modal.motion = Motion::Probe(n[3..].parse().map_err(|_| bad(w))?)
            }
            ("G", "17") => modal.plane = Plane::XY,
            ("G", "18") => modal.plane = Plane::ZX,
            ("G", "19") => modal.plane = Plane::YZ,
            ("G", "20") => modal.inches = true,
            ("G", "21") => modal.inches = false,
            ("G", "90") => modal.incremental = false,
            ("G", "91") => modal.incremental = true,
            ("G", "93") => modal.inverse_time = true,
            ("G", "94") => modal.inverse_time = false,
            ("G", _) if (54.0..=59.0).contains(&value) && value.fract() == 0.0 => {
                modal.coord_select = value as usize - 54;
            }
            ("G", _) => {}
            ("F", _) if value.is_finite() && value >= 0.0 => feed = value,
            ("F", _) => return Err(bad(w)),
            _ => {}
        }
    }
    interpreter.modal = modal;
    interpreter.feed_rate = feed;
    interpreter.coord_system = interpreter.stored[modal.coord_select];
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The refusals both rewriters share, on three axes and on six.
    #[test]
    fn what_grbl_refuses_is_refused_naming_the_line() {
        let cases: [(&str, &str); 7] = [
            ("G1 X1 X2 F100", "error:25"),
            // R and offsets in one arc: GRBL 1.1h leaves I/J/K unused (issue 38).
            ("G2 X60 Y50 I5 J5 R50 F600", "error:36"),
            ("G0 X1e308", "error:2"),
            ("G1 X1 F0", "error:22"),
            ("G1 X1 Q5 F100", "error:20"),
            ("G93 G1 X1", "error:22"),
            (
                "G0 X1 ?",
                "`?`, which GRBL would take as a real-time command",
            ),
        ];
        for (text, want) in cases {
            let mut three = Interpreter::new();
            let e = read_line(&mut three, text, 7).unwrap_err();
            assert_eq!(e.line, 7);
            assert!(e.to_string().contains(want), "{text}: {e}");
            let mut six = Interpreter::<6>::with_axes();
            let e = read_line(&mut six, text, 7).unwrap_err();
            assert!(e.to_string().contains(want), "{text} (6 axes): {e}");
        }
        let mut six = Interpreter::<6>::with_axes();
        assert!(read_line(&mut six, "G1 X1 A30 C45 F100", 1)
            .unwrap()
            .is_some());
        let e = read_line(&mut six, "G1 A1 A2", 2).unwrap_err();
        assert!(e.to_string().contains("error:25"), "{e}");
        let e = read_line(&mut six, "%", 3).unwrap_err();
        assert!(e.to_string().contains("error:1"), "{e}");
        assert!(read_line(&mut six, "(only a comment)", 4)
            .unwrap()
            .is_none());
    }

    #[test]
    fn modal_state_from_a_dollar_g_reply() {
        let mut i = Interpreter::<6>::with_axes();
        sync_modal(&mut i, "G1 G55 G17 G21 G90 G93 M5 M9 T0 F500 S0").unwrap();
        assert!(i.modal.inverse_time);
        assert_eq!(i.modal.coord_select, 1);
        assert_eq!(i.feed_rate, 500.0);
        assert!(sync_modal(&mut i, "G1 Fx").is_err());
        assert!(sync_modal(&mut i, "F-5").is_err());
    }
}

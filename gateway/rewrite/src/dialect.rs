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
/// without words (blank, a comment, a `%` delimiter), which goes as written. On an error
/// the interpreter is unchanged (GRBL's rule: a refused block changes nothing).
pub fn read_line<const N: usize>(
    interpreter: &mut Interpreter<N>,
    text: &str,
    line_no: usize,
) -> Result<Option<(Block, Vec<Action<N>>)>, RewriteError> {
    let fail = |kind| RewriteError {
        line: line_no,
        kind,
    };
    let block = Block::parse(text, line_no).map_err(|e| fail(RewriteErrorKind::Syntax(e)))?;
    if block.has_no_words() {
        return Ok(None);
    }
    let filtered = filter_line(text).map_err(|e| fail(RewriteErrorKind::Filter(e)))?;
    let actions = interpreter
        .execute(&filtered, false)
        .map_err(|code| fail(RewriteErrorKind::Refused { code }))?;
    Ok(Some((block, actions)))
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
            ("G0 X1 ?", "found `?`"),
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
        assert!(read_line(&mut six, "%", 3).unwrap().is_none());
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

//! The Fanuc dialect of a closed controller's tape (`protocol::fanuc`).

use protocol::fanuc::{arc_points, parse_line, Action, Interpreter, Line, Options};

/// Any text as a tape, line by line (the emulator's and the rewriter's reading): a
/// refused block names its line and leaves the interpreter unchanged; an accepted one
/// writes back to the same block; positions stay finite; arcs give a bounded number of
/// chords ending at the arc's end.
pub fn fanuc_tape(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    let calculator = data.first().is_some_and(|b| b & 1 == 1);
    let mut interp = Interpreter::new(
        Options {
            calculator_input: calculator,
            ..Options::default()
        },
        [0.0; 3],
    );
    for (i, raw) in text.split('\n').enumerate().take(300) {
        let line_no = i + 1;
        let raw = raw.trim_end_matches('\r');
        let block = match parse_line(raw, line_no) {
            Ok(Line::Block(b)) => b,
            Ok(_) => continue,
            Err(e) => {
                assert_eq!(e.line, line_no, "{e}");
                continue;
            }
        };
        // The block's own writing reads back to the same block.
        let again = parse_line(&block.to_string(), line_no);
        assert_eq!(again, Ok(Line::Block(block.clone())), "{raw:?}");
        let before = interp.clone();
        let from = interp.position;
        match interp.execute(&block, line_no, raw) {
            Err(e) => {
                assert_eq!(e.line, line_no, "{e}");
                assert_eq!(interp, before, "a refused block changed the state");
            }
            Ok(actions) => {
                for a in &actions {
                    match a {
                        Action::Arc { to, .. } => {
                            let pts = arc_points(from, a, 0.001);
                            assert!(!pts.is_empty() && pts.len() <= 100_000);
                            assert_eq!(pts.last(), Some(to));
                            assert!(
                                pts.iter().flatten().all(|v| v.is_finite())
                                    || !to.iter().all(|v| v.is_finite())
                            );
                        }
                        Action::Dwell { seconds } => assert!(*seconds >= 0.0),
                        _ => {}
                    }
                }
            }
        }
    }
}

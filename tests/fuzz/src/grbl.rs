//! GRBL: response lines through the line decoder, status reports, and the G-code
//! line filter and interpreter.

use protocol::grbl::gcode::{filter_bytes, filter_line, Interpreter, LINE_BUFFER_SIZE};
use protocol::grbl::response::{LineDecoder, Response, MAX_LINE};
use protocol::grbl::status::StatusReport;

/// Bytes from a controller: the line decoder fed whole and in small chunks gives the
/// same responses and never keeps more than a line; every line's status report, if
/// it parses, is written back and parses again to the same state and axes.
pub fn grbl_response(data: &[u8]) {
    let Some((&seed, data)) = data.split_first() else {
        return;
    };
    let mut whole = Vec::new();
    let mut d = LineDecoder::new();
    d.feed(data, &mut whole);
    assert!(d.pending().len() <= MAX_LINE);

    let mut pieces = Vec::new();
    let mut d = LineDecoder::new();
    crate::chunked(data, seed, |c| {
        d.feed(c, &mut pieces);
        assert!(d.pending().len() <= MAX_LINE);
    });
    assert_eq!(whole, pieces, "the chunking changed the responses");
    assert!(whole.len() <= data.len());

    for r in &whole {
        let _ = r.is_line_response();
        if let Response::Other(s) = r {
            // Shown text of a device line stays short (escaped, cut).
            assert!(s.chars().count() <= 200, "{} characters", s.chars().count());
        }
    }
    for line in String::from_utf8_lossy(data).split('\n') {
        let _ = Response::parse(line);
        if let Ok(report) = StatusReport::parse(line) {
            let written = report.to_line(4);
            let again = StatusReport::parse(&written)
                .unwrap_or_else(|e| panic!("{line:?} written as {written:?}: {e}"));
            assert_eq!(again.state, report.state, "{written:?}");
            assert_eq!(again.position_kind, report.position_kind, "{written:?}");
            assert_eq!(again.position.len(), report.position.len(), "{written:?}");
            let _ = report.machine_position(None);
        }
    }
}

/// A program sent to GRBL: every line through the byte filter and the host-side line
/// check, then through one interpreter (lines starting `$J=` as jogs), with its
/// `$G` state read after each line. A six-axis interpreter (X Y Z A B C) runs beside it:
/// a refused line leaves it unchanged too, and on a line without A, B or C it answers
/// exactly as the three-axis one.
pub fn grbl_gcode(data: &[u8]) {
    let mut interp = Interpreter::new();
    let mut six = Interpreter::<6>::with_axes();
    let mut diverged = false;
    for raw in data.split(|&b| b == b'\n').take(64) {
        let (filtered, overflow) = filter_bytes(raw);
        // GRBL's buffer counts the bytes kept: one character each here.
        assert!(filtered.chars().count() < LINE_BUFFER_SIZE, "{filtered:?}");
        if let Ok(text) = std::str::from_utf8(raw) {
            if let Ok(checked) = filter_line(text) {
                assert_eq!(checked, filtered);
            }
        }
        if overflow {
            continue;
        }
        let (line, jog) = match filtered.strip_prefix("$J=") {
            Some(rest) => (rest, true),
            None => (filtered.as_str(), false),
        };
        let before = interp.parser_state();
        let six_before = six.clone();
        let six_result = six.execute(line, jog);
        if six_result.is_err() {
            assert_eq!(six, six_before, "a refused line changed the six-axis state");
        }
        let rotary_words = line.contains(['A', 'B', 'C']);
        let three_result = interp.clone().execute(line, jog);
        // A line with A B C words that one accepts and the other refuses leaves their
        // states apart (feed, motion mode, position): from then on they may differ.
        if rotary_words && six_result.is_ok() != three_result.is_ok() {
            diverged = true;
        }
        if !rotary_words && !diverged {
            assert_eq!(
                six_result.as_ref().map(Vec::len),
                three_result.as_ref().map(Vec::len),
                "{line:?}: six axes and three answer differently"
            );
        }
        match interp.execute(line, jog) {
            Ok(actions) => {
                // Arcs come as chords: at most GRBL's segment count, plus the rest.
                assert!(actions.len() <= u16::MAX as usize + 8, "{}", actions.len());
            }
            Err(code) => {
                assert!(code > 0, "error code 0 for {line:?}");
                assert_eq!(
                    interp.parser_state(),
                    before,
                    "a refused line changed the state"
                );
            }
        }
        let _ = interp.parser_state_with(true);
        let _ = interp.wco();
    }
}

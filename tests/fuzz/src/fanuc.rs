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

/// A smooth stand-in for a map (a 5 mm-period screw error in X, a squareness in Y),
/// known on -300..300 mm.
pub(crate) struct Smooth;

impl rewrite::Compensation for Smooth {
    fn describe(&self) -> String {
        "smooth".into()
    }
    fn axes(&self) -> &[usize] {
        &[0, 1]
    }
    fn feature_length_mm(&self) -> f64 {
        1.0
    }
    fn command_for(
        &self,
        p: &rewrite::Pose,
        _: &[rewrite::Approach; rewrite::N_AXIS],
    ) -> Result<rewrite::Pose, String> {
        if !(-300.0..=300.0).contains(&p[0]) || !(-300.0..=300.0).contains(&p[1]) {
            return Err("outside".into());
        }
        let k = std::f64::consts::TAU / 5.0;
        Ok([p[0] - 0.003 * (k * p[0]).sin(), p[1] - 40e-6 * p[0], p[2]])
    }
}

/// Any text as a Fanuc program (its subprograms after M30) through
/// `rewrite::fanuc::rewrite_fanuc` (start known, a smooth stand-in map): a refusal names
/// a line of the program; an accepted tape is `%`-framed and every block on it reads and
/// runs on the controller's interpreter in sequence, within the block length. The same
/// text line by line through `FanucStream` (a live sender's tape) gives the same blocks.
pub fn fanuc_rewrite(data: &[u8]) {
    use rewrite::fanuc::{rewrite_fanuc, FanucOptions};
    let text = String::from_utf8_lossy(data);
    if text.len() > 4000 {
        return;
    }
    let options = FanucOptions {
        start: Some([10.0, 10.0, 0.0]),
        tolerance_mm: 0.005,
        max_output_bytes: 1 << 20,
        ..FanucOptions::default()
    };
    let max_block = options.max_block_chars;
    // The same text as a live sender sends it, line by line (`FanucStream`): a refusal
    // names one of its lines; a tape taken whole both ways is the same tape.
    let mut stream =
        rewrite::fanuc::FanucStream::new(None, &Smooth, &options).expect("the options are valid");
    let mut live = Some(String::new());
    for line in text.split('\n') {
        match stream.push_line(line) {
            Ok(out) => {
                if let Some(l) = live.as_mut() {
                    l.push_str(&out);
                }
            }
            Err(e) => {
                assert!(e.line <= text.split('\n').count(), "{e}");
                live = None;
                break;
            }
        }
    }
    // The whole rewrite frames its tape with `%` whatever the text has.
    let blocks = |t: &str| -> Vec<String> {
        t.lines()
            .filter(|l| *l != "%")
            .map(str::to_string)
            .collect()
    };
    if let (Some(live), Ok((whole, _))) =
        (&live, rewrite_fanuc(&text, None, &Smooth, options.clone()))
    {
        assert_eq!(blocks(live), blocks(&whole));
    }
    match rewrite_fanuc(&text, None, &Smooth, options) {
        Err(e) => assert!(e.line <= text.split('\n').count(), "{e}"),
        Ok((out, report)) => {
            assert!(out.starts_with("%\n") && out.ends_with("\n%\n"), "{out:?}");
            let mut interp = Interpreter::new(Options::default(), [10.0, 10.0, 0.0]);
            let mut blocks = 0;
            for (n, line) in out.lines().enumerate() {
                assert!(line.len() <= max_block, "{line:?}");
                let block = match parse_line(line, n + 1) {
                    Ok(Line::Block(b)) => b,
                    Ok(_) => continue,
                    Err(e) => panic!("the rewritten tape's line {}: {e}\n{out}", n + 1),
                };
                blocks += 1;
                if block.program_number().is_none() {
                    interp
                        .execute(&block, n + 1, line)
                        .unwrap_or_else(|e| panic!("{e}\n{out}"));
                }
            }
            assert_eq!(blocks, report.blocks_out, "{out}");
        }
    }
}

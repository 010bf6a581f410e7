//! The program rewriter and the pass-through's state machine: what a sender and a
//! controller may send.

use proxy::Proxy;
use rewrite::{rewrite_program, Approach, Compensation, Options, Pose, Rewriter, N_AXIS};

/// A smooth stand-in for a map: a 5 mm-period screw error in X, a squareness in Y, known
/// on 0..300 mm.
struct Smooth;

impl Compensation for Smooth {
    fn describe(&self) -> String {
        "smooth".into()
    }
    fn axes(&self) -> &[usize] {
        &[0, 1]
    }
    fn feature_length_mm(&self) -> f64 {
        1.0
    }
    fn command_for(&self, p: &Pose, _: &[Approach; N_AXIS]) -> Result<Pose, String> {
        if !(0.0..=300.0).contains(&p[0]) || !(0.0..=300.0).contains(&p[1]) {
            return Err("outside".into());
        }
        let k = std::f64::consts::TAU / 5.0;
        Ok([p[0] - 0.003 * (k * p[0]).sin(), p[1] - 40e-6 * p[0], p[2]])
    }
}

/// Any program: the rewrite refuses it naming a line inside it, or every line with words
/// it writes is one GRBL accepts in sequence (the same interpreter, started where the
/// rewrite started), and the report counts what was written.
pub fn nc_rewrite(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    if text.len() > 4000 {
        return;
    }
    let options = Options {
        start: Some([10.0, 10.0, 0.0]),
        tolerance_mm: 0.005,
        ..Options::default()
    };
    match rewrite_program(&text, &Smooth, options) {
        // Lines as the rewriter counts them: `\n`, `\r\n` or a lone `\r` ends one.
        Err(e) => assert!(
            e.line <= protocol::nc::split_lines(&text).count().max(1),
            "{e}"
        ),
        Ok((out, report)) => {
            let lines: Vec<&str> = protocol::nc::split_lines(&out).map(|(l, _)| l).collect();
            assert_eq!(lines.len(), report.output_lines, "{out:?}");
            let mut interp = protocol::grbl::gcode::Interpreter::new();
            interp.position = [10.0, 10.0, 0.0];
            for (n, line) in lines.into_iter().enumerate() {
                // `$` lines and lines without words (comments, `%`) pass as written:
                // what the controller makes of them is its business, as without the
                // gateway.
                let wordless = protocol::nc::Block::parse(line, n + 1)
                    .map(|b| b.has_no_words())
                    .unwrap_or(false);
                if line.trim_start().starts_with('$') || wordless {
                    continue;
                }
                let f = protocol::grbl::gcode::filter_line(line)
                    .unwrap_or_else(|e| panic!("`{line}` cannot go to GRBL: {e}"));
                interp
                    .execute(&f, false)
                    .unwrap_or_else(|c| panic!("GRBL refuses `{line}` with error:{c}"));
            }
        }
    }
}

/// Sender and controller bytes interleaved (each chunk's first byte says whose the rest
/// is): never a panic; the controller's buffer never holds more than GRBL's 128 bytes
/// (one piece at most when a single piece is longer); every line is accounted for once,
/// in order.
pub fn proxy_stream(data: &[u8]) {
    let rewriter = Rewriter::new(&Smooth, Options::default()).expect("valid options");
    let mut p = Proxy::new(rewriter, &Smooth);
    p.start();
    let mut t = 0.0;
    for chunk in data.chunks(16) {
        let (head, rest) = chunk.split_first().expect("chunks are not empty");
        t += 0.01;
        if head & 0x80 == 0 {
            p.from_sender(rest, t);
        } else {
            p.from_controller(rest, t);
        }
        p.take_to_sender();
        p.take_to_controller();
        assert!(
            p.in_flight_bytes() <= proxy::RX_BUFFER || p.in_flight_pieces() == 1,
            "{} bytes in the controller's buffer",
            p.in_flight_bytes()
        );
    }
    let a = p.account();
    let mut all: Vec<u64> = [a.acknowledged, a.refused, a.in_controller, a.not_sent].concat();
    let n = all.len();
    all.sort_unstable();
    all.dedup();
    assert_eq!(all.len(), n, "a line accounted twice");
}

use super::*;
use crate::{Approach, Identity};

/// The tool lands 12 um short in X and 5 um long in Y everywhere: the command is the
/// nominal point + (0.012, -0.005).
struct Shift;

impl Compensation for Shift {
    fn describe(&self) -> String {
        "shift".into()
    }
    fn axes(&self) -> &[usize] {
        &[0, 1]
    }
    fn command_for(&self, p: &Pose, _: &[Approach; N_AXIS]) -> Result<Pose, String> {
        Ok([p[0] + 0.012, p[1] - 0.005, p[2]])
    }
}

fn rewrite(text: &str) -> Result<(String, FanucReport), FanucError> {
    rewrite_fanuc(text, None, &Shift, FanucOptions::default())
}

/// The end points of every motion block of a tape as the controller runs it (the
/// subprograms expanded by the caller), machine mm.
fn ends(tape: &str) -> Vec<[f64; 3]> {
    let mut i = Interpreter::new(protocol::fanuc::Options::default(), [0.0; 3]);
    let mut out = Vec::new();
    for (k, l) in tape.lines().enumerate() {
        if let Line::Block(b) = parse_line(l, k + 1).unwrap() {
            for a in i.execute(&b, k + 1, l).unwrap() {
                match a {
                    Action::Rapid { to } | Action::Linear { to, .. } => {
                        out.push(to.map(|v: f64| (v * 1e6).round() / 1e6))
                    }
                    _ => {}
                }
            }
        }
    }
    out
}

#[test]
fn a_polygon_keeps_percent_o_and_n_and_lands_on_the_corrected_points() {
    let program = "%\nO1234(SQUARE)\nN10G90G17G21G54\nN20G00X10Y10.\nN30G01X50.F600\nN40Y40.\nN50X10.\nN60Y10.\nN70M30\n%\n";
    let (out, report) = rewrite(program).unwrap();
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(lines[0], "%");
    assert_eq!(lines[1], "O1234");
    assert_eq!(*lines.last().unwrap(), "%");
    // `X10` is 0.010 mm by the decimal-point rule (DPI = 0): written with its point.
    assert!(out.contains("N20G00X0.022Y9.995\n"), "{out}");
    // Y does not move: not written.
    assert!(out.contains("N30G01X50.012F600.\n"), "{out}");
    assert!(out.contains("N70M30\n"), "{out}");
    assert_eq!(
        ends(&out),
        vec![
            [0.022, 9.995, 0.0],
            [50.012, 9.995, 0.0],
            [50.012, 39.995, 0.0],
            [10.012, 39.995, 0.0],
            [10.012, 9.995, 0.0]
        ]
    );
    assert_eq!(report.program_number, Some(1234));
    assert_eq!(report.moves_compensated, 5);
    // Every number of an axis or feed has its point.
    for l in out.lines() {
        let b = match parse_line(l, 1).unwrap() {
            Line::Block(b) => b,
            _ => continue,
        };
        for w in &b.words {
            if matches!(w.letter, 'X' | 'Y' | 'Z' | 'F') {
                assert!(w.point, "{l}");
            }
        }
    }
}

#[test]
fn incremental_moves_and_an_inch_program() {
    let (out, _) = rewrite("G90G00X1.Y1.\nG91G01X2.Y0F100\nX-1.\n").unwrap();
    assert!(out.contains("G91G01X2.Y0.F100.\n"), "{out}");
    assert!(out.contains("G01X-1.\n"), "{out}");
    assert_eq!(ends(&out).last().unwrap(), &[2.012, 0.995, 0.0]);
    // Inch: 0.0001 in increments (IS-B); 12 um is 0.00047 in, rounded to 0.0005.
    let (out, _) = rewrite("G20G90G00X1.Y1.\n").unwrap();
    assert!(out.contains("G20G90G00X1.0005Y0.9998\n"), "{out}");
}

#[test]
fn arcs_become_chords_that_stay_on_the_corrected_circle() {
    for arc in ["G02X20.Y0R5.", "G03X20.Y0R-5.", "G02X20.Y0I5.J0"] {
        let (out, report) = rewrite(&format!("G90G00X10.Y0\nG01F300.\n{arc}\nM30\n")).unwrap();
        assert!(report.segments_added > 4, "{arc}: {out}");
        assert!(!out.contains("G02") && !out.contains('R'), "{arc}: {out}");
        for p in ends(&out).iter().skip(1) {
            let r = (p[0] - 15.012).hypot(p[1] + 0.005);
            assert!((r - 5.0).abs() < 0.0015, "{arc}: {p:?} at radius {r}");
        }
    }
}

#[test]
fn subprograms_are_expanded_where_they_run() {
    let program = "%\nO1\nG90G00X0Y0\nG01F500.\nM98P28003\nM30\nO8003\nN1G91X10.\nN2Y10.\nM99\n%\n";
    let (out, report) = rewrite(program).unwrap();
    assert_eq!(report.calls_expanded, 2);
    assert!(!out.contains("M98") && !out.contains("M99"), "{out}");
    assert!(out.contains("(CALL O8003 2 OF 2)"), "{out}");
    assert_eq!(ends(&out).last().unwrap(), &[20.012, 19.995, 0.0]);
    // Stored subprograms come from a second text.
    let (out2, _) = rewrite_fanuc(
        "O1\nG90G00X0Y0\nG01F500.\nM98P28003\nM30\n",
        Some("%\nO8003\nN1G91X10.\nN2Y10.\nM99\n%\n"),
        &Shift,
        FanucOptions::default(),
    )
    .unwrap();
    assert_eq!(out, out2);
}

#[test]
fn g92_dwells_offsets_and_the_block_skip() {
    let (out, _) =
        rewrite("G90G00X10.Y10.\nG04X1500\nG92X0Y0\nG01X5.F100.\n/G00X50.\nG10L2P1X1\n").unwrap();
    // The dwell goes as written; G92 is moved by the correction at the present point.
    assert!(out.contains("\nG04X1500\n"), "{out}");
    assert!(out.contains("\nG92X0.012Y-0.005\n"), "{out}");
    // After the shift, X5. is 15 mm in machine coordinates: commanded at 15.012.
    assert_eq!(ends(&out)[1], [15.012, 9.995, 0.0]);
    assert!(!out.contains("X50."), "skipped (switch on): {out}");
    assert!(out.contains("G10L2P1X0.001\n"), "{out}");
    let options = FanucOptions {
        program: protocol::fanuc::Options {
            block_skip: false,
            ..Default::default()
        },
        ..FanucOptions::default()
    };
    let (out, _) = rewrite_fanuc("G90G00X10.Y10.\n/G00X50.\n", None, &Identity, options).unwrap();
    assert!(out.contains("\nG00X50.\n"), "{out}");
}

#[test]
fn what_cannot_be_rewritten_is_refused_naming_the_block() {
    for (program, line, what) in [
        ("G90G00X1.Y1.\nG41X5.\n", 2, "G41"),
        ("G91G01X1.F100.\n", 1, "unknown position"),
        ("G00X1.\n", 1, "Y position is not known"),
        (
            "G90G00X1.Y1.\nM98P9001\nM30\n",
            2,
            "O9001 is not on the tape",
        ),
        ("G90G00X1.Y1.\nM99\n", 2, "M99 in the main program"),
        ("G90G00X1.Y1.\nX5.M98P8001\n", 2, "block of its own"),
        ("G90G00X1.Y1.\nM30\nG00X5.\n", 3, "only subprograms"),
        ("G90G00X1.Y1.\nM30\nO8001\nG00X1.\n", 3, "no M99"),
        ("G90G00X1.Y1.\nG01X99999.999F100.\n", 2, "digits"),
        ("G90G00X1.Y1.\ng01x2.\n", 2, "ISO"),
    ] {
        let e = rewrite(program).expect_err(program);
        assert_eq!(e.line, line, "{program}: {e}");
        assert!(e.to_string().contains(what), "{program}: {e}");
        assert!(e.to_string().starts_with(&format!("block {line} ")), "{e}");
    }
    let tight = FanucOptions {
        max_block_chars: 16,
        ..FanucOptions::default()
    };
    let e = rewrite_fanuc("G90G00X100.Y100.Z-10.\n", None, &Shift, tight).unwrap_err();
    assert!(e.to_string().contains("max_block_chars"), "{e}");
    // Inside a subprogram the call is named too.
    let e = rewrite("G90G00X0Y0\nM98P8001\nM30\nO8001\nG68X0Y0R45.\nM99\n").unwrap_err();
    assert_eq!(e.line, 5);
    assert!(e.to_string().contains("called from line 2"), "{e}");
}

#[test]
fn tv_padding_makes_every_block_even() {
    let options = FanucOptions {
        tv_pad: true,
        ..FanucOptions::default()
    };
    let (out, _) = rewrite_fanuc("G90G00X1.Y1.\nG01X2.F10.\n", None, &Shift, options).unwrap();
    for l in out
        .lines()
        .filter(|l| !l.starts_with('%') && !l.starts_with('('))
    {
        assert_eq!(l.len() % 2, 0, "`{l}`");
    }
}

#[test]
fn a_work_system_chosen_in_the_moving_block_applies_to_its_move() {
    let (out, _) = rewrite("G10L2P2X20.Y15.\nG55G90G00X20.Y20.\nG54G01X1.Y1.F100.\n").unwrap();
    assert!(out.contains("G55G90G00X20.012Y19.995\n"), "{out}");
    assert_eq!(ends(&out), vec![[40.012, 34.995, 0.0], [1.012, 0.995, 0.0]]);
}

/// A tape rewritten line by line as it arrives is the tape rewritten whole (stored
/// subprograms expanded the same way); a block after M30 on a live tape is refused
/// naming it, and a refused block names its line.
#[test]
fn a_live_tape_rewritten_line_by_line_is_the_whole_rewrite() {
    let program = "%\nO1234\nN10G90G00X10Y10.\nN20G01X50.F600\nN30G02X60.Y20.R10.\nM98P28001\nN40G91G01X-5.Y2.5\nM30\n%\n";
    let stored = "O8001\nG91G01X1.Y-1.\nM99\n";
    let options = FanucOptions::default();
    let (whole, report) = rewrite_fanuc(program, Some(stored), &Shift, options.clone()).unwrap();
    let mut stream = FanucStream::new(Some(stored), &Shift, &options).unwrap();
    let mut live = String::new();
    for line in program.lines() {
        live.push_str(&stream.push_line(line).unwrap());
    }
    assert_eq!(live, whole);
    let streamed = stream.finish();
    assert_eq!(streamed.blocks_out, report.blocks_out);
    assert_eq!(streamed.calls_expanded, 2);
    assert_eq!(streamed.largest_correction_um, report.largest_correction_um);

    let mut stream = FanucStream::new(None, &Shift, &options).unwrap();
    for line in ["%", "G90G00X1.Y1.", "M30"] {
        stream.push_line(line).unwrap();
    }
    let e = stream.push_line("O8001").unwrap_err();
    assert_eq!((e.line, e.text.as_str()), (4, "O8001"));
    assert!(e.message.contains("stored subprograms"), "{e:?}");
    let mut stream = FanucStream::new(None, &Shift, &options).unwrap();
    stream.push_line("%").unwrap();
    stream.push_line("G90G00X1.Y1.").unwrap();
    let e = stream.push_line("G41X2.").unwrap_err();
    assert_eq!((e.line, e.text.as_str()), (3, "G41X2."));
}

#[test]
fn exact_stop_mode_goes_as_written_and_g09_stops_at_the_programmed_point() {
    // A half circle in G61 with G09: it becomes chords, the first with the block's
    // number and G61, the last with the G09.
    let program = "%\nO1\nN10G90G00X0Y0\nN20G61G09G02X20.Y0R10.F300\nN30G64G01X30.\nN40M30\n%\n";
    let (out, _) = rewrite(program).unwrap();
    let blocks: Vec<&str> = out
        .lines()
        .filter(|l| l.contains("G01") || l.contains("G00"))
        .collect();
    let arc: Vec<&str> = blocks
        .iter()
        .copied()
        .skip_while(|l| !l.starts_with("N20"))
        .take_while(|l| !l.starts_with("N30"))
        .collect();
    assert!(arc.len() > 3, "chords: {out}");
    assert!(arc[0].starts_with("N20G61G01"), "{out}");
    assert_eq!(out.matches("G09").count(), 1, "{out}");
    assert!(arc.last().unwrap().starts_with("G09G01"), "{out}");
    assert!(out.contains("\nN30G64G01X30.012\n"), "{out}");
    // The chords end on the shifted half circle: its end point where the arc ends.
    let ends = ends(&out);
    assert_eq!(ends[ends.len() - 2], [20.012, -0.005, 0.0], "{out}");
}

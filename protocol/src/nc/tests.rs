//! Round trip, edits and error positions of the nc layer.

use super::*;

fn round_trip(text: &str) -> String {
    Program::parse(text).unwrap().to_string()
}

fn block(line: &str) -> Block {
    Block::parse(line, 1).unwrap()
}

#[test]
fn programs_round_trip_byte_identical() {
    for text in [
        "",
        "\n",
        "G0 X1\n",
        "G0 X1",
        "%\r\n(header)\r\nN10 G21 G90\r\n\r\n/N20 g1 x 01.500 y-.5 f1200. ; feed\r\nM30\r\n%\r\n",
        "  \t G1X1Y2 (a) (b);c\n\n\n  \n",
        "N1\rN2\rN3",
        "  / N5  G0 ( spaced ) X+1.0\tY -2 \n",
        "(only a comment)\n;only another\n%\n",
        "G1 X1 (nested ( opens are text)\n",
    ] {
        assert_eq!(round_trip(text), text, "{text:?}");
    }
}

/// Random programs from fragments that cover every token kind, spacing and case; each
/// must come back unchanged.
#[test]
fn random_programs_round_trip() {
    const FRAGMENTS: &[&str] = &[
        "G1",
        "g0",
        "X1.5",
        "x -2.",
        "Y.25",
        "Z+3",
        "F1200",
        "S 100",
        "N7",
        "n8",
        "(c)",
        "( two words )",
        " ",
        "  ",
        "\t",
        "M30",
        "T01",
        "I-0",
        "J0.000",
    ];
    const STARTS: &[&str] = &["", "/", " /", "%", "N10 ", "/N5"];
    const ENDINGS: &[&str] = &["\n", "\r\n", "\r", ";tail\n", " ; x\r\n"];
    let mut seed: u64 = 0x2545_f491_4f6c_dd1d;
    let mut next = |n: usize| {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed % n as u64) as usize
    };
    for _ in 0..500 {
        let mut text = String::new();
        for _ in 0..next(6) {
            text.push_str(STARTS[next(STARTS.len())]);
            for _ in 0..next(7) {
                text.push_str(FRAGMENTS[next(FRAGMENTS.len())]);
            }
            text.push_str(ENDINGS[next(ENDINGS.len())]);
        }
        // A word letter directly followed by a fragment's sign or digit would merge two
        // fragments into one word; that is still a program and must still round-trip.
        assert_eq!(round_trip(&text), text, "{text:?}");
    }
}

#[test]
fn block_structure() {
    let b = block(" /N10 G1 x1.5 (cut) Y2 ;end");
    assert!(b.block_delete);
    assert_eq!(b.line_no.as_ref().map(Word::value), Some(10.0));
    let letters: String = b.words().map(Word::letter).collect();
    assert_eq!(letters, "NGXY");
    assert_eq!(b.word('x').map(Word::text), Some("x1.5"));
    assert_eq!(b.word('X').map(Word::value), Some(1.5));
    let comments: Vec<_> = b.comments().map(Comment::body).collect();
    assert_eq!(comments, ["cut", "end"]);
    assert!(block("(just a note)").has_no_words());
    assert_eq!(block("%").items, [Item::ProgramMarker]);
    let later_n = block("G1 N5");
    assert_eq!(later_n.line_no, None, "only a first N is the line number");
    assert_eq!(later_n.word('N').map(Word::value), Some(5.0));
}

#[test]
fn edited_words_keep_the_rest_of_the_line() {
    let mut b = block("N10 g1 x 1.50 (keep) Y2 ; note");
    b.set_word('X', 2.0, 3).unwrap();
    b.set_word('y', -0.0001, 3).unwrap();
    assert_eq!(b.to_string(), "N10 g1 x2.000 (keep) Y0.000 ; note");
    b.set_word('F', 1500.0, 0).unwrap();
    assert_eq!(b.to_string(), "N10 g1 x2.000 (keep) Y0.000 F1500 ; note");
    b.set_word('N', 20.0, 0).unwrap();
    assert_eq!(b.to_string(), "N20 g1 x2.000 (keep) Y0.000 F1500 ; note");
    assert_eq!(b.word('X').map(Word::value), Some(2.0));
}

#[test]
fn words_are_added_in_the_block_style() {
    let mut compact = block("G1X1");
    compact.set_word('Z', 0.5, 2).unwrap();
    assert_eq!(compact.to_string(), "G1X1Z0.50");
    let mut spaced = block("(note) ;end");
    spaced.set_word('G', 0.0, 0).unwrap();
    assert_eq!(spaced.to_string(), "G0 (note) ;end");
    let mut empty = Block::new();
    empty.set_word('x', 1.0, 1).unwrap();
    empty.set_word('N', 5.0, 0).unwrap();
    assert_eq!(empty.to_string(), "N5X1.0");
    let mut numbered = block("G0 X1");
    numbered.set_word('N', 7.0, 0).unwrap();
    assert_eq!(numbered.to_string(), "N7 G0 X1");
}

#[test]
fn removing_a_word_removes_one_space_next_to_it() {
    let mut b = block("N1 G1 X1 Y2 (c)");
    assert_eq!(b.remove_word('X').map(|w| w.value()), Some(1.0));
    assert_eq!(b.to_string(), "N1 G1 Y2 (c)");
    b.remove_word('N');
    assert_eq!(b.to_string(), "G1 Y2 (c)");
    b.remove_word('G');
    assert_eq!(b.to_string(), "Y2 (c)");
    assert_eq!(b.remove_word('Q'), None);
}

#[test]
fn refused_edits_change_nothing() {
    let mut b = block("G1 X1");
    assert_eq!(
        b.set_word('X', f64::NAN, 3).unwrap_err().to_string(),
        "XNaN cannot be written as a G-code number (not finite)"
    );
    assert_eq!(b.set_word('#', 1.0, 3), Err(EditError::NotALetter('#')));
    assert_eq!(b.to_string(), "G1 X1");
}

#[test]
fn inserted_blocks_get_a_line_ending() {
    let mut p = Program::parse("G0 X0\r\nM30\r\n").unwrap();
    p.blocks.insert(1, block("G1 X5"));
    assert_eq!(p.to_string(), "G0 X0\r\nG1 X5\r\nM30\r\n");
}

#[test]
fn program_errors_name_every_bad_line() {
    let err = Program::parse("G0 X1\nG1 X#2\n(ok)\n  G1 (open\nG1 % \n").unwrap_err();
    let found: Vec<_> = err
        .errors
        .iter()
        .map(|e| (e.position.line, e.position.column, e.kind, e.text.as_str()))
        .collect();
    assert_eq!(
        found,
        [
            (2, 4, ErrorKind::ExpectedNumber { letter: 'X' }, "X#2"),
            (4, 6, ErrorKind::UnclosedComment, "(open"),
            (5, 4, ErrorKind::MisplacedPercent, "%"),
        ]
    );
    assert_eq!(
        err.to_string(),
        "3 line(s) could not be read\n  \
         line 2, column 4: expected a number after `X`, found `X#2`\n  \
         line 4, column 6: comment not closed by `)` on this line, found `(open`\n  \
         line 5, column 4: program marker `%` is only allowed at the start of a line, found `%`"
    );
}

//! The rotary table's centres file.

use rotary::{identify, parse_centres, write_centres, MachineConstants};

/// Any text as a centres file: rows or an error naming the line; rows read are written
/// again and read back the same (to the 6 decimals written), and identification from
/// them answers or refuses without panicking, with finite errors when it answers.
pub fn rotary_centres(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    let Ok(rows) = parse_centres(&text) else {
        return;
    };
    let again = parse_centres(&write_centres(&rows)).expect("written centres read back");
    assert_eq!(again.len(), rows.len());
    for (a, b) in rows.iter().zip(&again) {
        assert_eq!((a.axis, a.step, a.ball), (b.axis, b.step, b.ball));
        for (x, y) in [(a.x_mm, b.x_mm), (a.y_mm, b.y_mm), (a.z_mm, b.z_mm)] {
            // Half a unit of the 6th decimal, plus the binary representation's slack.
            assert!(
                (x - y).abs() <= 5e-7 + 1e-12 + 1e-15 * x.abs(),
                "{x} -> {y}"
            );
        }
    }
    if let Ok(id) = identify(&rows, &MachineConstants::default()) {
        for (_, v) in id.errors.named() {
            assert!(!v.is_infinite(), "an infinite error from finite centres");
        }
    }
}

/// Any text as the rotary JSON files: the errors file (`LocationErrors::from_json`, what
/// `gateway rotary identify --json` writes) and the measurement job
/// (`job::rotary::RotaryJob::from_json`). Accepted errors are within their checks and
/// give finite commands; an accepted job builds its simulated machine.
pub fn rotary_json(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    if let Ok(e) = rotary::LocationErrors::from_json(&text) {
        assert!(e.check().is_ok());
        let m = rotary::RotaryMachine::with_errors(rotary::MachineConstants::default(), e);
        if let Ok(cmd) = m.command_for(&rotary::Axes::new(0.0, 0.0, -190.0, 30.0, 45.0)) {
            assert!([cmd.x, cmd.y, cmd.z, cmd.a, cmd.c]
                .iter()
                .all(|v| v.is_finite()));
        }
    }
    if let Ok(job) = job::rotary::RotaryJob::from_json(&text) {
        let _ = job.simulated();
    }
}

/// Any text as a `[PRB:...]` line: a report or a refusal; a report is written back and
/// read again to the same axes count and flag, positions within GRBL's 3 decimals.
pub fn grbl_probe(data: &[u8]) {
    use protocol::grbl::probe::ProbeReport;
    let text = String::from_utf8_lossy(data);
    let Ok(r) = ProbeReport::parse_line(&text) else {
        return;
    };
    assert!((3..=6).contains(&r.position.len()));
    if r.position.iter().all(|v| v.abs() < 1e12) {
        let again = ProbeReport::parse_line(&r.to_line()).expect("written reports read back");
        assert_eq!(again.touched, r.touched);
        assert_eq!(again.position.len(), r.position.len());
        for (a, b) in r.position.iter().zip(&again.position) {
            assert!((a - b).abs() <= 5e-4 + 1e-12 * a.abs(), "{a} -> {b}");
        }
    }
}

/// Any text as a 5-axis program through `rotary::rewrite::rewrite_program` (the paper's
/// table, default tolerances): a refusal names a line of the program; a rewrite reads
/// back as a program, writes at least one point per move, and has no more blocks than
/// lines plus pieces added.
pub fn rotary_rewrite(data: &[u8]) {
    use rotary::rewrite::{rewrite_program, RewriteError, RewriteOptions};
    let text = String::from_utf8_lossy(data);
    let model = rotary::RotaryMachine::with_errors(
        rotary::MachineConstants::default(),
        rotary::LocationErrors::paper(),
    );
    let opts = RewriteOptions {
        max_depth: 4,
        ..RewriteOptions::default()
    };
    match rewrite_program(&text, &model, &opts) {
        Ok((out, report)) => {
            let again = protocol::nc::Program::parse(&out).expect("a rewrite reads back");
            assert!(report.points.len() >= report.moves);
            assert_eq!(again.blocks.len(), report.lines + report.pieces_added);
        }
        Err(RewriteError::Refused { line, .. }) => {
            // Lines as the NC layer counts them (a lone CR ends a line too).
            let lines = protocol::nc::split_lines(&text).count();
            assert!(line >= 1 && line <= lines.max(1), "line {line} of {lines}");
        }
        Err(RewriteError::Parse(_)) => {}
    }
}

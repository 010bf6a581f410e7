//! Readers added with issue 25: the controller's saved `$#` reply, a volumetric
//! campaign's files, the rotary errors file's machine constants, programs read as a
//! bounded stream of lines, and the one G-code dialect check both rewrites share.

use protocol::grbl::gcode::Interpreter;

/// Any text as a saved `$#` reply (`procedure::rewrite::read_parameters`): refused
/// naming a line (field `offsets`), or offsets that are finite, within the bound, taken
/// by the rewriter, and that read back the same when written as the controller writes
/// them.
pub fn dollar_hash(data: &[u8]) {
    use procedure::rewrite::{read_parameters, MAX_OFFSET_MM};
    let text = String::from_utf8_lossy(data);
    let Ok((stored, g92)) = read_parameters(&text) else {
        return;
    };
    for v in stored.iter().flatten().chain(g92.iter()) {
        assert!(v.is_finite() && v.abs() <= MAX_OFFSET_MM, "{v}");
    }
    let options = rewrite::Options {
        work_offsets: stored,
        g92_offset: g92,
        ..Default::default()
    };
    let mut r =
        rewrite::Rewriter::new(&rewrite::Identity, options).expect("offsets in bounds are taken");
    let _ = r.line("G0 X1 Y2 Z3", 1);
    let mut again = String::new();
    for (k, o) in stored.iter().enumerate() {
        again.push_str(&format!("[G{}:{},{},{}]\n", 54 + k, o[0], o[1], o[2]));
    }
    again.push_str(&format!("[G92:{},{},{}]\nok\n", g92[0], g92[1], g92[2]));
    assert_eq!(
        read_parameters(&again).expect("written offsets read back"),
        (stored, g92)
    );
}

/// A campaign from one text: sections starting with a line `### <file name>` (one of
/// the campaign's files, `laser_X.csv` ... `camera.csv`), read by
/// `volumetric::identify::Campaign::from_files` and identified (XYFZ): refused naming a
/// file, or identified with finite errors wherever the campaign's readings are finite.
pub fn volumetric_campaign(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    let mut files: Vec<(String, String)> = Vec::new();
    for line in text.split_inclusive('\n') {
        if let Some(name) = line.strip_prefix("### ") {
            files.push((name.trim().to_string(), String::new()));
        } else if let Some(f) = files.last_mut() {
            f.1.push_str(line);
        }
    }
    let Ok(campaign) = volumetric::identify::Campaign::from_files(&files) else {
        return;
    };
    let structure = protocol::volumetric::Structure::Xyfz;
    if let Ok(id) = volumetric::identify::identify(structure, &campaign) {
        let written = protocol::volumetric::write_model(&id.model.file);
        let again = protocol::volumetric::parse_model(&written)
            .expect("an identified model is written and read back");
        assert_eq!(again.tables.len(), id.model.file.tables.len());
    }
}

/// Any text as a rotary errors file with its machine constants: the errors
/// (`LocationErrors::from_json`), the constants it records
/// (`MachineConstants::from_errors_json`) and the choice a rewrite makes
/// (`MachineConstants::for_errors`): the stored constants when none are given, the
/// given ones when they agree or are forced, a refusal naming the difference otherwise;
/// the chosen constants check and the model answers a point with finite commands or
/// refuses.
pub fn rotary_errors(data: &[u8]) {
    use rotary::{Axes, LocationErrors, MachineConstants, RotaryMachine};
    let text = String::from_utf8_lossy(data);
    let Ok(stored) = MachineConstants::from_errors_json(&text) else {
        return;
    };
    if let Some(k) = stored {
        assert!(k.check().is_ok());
    }
    let chosen = MachineConstants::for_errors(stored, None, false).expect("nothing given: taken");
    assert_eq!(chosen, stored.unwrap_or_default());
    let given = MachineConstants::default();
    assert_eq!(
        MachineConstants::for_errors(stored, Some(given), true),
        Ok(given)
    );
    match MachineConstants::for_errors(stored, Some(given), false) {
        Ok(k) => assert_eq!(k, given),
        Err(e) => assert!(stored.is_some() && e.contains("in the errors file"), "{e}"),
    }
    if let Ok(errors) = LocationErrors::from_json(&text) {
        let m = RotaryMachine::with_errors(chosen, errors);
        if let Ok(c) = m.command_for(&Axes::new(0.0, 0.0, -190.0, 30.0, 45.0)) {
            assert!([c.x, c.y, c.z, c.a, c.c].iter().all(|v| v.is_finite()));
        }
    }
}

/// Any bytes as a program file read as a bounded stream of lines
/// (`protocol::config::open_lines`, through a temporary file: it takes a path): every
/// line is within the line cap; when every line reads, their texts with their endings
/// are the file (a leading byte-order mark dropped); an error ends the stream and names
/// the file and the line.
pub fn program_lines(data: &[u8]) {
    use protocol::config::{open_lines, DataKind, MAX_LINE_BYTES};
    use std::io::Write;
    let path = std::env::temp_dir().join(format!("fuzz-program-lines-{}.nc", std::process::id()));
    {
        let mut f = std::fs::File::create(&path).expect("a temporary file");
        f.write_all(data).expect("written");
    }
    let lines = open_lines(&path, DataKind::Program).expect("a regular file opens");
    let mut text = String::new();
    let mut failed = false;
    let mut count = 0;
    for item in lines.keep_endings() {
        count += 1;
        match item {
            Ok((n, l)) => {
                assert_eq!(n, count);
                assert!(l.len() <= MAX_LINE_BYTES + 2);
                text.push_str(&l);
            }
            Err(e) => {
                assert!(!failed, "the stream ends at its first error");
                failed = true;
                let m = e.to_string();
                assert!(m.contains(&format!("line {count}:")), "{m}");
                assert!(m.contains(&path.display().to_string()), "{m}");
            }
        }
    }
    let _ = std::fs::remove_file(&path);
    if !failed {
        let whole = std::str::from_utf8(data).expect("every line read: the file is UTF-8");
        assert_eq!(text, whole.strip_prefix('\u{FEFF}').unwrap_or(whole));
    }
}

/// Any program through the one dialect check (`rewrite::dialect::read_line`) on GRBL's
/// three axes and on a six-axis build, line by line: a refused line changes neither
/// interpreter and names its line; lines without A, B or C words are accepted or
/// refused alike by both (the 3-axis and the 5-axis rewrites refuse the same things).
pub fn gcode_dialect(data: &[u8]) {
    use rewrite::dialect::read_line;
    let text = String::from_utf8_lossy(data);
    let mut three = Interpreter::new();
    let mut six = Interpreter::<6>::with_axes();
    for (k, (line, _)) in protocol::nc::split_lines(&text).enumerate().take(200) {
        let before3 = three.clone();
        let before6 = six.clone();
        let r3 = read_line(&mut three, line, k + 1);
        let r6 = read_line(&mut six, line, k + 1);
        if let Err(e) = &r3 {
            assert_eq!(e.line, k + 1);
            assert_eq!(format!("{:?}", three.modal), format!("{:?}", before3.modal));
            assert_eq!(three.position, before3.position);
        }
        if let Err(e) = &r6 {
            assert_eq!(e.line, k + 1);
            assert_eq!(six.position, before6.position);
        }
        let rotary_words = line
            .chars()
            .any(|c| matches!(c.to_ascii_uppercase(), 'A' | 'B' | 'C'));
        if !rotary_words {
            assert_eq!(
                r3.as_ref().err().map(|e| e.to_string()),
                r6.as_ref().err().map(|e| e.to_string()),
                "line {line:?}"
            );
        }
        if r3.is_err() != r6.is_err() {
            // The interpreters part ways on this line (A B C words): start both again.
            three = Interpreter::new();
            six = Interpreter::<6>::with_axes();
        }
    }
}

/// Any text as a map's reference record (`procedure::reference::parse_record`, what
/// `gateway reference` writes beside the map and `rewrite`/`proxy` read): refused, or a
/// record whose numbers are finite, whose shift is within the bound, and that reads back
/// when written again.
pub fn reference_record(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    let Ok(r) = procedure::reference::parse_record(&text, "record") else {
        return;
    };
    for v in r.seen_um.iter().chain(&r.shift_um).chain(&r.reference_mm) {
        assert!(v.is_finite(), "{v}");
    }
    assert!(r.shift_um[0].hypot(r.shift_um[1]) <= errormap::reference::MAX_SHIFT_UM);
    // Issue 38: a count that would wrap, seen errors of 1e308, two times that disagree.
    assert!((1..=errormap::reference::MAX_REFERENCE_COUNT).contains(&r.reference_count));
    assert!(r
        .seen_um
        .iter()
        .all(|v| v.abs() <= errormap::reference::MAX_SEEN_UM));
    // Issue 39: an axis scale within its bounds, its rate too.
    if let Some(s) = &r.scale {
        assert!(s.at_mm.iter().all(|v| v.is_finite()));
        assert!(s
            .seen_um
            .iter()
            .all(|v| v.abs() <= errormap::reference::MAX_SEEN_UM));
        assert!(s
            .ppm
            .iter()
            .all(|v| v.abs() <= errormap::reference::MAX_RECORDED_SCALE_PPM));
        for v in s.ppm_per_h.iter().flatten() {
            assert!(v.abs() <= errormap::reference::MAX_SCALE_RATE_PPM_PER_H);
        }
        let ppm = r.predicted_scale_ppm(u64::MAX);
        assert!(ppm.iter().all(|v| v.abs() <= errormap::MAX_SCALE_PPM));
    }
    let again = serde_json::to_string(&r).expect("a record serializes");
    procedure::reference::parse_record(&again, "again").expect("a written record reads back");
}

#[cfg(test)]
mod tests {
    /// The seeds reach past the readers: the simulated campaign identifies, the GRBL
    /// reply gives its G55 and G92 offsets.
    #[test]
    fn the_seeds_reach_the_models() {
        let dir = crate::fuzz_dir().join("corpus");
        let text =
            std::fs::read_to_string(dir.join("volumetric_campaign/simulated_xyfz.txt")).unwrap();
        let mut files: Vec<(String, String)> = Vec::new();
        for line in text.split_inclusive('\n') {
            if let Some(name) = line.strip_prefix("### ") {
                files.push((name.trim().to_string(), String::new()));
            } else if let Some(f) = files.last_mut() {
                f.1.push_str(line);
            }
        }
        let c = volumetric::identify::Campaign::from_files(&files).unwrap();
        assert!(volumetric::identify::identify(protocol::volumetric::Structure::Xyfz, &c).is_ok());
        let reply = std::fs::read_to_string(dir.join("dollar_hash/grbl_reply.txt")).unwrap();
        let (stored, g92) = procedure::rewrite::read_parameters(&reply).unwrap();
        assert_eq!((stored[1], g92), ([10.0, -5.5, 0.0], [20.0, 0.0, -1.25]));
        let e = std::fs::read_to_string(dir.join("rotary_errors/other_machine.json")).unwrap();
        assert!(rotary::MachineConstants::for_errors(
            rotary::MachineConstants::from_errors_json(&e).unwrap(),
            Some(rotary::MachineConstants::default()),
            false
        )
        .is_err());
    }
}

//! Error map files and scan journals (both written by the gateway, read back from disk).

use errormap::scan::{journal, ScanPlan, ScanSpec};
use errormap::{Direction, MapModel};
use protocol::errormap::ErrorMap;

/// Any text as a map file: refused with an error or accepted; an accepted map is written
/// back and read again to the same map, and the model answers at its corners and
/// centre (inside the extent) without panicking.
pub fn error_map_json(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    let Ok(map) = ErrorMap::from_json("fuzz.json", &text) else {
        return;
    };
    let again = ErrorMap::from_json("fuzz.json", &map.to_json()).expect("written maps read back");
    assert_eq!(again, map);
    let model = MapModel::new(map);
    let (lo, hi) = model.extent();
    for p in [lo, hi, [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0]] {
        for dir in [Direction::FORWARD, Direction::REVERSE] {
            let _ = model.camera_error_um(p, dir);
            let _ = model.tool_error_um(p, dir);
            let _ = model.command_for(p, dir);
        }
    }
}

/// The header every fuzzed journal is read against (the seeds carry it).
pub fn scan_journal_header(plan: &ScanPlan) -> journal::Header {
    let identity = protocol::errormap::Identity {
        machine: "sim".into(),
        controller: "sim".into(),
        board: "b".into(),
        certificate_sha256: "00".into(),
        camera: "cam".into(),
    };
    journal::Header::new("job.toml", identity, plan)
}

/// The small plan every fuzzed journal is read against.
pub fn scan_journal_plan() -> ScanPlan {
    let spec = ScanSpec {
        grid_step_mm: 5.0,
        line_step_mm: 5.0,
        passes: 1,
    };
    ScanPlan::new([0.0, 0.0], [10.0, 10.0], spec).expect("a valid plan")
}

/// Any bytes as the journal of a small scan: samples or an error naming the line. What
/// is read holds: only indices of the plan, each once, possible values only; the kept
/// part ends at a newline and the torn tail is the rest (at most one line); the kept
/// part alone reads the
/// same with no tail; a sample appended after it is read back as a line of its own;
/// the samples written again read back the same.
pub fn scan_journal(data: &[u8]) {
    let plan = scan_journal_plan();
    let header = scan_journal_header(&plan);
    let Ok(read) = journal::read(&header, &plan, data) else {
        return;
    };
    assert_eq!(read.whole_bytes + read.torn_bytes, data.len());
    assert!(read.whole_bytes == 0 || data[read.whole_bytes - 1] == b'\n');
    // The torn tail: the bytes after the last newline, or a damaged last line.
    let tail = &data[read.whole_bytes..];
    assert!(!tail
        .split_last()
        .map_or(&[][..], |(_, t)| t)
        .contains(&b'\n'));
    let mut seen = std::collections::BTreeSet::new();
    for (i, s) in &read.samples {
        assert!(*i < plan.points.len() && seen.insert(*i));
        journal::check_sample(s).expect("only possible values are read");
    }
    let kept = &data[..read.whole_bytes];
    let again = journal::read(&header, &plan, kept).expect("the kept part reads alone");
    assert_eq!((&again.samples, again.torn_bytes), (&read.samples, 0));
    // A resume appends after the kept part (or after a new header when none was whole).
    let mut resumed = if kept.is_empty() {
        header.line().into_bytes()
    } else {
        kept.to_vec()
    };
    if let Some(next) = (0..plan.points.len()).find(|i| !seen.contains(i)) {
        let s = errormap::scan::Sample {
            error_um: [0.5, -0.25],
            yaw_urad: 1.0,
        };
        resumed.extend_from_slice(journal::line(next, &s).as_bytes());
        let after = journal::read(&header, &plan, &resumed).expect("an appended sample reads");
        assert_eq!(after.samples.last(), Some(&(next, s)));
        assert_eq!(after.samples.len(), read.samples.len() + 1);
    }
    let mut written = header.line();
    for (i, s) in &read.samples {
        written.push_str(&journal::line(*i, s));
    }
    let back =
        journal::read(&header, &plan, written.as_bytes()).expect("written journals read back");
    assert_eq!(back.samples, read.samples);
}

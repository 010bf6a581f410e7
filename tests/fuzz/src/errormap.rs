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

/// Any text as the journal of a small scan: samples or an error naming the line; the
/// samples read are written again and read back the same.
pub fn scan_journal(data: &[u8]) {
    let spec = ScanSpec {
        grid_step_mm: 5.0,
        line_step_mm: 5.0,
        passes: 1,
    };
    let plan = ScanPlan::new([0.0, 0.0], [10.0, 10.0], spec).expect("a valid plan");
    let text = String::from_utf8_lossy(data);
    let Ok(samples) = journal::read(&plan, &text) else {
        return;
    };
    assert!(samples.iter().all(|(i, _)| *i < plan.points.len()));
    let mut written = journal::header(&plan);
    for (i, s) in &samples {
        written.push_str(&journal::line(*i, s));
    }
    assert_eq!(
        journal::read(&plan, &written).expect("written journals read back"),
        samples
    );
}

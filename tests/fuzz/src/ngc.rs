//! LinuxCNC's dialect (RS274/NGC): `protocol::ngc` and `rewrite::ngc`.

use crate::fanuc::Smooth;
use protocol::ngc::{interpret, read_var_file, Bounds, Start};
use rewrite::ngc::{rewrite_ngc, NgcOptions};

/// Any text as a LinuxCNC program through `rewrite::ngc::rewrite_ngc` (start known, a
/// smooth stand-in map, small expansion bounds) and as a parameter file
/// (`read_var_file`): a refusal names a line of the text; an accepted rewrite is flat
/// (no parameter, O-word or bracket), reads again with `protocol::ngc`, and is within
/// its byte bound; an accepted parameter file has finite offsets.
pub fn ngc_rewrite(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    if text.len() > 4000 {
        return;
    }
    let lines = protocol::nc::split_lines(&text).count();
    if let Ok(start) = read_var_file(&text) {
        assert!(start.work_offsets.iter().flatten().all(|v| v.is_finite()));
        assert!(start.system < 9);
    }
    let bounds = Bounds {
        max_steps: 20_000,
        max_blocks: 2_000,
    };
    let options = NgcOptions {
        position: Some([10.0, 10.0, 0.0]),
        tolerance_mm: 0.005,
        max_output_bytes: 1 << 20,
        bounds,
        ..NgcOptions::default()
    };
    match rewrite_ngc(&text, &Smooth, &options) {
        Err(e) => assert!((1..=lines.max(1)).contains(&e.line), "{e}"),
        Ok((out, _)) => {
            assert!(out.len() <= 1 << 20);
            assert!(!out.contains(['#', '[', 'O', 'o']), "{out}");
            let start = Start {
                position: [10.0, 10.0, 0.0],
                ..Start::default()
            };
            let big = Bounds {
                max_steps: 10_000_000,
                max_blocks: 5_000_000,
            };
            interpret(&out, &start, big).unwrap_or_else(|e| panic!("{e}\n{out}"));
        }
    }
}

//! The partition and its resolution give exactly what the code gave before it was made
//! faster (issue 39): for every benchmark layout (ESICUP and Gardeyn records at
//! clearance G and G/2, generated nests), with moves only and with `--widen`, a
//! fingerprint of the groups (tool, window, shifts to the last bit, parts), the windows,
//! the overlaps found, every move and widening (or the error's text) is compared with the
//! one recorded in `tests/data/same_results.txt` from the code before.
//!
//! `LAYOUT_SAME_RESULTS_WRITE=1 cargo test -p layout --test same_results` rewrites the
//! record (only ever from the reference code); the 10 000-part nests run with
//! `cargo test --release -p layout --test same_results -- --ignored`.

#[path = "nests/mod.rs"]
mod nests;

use layout::{partition, resolve, resolve_widening, Params};
use layout_io::Part;

/// FNV-1a, 64 bits: a fingerprint of the outcome's JSON (serde_json writes every f64 so
/// that it reads back to the same bits).
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf29ce484222325u64, |h, &b| {
        (h ^ b as u64).wrapping_mul(0x100000001b3)
    })
}

/// One line: name, clearance, widen, the fingerprint and counts that say what it is.
fn outcome(name: &str, parts: &[Part], params: &Params, widen: bool) -> String {
    let clearance = params.clearance_mm.unwrap_or(params.gap_mm);
    let head = format!("{name} | C {clearance} | widen {widen}");
    let mut p = match partition(parts, params) {
        Ok(p) => p,
        Err(e) => return format!("{head} | refused: {e}"),
    };
    let r = if widen {
        resolve_widening(parts, &mut p, &[])
    } else {
        resolve(parts, &mut p, &[])
    };
    let (json, counts) = match &r {
        Ok(r) => (
            serde_json::to_string(&(&p.groups, &p.windows_mm, r)).expect("json"),
            format!(
                "{} groups, {} found, {} moves, {} widenings",
                p.groups.len(),
                r.found.len(),
                r.moves.len(),
                r.widenings.len()
            ),
        ),
        Err(e) => (
            serde_json::to_string(&(&p.groups, &p.windows_mm, e.to_string())).expect("json"),
            format!("{} groups, unresolved", p.groups.len()),
        ),
    };
    format!("{head} | {:016x} | {counts}", fnv1a(json.as_bytes()))
}

fn esicup_lines() -> Vec<String> {
    let mut out = Vec::new();
    for (name, doc) in nests::esicup() {
        let doc = doc.expect("the benchmark's layouts read");
        for clearance in [1.0, 0.5] {
            let params = nests::esicup_params(&doc, clearance);
            for widen in [false, true] {
                out.push(outcome(&name, &doc.parts, &params, widen));
            }
        }
    }
    out
}

fn generated_lines(n: usize) -> Vec<String> {
    let mut out = Vec::new();
    for case in nests::generated(n) {
        for widen in [false, true] {
            let name = format!("{} x {n}", case.name);
            out.push(outcome(&name, &case.parts, &case.params, widen));
        }
    }
    out
}

/// Compares `lines` with the record's lines of the same names (or writes them).
fn check(lines: Vec<String>) {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/same_results.txt");
    let key = |l: &str| l.splitn(4, " | ").take(3).collect::<Vec<_>>().join(" | ");
    let recorded = std::fs::read_to_string(&path).unwrap_or_default();
    if std::env::var_os("LAYOUT_SAME_RESULTS_WRITE").is_some() {
        let mut all: Vec<String> = recorded
            .lines()
            .filter(|r| !lines.iter().any(|l| key(l) == key(r)))
            .map(String::from)
            .chain(lines.iter().cloned())
            .collect();
        all.sort();
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, all.join("\n") + "\n").unwrap();
        return;
    }
    let mut differ = Vec::new();
    for l in &lines {
        match recorded.lines().find(|r| key(r) == key(l)) {
            Some(r) if r == l => {}
            Some(r) => differ.push(format!("now {l}\n was {r}")),
            None => differ.push(format!("not recorded: {l}")),
        }
    }
    assert!(
        differ.is_empty(),
        "{} of {} outcomes differ from the reference code's:\n{}",
        differ.len(),
        lines.len(),
        differ.join("\n")
    );
}

#[test]
fn benchmark_layouts_give_the_reference_results() {
    let lines = esicup_lines();
    assert_eq!(lines.len(), 17 * 4, "every ESICUP and Gardeyn record");
    check(lines);
}

#[test]
fn generated_nests_of_1000_parts_give_the_reference_results() {
    check(generated_lines(1_000));
}

#[test]
#[ignore = "10 000-part nests: run in release (see the module's documentation)"]
fn generated_nests_of_10000_parts_give_the_reference_results() {
    check(generated_lines(10_000));
}

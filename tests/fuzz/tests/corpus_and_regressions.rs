//! Replays every committed input through its target on stable, without libFuzzer:
//! `corpus/<target>/` (seeds and what fuzzing kept) and `regressions/<target>/` (every
//! crash input found, kept after its fix). A folder named after no target fails.

use fuzz_targets::{fuzz_dir, TARGETS};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;

fn inputs(folder: &Path) -> Vec<std::path::PathBuf> {
    let Ok(entries) = std::fs::read_dir(folder) else {
        return Vec::new();
    };
    let mut files: Vec<_> = entries
        .map(|e| e.expect("folder entry").path())
        .filter(|p| p.is_file())
        .collect();
    files.sort();
    files
}

fn replay(kind: &str) -> usize {
    let root = fuzz_dir().join(kind);
    if let Ok(entries) = std::fs::read_dir(&root) {
        for e in entries {
            let name = e.expect("folder entry").file_name();
            let name = name.to_string_lossy();
            assert!(
                TARGETS.iter().any(|(t, _)| *t == name),
                "{kind}/{name} is named after no fuzz target"
            );
        }
    }
    let mut failures = Vec::new();
    let mut count = 0;
    for (name, target) in TARGETS {
        for file in inputs(&root.join(name)) {
            let data = std::fs::read(&file).expect("input file");
            count += 1;
            if catch_unwind(AssertUnwindSafe(|| target(&data))).is_err() {
                failures.push(file.display().to_string());
            }
        }
    }
    assert!(failures.is_empty(), "inputs that fail: {failures:#?}");
    count
}

#[test]
fn every_corpus_input_passes() {
    let n = replay("corpus");
    // Every target has seeds.
    for (name, _) in TARGETS {
        assert!(
            !inputs(&fuzz_dir().join("corpus").join(name)).is_empty(),
            "corpus/{name} has no seed"
        );
    }
    eprintln!("{n} corpus inputs replayed");
}

#[test]
fn every_regression_input_passes() {
    let n = replay("regressions");
    eprintln!("{n} regression inputs replayed");
}

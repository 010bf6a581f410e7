//! Replays every committed input through its target on stable, without libFuzzer:
//! `corpus/<target>/` (seeds and what fuzzing kept) and `regressions/<target>/` (every
//! crash input found, kept after its fix). A folder named after no target fails.
//!
//! It also holds the libFuzzer binaries to their form (`fuzz_targets/<target>.rs`,
//! a `[[bin]]` each): they build only on nightly with `--features libfuzzer`, which CI
//! does not compile (tests/fuzz/README.md), so their text is what is checked here.

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

/// Whether a libFuzzer binary's text is one of the two forms the targets use: the two
/// lines cargo-fuzz expects, or (a target whose parser catches panics of its own) an
/// `init` that puts the default panic hook back first. Comment lines are not compared.
fn libfuzzer_binary_calls(text: &str, name: &str) -> bool {
    let code: Vec<&str> = text
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with("//"))
        .collect();
    let call = format!("|data: &[u8]| fuzz_targets::{name}(data)");
    let plain = [
        "#![no_main]".to_string(),
        format!("libfuzzer_sys::fuzz_target!({call});"),
    ];
    let with_init = [
        "#![no_main]".to_string(),
        "libfuzzer_sys::fuzz_target!(".to_string(),
        "init: {".to_string(),
        "drop(std::panic::take_hook());".to_string(),
        "},".to_string(),
        call.clone(),
        ");".to_string(),
    ];
    code == plain || code == with_init
}

/// Each libFuzzer binary calls the target of its own name; every target has one,
/// declared as a `[[bin]]` that needs `libfuzzer`.
#[test]
fn every_target_has_its_libfuzzer_binary() {
    let folder = fuzz_dir().join("fuzz_targets");
    let mut wrappers: Vec<String> = inputs(&folder)
        .iter()
        .map(|p| {
            p.file_stem()
                .expect("file name")
                .to_string_lossy()
                .into_owned()
        })
        .collect();
    wrappers.sort();
    let mut names: Vec<String> = TARGETS.iter().map(|(n, _)| n.to_string()).collect();
    names.sort();
    assert_eq!(wrappers, names, "fuzz_targets/ against TARGETS");

    let manifest: toml::Table = std::fs::read_to_string(fuzz_dir().join("Cargo.toml"))
        .expect("the fuzz crate's manifest")
        .parse()
        .expect("the fuzz crate's manifest is TOML");
    let bins = manifest["bin"].as_array().expect("[[bin]] entries");
    for name in &names {
        let text = std::fs::read_to_string(folder.join(format!("{name}.rs"))).expect("wrapper");
        assert!(
            libfuzzer_binary_calls(&text, name),
            "fuzz_targets/{name}.rs is not `#![no_main]` and a `fuzz_target!` calling \
             fuzz_targets::{name}:\n{text}"
        );
        let bin = bins
            .iter()
            .find(|b| b["name"].as_str() == Some(name.as_str()))
            .unwrap_or_else(|| panic!("no [[bin]] named {name}"));
        assert_eq!(
            bin["path"].as_str(),
            Some(format!("fuzz_targets/{name}.rs").as_str()),
            "[[bin]] {name}"
        );
        assert_eq!(
            bin["required-features"].as_array().map(|f| f.len()),
            Some(1),
            "[[bin]] {name} needs the libfuzzer feature alone"
        );
        assert_eq!(
            bin["required-features"][0].as_str(),
            Some("libfuzzer"),
            "[[bin]] {name}"
        );
    }
    assert_eq!(
        bins.len(),
        names.len(),
        "a [[bin]] for each target and no other"
    );
}

//! Issue 38, through the command line: a map's reference record that contradicts itself
//! is refused naming the field; outputs never replace a file the run read (the record,
//! the map, a board's certificate), also through links; a refused run leaves nothing
//! behind; duration flags are bounded.

use errormap::reference::{Circumstances, MapReference, MAX_SHIFT_UM};
use protocol::errormap::ErrorMap;
use std::path::{Path, PathBuf};
use std::process::Output;

use crate::common;

use common::{gateway, workspace as repo};

fn scratch(name: &str) -> PathBuf {
    common::scratch("outputs-cli", name)
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// The small map of the fuzz corpus as `dir/m.v1.json`, a program inside it, and a
/// record of a 6.27 um shift beside the map, measured a minute ago.
fn map_program_record(dir: &Path) -> (PathBuf, PathBuf, PathBuf, MapReference) {
    let map_path = dir.join("m.v1.json");
    std::fs::copy(
        repo().join("tests/fuzz/corpus/error_map_json/small_map.json"),
        &map_path,
    )
    .unwrap();
    let map = ErrorMap::load(&map_path).unwrap();
    let program = dir.join("in.nc");
    std::fs::write(&program, "G21 G90\nG0 X40 Y20\nG1 X60 Y30 F600\n").unwrap();
    let now = std::time::SystemTime::now() - std::time::Duration::from_secs(60);
    let record = MapReference::new(
        &map,
        [6.7, -8.29],
        MAX_SHIFT_UM,
        Circumstances {
            measured_at: errormap::scan::rfc3339(now),
            measured_unix_s: now.duration_since(std::time::UNIX_EPOCH).unwrap().as_secs(),
            previous_count: 0,
            ..Circumstances::default()
        },
    )
    .unwrap();
    let record_path = dir.join("m.v1.reference.json");
    std::fs::write(&record_path, serde_json::to_string_pretty(&record).unwrap()).unwrap();
    (map_path, program, record_path, record)
}

fn rewrite(map: &Path, program: &Path, out: &Path) -> Output {
    gateway(&[
        "rewrite",
        program.to_str().unwrap(),
        "--map",
        map.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ])
}

/// `text` without the reference's age (`(3 s old)`).
fn without_age(text: &str) -> String {
    text.lines()
        .map(|l| match (l.find(" ("), l.find(" old)")) {
            (Some(a), Some(b)) if a < b => format!("{}{}", &l[..a], &l[b + 5..]),
            _ => l.to_string(),
        })
        .collect::<Vec<_>>()
        .join("\n")
}

#[test]
fn a_record_that_contradicts_itself_is_refused_naming_the_field_and_a_bom_is_dropped() {
    let dir = scratch("contradicts");
    let (map, program, record_path, record) = map_program_record(&dir);
    let out = dir.join("out.nc");
    let o = rewrite(&map, &program, &out);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = std::fs::read_to_string(&out).unwrap();
    assert!(text.contains("reference #1"), "{text}");
    // With a byte-order mark, as an editor on another system saves it: the same.
    let json = std::fs::read_to_string(&record_path).unwrap();
    std::fs::write(&record_path, format!("\u{FEFF}{json}")).unwrap();
    let o = rewrite(&map, &program, &out);
    assert!(o.status.success(), "{}", stderr(&o));
    // The same program, but for the record's age in its header (a second may pass).
    assert_eq!(
        without_age(&std::fs::read_to_string(&out).unwrap()),
        without_age(&text)
    );
    // Issue 38: `seen_um` edited to 110 um printed the record's shift and applied another.
    let mut edited = record;
    edited.seen_um = [110.0, 0.0];
    std::fs::write(&record_path, serde_json::to_string(&edited).unwrap()).unwrap();
    std::fs::remove_file(&out).unwrap();
    let o = rewrite(&map, &program, &out);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(
        e.contains("`shift_um`") && e.contains("contradicts itself"),
        "{e}"
    );
    assert!(!out.exists(), "a refused run leaves nothing behind");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn rewrite_never_writes_over_the_record_or_the_map_it_read_nor_through_a_link() {
    let dir = scratch("over-record");
    let (map, program, record_path, _) = map_program_record(&dir);
    let before = std::fs::read(&record_path).unwrap();
    let o = rewrite(&map, &program, &record_path);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("never written over"), "{}", stderr(&o));
    assert_eq!(std::fs::read(&record_path).unwrap(), before);
    // An output name that links to the map: refused, the map as it was.
    let link = dir.join("out.nc");
    std::os::unix::fs::symlink(&map, &link).unwrap();
    let map_before = std::fs::read(&map).unwrap();
    let o = rewrite(&map, &program, &link);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("never written over"), "{}", stderr(&o));
    assert_eq!(std::fs::read(&map).unwrap(), map_before);
    let left: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".tmp"))
        .collect();
    assert!(left.is_empty(), "{left:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Issue 38: `board make -o` into the board's own folder replaced the measured
/// certificate when the board named `NAME.certificate-template.csv` as it.
#[test]
fn board_make_never_replaces_the_certificate_it_read_and_leaves_nothing_when_refused() {
    let dir = scratch("board-make");
    let plain = "[board]\nname = \"lab\"\npitch_mm = 0.5\ndot_diameter_mm = 0.25\n\
                 polarity = \"dark-on-light\"\ncols = 20\nrows = 10\norigin_mm = [0.0, 0.0]\n";
    let board = dir.join("lab.toml");
    std::fs::write(&board, plain).unwrap();
    // Make the board's template, have it "measured", then name it as the certificate.
    let made = dir.join("made");
    let o = gateway(&[
        "board",
        "make",
        board.to_str().unwrap(),
        "-o",
        made.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let nominal = std::fs::read_to_string(made.join("lab.certificate-template.csv")).unwrap();
    let mut lines: Vec<String> = nominal.lines().map(str::to_string).collect();
    let k = lines.iter().position(|l| l.starts_with("0,0,")).unwrap();
    let mut first: Vec<String> = lines[k].split(',').map(str::to_string).collect();
    first[2] = "0.000100".into();
    lines[k] = first.join(",");
    let measured = lines.join("\n") + "\n";
    assert_ne!(measured, nominal);
    let certificate = dir.join("lab.certificate-template.csv");
    std::fs::write(&certificate, &measured).unwrap();
    let certified = plain.replacen(
        "[board]\n",
        "[board]\ncertified = \"lab.certificate-template.csv\"\n",
        1,
    );
    std::fs::write(&board, certified).unwrap();
    let o = gateway(&[
        "board",
        "make",
        board.to_str().unwrap(),
        "-o",
        dir.to_str().unwrap(),
    ]);
    assert!(!o.status.success(), "board make replaced the certificate");
    let e = stderr(&o);
    assert!(
        e.contains("lab.certificate-template.csv") && e.contains("never written over"),
        "{e}"
    );
    assert_eq!(std::fs::read_to_string(&certificate).unwrap(), measured);
    for ext in ["svg", "dxf", "pdf"] {
        assert!(
            !dir.join(format!("lab.{ext}")).exists(),
            "lab.{ext} left behind"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The sweep's seed record (tests/fuzz/corpus/reference_record/small_map.json) is a
/// record of the corpus's small map that applies (else the sweep's seed is refused):
/// `MapReference::new(&map, [6.7, -8.29], MAX_SHIFT_UM, ...)` measured
/// 2026-11-28T09:30:00Z, written with `procedure::reference::record_json`.
#[test]
fn the_seed_record_of_the_sweep_belongs_to_the_small_map() {
    let corpus = repo().join("tests/fuzz/corpus");
    let map = ErrorMap::load(&corpus.join("error_map_json/small_map.json")).unwrap();
    let path = corpus.join("reference_record/small_map.json");
    let text = std::fs::read_to_string(&path).unwrap();
    let record = procedure::reference::parse_record(&text, "seed").unwrap();
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs();
    record
        .apply(errormap::MapModel::new(map), now)
        .expect("the seed applies to the small map");
}

/// Issue 38: `verify --repeat 2 --every-s 1e308` panicked ("cannot convert float
/// seconds to Duration"); it is refused naming the flag, before anything is read.
#[test]
fn a_pause_beyond_a_week_is_refused_naming_the_flag() {
    let o = gateway(&[
        "verify",
        "--config",
        "nowhere.toml",
        "--map",
        "nowhere.json",
        "--spot-check",
        "--repeat",
        "2",
        "--every-s",
        "1e308",
    ]);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(
        e.contains("--every-s") && e.contains("1e308") && !e.contains("panicked"),
        "{e}"
    );
}

/// Issue 38: `gateway iso230 --map` with another machine's map was refused but left its
/// output folder behind; the folder is made with the first file written into it.
#[test]
fn a_refused_iso230_run_leaves_no_output_folder() {
    let dir = scratch("iso230-other-map");
    let out = dir.join("iso");
    let map = repo().join("tests/fuzz/corpus/error_map_json/small_map.json");
    let config = repo().join("config/gateway/demo.toml");
    let o = gateway(&[
        "iso230",
        "--config",
        config.to_str().unwrap(),
        "--map",
        map.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--axis",
        "X",
    ]);
    assert!(!o.status.success(), "another machine's map was taken");
    assert!(stderr(&o).contains("machine"), "{}", stderr(&o));
    assert!(
        !out.exists(),
        "the refused run left {} behind",
        out.display()
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

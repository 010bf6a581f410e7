//! Drive profile files on disk: the shipped ones load, broken ones are refused with
//! the file, the line and the key.

use crate::modbus_common;

use modbus_common::config_dir;
use protocol::modbus::DriveProfile;
use std::path::PathBuf;

fn write(name: &str, text: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("modbus-profiles-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn generic() -> String {
    std::fs::read_to_string(config_dir().join("drives/generic.toml")).unwrap()
}

fn refused(name: &str, text: &str) -> (String, String) {
    let path = write(name, text);
    let e = DriveProfile::load(&path).unwrap_err().to_string();
    (path.display().to_string(), e)
}

#[test]
fn shipped_profiles_load_from_disk() {
    for f in ["generic", "oriental-az", "leadshine-pr0"] {
        let p = DriveProfile::load(&config_dir().join(format!("drives/{f}.toml"))).unwrap();
        assert!(p.file.ends_with(&format!("{f}.toml")));
        assert_eq!(
            p.counts_per_mm(),
            2000.0,
            "{f}: the demo machine's resolution"
        );
    }
}

#[test]
fn overlapping_registers_are_refused_with_file_line_and_key() {
    let text = generic().replace(
        "alarm_reset = { address = 0x0010,",
        "alarm_reset = { address = 0x0007,",
    );
    let (path, e) = refused("overlap.toml", &text);
    let line = text
        .lines()
        .position(|l| l.starts_with("alarm_reset"))
        .unwrap()
        + 1;
    assert!(
        e.starts_with(&format!("{path}:{line}: key `commands.alarm_reset`")),
        "{e}"
    );
    assert!(
        e.contains("overlaps `move.decel` (holding 0x0006-0x0007, u32)"),
        "{e}"
    );
}

#[test]
fn a_bad_word_order_is_refused_with_file_line_and_key() {
    let text = generic().replace(
        "speed = { address = 0x0002, type = \"u32\",",
        "speed = { address = 0x0002, type = \"u32\", word_order = \"little\",",
    );
    let (path, e) = refused("order.toml", &text);
    assert!(e.starts_with(&format!("{path}:")), "{e}");
    assert!(
        e.contains("key `move.speed.word_order`") && e.contains("high-first"),
        "{e}"
    );
}

#[test]
fn a_missing_required_register_is_refused_with_file_and_key() {
    let text = generic().replace("trigger = { address = 0x0008, value = 1 }\n", "");
    let (path, e) = refused("missing.toml", &text);
    assert!(e.starts_with(&format!("{path}:")), "{e}");
    assert!(
        e.contains("key `move`") && e.contains("missing field `trigger`"),
        "{e}"
    );
    let text = generic()
        .replace("busy = 0x0002\n", "")
        .replace("in_position = 0x0004\n", "");
    let (_, e) = refused("no-busy.toml", &text);
    assert!(
        e.contains("key `status`") && e.contains("`busy` or `in_position`"),
        "{e}"
    );
}

//! LinuxCNC set-up for the tests that run the real LinuxCNC 2.9 peer
//! (`../shared/peers/linuxcnc`): its configuration with the rig's follower in HAL.

use std::path::Path;

/// A copy of the configuration folder of `ini` (its `*.ini`, `*.hal`, `*.tbl`, `*.txt`,
/// as the peer's `start.sh` copies them) in a fresh folder, `ini`'s `[HAL]` given one
/// more `HALFILE = follow.hal` after its own, and `follow.hal` the sampler the rig's
/// follower reads, `hal` (`emulators::linuxcnc::SAMPLER_HAL`: every servo period's
/// motor commands of X, Y and Z). Returns the folder; the INI keeps its name in it.
pub fn config_with_follower(ini: &Path, hal: &str) -> std::io::Result<tempfile::TempDir> {
    let from = ini
        .parent()
        .ok_or_else(|| std::io::Error::other(format!("{}: no folder", ini.display())))?;
    let name = ini
        .file_name()
        .ok_or_else(|| std::io::Error::other(format!("{}: no file name", ini.display())))?;
    let dir = tempfile::tempdir()?;
    for entry in std::fs::read_dir(from)? {
        let path = entry?.path();
        let copied = path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| ["ini", "hal", "tbl", "txt"].contains(&e));
        if copied && path.is_file() {
            std::fs::copy(&path, dir.path().join(path.file_name().unwrap_or_default()))?;
        }
    }
    let text = std::fs::read_to_string(ini)?;
    let with = add_halfile(&text, "follow.hal")
        .ok_or_else(|| std::io::Error::other(format!("{}: no HALFILE in [HAL]", ini.display())))?;
    std::fs::write(dir.path().join(name), with)?;
    std::fs::write(dir.path().join("follow.hal"), hal)?;
    Ok(dir)
}

/// `ini` with `HALFILE = file` after its last `HALFILE` line (LinuxCNC runs them in
/// order, so the sampler is added to the servo thread after `motion-controller`).
fn add_halfile(ini: &str, file: &str) -> Option<String> {
    let lines: Vec<&str> = ini.lines().collect();
    let last = lines
        .iter()
        .rposition(|l| l.trim_start().starts_with("HALFILE"))?;
    let mut out = String::new();
    for (k, l) in lines.iter().enumerate() {
        out.push_str(l);
        out.push('\n');
        if k == last {
            out.push_str(&format!("HALFILE = {file}\n"));
        }
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::add_halfile;

    #[test]
    fn the_follower_hal_comes_after_the_machines_own() {
        let ini = "[HAL]\nHALFILE = x.hal\nHALFILE = y.hal\n\n[TRAJ]\nX = 1\n";
        assert_eq!(
            add_halfile(ini, "follow.hal").unwrap(),
            "[HAL]\nHALFILE = x.hal\nHALFILE = y.hal\nHALFILE = follow.hal\n\n[TRAJ]\nX = 1\n"
        );
        assert_eq!(add_halfile("[HAL]\n", "follow.hal"), None);
    }
}

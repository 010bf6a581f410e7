//! Helpers shared by the system tests in `tests/tests/` (interoperation tests that run
//! the stand-alone `emulators` binary and independent peers as separate processes).

use std::path::{Path, PathBuf};
use std::process::{Child, Command};

/// The workspace root.
pub fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .canonicalize()
        .expect("the workspace root exists")
}

/// The `emulators` binary next to the running test's executable, built if missing
/// (`cargo test --workspace` builds it; a filtered run may not have).
pub fn emulators_binary() -> PathBuf {
    let exe = std::env::current_exe().expect("the test knows its executable");
    let dir = exe
        .parent()
        .and_then(Path::parent)
        .expect("tests run from target/<profile>/deps")
        .to_path_buf();
    let bin = dir.join("emulators");
    if !bin.exists() {
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
        let status = Command::new(cargo)
            .args(["build", "-p", "emulators", "--bin", "emulators"])
            .current_dir(workspace())
            .status()
            .expect("cargo build");
        assert!(status.success(), "building the emulators binary failed");
    }
    bin
}

/// A child process that is killed and reaped when the test ends, pass or fail.
pub struct Kill(pub Child);

impl Drop for Kill {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

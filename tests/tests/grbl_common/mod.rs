//! Shared set-up of the GRBL system tests: a simulated rig, the GRBL emulator on a real
//! pseudo-terminal, and the driver connected to it by path.

// Not every test binary that includes this module uses all of it.
#![allow(dead_code, unused_imports)]

use drivers::grbl::{GrblOptions, GrblStage};
use emulators::grbl::{GrblConfig, GrblDevice, GrblPty};
use std::path::{Path, PathBuf};
use std::time::Duration;
use world::{Clock, SharedRig};

pub use system_tests::{config_dir, reference_rig as rig};

pub use system_tests::runtime;

/// The emulator on a fresh pseudo-terminal (inside a runtime).
pub fn emulator(
    rig: &SharedRig,
    clock: Clock,
    answer_limit: Option<u64>,
    link: Option<&Path>,
) -> GrblPty {
    let dev = GrblDevice::new(
        rig.clone(),
        GrblConfig {
            clock,
            answer_limit,
            ..Default::default()
        },
    );
    GrblPty::spawn(dev, link).expect("pseudo-terminal")
}

/// Options with short timeouts: a broken test fails in seconds, not minutes.
pub fn options() -> GrblOptions {
    GrblOptions {
        connect_timeout: Duration::from_secs(3),
        command_timeout: Duration::from_secs(2),
        motion_timeout: Duration::from_secs(20),
        poll_interval: Duration::from_millis(5),
        decimals: 4,
    }
}

pub async fn connect(path: &str) -> GrblStage {
    GrblStage::open(path, 115_200, options())
        .await
        .expect("connect to the emulator")
}

/// A unique path in the temp directory for a symlink.
pub fn temp_link(tag: &str) -> PathBuf {
    use std::sync::atomic::{AtomicU32, Ordering};
    static N: AtomicU32 = AtomicU32::new(0);
    std::env::temp_dir().join(format!(
        "grbl-{tag}-{}-{}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    ))
}

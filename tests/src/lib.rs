//! Helpers shared by the system tests in `tests/tests/` (interoperation tests that run
//! the stand-alone `emulators` binary and independent peers as separate processes).

pub mod dnc_rig;
pub mod faulty_serial;
pub mod faulty_tcp;
pub mod firmware;
pub mod linuxcnc;
pub mod netns;
pub mod program_path;
pub mod sender;
pub mod service_client;
pub mod truth_map;

use std::path::{Path, PathBuf};
use std::process::{Child, Command};

/// The workspace root.
pub fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .canonicalize()
        .expect("the workspace root exists")
}

/// The `emulators` binary, as this package's `emulators-under-test` (the emulators
/// package's main.rs, tests/Cargo.toml): cargo builds a package's binaries before it
/// runs the package's integration tests, with the tests' features, so it is the
/// emulator code under test. It lies next to the running test's `deps` folder.
pub fn emulators_binary() -> PathBuf {
    let exe = std::env::current_exe().expect("the test knows its executable");
    let bin = exe
        .parent()
        .and_then(Path::parent)
        .expect("tests run from target/<profile>/deps")
        .join("emulators-under-test");
    assert!(
        bin.is_file(),
        "{} is missing: run the test through cargo test -p system-tests, which builds it",
        bin.display()
    );
    bin
}

/// The repository's `config/` folder (machines, cameras, boards, drive profiles).
pub fn config_dir() -> PathBuf {
    workspace().join("config")
}

/// The reference rig of the system tests: the C5 ballscrew stage, the 1.3 MP mono
/// camera and the 0.5 mm dot grid, as the demo uses them.
pub fn reference_rig() -> world::SharedRig {
    reference_rig_with_camera(|_| {})
}

/// The reference rig with its camera adjusted first (a smaller sensor keeps debug
/// builds fast; another bit depth exercises other pixel formats).
pub fn reference_rig_with_camera(
    adjust: impl FnOnce(&mut world::camera::CameraModel),
) -> world::SharedRig {
    let d = config_dir();
    let machine = world::machine::MachineConfig::load(&d.join("machines/c5-stage.toml"))
        .expect("config/machines/c5-stage.toml loads");
    let mut camera = world::camera::CameraModel::load(&d.join("cameras/mono-1.3mp.toml"))
        .expect("config/cameras/mono-1.3mp.toml loads");
    adjust(&mut camera);
    let board = protocol::Board::load(&d.join("boards/dot-grid-0.5mm.toml"))
        .expect("config/boards/dot-grid-0.5mm.toml loads");
    world::shared_rig(machine, board, camera)
}

/// A child process that is killed and reaped when the test ends, pass or fail.
pub struct Kill(pub Child);

impl Drop for Kill {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// A current-thread runtime for one test.
pub fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("a tokio runtime")
}

/// A two-worker runtime, as the `gateway` binary uses (bus tasks keep running while a
/// frame is rendered or localized).
pub fn runtime_two_workers() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("a tokio runtime")
}

/// The demo's promise over any link: the job ran to the end, every target converged,
/// the stage really was off by at least `min_before_um` before compensation, and ends
/// within 1 um of the truth after it.
pub fn assert_demo_figure(report: &compensation::report::Report, min_before_um: f64) {
    assert!(report.error.is_none(), "{:?}", report.error);
    assert_eq!(report.converged, report.targets, "{}", report.to_text());
    let before = report
        .before_um
        .expect("a simulated machine reports the truth");
    let after = report
        .after_um
        .expect("a simulated machine reports the truth");
    assert!(
        before.max >= min_before_um,
        "uncompensated max {} um",
        before.max
    );
    assert!(
        after.max <= 1.0,
        "compensated max {} um\n{}",
        after.max,
        report.to_text()
    );
}

/// The independent GRBL sender (`tests/interop/grbl_sender.py`, pyserial) streaming
/// `program` to the controller (or pass-through) on `port`.
pub fn grbl_sender(port: &Path, program: &Path) -> Command {
    let mut c = Command::new("python3");
    c.arg(workspace().join("tests/interop/grbl_sender.py"))
        .arg(port)
        .arg(program);
    c
}

/// A sender process's one JSON object on stdout (our Python and Node peers print one),
/// after checking it exited successfully.
pub fn sender_json(out: &std::process::Output) -> serde_json::Value {
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "sender failed: {stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_str(stdout.trim()).unwrap_or_else(|e| panic!("{e}: {stdout}"))
}

/// Why an interoperation test cannot run here: python3 missing, or `modules` (a Python
/// import list such as `"canopen, can, serial"`) not importable; `packages` is what to
/// `pip install`. None when the peer can run. Callers fail with the reason, which names
/// the install step (a test never passes without its peer).
pub fn python_missing(modules: &str, packages: &str) -> Option<String> {
    match Command::new("python3")
        .args(["-c", &format!("import {modules}")])
        .output()
    {
        Err(e) => Some(format!(
            "python3 is not available ({e}): run tests/install-peers.sh"
        )),
        Ok(o) if !o.status.success() => Some(format!(
            "{packages} not installed (run tests/install-peers.sh, or python3 -m pip install {packages}): {}",
            String::from_utf8_lossy(&o.stderr).trim()
        )),
        Ok(_) => None,
    }
}

/// Where CNCjs is installed (tests/install-peers.sh puts it in tests/interop/cncjs;
/// CNCJS_DIR overrides), or why it cannot run, naming the install step.
pub fn cncjs_dir() -> Result<std::path::PathBuf, String> {
    let dir = std::env::var_os("CNCJS_DIR")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| workspace().join("tests/interop/cncjs"));
    if Command::new("node").arg("--version").output().is_err() {
        return Err("node is not available: run tests/install-peers.sh".into());
    }
    if !dir.join("node_modules/cncjs/package.json").exists() {
        return Err(format!(
            "CNCjs is not installed in {}: run tests/install-peers.sh",
            dir.display()
        ));
    }
    Ok(dir)
}

/// Every file of the test folder `dir` (a Rust file, or a folder of shared modules) is a
/// module of the one test binary `binary` (`BINARY.rs` in that folder, whose text is
/// `declared`): the package does not find its tests itself (`autotests = false`), so a
/// file left out would never run. Fails naming the first file not declared.
pub fn assert_every_test_file_declared(dir: &Path, binary: &str, declared: &str) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_stem().unwrap().to_string_lossy().into_owned();
        if name == binary || (path.is_file() && path.extension().is_none_or(|e| e != "rs")) {
            continue;
        }
        assert!(
            declared.lines().any(|l| l == format!("mod {name};")),
            "{} is not declared in {}",
            path.display(),
            dir.join(format!("{binary}.rs")).display()
        );
    }
}

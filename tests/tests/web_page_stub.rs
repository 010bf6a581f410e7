//! The web page in headless Chromium against tests/interop/web/contract_stub.js, a Node
//! stand-in that answers the service contract's API v1 with made-up data: the same walk
//! as tests/tests/service_web.rs (token in the fragment, a job with live progress, its
//! chart, activate and roll back, the heat map), so the page and the driver are checked
//! without the service. Needs `node`, `/usr/bin/chromium` and playwright-core in
//! tests/interop/web (installed by .ci/run); fails naming what to install without them.
//! Screenshot: `$CARGO_TARGET_DIR/tmp/web_page_stub/page.png`.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use system_tests::workspace;

fn missing_tools(web_dir: &Path) -> Option<String> {
    if Command::new("node").arg("--version").output().is_err() {
        return Some("node is not installed (apt-get install -y nodejs npm)".into());
    }
    if !Path::new("/usr/bin/chromium").exists() {
        return Some("/usr/bin/chromium is not installed (apt-get install -y chromium)".into());
    }
    if !web_dir
        .join("node_modules/playwright-core/package.json")
        .exists()
    {
        return Some(format!(
            "playwright-core is not installed in {0} (npm install --prefix {0} --no-package-lock; .ci/run does it)",
            web_dir.display()
        ));
    }
    None
}

/// Kills the stub when the test ends, passed or not.
struct Stub(std::process::Child);

impl Drop for Stub {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[test]
fn the_page_walks_through_the_contract_stub_in_headless_chromium() {
    let web_dir = workspace().join("tests/interop/web");
    if let Some(missing) = missing_tools(&web_dir) {
        panic!("cannot run the browser test: {missing}");
    }
    let artefacts = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("web_page_stub");
    let _ = std::fs::remove_dir_all(&artefacts);
    let profile_dir = artefacts.join("chromium-profile");
    std::fs::create_dir_all(&profile_dir).unwrap();
    let screenshot = artefacts.join("page.png");
    let token = "stub-token-7f3a";

    let mut stub = Stub(
        Command::new("node")
            .arg(web_dir.join("contract_stub.js"))
            .args(["0", token])
            .stdout(Stdio::piped())
            .spawn()
            .expect("node starts the stub"),
    );
    let mut line = String::new();
    BufReader::new(stub.0.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let port: u16 = line
        .trim()
        .strip_prefix("listening ")
        .and_then(|p| p.parse().ok())
        .unwrap_or_else(|| panic!("the stub did not say its port: {line:?}"));

    let output = Command::new("node")
        .arg(web_dir.join("drive_page.js"))
        .args([
            &format!("http://127.0.0.1:{port}"),
            token,
            "demo",
            "map",
            "{}",
        ])
        .arg(&screenshot)
        .arg(&profile_dir)
        .output()
        .expect("node runs the driver");
    let stdout = String::from_utf8_lossy(&output.stdout);
    let report: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap_or_else(|e| {
        panic!(
            "driver output is not JSON ({e}): {stdout}\n{}",
            String::from_utf8_lossy(&output.stderr)
        )
    });
    assert_eq!(report["ok"], true, "{report}");
    assert!(!report["url_after_load"].as_str().unwrap().contains(token));
    assert_eq!(report["job_id"], 1);
    assert_eq!(report["chart"], "deviation");
    // The stub's job takes 5 measurements.
    assert_eq!(report["measurements"], 5);
    // Versions 1 and 2 of "xy": activate 2, activate 1, roll back -> 2 alone is active.
    assert_eq!(report["rolled_back_to"], 2);
    assert_eq!(report["active_after_rollback"], serde_json::json!([2]));
    assert_eq!(
        report["heatmap"],
        serde_json::json!({"profile": "xy", "version": 2})
    );
    assert!(std::fs::read(&screenshot)
        .unwrap()
        .starts_with(b"\x89PNG\r\n\x1a\n"));
}

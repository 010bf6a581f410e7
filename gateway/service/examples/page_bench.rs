//! The web page's figures in headless Chromium (issue 30), over HTTPS (issue 37: the
//! self-signed pair, Chromium given its SPKI pin), printed, not asserted:
//! `cargo run --release -p service --example page_bench [jobs] [grid_step_mm] [line_step_mm]`
//! (defaults 1000, 4, 3: about 4 200 frames). The demo service starts in-process with `jobs` finished jobs
//! in its history; tests/interop/web/bench_page.js (node, playwright-core, /usr/bin/chromium
//! as for the browser test) then
//! 1. loads the page five times: from navigation to the machines, the history and the
//!    live connection shown (the history holds one 15 MB layout job too; the size of the
//!    list the page fetches is printed);
//! 2. starts a map job, times its first frame on the page (from the request to the
//!    picture loaded), then (its frames are its measurements, thousands at a fine grid), shows
//!    it, and times each measurement event the page appends (its handler and the layout
//!    after it), counting the page's fetches of the measurements.

use serde_json::json;
use std::process::Command;

fn seed(data_dir: &std::path::Path, jobs: usize) {
    let mut store = store::Store::open(&data_dir.join("gateway.sqlite")).expect("the store");
    let result = json!({"targets": 1, "converged": 1, "method": "fit",
        "before_um": {"mean": 12.7, "rms": 12.7, "max": 12.7},
        "after_um": {"mean": 0.33, "rms": 0.33, "max": 0.33}});
    for _ in 0..jobs {
        let job = store
            .enqueue("demo", "compensate", &json!({"targets": 1, "method": null}))
            .unwrap();
        store.start(job.id, None).unwrap();
        store
            .add_measurement(job.id, &json!({"target_index": 0, "deviation_um": 0.3}))
            .unwrap();
        store
            .finish(
                job.id,
                store::Outcome::Succeeded {
                    result: result.clone(),
                    metrics: Default::default(),
                },
            )
            .unwrap();
    }
    // One accepted 15 MB layout job (its file in params, its shifted layout in the
    // result), as issue 37 found it: the history list must not carry it.
    let layout = format!("{{\"parts\": []}}{}", " ".repeat(15 << 20));
    let job = store
        .enqueue(
            "demo",
            "layout",
            &json!({"layout": layout, "format": "json"}),
        )
        .unwrap();
    store.start(job.id, None).unwrap();
    store
        .finish(
            job.id,
            store::Outcome::Succeeded {
                result: json!({"groups": [], "layout": layout}),
                metrics: Default::default(),
            },
        )
        .unwrap();
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() {
    let arg = |n: usize, default: f64| {
        std::env::args()
            .nth(n)
            .and_then(|a| a.parse().ok())
            .unwrap_or(default)
    };
    let (jobs, grid, line) = (arg(1, 1000.0) as usize, arg(2, 4.0), arg(3, 3.0));
    let dir = tempfile::tempdir().unwrap();
    let started = std::time::Instant::now();
    seed(dir.path(), jobs);
    println!(
        "history: {jobs} finished jobs stored in {:.1} s",
        started.elapsed().as_secs_f64()
    );
    // Over HTTPS, as a box serves it (the self-signed pair made now; Chromium pins it).
    let mut config = service::BoxConfig::demo(dir.path());
    config.service.tls = service::TlsSource::SelfSigned;
    let s = service::start(config).await.unwrap();
    let base = s.url().trim_end_matches('/').to_string();
    let spki = s.tls().expect("HTTPS").spki_sha256_base64.clone();
    let script = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/interop/web/bench_page.js"
    );
    let profile = dir.path().join("chromium-profile");
    let params = json!({"name": "bench", "grid_step_mm": grid, "line_step_mm": line, "passes": 1})
        .to_string();
    let token = s.token().to_string();
    let output = tokio::task::spawn_blocking(move || {
        Command::new("node")
            .arg(script)
            .arg(base)
            .arg(token)
            .arg(params)
            .arg(profile)
            .arg(spki)
            .output()
    })
    .await
    .unwrap()
    .expect("node runs (tests/install-peers.sh installs it, chromium and playwright-core)");
    print!("{}", String::from_utf8_lossy(&output.stdout));
    eprint!("{}", String::from_utf8_lossy(&output.stderr));
    s.shutdown().await;
}

//! Store throughput: measurements inserted per second (one transaction each, as the
//! service writes them) and the database size after 10 000 finished jobs.
//!
//! cargo run --release -p store --example store_bench

use std::time::Instant;

use serde_json::{json, Map};
use store::{Outcome, Store};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = std::env::temp_dir().join(format!("store-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let path = dir.join("bench.sqlite");
    let mut store = Store::open(&path)?;

    // 1. Measurements, one committed row each.
    let job = store.enqueue("bench", "verify", &json!({}))?;
    store.start(job.id, None)?;
    let count = 20_000;
    let begin = Instant::now();
    for i in 0..count {
        let m =
            json!({"index": i, "x_mm": i as f64 * 0.1, "y_mm": 5.0, "dx_um": 1.25, "dy_um": -0.75});
        store.add_measurement(job.id, &m)?;
    }
    let seconds = begin.elapsed().as_secs_f64();
    println!(
        "measurements: {count} in {seconds:.2} s = {:.0} inserts/s",
        count as f64 / seconds
    );
    store.finish(
        job.id,
        Outcome::Succeeded {
            result: json!({}),
            metrics: Map::new(),
        },
    )?;

    // 2. 10 000 jobs, each with 10 measurements, a result and an outbox row.
    let begin = Instant::now();
    for j in 0..10_000 {
        let job = store.enqueue(
            "bench",
            "iso230",
            &json!({"targets": [0, 50, 100, 150, 200]}),
        )?;
        store.start(job.id, None)?;
        for i in 0..10 {
            store.add_measurement(job.id, &json!({"target": i * 20, "dev_um": 1.5, "run": 1}))?;
        }
        let mut metrics = Map::new();
        metrics.insert("A_um".into(), json!(3.2));
        metrics.insert("job".into(), json!(j));
        store.finish(
            job.id,
            Outcome::Succeeded {
                result: json!({"A_um": 3.2, "E_um": 2.1}),
                metrics,
            },
        )?;
    }
    let seconds = begin.elapsed().as_secs_f64();
    drop(store); // checkpoints the WAL into the main file
    let size = std::fs::metadata(&path)?.len();
    println!(
        "10000 jobs x 10 measurements in {seconds:.1} s; database {:.1} MB ({} bytes)",
        size as f64 / 1e6,
        size
    );
    std::fs::remove_dir_all(&dir)?;
    Ok(())
}

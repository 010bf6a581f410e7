//! Outbox rows published per second to a real broker: `cargo run --release -p northbound
//! --example northbound_rate [ROWS]` (starts Debian's `mosquitto` on a free loopback
//! port; each row a DDATA with five metrics, confirmed in batches of 100 by a SUBACK).

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

fn main() {
    let rows: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(20_000);
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let dir = std::env::temp_dir().join(format!("northbound-rate-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let conf = dir.join("mosquitto.conf");
    std::fs::write(
        &conf,
        format!("listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\n"),
    )
    .unwrap();
    let mut broker = std::process::Command::new("/usr/sbin/mosquitto")
        .arg("-c")
        .arg(&conf)
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("mosquitto (apt-get install mosquitto)");
    let mut store = store::Store::open_in_memory().unwrap();
    let mut metrics = serde_json::Map::new();
    metrics.insert("rms_um".into(), serde_json::json!(0.246));
    metrics.insert("max_um".into(), serde_json::json!(0.437));
    metrics.insert("targets".into(), serde_json::json!(30));
    for _ in 0..rows {
        store.outbox_push("m1", None, &metrics).unwrap();
    }
    let store = Arc::new(Mutex::new(store));
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let (elapsed, published) = rt.block_on(async {
        let (_tx, states) = tokio::sync::watch::channel(Vec::new());
        let config = northbound::MqttConfig {
            host: "127.0.0.1".into(),
            port,
            group_id: "bench".into(),
            edge_node_id: "box".into(),
            client_id: None,
            keep_alive_s: 30,
            username: None,
            password: None,
        };
        let t = Instant::now();
        let nb = northbound::spawn(
            config,
            store.clone(),
            vec!["m1".into()],
            states,
            Arc::new(tokio::sync::Notify::new()),
        );
        let mut published = nb.published();
        tokio::time::timeout(
            Duration::from_secs(600),
            published.wait_for(|n| *n >= rows as u64),
        )
        .await
        .expect("all rows within 10 minutes")
        .unwrap();
        let elapsed = t.elapsed();
        let n = *published.borrow();
        nb.shutdown().await;
        (elapsed, n)
    });
    let _ = broker.kill();
    let _ = broker.wait();
    let _ = std::fs::remove_dir_all(&dir);
    println!(
        "{published} outbox rows published and confirmed in {:.3} s: {:.0} rows/s (DDATA of 5 metrics, batches of 100, QoS 0 with a SUBACK barrier)",
        elapsed.as_secs_f64(),
        published as f64 / elapsed.as_secs_f64()
    );
}

//! Service benchmark: `cargo run --release -p service --example service_bench [jobs]`.
//! 1. API requests/s and p99 latency (GET /api/v1/machines, 8 concurrent clients) while
//!    a compensation job runs on the demo machine;
//! 2. WebSocket fan-out: 100 clients, time until all of them saw a job's final event;
//! 3. resident memory (VmRSS) while `jobs` jobs (default 10 000) go through the store:
//!    queued through the API and cancelled, every 50th one run to the end (1 target).

use futures_util::StreamExt;
use serde_json::{json, Value};
use std::time::{Duration, Instant};
use tokio_tungstenite::tungstenite::client::IntoClientRequest;

fn rss_kib() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1).and_then(|v| v.parse().ok()))
        })
        .unwrap_or(0)
}

type Ws =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

async fn connect(addr: std::net::SocketAddr, token: &str) -> Ws {
    let mut req = format!("ws://{addr}/api/v1/events")
        .into_client_request()
        .unwrap();
    req.headers_mut().insert(
        "Sec-WebSocket-Protocol",
        format!("gateway.v1, bearer.{token}").parse().unwrap(),
    );
    tokio_tungstenite::connect_async(req).await.unwrap().0
}

async fn wait_final(ws: &mut Ws, id: i64) {
    while let Some(Ok(m)) = ws.next().await {
        if let Ok(text) = m.to_text() {
            let v: Value = serde_json::from_str(text).unwrap_or(Value::Null);
            let state = v["job"]["state"].as_str().unwrap_or("");
            if v["type"] == "job" && v["job"]["id"] == id && state != "queued" && state != "running"
            {
                return;
            }
        }
    }
    panic!("event stream ended");
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() {
    let jobs: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(10_000);
    let dir = tempfile::tempdir().unwrap();
    let s = service::start(service::BoxConfig::demo(dir.path()))
        .await
        .unwrap();
    let (addr, token) = (s.local_addr(), s.token().to_string());
    let c = reqwest::Client::new();
    let base = format!("http://{addr}");
    let post_job = |params: Value| {
        c.post(format!("{base}/api/v1/machines/demo/jobs"))
            .bearer_auth(&token)
            .json(&json!({"kind": "compensate", "params": params}))
            .send()
    };

    // 1. API under load with a job running.
    let mut ws = connect(addr, &token).await;
    let long: Value = post_job(json!({})).await.unwrap().json().await.unwrap();
    let long_id = long["id"].as_i64().unwrap();
    let per_client = 500;
    let started = Instant::now();
    let mut tasks = Vec::new();
    for _ in 0..8 {
        let (c, url, token) = (c.clone(), format!("{base}/api/v1/machines"), token.clone());
        tasks.push(tokio::spawn(async move {
            let mut lat = Vec::with_capacity(per_client);
            for _ in 0..per_client {
                let t = Instant::now();
                let r = c.get(&url).bearer_auth(&token).send().await.unwrap();
                assert!(r.status().is_success());
                let _ = r.bytes().await.unwrap();
                lat.push(t.elapsed());
            }
            lat
        }));
    }
    let mut lat: Vec<Duration> = Vec::new();
    for t in tasks {
        lat.extend(t.await.unwrap());
    }
    let wall = started.elapsed();
    lat.sort();
    let p = |q: f64| lat[((lat.len() as f64 * q) as usize).min(lat.len() - 1)];
    println!(
        "API with a job running: {} requests in {:.2} s = {:.0} req/s; p50 {:.2} ms, p99 {:.2} ms",
        lat.len(),
        wall.as_secs_f64(),
        lat.len() as f64 / wall.as_secs_f64(),
        p(0.5).as_secs_f64() * 1e3,
        p(0.99).as_secs_f64() * 1e3
    );
    c.post(format!("{base}/api/v1/jobs/{long_id}/cancel"))
        .bearer_auth(&token)
        .send()
        .await
        .unwrap();
    wait_final(&mut ws, long_id).await;

    // 2. Fan-out to 100 WebSocket clients.
    let mut clients = Vec::new();
    for _ in 0..100 {
        clients.push(connect(addr, &token).await);
    }
    let job: Value = post_job(json!({"targets": 1}))
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let id = job["id"].as_i64().unwrap();
    let t = Instant::now();
    let waits: Vec<_> = clients
        .into_iter()
        .map(|mut ws| {
            tokio::spawn(async move {
                wait_final(&mut ws, id).await;
                Instant::now()
            })
        })
        .collect();
    let mut last = Vec::new();
    for w in waits {
        last.push(w.await.unwrap());
    }
    let first = *last.iter().min().unwrap();
    let latest = *last.iter().max().unwrap();
    println!(
        "fan-out: 100 WebSocket clients all got the job's final event ({:.2} s job); spread first..last client {:.2} ms",
        (first - t).as_secs_f64(),
        (latest - first).as_secs_f64() * 1e3
    );

    // 3. Memory over many jobs.
    let rss0 = rss_kib();
    println!("RSS before the job series: {rss0} KiB");
    let t = Instant::now();
    for i in 1..=jobs {
        let job: Value = post_job(json!({"targets": 1}))
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        let id = job["id"].as_i64().unwrap();
        if i % 50 == 0 {
            wait_final(&mut ws, id).await;
        } else {
            let r = c
                .post(format!("{base}/api/v1/jobs/{id}/cancel"))
                .bearer_auth(&token)
                .send()
                .await
                .unwrap();
            let _ = r.bytes().await;
        }
        if i % 1000 == 0 {
            println!(
                "after {i} jobs: RSS {} KiB ({:.1} s)",
                rss_kib(),
                t.elapsed().as_secs_f64()
            );
        }
    }
    s.shutdown().await;
}

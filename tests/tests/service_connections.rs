//! The service's connection limits (gateway/service/src/serve.rs), in-process on port 0
//! with a temp data dir and the embedded demo machine: many idle connections do not lock
//! a token holder out, a half request head is closed after the header timeout, an idle
//! keep-alive connection after the idle timeout, and a WebSocket is never idle-closed.
//! No wall-time sleeps and no timing assertions: every wait is on an answer or on the
//! server closing a socket, bounded by a timeout that only fails the test.

use futures_util::{SinkExt, StreamExt};
use reqwest::{Client, StatusCode};
use serde_json::Value;
use service::{BoxConfig, Running};
use std::path::Path;
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::time::timeout;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::Message;

/// Upper bound of any wait of these tests: reaching it fails the test.
const BOUND: Duration = Duration::from_secs(30);

/// Idle connections opened against the default `max_connections` (1024).
const IDLE_CONNECTIONS: usize = 1100;

/// Half a request head: the blank line that ends it never comes.
const HALF_HEAD: &[u8] = b"GET /api/v1/machines HTTP/1.1\r\nHost: gateway\r\n";

fn config(dir: &Path) -> BoxConfig {
    let mut c = BoxConfig::demo(dir);
    c.service.bad_token_delay_cap_ms = 5;
    c
}

async fn start(config: BoxConfig) -> Running {
    service::start(config).await.expect("service starts")
}

async fn stop(s: Running) {
    timeout(BOUND, s.shutdown())
        .await
        .expect("the service stops with connections open");
}

type Ws =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// The event stream, authenticated as the browser does (subprotocols), after its hello.
async fn events(s: &Running) -> Ws {
    let mut req = format!("ws://{}/api/v1/events", s.local_addr())
        .into_client_request()
        .unwrap();
    req.headers_mut().insert(
        "Sec-WebSocket-Protocol",
        format!("gateway.v1, bearer.{}", s.token()).parse().unwrap(),
    );
    let (mut ws, _) = timeout(BOUND, tokio_tungstenite::connect_async(req))
        .await
        .expect("ws connects in time")
        .expect("ws connects");
    let hello = timeout(BOUND, ws.next())
        .await
        .expect("hello in time")
        .expect("stream open")
        .expect("hello");
    let hello: Value = serde_json::from_str(hello.to_text().unwrap()).unwrap();
    assert_eq!(hello["type"], "hello");
    ws
}

/// The WebSocket answers a ping.
async fn still_open(ws: &mut Ws) {
    ws.send(Message::Ping(b"still there?".to_vec().into()))
        .await
        .expect("the WebSocket is open");
    timeout(BOUND, async {
        loop {
            match ws.next().await {
                Some(Ok(Message::Pong(p))) => {
                    assert_eq!(&p[..], b"still there?");
                    return;
                }
                Some(Ok(Message::Close(_))) | None => panic!("the WebSocket was closed"),
                Some(Ok(_)) => {}
                Some(Err(e)) => panic!("the WebSocket failed: {e}"),
            }
        }
    })
    .await
    .expect("pong in time");
}

/// Waits until the server has closed `stream` (EOF, or a reset when it closed with
/// bytes unread); anything the server sends before is skipped.
async fn closed(stream: &mut TcpStream) {
    let mut buf = [0u8; 4096];
    loop {
        match stream.read(&mut buf).await {
            Ok(0) => return,
            Ok(_) => {}
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::ConnectionReset | std::io::ErrorKind::ConnectionAborted
                ) =>
            {
                return
            }
            Err(e) => panic!("reading the connection: {e}"),
        }
    }
}

/// `GET /api/v1/machines` with the token on a raw HTTP/1.1 connection (kept alive);
/// returns the status line after reading the whole response.
async fn raw_get(stream: &mut TcpStream, token: &str) -> String {
    let request = format!(
        "GET /api/v1/machines HTTP/1.1\r\nHost: gateway\r\nAuthorization: Bearer {token}\r\n\r\n"
    );
    stream.write_all(request.as_bytes()).await.unwrap();
    let mut data = Vec::new();
    let mut buf = [0u8; 4096];
    let head_end = loop {
        if let Some(i) = data.windows(4).position(|w| w == b"\r\n\r\n") {
            break i + 4;
        }
        let n = stream.read(&mut buf).await.unwrap();
        assert!(n > 0, "connection closed before the response head");
        data.extend_from_slice(&buf[..n]);
    };
    let head = String::from_utf8_lossy(&data[..head_end]).to_string();
    let length: usize = head
        .lines()
        .find_map(|l| {
            let (name, value) = l.split_once(':')?;
            name.eq_ignore_ascii_case("content-length")
                .then(|| value.trim().parse().ok())?
        })
        .expect("a content-length");
    while data.len() < head_end + length {
        let n = stream.read(&mut buf).await.unwrap();
        assert!(n > 0, "connection closed in the response body");
        data.extend_from_slice(&buf[..n]);
    }
    head.lines().next().unwrap_or("").to_string()
}

/// The soft and hard open-file limits of this process (Linux), None elsewhere.
fn open_file_limits() -> Option<(u64, u64)> {
    let text = std::fs::read_to_string("/proc/self/limits").ok()?;
    let line = text.lines().find(|l| l.starts_with("Max open files"))?;
    let mut fields = line.split_whitespace().skip(3);
    let parse = |v: Option<&str>| match v? {
        "unlimited" => Some(u64::MAX),
        v => v.parse().ok(),
    };
    Some((parse(fields.next())?, parse(fields.next())?))
}

/// Makes room for `needed` open files: raises this process's soft limit towards the
/// hard one if it is lower. The tests crate has no binding of setrlimit (and forbids
/// unsafe code), so util-linux's `prlimit` does it on this process's pid. Returns the
/// soft limit in force (u64::MAX when unknown).
fn raise_open_files(needed: u64) -> u64 {
    let Some((soft, hard)) = open_file_limits() else {
        return u64::MAX;
    };
    if soft >= needed {
        return soft;
    }
    let target = needed.min(hard);
    let raised = std::process::Command::new("prlimit")
        .arg(format!("--pid={}", std::process::id()))
        .arg(format!("--nofile={target}:{hard}"))
        .status();
    if !matches!(raised, Ok(s) if s.success()) {
        eprintln!("could not raise the open-file limit with prlimit: {raised:?}");
    }
    open_file_limits().map_or(soft, |(soft, _)| soft)
}

/// 1100 connections that send nothing or half a request head, beyond the default cap of
/// 1024: a token holder is still answered, and the cap held (the connections waiting
/// longest were closed for the newer ones, while the timeouts are too long to have
/// closed any).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn idle_connections_do_not_lock_a_token_holder_out() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = config(dir.path());
    cfg.service.header_timeout = Duration::from_secs(3600);
    cfg.service.idle_timeout = Duration::from_secs(3600);
    let mut idle_count = IDLE_CONNECTIONS;
    // Both ends of every connection are in this process, plus the runtime's and the
    // service's own files.
    let soft = raise_open_files(2 * (idle_count as u64 + 1) + 256);
    if soft < 2 * (idle_count as u64 + 1) + 256 {
        // The hard limit forbids 1100: fewer idle connections, and a cap lowered below
        // them so that the test still goes beyond it.
        idle_count = (soft.saturating_sub(256) / 2) as usize;
        cfg.service.max_connections = idle_count * 9 / 10;
        eprintln!(
            "open-file limit {soft}: {idle_count} idle connections against max_connections = {}",
            cfg.service.max_connections
        );
        assert!(
            cfg.service.max_connections >= 1,
            "open-file limit {soft} too low for this test"
        );
    }
    let max = cfg.service.max_connections;
    let s = start(cfg).await;
    let addr = s.local_addr();

    let mut idle = Vec::with_capacity(idle_count);
    for i in 0..idle_count {
        let mut c = timeout(BOUND, TcpStream::connect(addr))
            .await
            .expect("connects in time")
            .expect("connects");
        if i % 2 == 1 {
            c.write_all(HALF_HEAD).await.unwrap();
        }
        idle.push(c);
    }

    let answer = timeout(
        BOUND,
        Client::new()
            .get(format!("http://{addr}/api/v1/machines"))
            .bearer_auth(s.token())
            .send(),
    )
    .await
    .expect("a token holder is answered in time despite the idle connections")
    .expect("the request gets an answer");
    assert_eq!(answer.status(), StatusCode::OK);
    let machines: Value = answer.json().await.unwrap();
    assert_eq!(machines[0]["id"], "demo");

    // Accepted in order, the idle connections plus the client's went beyond the cap by
    // this many: the oldest waiting ones were closed.
    let evicted = idle_count + 1 - max;
    for (i, c) in idle.iter_mut().take(evicted).enumerate() {
        timeout(BOUND, closed(c))
            .await
            .unwrap_or_else(|_| panic!("idle connection {i} closed at the connection cap"));
    }
    stop(s).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn half_a_request_head_is_closed_after_the_header_timeout() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = config(dir.path());
    cfg.service.header_timeout = Duration::from_secs(1);
    let s = start(cfg).await;
    let mut c = TcpStream::connect(s.local_addr()).await.unwrap();
    c.write_all(HALF_HEAD).await.unwrap();
    timeout(BOUND, closed(&mut c))
        .await
        .expect("closed after the header timeout");
    // Nothing at all is closed the same way.
    let mut c = TcpStream::connect(s.local_addr()).await.unwrap();
    timeout(BOUND, closed(&mut c))
        .await
        .expect("closed after the header timeout");
    stop(s).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_idle_keep_alive_connection_is_closed_after_the_idle_timeout() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = config(dir.path());
    // Only the idle timeout can close it within the bound.
    cfg.service.header_timeout = Duration::from_secs(3600);
    cfg.service.idle_timeout = Duration::from_secs(1);
    let s = start(cfg).await;
    let mut c = TcpStream::connect(s.local_addr()).await.unwrap();
    let status = timeout(BOUND, raw_get(&mut c, s.token()))
        .await
        .expect("answered in time");
    assert!(status.starts_with("HTTP/1.1 200"), "{status}");
    // Kept alive: a second request on the same connection is answered too.
    let status = timeout(BOUND, raw_get(&mut c, s.token()))
        .await
        .expect("answered in time");
    assert!(status.starts_with("HTTP/1.1 200"), "{status}");
    timeout(BOUND, closed(&mut c))
        .await
        .expect("closed after the idle timeout");
    stop(s).await;
}

/// A WebSocket outlives the header and idle timeouts: two connections with half a head,
/// opened after it, are closed (so more than twice the timeouts have passed since it
/// was upgraded), and it still answers a ping.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_websocket_is_not_idle_closed() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = config(dir.path());
    cfg.service.header_timeout = Duration::from_secs(1);
    cfg.service.idle_timeout = Duration::from_secs(1);
    let s = start(cfg).await;
    let mut ws = events(&s).await;

    for _ in 0..2 {
        let mut probe = TcpStream::connect(s.local_addr()).await.unwrap();
        probe.write_all(HALF_HEAD).await.unwrap();
        timeout(BOUND, closed(&mut probe))
            .await
            .expect("the probe is closed after the header timeout");
    }

    still_open(&mut ws).await;
    stop(s).await;
}

/// A WebSocket holds its connection slot and is never evicted: with
/// `max_connections = 1`, a new connection is closed at once while it is open (the
/// timeouts are too long to close anything), and it still answers.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_websocket_keeps_its_slot() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = config(dir.path());
    cfg.service.header_timeout = Duration::from_secs(3600);
    cfg.service.idle_timeout = Duration::from_secs(3600);
    cfg.service.max_connections = 1;
    let s = start(cfg).await;
    let mut ws = events(&s).await;
    let mut refused = TcpStream::connect(s.local_addr()).await.unwrap();
    timeout(BOUND, closed(&mut refused))
        .await
        .expect("the connection beyond the cap is closed");
    still_open(&mut ws).await;
    stop(s).await;
}

//! A client of the service in-process for tests: started on the demo machine with a
//! temporary data folder, its events on the WebSocket, requests with the token, and
//! waits that end on events (never on wall time).

use futures_util::StreamExt;
use reqwest::{Client, StatusCode};
use serde_json::{json, Value};
use service::{BoxConfig, Running};
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::Message;

type Ws =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

pub struct Api {
    _dir: tempfile::TempDir,
    pub s: Running,
    c: Client,
    ws: Ws,
    /// The machine jobs are queued on (the box's first).
    machine: String,
}

impl Api {
    pub async fn start() -> Api {
        Api::start_with(BoxConfig::demo).await
    }

    /// A service on the box `config` makes of a temporary data folder.
    pub async fn start_with(config: impl FnOnce(&std::path::Path) -> BoxConfig) -> Api {
        let dir = tempfile::tempdir().unwrap();
        let config = config(dir.path());
        let machine = config.machines[0].id.clone();
        let s = service::start(config).await.expect("service starts");
        let mut req = format!("ws://{}/api/v1/events", s.local_addr())
            .into_client_request()
            .unwrap();
        req.headers_mut().insert(
            "Sec-WebSocket-Protocol",
            format!("gateway.v1, bearer.{}", s.token()).parse().unwrap(),
        );
        let (ws, _) = tokio_tungstenite::connect_async(req).await.expect("ws");
        Api {
            _dir: dir,
            s,
            c: Client::new(),
            ws,
            machine,
        }
    }

    pub async fn next(&mut self) -> Value {
        loop {
            match self.ws.next().await.expect("events").expect("event") {
                Message::Text(t) => return serde_json::from_str(&t).unwrap(),
                Message::Close(_) => panic!("event stream closed"),
                _ => {}
            }
        }
    }

    /// Waits for the first event `pred` holds for.
    pub async fn until(&mut self, pred: impl Fn(&Value) -> bool) -> Value {
        loop {
            let e = self.next().await;
            if pred(&e) {
                return e;
            }
        }
    }

    pub async fn post(&self, path: &str, body: Value) -> (StatusCode, Value) {
        let r = self
            .c
            .post(format!("http://{}{path}", self.s.local_addr()))
            .bearer_auth(self.s.token())
            .json(&body)
            .send()
            .await
            .unwrap();
        let status = r.status();
        (status, r.json().await.unwrap_or(Value::Null))
    }

    pub async fn get(&self, path: &str) -> Value {
        let r = self
            .c
            .get(format!("http://{}{path}", self.s.local_addr()))
            .bearer_auth(self.s.token())
            .send()
            .await
            .unwrap();
        r.json().await.unwrap()
    }

    pub async fn queue(&self, kind: &str, params: Value) -> (StatusCode, Value) {
        let jobs = format!("/api/v1/machines/{}/jobs", self.machine);
        self.post(&jobs, json!({"kind": kind, "params": params}))
            .await
    }

    /// The job's final record.
    pub async fn finished(&mut self, id: &Value) -> Value {
        let e = self
            .until(|e| {
                e["type"] == "job"
                    && e["job"]["id"] == *id
                    && ["succeeded", "failed", "cancelled"]
                        .contains(&e["job"]["state"].as_str().unwrap_or(""))
            })
            .await;
        // The event is light (no params or result): the job's record has them.
        self.get(&format!("/api/v1/jobs/{}", e["job"]["id"])).await
    }

    /// Waits until the demo machine's devices are open (its state is idle).
    pub async fn machine_idle(&mut self) {
        if self.get("/api/v1/machines/demo").await["state"] == "idle" {
            return;
        }
        self.until(|e| e["type"] == "machine" && e["machine"]["state"] == "idle")
            .await;
    }
}

impl Api {
    /// Queues a job and waits for its final record.
    pub async fn run(&mut self, kind: &str, params: Value) -> Value {
        let (status, job) = self.queue(kind, params).await;
        assert_eq!(status, StatusCode::ACCEPTED, "{job}");
        self.finished(&job["id"]).await
    }
}

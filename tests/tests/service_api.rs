//! The service end to end, in-process on port 0 with a temp data dir and the embedded
//! demo machine: a job through the API with its events on the WebSocket, cancel,
//! restart recovery, the auth sweep of every route of the OpenAPI document, bad input.
//! No wall-time sleeps: every wait is on a WebSocket event.

use futures_util::StreamExt;
use reqwest::{Client, StatusCode};
use serde_json::{json, Value};
use service::{BoxConfig, Running};
use std::path::Path;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::Message;

type Ws =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

fn config(dir: &Path) -> BoxConfig {
    let mut c = BoxConfig::demo(dir);
    // Keep the wrong-token delay short so the sweep stays quick (the growth is the same).
    c.service.bad_token_delay_cap_ms = 5;
    c
}

async fn start(dir: &Path) -> Running {
    service::start(config(dir)).await.expect("service starts")
}

fn url(s: &Running, path: &str) -> String {
    format!("http://{}{}", s.local_addr(), path)
}

async fn get(c: &Client, s: &Running, path: &str) -> (StatusCode, Value) {
    let r = c
        .get(url(s, path))
        .bearer_auth(s.token())
        .send()
        .await
        .unwrap();
    let status = r.status();
    (status, r.json().await.unwrap_or(Value::Null))
}

async fn post(c: &Client, s: &Running, path: &str, body: Value) -> (StatusCode, Value) {
    let r = c
        .post(url(s, path))
        .bearer_auth(s.token())
        .json(&body)
        .send()
        .await
        .unwrap();
    let status = r.status();
    (status, r.json().await.unwrap_or(Value::Null))
}

/// Connects with the browser's way of authenticating: the subprotocol list.
async fn events(s: &Running) -> Ws {
    let mut req = format!("ws://{}/api/v1/events", s.local_addr())
        .into_client_request()
        .unwrap();
    req.headers_mut().insert(
        "Sec-WebSocket-Protocol",
        format!("gateway.v1, bearer.{}", s.token()).parse().unwrap(),
    );
    let (mut ws, response) = tokio_tungstenite::connect_async(req)
        .await
        .expect("ws connects");
    assert_eq!(
        response.headers().get("sec-websocket-protocol").unwrap(),
        "gateway.v1"
    );
    let hello = next(&mut ws).await;
    assert_eq!(hello["type"], "hello");
    assert_eq!(hello["machines"][0]["id"], "demo");
    ws
}

async fn next(ws: &mut Ws) -> Value {
    loop {
        match ws.next().await.expect("event stream open").expect("event") {
            Message::Text(t) => return serde_json::from_str(&t).unwrap(),
            Message::Close(_) => panic!("event stream closed"),
            _ => {}
        }
    }
}

/// Reads events until `pred` holds for one; returns every event seen up to it.
async fn until(ws: &mut Ws, pred: impl Fn(&Value) -> bool) -> Vec<Value> {
    let mut seen = Vec::new();
    loop {
        let e = next(ws).await;
        let done = pred(&e);
        seen.push(e);
        if done {
            return seen;
        }
    }
}

/// Reads events until job `id` has succeeded or failed; returns every event seen.
async fn until_finished(ws: &mut Ws, id: &Value) -> Vec<Value> {
    until(ws, |e| {
        e["type"] == "job"
            && e["job"]["id"] == *id
            && ["succeeded", "failed"].contains(&e["job"]["state"].as_str().unwrap_or(""))
    })
    .await
}

fn job_in(e: &Value, id: &Value, state: &str) -> bool {
    e["type"] == "job" && e["job"]["id"] == *id && e["job"]["state"] == state
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_runs_to_the_end_with_its_events() {
    let dir = tempfile::tempdir().unwrap();
    let s = start(dir.path()).await;
    let c = Client::new();
    let mut ws = events(&s).await;
    let (status, job) = post(
        &c,
        &s,
        "/api/v1/machines/demo/jobs",
        json!({"kind": "compensate", "params": {"targets": 1}}),
    )
    .await;
    assert_eq!(status, StatusCode::ACCEPTED, "{job}");
    assert_eq!(job["state"], "queued");
    let id = job["id"].clone();
    let seen = until(&mut ws, |e| job_in(e, &id, "succeeded")).await;
    assert!(seen.iter().any(|e| job_in(e, &id, "running")));
    // Job events are as light as the job list: ids, state, progress; never the params
    // or the result (a layout job's are megabytes), which the job's record holds.
    for e in seen.iter().filter(|e| e["type"] == "job") {
        assert!(
            e["job"].get("params").is_none() && e["job"].get("result").is_none(),
            "{e}"
        );
        assert!(
            e["job"]["kind"].is_string() && e["job"]["state"].is_string(),
            "{e}"
        );
    }
    assert!(seen
        .iter()
        .any(|e| e["type"] == "measurement" && e["job_id"] == id));
    assert!(seen
        .iter()
        .any(|e| e["type"] == "progress" && e["done"] == 1 && e["total"] == 1));
    assert!(seen
        .iter()
        .any(|e| e["type"] == "machine" && e["machine"]["state"] == "busy"));
    let (status, record) = get(&c, &s, &format!("/api/v1/jobs/{id}")).await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(record["state"], "succeeded");
    assert_eq!(record["progress"], json!({"done": 1, "total": 1}));
    assert_eq!(record["result"]["converged"], 1);
    let (_, ms) = get(&c, &s, &format!("/api/v1/jobs/{id}/measurements")).await;
    let n_measured = seen.iter().filter(|e| e["type"] == "measurement").count();
    assert_eq!(ms.as_array().unwrap().len(), n_measured);
    let (_, list) = get(&c, &s, "/api/v1/jobs?machine=demo&state=succeeded").await;
    assert_eq!(list.as_array().unwrap().len(), 1);
    let (_, charts) = get(&c, &s, &format!("/api/v1/jobs/{id}/charts")).await;
    assert_eq!(charts, json!([]));
    s.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cancel_a_queued_and_a_running_job() {
    let dir = tempfile::tempdir().unwrap();
    let s = start(dir.path()).await;
    let c = Client::new();
    let mut ws = events(&s).await;
    let (_, long) = post(
        &c,
        &s,
        "/api/v1/machines/demo/jobs",
        json!({"kind": "compensate"}),
    )
    .await;
    let (_, waiting) = post(
        &c,
        &s,
        "/api/v1/machines/demo/jobs",
        json!({"kind": "compensate", "params": {"targets": 1}}),
    )
    .await;
    let (long_id, waiting_id) = (long["id"].clone(), waiting["id"].clone());
    // The queued one goes at once.
    let (status, r) = post(
        &c,
        &s,
        &format!("/api/v1/jobs/{waiting_id}/cancel"),
        json!({}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{r}");
    assert_eq!(r["state"], "cancelled");
    // The running one stops after its first measurement, which is kept.
    until(&mut ws, |e| {
        e["type"] == "measurement" && e["job_id"] == long_id
    })
    .await;
    let (status, r) = post(&c, &s, &format!("/api/v1/jobs/{long_id}/cancel"), json!({})).await;
    assert_eq!(status, StatusCode::OK, "{r}");
    assert_eq!(r["state"], "cancelled");
    assert!(r["result"]["targets"].as_u64().unwrap() < 30, "{r}");
    let (_, ms) = get(&c, &s, &format!("/api/v1/jobs/{long_id}/measurements")).await;
    assert!(!ms.as_array().unwrap().is_empty());
    // A finished job cannot be cancelled: 409, and it stays as it was.
    let (status, e) = post(&c, &s, &format!("/api/v1/jobs/{long_id}/cancel"), json!({})).await;
    assert_eq!(status, StatusCode::CONFLICT);
    assert_eq!(e["error"], "job_finished");
    s.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn restart_marks_the_running_job_interrupted_and_runs_the_queue() {
    let dir = tempfile::tempdir().unwrap();
    {
        // The state a crash leaves: one job running, one queued.
        let mut store = store::Store::open(&dir.path().join("gateway.sqlite")).unwrap();
        let running = store.enqueue("demo", "compensate", &json!({})).unwrap();
        store.start(running.id, None).unwrap();
        store.add_measurement(running.id, &json!({"x": 1})).unwrap();
        store
            .enqueue("demo", "compensate", &json!({"targets": 1}))
            .unwrap();
    }
    // Subscribe before the worker can start the queued job: start, then connect; the
    // job may already be done, so read its record if the event was missed.
    let s = start(dir.path()).await;
    let c = Client::new();
    let (_, first) = get(&c, &s, "/api/v1/jobs/1").await;
    assert_eq!(first["state"], "interrupted");
    let (_, ms) = get(&c, &s, "/api/v1/jobs/1/measurements").await;
    assert_eq!(ms, json!([{"x": 1}]));
    let mut ws = events(&s).await;
    let (_, second) = get(&c, &s, "/api/v1/jobs/2").await;
    if second["state"] != "succeeded" {
        until(&mut ws, |e| job_in(e, &json!(2), "succeeded")).await;
    }
    let (_, second) = get(&c, &s, "/api/v1/jobs/2").await;
    assert_eq!(second["state"], "succeeded");
    s.shutdown().await;
}

/// Every route of the OpenAPI document, with its path parameters filled in.
async fn all_routes(c: &Client, s: &Running) -> Vec<(String, String)> {
    let (status, doc) = get(c, s, "/api/v1/openapi.json").await;
    assert_eq!(status, StatusCode::OK);
    assert!(doc["openapi"].as_str().unwrap().starts_with("3."));
    let mut routes = Vec::new();
    for (path, item) in doc["paths"].as_object().unwrap() {
        let concrete = path
            .replace("{machine}", "demo")
            .replace("{id}", "1")
            .replace("{name}", "error_map")
            .replace("{version}", "1")
            .replace("{file}", "deviation.svg");
        for method in item.as_object().unwrap().keys() {
            routes.push((method.to_uppercase(), concrete.clone()));
        }
    }
    assert!(routes.len() >= 16, "{routes:?}");
    routes
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn no_route_answers_with_data_without_the_right_token() {
    let dir = tempfile::tempdir().unwrap();
    let s = start(dir.path()).await;
    let c = Client::new();
    // Some data to leak: a job (on the demo machine) and a profile.
    post(
        &c,
        &s,
        "/api/v1/machines/demo/jobs",
        json!({"kind": "compensate", "params": {"targets": 1}}),
    )
    .await;
    s.store()
        .lock()
        .unwrap()
        .add_profile(
            "demo",
            "error_map",
            store::ProfileKind::ErrorMap,
            &json!({"secret": 1}),
            None,
            None,
        )
        .unwrap();
    for (method, path) in all_routes(&c, &s).await {
        let m: reqwest::Method = method.parse().unwrap();
        let cases = [
            (
                "no token",
                c.request(m.clone(), url(&s, &path)),
                StatusCode::UNAUTHORIZED,
            ),
            (
                "wrong token",
                c.request(m.clone(), url(&s, &path))
                    .bearer_auth("0".repeat(64)),
                StatusCode::UNAUTHORIZED,
            ),
            (
                "token in query",
                c.request(m.clone(), url(&s, &format!("{path}?token={}", s.token()))),
                StatusCode::BAD_REQUEST,
            ),
            (
                "token in query with header",
                c.request(
                    m.clone(),
                    url(&s, &format!("{path}?access_token={}", s.token())),
                )
                .bearer_auth(s.token()),
                StatusCode::BAD_REQUEST,
            ),
        ];
        for (what, req, want) in cases {
            let r = req
                .header("content-type", "application/json")
                .body("{}")
                .send()
                .await
                .unwrap();
            assert_eq!(r.status(), want, "{method} {path} {what}");
            let body: Value = r.json().await.unwrap();
            assert!(body["error"].is_string(), "{method} {path} {what}: {body}");
            assert_eq!(
                body.as_object().unwrap().len(),
                2,
                "{method} {path} {what}: {body}"
            );
        }
    }
    // The open routes hold no data.
    let r = c.get(url(&s, "/healthz")).send().await.unwrap();
    assert_eq!(r.json::<Value>().await.unwrap(), json!({"status": "ok"}));
    for page in ["/", "/app.js", "/style.css"] {
        assert_eq!(
            c.get(url(&s, page)).send().await.unwrap().status(),
            StatusCode::OK
        );
    }
    // Nothing was changed by the refused requests: still one job, no active profile.
    let (_, jobs) = get(&c, &s, "/api/v1/jobs").await;
    assert_eq!(jobs.as_array().unwrap().len(), 1);
    let (_, profiles) = get(&c, &s, "/api/v1/machines/demo/profiles").await;
    assert_eq!(profiles[0]["active"], false);
    s.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_input_gets_its_error_and_changes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = config(dir.path());
    let mut other = cfg.machines[0].clone();
    other.id = "other".into();
    cfg.machines.push(other);
    cfg.service.max_body_bytes = 1024;
    cfg.service.max_job_body_bytes = 2048;
    let s = service::start(cfg).await.unwrap();
    let c = Client::new();
    s.store()
        .lock()
        .unwrap()
        .add_profile(
            "demo",
            "error_map",
            store::ProfileKind::ErrorMap,
            &json!({}),
            None,
            None,
        )
        .unwrap();
    let jobs_path = "/api/v1/machines/demo/jobs";
    let raw = |body: &'static str| {
        c.post(url(&s, jobs_path))
            .bearer_auth(s.token())
            .header("content-type", "application/json")
            .body(body)
    };
    let checks: Vec<(&str, reqwest::RequestBuilder, StatusCode, &str)> = vec![
        (
            "bad JSON",
            raw("{\"kind\": "),
            StatusCode::BAD_REQUEST,
            "bad_json",
        ),
        (
            "wrong shape",
            raw("{\"kind\": 3}"),
            StatusCode::UNPROCESSABLE_ENTITY,
            "invalid_body",
        ),
        (
            "unknown field",
            raw("{\"kind\": \"compensate\", \"x\": 1}"),
            StatusCode::UNPROCESSABLE_ENTITY,
            "invalid_body",
        ),
        (
            "unknown kind",
            raw("{\"kind\": \"format_disk\"}"),
            StatusCode::UNPROCESSABLE_ENTITY,
            "invalid_job",
        ),
        (
            "bad params",
            raw("{\"kind\": \"compensate\", \"params\": {\"targets\": -1}}"),
            StatusCode::BAD_REQUEST,
            "invalid_params",
        ),
        (
            "body too large",
            c.post(url(&s, jobs_path))
                .bearer_auth(s.token())
                .header("content-type", "application/json")
                .body(format!(
                    "{{\"kind\": \"compensate\", \"params\": {{\"pad\": \"{}\"}}}}",
                    "x".repeat(4096)
                )),
            StatusCode::PAYLOAD_TOO_LARGE,
            "body_too_large",
        ),
        (
            "unknown machine",
            c.post(url(&s, "/api/v1/machines/nope/jobs"))
                .bearer_auth(s.token())
                .json(&json!({"kind": "compensate"})),
            StatusCode::NOT_FOUND,
            "unknown_machine",
        ),
        (
            "unknown job",
            c.get(url(&s, "/api/v1/jobs/999")).bearer_auth(s.token()),
            StatusCode::NOT_FOUND,
            "unknown_job",
        ),
        (
            "job id not a number",
            c.get(url(&s, "/api/v1/jobs/abc")).bearer_auth(s.token()),
            StatusCode::BAD_REQUEST,
            "bad_path",
        ),
        (
            "cancel unknown job",
            c.post(url(&s, "/api/v1/jobs/999/cancel"))
                .bearer_auth(s.token()),
            StatusCode::NOT_FOUND,
            "unknown_job",
        ),
        (
            "bad state filter",
            c.get(url(&s, "/api/v1/jobs?state=exploded"))
                .bearer_auth(s.token()),
            StatusCode::BAD_REQUEST,
            "bad_query",
        ),
        (
            "profile of another machine",
            c.get(url(&s, "/api/v1/machines/other/profiles/error_map/1"))
                .bearer_auth(s.token()),
            StatusCode::NOT_FOUND,
            "unknown_profile",
        ),
        (
            "activate a profile of another machine",
            c.post(url(
                &s,
                "/api/v1/machines/other/profiles/error_map/1/activate",
            ))
            .bearer_auth(s.token()),
            StatusCode::NOT_FOUND,
            "unknown_profile",
        ),
        (
            "unknown profile version",
            c.get(url(&s, "/api/v1/machines/demo/profiles/error_map/7"))
                .bearer_auth(s.token()),
            StatusCode::NOT_FOUND,
            "unknown_profile",
        ),
        (
            "path traversal",
            c.get(url(&s, "/api/v1/machines/..%2F..%2Fetc/profiles"))
                .bearer_auth(s.token()),
            StatusCode::NOT_FOUND,
            "unknown_machine",
        ),
        (
            "unknown route",
            c.get(url(&s, "/api/v1/nothing")).bearer_auth(s.token()),
            StatusCode::NOT_FOUND,
            "not_found",
        ),
    ];
    for (what, req, want, code) in checks {
        let r = req.send().await.unwrap();
        assert_eq!(r.status(), want, "{what}");
        let body: Value = r.json().await.unwrap();
        assert_eq!(body["error"], code, "{what}: {body}");
        assert!(!body["message"].as_str().unwrap().is_empty(), "{what}");
        if code == "body_too_large" {
            // The limit and where it is set are named.
            let m = body["message"].as_str().unwrap();
            assert!(
                m.contains("2048 bytes") && m.contains("service.max_job_body_bytes"),
                "{m}"
            );
        }
    }
    let (_, jobs) = get(&c, &s, "/api/v1/jobs").await;
    assert_eq!(jobs, json!([]), "a refused request queued a job");
    let (_, profiles) = get(&c, &s, "/api/v1/machines/demo/profiles").await;
    assert_eq!(profiles[0]["active"], false);

    // `if_idle` on a busy machine: 409, nothing queued.
    let mut ws = events(&s).await;
    let (_, long) = post(&c, &s, jobs_path, json!({"kind": "compensate"})).await;
    let long_id = long["id"].clone();
    until(&mut ws, |e| job_in(e, &long_id, "running")).await;
    let (status, e) = post(
        &c,
        &s,
        jobs_path,
        json!({"kind": "compensate", "if_idle": true}),
    )
    .await;
    assert_eq!(status, StatusCode::CONFLICT);
    assert_eq!(e["error"], "machine_busy");
    let (_, jobs) = get(&c, &s, "/api/v1/jobs").await;
    assert_eq!(jobs.as_array().unwrap().len(), 1);
    // Without if_idle it queues.
    let (status, _) = post(
        &c,
        &s,
        jobs_path,
        json!({"kind": "compensate", "params": {"targets": 1}}),
    )
    .await;
    assert_eq!(status, StatusCode::ACCEPTED);
    // Activating and rolling back go through.
    let (status, p) = post(
        &c,
        &s,
        "/api/v1/machines/demo/profiles/error_map/1/activate",
        json!({}),
    )
    .await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(p["active"], true);
    let (status, e) = post(
        &c,
        &s,
        "/api/v1/machines/demo/profiles/error_map/rollback",
        json!({}),
    )
    .await;
    assert_eq!(status, StatusCode::CONFLICT, "{e}");
    // Shutdown stops the running job safely: saved as cancelled with its measurements.
    let store = s.store();
    s.shutdown().await;
    let record = store
        .lock()
        .unwrap()
        .job(long_id.as_i64().unwrap())
        .unwrap()
        .unwrap();
    assert_eq!(record.state, store::JobState::Cancelled);
    ws.close(None).await.ok();
}

/// An ISO 230-2 job through the API: its measurements as they come, the figures in the
/// result, the deviation chart served as SVG; asked with the map while no error map is
/// active, it fails saying so, and nothing moved.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_iso230_job_keeps_its_figures_and_chart() {
    let dir = tempfile::tempdir().unwrap();
    let s = start(dir.path()).await;
    let c = Client::new();
    let mut ws = events(&s).await;
    let (status, job) = post(
        &c,
        &s,
        "/api/v1/machines/demo/jobs",
        json!({"kind": "iso230", "params": {"axis": "X", "positions": 5, "runs": 5}}),
    )
    .await;
    assert_eq!(status, StatusCode::ACCEPTED, "{job}");
    let id = job["id"].clone();
    let seen = until_finished(&mut ws, &id).await;
    // The event is light (no params or result): the job's record has them.
    let last = &get(&c, &s, &format!("/api/v1/jobs/{id}")).await.1;
    assert_eq!(last["state"], "succeeded", "{last}");
    // 5 positions x 5 runs x 2 directions, each seen live and kept.
    let live = seen
        .iter()
        .filter(|e| e["type"] == "measurement" && e["job_id"] == id)
        .count();
    assert_eq!(live, 50);
    let (_, kept) = get(&c, &s, &format!("/api/v1/jobs/{id}/measurements")).await;
    assert_eq!(kept.as_array().unwrap().len(), 50);
    // Each event's `row` rises, and a fetch names the row of its newest measurement:
    // a page appends only the events after its fetch.
    let rows: Vec<i64> = seen
        .iter()
        .filter(|e| e["type"] == "measurement" && e["job_id"] == id)
        .map(|e| e["row"].as_i64().expect("a measurement event's row"))
        .collect();
    assert!(rows.windows(2).all(|w| w[0] < w[1]), "{rows:?}");
    let r = c
        .get(url(&s, &format!("/api/v1/jobs/{id}/measurements")))
        .bearer_auth(s.token())
        .send()
        .await
        .unwrap();
    let last = r.headers()["x-last-measurement-row"].to_str().unwrap();
    assert_eq!(last.parse::<i64>().unwrap(), *rows.last().unwrap());
    assert!(kept[0]["deviation_um"].as_f64().unwrap().is_finite());
    let (_, record) = get(&c, &s, &format!("/api/v1/jobs/{id}")).await;
    assert_eq!(record["result"]["standard"], "ISO 230-2");
    assert_eq!(record["result"]["positions"], 5);
    assert_eq!(record["result"]["runs_up"], json!([5, 5, 5, 5, 5]));
    assert!(record["profile"].is_null());
    let (status, charts) = get(&c, &s, &format!("/api/v1/jobs/{id}/charts")).await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(charts[0]["name"], "deviation_x", "{charts}");
    let svg = c
        .get(url(&s, charts[0]["url"].as_str().unwrap()))
        .bearer_auth(s.token())
        .send()
        .await
        .unwrap();
    assert_eq!(svg.status(), StatusCode::OK);
    assert!(svg.text().await.unwrap().contains("<svg"));
    // The charts are files of the job, not part of its record (a 38 kB SVG each).
    assert!(record["result"].get("charts").is_none(), "{record}");
    assert!(
        record.to_string().len() < 20_000,
        "{} bytes",
        record.to_string().len()
    );
    let (_, files) = get(&c, &s, &format!("/api/v1/jobs/{id}/files")).await;
    let names: Vec<&str> = files
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|f| f["name"].as_str())
        .collect();
    assert!(
        names.contains(&"deviation_x.svg") && names.contains(&"report.html"),
        "{files}"
    );
    let report = files
        .as_array()
        .unwrap()
        .iter()
        .find(|f| f["name"] == "report.html")
        .unwrap();
    let r = c
        .get(url(&s, report["url"].as_str().unwrap()))
        .bearer_auth(s.token())
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::OK);
    // Anything but a picture is downloaded, never rendered in the service's origin.
    assert_eq!(
        r.headers()["content-disposition"],
        "attachment; filename=\"report.html\""
    );
    assert_eq!(r.bytes().await.unwrap().len() as u64, report["size"]);

    // With the map, but no error map is active on this machine.
    let (status, job) = post(
        &c,
        &s,
        "/api/v1/machines/demo/jobs",
        json!({"kind": "iso230", "params": {"axis": "Y", "with_map": true}}),
    )
    .await;
    assert_eq!(status, StatusCode::ACCEPTED, "{job}");
    let id = job["id"].clone();
    until(&mut ws, |e| job_in(e, &id, "failed")).await;
    let (_, record) = get(&c, &s, &format!("/api/v1/jobs/{id}")).await;
    assert!(
        record["error"]
            .as_str()
            .unwrap()
            .contains("no active error_map profile"),
        "{record}"
    );
    let (_, kept) = get(&c, &s, &format!("/api/v1/jobs/{id}/measurements")).await;
    assert!(kept.as_array().unwrap().is_empty());
    // Bad parameters are refused when queued.
    let (status, body) = post(
        &c,
        &s,
        "/api/v1/machines/demo/jobs",
        json!({"kind": "iso230", "params": {"axis": "Z"}}),
    )
    .await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");
    assert!(body["message"].as_str().unwrap().contains("params.axis"));
    s.shutdown().await;
}

/// The error map of the demo machine as a profile: refused when unreadable, stored,
/// drawn as a heat map, activated, and used by an ISO 230-2 job that records its version.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_uploaded_error_map_is_drawn_activated_and_used_by_a_job() {
    use job::{Job, StageSpec};
    let dir = tempfile::tempdir().unwrap();
    let s = start(dir.path()).await;
    let c = Client::new();
    let mut ws = events(&s).await;
    let demo = Job::demo();
    let StageSpec::Sim { machine } = &demo.stage else {
        unreachable!("the demo job is simulated")
    };
    let mut cold = machine.clone();
    cold.thermal = None;
    // The machine's own identity (a map of another machine is refused by every job).
    let identity = procedure::identity_of_job(&demo).await.unwrap();
    let map = system_tests::truth_map::map_from_truth(&cold, identity);
    let text = map.to_json();
    let body: Value = serde_json::from_str(&text).unwrap();

    // An unreadable body is refused naming what is wrong; nothing is stored.
    let (status, err) = post(
        &c,
        &s,
        "/api/v1/machines/demo/profiles/stage-map",
        json!({"kind": "error_map", "body": {"schema": "nonsense"}}),
    )
    .await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{err}");
    assert_eq!(err["error"], "invalid_profile");
    let (_, list) = get(&c, &s, "/api/v1/machines/demo/profiles").await;
    assert!(list.as_array().unwrap().is_empty());

    let (status, p) = post(
        &c,
        &s,
        "/api/v1/machines/demo/profiles/stage-map",
        json!({"kind": "error_map", "body": body, "note": "from the truth"}),
    )
    .await;
    assert_eq!(status, StatusCode::CREATED, "{p}");
    assert_eq!(p["version"], 1);
    assert_eq!(p["active"], false);
    let heat = c
        .get(url(
            &s,
            "/api/v1/machines/demo/profiles/stage-map/1/heatmap.svg",
        ))
        .bearer_auth(s.token())
        .send()
        .await
        .unwrap();
    assert_eq!(heat.status(), StatusCode::OK);
    // Served sandboxed: opened on its own, an SVG runs nothing in the service's origin.
    let csp = heat.headers()["content-security-policy"].to_str().unwrap();
    assert!(
        csp.contains("sandbox") && csp.contains("default-src 'none'"),
        "{csp}"
    );
    let svg = heat.text().await.unwrap();
    assert!(svg.contains("<svg") && svg.contains("Error map stage-map v1"));
    // A second scan in which one node moved by (3, 4) um: the diff finds it, there.
    let mut moved = map.clone();
    let node = &mut moved.grid.nodes[7];
    for side in [&mut node.forward, &mut node.reverse] {
        side.ex_um.mean += 3.0;
        side.ey_um.mean += 4.0;
    }
    let moved_body: Value = serde_json::from_str(&moved.to_json()).unwrap();
    let (status, p) = post(
        &c,
        &s,
        "/api/v1/machines/demo/profiles/stage-map",
        json!({"kind": "error_map", "body": moved_body}),
    )
    .await;
    assert_eq!(status, StatusCode::CREATED, "{p}");
    let (status, d) = get(&c, &s, "/api/v1/machines/demo/profiles/stage-map/2/diff").await;
    assert_eq!(status, StatusCode::OK, "{d}");
    assert_eq!((d["from"].as_u64(), d["to"].as_u64()), (Some(1), Some(2)));
    assert!(
        (d["map"]["max_um"].as_f64().unwrap() - 5.0).abs() < 1e-9,
        "{d}"
    );
    let g = &map.grid;
    let at = [g.xs[7 % g.xs.len()], g.ys[7 / g.xs.len()]];
    assert_eq!(d["map"]["max_at_mm"], json!(at), "{d}");
    assert!(d["summary"].as_str().unwrap().contains("5.00 µm"), "{d}");
    let (status, _) = get(&c, &s, "/api/v1/machines/demo/profiles/stage-map/1/diff").await;
    assert_eq!(
        status,
        StatusCode::NOT_FOUND,
        "version 1 has none before it"
    );
    let (status, _) = post(
        &c,
        &s,
        "/api/v1/machines/demo/profiles/stage-map/1/activate",
        json!({}),
    )
    .await;
    assert_eq!(status, StatusCode::OK);

    let (status, job) = post(
        &c,
        &s,
        "/api/v1/machines/demo/jobs",
        json!({"kind": "iso230", "params": {"axis": "X", "positions": 5, "runs": 5, "with_map": true}}),
    )
    .await;
    assert_eq!(status, StatusCode::ACCEPTED, "{job}");
    let id = job["id"].clone();
    until_finished(&mut ws, &id).await;
    // The event is light (no params or result): the job's record has them.
    let last = &get(&c, &s, &format!("/api/v1/jobs/{id}")).await.1;
    assert_eq!(last["state"], "succeeded", "{last}");
    assert_eq!(last["profile"], json!({"name": "stage-map", "version": 1}));

    // A verification with the active map: the camera's residual at random points is far
    // below what the map predicts without it.
    let (status, job) = post(
        &c,
        &s,
        "/api/v1/machines/demo/jobs",
        json!({"kind": "verify", "params": {"points": 4, "seed": 3}}),
    )
    .await;
    assert_eq!(status, StatusCode::ACCEPTED, "{job}");
    let id = job["id"].clone();
    until_finished(&mut ws, &id).await;
    // The event is light (no params or result): the job's record has them.
    let last = &get(&c, &s, &format!("/api/v1/jobs/{id}")).await.1;
    assert_eq!(last["state"], "succeeded", "{last}");
    assert_eq!(last["profile"], json!({"name": "stage-map", "version": 1}));
    let r = &last["result"];
    assert_eq!(r["points"].as_array().unwrap().len(), 4);
    let residual = r["residual_um"]["max"].as_f64().unwrap();
    let without = r["uncompensated_um"]["max"].as_f64().unwrap();
    assert!(residual < 0.2 * without, "{residual} vs {without}");
    s.shutdown().await;
}

/// A layout job partitions a layout given in its params (no device moves); bad params
/// are refused at queue time naming the parameter.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_layout_job_partitions_the_layout_it_is_given() {
    let dir = tempfile::tempdir().unwrap();
    let s = start(dir.path()).await;
    let c = Client::new();
    let mut ws = events(&s).await;
    // Three squares along X: L' 25 mm puts the third in a second window.
    let layout = json!({"units": "mm", "width_mm": 40, "parts": [
        {"id": "a", "contours": [[[0, 5], [10, 5], [10, 15], [0, 15]]]},
        {"id": "b", "contours": [[[12, 5], [22, 5], [22, 15], [12, 15]]]},
        {"id": "c", "contours": [[[24, 5], [34, 5], [34, 15], [24, 15]]]},
    ]})
    .to_string();
    let (status, err) = post(
        &c,
        &s,
        "/api/v1/machines/demo/jobs",
        json!({"kind": "layout", "params": {"layout": layout, "format": "json", "tools": 2, "window_mm": 25}}),
    )
    .await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{err}");
    assert!(err["message"].as_str().unwrap().contains("gap_mm"), "{err}");
    let (status, job) = post(
        &c,
        &s,
        "/api/v1/machines/demo/jobs",
        json!({"kind": "layout", "params": {"layout": layout, "format": "json", "tools": 2, "window_mm": 25, "gap_mm": 2}}),
    )
    .await;
    assert_eq!(status, StatusCode::ACCEPTED, "{job}");
    let id = job["id"].clone();
    until_finished(&mut ws, &id).await;
    // The event is light (no params or result): the job's record has them.
    let last = &get(&c, &s, &format!("/api/v1/jobs/{id}")).await.1;
    assert_eq!(last["state"], "succeeded", "{last}");
    let groups = last["result"]["groups"].as_array().unwrap();
    assert_eq!(groups.len(), 2, "{groups:?}");
    assert_eq!(groups[0]["parts"], json!(["a", "b"]));
    assert_eq!(groups[1]["parts"], json!(["c"]));
    assert_eq!(groups[1]["dx_mm"], 2.0);
    // The shifted layout comes back in the format it was given.
    let shifted: Value = serde_json::from_str(last["result"]["layout"].as_str().unwrap()).unwrap();
    assert_eq!(shifted["parts"][2]["contours"][0][0], json!([26.0, 5.0]));
    s.shutdown().await;
}

/// A map job scans the demo machine and leaves the map as the next version of its
/// profile (inactive), with the job as its source; its heat map is drawn.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_map_job_becomes_a_profile_version() {
    let dir = tempfile::tempdir().unwrap();
    let s = start(dir.path()).await;
    let c = Client::new();
    let mut ws = events(&s).await;
    let (status, body) = post(
        &c,
        &s,
        "/api/v1/machines/demo/jobs",
        json!({"kind": "map", "params": {"name": "bad name!"}}),
    )
    .await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");
    let (status, job) = post(
        &c,
        &s,
        "/api/v1/machines/demo/jobs",
        json!({"kind": "map", "params": {"name": "scan", "grid_step_mm": 50.0, "line_step_mm": 25.0, "passes": 1}}),
    )
    .await;
    assert_eq!(status, StatusCode::ACCEPTED, "{job}");
    let id = job["id"].clone();
    let seen = until_finished(&mut ws, &id).await;
    // The event is light (no params or result): the job's record has them.
    let last = &get(&c, &s, &format!("/api/v1/jobs/{id}")).await.1;
    assert_eq!(last["state"], "succeeded", "{last}");
    assert_eq!(
        (&last["result"]["name"], &last["result"]["version"]),
        (&json!("scan"), &json!(1))
    );
    assert_eq!(last["result"]["kept_as"], "error_map profile scan v1");
    let frames = last["result"]["frames"].as_u64().unwrap();
    let (_, kept) = get(&c, &s, &format!("/api/v1/jobs/{id}/measurements")).await;
    assert_eq!(kept.as_array().unwrap().len() as u64, frames);
    let (_, list) = get(&c, &s, "/api/v1/machines/demo/profiles").await;
    assert_eq!(list[0]["name"], "scan");
    assert_eq!(list[0]["kind"], "error_map");
    assert_eq!(list[0]["active"], false);
    assert_eq!(list[0]["source_job"], id);
    // The scan shows its frames too: the machine's last one is this job's, with its dots
    // and the plan point it measured.
    assert!(seen
        .iter()
        .any(|e| e["type"] == "frame" && e["job_id"] == id));
    let (status, f) = get(&c, &s, "/api/v1/machines/demo/frame.json").await;
    assert_eq!(status, StatusCode::OK, "{f}");
    assert_eq!(f["job_id"], id);
    assert!(f["overlay"]["dots"].as_array().unwrap().len() >= 12, "{f}");
    let heat = c
        .get(url(&s, "/api/v1/machines/demo/profiles/scan/1/heatmap.svg"))
        .bearer_auth(s.token())
        .send()
        .await
        .unwrap();
    assert_eq!(heat.status(), StatusCode::OK);
    s.shutdown().await;
}

/// A rotary job measures the demo machine's simulated A/C table through the paper's
/// cycle: progress per ball, every ball's sphere kept, the eight errors identified
/// within the probe's noise of the injected ones, and kept as the next (inactive)
/// version of a rotary profile whose body `gateway rewrite --rotary` reads.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_rotary_job_identifies_the_table_and_becomes_a_profile_version() {
    let dir = tempfile::tempdir().unwrap();
    let s = start(dir.path()).await;
    let c = Client::new();
    let mut ws = events(&s).await;
    let (_, machine) = get(&c, &s, "/api/v1/machines/demo").await;
    assert_eq!(machine["rotary"], "sim", "{machine}");
    let (status, body) = post(
        &c,
        &s,
        "/api/v1/machines/demo/jobs",
        json!({"kind": "rotary", "params": {"name": "table", "steps": 3}}),
    )
    .await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");
    assert!(
        body["message"].as_str().unwrap().contains("params.steps"),
        "{body}"
    );
    let (status, job) = post(
        &c,
        &s,
        "/api/v1/machines/demo/jobs",
        json!({"kind": "rotary", "params": {"name": "table"}}),
    )
    .await;
    assert_eq!(status, StatusCode::ACCEPTED, "{job}");
    let id = job["id"].clone();
    let seen = until_finished(&mut ws, &id).await;
    // The event is light (no params or result): the job's record has them.
    let last = &get(&c, &s, &format!("/api/v1/jobs/{id}")).await.1;
    assert_eq!(last["state"], "succeeded", "{last}");
    let progress: Vec<u64> = seen
        .iter()
        .filter(|e| e["type"] == "progress")
        .map(|e| e["done"].as_u64().unwrap())
        .collect();
    let balls = last["result"]["cycle"]["balls"].as_u64().unwrap();
    assert_eq!(progress.last(), Some(&balls), "{progress:?}");
    let result = &last["result"];
    for name in [
        "delta_XC_mm",
        "delta_YC_mm",
        "alpha_XC_deg",
        "alpha_YC_deg",
        "delta_YA_mm",
        "delta_ZA_mm",
        "alpha_YA_deg",
        "alpha_ZA_deg",
    ] {
        let d = result["truth"][name]["difference"].as_f64().unwrap();
        let tol = if name.ends_with("_deg") {
            0.0005
        } else {
            0.001
        };
        assert!(d.abs() <= tol, "{name}: {d}");
    }
    assert!(
        result["compensation_check"]["tip_improvement_pct"]
            .as_f64()
            .unwrap()
            >= 95.0
    );
    assert_eq!(result["kept_as"], "rotary profile table v1");
    let (_, kept) = get(&c, &s, &format!("/api/v1/jobs/{id}/measurements")).await;
    assert_eq!(kept.as_array().unwrap().len() as u64, balls);
    let (_, charts) = get(&c, &s, &format!("/api/v1/jobs/{id}/charts")).await;
    assert_eq!(charts[0]["name"], "rotary-sweeps", "{charts}");
    let (_, list) = get(&c, &s, "/api/v1/machines/demo/profiles").await;
    let profile = list
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["name"] == "table")
        .unwrap();
    assert_eq!(profile["kind"], "rotary");
    assert_eq!(profile["active"], false);
    assert_eq!(profile["source_job"], id);
    // The body is the errors file `gateway rewrite --rotary` reads.
    let (_, stored) = get(&c, &s, "/api/v1/machines/demo/profiles/table/1").await;
    let errors = rotary::LocationErrors::from_json(&stored["body"].to_string()).unwrap();
    assert_eq!(json!(errors.delta_xc_mm), result["delta_XC_mm"]);
    s.shutdown().await;

    // A machine without a rotary table refuses the job, naming what is missing.
    let dir = tempfile::tempdir().unwrap();
    let mut without = config(dir.path());
    without.machines[0].rotary = None;
    let s = service::start(without).await.expect("service starts");
    let (_, machine) = get(&c, &s, "/api/v1/machines/demo").await;
    assert_eq!(machine["rotary"], Value::Null);
    let (status, body) = post(
        &c,
        &s,
        "/api/v1/machines/demo/jobs",
        json!({"kind": "rotary"}),
    )
    .await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    assert!(
        body["message"].as_str().unwrap().contains("rotary"),
        "{body}"
    );
    let (_, jobs) = get(&c, &s, "/api/v1/jobs").await;
    assert_eq!(jobs.as_array().map(Vec::len), Some(0), "{jobs}");
    s.shutdown().await;
}

/// Every answer carries the page's security headers; the auth scheme is
/// case-insensitive; a job's body may carry a layout of apparel size (the 413 that names
/// its limit: `bad_input_gets_its_error_and_changes_nothing`).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn answers_carry_the_security_headers_and_take_a_layout_sized_job() {
    let dir = tempfile::tempdir().unwrap();
    let s = start(dir.path()).await;
    let c = Client::new();
    for path in [
        "/",
        "/app.js",
        "/healthz",
        "/api/v1/machines",
        "/api/v1/nothing",
    ] {
        let r = c
            .get(url(&s, path))
            .bearer_auth(s.token())
            .send()
            .await
            .unwrap();
        let h = r.headers();
        let csp = h["content-security-policy"].to_str().unwrap();
        assert!(
            csp.contains("script-src 'self'") && csp.contains("frame-ancestors 'none'"),
            "{path}: {csp}"
        );
        assert_eq!(h["x-content-type-options"], "nosniff", "{path}");
        assert_eq!(h["x-frame-options"], "DENY", "{path}");
    }
    // `bearer`, `BEARER`: the scheme is case-insensitive (RFC 9110).
    for scheme in ["bearer", "BEARER", "Bearer"] {
        let r = c
            .get(url(&s, "/api/v1/machines"))
            .header("authorization", format!("{scheme} {}", s.token()))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), StatusCode::OK, "{scheme}");
    }
    // A 300 kB layout job is taken (the job route's own limit, 16 MiB by default).
    let layout = format!("{{\"parts\": [], \"pad\": \"{}\"}}", "x".repeat(300 * 1024));
    let r = c
        .post(url(&s, "/api/v1/machines/demo/jobs"))
        .bearer_auth(s.token())
        .json(
            &json!({"kind": "layout", "params": {"layout": layout, "format": "json",
            "tools": 2, "window_mm": 100.0, "gap_mm": 5.0}}),
        )
        .send()
        .await
        .unwrap();
    assert_ne!(r.status(), StatusCode::PAYLOAD_TOO_LARGE);
    s.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_queued_job_is_moved_and_the_queue_runs_in_its_new_order() {
    let dir = tempfile::tempdir().unwrap();
    let s = start(dir.path()).await;
    let c = Client::new();
    let mut ws = events(&s).await;
    let enqueue = |params: Value| {
        let (c, s) = (&c, &s);
        async move {
            let (status, job) = post(
                c,
                s,
                "/api/v1/machines/demo/jobs",
                json!({"kind": "compensate", "params": params}),
            )
            .await;
            assert_eq!(status, StatusCode::ACCEPTED, "{job}");
            job["id"].as_i64().unwrap()
        }
    };
    // A long job holds the machine while three short ones wait behind it.
    let long = enqueue(json!({})).await;
    until(&mut ws, |e| job_in(e, &json!(long), "running")).await;
    let (a, b, d) = (
        enqueue(json!({"targets": 1})).await,
        enqueue(json!({"targets": 1})).await,
        enqueue(json!({"targets": 1})).await,
    );
    let queue_ids = |v: &Value| -> Vec<i64> {
        v.as_array()
            .unwrap()
            .iter()
            .map(|j| j["id"].as_i64().unwrap())
            .collect()
    };
    // To the front by position, then one to the end with `before: null`.
    let (status, r) = post(
        &c,
        &s,
        &format!("/api/v1/jobs/{d}/move"),
        json!({"position": 0}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{r}");
    assert_eq!(r["machine"], "demo");
    assert_eq!(queue_ids(&r["queue"]), [d, a, b]);
    let (status, r) = post(
        &c,
        &s,
        &format!("/api/v1/jobs/{a}/move"),
        json!({"before": null}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{r}");
    assert_eq!(queue_ids(&r["queue"]), [d, b, a]);
    let (status, r) = post(
        &c,
        &s,
        &format!("/api/v1/jobs/{a}/move"),
        json!({"before": b}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{r}");
    assert_eq!(queue_ids(&r["queue"]), [d, a, b]);
    // The queue route, the machine's record and its event say the same.
    let (_, q) = get(&c, &s, "/api/v1/machines/demo/queue").await;
    assert_eq!(queue_ids(&q), [d, a, b]);
    let (_, m) = get(&c, &s, "/api/v1/machines/demo").await;
    assert_eq!(queue_ids(&m["queue"]), [d, a, b]);
    assert_eq!(m["queued"], 3);
    let seen = until(&mut ws, |e| {
        e["type"] == "machine"
            && e["machine"]["queue"]
                .as_array()
                .is_some_and(|q| q.len() == 3 && q[0]["id"] == d && q[1]["id"] == a)
    })
    .await;
    assert!(!seen.is_empty());
    // Refusals name their field; nothing moves.
    for (body, field) in [
        (json!({}), "before"),
        (json!({"position": 3}), "position"),
        (json!({"position": -1}), "position"),
        (json!({"before": long}), "before"),
        (json!({"before": "x"}), "before"),
        (json!({"before": a, "position": 0}), "position"),
        (json!({"after": a}), "after"),
    ] {
        let (status, e) = post(&c, &s, &format!("/api/v1/jobs/{b}/move"), body.clone()).await;
        assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}: {e}");
        assert_eq!(e["error"], "invalid_body", "{body}: {e}");
        assert_eq!(e["field"], field, "{body}: {e}");
        assert!(
            e["message"]
                .as_str()
                .unwrap()
                .starts_with(&format!("{field}: ")),
            "{e}"
        );
    }
    let (status, e) = post(
        &c,
        &s,
        &format!("/api/v1/jobs/{long}/move"),
        json!({"position": 0}),
    )
    .await;
    assert_eq!(status, StatusCode::CONFLICT, "{e}");
    assert_eq!(e["error"], "not_queued");
    let (status, e) = post(&c, &s, "/api/v1/jobs/9999/move", json!({"position": 0})).await;
    assert_eq!(status, StatusCode::NOT_FOUND, "{e}");
    assert_eq!(e["error"], "unknown_job");
    let (_, q) = get(&c, &s, "/api/v1/machines/demo/queue").await;
    assert_eq!(queue_ids(&q), [d, a, b]);
    // The worker follows the new order: after the long job, `d` runs first, then `a`.
    let (status, r) = post(&c, &s, &format!("/api/v1/jobs/{b}/cancel"), json!({})).await;
    assert_eq!(
        (status, r["state"].as_str()),
        (StatusCode::OK, Some("cancelled"))
    );
    let (status, r) = post(&c, &s, &format!("/api/v1/jobs/{long}/cancel"), json!({})).await;
    assert_eq!(
        (status, r["state"].as_str()),
        (StatusCode::OK, Some("cancelled"))
    );
    let started: Vec<i64> = until(&mut ws, |e| job_in(e, &json!(a), "succeeded"))
        .await
        .iter()
        .filter(|e| e["type"] == "job" && e["job"]["state"] == "running")
        .map(|e| e["job"]["id"].as_i64().unwrap())
        .collect();
    assert_eq!(started, [d, a]);
    s.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_compensate_job_shows_its_last_frame_with_the_dots() {
    let dir = tempfile::tempdir().unwrap();
    let s = start(dir.path()).await;
    let c = Client::new();
    // None before any job: the API's error shape.
    let (status, body) = get(&c, &s, "/api/v1/machines/demo/frame").await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    assert_eq!(body["error"], "no_frame", "{body}");
    let (status, body) = get(&c, &s, "/api/v1/machines/demo/frame.json").await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    assert_eq!(body["error"], "no_frame", "{body}");
    let (status, body) = get(&c, &s, "/api/v1/machines/nope/frame").await;
    assert_eq!(
        (status, body["error"].clone()),
        (StatusCode::NOT_FOUND, json!("unknown_machine"))
    );

    let mut ws = events(&s).await;
    let (status, job) = post(
        &c,
        &s,
        "/api/v1/machines/demo/jobs",
        json!({"kind": "compensate", "params": {"targets": 1}}),
    )
    .await;
    assert_eq!(status, StatusCode::ACCEPTED, "{job}");
    let id = job["id"].clone();
    let seen = until(&mut ws, |e| job_in(e, &id, "succeeded")).await;
    // The event says a frame is there, without its bytes.
    let frames: Vec<&Value> = seen.iter().filter(|e| e["type"] == "frame").collect();
    assert!(!frames.is_empty(), "no frame event");
    for f in &frames {
        assert_eq!(f["machine"], "demo");
        assert_eq!(f["job_id"], id);
        assert!(f.get("png").is_none() && f.to_string().len() < 300, "{f}");
    }

    let r = c
        .get(url(&s, "/api/v1/machines/demo/frame"))
        .bearer_auth(s.token())
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::OK);
    assert_eq!(r.headers()["content-type"], "image/png");
    let png = r.bytes().await.unwrap();
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    assert_eq!(&png[12..16], b"IHDR");
    let be = |b: &[u8]| u32::from_be_bytes([b[0], b[1], b[2], b[3]]);
    let (w, h) = (be(&png[16..20]), be(&png[20..24]));
    // 8-bit grey.
    assert_eq!((png[24], png[25]), (8, 0));

    let (status, f) = get(&c, &s, "/api/v1/machines/demo/frame.json").await;
    assert_eq!(status, StatusCode::OK, "{f}");
    assert_eq!(f["job_id"], id);
    assert!(f["at"].as_str().unwrap().ends_with('Z'), "{f}");
    let o = &f["overlay"];
    assert_eq!(
        (o["width"].as_u64(), o["height"].as_u64()),
        (Some(w.into()), Some(h.into()))
    );
    assert!((100..=320).contains(&w), "{w}x{h}");
    assert_eq!(
        o["source_width"].as_u64().unwrap() / o["factor"].as_u64().unwrap(),
        u64::from(w)
    );
    let dots = o["dots"].as_array().unwrap();
    assert!(dots.len() >= 12, "{} dots", dots.len());
    for d in dots {
        let (x, y) = (d[0].as_f64().unwrap(), d[1].as_f64().unwrap());
        assert!(
            (-0.5..w as f64).contains(&x) && (-0.5..h as f64).contains(&y),
            "{d}"
        );
    }
    // The measured point: the image centre and its board coordinate near the target.
    let c_px = &o["centre_px"];
    assert!(
        (c_px[0].as_f64().unwrap() - (w as f64 - 1.0) / 2.0).abs() < 1.0,
        "{c_px}"
    );
    // Which frame was the last shown depends on wall time (one per FRAME_EVERY): one of
    // a target carries its deviation, one of the orientation check has neither.
    assert!(o["centre_mm"][0].is_number(), "{o}");
    if o["target_mm"].is_null() {
        assert!(o["deviation_um"].is_null(), "{o}");
    } else {
        let dev = o["deviation_um"].as_array().unwrap();
        assert!(dev[0].as_f64().unwrap().abs() < 2000.0, "{dev:?}");
    }
    s.shutdown().await;
}

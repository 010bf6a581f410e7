//! The service runs the same procedures as the command line: requests checked once when
//! queued (400 naming the field, also for the frames a scan would take on this machine),
//! a stopped scan resumed by the next scan of the same plan, another machine's map
//! refused naming what differs. In-process on port 0; every wait is on an event.

use reqwest::StatusCode;
use serde_json::json;

use system_tests::service_client::Api;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_requests_are_refused_when_queued_naming_the_field() {
    let mut api = Api::start().await;
    let (status, body) = api.queue("map", json!({"grid_step_mm": 1e-300})).await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");
    assert_eq!(body["error"], "invalid_params");
    assert_eq!(body["field"], "params.grid_step_mm", "{body}");

    // Steps that pass on their own, but whose frames over this machine's travel are
    // past the bound, once the machine's travel is known.
    api.machine_idle().await;
    let (status, body) = api.queue("map", json!({"grid_step_mm": 0.25})).await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");
    assert_eq!(body["field"], "params.grid_step_mm", "{body}");
    assert!(
        body["message"].as_str().unwrap().contains("frames"),
        "{body}"
    );

    // A malformed forced assignment is reported, not dropped.
    let layout = json!({"units": "mm", "width_mm": 40, "parts": [
        {"id": "a", "contours": [[[0, 5], [10, 5], [10, 15], [0, 15]]]}]})
    .to_string();
    let (status, body) = api
        .queue(
            "layout",
            json!({"layout": layout, "format": "json", "tools": 2, "window_mm": 25,
                   "gap_mm": 2, "assign": ["a=1", "a-without-group"]}),
        )
        .await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");
    assert_eq!(body["field"], "params.assign[1]", "{body}");

    // ISO 230-2 measurements past the bound.
    let (status, body) = api
        .queue(
            "iso230",
            json!({"axis": "X", "positions": 10000, "runs": 1000}),
        )
        .await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");
    assert_eq!(body["field"], "params.positions", "{body}");
    let (_, jobs) = ((), api.get("/api/v1/jobs").await.as_array().unwrap().len());
    assert_eq!(jobs, 0, "nothing was queued");
    api.s.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stopped_scan_is_resumed_by_the_next_scan_of_the_same_plan() {
    let mut api = Api::start().await;
    let params = json!({"name": "scan", "grid_step_mm": 50.0, "line_step_mm": 25.0, "passes": 1});
    let (status, first) = api.queue("map", params.clone()).await;
    assert_eq!(status, StatusCode::ACCEPTED, "{first}");
    let first_id = first["id"].clone();
    // Stop it once it has measured a few frames.
    api.until(|e| e["type"] == "progress" && e["job_id"] == first_id && e["done"] == 5)
        .await;
    let (status, cancelled) = api
        .post(&format!("/api/v1/jobs/{first_id}/cancel"), json!({}))
        .await;
    assert_eq!(status, StatusCode::OK, "{cancelled}");
    assert_eq!(cancelled["state"], "cancelled", "{cancelled}");
    let kept = api
        .get(&format!("/api/v1/jobs/{first_id}/measurements"))
        .await;
    let kept = kept.as_array().unwrap().len();
    assert!(kept >= 5, "{kept} frames kept");

    let (status, second) = api.queue("map", params.clone()).await;
    assert_eq!(status, StatusCode::ACCEPTED, "{second}");
    let record = api.finished(&second["id"]).await;
    assert_eq!(record["state"], "succeeded", "{record}");
    let r = &record["result"];
    assert_eq!(r["resumed_frames"], kept, "{r}");
    assert_eq!(r["resumed_from_job"], first_id, "{r}");
    let all = api
        .get(&format!("/api/v1/jobs/{}/measurements", second["id"]))
        .await;
    assert_eq!(json!(all.as_array().unwrap().len()), r["frames"], "{r}");

    // A scan asked differently starts anew.
    let mut other = params.clone();
    other["passes"] = json!(2);
    let (_, third) = api.queue("map", other).await;
    let third_id = third["id"].clone();
    // Its first progress says where it starts.
    let first = api
        .until(|e| e["type"] == "progress" && e["job_id"] == third_id)
        .await;
    assert_eq!(first["done"], 0, "{first}");
    let (status, r) = api
        .post(&format!("/api/v1/jobs/{third_id}/cancel"), json!({}))
        .await;
    assert_eq!(status, StatusCode::OK, "{r}");
    assert_eq!(r["result"]["resumed_frames"], 0, "{r}");
    api.s.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_map_of_another_machine_is_refused_naming_what_differs() {
    let mut api = Api::start().await;
    let (_, first) = api
        .queue(
            "map",
            json!({"name": "scan", "grid_step_mm": 50.0, "line_step_mm": 25.0, "passes": 1}),
        )
        .await;
    let record = api.finished(&first["id"]).await;
    assert_eq!(record["state"], "succeeded", "{record}");
    let mut body = api
        .get("/api/v1/machines/demo/profiles/scan/1")
        .await
        .get("body")
        .cloned()
        .expect("the profile's body");
    body["identity"]["machine"] = json!("another machine");
    let (status, p) = api
        .post(
            "/api/v1/machines/demo/profiles/foreign",
            json!({"kind": "error_map", "body": body}),
        )
        .await;
    assert_eq!(status, StatusCode::CREATED, "{p}");
    let (status, a) = api
        .post(
            "/api/v1/machines/demo/profiles/foreign/1/activate",
            json!({}),
        )
        .await;
    assert_eq!(status, StatusCode::OK, "{a}");
    for (kind, params) in [
        ("verify", json!({"points": 2})),
        ("iso230", json!({"axis": "X", "with_map": true})),
    ] {
        let (_, job) = api.queue(kind, params).await;
        let record = api.finished(&job["id"]).await;
        assert_eq!(record["state"], "failed", "{record}");
        let error = record["error"].as_str().unwrap();
        assert!(
            error.contains("machine `another machine`") && error.contains("refused"),
            "{kind}: {error}"
        );
        let kept = api
            .get(&format!("/api/v1/jobs/{}/measurements", job["id"]))
            .await;
        assert!(kept.as_array().unwrap().is_empty(), "nothing moved");
    }
    api.s.shutdown().await;
}

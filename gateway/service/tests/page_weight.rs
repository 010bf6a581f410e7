//! What the page downloads and uploads, through the real service (demo machine, port
//! 0): a job list stays light with a 15 MB layout job in the history (its file and
//! result are fetched per job), a layout the job's reader would refuse is refused when
//! it is queued with that reader's message, the page's files carry an ETag, are
//! revalidated with 304 and sent gzip-compressed, and the store's file is its owner's
//! only. The list's size is printed (docs/service.md quotes it).

use serde_json::{json, Value};

async fn demo() -> (service::Running, tempfile::TempDir, String, reqwest::Client) {
    let dir = tempfile::tempdir().unwrap();
    let running = service::start(service::BoxConfig::demo(dir.path()))
        .await
        .expect("the demo service starts");
    let base = format!("http://{}", running.local_addr());
    (running, dir, base, reqwest::Client::new())
}

/// A three-part layout padded with whitespace to `bytes` (valid JSON: the reader reads
/// it whole).
fn layout_of(bytes: usize) -> String {
    let mut text = json!({"units": "mm", "width_mm": 40, "parts": [
        {"id": "a", "contours": [[[0, 5], [10, 5], [10, 15], [0, 15]]]},
        {"id": "b", "contours": [[[12, 5], [22, 5], [22, 15], [12, 15]]]},
        {"id": "c", "contours": [[[24, 5], [34, 5], [34, 15], [24, 15]]]},
    ]})
    .to_string();
    text.push_str(&" ".repeat(bytes.saturating_sub(text.len())));
    text
}

async fn queue_layout(
    client: &reqwest::Client,
    base: &str,
    token: &str,
    layout: &str,
    format: &str,
) -> reqwest::Response {
    client
        .post(format!("{base}/api/v1/machines/demo/jobs"))
        .bearer_auth(token)
        .json(
            &json!({"kind": "layout", "params": {"layout": layout, "format": format,
            "tools": 2, "window_mm": 25, "gap_mm": 2}}),
        )
        .send()
        .await
        .unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_15_mb_layout_job_leaves_the_job_list_light() {
    let (running, _dir, base, client) = demo().await;
    let token = running.token().to_string();
    let layout = layout_of(15 << 20);
    let queued = queue_layout(&client, &base, &token, &layout, "json").await;
    assert_eq!(queued.status(), 202, "{}", queued.text().await.unwrap());
    let id = queued.json::<Value>().await.unwrap()["id"]
        .as_i64()
        .unwrap();
    // Small jobs after it, as a history has.
    for _ in 0..5 {
        let r = client
            .post(format!("{base}/api/v1/machines/demo/jobs"))
            .bearer_auth(&token)
            .json(&json!({"kind": "compensate", "params": {"targets": 1}}))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 202);
    }
    let list = client
        .get(format!("{base}/api/v1/jobs?limit=50"))
        .bearer_auth(&token)
        .send()
        .await
        .unwrap()
        .bytes()
        .await
        .unwrap();
    let jobs: Value = serde_json::from_slice(&list).unwrap();
    let jobs = jobs.as_array().unwrap();
    assert_eq!(jobs.len(), 6);
    for job in jobs {
        assert!(
            job.get("params").is_none() && job.get("result").is_none(),
            "{job}"
        );
        assert!(job["state"].is_string() && job["kind"].is_string(), "{job}");
    }
    println!(
        "GET /api/v1/jobs?limit=50 with a {} byte layout job and 5 others: {} bytes",
        layout.len(),
        list.len()
    );
    assert!(list.len() < 8 * 1024, "{} bytes", list.len());
    // The job itself still has its file.
    let one: Value = client
        .get(format!("{base}/api/v1/jobs/{id}"))
        .bearer_auth(&token)
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert_eq!(
        one["params"]["layout"].as_str().unwrap().len(),
        layout.len()
    );
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_file_the_layout_reader_refuses_is_refused_when_queued() {
    let (running, _dir, base, client) = demo().await;
    let token = running.token().to_string();
    // A PNG as the page would have sent it (its bytes read as text), a JSON that is not a
    // layout, a DXF cut short.
    let png = String::from_utf8_lossy(b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR\0\0\x01\0").into_owned();
    let dxf = "0\nSECTION\n2\nENTITIES\n0\nLINE\n10\nnot-a-number\n";
    for (layout, format) in [
        (png.as_str(), "json"),
        (r#"{"hello": 1}"#, "json"),
        (dxf, "dxf"),
    ] {
        let answer = queue_layout(&client, &base, &token, layout, format).await;
        assert_eq!(answer.status(), 400, "{format}: {layout:?}");
        let body: Value = answer.json().await.unwrap();
        assert_eq!(body["error"], "invalid_params", "{body}");
        assert_eq!(body["field"], "params.layout", "{body}");
        let message = body["message"].as_str().unwrap();
        let prefix = format!(
            "params.layout: the file is not a layout the job can read as {}: ",
            format.to_uppercase()
        );
        assert!(message.starts_with(&prefix), "{message}");
        assert!(
            message.len() > prefix.len(),
            "the reader's words follow: {message}"
        );
    }
    let jobs: Value = client
        .get(format!("{base}/api/v1/jobs"))
        .bearer_auth(&token)
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert_eq!(jobs, json!([]), "nothing was queued");
    // A readable one is queued.
    let ok = queue_layout(&client, &base, &token, &layout_of(0), "json").await;
    assert_eq!(ok.status(), 202);
    running.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_files_are_cached_compressed_and_the_store_is_private() {
    let (running, dir, base, client) = demo().await;
    let first = client
        .get(format!("{base}/app.js"))
        .header("accept-encoding", "gzip")
        .send()
        .await
        .unwrap();
    assert_eq!(first.status(), 200);
    assert_eq!(first.headers()["content-encoding"], "gzip");
    assert_eq!(first.headers()["cache-control"], "no-cache");
    // The security headers are on the page's files too.
    assert_eq!(first.headers()["x-content-type-options"], "nosniff");
    let etag = first.headers()["etag"].clone();
    let zipped = first.bytes().await.unwrap().len();
    println!(
        "app.js: {} bytes, {} gzip-compressed",
        webpage::APP_JS.len(),
        zipped
    );
    let again = client
        .get(format!("{base}/app.js"))
        .header("if-none-match", etag)
        .send()
        .await
        .unwrap();
    assert_eq!(again.status(), 304);
    assert!(again.bytes().await.unwrap().is_empty());

    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(dir.path().join("gateway.sqlite"))
            .unwrap()
            .permissions()
            .mode();
        assert_eq!(mode & 0o777, 0o600, "{mode:o}");
    }
    #[cfg(not(unix))]
    let _ = dir;
    running.shutdown().await;
}

//! One procedure per capability: the same request through the command line (`--json`)
//! and through the service's API gives the same outcome object, modulo ids and times.
//! Each side starts from a fresh simulated machine (a new process, a new service), so
//! the seeded machine behaves the same on both. No wall-time sleeps: the API side waits
//! on the job's events.

use reqwest::StatusCode;
use serde_json::{json, Value};
use std::path::PathBuf;
use system_tests::service_client::Api;

mod common;

use common::{gateway, job_file, workspace};

/// Keys whose values are times or where a product was delivered (the CLI writes files,
/// the service keeps charts and the shifted layout in the record): they differ.
const VOLATILE: &[&str] = &["wall_time_s", "partition_ms", "kept_as", "charts", "layout"];

fn stripped(mut v: Value) -> Value {
    fn walk(v: &mut Value) {
        match v {
            Value::Object(o) => {
                for k in VOLATILE {
                    o.remove(*k);
                }
                o.values_mut().for_each(walk);
            }
            Value::Array(a) => a.iter_mut().for_each(walk),
            _ => {}
        }
    }
    walk(&mut v);
    v
}

fn demo_job() -> String {
    job_file("demo.toml")
}

fn scratch(name: &str) -> PathBuf {
    common::scratch("procedures", name)
}

/// The CLI's `--json` object (the command must succeed).
fn cli(args: &[&str]) -> Value {
    let o = gateway(args);
    assert!(
        o.status.success(),
        "gateway {args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    serde_json::from_slice(&o.stdout).expect("one JSON object")
}

async fn api_result(kind: &str, params: Value) -> Value {
    let mut api = Api::start().await;
    let job = api.run(kind, params).await;
    assert_eq!(job["state"], "succeeded", "{job}");
    job["result"].clone()
}

fn assert_same(cli: Value, api: Value) {
    let (c, a) = (stripped(cli), stripped(api));
    assert!(c == a, "the CLI and the API differ:\nCLI {c:#}\nAPI {a:#}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn compensate_through_the_cli_and_the_api_gives_one_outcome() {
    let from_cli = cli(&["demo", "--json", "--targets", "2"]);
    let from_api = api_result("compensate", json!({"targets": 2})).await;
    assert_eq!(from_cli["targets"], 2);
    assert_same(from_cli, from_api);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn map_verify_and_iso230_through_the_cli_and_the_api_give_one_outcome() {
    let dir = scratch("map");
    let out = dir.display().to_string();
    let job = demo_job();
    let scan = [
        "--grid-step-mm",
        "50",
        "--line-step-mm",
        "25",
        "--passes",
        "1",
    ];
    let mut args = vec![
        "map", "--config", &job, "--out", &out, "--name", "scan", "--json",
    ];
    args.extend(scan);
    let from_cli = cli(&args);
    let from_api = api_result(
        "map",
        json!({"name": "scan", "grid_step_mm": 50.0, "line_step_mm": 25.0, "passes": 1}),
    )
    .await;
    assert_eq!(from_cli["version"], 1);
    assert_same(from_cli.clone(), from_api);

    // Verify with that map: on the CLI from its file, on a fresh service as the
    // machine's active profile.
    let map_file = from_cli["kept_as"].as_str().unwrap().to_string();
    let body: Value = serde_json::from_str(&std::fs::read_to_string(&map_file).unwrap()).unwrap();
    let from_cli = cli(&[
        "verify", "--config", &job, "--map", &map_file, "--points", "3", "--json",
    ]);
    let mut api = Api::start().await;
    let (status, p) = api
        .post(
            "/api/v1/machines/demo/profiles/error_map",
            json!({"kind": "error_map", "body": body}),
        )
        .await;
    assert_eq!(status, StatusCode::CREATED, "{p}");
    let (status, a) = api
        .post(
            "/api/v1/machines/demo/profiles/error_map/1/activate",
            json!({}),
        )
        .await;
    assert_eq!(status, StatusCode::OK, "{a}");
    let job_record = api.run("verify", json!({"points": 3})).await;
    assert_eq!(job_record["state"], "succeeded", "{job_record}");
    assert_eq!(from_cli["points"].as_array().unwrap().len(), 3);
    assert_same(from_cli, job_record["result"].clone());

    // The reference after homing, three times, then a spot check: the same rules on both
    // sides (each record continues the previous one, the spot check applies the
    // recorded reference instead of homing). The machines are not the same run (one
    // process per command on the CLI, one service), so the rules are compared, not the
    // micrometres.
    let reference = |from: &Value| {
        assert_eq!(from["reference_count"], 3, "{from}");
        assert!(from["drift_since_previous_um"].is_array(), "{from}");
        assert!(from["written_to"].is_string(), "{from}");
    };
    let spot = |from: &Value| {
        assert_eq!(from["spot_check"], true, "{from}");
        assert_eq!(from["recorded_reference"]["reference_count"], 3, "{from}");
        assert!(from["drift_since_reference_um"].is_array(), "{from}");
        assert!(from.get("warning").is_none(), "{from}");
    };
    let keys = |v: &Value| {
        let mut k: Vec<String> = v.as_object().unwrap().keys().cloned().collect();
        k.sort();
        k
    };
    let _ = std::fs::remove_file(map_file.replace(".json", ".reference.json"));
    for _ in 0..2 {
        cli(&["reference", "--config", &job, "--map", &map_file, "--json"]);
    }
    // The CLI's context in this process (the binary's simulated machine lives only as
    // long as its process: a spot check needs the machine the reference was taken on).
    let (cli_reference, cli_spot) = {
        let mut sink = procedure::Discard;
        let (_raise, stop) = procedure::Stop::new();
        let mut files = procedure::files::Files::new(&mut sink, stop)
            .job_file(std::path::Path::new(&job))
            .map_file(std::path::Path::new(&map_file));
        let run = |kind: &str| procedure::kinds::kind(kind).unwrap();
        let r = run("reference").run(json!({}), &mut files).await;
        assert!(r.is_success(), "{:?}", r.error());
        let params = json!({"spot_check": true, "points": 2});
        let v = run("verify").run(params, &mut files).await;
        assert!(v.is_success(), "{:?}", v.error());
        (r.result.unwrap(), v.result.unwrap())
    };
    let mut api_reference = Value::Null;
    for _ in 0..3 {
        let r = api.run("reference", json!({})).await;
        assert_eq!(r["state"], "succeeded", "{r}");
        api_reference = r["result"].clone();
    }
    let api_spot = api
        .run("verify", json!({"spot_check": true, "points": 2}))
        .await;
    assert_eq!(api_spot["state"], "succeeded", "{api_spot}");
    let api_spot = api_spot["result"].clone();
    for (c, a) in [(&cli_reference, &api_reference), (&cli_spot, &api_spot)] {
        assert_eq!(
            keys(c),
            keys(a),
            "the same result's fields:\nCLI {c:#}\nAPI {a:#}"
        );
    }
    for r in [&cli_reference, &api_reference] {
        reference(r);
    }
    for r in [&cli_spot, &api_spot] {
        spot(r);
    }

    // ISO 230-2 without a map.
    let iso = scratch("iso230");
    let iso_out = iso.display().to_string();
    let from_cli = cli(&[
        "iso230",
        "--config",
        &job,
        "--axis",
        "x",
        "--positions",
        "5",
        "--runs",
        "5",
        "--out",
        &iso_out,
        "--json",
    ]);
    let from_api = api_result("iso230", json!({"axis": "X", "positions": 5, "runs": 5})).await;
    assert!(iso.join("report.html").is_file());
    assert!(iso.join("deviation_x.svg").is_file());
    assert_same(from_cli, from_api);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn layout_through_the_cli_and_the_api_gives_one_outcome() {
    let dir = scratch("layout");
    let input = workspace().join("gateway/layout/data/esicup/shirts.json");
    let out = dir.join("shifted.json");
    let from_cli = cli(&[
        "layout",
        "partition",
        input.to_str().unwrap(),
        "--tools",
        "2",
        "--window-mm",
        "20",
        "--gap-mm",
        "2",
        "--widen",
        // The 40 mm strip's parts end 4 mm wider after the shifts.
        "--material-width-mm",
        "50",
        "--out",
        out.to_str().unwrap(),
        "--json",
    ]);
    let text = std::fs::read_to_string(&input).unwrap();
    let from_api = api_result(
        "layout",
        json!({"layout": text, "format": "json", "tools": 2, "window_mm": 20.0, "gap_mm": 2.0, "widen": true, "material_width_mm": 50.0}),
    )
    .await;
    assert!(out.is_file());
    assert!(from_cli["groups"].as_array().unwrap().len() > 2);
    assert_same(from_cli, from_api);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rotary_measure_through_the_cli_and_the_api_gives_one_outcome() {
    let dir = scratch("rotary");
    // The service's demo machine measures the built-in table: every default.
    let config = dir.join("table.json");
    std::fs::write(&config, "{}").unwrap();
    let from_cli = cli(&[
        "rotary",
        "measure",
        "--config",
        config.to_str().unwrap(),
        "--out",
        dir.to_str().unwrap(),
        "--json",
    ]);
    let from_api = api_result("rotary", json!({})).await;
    assert!(dir.join("errors.json").is_file());
    assert!(from_cli["cycle"]["balls"].as_u64().unwrap() > 10);
    assert_same(from_cli, from_api);
}

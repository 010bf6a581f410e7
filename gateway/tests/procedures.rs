//! One procedure per capability: the same request through the command line (`--json`)
//! and through the service's API gives the same outcome object, modulo ids and times.
//! Each side starts from a fresh simulated machine (a new process, a new service), so
//! the seeded machine behaves the same on both. No wall-time sleeps: the API side waits
//! on the job's events.

use reqwest::StatusCode;
use serde_json::{json, Value};
use std::path::PathBuf;
use system_tests::service_client::Api;

use crate::common;

use common::{gateway, job_file, workspace};

/// Keys whose values are times or where a product was delivered (the CLI writes files,
/// the service keeps charts and the shifted layout in the record): they differ.
const VOLATILE: &[&str] = &[
    "wall_time_s",
    "rewrite_ms",
    "first_piece_out_ms",
    "starvation_events",
    "partition_ms",
    "elapsed_ms",
    "elapsed_s",
    "output",
    "kept_as",
    "file",
    "charts",
    "layout",
];

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

/// Every kind the tests below run through both front ends.
const COMPARED: &[&str] = &[
    "compensate",
    "map",
    "reference",
    "verify",
    "iso230",
    "iso230-evaluate",
    "export",
    "rewrite",
    "layout",
    "rotary",
    "rotary-identify",
    "rotary-rewrite",
    "cut",
    "volumetric-identify",
    "volumetric-eval",
    "volumetric-contributions",
    "volumetric-campaign",
    "volumetric-export-isg",
    "board-make",
    "localize",
    "dnc",
    "proxy",
];

/// A registered kind is compared here, or this fails naming it: a new capability
/// cannot join the registry without its front ends checked alike.
#[test]
fn every_registered_kind_is_compared() {
    for kind in procedure::KINDS {
        assert!(
            COMPARED.contains(&kind.name),
            "kind {} is not compared",
            kind.name
        );
        // Its request is really run below (not only listed).
        let source = include_str!("procedures.rs");
        assert!(
            source.matches(&format!("\"{}\"", kind.name)).count() >= 2,
            "{}",
            kind.name
        );
    }
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
async fn map_verify_export_rewrite_and_reference_through_the_cli_and_the_api_give_one_outcome() {
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

    // The same map as the controller's own tables, and a program rewritten with it.
    let _ = std::fs::remove_file(map_file.replace(".json", ".reference.json"));
    let tables = dir.join("tables");
    let from_cli = cli(&[
        "export",
        "--map",
        &map_file,
        "--format",
        "csv",
        "--out",
        &tables.display().to_string(),
        "--json",
    ]);
    let job_record = api.run("export", json!({"format": "csv"})).await;
    assert_eq!(job_record["state"], "succeeded", "{job_record}");
    assert_same(from_cli, job_record["result"].clone());
    let program = dir.join("part.nc");
    let text = "G21 G90\nG0 X60 Y60\nG1 X90 Y75 F600\nG0 X60 Y60\n";
    std::fs::write(&program, text).unwrap();
    let from_cli = cli(&[
        "rewrite",
        &program.display().to_string(),
        "--map",
        &map_file,
        "--out",
        &dir.join("part.rewritten.nc").display().to_string(),
        "--json",
    ]);
    let job_record = api
        .run(
            "rewrite",
            json!({"program": text, "program_name": program.display().to_string()}),
        )
        .await;
    assert_eq!(job_record["state"], "succeeded", "{job_record}");
    assert_same(from_cli, job_record["result"].clone());
    // A Fanuc tape rewritten with it for a closed controller, kept rather than sent.
    let tape = dir.join("O1000.nc");
    let text = "%\nO1000\nG21 G90\nG0 X60. Y60.\nG1 X90. Y75. F600.\nM30\n%\n";
    std::fs::write(&tape, text).unwrap();
    let from_cli = cli(&[
        "dnc",
        &tape.display().to_string(),
        "--map",
        &map_file,
        "--no-send",
        "--out",
        &dir.join("O1000.rewritten.nc").display().to_string(),
        "--json",
    ]);
    let params = json!({"program": text, "program_name": tape.display().to_string(),
        "send": false});
    let job_record = api.run("dnc", params).await;
    assert_eq!(job_record["state"], "succeeded", "{job_record}");
    assert_eq!(from_cli["blocks_in"], 5, "{from_cli}");
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
        assert_eq!(from["homed"], false, "{from}");
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
    cli(&["reference", "--config", &job, "--map", &map_file, "--json"]);
    // The CLI's context in this process (the binary's simulated machine lives only as
    // long as its process: a spot check needs the machine the reference was taken on).
    let (cli_reference, cli_spot) = {
        let mut sink = procedure::Discard;
        let (_raise, stop) = procedure::Stop::new();
        let mut files = procedure::files::Files::new(&mut sink, stop)
            .job_file(std::path::Path::new(&job))
            .map_file(std::path::Path::new(&map_file));
        let run = |kind: &str| procedure::kinds::kind(kind).unwrap();
        // The second after a homing, the third in use, without homing. A reference in use
        // on a machine that has not homed is refused (the stage says so).
        let no_home = json!({"no_home": true});
        let r = run("reference").run(no_home.clone(), &mut files).await;
        assert!(r.error().is_some_and(|e| e.contains("not homed")), "{r:?}");
        let r = run("reference").run(json!({}), &mut files).await;
        assert!(r.is_success(), "{:?}", r.error());
        let r = run("reference").run(no_home, &mut files).await;
        assert!(r.is_success(), "{:?}", r.error());
        let params = json!({"spot_check": true, "points": 2});
        let v = run("verify").run(params, &mut files).await;
        assert!(v.is_success(), "{:?}", v.error());
        (r.result.unwrap(), v.result.unwrap())
    };
    let mut api_reference = Value::Null;
    for no_home in [false, false, true] {
        let r = api.run("reference", json!({"no_home": no_home})).await;
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
}

/// ISO 230-2 without a map: a test of its own (it needs nothing of the map's), so the
/// harness runs it beside the map's chain instead of after it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn iso230_through_the_cli_and_the_api_gives_one_outcome() {
    let job = demo_job();
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

/// The CLI's `--json` result and the service's for one request of a files-in kind.
async fn both(api: &mut Api, args: &[&str], kind: &str, params: Value) -> (Value, Value) {
    let from_cli = cli(args);
    let job = api.run(kind, params).await;
    assert_eq!(job["state"], "succeeded", "{kind}: {job}");
    (from_cli, job["result"].clone())
}

fn text(path: &std::path::Path) -> String {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The kinds that take files and give files (no machine moves): each through both front
/// ends, the CLI reading the files, the API given their text (the page's uploads).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn files_in_files_out_kinds_through_the_cli_and_the_api_give_one_outcome() {
    let dir = scratch("files");
    let corpus = workspace().join("tests/fuzz/corpus");
    let path = |p: &std::path::Path| p.display().to_string();
    let mut api = Api::start().await;

    // ISO 230-2 of a measurements file.
    let file = corpus.join("iso230_csv/five_positions.csv");
    let (c, a) = both(
        &mut api,
        &["iso230", "evaluate", &path(&file), "--json"],
        "iso230-evaluate",
        json!({"measurements": text(&file), "measurements_name": path(&file)}),
    )
    .await;
    assert_same(c, a);

    // The rotary table's errors from measured centres, and a program rewritten with them.
    let centres = corpus.join("rotary_centres/paper.csv");
    let (c, a) = both(
        &mut api,
        &["rotary", "identify", "--centres", &path(&centres), "--json"],
        "rotary-identify",
        json!({"centres": text(&centres), "centres_name": path(&centres)}),
    )
    .await;
    assert_same(c, a);
    let (program, errors) = (
        corpus.join("rotary_rewrite/program.nc"),
        corpus.join("rotary_errors/measured.json"),
    );
    let out = dir.join("five-axis.nc");
    let (c, a) = both(
        &mut api,
        &[
            "rotary",
            "rewrite",
            &path(&program),
            "--errors",
            &path(&errors),
            "--out",
            &path(&out),
            "--json",
        ],
        "rotary-rewrite",
        json!({"program": text(&program), "program_name": path(&program),
               "errors": text(&errors), "errors_name": path(&errors)}),
    )
    .await;
    assert_same(c, a);

    // The volumetric model: a simulated campaign, identified, evaluated, its
    // contributions and its ISG tables.
    let campaign = dir.join("campaign");
    let (c, a) = both(
        &mut api,
        &[
            "volumetric",
            "simulate-campaign",
            "--out",
            &path(&campaign),
            "--seed",
            "4",
            "--json",
        ],
        "volumetric-campaign",
        json!({"seed": 4}),
    )
    .await;
    assert_same(c, a);
    let model = dir.join("model.vol.csv");
    let mut params = json!({"structure": "XYFZ", "campaign_name": path(&campaign)});
    for name in procedure::volumetric::CAMPAIGN_FILES {
        let file = campaign.join(name);
        if file.exists() {
            let field = name.trim_end_matches(".csv").to_ascii_lowercase();
            params[field] = json!(text(&file));
        }
    }
    let (c, a) = both(
        &mut api,
        &[
            "volumetric",
            "identify",
            "--campaign",
            &path(&campaign),
            "--structure",
            "XYFZ",
            "--out",
            &path(&model),
            "--json",
        ],
        "volumetric-identify",
        params,
    )
    .await;
    assert_eq!(c["errors"].as_array().unwrap().len(), 21);
    assert_same(c, a);
    let points = dir.join("points.csv");
    std::fs::write(&points, "x_mm,y_mm,z_mm\n10,20,30\n100,150,200\n").unwrap();
    let model_text = text(&model);
    let (c, a) = both(
        &mut api,
        &[
            "volumetric",
            "eval",
            "--model",
            &path(&model),
            "--points",
            &path(&points),
            "--json",
        ],
        "volumetric-eval",
        json!({"model": model_text, "model_name": path(&model),
               "points": text(&points), "points_name": path(&points)}),
    )
    .await;
    assert_eq!(c["points"].as_array().unwrap().len(), 2);
    assert_same(c, a);
    let (c, a) = both(
        &mut api,
        &[
            "volumetric",
            "contributions",
            "--model",
            &path(&model),
            "--grid",
            "5",
            "--out",
            &path(&dir.join("contributions")),
            "--json",
        ],
        "volumetric-contributions",
        json!({"model": model_text, "model_name": path(&model), "grid": 5}),
    )
    .await;
    assert_same(c, a);
    let (c, a) = both(
        &mut api,
        &[
            "volumetric",
            "export-isg",
            "--model",
            &path(&model),
            "--out",
            &path(&dir.join("isg")),
            "--json",
        ],
        "volumetric-export-isg",
        json!({"model": model_text, "model_name": path(&model)}),
    )
    .await;
    assert_same(c, a);

    // The machine's board: its artwork (named after the file on the CLI, after the
    // board's name in the service), and one frame of it localized.
    let board = workspace().join("config/boards/dot-grid-0.5mm.toml");
    let (mut c, mut a) = both(
        &mut api,
        &[
            "board",
            "make",
            &path(&board),
            "-o",
            &path(&dir.join("board")),
            "--json",
        ],
        "board-make",
        json!({}),
    )
    .await;
    let names = |r: &mut Value| r.as_object_mut().unwrap().remove("files").unwrap();
    let (cli_files, api_files) = (names(&mut c), names(&mut a));
    assert_eq!(cli_files[0], "dot-grid-0.5mm.svg");
    assert_eq!(api_files[0], "dot-grid-0-5-mm-421-x-321-certified.svg");
    assert_same(c, a);
    let frame = dir.join("frame.png");
    render_frame(&board, [60.25, 40.5], &frame);
    let image = base64_of(&std::fs::read(&frame).unwrap());
    let (c, a) = both(
        &mut api,
        &[
            "localize",
            &path(&frame),
            "--board",
            &path(&board),
            "--near",
            "60.22,40.48",
            "--json",
        ],
        "localize",
        json!({"image": image, "image_name": path(&frame), "near": [60.22, 40.48]}),
    )
    .await;
    assert!((c["x_mm"].as_f64().unwrap() - 60.25).abs() < 0.01, "{c}");
    assert_same(c, a);

    // A layout cut on the emulated cutter (the service cuts nowhere else).
    let layout = dir.join("three.json");
    let three = json!({"units": "mm", "width_mm": 40, "parts": [
        {"id": "a", "contours": [[[0, 5], [10, 5], [10, 15], [0, 15]]]},
        {"id": "b", "contours": [[[12, 5], [22, 5], [22, 15], [12, 15]]]},
        {"id": "c", "contours": [[[24, 5], [34, 5], [34, 15], [24, 15]]]}]});
    std::fs::write(&layout, three.to_string()).unwrap();
    let (c, a) = both(
        &mut api,
        &[
            "layout",
            "cut",
            &path(&layout),
            "--tools",
            "2",
            "--window-mm",
            "25",
            "--gap-mm",
            "1.5",
            "--json",
        ],
        "cut",
        json!({"partition": {"layout": three.to_string(), "format": "json", "tools": 2,
               "window_mm": 25.0, "gap_mm": 1.5}}),
    )
    .await;
    assert_eq!(c["strokes"], 12, "{c}");
    assert_same(c, a);
    let (status, refused) = api
        .queue(
            "cut",
            json!({"partition": {"layout": three.to_string(), "format": "json", "tools": 2,
                   "window_mm": 25.0, "gap_mm": 1.5}, "conveyor": "/dev/ttyS0",
                   "heads": ["/dev/ttyS1", "/dev/ttyS2"]}),
        )
        .await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{refused}");
    assert_eq!(refused["field"], "params.conveyor", "{refused}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A frame of `board` centred on `centre_mm`, as the demo's camera takes it.
fn render_frame(board: &std::path::Path, centre_mm: [f64; 2], png: &std::path::Path) {
    let board = protocol::Board::load(board).unwrap();
    let doc =
        protocol::config::ConfigDoc::read(&workspace().join("config/cameras/mono-1.3mp.toml"))
            .unwrap();
    let camera = world::camera::CameraModel::from_doc(&doc).unwrap();
    let pose = world::camera::CameraPose {
        centre_mm,
        rotation_rad: 0.0,
    };
    let f = world::render::render(&board, &camera, &pose, 3);
    vision::image_io::save_png(&f.image, png).unwrap();
}

fn base64_of(bytes: &[u8]) -> String {
    use base64::Engine;
    base64::engine::general_purpose::STANDARD.encode(bytes)
}

/// The pass-through on the GRBL demo job (its controller emulated on a pseudo-terminal)
/// with a map of that machine: `gateway proxy --once` and a `proxy` job on a service whose
/// machine is that job account for one sender session alike.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn proxy_through_the_cli_and_the_api_gives_one_outcome() {
    use std::io::{BufRead, BufReader};
    let dir = scratch("proxy");
    let (job_path, map) = system_tests::truth_map::grbl_demo_map().await;
    let map_path = dir.join("m.v1.json");
    map.save_new(&map_path).unwrap();

    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_gateway"))
        .args(["proxy", "--once", "--no-reference", "--json", "--config"])
        .arg(&job_path)
        .arg("--map")
        .arg(&map_path)
        .stdout(std::process::Stdio::piped())
        .spawn()
        .expect("gateway runs");
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let hello: Value = serde_json::from_str(&lines.next().unwrap().unwrap()).unwrap();
    system_tests::sender::unlock_and_move(hello["sender_port"].as_str().unwrap()).await;
    let last = lines
        .map(Result::unwrap)
        .last()
        .expect("the session's account");
    assert!(child.wait().unwrap().success());
    let from_cli: Value = serde_json::from_str(&last).unwrap();

    let mut api = Api::start_with(|d| {
        let mut config = service::BoxConfig::demo(d);
        config.machines[0].job = service::config::JobSource::File(job_path.clone());
        config
    })
    .await;
    let body: Value = serde_json::from_str(&std::fs::read_to_string(&map_path).unwrap()).unwrap();
    let (status, p) = api
        .post(
            "/api/v1/machines/demo/profiles/error_map",
            json!({"kind": "error_map", "body": body}),
        )
        .await;
    assert_eq!(status, StatusCode::CREATED, "{p}");
    let activate = "/api/v1/machines/demo/profiles/error_map/1/activate";
    assert_eq!(api.post(activate, json!({})).await.0, StatusCode::OK);
    let (status, queued) = api
        .queue("proxy", json!({"once": true, "no_reference": true}))
        .await;
    assert_eq!(status, StatusCode::ACCEPTED, "{queued}");
    let ready = api
        .until(|e| e["type"] == "measurement" && e["measurement"]["sender_port"].is_string())
        .await;
    system_tests::sender::unlock_and_move(ready["measurement"]["sender_port"].as_str().unwrap())
        .await;
    let record = api.finished(&queued["id"]).await;
    assert_eq!(record["state"], "succeeded", "{record}");
    assert_eq!(from_cli["lines_received"], 3, "{from_cli}");
    assert_same(from_cli, record["result"].clone());
}

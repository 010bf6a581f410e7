//! The service's web page in a real browser: the service runs in-process (demo machine,
//! port 0, a fresh data directory) and tests/interop/web/drive_page.js drives headless
//! Debian Chromium through playwright-core, over HTTPS (the self-signed pair made at the
//! service's first start, Chromium given its public key's pin): the page opens with the token in the URL
//! fragment, starts a job, sees its live progress over the WebSocket and the finished
//! job in the history, shows its chart and measurements and the error map's heat map,
//! activates a profile version and rolls back. Needs `node`, `/usr/bin/chromium` and
//! playwright-core in tests/interop/web (all installed by tests/install-peers.sh); without them the test
//! fails naming what to install. The screenshot is kept as
//! `$CARGO_TARGET_DIR/tmp/service_web/page.png` (target/tmp/service_web/page.png by default).

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use plot::plotters::coord::Shift;
use plot::plotters::prelude::*;
use system_tests::workspace;

/// The job the page starts on the demo machine (the kind the service runs so far; it
/// draws no chart yet, so the driver is told charts are optional).
const JOB_KIND: &str = "compensate";
const JOB_PARAMS: &str = r#"{"targets": 1}"#;
const CHARTS: &str = "optional";

/// A 3 x 3 heat map drawn with the plot crate, the body's `heatmap_svg` of the two
/// error-map versions put in the store before the service starts (the service's jobs do
/// not make error maps yet).
struct Grid([f64; 9]);

impl plot::Chart for Grid {
    fn draw<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        area.fill(&WHITE)?;
        for (cell, value) in area.split_evenly((3, 3)).iter().zip(self.0) {
            let red = (255.0 * value) as u8;
            cell.fill(&RGBColor(red, 60, 255 - red))?;
        }
        Ok(())
    }
}

fn seed_profiles(data_dir: &Path) {
    let mut store = store::Store::open(&data_dir.join("gateway.sqlite")).expect("the store opens");
    for values in [[0.1, 0.5, 0.9, 0.2, 0.4, 0.6, 0.3, 0.7, 1.0], [0.0; 9]] {
        let svg = plot::render_svg(&Grid(values), 300, 300).expect("the heat map renders");
        store
            .add_profile(
                "demo",
                "demo-map",
                store::ProfileKind::ErrorMap,
                &serde_json::json!({ "heatmap_svg": svg }),
                None,
                Some("seeded by the browser test"),
            )
            .expect("a profile version");
    }
}

/// What is missing to run the browser, as an install instruction.
fn missing_tools(web_dir: &Path) -> Option<String> {
    if Command::new("node").arg("--version").output().is_err() {
        return Some("node is not installed (apt-get install -y nodejs npm)".into());
    }
    if !Path::new("/usr/bin/chromium").exists() {
        return Some("/usr/bin/chromium is not installed (apt-get install -y chromium)".into());
    }
    for package in ["playwright-core", "axe-core"] {
        if !web_dir
            .join("node_modules")
            .join(package)
            .join("package.json")
            .exists()
        {
            return Some(format!(
                "{package} is not installed in {0} (tests/install-peers.sh installs the pinned \
                 versions of its package.json; .ci/run runs it)",
                web_dir.display()
            ));
        }
    }
    None
}

/// Every job kind the demo machine runs, with the quickest params its schema allows, in
/// an order that works: the map becomes the machine's active `error_map`, which verify
/// uses. `chart`: the kind draws one. Each entry is started from the page's form.
fn kind_jobs() -> serde_json::Value {
    let layout = serde_json::json!({"units": "mm", "width_mm": 40, "parts": [
        {"id": "a", "contours": [[[0, 5], [10, 5], [10, 15], [0, 15]]]},
        {"id": "b", "contours": [[[12, 5], [22, 5], [22, 15], [12, 15]]]},
        {"id": "c", "contours": [[[24, 5], [34, 5], [34, 15], [24, 15]]]},
    ]})
    .to_string();
    let model = corpus("volumetric_model/xyfz_identified.vol.csv");
    serde_json::json!([
        {"kind": "compensate", "params": {"targets": 1}, "chart": false},
        {"kind": "iso230", "params": {"axis": "X", "positions": 5, "runs": 5}, "chart": true},
        {"kind": "map", "params": {"name": "error_map", "grid_step_mm": 50, "line_step_mm": 25, "passes": 1},
            "chart": false, "activate": "error_map"},
        {"kind": "verify", "params": {"points": 2, "seed": 3, "drift_threshold_um": "2,5"}, "chart": false},
        {"kind": "layout", "params": {"layout": {"name": "three.json", "text": layout},
            "tools": 2, "window_mm": "25,0", "gap_mm": "1,5", "picture": "svg"}, "chart": true},
        {"kind": "rotary", "params": {}, "chart": true},
        {"kind": "reference", "params": {}, "chart": false},
        {"kind": "export", "params": {"format": "csv"}, "chart": false},
        {"kind": "rewrite", "params": {"program": {"name": "part.nc",
            "text": "G21 G90\nG0 X60 Y60\nG1 X90 Y75 F600\nG0 X60 Y60\n"}}, "chart": false},
        {"kind": "iso230-evaluate", "params": {"measurements": corpus("iso230_csv/five_positions.csv")},
            "chart": true},
        {"kind": "rotary-identify", "params": {"centres": corpus("rotary_centres/paper.csv")},
            "chart": true},
        {"kind": "rotary-rewrite", "params": {"program": corpus("rotary_rewrite/program.nc"),
            "errors": corpus("rotary_errors/measured.json")}, "chart": false},
        {"kind": "cut", "params": {"partition.layout": {"name": "three.json", "text": layout},
            "partition.tools": 2, "partition.window_mm": "25,0", "partition.gap_mm": "1,5"},
            "chart": false},
        {"kind": "volumetric-campaign", "params": {"seed": 2}, "chart": false},
        {"kind": "volumetric-identify", "params": volumetric_campaign(), "chart": false},
        {"kind": "volumetric-eval", "params": {"model": model.clone(),
            "points": {"name": "points.csv", "text": "x_mm,y_mm,z_mm\n10,20,30\n"}}, "chart": false},
        {"kind": "volumetric-contributions", "params": {"model": model.clone(), "grid": 5},
            "chart": false},
        {"kind": "volumetric-export-isg", "params": {"model": model}, "chart": false},
        {"kind": "board-make", "params": {}, "chart": false},
        {"kind": "localize", "params": {"image": demo_frame([60.25, 40.5]), "near": "60.22; 40.48"},
            "chart": false},
        {"kind": "dnc", "params": {"program": {"name": "part.nc",
            "text": "%\nO1\nG90G21\nG00X60.Y60.\nG01X90.Y75.F600.\nM30\n%\n"}, "send": false},
            "chart": false},
        // On the box's GRBL machine: the test's sender runs one session through the port
        // the job opens (the driver asks for it), then the job ends.
        {"kind": "proxy", "machine": GRBL_MACHINE, "params": {"once": true}, "sender": true,
            "chart": false},
    ])
}

/// The box's second machine: the GRBL demo job (its controller emulated on a
/// pseudo-terminal), for the pass-through.
const GRBL_MACHINE: &str = "grbl";

/// Its active error map: the truth of its simulated stage, as a scan would measure it.
async fn seed_grbl_map(data_dir: &Path) {
    let (_, map) = system_tests::truth_map::grbl_demo_map().await;
    let mut store = store::Store::open(&data_dir.join("gateway.sqlite")).expect("the store opens");
    let body = serde_json::to_value(&map).unwrap();
    let v = (store.add_profile(
        GRBL_MACHINE,
        "error_map",
        store::ProfileKind::ErrorMap,
        &body,
        None,
        None,
    ))
    .expect("a profile version");
    store
        .activate(GRBL_MACHINE, "error_map", v.version)
        .expect("activated");
}

/// The emulated machine's campaign as the identify form's uploads (one field per file).
fn volumetric_campaign() -> serde_json::Value {
    let mut files = procedure::Collect::default();
    let request = serde_json::from_value(serde_json::json!({"seed": 2})).unwrap();
    assert!(procedure::volumetric::simulate_campaign(&request, &mut files).is_success());
    let mut params = serde_json::json!({"structure": "XYFZ"});
    for a in files.0 {
        let field = a.name.trim_end_matches(".csv").to_ascii_lowercase();
        params[field] = serde_json::json!({"name": a.name,
            "text": String::from_utf8(a.bytes).unwrap()});
    }
    params
}

/// A frame of the demo machine's board centred on `centre_mm`, as a PNG upload.
fn demo_frame(centre_mm: [f64; 2]) -> serde_json::Value {
    use base64::Engine;
    let ws = workspace();
    let board = protocol::Board::load(&ws.join("config/boards/dot-grid-0.5mm.toml")).unwrap();
    let doc =
        protocol::config::ConfigDoc::read(&ws.join("config/cameras/mono-1.3mp.toml")).unwrap();
    let camera = world::camera::CameraModel::from_doc(&doc).unwrap();
    let pose = world::camera::CameraPose {
        centre_mm,
        rotation_rad: 0.0,
    };
    let frame = world::render::render(&board, &camera, &pose, 3);
    let png = fresh_dir(ws.join("target/tmp/service-web-frame")).join("frame.png");
    vision::image_io::save_png(&frame.image, &png).unwrap();
    let bytes = std::fs::read(&png).unwrap();
    serde_json::json!({"name": "frame.png",
        "base64": base64::engine::general_purpose::STANDARD.encode(bytes)})
}

/// A fuzz corpus file as a file the page uploads (`{name, text}`).
fn corpus(path: &str) -> serde_json::Value {
    let full = workspace().join("tests/fuzz/corpus").join(path);
    let text = std::fs::read_to_string(&full).unwrap_or_else(|e| panic!("{}: {e}", full.display()));
    let name = full.file_name().unwrap().to_string_lossy().into_owned();
    serde_json::json!({ "name": name, "text": text })
}

/// The demo box over HTTPS (`tls = "self-signed"`; its pair in `data_dir/tls`, kept
/// across the restart).
fn https_demo(data_dir: &Path) -> service::BoxConfig {
    let mut config = service::BoxConfig::demo(data_dir);
    config.service.tls = service::TlsSource::SelfSigned;
    config.machines.push(service::MachineConfig {
        id: GRBL_MACHINE.into(),
        description: "The GRBL demo job: its controller emulated on a pseudo-terminal".into(),
        job: service::JobSource::File(workspace().join("config/gateway/grbl-demo.toml")),
        map_profile: "error_map".into(),
        rotary: None,
    });
    config
}

/// A JSON array of strings, sorted.
fn sorted(v: &serde_json::Value) -> Vec<&str> {
    let mut all: Vec<&str> = v
        .as_array()
        .map(|a| a.iter().filter_map(|s| s.as_str()).collect())
        .unwrap_or_default();
    all.sort_unstable();
    all
}

/// The driver's walks written to a file, passed as `@FILE` (its uploads are larger than
/// one command-line argument may be).
fn walks_file(dir: &Path, walks: serde_json::Value) -> String {
    let path = dir.join("walks.json");
    std::fs::write(&path, walks.to_string()).expect("the walks file");
    format!("@{}", path.display())
}

fn fresh_dir(path: PathBuf) -> PathBuf {
    let _ = std::fs::remove_dir_all(&path);
    std::fs::create_dir_all(&path).expect("a temp dir under the target dir");
    path
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_runs_a_job_and_switches_profiles_in_headless_chromium() {
    let web_dir = workspace().join("tests/interop/web");
    if let Some(missing) = missing_tools(&web_dir) {
        panic!("cannot run the browser test: {missing}");
    }
    let artefacts = fresh_dir(PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("service_web"));
    let data_dir = fresh_dir(artefacts.join("data"));
    let profile_dir = fresh_dir(artefacts.join("chromium-profile"));
    let screenshot = artefacts.join("page.png");
    seed_profiles(&data_dir);
    seed_grbl_map(&data_dir).await;

    let first = service::start(https_demo(&data_dir))
        .await
        .expect("the demo service starts");
    let addr = first.local_addr();
    // Over HTTPS with the self-signed pair made at this first start: Chromium trusts
    // exactly its public key (the pin the service logs), as an operator who checked the
    // fingerprint would.
    let base = first.url().trim_end_matches('/').to_string();
    assert!(base.starts_with("https://"), "{base}");
    let spki = first.tls().expect("HTTPS").spki_sha256_base64.clone();
    let token = first.token().to_string();
    let mut running = Some(first);

    let driver = web_dir.join("drive_page.js");
    let args: Vec<String> = vec![
        driver.display().to_string(),
        base,
        token.clone(),
        "demo".into(),
        JOB_KIND.into(),
        JOB_PARAMS.into(),
        screenshot.display().to_string(),
        profile_dir.display().to_string(),
        CHARTS.into(),
        walks_file(
            &artefacts,
            serde_json::json!({
                "queue": {"kind": "compensate", "long": {"targets": null}, "short": {"targets": 1}},
                "form": true,
                "kinds": {"screenshots": artefacts.display().to_string(), "jobs": kind_jobs()},
                "spki": spki,
                "restart": {"screenshots": artefacts.display().to_string(), "params":
                    {"name": "restart_map", "grid_step_mm": 100, "line_step_mm": "50,0", "passes": 1}},
            }),
        ),
    ];
    // The driver asks on stdout ({"ask": "stop"} / {"ask": "start"}) for the service to
    // be shut down (as SIGTERM does) and started again on the same port and data, and is
    // answered on stdin; its last line is its report.
    let mut child = Command::new("node")
        .args(&args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("node runs");
    let mut answers = child.stdin.take().unwrap();
    let stdout = child.stdout.take().unwrap();
    let (lines_tx, mut lines) = tokio::sync::mpsc::unbounded_channel();
    let reader = std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            let _ = lines_tx.send(line);
        }
    });
    let mut report_line = String::new();
    while let Some(line) = lines.recv().await {
        let asked: serde_json::Value = serde_json::from_str(&line).unwrap_or_default();
        match asked["ask"].as_str() {
            Some("stop") => {
                running.take().expect("running").shutdown().await;
                writeln!(answers, "stopped").unwrap();
            }
            Some("start") => {
                let mut config = https_demo(&data_dir);
                config.service.listen = addr;
                running = Some(
                    service::start(config)
                        .await
                        .expect("the service starts again"),
                );
                writeln!(answers, "started").unwrap();
            }
            Some(sender) if sender.starts_with("sender ") => {
                system_tests::sender::unlock_and_move(&sender["sender ".len()..]).await;
                writeln!(answers, "sent").unwrap();
            }
            _ => report_line = line,
        }
    }
    reader.join().unwrap();
    let output = child.wait_with_output().expect("the driver ends");
    if let Some(r) = running.take() {
        r.shutdown().await;
    }

    let stderr = String::from_utf8_lossy(&output.stderr);
    std::fs::write(artefacts.join("report.json"), &report_line).expect("the report is kept");
    let report: serde_json::Value = serde_json::from_str(report_line.trim())
        .unwrap_or_else(|e| panic!("driver output is not JSON ({e}): {report_line}\n{stderr}"));
    assert_eq!(
        report["ok"],
        true,
        "the page walk failed (screenshot {}): {report}\n{stderr}",
        screenshot.display()
    );
    // The page, its API calls and its event WebSocket were over TLS (a secure context:
    // Chromium accepted the pinned certificate; the page was live over wss).
    assert_eq!(report["tls"]["protocol"], "https:", "{report}");
    assert_eq!(report["tls"]["secure_context"], true, "{report}");
    assert_eq!(report["tls"]["socket"], "wss:", "{report}");
    // The token left the address bar.
    let url = report["url_after_load"].as_str().unwrap();
    assert!(!url.contains(&token) && !url.contains("token="), "{url}");
    // The camera's last frame of the job: the thumbnail loaded (at most 320 px wide) with
    // the detected dots and the measured point drawn over it.
    // Shown after the tab was reopened mid-job: only the running job's frame, and it
    // went when the job ended.
    let frame = &report["frame"];
    let width = frame["width"].as_u64().unwrap_or(0);
    assert!((1..=320).contains(&width), "{frame}");
    assert!(frame["dots"].as_u64().unwrap_or(0) >= 12, "{frame}");
    assert_eq!(frame["centre"], true, "{frame}");
    assert_eq!(
        frame["jobs_shown"],
        serde_json::json!([frame["running_job"]]),
        "{frame}"
    );
    assert_eq!(frame["dropped_after_end"], true, "{frame}");
    // The map form has a field per param of the API's schema, and shows the API's
    // refusal of a too-fine grid beside its field (the message the API itself gives).
    let fields: Vec<&str> = report["form_fields"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|f| f.as_str())
        .collect();
    assert_eq!(
        fields,
        [
            "name",
            "grid_step_mm",
            "line_step_mm",
            "passes",
            "tool_offset_mm"
        ]
    );
    // Every bad field is refused at once, beside its field and in a list above Start,
    // in the page's words, before anything is queued.
    let words = |v: &serde_json::Value| v.as_str().unwrap_or("").replace('\u{a0}', " ");
    assert_eq!(
        words(&report["field_error"]),
        "Grid step must be between 0.25 and 10 000 mm; you entered 0.01.",
        "{report}"
    );
    let errors = &report["field_errors"];
    assert!(
        words(&errors["line_step_mm"]).starts_with("Line step is not a number"),
        "{errors}"
    );
    assert!(
        words(&errors["passes"]).starts_with("Passes must be a whole number; you entered 2,5"),
        "{errors}"
    );
    assert!(
        words(&errors["tool_offset_mm"]).contains("could be 1.250 or 1250"),
        "{errors}"
    );
    assert_eq!(report["form_errors_listed"], 4, "{report}");
    // The API's refusal of what the page could not know (the scan's size over this
    // machine's travel) is beside the field it names, without the API's field path.
    let api_errors = report["api_field_errors"]
        .as_object()
        .expect("the API's refusal");
    assert_eq!(api_errors.len(), 1, "{report}");
    for message in api_errors.values() {
        assert!(!words(message).contains("params."), "{message}");
    }
    // Bad values in the other forms too: each form with number fields, a word in each,
    // has every one of them refused at once (beside its field, listed above Start).
    let others = report["other_forms"]
        .as_array()
        .expect("other forms walked");
    let several = others
        .iter()
        .filter(|f| f["bad"].as_array().unwrap().len() >= 2)
        .count();
    assert!(
        several >= 3,
        "forms with two or more bad fields: {others:?}"
    );
    for form in others {
        let bad = form["bad"].as_array().unwrap();
        let marked = form["marked"].as_array().unwrap();
        for field in bad {
            assert!(marked.contains(field), "{field} not marked: {form}");
        }
        assert!(
            form["listed"].as_u64().unwrap() >= bad.len() as u64,
            "{form}"
        );
    }
    // A picture is refused when chosen; a JSON that is no layout and a broken DXF by the
    // layout reader the job uses, when queued.
    let uploads = &report["upload_errors"];
    assert!(
        words(&uploads["png"]).contains("is a PNG picture, not a layout"),
        "{uploads}"
    );
    for format in ["json", "dxf"] {
        assert!(
            words(&uploads[format])
                .starts_with("Layout file: the file is not a layout the job can read as"),
            "{uploads}"
        );
    }
    assert_eq!(report["machine_state_before"], "idle");
    assert_eq!(report["machine_state_after"], "idle");
    assert_eq!(report["job_detail_state"], "succeeded");
    // The finished job reads as the CLI's summary, not as raw JSON.
    let summary = report["job_summary"].as_str().unwrap();
    assert!(
        summary.contains("targets: 1 of 1 (1 within tolerance)")
            && summary.contains("error vs truth, after compensation"),
        "{summary}"
    );
    assert!(report["measurements"].as_u64().unwrap_or(0) > 0, "{report}");
    // Activating the older version and rolling back leaves exactly the newer one active.
    let newer = report["rolled_back_to"].as_u64().unwrap();
    assert_eq!(report["active_after_rollback"], serde_json::json!([newer]));
    assert_eq!(report["heatmap"]["version"], newer);
    // Of the error maps with an active version, the page says which one jobs use (the one
    // activated last: the kinds' walk activated the scanned map after the seeded one),
    // and offers to put a displaced one back in use.
    let rows = report["profile_rows"].as_array().unwrap();
    let in_use = |kind: &str| {
        rows.iter()
            .filter(|r| r["kind"] == kind && r["in_use"] == true)
            .count()
    };
    assert_eq!(in_use("error_map"), 1, "{rows:?}");
    assert!(in_use("rotary") <= 1, "{rows:?}");
    let displaced: Vec<&serde_json::Value> = rows
        .iter()
        .filter(|r| r["active"] == true && r["in_use"] == false)
        .collect();
    assert!(!displaced.is_empty(), "no displaced map: {rows:?}");
    for r in rows {
        let (shown, can) = (r["shown"].as_str().unwrap(), r["can_activate"] == true);
        match (r["active"] == true, r["in_use"] == true) {
            (_, true) => assert!(shown == "in use" && !can, "{r}"),
            (true, false) => assert!(shown == "active, not in use" && can, "{r}"),
            (false, _) => assert!(shown.is_empty() && can, "{r}"),
        }
    }
    // Each activation was confirmed by the operator, told which machine it affects.
    let dialogs = report["dialogs"].as_array().unwrap();
    assert!(!dialogs.is_empty(), "{report}");
    for d in dialogs {
        assert!(d.as_str().unwrap().contains("on machine demo"), "{d}");
    }
    // Cancel and Roll back ask too.
    for verb in ["Cancel ", "Roll back "] {
        assert!(
            dialogs
                .iter()
                .any(|d| d.as_str().unwrap().starts_with(verb)),
            "no confirmation of {verb}: {dialogs:?}"
        );
    }
    // Nothing wider than the screen on a 390 px phone or a 1366 px desktop.
    for (label, width) in [("390", 390), ("1366", 1366)] {
        let got = report["widths"][label].as_u64().unwrap();
        assert!(
            got <= width,
            "the page is {got} px wide at {width} px: {report}"
        );
    }
    assert!(
        report["phone_form_width"].as_u64().unwrap() <= 390,
        "{report}"
    );
    // axe-core: no serious or critical violation on any view.
    assert_eq!(report["axe"], serde_json::json!([]), "axe-core violations");
    // The seeded versions carry only drawings, no map: the page says what the API
    // answers for them (they cannot be compared node by node).
    assert!(
        report["diff"]
            .as_str()
            .unwrap()
            .contains(&format!("-> v{newer}")),
        "{report}"
    );
    // The machine's queue: Down, Up and Cancel reordered it as the page showed, and the
    // worker ran what was left in that order once the long job was cancelled.
    let queue = &report["queue"];
    let ids = |v: &serde_json::Value| -> Vec<u64> {
        v.as_array()
            .unwrap_or_else(|| panic!("{report}"))
            .iter()
            .map(|i| i.as_u64().unwrap())
            .collect()
    };
    let [a, b, c] = ids(&queue["queued"])[..] else {
        panic!("three queued jobs: {queue}")
    };
    assert_eq!(ids(&queue["after_moves"]), [b, c, a], "{queue}");
    assert_eq!(ids(&queue["after_cancel"]), [b, c], "{queue}");
    assert_eq!(ids(&queue["run_order"]), [b, c], "{queue}");
    // Every job kind the machine runs, started from its form, succeeded and shows its
    // numbers as a table (and its chart when it draws one), the raw JSON collapsed.
    let kinds = report["kinds"]
        .as_array()
        .unwrap_or_else(|| panic!("{report}"));
    let mut walked: Vec<&str> = kinds.iter().map(|k| k["kind"].as_str().unwrap()).collect();
    walked.sort_unstable();
    let mut registered: Vec<&str> = procedure::kinds::kinds().collect();
    registered.sort_unstable();
    assert_eq!(
        walked, registered,
        "every job kind is started from its form: a new kind needs its quickest params in \
         kind_jobs() (and its result table in the page, or it shows its numbers by name)"
    );
    for (k, want) in kinds.iter().zip(kind_jobs().as_array().unwrap()) {
        assert_eq!(k["state"], "succeeded", "{k}");
        // The form offers no field the service would refuse (real ports: the command
        // line's), and every field the walk filled.
        let name = k["kind"].as_str().unwrap();
        let fields: Vec<&str> = (k["fields"].as_array().unwrap().iter())
            .map(|f| f.as_str().unwrap())
            .collect();
        let registered = procedure::kinds::find(name).unwrap();
        for only in registered.command_line_only {
            assert!(!fields.contains(only), "{name} offers {only}: {fields:?}");
        }
        // A file's name is sent with the file, never typed: no `program_name` field.
        for field in &fields {
            let file = field.strip_suffix("_name").unwrap_or("");
            assert!(!fields.contains(&file), "{name} offers {field}: {fields:?}");
        }
        for filled in want["params"].as_object().unwrap().keys() {
            assert!(
                fields.contains(&filled.as_str()),
                "{name}: {filled} not in {fields:?}"
            );
        }
        let table = match k["kind"].as_str().unwrap() {
            "iso230" => "iso230-figures",
            "verify" => "verify-before-after",
            "compensate" => "compensate-before-after",
            _ => "figures",
        };
        assert_eq!(k["table"], table, "{k}");
        assert!(k["table_rows"].as_u64().unwrap() > 0, "{k}");
        if want["chart"] == true {
            assert!(!k["charts"].as_array().unwrap().is_empty(), "{k}");
        }
        // Charts people can read (measured by Chromium's layout of each SVG): a legend
        // covers no data point and is inside the picture; ISO 230-2's deviation chart
        // has its legend (both directions and the bands) and its axes' units.
        for (name, g) in k["chart_geometry"].as_object().unwrap() {
            let legend = &g["legend"];
            if legend["entries"].as_u64().unwrap() > 0 {
                assert_eq!(legend["covered"], 0, "{name}: {g}");
                assert_eq!(legend["inside"], true, "{name}: {g}");
            }
            if k["kind"].as_str().unwrap().starts_with("iso230") {
                assert!(legend["entries"].as_u64().unwrap() >= 3, "{name}: {g}");
                assert!(legend["points"].as_u64().unwrap() > 0, "{name}: {g}");
                assert_eq!(
                    sorted(&g["units"]),
                    [
                        "positional deviation (µm)",
                        "target position, machine axis (mm)"
                    ],
                    "{name}: {g}"
                );
            }
        }
        // The scanned map's heat map: every arrow inside the plot, an arrow-length scale,
        // the colour bar's value written at both ends, axes in machine mm.
        if want["activate"].is_string() {
            let g = &k["heatmap_geometry"];
            let h = &g["heatmap"];
            assert!(h["arrows"].as_u64().unwrap() > 0, "{g}");
            assert_eq!(h["arrows_outside_plot"], 0, "{g}");
            assert_eq!(h["scale_arrow"], 2, "a shaft and a head: {g}");
            assert!(h["scale_text"].as_str().is_some(), "{g}");
            let value = |v: &serde_json::Value| -> Vec<f64> {
                v.as_array()
                    .unwrap()
                    .iter()
                    .map(|t| t.as_str().unwrap().parse::<f64>().unwrap())
                    .collect()
            };
            let top = value(&h["bar_top"]);
            assert!(top.len() == 1 && top[0] > 0.0, "{g}");
            assert_eq!(value(&h["bar_bottom"]), [0.0], "{g}");
            assert_eq!(
                sorted(&g["units"]),
                [
                    "X, machine position (mm)",
                    "Y, machine position (mm)",
                    "|e|, µm"
                ],
                "{g}"
            );
        }
        assert_eq!(k["raw_collapsed"], true, "{k}");
        // An uploaded file gives its name to the field that names it in messages.
        for (file, named) in [
            ("program", "program_name"),
            ("centres", "centres_name"),
            ("measurements", "measurements_name"),
            ("errors", "errors_name"),
        ] {
            if let Some(upload) = want["params"][file]["name"].as_str() {
                assert_eq!(k["params"][named], upload, "{}", k["kind"]);
            }
        }
        assert_eq!(k["raw_hidden"], true, "{k}");
        assert!(k["phone_width"].as_u64().unwrap() <= 390, "{k}");
        // Each number as typed (a decimal comma too) is the number stored.
        for (name, typed) in want["params"].as_object().unwrap() {
            if let Some(text) = typed.as_str().filter(|t| t.contains(',')) {
                let exact: f64 = text.replace(',', ".").parse().unwrap();
                // A nested field (`partition.gap_mm`) is stored nested.
                let stored = k["params"].pointer(&format!("/{}", name.replace('.', "/")));
                let stored = stored.and_then(serde_json::Value::as_f64);
                assert_eq!(stored, Some(exact), "{name} typed {text}: {k}");
            }
        }
        let shot = std::fs::read(k["screenshot"].as_str().unwrap()).expect("a screenshot per kind");
        assert!(shot.starts_with(b"\x89PNG\r\n\x1a\n"), "{k}");
    }
    // The service stopped mid-scan: the page said it was not live (every action
    // disabled, no time left); back up, the job is what the service recorded, no frame
    // or progress of it is left, and Resume measured only what was missing.
    let restart = &report["restart"];
    assert_eq!(restart["down"]["stale_shown"], true, "{restart}");
    assert_eq!(restart["down"]["actions_disabled"], true, "{restart}");
    assert!(
        restart["down"]["actions"].as_u64().unwrap() > 0,
        "{restart}"
    );
    for p in restart["down"]["progress"].as_array().unwrap() {
        let p = p.as_str().unwrap();
        assert!(p.contains("not live") && !p.contains("left"), "{p}");
    }
    assert_eq!(restart["after"]["state"], "cancelled", "{restart}");
    assert_eq!(restart["after"]["row_state"], "cancelled", "{restart}");
    assert!(
        restart["after"]["next"]
            .as_str()
            .unwrap()
            .contains("kept. Starting the same scan again measures only what is missing"),
        "{restart}"
    );
    // What stopped it, as the service recorded it: its shutdown, not a Cancel.
    assert!(
        restart["after"]["next"]
            .as_str()
            .unwrap()
            .starts_with("Cancelled before the end: the service was shut down while it ran"),
        "{restart}"
    );
    assert_eq!(restart["after"]["running"], 0, "{restart}");
    assert_eq!(restart["after"]["frames"], 0, "{restart}");
    assert_eq!(restart["resumed"]["state"], "succeeded", "{restart}");
    assert_eq!(
        restart["resumed"]["resumed_from_job"], restart["job"],
        "{restart}"
    );
    assert!(
        restart["resumed"]["resumed_frames"].as_u64().unwrap() > 0,
        "{restart}"
    );
    let png = std::fs::read(&screenshot).expect("the screenshot was written");
    assert!(
        png.starts_with(b"\x89PNG\r\n\x1a\n"),
        "not a PNG: {}",
        screenshot.display()
    );
}

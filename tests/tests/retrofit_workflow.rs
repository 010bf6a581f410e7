//! The retrofit workflow end to end with no truth map anywhere: the map is scanned by
//! the camera through the GRBL controller (the `gateway map` procedure), the machine is
//! homed again and referenced (the `gateway reference` procedure, its record written
//! beside the map and read back), then an independent sender (pyserial) streams a
//! program through the pass-through, once with the map as scanned and once with its
//! reference. The simulated machine's trace of the true tool point is compared with the
//! program: the truth is read only there, never by what compensates.
//!
//! One simulated machine behind one GRBL emulator (a pseudo-terminal) for the whole
//! test, as one real machine is for a shop: the map, the reference and the sessions each
//! open the controller's port and close it again. Thermal drift is off (the scan takes
//! simulated minutes; drift is what a later reference is for). A smaller camera window
//! keeps the debug build's frames cheap. Without python3/pyserial it fails, naming the install step.

use devices::{spawn_grbl_emulator, Devices};
use drivers::grbl::GrblOptions;
use drivers::open_grbl_line as open_controller;
use drivers::StageLink;
use job::{CameraSpec, Job, StageSpec};
use procedure::map::{FileJournal, FolderShelf};
use procedure::reference::{self as refer, Choice};
use procedure::request::{MapRequest, ReferenceRequest};
use protocol::errormap::ErrorMap;
use proxy::{Ending, Proxy, SenderPort};
use rewrite::{Options, Rewriter};
use std::path::Path;
use std::time::Duration;
use system_tests::program_path::{programmed_path, worst_distance};
use system_tests::{python_missing, runtime};
use world::{lock, Clock, SharedRig};

/// Lines, arcs, long diagonals and the long X move of issue 26 (where the Y correction
/// creeps up and back along the move), inside the map, feed moves after the first rapid.
const PROGRAM: &str = "(retrofit workflow)
G21 G90 G17
G0 X20 Y20
G1 X150 Y20 F3000
G1 X150 Y110
G2 X110 Y110 I-20 J0
G1 X20 Y30 (long diagonal)
G3 X60 Y60 I20 J15
G1 X180 Y130
G1 X30 Y120
G1 X17.5 Y12.25 F2400
G1 X172.5 Y12.25
";

/// How long a session waits for the controller's banner when it opens the port: not
/// at all. The emulator printed its banner once, at power-up, to the map's driver; a
/// port opened again gets none (a real board would reset on DTR and print one, which
/// `gateway proxy` waits up to 2.5 s for). Whatever the controller sent already is still
/// read first: the wait polls the port before it looks at the clock.
const NO_BANNER: Duration = Duration::ZERO;

/// The programmed feed path, machine mm (arcs as chords within 1 nm), from (20, 20).
fn nominal_path() -> Vec<[f64; 2]> {
    // Feed moves start where the rapid to (20, 20) ended.
    programmed_path(PROGRAM, [20.0, 20.0])
}

/// The demo job on a smaller camera window, thermal drift off.
fn job() -> Job {
    let mut job = Job::demo();
    let CameraSpec::Sim { model } = &mut job.camera else {
        unreachable!("the demo job simulates its camera")
    };
    // 2.4 x 1.9 mm of board: about 5 x 4 pitches.
    model.width = 600;
    model.height = 480;
    job.localize.min_points = 8;
    let StageSpec::Sim { machine } = &mut job.stage else {
        unreachable!("the demo job is simulated")
    };
    machine.thermal = None;
    job
}

/// The job's devices on the machine behind the emulator at `port`: the GRBL driver on
/// its port, the camera looking at the same machine.
async fn open(port: &str, rig: &SharedRig) -> Devices {
    let link = StageLink::Grbl {
        port: port.to_string(),
        baud: 115_200,
        options: GrblOptions {
            poll_interval: Duration::from_millis(1),
            ..Default::default()
        },
    };
    Devices {
        stage: drivers::open_stage(&link)
            .await
            .expect("the GRBL driver opens"),
        camera: Box::new(drivers::sim::SimCamera::new(rig.clone())),
        rig: Some(rig.clone()),
    }
}

/// The pass-through's re-reference after the sender's homing, as `gateway proxy` makes
/// it (no re-reference in use), `recorded` told of each record.
fn after_homing<'a>(
    job: &Job,
    map: &'a ErrorMap,
    shared: &'a procedure::proxy::SharedMap,
    previous: &'a std::cell::RefCell<Option<errormap::reference::MapReference>>,
    mut recorded: impl FnMut(&errormap::reference::MapReference) + 'a,
) -> proxy::AfterHoming<'a> {
    proxy::AfterHoming::Reference(procedure::proxy::map_rereference(
        map,
        shared,
        job.policy.approach_mm,
        procedure::reference::shift_bound_um(job, errormap::reference::MAX_SHIFT_UM),
        None,
        previous,
        move |record, _| {
            recorded(record);
            Ok(())
        },
    ))
}

/// One session of the pyserial sender through the pass-through with `model`; the trace
/// of the true tool point and the sender's report.
/// With `rereference`, the pass-through re-references with the camera after the
/// sender's homing (as `gateway proxy` does); the count of those comes back too.
#[allow(clippy::too_many_arguments)]
async fn stream(
    port: &str,
    rig: &SharedRig,
    job: &Job,
    model: errormap::MapModel,
    rereference: bool,
    greeting: &str,
    dir: &Path,
    sender: impl FnOnce(&Path, &Path) -> std::process::Command,
) -> (Vec<world::machine::TraceRow>, serde_json::Value, usize) {
    let program = dir.join("prog.nc");
    std::fs::write(&program, PROGRAM).unwrap();
    let link = dir.join("ttyGATEWAY");
    lock(rig).machine_mut().start_trace();
    let (mut controller, _) = open_controller(port, 115_200, NO_BANNER).await.unwrap();
    let mut sender_port = SenderPort::create(Some(&link)).unwrap();
    let mut command = sender(&link, &program);
    let client = tokio::task::spawn_blocking(move || command.output().expect("run the sender"));
    let map = model.map().clone();
    let shared = procedure::proxy::SharedMap::new(model);
    let rereferenced = std::cell::Cell::new(0);
    let previous = std::cell::RefCell::new(None);
    let mut proxy = Proxy::new(Rewriter::new(&shared, Options::default()).unwrap(), &shared);
    proxy.start();
    proxy.greet(greeting);
    if rereference {
        proxy.after_homing(after_homing(job, &map, &shared, &previous, |_| {
            rereferenced.set(rereferenced.get() + 1)
        }));
    }
    let mut frames = procedure::proxy::CameraFrames {
        camera: Box::new(drivers::sim::SimCamera::new(rig.clone())),
        job,
    };
    let ending = proxy::serve_with_camera(
        &mut proxy,
        &mut sender_port,
        &mut controller,
        std::future::pending(),
        Some(&mut frames),
    )
    .await;
    drop(proxy);
    let sender = client.await.unwrap();
    let Ending::SenderLeft(account) = &ending else {
        panic!("{ending:?}")
    };
    assert!(
        account.refused.is_empty() && account.not_sent.is_empty(),
        "{account:?}"
    );
    (
        lock(rig).machine_mut().take_trace(),
        system_tests::sender_json(&sender),
        rereferenced.get(),
    )
}

/// A sender of our own that homes first (`$H`), then sends the program line by line,
/// each after the previous one's answer; everything it got back.
async fn home_then_send(link: &Path) -> String {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    use tokio_serial::SerialPortBuilderExt;
    let mut port = tokio_serial::new(link.to_string_lossy(), 115_200)
        .open_native_async()
        .expect("open the gateway's port");
    let mut got = String::new();
    let mut buf = [0u8; 1024];
    let lines = std::iter::once("$H").chain(PROGRAM.lines());
    for line in lines {
        let answers = |s: &str| {
            s.lines()
                .filter(|l| *l == "ok" || l.starts_with("error:"))
                .count()
        };
        let before = answers(&got);
        port.write_all(format!("{line}\n").as_bytes())
            .await
            .unwrap();
        while answers(&got) == before {
            let k = port.read(&mut buf).await.unwrap();
            assert!(k > 0, "the gateway closed the port");
            got.push_str(&String::from_utf8_lossy(&buf[..k]).replace('\r', ""));
        }
    }
    got
}

/// The true tool path from its arrival at (20, 20) against the program, mm.
fn path_deviation(rows: &[world::machine::TraceRow]) -> f64 {
    let start = rows
        .windows(2)
        .position(|w| {
            (w[0].cmd_mm[0] - 20.0).hypot(w[0].cmd_mm[1] - 20.0) < 0.1 && w[0].cmd_mm == w[1].cmd_mm
        })
        .expect("the tool reached the start of the feed moves");
    let feed = &rows[start..];
    assert!(feed.len() > 5000, "{} rows", feed.len());
    worst_distance(feed.iter().map(|r| r.true_mm), &nominal_path())
}

#[test]
fn scan_home_reference_and_stream_without_a_truth_map_keeps_the_tool_on_the_program() {
    if let Some(why) = python_missing("serial", "pyserial") {
        panic!("cannot run: {why}");
    }
    let job = job();
    let StageSpec::Sim { machine } = &job.stage else {
        unreachable!()
    };
    let dir = tempfile::tempdir().unwrap();
    let rt = runtime();
    rt.block_on(async {
        let (emulator, rig) = spawn_grbl_emulator(&job, machine, Clock::Unconstrained).unwrap();
        let port = emulator.path().to_string();

        // 1. The scan (homes first), as `gateway map` runs it.
        let mut devices = open(&port, &rig).await;
        let passes: u32 = std::env::var("RETROFIT_PASSES")
            .ok()
            .and_then(|p| p.parse().ok())
            .unwrap_or(1);
        let request = MapRequest {
            name: "retrofit".into(),
            passes,
            ..MapRequest::default()
        };
        let maps = dir.path().join("maps");
        std::fs::create_dir_all(&maps).unwrap();
        let mut journal = FileJournal::new(maps.join("retrofit.scan.jsonl"));
        let mut shelf = FolderShelf::new(&maps);
        let scanned = procedure::map::run(
            &request,
            &job,
            &mut devices,
            &mut journal,
            &mut shelf,
            &mut procedure::Discard,
            std::future::pending(),
        )
        .await;
        assert!(scanned.is_success(), "{:?}", scanned.error());
        let kept = (scanned.result.as_ref())
            .and_then(|r| r.kept_as.clone())
            .unwrap();
        let map_path = Path::new(&kept).to_path_buf();
        let map = ErrorMap::load(&map_path).unwrap();

        // 2. Home again (the zero moves) and reference, as `gateway reference` does; the
        // record goes beside the map and is read back from there.
        let homings_before = lock(&rig).machine().homings();
        let mut artifacts = procedure::Collect::default();
        let referenced = procedure::reference::run(
            &ReferenceRequest::default(),
            &job,
            &mut devices,
            &map,
            &kept,
            None,
            std::time::SystemTime::now(),
            &mut artifacts,
        )
        .await;
        assert!(referenced.is_success(), "{:?}", referenced.error());
        assert!(lock(&rig).machine().homings() > homings_before, "it homed");
        let r = referenced.result.unwrap();
        let record_path = refer::reference_path(&map_path);
        protocol::config::write_output(&record_path, &artifacts.0[0].bytes, &[&map_path]).unwrap();
        let record = refer::read_record(&record_path).unwrap().expect("recorded");
        let machine_time_s = r.machine_time_s.unwrap();
        let shift = record.shift_um;

        // A spot check right after: the recorded reference applies, no homing; the zero
        // has not drifted since, and the map holds.
        let spot = procedure::verify::check_map(
            &procedure::request::VerifyRequest {
                spot_check: true,
                ..Default::default()
            },
            &job,
            &mut devices,
            map.clone(),
            &kept,
            Some(&record),
            std::time::SystemTime::now(),
            &mut procedure::Discard,
        )
        .await;
        assert!(spot.is_success(), "{:?}", spot.error());
        let spot = spot.result.unwrap();
        let drift = spot.drift_since_reference_um.unwrap();
        let drift = drift[0].hypot(drift[1]);
        let spot_max = spot.residual_um.max;
        eprintln!(
            "spot check on the recorded reference: drift since it {drift:.2} um, residual max \
             {spot_max:.2} um"
        );
        assert!(drift < 0.5, "{spot:?}");
        assert!(spot_max < 1.5, "{spot:?}");
        assert!(!spot.rescan);
        drop(devices);

        // 3. The same program through the pass-through: with the map as scanned, then
        // with its reference.
        let mut worst = Vec::new();
        for choice in [Choice::NotWanted, Choice::Recorded(record.clone())] {
            let applied = refer::apply(map.clone(), &choice, std::time::SystemTime::now()).unwrap();
            let (rows, sender, _) = stream(
                &port,
                &rig,
                &job,
                applied.model,
                false,
                &applied.describe,
                dir.path(),
                system_tests::grbl_sender,
            )
            .await;
            assert_eq!(sender["errors"].as_array().unwrap().len(), 0, "{sender}");
            worst.push(path_deviation(&rows));
        }
        let (unreferenced, referenced) = (worst[0] * 1000.0, worst[1] * 1000.0);
        eprintln!(
            "retrofit workflow (map scanned by the camera, {passes} pass(es)): reference step \
             {machine_time_s:.1} s of machine time, zero shift ({:+.2}, {:+.2}) um; true path \
             within {referenced:.3} um of the program with the reference, {unreferenced:.3} um \
             with the map as scanned",
            shift[0], shift[1]
        );
        // Homing, the orientation check, the reference frame and (issue 39) one frame
        // at the map's far end along each axis for the axes' thermal growth.
        assert!(
            machine_time_s <= 12.0,
            "the reference took {machine_time_s} s"
        );
        assert!(
            shift[0].hypot(shift[1]) > 1.0,
            "the homing moved the zero: {shift:?}"
        );
        assert!(
            unreferenced > referenced + 1.0,
            "the reference must matter: {unreferenced:.3} um without, {referenced:.3} um with"
        );
        assert!(referenced < 2.5, "{referenced:.3} um with the reference");

        // CNCjs as the sender (headless, through its socket.io API): it homes first, so
        // the pass-through re-references by itself.
        let cncjs = system_tests::cncjs_dir().unwrap_or_else(|why| panic!("cannot run: {why}"));
        let applied = refer::apply(
            map.clone(),
            &Choice::Recorded(record.clone()),
            std::time::SystemTime::now(),
        )
        .unwrap();
        let (rows, v, rereferenced) = stream(
            &port,
            &rig,
            &job,
            applied.model,
            true,
            &applied.describe,
            dir.path(),
            move |link, program| {
                let mut c = std::process::Command::new("node");
                c.arg(system_tests::workspace().join("tests/interop/cncjs_sender.js"))
                    .arg(&cncjs)
                    .arg(link)
                    .arg(program);
                c
            },
        )
        .await;
        assert_eq!(v["errors"].as_array().unwrap().len(), 0, "{v}");
        assert_eq!(v["alarms"].as_array().unwrap().len(), 0, "{v}");
        // CNCjs homes before it streams: the pass-through re-referenced.
        assert_eq!(rereferenced, 1, "{v}");
        let with_cncjs = path_deviation(&rows) * 1000.0;
        eprintln!(
            "CNCjs (it homes first) through the pass-through, which re-referenced by \
             itself: true path within {with_cncjs:.3} um of the program"
        );
        assert!(with_cncjs < 2.5, "{with_cncjs:.3} um with CNCjs");

        // 4. The sender homes (the zero moves again): the pass-through re-references by
        // itself with the camera before the next line, and the program stays on its path.
        let shared = procedure::proxy::SharedMap::new(
            refer::apply(
                map.clone(),
                &Choice::Recorded(record.clone()),
                std::time::SystemTime::now(),
            )
            .unwrap()
            .model,
        );
        let seen = std::cell::Cell::new(None);
        let previous = std::cell::RefCell::new(None);
        let homings = lock(&rig).machine().homings();
        lock(&rig).machine_mut().start_trace();
        let (mut controller, _) = open_controller(&port, 115_200, NO_BANNER).await.unwrap();
        let link = dir.path().join("ttyHOMING");
        let mut sender_port = SenderPort::create(Some(&link)).unwrap();
        let mut proxy = Proxy::new(Rewriter::new(&shared, Options::default()).unwrap(), &shared);
        proxy.after_homing(after_homing(&job, &map, &shared, &previous, |record| {
            seen.set(Some(record.seen_um))
        }));
        proxy.start();
        let mut frames = procedure::proxy::CameraFrames {
            camera: Box::new(drivers::sim::SimCamera::new(rig.clone())),
            job: &job,
        };
        let session = proxy::serve_with_camera(
            &mut proxy,
            &mut sender_port,
            &mut controller,
            std::future::pending(),
            Some(&mut frames),
        );
        let (ending, got) = tokio::join!(session, home_then_send(&link));
        assert!(matches!(ending, Ending::SenderLeft(_)), "{ending:?}");
        let rows = lock(&rig).machine_mut().take_trace();
        assert!(lock(&rig).machine().homings() > homings, "the sender homed");
        assert!(got.contains("[MSG:gateway: homed:"), "{got}");
        assert!(got.contains("[MSG:gateway: referenced: "), "{got}");
        assert!(!got.contains("error:"), "{got}");
        let seen = seen.get().expect("the reference frame was measured");
        // The camera was over the reference point, and the tool came back before the
        // program's first move.
        let r = map.reference_mm;
        assert!(
            rows.iter()
                .any(|row| (row.cmd_mm[0] - r[0]).hypot(row.cmd_mm[1] - r[1]) < 0.02),
            "the stage went to the reference point"
        );
        let after_homing = path_deviation(&rows) * 1000.0;
        eprintln!(
            "after the sender's $H the pass-through re-referenced by itself (camera saw \
             ({:+.2}, {:+.2}) um): true path within {after_homing:.3} um of the program",
            seen[0], seen[1]
        );
        assert!(after_homing < 2.5, "{after_homing:.3} um after the homing");
    });
}

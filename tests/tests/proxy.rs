//! The live pass-through end to end: an independent pyserial sender (written against
//! GRBL's public docs: `?`, `$I`, `$$`, `$G`, homing, character-counting streaming)
//! talks to `gateway proxy`'s pseudo-terminal as it would to GRBL; the gateway rewrites
//! every line with the error map and streams the pieces to the GRBL emulator driving the
//! simulated stage. The emulator's trace of the true tool point along the executed path
//! is compared with the programmed path. Skips, saying why, without python3/pyserial.

use devices::spawn_grbl_emulator;
use drivers::open_grbl_line as open_controller;
use errormap::MapModel;
use job::{Job, StageSpec};
use protocol::errormap::Identity;
use proxy::{serve, Ending, Proxy, SenderPort};
use rewrite::{Options, Rewriter};
use std::process::Command;
use std::time::Duration;
use system_tests::program_path::{programmed_path, worst_distance};
use system_tests::truth_map::map_from_truth;
use system_tests::{python_missing, runtime, workspace};
use world::{lock, Clock};

/// Lines, arcs and long diagonals, inside the map (0..200 x 0..150 mm), feed moves
/// only after the first rapid.
const PROGRAM: &str = "(pass-through test)
G21 G90 G17
G0 X20 Y20
G1 X150 Y20 F3000
G1 X150 Y110
G2 X110 Y110 I-20 J0
G1 X20 Y30 (long diagonal)
G3 X60 Y60 I20 J15
G1 X180 Y130
G1 X30 Y120
";

/// The programmed feed path, machine mm (arcs as chords within 1 nm), from (20, 20).
fn nominal_path() -> Vec<[f64; 2]> {
    // Feed moves start where the rapid to (20, 20) ended.
    programmed_path(PROGRAM, [20.0, 20.0])
}

/// What a streaming session through the proxy gave.
struct Streamed {
    /// Where the tool sits at the map's reference point relative to where the yaw-free
    /// arm would put it: a shop touches the tool off there (a work offset), so this
    /// constant is not a path error.
    tool_zero_mm: [f64; 2],
    ending: Ending,
    sender: std::process::Output,
    stats: proxy::ProxyStats,
    rows: Vec<world::machine::TraceRow>,
}

/// The GRBL emulator on the demo stage (thermal drift off), the proxy with a map made
/// from the truth, and `sender(port_link, program_file)` as the sender; the emulator's
/// trace of the whole session.
fn stream_through_proxy(
    tool_offset_mm: [f64; 2],
    map_told: bool,
    sender: impl FnOnce(&std::path::Path, &std::path::Path) -> Command + Send + 'static,
) -> Streamed {
    let (job, machine, model) = demo_machine_with_tool(tool_offset_mm, map_told);
    let reference = model.map().reference_mm;
    let yaw_ref = model
        .yaw_urad(reference, errormap::Direction::FORWARD)
        .unwrap()
        * 1e-6;
    let [ox, oy] = tool_offset_mm;
    let tool_zero_mm = [-yaw_ref * oy, yaw_ref * ox];
    let dir = std::env::temp_dir().join(format!("proxy-test-{}-{}", std::process::id(), unique()));
    std::fs::create_dir_all(&dir).unwrap();
    let program = dir.join("prog.nc");
    std::fs::write(&program, PROGRAM).unwrap();
    let link = dir.join("ttyGATEWAY");
    let rt = runtime();
    rt.block_on(async {
        let (emulator, rig) = spawn_grbl_emulator(&job, &machine, Clock::Unconstrained).unwrap();
        lock(&rig).machine_mut().start_trace();
        let (mut controller, banner) =
            open_controller(emulator.path(), 115_200, Duration::from_secs(10))
                .await
                .unwrap();
        assert!(banner.contains("Grbl 1.1"), "{banner}");
        let mut sender_port = SenderPort::create(Some(&link)).unwrap();
        let mut command = sender(&link, &program);
        let client = tokio::task::spawn_blocking(move || command.output().expect("run the sender"));
        let rewriter = Rewriter::new(&model, Options::default()).unwrap();
        let mut proxy = Proxy::new(rewriter, &model);
        proxy.start();
        let ending = serve(
            &mut proxy,
            &mut sender_port,
            &mut controller,
            std::future::pending(),
        )
        .await;
        let sender = client.await.unwrap();
        let rows = lock(&rig).machine_mut().take_trace();
        Streamed {
            tool_zero_mm,
            ending,
            sender,
            stats: proxy.stats().clone(),
            rows,
        }
    })
}

fn unique() -> u32 {
    use std::sync::atomic::{AtomicU32, Ordering};
    static N: AtomicU32 = AtomicU32::new(0);
    N.fetch_add(1, Ordering::Relaxed)
}

/// Every line answered, the true tool path within `bound_mm` of the program; prints the
/// figures and returns the largest distance, mm.
fn check_session(s: &Streamed, who: &str, bound_mm: f64) -> f64 {
    let Ending::SenderLeft(account) = &s.ending else {
        panic!("{:?}", s.ending)
    };
    assert!(
        account.not_sent.is_empty()
            && account.in_controller.is_empty()
            && account.refused.is_empty(),
        "{account:?}"
    );
    assert!(
        s.stats.pieces_sent > 200,
        "moves were split: {}",
        s.stats.pieces_sent
    );
    // The true tool path, from its arrival at (20, 20) on, against the programmed path.
    let path = nominal_path();
    // The end of the rapid onto it: the first row near (20, 20) where the command has
    // stopped (the trace repeats a row at every move's end).
    let start = s
        .rows
        .windows(2)
        .position(|w| {
            (w[0].cmd_mm[0] - 20.0).hypot(w[0].cmd_mm[1] - 20.0) < 0.1 && w[0].cmd_mm == w[1].cmd_mm
        })
        .expect("the tool reached the start of the feed moves");
    let feed_rows = &s.rows[start..];
    assert!(feed_rows.len() > 5000, "{} rows", feed_rows.len());
    let z = s.tool_zero_mm;
    let worst = worst_distance(
        feed_rows
            .iter()
            .map(|r| [r.true_mm[0] - z[0], r.true_mm[1] - z[1]]),
        &path,
    );
    // Without the gateway the same rows are the commands: how far the stage is off.
    let raw_worst = feed_rows
        .iter()
        .map(|r| (r.true_mm[0] - r.cmd_mm[0]).hypot(r.true_mm[1] - r.cmd_mm[1]))
        .fold(0.0f64, f64::max);
    eprintln!(
        "pass-through with {who}: {} trace rows, true path within {:.3} um of the program (stage error up to {:.2} um), {} pieces for {} lines",
        feed_rows.len(),
        worst * 1000.0,
        raw_worst * 1000.0,
        s.stats.pieces_sent,
        s.stats.lines
    );
    assert!(
        raw_worst > 0.015,
        "the stage is off by {raw_worst} mm uncompensated"
    );
    assert!(
        worst < bound_mm,
        "true path {:.3} um from the program",
        worst * 1000.0
    );
    worst
}

#[test]
fn an_independent_sender_streams_through_the_proxy_and_the_tool_follows_the_program() {
    if let Some(why) = python_missing("serial", "pyserial") {
        panic!("cannot run: {why}");
    }
    let s = stream_through_proxy([0.0, 0.0], true, |link, program| {
        system_tests::grbl_sender(link, program)
    });
    let v = system_tests::sender_json(&s.sender);
    let n = PROGRAM.lines().count() as u64;
    assert_eq!(v["acknowledged"], n, "{v}");
    assert_eq!(v["errors"].as_array().unwrap().len(), 0, "{v}");
    // The sender sees the programmed end point (within the controller's 0.5 um steps),
    // not the corrected command, which is several um away.
    let status = v["final_status"].as_str().unwrap();
    let mpos: Vec<f64> = status
        .split("MPos:")
        .nth(1)
        .and_then(|s| s.split('|').next())
        .unwrap()
        .split(',')
        .map(|x| x.trim_end_matches('>').parse().unwrap())
        .collect();
    assert!(
        (mpos[0] - 30.0).abs() <= 0.0011 && (mpos[1] - 120.0).abs() <= 0.0011,
        "{status}"
    );
    check_session(&s, "pyserial", 0.002);
}

#[test]
fn a_tool_away_from_the_camera_follows_the_program_when_the_map_knows_the_arm() {
    if let Some(why) = python_missing("serial", "pyserial") {
        panic!("cannot run: {why}");
    }
    // 120 mm right of and 80 mm below the camera (a tool on a long arm, a laser head
    // beside the camera): the carriage's yaw (up to 8 arcsec on X) moves the tool by
    // several um more than the camera sees (Abbe).
    let run = |map_told: bool| {
        stream_through_proxy([120.0, -80.0], map_told, |link, program| {
            system_tests::grbl_sender(link, program)
        })
    };
    let told = run(true);
    assert_eq!(
        system_tests::sender_json(&told.sender)["errors"]
            .as_array()
            .unwrap()
            .len(),
        0
    );
    let with_arm = check_session(
        &told,
        "the tool 120,-80 mm from the camera, the map told",
        0.0025,
    );
    let untold = run(false);
    let without_arm = check_session(
        &untold,
        "the tool 120,-80 mm from the camera, the map not told",
        0.01,
    );
    assert!(
        without_arm > with_arm + 0.001,
        "the Abbe term should matter: {:.3} um told, {:.3} um not told",
        with_arm * 1e3,
        without_arm * 1e3
    );
}

#[test]
fn cncjs_streams_through_the_proxy_and_the_tool_follows_the_program() {
    let dir = system_tests::cncjs_dir().unwrap_or_else(|why| panic!("cannot run: {why}"));
    let s = stream_through_proxy([0.0, 0.0], true, move |link, program| {
        let mut c = Command::new("node");
        c.arg(workspace().join("tests/interop/cncjs_sender.js"))
            .arg(&dir)
            .arg(link)
            .arg(program);
        c
    });
    let v = system_tests::sender_json(&s.sender);
    // CNCjs adds one line of its own (`%wait`, a dwell) to every program.
    assert_eq!(v["received"], v["total"], "{v}");
    assert!(
        v["total"].as_u64().unwrap() >= PROGRAM.lines().count() as u64 - 1,
        "{v}"
    );
    assert_eq!(v["errors"].as_array().unwrap().len(), 0, "{v}");
    assert_eq!(v["alarms"].as_array().unwrap().len(), 0, "{v}");
    // CNCjs shows the programmed end point.
    let mpos = &v["final_status"]["mpos"];
    let x: f64 = mpos["x"].as_str().unwrap().parse().unwrap();
    let y: f64 = mpos["y"].as_str().unwrap().parse().unwrap();
    assert!(
        (x - 30.0).abs() <= 0.0011 && (y - 120.0).abs() <= 0.0011,
        "{v}"
    );
    check_session(&s, "CNCjs", 0.002);
}

/// A sender of our own on the pseudo-terminal: writes lines, reads what comes back.
struct RawSender {
    port: tokio_serial::SerialStream,
    got: String,
}

impl RawSender {
    fn open(path: &std::path::Path) -> RawSender {
        use tokio_serial::SerialPortBuilderExt;
        let port = tokio_serial::new(path.to_string_lossy(), 115_200)
            .open_native_async()
            .expect("open the gateway's port");
        RawSender {
            port,
            got: String::new(),
        }
    }

    async fn send(&mut self, text: &str) {
        use tokio::io::AsyncWriteExt;
        self.port.write_all(text.as_bytes()).await.unwrap();
    }

    /// Read until `n` answers (`ok`/`error:`) or an `ALARM:` have come.
    async fn until_answers(&mut self, n: usize) {
        use tokio::io::AsyncReadExt;
        let answers = |s: &str| {
            s.lines()
                .filter(|l| *l == "ok" || l.starts_with("error:"))
                .count()
        };
        let mut buf = [0u8; 1024];
        while answers(&self.got) < n && !self.got.contains("ALARM:") {
            let k = self.port.read(&mut buf).await.unwrap();
            assert!(k > 0, "the gateway closed the port");
            self.got
                .push_str(&String::from_utf8_lossy(&buf[..k]).replace('\r', ""));
        }
    }
}

/// Long, slow moves on a real-time controller: the program is still running when the
/// fault comes.
fn slow_program() -> String {
    let mut p = String::from("G21 G90\nG0 X10 Y10\n");
    for k in 0..12 {
        let (x, y) = if k % 2 == 0 {
            (190.0, 10.0 + k as f64)
        } else {
            (10.0, 10.0 + k as f64)
        };
        p.push_str(&format!("G1 X{x} Y{y} F600\n"));
    }
    p
}

fn demo_machine() -> (Job, world::machine::MachineConfig, MapModel) {
    demo_machine_with_tool([0.0, 0.0], true)
}

/// The demo stage with the tool on an arm `tool_offset_mm` from the camera (the map is
/// told the offset, as `gateway map --tool-offset-mm` is).
fn demo_machine_with_tool(
    tool_offset_mm: [f64; 2],
    map_told: bool,
) -> (Job, world::machine::MachineConfig, MapModel) {
    let mut job = Job::demo();
    let StageSpec::Sim { machine } = &mut job.stage else {
        unreachable!("the demo job simulates its stage")
    };
    machine.thermal = None;
    machine.machine.tool_offset_mm = tool_offset_mm;
    let machine = machine.clone();
    let id = Identity {
        machine: "sim".into(),
        controller: "sim".into(),
        board: job.board.name.clone(),
        certificate_sha256: job.board.fingerprint_sha256(),
        camera: "sim".into(),
    };
    let mut map = map_from_truth(&machine, id);
    if !map_told {
        map.tool_offset_mm = [0.0, 0.0];
    }
    (job, machine, MapModel::new(map))
}

#[test]
fn a_sender_leaving_mid_stream_gets_a_feed_hold_and_an_account_of_its_lines() {
    let (job, machine, model) = demo_machine();
    let link = std::env::temp_dir().join(format!("proxy-leave-{}", std::process::id()));
    let rt = runtime();
    rt.block_on(async {
        // Real time: each 180 mm move at 600 mm/min takes 18 s.
        let (emulator, _rig) = spawn_grbl_emulator(&job, &machine, Clock::Scaled(1.0)).unwrap();
        let (mut controller, _) =
            open_controller(emulator.path(), 115_200, Duration::from_secs(10))
                .await
                .unwrap();
        let mut sender_port = SenderPort::create(Some(&link)).unwrap();
        let rewriter = Rewriter::new(&model, Options::default()).unwrap();
        let mut proxy = Proxy::new(rewriter, &model);
        proxy.start();
        let mut sender = RawSender::open(&link);
        let session = serve(
            &mut proxy,
            &mut sender_port,
            &mut controller,
            std::future::pending(),
        );
        let client = async {
            sender.send("$X\n").await;
            sender.until_answers(1).await;
            let program = slow_program();
            sender.send(&program).await;
            // `$X`, the modes and the rapid answered; the first 180 mm move (pieces of
            // about a millimetre, answered only when its last piece is planned) still
            // running: leave.
            sender.until_answers(3).await;
            drop(sender);
        };
        let (ending, ()) = tokio::join!(session, client);
        let Ending::SenderLeft(account) = ending else {
            panic!("{ending:?}")
        };
        let total = 1 + slow_program().lines().count();
        let seen = account.acknowledged.len()
            + account.in_controller.len()
            + account.not_sent.len()
            + account.refused.len();
        assert_eq!(seen, total, "every line accounted for: {account:?}");
        assert!(account.acknowledged.starts_with(&[1, 2, 3]), "{account:?}");
        assert!(
            !account.in_controller.is_empty() || !account.not_sent.is_empty(),
            "{account:?}"
        );
        // The controller was told to hold: its status says so.
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        controller.write_all(b"?").await.unwrap();
        let mut got = String::new();
        let mut buf = [0u8; 512];
        while !got.contains('>') {
            let k = controller.read(&mut buf).await.unwrap();
            got.push_str(&String::from_utf8_lossy(&buf[..k]));
        }
        assert!(got.contains("<Hold"), "{got}");
    });
}

#[test]
fn a_lost_controller_alarms_the_sender_and_nothing_is_resent() {
    let (job, machine, model) = demo_machine();
    let link = std::env::temp_dir().join(format!("proxy-lost-{}", std::process::id()));
    let rt = runtime();
    rt.block_on(async {
        let (emulator, _rig) = spawn_grbl_emulator(&job, &machine, Clock::Scaled(1.0)).unwrap();
        let (mut controller, _) =
            open_controller(emulator.path(), 115_200, Duration::from_secs(10))
                .await
                .unwrap();
        let mut sender_port = SenderPort::create(Some(&link)).unwrap();
        let rewriter = Rewriter::new(&model, Options::default()).unwrap();
        let mut proxy = Proxy::new(rewriter, &model);
        proxy.start();
        let mut sender = RawSender::open(&link);
        let session = serve(
            &mut proxy,
            &mut sender_port,
            &mut controller,
            std::future::pending(),
        );
        let client = async {
            sender.send("$X\n").await;
            sender.until_answers(1).await;
            sender.send(&slow_program()).await;
            sender.until_answers(3).await;
            // The controller's port goes away (a USB cable pulled).
            emulator.hang_up().await;
            sender.until_answers(usize::MAX).await;
            sender
        };
        let (ending, sender) = tokio::join!(session, client);
        let Ending::ControllerLost { lines, .. } = ending else {
            panic!("{ending:?}")
        };
        assert!(
            sender.got.contains("[MSG:gateway: controller lost"),
            "{}",
            sender.got
        );
        assert!(sender.got.contains("ALARM:3"), "{}", sender.got);
        assert!(lines.acknowledged.starts_with(&[1, 2, 3]), "{lines:?}");
        assert!(
            !lines.in_controller.is_empty() || !lines.not_sent.is_empty(),
            "{lines:?}"
        );
    });
}

/// The peak resident memory of this process, KiB (`VmHWM`).
fn peak_kib() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .unwrap()
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .unwrap()
}

#[test]
fn a_hostile_sender_cannot_make_the_gateway_hold_or_echo_a_50_mib_line_and_its_leaving_ends_the_session(
) {
    let (job, machine, model) = demo_machine();
    let link = std::env::temp_dir().join(format!("proxy-huge-{}", std::process::id()));
    let rt = runtime();
    let before = peak_kib();
    rt.block_on(async {
        let (emulator, _rig) = spawn_grbl_emulator(&job, &machine, Clock::Unconstrained).unwrap();
        let (mut controller, _) =
            open_controller(emulator.path(), 115_200, Duration::from_secs(10))
                .await
                .unwrap();
        let mut sender_port = SenderPort::create(Some(&link)).unwrap();
        let rewriter = Rewriter::new(&model, Options::default()).unwrap();
        let mut proxy = Proxy::new(rewriter, &model);
        proxy.start();
        let mut sender = RawSender::open(&link);
        let session = serve(
            &mut proxy,
            &mut sender_port,
            &mut controller,
            std::future::pending(),
        );
        let client = async {
            // 50 MiB of one line, written in 1 MiB pieces (never held whole here either).
            let piece = "G1X1".repeat(1 << 18);
            for _ in 0..50 {
                sender.send(&piece).await;
            }
            sender.send("\n$I\n").await;
            sender.until_answers(2).await;
            // It leaves: the session ends (`--once` exits).
            sender.got
        };
        let (ending, got) = tokio::join!(session, client);
        assert!(matches!(ending, Ending::SenderLeft(_)), "{ending:?}");
        // GRBL's answer to an overlong line, error:11, with the gateway's note; no echo.
        assert!(got.len() < 1024, "{} bytes back", got.len());
        let answers: Vec<&str> = got
            .lines()
            .filter(|l| *l == "ok" || l.starts_with("error:"))
            .collect();
        assert_eq!(answers, ["error:11", "ok"], "{got}");
        assert!(got.contains("longer than GRBL's line buffer"), "{got}");
        assert!(got.contains("[VER:"), "the next line went through: {got}");
    });
    let grown_mib = (peak_kib().saturating_sub(before)) as f64 / 1024.0;
    println!("50 MiB line: peak memory grew by {grown_mib:.1} MiB");
}

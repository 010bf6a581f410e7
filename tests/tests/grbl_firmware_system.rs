//! The real controller firmware as the controller (GRBL 1.1h with grbl-sim, grblHAL
//! with its simulator; `system_tests::firmware`): the driver connecting to a first
//! power-up (the firmware starts when the port is opened, as an Arduino resets on DTR,
//! and prints `error:7`, its settings dump and its banner), the rotary job's link on
//! the six-axis grblHAL, the pass-through streaming a program to real GRBL, and
//! `layout cut` on three real GRBL 1.1h controllers (conveyor and two heads), checked
//! against the firmwares' own logs of every block they planned (`-b`).
//!
//! A firmware or socat that is missing fails the test naming the install step
//! (`tests/install-peers.sh`); nothing is skipped. The firmwares run in real time:
//! programs are short, and every wait is for the controller's replies (bounded only so
//! that a broken test ends).

use drivers::grbl::{GrblOptions, GrblStage};
use drivers::open_grbl_line as open_controller;
use drivers::{Axis, AxisValues, Stage, StageState};
use protocol::grbl::command::Command;
use protocol::grbl::response::Response;
use proxy::{serve, Ending, Proxy, SenderPort};
use rewrite::{Approach, Compensation, Options, Pose, Rewriter, N_AXIS};
use std::time::Duration;
use system_tests::firmware::{Firmware, RunningFirmware, INSTALL_STEP};
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};

/// Start `fw` in a fresh working directory (a first power-up); a missing peer fails
/// the test naming the install step.
fn start(fw: Firmware) -> RunningFirmware {
    fw.start().unwrap_or_else(|e| {
        assert!(e.contains("install-peers"), "{e} ({INSTALL_STEP})");
        panic!("{e}")
    })
}

/// GRBL 1.1h's default steps per mm on every axis ($100-$102 after a first power-up).
const STEPS_PER_MM: f64 = 250.0;

/// One planned block of the `-b` log: target in steps, feed, condition.
#[derive(Debug, Clone, PartialEq)]
struct Block {
    steps: [i64; 3],
    feed: f64,
}

fn blocks(log: &str) -> Vec<Block> {
    log.lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let f: Vec<&str> = l.split(',').map(str::trim).collect();
            assert!(f.len() >= 4, "a block line: {l:?}");
            Block {
                steps: [0, 1, 2].map(|k| f[k].parse().unwrap_or_else(|_| panic!("{l:?}"))),
                feed: f[3].parse().unwrap_or_else(|_| panic!("{l:?}")),
            }
        })
        .collect()
}

/// The driver's defaults with room for a simulated controller on a busy machine (the
/// whole suite runs beside it): it answers late at times, never wrongly.
fn patient() -> GrblOptions {
    GrblOptions {
        command_timeout: Duration::from_secs(15),
        // grbl-sim's first power-up (the EEPROM written, the settings dump, the banner)
        // took over 5 s with the cores busy
        connect_timeout: Duration::from_secs(20),
        ..GrblOptions::default()
    }
}

#[test]
fn the_driver_connects_to_grbl_11h_at_its_first_power_up_and_moves_as_planned() {
    let fw = start(Firmware::Grbl11h);
    let rt = system_tests::runtime();
    rt.block_on(async {
        // Opening the port powers the firmware up: `error:7`, the settings dump and the
        // banner come first; the `$I` of a driver that did not wait would be lost.
        let mut g = GrblStage::open(&fw.path(), 115_200, patient())
            .await
            .unwrap_or_else(|e| panic!("connects to a first power-up: {e}"));
        assert!(
            g.build_info().version.starts_with("1.1h"),
            "{:?}",
            g.build_info()
        );
        assert_eq!(g.build_info().rx_buffer, 128);
        assert_eq!(g.axis_count(), 3);
        let x = g.info().axis(Axis::X).unwrap().clone();
        assert_eq!(x.resolution_mm, 1.0 / STEPS_PER_MM);
        // No homing on a first power-up ($22=0): idle, one travel either way.
        assert_eq!((x.min_mm, x.max_mm), (-200.0, 200.0));
        assert_eq!(g.status().await.unwrap().state, StageState::Idle);
        g.move_to(AxisValues::xy(5.0, 3.0), 1000.0).await.unwrap();
        g.wait_idle().await.unwrap();
        let p = g.position().await.unwrap();
        assert_eq!((p.get(Axis::X), p.get(Axis::Y)), (Some(5.0), Some(3.0)));
    });
    let planned = blocks(&fw.blocks());
    assert_eq!(
        planned,
        [Block {
            steps: [1250, 750, 0],
            feed: 1000.0
        }],
        "the firmware planned exactly the move"
    );
}

#[test]
fn the_rotary_jobs_link_on_six_axis_grblhal_at_its_first_power_up() {
    let rt = system_tests::runtime();
    // Through the job, as `gateway rotary` opens it.
    let fw = start(Firmware::GrblHal6);
    rt.block_on(async {
        let job = job::rotary::RotaryJob {
            link: Some(job::rotary::RotaryLink::Grbl(job::rotary::GrblPort {
                port: fw.path(),
                baud: 115_200,
                poll_ms: None,
            })),
            ..job::rotary::RotaryJob::default()
        };
        match devices::open_rotary(&job).await {
            Ok(devices::RotaryTable::Linked(t)) => {
                assert!(t.prober.name().contains("1.1f"), "{}", t.prober.name())
            }
            Ok(_) => panic!("not the linked table"),
            Err(e) => panic!("the rotary link to grblHAL at its first power-up: {e}"),
        }
    });
    drop(fw);
    // The link itself: axes, `$#`, status.
    let fw = start(Firmware::GrblHal6);
    rt.block_on(async {
        let mut g = GrblStage::open(&fw.path(), 115_200, patient())
            .await
            .unwrap_or_else(|e| panic!("connects to a first power-up: {e}"));
        assert!(
            g.build_info().version.starts_with("1.1f"),
            "{:?}",
            g.build_info()
        );
        assert_eq!(g.axis_count(), 6);
        let axes: Vec<Axis> = g.info().axes.iter().map(|a| a.axis).collect();
        assert_eq!(axes, [Axis::X, Axis::Y, Axis::Z, Axis::A, Axis::B, Axis::C]);
        assert_eq!(
            g.capabilities().rotary_axes,
            drivers::Capabilities::rotary_among(axes.iter().copied())
        );
        let answer = g.command(&Command::ViewParameters).await.unwrap();
        let names: Vec<String> = answer
            .iter()
            .map(|r| match r {
                Response::Parameter { name, .. } => name.clone(),
                Response::Other(l) => l.trim_start_matches('[').split(':').next().unwrap().into(),
                other => format!("{other:?}"),
            })
            .collect();
        for want in [
            "G54", "G59", "G59.1", "G59.2", "G59.3", "G28", "G30", "G92", "TLO", "PRB",
        ] {
            assert!(names.iter().any(|n| n == want), "{want} in {names:?}");
        }
        let offsets = answer
            .iter()
            .find_map(|r| match r {
                Response::Parameter { name, value } if name == "G54" => Some(value.clone()),
                _ => None,
            })
            .unwrap();
        assert_eq!(offsets.split(',').count(), 6, "{offsets}");
        let s = g.status_report().await.unwrap();
        assert_eq!(s.position.len(), 6, "{s:?}");
        assert_eq!(g.status().await.unwrap().state, StageState::Idle);
        g.move_to(
            AxisValues::default()
                .with(Axis::A, 12.5)
                .with(Axis::C, -30.0),
            1000.0,
        )
        .await
        .unwrap();
        g.wait_idle().await.unwrap();
        let p = g.position().await.unwrap();
        assert_eq!((p.get(Axis::A), p.get(Axis::C)), (Some(12.5), Some(-30.0)));
    });
}

/// The tool lands 10 um short in X and 0.1 % long in Y (as in the proxy's unit tests).
struct Skewed;

impl Compensation for Skewed {
    fn describe(&self) -> String {
        "skewed".into()
    }
    fn axes(&self) -> &[usize] {
        &[0, 1]
    }
    fn command_for(&self, p: &Pose, _: &[Approach; N_AXIS]) -> Result<Pose, String> {
        Ok([p[0] + 0.010, p[1] / 1.001, p[2]])
    }
    fn tool_for(&self, c: &Pose, _: &[Approach; N_AXIS]) -> Result<Pose, String> {
        Ok([c[0] - 0.010, c[1] * 1.001, c[2]])
    }
}

/// A short program (real time: about two seconds of motion at MACHINE_RATES).
const PROGRAM: &str = "G21 G90
G1 F3000
G1 X10 Y0
G1 X10 Y10 (a comment)
G1 X0 Y10
G0 X5 Y5
G1 X20.5 Y7.25 F2400
G1 X20.5 Y0
%
G1 X0 Y0
";

/// What a plain sender got: each line's answer, and everything else it received.
struct Sent {
    answers: Vec<String>,
    other: Vec<String>,
}

/// Line by line, each line's answer before the next; then `?` until idle.
async fn send_program(path: std::path::PathBuf, program: &str) -> Sent {
    use tokio_serial::SerialPortBuilderExt;
    let port = tokio_serial::new(path.to_string_lossy(), 115_200)
        .open_native_async()
        .expect("open the gateway's port");
    let (read, mut write) = tokio::io::split(port);
    let mut lines = BufReader::new(read).lines();
    let mut sent = Sent {
        answers: Vec::new(),
        other: Vec::new(),
    };
    for line in program.lines() {
        write
            .write_all(format!("{line}\n").as_bytes())
            .await
            .unwrap();
        loop {
            let got = tokio::time::timeout(Duration::from_secs(60), lines.next_line())
                .await
                .expect("the gateway answers")
                .expect("read")
                .expect("a line");
            let got = got.trim().to_string();
            if got == "ok" || got.starts_with("error:") {
                sent.answers.push(got);
                break;
            }
            sent.other.push(got);
        }
    }
    // Status reports, asked for, until the program has run: the one kind of line that
    // is not an answer it may get; only the last is kept.
    loop {
        write.write_all(b"?").await.unwrap();
        let got = tokio::time::timeout(Duration::from_secs(60), lines.next_line())
            .await
            .expect("a status report")
            .unwrap()
            .unwrap();
        let idle = got.starts_with("<Idle");
        if !got.starts_with('<') || idle {
            sent.other.push(got.trim().to_string());
        }
        if idle {
            break;
        }
    }
    sent
}

/// Rates and accelerations of a machine instead of a first power-up's 500 mm/min and
/// 10 mm/s^2 ($110-$112, $120-$122): the firmware runs in real time, and the defaults
/// (capping F3000 at 500 mm/min) made PROGRAM 12 s of motion. The blocks GRBL plans,
/// which the test checks, are the same at any rate.
const MACHINE_RATES: &[(u32, f64)] = &[
    (110, 20_000.0),
    (111, 20_000.0),
    (112, 20_000.0),
    (120, 2_000.0),
    (121, 2_000.0),
    (122, 2_000.0),
];

/// The pass-through between a plain sender and `fw` (first power-up, then `settings`
/// sent on the controller's line before the session), with the Skewed compensation:
/// what the sender got and the session's end.
fn stream_through_proxy(
    fw: &RunningFirmware,
    settings: &[(u32, f64)],
    program: &'static str,
) -> (Sent, Ending, u64) {
    let rt = system_tests::runtime();
    let link = fw.workdir.join("ttyGATEWAY");
    rt.block_on(async {
        use tokio::io::AsyncReadExt;
        let (mut controller, banner) =
            open_controller(&fw.path(), 115_200, Duration::from_secs(10))
                .await
                .expect("the controller's port");
        assert!(banner.contains("error:7"), "a first power-up: {banner}");
        for (n, v) in settings {
            controller
                .write_all(format!("${n}={v}\n").as_bytes())
                .await
                .unwrap();
            let mut answer = Vec::new();
            let mut buf = [0u8; 64];
            while !answer.ends_with(b"ok\r\n") {
                let k = tokio::time::timeout(Duration::from_secs(60), controller.read(&mut buf))
                    .await
                    .expect("the firmware answers a setting")
                    .unwrap();
                assert!(k > 0, "the firmware's port closed");
                answer.extend_from_slice(&buf[..k]);
                assert!(
                    !String::from_utf8_lossy(&answer).contains("error"),
                    "${n}={v}: {}",
                    String::from_utf8_lossy(&answer)
                );
            }
        }
        let comp = Skewed;
        let rewriter = Rewriter::new(&comp, Options::default()).unwrap();
        let mut proxy = Proxy::new(rewriter, &comp);
        proxy.start();
        let mut sender_port = SenderPort::create(Some(&link)).unwrap();
        let client = send_program(link.clone(), program);
        let session = serve(
            &mut proxy,
            &mut sender_port,
            &mut controller,
            std::future::pending(),
        );
        let (ending, sent) = tokio::join!(session, client);
        (sent, ending, proxy.stats().pieces_sent)
    })
}

#[test]
fn the_pass_through_streams_to_real_grbl_and_the_firmware_plans_the_compensated_program() {
    let fw = start(Firmware::Grbl11h);
    let (sent, ending, pieces) = stream_through_proxy(&fw, MACHINE_RATES, PROGRAM);
    assert!(matches!(ending, Ending::SenderLeft(_)), "{ending:?}");
    // Every line answered as GRBL would: `%` is GRBL 1.1h's error:1; the rest ok.
    let expected: Vec<&str> = PROGRAM
        .lines()
        .map(|l| if l == "%" { "error:1" } else { "ok" })
        .collect();
    assert_eq!(sent.answers, expected);
    // Nothing the sender did not ask for: no boot lines, none of the gateway's `$#`
    // and `$G` answers; only the gateway's note on `%` and the status report asked for.
    let (notes, rest): (Vec<&String>, Vec<&String>) = sent
        .other
        .iter()
        .partition(|l| l.starts_with("[MSG:gateway:"));
    assert_eq!(notes.len(), 1, "{:?}", sent.other);
    assert_eq!(rest.len(), 1, "{:?}", sent.other);
    assert!(rest[0].starts_with("<Idle|"), "{:?}", rest);
    // The firmware's own log: every block the program's compensated target, in order.
    let planned = blocks(&fw.blocks());
    let mut nominal = Vec::new();
    let mut at = [0.0f64; 2];
    for l in PROGRAM.lines() {
        let mut moved = false;
        for w in l.split_whitespace() {
            if let Some(v) = w.strip_prefix('X') {
                at[0] = v.parse().unwrap();
                moved = true;
            }
            if let Some(v) = w.strip_prefix('Y') {
                at[1] = v.parse().unwrap();
                moved = true;
            }
        }
        if moved {
            nominal.push(at);
        }
    }
    let steps = |p: [f64; 2]| {
        let c = Skewed
            .command_for(&[p[0], p[1], 0.0], &[Approach::Forward; N_AXIS])
            .unwrap();
        [
            (c[0] * STEPS_PER_MM).round() as i64,
            (c[1] * STEPS_PER_MM).round() as i64,
            0,
        ]
    };
    // Each program target is where a block ends, in the program's order; every block
    // lies on the compensated path (a straight line's pieces stay on it).
    let mut k = 0;
    for p in &nominal {
        let want = steps(*p);
        while k < planned.len() && planned[k].steps != want {
            k += 1;
        }
        assert!(
            k < planned.len(),
            "no block ends at {p:?} ({want:?}): {planned:?}"
        );
        k += 1;
    }
    assert_eq!(
        planned.last().unwrap().steps,
        steps(*nominal.last().unwrap()),
        "the last block is the program's end"
    );
    assert!(planned.iter().all(|b| b.steps[2] == 0), "{planned:?}");
    // Every block on the compensated path (an affine compensation keeps the program's
    // straight lines straight): within a step of the polyline through the targets.
    let mut path = vec![[3i64, 0, 0]];
    path.extend(nominal.iter().map(|p| steps(*p)));
    let off_path = |b: &Block| {
        path.windows(2)
            .map(|w| {
                let (a, c) = (w[0].map(|v| v as f64), w[1].map(|v| v as f64));
                let q = b.steps.map(|v| v as f64);
                let d = [c[0] - a[0], c[1] - a[1]];
                let len2 = d[0] * d[0] + d[1] * d[1];
                let t = if len2 == 0.0 {
                    0.0
                } else {
                    (((q[0] - a[0]) * d[0] + (q[1] - a[1]) * d[1]) / len2).clamp(0.0, 1.0)
                };
                ((q[0] - a[0] - t * d[0]).powi(2) + (q[1] - a[1] - t * d[1]).powi(2)).sqrt()
            })
            .fold(f64::INFINITY, f64::min)
    };
    for b in &planned {
        assert!(off_path(b) <= 1.0, "{b:?} off the compensated path");
    }
    assert!(
        pieces >= planned.len() as u64,
        "{pieces} pieces, {planned:?}"
    );
    println!(
        "real GRBL 1.1h through the pass-through: {} program lines, {} pieces, {} planned blocks",
        PROGRAM.lines().count(),
        pieces,
        planned.len()
    );
}

#[test]
fn the_pass_through_on_grblhal_passes_none_of_its_own_answers_to_the_sender() {
    let fw = start(Firmware::GrblHal3);
    const SHORT: &str = "G21 G90\nG1 X1 Y1 F1000\n$#\n";
    let (sent, ending, _) = stream_through_proxy(&fw, &[], SHORT);
    assert!(matches!(ending, Ending::SenderLeft(_)), "{ending:?}");
    assert_eq!(sent.answers, ["ok", "ok", "ok"]);
    // The sender's own `$#`: every line of it (G59.1-G59.3 included); the gateway's
    // `$#` at start: none.
    let g59_1 = sent
        .other
        .iter()
        .filter(|l| l.starts_with("[G59.1:"))
        .count();
    assert_eq!(g59_1, 1, "{:?}", sent.other);
    let g54 = sent.other.iter().filter(|l| l.starts_with("[G54:")).count();
    assert_eq!(g54, 1, "{:?}", sent.other);
    assert!(
        sent.other.last().unwrap().starts_with("<Idle|"),
        "{:?}",
        sent.other
    );
}

/// GRBL 1.1h to cut with: fresh (a first power-up), connected by the driver, set for a
/// cutter (rates and acceleration of a cutting table instead of the defaults' 500
/// mm/min and 10 mm/s^2, 400 mm of travel, and a junction deviation that lets the knife
/// round a contour's many corners at speed: at the default 0.01 mm and 2 000 mm/s^2 a
/// right angle slowed it to 7 mm/s, and three firmwares in real time took a minute).
/// The blocks GRBL plans, which the test checks, are the same at any rate.
async fn cutter_controller(fw: &RunningFirmware) -> GrblStage {
    let opts = GrblOptions {
        poll_interval: Duration::from_millis(5),
        // Three simulated controllers on a busy machine answer late at times.
        command_timeout: Duration::from_secs(10),
        ..GrblOptions::default()
    };
    let mut g = GrblStage::open(&fw.path(), 115_200, opts)
        .await
        .unwrap_or_else(|e| panic!("connects to a first power-up: {e}"));
    for (n, v) in [
        (110, 20_000.0),
        (111, 20_000.0),
        (112, 20_000.0),
        (11, 0.1),
        (120, 10_000.0),
        (121, 10_000.0),
        (122, 10_000.0),
        (130, 400.0),
        (131, 400.0),
        (132, 400.0),
    ] {
        g.set_setting(n, v).await.unwrap();
    }
    g
}

/// The blocks GRBL plans for `program` from `start` (absolute mm, one target per line
/// with an axis word): targets in steps, a move of no step planning none.
fn expected_blocks(program: &str, start: &mut [f64; 3], out: &mut Vec<[i64; 3]>) {
    for line in program.lines() {
        let mut moved = false;
        for w in line.split_whitespace() {
            let k = match w.as_bytes()[0] {
                b'X' => 0,
                b'Y' => 1,
                b'Z' => 2,
                _ => continue,
            };
            start[k] = w[1..].parse().unwrap();
            moved = true;
        }
        if moved {
            let steps = start.map(|v| (v * STEPS_PER_MM).round() as i64);
            if out.last().is_none_or(|l| *l != steps) && (!out.is_empty() || steps != [0; 3]) {
                out.push(steps);
            }
        }
    }
}

/// Planned blocks against the expected ones: the same count, each within a step per
/// axis (GRBL computes in 32-bit floats: a target on a half step may round either way).
fn same_blocks(who: &str, planned: &[Block], expected: &[[i64; 3]]) {
    assert_eq!(
        planned.len(),
        expected.len(),
        "{who}: {} blocks planned, {} expected",
        planned.len(),
        expected.len()
    );
    for (k, (b, e)) in planned.iter().zip(expected).enumerate() {
        assert!(
            (0..3).all(|a| (b.steps[a] - e[a]).abs() <= 1),
            "{who}: block {k} {b:?}, expected {e:?}"
        );
    }
}

#[test]
fn layout_cut_on_three_real_grbl_controllers_plans_every_stroke_of_the_plan() {
    use layout::cut::{plan, CutSettings, CutterSpec};
    use layout_io::{Format, Layout, ReadOptions};
    let path = system_tests::workspace().join("gateway/layout/data/esicup/trousers.json");
    let doc = Layout::read(
        &std::fs::read(path).expect("the trousers layout"),
        Format::Json,
        &ReadOptions::default(),
    )
    .expect("reads");
    let w = doc.width_mm.expect("the layout's width");
    // The parts within its first 80 mm (19 parts, two stops): the firmware runs in
    // real time (the whole nest takes minutes on three simulated controllers).
    let mut doc = doc;
    doc.parts.retain(|p| p.bounds()[2] < 80.0);
    let params = layout::Params {
        tools: 2,
        window_mm: 0.8 * w,
        gap_mm: w / 80.0,
        width_mm: Some(w),
        clearance_mm: None,
    };
    let mut partition = layout::partition(&doc.parts, &params).unwrap();
    layout::resolve_widening(&doc.parts, &mut partition, &[]).unwrap();
    let cutter = CutterSpec::for_partition(&doc.parts, &partition);
    let stops = plan(&doc.parts, &partition, &cutter).unwrap();
    let settings = CutSettings::default();
    let fresh = || start(Firmware::Grbl11h);
    let conveyor_fw = fresh();
    let head_fws: Vec<RunningFirmware> = (0..cutter.heads.len()).map(|_| fresh()).collect();
    let rt = system_tests::runtime();
    let run = rt.block_on(async {
        let mut conveyor = cutter_controller(&conveyor_fw).await;
        let mut heads: Vec<Box<dyn Stage>> = Vec::new();
        for fw in &head_fws {
            heads.push(Box::new(cutter_controller(fw).await));
        }
        let stream = drivers::StreamOptions {
            status_interval: Duration::from_millis(5),
            ..drivers::StreamOptions::default()
        };
        runner::cutter::run_cut(
            &stops,
            &mut conveyor,
            &mut heads,
            &settings,
            &stream,
            |_, _| {},
        )
        .await
        .unwrap_or_else(|e| panic!("{e}"))
    });
    assert_eq!(run.stops, stops.len());
    // The conveyor: one block per stop that moves it, to the stop.
    let mut at = [0.0; 3];
    let mut expected = Vec::new();
    for s in &stops {
        expected_blocks(&format!("X{:.4}", s.conveyor_mm), &mut at, &mut expected);
    }
    same_blocks("conveyor", &blocks(&conveyor_fw.blocks()), &expected);
    // Each head: its programs at every stop, block for block.
    let mut strokes = 0;
    for (t, fw) in head_fws.iter().enumerate() {
        let mut at = [0.0; 3];
        let mut expected = Vec::new();
        for s in &stops {
            for j in s.jobs.iter().filter(|j| j.tool == t) {
                expected_blocks(&j.program(&settings), &mut at, &mut expected);
            }
        }
        let planned = blocks(&fw.blocks());
        same_blocks(&format!("head {t}"), &planned, &expected);
        // Knife strokes: blocks in the material (Z at the knife's depth) from a point
        // already there.
        let down = (settings.knife_down_mm * STEPS_PER_MM).round() as i64;
        strokes += planned
            .windows(2)
            .filter(|w| w[0].steps[2] == down && w[1].steps[2] == down)
            .count();
    }
    // Every edge of every part: one stroke each (a contour's points close it).
    let edges: usize = doc
        .parts
        .iter()
        .map(|p| p.outer.len() + p.holes.iter().map(Vec::len).sum::<usize>())
        .sum();
    assert_eq!(strokes, edges, "knife strokes against the layout's edges");
    let groups: usize = run.heads.iter().map(|h| h.groups).sum();
    println!(
        "trousers on real GRBL 1.1h: {} parts, {} groups, {} stops, {strokes} knife strokes planned",
        doc.parts.len(),
        groups,
        run.stops
    );
}

/// The `Pn:` field of a status report (empty when there is none).
fn pins(status: &str) -> &str {
    status
        .trim_end()
        .trim_end_matches('>')
        .split('|')
        .find_map(|f| f.strip_prefix("Pn:"))
        .unwrap_or("")
}

/// Sends `line` and returns everything up to its answer (`ok`, `error:N` or `ALARM:N`).
fn answer(c: &mut system_tests::firmware::TtyClient, line: &str) -> String {
    c.send(format!("{line}\n").as_bytes());
    c.read_through_line(Duration::from_secs(120), |l| {
        l == "ok" || l.starts_with("error:") || l.starts_with("ALARM:")
    })
    .unwrap_or_else(|e| panic!("{line}: {e}"))
}

/// A status report (`?`), once the controller has answered it.
fn status(c: &mut system_tests::firmware::TtyClient) -> String {
    c.send(b"?");
    c.read_through_line(Duration::from_secs(30), |l| l.starts_with('<'))
        .unwrap_or_else(|e| panic!("`?`: {e}"))
        .lines()
        .rfind(|l| l.starts_with('<'))
        .unwrap()
        .to_string()
}

#[test]
fn grbl_11h_powers_up_locked_with_homing_on_and_homes_to_the_harness_switches() {
    let mut fw = start(Firmware::Grbl11h);
    let mut c = fw.open().unwrap_or_else(|e| panic!("{e}"));
    c.read_through_line(Duration::from_secs(60), |l| l.starts_with("Grbl 1.1h"))
        .unwrap();
    // A first power-up ($22=0): idle, and no limit switch pressed (the carriages start
    // 1250 steps short of them).
    let s = status(&mut c);
    assert!(s.starts_with("<Idle|MPos:0.000,0.000,0.000|"), "{s}");
    assert!(!pins(&s).contains(['X', 'Y', 'Z']), "{s}");
    // Homing without `$22=1` is refused.
    assert_eq!(answer(&mut c, "$H"), "error:5\r\n");
    // Homing on, and quick: locate at 200 mm/min, seek at 1000, 10 ms debounce, and
    // 100 mm/s² (the simulator runs slower than real time on a busy machine).
    for setting in [
        "$22=1", "$24=200", "$25=1000", "$26=10", "$120=100", "$121=100", "$122=100",
    ] {
        assert_eq!(answer(&mut c, setting), "ok\r\n", "{setting}");
    }
    drop(c);
    let dir = fw.keep_workdir();
    drop(fw);

    // The next power-up with homing on: GRBL 1.1h (HOMING_INIT_LOCK) starts in Alarm
    // and locks out motion until `$H` (or `$X`).
    let fw = Firmware::Grbl11h
        .start_in(&dir)
        .unwrap_or_else(|e| panic!("{e}"));
    let mut c = fw.open().unwrap();
    let boot = c
        .read_through_line(Duration::from_secs(60), |l| {
            l == "[MSG:'$H'|'$X' to unlock]"
        })
        .unwrap();
    assert!(
        boot.ends_with("Grbl 1.1h ['$' for help]\r\n[MSG:'$H'|'$X' to unlock]\r\n")
            && !boot.contains("error:7"),
        "a second power-up with a valid EEPROM: {boot:?}"
    );
    let s = status(&mut c);
    assert!(s.starts_with("<Alarm|MPos:0.000,0.000,0.000|"), "{s}");
    assert_eq!(answer(&mut c, "G0 X1"), "error:9\r\n");
    // `$H`: Z, then X and Y, seek the switches in the positive direction ($23=0),
    // locate them at $24, pull off $27 (1 mm) and set the machine position there.
    assert_eq!(answer(&mut c, "$H"), "ok\r\n");
    let s = status(&mut c);
    assert!(s.starts_with("<Idle|MPos:-1.000,-1.000,-1.000|"), "{s}");
    assert!(
        !pins(&s).contains(['X', 'Y', 'Z']),
        "pulled off every switch: {s}"
    );
    // The switches are 1 mm beyond: X at machine zero presses X's switch, only it.
    for line in ["G0 X0 Y-0.5", "G4 P0"] {
        assert_eq!(answer(&mut c, line), "ok\r\n", "{line}");
    }
    let s = status(&mut c);
    assert!(s.starts_with("<Idle|MPos:0.000,-0.500,-1.000|"), "{s}");
    assert!(
        pins(&s).contains('X') && !pins(&s).contains(['Y', 'Z']),
        "{s}"
    );
    for line in ["G0 X-0.5", "G4 P0"] {
        assert_eq!(answer(&mut c, line), "ok\r\n", "{line}");
    }
    let s = status(&mut c);
    assert!(
        !pins(&s).contains(['X', 'Y', 'Z']),
        "off the switch again: {s}"
    );
    // The firmware's own record of the homing: each cycle's first block seeks
    // +1.5 x max travel ($130-$132 = 200 mm) on its axes, Z first.
    let planned = blocks(&fw.blocks());
    assert_eq!(
        planned.first().map(|b| (b.steps[2], b.feed)),
        Some((75_000, 1000.0)),
        "{planned:?}"
    );
    drop(c);
    drop(fw);
    let _ = std::fs::remove_dir_all(dir);
}

//! DNC drip-feed over a pseudo-terminal: the drip-feed driver (`drivers::dnc`) against
//! the closed-controller emulator (`emulators dnc`), flow control real (the emulator
//! executes at a scaled machine pace, so its buffer fills and it sends DC3/DC1).
//! Nothing here waits on wall time: the tests await the emulator's counters.

use drivers::dnc::{DncOptions, DncSender, Flow, Tape};
use emulators::dnc::{checksum_lines, DncConfig, DncDevice, DncPty, DncStats, NAK};
use std::time::Duration;
use system_tests::{reference_rig, runtime_two_workers};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_serial::SerialPortBuilderExt;

/// A safety bound on a whole test (a hung test fails instead of hanging CI); never
/// reached by a passing run.
const BOUND: Duration = Duration::from_secs(600);

/// The controller, its DC3 at 3072 free characters of its 4096 (a Fanuc 0 sends it at
/// 1024): a pseudo-terminal has no wire, and with the cores busy the kernel handed the
/// DC3 to the sender tens of milliseconds after the controller wrote it (a sender paced
/// at 921 600 baud wrote 960 and then about 3000 characters meanwhile, in two runs). A
/// wire delivers it within a character.
fn controller(time_scale: f64) -> DncPty {
    let cfg = DncConfig {
        clock: world::Clock::Scaled(time_scale),
        dc3_free: 3072,
        dc1_free: 3584,
        ..DncConfig::default()
    };
    DncPty::spawn(DncDevice::new(reference_rig(), cfg), None).expect("a pseudo-terminal")
}

/// The drip-feed sender at 230 400 baud (the pseudo-terminal has no line: the sender
/// paces itself at that rate, 23 000 characters a second, so a DC3 the kernel hands
/// over 100 ms late finds it within the controller's room).
fn sender(path: &str) -> DncSender {
    let port = tokio_serial::new(path, BAUD)
        .open_native_async()
        .expect("the emulator's port opens");
    DncSender::from_stream(
        port,
        format!("tape port {path}"),
        BAUD,
        DncOptions::default(),
    )
}

const BAUD: u32 = 230_400;

/// `n` short moves back and forth (2 um: 4 counts of the C5 stage) after a rapid to
/// (10, 10), then M30.
fn shuttle_program(n: usize) -> Vec<String> {
    let mut lines = vec![
        "O1234(SHUTTLE)".to_string(),
        "G90G17G21G54".into(),
        "G00X10.Y10.".into(),
        "G91G01F3000.".into(),
    ];
    for i in 0..n {
        lines.push(if i % 2 == 0 { "X.002" } else { "X-.002" }.into());
    }
    lines.push("G90".into());
    lines.push("M30".into());
    lines
}

fn tape_of(lines: &[String]) -> Tape {
    let mut all = vec!["%".to_string()];
    all.extend(lines.iter().cloned());
    all.push("%".into());
    Tape { lines: all }
}

async fn finished(pty: &mut DncPty, tapes: u64) -> DncStats {
    tokio::time::timeout(
        BOUND,
        pty.wait_for(|s| (s.tapes >= tapes && !s.busy) || !s.alarms.is_empty()),
    )
    .await
    .expect("the controller ends the tape (or alarms) within the bound")
}

#[test]
fn a_100000_block_program_is_drip_fed_with_every_dc1_dc3_honoured() {
    runtime_two_workers().block_on(async {
        // Machine time ~320 s of 2-um moves (3.2 ms each) at 8x: 40 s, slower than
        // the line (600 kB in 26 s), so the buffer fills and flow control works.
        let mut pty = controller(8.0);
        let mut tx = sender(pty.path());
        let program = shuttle_program(100_000);
        let tape = tape_of(&program);
        let mut reported = 0;
        let sent_or = tokio::time::timeout(
            BOUND,
            tx.send_tape(&tape, &mut |p| {
                assert_eq!(p.sent, reported + 1, "progress comes once per block");
                reported = p.sent;
                Flow::Continue
            }),
        )
        .await
        .expect("the tape goes out within the bound");
        let sent = match sent_or {
            Ok(s) => s,
            Err(e) => {
                let s = finished(&mut pty, 1).await;
                panic!("{e}; the controller: {:?}", s.alarms)
            }
        };
        assert_eq!(sent.sent, tape.lines.len());
        let s = finished(&mut pty, 1).await;
        assert!(s.alarms.is_empty(), "alarms: {:?}", s.alarms);
        // Nothing lost: every line arrived, in order, and ran.
        assert_eq!(s.lines, program.len() as u64);
        assert_eq!(
            s.checksum,
            checksum_lines(program.iter().map(String::as_str))
        );
        assert_eq!(s.blocks, program.len() as u64);
        assert_eq!(s.position, [10.0, 10.0, 0.0]);
        // The flow control ran for real: the buffer filled and was paused many times,
        // the sender paused as often, and what it wrote after a DC3 fitted in the
        // buffer's room with the line's characters on their way.
        assert!(s.dc3_sent > 10, "DC3 sent {} times", s.dc3_sent);
        assert!(s.dc1_sent > 10, "DC1 sent {} times", s.dc1_sent);
        assert!(sent.pauses > 10, "the sender paused {} times", sent.pauses);
        assert!(
            s.max_after_dc3 < DncConfig::default().dc3_free as u64,
            "{} characters after a DC3",
            s.max_after_dc3
        );
        assert!(s.max_fill <= DncConfig::default().buffer);
    });
}

#[test]
fn a_sender_that_ignores_dc3_makes_the_controller_alarm() {
    runtime_two_workers().block_on(async {
        let mut pty = controller(1.0);
        let mut port = tokio_serial::new(pty.path(), 9600)
            .open_native_async()
            .expect("the emulator's port opens");
        let mut text = String::from("%\n");
        for l in shuttle_program(5_000) {
            text.push_str(&l);
            text.push('\n');
        }
        text.push_str("%\n");
        // Written without ever looking at what the controller says.
        let writer = tokio::spawn(async move {
            for chunk in text.as_bytes().chunks(64) {
                if port.write_all(chunk).await.is_err() {
                    break;
                }
            }
            port
        });
        let s = finished(&mut pty, 1).await;
        assert_eq!(s.tapes, 0, "the tape must not run to its end");
        assert!(
            s.alarms.iter().any(|a| a.contains("overrun")),
            "alarms: {:?}",
            s.alarms
        );
        let mut port = writer.await.expect("the writer ends");
        // The controller said so on the line: NAK after its DC3.
        let mut seen = Vec::new();
        let mut buf = [0u8; 256];
        while !seen.contains(&NAK) {
            let n = tokio::time::timeout(BOUND, port.read(&mut buf))
                .await
                .expect("the NAK arrives")
                .expect("the port reads");
            seen.extend_from_slice(&buf[..n]);
        }
    });
}

#[test]
fn an_alarm_stops_the_driver_naming_the_operators_steps_and_a_reset_is_reported() {
    runtime_two_workers().block_on(async {
        let mut pty = controller(1.0);
        let mut tx = sender(pty.path());
        // A block the controller refuses early in a long tape: the sender is paused by
        // DC3 when the alarm's NAK comes.
        let mut program = shuttle_program(5_000);
        program.insert(5, "G41X1.".into());
        let e = tokio::time::timeout(
            BOUND,
            tx.send_tape(&tape_of(&program), &mut |_| Flow::Continue),
        )
        .await
        .expect("the sender ends within the bound")
        .expect_err("the alarm stops the tape");
        let text = e.to_string();
        assert!(text.contains("NAK") && text.contains("RESET"), "{text}");
        let s = pty.stats();
        assert!(s.alarms.iter().any(|a| a.contains("G41")), "{:?}", s.alarms);
        // The operator resets and the (automatic) cycle start lets a new tape through.
        pty.reset();
        let short = shuttle_program(10);
        tokio::time::timeout(
            BOUND,
            tx.send_tape(&tape_of(&short), &mut |_| Flow::Continue),
        )
        .await
        .expect("the sender ends within the bound")
        .expect("after reset and cycle start a tape goes through");
        let s = tokio::time::timeout(
            BOUND,
            pty.wait_for(|s| (s.tapes >= 1 && !s.busy) || s.alarms.len() > 1),
        )
        .await
        .expect("the second tape ends within the bound");
        assert_eq!(s.resets, 1);
        assert_eq!(s.tapes, 1, "{:?}", s.alarms);
    });
}

#[test]
fn the_stage_says_it_has_no_position_and_sends_moves_as_tapes() {
    runtime_two_workers().block_on(async {
        use drivers::Stage;
        let mut pty = controller(1000.0);
        let tx = sender(pty.path());
        let axes = vec![
            drivers::dnc::DncAxis {
                axis: drivers::Axis::X,
                min_mm: 0.0,
                max_mm: 200.0,
                max_feed_mm_min: 6000.0,
            },
            drivers::dnc::DncAxis {
                axis: drivers::Axis::Y,
                min_mm: 0.0,
                max_mm: 150.0,
                max_feed_mm_min: 6000.0,
            },
        ];
        let mut stage = drivers::dnc::DncStage::new(tx, pty.path(), axes);
        let caps = stage.capabilities();
        assert!(caps.tape_only && caps.program_streaming);
        let e = stage.position().await.unwrap_err().to_string();
        assert!(e.contains("no position") && e.contains("tape_only"), "{e}");
        let e = stage.home().await.unwrap_err().to_string();
        assert!(
            e.contains("reference return") && e.contains("CYCLE START"),
            "{e}"
        );
        stage
            .move_to(drivers::AxisValues::xy(12.5, 7.25), 3000.0)
            .await
            .expect("the move's tape goes out");
        let s = finished(&mut pty, 1).await;
        assert_eq!(s.position, [12.5, 7.25, 0.0], "{:?}", s.alarms);
        assert!(stage
            .move_to(drivers::AxisValues::xy(250.0, 7.0), 3000.0)
            .await
            .is_err());
    });
}

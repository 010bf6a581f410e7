//! The driver against a scripted stock GRBL 1.1h (no emulator): the exact lines a stock
//! build prints, negative machine space (no force-origin option), WPos reports ($10=0)
//! with the work offset only in some reports.

use super::*;
use tokio::io::{AsyncWriteExt, BufReader};

const SETTINGS: &str = "$0=10\r\n$1=25\r\n$2=0\r\n$3=0\r\n$4=0\r\n$5=0\r\n$6=0\r\n$10=0\r\n$11=0.010\r\n$12=0.002\r\n$13=0\r\n$20=0\r\n$21=0\r\n$22=1\r\n$23=0\r\n$24=25.000\r\n$25=500.000\r\n$26=250\r\n$27=1.000\r\n$30=1000\r\n$31=0\r\n$32=0\r\n$100=250.000\r\n$101=250.000\r\n$102=250.000\r\n$110=500.000\r\n$111=500.000\r\n$112=500.000\r\n$120=10.000\r\n$121=10.000\r\n$122=10.000\r\n$130=200.000\r\n$131=200.000\r\n$132=200.000\r\nok\r\n";

/// How the scripted controller starts when the port opens.
#[derive(Clone, Copy, PartialEq)]
enum Boot {
    /// Prints its banner at once (a board that resets on DTR and boots fast).
    Banner,
    /// Running already, says nothing: answers `?` (a board that does not reset).
    Running,
    /// A first power-up (an Arduino booting after DTR: its boot loader then GRBL with
    /// an empty EEPROM): everything received before its banner is lost; once it has
    /// received its first bytes it prints `error:7`, the settings dump and the banner.
    FirstPowerUp,
    /// grblHAL's first power-up: `error:7`, a blank line, warnings, its own banner.
    GrblHalFirstPowerUp,
    /// Wedged until a soft reset (0x18): then the banner.
    NeedsReset,
}

/// What the scripted controller received: lines, and the real-time bytes apart.
#[derive(Default)]
struct Heard {
    lines: Vec<String>,
    polls: usize,
    resets: usize,
}

const BOOT_GRBL: &str = "error:7\r\n$0=10\r\n$1=25\r\n$2=0\r\n$3=0\r\n$4=0\r\n$5=0\r\n$6=0\r\n$10=1\r\n$11=0.010\r\n$12=0.002\r\n$13=0\r\n$20=0\r\n$21=0\r\n$22=0\r\n$23=0\r\n$24=25.000\r\n$25=500.000\r\n$26=250\r\n$27=1.000\r\n$30=1000\r\n$31=0\r\n$32=0\r\n$100=250.000\r\n$101=250.000\r\n$102=250.000\r\n$110=500.000\r\n$111=500.000\r\n$112=500.000\r\n$120=10.000\r\n$121=10.000\r\n$122=10.000\r\n$130=200.000\r\n$131=200.000\r\n$132=200.000\r\n\r\nGrbl 1.1h ['$' for help]\r\n";
const BOOT_GRBLHAL: &str = "error:7\r\n\r\n[MSG:Warning: Spindle off]\r\nGrblHAL 1.1f ['$' or '$HELP' for help]\r\n[MSG:'$H'|'$X' to unlock]\r\n";

/// A stock GRBL answering by script: every line it receives and every `?`.
async fn fake_grbl(
    io: tokio::io::DuplexStream,
    log: std::sync::Arc<std::sync::Mutex<Vec<String>>>,
) {
    scripted_grbl(io, Boot::Banner, log, Default::default()).await
}

/// The scripted controller, booting as `boot` says.
async fn scripted_grbl(
    io: tokio::io::DuplexStream,
    boot: Boot,
    log: std::sync::Arc<std::sync::Mutex<Vec<String>>>,
    heard: std::sync::Arc<std::sync::Mutex<Heard>>,
) {
    let (r, mut w) = tokio::io::split(io);
    let mut r = BufReader::new(r);
    let mut polls = 0;
    // Until it has booted, what it receives is lost.
    let mut booted = match boot {
        Boot::Banner => {
            w.write_all(b"\r\nGrbl 1.1h ['$' for help]\r\n[MSG:'$H'|'$X' to unlock]\r\n")
                .await
                .unwrap();
            true
        }
        Boot::Running => true,
        _ => false,
    };
    loop {
        let mut buf = Vec::new();
        // Real-time `?` has no line end: read byte-wise up to '\n' or '?'.
        loop {
            let mut b = [0u8; 1];
            if tokio::io::AsyncReadExt::read(&mut r, &mut b)
                .await
                .unwrap_or(0)
                == 0
            {
                return;
            }
            match b[0] {
                b'?' => heard.lock().unwrap().polls += 1,
                0x18 => heard.lock().unwrap().resets += 1,
                _ => {}
            }
            if !booted {
                let text = match (boot, b[0]) {
                    (Boot::FirstPowerUp, _) => BOOT_GRBL,
                    (Boot::GrblHalFirstPowerUp, _) => BOOT_GRBLHAL,
                    (Boot::NeedsReset, 0x18) => "\r\nGrbl 1.1h ['$' for help]\r\n",
                    _ => continue,
                };
                w.write_all(text.as_bytes()).await.unwrap();
                booted = true;
                continue;
            }
            if b[0] == b'?' && buf.is_empty() {
                polls += 1;
                // WCO only in every third report, as GRBL refreshes it.
                let wco = if polls % 3 == 0 {
                    "|WCO:-10.000,-20.000,0.000"
                } else {
                    ""
                };
                let s = format!("<Idle|WPos:-5.000,-7.500,0.000|FS:0,0{wco}>\r\n");
                w.write_all(s.as_bytes()).await.unwrap();
                continue;
            }
            if b[0] == 0x18 {
                w.write_all(b"\r\nGrbl 1.1h ['$' for help]\r\n")
                    .await
                    .unwrap();
                continue;
            }
            if b[0] == b'\n' {
                break;
            }
            buf.push(b[0]);
        }
        let line = String::from_utf8(buf).unwrap();
        log.lock().unwrap().push(line.clone());
        heard.lock().unwrap().lines.push(line.clone());
        let reply = match line.as_str() {
            "$I" => "[VER:1.1h.20190830:]\r\n[OPT:V,15,128]\r\nok\r\n".to_string(),
            "$$" => SETTINGS.to_string(),
            "$H" => "ok\r\n".to_string(),
            "$130=400" => "ok\r\n".to_string(),
            l if l.starts_with("G21G53G1") => "ok\r\n".to_string(),
            _ => "error:20\r\n".to_string(),
        };
        w.write_all(reply.as_bytes()).await.unwrap();
    }
}

/// Connect to a scripted controller booting as `boot`: the stage (or the error) and
/// what the controller received.
async fn connect_to(
    boot: Boot,
    opts: GrblOptions,
) -> (
    Result<GrblStage, DriverError>,
    std::sync::Arc<std::sync::Mutex<Heard>>,
) {
    let (a, b) = tokio::io::duplex(4096);
    let heard = std::sync::Arc::new(std::sync::Mutex::new(Heard::default()));
    tokio::spawn(scripted_grbl(b, boot, Default::default(), heard.clone()));
    let g = GrblStage::connect(Box::new(a), "fake".into(), opts).await;
    (g, heard)
}

#[tokio::test]
async fn a_first_power_up_is_waited_for_and_its_boot_lines_passed_over() {
    let (g, heard) = connect_to(Boot::FirstPowerUp, GrblOptions::default()).await;
    let g = g.expect("connects after the boot");
    assert_eq!(g.build_info().version, "1.1h.20190830");
    assert_eq!(g.info().axis(Axis::X).unwrap().resolution_mm, 0.004);
    let heard = heard.lock().unwrap();
    // Nothing but `?` before the banner: no $I lost in the boot, no reset needed.
    assert_eq!(heard.lines, ["$I", "$$"]);
    assert_eq!(heard.resets, 0);
}

#[tokio::test]
async fn a_grblhal_first_power_up_with_warnings_and_its_own_banner() {
    let (g, heard) = connect_to(Boot::GrblHalFirstPowerUp, GrblOptions::default()).await;
    let g = g.expect("connects after the boot");
    assert_eq!(g.build_info().version, "1.1h.20190830");
    assert_eq!(heard.lock().unwrap().lines, ["$I", "$$"]);
    assert_eq!(heard.lock().unwrap().resets, 0);
}

#[tokio::test]
async fn a_running_controller_that_says_nothing_is_found_by_a_status_query_without_reset() {
    let (g, heard) = connect_to(Boot::Running, GrblOptions::default()).await;
    g.expect("connects");
    let heard = heard.lock().unwrap();
    assert_eq!(heard.resets, 0, "a running controller is not reset");
    assert_eq!(heard.lines, ["$I", "$$"]);
}

#[tokio::test]
async fn a_controller_that_does_not_greet_is_reset_once_then_connects() {
    let (g, heard) = connect_to(Boot::NeedsReset, quick()).await;
    g.expect("connects after the soft reset");
    let heard = heard.lock().unwrap();
    assert_eq!(heard.resets, 1);
    assert!(heard.polls >= 1);
    assert_eq!(heard.lines, ["$I", "$$"]);
}

#[tokio::test]
async fn a_silent_device_is_a_clear_error_within_the_connect_timeout() {
    let (a, b) = tokio::io::duplex(4096);
    let got = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
    let g2 = got.clone();
    // Reads and keeps everything, answers nothing.
    tokio::spawn(async move {
        let mut b = b;
        let mut buf = [0u8; 64];
        while let Ok(n) = tokio::io::AsyncReadExt::read(&mut b, &mut buf).await {
            if n == 0 {
                return;
            }
            g2.lock().unwrap().extend_from_slice(&buf[..n]);
        }
    });
    let e = GrblStage::connect(Box::new(a), "fake".into(), quick())
        .await
        .err()
        .expect("never greets");
    let m = e.to_string();
    assert!(
        matches!(e, DriverError::Timeout { after_ms: 300, .. }),
        "{m}"
    );
    assert!(
        m.contains("no start-up banner") && m.contains("soft reset"),
        "{m}"
    );
    assert!(m.contains("sent nothing"), "{m}");
    let got = got.lock().unwrap().clone();
    // Real-time bytes only (status queries, then one soft reset), and a last `$I`.
    let (realtime, line) = got.split_at(got.len() - 3);
    assert!(realtime.iter().all(|b| *b == b'?' || *b == 0x18), "{got:?}");
    assert_eq!(
        realtime.iter().filter(|b| **b == 0x18).count(),
        1,
        "{got:?}"
    );
    assert_eq!(line, b"$I\n");
}

#[tokio::test]
async fn stock_grbl_negative_space_and_wpos_reports() {
    let (a, b) = tokio::io::duplex(4096);
    let log = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
    tokio::spawn(fake_grbl(b, log.clone()));
    let mut g = GrblStage::connect(Box::new(a), "fake".into(), GrblOptions::default())
        .await
        .unwrap();
    let x = g.info().axis(Axis::X).unwrap().clone();
    assert_eq!((x.min_mm, x.max_mm, x.resolution_mm), (-200.0, 0.0, 0.004));
    assert_eq!(g.status().await.unwrap().state, StageState::Idle);
    // WPos + WCO (seen in a later report) = MPos.
    let p = g.position().await.unwrap();
    assert_eq!((p.get(Axis::X), p.get(Axis::Y)), (Some(-15.0), Some(-27.5)));
    g.home().await.unwrap();
    g.move_to(AxisValues::xy(-12.34567, -1.0), 1500.0)
        .await
        .unwrap();
    assert!(matches!(
        g.move_to(AxisValues::xy(5.0, -1.0), 1500.0).await,
        Err(DriverError::OutOfLimits { .. })
    ));
    let e = g
        .command(&Command::Gcode("G1X1Q1".into()))
        .await
        .unwrap_err();
    assert!(matches!(e, DriverError::Refused { code: 20, .. }), "{e}");
    let log = log.lock().unwrap().clone();
    assert_eq!(
        log,
        ["$I", "$$", "$H", "G21G53G1X-12.3457Y-1F1500", "G1X1Q1"]
    );
}

#[tokio::test]
async fn a_feed_that_is_not_a_positive_number_is_refused_before_anything_is_sent() {
    let (a, b) = tokio::io::duplex(4096);
    let log = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
    tokio::spawn(fake_grbl(b, log.clone()));
    let mut g = GrblStage::connect(Box::new(a), "fake".into(), GrblOptions::default())
        .await
        .unwrap();
    g.home().await.unwrap();
    for feed in [f64::NAN, 0.0, -1.0, f64::INFINITY] {
        let e = g
            .move_to(AxisValues::xy(-12.0, -1.0), feed)
            .await
            .unwrap_err();
        assert!(
            matches!(e, DriverError::Unsupported { .. }) && e.to_string().contains("feed"),
            "{feed}: {e}"
        );
        let e = g
            .move_by(AxisValues::xy(-1.0, 0.0), feed)
            .await
            .unwrap_err();
        assert!(e.to_string().contains("feed"), "{feed}: {e}");
    }
    let log = log.lock().unwrap().clone();
    assert_eq!(log, ["$I", "$$", "$H"]);
}

/// A device that answers every byte it gets with `reply`, forever.
async fn echo_device(io: tokio::io::DuplexStream, reply: &'static [u8]) {
    let (mut r, mut w) = tokio::io::split(io);
    let mut b = [0u8; 64];
    while let Ok(n) = tokio::io::AsyncReadExt::read(&mut r, &mut b).await {
        if n == 0 || w.write_all(reply).await.is_err() {
            return;
        }
    }
}

fn quick() -> GrblOptions {
    GrblOptions {
        connect_timeout: std::time::Duration::from_millis(300),
        ..GrblOptions::default()
    }
}

#[tokio::test]
async fn a_device_that_only_says_ok_is_not_said_to_have_sent_nothing() {
    let (a, b) = tokio::io::duplex(4096);
    tokio::spawn(echo_device(b, b"ok\r\nok\r\nok\r\n"));
    let e = GrblStage::connect(Box::new(a), "fake".into(), quick())
        .await
        .err()
        .expect("not GRBL");
    let m = e.to_string();
    assert!(!m.contains("sent nothing"), "{m}");
    assert!(
        m.contains("answered only `ok` ") && m.contains("never a start-up banner"),
        "{m}"
    );
}

#[tokio::test]
async fn binary_garbage_from_a_device_is_shown_escaped_and_cut() {
    static GARBAGE: [u8; 300] = {
        let mut g = [0u8; 300];
        let mut i = 0;
        while i < 300 {
            g[i] = (i as u8).wrapping_mul(37) | 0x80;
            i += 1;
        }
        g
    };
    let (a, b) = tokio::io::duplex(4096);
    tokio::spawn(echo_device(b, &GARBAGE));
    let e = GrblStage::connect(Box::new(a), "fake".into(), quick())
        .await
        .err()
        .expect("not GRBL");
    let m = e.to_string();
    assert!(m.contains("\\x80\\xA5"), "{m}");
    assert!(m.contains(" bytes)"), "cut with the byte count: {m}");
    assert!(
        m.chars().all(|c| (' '..='~').contains(&c) || c == '…'),
        "only printable characters: {m}"
    );
    assert!(m.len() < 600, "{} characters: {m}", m.len());
}

#[tokio::test]
async fn a_changed_setting_moves_the_limits_with_it() {
    let (g, heard) = connect_to(Boot::Banner, GrblOptions::default()).await;
    let mut g = g.unwrap();
    let x = |g: &GrblStage| {
        let a = g.info().axis(Axis::X).unwrap();
        (a.min_mm, a.max_mm)
    };
    assert_eq!(x(&g), (-200.0, 0.0));
    g.set_setting(130, 400.0).await.unwrap();
    assert_eq!(x(&g), (-400.0, 0.0));
    assert_eq!(g.settings().max_travel_mm(0), Some(400.0));
    // Refused by the controller: nothing changes.
    assert!(g.set_setting(131, 1.0).await.is_err());
    assert_eq!(g.settings().max_travel_mm(1), Some(200.0));
    assert!(g.set_setting(130, f64::NAN).await.is_err());
    assert_eq!(
        heard.lock().unwrap().lines,
        ["$I", "$$", "$130=400", "$131=1"]
    );
}

//! The driver against a scripted stock GRBL 1.1h (no emulator): the exact lines a stock
//! build prints, negative machine space (no force-origin option), WPos reports ($10=0)
//! with the work offset only in some reports.

use super::*;
use tokio::io::{AsyncWriteExt, BufReader};

const SETTINGS: &str = "$0=10\r\n$1=25\r\n$2=0\r\n$3=0\r\n$4=0\r\n$5=0\r\n$6=0\r\n$10=0\r\n$11=0.010\r\n$12=0.002\r\n$13=0\r\n$20=0\r\n$21=0\r\n$22=1\r\n$23=0\r\n$24=25.000\r\n$25=500.000\r\n$26=250\r\n$27=1.000\r\n$30=1000\r\n$31=0\r\n$32=0\r\n$100=250.000\r\n$101=250.000\r\n$102=250.000\r\n$110=500.000\r\n$111=500.000\r\n$112=500.000\r\n$120=10.000\r\n$121=10.000\r\n$122=10.000\r\n$130=200.000\r\n$131=200.000\r\n$132=200.000\r\nok\r\n";

/// A stock GRBL answering by script: every line it receives and every `?`.
async fn fake_grbl(
    io: tokio::io::DuplexStream,
    log: std::sync::Arc<std::sync::Mutex<Vec<String>>>,
) {
    let (r, mut w) = tokio::io::split(io);
    let mut r = BufReader::new(r);
    let mut polls = 0;
    w.write_all(b"\r\nGrbl 1.1h ['$' for help]\r\n[MSG:'$H'|'$X' to unlock]\r\n")
        .await
        .unwrap();
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
            if b[0] == b'\n' {
                break;
            }
            buf.push(b[0]);
        }
        let line = String::from_utf8(buf).unwrap();
        log.lock().unwrap().push(line.clone());
        let reply = match line.as_str() {
            "$I" => "[VER:1.1h.20190830:]\r\n[OPT:V,15,128]\r\nok\r\n".to_string(),
            "$$" => SETTINGS.to_string(),
            "$H" => "ok\r\n".to_string(),
            l if l.starts_with("G21G53G1") => "ok\r\n".to_string(),
            _ => "error:20\r\n".to_string(),
        };
        w.write_all(reply.as_bytes()).await.unwrap();
    }
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
        m.contains("answered only `ok` 3 times") && m.contains("never a version report"),
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

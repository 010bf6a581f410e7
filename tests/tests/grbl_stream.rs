//! Streaming whole programs through the driver and the emulator over a real
//! pseudo-terminal: thousands of lines with the planner full, a malformed line, an
//! alarm mid-stream, and the port disappearing mid-stream.

use crate::grbl_common;

use drivers::grbl::StreamOptions;
use drivers::{Axis, DriverError, Stage};
use grbl_common::*;
use protocol::grbl::Command;
use world::Clock;

/// A zig-zag of short moves inside the travel, `n` lines, with comments and blank lines
/// as real files have them.
fn program(n: usize) -> String {
    let mut s = String::from("(zig-zag test program)\nG21 G90\n");
    let mut lines = 2;
    let mut i = 0;
    while lines < n {
        let x = 10.0 + (i % 100) as f64 * 0.5;
        let y = 10.0 + ((i / 100) % 50) as f64 * 0.5 + if i % 2 == 0 { 0.25 } else { 0.0 };
        s.push_str(&format!("G1 X{x:.3} Y{y:.4} F3000 ; step {i}\n"));
        i += 1;
        lines += 1;
    }
    s
}

#[test]
fn thousands_of_lines_stream_with_the_planner_full_and_nothing_dropped() {
    let rt = runtime();
    rt.block_on(async {
        let rig = rig();
        let emu = emulator(&rig, Clock::Unconstrained, None, None);
        let mut g = connect(emu.path()).await;
        g.home().await.unwrap();
        // Status reports with Bf: so the driver sees the planner and RX buffer.
        g.command(&Command::WriteSetting(10, 3.0)).await.unwrap();
        let prog = program(3000);
        let mut calls = 0usize;
        let mut last: Option<protocol::grbl::StreamProgress> = None;
        // No status polls while streaming: with the unconstrained clock a poll lets
        // the queued motion run, and here the planner must fill whatever the speed.
        let opts = StreamOptions {
            status_interval: std::time::Duration::from_secs(60),
            ..Default::default()
        };
        let report = g
            .stream_program(&prog, &opts, &mut |p| {
                calls += 1;
                if let Some(prev) = last {
                    assert!(
                        p.acknowledged >= prev.acknowledged && p.executed >= prev.executed,
                        "progress went back"
                    );
                }
                last = Some(p);
            })
            .await
            .unwrap();
        assert_eq!(report.progress.total, 3000);
        assert_eq!(report.progress.acknowledged, 3000);
        assert_eq!(report.progress.executed, 3000);
        assert!(calls >= 3000);
        assert!(
            report.max_in_flight_bytes <= 127,
            "{}",
            report.max_in_flight_bytes
        );
        assert!(
            report.max_in_flight_bytes > 100,
            "character counting keeps the buffer full: {}",
            report.max_in_flight_bytes
        );
        let stats = emu.stats();
        assert_eq!(
            stats.rx_dropped, 0,
            "character counting never overflows the RX buffer"
        );
        assert_eq!(stats.planner_high_water, 15, "the planner filled up");
        assert_eq!(stats.errors, 0);
        // Every line answered exactly once: 3000 program lines + $H + $10 + $G.
        assert_eq!(stats.responses, 3000 + 3 + 2);
        // The machine ended where the last line said, to the step.
        let last_line = prog.lines().last().unwrap();
        let x: f64 = last_line.split_whitespace().nth(1).unwrap()[1..]
            .parse()
            .unwrap();
        let p = g.position().await.unwrap();
        assert!(
            (p.get(Axis::X).unwrap() - x).abs() < 0.0006,
            "{p:?} vs {last_line}"
        );
    });
}

#[test]
fn malformed_line_stops_the_stream_there_with_grbls_error() {
    let rt = runtime();
    rt.block_on(async {
        let rig = rig();
        let emu = emulator(&rig, Clock::Unconstrained, None, None);
        let mut g = connect(emu.path()).await;
        g.home().await.unwrap();
        let mut lines: Vec<String> = program(200).lines().map(str::to_string).collect();
        lines[99] = "G1 X10 Q5".into(); // line 100: Q is not a GRBL word
        let prog = lines.join("\n");

        // Checked before sending: nothing goes out, the line and GRBL's code are named.
        let before = emu.stats().responses;
        let e = g
            .stream_program(&prog, &StreamOptions::default(), &mut |_| {})
            .await
            .unwrap_err();
        assert_eq!(e.line, Some(100));
        assert!(
            matches!(e.cause, DriverError::Refused { code: 20, .. }),
            "{e}"
        );
        assert_eq!(e.progress.sent, 0);
        // ($G and ? of the preflight are the only lines the device saw.)
        assert_eq!(emu.stats().responses, before + 1);
        assert!(e.to_string().contains("line 100 `G1X10Q5`"), "{e}");

        // Without the check, the device refuses it; the stream stops sending there.
        let opts = StreamOptions {
            preflight: false,
            ..Default::default()
        };
        let before = emu.stats().responses;
        let e = g
            .stream_program(&prog, &opts, &mut |_| {})
            .await
            .unwrap_err();
        assert_eq!(e.line, Some(100), "{e}");
        assert!(
            matches!(e.cause, DriverError::Refused { code: 20, .. }),
            "{e}"
        );
        let p = e.progress;
        assert_eq!(
            p.acknowledged, p.sent,
            "every line sent was answered: none lost, none resent"
        );
        assert!(
            p.sent < 200,
            "stopped sending after the refusal: sent {}",
            p.sent
        );
        assert_eq!(e.acknowledged_after, (101..=p.sent).collect::<Vec<_>>());
        assert_eq!(
            emu.stats().responses - before,
            p.sent as u64,
            "the device saw each line once"
        );
        let msg = e.to_string();
        assert!(
            msg.contains("line 100") && msg.contains("code 20") && msg.contains("unsupported"),
            "{msg}"
        );
    });
}

#[test]
fn alarm_mid_stream_stops_it_as_an_error() {
    let rt = runtime();
    rt.block_on(async {
        let rig = rig();
        let emu = emulator(&rig, Clock::Unconstrained, None, None);
        let mut g = connect(emu.path()).await;
        g.home().await.unwrap();
        let mut lines: Vec<String> = program(300).lines().map(str::to_string).collect();
        lines[149] = "G53 G0 X260".into(); // beyond the 200 mm travel: soft limit
        let opts = StreamOptions {
            preflight: false,
            ..Default::default()
        };
        let e = g
            .stream_program(&lines.join("\n"), &opts, &mut |_| {})
            .await
            .unwrap_err();
        assert!(matches!(e.cause, DriverError::Alarm { code: 2, .. }), "{e}");
        assert_eq!(e.progress.acknowledged, 149, "{e}");
        assert_eq!(e.line, Some(150));
        // The stage stays in alarm until reset; homing clears it.
        g.home().await.unwrap();
        g.wait_idle().await.unwrap();
    });
}

#[test]
fn port_disappearing_mid_stream_reports_acknowledged_lines_and_reconnects() {
    let rt = runtime();
    rt.block_on(async {
        let rig = rig();
        let link = temp_link("unplug");
        // The device answers 500 lines ($I and $$ of the handshake, $H, $10 and 496
        // program lines), then the
        // pseudo-terminal closes, as an unplugged USB adapter does.
        let mut emu = emulator(&rig, Clock::Unconstrained, Some(500), Some(&link));
        let mut g = connect(link.to_str().unwrap()).await;
        g.home().await.unwrap();
        g.command(&Command::WriteSetting(10, 3.0)).await.unwrap();
        let opts = StreamOptions {
            preflight: false,
            ..Default::default()
        };
        let e = g
            .stream_program(&program(2000), &opts, &mut |_| {})
            .await
            .unwrap_err();
        assert!(matches!(e.cause, DriverError::Transport { .. }), "{e}");
        assert_eq!(e.progress.acknowledged, 496, "{e}");
        assert!(e.progress.sent > 496 && e.progress.sent < 2000, "{e}");
        let msg = e.to_string();
        assert!(msg.contains("lines 1..=496 acknowledged"), "{msg}");
        assert!(
            msg.contains(&format!(
                "lines 497..={} sent but not acknowledged",
                e.progress.sent
            )),
            "{msg}"
        );
        emu.closed().await;

        // The adapter comes back under the same name.
        let emu2 = emulator(&rig, Clock::Unconstrained, None, Some(&link));
        g.reconnect().await.unwrap();
        g.home().await.unwrap();
        assert!(g.position().await.is_ok());
        drop(emu2);
        let _ = std::fs::remove_file(&link);
    });
}

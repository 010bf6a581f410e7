//! The GRBL driver against the GRBL emulator over a real pseudo-terminal: connect,
//! home, moves, jog and cancel, hold and resume, alarms as errors, and clear errors
//! for a wrong port or a device that is not GRBL.

use crate::grbl_common;

use drivers::grbl::GrblStage;
use drivers::{Axis, AxisValues, DriverError, Stage, StageState};
use emulators::grbl::{Foreign, ForeignPty};
use grbl_common::*;
use protocol::grbl::Command;
use std::time::Duration;
use world::Clock;

#[test]
fn connects_homes_and_moves_to_the_step() {
    let rt = runtime();
    rt.block_on(async {
        let rig = rig();
        let emu = emulator(&rig, Clock::Unconstrained, None, None);
        let mut g = connect(emu.path()).await;
        let info = g.info().clone();
        assert!(info.name.contains("GRBL 1.1h"), "{}", info.name);
        let x = info.axis(Axis::X).unwrap();
        assert_eq!((x.min_mm, x.max_mm), (0.0, 200.0));
        assert_eq!(x.resolution_mm, 0.0005);
        assert_eq!(info.axis(Axis::Y).unwrap().max_mm, 150.0);
        assert_eq!(g.build_info().rx_buffer, 128);
        assert_eq!(g.build_info().planner_blocks, 15);
        // GRBL boots locked when homing is enabled.
        assert_eq!(g.status().await.unwrap().state, StageState::NotHomed);
        g.home().await.unwrap();
        assert_eq!(g.status().await.unwrap().state, StageState::Idle);

        g.move_to(AxisValues::xy(10.12345, 20.5), 3000.0)
            .await
            .unwrap();
        g.wait_idle().await.unwrap();
        // Sent with 4 decimals (10.1235), quantised by the machine to 0.5 um steps.
        assert_eq!(rig.lock().unwrap().machine().counts(), [20247, 41000]);
        let p = g.position().await.unwrap();
        assert!(
            (p.get(Axis::X).unwrap() - 10.1235).abs() <= 0.0005 + 1e-9,
            "{p:?}"
        );
        assert_eq!(p.get(Axis::Y), Some(20.5));

        // Relative moves start from the exact commanded target, not the 1 um report.
        g.move_by(AxisValues::default().with(Axis::X, 0.0005), 3000.0)
            .await
            .unwrap();
        g.wait_idle().await.unwrap();
        assert_eq!(rig.lock().unwrap().machine().counts(), [20248, 41000]);
    });
}

#[test]
fn soft_limits_are_checked_before_anything_is_sent() {
    let rt = runtime();
    rt.block_on(async {
        let rig = rig();
        let emu = emulator(&rig, Clock::Unconstrained, None, None);
        let mut g = connect(emu.path()).await;
        g.home().await.unwrap();
        let before = emu.stats().responses;
        let e = g
            .move_to(AxisValues::xy(250.0, 10.0), 1000.0)
            .await
            .unwrap_err();
        assert!(
            matches!(e, DriverError::OutOfLimits { axis: Axis::X, .. }),
            "{e}"
        );
        let _ = g.position().await.unwrap();
        assert_eq!(
            emu.stats().responses,
            before,
            "nothing reached the controller"
        );
    });
}

#[test]
fn alarms_stop_motion_and_surface_as_errors() {
    let rt = runtime();
    rt.block_on(async {
        let rig = rig();
        let emu = emulator(&rig, Clock::Unconstrained, None, None);
        let mut g = connect(emu.path()).await;
        // G-code while locked: GRBL's error 9, a device refusal.
        let e = g
            .move_to(AxisValues::xy(1.0, 1.0), 1000.0)
            .await
            .unwrap_err();
        assert!(matches!(e, DriverError::Refused { code: 9, .. }), "{e}");
        g.home().await.unwrap();
        // A raw line past the travel: GRBL's soft-limit alarm (critical).
        let e = g
            .command(&Command::Gcode("G53G0X300".into()))
            .await
            .unwrap_err();
        match &e {
            DriverError::Alarm {
                code: 2, message, ..
            } => assert!(message.contains("soft limit"), "{message}"),
            other => panic!("expected ALARM:2, got {other}"),
        }
        let s = g.status().await.unwrap();
        assert!(
            matches!(s.state, StageState::Alarm(ref m) if m.contains("ALARM:2")),
            "{s:?}"
        );
        // Everything but a reset is refused until then; home() resets and re-homes.
        assert!(matches!(
            g.move_to(AxisValues::xy(1.0, 1.0), 1000.0).await,
            Err(DriverError::Alarm { code: 2, .. })
        ));
        g.home().await.unwrap();
        g.move_to(AxisValues::xy(1.0, 1.0), 1000.0).await.unwrap();
        g.wait_idle().await.unwrap();
        // Homing disabled: $H is refused with GRBL's error 5.
        g.command(&Command::WriteSetting(22, 0.0)).await.unwrap();
        let e = g.home().await.unwrap_err();
        assert!(matches!(e, DriverError::Refused { code: 5, .. }), "{e}");
    });
}

#[test]
fn jog_is_cancelled_and_hold_resume_and_stop_keep_position() {
    let rt = runtime();
    rt.block_on(async {
        let rig = rig();
        // Real time: a 100 mm jog at 600 mm/min takes 10 s, so it is still running
        // when the cancel goes out right after it.
        let emu = emulator(&rig, Clock::Scaled(1.0), None, None);
        let mut g = connect(emu.path()).await;
        g.unlock().await.unwrap();
        g.jog(AxisValues::default().with(Axis::X, 100.0), 600.0, true)
            .await
            .unwrap();
        g.jog_cancel().await.unwrap();
        let x = g.position().await.unwrap().get(Axis::X).unwrap();
        assert!(x < 100.0, "jog not cancelled: at {x}");
        assert_eq!(g.status().await.unwrap().state, StageState::Idle);
        // Jog beyond the limits is refused locally.
        assert!(matches!(
            g.jog(AxisValues::default().with(Axis::X, 500.0), 600.0, true)
                .await,
            Err(DriverError::OutOfLimits { .. })
        ));

        // A slow deceleration (10 mm/s^2: about a second from 600 mm/min): GRBL ignores
        // a cycle start while the hold still decelerates (`Hold:1`), so `resume` waits
        // for the hold to complete before it sends `~`.
        for axis in [120, 121] {
            g.command(&Command::WriteSetting(axis, 10.0)).await.unwrap();
        }
        g.move_to(AxisValues::xy(120.0, 0.0), 600.0).await.unwrap();
        g.feed_hold().await.unwrap();
        let held = g.status().await.unwrap();
        assert_eq!(held.state, StageState::Hold);
        g.resume().await.unwrap();
        assert_eq!(g.status().await.unwrap().state, StageState::Moving);
        // stop(): hold, then reset to flush; no ALARM:3 since the axes had stopped.
        g.stop().await.unwrap();
        let s = g.status().await.unwrap();
        assert_eq!(s.state, StageState::Idle, "{s:?}");
        let x = s.position.get(Axis::X).unwrap();
        assert!(x < 120.0, "stopped at {x}");
    });
}

/// Ctrl-C during homing (the job's cancel drops the homing future after `$H` went out):
/// `stop` ends the cycle with a reset, the controller reports the homing reset alarm
/// and stays locked, and the driver homes again afterwards.
#[test]
fn stop_during_homing_resets_and_homing_again_works() {
    let rt = runtime();
    rt.block_on(async {
        let rig = rig();
        // Real time: the homing cycle takes seconds, so it is still running when the
        // cancel comes right after `$H` was written.
        let emu = emulator(&rig, Clock::Scaled(1.0), None, None);
        let mut g = connect(emu.path()).await;
        // Away from the switches, so that the cycle has a way to go.
        g.unlock().await.unwrap();
        g.move_to(AxisValues::xy(40.0, 30.0), 6000.0).await.unwrap();
        g.wait_idle().await.unwrap();
        let homings = rig.lock().unwrap().machine().homings();
        {
            let home = g.home();
            tokio::pin!(home);
            // The cancel comes once the controller has started the cycle (the emulator's
            // thread counts it; this task yields to the homing future meanwhile).
            let started = async {
                while rig.lock().unwrap().machine().homings() == homings {
                    tokio::task::yield_now().await;
                }
            };
            tokio::select! {
                r = &mut home => panic!("homing ended before the cancel: {r:?}"),
                () = started => {}
            }
        }
        // GRBL answers no status report during a homing cycle: stop resets at once.
        g.stop().await.unwrap();
        let after = g.status().await.unwrap();
        match &after.state {
            StageState::Alarm(m) => assert!(m.contains("ALARM:6"), "{m}"),
            other => panic!("after a stop during homing: {other:?}"),
        }
        // Locked until homed: a move is refused by the controller, not executed.
        assert!(g.move_to(AxisValues::xy(1.0, 1.0), 1000.0).await.is_err());
        g.home().await.unwrap();
        assert_eq!(g.status().await.unwrap().state, StageState::Idle);
    });
}

#[test]
fn wrong_port_and_foreign_devices_fail_clearly_and_quickly() {
    let rt = runtime();
    rt.block_on(async {
        let e = GrblStage::open("/dev/does-not-exist-grbl", 115_200, options())
            .await
            .err()
            .unwrap();
        let msg = e.to_string();
        assert!(matches!(e, DriverError::Transport { .. }), "{msg}");
        assert!(msg.contains("/dev/does-not-exist-grbl"), "{msg}");

        let mut opts = options();
        opts.connect_timeout = Duration::from_millis(300);
        for kind in [Foreign::Silent, Foreign::Echo, Foreign::Chatter] {
            let dev = ForeignPty::spawn(kind).unwrap();
            let e = GrblStage::open(dev.path(), 115_200, opts.clone())
                .await
                .err()
                .unwrap();
            let msg = e.to_string();
            assert!(
                matches!(e, DriverError::Timeout { after_ms: 300, .. }),
                "{kind:?}: {msg}"
            );
            assert!(
                msg.contains("no start-up banner") && msg.contains("$I") && msg.contains("GRBL"),
                "{kind:?}: {msg}"
            );
            match kind {
                Foreign::Silent => assert!(msg.contains("sent nothing"), "{msg}"),
                // Its echo of the greeting's `?` and soft reset, then of the last `$I`.
                Foreign::Echo => assert!(msg.contains("?\\x18$I`"), "{msg}"),
                Foreign::Chatter => assert!(msg.contains("Unknown command"), "{msg}"),
            }
        }
    });
}

#[test]
fn check_mode_and_settings_by_send_response() {
    let rt = runtime();
    rt.block_on(async {
        let rig = rig();
        let emu = emulator(&rig, Clock::Unconstrained, None, None);
        let mut g = connect(emu.path()).await;
        g.unlock().await.unwrap();
        let e = g.command(&Command::WriteSetting(0, 1.0)).await.unwrap_err();
        assert!(matches!(e, DriverError::Refused { code: 6, .. }), "{e}");
        let info = g.command(&Command::CheckMode).await.unwrap();
        assert!(!info.is_empty());
        let e = g
            .command(&Command::Gcode("G1X10".into()))
            .await
            .unwrap_err();
        assert!(
            matches!(e, DriverError::Refused { code: 22, .. }),
            "undefined feed: {e}"
        );
        g.command(&Command::Gcode("G1X10F100".into()))
            .await
            .unwrap();
        assert_eq!(
            rig.lock().unwrap().machine().counts(),
            [0, 0],
            "check mode moves nothing"
        );
    });
}

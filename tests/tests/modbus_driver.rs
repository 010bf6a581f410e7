//! The Modbus driver against the drive emulator: over TCP on the loopback interface and
//! over RTU on a real pseudo-terminal, for each shipped profile; exceptions and alarms
//! as typed errors naming the register.

use crate::modbus_common;

use drivers::modbus::{open_stage, Endpoint, Op};
use drivers::{Axis, AxisDrive, AxisValues, DriverError, Stage, StageState};
use emulators::modbus::MachineAxis;
use modbus_common::*;

async fn home_move_and_check(stage: &mut dyn Stage, rig: &world::SharedRig) {
    stage.home().await.unwrap();
    let st = stage.status().await.unwrap();
    assert_eq!(st.state, StageState::Idle, "{st:?}");
    for (x, y) in [(50.0, 30.0), (120.2345, 80.5), (10.0, 140.0)] {
        stage.move_to(AxisValues::xy(x, y), 3000.0).await.unwrap();
        stage.wait_idle().await.unwrap();
        let p = stage.position().await.unwrap();
        let (px, py) = (p.get(Axis::X).unwrap(), p.get(Axis::Y).unwrap());
        assert!(
            (px - x).abs() <= 0.0005 && (py - y).abs() <= 0.0005,
            "at {px}, {py} for {x}, {y}"
        );
        let m = machine_mm(rig);
        assert!(
            (m[0] - x).abs() <= 0.0005 && (m[1] - y).abs() <= 0.0005,
            "machine at {m:?}"
        );
    }
}

#[test]
fn generic_drives_over_tcp_loopback_home_move_and_report() {
    runtime().block_on(async {
        let rig = rig();
        let p = profile("generic");
        let dev = device(&rig, &p, &[(1, MachineAxis::X), (2, MachineAxis::Y)]);
        let server = tcp(&dev).await;
        let axes = [axis_cfg(Axis::X, 1), axis_cfg(Axis::Y, 2)];
        let mut stage = open_stage(
            Endpoint::Tcp(server.local_addr()),
            options(),
            p.clone(),
            &axes,
        )
        .await
        .unwrap();
        assert!(
            stage.info().name.starts_with("Modbus TCP 127.0.0.1:"),
            "{}",
            stage.info().name
        );
        home_move_and_check(&mut stage, &rig).await;
        let s = dev.stats();
        assert_eq!(
            (s.triggers_of(1), s.triggers_of(2)),
            (3, 3),
            "one trigger per axis move: {s:?}"
        );
        assert_eq!(s.exceptions, 0);
    });
}

#[test]
fn oriental_az_drives_on_one_rtu_line_of_a_real_pseudo_terminal() {
    runtime().block_on(async {
        let rig = rig();
        let p = profile("oriental-az");
        // Unit 17 is 0x11 (XON): the line must be raw for Modbus bytes to pass.
        let dev = device(&rig, &p, &[(17, MachineAxis::X), (3, MachineAxis::Y)]);
        let line = rtu(&dev);
        assert!(line.path().starts_with("/dev/"), "{}", line.path());
        let axes = [axis_cfg(Axis::X, 17), axis_cfg(Axis::Y, 3)];
        let mut stage = open_stage(rtu_endpoint(line.path()), options(), p.clone(), &axes)
            .await
            .unwrap();
        home_move_and_check(&mut stage, &rig).await;
        let s = dev.stats();
        assert_eq!((s.triggers_of(17), s.triggers_of(3)), (3, 3), "{s:?}");
        assert_eq!(s.crc_errors, 0);
    });
}

#[test]
fn leadshine_pr0_over_tcp_with_rpm_speed_and_time_accelerations() {
    runtime().block_on(async {
        let rig = rig();
        let p = profile("leadshine-pr0");
        let dev = device(&rig, &p, &[(1, MachineAxis::X), (2, MachineAxis::Y)]);
        let server = tcp(&dev).await;
        let axes = [axis_cfg(Axis::X, 1), axis_cfg(Axis::Y, 2)];
        let mut stage = open_stage(Endpoint::Tcp(server.local_addr()), options(), p, &axes)
            .await
            .unwrap();
        home_move_and_check(&mut stage, &rig).await;
    });
}

#[test]
fn exceptions_become_refusals_naming_the_register() {
    runtime().block_on(async {
        let rig = rig();
        let generic = profile("generic");
        let dev = device(&rig, &generic, &[(1, MachineAxis::X)]);
        let server = tcp(&dev).await;
        let ep = Endpoint::Tcp(server.local_addr());
        // A driver with another drive's profile reads registers this drive lacks.
        let mut wrong = axis(ep.clone(), &profile("oriental-az"), Axis::X, 1).await;
        let e = wrong.status().await.unwrap_err();
        match &e {
            DriverError::Refused {
                code: 2,
                what,
                message,
                ..
            } => {
                assert!(
                    what.contains("`status.register` (holding 0x007E-0x007F, u32)"),
                    "{what}"
                );
                assert_eq!(message, "illegal data address");
            }
            other => panic!("expected a refusal, got {other:?}"),
        }
        assert!(e.to_string().contains("unit 1"), "{e}");
        // An illegal value: a trigger value the drive does not know.
        let a = axis(ep.clone(), &generic, Axis::X, 1).await;
        let trig = generic.motion.trigger.reg.address;
        let e = a
            .bus()
            .lock()
            .await
            .call(
                1,
                &Op::WriteSingle(trig, 7),
                "drive",
                "write `move.trigger`",
            )
            .await
            .unwrap_err();
        assert!(matches!(e, DriverError::Refused { code: 3, .. }), "{e:?}");
        // Writing a read-only register.
        let st = generic.status.reg.address;
        let e = a
            .bus()
            .lock()
            .await
            .call(1, &Op::WriteSingle(st, 1), "drive", "write")
            .await
            .unwrap_err();
        assert!(matches!(e, DriverError::Refused { code: 2, .. }), "{e:?}");
        assert_eq!(dev.stats().triggers_of(1), 0, "nothing started");
    });
}

#[test]
fn a_move_beyond_the_travel_raises_the_drive_alarm_which_a_reset_clears() {
    runtime().block_on(async {
        let rig = rig();
        let p = profile("generic");
        let dev = device(&rig, &p, &[(1, MachineAxis::X)]);
        let server = tcp(&dev).await;
        let mut cfg = axis_cfg(Axis::X, 1);
        cfg.max_mm = 400.0; // wider than the machine: the drive, not the driver, refuses
        let bus =
            drivers::modbus::ModbusBus::new(Endpoint::Tcp(server.local_addr()), options()).shared();
        let mut a = drivers::modbus::ModbusAxis::new(bus, p.clone(), &cfg).await;
        a.home().await.unwrap();
        a.start_move(300.0, 3000.0).await.unwrap();
        let e = a.wait_idle().await.unwrap_err();
        match &e {
            DriverError::Alarm {
                code: 0x0101,
                message,
                ..
            } => assert!(message.contains("software overtravel"), "{message}"),
            other => panic!("expected the overtravel alarm, got {other:?}"),
        }
        assert!(a.status().await.unwrap().fault.is_some());
        a.reset_alarm().await.unwrap();
        assert_eq!(a.status().await.unwrap().fault, None);
        a.start_move(20.0, 3000.0).await.unwrap();
        a.wait_idle().await.unwrap();
        assert!((a.position().await.unwrap() - 20.0).abs() < 1e-9);
        // The driver's own soft limits refuse before anything is sent.
        let before = dev.stats().requests;
        assert!(matches!(
            a.start_move(-1.0, 3000.0).await,
            Err(DriverError::OutOfLimits { .. })
        ));
        assert_eq!(dev.stats().requests, before);
    });
}

#[test]
fn a_unit_that_is_not_on_the_line_times_out_within_the_retries() {
    runtime().block_on(async {
        let rig = rig();
        let p = profile("generic");
        let dev = device(&rig, &p, &[(1, MachineAxis::X)]);
        let line = rtu(&dev);
        let mut a = axis(rtu_endpoint(line.path()), &p, Axis::X, 9).await;
        let e = a.position().await.unwrap_err();
        match &e {
            DriverError::Timeout {
                what,
                after_ms: 150,
                ..
            } => {
                assert!(
                    what.contains("`position`")
                        && what.contains("3 attempts: no reply; no reply; no reply"),
                    "{what}"
                )
            }
            other => panic!("expected a timeout, got {other:?}"),
        }
        assert!(e.to_string().contains("unit 9"), "{e}");
        // The line still works for the unit that is there.
        let mut b = axis(rtu_endpoint(line.path()), &p, Axis::X, 1).await;
        b.position().await.unwrap();
    });
}

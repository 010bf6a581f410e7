//! Faults injected by the drive emulator: lost requests, lost replies, replies with a
//! bad CRC and late replies. Every move is started exactly once (the emulator counts
//! triggers), none is lost, and failures that persist are reported within bounds.

use crate::modbus_common;

use drivers::modbus::{Endpoint, ModbusAxis};
use drivers::{Axis, AxisDrive, DriverError};
use emulators::modbus::{Fault, FaultRule, MachineAxis, ModbusDevice};
use modbus_common::*;
use protocol::modbus::frame::function::{
    READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS, WRITE_MULTIPLE_REGISTERS,
};
use std::sync::Arc;
use std::time::Duration;
use world::SharedRig;

const MOVE: u8 = WRITE_MULTIPLE_REGISTERS;

async fn homed_x(ep: Endpoint, rig: &SharedRig) -> ModbusAxis {
    let mut a = axis(ep, &profile("generic"), Axis::X, 1).await;
    a.home().await.unwrap();
    // The X drive homes machine axis X (Y is not homed by it).
    assert!(rig.lock().unwrap().machine().is_axis_homed(0));
    a
}

/// Move, wait, and check the machine arrived; returns the triggers counted.
async fn move_and_arrive(
    a: &mut ModbusAxis,
    dev: &Arc<ModbusDevice>,
    rig: &SharedRig,
    to: f64,
) -> u64 {
    a.start_move(to, 3000.0).await.unwrap();
    a.wait_idle().await.unwrap();
    assert!(
        (machine_mm(rig)[0] - to).abs() <= 0.0005,
        "machine at {:?}, target {to}",
        machine_mm(rig)
    );
    dev.stats().triggers_of(1)
}

fn setup() -> (SharedRig, Arc<ModbusDevice>) {
    let rig = rig();
    let dev = device(&rig, &profile("generic"), &[(1, MachineAxis::X)]);
    (rig, dev)
}

#[test]
fn lost_reply_to_a_move_is_proven_received_by_read_back_and_not_sent_again() {
    runtime().block_on(async {
        let (rig, dev) = setup();
        let server = tcp(&dev).await;
        let mut a = homed_x(Endpoint::Tcp(server.local_addr()), &rig).await;
        dev.set_faults(vec![FaultRule::new(Fault::DropReply)
            .on_function(MOVE)
            .times(1)]);
        assert_eq!(
            move_and_arrive(&mut a, &dev, &rig, 42.0).await,
            1,
            "exactly one trigger"
        );
        let s = a.move_stats();
        assert_eq!(
            (s.writes, s.proven_by_readback, s.resent),
            (1, 1, 0),
            "{s:?}"
        );
        let bus = a.bus().lock().await.stats();
        assert_eq!((bus.timeouts, bus.reconnects), (1, 1), "{bus:?}");
        // The next move goes through normally on the new connection.
        assert_eq!(move_and_arrive(&mut a, &dev, &rig, 17.5).await, 2);
    });
}

#[test]
fn lost_move_request_is_sent_again_once() {
    runtime().block_on(async {
        let (rig, dev) = setup();
        let server = tcp(&dev).await;
        let mut a = homed_x(Endpoint::Tcp(server.local_addr()), &rig).await;
        dev.set_faults(vec![FaultRule::new(Fault::DropRequest)
            .on_function(MOVE)
            .times(1)]);
        assert_eq!(
            move_and_arrive(&mut a, &dev, &rig, 61.25).await,
            1,
            "neither lost nor duplicated"
        );
        let s = a.move_stats();
        assert_eq!((s.writes, s.resent, s.acknowledged), (2, 1, 1), "{s:?}");
    });
}

#[test]
fn same_target_twice_with_a_lost_reply_is_judged_by_busy_or_arrival() {
    runtime().block_on(async {
        let (rig, dev) = setup();
        let server = tcp(&dev).await;
        let mut a = homed_x(Endpoint::Tcp(server.local_addr()), &rig).await;
        assert_eq!(move_and_arrive(&mut a, &dev, &rig, 30.0).await, 1);
        a.start_move(80.0, 3000.0).await.unwrap();
        a.stop().await.unwrap(); // stopped on the way: the drive still latches 80
        let stopped = machine_mm(&rig)[0];
        assert!(stopped < 80.0);
        // 80 again, reply lost: the latched target was already 80, the drive is idle
        // and not there, so the read-back cannot prove it; but the drive took it and
        // is busy, which proves it.
        dev.set_faults(vec![FaultRule::new(Fault::DropReply)
            .on_function(MOVE)
            .times(1)]);
        assert_eq!(move_and_arrive(&mut a, &dev, &rig, 80.0).await, 3);
        assert_eq!(a.move_stats().proven_by_readback, 1);
    });
}

#[test]
fn bad_crc_on_an_rtu_move_reply_is_not_a_second_move() {
    runtime().block_on(async {
        let (rig, dev) = setup();
        let line = rtu(&dev);
        let mut a = homed_x(rtu_endpoint(line.path()), &rig).await;
        dev.set_faults(vec![FaultRule::new(Fault::CorruptReply)
            .on_function(MOVE)
            .times(1)]);
        assert_eq!(move_and_arrive(&mut a, &dev, &rig, 99.0).await, 1);
        assert_eq!(a.move_stats().proven_by_readback, 1);
        let bus = a.bus().lock().await.stats();
        assert_eq!(
            bus.timeouts, 1,
            "the client's decoder waits for a valid frame: {bus:?}"
        );
    });
}

#[test]
fn late_rtu_reply_is_discarded_not_taken_for_the_next_answer() {
    runtime().block_on(async {
        let (rig, dev) = setup();
        let line = rtu(&dev);
        let mut a = homed_x(rtu_endpoint(line.path()), &rig).await;
        // The move's reply comes 100 ms after the 150 ms timeout.
        dev.set_faults(vec![FaultRule::new(Fault::SlowReply(
            Duration::from_millis(250),
        ))
        .on_function(MOVE)
        .times(1)]);
        assert_eq!(move_and_arrive(&mut a, &dev, &rig, 12.345).await, 1);
        // Every later answer is the right one: position reads agree with the machine.
        for to in [150.0, 7.0] {
            assert_eq!(
                move_and_arrive(&mut a, &dev, &rig, to).await as usize,
                if to == 150.0 { 2 } else { 3 }
            );
            assert!((a.position().await.unwrap() - to).abs() < 1e-9);
        }
        let bus = a.bus().lock().await.stats();
        assert_eq!((bus.timeouts, bus.garbled), (1, 0), "{bus:?}");
    });
}

#[test]
fn late_tcp_reply_arrives_on_a_closed_connection() {
    runtime().block_on(async {
        let (rig, dev) = setup();
        let server = tcp(&dev).await;
        let mut a = homed_x(Endpoint::Tcp(server.local_addr()), &rig).await;
        dev.set_faults(vec![FaultRule::new(Fault::SlowReply(
            Duration::from_millis(200),
        ))
        .on_function(READ_INPUT_REGISTERS)
        .times(1)]);
        let p = a.position().await.unwrap();
        assert_eq!(p, 0.0);
        assert_eq!(move_and_arrive(&mut a, &dev, &rig, 55.0).await, 1);
        let bus = a.bus().lock().await.stats();
        assert_eq!(
            (bus.timeouts, bus.garbled, bus.retries),
            (1, 0, 1),
            "{bus:?}"
        );
    });
}

#[test]
fn crc_errors_and_silence_are_retried_within_bounds_then_reported() {
    runtime().block_on(async {
        let (rig, dev) = setup();
        let line = rtu(&dev);
        let a = homed_x(rtu_endpoint(line.path()), &rig).await;
        let mut a = a;
        // One bad CRC: retried, success.
        dev.set_faults(vec![FaultRule::new(Fault::CorruptReply)
            .on_function(READ_INPUT_REGISTERS)
            .times(1)]);
        a.position().await.unwrap();
        // Always a bad CRC: reported after 3 attempts, naming the register and the CRC.
        dev.set_faults(vec![
            FaultRule::new(Fault::CorruptReply).on_function(READ_INPUT_REGISTERS)
        ]);
        let e = a.position().await.unwrap_err();
        match &e {
            DriverError::Protocol { message, .. } => {
                assert!(
                    message.contains("`position`") && message.contains("3 attempts"),
                    "{message}"
                );
                assert_eq!(message.matches("bad CRC").count(), 3, "{message}");
            }
            other => panic!("expected a protocol error, got {other:?}"),
        }
        // Never any reply: a timeout.
        dev.set_faults(vec![
            FaultRule::new(Fault::DropReply).on_function(READ_HOLDING_REGISTERS)
        ]);
        let before = dev.stats().triggers_of(1);
        let e = a.start_move(20.0, 1000.0).await.unwrap_err();
        assert!(matches!(e, DriverError::Timeout { .. }), "{e:?}");
        assert_eq!(
            dev.stats().triggers_of(1),
            before,
            "the latched target could not be read: nothing sent"
        );
        dev.set_faults(vec![]);
        assert_eq!(move_and_arrive(&mut a, &dev, &rig, 20.0).await, before + 1);
    });
}

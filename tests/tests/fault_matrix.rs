//! The fault matrix: the compensation job over a real link (the driver on a
//! pseudo-terminal, the device's emulator behind a man in the middle), with one fault
//! injected mid-job. Every case ends in one of two ways, asserted here: recovery (the job
//! finishes with every target converged, as good as without the fault) or a safe stop
//! (the job stops with an error naming what happened, the stage told to stop, and every
//! target finished before the fault kept in the report). Never a panic or a hang: each
//! case runs under a bound far above its expected time, and a timeout fails the test.
//!
//! What each link tolerates is in docs/reliability.md.

use devices::{open_camera, spawn_grbl_emulator, Devices};
use drivers::can::BusSpec;
use drivers::canopen::CanopenOptions;
use drivers::grbl::GrblOptions;
use drivers::modbus::{Endpoint, ModbusOptions, Parity};
use drivers::StageLink;
use emulators::canopen::{
    DriveSet as CanDriveSet, DriveSetConfig as CanDriveSetConfig, SlcanPty, DRIVE_EDS,
    DRIVE_EDS_NAME,
};
use emulators::modbus::{DriveSet, MachineAxis, ModbusDevice, ModbusRtu, ModbusTcp};
use job::{Job, StageSpec};
use runner::run_job;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use system_tests::faulty_serial::{FaultySerial, Framing, SerialFault};
use system_tests::faulty_tcp::FaultyTcp;
use system_tests::runtime;
use world::Clock;

/// The demo job cut to its first `n` targets (each a few GRBL lines).
fn short_job(n: usize) -> Job {
    let mut job = Job::demo();
    job.targets.truncate(n);
    job
}

/// The demo job over Modbus TCP drives with `fault` on the connection.
fn modbus_tcp_case(
    fault: SerialFault,
    timeout: Duration,
    retries: u32,
) -> (Outcome, bool, compensation::report::Report) {
    let mut job = short_job(6);
    job::demo::over_modbus(&mut job, false).unwrap();
    let StageSpec::Modbus(spec) = &job.stage else {
        unreachable!("over_modbus made a Modbus stage")
    };
    let job::modbus::ModbusLink::Emulate { machine, .. } = &spec.link else {
        unreachable!("the demo's Modbus stage is emulated")
    };
    let (spec, machine) = (spec.clone(), machine.clone());
    runtime().block_on(async {
        let rig = devices::new_rig(&job, &machine);
        let units = [(1, MachineAxis::X), (2, MachineAxis::Y)];
        let set = DriveSet::new(
            rig.clone(),
            spec.profile.clone(),
            &units,
            Clock::Unconstrained,
        );
        let server = ModbusTcp::bind(ModbusDevice::new(set), ([127, 0, 0, 1], 0).into())
            .await
            .unwrap();
        let link = FaultyTcp::spawn(server.local_addr(), fault).await.unwrap();
        let stage = drivers::open_stage(&StageLink::Modbus {
            endpoint: Endpoint::Tcp(link.addr()),
            options: ModbusOptions {
                timeout,
                retries,
                poll_interval: Duration::from_millis(1),
                ..ModbusOptions::default()
            },
            profile: spec.profile.clone(),
            axes: spec.axes.clone(),
        })
        .await
        .expect("the driver connects through the link");
        let report = run_bounded(&job, stage, rig).await;
        drop(server);
        (outcome_of(&report), link.fired(), report)
    })
}

/// The demo job over Modbus RTU drives (the generic profile, units 1 = X and 2 = Y)
/// with `fault` on the line; each request waits `timeout` for its reply and is tried
/// again `retries` times.
fn modbus_rtu_case(
    fault: SerialFault,
    timeout: Duration,
    retries: u32,
) -> (Outcome, bool, compensation::report::Report) {
    let mut job = short_job(6);
    job::demo::over_modbus(&mut job, true).unwrap();
    let StageSpec::Modbus(spec) = &job.stage else {
        unreachable!("over_modbus made a Modbus stage")
    };
    let job::modbus::ModbusLink::Emulate { machine, .. } = &spec.link else {
        unreachable!("the demo's Modbus stage is emulated")
    };
    let (spec, machine) = (spec.clone(), machine.clone());
    runtime().block_on(async {
        let rig = devices::new_rig(&job, &machine);
        let units = [(1, MachineAxis::X), (2, MachineAxis::Y)];
        let set = DriveSet::new(
            rig.clone(),
            spec.profile.clone(),
            &units,
            Clock::Unconstrained,
        );
        let line = ModbusRtu::spawn(ModbusDevice::new(set), None).unwrap();
        let link = FaultySerial::spawn(line.path(), Framing::Chunks, fault).unwrap();
        let stage = drivers::open_stage(&StageLink::Modbus {
            endpoint: Endpoint::Rtu {
                path: link.path().to_string(),
                baud: 115_200,
                parity: Parity::None,
            },
            options: ModbusOptions {
                timeout,
                retries,
                poll_interval: Duration::from_millis(1),
                ..ModbusOptions::default()
            },
            profile: spec.profile.clone(),
            axes: spec.axes.clone(),
        })
        .await
        .expect("the driver connects through the link");
        let report = run_bounded(&job, stage, rig).await;
        drop(line);
        (outcome_of(&report), link.fired(), report)
    })
}

/// The demo job over CiA 402 drives behind an SLCAN adapter with `fault` on its serial
/// line (SLCAN lines end with `\r`); the driver's heartbeat timeout is `heartbeat`.
fn canopen_case(
    fault: SerialFault,
    heartbeat: Duration,
) -> (Outcome, bool, compensation::report::Report) {
    let mut job = short_job(6);
    job::demo::over_canopen(&mut job).unwrap();
    let StageSpec::Canopen(spec) = &job.stage else {
        unreachable!("over_canopen made a CANopen stage")
    };
    let job::canopen::CanopenLink::Emulate { machine, .. } = &spec.link else {
        unreachable!("the demo's CANopen stage is emulated")
    };
    let (spec, machine) = (spec.clone(), machine.clone());
    runtime().block_on(async {
        let rig = devices::new_rig(&job, &machine);
        let cfg = CanDriveSetConfig {
            clock: Clock::Unconstrained,
            nodes: spec
                .axes
                .iter()
                .map(|a| (a.node, if a.axis == drivers::Axis::X { 0 } else { 1 }))
                .collect(),
            eds: (DRIVE_EDS_NAME.to_string(), DRIVE_EDS.to_string()),
        };
        let set = CanDriveSet::new(rig.clone(), &cfg, 0.0).unwrap();
        let adapter = SlcanPty::spawn(Arc::new(Mutex::new(set)), None).unwrap();
        let link = FaultySerial::spawn(adapter.path(), Framing::Lines(b'\r'), fault).unwrap();
        let stage = drivers::open_stage(&StageLink::Canopen {
            bus: BusSpec::Slcan {
                port: link.path().to_string(),
                bitrate: 1_000_000,
            },
            options: CanopenOptions {
                heartbeat_timeout: heartbeat,
                ..spec.options.clone()
            },
            axes: spec.axes.clone(),
        })
        .await
        .expect("the driver connects through the link");
        let report = run_bounded(&job, stage, rig).await;
        drop(adapter);
        (outcome_of(&report), link.fired(), report)
    })
}

/// The job over `stage` and the simulated camera of `rig`, bounded far above its
/// expected time: a hang fails the test.
async fn run_bounded(
    job: &Job,
    stage: Box<dyn drivers::Stage>,
    rig: world::SharedRig,
) -> compensation::report::Report {
    let camera = open_camera(&job.camera, Some(&rig)).await.unwrap();
    let mut devices = Devices {
        stage,
        camera,
        rig: Some(rig),
    };
    tokio::time::timeout(
        Duration::from_secs(60),
        run_job(job, &mut devices, &mut |_, _| {}),
    )
    .await
    .expect("the job ends by itself: recovered or stopped, never hung")
}

fn outcome_of(report: &compensation::report::Report) -> Outcome {
    match &report.error {
        None => Outcome::Recovered,
        Some(e) => Outcome::SafeStop {
            error: e.clone(),
            finished: report.targets,
        },
    }
}

/// What a case came to.
#[derive(Debug)]
enum Outcome {
    Recovered,
    SafeStop { error: String, finished: usize },
}

/// The demo job over GRBL with `fault` on the link; the driver's command timeout is
/// `timeout`.
fn grbl_case(
    fault: SerialFault,
    timeout: Duration,
) -> (Outcome, bool, compensation::report::Report, String) {
    let job = short_job(6);
    let StageSpec::Sim { machine } = &job.stage else {
        unreachable!("the demo job simulates its stage")
    };
    let machine = machine.clone();
    runtime().block_on(async {
        let (emulator, rig) = spawn_grbl_emulator(&job, &machine, Clock::Unconstrained).unwrap();
        let link = FaultySerial::spawn(emulator.path(), Framing::Lines(b'\n'), fault).unwrap();
        let stage = drivers::open_stage(&StageLink::Grbl {
            port: link.path().to_string(),
            baud: 115_200,
            options: GrblOptions {
                command_timeout: timeout,
                poll_interval: Duration::from_millis(2),
                ..GrblOptions::default()
            },
        })
        .await
        .expect("the driver connects through the link");
        let report = run_bounded(&job, stage, rig).await;
        let outcome = outcome_of(&report);
        drop(emulator);
        let sent = String::from_utf8_lossy(&link.host_bytes()).into_owned();
        (outcome, link.fired(), report, sent)
    })
}

fn assert_recovered(outcome: &Outcome, report: &compensation::report::Report) {
    assert!(
        matches!(outcome, Outcome::Recovered),
        "{outcome:?}\n{}",
        report.to_text()
    );
    assert_eq!(
        report.converged,
        report.targets_planned,
        "{}",
        report.to_text()
    );
    let after = report.after_um.expect("simulated: the truth is reported");
    assert!(
        after.max <= 1.0,
        "as good as without the fault: {}",
        report.to_text()
    );
}

fn assert_safe_stop(outcome: &Outcome, report: &compensation::report::Report, says: &[&str]) {
    let Outcome::SafeStop { error, finished } = outcome else {
        panic!(
            "expected a safe stop, the job recovered:\n{}",
            report.to_text()
        )
    };
    eprintln!("safe stop after {finished} targets: {error}");
    assert!(
        says.iter().any(|s| error.to_lowercase().contains(s)),
        "the error should say one of {says:?}: {error}"
    );
    // Work done before the fault is kept.
    assert!(
        *finished >= 1,
        "targets finished before the fault are kept: {}",
        report.to_text()
    );
    assert!(report.per_target.len() >= *finished);
}

/// After the homing, the orientation check and the first targets: mid-job.
const MID_JOB: usize = 30;

#[test]
fn grbl_without_a_fault_is_the_baseline() {
    let (outcome, _, report, _) = grbl_case(
        SerialFault::DropReply { after: usize::MAX },
        Duration::from_secs(2),
    );
    assert_recovered(&outcome, &report);
}

#[test]
fn grbl_brief_stall_is_survived() {
    let (outcome, fired, report, _) = grbl_case(
        SerialFault::Stall {
            after: MID_JOB,
            duration: Duration::from_millis(400),
        },
        Duration::from_secs(2),
    );
    assert!(fired);
    assert_recovered(&outcome, &report);
}

#[test]
fn grbl_stall_beyond_the_timeout_is_a_safe_stop() {
    let (outcome, fired, report, _) = grbl_case(
        SerialFault::Stall {
            after: MID_JOB,
            duration: Duration::from_millis(2500),
        },
        Duration::from_millis(800),
    );
    assert!(fired);
    assert_safe_stop(&outcome, &report, &["no answer"]);
}

#[test]
fn grbl_killed_mid_job_is_a_safe_stop() {
    // The command timeout only bounds the wait: the closed port is seen at once, but
    // with the cores busy the link's own task ran more than 2 s late once.
    let (outcome, fired, report, _) = grbl_case(
        SerialFault::Kill { after: MID_JOB },
        Duration::from_secs(20),
    );
    assert!(fired);
    assert_safe_stop(&outcome, &report, &["the port closed"]);
}

#[test]
fn grbl_lost_reply_is_a_safe_stop_not_a_resend() {
    let (outcome, fired, report, sent) = grbl_case(
        SerialFault::DropReply { after: MID_JOB },
        Duration::from_millis(800),
    );
    assert!(fired);
    assert_safe_stop(&outcome, &report, &["no answer"]);
    // The line is not sent again: without its `ok` nobody knows whether GRBL took it.
    let error = report.error.clone().unwrap();
    let unanswered = error.split('`').nth(1).expect("the error names the line");
    // Status requests (`?`, real-time) fall between lines.
    let times = sent
        .lines()
        .filter(|l| l.replace('?', "") == unanswered)
        .count();
    assert_eq!(times, 1, "`{unanswered}` sent {times} times");
}

#[test]
fn grbl_corrupted_reply_is_a_safe_stop() {
    let (outcome, fired, report, _) = grbl_case(
        SerialFault::CorruptReply { after: MID_JOB },
        Duration::from_millis(800),
    );
    assert!(fired);
    // The garbled `ok` (`pk`) is named in the error, so it reads apart from a lost one.
    assert_safe_stop(&outcome, &report, &["sent `pk`"]);
}

#[test]
fn grbl_alarm_mid_job_is_a_safe_stop_naming_it() {
    // A line from elsewhere (a pendant) runs into the soft limit: GRBL raises ALARM:2 and
    // stops; the job must stop too, saying so, and move no more.
    let (outcome, fired, report, _) = grbl_case(
        SerialFault::Inject {
            after: MID_JOB,
            bytes: b"G53G0X300\n",
        },
        Duration::from_secs(2),
    );
    assert!(fired);
    assert_safe_stop(&outcome, &report, &["alarm 2: soft limit"]);
}

#[test]
fn grbl_late_reply_within_the_timeout_is_survived() {
    let (outcome, fired, report, _) = grbl_case(
        SerialFault::LateReply {
            after: MID_JOB,
            delay: Duration::from_millis(300),
        },
        Duration::from_secs(2),
    );
    assert!(fired);
    assert_recovered(&outcome, &report);
}

/// Modbus requests per target: the drives are polled while they move, so "mid-job" is
/// a larger count than on GRBL.
const MODBUS_MID_JOB: usize = 150;

#[test]
fn modbus_rtu_lost_reply_is_retried_and_the_job_recovers() {
    let (outcome, fired, report) = modbus_rtu_case(
        SerialFault::DropReply {
            after: MODBUS_MID_JOB,
        },
        Duration::from_millis(300),
        2,
    );
    assert!(fired);
    assert_recovered(&outcome, &report);
}

#[test]
fn modbus_rtu_corrupted_reply_is_retried_and_the_job_recovers() {
    let (outcome, fired, report) = modbus_rtu_case(
        SerialFault::CorruptReply {
            after: MODBUS_MID_JOB,
        },
        Duration::from_millis(300),
        2,
    );
    assert!(fired);
    assert_recovered(&outcome, &report);
}

#[test]
fn modbus_rtu_brief_stall_is_survived() {
    let (outcome, fired, report) = modbus_rtu_case(
        SerialFault::Stall {
            after: MODBUS_MID_JOB,
            duration: Duration::from_millis(400),
        },
        Duration::from_millis(300),
        2,
    );
    assert!(fired);
    assert_recovered(&outcome, &report);
}

#[test]
fn modbus_rtu_stall_beyond_the_retries_is_a_safe_stop() {
    let (outcome, fired, report) = modbus_rtu_case(
        SerialFault::Stall {
            after: MODBUS_MID_JOB,
            duration: Duration::from_millis(3000),
        },
        Duration::from_millis(200),
        2,
    );
    assert!(fired);
    assert_safe_stop(&outcome, &report, &["no answer", "timed out", "timeout"]);
}

#[test]
fn modbus_rtu_killed_mid_job_is_a_safe_stop() {
    let (outcome, fired, report) = modbus_rtu_case(
        SerialFault::Kill {
            after: MODBUS_MID_JOB,
        },
        Duration::from_millis(300),
        2,
    );
    assert!(fired);
    assert_safe_stop(&outcome, &report, &["closed", "link failed", "no answer"]);
}

/// Lines from the driver: the 6-target job sends about 360 (the bring-up's SDOs, NMT and
/// homing about 210, then some 25 per target): 300 is mid-job.
const CAN_MID_JOB: usize = 300;

#[test]
fn canopen_brief_stall_within_the_heartbeat_budget_is_survived() {
    let (outcome, fired, report) = canopen_case(
        SerialFault::Stall {
            after: CAN_MID_JOB,
            duration: Duration::from_millis(150),
        },
        Duration::from_millis(600),
    );
    assert!(fired);
    assert_recovered(&outcome, &report);
}

#[test]
fn canopen_stall_beyond_the_heartbeat_timeout_is_a_safe_stop() {
    let (outcome, fired, report) = canopen_case(
        SerialFault::Stall {
            after: CAN_MID_JOB,
            duration: Duration::from_millis(2000),
        },
        Duration::from_millis(350),
    );
    assert!(fired);
    assert_safe_stop(&outcome, &report, &["heartbeat", "no answer", "timed out"]);
}

#[test]
fn canopen_adapter_killed_mid_job_is_a_safe_stop() {
    let (outcome, fired, report) = canopen_case(
        SerialFault::Kill { after: CAN_MID_JOB },
        Duration::from_millis(350),
    );
    assert!(fired);
    assert_safe_stop(
        &outcome,
        &report,
        &["closed", "link failed", "heartbeat", "no answer"],
    );
}

#[test]
fn canopen_lost_frame_is_survived_or_stops_safely() {
    let (outcome, fired, report) = canopen_case(
        SerialFault::DropReply { after: CAN_MID_JOB },
        Duration::from_millis(600),
    );
    assert!(fired);
    // One frame lost: a PDO or heartbeat is refreshed by the next one; a lost SDO reply
    // times out. Either way the job ends cleanly.
    eprintln!("canopen, frame lost: {outcome:?}");
    match &outcome {
        Outcome::Recovered => assert_recovered(&outcome, &report),
        Outcome::SafeStop { .. } => {
            assert_safe_stop(&outcome, &report, &["no answer", "timed out", "sdo"])
        }
    }
}

#[test]
fn canopen_corrupted_frame_is_survived_or_stops_safely() {
    let (outcome, fired, report) = canopen_case(
        SerialFault::CorruptReply { after: CAN_MID_JOB },
        Duration::from_millis(600),
    );
    assert!(fired);
    eprintln!("canopen, frame corrupted: {outcome:?}");
    match &outcome {
        Outcome::Recovered => assert_recovered(&outcome, &report),
        Outcome::SafeStop { .. } => assert_safe_stop(
            &outcome,
            &report,
            &["no answer", "timed out", "sdo", "slcan", "garbled"],
        ),
    }
}

#[test]
fn modbus_tcp_lost_reply_is_retried_and_the_job_recovers() {
    let (outcome, fired, report) = modbus_tcp_case(
        SerialFault::DropReply {
            after: MODBUS_MID_JOB,
        },
        Duration::from_millis(300),
        2,
    );
    assert!(fired);
    assert_recovered(&outcome, &report);
}

#[test]
fn modbus_tcp_reply_with_a_wrong_transaction_id_is_not_taken() {
    let (outcome, fired, report) = modbus_tcp_case(
        SerialFault::CorruptReply {
            after: MODBUS_MID_JOB,
        },
        Duration::from_millis(300),
        2,
    );
    assert!(fired);
    assert_recovered(&outcome, &report);
}

#[test]
fn modbus_tcp_late_reply_within_the_timeout_is_survived() {
    let (outcome, fired, report) = modbus_tcp_case(
        SerialFault::LateReply {
            after: MODBUS_MID_JOB,
            delay: Duration::from_millis(150),
        },
        Duration::from_millis(500),
        2,
    );
    assert!(fired);
    assert_recovered(&outcome, &report);
}

#[test]
fn modbus_tcp_device_gone_mid_job_is_a_safe_stop() {
    let (outcome, fired, report) = modbus_tcp_case(
        SerialFault::Kill {
            after: MODBUS_MID_JOB,
        },
        Duration::from_millis(300),
        2,
    );
    assert!(fired);
    assert_safe_stop(
        &outcome,
        &report,
        &["closed", "link failed", "no answer", "refused", "reset"],
    );
}

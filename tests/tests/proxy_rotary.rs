//! The live pass-through with the rotary table's 5-axis rewrite: a sender streams an
//! X Y Z A C program to the gateway's pseudo-terminal; the gateway rewrites every line
//! for the table's location errors and streams the pieces to the GRBL emulator (six
//! axes, grblHAL letters, the A/C table of source B behind it) on another
//! pseudo-terminal. Where the emulated axes really ended each move goes through the
//! simulation's own chain (`world::rotary`, not the `rotary` crate's) and is compared
//! with the programmed tool tip and direction; the status the sender sees is in
//! programmed coordinates.

use drivers::open_grbl_line as open_controller;
use emulators::grbl::{GrblConfig, GrblDevice, GrblPty};
use job::rotary::RotaryJob;
use proxy::{serve, Ending, FiveAxisRewriter, Proxy, SenderPort};
use rotary::rewrite::{RewriteOptions, RotaryRewriter};
use rotary::{Axes, MachineConstants, RotaryMachine};
use std::time::Duration;
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use world::axes::{lock_axes, AxesMachine};

/// Several orientations over the A range, C all round; feed moves turn both rotary axes.
const PROGRAM: &str = "(five-axis pass-through)
G21 G90 G94
G0 X10 Y5 Z-170 A0 C0
G1 X12 Y6 Z-175 A15 C30 F800
G1 X-8 Y4 Z-180 A30 C120
G1 X20 Y-10 Z-185 A45 C200
G1 X-15 Y12 Z-178 A60 C290
G1 X5 Y-20 Z-190 A85 C350
G0 X0 Y0 Z-150 A10 C10
";

/// The programmed points (each move's end).
fn programmed() -> Vec<Axes> {
    let mut known = [0.0; 5];
    let mut out = Vec::new();
    for line in PROGRAM.lines() {
        let mut moved = false;
        for word in line.split_whitespace() {
            let (letter, value) = word.split_at(1);
            if let (Some(i), Ok(v)) = ("XYZAC".find(letter), value.parse::<f64>()) {
                known[i] = v;
                moved = true;
            }
        }
        if moved {
            out.push(Axes::new(known[0], known[1], known[2], known[3], known[4]));
        }
    }
    out
}

/// A plain sender: each line, then its `ok` or `error:N`; at the end `?` until idle.
/// Returns every line's answer and the last status report.
async fn send(path: String) -> (Vec<String>, String) {
    use tokio_serial::SerialPortBuilderExt;
    let port = tokio_serial::new(&path, 115_200)
        .open_native_async()
        .expect("open the gateway's port");
    let (read, mut write) = tokio::io::split(port);
    let mut lines = BufReader::new(read).lines();
    let mut next = async || -> String {
        tokio::time::timeout(Duration::from_secs(30), lines.next_line())
            .await
            .expect("the gateway answers")
            .expect("read")
            .expect("a line")
    };
    let mut answers = Vec::new();
    for line in PROGRAM.lines() {
        write
            .write_all(format!("{line}\n").as_bytes())
            .await
            .unwrap();
        loop {
            let got = next().await;
            let got = got.trim().to_string();
            if got == "ok" || got.starts_with("error:") {
                answers.push(got);
                break;
            }
        }
    }
    let status = loop {
        write.write_all(b"?").await.unwrap();
        let got = next().await;
        if got.starts_with("<Idle") {
            break got;
        }
    };
    (answers, status)
}

#[test]
fn a_five_axis_program_through_the_pass_through_lands_on_the_programmed_tip_and_direction() {
    pass_through_lands_on_the_program(|path| tokio::spawn(send(path)));
}

/// The same with the independent Python sender of `tests/interop/grbl_sender.py` (what UGS
/// and CNCjs do at connect, then character counting; whitespace and comments stripped as
/// GRBL senders do): its status parsing and streaming against the 5-axis pass-through.
#[test]
fn an_independent_sender_streams_a_five_axis_program_through_the_pass_through() {
    if let Some(why) = system_tests::python_missing("serial", "pyserial") {
        panic!("a peer of this test is missing (install every test peer with tests/install-peers.sh, README: Set-up): {why}");
    }
    pass_through_lands_on_the_program(|path| {
        tokio::task::spawn_blocking(move || {
            let dir = tempfile::tempdir().unwrap();
            let program = dir.path().join("five-axis.nc");
            std::fs::write(&program, PROGRAM).unwrap();
            let out = system_tests::grbl_sender(std::path::Path::new(&path), &program)
                .output()
                .expect("python3 runs");
            let v = system_tests::sender_json(&out);
            assert_eq!(v["acknowledged"], PROGRAM.lines().count() as u64, "{v}");
            let mut answers = vec!["ok".to_string(); PROGRAM.lines().count()];
            for e in v["errors"].as_array().unwrap() {
                answers.push(e.to_string());
            }
            (answers, v["final_status"].as_str().unwrap().to_string())
        })
    });
}

/// A sender (given the gateway's port) streams [`PROGRAM`] through the pass-through with
/// the table's errors; the emulated axes land on the programmed tip and direction, and
/// the sender sees programmed coordinates.
fn pass_through_lands_on_the_program(
    sender: impl FnOnce(String) -> tokio::task::JoinHandle<(Vec<String>, String)>,
) {
    let job = RotaryJob::default();
    let sim = job.simulated().sim;
    let t = sim.errors;
    // The model the gateway rewrites with: the table's errors as identified (here the
    // injected ones; the identification is tested elsewhere).
    let errors = job::rotary::injected_errors(&t);
    let constants = MachineConstants::default();
    let model = RotaryMachine::with_errors(constants, errors);
    let axes = AxesMachine::new(Box::new(world::rotary::RotaryWorkpiece {
        sim: sim.clone(),
    }))
    .shared();
    lock_axes(&axes).record_move_ends();
    let rt = system_tests::runtime();
    let (ending, answers, status) = rt.block_on(async {
        let emulator = GrblPty::spawn(
            GrblDevice::with_axes(axes.clone(), GrblConfig::default()),
            None,
        )
        .expect("pseudo-terminal");
        let (mut controller, banner) =
            open_controller(emulator.path(), 115_200, Duration::from_secs(10))
                .await
                .unwrap();
        assert!(banner.contains("Grbl"), "{banner}");
        let mut sender_port = SenderPort::create(None).unwrap();
        let client = sender(sender_port.path().to_string());
        let rewriter = RotaryRewriter::new(&model, RewriteOptions::default());
        let mut proxy = Proxy::with_rewriter(Box::new(FiveAxisRewriter::new(rewriter)));
        proxy.start();
        let ending = serve(
            &mut proxy,
            &mut sender_port,
            &mut controller,
            std::future::pending(),
        )
        .await;
        let (answers, status) = client.await.unwrap();
        drop(emulator);
        (ending, answers, status)
    });
    let Ending::SenderLeft(account) = &ending else {
        panic!("{ending:?}")
    };
    assert!(
        account.refused.is_empty() && account.not_sent.is_empty(),
        "{account:?}"
    );
    assert!(answers.iter().all(|a| a == "ok"), "{answers:?}");

    // The truth where the axes ended, against the programmed tip and direction.
    let ends: Vec<Axes> = lock_axes(&axes)
        .take_move_ends()
        .iter()
        .map(|e| Axes::new(e[0], e[1], e[2], e[3], e[5]))
        .collect();
    let ideal = RotaryMachine::nominal(constants);
    let (mut tip_before, mut tip_after, mut dir_before, mut dir_after) =
        (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for p in programmed() {
        let want = ideal.forward(&p);
        let truth = |c: &Axes| sim.tool_in_workpiece([c.x, c.y, c.z, c.a, c.c]);
        let err = |c: &Axes| {
            let (tip, dir) = truth(c);
            (
                (tip - want.position).norm(),
                dir.dot(&want.direction).clamp(-1.0, 1.0).acos(),
            )
        };
        let plain = err(&p);
        // The move end nearest the programmed point (each line's last piece).
        let reached = ends
            .iter()
            .map(err)
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .expect("moves ran");
        tip_before = tip_before.max(plain.0);
        dir_before = dir_before.max(plain.1);
        tip_after = tip_after.max(reached.0);
        dir_after = dir_after.max(reached.1);
    }
    eprintln!(
        "tip max {tip_before:.4} -> {tip_after:.5} mm, direction max {dir_before:.6} -> {dir_after:.7} rad"
    );
    assert!(
        tip_before > 0.1,
        "the table's errors move the tip: {tip_before}"
    );
    assert!(
        tip_after <= 0.05 * tip_before,
        "{tip_after} vs {tip_before}"
    );
    assert!(
        dir_after <= 0.05 * dir_before,
        "{dir_after} vs {dir_before}"
    );

    // The sender sees the programmed position: the last point, X0 Y0 Z-150 A10 C10.
    let mpos: Vec<f64> = status
        .split('|')
        .find_map(|f| f.strip_prefix("MPos:"))
        .expect("MPos in the report")
        .split(',')
        .map(|v| v.parse().unwrap())
        .collect();
    for (got, want) in [mpos[0], mpos[1], mpos[2], mpos[3], mpos[5]]
        .iter()
        .zip([0.0, 0.0, -150.0, 10.0, 10.0])
    {
        assert!((got - want).abs() <= 0.0015, "{status}");
    }
    // The controller itself is elsewhere: the correction is tenths of a millimetre.
    let last = ends.last().unwrap();
    assert!((last.x - 0.0).abs() + (last.y - 0.0).abs() + (last.z + 150.0).abs() > 0.05);
}

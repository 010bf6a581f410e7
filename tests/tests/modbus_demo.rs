//! The demo job with its stage behind the Modbus drive emulator (loopback TCP and a
//! real pseudo-terminal), driven by the Modbus driver: the in-process demo's figure
//! (after-compensation max <= 1 um) must hold over Modbus too.

use devices::open_devices_async;
use job::demo::over_modbus;
use job::modbus::ModbusLink;
use job::{Job, StageSpec};
use runner::run_job;
use system_tests::{assert_demo_figure, runtime};

fn run(mut job: Job, rtu: bool, targets: usize) -> compensation::report::Report {
    over_modbus(&mut job, rtu).unwrap();
    // A few targets spread over the travel keep the debug-build test fast.
    let n = job.targets.len();
    job.targets = (0..targets)
        .map(|k| job.targets[k * (n - 1) / (targets - 1).max(1)])
        .collect();
    runtime().block_on(async {
        let mut devices = open_devices_async(&job).await.unwrap();
        let name = devices.stage.info().name.clone();
        assert!(
            name.starts_with(if rtu {
                "Modbus RTU /dev/"
            } else {
                "Modbus TCP 127.0.0.1:"
            }),
            "{name}"
        );
        run_job(&job, &mut devices, &mut |_, _| {}).await
    })
}

#[test]
fn demo_over_modbus_tcp_compensates_to_within_a_micrometre() {
    assert_demo_figure(&run(Job::demo(), false, 4), 20.0);
}

#[test]
fn demo_over_modbus_rtu_on_a_pty_compensates_to_within_a_micrometre() {
    assert_demo_figure(&run(Job::demo(), true, 3), 20.0);
}

#[test]
fn modbus_stage_config_is_checked_with_file_line_and_key() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/gateway");
    let job = Job::load(&dir.join("modbus-demo.toml")).unwrap();
    let StageSpec::Modbus(spec) = &job.stage else {
        panic!("not a modbus stage")
    };
    assert!(matches!(spec.link, ModbusLink::Emulate { rtu: false, .. }));
    assert_eq!(spec.axes.iter().map(|a| a.unit).collect::<Vec<_>>(), [1, 2]);
    let text = std::fs::read_to_string(dir.join("modbus-demo.toml")).unwrap();
    let bad = |from: &str, to: &str| {
        assert!(text.contains(from), "{from}");
        let doc = protocol::config::ConfigDoc::from_text("job.toml", &text.replace(from, to), &dir);
        Job::from_doc(&doc).unwrap_err().to_string()
    };
    let e = bad("{ axis = \"y\", unit = 2,", "{ axis = \"y\", unit = 1,");
    assert!(
        e.contains("job.toml:") && e.contains("key `stage.axes[1].unit`") && e.contains("twice"),
        "{e}"
    );
    // A feed limit of 0 or below would stall every move: refused at load.
    for feed in ["0.0", "-100.0", "nan"] {
        let e = bad(
            "{ axis = \"x\", unit = 1, min_mm = 0.0, max_mm = 200.0 }",
            &format!("{{ axis = \"x\", unit = 1, min_mm = 0.0, max_mm = 200.0, max_feed_mm_min = {feed} }}"),
        );
        assert!(
            e.contains("key `stage.axes[0].max_feed_mm_min`"),
            "{feed}: {e}"
        );
    }
    let e = bad("transport = \"tcp\"", "transport = \"udp\"");
    assert!(e.contains("key `stage.transport`"), "{e}");
    let e = bad(
        "emulate = \"../machines/c5-stage.toml\"",
        "tcp = \"10.0.0.1:502\"\nrtu = \"/dev/ttyUSB0\"",
    );
    assert!(e.contains("exactly one of"), "{e}");
    // A profile that fails its own checks is reported in its own file.
    let e = bad(
        "profile = \"../drives/generic.toml\"",
        "profile = \"../drives/nope.toml\"",
    );
    assert!(
        e.contains("key `stage.profile`") && e.contains("nope.toml"),
        "{e}"
    );
    // A real link with the simulated camera is refused when opened, clearly.
    let mut real = job.clone();
    if let StageSpec::Modbus(s) = &mut real.stage {
        s.link = ModbusLink::Tcp("127.0.0.1:1".parse().unwrap());
    }
    let e = runtime().block_on(open_devices_async(&real)).err().unwrap();
    assert!(e.to_string().contains("simulated camera"), "{e}");
}

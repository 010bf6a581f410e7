//! The demo job with its stage behind the CiA 402 drive emulator on an SLCAN
//! pseudo-terminal, driven by the CANopen driver: the in-process demo's figure
//! (after-compensation max <= 1 um) must hold over CANopen too.

use devices::open_devices_async;
use job::canopen::CanopenLink;
use job::demo::over_canopen;
use job::{Job, StageSpec};
use runner::run_job;
use system_tests::{assert_demo_figure, runtime};

#[test]
fn demo_over_canopen_compensates_to_within_a_micrometre() {
    let mut job = Job::demo();
    over_canopen(&mut job).unwrap();
    // Targets spread over the whole travel (corners included) keep the debug build fast.
    let n = job.targets.len();
    let pick = [0, 5, n / 2, n - 6, n - 1];
    job.targets = pick.iter().map(|&k| job.targets[k]).collect();
    let report = runtime().block_on(async {
        let mut devices = open_devices_async(&job).await.unwrap();
        let name = devices.stage.info().name.clone();
        assert!(name.starts_with("CANopen CiA 402 on slcan /dev/"), "{name}");
        assert!(name.ends_with("X = node 1, Y = node 2"), "{name}");
        // Positioning drives: one target at a time, no program to stream.
        let caps = devices.stage.capabilities();
        assert!(!caps.program_streaming && !caps.probing, "{caps:?}");
        assert!(caps.rotary_axes.is_empty(), "{caps:?}");
        run_job(&job, &mut devices, &mut |_, _| {}).await
    });
    assert_demo_figure(&report, 20.0);
}

#[test]
fn canopen_stage_config_is_checked_with_file_line_and_key() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/gateway");
    let job = Job::load(&dir.join("canopen-demo.toml")).unwrap();
    let StageSpec::Canopen(spec) = &job.stage else {
        panic!("not a canopen stage")
    };
    assert!(matches!(spec.link, CanopenLink::Emulate { .. }));
    assert_eq!(spec.axes.iter().map(|a| a.node).collect::<Vec<_>>(), [1, 2]);
    assert_eq!(spec.options.heartbeat_ms, 100);
    let text = std::fs::read_to_string(dir.join("canopen-demo.toml")).unwrap();
    let bad = |from: &str, to: &str| {
        assert!(text.contains(from), "{from}");
        let doc = protocol::config::ConfigDoc::from_text("job.toml", &text.replace(from, to), &dir);
        Job::from_doc(&doc).unwrap_err().to_string()
    };
    let e = bad("{ axis = \"y\", node = 2,", "{ axis = \"y\", node = 1,");
    assert!(
        e.contains("job.toml:") && e.contains("key `stage.axes[1].node`") && e.contains("twice"),
        "{e}"
    );
    let e = bad("node = 2,", "node = 128,");
    assert!(
        e.contains("key `stage.axes[1].node`") && e.contains("1..=127"),
        "{e}"
    );
    let e = bad("bitrate = 1000000", "bitrate = 83333");
    assert!(e.contains("key `stage.bitrate`"), "{e}");
    let e = bad(
        "emulate = \"../machines/c5-stage.toml\"",
        "emulate = \"../machines/c5-stage.toml\"\nslcan = \"/dev/ttyACM0\"",
    );
    assert!(e.contains("exactly one of `slcan`"), "{e}");
    let e = bad(
        "{ axis = \"x\", node = 1, counts_per_mm = 2000.0",
        "{ axis = \"x\", node = 1, counts_per_mm = 1000.0",
    );
    assert!(
        e.contains("key `stage.axes`") && e.contains("counts_per_mm 1000"),
        "{e}"
    );
    // An EDS without what the driver needs is refused, naming the EDS.
    let eds = std::fs::read_to_string(dir.join("../canopen/drive.eds")).unwrap();
    let tmp = std::env::temp_dir().join(format!("canopen-demo-{}.eds", std::process::id()));
    std::fs::write(&tmp, eds.replace("[6081]\nParameterName=Profile velocity\nObjectType=0x7\nDataType=0x0007\nAccessType=rww\nDefaultValue=100000\nPDOMapping=1", "[6081]\nParameterName=Profile velocity\nObjectType=0x7\nDataType=0x0007\nAccessType=rww\nDefaultValue=100000\nPDOMapping=0")).unwrap();
    let e = bad(
        "eds = \"../canopen/drive.eds\"",
        &format!("eds = \"{}\"", tmp.display()),
    );
    assert!(
        e.contains("key `stage.eds`")
            && e.contains("0x6081 (profile velocity) is not PDO-mappable"),
        "{e}"
    );
    std::fs::write(
        &tmp,
        eds.replace(
            "DataType=0x0007\nAccessType=rww\nDefaultValue=100000",
            "DataType=0x0099\nAccessType=rww\nDefaultValue=100000",
        ),
    )
    .unwrap();
    let e = bad(
        "eds = \"../canopen/drive.eds\"",
        &format!("eds = \"{}\"", tmp.display()),
    );
    assert!(e.contains("key `[6081] DataType`"), "{e}");
    let _ = std::fs::remove_file(&tmp);
    // A real bus with the simulated camera is refused when opened, clearly.
    let mut real = job.clone();
    if let StageSpec::Canopen(s) = &mut real.stage {
        s.link = CanopenLink::Bus(drivers::can::BusSpec::SocketCan {
            interface: "can0".into(),
        });
    }
    let e = runtime().block_on(open_devices_async(&real)).err().unwrap();
    assert!(e.to_string().contains("simulated camera"), "{e}");
}

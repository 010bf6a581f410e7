//! The demo job with its stage behind the GRBL emulator on a real pseudo-terminal,
//! driven by the GRBL serial driver: the same figures as the in-process demo
//! (`compensation.rs` holds the in-process run to the same bounds).

use devices::open_devices_async;
use job::demo::over_grbl;
use job::{GrblLink, Job, StageSpec};
use runner::run_job;
use system_tests::{assert_demo_figure, runtime};

#[test]
fn demo_over_grbl_compensates_to_within_a_micrometre_like_the_in_process_demo() {
    let rt = runtime();
    let mut job = Job::demo();
    over_grbl(&mut job).unwrap();
    assert!(matches!(
        job.stage,
        StageSpec::Grbl {
            link: GrblLink::Emulate(_),
            ..
        }
    ));
    let report = rt.block_on(async {
        let mut devices = open_devices_async(&job).await.unwrap();
        assert!(
            devices.stage.info().name.contains("GRBL 1.1h"),
            "{}",
            devices.stage.info().name
        );
        // GRBL runs streamed programs and probes; it drives no rotary axis.
        let caps = devices.stage.capabilities();
        assert!(caps.program_streaming && caps.probing, "{caps:?}");
        assert!(
            !caps.table_upload && caps.rotary_axes.is_empty(),
            "{caps:?}"
        );
        run_job(&job, &mut devices, &mut |_, _| {}).await
    });
    assert_demo_figure(&report, 20.0);
}

#[test]
fn grbl_stage_config_needs_a_port_or_an_emulated_machine() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/gateway");
    let job = Job::load(&dir.join("grbl-demo.toml")).unwrap();
    assert!(matches!(
        job.stage,
        StageSpec::Grbl {
            link: GrblLink::Emulate(_),
            baud: 115_200
        }
    ));
    // A real port with the simulated camera is refused when opened, clearly.
    let mut real = job.clone();
    real.stage = StageSpec::Grbl {
        link: GrblLink::Port("/dev/ttyUSB0".into()),
        baud: 115_200,
    };
    let e = runtime().block_on(open_devices_async(&real)).err().unwrap();
    assert!(e.to_string().contains("simulated camera"), "{e}");
}

//! The demo job with its frames over GigE Vision (the camera emulator on a loopback UDP
//! port, read by the GigE driver) and its stage over GRBL on a pseudo-terminal: two real
//! links, one simulated machine; the same figure as the in-process demo (after
//! compensation, max error <= 1 um). A few targets keep the debug build fast.

use devices::{open_devices, open_devices_async};
use job::demo::{over_gige, over_grbl};
use job::{CameraSpec, Job};
use runner::run_job;
use system_tests::{assert_demo_figure, runtime_two_workers};

fn few_targets(job: &mut Job) {
    job.targets = vec![[12.0, 12.0], [105.0, 80.0], [198.0, 148.0], [12.0, 148.0]];
}

#[test]
fn demo_over_gige_and_grbl_compensates_to_within_a_micrometre() {
    let rt = runtime_two_workers();
    let mut job = Job::demo();
    over_grbl(&mut job).unwrap();
    over_gige(&mut job).unwrap();
    few_targets(&mut job);
    let report = rt.block_on(async {
        let mut devices = open_devices_async(&job).await.unwrap();
        let info = devices.camera.info().clone();
        assert_eq!(info.model, "XYGateway SimMono", "{info:?}");
        assert_eq!((info.width, info.height, info.bit_depth), (1280, 1024, 8));
        run_job(&job, &mut devices, &mut |_, _| {}).await
    });
    assert_demo_figure(&report, 10.0);
}

#[test]
fn gige_demo_config_emulates_the_camera_and_refuses_bad_keys() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/gateway");
    let job = Job::load(&dir.join("gige-demo.toml")).unwrap();
    assert!(
        matches!(
            job.camera,
            CameraSpec::EmulatedGige {
                packet_size: 8192,
                ..
            }
        ),
        "{:?}",
        job.camera
    );
    // The synchronous opener says where GigE cameras are opened.
    let e = open_devices(&job).err().unwrap().to_string();
    assert!(e.contains("open_devices_async"), "{e}");
    let text = std::fs::read_to_string(dir.join("gige-demo.toml")).unwrap();
    let bad = |from: &str, to: &str| {
        let t = text.replace(from, to);
        let doc = protocol::config::ConfigDoc::from_text("bad.toml", &t, &dir);
        Job::from_doc(&doc).expect_err("refused").to_string()
    };
    let e = bad("packet_size = 8192", "packet_size = 100");
    assert!(e.contains("camera.packet_size"), "{e}");
    let e = bad(
        "model = \"../cameras/mono-1.3mp.toml\"\npacket_size",
        "packet_size",
    );
    assert!(e.contains("camera.camera") && e.contains("needs"), "{e}");
    let e = bad(
        "packet_size = 8192",
        "packet_size = 8192\ncamera = \"127.0.0.1\"",
    );
    assert!(e.contains("not both"), "{e}");
    let e = bad("driver = \"gige\"", "driver = \"replay\"");
    assert!(e.contains("camera.folder"), "{e}");
}

#[test]
fn a_real_camera_address_with_a_simulated_machine_is_refused_clearly() {
    let rt = runtime_two_workers();
    let mut job = Job::demo();
    job.camera = CameraSpec::Gige {
        device: "127.0.0.1:9".into(),
        packet_size: 1500,
    };
    let e = rt
        .block_on(open_devices_async(&job))
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("cannot see a simulated machine"), "{e}");
}

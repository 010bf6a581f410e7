//! The `aravis` camera backend. Without cargo feature `aravis`: a clear NotAvailable.
//! With it (`cargo test -p drivers --features aravis --test aravis_backend`): Aravis
//! opens our GigE Vision emulator on 127.0.0.1:3956 and the frames it delivers equal the
//! frames rendered, bit for bit.

use drivers::aravis::AravisCamera;
use std::time::Duration;

#[cfg(not(feature = "aravis"))]
#[test]
fn without_the_feature_the_backend_says_how_to_get_it() {
    let rt = tokio::runtime::Builder::new_current_thread()
        .build()
        .unwrap();
    let e = rt
        .block_on(AravisCamera::open(
            Some("127.0.0.1"),
            Duration::from_secs(1),
        ))
        .err()
        .expect("not available in this build");
    assert!(
        matches!(e, drivers::DriverError::NotAvailable { .. }),
        "{e}"
    );
    let m = e.to_string();
    assert!(
        m.contains("--features drivers/aravis") && m.contains("libaravis-dev"),
        "{m}"
    );
    assert!(m.contains("`gige` backend"), "{m}");
}

#[cfg(feature = "aravis")]
#[test]
fn aravis_streams_our_emulator_bit_for_bit() {
    use drivers::Camera;
    use emulators::gige::{GigeCameraServer, GigeConfig, GigeServerOptions};
    let d = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config");
    let m = world::machine::MachineConfig::load(&d.join("machines/c5-stage.toml")).unwrap();
    let mut c = world::camera::CameraModel::load(&d.join("cameras/mono-1.3mp.toml")).unwrap();
    (c.width, c.height) = (320, 240);
    let b = protocol::Board::load(&d.join("boards/dot-grid-0.5mm.toml")).unwrap();
    let rig = world::shared_rig(m, b, c);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let _emu = GigeCameraServer::spawn(
            rig.clone(),
            GigeServerOptions {
                bind: "127.0.0.1:3956".parse().unwrap(),
                broadcast: false,
                config: GigeConfig::default(),
            },
        )
        .await
        .expect("127.0.0.1:3956 free");
        let mut cam = AravisCamera::open(Some("127.0.0.1"), Duration::from_secs(10))
            .await
            .unwrap();
        assert_eq!((cam.info().width, cam.info().height), (320, 240));
        for _ in 0..2 {
            let expected = rig.lock().unwrap().clone().grab().0;
            let f = cam.grab().await.unwrap();
            assert!(f.image == expected);
        }
    });
}

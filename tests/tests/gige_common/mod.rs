//! Shared set-up of the GigE Vision system tests: a simulated rig (optionally with a
//! smaller sensor so debug builds stay fast), the emulated camera on a loopback port
//! and the driver connected to it.

// Not every test binary that includes this module uses all of it.
#![allow(dead_code, unused_imports)]

use drivers::gige::{GigeCamera, GigeOptions};
use emulators::gige::{GigeCameraServer, GigeConfig, GigeServerOptions};
use std::time::Duration;

pub use world::SharedRig;

/// The demo rig, its camera cropped to `w` x `h` at `bit_depth` (None: as configured).
pub fn rig(size: Option<(u32, u32)>, bit_depth: Option<u8>) -> SharedRig {
    system_tests::reference_rig_with_camera(|c| {
        if let Some((w, h)) = size {
            c.width = w;
            c.height = h;
        }
        if let Some(b) = bit_depth {
            c.bit_depth = b;
            if b == 16 {
                c.noise_sigma *= 257.0;
            }
        }
    })
}

pub use system_tests::config_dir;
pub use system_tests::runtime_two_workers as runtime;

pub async fn emulator(rig: &SharedRig, config: GigeConfig) -> GigeCameraServer {
    GigeCameraServer::spawn(
        rig.clone(),
        GigeServerOptions {
            config,
            ..Default::default()
        },
    )
    .await
    .expect("emulated camera on loopback")
}

/// Short timeouts: a broken test fails in seconds.
pub fn options() -> GigeOptions {
    GigeOptions {
        timeout: Duration::from_millis(300),
        retries: 2,
        packet_size: 8192,
        frame_timeout: Duration::from_secs(20),
        packet_timeout: Duration::from_millis(200),
        resend_rounds: 3,
        heartbeat_timeout_ms: None,
    }
}

pub async fn connect(emu: &GigeCameraServer, opts: GigeOptions) -> GigeCamera {
    GigeCamera::open(&emu.control_addr().to_string(), opts)
        .await
        .expect("driver opens the emulated camera")
}

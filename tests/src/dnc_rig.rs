//! The rig of the tape-port tests (issue 40): the demo's C5 stage under the coded board,
//! driven by the DNC controller emulator on a pseudo-terminal whose clock is paced by the
//! simulated camera's frames, the tape-only stage on its port, and the camera in lockstep
//! with it. Used by tests/tests/dnc_scan.rs and the `dnc_map_accuracy` example.

use drivers::dnc::{DncAxis, DncOptions, DncSender, DncStage};
use emulators::dnc::{DncConfig, DncDevice, DncPty, DncStats};
use job::Job;
use tokio_serial::SerialPortBuilderExt;
use world::machine::MachineConfig;
use world::{lock, SharedRig};

pub const BAUD: u32 = 115_200;
/// Machine seconds per camera frame (the emulator's clock paced by the frames, not the
/// wall, in lockstep: frame times are multiples of it). A target's dwell of 3 s holds 4
/// frames; the first at rest comes at most 0.75 s after the machine arrives, the stop
/// (1 s still) two frames later, 2.25 s after: whatever the load on the machine running
/// the test.
pub const SECONDS_PER_FRAME: f64 = 0.75;

/// The demo's C5 stage (thermal drift off) under the coded board (every frame says
/// where it is: a plain grid gives the position only modulo its pitch, and a still
/// camera would seem to stop at every target), and the DNC emulator driving it on the
/// camera's frames.
pub fn coded_rig() -> (Job, MachineConfig, SharedRig, DncDevice) {
    let (_, machine) = crate::truth_map::demo_machine();
    let job = Job::load(&crate::config_dir().join("gateway/stepper-coded.toml"))
        .expect("the coded job loads");
    assert!(job.board.code.is_some());
    let rig = devices::new_rig(&job, &machine);
    let dev = DncDevice::new(
        rig.clone(),
        DncConfig {
            seconds_per_frame: Some(SECONDS_PER_FRAME),
            ..DncConfig::default()
        },
    );
    (job, machine, rig, dev)
}

/// The tape-only stage on the emulator's pseudo-terminal (the demo's 200 x 150 mm).
pub fn tape_stage(pty: &DncPty) -> DncStage {
    let port = tokio_serial::new(pty.path(), BAUD)
        .open_native_async()
        .expect("the emulator's port opens");
    let sender = DncSender::from_stream(port, "tape".into(), BAUD, DncOptions::default());
    let axis = |axis, max_mm| DncAxis {
        axis,
        min_mm: 0.0,
        max_mm,
        max_feed_mm_min: 6000.0,
    };
    DncStage::new(
        sender,
        pty.path(),
        vec![axis(drivers::Axis::X, 200.0), axis(drivers::Axis::Y, 150.0)],
    )
}

/// The simulated camera in lockstep with the emulator's clock paced by its frames: each
/// frame waits (on the emulator's counters, not on the wall clock) until the emulator
/// has run the time of the frames before it, so every slice of machine time is seen.
pub struct PacedCamera {
    inner: drivers::sim::SimCamera,
    rig: SharedRig,
    run: tokio::sync::watch::Receiver<DncStats>,
}

#[async_trait::async_trait]
impl drivers::Camera for PacedCamera {
    fn info(&self) -> &drivers::CameraInfo {
        drivers::Camera::info(&self.inner)
    }
    async fn grab(&mut self) -> Result<drivers::Frame, drivers::DriverError> {
        let grabbed = lock(&self.rig).frames();
        // A closed channel (the emulator ended) lets the frame go: the tape fails then.
        let _ = self.run.wait_for(|s| s.frames_run >= grabbed).await;
        drivers::Camera::grab(&mut self.inner).await
    }
}

pub fn paced_camera(pty: &DncPty, rig: &SharedRig) -> PacedCamera {
    PacedCamera {
        inner: drivers::sim::SimCamera::new(rig.clone()),
        rig: rig.clone(),
        run: pty.watch(),
    }
}

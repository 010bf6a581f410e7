//! No motion is based on a bad frame: the compensation job over a GigE Vision camera
//! whose packets are lost for good (resends lost too) stops at the first grab with the
//! incomplete-frame error, and after that grab the stage receives no command at all.

use crate::gige_common;

use async_trait::async_trait;
use devices::Devices;
use drivers::sim::SimStage;
use drivers::{AxisValues, Camera, CameraInfo, DriverError, Frame, Stage, StageInfo, StageStatus};
use emulators::gige::GigeConfig;
use gige_common::*;
use job::Job;
use runner::run_job;
use std::sync::{Arc, Mutex};

type Log = Arc<Mutex<Vec<String>>>;

struct LoggedStage(SimStage, Log);
struct LoggedCamera(drivers::gige::GigeCamera, Log);

#[async_trait]
impl Stage for LoggedStage {
    fn info(&self) -> &StageInfo {
        self.0.info()
    }
    fn capabilities(&self) -> drivers::Capabilities {
        self.0.capabilities()
    }
    async fn home(&mut self) -> Result<(), DriverError> {
        self.1.lock().unwrap().push("home".into());
        self.0.home().await
    }
    async fn move_to(&mut self, t: AxisValues, f: f64) -> Result<(), DriverError> {
        self.1.lock().unwrap().push("move".into());
        self.0.move_to(t, f).await
    }
    async fn move_by(&mut self, d: AxisValues, f: f64) -> Result<(), DriverError> {
        self.1.lock().unwrap().push("move".into());
        self.0.move_by(d, f).await
    }
    async fn position(&mut self) -> Result<AxisValues, DriverError> {
        self.0.position().await
    }
    async fn wait_idle(&mut self) -> Result<(), DriverError> {
        self.0.wait_idle().await
    }
    async fn stop(&mut self) -> Result<(), DriverError> {
        self.0.stop().await
    }
    async fn status(&mut self) -> Result<StageStatus, DriverError> {
        self.0.status().await
    }
}

#[async_trait]
impl Camera for LoggedCamera {
    fn info(&self) -> &CameraInfo {
        self.0.info()
    }
    async fn grab(&mut self) -> Result<Frame, DriverError> {
        let r = self.0.grab().await;
        self.1
            .lock()
            .unwrap()
            .push(if r.is_ok() { "grab ok" } else { "grab failed" }.into());
        r
    }
}

#[test]
fn a_frame_lost_for_good_stops_the_job_before_any_motion_based_on_it() {
    let rt = runtime();
    rt.block_on(async {
        let job = Job::demo();
        let rig = rig(None, None);
        let emu = emulator(
            &rig,
            GigeConfig {
                drop_every: Some(50),
                loss_on_resend: true,
                ..Default::default()
            },
        )
        .await;
        let log: Log = Arc::default();
        let mut opts = options();
        opts.resend_rounds = 1;
        opts.packet_timeout = std::time::Duration::from_millis(50);
        let camera = connect(&emu, opts).await;
        let mut devices = Devices {
            stage: Box::new(LoggedStage(SimStage::new(rig.clone()), log.clone())),
            camera: Box::new(LoggedCamera(camera, log.clone())),
            rig: Some(rig.clone()),
        };
        let report = run_job(&job, &mut devices, &mut |_, _| {}).await;
        let err = report.error.clone().expect("the job stops");
        assert!(err.contains("incomplete frame"), "{err}");
        let log = log.lock().unwrap().clone();
        let first_bad = log
            .iter()
            .position(|e| e == "grab failed")
            .unwrap_or_else(|| panic!("{log:?}"));
        assert!(
            !log[first_bad..].iter().any(|e| e == "move"),
            "motion after a bad frame: {log:?}"
        );
        assert_eq!(report.converged, 0);
    });
}

/// A lost frame is dropped and the camera triggered again, as Aravis drops a bad buffer
/// and keeps streaming: a grab fails only when `GRAB_ATTEMPTS` frames in a row are lost
/// (here every frame is refused, being of another size than declared), and says so;
/// each lost frame is one trigger and is counted. Frames that arrive whole afterwards
/// are taken at the first trigger.
#[test]
fn a_lost_frame_is_retried_a_bounded_number_of_times_and_counted() {
    use drivers::gige::GRAB_ATTEMPTS;
    let rt = runtime();
    rt.block_on(async {
        let rig = rig(Some((160, 120)), None);
        let emu = emulator(&rig, GigeConfig::default()).await;
        let mut cam = connect(&emu, options()).await;
        cam.grab().await.unwrap();
        assert_eq!((emu.frames_sent(), cam.dropped_frames()), (1, 0));
        rig.lock().unwrap().camera_mut().width = 200;
        let m = cam.grab().await.unwrap_err().to_string();
        assert!(
            m.contains("is 200x120 Mono8 but the camera declared 160x120 Mono8")
                && m.contains(&format!(
                    "({GRAB_ATTEMPTS} frames in a row lost; 3 dropped since open)"
                )),
            "{m}"
        );
        // The driver refuses a frame at its leader, before the emulator has counted it
        // as sent: await the count (bounded only against a hang).
        let sent = |n: u64| {
            let mut watch = emu.frames_watch();
            async move {
                tokio::time::timeout(
                    std::time::Duration::from_secs(30),
                    watch.wait_for(|sent| *sent >= n),
                )
                .await
                .expect("the emulator streams the frames it was triggered for")
                .map(|v| *v)
                .unwrap()
            }
        };
        assert_eq!(
            sent(1 + GRAB_ATTEMPTS as u64).await,
            1 + GRAB_ATTEMPTS as u64,
            "one trigger per attempt"
        );
        assert_eq!(cam.dropped_frames(), GRAB_ATTEMPTS as u64);
        rig.lock().unwrap().camera_mut().width = 160;
        let expected = rig.lock().unwrap().clone().grab().0;
        assert!(cam.grab().await.unwrap().image == expected);
        assert_eq!(
            sent(2 + GRAB_ATTEMPTS as u64).await,
            2 + GRAB_ATTEMPTS as u64
        );
        assert_eq!(cam.dropped_frames(), GRAB_ATTEMPTS as u64);
    });
}

//! What the in-process emulators share: the simulated machine (rig) of a job, and the
//! stage that keeps its emulator alive.

use async_trait::async_trait;
use drivers::{
    AxisValues, Capabilities, DriverError, ProbeHit, ProbeMode, Stage, StageInfo, StageStatus,
    StreamError, StreamOptions, StreamReport,
};
use job::Job;
use protocol::config::ConfigDoc;
use std::any::Any;
use std::path::Path;
use world::camera::CameraModel;
use world::machine::MachineConfig;
use world::SharedRig;

/// A stage whose controller or drives are emulated in this process: the emulator (a
/// pseudo-terminal, a server) is kept alive exactly as long as the stage.
pub struct EmulatedStage {
    stage: Box<dyn Stage>,
    _emulator: Box<dyn Any + Send>,
}

impl EmulatedStage {
    pub fn new(stage: Box<dyn Stage>, emulator: impl Any + Send) -> Self {
        Self {
            stage,
            _emulator: Box::new(emulator),
        }
    }
}

#[async_trait]
impl Stage for EmulatedStage {
    fn info(&self) -> &StageInfo {
        self.stage.info()
    }
    fn capabilities(&self) -> Capabilities {
        self.stage.capabilities()
    }
    async fn home(&mut self) -> Result<(), DriverError> {
        self.stage.home().await
    }
    async fn move_to(&mut self, target: AxisValues, feed_mm_min: f64) -> Result<(), DriverError> {
        self.stage.move_to(target, feed_mm_min).await
    }
    async fn move_by(&mut self, delta: AxisValues, feed_mm_min: f64) -> Result<(), DriverError> {
        self.stage.move_by(delta, feed_mm_min).await
    }
    async fn position(&mut self) -> Result<AxisValues, DriverError> {
        self.stage.position().await
    }
    async fn wait_idle(&mut self) -> Result<(), DriverError> {
        self.stage.wait_idle().await
    }
    async fn stop(&mut self) -> Result<(), DriverError> {
        self.stage.stop().await
    }
    async fn status(&mut self) -> Result<StageStatus, DriverError> {
        self.stage.status().await
    }
    async fn probe(
        &mut self,
        target: AxisValues,
        feed: f64,
        mode: ProbeMode,
    ) -> Result<ProbeHit, DriverError> {
        self.stage.probe(target, feed, mode).await
    }
    async fn stream_program(
        &mut self,
        program: &str,
        opts: &StreamOptions,
        progress: &mut (dyn FnMut(protocol::grbl::stream::StreamProgress) + Send),
    ) -> Result<StreamReport, StreamError> {
        self.stage.stream_program(program, opts, progress).await
    }
}

/// What a stage backend opens: the stage, and the rig when the machine is simulated.
pub type OpenedStage = (Box<dyn Stage>, Option<SharedRig>);

/// The simulated machine of a job: `machine` with the job's board, seen by the job's
/// camera optics.
pub fn new_rig(job: &Job, machine: &MachineConfig) -> SharedRig {
    // Replayed frames on a simulated machine: the rig still needs optics; they are
    // never rendered.
    let model = job.camera.model().cloned().unwrap_or_else(reference_camera);
    world::shared_rig(machine.clone(), job.board.clone(), model)
}

fn reference_camera() -> CameraModel {
    let (name, text) = job::EMBEDDED
        .iter()
        .find(|(name, _)| name.ends_with("mono-1.3mp.toml"))
        .expect("the reference camera is embedded");
    let doc = ConfigDoc::from_text(name, text, Path::new("config/cameras"));
    CameraModel::from_doc(&doc).expect("the embedded reference camera is valid")
}

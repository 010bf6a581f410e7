//! The files every emulator's simulated rig is made of: `--machine`, `--board`,
//! `--camera` (the same flags and defaults for the GRBL, Modbus, CANopen, GigE and DNC
//! emulators).

use std::path::PathBuf;
use world::rig::SimRig;

#[derive(clap::Args, Debug, Clone)]
pub struct RigFiles {
    /// Simulated machine file.
    #[arg(long, default_value = "config/machines/c5-stage.toml")]
    pub machine: PathBuf,
    /// Board the camera sees (the rig's board).
    #[arg(long, default_value = "config/boards/dot-grid-0.5mm.toml")]
    pub board: PathBuf,
    /// Camera optics file (sensor size and bit depth: Mono8 or Mono16).
    #[arg(long, default_value = "config/cameras/mono-1.3mp.toml")]
    pub camera: PathBuf,
}

impl RigFiles {
    /// The simulated rig of these files.
    pub fn rig(&self) -> anyhow::Result<SimRig> {
        let m = world::machine::MachineConfig::load(&self.machine)?;
        let b = protocol::Board::load(&self.board)?;
        let c = world::camera::CameraModel::load(&self.camera)?;
        Ok(SimRig::new(world::machine::SimMachine::new(m), b, c))
    }
}

//! One simulated physical set-up: the imperfect machine, the calibration board fixed to
//! the machine frame, and the camera riding on the carriage. Every emulated device of a
//! process (stage controllers on any bus, the camera) shares one `SimRig`, so a move
//! commanded over any link changes what the camera sees.

use crate::camera::{CameraModel, CameraPose};
use crate::machine::{MachineConfig, SimMachine};
use crate::render::render;
use protocol::{Board, MonoImage};
use std::sync::{Arc, Mutex, MutexGuard};

/// The rig as every emulated device of a process shares it.
pub type SharedRig = Arc<Mutex<SimRig>>;

/// Locks state shared between emulated devices (the rig, a set of drives), tolerating
/// poison: a device thread that panicked mid-update leaves plain numbers (positions,
/// time, registers) that are still meaningful, and the other devices must keep answering.
pub fn lock<T>(shared: &Mutex<T>) -> MutexGuard<'_, T> {
    shared.lock().unwrap_or_else(|p| p.into_inner())
}

/// A rig shared by every device of a process: the machine built from its description,
/// the board on the machine frame, the camera on the carriage.
pub fn shared_rig(machine: MachineConfig, board: Board, camera: CameraModel) -> SharedRig {
    Arc::new(Mutex::new(SimRig::new(
        SimMachine::new(machine),
        board,
        camera,
    )))
}

/// Simulated exposure + readout time of one frame.
const FRAME_TIME_S: f64 = 0.01;

/// What the emulated camera reports with a frame (no truth in it).
#[derive(Clone, Debug, PartialEq)]
pub struct SimFrameInfo {
    pub sequence: u64,
    /// Simulated time at the start of exposure, seconds since power-on.
    pub time_s: f64,
}

#[derive(Clone, Debug)]
pub struct SimRig {
    machine: SimMachine,
    board: Board,
    camera: CameraModel,
    noise_seed: u64,
    frames: u64,
    /// Whether a frame's exposure advances the machine's time. It does when the rig's
    /// time moves only by what is done to it (in-process, an unconstrained clock); not
    /// when a controller emulator on a wall clock owns the time, which passes during
    /// the exposure anyway: frames advancing it too would run the machine ahead of its
    /// controller, faster the faster frames are rendered.
    frames_advance_time: bool,
}

impl SimRig {
    pub fn new(machine: SimMachine, board: Board, camera: CameraModel) -> Self {
        let noise_seed = machine.config().machine.seed ^ 0x00C0_FFEE;
        Self {
            machine,
            board,
            camera,
            noise_seed,
            frames: 0,
            frames_advance_time: true,
        }
    }

    /// A controller emulator on a wall clock owns the machine's time: frames no longer
    /// advance it.
    pub fn time_owned_by_wall_clock(&mut self) {
        self.frames_advance_time = false;
    }

    /// Frames exposed so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// The machine as its controllers see and drive it: commands, encoder counts, time.
    pub fn machine(&self) -> &SimMachine {
        &self.machine
    }

    /// The machine, to command moves, homing and stops, or to advance its time.
    pub fn machine_mut(&mut self) -> &mut SimMachine {
        &mut self.machine
    }

    /// The calibration board fixed to the machine frame.
    pub fn board(&self) -> &Board {
        &self.board
    }

    /// The camera's optics and sensor.
    pub fn camera(&self) -> &CameraModel {
        &self.camera
    }

    /// The camera, to change what its device configures (sensor window, bit depth).
    pub fn camera_mut(&mut self) -> &mut CameraModel {
        &mut self.camera
    }

    /// Expose one frame where the camera really is (motion continues during exposure).
    pub fn grab(&mut self) -> (MonoImage, SimFrameInfo) {
        let info = SimFrameInfo {
            sequence: self.frames,
            time_s: self.machine.now_s(),
        };
        let pose = self.machine.camera_pose();
        let seed = self
            .noise_seed
            .wrapping_add(self.frames.wrapping_mul(0x9E37_79B9));
        let frame = render(&self.board, &self.camera, &pose, seed);
        self.frames += 1;
        if self.frames_advance_time {
            self.machine.advance(FRAME_TIME_S);
        }
        (frame.image, info)
    }

    /// The truth: where the camera's image centre really is on the board. For tests and
    /// reports only; the gateway's pipeline never sees it.
    pub fn truth(&self) -> CameraPose {
        self.machine.camera_pose()
    }
}

//! Async device drivers behind small object-safe traits.
//!
//! * [`Stage`]: a motion stage as the compensation pipeline sees it (home, move, read
//!   the controller position, wait, stop, status), whatever the bus.
//! * [`AxisDrive`]: one independently driven axis (a CANopen or Modbus drive); any set of
//!   them becomes a `Stage` through [`MultiAxisStage`].
//! * [`Camera`]: grab a frame with its metadata.
//! * [`Prober`]: positioning and probing moves of a touch probe (a [`Stage`] with the
//!   `probing` capability through [`StageProber`], opened by [`open_prober`]).
//!
//! Architecture invariant: drivers know nothing of the compensation pipeline and never
//! read the simulated truth; the `sim` backend reaches the simulated machine only
//! through controller counts and rendered frames, as a real device would.

pub mod aravis;
pub mod camera;
pub mod can;
pub mod canopen;
#[cfg(feature = "serial")]
pub mod dnc;
pub mod error;
mod factory;
pub mod gige;
pub mod grbl;
pub mod linuxcnc;
#[cfg(feature = "modbus")]
pub mod modbus;
pub mod multi_axis;
pub mod prober;
pub mod program;
#[cfg(feature = "sim")]
pub mod sim;
pub mod stage;

pub use camera::{Camera, CameraInfo, Frame, FrameMeta};
pub use error::DriverError;
#[cfg(feature = "serial")]
pub use factory::open_grbl_line;
pub use factory::{open_camera, open_prober, open_stage};
pub use link_spec::{CameraLink, StageLink};
pub use multi_axis::{AxisDrive, AxisStatus, MultiAxisStage};
pub use prober::{Prober, ProberError, StageProber};
pub use program::{StreamError, StreamOptions, StreamReport};
pub use stage::{
    Axis, AxisInfo, AxisValues, Capabilities, ProbeHit, ProbeMode, Stage, StageInfo, StageState,
    StageStatus,
};

/// Run CPU-heavy work (rendering, localization: milliseconds) from async code without
/// stalling the other tasks of the runtime, such as a CAN bus task supervising
/// heartbeats: on a multi-thread runtime the worker hands its other tasks over first;
/// on a current-thread runtime (tests) it simply runs.
pub fn blocking<R>(f: impl FnOnce() -> R) -> R {
    match tokio::runtime::Handle::try_current().map(|h| h.runtime_flavor()) {
        Ok(tokio::runtime::RuntimeFlavor::MultiThread) => tokio::task::block_in_place(f),
        _ => f(),
    }
}

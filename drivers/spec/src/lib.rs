//! Every device link described as plain data: what the drivers need to open a stage or
//! a camera, without the drivers themselves (no tokio, no I/O), so that a pure crate
//! can check a job into a spec and the drivers crate alone opens it.
//!
//! Organised by link family; the `drivers` crate re-exports each type at the path its
//! backend has always used (`drivers::modbus::Endpoint`, `drivers::grbl::GrblOptions`...).

pub mod axis;
pub mod can;
pub mod canopen;
pub mod capabilities;
pub mod dnc;
pub mod gige;
pub mod grbl;
pub mod link;
pub mod linuxcnc;
pub mod modbus;

pub use axis::Axis;
pub use capabilities::Capabilities;
pub use link::{CameraLink, StageLink};

//! The simulated physical world, pure: one imperfect X-Y machine (ballscrew pitch and
//! periodic errors, backlash, squareness, thermal drift), the camera optics, the
//! rendering of the calibration board as the camera sees it, the rig that ties them
//! together, a deterministic random source, and how emulated time runs.
//!
//! Architecture invariants (enforced by this crate's manifest and `.ci/check-architecture`):
//! no I/O, no async runtime, no bus protocol. The bus devices in `emulators` drive this
//! world through [`rig::SimRig`]; the truth (where the camera really is) leaves it only
//! through [`rig::SimRig::truth`], for tests and reports. The gateway's pipeline crates
//! cannot depend on this crate at all.

pub mod axes;
pub mod camera;
pub mod clock;
pub mod cutter;
pub mod machine;
pub mod plate;
pub mod render;
pub mod rig;
pub mod rng;
pub mod rotary;
pub mod volumetric;

pub use clock::Clock;
pub use rig::{lock, shared_rig, SharedRig, SimRig};

//! The compensation loop of SPEC A, pure and sans-IO.
//!
//! - [`correction`]: the deviation D = observed - target, the correction policy, the
//!   bound on every correction and the soft limits, as pure functions.
//! - [`session`]: the loop as a state machine, observations in and the next action
//!   out ([`session::CompensationSession`]); the runner drives it over the device
//!   traits, and the service, ISO 230-2 runs and map scans will drive the same one.
//! - [`report`]: per-target rows and summary statistics of a finished (or stopped) job.
//!
//! Architecture invariant (enforced by the manifest and `.ci/check-architecture`): no
//! async runtime, no drivers, no emulators, no simulated world. Truth figures reach
//! the report only as numbers the runner passes in.

pub mod correction;
pub mod report;
pub mod session;

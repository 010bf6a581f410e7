//! Vision, pure: board localization ([`localize`]) and the PNG frame codec
//! ([`image_io`]). Nothing here knows where a frame came from or moves anything.
//!
//! Architecture invariant (enforced by the manifest and `.ci/check-architecture`): no
//! async runtime, no drivers, no emulators and no simulated world outside the tests.

pub mod image_io;
pub mod localize;

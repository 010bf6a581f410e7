//! Software devices for every bus, all driven by one simulated imperfect machine.
//!
//! Architecture invariant: this crate depends on `protocol`, never on `drivers` or
//! `gateway`; the truth it holds (where the tool really is) reaches the gateway only
//! through the bytes and frames a real device would send.

pub mod camera;
pub mod canopen;
pub mod gige;
pub mod grbl;
pub mod machine;
pub mod modbus;
pub mod plate;
pub mod pty;
pub mod render;
pub mod rig;
pub mod rng;

//! Software bus devices, all driving one simulated imperfect machine (the `world` crate):
//! sans-IO device state machines for GRBL, CANopen CiA 402, Modbus drives and a GigE
//! Vision camera, their servers and pseudo-terminal ports, and the stand-alone CLI.
//!
//! Architecture invariant: this crate depends on `protocol` and `world`, never on
//! `drivers` or `gateway`; the truth the world holds (where the tool really is) reaches
//! the gateway only through the bytes and frames a real device would send.

pub mod canopen;
pub mod cutter;
pub mod dnc;
pub mod gige;
pub mod grbl;
pub mod linuxcnc;
pub mod modbus;
pub mod pty;
pub mod rig_files;
pub mod trace;

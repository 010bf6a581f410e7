//! Modbus RTU and TCP positioning drives on the simulated machine, register maps from
//! drive profiles (`config/drives/*.toml`): [`device`] is the drives' behaviour
//! (sans-IO), [`server`] serves them on a TCP socket and on a real pseudo-terminal,
//! with fault injection.

pub mod cli;
pub mod device;
pub mod server;

pub use device::{DriveSet, MachineAxis, ModbusStats};
pub use server::{Fault, FaultRule, ModbusDevice, ModbusRtu, ModbusTcp};

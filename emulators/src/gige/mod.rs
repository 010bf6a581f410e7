//! A GigE Vision camera on the simulated machine: the sans-IO register device
//! ([`device`]) and its UDP server ([`server`]).

pub mod device;
pub mod server;

pub use device::{GigeConfig, GigeDevice};
pub use server::{GigeCameraServer, GigeServerOptions};

//! A GigE Vision camera on the simulated machine: the sans-IO register device
//! ([`device`]), its UDP server ([`server`]) and the stand-alone command ([`cli`]).

pub mod cli;
pub mod device;
pub mod server;

pub use device::{GigeConfig, GigeDevice};
pub use server::{GigeCameraServer, GigeServerOptions};

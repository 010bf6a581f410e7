//! Every format the gateway speaks or reads, sans-IO.
//!
//! Architecture invariant: nothing in this crate does I/O on a device, reads a clock or
//! depends on an async runtime. Files are read only by the small `config` loader so that
//! every data file gets the same error reporting (file, line, key).

pub mod board;
pub mod board_code;
pub mod can;
pub mod canopen;
pub mod cia402;
pub mod config;
pub mod errormap;
pub mod fanuc;
pub mod gige;
pub mod grbl;
pub mod image;
pub mod modbus;
pub mod nc;
pub mod ngc;
pub mod slcan;
pub mod text;
pub mod volumetric;

pub use board::{Board, Polarity};
pub use config::ConfigError;
pub use image::{MonoImage, Pixels};

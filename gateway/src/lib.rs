//! The compensation gateway: configuration, the localization and compensation pipeline,
//! the orchestrator that runs it through driver traits, and the CLI.
//!
//! Architecture invariant: `localize` and `correction` are pure functions (image or
//! observation in, numbers or moves out); only `orchestrator` does I/O, and only through
//! the `drivers` traits.

pub mod camera_link;
pub mod canopen_stage;
pub mod config;
pub mod correction;
pub mod grbl_stage;
pub mod image_io;
pub mod localize;
pub mod modbus_stage;
pub mod orchestrator;
pub mod report;
pub mod run;

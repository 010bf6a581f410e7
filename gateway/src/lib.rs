//! The compensation gateway: configuration, the localization and compensation pipeline,
//! the orchestrator that runs it through driver traits, and the CLI.
//!
//! Architecture invariant: `localize`, `deviation` and `correction` are pure functions
//! (image/observation in, numbers/moves out); only `orchestrator` does I/O, and only
//! through the `drivers` traits.

pub mod localize;

//! One error type for every driver. Device refusals (a controller's error code, an
//! alarm, an SDO abort, a Modbus exception) are kept apart from transport failures, so
//! callers can tell "the device said no" from "the link is broken".

use link_spec::Axis;

#[derive(Debug, thiserror::Error)]
pub enum DriverError {
    /// The link itself failed (port gone, socket closed, write error).
    #[error("{device}: link failed: {message}")]
    Transport { device: String, message: String },
    /// No answer in time.
    #[error("{device}: no answer to {what} within {after_ms} ms")]
    Timeout {
        device: String,
        what: String,
        after_ms: u64,
    },
    /// The device understood and refused (e.g. GRBL `error:N`, SDO abort, exception).
    #[error("{device} refused {what}: code {code}: {message}")]
    Refused {
        device: String,
        what: String,
        code: u32,
        message: String,
    },
    /// The device is in an alarm or fault state; motion is stopped.
    #[error("{device} alarm {code}: {message}")]
    Alarm {
        device: String,
        code: u32,
        message: String,
    },
    /// A command was refused before it was sent because it breaks a soft limit.
    #[error("axis {axis}: {value_mm:.4} mm is outside the soft limits {min_mm}..{max_mm} mm")]
    OutOfLimits {
        axis: Axis,
        value_mm: f64,
        min_mm: f64,
        max_mm: f64,
    },
    /// The device answered something this driver cannot make sense of.
    #[error("{device}: protocol violation: {message}")]
    Protocol { device: String, message: String },
    /// The operation needs a state the device is not in (not homed, not enabled...).
    #[error("{device}: {message}")]
    InvalidState { device: String, message: String },
    /// This backend is not available on this machine or build.
    #[error("backend `{backend}` is not available: {reason}")]
    NotAvailable { backend: String, reason: String },
    /// The caller asked for something the driver does not do (an axis it lacks...).
    #[error("{device}: {message}")]
    Unsupported { device: String, message: String },
}

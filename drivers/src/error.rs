//! One error type for every driver. Device refusals (a controller's error code, an
//! alarm, an SDO abort, a Modbus exception) are kept apart from transport failures, so
//! callers can tell "the device said no" from "the link is broken".

use link_spec::Axis;

/// A device's code as its standard writes it: small numbers (GRBL's `error:20` and
/// `ALARM:9`, Modbus exception codes) in decimal; 16- and 32-bit codes (CiA 301 SDO
/// abort codes such as 0x06020000, CiA 402 / EMCY error codes such as 0x8611, GigE
/// Vision status codes, drive alarm registers) in hex with all their digits.
pub fn code_text(code: u32) -> String {
    match code {
        0..=0xFF => code.to_string(),
        0x100..=0xFFFF => format!("0x{code:04X}"),
        _ => format!("0x{code:08X}"),
    }
}

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
    #[error("{device} refused {what}: code {}: {message}", code_text(*code))]
    Refused {
        device: String,
        what: String,
        code: u32,
        message: String,
    },
    /// The device is in an alarm or fault state; motion is stopped.
    #[error("{device} alarm {}: {message}", code_text(*code))]
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_are_written_as_their_standards_write_them() {
        let alarm = |code| {
            DriverError::Alarm {
                device: "d".into(),
                code,
                message: "m".into(),
            }
            .to_string()
        };
        // CiA 402 / 301 error codes (EMCY) are 16-bit hex.
        assert_eq!(alarm(0x8611), "d alarm 0x8611: m");
        // GRBL's alarm numbers are small decimals.
        assert_eq!(alarm(9), "d alarm 9: m");
        let refused = |code| {
            DriverError::Refused {
                device: "d".into(),
                what: "w".into(),
                code,
                message: "m".into(),
            }
            .to_string()
        };
        assert_eq!(refused(0x0602_0000), "d refused w: code 0x06020000: m");
        assert_eq!(refused(20), "d refused w: code 20: m");
    }
}

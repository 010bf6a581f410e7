//! Emergency (EMCY) messages: error code, error register and five manufacturer bytes,
//! sent by a node on COB-ID 0x80 + id when an error occurs or is cleared (code 0).

use super::{NodeId, COB_EMCY};
use crate::can::CanFrame;

/// An emergency message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Emcy {
    /// CiA 301 / CiA 402 error code (0x0000 = error reset or no error).
    pub code: u16,
    /// The node's error register (0x1001) at the time.
    pub register: u8,
    pub vendor: [u8; 5],
}

/// Error codes this project sends or names (CiA 301 table 21, CiA 402 annex).
pub mod codes {
    pub const NO_ERROR: u16 = 0x0000;
    pub const GENERIC: u16 = 0x1000;
    pub const CURRENT: u16 = 0x2000;
    pub const VOLTAGE: u16 = 0x3000;
    pub const TEMPERATURE: u16 = 0x4000;
    pub const DEVICE_HARDWARE: u16 = 0x5000;
    pub const DEVICE_SOFTWARE: u16 = 0x6000;
    pub const MONITORING: u16 = 0x8000;
    pub const CAN_OVERRUN: u16 = 0x8110;
    pub const CAN_ERROR_PASSIVE: u16 = 0x8120;
    pub const HEARTBEAT_ERROR: u16 = 0x8130;
    pub const PDO_LENGTH: u16 = 0x8210;
    pub const FOLLOWING_ERROR: u16 = 0x8611;
    pub const REFERENCE_LIMIT: u16 = 0x8612;
    pub const DEVICE_SPECIFIC: u16 = 0xFF00;
}

/// Error register (0x1001) bits.
pub mod register {
    pub const GENERIC: u8 = 0x01;
    pub const CURRENT: u8 = 0x02;
    pub const VOLTAGE: u8 = 0x04;
    pub const TEMPERATURE: u8 = 0x08;
    pub const COMMUNICATION: u8 = 0x10;
    pub const PROFILE: u8 = 0x20;
    pub const MANUFACTURER: u8 = 0x80;
}

impl Emcy {
    pub fn new(code: u16, register: u8) -> Self {
        Self {
            code,
            register,
            vendor: [0; 5],
        }
    }

    pub fn frame(&self, node: NodeId) -> CanFrame {
        let mut d = [0u8; 8];
        d[..2].copy_from_slice(&self.code.to_le_bytes());
        d[2] = self.register;
        d[3..].copy_from_slice(&self.vendor);
        CanFrame::std(node.emcy(), &d)
    }

    /// Parse an EMCY frame (exactly 8 bytes, as python-canopen and most masters expect).
    pub fn parse(frame: &CanFrame) -> Option<(NodeId, Emcy)> {
        let id = frame.id().as_standard()?;
        if id & 0x780 != COB_EMCY || frame.is_remote() {
            return None;
        }
        let node = NodeId::new((id & 0x7F) as u8)?;
        let d = frame.data();
        if d.len() != 8 {
            return None;
        }
        let mut vendor = [0u8; 5];
        vendor.copy_from_slice(&d[3..]);
        Some((
            node,
            Emcy {
                code: u16::from_le_bytes([d[0], d[1]]),
                register: d[2],
                vendor,
            },
        ))
    }

    /// Whether this message clears errors (code 0x00xx).
    pub fn is_reset(&self) -> bool {
        self.code & 0xFF00 == 0
    }

    pub fn describe(&self) -> &'static str {
        describe(self.code)
    }
}

/// The CiA 301 / CiA 402 name of an error code, most specific first, else its class.
pub fn describe(code: u16) -> &'static str {
    match code {
        0x0000..=0x00FF => "no error (error reset)",
        codes::CAN_OVERRUN => "CAN overrun (objects lost)",
        codes::CAN_ERROR_PASSIVE => "CAN in error passive mode",
        codes::HEARTBEAT_ERROR => "life guard or heartbeat error",
        0x8140 => "recovered from bus off",
        codes::PDO_LENGTH => "PDO not processed due to length error",
        0x8220 => "PDO length exceeded",
        codes::FOLLOWING_ERROR => "following error",
        codes::REFERENCE_LIMIT => "reference limit (position limit reached)",
        0x1000..=0x1FFF => "generic error",
        0x2000..=0x2FFF => "current error",
        0x3000..=0x3FFF => "voltage error",
        0x4000..=0x4FFF => "temperature error",
        0x5000..=0x5FFF => "device hardware error",
        0x6000..=0x6FFF => "device software error",
        0x7000..=0x7FFF => "additional modules error",
        0x8000..=0x8FFF => "monitoring error",
        0x9000..=0x9FFF => "external error",
        0xF000..=0xFEFF => "additional functions",
        0xFF00..=0xFFFF => "device specific",
        _ => "unknown error code class",
    }
}

impl std::fmt::Display for Emcy {
    /// `0x8611 (following error), error register 0x21`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "0x{:04X} ({}), error register 0x{:02X}",
            self.code,
            self.describe(),
            self.register
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_error_code_class_has_the_standards_name() {
        for (code, name) in [
            (0x0000, "no error (error reset)"),
            (0x1000, "generic error"),
            (0x2310, "current error"),
            (0x3210, "voltage error"),
            (0x4310, "temperature error"),
            (0x5530, "device hardware error"),
            (0x6100, "device software error"),
            (0x7300, "additional modules error"),
            (0x8400, "monitoring error"),
            (0x8611, "following error"),
            (0x9000, "external error"),
            (0xF001, "additional functions"),
            (0xFF00, "device specific"),
            (0xA000, "unknown error code class"),
            (0x0100, "unknown error code class"),
        ] {
            assert_eq!(describe(code), name, "0x{code:04X}");
        }
        let e = Emcy::new(
            codes::FOLLOWING_ERROR,
            register::GENERIC | register::PROFILE,
        );
        assert_eq!(
            e.to_string(),
            "0x8611 (following error), error register 0x21"
        );
    }

    #[test]
    fn emcy_round_trips_and_names_its_code() {
        let n = NodeId::new(4).unwrap();
        let e = Emcy {
            code: codes::FOLLOWING_ERROR,
            register: register::GENERIC | register::PROFILE,
            vendor: [1, 2, 3, 4, 5],
        };
        let f = e.frame(n);
        assert_eq!(f.to_string(), "084#1186210102030405");
        assert_eq!(Emcy::parse(&f), Some((n, e)));
        assert_eq!(e.describe(), "following error");
        assert!(Emcy::new(0, 0).is_reset());
        assert!(
            Emcy::parse(&CanFrame::std(0x084, &[0x11, 0x86])).is_none(),
            "short EMCY"
        );
        assert!(
            Emcy::parse(&CanFrame::std(0x080, &[0; 8])).is_none(),
            "SYNC is not EMCY"
        );
    }
}

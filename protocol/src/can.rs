//! One classic CAN frame type used by every codec, bus backend and emulated device.
//!
//! A frame has an 11-bit (standard) or 29-bit (extended) identifier, may be a remote
//! request (RTR: a DLC and no data), and carries 0-8 data bytes. CAN FD is not covered:
//! CANopen CiA 301/402 and SLCAN's `t/T/r/R` frames are classic CAN.

use std::fmt;

/// A CAN identifier, range-checked at construction.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum CanId {
    /// 11-bit identifier (0..=0x7FF).
    Standard(u16),
    /// 29-bit identifier (0..=0x1FFF_FFFF).
    Extended(u32),
}

pub const MAX_STANDARD_ID: u16 = 0x7FF;
pub const MAX_EXTENDED_ID: u32 = 0x1FFF_FFFF;

/// Why a frame could not be built.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    #[error("standard CAN id 0x{0:X} is above 0x7FF")]
    StandardIdRange(u32),
    #[error("extended CAN id 0x{0:X} is above 0x1FFFFFFF")]
    ExtendedIdRange(u32),
    #[error("{0} data bytes: a classic CAN frame carries at most 8")]
    TooLong(usize),
}

impl CanId {
    pub fn standard(id: u16) -> Result<Self, FrameError> {
        if id > MAX_STANDARD_ID {
            return Err(FrameError::StandardIdRange(id.into()));
        }
        Ok(CanId::Standard(id))
    }

    pub fn extended(id: u32) -> Result<Self, FrameError> {
        if id > MAX_EXTENDED_ID {
            return Err(FrameError::ExtendedIdRange(id));
        }
        Ok(CanId::Extended(id))
    }

    /// The identifier's numeric value (without any format flag).
    pub fn raw(self) -> u32 {
        match self {
            CanId::Standard(i) => i.into(),
            CanId::Extended(i) => i,
        }
    }

    pub fn is_extended(self) -> bool {
        matches!(self, CanId::Extended(_))
    }

    /// The 11-bit value if this is a standard id (CANopen COB-IDs are standard).
    pub fn as_standard(self) -> Option<u16> {
        match self {
            CanId::Standard(i) => Some(i),
            CanId::Extended(_) => None,
        }
    }
}

/// A classic CAN frame. Unused data bytes are always zero, so frames compare by value.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct CanFrame {
    id: CanId,
    rtr: bool,
    dlc: u8,
    data: [u8; 8],
}

impl CanFrame {
    /// A data frame.
    pub fn new(id: CanId, data: &[u8]) -> Result<Self, FrameError> {
        if data.len() > 8 {
            return Err(FrameError::TooLong(data.len()));
        }
        let mut d = [0u8; 8];
        d[..data.len()].copy_from_slice(data);
        Ok(Self {
            id,
            rtr: false,
            dlc: data.len() as u8,
            data: d,
        })
    }

    /// A remote (RTR) frame asking for `dlc` bytes.
    pub fn remote(id: CanId, dlc: u8) -> Result<Self, FrameError> {
        if dlc > 8 {
            return Err(FrameError::TooLong(dlc.into()));
        }
        Ok(Self {
            id,
            rtr: true,
            dlc,
            data: [0; 8],
        })
    }

    /// A standard-id data frame. Panics on a bad id or length: for constants and for
    /// ids already checked (CANopen COB-IDs built from a valid node id).
    pub fn std(id: u16, data: &[u8]) -> Self {
        Self::new(CanId::standard(id).expect("standard id"), data).expect("at most 8 bytes")
    }

    pub fn id(&self) -> CanId {
        self.id
    }

    pub fn is_remote(&self) -> bool {
        self.rtr
    }

    pub fn dlc(&self) -> u8 {
        self.dlc
    }

    /// The data bytes (empty for a remote frame).
    pub fn data(&self) -> &[u8] {
        if self.rtr {
            &[]
        } else {
            &self.data[..usize::from(self.dlc)]
        }
    }

    /// Bits on the wire without stuff bits: SOF, arbitration, control, data, CRC,
    /// delimiters, ACK, EOF and the 3-bit interframe space.
    pub fn bits_unstuffed(&self) -> u32 {
        let data = if self.rtr { 0 } else { 8 * u32::from(self.dlc) };
        let header = if self.id.is_extended() { 67 } else { 47 };
        header + data
    }
}

impl fmt::Debug for CanFrame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Display::fmt(self, f)
    }
}

/// candump's compact form: `601#2B40600006000000`, `12345678#11`, `701#R1`.
impl fmt::Display for CanFrame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.id {
            CanId::Standard(i) => write!(f, "{i:03X}#")?,
            CanId::Extended(i) => write!(f, "{i:08X}#")?,
        }
        if self.rtr {
            return write!(f, "R{}", self.dlc);
        }
        for b in self.data() {
            write!(f, "{b:02X}")?;
        }
        Ok(())
    }
}

/// Frames per second a bus can carry at `bitrate` for frames like `frame`, assuming the
/// worst-case bit stuffing of the stuffable part (one stuff bit per 4 bits after the
/// first) when `worst_case_stuffing`, else none.
pub fn bus_capacity_frames_per_s(bitrate: u32, frame: &CanFrame, worst_case_stuffing: bool) -> f64 {
    let bits = frame.bits_unstuffed();
    // SOF..CRC is stuffed; CRC delimiter, ACK, EOF and interframe space (13 bits) are not.
    let stuffable = bits - 13;
    let stuffed = if worst_case_stuffing {
        (stuffable - 1) / 4
    } else {
        0
    };
    f64::from(bitrate) / f64::from(bits + stuffed)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_are_range_checked() {
        assert!(CanId::standard(0x7FF).is_ok());
        assert_eq!(
            CanId::standard(0x800),
            Err(FrameError::StandardIdRange(0x800))
        );
        assert!(CanId::extended(0x1FFF_FFFF).is_ok());
        assert!(CanId::extended(0x2000_0000).is_err());
        assert_eq!(
            CanFrame::new(CanId::Standard(1), &[0; 9]),
            Err(FrameError::TooLong(9))
        );
    }

    #[test]
    fn frames_print_like_candump() {
        let f = CanFrame::std(0x601, &[0x40, 0x41, 0x60, 0, 0, 0, 0, 0]);
        assert_eq!(f.to_string(), "601#4041600000000000");
        let r = CanFrame::remote(CanId::Extended(0x1234), 2).unwrap();
        assert_eq!(r.to_string(), "00001234#R2");
        assert!(r.data().is_empty());
        assert_eq!(r.dlc(), 2);
    }

    #[test]
    fn capacity_of_a_1_mbit_bus_for_8_byte_standard_frames() {
        let f = CanFrame::std(0x181, &[0; 8]);
        // 111 bits unstuffed, up to 24 stuff bits: 7407..9009 frames/s.
        assert_eq!(f.bits_unstuffed(), 111);
        let best = bus_capacity_frames_per_s(1_000_000, &f, false);
        let worst = bus_capacity_frames_per_s(1_000_000, &f, true);
        assert!((best - 9009.0).abs() < 1.0, "{best}");
        assert!((worst - 7407.4).abs() < 1.0, "{worst}");
    }
}

//! GRBL real-time command bytes.
//!
//! GRBL picks these out of the serial stream in its receive interrupt, wherever they
//! occur (even in the middle of a line): they never enter the 128-byte RX buffer and
//! never get an `ok`. Only `?` produces an answer (a status report). Bytes >= 0x80 that
//! GRBL does not know are discarded, so a host may send them safely.

/// A real-time command, as GRBL 1.1 defines them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Realtime {
    /// 0x18 (ctrl-x): soft reset; flushes the RX buffer and the planner, prints the banner.
    SoftReset,
    /// `?`: request a status report.
    StatusQuery,
    /// `~`: cycle start / resume after a feed hold.
    CycleStart,
    /// `!`: feed hold (controlled deceleration, position kept).
    FeedHold,
    /// 0x84: safety door.
    SafetyDoor,
    /// 0x85: jog cancel (stops the jog and flushes queued jog blocks).
    JogCancel,
    /// 0x90: feed override back to 100 %.
    FeedOverrideReset,
    /// 0x91 / 0x92: feed override +10 % / -10 %.
    FeedOverrideCoarsePlus,
    FeedOverrideCoarseMinus,
    /// 0x93 / 0x94: feed override +1 % / -1 %.
    FeedOverrideFinePlus,
    FeedOverrideFineMinus,
    /// 0x95 / 0x96 / 0x97: rapid override 100 % / 50 % / 25 %.
    RapidOverrideReset,
    RapidOverrideMedium,
    RapidOverrideLow,
    /// 0x99: spindle override back to 100 %.
    SpindleOverrideReset,
    /// 0x9A / 0x9B: spindle override +10 % / -10 %.
    SpindleOverrideCoarsePlus,
    SpindleOverrideCoarseMinus,
    /// 0x9C / 0x9D: spindle override +1 % / -1 %.
    SpindleOverrideFinePlus,
    SpindleOverrideFineMinus,
    /// 0x9E: spindle stop (only in Hold).
    SpindleStop,
    /// 0xA0: toggle flood coolant.
    FloodToggle,
    /// 0xA1: toggle mist coolant.
    MistToggle,
}

impl Realtime {
    pub const ALL: [Realtime; 22] = [
        Realtime::SoftReset,
        Realtime::StatusQuery,
        Realtime::CycleStart,
        Realtime::FeedHold,
        Realtime::SafetyDoor,
        Realtime::JogCancel,
        Realtime::FeedOverrideReset,
        Realtime::FeedOverrideCoarsePlus,
        Realtime::FeedOverrideCoarseMinus,
        Realtime::FeedOverrideFinePlus,
        Realtime::FeedOverrideFineMinus,
        Realtime::RapidOverrideReset,
        Realtime::RapidOverrideMedium,
        Realtime::RapidOverrideLow,
        Realtime::SpindleOverrideReset,
        Realtime::SpindleOverrideCoarsePlus,
        Realtime::SpindleOverrideCoarseMinus,
        Realtime::SpindleOverrideFinePlus,
        Realtime::SpindleOverrideFineMinus,
        Realtime::SpindleStop,
        Realtime::FloodToggle,
        Realtime::MistToggle,
    ];

    /// The byte on the wire.
    pub fn byte(self) -> u8 {
        match self {
            Realtime::SoftReset => 0x18,
            Realtime::StatusQuery => b'?',
            Realtime::CycleStart => b'~',
            Realtime::FeedHold => b'!',
            Realtime::SafetyDoor => 0x84,
            Realtime::JogCancel => 0x85,
            Realtime::FeedOverrideReset => 0x90,
            Realtime::FeedOverrideCoarsePlus => 0x91,
            Realtime::FeedOverrideCoarseMinus => 0x92,
            Realtime::FeedOverrideFinePlus => 0x93,
            Realtime::FeedOverrideFineMinus => 0x94,
            Realtime::RapidOverrideReset => 0x95,
            Realtime::RapidOverrideMedium => 0x96,
            Realtime::RapidOverrideLow => 0x97,
            Realtime::SpindleOverrideReset => 0x99,
            Realtime::SpindleOverrideCoarsePlus => 0x9A,
            Realtime::SpindleOverrideCoarseMinus => 0x9B,
            Realtime::SpindleOverrideFinePlus => 0x9C,
            Realtime::SpindleOverrideFineMinus => 0x9D,
            Realtime::SpindleStop => 0x9E,
            Realtime::FloodToggle => 0xA0,
            Realtime::MistToggle => 0xA1,
        }
    }

    /// The command a byte stands for, if it is one GRBL 1.1 intercepts.
    pub fn from_byte(b: u8) -> Option<Realtime> {
        Realtime::ALL.into_iter().find(|r| r.byte() == b)
    }
}

/// What GRBL's receive interrupt does with one incoming byte.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RxByte {
    /// A real-time command: acted on at once, not buffered.
    Realtime(Realtime),
    /// An extended byte (>= 0x80) GRBL does not know: discarded.
    Discarded,
    /// Anything else goes into the RX buffer (if there is room).
    Buffered(u8),
}

/// Classify a byte as GRBL's receive interrupt does.
pub fn classify(b: u8) -> RxByte {
    match Realtime::from_byte(b) {
        Some(r) => RxByte::Realtime(r),
        None if b >= 0x80 => RxByte::Discarded,
        None => RxByte::Buffered(b),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_round_trip_and_are_distinct() {
        let mut seen = std::collections::HashSet::new();
        for r in Realtime::ALL {
            assert!(seen.insert(r.byte()), "{r:?} byte repeated");
            assert_eq!(Realtime::from_byte(r.byte()), Some(r));
        }
        assert_eq!(classify(b'G'), RxByte::Buffered(b'G'));
        assert_eq!(classify(0x18), RxByte::Realtime(Realtime::SoftReset));
        assert_eq!(classify(0x98), RxByte::Discarded);
        assert_eq!(classify(b'\n'), RxByte::Buffered(b'\n'));
    }
}

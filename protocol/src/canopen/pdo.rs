//! Process data objects: communication records (0x1400/0x1800 + n) and mapping records
//! (0x1600/0x1A00 + n), and packing mapped values into a PDO's bytes and back.
//!
//! Mappings here are byte-aligned (8, 16, 32 or 64-bit entries), which is what CiA 402
//! drives map; a bit-packed mapping is refused with "object cannot be mapped".

use super::sdo::AbortCode;

pub const RPDO_COMM: u16 = 0x1400;
pub const RPDO_MAP: u16 = 0x1600;
pub const TPDO_COMM: u16 = 0x1800;
pub const TPDO_MAP: u16 = 0x1A00;

/// COB-ID entry (sub 1) flags.
pub const COB_INVALID: u32 = 1 << 31;
pub const COB_NO_RTR: u32 = 1 << 30;
pub const COB_FRAME_29BIT: u32 = 1 << 29;

/// Transmission types (sub 2).
pub const TT_SYNC_ACYCLIC: u8 = 0;
pub const TT_SYNC_RTR: u8 = 252;
pub const TT_EVENT_RTR: u8 = 253;
pub const TT_EVENT_MANUFACTURER: u8 = 254;
pub const TT_EVENT_PROFILE: u8 = 255;

/// One mapping entry: `index << 16 | sub << 8 | bits`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MapEntry {
    pub index: u16,
    pub sub: u8,
    pub bits: u8,
}

impl MapEntry {
    pub fn new(index: u16, sub: u8, bits: u8) -> Self {
        Self { index, sub, bits }
    }

    pub fn from_u32(v: u32) -> Self {
        Self {
            index: (v >> 16) as u16,
            sub: (v >> 8) as u8,
            bits: v as u8,
        }
    }

    pub fn to_u32(self) -> u32 {
        (u32::from(self.index) << 16) | (u32::from(self.sub) << 8) | u32::from(self.bits)
    }

    pub fn bytes(self) -> usize {
        usize::from(self.bits / 8)
    }
}

/// A PDO communication record.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PdoComm {
    /// Sub 1 as stored (flags included).
    pub cob_id: u32,
    pub transmission_type: u8,
    /// Minimum time between two transmissions, in 100 us units (TPDO only).
    pub inhibit_100us: u16,
    /// Event timer, ms (0 = off).
    pub event_timer_ms: u16,
    pub sync_start: u8,
}

impl PdoComm {
    pub fn valid(&self) -> bool {
        self.cob_id & COB_INVALID == 0
    }

    /// The 11-bit COB-ID (extended PDO ids are not supported here).
    pub fn can_id(&self) -> u16 {
        (self.cob_id & 0x7FF) as u16
    }

    /// Sent on every n-th SYNC (1..=240) or acyclically on SYNC (0).
    pub fn is_synchronous(&self) -> bool {
        self.transmission_type <= 240
    }

    /// Sent on an event (change of mapped data or the event timer).
    pub fn is_event_driven(&self) -> bool {
        self.transmission_type >= TT_EVENT_MANUFACTURER
    }
}

/// Check a mapping: entries byte-aligned and at most 64 bits in all.
pub fn check_mapping(entries: &[MapEntry]) -> Result<(), AbortCode> {
    let mut total = 0usize;
    for e in entries {
        if e.bits == 0 || e.bits % 8 != 0 || e.bits > 64 {
            return Err(AbortCode::NOT_MAPPABLE);
        }
        total += usize::from(e.bits);
    }
    if total > 64 {
        return Err(AbortCode::PDO_TOO_LONG);
    }
    Ok(())
}

/// Pack mapped values into PDO bytes. `value` gives an entry's current bytes (LE); it
/// is cut or zero-extended to the mapped length.
pub fn pack(entries: &[MapEntry], mut value: impl FnMut(&MapEntry) -> Vec<u8>) -> Vec<u8> {
    let mut out = Vec::with_capacity(8);
    for e in entries {
        let mut v = value(e);
        v.resize(e.bytes(), 0);
        out.extend_from_slice(&v);
    }
    out
}

/// Split received PDO bytes by a mapping. Fails (CiA 301: EMCY 0x8210) if the frame is
/// shorter than the mapping; extra bytes are ignored.
pub fn unpack<'a>(
    entries: &[MapEntry],
    data: &'a [u8],
) -> Result<Vec<(MapEntry, &'a [u8])>, usize> {
    let need: usize = entries.iter().map(|e| e.bytes()).sum();
    if data.len() < need {
        return Err(need);
    }
    let mut at = 0;
    Ok(entries
        .iter()
        .map(|e| {
            let v = &data[at..at + e.bytes()];
            at += e.bytes();
            (*e, v)
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mapping_entries_pack_and_unpack() {
        let cw = MapEntry::from_u32(0x6040_0010);
        assert_eq!(cw, MapEntry::new(0x6040, 0, 16));
        assert_eq!(cw.to_u32(), 0x6040_0010);
        let map = [cw, MapEntry::new(0x607A, 0, 32)];
        check_mapping(&map).unwrap();
        let bytes = pack(&map, |e| {
            if e.index == 0x6040 {
                vec![0x1F, 0x00]
            } else {
                (-2i32).to_le_bytes().to_vec()
            }
        });
        assert_eq!(bytes, [0x1F, 0x00, 0xFE, 0xFF, 0xFF, 0xFF]);
        let parts = unpack(&map, &bytes).unwrap();
        assert_eq!(parts[1].1, &[0xFE, 0xFF, 0xFF, 0xFF]);
        assert_eq!(unpack(&map, &bytes[..5]), Err(6));
        assert_eq!(
            check_mapping(&[MapEntry::new(0x6041, 0, 12)]),
            Err(AbortCode::NOT_MAPPABLE)
        );
        assert_eq!(
            check_mapping(&[MapEntry::new(0x6064, 0, 32); 3]),
            Err(AbortCode::PDO_TOO_LONG)
        );
        let c = PdoComm {
            cob_id: 0x181 | COB_INVALID,
            transmission_type: 255,
            inhibit_100us: 0,
            event_timer_ms: 0,
            sync_start: 0,
        };
        assert!(!c.valid() && c.is_event_driven() && !c.is_synchronous());
        assert_eq!(c.can_id(), 0x181);
    }
}

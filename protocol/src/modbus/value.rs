//! Register values: 16- and 32-bit integers spread over 16-bit Modbus registers, and
//! the physical units drives use for them (counts, rpm, acceleration times) converted
//! to and from millimetres.
//!
//! Modbus itself only defines 16-bit big-endian registers; how a 32-bit value is split
//! over two of them is the vendor's choice (Oriental Motor and Leadshine put the upper
//! word first, Delta ASDA the lower word), so the word order is part of every profile.

use serde::Deserialize;
use std::fmt;

/// How a register's value is represented.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DataType {
    U16,
    I16,
    U32,
    I32,
}

impl DataType {
    /// Number of 16-bit registers the value occupies.
    pub fn words(self) -> u16 {
        match self {
            DataType::U16 | DataType::I16 => 1,
            DataType::U32 | DataType::I32 => 2,
        }
    }

    /// Smallest and largest representable value.
    pub fn range(self) -> (i64, i64) {
        match self {
            DataType::U16 => (0, u16::MAX as i64),
            DataType::I16 => (i16::MIN as i64, i16::MAX as i64),
            DataType::U32 => (0, u32::MAX as i64),
            DataType::I32 => (i32::MIN as i64, i32::MAX as i64),
        }
    }
}

impl fmt::Display for DataType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            DataType::U16 => "u16",
            DataType::I16 => "i16",
            DataType::U32 => "u32",
            DataType::I32 => "i32",
        })
    }
}

/// Which 16-bit half of a 32-bit value comes at the lower register address.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum WordOrder {
    /// Upper word at the lower address ("big-endian words", Oriental Motor, Leadshine).
    #[default]
    HighFirst,
    /// Lower word at the lower address ("word-swapped", Delta ASDA).
    LowFirst,
}

/// A value that does not fit its register type.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{value} does not fit a {ty} register ({min}..={max})")]
pub struct OutOfRange {
    pub value: i64,
    pub ty: DataType,
    pub min: i64,
    pub max: i64,
}

/// The registers (1 or 2 words) holding `value`.
pub fn encode(value: i64, ty: DataType, order: WordOrder) -> Result<Vec<u16>, OutOfRange> {
    let (min, max) = ty.range();
    if value < min || value > max {
        return Err(OutOfRange {
            value,
            ty,
            min,
            max,
        });
    }
    Ok(match ty {
        DataType::U16 | DataType::I16 => vec![value as u16],
        DataType::U32 | DataType::I32 => {
            let v = value as u32;
            let (hi, lo) = ((v >> 16) as u16, v as u16);
            match order {
                WordOrder::HighFirst => vec![hi, lo],
                WordOrder::LowFirst => vec![lo, hi],
            }
        }
    })
}

/// The value held by `words` (exactly `ty.words()` of them).
pub fn decode(words: &[u16], ty: DataType, order: WordOrder) -> i64 {
    match ty {
        DataType::U16 => words[0] as i64,
        DataType::I16 => words[0] as i16 as i64,
        DataType::U32 | DataType::I32 => {
            let (hi, lo) = match order {
                WordOrder::HighFirst => (words[0], words[1]),
                WordOrder::LowFirst => (words[1], words[0]),
            };
            let v = ((hi as u32) << 16) | lo as u32;
            if ty == DataType::I32 {
                v as i32 as i64
            } else {
                v as i64
            }
        }
    }
}

/// What a register's number means physically.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
pub enum Unit {
    /// Encoder counts or steps (positions).
    #[serde(rename = "counts")]
    Counts,
    /// Counts per second (step frequency in Hz).
    #[serde(rename = "counts/s")]
    CountsPerS,
    /// Motor revolutions per minute.
    #[serde(rename = "rpm")]
    Rpm,
    /// Counts per second squared (Oriental Motor's 0.001 kHz/s is the same unit).
    #[serde(rename = "counts/s2")]
    CountsPerS2,
    /// Milliseconds to gain (or lose) 1000 rpm: a time, so it is inversely
    /// proportional to the acceleration (Leadshine PR acceleration/deceleration).
    #[serde(rename = "ms/1000rpm")]
    MsPer1000Rpm,
}

/// The physical quantity a unit measures.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Quantity {
    /// mm
    Position,
    /// mm/s
    Speed,
    /// mm/s^2
    Acceleration,
}

impl Unit {
    pub fn quantity(self) -> Quantity {
        match self {
            Unit::Counts => Quantity::Position,
            Unit::CountsPerS | Unit::Rpm => Quantity::Speed,
            Unit::CountsPerS2 | Unit::MsPer1000Rpm => Quantity::Acceleration,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Unit::Counts => "counts",
            Unit::CountsPerS => "counts/s",
            Unit::Rpm => "rpm",
            Unit::CountsPerS2 => "counts/s2",
            Unit::MsPer1000Rpm => "ms/1000rpm",
        }
    }
}

/// The mechanics between motor and carriage: counts per motor revolution and the
/// carriage travel per revolution (the screw lead times any gear ratio).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Mechanics {
    pub counts_per_rev: f64,
    pub mm_per_rev: f64,
}

impl Mechanics {
    pub fn counts_per_mm(&self) -> f64 {
        self.counts_per_rev / self.mm_per_rev
    }

    /// A physical value (mm, mm/s or mm/s^2, by the unit's quantity) as the register's
    /// number (not yet rounded).
    pub fn to_register(&self, unit: Unit, physical: f64) -> f64 {
        let cpm = self.counts_per_mm();
        match unit {
            Unit::Counts | Unit::CountsPerS | Unit::CountsPerS2 => physical * cpm,
            Unit::Rpm => physical * 60.0 / self.mm_per_rev,
            Unit::MsPer1000Rpm => {
                let rpm_per_s = physical * 60.0 / self.mm_per_rev;
                1000.0 * 1000.0 / rpm_per_s
            }
        }
    }

    /// A register's number as the physical value (inverse of [`Self::to_register`]).
    pub fn from_register(&self, unit: Unit, raw: f64) -> f64 {
        let cpm = self.counts_per_mm();
        match unit {
            Unit::Counts | Unit::CountsPerS | Unit::CountsPerS2 => raw / cpm,
            Unit::Rpm => raw * self.mm_per_rev / 60.0,
            Unit::MsPer1000Rpm => {
                let rpm_per_s = 1000.0 * 1000.0 / raw;
                rpm_per_s * self.mm_per_rev / 60.0
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thirty_two_bit_values_split_in_either_word_order() {
        let hi = encode(100_000, DataType::I32, WordOrder::HighFirst).unwrap();
        assert_eq!(hi, vec![0x0001, 0x86A0]);
        let lo = encode(100_000, DataType::I32, WordOrder::LowFirst).unwrap();
        assert_eq!(lo, vec![0x86A0, 0x0001]);
        assert_eq!(decode(&hi, DataType::I32, WordOrder::HighFirst), 100_000);
        assert_eq!(decode(&lo, DataType::I32, WordOrder::LowFirst), 100_000);
        let neg = encode(-2, DataType::I32, WordOrder::HighFirst).unwrap();
        assert_eq!(neg, vec![0xFFFF, 0xFFFE]);
        assert_eq!(decode(&neg, DataType::I32, WordOrder::HighFirst), -2);
        assert_eq!(
            decode(&neg, DataType::U32, WordOrder::HighFirst),
            0xFFFF_FFFE
        );
        assert_eq!(decode(&[0xFFFF], DataType::I16, WordOrder::HighFirst), -1);
    }

    #[test]
    fn out_of_range_values_are_refused_not_wrapped() {
        assert!(encode(-1, DataType::U16, WordOrder::HighFirst).is_err());
        assert!(encode(70_000, DataType::I16, WordOrder::HighFirst).is_err());
        let e = encode(1 << 31, DataType::I32, WordOrder::HighFirst).unwrap_err();
        assert!(e.to_string().contains("i32"), "{e}");
    }

    #[test]
    fn units_convert_both_ways() {
        // 10000 counts/rev on a 5 mm lead: 2000 counts/mm.
        let m = Mechanics {
            counts_per_rev: 10_000.0,
            mm_per_rev: 5.0,
        };
        assert_eq!(m.to_register(Unit::Counts, 50.0), 100_000.0);
        // 500 rpm on 5 mm/rev = 41.667 mm/s.
        let v = m.from_register(Unit::Rpm, 500.0);
        assert!((v - 500.0 * 5.0 / 60.0).abs() < 1e-9);
        // 100 ms per 1000 rpm = 10000 rpm/s = 833.3 mm/s^2 on 5 mm/rev.
        let a = m.from_register(Unit::MsPer1000Rpm, 100.0);
        assert!((a - 10_000.0 * 5.0 / 60.0).abs() < 1e-9, "{a}");
        for u in [
            Unit::Counts,
            Unit::CountsPerS,
            Unit::Rpm,
            Unit::CountsPerS2,
            Unit::MsPer1000Rpm,
        ] {
            let back = m.from_register(u, m.to_register(u, 123.4));
            assert!((back - 123.4).abs() < 1e-9, "{u:?}");
        }
    }
}

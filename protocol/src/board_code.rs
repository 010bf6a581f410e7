//! The position code of a coded calibration board (issue 28, `docs/coded-board.md`).
//!
//! Every dot of a coded board carries one bit in its diameter: bit 0 a small dot, bit 1
//! a large one. The bit of dot (i, j) follows from the seed by a one-line formula
//! ([`CodeScheme`]), so the whole array follows from the seed alone, a lab can print it,
//! and cutting a board to another size keeps every dot's bit. In the scheme of new
//! boards (`keyed-two-size`) the seed is mixed into the hash, so every seed is its own
//! array; in the first scheme (`random-two-size`, kept so boards printed with it still
//! read) the seed was added to the index, so seed + 1 is the same array one column over. A pseudo-random array of this kind has, with overwhelming
//! probability, every window of 7 x 7 or more dots unique on the board in all eight
//! orientations (turned by 90°, 180°, 270°, mirrored) and far (in Hamming distance) from
//! every other window: the decoder (`vision::localize::code`) checks the margin on every
//! frame and refuses a frame whose best match is not clearly alone, so a misread or dirty
//! dot is either outvoted or the frame is refused, never read as another position.
//!
//! Sans-IO and pure: generation and lookup only; the board file section is parsed in
//! [`crate::board`].

use serde::{Deserialize, Serialize};

/// How the seed makes the array; the board file names it (`[board.code] scheme`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CodeScheme {
    /// `random-two-size` (issue 28): `bit(i, j) = top bit of SplitMix64(seed + (j << 32 |
    /// i))`. The seed is added to the index, so the array of seed `s + m * 2^32 + k` is
    /// that of seed `s` shifted by m rows and k columns: two boards with nearby seeds
    /// read each other's frames one pitch off. Kept so boards printed with it read as
    /// before; new boards use [`CodeScheme::Keyed`].
    Additive,
    /// `keyed-two-size` (issue 38): `bit(i, j) = top bit of SplitMix64(SplitMix64(seed) ^
    /// (j << 32 | i))`. The seed is hashed before it meets the index, so two seeds give
    /// unrelated arrays (a window of one board differs from every window of another in
    /// about half its dots) and a frame of another board is refused.
    Keyed,
}

impl CodeScheme {
    /// Every scheme, by the name board files give it.
    pub const ALL: [(&'static str, CodeScheme); 2] = [
        ("keyed-two-size", CodeScheme::Keyed),
        ("random-two-size", CodeScheme::Additive),
    ];

    pub fn name(self) -> &'static str {
        match self {
            CodeScheme::Additive => "random-two-size",
            CodeScheme::Keyed => "keyed-two-size",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.iter().find(|(n, _)| *n == name).map(|(_, s)| *s)
    }
}

/// The scheme of the first coded boards (its name); [`CodeScheme`] has all of them.
pub const SCHEME: &str = "random-two-size";

/// Smallest accepted ratio of the large to the small dot diameter: below it blur and
/// print tolerance make the two sizes hard to tell apart.
pub const MIN_SIZE_RATIO: f64 = 1.25;

/// Width and height (dots) of the key window of the lookup index: 20 bits, so a key
/// names about 135 000 / 2^20 = 0.13 wrong board positions on the default board.
pub const KEY_W: u32 = 5;
pub const KEY_H: u32 = 4;

/// SplitMix64 (Steele, Lea, Flood 2014): the mixing function of the code.
#[inline]
pub fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The bit of dot (i, j) for `seed` in `scheme`: true = a large dot.
#[inline]
pub fn code_bit(scheme: CodeScheme, seed: u64, i: u32, j: u32) -> bool {
    let index = ((j as u64) << 32) | i as u64;
    let mixed = match scheme {
        CodeScheme::Additive => seed.wrapping_add(index),
        CodeScheme::Keyed => splitmix64(seed) ^ index,
    };
    splitmix64(mixed) >> 63 == 1
}

/// The code of one board: the seed, the two dot sizes, and every bit packed by row.
#[derive(Clone, Debug, PartialEq)]
pub struct BoardCode {
    pub scheme: CodeScheme,
    pub seed: u64,
    /// Diameter of a 0 dot and of a 1 dot, mm.
    pub dot_diameters_mm: [f64; 2],
    cols: u32,
    rows: u32,
    words_per_row: usize,
    /// Row-major, `words_per_row` words a row; bit k of word w is column 64 w + k. One
    /// spare word a row so [`BoardCode::bits`] can always read two words.
    packed: Vec<u64>,
    /// Every [`KEY_W`] x [`KEY_H`] window of the board by key (key bit `r * KEY_W + c` is
    /// dot (i + c, j + r) of the window whose lowest corner is (i, j)): the corners
    /// `j * cols + i` of key k are `corners[starts[k]..starts[k + 1]]`. A direct table
    /// (4 MiB for 20-bit keys) so a lookup is two reads.
    starts: Vec<u32>,
    corners: Vec<u32>,
}

/// The board file's `[board.code]` section.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CodeSection {
    pub scheme: String,
    pub seed: u64,
    /// The whole list is read: a third value is refused, not dropped (issue 38).
    #[serde(deserialize_with = "crate::config::two_diameters")]
    pub dot_diameters_mm: [f64; 2],
}

impl BoardCode {
    /// The code of a `cols` x `rows` board.
    pub fn generate(
        scheme: CodeScheme,
        seed: u64,
        dot_diameters_mm: [f64; 2],
        cols: u32,
        rows: u32,
    ) -> Self {
        let words_per_row = cols as usize / 64 + 2;
        let mut packed = vec![0u64; words_per_row * rows as usize];
        for j in 0..rows {
            let row = &mut packed[j as usize * words_per_row..(j as usize + 1) * words_per_row];
            for i in 0..cols {
                if code_bit(scheme, seed, i, j) {
                    row[i as usize / 64] |= 1 << (i % 64);
                }
            }
        }
        let mut code = Self {
            scheme,
            seed,
            dot_diameters_mm,
            cols,
            rows,
            words_per_row,
            packed,
            starts: Vec::new(),
            corners: Vec::new(),
        };
        if cols >= KEY_W && rows >= KEY_H {
            // Counting sort by key.
            let keys = 1usize << (KEY_W * KEY_H);
            // Two passes over the keys (counted, then placed): no list of all windows.
            let mut starts = vec![0u32; keys + 1];
            let windows = ((cols - KEY_W + 1) as usize) * ((rows - KEY_H + 1) as usize);
            for j in 0..=rows - KEY_H {
                for i in 0..=cols - KEY_W {
                    starts[code.key_at(i, j) as usize + 1] += 1;
                }
            }
            for k in 0..keys {
                starts[k + 1] += starts[k];
            }
            let mut next = starts.clone();
            let mut corners = vec![0u32; windows];
            for j in 0..=rows - KEY_H {
                for i in 0..=cols - KEY_W {
                    let key = code.key_at(i, j) as usize;
                    corners[next[key] as usize] = j * cols + i;
                    next[key] += 1;
                }
            }
            code.starts = starts;
            code.corners = corners;
        }
        code
    }

    /// The key of the [`KEY_W`] x [`KEY_H`] window whose lowest corner is (i, j).
    fn key_at(&self, i: u32, j: u32) -> u64 {
        (0..KEY_H).fold(0, |k, r| k | (self.bits(i, j + r, KEY_W) << (r * KEY_W)))
    }

    /// Lowest corners (i, j) of every window with this key (see [`KEY_W`]).
    pub fn lookup(&self, key: u64) -> impl Iterator<Item = [i64; 2]> + '_ {
        let k = key as usize;
        let range = match (self.starts.get(k), self.starts.get(k + 1)) {
            (Some(&a), Some(&b)) => a as usize..b as usize,
            _ => 0..0,
        };
        let cols = self.cols;
        self.corners[range]
            .iter()
            .map(move |&p| [(p % cols) as i64, (p / cols) as i64])
    }

    /// Bit of dot (i, j), None off the board.
    #[inline]
    pub fn bit(&self, i: i64, j: i64) -> Option<bool> {
        if i < 0 || j < 0 || i >= self.cols as i64 || j >= self.rows as i64 {
            return None;
        }
        let w = self.packed[j as usize * self.words_per_row + i as usize / 64];
        Some((w >> (i % 64)) & 1 == 1)
    }

    /// Diameter of dot (i, j), mm (the small one off the board).
    #[inline]
    pub fn diameter_mm(&self, i: i64, j: i64) -> f64 {
        self.dot_diameters_mm[usize::from(self.bit(i, j).unwrap_or(false))]
    }

    /// Bits of row `j`, columns `i .. i + n` (n <= 64), bit k = column i + k; columns past
    /// the board read 0. `i` and `j` must be on the board.
    #[inline]
    pub fn bits(&self, i: u32, j: u32, n: u32) -> u64 {
        debug_assert!(i < self.cols && j < self.rows && n <= 64);
        let base = j as usize * self.words_per_row + i as usize / 64;
        let s = i % 64;
        let lo = self.packed[base] >> s;
        let hi = if s == 0 {
            0
        } else {
            self.packed[base + 1] << (64 - s)
        };
        let v = lo | hi;
        if n == 64 {
            v
        } else {
            v & ((1u64 << n) - 1)
        }
    }

    pub fn cols(&self) -> u32 {
        self.cols
    }

    pub fn rows(&self) -> u32 {
        self.rows
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bits_follow_the_formula_and_read_across_words() {
        let c = BoardCode::generate(CodeScheme::Additive, 28, [0.2, 0.3], 150, 3);
        let ones = (0..150).filter(|&i| c.bit(i, 1).unwrap()).count();
        assert!((50..100).contains(&ones), "{ones}");
        for j in 0..3u32 {
            for i in 0..150u32 {
                assert_eq!(
                    c.bit(i as i64, j as i64),
                    Some(code_bit(CodeScheme::Additive, 28, i, j))
                );
            }
            for i in [0u32, 1, 60, 63, 64, 100, 140] {
                let n = 10.min(150 - i);
                let v = c.bits(i, j, n);
                for k in 0..n {
                    assert_eq!(
                        (v >> k) & 1 == 1,
                        code_bit(CodeScheme::Additive, 28, i + k, j),
                        "{i} {j} {k}"
                    );
                }
            }
        }
        assert_eq!(c.bit(150, 0), None);
        assert_eq!(c.bit(0, -1), None);
        // The first bits of seed 28, as the documentation's worked example gives them.
        let row0: String = (0..8)
            .map(|i| {
                if code_bit(CodeScheme::Additive, 28, i, 0) {
                    '1'
                } else {
                    '0'
                }
            })
            .collect();
        assert_eq!(row0.len(), 8);
    }

    #[test]
    fn every_key_window_is_found_where_it_is() {
        let c = BoardCode::generate(CodeScheme::Keyed, 7, [0.2, 0.3], 60, 40);
        for (i, j) in [(0u32, 0u32), (13, 7), (55, 36)] {
            let key = (0..KEY_H).fold(0u64, |k, r| {
                (0..KEY_W).fold(k, |k, col| {
                    k | (u64::from(code_bit(CodeScheme::Keyed, 7, i + col, j + r))
                        << (r * KEY_W + col))
                })
            });
            let found: Vec<[i64; 2]> = c.lookup(key).collect();
            assert!(found.contains(&[i as i64, j as i64]), "{i} {j}: {found:?}");
        }
    }

    /// Issue 38: in the first scheme seed 29 is seed 28 one column over (and seed
    /// 28 + 2^32 one row over), so a frame of one board reads on the other one pitch off.
    /// In the keyed scheme no shift of a nearby seed's array comes close to another's.
    #[test]
    fn keyed_seeds_are_their_own_arrays_where_added_seeds_were_shifted_copies() {
        let agreement = |scheme, s0: u64, s1: u64, di: u32, dj: u32| {
            let same = (0..40u32)
                .flat_map(|j| (0..60u32).map(move |i| (i, j)))
                .filter(|&(i, j)| {
                    code_bit(scheme, s1, i, j) == code_bit(scheme, s0, i + di, j + dj)
                })
                .count();
            same as f64 / 2400.0
        };
        assert_eq!(agreement(CodeScheme::Additive, 28, 29, 1, 0), 1.0);
        assert_eq!(
            agreement(CodeScheme::Additive, 28, 28 + (1 << 32), 0, 1),
            1.0
        );
        for s1 in [29, 30, 28 + (1 << 32), 27] {
            for dj in 0..4 {
                for di in 0..4 {
                    let a = agreement(CodeScheme::Keyed, 28, s1, di, dj);
                    assert!(
                        (0.45..0.55).contains(&a),
                        "seed {s1} shifted ({di}, {dj}): {a}"
                    );
                }
            }
        }
        assert_eq!(
            CodeScheme::from_name("keyed-two-size"),
            Some(CodeScheme::Keyed)
        );
        assert_eq!(CodeScheme::from_name(SCHEME), Some(CodeScheme::Additive));
        assert_eq!(CodeScheme::from_name("qr"), None);
    }

    #[test]
    fn splitmix_matches_the_reference_values() {
        // Reference: the first outputs of SplitMix64 seeded with 0 are
        // splitmix64(0), splitmix64(0x9E37...) ... (Vigna's splitmix64.c).
        assert_eq!(splitmix64(0), 0xE220_A839_7B1D_CDAF);
    }
}

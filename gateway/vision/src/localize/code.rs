//! Decoding a coded board (`protocol::board_code`, `docs/coded-board.md`): which board
//! dots are in view, read from the dots' sizes alone, with no hint.
//!
//! 1. [`classify`]: every indexed dot's diameter is read as a bit (small 0, large 1) by
//!    two-means clustering seeded with the board's two sizes; a dot in the middle band
//!    between the two clusters is an erasure (not read), like a missing dot.
//! 2. [`decode`]: in each of the eight orientations of the lattice on the board (four
//!    turns, mirrored or not), every fully read 5 x 4 window of the view is looked up in
//!    the board's index (`protocol::board_code::BoardCode::lookup`): each hit is a
//!    candidate board position, and each candidate is compared with every dot read. The
//!    best candidate is accepted only when it has at most [`max_errors`] disagreeing dots
//!    and every other candidate disagrees in at least [`MIN_MARGIN`] more: so a few
//!    misread (dirty, damaged) dots are outvoted, and a frame that could be read two ways
//!    is refused, never misread. A position that shares no error-free 5 x 4 window with
//!    the view is not a candidate: it disagrees with the view in at least one dot in
//!    every such window, hence far more than the accepted best (the default view holds
//!    about 30 of them).
//!
//! [`decode_exhaustive`] compares with every board position instead (the same answer,
//! 50 times slower): the tests check the two agree, so the candidates' margin is the
//! true one.

use protocol::board_code::BoardCode;

/// Fewest readable dots a decode accepts (a 6 x 5 window; the default optics show about
/// 10 x 8).
pub const MIN_BITS: usize = 30;

/// Fewest extra disagreeing dots of the second-best board position or orientation over
/// the best, for the best to be accepted.
pub const MIN_MARGIN: usize = 6;

/// Most dots not read in a key window that is still looked up (with each value).
pub const MAX_KEY_HOLES: usize = 2;

/// Largest view side, in dots, that is used for decoding (a window around the dot nearest
/// the image centre): more adds nothing to the margin and costs time.
pub const MAX_SIDE: i64 = 24;

/// Most disagreeing dots the best match may have: one in eight of the bits read.
pub fn max_errors(bits: usize) -> usize {
    bits / 8
}

/// The eight orientations of the lattice on the board: board direction of lattice
/// index `a` (image x) and of `b` (image y).
pub const ORIENTATIONS: [[[i64; 2]; 2]; 8] = [
    [[1, 0], [0, -1]],
    [[1, 0], [0, 1]],
    [[-1, 0], [0, 1]],
    [[-1, 0], [0, -1]],
    [[0, 1], [1, 0]],
    [[0, 1], [-1, 0]],
    [[0, -1], [1, 0]],
    [[0, -1], [-1, 0]],
];

/// What the code said about a frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Decoded {
    /// Board direction of lattice index a and of b.
    pub axes: [[i64; 2]; 2],
    /// Board index of lattice index (0, 0).
    pub ij0: [i64; 2],
    /// Dots read (bits compared).
    pub bits: usize,
    /// Read dots that disagree with the board at the accepted position.
    pub errors: usize,
    /// Disagreeing dots of the second-best position or orientation (at most the search
    /// cut-off, `max_errors + MIN_MARGIN`: larger ones are not counted exactly).
    pub second: usize,
}

/// Why a frame's code could not be read.
#[derive(Clone, Debug, PartialEq)]
pub enum DecodeError {
    TooFewBits {
        bits: usize,
    },
    NoMatch {
        bits: usize,
        best: usize,
        limit: usize,
    },
    NotAlone {
        bits: usize,
        best: usize,
        second: usize,
    },
}

/// Read each dot diameter (any unit, None for a dot not on the lattice) as a bit, given
/// the board's two nominal sizes in the same unit: None for a dot not read.
pub fn classify(diameters: &[Option<f64>], sizes: [f64; 2]) -> Vec<Option<bool>> {
    let known: Vec<f64> = diameters.iter().flatten().copied().collect();
    let (mut m0, mut m1) = (sizes[0], sizes[1]);
    // Two-means from the nominal sizes: blur, print and threshold shift both clusters.
    for _ in 0..8 {
        let t = 0.5 * (m0 + m1);
        let (mut s0, mut n0, mut s1, mut n1) = (0.0, 0usize, 0.0, 0usize);
        for &d in &known {
            if d < t {
                s0 += d;
                n0 += 1;
            } else {
                s1 += d;
                n1 += 1;
            }
        }
        if n0 == 0 || n1 == 0 {
            break;
        }
        (m0, m1) = (s0 / n0 as f64, s1 / n1 as f64);
    }
    // Clusters that collapsed or crossed: fall back to the nominal sizes.
    if !(m1 - m0 > 0.3 * (sizes[1] - sizes[0])) {
        (m0, m1) = (sizes[0], sizes[1]);
    }
    let t = 0.5 * (m0 + m1);
    let band = 0.2 * (m1 - m0);
    diameters
        .iter()
        .map(|d| {
            let d = (*d)?;
            if (d - t).abs() < band {
                None
            } else {
                Some(d > t)
            }
        })
        .collect()
}

/// The board position and orientation of the observed bits (`(lattice index, bit)`),
/// or why none is accepted: candidates from the board's index of 5 x 4 windows, and
/// when none of them is within [`max_errors`], the exhaustive search
/// ([`decode_exhaustive`]). In the 9 x 7 view the default optics guarantee, every 5 x 4
/// window holds the centre dot, so one misread dot there hides the true position from
/// every lookup (issue 38); the exhaustive search finds it whenever it is within the
/// accepted number of misread dots, wherever they are, at its cost (tens of ms) on
/// those frames only.
pub fn decode(code: &BoardCode, obs: &[([i64; 2], bool)]) -> Result<Decoded, DecodeError> {
    match decode_indexed(code, obs) {
        Err(DecodeError::NoMatch { .. }) => decode_exhaustive(code, obs),
        other => other,
    }
}

/// [`decode`] from the index alone: a position becomes a candidate only through a 5 x 4
/// window of the view read without error (up to [`MAX_KEY_HOLES`] dots not read).
pub fn decode_indexed(code: &BoardCode, obs: &[([i64; 2], bool)]) -> Result<Decoded, DecodeError> {
    use protocol::board_code::{KEY_H, KEY_W};
    let obs: Vec<([i64; 2], bool)> = obs
        .iter()
        .filter(|(ab, _)| ab[0].abs() <= MAX_SIDE / 2 && ab[1].abs() <= MAX_SIDE / 2)
        .copied()
        .collect();
    let bits = obs.len();
    if bits < MIN_BITS {
        return Err(DecodeError::TooFewBits { bits });
    }
    let limit = max_errors(bits);
    let cutoff = limit + MIN_MARGIN;
    let side = MAX_SIDE as usize + 1;
    let half = MAX_SIDE / 2;
    // Every key first, then every lookup: each lookup is a cache miss in the board's
    // index (megabytes), and with nothing between them the processor has several in
    // flight at once instead of one per window (the same keys in the same order, so
    // the same candidates in the same order).
    let mut keys: Vec<(usize, usize, usize, u64)> = Vec::new();
    for (o, axes) in ORIENTATIONS.iter().enumerate() {
        // The view in board-aligned cells: -1 not read, else the bit.
        let mut grid = vec![-1i8; side * side];
        for (ab, bit) in &obs {
            let q = [
                ab[0] * axes[0][0] + ab[1] * axes[1][0] + half,
                ab[0] * axes[0][1] + ab[1] * axes[1][1] + half,
            ];
            grid[q[1] as usize * side + q[0] as usize] = i8::from(*bit);
        }
        let (kw, kh) = (KEY_W as usize, KEY_H as usize);
        // Placements inside the cells read only.
        let (mut c_lo, mut c_hi, mut r_lo, mut r_hi) = (side, 0, side, 0);
        for (k, v) in grid.iter().enumerate() {
            if *v >= 0 {
                let (c, r) = (k % side, k / side);
                (c_lo, c_hi, r_lo, r_hi) = (c_lo.min(c), c_hi.max(c), r_lo.min(r), r_hi.max(r));
            }
        }
        if c_hi + 1 < c_lo + kw || r_hi + 1 < r_lo + kh {
            continue;
        }
        for r0 in r_lo..=r_hi + 1 - kh {
            'window: for c0 in c_lo..=c_hi + 1 - kw {
                // A window with up to MAX_KEY_HOLES dots not read is looked up with every
                // value of them: missing and merged dots must not hide the position.
                let (mut key, mut holes) = (0u64, Vec::new());
                for r in 0..kh {
                    for c in 0..kw {
                        let bit = r * kw + c;
                        match grid[(r0 + r) * side + c0 + c] {
                            -1 if holes.len() == MAX_KEY_HOLES => continue 'window,
                            -1 => holes.push(bit),
                            b => key |= (b as u64) << bit,
                        }
                    }
                }
                for fill in 0..1u64 << holes.len() {
                    let mut k = key;
                    for (n, bit) in holes.iter().enumerate() {
                        k |= ((fill >> n) & 1) << bit;
                    }
                    keys.push((o, c0, r0, k));
                }
            }
        }
    }
    let mut cands: Vec<(usize, [i64; 2])> = Vec::new();
    for &(o, c0, r0, k) in &keys {
        for corner in code.lookup(k) {
            // Board index of the view's cell (half, half), i.e. lattice (0, 0).
            let ij0 = [corner[0] - c0 as i64 + half, corner[1] - r0 as i64 + half];
            if !cands.contains(&(o, ij0)) {
                cands.push((o, ij0));
            }
        }
    }
    let mut best: Option<(usize, usize, [i64; 2])> = None;
    let mut second = cutoff + 1;
    for (o, ij0) in cands {
        let axes = ORIENTATIONS[o];
        // Once a best within the cut-off is known, a candidate past the cut-off changes
        // nothing (the second is counted only up to cutoff + 1): stop counting there.
        // Most candidates are chance matches of one window in a wrong orientation and
        // disagree in half the dots.
        let stop_past = match best {
            Some((b, _, _)) if b <= cutoff => cutoff,
            _ => usize::MAX,
        };
        let mut d = 0;
        for (ab, bit) in &obs {
            let ij = [
                ij0[0] + ab[0] * axes[0][0] + ab[1] * axes[1][0],
                ij0[1] + ab[0] * axes[0][1] + ab[1] * axes[1][1],
            ];
            if code.bit(ij[0], ij[1]) != Some(*bit) {
                d += 1;
                if d > stop_past {
                    break;
                }
            }
        }
        match best {
            Some(b) if d >= b.0 => second = second.min(d),
            Some(b) => {
                second = second.min(b.0);
                best = Some((d, o, ij0));
            }
            None => best = Some((d, o, ij0)),
        }
    }
    accept(bits, limit, cutoff, best, second)
}

fn accept(
    bits: usize,
    limit: usize,
    cutoff: usize,
    best: Option<(usize, usize, [i64; 2])>,
    second: usize,
) -> Result<Decoded, DecodeError> {
    let second = second.min(cutoff + 1);
    let Some((errors, o, ij0)) = best else {
        return Err(DecodeError::NoMatch {
            bits,
            best: cutoff + 1,
            limit,
        });
    };
    if errors > limit {
        return Err(DecodeError::NoMatch {
            bits,
            best: errors,
            limit,
        });
    }
    if second < errors + MIN_MARGIN {
        return Err(DecodeError::NotAlone {
            bits,
            best: errors,
            second,
        });
    }
    Ok(Decoded {
        axes: ORIENTATIONS[o],
        ij0,
        bits,
        errors,
        second,
    })
}

/// [`decode`] by comparing with every board position in every orientation (a bit-packed
/// search a board row at a time): the reference the index is checked against.
pub fn decode_exhaustive(
    code: &BoardCode,
    obs: &[([i64; 2], bool)],
) -> Result<Decoded, DecodeError> {
    let obs: Vec<([i64; 2], bool)> = obs
        .iter()
        .filter(|(ab, _)| ab[0].abs() <= MAX_SIDE / 2 && ab[1].abs() <= MAX_SIDE / 2)
        .copied()
        .collect();
    let bits = obs.len();
    if bits < MIN_BITS {
        return Err(DecodeError::TooFewBits { bits });
    }
    let limit = max_errors(bits);
    let cutoff = limit + MIN_MARGIN;
    // (distance, orientation, board index of the window's corner)
    let mut best: Option<(usize, usize, [i64; 2])> = None;
    let mut second = usize::MAX;
    for (o, axes) in ORIENTATIONS.iter().enumerate() {
        let q: Vec<([i64; 2], bool)> = obs
            .iter()
            .map(|(ab, bit)| {
                (
                    [
                        ab[0] * axes[0][0] + ab[1] * axes[1][0],
                        ab[0] * axes[0][1] + ab[1] * axes[1][1],
                    ],
                    *bit,
                )
            })
            .collect();
        let lo = [
            q.iter().map(|p| p.0[0]).min().unwrap_or(0),
            q.iter().map(|p| p.0[1]).min().unwrap_or(0),
        ];
        let hi = [
            q.iter().map(|p| p.0[0]).max().unwrap_or(0),
            q.iter().map(|p| p.0[1]).max().unwrap_or(0),
        ];
        let (w, h) = ((hi[0] - lo[0] + 1) as u32, (hi[1] - lo[1] + 1) as u32);
        if w > code.cols() || h > code.rows() || w > 64 {
            continue;
        }
        let mut val = vec![0u64; h as usize];
        let mut mask = vec![0u64; h as usize];
        for (p, bit) in &q {
            let (c, r) = ((p[0] - lo[0]) as u32, (p[1] - lo[1]) as usize);
            mask[r] |= 1 << c;
            if *bit {
                val[r] |= 1 << c;
            }
        }
        // Rows with the most dots first: a wrong position is left soonest.
        let mut order: Vec<usize> = (0..h as usize).filter(|&r| mask[r] != 0).collect();
        order.sort_by_key(|&r| std::cmp::Reverse(mask[r].count_ones()));
        for j0 in 0..=(code.rows() - h) {
            for i0 in 0..=(code.cols() - w) {
                let stop = second.min(cutoff + 1);
                let mut d = 0usize;
                for &r in &order {
                    let b = code.bits(i0, j0 + r as u32, w);
                    d += ((b ^ val[r]) & mask[r]).count_ones() as usize;
                    if d >= stop {
                        break;
                    }
                }
                if d >= stop {
                    continue;
                }
                let here = (d, o, [i0 as i64 - lo[0], j0 as i64 - lo[1]]);
                match best {
                    Some(b) if d >= b.0 => second = d,
                    Some(b) => {
                        second = b.0;
                        best = Some(here);
                    }
                    None => best = Some(here),
                }
            }
        }
    }
    accept(bits, limit, cutoff, best, second)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view(
        code: &BoardCode,
        axes: [[i64; 2]; 2],
        at: [i64; 2],
        n: [i64; 2],
    ) -> Vec<([i64; 2], bool)> {
        let mut obs = Vec::new();
        for b in -n[1]..=n[1] {
            for a in -n[0]..=n[0] {
                let ij = [
                    at[0] + a * axes[0][0] + b * axes[1][0],
                    at[1] + a * axes[0][1] + b * axes[1][1],
                ];
                if let Some(bit) = code.bit(ij[0], ij[1]) {
                    obs.push(([a, b], bit));
                }
            }
        }
        obs
    }

    /// The index finds what the exhaustive search finds; its runner-up is never nearer
    /// than the true one (it may miss near positions that share no clean key window).
    fn same_answer(index: &Decoded, all: &Decoded) {
        assert_eq!(
            (index.axes, index.ij0, index.bits, index.errors),
            (all.axes, all.ij0, all.bits, all.errors)
        );
        assert!(index.second >= all.second, "{index:?} {all:?}");
    }

    #[test]
    fn every_orientation_is_found_and_named() {
        let code = BoardCode::generate(
            protocol::board_code::CodeScheme::Additive,
            28,
            [0.2, 0.3],
            421,
            321,
        );
        for (k, axes) in ORIENTATIONS.iter().enumerate() {
            let at = [17 + 40 * k as i64, 300 - 30 * k as i64];
            let obs = view(&code, *axes, at, [4, 3]);
            let d = decode(&code, &obs).unwrap();
            assert_eq!((d.axes, d.ij0, d.errors), (*axes, at, 0), "{k}");
            if k < 2 {
                same_answer(&d, &decode_exhaustive(&code, &obs).unwrap());
            }
            assert_eq!(d.bits, 63);
            assert!(d.second >= MIN_MARGIN, "{d:?}");
        }
    }

    #[test]
    fn misread_dots_are_outvoted_and_too_many_refused() {
        let code = BoardCode::generate(
            protocol::board_code::CodeScheme::Additive,
            28,
            [0.2, 0.3],
            421,
            321,
        );
        let axes = ORIENTATIONS[0];
        let mut obs = view(&code, axes, [200, 100], [4, 3]);
        for k in [3, 20, 41] {
            obs[k].1 = !obs[k].1;
        }
        let d = decode(&code, &obs).unwrap();
        assert_eq!((d.ij0, d.errors), ([200, 100], 3));
        same_answer(&d, &decode_exhaustive(&code, &obs).unwrap());
        // A third of the dots flipped: no position is close, refused.
        for k in (0..obs.len()).step_by(3) {
            obs[k].1 = !obs[k].1;
        }
        assert!(decode(&code, &obs).is_err());
        // Too small a window is refused before searching.
        let few = view(&code, axes, [200, 100], [2, 2]);
        assert_eq!(
            decode(&code, &few),
            Err(DecodeError::TooFewBits { bits: 25 })
        );
    }

    /// Issue 38: in the guaranteed 9 x 7 view every 5 x 4 window holds the centre dot;
    /// one misread dot there made the true position no candidate at all. Up to the
    /// accepted number of misread dots, wherever they are, the position is found.
    #[test]
    fn misread_dots_at_the_centre_do_not_hide_the_position() {
        let code = BoardCode::generate(
            protocol::board_code::CodeScheme::Keyed,
            28,
            [0.2, 0.3],
            421,
            321,
        );
        for (k, axes) in ORIENTATIONS.iter().enumerate().step_by(3) {
            let at = [60 + 50 * k as i64, 250 - 20 * k as i64];
            let clean = view(&code, *axes, at, [4, 3]);
            let limit = max_errors(clean.len());
            assert_eq!(limit, 7);
            // The centre first, then its neighbours: dots in the most windows.
            let mut central: Vec<usize> = (0..clean.len()).collect();
            central.sort_by_key(|&n| {
                let [a, b] = clean[n].0;
                (a.abs() + b.abs(), a.abs(), b, a)
            });
            for wrong in 1..=limit {
                let mut obs = clean.clone();
                for &n in &central[..wrong] {
                    obs[n].1 = !obs[n].1;
                }
                // Turned a quarter, the view is 7 x 9 on the board and some windows
                // leave the centre out; otherwise the index alone misses it.
                if k < 4 {
                    assert!(
                        matches!(
                            decode_indexed(&code, &obs),
                            Err(DecodeError::NoMatch { .. })
                        ),
                        "the index alone misses it: {k}, {wrong}"
                    );
                }
                let d = decode(&code, &obs).unwrap_or_else(|e| panic!("{k}, {wrong}: {e:?}"));
                assert_eq!((d.axes, d.ij0, d.errors), (*axes, at, wrong), "{k}");
            }
        }
    }

    #[test]
    fn sizes_are_read_with_a_middle_band_left_unread() {
        let d = [
            Some(0.21),
            Some(0.29),
            None,
            Some(0.25),
            Some(0.19),
            Some(0.31),
        ];
        assert_eq!(
            classify(&d, [0.2, 0.3]),
            vec![Some(false), Some(true), None, None, Some(false), Some(true)]
        );
        // A blur that grows every dot by 10 % shifts the threshold with it.
        let grown: Vec<Option<f64>> = d.iter().map(|v| v.map(|x| x * 1.1)).collect();
        assert_eq!(classify(&grown, [0.2, 0.3])[0], Some(false));
        assert_eq!(classify(&grown, [0.2, 0.3])[1], Some(true));
    }
}

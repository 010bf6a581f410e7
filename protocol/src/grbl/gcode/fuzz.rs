//! Deterministic randomized input for the interpreter: lines of G-code letters, digits,
//! signs, dots, huge numbers, words GRBL does not know and garbage, many words per
//! line, run in sequence through one interpreter (so modal state, offsets and stored
//! systems carry over), as GRBL's filter would pass them and as jogs. No line may
//! panic, and none may take more than a few milliseconds.

use super::*;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::time::{Duration, Instant};

/// xorshift64*: small, fast, the same sequence on every machine.
pub(crate) struct Rng(u64);

impl Rng {
    pub(crate) fn new(seed: u64) -> Self {
        Self(seed | 1)
    }
    pub(crate) fn next(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.0 = x;
        x.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    /// 0..n (n > 0).
    pub(crate) fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
    pub(crate) fn pick<'a, T>(&mut self, from: &'a [T]) -> &'a T {
        &from[self.below(from.len())]
    }
}

const LETTERS: &[u8] = b"GGGGMMXXYYZZIJKFFLNPPRRSTABCDEHOQUVW";
const COMMANDS: &[&str] = &[
    "0",
    "1",
    "2",
    "3",
    "4",
    "10",
    "17",
    "18",
    "19",
    "20",
    "21",
    "28",
    "28.1",
    "30",
    "30.1",
    "38.2",
    "38.3",
    "38.4",
    "38.5",
    "38.6",
    "40",
    "43.1",
    "49",
    "53",
    "54",
    "55",
    "56",
    "57",
    "58",
    "59",
    "59.1",
    "59.9",
    "61",
    "61.1",
    "80",
    "90",
    "90.1",
    "91",
    "91.1",
    "92",
    "92.1",
    "93",
    "94",
    "5",
    "8",
    "9",
    "30",
    "255",
    "256",
    "65536",
    "4294967296",
    "-0.5",
    "0.001",
    "99.99",
    "1.995",
];
const ODD: &[&str] = &[
    "", "-", "+", ".", "-.", "+.", "..", "1.2.3", "1e5", "1E308", "NaN", "nan", "inf", "-inf",
    "0x10", " 1", "--1", "+-1", "1-", "0.", ".0", "-0", "-0.0",
];

/// A number: small, round, with decimals, huge (up to 70 digits), signed.
fn number(rng: &mut Rng) -> String {
    let sign = *rng.pick(&["", "", "", "-", "+"]);
    let body = match rng.below(8) {
        0 => rng.pick(COMMANDS).to_string(),
        1 => rng.pick(ODD).to_string(),
        2 => "9".repeat(1 + rng.below(70)),
        3 => format!("{}.{}", "5".repeat(1 + rng.below(40)), rng.below(1000)),
        4 => format!("0.{}", "0".repeat(rng.below(40)) + "1"),
        5 => rng.below(10).to_string(),
        6 => format!("{}.{:03}", rng.below(2000), rng.below(1000)),
        _ => rng.below(100_000).to_string(),
    };
    format!("{sign}{body}")
}

/// Letters GRBL knows, weighted towards commands and axes.
const GRBL_LETTERS: &[u8] = b"GGGGGGMMXXXYYYZZIJKFFLLNPPRRSTT";

/// Blocks that pass GRBL's reading, `#` standing for a random number: they take the
/// interpreter through its checks and its run step with absurd values.
const TEMPLATES: &[&str] = &[
    "G0X#Y#",
    "G1X#F#",
    "G1Z#",
    "G2X#Y#I#J#F#",
    "G3X#Y#R#F#",
    "G2X#I#",
    "G3Y#J#F#",
    "G18G2Z#X#R#F#",
    "G19G3Y#Z#J#K#F#",
    "G17G2X#Y#R#",
    "G10L2P#X#Y#",
    "G10L20P#Z#",
    "G10L2P#X#",
    "G28",
    "G28X#",
    "G28.1",
    "G30Y#",
    "G30.1",
    "G92X#Y#",
    "G92.1",
    "G43.1Z#",
    "G49",
    "G38.2Z#F#",
    "G38.4X#F#",
    "G4P#",
    "N#G1X#",
    "N#",
    "T#M3",
    "S#M3",
    "S#",
    "M4S#",
    "M5",
    "M8",
    "M9",
    "G93G1X#F#",
    "G93G2X#Y#R#F#",
    "G94",
    "G20",
    "G21",
    "G91X#",
    "G90",
    "G91.1",
    "G54",
    "G55",
    "G56",
    "G57",
    "G58",
    "G59",
    "G53G0X#",
    "G53G1Y#F#",
    "G80",
    "M2",
    "M30",
    "M0",
    "M1",
    "G61",
    "G40",
    "G0X#Y#Z#F#S#T#N#",
];

fn template(rng: &mut Rng) -> String {
    let mut out = String::new();
    for c in rng.pick(TEMPLATES).chars() {
        if c == '#' {
            match rng.below(3) {
                0 => out.push_str(&number(rng)),
                _ => out.push_str(&format!("{}{}", rng.pick(&["", "-"]), rng.below(12))),
            }
        } else {
            out.push(c);
        }
    }
    out
}

/// One line: mostly words GRBL knows (so blocks reach the later checks and run),
/// sometimes unknown letters, garbage bytes or comments.
pub(crate) fn line(rng: &mut Rng) -> String {
    if rng.below(4) == 0 {
        return template(rng);
    }
    let known_only = rng.below(3) > 0;
    let letters = if known_only { GRBL_LETTERS } else { LETTERS };
    let mut out = String::new();
    for _ in 0..rng.below(10) {
        if !known_only {
            match rng.below(16) {
                0 => out.push(*rng.pick(&['(', ')', ';', '/', '%', ' ', '$', '=', '#', '[', '*'])),
                1 => out.push(char::from(rng.below(128) as u8)),
                2 => out.push(*rng.pick(&['é', '\u{2212}', '\u{0}', '\u{7f}'])),
                3 => out.push(char::from(b'a' + rng.below(26) as u8)),
                _ => {}
            }
        }
        let letter = char::from(*rng.pick(letters));
        out.push(letter);
        match (known_only, letter) {
            (true, 'G' | 'M') if rng.below(4) > 0 => out.push_str(rng.pick::<&str>(COMMANDS)),
            (true, _) if rng.below(2) > 0 => {
                out.push_str(&format!("{}{}", rng.pick(&["", "-"]), rng.below(20)))
            }
            _ => out.push_str(&number(rng)),
        }
    }
    out
}

#[test]
fn random_lines_never_panic_or_take_long() {
    let mut rng = Rng::new(0x05EE_D0F6_C0DE);
    let mut i = Interpreter::new();
    let mut recent: Vec<String> = Vec::new();
    let (mut ok, mut refused) = (0usize, 0usize);
    let mut slowest = (Duration::ZERO, String::new());
    let lines = 50_000;
    let start = Instant::now();
    for n in 0..lines {
        if n % 500 == 0 {
            i = Interpreter::new();
            recent.clear();
            // `$12` is a setting: any value must be survivable too.
            i.arc_tolerance = *rng.pick(&[0.002, 0.002, 0.0, -1.0, 1e-30, 1e30, f64::NAN]);
        }
        let raw = line(&mut rng);
        let jog = rng.below(10) == 0;
        let (filtered, _) = filter_bytes(raw.as_bytes());
        recent.push(format!("{}{raw:?}", if jog { "$J=" } else { "" }));
        if recent.len() > 8 {
            recent.remove(0);
        }
        let t = Instant::now();
        let r = catch_unwind(AssertUnwindSafe(|| {
            let r = i.execute(&filtered, jog);
            // What the emulator and the driver read back after every block.
            let _ = (i.parser_state(), i.wco());
            r
        }));
        let took = t.elapsed();
        match r {
            Ok(Ok(_)) => ok += 1,
            Ok(Err(_)) => refused += 1,
            Err(_) => panic!(
                "line {n} panicked: {:?} (filtered {filtered:?}); lines since the last reset, last one offending: {recent:#?}",
                recent.last()
            ),
        }
        if took > slowest.0 {
            slowest = (took, raw);
        }
    }
    let elapsed = start.elapsed();
    eprintln!(
        "{lines} lines in {elapsed:?}: {ok} accepted, {refused} refused; slowest {:?} for {:?}",
        slowest.0, slowest.1
    );
    assert!(
        ok > 1000,
        "too few lines accepted ({ok}) to reach the interpreter's later steps"
    );
    assert!(slowest.0 < Duration::from_millis(250), "{slowest:?}");
}

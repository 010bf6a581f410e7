//! Random G-code programs, for the tests and benchmarks that check the rewriter against
//! a machine: straight moves short and long (some along one axis only, where the other
//! axis's correction creeps), arcs G2/G3 in the three planes (G17, G18, G19), G91
//! sections, inches (G20), work offsets (G54-G59, G92, G92.1), feed changes and rapids,
//! every point inside a box given in machine coordinates. Reproducible from a seed.

use crate::{Pose, N_AXIS};
use std::fmt::Write;

/// What to generate.
#[derive(Clone, Debug, PartialEq)]
pub struct ProgramSpec {
    /// The box every programmed point stays in, machine mm (X, Y, Z).
    pub lo: Pose,
    pub hi: Pose,
    /// Moves (and mode changes) to generate.
    pub items: usize,
    pub seed: u64,
    /// Whether G92 and G92.1 are among the items.
    pub g92: bool,
}

/// A generated program.
#[derive(Clone, Debug, PartialEq)]
pub struct Program {
    pub text: String,
    /// The G54..G59 offsets the program expects the controller to hold (its `$#`),
    /// machine mm: set them (`G10 L2 Pn ...`) before running it.
    pub work_offsets: [Pose; 6],
}

impl Program {
    /// The lines that store [`Program::work_offsets`] in a GRBL controller.
    pub fn setup_lines(&self) -> Vec<String> {
        self.work_offsets
            .iter()
            .enumerate()
            .map(|(k, o)| format!("G10 L2 P{} X{:.4} Y{:.4} Z{:.4}", k + 1, o[0], o[1], o[2]))
            .collect()
    }
}

/// A small xorshift generator: the same program for the same seed everywhere.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }
    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        let mut s = self.0;
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        self.0 = s;
        (s >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.uniform()
    }
    pub fn chance(&mut self, p: f64) -> bool {
        self.uniform() < p
    }
}

struct State {
    /// Machine position, mm.
    m: Pose,
    inches: bool,
    incremental: bool,
    /// 0: G17 (X, Y), 1: G18 (Z, X), 2: G19 (Y, Z).
    plane: usize,
    cs: usize,
    stored: [Pose; 6],
    g92: Pose,
    text: String,
}

impl State {
    fn unit(&self) -> f64 {
        if self.inches {
            25.4
        } else {
            1.0
        }
    }
    fn decimals(&self) -> usize {
        if self.inches {
            5
        } else {
            4
        }
    }
    fn wco(&self, i: usize) -> f64 {
        self.stored[self.cs][i] + self.g92[i]
    }
    fn round(&self, v: f64) -> f64 {
        let s = 10f64.powi(self.decimals() as i32);
        (v * s).round() / s
    }
    /// The axis words (only `axes`) that take the machine to `t`; the position is
    /// updated as the controller will read them.
    fn words(&mut self, t: &Pose, axes: &[usize]) -> String {
        let mut w = String::new();
        let unit = self.unit();
        for &i in axes {
            let v = if self.incremental {
                self.round((t[i] - self.m[i]) / unit)
            } else {
                self.round((t[i] - self.wco(i)) / unit)
            };
            self.m[i] = if self.incremental {
                self.m[i] + v * unit
            } else {
                self.wco(i) + v * unit
            };
            let _ = write!(w, "{}{:.*}", ['X', 'Y', 'Z'][i], self.decimals(), v);
        }
        w
    }
    fn feed(&self, rng: &mut Rng) -> String {
        let mm_min = rng.range(300.0, 6000.0);
        format!("F{:.0}", mm_min / self.unit())
    }
    fn line(&mut self, s: &str) {
        self.text.push_str(s);
        self.text.push('\n');
    }
}

/// A random program inside `spec`'s box (see the module's description).
pub fn random_program(spec: &ProgramSpec) -> Program {
    let mut rng = Rng::new(spec.seed);
    let mut stored = [[0.0; N_AXIS]; 6];
    for o in stored.iter_mut().skip(1) {
        *o = [
            rng.range(-20.0, 20.0),
            rng.range(-20.0, 20.0),
            rng.range(-5.0, 5.0),
        ];
    }
    let (lo, hi) = (spec.lo, spec.hi);
    let mut s = State {
        m: [0.0; N_AXIS],
        inches: false,
        incremental: false,
        plane: 0,
        cs: 0,
        stored,
        g92: [0.0; N_AXIS],
        text: String::new(),
    };
    let point = |rng: &mut Rng| -> Pose { std::array::from_fn(|i| rng.range(lo[i], hi[i])) };
    s.line("G21 G90 G17 G54 G94");
    let start = point(&mut rng);
    let w = s.words(&start, &[0, 1, 2]);
    s.line(&format!("G0 {w}"));
    let f = s.feed(&mut rng);
    s.line(&format!("G1 {f}"));
    for _ in 0..spec.items {
        let u = rng.uniform();
        if u < 0.05 {
            s.inches = !s.inches;
            s.line(if s.inches { "G20" } else { "G21" });
            // A feed in the new units.
            let f = s.feed(&mut rng);
            s.line(&f);
        } else if u < 0.09 {
            s.cs = (rng.uniform() * 6.0) as usize % 6;
            s.line(&format!("G{}", 54 + s.cs));
        } else if u < 0.11 && spec.g92 {
            // G92: the present point gets these coordinates.
            let unit = s.unit();
            let mut words = String::new();
            for (i, letter) in ['X', 'Y'].into_iter().enumerate() {
                let v = s.round(rng.range(-50.0, 50.0) / unit);
                s.g92[i] = s.m[i] - s.stored[s.cs][i] - v * unit;
                let _ = write!(words, "{letter}{:.*}", s.decimals(), v);
            }
            s.line(&format!("G92 {words}"));
        } else if u < 0.12 && spec.g92 {
            s.g92 = [0.0; N_AXIS];
            s.line("G92.1");
        } else if u < 0.17 {
            s.plane = (rng.uniform() * 3.0) as usize % 3;
            s.line(["G17", "G18", "G19"][s.plane]);
        } else if u < 0.21 {
            let f = s.feed(&mut rng);
            s.line(&f);
        } else if u < 0.29 {
            // An incremental section of a few moves.
            s.incremental = true;
            s.line("G91");
            for _ in 0..(2 + (rng.uniform() * 4.0) as usize) {
                let (t, axes) = target(&s, &mut rng, lo, hi);
                let w = s.words(&t, &axes);
                s.line(&format!("G1 {w}"));
            }
            s.incremental = false;
            s.line("G90");
        } else if u < 0.36 {
            let t = point(&mut rng);
            let w = s.words(&t, &[0, 1]);
            s.line(&format!("G0 {w}"));
        } else if u < 0.6 {
            if !arc(&mut s, &mut rng, lo, hi) {
                let (t, axes) = target(&s, &mut rng, lo, hi);
                let w = s.words(&t, &axes);
                s.line(&format!("G1 {w}"));
            }
        } else {
            let (t, axes) = target(&s, &mut rng, lo, hi);
            let w = s.words(&t, &axes);
            let f = if rng.chance(0.2) {
                format!(" {}", s.feed(&mut rng))
            } else {
                String::new()
            };
            s.line(&format!("G1 {w}{f}"));
        }
    }
    Program {
        text: s.text,
        work_offsets: s.stored,
    }
}

/// A straight move's end: short, medium or long, a third of them along one axis only.
fn target(s: &State, rng: &mut Rng, lo: Pose, hi: Pose) -> (Pose, Vec<usize>) {
    let m = s.m;
    let u = rng.uniform();
    let length = if u < 0.5 {
        rng.range(0.2, 3.0)
    } else if u < 0.85 {
        rng.range(3.0, 30.0)
    } else {
        rng.range(30.0, 180.0)
    };
    let clamp = |p: &mut Pose| {
        for i in 0..N_AXIS {
            p[i] = p[i].clamp(lo[i], hi[i]);
        }
    };
    let mut t = m;
    let axes = if rng.chance(0.35) {
        let i = if rng.chance(0.5) { 0 } else { 1 };
        t[i] += if rng.chance(0.5) { length } else { -length };
        if t[i] > hi[i] || t[i] < lo[i] {
            t[i] = 2.0 * m[i] - t[i];
        }
        clamp(&mut t);
        vec![i]
    } else {
        let a = rng.range(0.0, std::f64::consts::TAU);
        t[0] += length * a.cos();
        t[1] += length * a.sin();
        if rng.chance(0.15) {
            t[2] += rng.range(-3.0, 3.0);
        }
        clamp(&mut t);
        vec![0, 1, 2]
    };
    (t, axes)
}

/// An arc in the present plane from the present point, inside the box; false when none
/// fits.
fn arc(s: &mut State, rng: &mut Rng, lo: Pose, hi: Pose) -> bool {
    let (a, b) = [(0, 1), (2, 0), (1, 2)][s.plane];
    let m = s.m;
    let mut r = rng.range(0.5, 20.0);
    let phi = rng.range(0.0, std::f64::consts::TAU);
    for _ in 0..6 {
        let c = [m[a] + r * phi.cos(), m[b] + r * phi.sin()];
        let inside = c[0] - r > lo[a] && c[0] + r < hi[a] && c[1] - r > lo[b] && c[1] + r < hi[b];
        if inside {
            let clockwise = rng.chance(0.5);
            let sweep = rng.range(0.3, 5.9) * if clockwise { -1.0 } else { 1.0 };
            let start = phi + std::f64::consts::PI;
            let mut t = m;
            t[a] = c[0] + r * (start + sweep).cos();
            t[b] = c[1] + r * (start + sweep).sin();
            let unit = s.unit();
            let decimals = s.decimals();
            let offsets = [
                (a, s.round((c[0] - m[a]) / unit)),
                (b, s.round((c[1] - m[b]) / unit)),
            ];
            let w = s.words(&t, &[a, b]);
            let mut text = format!("G{} {w}", if clockwise { 2 } else { 3 });
            let mut offsets = offsets.to_vec();
            offsets.sort_by_key(|o| o.0);
            for (axis, v) in offsets {
                let _ = write!(text, " {}{v:.decimals$}", ['I', 'J', 'K'][axis]);
            }
            s.line(&text);
            return true;
        }
        r /= 2.0;
    }
    false
}

//! The expanded blocks ([`super::flow::Flat`]) read as LinuxCNC's canonical machine
//! would move: modal state (units, distance modes, plane, work system, G92, retract
//! mode, path control), every move in machine millimetres, canned cycles G81, G82, G85
//! and G89 (XY plane) expanded into the moves LinuxCNC makes for them
//! (`interp_cycles.cc`). Anything whose result depends on the machine's state or on
//! what the rewrite does not model is refused naming the line.

use super::flow::Flat;
use super::NgcError;

/// Axis order X, Y, Z.
pub type Xyz = [f64; 3];

/// The arc planes (first axis, second axis, normal axis as indices into [`Xyz`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Plane {
    Xy,
    Zx,
    Yz,
}

impl Plane {
    pub fn axes(self) -> (usize, usize, usize) {
        match self {
            Plane::Xy => (0, 1, 2),
            Plane::Zx => (2, 0, 1),
            Plane::Yz => (1, 2, 0),
        }
    }
}

/// Path control (`G61`, `G61.1`, `G64 [P] [Q]`, P and Q in mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PathMode {
    ExactPath,
    ExactStop,
    Blend {
        p_mm: Option<f64>,
        q_mm: Option<f64>,
    },
}

/// What one block does, in order.
#[derive(Clone, Debug, PartialEq)]
pub enum Action {
    /// G0 to a machine position (`g53`: programmed in machine coordinates).
    Rapid {
        to: Xyz,
    },
    /// G1 at a feed, mm/min.
    Linear {
        to: Xyz,
        feed: f64,
    },
    /// G2/G3 (one turn at most), centre in machine mm.
    Arc {
        to: Xyz,
        centre: Xyz,
        clockwise: bool,
        plane: Plane,
        feed: f64,
    },
    /// G4 P seconds.
    Dwell(f64),
    /// Words with no motion that go to the controller as written (M, S, T, G40, ...),
    /// upper-case.
    Pass(String),
    /// The program's path control changed.
    Path(PathMode),
    /// A canned cycle's moves start (LinuxCNC runs them in exact path mode) or end.
    Cycle(bool),
    /// G54..G59.3 selected (index 0..=8) in the controller.
    Select(usize),
    /// G92 (values in mm, in the program's frame), G92.1, G92.2, G92.3.
    G92(Vec<(usize, f64)>),
    G92Code(&'static str),
    /// M2 or M30.
    End(String),
}

/// A block's actions and where it came from.
#[derive(Clone, Debug, PartialEq)]
pub struct Step {
    pub line: usize,
    pub calls: Vec<(String, usize)>,
    pub actions: Vec<Action>,
    /// The axes (X, Y, Z) the block names.
    pub axes: [bool; 3],
    /// The block's moves are in machine coordinates (G53).
    pub g53: bool,
}

/// The controller's state the program starts from.
#[derive(Clone, Debug, PartialEq)]
pub struct Start {
    /// Machine position, mm.
    pub position: Xyz,
    /// G54..G59.3 offsets (#5221.. in the parameter file), mm.
    pub work_offsets: [Xyz; 9],
    /// Active system index (0 = G54).
    pub system: usize,
    /// G92 offset in effect and the one stored in #5211.. (G92.3 restores it), mm.
    pub g92: Xyz,
    pub g92_stored: Xyz,
}

impl Default for Start {
    fn default() -> Self {
        Self {
            position: [0.0; 3],
            work_offsets: [[0.0; 3]; 9],
            system: 0,
            g92: [0.0; 3],
            g92_stored: [0.0; 3],
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Motion {
    None,
    Rapid,
    Linear,
    Arc(bool),
    Cycle(u8),
}

/// The modal state, as LinuxCNC starts a program by default (`G17 G21 G90 G91.1 G94
/// G98 G54 G80`; units are the machine's, mm here).
#[derive(Clone, Debug)]
pub struct Machine {
    pub position: Xyz,
    pub inch: bool,
    pub incremental: bool,
    pub arc_absolute: bool,
    pub plane: Plane,
    pub system: usize,
    pub offsets: [Xyz; 9],
    pub g92: Xyz,
    pub g92_stored: Xyz,
    /// Feed, program units per minute (0: none yet).
    pub feed: f64,
    /// The program has said its units (G20 or G21).
    pub units_set: bool,
    motion: Motion,
    retract_r: bool,
    cycle_r: f64,
    cycle_z: f64,
    cycle_p: f64,
    cycle_initial: Option<f64>,
}

impl Machine {
    pub fn new(start: &Start) -> Self {
        Self {
            position: start.position,
            inch: false,
            incremental: false,
            arc_absolute: false,
            plane: Plane::Xy,
            system: start.system,
            offsets: start.work_offsets,
            g92: start.g92,
            g92_stored: start.g92_stored,
            feed: 0.0,
            units_set: false,
            motion: Motion::None,
            retract_r: false,
            cycle_r: 0.0,
            cycle_z: 0.0,
            cycle_p: 0.0,
            cycle_initial: None,
        }
    }

    fn unit(&self) -> f64 {
        if self.inch {
            25.4
        } else {
            1.0
        }
    }

    /// The origin of the program's coordinates, machine mm.
    pub fn origin(&self) -> Xyz {
        let w = self.offsets[self.system];
        [w[0] + self.g92[0], w[1] + self.g92[1], w[2] + self.g92[2]]
    }

    /// Reads one block; the machine changes only when it is accepted.
    pub fn run(&mut self, flat: &Flat) -> Result<Step, NgcError> {
        let mut next = self.clone();
        let actions = next.block(&flat.words).map_err(|m| {
            let mut m = m;
            for (name, line) in flat.calls.iter().rev() {
                m = format!("{m} (in o{name}, called from line {line})");
            }
            NgcError::new(flat.line, "", m)
        })?;
        *self = next;
        let named = |l: char| flat.words.iter().any(|&(w, _)| w == l);
        Ok(Step {
            line: flat.line,
            calls: flat.calls.clone(),
            actions,
            axes: [named('x'), named('y'), named('z')],
            g53: flat.words.iter().any(|&(w, v)| w == 'g' && v == 53.0),
        })
    }

    fn block(&mut self, words: &[(char, f64)]) -> Result<Vec<Action>, String> {
        let mut actions = Vec::new();
        let mut seen = std::collections::HashSet::new();
        let value = |l: char| -> Result<Option<f64>, String> {
            let mut found = None;
            for &(w, v) in words {
                if w == l {
                    if found.is_some() {
                        return Err(format!("two {} words in one block", l.to_ascii_uppercase()));
                    }
                    found = Some(v);
                }
            }
            Ok(found)
        };
        let mut gs: Vec<f64> = Vec::new();
        let mut ms: Vec<f64> = Vec::new();
        let mut passed = String::new();
        let mut compensation_word = None;
        for &(l, v) in words {
            match l {
                'g' => gs.push((v * 10.0).round() / 10.0),
                'm' => ms.push(v),
                'x' | 'y' | 'z' | 'i' | 'j' | 'k' | 'r' | 'p' | 'q' | 'l' | 'f' => {}
                's' | 't' | 'd' | 'h' | 'e' => {
                    if !seen.insert(l) {
                        return Err(format!("two {} words in one block", l.to_ascii_uppercase()));
                    }
                    if l != 's' && l != 't' {
                        // Named after the G codes (a G43 says more than its H).
                        compensation_word.get_or_insert(format!(
                            "{}{}: only with cutter or tool length compensation, which the rewrite refuses",
                            l.to_ascii_uppercase(),
                            fmt(v)
                        ));
                        continue;
                    }
                    passed.push_str(&format!(" {}{}", l.to_ascii_uppercase(), fmt(v)));
                }
                'a' | 'b' | 'c' | 'u' | 'v' | 'w' => {
                    return Err(format!(
                        "{}{}: the rewrite is for X, Y and Z; other axes are not rewritten",
                        l.to_ascii_uppercase(),
                        fmt(v)
                    ))
                }
                _ => {
                    return Err(format!(
                        "{}{}: a word LinuxCNC's interpreter does not know",
                        l.to_ascii_uppercase(),
                        fmt(v)
                    ))
                }
            }
        }
        let x = value('x')?;
        let y = value('y')?;
        let z = value('z')?;
        let axes = [x, y, z];
        let any_axis = axes.iter().any(Option::is_some);
        let p = value('p')?;
        let q = value('q')?;
        let r = value('r')?;
        let l = value('l')?;
        let ijk = [value('i')?, value('j')?, value('k')?];
        let f = value('f')?;

        // Modal groups: one code of each per block.
        let group = |g: f64| -> Option<u8> {
            Some(match g {
                0.0 | 1.0 | 2.0 | 3.0 | 80.0 | 81.0 | 82.0 | 85.0 | 89.0 => 1,
                17.0 | 18.0 | 19.0 => 2,
                90.0 | 91.0 => 3,
                90.1 | 91.1 => 4,
                20.0 | 21.0 => 6,
                40.0 => 7,
                49.0 => 8,
                98.0 | 99.0 => 10,
                54.0 | 55.0 | 56.0 | 57.0 | 58.0 | 59.0 | 59.1 | 59.2 | 59.3 => 12,
                61.0 | 61.1 | 64.0 => 13,
                94.0 => 5,
                4.0 | 53.0 | 92.0 | 92.1 | 92.2 | 92.3 => 0,
                _ => return None,
            })
        };
        let mut groups = std::collections::HashMap::new();
        for &g in &gs {
            let Some(k) = group(g) else {
                return Err(refusal_g(g));
            };
            if let Some(other) = groups.insert(k, g) {
                return Err(format!(
                    "G{} and G{} in one block: the same modal group",
                    fmt(other),
                    fmt(g)
                ));
            }
        }
        if let Some(e) = compensation_word {
            return Err(e);
        }
        let has = |g: f64| gs.contains(&g);
        for &m in &ms {
            let ok = matches!(
                m,
                0.0 | 1.0
                    | 3.0
                    | 4.0
                    | 5.0
                    | 7.0
                    | 8.0
                    | 9.0
                    | 19.0
                    | 48.0
                    | 49.0
                    | 50.0
                    | 51.0
                    | 52.0
                    | 53.0
                    | 60.0
                    | 62.0
                    | 63.0
                    | 64.0
                    | 65.0
                    | 67.0
                    | 68.0
                    | 2.0
                    | 30.0
            ) || (100.0..=199.0).contains(&m) && m.fract() == 0.0;
            if !ok {
                return Err(refusal_m(m));
            }
        }
        // LinuxCNC's order of execution: feed, speed, tool, spindle, coolant, ...
        if let Some(f) = f {
            if f < 0.0 {
                return Err(format!("F{}: a negative feed", fmt(f)));
            }
            self.feed = f;
        }
        let ends: Vec<f64> = ms
            .iter()
            .copied()
            .filter(|&m| m == 2.0 || m == 30.0)
            .collect();
        for &m in ms.iter().filter(|&&m| m != 2.0 && m != 30.0) {
            passed.push_str(&format!(" M{}", fmt(m)));
            if matches!(m, 62.0..=65.0 | 67.0 | 68.0 | 19.0 | 48.0..=53.0) {
                for (letter, v) in [('P', p), ('Q', q), ('R', r), ('E', None)] {
                    if let Some(v) = v {
                        passed.push_str(&format!(" {letter}{}", fmt(v)));
                    }
                }
            }
        }
        if let Some(l) = l {
            if !gs.iter().any(|g| [81.0, 82.0, 85.0, 89.0].contains(g))
                && !matches!(self.motion, Motion::Cycle(_))
            {
                return Err(format!("L{}: only with a canned cycle here", fmt(l)));
            }
        }
        if has(40.0) {
            passed.push_str(" G40");
        }
        if has(49.0) {
            passed.push_str(" G49");
        }
        if has(94.0) {
            passed.push_str(" G94");
        }
        let passed = passed.trim().to_string();
        if !passed.is_empty() {
            actions.push(Action::Pass(passed));
        }
        if has(4.0) {
            let Some(p) = p else {
                return Err("G4 without P (the dwell in seconds)".into());
            };
            if p < 0.0 {
                return Err(format!("G4 P{}: a negative dwell", fmt(p)));
            }
            actions.push(Action::Dwell(p));
        }
        for (g, plane) in [(17.0, Plane::Xy), (18.0, Plane::Zx), (19.0, Plane::Yz)] {
            if has(g) {
                self.plane = plane;
            }
        }
        if has(20.0) {
            self.inch = true;
            self.units_set = true;
        }
        if has(21.0) {
            self.inch = false;
            self.units_set = true;
        }
        let unit_now = self.unit();
        for (k, g) in [54.0, 55.0, 56.0, 57.0, 58.0, 59.0, 59.1, 59.2, 59.3]
            .into_iter()
            .enumerate()
        {
            if has(g) {
                self.system = k;
                actions.push(Action::Select(k));
            }
        }
        if has(61.0) {
            actions.push(Action::Path(PathMode::ExactPath));
        }
        if has(61.1) {
            actions.push(Action::Path(PathMode::ExactStop));
        }
        if has(64.0) {
            let len = |v: Option<f64>| -> Result<Option<f64>, String> {
                match v {
                    Some(v) if v < 0.0 => Err(format!("G64 with a negative tolerance {}", fmt(v))),
                    Some(v) => Ok(Some(v * unit_now)),
                    None => Ok(None),
                }
            };
            actions.push(Action::Path(PathMode::Blend {
                p_mm: len(p)?,
                q_mm: len(q)?,
            }));
        }
        if has(90.0) {
            self.incremental = false;
        }
        if has(91.0) {
            self.incremental = true;
        }
        if has(90.1) {
            self.arc_absolute = true;
        }
        if has(91.1) {
            self.arc_absolute = false;
        }
        if has(98.0) {
            self.retract_r = false;
        }
        if has(99.0) {
            self.retract_r = true;
        }
        // Group 0 and motion.
        let g53 = has(53.0);
        let motion_code = groups.get(&1).copied();
        let g92 = [92.0, 92.1, 92.2, 92.3].into_iter().find(|g| has(*g));
        if g92.is_some() && motion_code.is_some() && any_axis {
            return Err("G92 and a motion in one block both use the axis words".into());
        }
        if let Some(g) = g92 {
            self.g92_code(g, axes, &mut actions)?;
        }
        if let Some(code) = motion_code {
            self.motion = match code {
                0.0 => Motion::Rapid,
                1.0 => Motion::Linear,
                2.0 => Motion::Arc(true),
                3.0 => Motion::Arc(false),
                80.0 => Motion::None,
                c => {
                    if !matches!(self.motion, Motion::Cycle(k) if f64::from(k) == c) {
                        // Another cycle: its Z and R must be given; the initial level
                        // is kept from cycle to cycle (LinuxCNC's `cycle_il`).
                        if !matches!(self.motion, Motion::Cycle(_)) {
                            self.cycle_initial = None;
                        }
                        if z.is_none() {
                            return Err(format!(
                                "G{}: Z missing for the first block of a canned cycle",
                                fmt(c)
                            ));
                        }
                        if r.is_none() {
                            return Err(format!(
                                "G{}: R missing for the first block of a canned cycle",
                                fmt(c)
                            ));
                        }
                        if (c == 82.0 || c == 89.0) && p.is_none() {
                            return Err(format!("G{}: P (dwell) missing", fmt(c)));
                        }
                    }
                    Motion::Cycle(c as u8)
                }
            };
        }
        if g92.is_some() {
            return Ok(with_end(actions, ends));
        }
        if !any_axis {
            if matches!(motion_code, Some(c) if c != 80.0)
                && !matches!(self.motion, Motion::Cycle(_))
            {
                return Err(format!(
                    "G{}: a motion without any axis word",
                    fmt(motion_code.unwrap_or(0.0))
                ));
            }
            return Ok(with_end(actions, ends));
        }
        if g53 {
            if self.incremental {
                return Err("G53 in incremental mode (G91)".into());
            }
            if !matches!(self.motion, Motion::Rapid | Motion::Linear) {
                return Err("G53 needs G0 or G1".into());
            }
            let mut to = self.position;
            for k in 0..3 {
                if let Some(v) = axes[k] {
                    to[k] = v * unit_now;
                }
            }
            self.straight(to, &mut actions)?;
            return Ok(with_end(actions, ends));
        }
        let to = self.target(axes);
        match self.motion {
            Motion::None => {
                return Err("axis words without a motion mode (G80 is in effect)".into());
            }
            Motion::Rapid | Motion::Linear => self.straight(to, &mut actions)?,
            Motion::Arc(clockwise) => self.arc(to, axes, ijk, r, p, clockwise, &mut actions)?,
            Motion::Cycle(c) => self.cycle(c, axes, r, p, l, &mut actions)?,
        }
        Ok(with_end(actions, ends))
    }

    /// The machine position the axis words name.
    fn target(&self, axes: [Option<f64>; 3]) -> Xyz {
        let o = self.origin();
        let u = self.unit();
        let mut to = self.position;
        for k in 0..3 {
            if let Some(v) = axes[k] {
                to[k] = if self.incremental {
                    self.position[k] + v * u
                } else {
                    v * u + o[k]
                };
            }
        }
        to
    }

    fn feed_mm(&self) -> Result<f64, String> {
        if self.feed <= 0.0 {
            return Err("a feed move with no feed rate (F) set".into());
        }
        Ok(self.feed * self.unit())
    }

    fn straight(&mut self, to: Xyz, actions: &mut Vec<Action>) -> Result<(), String> {
        match self.motion {
            Motion::Rapid => actions.push(Action::Rapid { to }),
            _ => actions.push(Action::Linear {
                to,
                feed: self.feed_mm()?,
            }),
        }
        self.position = to;
        Ok(())
    }

    #[allow(clippy::too_many_arguments)]
    fn arc(
        &mut self,
        to: Xyz,
        axes: [Option<f64>; 3],
        ijk: [Option<f64>; 3],
        r: Option<f64>,
        p: Option<f64>,
        clockwise: bool,
        actions: &mut Vec<Action>,
    ) -> Result<(), String> {
        let (a, b, _) = self.plane.axes();
        let feed = self.feed_mm()?;
        if axes[a].is_none() && axes[b].is_none() && r.is_some() {
            return Err("an R arc needs an end point in its plane".into());
        }
        if let Some(p) = p {
            if p != 1.0 {
                return Err(format!(
                    "an arc with P{} (turns): only one turn is rewritten",
                    fmt(p)
                ));
            }
        }
        let u = self.unit();
        let from = self.position;
        let offset_letter = ['I', 'J', 'K'];
        let centre = match r {
            Some(radius) => {
                if ijk[a].is_some() || ijk[b].is_some() {
                    return Err("an arc with both R and centre offsets".into());
                }
                let radius = radius * u;
                let (sx, sy, ex, ey) = (from[a], from[b], to[a], to[b]);
                if sx == ex && sy == ey {
                    return Err(
                        "an R arc whose end is its start (a full circle needs I/J/K)".into(),
                    );
                }
                let (mx, my) = ((sx + ex) / 2.0, (sy + ey) / 2.0);
                let mut half = (mx - ex).hypot(my - ey);
                let abs_r = radius.abs();
                // LinuxCNC's tolerance for this check: 0.001 mm (0.0001 in).
                let tolerance = if self.inch { 0.0001 * 25.4 } else { 0.001 };
                if half - abs_r > tolerance {
                    return Err(format!(
                        "R{}: the radius is too small to reach the end point",
                        fmt(radius / u)
                    ));
                }
                if half / abs_r > 1.0 - 1e-12 {
                    half = abs_r;
                }
                let base = (ey - sy).atan2(ex - sx);
                let theta = if clockwise == (radius > 0.0) {
                    base - std::f64::consts::FRAC_PI_2
                } else {
                    base + std::f64::consts::FRAC_PI_2
                };
                let offset = abs_r * (half / abs_r).asin().cos();
                let mut c = from;
                c[a] = mx + offset * theta.cos();
                c[b] = my + offset * theta.sin();
                c
            }
            None => {
                if ijk[a].is_none() && ijk[b].is_none() {
                    return Err(format!(
                        "an arc without R or its centre ({} or {})",
                        offset_letter[a], offset_letter[b]
                    ));
                }
                let mut c = from;
                let o = self.origin();
                for k in [a, b] {
                    let v = ijk[k].unwrap_or(0.0) * u;
                    c[k] = if self.arc_absolute {
                        if ijk[k].is_none() {
                            return Err(format!(
                                "G90.1 arc without {}: an absolute centre needs both",
                                offset_letter[k]
                            ));
                        }
                        v + o[k]
                    } else {
                        from[k] + v
                    };
                }
                c
            }
        };
        let r0 = (from[a] - centre[a]).hypot(from[b] - centre[b]);
        let r1 = (to[a] - centre[a]).hypot(to[b] - centre[b]);
        if r0 == 0.0 {
            return Err("an arc of radius zero".into());
        }
        // LinuxCNC runs a small difference as a spiral; the rewrite's chords follow a
        // circle, so it takes only what is a circle within 0.1 um.
        if (r1 - r0).abs() > 1e-4 {
            return Err(format!(
                "the arc's end is {:.4} mm off its circle (radius {:.4} at the start, {:.4} at the end): LinuxCNC runs it as a spiral, which the rewrite does not",
                (r1 - r0).abs(),
                r0,
                r1
            ));
        }
        actions.push(Action::Arc {
            to,
            centre,
            clockwise,
            plane: self.plane,
            feed,
        });
        self.position = to;
        Ok(())
    }

    /// G81, G82, G85, G89 in the XY plane, as `convert_cycle_xy` moves (in the
    /// program's frame: Z and R in its units and from its origin).
    #[allow(clippy::too_many_arguments)]
    fn cycle(
        &mut self,
        code: u8,
        axes: [Option<f64>; 3],
        r: Option<f64>,
        p: Option<f64>,
        l: Option<f64>,
        actions: &mut Vec<Action>,
    ) -> Result<(), String> {
        if self.plane != Plane::Xy {
            return Err(format!("G{code} outside the XY plane (G17): not rewritten"));
        }
        let feed = self.feed_mm()?;
        let u = self.unit();
        let o = self.origin();
        // Positions in the program's frame (its units).
        let here = |m: &Xyz, k: usize| (m[k] - o[k]) / u;
        let current_z = here(&self.position, 2);
        let z = axes[2].unwrap_or(self.cycle_z);
        let r_word = r.unwrap_or(self.cycle_r);
        let repeats = match l {
            Some(l) if l.fract() != 0.0 || !(1.0..=10_000.0).contains(&l) => {
                return Err(format!("L{}: not a count of repeats (1 to 10000)", fmt(l)))
            }
            Some(l) => l as u32,
            None => 1,
        };
        let old_initial = *self.cycle_initial.get_or_insert(current_z);
        let mut old_z = old_initial;
        let (mut aa, mut bb, aa_inc, bb_inc, rr, zz);
        if self.incremental {
            aa_inc = axes[0].unwrap_or(0.0);
            bb_inc = axes[1].unwrap_or(0.0);
            rr = r_word + old_z;
            zz = rr + z;
            aa = here(&self.position, 0);
            bb = here(&self.position, 1);
        } else {
            aa_inc = 0.0;
            bb_inc = 0.0;
            rr = r_word;
            zz = z;
            aa = axes[0].unwrap_or_else(|| here(&self.position, 0));
            bb = axes[1].unwrap_or_else(|| here(&self.position, 1));
        }
        if rr < zz {
            return Err(format!("G{code}: R below Z in the cycle"));
        }
        let dwell = if code == 82 || code == 89 {
            let d = p.unwrap_or(self.cycle_p);
            if d < 0.0 {
                return Err(format!("G{code}: a negative dwell"));
            }
            self.cycle_p = d;
            Some(d)
        } else {
            None
        };
        let m = |x: f64, y: f64, zv: f64| [x * u + o[0], y * u + o[1], zv * u + o[2]];
        actions.push(Action::Cycle(true));
        let mut cur_z = current_z;
        if old_z < rr {
            actions.push(Action::Rapid {
                to: m(here(&self.position, 0), here(&self.position, 1), rr),
            });
            old_z = rr;
            cur_z = rr;
        }
        let clear = if self.retract_r { rr } else { old_z };
        for k in 0..repeats {
            aa += aa_inc;
            bb += bb_inc;
            if k == 0 && cur_z > rr {
                actions.push(Action::Rapid {
                    to: m(aa, bb, cur_z),
                });
                actions.push(Action::Rapid { to: m(aa, bb, rr) });
            } else {
                actions.push(Action::Rapid {
                    to: m(aa, bb, clear),
                });
                if clear > rr {
                    actions.push(Action::Rapid { to: m(aa, bb, rr) });
                }
            }
            actions.push(Action::Linear {
                to: m(aa, bb, zz),
                feed,
            });
            if let Some(d) = dwell {
                actions.push(Action::Dwell(d));
            }
            match code {
                81 | 82 => actions.push(Action::Rapid {
                    to: m(aa, bb, clear),
                }),
                85 => {
                    actions.push(Action::Linear {
                        to: m(aa, bb, rr),
                        feed,
                    });
                    actions.push(Action::Rapid {
                        to: m(aa, bb, clear),
                    });
                }
                _ => actions.push(Action::Linear {
                    to: m(aa, bb, clear),
                    feed,
                }),
            }
        }
        actions.push(Action::Cycle(false));
        self.position = m(aa, bb, clear);
        self.cycle_z = z;
        self.cycle_r = r_word;
        Ok(())
    }

    fn g92_code(
        &mut self,
        g: f64,
        axes: [Option<f64>; 3],
        actions: &mut Vec<Action>,
    ) -> Result<(), String> {
        let u = self.unit();
        if g == 92.0 {
            let named: Vec<(usize, f64)> =
                (0..3).filter_map(|k| axes[k].map(|v| (k, v * u))).collect();
            if named.is_empty() {
                return Err("G92 without an axis word".into());
            }
            let w = self.offsets[self.system];
            for &(k, v) in &named {
                // The present point reads v: the shift is what is left.
                self.g92[k] = self.position[k] - w[k] - v;
            }
            self.g92_stored = self.g92;
            actions.push(Action::G92(named));
            return Ok(());
        }
        if axes.iter().any(Option::is_some) {
            return Err(format!("G{} with axis words", fmt(g)));
        }
        let code = match g {
            92.1 => {
                self.g92 = [0.0; 3];
                self.g92_stored = [0.0; 3];
                "G92.1"
            }
            92.2 => {
                self.g92 = [0.0; 3];
                "G92.2"
            }
            _ => {
                self.g92 = self.g92_stored;
                "G92.3"
            }
        };
        actions.push(Action::G92Code(code));
        Ok(())
    }
}

fn with_end(mut actions: Vec<Action>, ends: Vec<f64>) -> Vec<Action> {
    if let Some(m) = ends.first() {
        actions.push(Action::End(format!("M{}", fmt(*m))));
    }
    actions
}

/// A number as LinuxCNC reads it back: up to 6 decimals, no exponent.
pub fn fmt(v: f64) -> String {
    let t = format!("{v:.6}");
    let t = t.trim_end_matches('0').trim_end_matches('.');
    if t == "-0" {
        "0".into()
    } else {
        t.to_string()
    }
}

fn refusal_g(g: f64) -> String {
    let why = match g {
        10.0 => "sets stored offsets or tool data (the machine's state)",
        28.0 | 28.1 | 30.0 | 30.1 => "goes to or sets a stored position (the machine's state)",
        33.0 | 33.1 | 76.0 => "is synchronised with the spindle",
        38.2 | 38.3 | 38.4 | 38.5 => "probes: where it stops is not known before it runs",
        41.0 | 42.0 | 41.1 | 42.1 => "is cutter radius compensation (the tool table)",
        43.0 | 43.1 | 43.2 => "applies a tool length offset (the tool table)",
        52.0 => "is a local offset the rewrite does not model",
        5.0 | 5.1 | 5.2 | 5.3 => "is a spline the rewrite does not model",
        7.0 | 8.0 | 70.0 | 71.0 | 72.0 | 71.1 | 71.2 | 72.1 | 72.2 => "is lathe mode",
        73.0 | 74.0 | 83.0 | 84.0 | 86.0 | 87.0 | 88.0 => {
            "is a canned cycle the rewrite does not expand (G81, G82, G85 and G89 are)"
        }
        93.0 => "is inverse-time feed: a split move would need its own F for every piece",
        95.0 => "is feed per revolution (the spindle's speed)",
        17.1 | 18.1 | 19.1 => "is a UVW plane",
        _ => "is not rewritten (not one the rewrite models)",
    };
    format!("G{}: {why}", fmt(g))
}

fn refusal_m(m: f64) -> String {
    let why = match m {
        6.0 | 61.0 => {
            "changes the tool (a tool change may move the machine and changes its offsets)"
        }
        66.0 => "waits on an input: what follows depends on the machine",
        70.0 | 71.0 | 72.0 | 73.0 => "saves or restores modal state the rewrite does not track",
        98.0 | 99.0 => "is a Fanuc-style subprogram call",
        _ => "is not rewritten (not one the rewrite models)",
    };
    format!("M{}: {why}", fmt(m))
}

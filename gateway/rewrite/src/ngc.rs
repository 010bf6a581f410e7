//! LinuxCNC's dialect (RS274/NGC): a program for a LinuxCNC machine rewritten with a
//! [`Compensation`], to run in LinuxCNC's auto mode.
//!
//! The program is read as LinuxCNC's interpreter reads it ([`protocol::ngc`]):
//! parameters, expressions, O-word subroutines, loops and conditions are run as far as
//! their values go and the blocks come out in the order LinuxCNC runs them, each move
//! in machine millimetres (work systems G54-G59.3 and G92 from the controller's
//! parameter file, [`NgcOptions::start`]). What depends on the machine's state, or
//! what the reader does not model, is refused naming the line and the construct; see
//! [`protocol::ngc`] for the list. Each move goes to the GRBL rewriter ([`Rewriter`]) in
//! machine coordinates, which does the compensation (moves split against the
//! tolerance, arcs as chords, backlash taken up where an axis's command turns back,
//! rapids corrected at their end).
//!
//! The rewritten program is flat (no parameters, no O-words, no arcs, no cycles) and
//! written as LinuxCNC reads it:
//!
//! * it starts with `G21 G90 G64 P<tolerance> Q0`: millimetres, absolute, and path
//!   blending held within the rewrite's tolerance with LinuxCNC's naive-CAM merging off
//!   (Q0), so that the many short pieces run at speed without a corner rounded by more
//!   than the tolerance and without pieces merged away. A `G64` of the program becomes
//!   `G64 P<the smaller of its P and the tolerance> Q0`; `G61` and `G61.1` go as
//!   written (exact path and exact stop are closer still), but a move split into
//!   pieces runs its pieces but the last in `G64 P<tolerance> Q0` and the last in the
//!   program's mode again, so the machine stops at the program's points and not at
//!   every piece (a circle in 200 pieces would otherwise stop 200 times). The executed
//!   path is then within twice the tolerance of the compensated path (the split, then
//!   the blend);
//! * every move is `G0`/`G1` with absolute coordinates in the program's work system
//!   (`G53` moves stay `G53`), 6 decimals; F in mm/min where it changes;
//! * a canned cycle's moves are written between `G61` and the path mode in effect, as
//!   LinuxCNC runs a cycle in exact path mode;
//! * G54-G59.3, G92.1/.2/.3, dwells, and the words without motion (M, S, T, G40, G49,
//!   G94) go as written; `G92` values are moved by the correction at the present point
//!   (the controller takes its corrected position for the present point, so the offset
//!   it sets is the one the program meant);
//! * at the end, before M2/M30, the program's last units, distance mode, arc centre
//!   mode and plane are set again, so that LinuxCNC is left as the program left it.
//!
//! Units must be set by the program (G20 or G21) before its first move: the
//! controller's units at the start are not known to the rewrite. Distance mode, plane
//! and arc centre mode start as LinuxCNC's defaults (G90, G17, G91.1), the work system
//! and G92 from the parameter file (none given: G54 and every offset zero).
//!
//! Worked example (a compensation commanding 10 um more X per 100 mm of X, G54 zero,
//! tolerance 0.5 um; the test `the_docs_worked_example`): `o10 sub` / `G1 X#1 Y20
//! F600` / `o10 endsub` / `G0 X0 Y20` / `o10 call [25 * 2]` becomes `G0 X0 Y20` /
//! `G1 X50.005 Y20 F600`, after the line `G21 G90 G64 P0.0005 Q0`.

use crate::{Compensation, Limits, Note, Options, Pose, RewriteError, Rewriter};
use protocol::grbl::gcode::{
    filter_line, Action as GrblAction, Interpreter as GrblInterpreter, Rate,
};
use protocol::ngc::machine::fmt;
use protocol::ngc::{Action, Bounds, Machine, NgcError, PathMode, Plane, Start, Step};

const LETTERS: [char; 3] = ['X', 'Y', 'Z'];

/// How to rewrite for one LinuxCNC machine.
#[derive(Clone, Debug, PartialEq)]
pub struct NgcOptions {
    /// Largest distance of the executed (straight) path from the compensated path, mm;
    /// also the emitted `G64 P`.
    pub tolerance_mm: f64,
    /// Largest correction accepted at any point, mm.
    pub max_correction_mm: f64,
    /// Soft limits, machine mm.
    pub limits: Option<Limits>,
    /// The machine position when the program starts, if known (else the first moves
    /// must name every compensated axis in G90).
    pub position: Option<Pose>,
    /// The controller's offsets ([`protocol::ngc::read_var_file`]).
    pub start: Start,
    /// The most bytes the rewritten program may hold.
    pub max_output_bytes: usize,
    /// Bounds of the expansion (statements run, blocks).
    pub bounds: Bounds,
}

impl Default for NgcOptions {
    fn default() -> Self {
        Self {
            tolerance_mm: 0.0005,
            max_correction_mm: 0.2,
            limits: None,
            position: None,
            start: Start::default(),
            max_output_bytes: 256 << 20,
            bounds: Bounds::default(),
        }
    }
}

/// What an RS274/NGC rewrite did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NgcReport {
    /// Blocks run (a loop's blocks once per pass).
    pub blocks_run: usize,
    pub output_lines: usize,
    pub moves_compensated: usize,
    pub segments_added: usize,
    /// Subroutine calls and loop passes are expanded: blocks written from inside a call.
    pub blocks_in_calls: usize,
    /// Largest |command - nominal| over the compensated axes, um, and its line.
    pub largest_correction_um: f64,
    pub largest_correction_line: usize,
    pub notes: Vec<Note>,
}

/// Rewrites an RS274/NGC program with `compensation`.
pub fn rewrite_ngc(
    text: &str,
    compensation: &dyn Compensation,
    options: &NgcOptions,
) -> Result<(String, NgcReport), NgcError> {
    let mut start = options.start.clone();
    if let Some(p) = options.position {
        start.position = p;
    }
    let flats = protocol::ngc::expand(text, options.bounds)?;
    let mut w = Writer::new(compensation, options, &start)?;
    w.out
        .push_str(&format!("G21 G90 G64 P{} Q0\n", fmt(options.tolerance_mm)));
    let line_text = |n: usize| {
        protocol::nc::split_lines(text)
            .nth(n.wrapping_sub(1))
            .map(|(l, _)| l.to_string())
            .unwrap_or_default()
    };
    let mut machine = Machine::new(&start);
    for flat in &flats {
        let before = machine.clone();
        let step = machine.run(flat).map_err(|mut e| {
            e.text = NgcError::new(0, &line_text(e.line), String::new()).text;
            e
        })?;
        w.report.blocks_run += 1;
        if !step.calls.is_empty() {
            w.report.blocks_in_calls += 1;
        }
        w.step(&step, &before, &machine).map_err(|m| {
            let mut m = m;
            for (name, line) in step.calls.iter().rev() {
                m = format!("{m} (in o{name}, called from line {line})");
            }
            NgcError::new(step.line, &line_text(step.line), m)
        })?;
        if w.ended {
            break;
        }
    }
    if !w.ended {
        w.restore(&machine);
    }
    let mut report = w.report;
    let grbl = w.rewriter.into_report();
    report.largest_correction_um = grbl.largest_correction_um;
    report.largest_correction_line = grbl.largest_correction_line;
    report.notes.extend(grbl.notes);
    report.output_lines = w.out.lines().count();
    Ok((w.out, report))
}

struct Writer<'a> {
    options: &'a NgcOptions,
    rewriter: Rewriter<'a>,
    /// Where the controller is after the written blocks, machine mm.
    controller: Pose,
    /// The nominal position after the last move, machine mm.
    nominal: Pose,
    known: [bool; 3],
    /// Commands of the pieces the GRBL rewriter wrote (machine mm).
    pieces: GrblInterpreter,
    path: PathMode,
    feed_written: Option<f64>,
    in_cycle: bool,
    ended: bool,
    out: String,
    report: NgcReport,
}

impl<'a> Writer<'a> {
    fn new(
        compensation: &'a dyn Compensation,
        options: &'a NgcOptions,
        start: &Start,
    ) -> Result<Self, NgcError> {
        let bad = |m: String| NgcError::new(0, "", format!("options: {m}"));
        if !(options.tolerance_mm > 0.0 && options.tolerance_mm <= 1.0) {
            return Err(bad("the tolerance must be above 0 and at most 1 mm".into()));
        }
        let rewriter = Rewriter::new(
            compensation,
            Options {
                tolerance_mm: options.tolerance_mm,
                max_correction_mm: options.max_correction_mm,
                limits: options.limits,
                start: options.position,
                ..Options::default()
            },
        )
        .map_err(|e| bad(e.to_string()))?;
        let mut pieces = GrblInterpreter::new();
        pieces.position = start.position;
        Ok(Self {
            options,
            rewriter,
            controller: start.position,
            nominal: start.position,
            known: [options.position.is_some(); 3],
            pieces,
            path: PathMode::Blend {
                p_mm: Some(options.tolerance_mm),
                q_mm: Some(0.0),
            },
            feed_written: None,
            in_cycle: false,
            ended: false,
            out: String::new(),
            report: NgcReport::default(),
        })
    }

    fn emit(&mut self, text: &str) -> Result<(), String> {
        self.out.push_str(text);
        self.out.push('\n');
        if self.out.len() > self.options.max_output_bytes {
            return Err(format!(
                "the rewritten program passes {} bytes, the most accepted (a larger tolerance, or fewer loop passes, gives a shorter program)",
                self.options.max_output_bytes
            ));
        }
        Ok(())
    }

    fn path_text(&self, mode: PathMode) -> String {
        match mode {
            PathMode::ExactPath => "G61".into(),
            PathMode::ExactStop => "G61.1".into(),
            PathMode::Blend { p_mm, .. } => {
                let p = p_mm.map_or(self.options.tolerance_mm, |p| {
                    p.min(self.options.tolerance_mm)
                });
                format!("G64 P{} Q0", fmt(p))
            }
        }
    }

    /// Writes one block: `before` and `after` are the program's machine around it.
    fn step(&mut self, step: &Step, before: &Machine, after: &Machine) -> Result<(), String> {
        // The origin of the block's moves: its work system and G92 are set before its
        // motion (LinuxCNC's order of execution).
        let origin = if step.g53 { [0.0; 3] } else { after.origin() };
        for action in &step.actions {
            match action {
                Action::Pass(words) => self.emit(words)?,
                Action::Dwell(p) => self.emit(&format!("G4 P{}", fmt(*p)))?,
                Action::Select(k) => {
                    let g = [
                        "G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3",
                    ][*k];
                    self.emit(g)?;
                }
                Action::Path(mode) => {
                    self.path = *mode;
                    let t = self.path_text(*mode);
                    self.emit(&t)?;
                }
                Action::Cycle(start) => {
                    self.in_cycle = *start;
                    if self.path != PathMode::ExactPath {
                        let t = if *start {
                            "G61".to_string()
                        } else {
                            self.path_text(self.path)
                        };
                        self.emit(&t)?;
                    }
                    if *start && self.known != [true; 3] {
                        return Err("a canned cycle from an unknown position: start with an absolute (G90) move of every axis, or give the start position".into());
                    }
                }
                Action::G92(named) => {
                    let mut text = "G92".to_string();
                    for &(k, v) in named {
                        if !self.known[k] {
                            return Err(format!(
                                "G92 on {} at an unknown position cannot be rewritten: start with an absolute (G90) move of every axis, or give the start position",
                                LETTERS[k]
                            ));
                        }
                        let v = v + (self.controller[k] - before.position[k]);
                        text.push_str(&format!(" {}{}", LETTERS[k], fmt(v)));
                    }
                    self.emit(&text)?;
                }
                Action::G92Code(code) => self.emit(code)?,
                Action::End(m) => {
                    self.restore(after);
                    self.emit(m)?;
                    self.ended = true;
                }
                Action::Rapid { .. } | Action::Linear { .. } | Action::Arc { .. } => {
                    if !after.units_set {
                        return Err("a move before the program sets its units (G20 or G21): the controller's units at the start are not known to the rewrite".into());
                    }
                    let mut named = step.axes;
                    if self.in_cycle {
                        named = [true; 3];
                    }
                    if let Action::Arc { plane, .. } = action {
                        let (a, b, _) = plane.axes();
                        for k in [a, b] {
                            if !self.known[k] {
                                return Err(format!(
                                    "an arc from an unknown {} position cannot be rewritten: start with an absolute (G90) move of every axis, or give the start position",
                                    LETTERS[k]
                                ));
                            }
                            named[k] = true;
                        }
                    }
                    for k in 0..3 {
                        if named[k] && !self.known[k] && after.incremental && !step.g53 {
                            return Err(format!(
                                "an incremental (G91) move of {} from an unknown position: start with an absolute (G90) move of every axis, or give the start position",
                                LETTERS[k]
                            ));
                        }
                    }
                    self.motion(step.line, action, origin, step.g53, named)?;
                }
            }
        }
        Ok(())
    }

    /// The program's last modes, set again (before its end, or at the end of the text).
    fn restore(&mut self, n: &Machine) {
        let mut words = Vec::new();
        if n.inch {
            words.push("G20");
        }
        if n.incremental {
            words.push("G91");
        }
        if n.arc_absolute {
            words.push("G90.1");
        }
        match n.plane {
            Plane::Xy => {}
            Plane::Zx => words.push("G18"),
            Plane::Yz => words.push("G19"),
        }
        if !words.is_empty() {
            let t = words.join(" ");
            self.out.push_str(&t);
            self.out.push('\n');
        }
    }

    fn motion(
        &mut self,
        line: usize,
        action: &Action,
        origin: Pose,
        g53: bool,
        named: [bool; 3],
    ) -> Result<(), String> {
        let axes: Vec<usize> = (0..3).filter(|&k| named[k]).collect();
        let (to, feed) = match action {
            Action::Rapid { to } => (*to, None),
            Action::Linear { to, feed } | Action::Arc { to, feed, .. } => (*to, Some(*feed)),
            _ => unreachable!("a move"),
        };
        let canonical = canonical_line(action, self.nominal, &axes)
            .ok_or_else(|| "a coordinate has no finite value".to_string())?;
        let pieces = self
            .rewriter
            .line(&canonical, line)
            .map_err(|e: RewriteError| e.kind.to_string())?;
        for &k in &axes {
            self.known[k] = true;
        }
        self.nominal = to;
        let mut commands: Vec<(Pose, bool)> = Vec::new();
        for p in &pieces {
            let filtered = filter_line(p).map_err(|e| e.to_string())?;
            let acts = self
                .pieces
                .execute(&filtered, false)
                .map_err(|code| format!("internal: piece `{p}` refused with error:{code}"))?;
            for a in acts {
                if let GrblAction::Move { target, rate, .. } = a {
                    commands.push((target, matches!(rate, Rate::Rapid)));
                }
            }
        }
        // In exact path or exact stop mode the program asked to stop at its own points,
        // not at every piece of a split move: the pieces but the last blend within the
        // tolerance, and the mode comes back for the last (LinuxCNC ends each piece as
        // that piece's mode says). A canned cycle keeps its exact path.
        let exact = matches!(self.path, PathMode::ExactPath | PathMode::ExactStop);
        let split_exact = exact && !self.in_cycle && commands.len() > 1;
        for (k, (command, rapid)) in commands.iter().enumerate() {
            if split_exact && k == 0 {
                let blend = self.path_text(PathMode::Blend {
                    p_mm: None,
                    q_mm: None,
                });
                self.emit(&blend)?;
            }
            if split_exact && k + 1 == commands.len() {
                let mode = self.path_text(self.path);
                self.emit(&mode)?;
            }
            let mut text = String::new();
            if g53 {
                text.push_str("G53 ");
            }
            text.push_str(if *rapid { "G0" } else { "G1" });
            for i in 0..3 {
                let moved = (command[i] - self.controller[i]).abs() > 5e-7;
                let name = k == 0 && named[i];
                if !(moved || name) {
                    continue;
                }
                let v = fmt(command[i] - origin[i]);
                let back: f64 = v.parse().unwrap_or(f64::NAN);
                text.push_str(&format!(" {}{v}", LETTERS[i]));
                self.controller[i] = back + origin[i];
            }
            if !*rapid {
                if let Some(f) = feed {
                    if self.feed_written != Some(f) {
                        text.push_str(&format!(" F{}", fmt(f)));
                        self.feed_written = Some(f);
                    }
                }
            }
            self.emit(&text)?;
        }
        self.report.moves_compensated += 1;
        self.report.segments_added += commands.len().saturating_sub(1);
        Ok(())
    }
}

/// The move as one GRBL line in machine coordinates (G90 G21, no offsets): the named
/// axes (an arc: both axes of its plane too), the centre as I/J/K from the start.
fn canonical_line(motion: &Action, from: Pose, named: &[usize]) -> Option<String> {
    let num = |v: f64| {
        let t = protocol::nc::format_number(v, 6)?;
        Some(if t.contains('.') {
            t.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            t
        })
    };
    let mut text = String::new();
    let to = match motion {
        Action::Rapid { to } => {
            text.push_str("G0");
            *to
        }
        Action::Linear { to, feed } => {
            text.push_str(&format!("G1F{}", num(*feed)?));
            *to
        }
        Action::Arc {
            to,
            centre,
            clockwise,
            plane,
            feed,
        } => {
            let (a, b, _) = plane.axes();
            text.push_str(match plane {
                Plane::Xy => "G17",
                Plane::Zx => "G18",
                Plane::Yz => "G19",
            });
            text.push_str(if *clockwise { "G2" } else { "G3" });
            text.push_str(&format!("F{}", num(*feed)?));
            for k in [a, b] {
                text.push(['I', 'J', 'K'][k]);
                text.push_str(&num(centre[k] - from[k])?);
            }
            *to
        }
        _ => return None,
    };
    for &k in named {
        text.push(LETTERS[k]);
        text.push_str(&num(to[k])?);
    }
    Some(text)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Approach, Identity, N_AXIS};

    /// 10 um more X per 100 mm of X.
    struct Stretch;
    impl Compensation for Stretch {
        fn describe(&self) -> String {
            "stretch".into()
        }
        fn axes(&self) -> &[usize] {
            &[0, 1]
        }
        fn command_for(&self, n: &Pose, _: &[Approach; N_AXIS]) -> Result<Pose, String> {
            Ok([n[0] * 1.0001, n[1], n[2]])
        }
    }

    fn ends(text: &str) -> Vec<Pose> {
        protocol::ngc::interpret(text, &Start::default(), Bounds::default())
            .unwrap()
            .into_iter()
            .flat_map(|s| s.actions)
            .filter_map(|a| match a {
                Action::Rapid { to } | Action::Linear { to, .. } => Some(to),
                _ => None,
            })
            .collect()
    }

    const PROGRAM: &str = "(square by a subroutine)\nG21 G17\n#<side> = 20\no<sq> sub\n  G1 X[#1 + #<_side>] F600\n  G1 Y[#2 + #<_side>]\n  G1 X#1\n  G1 Y#2\no<sq> endsub\n#<_side> = #<side>\nG0 X10 Y10 Z0\no1 repeat [2]\n  o<sq> call [10] [10]\no1 endrepeat\nG91 G0 X5\nM2\n";

    /// In G61 a split move blends between its own pieces and stops at its end, where
    /// the program asked; a move of one piece and a canned cycle stay in exact path.
    #[test]
    fn in_exact_path_a_split_move_stops_only_at_the_programs_points() {
        let program = "G21 G90 G17 G61\nG0 X10 Y10 Z5\nG2 X30 Y10 I10 J0 F3000\nG1 X31\n\
                       G81 X40 Y10 Z-1 R2\nG80\nM2\n";
        let (out, _) = rewrite_ngc(program, &Stretch, &NgcOptions::default()).unwrap();
        let lines: Vec<&str> = out.lines().collect();
        let arc = lines
            .iter()
            .position(|l| *l == "G64 P0.0005 Q0")
            .unwrap_or_else(|| panic!("{out}"));
        let back = lines[arc..]
            .iter()
            .position(|l| *l == "G61")
            .map(|k| arc + k)
            .unwrap_or_else(|| panic!("{out}"));
        // The arc's pieces but its last between the two, its last after G61: it ends on
        // the program's X30 Y10 (stretched).
        assert!(back - arc > 10, "{out}");
        assert!(
            lines[arc + 1..back].iter().all(|l| l.starts_with("G1")),
            "{out}"
        );
        assert_eq!(lines[back + 1], "G1 X30.003 Y10", "{out}");
        // The one-piece line and the cycle add no mode lines.
        assert_eq!(lines[back + 2], "G1 X31.0031", "{out}");
        assert_eq!(out.matches("G64 P0.0005 Q0").count(), 2, "{out}");
    }

    #[test]
    fn a_program_with_subroutines_is_flat_and_lands_where_programmed() {
        let (out, report) = rewrite_ngc(PROGRAM, &Identity, &NgcOptions::default()).unwrap();
        assert!(out.starts_with("G21 G90 G64 P0.0005 Q0\n"), "{out}");
        assert!(out.ends_with("G91\nM2\n"), "{out}");
        assert_eq!(report.blocks_in_calls, 8);
        assert_eq!(ends(&out), ends(PROGRAM));
        let (out, _) = rewrite_ngc(PROGRAM, &Stretch, &NgcOptions::default()).unwrap();
        let e = ends(&out);
        assert!(e.iter().any(|p| (p[0] - 30.003).abs() < 1e-9), "{out}");
        assert!((e.last().unwrap()[0] - 15.0015).abs() < 1e-9, "{out}");
    }

    /// The worked example of docs/compensation.md, exactly.
    #[test]
    fn the_docs_worked_example() {
        let program = "G21 G90 G64 P0.0001\no10 sub\n  G1 X#1 Y20 F600\no10 endsub\nG0 X0 Y20\no10 call [25 * 2]\nM2\n";
        let (out, _) = rewrite_ngc(program, &Stretch, &NgcOptions::default()).unwrap();
        assert_eq!(
            out,
            "G21 G90 G64 P0.0005 Q0\nG64 P0.0001 Q0\nG0 X0 Y20\nG1 X50.005 Y20 F600\nM2\n"
        );
    }

    #[test]
    fn refusals_name_the_line_and_the_call() {
        let text = "G21\nG0 X0 Y0 Z0\no<p> sub\n G38.2 Z-1 F10\no<p> endsub\no<p> call\n";
        let e = rewrite_ngc(text, &Identity, &NgcOptions::default()).unwrap_err();
        assert_eq!(e.line, 4);
        assert!(
            e.to_string().contains("(in o<p>, called from line 6)"),
            "{e}"
        );
        let e = rewrite_ngc("G0 X1\n", &Identity, &NgcOptions::default()).unwrap_err();
        assert!(e.to_string().contains("units"), "{e}");
        let e = rewrite_ngc("G21 G91 G0 X1\n", &Identity, &NgcOptions::default()).unwrap_err();
        assert!(e.to_string().contains("unknown position"), "{e}");
    }

    #[test]
    fn g92_and_offsets_keep_the_program_frame() {
        let mut o = NgcOptions::default();
        o.start.work_offsets[0] = [100.0, 0.0, 0.0];
        let text = "G21 G0 X10 Y0 Z0\nG92 X0\nG1 X10 F100\nG92.1\nM30\n";
        let (out, _) = rewrite_ngc(text, &Stretch, &o).unwrap();
        // X10 in G54 is machine 110: commanded 110.011, written 10.011; G92 X0 there
        // is moved by the correction, so G92's X10 is machine 120 (120.012).
        assert!(out.contains("G0 X10.011 Y0 Z0\n"), "{out}");
        assert!(out.contains("G92 X0.011\n"), "{out}");
        assert!(out.contains("G1 X10.012 F100\n"), "{out}");
    }
}

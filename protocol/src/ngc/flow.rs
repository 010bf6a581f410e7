//! A whole RS274/NGC program run as far as its values go: parameters set and read,
//! expressions evaluated with LinuxCNC's rules (`interp_execute.cc`), O-word
//! subroutines called with their `#1`..`#30` arguments, loops and conditions followed.
//! What comes out is the program's blocks as they run, each a list of plain words with
//! numbers ([`Flat`]); what would need the machine's state to evaluate is refused
//! naming the line.

use super::read::{read_line, Expr, Func, Item, Line, OKind, Op, Param, Statement};
use super::NgcError;
use std::collections::{BTreeMap, HashMap};

/// One block as it runs: its line and its words with their values (letters
/// lower-case, in the order written).
#[derive(Clone, Debug, PartialEq)]
pub struct Flat {
    pub line: usize,
    pub words: Vec<(char, f64)>,
    /// Where it runs: the subroutine calls around it, innermost last (`o<name>` and
    /// the line of its call), for messages.
    pub calls: Vec<(String, usize)>,
}

/// Bounds of an expansion (hostile or endless programs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds {
    /// Most statements run (loops count every pass).
    pub max_steps: usize,
    /// Most blocks put out.
    pub max_blocks: usize,
}

impl Default for Bounds {
    fn default() -> Self {
        Self {
            max_steps: 2_000_000,
            max_blocks: 500_000,
        }
    }
}

/// LinuxCNC's deepest subroutine nesting (`o-code.adoc`: 10).
pub const MAX_CALL_DEPTH: usize = 10;

/// LinuxCNC's `TOLERANCE_EQUAL`: two numbers compare EQ when closer than this.
const TOLERANCE_EQUAL: f64 = 1e-6;

/// The program's lines, read; a line that cannot be read is an error naming it.
struct Source {
    lines: Vec<(usize, String, Line)>,
}

/// The structure found by one pass: for each O-word statement, its partners.
#[derive(Default)]
struct Structure {
    /// if: the indices of its elseif/else branches and its endif.
    branches: HashMap<usize, Vec<usize>>,
    endif_of: HashMap<usize, usize>,
    /// while (leading)/repeat/do: the closing statement; and back.
    close_of: HashMap<usize, usize>,
    open_of: HashMap<usize, usize>,
    /// break/continue/return/endsub: the loop or sub they belong to.
    owner: HashMap<usize, usize>,
}

struct Frame {
    /// #1..#30 (None: not known to the rewrite).
    locals: [Option<f64>; 30],
    named: BTreeMap<String, f64>,
    return_to: usize,
    /// Repeat counters: the repeat statement's index -> passes left.
    repeats: HashMap<usize, i64>,
    name: String,
    call_line: usize,
}

impl Frame {
    fn new(name: String, call_line: usize, return_to: usize) -> Self {
        Self {
            locals: [None; 30],
            named: BTreeMap::new(),
            return_to,
            repeats: HashMap::new(),
            name,
            call_line,
        }
    }
}

/// Runs the program's control flow and values; the blocks in the order LinuxCNC runs
/// them. Block delete (`/`) is refused: whether a block runs depends on the operator's
/// switch.
pub fn expand(text: &str, bounds: Bounds) -> Result<Vec<Flat>, NgcError> {
    let source = read_source(text)?;
    let structure = structure(&source)?;
    let mut run = Run {
        source: &source,
        structure: &structure,
        frames: vec![Frame::new(String::new(), 0, 0)],
        globals: BTreeMap::new(),
        numbered: HashMap::new(),
        subs: HashMap::new(),
        out: Vec::new(),
        bounds,
    };
    run.go()?;
    Ok(run.out)
}

fn read_source(text: &str) -> Result<Source, NgcError> {
    let mut lines = Vec::new();
    let mut percent = None;
    for (k, (raw, _)) in crate::nc::split_lines(text).enumerate() {
        let n = k + 1;
        let line = read_line(raw, n)?;
        match line.statement {
            Statement::Percent => {
                // A first `%` opens the program; the next one ends it: what follows
                // is not read (LinuxCNC).
                if lines.iter().all(|(_, _, l): &(usize, String, Line)| {
                    matches!(l.statement, Statement::Empty)
                }) && percent.is_none()
                {
                    percent = Some(n);
                    continue;
                }
                if percent.is_some() {
                    break;
                }
                return Err(NgcError::new(
                    n,
                    raw,
                    "`%` ends a program that did not start with `%`".into(),
                ));
            }
            Statement::Empty if !line.block_delete => continue,
            _ => lines.push((n, raw.to_string(), line)),
        }
    }
    Ok(Source { lines })
}

fn structure(source: &Source) -> Result<Structure, NgcError> {
    let mut s = Structure::default();
    // Open statements: (name, kind, index); a sub is the outermost.
    let mut open: Vec<(String, &'static str, usize)> = Vec::new();
    for (i, (n, raw, line)) in source.lines.iter().enumerate() {
        let Statement::O(name, kind) = &line.statement else {
            continue;
        };
        let fail = |m: String| NgcError::new(*n, raw, m);
        if line.block_delete {
            return Err(fail("block delete `/` on an O-word line".into()));
        }
        let find = |open: &[(String, &str, usize)], kinds: &[&str]| {
            open.iter()
                .rev()
                .find(|(o, k, _)| o == name && kinds.contains(k))
                .map(|(_, _, at)| *at)
        };
        let close = |open: &mut Vec<(String, &'static str, usize)>,
                     kind: &str,
                     what: &str|
         -> Result<usize, NgcError> {
            match open.last() {
                Some((o, k, at)) if o == name && *k == kind => {
                    let at = *at;
                    open.pop();
                    Ok(at)
                }
                Some((o, k, _)) => {
                    Err(fail(format!("o{name} {what} while o{o} {k} is still open")))
                }
                None => Err(fail(format!("o{name} {what} without its o{name} {kind}"))),
            }
        };
        match kind {
            OKind::Sub => {
                if !open.is_empty() {
                    return Err(fail(format!(
                        "o{name} sub inside another block: subroutine definitions may not be nested"
                    )));
                }
                open.push((name.clone(), "sub", i));
            }
            OKind::EndSub(_) => {
                let at = close(&mut open, "sub", "endsub")?;
                s.close_of.insert(at, i);
                s.open_of.insert(i, at);
            }
            OKind::Return(_) => match open.first() {
                Some((o, "sub", at)) if o == name => {
                    s.owner.insert(i, *at);
                }
                _ => return Err(fail(format!("o{name} return outside o{name} sub"))),
            },
            OKind::Call(_) => {}
            OKind::Do => open.push((name.clone(), "do", i)),
            OKind::While(_) => {
                if matches!(open.last(), Some((o, "do", _)) if o == name) {
                    let at = close(&mut open, "do", "while")?;
                    s.close_of.insert(at, i);
                    s.open_of.insert(i, at);
                } else {
                    open.push((name.clone(), "while", i));
                }
            }
            OKind::EndWhile => {
                let at = close(&mut open, "while", "endwhile")?;
                s.close_of.insert(at, i);
                s.open_of.insert(i, at);
            }
            OKind::Repeat(_) => open.push((name.clone(), "repeat", i)),
            OKind::EndRepeat => {
                let at = close(&mut open, "repeat", "endrepeat")?;
                s.close_of.insert(at, i);
                s.open_of.insert(i, at);
            }
            OKind::If(_) => {
                open.push((name.clone(), "if", i));
                s.branches.insert(i, Vec::new());
            }
            OKind::ElseIf(_) | OKind::Else => {
                let what = if matches!(kind, OKind::Else) {
                    "else"
                } else {
                    "elseif"
                };
                match open.last() {
                    Some((o, "if", at)) if o == name => {
                        let branches = s.branches.entry(*at).or_default();
                        if branches.last().is_some_and(|&b| {
                            matches!(source.lines[b].2.statement, Statement::O(_, OKind::Else))
                        }) {
                            return Err(fail(format!("o{name} {what} after o{name} else")));
                        }
                        branches.push(i);
                        s.owner.insert(i, *at);
                    }
                    _ => return Err(fail(format!("o{name} {what} without its o{name} if"))),
                }
            }
            OKind::EndIf => {
                let at = close(&mut open, "if", "endif")?;
                s.endif_of.insert(at, i);
                for b in s.branches.get(&at).cloned().unwrap_or_default() {
                    s.endif_of.insert(b, i);
                }
            }
            OKind::Break | OKind::Continue => {
                let what = if matches!(kind, OKind::Break) {
                    "break"
                } else {
                    "continue"
                };
                // LinuxCNC: `break` and `continue` belong to a while or do loop
                // (`interp_o_word.cc`: "no matching while/do label"), not to repeat.
                let Some(at) = find(&open, &["while", "do"]) else {
                    return Err(fail(format!(
                        "o{name} {what} outside an o{name} while or do loop (LinuxCNC refuses it, in a repeat too)"
                    )));
                };
                // LinuxCNC 2.9 does not loop again after `continue` in a do-while
                // (its manual says it should): seen running the corpus in LinuxCNC.
                if matches!(kind, OKind::Continue)
                    && matches!(source.lines[at].2.statement, Statement::O(_, OKind::Do))
                {
                    return Err(fail(format!(
                        "o{name} continue in a do-while loop: LinuxCNC 2.9 leaves the loop there, not as its manual says; not rewritten (use a while loop)"
                    )));
                }
                s.owner.insert(i, at);
            }
        }
    }
    if let Some((name, kind, at)) = open.last() {
        let (n, raw, _) = &source.lines[*at];
        return Err(NgcError::new(
            *n,
            raw,
            format!("o{name} {kind} is never closed"),
        ));
    }
    Ok(s)
}

struct Run<'a> {
    source: &'a Source,
    structure: &'a Structure,
    frames: Vec<Frame>,
    /// Global named parameters set by the program (`#<_name>`).
    globals: BTreeMap<String, f64>,
    /// #31..#5000 set by the program.
    numbered: HashMap<u32, f64>,
    /// Subroutines defined so far: name -> the index of its `sub`.
    subs: HashMap<String, usize>,
    out: Vec<Flat>,
    bounds: Bounds,
}

/// What a statement does to the program counter.
enum Next {
    Step,
    Jump(usize),
    End,
}

impl Run<'_> {
    fn go(&mut self) -> Result<(), NgcError> {
        let mut pc = 0;
        let mut steps = 0usize;
        while pc < self.source.lines.len() {
            steps += 1;
            let (n, raw, _) = &self.source.lines[pc];
            if steps > self.bounds.max_steps {
                return Err(NgcError::new(
                    *n,
                    raw,
                    format!(
                        "the program runs more than {} statements (a loop that does not end?): not rewritten",
                        self.bounds.max_steps
                    ),
                ));
            }
            match self.step(pc).map_err(|m| self.error(pc, m))? {
                Next::Step => pc += 1,
                Next::Jump(to) => pc = to,
                Next::End => return Ok(()),
            }
        }
        Ok(())
    }

    fn error(&self, pc: usize, message: String) -> NgcError {
        let (n, raw, _) = &self.source.lines[pc];
        let mut m = message;
        for f in self.frames.iter().skip(1).rev() {
            m = format!("{m} (in o{}, called from line {})", f.name, f.call_line);
        }
        NgcError::new(*n, raw, m)
    }

    fn frame(&mut self) -> &mut Frame {
        self.frames.last_mut().expect("the main program's frame")
    }

    fn step(&mut self, pc: usize) -> Result<Next, String> {
        let (n, _, line) = &self.source.lines[pc];
        if line.block_delete {
            return Err("block delete `/`: whether the block runs is the operator's switch on the controller, unknown to the rewrite".into());
        }
        match &line.statement {
            Statement::Empty | Statement::Percent => Ok(Next::Step),
            Statement::Words(items) => self.words(*n, items),
            Statement::O(name, kind) => self.o_word(pc, *n, name, kind),
        }
    }

    fn words(&mut self, n: usize, items: &[Item]) -> Result<Next, String> {
        let mut words = Vec::new();
        let mut sets = Vec::new();
        // Every value is read before any setting takes effect (LinuxCNC).
        for item in items {
            match item {
                Item::Word(letter, e) => words.push((*letter, self.eval(e)?)),
                Item::Set(p, e) => {
                    let target = self.target(p)?;
                    sets.push((target, self.eval(e)?));
                }
            }
        }
        for (target, v) in sets {
            self.set(target, v)?;
        }
        if words.is_empty() {
            return Ok(Next::Step);
        }
        let ends = words
            .iter()
            .any(|&(l, v)| l == 'm' && (v == 2.0 || v == 30.0));
        if words
            .iter()
            .any(|&(l, v)| l == 'm' && (v == 98.0 || v == 99.0))
        {
            return Err(
                "M98/M99 (Fanuc-style subprograms) are not rewritten: use o-word subroutines"
                    .into(),
            );
        }
        if self.out.len() >= self.bounds.max_blocks {
            return Err(format!(
                "the program runs more than {} blocks: not rewritten",
                self.bounds.max_blocks
            ));
        }
        let calls = self
            .frames
            .iter()
            .skip(1)
            .map(|f| (f.name.clone(), f.call_line))
            .collect();
        self.out.push(Flat {
            line: n,
            words,
            calls,
        });
        Ok(if ends { Next::End } else { Next::Step })
    }

    fn o_word(&mut self, pc: usize, n: usize, name: &str, kind: &OKind) -> Result<Next, String> {
        let st = self.structure;
        match kind {
            OKind::Sub => {
                if self.subs.contains_key(name) {
                    return Err(format!("o{name} sub is defined twice"));
                }
                self.subs.insert(name.to_string(), pc);
                Ok(Next::Jump(st.close_of[&pc] + 1))
            }
            OKind::EndSub(value) | OKind::Return(value) => {
                if self.frames.len() < 2 {
                    return Err(format!("o{name} endsub/return outside a call"));
                }
                let v = value.as_ref().map(|e| self.eval(e)).transpose()?;
                let frame = self.frames.pop().expect("a called frame");
                match v {
                    Some(v) => {
                        self.globals.insert("_value".into(), v);
                        self.globals.insert("_value_returned".into(), 1.0);
                    }
                    None => {
                        // LinuxCNC leaves #<_value> as it was: unknown here.
                        self.globals.remove("_value");
                        self.globals.insert("_value_returned".into(), 0.0);
                    }
                }
                Ok(Next::Jump(frame.return_to))
            }
            OKind::Call(args) => {
                let Some(&at) = self.subs.get(name) else {
                    return Err(format!(
                        "o{name} call: o{name} is not defined above in this program (LinuxCNC calls only what is defined before; a subroutine in another file is not rewritten)"
                    ));
                };
                if self.frames.len() > MAX_CALL_DEPTH {
                    return Err(format!(
                        "o{name} call nests deeper than LinuxCNC's {MAX_CALL_DEPTH} calls"
                    ));
                }
                let values: Vec<f64> = args
                    .iter()
                    .map(|e| self.eval(e))
                    .collect::<Result<_, _>>()?;
                let mut frame = Frame::new(name.to_string(), n, pc + 1);
                for (k, v) in values.into_iter().enumerate() {
                    frame.locals[k] = Some(v);
                }
                self.frames.push(frame);
                Ok(Next::Jump(at + 1))
            }
            OKind::Do => Ok(Next::Step),
            OKind::While(cond) => {
                if let Some(&open) = st.open_of.get(&pc) {
                    // do ... while: back to the body while true.
                    return Ok(if self.truth(cond)? {
                        Next::Jump(open + 1)
                    } else {
                        Next::Step
                    });
                }
                Ok(if self.truth(cond)? {
                    Next::Step
                } else {
                    Next::Jump(st.close_of[&pc] + 1)
                })
            }
            OKind::EndWhile => Ok(Next::Jump(st.open_of[&pc])),
            OKind::Repeat(count) => {
                let count = self.eval(count)?;
                let passes = count.round();
                if !(0.0..=1e9).contains(&passes) {
                    return Err(format!("o{name} repeat [{count}]: not a count of passes"));
                }
                if passes < 1.0 {
                    return Ok(Next::Jump(st.close_of[&pc] + 1));
                }
                self.frame().repeats.insert(pc, passes as i64);
                Ok(Next::Step)
            }
            OKind::EndRepeat => {
                let open = st.open_of[&pc];
                let left = self.frame().repeats.get(&open).copied().unwrap_or(0) - 1;
                if left > 0 {
                    self.frame().repeats.insert(open, left);
                    Ok(Next::Jump(open + 1))
                } else {
                    self.frame().repeats.remove(&open);
                    Ok(Next::Step)
                }
            }
            OKind::If(cond) => {
                if self.truth(cond)? {
                    return Ok(Next::Step);
                }
                for &b in &st.branches[&pc] {
                    match &self.source.lines[b].2.statement {
                        Statement::O(_, OKind::ElseIf(c)) => {
                            if self.truth(c)? {
                                return Ok(Next::Jump(b + 1));
                            }
                        }
                        _ => return Ok(Next::Jump(b + 1)),
                    }
                }
                Ok(Next::Jump(st.endif_of[&pc] + 1))
            }
            // Reached after a branch ran: on to the end.
            OKind::ElseIf(_) | OKind::Else => Ok(Next::Jump(st.endif_of[&pc] + 1)),
            OKind::EndIf => Ok(Next::Step),
            OKind::Break => {
                let open = st.owner[&pc];
                self.frame().repeats.remove(&open);
                Ok(Next::Jump(st.close_of[&open] + 1))
            }
            OKind::Continue => {
                let open = st.owner[&pc];
                Ok(match &self.source.lines[open].2.statement {
                    // A do's while tests.
                    Statement::O(_, OKind::Do) => Next::Jump(st.close_of[&open]),
                    _ => Next::Jump(open),
                })
            }
        }
    }

    fn truth(&mut self, e: &Expr) -> Result<bool, String> {
        Ok(self.eval(e)? != 0.0)
    }

    fn eval(&mut self, e: &Expr) -> Result<f64, String> {
        let v = match e {
            Expr::Number(v) => *v,
            Expr::Param(p) => {
                let t = self.target(p)?;
                self.get(t)?
            }
            Expr::Neg(e) => -self.eval(e)?,
            Expr::Unary(f, e) => unary(*f, self.eval(e)?)?,
            Expr::Atan(y, x) => {
                let (y, x) = (self.eval(y)?, self.eval(x)?);
                y.atan2(x).to_degrees()
            }
            Expr::Exists(name) => {
                if name.starts_with('_') && !self.globals.contains_key(name) {
                    return Err(format!(
                        "EXISTS[#<{name}>]: a global name the program has not set may be one of LinuxCNC's predefined parameters (the machine's state)"
                    ));
                }
                let local = self
                    .frames
                    .last()
                    .is_some_and(|f| f.named.contains_key(name));
                f64::from(u8::from(local || self.globals.contains_key(name)))
            }
            Expr::Binary(op, l, r) => binary(*op, self.eval(l)?, self.eval(r)?)?,
        };
        if v.is_nan() {
            return Err("a calculation resulted in 'not a number'".into());
        }
        if v.is_infinite() {
            return Err("a calculation resulted in 'infinity'".into());
        }
        Ok(v)
    }

    fn target(&mut self, p: &Param) -> Result<Target, String> {
        match p {
            Param::Named(name) => Ok(Target::Named(name.clone())),
            Param::Numbered(index) => {
                let v = self.eval(index)?;
                let k = v.round();
                if (v - k).abs() > 0.0001 || !(1.0..=5601.0).contains(&k) {
                    return Err(format!("#{v}: parameter number out of range (1 to 5601)"));
                }
                Ok(Target::Numbered(k as u32))
            }
        }
    }

    fn get(&self, t: Target) -> Result<f64, String> {
        match t {
            Target::Numbered(k @ 1..=30) => {
                let frame = self.frames.last().expect("a frame");
                frame.locals[k as usize - 1].ok_or_else(|| {
                    if self.frames.len() > 1 {
                        format!("#{k} is read in o{} but is neither one of its arguments nor set in it (LinuxCNC 2.9's source gives 0, its manual the caller's value): not rewritten", frame.name)
                    } else {
                        format!("#{k} is read before the program sets it: its value is the controller's, unknown to the rewrite")
                    }
                })
            }
            Target::Numbered(k @ 31..=5000) => self.numbered.get(&k).copied().ok_or_else(|| {
                format!("#{k} is read before the program sets it: its value is the controller's, unknown to the rewrite")
            }),
            Target::Numbered(k) => Err(format!(
                "#{k} is a system parameter: its value depends on the machine's state (offsets, position, tool), unknown to the rewrite"
            )),
            Target::Named(name) => {
                if let Some(v) = self.frames.last().and_then(|f| f.named.get(&name)) {
                    return Ok(*v);
                }
                if let Some(v) = self.globals.get(&name) {
                    return Ok(*v);
                }
                if name.starts_with('_') {
                    Err(format!("#<{name}> is not set by the program: a predefined parameter reads the machine's state (position, modes, offsets), unknown to the rewrite"))
                } else {
                    Err(format!("#<{name}> is read before it is set (LinuxCNC: named parameter not defined)"))
                }
            }
        }
    }

    fn set(&mut self, t: Target, v: f64) -> Result<(), String> {
        match t {
            Target::Numbered(k @ 1..=30) => self.frame().locals[k as usize - 1] = Some(v),
            Target::Numbered(k @ 31..=5000) => {
                self.numbered.insert(k, v);
            }
            Target::Numbered(k) => {
                return Err(format!(
                    "#{k} is a system parameter: setting it changes the machine's state (offsets, stored positions), not rewritten"
                ))
            }
            Target::Named(name) if is_predefined(&name) => {
                return Err(format!(
                    "#<{name}> is one of LinuxCNC's predefined parameters, read-only (LinuxCNC: cannot assign to read-only parameter)"
                ))
            }
            Target::Named(name) if name.starts_with('_') => {
                self.globals.insert(name, v);
            }
            Target::Named(name) => {
                self.frame().named.insert(name, v);
            }
        }
        Ok(())
    }
}

/// LinuxCNC 2.9's predefined named parameters (`interp_namedparams.cc`,
/// `init_readonly_param`), and its `_ini[...]` and `_hal[...]` reads: read-only, and
/// read from the machine's state.
const PREDEFINED: [&str; 58] = [
    "_line",
    "_motion_mode",
    "_plane",
    "_ccomp",
    "_metric",
    "_imperial",
    "_absolute",
    "_incremental",
    "_inverse_time",
    "_units_per_minute",
    "_units_per_rev",
    "_coord_system",
    "_tool_offset",
    "_retract_r_plane",
    "_retract_old_z",
    "_control_mode",
    "_spindle_rpm_mode",
    "_spindle_css_mode",
    "_ijk_absolute_mode",
    "_lathe_diameter_mode",
    "_lathe_radius_mode",
    "_spindle_on",
    "_spindle_cw",
    "_mist",
    "_flood",
    "_speed_override",
    "_feed_override",
    "_adaptive_feed",
    "_feed_hold",
    "_feed",
    "_rpm",
    "_current_tool",
    "_current_pocket",
    "_selected_pocket",
    "_selected_tool",
    "_x",
    "_y",
    "_z",
    "_a",
    "_b",
    "_c",
    "_u",
    "_v",
    "_w",
    "_abs_x",
    "_abs_y",
    "_abs_z",
    "_abs_a",
    "_abs_b",
    "_abs_c",
    "_abs_u",
    "_abs_v",
    "_abs_w",
    "_value",
    "_value_returned",
    "_task",
    "_call_level",
    "_remap_level",
];

fn is_predefined(name: &str) -> bool {
    PREDEFINED.contains(&name)
        || name.starts_with("_ini[")
        || name.starts_with("_hal[")
        || name == "_vmajor"
        || name == "_vminor"
}

#[derive(Clone, Debug)]
enum Target {
    Numbered(u32),
    Named(String),
}

/// `execute_unary`: angles in degrees.
fn unary(f: Func, v: f64) -> Result<f64, String> {
    Ok(match f {
        Func::Abs => v.abs(),
        Func::Acos => {
            if !(-1.0..=1.0).contains(&v) {
                return Err(format!("ACOS[{v}]: argument out of range"));
            }
            v.acos().to_degrees()
        }
        Func::Asin => {
            if !(-1.0..=1.0).contains(&v) {
                return Err(format!("ASIN[{v}]: argument out of range"));
            }
            v.asin().to_degrees()
        }
        Func::Cos => v.to_radians().cos(),
        Func::Exp => v.exp(),
        Func::Fix => v.floor(),
        Func::Fup => v.ceil(),
        Func::Ln => {
            if v <= 0.0 {
                return Err(format!("LN[{v}]: zero or negative argument"));
            }
            v.ln()
        }
        // (int)(v + 0.5) or (int)(v - 0.5): halves away from zero; past i32 LinuxCNC's
        // cast is undefined, so refused.
        Func::Round => {
            let r = if v < 0.0 { v - 0.5 } else { v + 0.5 };
            if r.abs() >= 2_147_483_647.0 {
                return Err(format!("ROUND[{v}]: beyond LinuxCNC's integer range"));
            }
            r.trunc()
        }
        Func::Sin => v.to_radians().sin(),
        Func::Sqrt => {
            if v < 0.0 {
                return Err(format!("SQRT[{v}]: negative argument"));
            }
            v.sqrt()
        }
        Func::Tan => v.to_radians().tan(),
    })
}

/// `execute_binary1` and `execute_binary2`.
fn binary(op: Op, l: f64, r: f64) -> Result<f64, String> {
    let truth = |b: bool| f64::from(u8::from(b));
    Ok(match op {
        Op::Div => {
            if r == 0.0 {
                return Err("division by zero".into());
            }
            l / r
        }
        Op::Mod => {
            let m = l % r;
            if m < 0.0 {
                m + r.abs()
            } else {
                m
            }
        }
        Op::Pow => {
            if l < 0.0 && r.floor() != r {
                return Err(format!(
                    "{l} ** {r}: a negative number to a non-integer power"
                ));
            }
            l.powf(r)
        }
        Op::Mul => l * r,
        Op::Add => l + r,
        Op::Sub => l - r,
        Op::And => truth(l != 0.0 && r != 0.0),
        Op::Or => truth(l != 0.0 || r != 0.0),
        Op::Xor => truth((l == 0.0) != (r == 0.0)),
        Op::Lt => truth(l < r),
        Op::Gt => truth(l > r),
        Op::Eq => truth((l - r).abs() < TOLERANCE_EQUAL),
        Op::Ne => truth((l - r).abs() >= TOLERANCE_EQUAL),
        Op::Le => truth((l - r).abs() < TOLERANCE_EQUAL || l <= r),
        Op::Ge => truth((l - r).abs() < TOLERANCE_EQUAL || l >= r),
    })
}

//! LinuxCNC's dialect of G-code, RS274/NGC (LinuxCNC 2.9's `rs274ngc` interpreter),
//! read so that a program can be rewritten exactly or refused, sans-IO.
//!
//! Three steps, each following LinuxCNC's interpreter (`src/emc/rs274ngc`) and manual
//! ("O Codes", "Numbered Parameters", "Expressions", "G Codes"):
//!
//! * [`read`]: one line into an O-word statement or words and parameter settings, every
//!   value an expression (`[...]` with `** * / MOD + - EQ NE GT GE LT LE AND OR XOR`,
//!   LinuxCNC's precedence, and `ABS ACOS ASIN ATAN[]/[] COS EXP FIX FUP LN ROUND SIN
//!   SQRT TAN EXISTS`);
//! * [`flow`]: the program run as far as its values go: parameters (`#1`-`#30` local
//!   to a call, `#31`-`#5000` global, `#<name>` local, `#<_name>` global), O-word
//!   `sub`/`endsub`/`return`/`call [args]`, `while`/`endwhile`, `do`/`while`,
//!   `repeat`/`endrepeat`, `if`/`elseif`/`else`/`endif`, `break`, `continue`; the
//!   blocks in the order they run, every value a number;
//! * [`machine`]: those blocks as moves in machine millimetres (G0-G3 in G17/G18/G19
//!   with I/J/K or R, G90/G91, G90.1/G91.1, G20/G21, G53, G54-G59.3, G92 and
//!   G92.1/.2/.3, G61/G61.1/G64 P Q, canned cycles G81/G82/G85/G89 with G98/G99 and L
//!   expanded).
//!
//! Refused, naming the line and the construct (never a guess): values that depend on
//! the machine's state (`#5001` and up, predefined `#<_...>` names such as `#<_x>`,
//! numbered parameters read before the program sets them, `#k` in a subroutine beyond
//! its arguments where LinuxCNC's source and manual disagree), probing (G38.x), inputs
//! (M66), stored positions (G28/G30), offsets and tool data (G10, G43, G41/G42, M6),
//! calls of subroutines not defined above in the program (files), block delete `/`,
//! Fanuc-style M98/M99, other axes than X, Y, Z, spiral arcs, arcs of more than one
//! turn, and every code or word the rewrite does not model.

pub mod flow;
pub mod machine;
pub mod read;

pub use flow::{expand, Bounds, Flat};
pub use machine::{Action, Machine, PathMode, Plane, Start, Step, Xyz};

use std::fmt;

/// What could not be read or rewritten, and where: the line (1-based), its text as
/// written, and why.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub struct NgcError {
    pub line: usize,
    pub text: String,
    pub message: String,
}

impl NgcError {
    pub fn new(line: usize, text: &str, message: String) -> Self {
        Self {
            line,
            text: crate::text::escape_bytes(text.trim().as_bytes()),
            message,
        }
    }
}

impl fmt::Display for NgcError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.text.is_empty() {
            write!(f, "line {}: {}", self.line, self.message)
        } else {
            write!(f, "line {}: `{}`: {}", self.line, self.text, self.message)
        }
    }
}

/// The whole program as moves: [`expand`], then every block through a [`Machine`]
/// that starts from `start`. Errors name the line with its text.
pub fn interpret(text: &str, start: &Start, bounds: Bounds) -> Result<Vec<Step>, NgcError> {
    let flats = expand(text, bounds)?;
    let mut machine = Machine::new(start);
    let mut steps = Vec::with_capacity(flats.len());
    for flat in &flats {
        let step = machine.run(flat).map_err(|mut e| {
            if let Some((raw, _)) = crate::nc::split_lines(text).nth(e.line.wrapping_sub(1)) {
                e.text = crate::text::escape_bytes(raw.trim().as_bytes());
            }
            e
        })?;
        let end = step.actions.iter().any(|a| matches!(a, Action::End(_)));
        steps.push(step);
        if end {
            break;
        }
    }
    Ok(steps)
}

/// The largest parameter file read (a LinuxCNC `.var` file is a few kB).
pub const MAX_VAR_BYTES: usize = 1 << 20;

/// The offsets of a LinuxCNC parameter file (`[RS274NGC] PARAMETER_FILE`, e.g.
/// `sim.var`: lines `NUMBER VALUE`): G54-G59.3 from #5221.. (20 apart, X Y Z first),
/// the active system from #5220 (1 = G54), the G92 offset #5211-#5213 (in effect when
/// #5210 is 1). A work system rotated in XY (#5230 + 20k, its R) is refused. Values
/// are in the machine's units, mm here. Other lines are ignored; a malformed line is
/// an error naming it.
pub fn read_var_file(text: &str) -> Result<Start, NgcError> {
    if text.len() > MAX_VAR_BYTES {
        return Err(NgcError::new(
            0,
            "",
            format!(
                "{} bytes: a parameter file has at most {MAX_VAR_BYTES}",
                text.len()
            ),
        ));
    }
    let mut values = std::collections::HashMap::new();
    for (k, line) in text.lines().enumerate() {
        let t = line.trim();
        if t.is_empty() {
            continue;
        }
        let mut parts = t.split_whitespace();
        let (Some(n), Some(v), None) = (parts.next(), parts.next(), parts.next()) else {
            return Err(NgcError::new(k + 1, line, "expected `NUMBER VALUE`".into()));
        };
        let (Ok(n), Ok(v)) = (n.parse::<u32>(), v.parse::<f64>()) else {
            return Err(NgcError::new(k + 1, line, "expected `NUMBER VALUE`".into()));
        };
        if !v.is_finite() || v.abs() > 1e6 {
            return Err(NgcError::new(k + 1, line, "a value beyond 1e6".into()));
        }
        if values.insert(n, (v, k + 1)).is_some() {
            return Err(NgcError::new(k + 1, line, format!("#{n} a second time")));
        }
    }
    let get = |n: u32| values.get(&n).map_or(0.0, |(v, _)| *v);
    let mut start = Start::default();
    for s in 0..9u32 {
        let base = 5221 + 20 * s;
        start.work_offsets[s as usize] = [get(base), get(base + 1), get(base + 2)];
        if get(base + 9) != 0.0 {
            let line = values.get(&(base + 9)).map_or(0, |(_, l)| *l);
            return Err(NgcError::new(
                line,
                "",
                format!(
                    "#{}: a work system rotated in XY is not rewritten",
                    base + 9
                ),
            ));
        }
    }
    let system = get(5220);
    if values.contains_key(&5220) {
        if !(1.0..=9.0).contains(&system) || system.fract() != 0.0 {
            let line = values[&5220].1;
            return Err(NgcError::new(
                line,
                "",
                "#5220 is not a work system 1..9".into(),
            ));
        }
        start.system = system as usize - 1;
    }
    start.g92_stored = [get(5211), get(5212), get(5213)];
    if get(5210) == 1.0 {
        start.g92 = start.g92_stored;
    }
    Ok(start)
}

#[cfg(test)]
mod tests;

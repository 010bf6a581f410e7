//! Independent readers of the controllers' compensation tables, written from the
//! manuals' descriptions (`../shared/notes/legacy-controllers.md` section 3), not from
//! the exporter's code: each parses the text as the controller would, refuses what the
//! controller refuses, and evaluates the correction it applies at a position approached
//! from a side, as the error it cancels (mm, actual minus commanded).
//!
//! The options the manuals leave open (Fanuc's unit, sign and section; Heidenhain's
//! sign and BACKLASH; Haas's sign; CEC's multiplier) are given to the reader as the
//! engineer would configure the control.

use std::collections::BTreeMap;

/// +1 moving in + (approached from below), -1 in -.
pub type Side = i8;

fn num(s: &str, what: &str) -> Result<f64, String> {
    s.trim()
        .parse::<f64>()
        .map_err(|_| format!("{what}: `{s}` is not a number"))
}

/// Linear between points at `min + i step`, end values held.
fn linear(values: &[f64], min: f64, step: f64, s: f64) -> f64 {
    let n = values.len();
    let u = (s - min) / step;
    if u <= 0.0 {
        return values[0];
    }
    if u >= (n - 1) as f64 {
        return values[n - 1];
    }
    let i = u.floor() as usize;
    let t = u - i as f64;
    values[i] * (1.0 - t) + values[i + 1] * t
}

/// Linear between (position, value) pairs at increasing positions, end values held.
fn linear_at(points: &[(f64, f64)], s: f64) -> f64 {
    if s <= points[0].0 {
        return points[0].1;
    }
    for w in points.windows(2) {
        if s <= w[1].0 {
            let t = (s - w[0].0) / (w[1].0 - w[0].0);
            return w[0].1 + (w[1].1 - w[0].1) * t;
        }
    }
    points[points.len() - 1].1
}

// ---------------------------------------------------------------- Siemens

/// A SINUMERIK `_INI` part program of assignments: `$NAME[i,j,...]=value`, `;` comments,
/// `%_N_..._INI` first, `CHANDATA(n)`, `M17` last.
#[derive(Default, Debug)]
pub struct SiemensIni {
    /// name -> (indices as written) -> value as written.
    vars: BTreeMap<String, BTreeMap<Vec<String>, String>>,
}

impl SiemensIni {
    pub fn parse(text: &str) -> Result<Self, String> {
        let mut lines = text
            .lines()
            .map(|l| l.split(';').next().unwrap_or("").trim());
        let first = lines.next().unwrap_or("");
        if !(first.starts_with("%_N_") && first.ends_with("_INI")) {
            return Err(format!("first line `{first}`: %_N_..._INI expected"));
        }
        let mut ini = SiemensIni::default();
        let mut ended = false;
        for l in lines.filter(|l| !l.is_empty()) {
            if ended {
                return Err(format!("`{l}` after M17"));
            }
            if l == "M17" || l == "M30" {
                ended = true;
                continue;
            }
            if l.starts_with("CHANDATA(") {
                continue;
            }
            let (lhs, rhs) = l
                .split_once('=')
                .ok_or(format!("`{l}`: not an assignment"))?;
            let (name, idx) = lhs
                .strip_suffix(']')
                .and_then(|x| x.split_once('['))
                .ok_or(format!("`{lhs}`: $NAME[...] expected"))?;
            if !name.starts_with('$') {
                return Err(format!("`{name}`: a system variable starts with $"));
            }
            let idx = idx.split(',').map(|s| s.trim().to_string()).collect();
            ini.vars
                .entry(name.to_string())
                .or_default()
                .insert(idx, rhs.trim().to_string());
        }
        if !ended {
            return Err("no M17 at the end".into());
        }
        Ok(ini)
    }

    fn get(&self, name: &str, idx: &[&str]) -> Result<&str, String> {
        let key: Vec<String> = idx.iter().map(|s| s.to_string()).collect();
        self.vars
            .get(name)
            .and_then(|m| m.get(&key))
            .map(|s| s.as_str())
            .ok_or(format!("{name}[{}] is not set", idx.join(",")))
    }

    /// The values `name[..prefix.., N, ..suffix..]` for N = 0, 1, ... (contiguous).
    fn series(&self, name: &str, prefix: &[&str], suffix: &[&str]) -> Result<Vec<f64>, String> {
        let mut out = Vec::new();
        loop {
            let n = out.len().to_string();
            let mut idx: Vec<&str> = prefix.to_vec();
            idx.push(&n);
            idx.extend_from_slice(suffix);
            match self.get(name, &idx) {
                Ok(v) => out.push(num(v, name)?),
                Err(_) => break,
            }
        }
        let written = self.vars.get(name).map_or(0, |m| {
            m.keys()
                .filter(|k| {
                    k.len() == prefix.len() + 1 + suffix.len()
                        && k[..prefix.len()] == *prefix
                        && k[prefix.len() + 1..] == *suffix
                })
                .count()
        });
        if written != out.len() {
            return Err(format!(
                "{name}: {written} points written, only 0..{} contiguous",
                out.len()
            ));
        }
        Ok(out)
    }
}

/// A regular table as Siemens checks it: (MAX - MIN) / STEP + 1 points, at most `md`.
fn regular_table(
    values: Vec<f64>,
    step: f64,
    min: f64,
    max: f64,
    md: usize,
    what: &str,
) -> Result<Vec<f64>, String> {
    if !(step > 0.0 && max > min) {
        return Err(format!("{what}: STEP {step}, MIN {min}, MAX {max}"));
    }
    let points = (max - min) / step + 1.0;
    if (points - points.round()).abs() > 1e-6 || points.round() as usize != values.len() {
        return Err(format!(
            "{what}: (MAX - MIN) / STEP + 1 = {points:.3} points, {} written",
            values.len()
        ));
    }
    if values.len() > md {
        return Err(format!(
            "{what}: {} points, the machine data allows {md}",
            values.len()
        ));
    }
    Ok(values)
}

pub struct Eec {
    values: Vec<f64>,
    step: f64,
    min: f64,
}

impl Eec {
    /// The EEC of `axis`, measuring system 0, with MD38000 = `md`.
    pub fn read(ini: &SiemensIni, axis: &str, md: usize) -> Result<Self, String> {
        let v = ini.series("$AA_ENC_COMP", &["0"], &[axis])?;
        let f = |n: &str| -> Result<f64, String> { num(ini.get(n, &["0", axis])?, n) };
        let (step, min, max) = (
            f("$AA_ENC_COMP_STEP")?,
            f("$AA_ENC_COMP_MIN")?,
            f("$AA_ENC_COMP_MAX")?,
        );
        if f("$AA_ENC_COMP_IS_MODULO")? != 0.0 {
            return Err("modulo tables are not for a linear axis".into());
        }
        let values = regular_table(v, step, min, max, md, &format!("EEC {axis}"))?;
        Ok(Self { values, step, min })
    }

    pub fn at(&self, s: f64) -> f64 {
        linear(&self.values, self.min, self.step, s)
    }
}

pub struct CecTable {
    values: Vec<f64>,
    input: String,
    output: String,
    step: f64,
    min: f64,
    direction: i8,
    mult: usize,
}

pub struct Cec {
    tables: Vec<CecTable>,
    /// Whether a table used as a multiplier also adds its own output.
    own_output_added: bool,
}

impl Cec {
    /// Tables 0.. of the file, each at most `md` points (MD18342), at most `max_tables`.
    pub fn read(
        ini: &SiemensIni,
        md: usize,
        max_tables: usize,
        own_output_added: bool,
    ) -> Result<Self, String> {
        let mut tables = Vec::new();
        loop {
            let t = tables.len().to_string();
            if ini.get("$AN_CEC_STEP", &[&t]).is_err() {
                break;
            }
            let f = |n: &str| -> Result<f64, String> { num(ini.get(n, &[&t])?, n) };
            let axis = |n: &str| -> Result<String, String> {
                let v = ini.get(n, &[&t])?;
                v.strip_prefix('(')
                    .and_then(|v| v.strip_suffix(')'))
                    .map(str::to_string)
                    .ok_or(format!("{n}[{t}] = {v}: (AXIS) expected"))
            };
            let v = ini.series("$AN_CEC", &[&t], &[])?;
            let (step, min, max) = (f("$AN_CEC_STEP")?, f("$AN_CEC_MIN")?, f("$AN_CEC_MAX")?);
            let values = regular_table(v, step, min, max, md, &format!("CEC table {t}"))?;
            let direction = f("$AN_CEC_DIRECTION")? as i8;
            if ![-1, 0, 1].contains(&direction) {
                return Err(format!("CEC table {t}: direction {direction}"));
            }
            if f("$AN_CEC_IS_MODULO")? != 0.0 {
                return Err("modulo tables are not for a linear axis".into());
            }
            tables.push(CecTable {
                values,
                input: axis("$AN_CEC_INPUT_AXIS")?,
                output: axis("$AN_CEC_OUTPUT_AXIS")?,
                step,
                min,
                direction,
                mult: f("$AN_CEC_MULT_BY_TABLE")? as usize,
            });
        }
        if tables.len() > max_tables {
            return Err(format!(
                "{} CEC tables, the control has {max_tables}",
                tables.len()
            ));
        }
        for (t, c) in tables.iter().enumerate() {
            if c.mult > tables.len() || c.mult == t + 1 {
                return Err(format!("CEC table {t}: MULT_BY_TABLE {}", c.mult));
            }
        }
        Ok(Self {
            tables,
            own_output_added,
        })
    }

    pub fn count(&self) -> usize {
        self.tables.len()
    }

    /// The sum of the tables of `output` at positions `pos(axis)` moved in `side(axis)`.
    pub fn at(&self, output: &str, pos: &dyn Fn(&str) -> f64, side: &dyn Fn(&str) -> Side) -> f64 {
        let multipliers: Vec<usize> = self
            .tables
            .iter()
            .filter(|t| t.mult > 0)
            .map(|t| t.mult - 1)
            .collect();
        let value = |t: &CecTable| linear(&t.values, t.min, t.step, pos(&t.input));
        let mut sum = 0.0;
        for (k, t) in self.tables.iter().enumerate() {
            if t.output != output {
                continue;
            }
            if t.direction != 0 && t.direction != side(&t.input) {
                continue;
            }
            if multipliers.contains(&k) && !self.own_output_added {
                continue;
            }
            let mut v = value(t);
            if t.mult > 0 {
                v *= value(&self.tables[t.mult - 1]);
            }
            sum += v;
        }
        sum
    }
}

// ---------------------------------------------------------------- Fanuc

pub enum FanucShape {
    StepEnding,
    StepStarting,
    Ramp,
}

/// A Fanuc parameter file with pitch error data: `%`, records, `%`; EOB LF.
pub struct FanucPitch {
    axes: Vec<FanucAxis>,
}

struct FanucAxis {
    /// (position mm, absolute correction as the error it cancels, mm) per point.
    points: Vec<(f64, f64)>,
    interval: f64,
}

fn fanuc_word(s: &str, letter: char) -> Option<(&str, &str)> {
    let s = s.strip_prefix(letter)?;
    let end = s
        .find(|c: char| !(c.is_ascii_digit() || c == '-' || c == '+' || c == '.'))
        .unwrap_or(s.len());
    Some((&s[..end], &s[end..]))
}

impl FanucPitch {
    /// `tv_without_eob`: the TV check on (characters of a block, EOB not counted, even).
    /// `unit_mm`: a value's unit; `error_sign`: values are the error (else minus it).
    pub fn parse(
        text: &str,
        tv_without_eob: bool,
        unit_mm: f64,
        error_sign: bool,
        record_base: usize,
    ) -> Result<Self, String> {
        let body = text
            .strip_prefix("%\n")
            .and_then(|t| t.strip_suffix("%\n"))
            .ok_or("the file is framed by % lines")?;
        let mut axis_params: BTreeMap<u32, Vec<i64>> = BTreeMap::new();
        let mut pitch: BTreeMap<usize, i64> = BTreeMap::new();
        for (line_no, block) in body.split('\n').enumerate() {
            if block.is_empty() {
                continue;
            }
            if tv_without_eob && block.chars().count() % 2 == 1 {
                return Err(format!(
                    "block {}: {} characters (TV check, alarm 002)",
                    line_no + 2,
                    block.len()
                ));
            }
            if !block
                .chars()
                .all(|c| c.is_ascii_uppercase() || c.is_ascii_digit() || "+-. ".contains(c))
            {
                return Err(format!(
                    "block `{block}`: a character outside the ISO subset"
                ));
            }
            let b = block.trim_end_matches(' ');
            let (n, rest) = fanuc_word(b, 'N').ok_or(format!("`{b}`: N first"))?;
            let n: usize = n.parse().map_err(|_| format!("`{b}`: N number"))?;
            if n >= record_base {
                let (p, rest) = fanuc_word(rest, 'P').ok_or(format!("`{b}`: P expected"))?;
                if !rest.is_empty() {
                    return Err(format!("`{b}`: trailing `{rest}`"));
                }
                pitch.insert(
                    n - record_base,
                    p.parse().map_err(|_| format!("`{b}`: integer value"))?,
                );
            } else {
                let mut rest = rest;
                let mut values = Vec::new();
                while !rest.is_empty() {
                    let (a, r) = fanuc_word(rest, 'A').ok_or(format!("`{b}`: A expected"))?;
                    let (p, r) = fanuc_word(r, 'P').ok_or(format!("`{b}`: P expected"))?;
                    if a.parse::<usize>() != Ok(values.len() + 1) {
                        return Err(format!("`{b}`: axis {a} out of order"));
                    }
                    values.push(p.parse().map_err(|_| format!("`{b}`: integer parameter"))?);
                    rest = r;
                }
                axis_params.insert(n as u32, values);
            }
        }
        let param = |n: u32| axis_params.get(&n).ok_or(format!("parameter {n} missing"));
        let (refs, neg, pos, mag, interval) = (
            param(3620)?,
            param(3621)?,
            param(3622)?,
            param(3623)?,
            param(3624)?,
        );
        let mut axes = Vec::new();
        for a in 0..refs.len() {
            let (r, lo, hi) = (refs[a], neg[a], pos[a]);
            if !(lo <= r && r <= hi) {
                return Err(format!(
                    "axis {}: reference point {r} outside {lo}..{hi}",
                    a + 1
                ));
            }
            let q = unit_mm * mag[a] as f64;
            let iv = interval[a] as f64 * unit_mm;
            let sign = if error_sign { 1.0 } else { -1.0 };
            // Absolute at point k: sum of values after the reference up to k; below the
            // reference minus the values from k + 1 up to it.
            let value = |k: i64| -> Result<i64, String> {
                pitch
                    .get(&(k as usize))
                    .copied()
                    .ok_or(format!("pitch point {k} missing"))
            };
            let mut points = Vec::new();
            for k in lo..=hi {
                let mut sum = 0i64;
                if k > r {
                    for j in r + 1..=k {
                        sum += value(j)?;
                    }
                } else {
                    for j in k + 1..=r {
                        sum -= value(j)?;
                    }
                }
                points.push(((k - r) as f64 * iv, sign * sum as f64 * q));
            }
            axes.push(FanucAxis {
                points,
                interval: iv,
            });
        }
        Ok(Self { axes })
    }

    /// The correction of axis `a` (0 = axis 1) at `s`, as the error it cancels, mm.
    pub fn at(&self, a: usize, s: f64, shape: &FanucShape) -> f64 {
        let p = &self.axes[a].points;
        let iv = self.axes[a].interval;
        match shape {
            FanucShape::Ramp => linear_at(p, s),
            FanucShape::StepEnding | FanucShape::StepStarting => {
                // The section holding s, and the point whose sum holds there.
                let u = (s - p[0].0) / iv;
                let k = match shape {
                    FanucShape::StepEnding => u.ceil(),
                    _ => u.floor(),
                };
                p[(k.max(0.0) as usize).min(p.len() - 1)].1
            }
        }
    }
}

// ---------------------------------------------------------------- Heidenhain

/// A TNC table: `BEGIN name [MM]`, a header of column names, rows, `[END]`.
pub struct TncTable {
    pub name: String,
    columns: Vec<String>,
    rows: Vec<Vec<String>>,
}

impl TncTable {
    pub fn parse(text: &str) -> Result<Self, String> {
        let mut lines = text.lines();
        let begin = lines.next().unwrap_or("");
        let name = begin
            .strip_prefix("BEGIN ")
            .and_then(|s| s.split_whitespace().next())
            .ok_or(format!("`{begin}`: BEGIN name expected"))?
            .to_string();
        let columns: Vec<String> = lines
            .next()
            .unwrap_or("")
            .split_whitespace()
            .map(str::to_string)
            .collect();
        if columns.first().map(String::as_str) != Some("NR") {
            return Err("the header starts with NR".into());
        }
        let mut rows = Vec::new();
        let mut ended = false;
        for l in lines {
            if l.trim() == "[END]" {
                ended = true;
                break;
            }
            let cells: Vec<String> = l.split_whitespace().map(str::to_string).collect();
            if cells.len() != columns.len() {
                return Err(format!(
                    "`{l}`: {} cells for {} columns",
                    cells.len(),
                    columns.len()
                ));
            }
            if cells[0] != rows.len().to_string() {
                return Err(format!("`{l}`: NR {} out of order", cells[0]));
            }
            rows.push(cells);
        }
        if !ended {
            return Err("no [END]".into());
        }
        Ok(Self {
            name,
            columns,
            rows,
        })
    }

    fn column(&self, name: &str) -> Result<Vec<f64>, String> {
        let c = self
            .columns
            .iter()
            .position(|c| c == name)
            .ok_or(format!("{}: no column {name}", self.name))?;
        self.rows.iter().map(|r| num(&r[c], name)).collect()
    }

    fn cell(&self, row: usize, name: &str) -> Result<String, String> {
        let c = self
            .columns
            .iter()
            .position(|c| c == name)
            .ok_or(format!("{}: no column {name}", self.name))?;
        Ok(self.rows.get(row).ok_or("no such row")?[c].clone())
    }
}

/// One `.COM` assigned to an input axis: (axis, AXISPOS, columns by axis, BACKLASH).
type ComTable = (String, Vec<f64>, BTreeMap<String, Vec<f64>>, Vec<f64>);

/// The `.CMA`'s active line and the `.COM` tables it assigns.
pub struct HeidenhainCom {
    tables: Vec<ComTable>,
    error_sign: bool,
}

impl HeidenhainCom {
    pub fn read(
        cma: &str,
        com: &dyn Fn(&str) -> Option<String>,
        error_sign: bool,
    ) -> Result<Self, String> {
        let cma = TncTable::parse(cma)?;
        let active: Vec<usize> = (0..cma.rows.len())
            .filter(|&r| cma.cell(r, "ACTIVE").is_ok_and(|c| c == "*"))
            .collect();
        let [row] = active[..] else {
            return Err(format!(
                "{} active lines in the .CMA, one expected",
                active.len()
            ));
        };
        let mut tables = Vec::new();
        for axis in cma.columns.iter().filter(|c| *c != "NR" && *c != "ACTIVE") {
            let file = cma.cell(row, axis)?;
            let text = com(&file).ok_or(format!("{file} is missing"))?;
            let t = TncTable::parse(&text)?;
            if t.name != file {
                return Err(format!("{file} begins as {}", t.name));
            }
            if t.rows.len() > 256 {
                return Err(format!(
                    "{file}: {} entries, a .COM holds 256",
                    t.rows.len()
                ));
            }
            let pos = t.column("AXISPOS")?;
            if pos.windows(2).any(|w| w[1] <= w[0]) {
                return Err(format!("{file}: AXISPOS not increasing"));
            }
            let mut cols = BTreeMap::new();
            for c in t
                .columns
                .iter()
                .filter(|c| !["NR", "AXISPOS", "BACKLASH"].contains(&c.as_str()))
            {
                cols.insert(c.clone(), t.column(c)?);
            }
            let backlash = t
                .column("BACKLASH")
                .unwrap_or_else(|_| vec![0.0; pos.len()]);
            tables.push((axis.clone(), pos, cols, backlash));
        }
        Ok(Self { tables, error_sign })
    }

    /// The correction of `output` at positions `pos(axis)`, moved in `side(axis)`, as the
    /// error it cancels, mm.
    pub fn at(&self, output: &str, pos: &dyn Fn(&str) -> f64, side: &dyn Fn(&str) -> Side) -> f64 {
        let sign = if self.error_sign { 1.0 } else { -1.0 };
        let mut sum = 0.0;
        for (input, at, cols, backlash) in &self.tables {
            let s = pos(input);
            let pts = |v: &Vec<f64>| {
                at.iter()
                    .copied()
                    .zip(v.iter().copied())
                    .collect::<Vec<_>>()
            };
            if let Some(v) = cols.get(output) {
                sum += linear_at(&pts(v), s);
            }
            if input == output && side(input) < 0 {
                sum += linear_at(&pts(backlash), s);
            }
        }
        sign * sum
    }
}

/// A TNC 306/360 64-value table: `X=F(X)`, `DATUM POINT X+d`, `SETUP e`, `i X+pos X+val`.
pub struct Heidenhain64 {
    pub axis: String,
    datum: f64,
    points: Vec<(f64, f64)>,
}

impl Heidenhain64 {
    pub fn parse(text: &str, error_sign: bool) -> Result<Self, String> {
        let mut lines = text.lines();
        let dep = lines.next().unwrap_or("");
        let (out, input) = dep
            .split_once("=F(")
            .ok_or(format!("`{dep}`: A=F(B) expected"))?;
        let input = input.strip_suffix(')').ok_or("F( not closed")?.to_string();
        if out != input {
            return Err(format!(
                "{dep}: only the axis's own dependency is read here"
            ));
        }
        let datum_line = lines.next().unwrap_or("");
        let datum = num(
            datum_line
                .strip_prefix(&format!("DATUM POINT {out}"))
                .ok_or(format!("`{datum_line}`"))?,
            "datum",
        )?;
        let setup_line = lines.next().unwrap_or("");
        let e: u32 = setup_line
            .strip_prefix("SETUP ")
            .and_then(|s| s.trim().parse().ok())
            .ok_or(format!("`{setup_line}`"))?;
        if e > 23 {
            return Err(format!("SETUP {e}: at most 23"));
        }
        let spacing = f64::from(1u32 << e) / 1000.0;
        let sign = if error_sign { 1.0 } else { -1.0 };
        let mut points = Vec::new();
        for l in lines {
            let cells: Vec<&str> = l.split_whitespace().collect();
            let [i, p, v] = cells[..] else {
                return Err(format!("`{l}`: three cells"));
            };
            if i != points.len().to_string() {
                return Err(format!("`{l}`: index out of order"));
            }
            let p = num(p.strip_prefix(out).ok_or(format!("`{l}`"))?, "position")?;
            let v = num(v.strip_prefix(out).ok_or(format!("`{l}`"))?, "value")?;
            if (p - points.len() as f64 * spacing).abs() > 1e-9 {
                return Err(format!("`{l}`: position not {} x {spacing}", points.len()));
            }
            points.push((p, sign * v));
        }
        if points.len() > 64 {
            return Err(format!("{} values, at most 64", points.len()));
        }
        if points.first().is_none_or(|p| p.1 != 0.0) {
            return Err("the value at the datum must be 0".into());
        }
        for w in points.windows(2) {
            if (w[1].1 - w[0].1).abs() > spacing / 64.0 + 1e-9 {
                return Err(format!(
                    "values at {} and {} differ by more than spacing / 64",
                    w[0].0, w[1].0
                ));
            }
        }
        Ok(Self {
            axis: out.to_string(),
            datum,
            points,
        })
    }

    pub fn at(&self, s: f64) -> f64 {
        linear_at(&self.points, s - self.datum)
    }
}

// ---------------------------------------------------------------- Haas

/// A Haas lead screw compensation listing: entries every 0.5 in from machine zero down.
pub struct HaasLeadScrew {
    /// (machine inch, value inch as the error it cancels), increasing.
    points: Vec<(f64, f64)>,
}

impl HaasLeadScrew {
    pub fn parse(text: &str, error_sign: bool) -> Result<Self, String> {
        let sign = if error_sign { 1.0 } else { -1.0 };
        let mut points = Vec::new();
        for l in text.lines().skip_while(|l| !l.starts_with("ENTRY")).skip(1) {
            let cells: Vec<&str> = l.split_whitespace().collect();
            let [i, m, v] = cells[..] else {
                return Err(format!("`{l}`: three cells"));
            };
            let (m, v) = (num(m, "machine")?, num(v, "value")?);
            if i != points.len().to_string() || (m + 0.5 * points.len() as f64).abs() > 1e-9 {
                return Err(format!(
                    "`{l}`: entry {} is at -{} in",
                    points.len(),
                    0.5 * points.len() as f64
                ));
            }
            if (v * 10_000.0 - (v * 10_000.0).round()).abs() > 1e-6 {
                return Err(format!("`{l}`: finer than 0.0001 in"));
            }
            points.push((m, sign * v));
        }
        if points.is_empty() {
            return Err("no entries".into());
        }
        points.reverse();
        Ok(Self { points })
    }

    /// At Haas machine coordinate `inch`, inches.
    pub fn at(&self, inch: f64) -> f64 {
        linear_at(&self.points, inch)
    }
}

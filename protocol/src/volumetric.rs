//! The volumetric error model file and the measurement campaign's instrument files.
//!
//! # Model file (`*.vol.csv`)
//!
//! Plain comma-separated text, no quoting, `#` starts a comment line. Key rows first, then
//! one table per axis in the ISG/Beckhoff volumetric CSV layout (position, then the six
//! error motions of that axis, ISO 230-1 names without the underscore):
//!
//! ```text
//! # volumetric error model
//! structure,XYFZ
//! units,mm,rad
//! tool_offset,0,0,0
//! work_offset,0,0,0
//! squareness,E_C0Y,2.0e-5,E_B0Z,-1.5e-5,E_A0Z,1.0e-5
//! fit,yes
//! X,EXX,EYX,EZX,EAX,EBX,ECX
//! 0,0,0,0,0,0,0
//! 250,0.012,-0.003,0.001,1.0e-6,-5.0e-6,2.0e-6
//! 500,0.025,0.0,0.0,2.0e-6,-8.0e-6,3.0e-6
//! Y,EXY,EYY,EZY,EAY,EBY,ECY
//! ...
//! Z,EXZ,EYZ,EZZ,EAZ,EBZ,ECZ
//! ...
//! ```
//!
//! - `units,LEN,ANG`: LEN (positions, offsets, translational errors) is `mm` or `um`; ANG
//!   (angular errors, squareness) is `rad`, `mrad` or `urad`. Values are held in mm and rad.
//! - `structure`: FXYZ, XFYZ, XYFZ or XYZF (letters before F move the workpiece).
//! - `fit`: `yes` when identification found the residuals within the instruments'
//!   uncertainty, `no` otherwise (the model must then not be used to compensate).
//! - Each axis table: at least two rows, positions strictly increasing.
//!
//! # Instrument files of a campaign
//!
//! Header lines `# key: value` (at least `instrument`, `axis`, `uncertainty_um` or
//! `uncertainty_urad`), then a column header row, then data rows. Every column name ends
//! in its unit (`_mm`, `_um`, `_urad`); a name with another unit is refused.
//! - `laser_<A>.csv`: `run,position_mm,E_<A><A>_um,E_<S1><A>_um,E_<S2><A>_um,E_<P><A>_urad,E_<W><A>_urad`:
//!   positioning, the two straightnesses and the two angles a laser interferometer's
//!   angular optics see (for X: E_BX pitch, E_CX yaw; Y: E_AY, E_CY; Z: E_AZ, E_BZ).
//! - `level_<A>.csv`: `run,position_mm,E_<R><A>_urad`: the roll (E_AX, E_BY, E_CZ).
//! - `squareness.csv`: `name,value_urad,uncertainty_urad`, rows E_C0Y, E_B0Z, E_A0Z.
//!
//! Within a run, positions are strictly increasing; each run covers the same positions.

use std::fmt;

/// A line/column located problem in a volumetric file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("line {line}, column {column}: {message}")]
pub struct VolFileError {
    pub line: usize,
    pub column: usize,
    pub message: String,
}

fn err(line: usize, column: usize, message: impl Into<String>) -> VolFileError {
    VolFileError {
        line,
        column,
        message: message.into(),
    }
}

/// Machine structure: letters before F move the workpiece, letters after F the tool, each
/// axis carried by the one before it when read outwards from F.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Structure {
    Fxyz,
    Xfyz,
    Xyfz,
    Xyzf,
}

impl Structure {
    pub const ALL: [Structure; 4] = [
        Structure::Fxyz,
        Structure::Xfyz,
        Structure::Xyfz,
        Structure::Xyzf,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Structure::Fxyz => "FXYZ",
            Structure::Xfyz => "XFYZ",
            Structure::Xyfz => "XYFZ",
            Structure::Xyzf => "XYZF",
        }
    }

    pub fn parse(s: &str) -> Option<Structure> {
        Structure::ALL
            .into_iter()
            .find(|k| k.name().eq_ignore_ascii_case(s.trim()))
    }

    /// Axis indices (0 = X, 1 = Y, 2 = Z) from the frame outwards to the workpiece.
    pub fn work_chain(self) -> &'static [usize] {
        match self {
            Structure::Fxyz => &[],
            Structure::Xfyz => &[0],
            Structure::Xyfz => &[1, 0],
            Structure::Xyzf => &[2, 1, 0],
        }
    }

    /// Axis indices from the frame outwards to the tool.
    pub fn tool_chain(self) -> &'static [usize] {
        match self {
            Structure::Fxyz => &[0, 1, 2],
            Structure::Xfyz => &[1, 2],
            Structure::Xyfz => &[2],
            Structure::Xyzf => &[],
        }
    }

    /// Whether axis `a` moves the workpiece.
    pub fn moves_work(self, a: usize) -> bool {
        self.work_chain().contains(&a)
    }
}

impl fmt::Display for Structure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

pub const AXES: [char; 3] = ['X', 'Y', 'Z'];
/// Column names of an axis table, without the axis letter: translations along X, Y, Z
/// (mm), rotations about X, Y, Z (A, B, C; rad).
pub const COMPONENTS: [char; 6] = ['X', 'Y', 'Z', 'A', 'B', 'C'];
/// Squareness names, in the order they are held.
pub const SQUARENESS: [&str; 3] = ["E_C0Y", "E_B0Z", "E_A0Z"];

/// The error motions of one axis against its position.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct AxisTable {
    /// Positions, mm, strictly increasing.
    pub positions_mm: Vec<f64>,
    /// Per position: E_X, E_Y, E_Z of the axis (mm), E_A, E_B, E_C (rad).
    pub errors: Vec<[f64; 6]>,
}

/// The whole model file.
#[derive(Debug, Clone, PartialEq)]
pub struct VolumetricFile {
    pub structure: Structure,
    pub tool_offset_mm: [f64; 3],
    pub work_offset_mm: [f64; 3],
    /// E_C0Y, E_B0Z, E_A0Z, rad.
    pub squareness_rad: [f64; 3],
    pub fit: bool,
    /// X, Y, Z.
    pub tables: [AxisTable; 3],
}

fn length_scale(u: &str) -> Option<f64> {
    match u {
        "mm" => Some(1.0),
        "um" => Some(1e-3),
        _ => None,
    }
}

fn angle_scale(u: &str) -> Option<f64> {
    match u {
        "rad" => Some(1.0),
        "mrad" => Some(1e-3),
        "urad" => Some(1e-6),
        _ => None,
    }
}

/// Splits a line into trimmed fields with their 1-based starting columns.
fn fields(line: &str) -> Vec<(usize, &str)> {
    let mut out = Vec::new();
    let mut start = 0;
    for part in line.split(',') {
        let lead = part.len() - part.trim_start().len();
        out.push((start + lead + 1, part.trim()));
        start += part.len() + 1;
    }
    out
}

fn number(line: usize, (col, text): (usize, &str), what: &str) -> Result<f64, VolFileError> {
    let v: f64 = text
        .parse()
        .map_err(|_| err(line, col, format!("{what}: `{text}` is not a number")))?;
    if !v.is_finite() {
        return Err(err(line, col, format!("{what}: `{text}` is not finite")));
    }
    Ok(v)
}

/// The largest position or offset a model may hold, mm: beyond any machine.
pub const MAX_POSITION_MM: f64 = 10_000.0;
/// The largest translational error a model may hold, mm: a machine 10 mm off is not
/// compensated, it is repaired; more is a corrupt file.
pub const MAX_TRANSLATION_MM: f64 = 10.0;
/// The largest angular error or squareness a model may hold, rad (5.7 degrees).
pub const MAX_ANGLE_RAD: f64 = 0.1;

/// `value` (in the model's mm or rad) inside +/-`limit`, else an error at the field.
fn within(
    line: usize,
    (col, text): (usize, &str),
    value: f64,
    limit: f64,
    what: &str,
    unit: &str,
) -> Result<(), VolFileError> {
    if value.abs() <= limit {
        return Ok(());
    }
    Err(err(
        line,
        col,
        format!("{what}: `{text}` is {value} {unit}, beyond any machine (at most {limit} {unit})"),
    ))
}

fn expect_len(line: usize, f: &[(usize, &str)], n: usize, what: &str) -> Result<(), VolFileError> {
    if f.len() != n {
        let col = f.last().map(|x| x.0).unwrap_or(1);
        return Err(err(
            line,
            col,
            format!("{what}: expected {n} fields, found {}", f.len()),
        ));
    }
    Ok(())
}

/// Reads a model file.
pub fn parse_model(text: &str) -> Result<VolumetricFile, VolFileError> {
    let mut structure = None;
    let mut units: Option<(f64, f64)> = None;
    let mut tool = None;
    let mut work = None;
    let mut squareness = None;
    let mut fit = None;
    let mut tables: [Option<AxisTable>; 3] = [None, None, None];
    let mut current: Option<usize> = None;
    let mut last_line = 0;
    for (i, raw) in text.lines().enumerate() {
        let ln = i + 1;
        last_line = ln;
        let line = raw.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let f = fields(line);
        let key = f[0].1;
        let axis_header = AXES
            .iter()
            .position(|a| key.len() == 1 && key.starts_with(*a));
        if let Some(a) = axis_header {
            expect_len(ln, &f, 7, "axis table header")?;
            for (k, c) in COMPONENTS.iter().enumerate() {
                let want = format!("E{c}{}", AXES[a]);
                if !f[k + 1].1.eq_ignore_ascii_case(&want) {
                    return Err(err(
                        ln,
                        f[k + 1].0,
                        format!(
                            "column {}: expected `{want}`, found `{}`",
                            k + 2,
                            f[k + 1].1
                        ),
                    ));
                }
            }
            if tables[a].is_some() {
                return Err(err(ln, 1, format!("axis {} given twice", AXES[a])));
            }
            if units.is_none() {
                return Err(err(ln, 1, "the `units` row must come before the tables"));
            }
            tables[a] = Some(AxisTable::default());
            current = Some(a);
            continue;
        }
        if let Some(a) = current {
            if key.parse::<f64>().is_ok() || key.eq_ignore_ascii_case("nan") {
                let (ls, as_) = units.unwrap_or((1.0, 1.0));
                expect_len(ln, &f, 7, "table row")?;
                let mut v = [0.0; 7];
                for k in 0..7 {
                    v[k] = number(ln, f[k], if k == 0 { "position" } else { "error" })?;
                }
                let pos = v[0] * ls;
                within(ln, f[0], pos, MAX_POSITION_MM, "position", "mm")?;
                for k in 1..7 {
                    let (value, limit, unit) = if k < 4 {
                        (v[k] * ls, MAX_TRANSLATION_MM, "mm")
                    } else {
                        (v[k] * as_, MAX_ANGLE_RAD, "rad")
                    };
                    within(ln, f[k], value, limit, "error", unit)?;
                }
                let t = tables[a].as_mut().expect("current table exists");
                if let Some(&prev) = t.positions_mm.last() {
                    if pos == prev {
                        return Err(err(ln, f[0].0, format!("position {} duplicated", f[0].1)));
                    }
                    if pos < prev {
                        return Err(err(
                            ln,
                            f[0].0,
                            format!("position {} is below the previous row's: unsorted", f[0].1),
                        ));
                    }
                }
                t.positions_mm.push(pos);
                t.errors.push([
                    v[1] * ls,
                    v[2] * ls,
                    v[3] * ls,
                    v[4] * as_,
                    v[5] * as_,
                    v[6] * as_,
                ]);
                continue;
            }
        }
        match key.to_ascii_lowercase().as_str() {
            "structure" => {
                expect_len(ln, &f, 2, "structure")?;
                structure = Some(Structure::parse(f[1].1).ok_or_else(|| {
                    err(
                        ln,
                        f[1].0,
                        format!("unknown structure `{}` (FXYZ, XFYZ, XYFZ, XYZF)", f[1].1),
                    )
                })?);
            }
            "units" => {
                expect_len(ln, &f, 3, "units")?;
                let l = length_scale(f[1].1).ok_or_else(|| {
                    err(
                        ln,
                        f[1].0,
                        format!("length unit `{}`: expected mm or um", f[1].1),
                    )
                })?;
                let a = angle_scale(f[2].1).ok_or_else(|| {
                    err(
                        ln,
                        f[2].0,
                        format!("angle unit `{}`: expected rad, mrad or urad", f[2].1),
                    )
                })?;
                units = Some((l, a));
            }
            "tool_offset" | "work_offset" => {
                expect_len(ln, &f, 4, key)?;
                let Some((ls, _)) = units else {
                    return Err(err(ln, 1, "the `units` row must come before offsets"));
                };
                let mut o = [0.0; 3];
                for k in 0..3 {
                    o[k] = number(ln, f[k + 1], key)? * ls;
                    within(ln, f[k + 1], o[k], MAX_POSITION_MM, key, "mm")?;
                }
                if key.eq_ignore_ascii_case("tool_offset") {
                    tool = Some(o);
                } else {
                    work = Some(o);
                }
            }
            "squareness" => {
                expect_len(ln, &f, 7, "squareness")?;
                let Some((_, as_)) = units else {
                    return Err(err(ln, 1, "the `units` row must come before squareness"));
                };
                let mut s = [0.0; 3];
                for k in 0..3 {
                    if !f[1 + 2 * k].1.eq_ignore_ascii_case(SQUARENESS[k]) {
                        return Err(err(
                            ln,
                            f[1 + 2 * k].0,
                            format!("expected `{}`, found `{}`", SQUARENESS[k], f[1 + 2 * k].1),
                        ));
                    }
                    s[k] = number(ln, f[2 + 2 * k], SQUARENESS[k])? * as_;
                    within(ln, f[2 + 2 * k], s[k], MAX_ANGLE_RAD, SQUARENESS[k], "rad")?;
                }
                squareness = Some(s);
            }
            "fit" => {
                expect_len(ln, &f, 2, "fit")?;
                fit = Some(match f[1].1 {
                    "yes" => true,
                    "no" => false,
                    other => {
                        return Err(err(
                            ln,
                            f[1].0,
                            format!("fit `{other}`: expected yes or no"),
                        ))
                    }
                });
            }
            _ => {
                return Err(err(ln, f[0].0, format!("unknown row `{key}`")));
            }
        }
    }
    let end = last_line.max(1);
    let missing = |what: &str| err(end, 1, format!("missing `{what}` row"));
    let structure = structure.ok_or_else(|| missing("structure"))?;
    let tool_offset_mm = tool.ok_or_else(|| missing("tool_offset"))?;
    let work_offset_mm = work.ok_or_else(|| missing("work_offset"))?;
    let squareness_rad = squareness.ok_or_else(|| missing("squareness"))?;
    let fit = fit.unwrap_or(true);
    let mut out: [AxisTable; 3] = Default::default();
    for a in 0..3 {
        let t = tables[a]
            .take()
            .ok_or_else(|| err(end, 1, format!("missing axis {} table", AXES[a])))?;
        if t.positions_mm.len() < 2 {
            return Err(err(
                end,
                1,
                format!("axis {} table needs at least two rows", AXES[a]),
            ));
        }
        out[a] = t;
    }
    Ok(VolumetricFile {
        structure,
        tool_offset_mm,
        work_offset_mm,
        squareness_rad,
        fit,
        tables: out,
    })
}

/// Writes a model file (mm, rad; values in Rust's shortest round-trip form).
pub fn write_model(m: &VolumetricFile) -> String {
    let mut s = String::from("# volumetric error model (ISO 230-1 names)\n");
    s += &format!("structure,{}\nunits,mm,rad\n", m.structure);
    let o = m.tool_offset_mm;
    s += &format!("tool_offset,{},{},{}\n", o[0], o[1], o[2]);
    let o = m.work_offset_mm;
    s += &format!("work_offset,{},{},{}\n", o[0], o[1], o[2]);
    let q = m.squareness_rad;
    s += &format!(
        "squareness,{},{},{},{},{},{}\n",
        SQUARENESS[0], q[0], SQUARENESS[1], q[1], SQUARENESS[2], q[2]
    );
    s += &format!("fit,{}\n", if m.fit { "yes" } else { "no" });
    for a in 0..3 {
        s.push(AXES[a]);
        for c in COMPONENTS {
            s += &format!(",E{c}{}", AXES[a]);
        }
        s.push('\n');
        let t = &m.tables[a];
        for (p, e) in t.positions_mm.iter().zip(&t.errors) {
            s += &format!(
                "{p},{},{},{},{},{},{}\n",
                e[0], e[1], e[2], e[3], e[4], e[5]
            );
        }
    }
    s
}

/// The ISG names of the squareness constants (ISO 230-1 `E_C0Y` is ISG `C0Y`, ...).
pub const ISG_SQUARENESS: [&str; 3] = ["C0Y", "B0Z", "A0Z"];

/// The model's tables in the ISG CSV format of the ISG kernel's volumetric
/// compensation (Beckhoff TwinCAT 3 CNC TF5280, "ISG CSV format"): blocks separated by
/// a line holding `#` (the format's file break), each a header line naming the columns
/// (argument, then parameters) followed by its records, values separated by blanks,
/// comments starting `//`. The first block holds the position errors (the squareness
/// constants `C0Y B0Z A0Z`) and the tool's zero position `P0X P0Y P0Z`, one record;
/// then one block per axis, `X EXX EYX EZX EAX EBX ECX` and likewise for Y and Z.
/// Units as the format requires: parameter values mm and rad, arguments mm.
pub fn write_isg_csv(m: &VolumetricFile) -> String {
    let mut s = String::from(
        "// Volumetric compensation parameters, ISG CSV format (mm, rad; arguments mm)\n",
    );
    s += &format!(
        "// structure {}: workpiece axes {}; ISO 230-1 names without the E_ of squareness\n",
        m.structure,
        m.structure.work_chain().len()
    );
    s += &format!("{} P0X P0Y P0Z\n", ISG_SQUARENESS.join(" "));
    let q = m.squareness_rad;
    let t = m.tool_offset_mm;
    s += &format!("{} {} {} {} {} {}\n", q[0], q[1], q[2], t[0], t[1], t[2]);
    for a in 0..3 {
        s += "#\n";
        s.push(AXES[a]);
        for c in COMPONENTS {
            s += &format!(" E{c}{}", AXES[a]);
        }
        s.push('\n');
        let tab = &m.tables[a];
        for (p, e) in tab.positions_mm.iter().zip(&tab.errors) {
            s += &format!(
                "{p} {} {} {} {} {} {}\n",
                e[0], e[1], e[2], e[3], e[4], e[5]
            );
        }
    }
    s
}

/// The compensation list (`.lis`) that points the ISG kernel at `csv_name`: the logical
/// axis numbers of X, Y and Z (1, 2, 3 here: the machine's own must be put in), the
/// number of workpiece-side axes of the structure (`workpiece_axes`), the parameter
/// file and its format `ISG_CSV`, grid interpolation. Keys as in Beckhoff's published
/// example; the kinematic chain parameter is not written (its values are not published
/// in the pages we could check).
pub fn write_isg_lis(m: &VolumetricFile, csv_name: &str) -> String {
    let mut s = String::from("# Volumetric compensation list (ISG kernel / TF5280)\n");
    s += &format!("# structure {}\n", m.structure);
    s += &format!(
        "workpiece_axes           {}\n",
        m.structure.work_chain().len()
    );
    s += "X                        1\nY                        2\nZ                        3\n";
    s += "interpolation            GRID\n";
    s += &format!("file[0]                  {csv_name}\n");
    s += "file_format[0]           ISG_CSV\n";
    s
}

/// One instrument file: header keys, column names and runs of rows.
#[derive(Debug, Clone, PartialEq)]
pub struct InstrumentFile {
    pub meta: Vec<(String, String)>,
    pub columns: Vec<String>,
    /// Per run (in file order): rows of the columns after `run`.
    pub runs: Vec<Vec<Vec<f64>>>,
}

impl InstrumentFile {
    pub fn meta(&self, key: &str) -> Option<&str> {
        self.meta
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }
}

/// Reads an instrument file whose columns must be `run` then `expected` (exact names,
/// units included). Runs are numbered by the `run` column; positions (the first column
/// after `run`) strictly increase within a run and every run has the same positions.
pub fn parse_instrument(text: &str, expected: &[&str]) -> Result<InstrumentFile, VolFileError> {
    let mut meta = Vec::new();
    let mut columns: Option<Vec<String>> = None;
    let mut runs: Vec<(String, Vec<Vec<f64>>)> = Vec::new();
    let mut last_line = 0;
    for (i, raw) in text.lines().enumerate() {
        let ln = i + 1;
        last_line = ln;
        let line = raw.trim();
        if line.is_empty() {
            continue;
        }
        if let Some(rest) = line.strip_prefix('#') {
            if columns.is_none() {
                if let Some((k, v)) = rest.split_once(':') {
                    meta.push((k.trim().to_string(), v.trim().to_string()));
                }
            }
            continue;
        }
        let f = fields(line);
        let Some(cols) = &columns else {
            expect_len(ln, &f, expected.len() + 1, "column header")?;
            if f[0].1 != "run" {
                return Err(err(
                    ln,
                    f[0].0,
                    format!("expected `run`, found `{}`", f[0].1),
                ));
            }
            for (k, want) in expected.iter().enumerate() {
                let got = f[k + 1].1;
                if got != *want {
                    let unit_of = |s: &str| s.rsplit('_').next().unwrap_or("").to_string();
                    let stem = |s: &str| s.rsplit_once('_').map(|x| x.0.to_string());
                    let msg = if stem(got) == stem(want) {
                        format!(
                            "column `{got}`: wrong unit `{}`, expected `{}`",
                            unit_of(got),
                            unit_of(want)
                        )
                    } else {
                        format!("expected column `{want}`, found `{got}`")
                    };
                    return Err(err(ln, f[k + 1].0, msg));
                }
            }
            columns = Some(f.iter().skip(1).map(|x| x.1.to_string()).collect());
            continue;
        };
        expect_len(ln, &f, cols.len() + 1, "data row")?;
        let run = f[0].1.to_string();
        let mut row = Vec::with_capacity(cols.len());
        for k in 1..f.len() {
            row.push(number(ln, f[k], &cols[k - 1])?);
        }
        let idx = match runs.iter().position(|r| r.0 == run) {
            Some(i) => i,
            None => {
                runs.push((run, Vec::new()));
                runs.len() - 1
            }
        };
        let rows = &mut runs[idx].1;
        if let Some(prev) = rows.last() {
            if row[0] == prev[0] {
                return Err(err(ln, f[1].0, format!("position {} duplicated", f[1].1)));
            }
            if row[0] < prev[0] {
                return Err(err(
                    ln,
                    f[1].0,
                    format!("position {} below the previous row's: unsorted", f[1].1),
                ));
            }
        }
        if idx > 0 {
            let first = &runs[0].1;
            let k = runs[idx].1.len();
            if first.get(k).map(|r| r[0]) != Some(row[0]) {
                return Err(err(
                    ln,
                    f[1].0,
                    format!(
                        "run `{}`: position {} differs from the first run's",
                        f[0].1, f[1].1
                    ),
                ));
            }
        }
        runs[idx].1.push(row);
    }
    if columns.is_none() {
        return Err(err(last_line.max(1), 1, "no column header row"));
    }
    let n = runs.first().map(|r| r.1.len()).unwrap_or(0);
    if n < 2 {
        return Err(err(last_line.max(1), 1, "needs at least two positions"));
    }
    if let Some(r) = runs.iter().find(|r| r.1.len() != n) {
        return Err(err(
            last_line.max(1),
            1,
            format!(
                "run `{}` has {} positions, the first run {n}",
                r.0,
                r.1.len()
            ),
        ));
    }
    Ok(InstrumentFile {
        meta,
        columns: columns.unwrap_or_default(),
        runs: runs.into_iter().map(|r| r.1).collect(),
    })
}

/// Reads `squareness.csv`: header `name,value_urad,uncertainty_urad`, then one row per
/// squareness error (E_C0Y, E_B0Z, E_A0Z, any order, each once). Returns (value,
/// uncertainty) in rad, in [`SQUARENESS`] order.
pub fn parse_squareness(text: &str) -> Result<[(f64, f64); 3], VolFileError> {
    let mut header = false;
    let mut out: [Option<(f64, f64)>; 3] = [None; 3];
    let mut last_line = 0;
    for (i, raw) in text.lines().enumerate() {
        let ln = i + 1;
        last_line = ln;
        let line = raw.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let f = fields(line);
        if !header {
            let want = ["name", "value_urad", "uncertainty_urad"];
            expect_len(ln, &f, 3, "column header")?;
            for k in 0..3 {
                if f[k].1 != want[k] {
                    return Err(err(
                        ln,
                        f[k].0,
                        format!("expected column `{}`, found `{}`", want[k], f[k].1),
                    ));
                }
            }
            header = true;
            continue;
        }
        expect_len(ln, &f, 3, "squareness row")?;
        let k = SQUARENESS
            .iter()
            .position(|n| n.eq_ignore_ascii_case(f[0].1))
            .ok_or_else(|| err(ln, f[0].0, format!("unknown squareness `{}`", f[0].1)))?;
        if out[k].is_some() {
            return Err(err(ln, f[0].0, format!("{} given twice", SQUARENESS[k])));
        }
        let v = number(ln, f[1], "value_urad")?;
        let u = number(ln, f[2], "uncertainty_urad")?;
        if !(u > 0.0) {
            return Err(err(ln, f[2].0, "uncertainty must be positive"));
        }
        out[k] = Some((v * 1e-6, u * 1e-6));
    }
    let mut r = [(0.0, 0.0); 3];
    for k in 0..3 {
        r[k] =
            out[k].ok_or_else(|| err(last_line.max(1), 1, format!("missing {}", SQUARENESS[k])))?;
    }
    Ok(r)
}

/// Reads a points file: header `x_mm,y_mm,z_mm`, then one point per row.
pub fn parse_points(text: &str) -> Result<Vec<[f64; 3]>, VolFileError> {
    let mut header = false;
    let mut out = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let ln = i + 1;
        let line = raw.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let f = fields(line);
        expect_len(
            ln,
            &f,
            3,
            if header { "point row" } else { "column header" },
        )?;
        if !header {
            for (k, want) in ["x_mm", "y_mm", "z_mm"].iter().enumerate() {
                if f[k].1 != *want {
                    return Err(err(
                        ln,
                        f[k].0,
                        format!("expected column `{want}`, found `{}`", f[k].1),
                    ));
                }
            }
            header = true;
            continue;
        }
        out.push([
            number(ln, f[0], "x_mm")?,
            number(ln, f[1], "y_mm")?,
            number(ln, f[2], "z_mm")?,
        ]);
    }
    if !header {
        return Err(err(1, 1, "no `x_mm,y_mm,z_mm` header row"));
    }
    Ok(out)
}

/// Fuzz entry: neither parser may panic on any text.
pub fn fuzz_parse(text: &str) {
    if let Ok(m) = parse_model(text) {
        let again = parse_model(&write_model(&m)).expect("written model reads back");
        assert_eq!(again, m);
    }
    let _ = parse_instrument(text, &["position_mm", "E_XX_um"]);
    let _ = parse_squareness(text);
    let _ = parse_points(text);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> String {
        "# test\nstructure,xyfz\nunits,um,urad\ntool_offset,0,0,100000\nwork_offset,1000,0,0\n\
         squareness,E_C0Y,20,E_B0Z,-15,E_A0Z,10\nfit,yes\n\
         X,EXX,EYX,EZX,EAX,EBX,ECX\n0,0,0,0,0,0,0\n500000,25,-3,1,2,-8,3\n\
         Y,EXY,EYY,EZY,EAY,EBY,ECY\n0,0,0,0,0,0,0\n400000,1,2,3,4,5,6\n\
         Z,EXZ,EYZ,EZZ,EAZ,EBZ,ECZ\n0,0,0,0,0,0,0\n400000,1,2,3,4,5,6\n"
            .to_string()
    }

    #[test]
    fn isg_csv_has_the_documented_blocks() {
        let m = VolumetricFile {
            structure: Structure::Xyfz,
            tool_offset_mm: [0.0, 0.0, 100.0],
            work_offset_mm: [0.0; 3],
            squareness_rad: [2e-5, -1.5e-5, 1e-5],
            fit: true,
            tables: [
                AxisTable {
                    positions_mm: vec![0.0, 250.0],
                    errors: vec![[0.0; 6], [0.005, -0.001, 0.0, 1e-6, 0.0, -2e-6]],
                },
                AxisTable {
                    positions_mm: vec![0.0, 10.5],
                    errors: vec![[0.0; 6]; 2],
                },
                AxisTable {
                    positions_mm: vec![0.0, 400.0],
                    errors: vec![[0.0; 6], [0.0, 0.0, 0.25, 0.0, 0.0, 0.0]],
                },
            ],
        };
        let csv = write_isg_csv(&m);
        let data: Vec<&str> = csv.lines().filter(|l| !l.starts_with("//")).collect();
        assert_eq!(
            data,
            [
                "C0Y B0Z A0Z P0X P0Y P0Z",
                "0.00002 -0.000015 0.00001 0 0 100",
                "#",
                "X EXX EYX EZX EAX EBX ECX",
                "0 0 0 0 0 0 0",
                "250 0.005 -0.001 0 0.000001 0 -0.000002",
                "#",
                "Y EXY EYY EZY EAY EBY ECY",
                "0 0 0 0 0 0 0",
                "10.5 0 0 0 0 0 0",
                "#",
                "Z EXZ EYZ EZZ EAZ EBZ ECZ",
                "0 0 0 0 0 0 0",
                "400 0 0 0.25 0 0 0",
            ]
        );
        let lis = write_isg_lis(&m, "volcomp.csv");
        assert!(lis.contains("workpiece_axes           2\n"), "{lis}");
        assert!(lis
            .contains("file[0]                  volcomp.csv\nfile_format[0]           ISG_CSV\n"));
    }

    #[test]
    fn reads_units_and_round_trips() {
        let m = parse_model(&sample()).unwrap();
        assert_eq!(m.structure, Structure::Xyfz);
        assert_eq!(m.tool_offset_mm, [0.0, 0.0, 100.0]);
        assert_eq!(m.work_offset_mm, [1.0, 0.0, 0.0]);
        assert!((m.squareness_rad[0] - 20e-6).abs() < 1e-18);
        assert_eq!(m.tables[0].positions_mm, vec![0.0, 500.0]);
        assert!((m.tables[0].errors[1][0] - 0.025).abs() < 1e-15);
        assert!((m.tables[0].errors[1][4] + 8e-6).abs() < 1e-18);
        let again = parse_model(&write_model(&m)).unwrap();
        assert_eq!(again, m);
    }

    #[test]
    fn values_beyond_any_machine_are_refused_at_their_field() {
        // In the file's units (um, urad): an error of 20 mm, an angle of 0.2 rad, a
        // position 20 m out, a squareness of 1 rad.
        for (from, to, at) in [
            ("500000,25,-3", "500000,20000000,-3", "line 10, column 8"),
            (
                "400000,1,2,3,4,5,6\nZ",
                "400000,1,2,3,200000,5,6\nZ",
                "line 13",
            ),
            ("500000,25", "20000000,25", "line 10, column 1"),
            ("E_C0Y,20,", "E_C0Y,1000000,", "line 6"),
        ] {
            let s = sample().replace(from, to);
            assert_ne!(s, sample(), "{from}");
            let e = parse_model(&s).unwrap_err().to_string();
            assert!(e.contains(at) && e.contains("beyond any machine"), "{e}");
        }
    }

    #[test]
    fn refusals_name_line_and_column() {
        let s = sample().replace("500000,25", "0,25");
        let e = parse_model(&s).unwrap_err();
        assert_eq!((e.line, e.column), (10, 1), "{e}");
        assert!(e.message.contains("duplicated"));
        let s = sample().replace("400000,1,2,3,4,5,6\nZ", "-5,1,2,3,4,5,6\nZ");
        let e = parse_model(&s).unwrap_err();
        assert!(e.message.contains("unsorted"), "{e}");
        assert_eq!(e.line, 13);
        let s = sample().replace("units,um,urad", "units,in,urad");
        let e = parse_model(&s).unwrap_err();
        assert_eq!((e.line, e.column), (3, 7), "{e}");
        let s = sample().replace("500000,25,-3", "500000,25,NaN");
        let e = parse_model(&s).unwrap_err();
        assert_eq!((e.line, e.column), (10, 11), "{e}");
        let cut = sample();
        let cut = &cut[..cut.find("Z,EXZ").unwrap()];
        let e = parse_model(cut).unwrap_err();
        assert!(e.message.contains("missing axis Z"), "{e}");
    }

    #[test]
    fn instrument_files_check_units_runs_and_order() {
        let cols = ["position_mm", "E_XX_um"];
        let ok = "# instrument: laser\n# axis: X\nrun,position_mm,E_XX_um\n1,0,0\n1,10,1.5\n2,0,0.1\n2,10,1.4\n";
        let f = parse_instrument(ok, &cols).unwrap();
        assert_eq!(f.meta("axis"), Some("X"));
        assert_eq!(f.runs.len(), 2);
        assert_eq!(f.runs[1][1], vec![10.0, 1.4]);
        let e = parse_instrument(&ok.replace("E_XX_um", "E_XX_mm"), &cols).unwrap_err();
        assert_eq!((e.line, e.column), (3, 17));
        assert!(e.message.contains("wrong unit"), "{e}");
        let e = parse_instrument(&ok.replace("1,10,1.5", "1,0,1.5"), &cols).unwrap_err();
        assert_eq!((e.line, e.column), (5, 3));
        let e = parse_instrument(&ok.replace("2,10,1.4", "2,12,1.4"), &cols).unwrap_err();
        assert!(e.message.contains("differs"), "{e}");
    }

    #[test]
    fn points_file() {
        let p = parse_points("x_mm,y_mm,z_mm\n1,2,3\n\n4.5, 5 ,6\n").unwrap();
        assert_eq!(p, vec![[1.0, 2.0, 3.0], [4.5, 5.0, 6.0]]);
        let e = parse_points("x_mm,y_mm,z_mm\n1,2,x\n").unwrap_err();
        assert_eq!((e.line, e.column), (2, 5));
        assert!(parse_points("x,y,z\n").is_err());
    }

    #[test]
    fn squareness_file_reads_and_refuses() {
        let ok = "name,value_urad,uncertainty_urad\nE_B0Z,-3,2\nE_C0Y,12.5,2\nE_A0Z,1,2\n";
        let r = parse_squareness(ok).unwrap();
        assert!((r[0].0 - 12.5e-6).abs() < 1e-18 && (r[1].0 + 3e-6).abs() < 1e-18);
        let e = parse_squareness(&ok.replace("E_A0Z,1,2\n", "")).unwrap_err();
        assert!(e.message.contains("missing E_A0Z"), "{e}");
        let e = parse_squareness(&ok.replace("-3,2", "-3,inf")).unwrap_err();
        assert_eq!((e.line, e.column), (2, 10), "{e}");
    }
}

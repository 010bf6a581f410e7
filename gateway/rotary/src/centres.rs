//! The centres file: ball centres measured elsewhere (a CMM, as in the paper) or written
//! by `gateway rotary measure`.
//!
//! Comma-separated, one header line naming exactly these columns in this order, then one
//! row per centre (blank lines and lines starting with `#` are skipped; no quoting):
//!
//! ```text
//! axis,step,angle_deg,ball,x_mm,y_mm,z_mm
//! C,0,0,1,-55.0015,0.0009,-260.0
//! ```
//!
//! `axis` is `C` (the C sweep, at A = 0) or `A` (the A sweep, at C = 0); `step` counts
//! from 0 within the sweep; `ball` is 1 (the 26 mm ball) or 2 (the 41 mm ball);
//! coordinates are machine coordinates in mm. One row per (axis, step, ball).

use protocol::text::escape_bytes;
use serde::Serialize;
use std::collections::HashMap;
use std::fmt;

/// The rotary axis a sweep turned.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
pub enum Axis {
    A,
    C,
}

impl fmt::Display for Axis {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Axis::A => "A",
            Axis::C => "C",
        })
    }
}

/// One measured centre.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct CentreRow {
    pub axis: Axis,
    pub step: u32,
    pub angle_deg: f64,
    pub ball: u8,
    pub x_mm: f64,
    pub y_mm: f64,
    pub z_mm: f64,
}

/// The largest coordinate a fit takes, mm (10 m): beyond any machine a probe or a CMM
/// measures on. Points past it (or not finite) are refused before the linear algebra,
/// whose iterations need not end on such input (a centre of 1e308 looped the SVD).
pub const MAX_COORDINATE_MM: f64 = 10_000.0;

/// The header the file must start with.
pub const HEADER: &str = "axis,step,angle_deg,ball,x_mm,y_mm,z_mm";

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CentresError {
    #[error("line {line}: expected the header `{HEADER}`, found `{found}`")]
    Header { line: usize, found: String },
    #[error("no header line (`{HEADER}`)")]
    NoHeader,
    #[error("line {line}: {n} fields, expected 7 ({HEADER})")]
    FieldCount { line: usize, n: usize },
    #[error("line {line}, column {column} ({name}): `{found}` {why}")]
    Field {
        line: usize,
        column: usize,
        name: &'static str,
        found: String,
        why: &'static str,
    },
    #[error(
        "line {line}: a second row for axis {axis} step {step} ball {ball} (first on line {first})"
    )]
    Duplicate {
        line: usize,
        axis: Axis,
        step: u32,
        ball: u8,
        first: usize,
    },
    #[error("no rows after the header")]
    Empty,
}

const NAMES: [&str; 7] = ["axis", "step", "angle_deg", "ball", "x_mm", "y_mm", "z_mm"];

/// Reads a centres file's text; errors name the line (from 1) and the column (from 1).
pub fn parse_centres(text: &str) -> Result<Vec<CentreRow>, CentresError> {
    let mut rows: Vec<CentreRow> = Vec::new();
    let mut seen: HashMap<(Axis, u32, u8), usize> = HashMap::new();
    let mut header_seen = false;
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let trimmed = raw.trim();
        if trimmed.is_empty() || trimmed.starts_with('#') {
            continue;
        }
        if !header_seen {
            let cols: Vec<&str> = trimmed.split(',').map(str::trim).collect();
            if cols != NAMES {
                return Err(CentresError::Header {
                    line,
                    found: escape_bytes(trimmed.as_bytes()),
                });
            }
            header_seen = true;
            continue;
        }
        let fields: Vec<&str> = trimmed.split(',').map(str::trim).collect();
        if fields.len() != 7 {
            return Err(CentresError::FieldCount {
                line,
                n: fields.len(),
            });
        }
        let bad = |column: usize, why: &'static str| CentresError::Field {
            line,
            column,
            name: NAMES[column - 1],
            found: escape_bytes(fields[column - 1].as_bytes()),
            why,
        };
        let axis = match fields[0] {
            "A" | "a" => Axis::A,
            "C" | "c" => Axis::C,
            _ => return Err(bad(1, "is not an axis (A or C)")),
        };
        let step: u32 = fields[1]
            .parse()
            .map_err(|_| bad(2, "is not a step number (0, 1, ...)"))?;
        let number = |column: usize, limit: f64, why: &'static str| match fields[column - 1]
            .parse::<f64>()
        {
            Ok(v) if v.is_finite() && v.abs() <= limit => Ok(v),
            Ok(v) if v.is_finite() => Err(bad(column, why)),
            _ => Err(bad(column, "is not a finite number")),
        };
        let coordinate = |column: usize| {
            number(
                column,
                MAX_COORDINATE_MM,
                "is outside any machine (at most 10 000 mm from zero)",
            )
        };
        let angle_deg = number(3, 360.0, "is not an angle of a sweep (-360 to 360 degrees)")?;
        let ball = match fields[3] {
            "1" => 1,
            "2" => 2,
            _ => return Err(bad(4, "is not a ball (1 or 2)")),
        };
        let row = CentreRow {
            axis,
            step,
            angle_deg,
            ball,
            x_mm: coordinate(5)?,
            y_mm: coordinate(6)?,
            z_mm: coordinate(7)?,
        };
        if let Some(first) = seen.insert((axis, step, ball), line) {
            return Err(CentresError::Duplicate {
                line,
                axis,
                step,
                ball,
                first,
            });
        }
        rows.push(row);
    }
    if !header_seen {
        return Err(CentresError::NoHeader);
    }
    if rows.is_empty() {
        return Err(CentresError::Empty);
    }
    Ok(rows)
}

/// Writes rows in the same format (round trip with [`parse_centres`]).
pub fn write_centres(rows: &[CentreRow]) -> String {
    let mut out = String::from(HEADER);
    out.push('\n');
    for r in rows {
        out.push_str(&format!(
            "{},{},{},{},{:.6},{:.6},{:.6}\n",
            r.axis, r.step, r.angle_deg, r.ball, r.x_mm, r.y_mm, r.z_mm
        ));
    }
    out
}

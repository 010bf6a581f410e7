//! The measurements file: one row per measured deviation, with a header row naming the
//! columns `axis,position_index,target_mm,run,direction,deviation_um` (in any order;
//! further columns, such as an interferometer's timestamp, are ignored):
//!
//! ```text
//! axis,position_index,target_mm,run,direction,deviation_um
//! X,1,10.000,1,+,-2.310
//! X,1,10.000,1,-,1.020
//! ```
//!
//! `position_index` i and `run` j count from 1; `direction` is `+` (↑, approached
//! moving in the positive direction) or `-` (↓); `deviation_um` is actual minus target
//! (x_ij = P_ij - P_i), micrometres; `target_mm` is P_i in millimetres. One axis per
//! file. The reader refuses, naming the line (the header is line 1): a missing column, a
//! value that is not a number (or not a positive integer for i and j), a direction other
//! than `+`/`-`, a row repeating (i, j, direction), a position whose rows disagree on the
//! target or two positions on one target, another axis; then, naming the position and its
//! lines: a position without one of the directions or with fewer than 5 runs in one, and
//! fewer than 5 positions in all.

use crate::{Direction, Measurement, MIN_POSITIONS, MIN_RUNS};
use std::collections::BTreeMap;

pub const COLUMNS: [&str; 6] = [
    "axis",
    "position_index",
    "target_mm",
    "run",
    "direction",
    "deviation_um",
];

/// The largest target position taken, mm: 100 m, beyond any machine's travel.
pub const MAX_TARGET_MM: f64 = 100_000.0;
/// The largest deviation taken, um: 100 mm, beyond anything a positioning test measures
/// (a figure past it is a unit or transcription error, and would only wreck the charts).
pub const MAX_DEVIATION_UM: f64 = 100_000.0;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CsvError {
    #[error("line {line}: {message}")]
    Syntax { line: u64, message: String },
    #[error("the header (line 1) has no `{0}` column; expected axis,position_index,target_mm,run,direction,deviation_um")]
    MissingColumn(&'static str),
    #[error("line {line}, column {column}: `{value}` {why}")]
    Field {
        line: u64,
        column: &'static str,
        value: String,
        why: &'static str,
    },
    #[error("line {line} repeats position {position_index}, run {run}, direction {} of line {first_line}", direction.sign())]
    Duplicate {
        line: u64,
        first_line: u64,
        position_index: usize,
        run: usize,
        direction: Direction,
    },
    #[error("line {line}: position {position_index} has target {target_mm} mm here but {first_target_mm} mm on line {first_line}")]
    TargetMismatch {
        line: u64,
        first_line: u64,
        position_index: usize,
        target_mm: f64,
        first_target_mm: f64,
    },
    #[error("line {line}: position {position_index} has the target {target_mm} mm of position {other_index} (line {first_line})")]
    SharedTarget {
        line: u64,
        first_line: u64,
        position_index: usize,
        other_index: usize,
        target_mm: f64,
    },
    #[error("line {line}: axis `{axis}` differs from `{first_axis}` on line {first_line}; one axis per file")]
    MixedAxes {
        line: u64,
        first_line: u64,
        axis: String,
        first_axis: String,
    },
    #[error("no measurement rows")]
    Empty,
    #[error("position {position_index} (lines {lines}) has no runs in the {} direction", direction.sign())]
    MissingDirection {
        position_index: usize,
        direction: Direction,
        lines: String,
    },
    #[error("position {position_index}, direction {} (lines {lines}): {found} runs; ISO 230-2 needs at least {MIN_RUNS}", direction.sign())]
    TooFewRuns {
        position_index: usize,
        direction: Direction,
        found: usize,
        lines: String,
    },
    #[error("{found} target positions in the file; ISO 230-2 needs at least {MIN_POSITIONS}")]
    TooFewPositions { found: usize },
}

fn lines_list(lines: &[u64]) -> String {
    lines
        .iter()
        .map(u64::to_string)
        .collect::<Vec<_>>()
        .join(", ")
}

/// Read and check a measurements file.
pub fn read(text: &str) -> Result<Vec<Measurement>, CsvError> {
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(true)
        .trim(csv::Trim::All)
        .from_reader(text.as_bytes());
    let headers = reader
        .headers()
        .map_err(|e| CsvError::Syntax {
            line: 1,
            message: e.to_string(),
        })?
        .clone();
    let mut col = [0usize; 6];
    for (k, name) in COLUMNS.iter().enumerate() {
        col[k] = headers
            .iter()
            .position(|h| h.eq_ignore_ascii_case(name))
            .ok_or(CsvError::MissingColumn(name))?;
    }
    let mut out: Vec<Measurement> = Vec::new();
    let mut seen: BTreeMap<(usize, usize, Direction), u64> = BTreeMap::new();
    let mut targets: BTreeMap<usize, (f64, u64)> = BTreeMap::new();
    // Per position and direction: the lines of its runs.
    let mut runs: BTreeMap<(usize, Direction), Vec<u64>> = BTreeMap::new();
    let mut first_axis: Option<(String, u64)> = None;
    let mut record = csv::StringRecord::new();
    loop {
        let line = reader.position().line();
        match reader.read_record(&mut record) {
            Ok(true) => {}
            Ok(false) => break,
            Err(e) => {
                let line = e.position().map_or(line, |p| p.line());
                return Err(CsvError::Syntax {
                    line,
                    message: e.to_string(),
                });
            }
        }
        let line = record.position().map_or(line, |p| p.line());
        if record.iter().all(str::is_empty) {
            continue;
        }
        let field = |k: usize| record.get(col[k]).unwrap_or("");
        let bad = |k: usize, why| CsvError::Field {
            line,
            column: COLUMNS[k],
            value: field(k).to_string(),
            why,
        };
        let axis = field(0).to_string();
        if axis.is_empty() {
            return Err(bad(0, "is empty: expected the axis name"));
        }
        let index = |k: usize| match field(k).parse::<usize>() {
            Ok(v) if v >= 1 => Ok(v),
            _ => Err(bad(k, "is not a whole number from 1 up")),
        };
        let number = |k: usize, limit: f64, why: &'static str| match field(k).parse::<f64>() {
            Ok(v) if v.is_finite() && v.abs() <= limit => Ok(v),
            Ok(v) if v.is_finite() => Err(bad(k, why)),
            _ => Err(bad(k, "is not a number")),
        };
        let position_index = index(1)?;
        let target_mm = number(
            2,
            MAX_TARGET_MM,
            "is outside any machine's travel (at most 100 000 mm from zero)",
        )?;
        let run = index(3)?;
        let direction = match field(4) {
            "+" => Direction::Up,
            "-" => Direction::Down,
            _ => return Err(bad(4, "is not a direction: expected + or -")),
        };
        let deviation_um = number(
            5,
            MAX_DEVIATION_UM,
            "is not a positioning deviation (at most 100 000 um, 100 mm, either way)",
        )?;
        match &first_axis {
            None => first_axis = Some((axis.clone(), line)),
            Some((a, first_line)) if *a != axis => {
                return Err(CsvError::MixedAxes {
                    line,
                    first_line: *first_line,
                    axis,
                    first_axis: a.clone(),
                })
            }
            Some(_) => {}
        }
        if let Some(&first_line) = seen.get(&(position_index, run, direction)) {
            return Err(CsvError::Duplicate {
                line,
                first_line,
                position_index,
                run,
                direction,
            });
        }
        match targets.get(&position_index) {
            Some(&(t, first_line)) if t != target_mm => {
                return Err(CsvError::TargetMismatch {
                    line,
                    first_line,
                    position_index,
                    target_mm,
                    first_target_mm: t,
                })
            }
            Some(_) => {}
            None => {
                if let Some((&other_index, &(_, first_line))) =
                    targets.iter().find(|(_, (t, _))| *t == target_mm)
                {
                    return Err(CsvError::SharedTarget {
                        line,
                        first_line,
                        position_index,
                        other_index,
                        target_mm,
                    });
                }
                targets.insert(position_index, (target_mm, line));
            }
        }
        seen.insert((position_index, run, direction), line);
        runs.entry((position_index, direction))
            .or_default()
            .push(line);
        out.push(Measurement {
            axis,
            position_index,
            target_mm,
            run,
            direction,
            deviation_um,
        });
    }
    if out.is_empty() {
        return Err(CsvError::Empty);
    }
    for &position_index in targets.keys() {
        for direction in [Direction::Up, Direction::Down] {
            match runs.get(&(position_index, direction)) {
                None => {
                    let other = match direction {
                        Direction::Up => Direction::Down,
                        Direction::Down => Direction::Up,
                    };
                    return Err(CsvError::MissingDirection {
                        position_index,
                        direction,
                        lines: lines_list(&runs[&(position_index, other)]),
                    });
                }
                Some(l) if l.len() < MIN_RUNS => {
                    return Err(CsvError::TooFewRuns {
                        position_index,
                        direction,
                        found: l.len(),
                        lines: lines_list(l),
                    })
                }
                Some(_) => {}
            }
        }
    }
    if targets.len() < MIN_POSITIONS {
        return Err(CsvError::TooFewPositions {
            found: targets.len(),
        });
    }
    Ok(out)
}

/// Write measurements in the file's format (targets to 0.1 um, deviations to 1 nm).
pub fn write(measurements: &[Measurement]) -> String {
    let mut w = csv::Writer::from_writer(Vec::new());
    // Writing to memory cannot fail.
    let _ = w.write_record(COLUMNS);
    for m in measurements {
        let _ = w.write_record([
            m.axis.clone(),
            m.position_index.to_string(),
            format!("{:.4}", m.target_mm),
            m.run.to_string(),
            m.direction.sign().to_string(),
            format!("{:.3}", m.deviation_um),
        ]);
    }
    String::from_utf8(w.into_inner().unwrap_or_default()).unwrap_or_default()
}

//! A 3-axis G-code program rewritten through a compensation (an error map or a
//! volumetric model) so every move lands where it was programmed: the program text in,
//! the rewritten program as an artifact ([`PROGRAM_ARTIFACT`]), the report as the result.
//! (The 5-axis rewrite for a rotary table is `rotary`'s.)

use crate::command_line::{self, FileArg};
use crate::request::{number, RequestError};
use crate::{Artifact, Outcome, Sink};
use errormap::MapModel;
use protocol::errormap::ErrorMap;
use protocol::grbl::response::Response;
use rewrite::{Compensation, Limits, Options, Pose, Rewriter, N_AXIS};
use serde::{Deserialize, Serialize};
use std::fmt::Write;
use std::time::Instant;

/// The rewritten program's artifact.
pub const PROGRAM_ARTIFACT: &str = "program.nc";

/// The largest program accepted (the bounded reader's limit for a data file).
pub const MAX_PROGRAM_BYTES: usize = 16 << 20;

/// A program file's text for a [`RewriteRequest`], read as a bounded stream of lines
/// ([`protocol::config::open_lines`]: regular files only, refused before opening, at
/// most [`MAX_PROGRAM_BYTES`] in all and 64 KiB per line; line endings kept). Errors name
/// the file and the line.
pub fn read_program(path: &std::path::Path) -> Result<String, crate::Error> {
    let lines =
        protocol::config::open_lines(path, protocol::config::DataKind::Program)?.keep_endings();
    let mut text = String::new();
    for line in lines {
        let (n, l) = line?;
        if text.len() + l.len() > MAX_PROGRAM_BYTES {
            return Err(crate::Error::Refused(format!(
                "program {}: line {n}: the program passes {} MiB, the most a rewrite takes",
                path.display(),
                MAX_PROGRAM_BYTES >> 20
            )));
        }
        text.push_str(&l);
    }
    Ok(text)
}

/// A saved `$#` reply's text, bounded ([`protocol::config::DataKind::Parameters`]).
pub fn read_offsets_file(path: &std::path::Path) -> Result<String, crate::Error> {
    Ok(protocol::config::read_kind(
        path,
        protocol::config::DataKind::Parameters,
    )?)
}

/// The largest `$#` reply accepted.
pub const MAX_OFFSETS_BYTES: usize = 1 << 20;

/// The largest rewritten program: a move is split into at most 2^16 pieces, so a fine
/// tolerance on a long program could otherwise grow without end; the rewrite stops
/// (naming the line) when its output passes this.
pub const MAX_OUTPUT_BYTES: usize = 256 << 20;

/// The largest machine coordinate accepted in `start` and `limits`, mm.
pub const MAX_COORDINATE_MM: f64 = 1e6;

fn default_tolerance() -> f64 {
    0.5
}
fn default_max_correction() -> f64 {
    200.0
}

fn default_program_name() -> String {
    "program.nc".into()
}

/// A program rewrite. On the command line its flags are these fields (the files, the
/// program and `$#` reply, are read into them by the front end); none of them applies to
/// the 5-axis `--rotary` rewrite, so each conflicts with it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields)]
pub struct RewriteRequest {
    /// The program's text (G-code for GRBL 1.1).
    #[schema(format = Binary, max_length = 67108864)]
    #[cfg_attr(feature = "cli", arg(skip))]
    pub program: String,
    /// How messages name the program (its file name).
    #[serde(default = "default_program_name")]
    #[schema(default = default_program_name)]
    #[cfg_attr(feature = "cli", arg(skip = default_program_name()))]
    pub program_name: String,
    /// Apply the map as scanned, without its recorded reference (the reference after
    /// the last homing, MAP.reference.json written by `gateway reference`).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, requires = "map"))]
    pub no_reference: bool,
    /// Largest distance of the executed path from the compensated path, um.
    #[serde(default = "default_tolerance")]
    #[schema(default = default_tolerance, minimum = 0.01, maximum = 1000.0)]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_tolerance()))]
    pub tolerance_um: f64,
    /// Largest correction accepted at any point, um.
    #[serde(default = "default_max_correction")]
    #[schema(default = default_max_correction, minimum = 0.001, maximum = 100000.0)]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_max_correction(), conflicts_with = "rotary"))]
    pub max_correction_um: f64,
    /// The controller's reply to `$#` (its `[G54:x,y,z]` ... `[G59:...]` lines).
    #[serde(default)]
    #[schema(format = Binary)]
    #[cfg_attr(feature = "cli", arg(skip))]
    pub offsets: Option<String>,
    /// Machine position when the program starts, `[x, y]` or `[x, y, z]` mm (else the
    /// first moves must name every compensated axis). Command line: `X,Y[,Z]`.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, value_parser = pose_mm, conflicts_with = "rotary"))]
    pub start: Option<::std::vec::Vec<f64>>,
    /// Soft limits, `[[xmin, xmax], [ymin, ymax]]` and optionally `[zmin, zmax]`,
    /// machine mm (Z unbounded when left out). Command line:
    /// `XMIN:XMAX,YMIN:YMAX[,ZMIN:ZMAX]`.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, value_parser = limits_mm, conflicts_with = "rotary"))]
    pub limits: Option<::std::vec::Vec<[f64; 2]>>,
    /// A volumetric model file's text (`volumetric identify`'s): X, Y and Z corrected
    /// by it instead of by the machine's error map.
    #[serde(default)]
    #[schema(format = Binary)]
    #[cfg_attr(feature = "cli", arg(skip))]
    pub volumetric: Option<String>,
    /// How messages name the volumetric model (its file name).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(skip))]
    pub volumetric_name: Option<String>,
    /// The program's dialect: `grbl` (GRBL 1.1) or `linuxcnc` (RS274/NGC, LinuxCNC
    /// 2.9: parameters, expressions, O-word subroutines and loops expanded, canned
    /// cycles G81/G82/G85/G89 expanded, the rest refused naming the line; `offsets` is
    /// then LinuxCNC's parameter file, its `.var`). See docs/compensation.md.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value_t = Dialect::Grbl, conflicts_with = "rotary"))]
    #[schema(inline)]
    pub dialect: Dialect,
}

/// The dialect a program is read in.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Dialect {
    /// GRBL 1.1 G-code (and grblHAL).
    #[default]
    Grbl,
    /// LinuxCNC's RS274/NGC.
    Linuxcnc,
}

/// `X,Y[,Z]` (mm) as numbers (a command-line value); the count and the bounds are the
/// request's to check.
#[cfg(feature = "cli")]
pub fn pose_mm(text: &str) -> Result<Vec<f64>, String> {
    text.split(',')
        .map(|p| p.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("`{text}`: expected X,Y or X,Y,Z in mm"))
}

/// `XMIN:XMAX,YMIN:YMAX[,ZMIN:ZMAX]` (mm) as ranges (a command-line value); the count and
/// the bounds are the request's to check.
#[cfg(feature = "cli")]
pub fn limits_mm(text: &str) -> Result<Vec<[f64; 2]>, String> {
    let bad = || format!("`{text}`: expected XMIN:XMAX,YMIN:YMAX[,ZMIN:ZMAX] in mm");
    text.split(',')
        .map(|part| {
            let (a, b) = part.split_once(':').ok_or_else(bad)?;
            Ok([
                a.trim().parse().map_err(|_| bad())?,
                b.trim().parse().map_err(|_| bad())?,
            ])
        })
        .collect()
}

impl RewriteRequest {
    pub fn new(program: String) -> Self {
        Self {
            program,
            program_name: default_program_name(),
            no_reference: false,
            tolerance_um: default_tolerance(),
            max_correction_um: default_max_correction(),
            offsets: None,
            start: None,
            limits: None,
            volumetric: None,
            volumetric_name: None,
            dialect: Dialect::Grbl,
        }
    }

    pub fn check(&self) -> Result<(), RequestError> {
        if let Some(text) = &self.volumetric {
            let most = crate::volumetric::MAX_FILE_BYTES;
            if text.len() > most {
                return Err(RequestError::new(
                    "volumetric",
                    format!("{} bytes; at most {most} are accepted", text.len()),
                ));
            }
        }
        self.options().map(|_| ())
    }

    /// The rewriter's options, every field checked (the field named).
    pub fn options(&self) -> Result<Options, RequestError> {
        if self.program.len() > MAX_PROGRAM_BYTES {
            return Err(RequestError::new(
                "program",
                format!(
                    "{} bytes; at most {MAX_PROGRAM_BYTES} are accepted",
                    self.program.len()
                ),
            ));
        }
        // The rewriter's own floor: 0.01 um.
        number("tolerance_um", self.tolerance_um, 0.01, 1000.0)?;
        number("max_correction_um", self.max_correction_um, 1e-3, 1e5)?;
        let start = start_point(self.start.as_deref())?;
        let limits = match &self.limits {
            Some(v) => {
                if !(2..=N_AXIS).contains(&v.len()) {
                    return Err(RequestError::new(
                        "limits",
                        format!(
                            "expected XMIN:XMAX,YMIN:YMAX[,ZMIN:ZMAX] in mm, got {} ranges",
                            v.len()
                        ),
                    ));
                }
                let mut limits = Limits {
                    min: [f64::NEG_INFINITY; N_AXIS],
                    max: [f64::INFINITY; N_AXIS],
                };
                for (k, [a, b]) in v.iter().enumerate() {
                    let field = format!("limits[{k}]");
                    number(&field, *a, -MAX_COORDINATE_MM, MAX_COORDINATE_MM)?;
                    number(&field, *b, -MAX_COORDINATE_MM, MAX_COORDINATE_MM)?;
                    if a >= b {
                        return Err(RequestError::new(
                            field,
                            format!("{a}:{b}: the minimum must be below the maximum"),
                        ));
                    }
                    limits.min[k] = *a;
                    limits.max[k] = *b;
                }
                Some(limits)
            }
            None => None,
        };
        let (work_offsets, g92_offset) = match (&self.offsets, self.dialect) {
            (Some(text), Dialect::Grbl) => read_parameters(text)?,
            (Some(text), Dialect::Linuxcnc) => {
                protocol::ngc::read_var_file(text).map_err(|e| {
                    RequestError::new("offsets", format!("LinuxCNC parameter file: {e}"))
                })?;
                ([[0.0; N_AXIS]; 6], [0.0; N_AXIS])
            }
            (None, _) => ([[0.0; N_AXIS]; 6], [0.0; N_AXIS]),
        };
        Ok(Options {
            tolerance_mm: self.tolerance_um / 1000.0,
            max_correction_mm: self.max_correction_um / 1000.0,
            limits,
            start,
            work_offsets,
            g92_offset,
        })
    }
}

/// Where the machine is when a program starts (`start`: X,Y or X,Y,Z in mm), checked.
pub fn start_point(start: Option<&[f64]>) -> Result<Option<Pose>, RequestError> {
    let Some(v) = start else {
        return Ok(None);
    };
    if !(2..=N_AXIS).contains(&v.len()) {
        return Err(RequestError::new(
            "start",
            format!("expected X,Y or X,Y,Z in mm, got {} numbers", v.len()),
        ));
    }
    let mut p = [0.0; N_AXIS];
    for (k, c) in v.iter().enumerate() {
        number(
            &format!("start[{k}]"),
            *c,
            -MAX_COORDINATE_MM,
            MAX_COORDINATE_MM,
        )?;
        p[k] = *c;
    }
    Ok(Some(p))
}

/// The stored work offsets from a saved `$#` reply (`[G54:x,y,z]` lines); other lines
/// are ignored, a malformed offset line is an error naming it (field `offsets`).
pub fn read_offsets(text: &str) -> Result<[Pose; 6], RequestError> {
    read_parameters(text).map(|(offsets, _)| offsets)
}

/// The largest work or G92 offset taken from a `$#` reply, mm (a controller's travel is
/// far smaller; 1e308 is a corrupted reply, not an offset).
pub const MAX_OFFSET_MM: f64 = 1e5;

/// A saved `$#` reply: the stored G54..G59 offsets and the G92 offset (`[G92:x,y,z]`;
/// a reply without any of these seven lines is refused as cut), as GRBL applies them: the machine position of
/// a programmed point is the point plus the active work offset plus G92. A malformed or
/// repeated offset line, or a value beyond [`MAX_OFFSET_MM`], is an error naming the
/// line (field `offsets`).
pub fn read_parameters(text: &str) -> Result<([Pose; 6], Pose), RequestError> {
    if text.len() > MAX_OFFSETS_BYTES {
        return Err(RequestError::new(
            "offsets",
            format!(
                "{} bytes; a `$#` reply has at most {MAX_OFFSETS_BYTES}",
                text.len()
            ),
        ));
    }
    let mut offsets = [[0.0; N_AXIS]; 7];
    let mut seen = 0;
    let mut first_line = [0usize; 7];
    for (n, line) in text.lines().enumerate() {
        if let Response::Parameter { name, value } = Response::parse(line.trim()) {
            let Some(k) = ["G54", "G55", "G56", "G57", "G58", "G59", "G92"]
                .iter()
                .position(|g| *g == name)
            else {
                continue;
            };
            if first_line[k] != 0 {
                return Err(RequestError::new(
                    "offsets",
                    format!(
                        "line {}: a second {name} line (the first on line {})",
                        n + 1,
                        first_line[k]
                    ),
                ));
            }
            first_line[k] = n + 1;
            let values: Vec<f64> = value
                .split(',')
                .map(|v| v.trim().parse::<f64>())
                .collect::<Result<_, _>>()
                .ok()
                .filter(|v: &Vec<f64>| {
                    v.len() == N_AXIS && v.iter().all(|x| x.is_finite() && x.abs() <= MAX_OFFSET_MM)
                })
                .ok_or_else(|| {
                    RequestError::new(
                        "offsets",
                        format!(
                            "line {}: `{}` is not {name} with {N_AXIS} numbers of at most {MAX_OFFSET_MM} mm",
                            n + 1,
                            protocol::text::escape_bytes(line.as_bytes())
                        ),
                    )
                })?;
            offsets[k].copy_from_slice(&values);
            if k < 6 {
                seen += 1;
            }
        }
    }
    if seen == 0 {
        return Err(RequestError::new(
            "offsets",
            "no [G54:...] line (save the controller's reply to `$#`)",
        ));
    }
    // GRBL and grblHAL answer `$#` with every work system and G92: a reply without one
    // is cut or damaged, and reading the missing offset as zero would move the tool.
    let names = ["G54", "G55", "G56", "G57", "G58", "G59", "G92"];
    let missing: Vec<&str> = (0..7)
        .filter(|&k| first_line[k] == 0)
        .map(|k| names[k])
        .collect();
    if !missing.is_empty() {
        return Err(RequestError::new(
            "offsets",
            format!(
                "the `$#` reply has no {} line{}: it is cut or damaged (save the whole reply)",
                missing.join(", "),
                if missing.len() > 1 { "s" } else { "" }
            ),
        ));
    }
    let mut stored = [[0.0; N_AXIS]; 6];
    stored.copy_from_slice(&offsets[..6]);
    Ok((stored, offsets[6]))
}

/// A program rewritten: what went in and out, and what the compensation did.
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
pub struct RewriteResult {
    /// The program as the request names it (its file name).
    pub input: String,
    /// The rewritten program's artifact ([`PROGRAM_ARTIFACT`]; the CLI: its `--out`).
    pub output: String,
    /// The compensation in one line (the map or model, its extent).
    pub compensation: String,
    /// The chord tolerance, um.
    pub tolerance_um: f64,
    /// Lines of the program (LinuxCNC: blocks run).
    pub input_lines: usize,
    /// Lines of the rewritten program.
    pub output_lines: usize,
    /// Moves whose commands were corrected.
    pub moves_compensated: usize,
    /// Lines added by splitting moves and turning arcs into chords.
    pub segments_added: usize,
    /// Largest |command - nominal| over the compensated axes, um.
    pub largest_correction_um: f64,
    /// Line of that largest correction.
    pub largest_correction_line: usize,
    /// Whether the controller's work offsets were given.
    pub offsets_given: bool,
    /// What is worth telling that did not stop the rewrite, by line.
    #[schema(inline)]
    pub notes: Vec<LineNote>,
    /// How long the rewrite took, s.
    pub elapsed_s: f64,
    /// The controller's language.
    #[schema(inline)]
    pub dialect: Dialect,
    /// The reference the map applied under (null: a volumetric model or a map as
    /// scanned without one asked for).
    #[schema(inline)]
    pub reference: Option<ReferenceUsed>,
}

/// A note on one line of a program.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct LineNote {
    /// The line, from 1.
    pub line: usize,
    pub note: String,
}

impl LineNote {
    pub fn of(n: &rewrite::Note) -> Self {
        Self {
            line: n.line,
            note: n.text.clone(),
        }
    }
}

/// Which reference a map applied under, as a result says it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ReferenceUsed {
    /// Which reference and how old, in one line (also the program's first line).
    pub describe: String,
    /// What applying none costs, when none is recorded.
    pub warning: Option<String>,
    /// The record applied (null: none).
    #[schema(inline)]
    pub record: Option<crate::reference::AppliedReference>,
}

/// The compensation a program is rewritten with.
pub enum RewriteModel {
    /// An error map as scanned (no reference, no header line).
    Map(ErrorMap),
    /// An error map under its current reference ([`crate::reference::choose`]): the
    /// program's first line is a `;` comment saying which reference and how old it is.
    ReferencedMap {
        map: ErrorMap,
        reference: crate::reference::Choice,
    },
    /// A volumetric model and how messages name it (a file, a profile).
    Volumetric {
        model: volumetric::Model,
        name: String,
    },
}

/// Rewrites the program (`source` names it in messages): the rewritten program goes to
/// the sink as [`PROGRAM_ARTIFACT`] only when every line was rewritten. The result:
/// [`RewriteResult`] (`input` is `source`).
pub fn run(
    request: &RewriteRequest,
    model: RewriteModel,
    source: &str,
    now: std::time::SystemTime,
    sink: &mut dyn Sink,
) -> Outcome<RewriteResult> {
    let options = match request.options() {
        Ok(o) => o,
        Err(e) => return Outcome::failed(e.to_string()),
    };
    let mut header = None;
    let mut reference = None;
    let compensation: Box<dyn Compensation> = match model {
        RewriteModel::Map(map) => Box::new(MapModel::new(map)),
        RewriteModel::ReferencedMap { map, reference: r } => {
            let applied = match crate::reference::apply(map, &r, now) {
                Ok(a) => a,
                Err(e) => return Outcome::failed(e),
            };
            header = Some(format!("; gateway: {}", applied.describe));
            reference = Some(ReferenceUsed {
                describe: applied.describe,
                warning: applied.warning,
                record: applied.record,
            });
            Box::new(applied.model)
        }
        RewriteModel::Volumetric { model, name } => {
            if !model.file.fit {
                return Outcome::failed(format!(
                    "{name}: the model is marked unfit for compensation (its residuals exceed the instruments' uncertainty)"
                ));
            }
            Box::new(model)
        }
    };
    let started = Instant::now();
    let rewritten = match request.dialect {
        Dialect::Grbl => rewrite_bounded(
            &request.program,
            compensation.as_ref(),
            options,
            MAX_OUTPUT_BYTES,
        ),
        Dialect::Linuxcnc => rewrite_linuxcnc(request, compensation.as_ref(), &options),
    };
    let (mut out, report) = match rewritten {
        Ok(r) => r,
        Err(e) => return Outcome::failed(format!("{source}: {e}")),
    };
    if let Some(h) = header {
        // The reference the program was compensated for, ahead of its first line.
        let ending = if request.program.contains("\r\n") {
            "\r\n"
        } else {
            "\n"
        };
        out.insert_str(0, &format!("{h}{ending}"));
    }
    let elapsed_s = started.elapsed().as_secs_f64();
    if let Err(e) = sink.artifact(Artifact {
        name: PROGRAM_ARTIFACT.into(),
        title: None,
        media_type: "text/x-gcode",
        bytes: out.into_bytes(),
    }) {
        return Outcome::failed(e);
    }
    let result = RewriteResult {
        input: source.into(),
        output: PROGRAM_ARTIFACT.into(),
        compensation: compensation.describe(),
        tolerance_um: request.tolerance_um,
        input_lines: report.input_lines,
        output_lines: report.output_lines,
        moves_compensated: report.moves_compensated,
        segments_added: report.segments_added,
        largest_correction_um: report.largest_correction_um,
        largest_correction_line: report.largest_correction_line,
        offsets_given: request.offsets.is_some(),
        notes: report.notes.iter().map(LineNote::of).collect(),
        elapsed_s,
        dialect: request.dialect,
        reference,
    };
    let metrics = [
        ("moves_compensated", result.moves_compensated.into()),
        ("segments_added", result.segments_added.into()),
        ("largest_correction_um", result.largest_correction_um.into()),
    ];
    let metrics = metrics.into_iter().map(|(k, v)| (k.into(), v)).collect();
    Outcome::succeeded(result, metrics)
}

/// A LinuxCNC program ([`rewrite::ngc`]) with the request's options and its parameter
/// file; the report in the GRBL rewrite's terms (lines in: the blocks run).
fn rewrite_linuxcnc(
    request: &RewriteRequest,
    compensation: &dyn Compensation,
    options: &Options,
) -> Result<(String, rewrite::Report), crate::Error> {
    let start = match &request.offsets {
        Some(text) => protocol::ngc::read_var_file(text)
            .map_err(|e| crate::Error::Refused(format!("LinuxCNC parameter file: {e}")))?,
        None => protocol::ngc::Start::default(),
    };
    let ngc = rewrite::ngc::NgcOptions {
        tolerance_mm: options.tolerance_mm,
        max_correction_mm: options.max_correction_mm,
        limits: options.limits,
        position: options.start,
        start,
        max_output_bytes: MAX_OUTPUT_BYTES,
        ..Default::default()
    };
    let (out, r) = rewrite::ngc::rewrite_ngc(&request.program, compensation, &ngc)
        .map_err(|e| crate::Error::Refused(e.to_string()))?;
    let report = rewrite::Report {
        input_lines: protocol::nc::split_lines(&request.program).count(),
        output_lines: r.output_lines,
        moves_compensated: r.moves_compensated,
        segments_added: r.segments_added,
        largest_correction_um: r.largest_correction_um,
        largest_correction_line: r.largest_correction_line,
        notes: r.notes,
        ..Default::default()
    };
    Ok((out, report))
}

/// `rewrite::rewrite_program`, line by line, stopped when the output passes `cap` bytes
/// ([`MAX_OUTPUT_BYTES`]).
fn rewrite_bounded(
    text: &str,
    compensation: &dyn Compensation,
    options: Options,
    cap: usize,
) -> Result<(String, rewrite::Report), crate::Error> {
    // A line the controller would refuse, or a correction past its bound: nothing is
    // written.
    let refused = |e: rewrite::RewriteError| crate::Error::Refused(e.to_string());
    let mut rewriter = Rewriter::new(compensation, options).map_err(refused)?;
    let mut out = String::with_capacity(text.len() + text.len() / 4);
    for (index, (line, ending)) in protocol::nc::split_lines(text).enumerate() {
        let ending = match ending {
            protocol::nc::LineEnding::None => "\n",
            e => e.as_str(),
        };
        for piece in rewriter.line(line, index + 1).map_err(refused)? {
            out.push_str(&piece);
            out.push_str(ending);
        }
        if out.len() > cap {
            return Err(crate::Error::Refused(format!(
                "line {}: the rewritten program passes {} bytes, the most accepted (a larger tolerance gives fewer pieces)",
                index + 1,
                cap
            )));
        }
    }
    if !text.ends_with(['\n', '\r']) && out.ends_with('\n') {
        out.pop();
    }
    Ok((out, rewriter.into_report()))
}

/// The report as text (`input` and `output` as the front end left them).
pub fn summary(r: &RewriteResult) -> String {
    let mut t = String::new();
    let _ = writeln!(t, "{} -> {} with {}", r.input, r.output, r.compensation);
    let _ = writeln!(
        t,
        "{} lines in, {} out: {} moves corrected, {} segments added; largest correction {:.2} um (line {}); tolerance {} um; {:.3} s",
        r.input_lines,
        r.output_lines,
        r.moves_compensated,
        r.segments_added,
        r.largest_correction_um,
        r.largest_correction_line,
        r.tolerance_um,
        r.elapsed_s
    );
    if let Some(reference) = &r.reference {
        let _ = writeln!(t, "map {}", reference.describe);
        if let Some(w) = &reference.warning {
            let _ = writeln!(t, "warning: {w}");
        }
    }
    if !r.offsets_given && r.dialect == Dialect::Linuxcnc {
        let _ = writeln!(t, "work offsets: none given (--offsets FILE with LinuxCNC's parameter file, its .var); G54 and G92 are taken as zero");
    } else if !r.offsets_given {
        let _ = writeln!(t, "work offsets: none given (--offsets FILE with the controller's `$#` reply); the program's coordinates are taken as machine coordinates");
    }
    for n in &r.notes {
        let _ = writeln!(t, "line {}: {}", n.line, n.note);
    }
    t
}

/// A program rewritten with the error map (under its current reference unless the
/// request says `no_reference`) as a registered procedure. When the context knows the
/// machine (the CLI's `--config`, the service's machine), the map must have been
/// measured on it.
pub struct Rewrite;

impl crate::registry::Procedure for Rewrite {
    const KIND: &'static str = "rewrite";
    const TITLE: &'static str =
        "Rewrite a program: every move lands where it was programmed, without the camera";
    const COMMAND: &'static str = "rewrite";
    const LABEL: &'static str = "Program rewrite";
    const HELP: &'static str = "Rewrites a G-code program with the active error map (or a volumetric model) so that every move lands where it was programmed; download the rewritten program and run it on the machine. What the controller would refuse is refused here first, naming the line.";
    const FIELD_HELP: &'static [(&'static str, &'static str)] = &[
        ("program", "The program to rewrite, as the controller reads it."),
        ("dialect", "The controller's language: grbl (GRBL 1.1) or linuxcnc (LinuxCNC 2.9, RS274/NGC, with its subroutines and loops written out)."),
        ("no_reference", "Use the map as scanned, without the machine zero recorded after the last homing."),
        ("offsets", "The controller's work offsets: for GRBL its answer to $# saved as a file, for LinuxCNC its parameter file (.var). Empty: the program's coordinates are taken as machine coordinates."),
        ("start", "Where the machine stands when the program starts, X; Y (or X; Y; Z) in mm. Empty: the first moves must name every axis."),
        ("limits", "The machine's travel, to refuse a corrected move outside it. Empty: the controller's own soft limits apply."),
        ("volumetric", "A volumetric model file: X, Y and Z corrected by it instead of by the error map."),
    ];
    const USES: crate::registry::Uses = crate::registry::Uses {
        map: crate::registry::MapUse::WhenAsked,
        ..crate::registry::Uses::NOTHING
    };
    type Request = RewriteRequest;
    type Result = RewriteResult;
    const FILES: &'static [FileArg] = &[
        FileArg::positional("input", "The program to rewrite (never overwritten).", |path, plan| {
            plan.text(path, "program", Some("program_name"), read_program)
        }),
        FileArg::flag(
            "map",
            "The error map (a version file written by `gateway map`).",
            command_line::map,
        )
        .conflicts(&["volumetric"]),
        FileArg::flag(
            "config",
            "With --map: the job of the machine the program is for; the map is refused unless it was measured on that machine, controller, board and camera.",
            command_line::job,
        )
        .requires(&["map"]),
        FileArg::flag(
            "volumetric",
            "A volumetric model file (`gateway volumetric identify`): X, Y and Z corrected.",
            |path, plan| {
                plan.text(path, "volumetric", Some("volumetric_name"), crate::volumetric::read_file)
            },
        ),
        FileArg::required("out", "The rewritten program (never over an input).", |path, plan| {
            plan.artifacts.push((PROGRAM_ARTIFACT.into(), path.to_path_buf()));
            Ok(())
        }),
        FileArg::flag(
            "offsets",
            "The controller's `$#` reply saved to a file: its G54..G59 offsets.",
            |path, plan| plan.text(path, "offsets", None, read_offsets_file),
        ),
        FileArg::flag(
            "rotary",
            "The location errors of an A/C tilting table: a 5-axis program (X Y Z A C) rewritten so the tool tip and direction land where programmed; the same as `gateway rotary rewrite INPUT --errors FILE` (with its --machine and --force-machine).",
            |_, _| Err(crate::Error::Input("--rotary is `gateway rotary rewrite --errors`".into())),
        )
        .conflicts(&["map", "volumetric", "offsets", "config"]),
    ];

    /// The machine's map, unless a volumetric model is given.
    fn uses_map(request: &RewriteRequest) -> bool {
        request.volumetric.is_none()
    }

    async fn run(request: RewriteRequest, cx: &mut dyn crate::Context) -> Outcome<RewriteResult> {
        if let Some(text) = &request.volumetric {
            // A volumetric model is not a map: the same rewrite, another compensation.
            let name = request
                .volumetric_name
                .as_deref()
                .unwrap_or("volumetric model");
            let model = RewriteModel::Volumetric {
                model: crate::or_fail!(crate::volumetric::read_model(name, text)),
                name: name.to_string(),
            };
            let now = cx.now();
            let program = request.program_name.clone();
            return run(&request, model, &program, now, cx.sink());
        }
        let (map, reference) =
            crate::or_fail!(crate::reference::active_map(cx, request.no_reference).await);
        let model = RewriteModel::ReferencedMap { map, reference };
        let now = cx.now();
        let name = request.program_name.clone();
        run(&request, model, &name, now, cx.sink())
    }

    fn summary(result: &RewriteResult) -> String {
        summary(result)
    }
}

impl crate::registry::Checked for RewriteRequest {
    fn check(&self) -> Result<(), RequestError> {
        RewriteRequest::check(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::volumetric::Structure;

    use crate::Collect as Keep;

    /// 10 um of X error per 100 mm of X.
    fn model() -> volumetric::Model {
        let mut m = volumetric::Model::zero(Structure::Xyfz, [500.0, 400.0, 400.0]);
        m.file.tables[0].errors[1][0] = 0.050;
        m
    }

    #[test]
    fn bounds_are_named() {
        let mut r = RewriteRequest::new("G0 X1\n".into());
        r.tolerance_um = f64::NAN;
        assert_eq!(r.check().unwrap_err().flag(), "--tolerance-um");
        r.tolerance_um = 0.001;
        assert_eq!(r.check().unwrap_err().field, "tolerance_um");
        r.tolerance_um = 0.5;
        r.max_correction_um = 0.0;
        assert_eq!(r.check().unwrap_err().field, "max_correction_um");
        r.max_correction_um = 200.0;
        r.start = Some(vec![1.0]);
        assert_eq!(r.check().unwrap_err().field, "start");
        r.start = Some(vec![1.0, f64::INFINITY]);
        assert_eq!(
            r.check().unwrap_err().for_cli().split(':').next(),
            Some("--start")
        );
        r.start = None;
        r.limits = Some(vec![[0.0, 10.0], [5.0, 5.0]]);
        assert_eq!(r.check().unwrap_err().field, "limits[1]");
        r.limits = None;
        r.offsets = Some("[G54:1,2]\nok\n".into());
        let e = r.check().unwrap_err();
        assert_eq!(e.field, "offsets");
        assert!(e.message.starts_with("line 1: "), "{e}");
        r.offsets = Some("ok\n".into());
        assert!(r.check().unwrap_err().message.contains("no [G54:...] line"));
        r.offsets = Some("[G54:1,2,3]\n[G55:0,0,0]\nok\n".into());
        let e = r.check().unwrap_err();
        assert!(
            e.message.contains("no G56, G57, G58, G59, G92 lines"),
            "{e}"
        );
        let full = "[G55:0,0,0]\n[G56:0,0,0]\n[G57:0,0,0]\n[G58:0,0,0]\n[G59:0,0,0]\n";
        r.offsets = Some(format!("[G54:1,2,3]\n{full}[G92:0,0,0]\nok\n"));
        assert_eq!(r.options().unwrap().work_offsets[0], [1.0, 2.0, 3.0]);
        r.offsets = Some("[G54:1,2,3]\n[G92:1e308,0,0]\nok\n".into());
        let e = r.check().unwrap_err();
        assert!(e.message.starts_with("line 2: `[G92:1e308,0,0]`"), "{e}");
        r.offsets = Some("[G54:1,2,3]\n[G54:1,2,3]\n".into());
        assert!(r.check().unwrap_err().message.contains("a second G54 line"));
        r.program = "G0 X0\n".repeat(MAX_PROGRAM_BYTES / 6 + 1);
        assert_eq!(r.check().unwrap_err().field, "program");
    }

    /// The `$#` reply's `[G92:...]` line shifts the program as on the controller: X10
    /// with G54 X5 and G92 X20 is machine X35, and it is corrected as machine X35 (the
    /// model's X error is 0.1 um per mm of X), written back in the program's frame.
    #[test]
    fn the_g92_offset_of_the_dollar_hash_reply_is_honoured() {
        let mut r = RewriteRequest::new("G21 G90\nG0 X10 Y0 Z0\n".into());
        r.offsets = Some(
            "[G54:5.000,0.000,0.000]\n[G55:0,0,0]\n[G56:0,0,0]\n[G57:0,0,0]\n[G58:0,0,0]\n\
             [G59:0,0,0]\n[G92:20.000,0.000,0.000]\n[TLO:0.000]\nok\n"
                .into(),
        );
        let o = r.options().unwrap();
        assert_eq!(o.g92_offset, [20.0, 0.0, 0.0]);
        let run_with = |r: &RewriteRequest| {
            let mut sink = Keep::default();
            let out = run(
                r,
                RewriteModel::Volumetric {
                    model: model(),
                    name: "m".into(),
                },
                "in.nc",
                std::time::SystemTime::now(),
                &mut sink,
            );
            assert!(out.is_success(), "{:?}", out.error());
            String::from_utf8(sink.0[0].bytes.clone()).unwrap()
        };
        let with_g92 = run_with(&r);
        r.offsets = r.offsets.map(|o| o.replace("[G92:20.000", "[G92:0.000"));
        let without = run_with(&r);
        // The correction at machine X35 (3.5 um) differs from that at X15 (1.5 um).
        assert!(with_g92.contains("X10.0035 "), "{with_g92}");
        assert!(without.contains("X10.0015 "), "{without}");
    }

    #[test]
    fn a_program_through_a_volumetric_model() {
        let mut r = RewriteRequest::new("G21 G90\nG0 X0 Y0 Z0\nG1 X100 F500\n".into());
        r.start = Some(vec![0.0, 0.0, 0.0]);
        let mut sink = Keep::default();
        let m = RewriteModel::Volumetric {
            model: model(),
            name: "m.vol.csv".into(),
        };
        let out = run(&r, m, "in.nc", std::time::SystemTime::now(), &mut sink);
        assert!(out.is_success(), "{:?}", out.error());
        let res = out.result.unwrap();
        assert_eq!(res.input, "in.nc");
        assert_eq!(res.input_lines, 3);
        assert!(res.largest_correction_um > 9.0, "{res:?}");
        assert_eq!(sink.0.len(), 1);
        assert_eq!(sink.0[0].name, PROGRAM_ARTIFACT);
        let text = String::from_utf8(sink.0[0].bytes.clone()).unwrap();
        assert!(text.starts_with("G21 G90\n"), "{text}");
        assert!(summary(&res).contains("in.nc -> program.nc with volumetric model"));
        // An unfit model is refused, nothing produced; a refused line is named.
        let mut unfit = model();
        unfit.file.fit = false;
        let mut sink = Keep::default();
        let out = run(
            &r,
            RewriteModel::Volumetric {
                model: unfit,
                name: "m.vol.csv".into(),
            },
            "in.nc",
            std::time::SystemTime::now(),
            &mut sink,
        );
        assert!(out
            .error()
            .unwrap()
            .starts_with("m.vol.csv: the model is marked unfit"));
        assert!(sink.0.is_empty());
        r.program = "G0 X0 Y0 Z0\nG1 X900 F500\n".into();
        let out = run(
            &r,
            RewriteModel::Volumetric {
                model: model(),
                name: "m".into(),
            },
            "in.nc",
            std::time::SystemTime::now(),
            &mut sink,
        );
        assert!(
            out.error().unwrap().starts_with("in.nc: line 2"),
            "{:?}",
            out.error()
        );
        assert!(sink.0.is_empty());
    }

    /// A LinuxCNC program: its loop expanded, its parameter file's G54 applied, each
    /// move corrected (10 um of X per 100 mm of X); what reads the machine is refused
    /// naming the line.
    #[test]
    fn a_linuxcnc_program_in_its_dialect() {
        let program = "G21\n#1 = 100\nG0 X0 Y0 Z0\no1 repeat [2]\n  G91 G1 X[#1 / 2] F500\no1 endrepeat\nM2\n";
        let mut r = RewriteRequest::new(program.into());
        r.dialect = Dialect::Linuxcnc;
        r.offsets = Some("5220 1\n5221 100.0\n5222 0\n5223 0\n".into());
        let go = |r: &RewriteRequest| {
            let mut sink = Keep::default();
            let m = RewriteModel::Volumetric {
                model: model(),
                name: "m".into(),
            };
            let out = run(r, m, "in.ngc", std::time::SystemTime::now(), &mut sink);
            (out, sink)
        };
        let (out, sink) = go(&r);
        assert!(out.is_success(), "{:?}", out.error());
        let text = String::from_utf8(sink.0[0].bytes.clone()).unwrap();
        // X0 is machine X100 (G54): 10 um; X50 machine 150: 15 um; X100: 20 um.
        assert!(text.contains("G0 X0.01 Y0 Z0\n"), "{text}");
        assert!(text.contains("X50.015"), "{text}");
        assert!(text.contains("X100.02"), "{text}");
        assert_eq!(out.result.unwrap().dialect, Dialect::Linuxcnc);
        r.program = "G21\nG0 X0 Y0 Z0\nG1 X#5420 F100\n".into();
        let (out, sink) = go(&r);
        let e = out.error().unwrap();
        assert!(
            e.starts_with("in.ngc: line 3: `G1 X#5420 F100`: #5420 is a system parameter"),
            "{e}"
        );
        assert!(sink.0.is_empty());
        r.offsets = Some("5221 x\n".into());
        assert_eq!(r.check().unwrap_err().field, "offsets");
    }

    #[test]
    fn the_output_is_bounded_as_it_grows() {
        let mut r = RewriteRequest::new("G0 X0 Y0 Z0\nG1 X100 F500\nG1 X0\n".into());
        r.tolerance_um = 0.01;
        let options = || r.options().unwrap();
        // E_XX zig-zags by 5 um every 10 mm: the moves are split at every corner.
        let mut wavy = model();
        let x = &mut wavy.file.tables[0];
        x.positions_mm = (0..=50).map(|k| k as f64 * 10.0).collect();
        x.errors = (0..=50)
            .map(|k| [0.005 * (k % 2) as f64, 0.0, 0.0, 0.0, 0.0, 0.0])
            .collect();
        let (whole, _) = rewrite_bounded(&r.program, &wavy, options(), usize::MAX).unwrap();
        assert!(whole.lines().count() > 20, "{}", whole.lines().count());
        let e = rewrite_bounded(&r.program, &wavy, options(), whole.len() / 2).unwrap_err();
        assert!(matches!(e, crate::Error::Refused(_)), "{e:?}");
        assert!(
            e.to_string()
                .starts_with("line 2: the rewritten program passes"),
            "{e}"
        );
    }
}

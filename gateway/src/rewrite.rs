//! `gateway rewrite`: a user's program rewritten with a compensation model.

use anyhow::Context;
use errormap::MapModel;
use protocol::errormap::ErrorMap;
use protocol::grbl::response::Response;
use rewrite::{rewrite_program, Compensation, Limits, Options, Pose, N_AXIS};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

/// What the command line gave.
pub struct RewriteArgs {
    pub input: PathBuf,
    pub out: PathBuf,
    pub map: Option<PathBuf>,
    /// A volumetric model file (`gateway volumetric identify`).
    pub volumetric: Option<PathBuf>,
    pub tolerance_um: f64,
    pub max_correction_um: f64,
    pub offsets: Option<PathBuf>,
    pub start: Option<String>,
    pub limits: Option<String>,
    pub json: bool,
}

/// The stored work offsets from a saved `$#` reply (`[G54:x,y,z]` lines); other lines
/// are ignored, a malformed offset line is an error naming it.
pub fn read_offsets(path: &Path) -> anyhow::Result<[Pose; 6]> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let mut offsets = [[0.0; N_AXIS]; 6];
    let mut seen = 0;
    for (n, line) in text.lines().enumerate() {
        if let Response::Parameter { name, value } = Response::parse(line.trim()) {
            let Some(k) = ["G54", "G55", "G56", "G57", "G58", "G59"]
                .iter()
                .position(|g| *g == name)
            else {
                continue;
            };
            let values: Vec<f64> = value
                .split(',')
                .map(|v| v.trim().parse::<f64>())
                .collect::<Result<_, _>>()
                .ok()
                .filter(|v: &Vec<f64>| v.len() == N_AXIS && v.iter().all(|x| x.is_finite()))
                .with_context(|| {
                    format!(
                        "{} line {}: `{line}` is not {name} with {N_AXIS} numbers",
                        path.display(),
                        n + 1
                    )
                })?;
            offsets[k].copy_from_slice(&values);
            seen += 1;
        }
    }
    if seen == 0 {
        anyhow::bail!(
            "{}: no [G54:...] line (save the controller's reply to `$#`)",
            path.display()
        );
    }
    Ok(offsets)
}

/// `X,Y,Z` in mm (Z may be left out: 0).
fn parse_pose(what: &str, s: &str) -> anyhow::Result<Pose> {
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .ok()
        .filter(|v: &Vec<f64>| (2..=N_AXIS).contains(&v.len()) && v.iter().all(|x| x.is_finite()))
        .with_context(|| format!("{what} `{s}`: expected X,Y or X,Y,Z in mm"))?;
    let mut p = [0.0; N_AXIS];
    p[..v.len()].copy_from_slice(&v);
    Ok(p)
}

/// `XMIN:XMAX,YMIN:YMAX[,ZMIN:ZMAX]` in mm (Z unbounded when left out).
fn parse_limits(s: &str) -> anyhow::Result<Limits> {
    let bad = || anyhow::anyhow!("--limits `{s}`: expected XMIN:XMAX,YMIN:YMAX[,ZMIN:ZMAX] in mm");
    let parts: Vec<&str> = s.split(',').collect();
    if !(2..=N_AXIS).contains(&parts.len()) {
        return Err(bad());
    }
    let mut limits = Limits {
        min: [f64::NEG_INFINITY; N_AXIS],
        max: [f64::INFINITY; N_AXIS],
    };
    for (i, part) in parts.iter().enumerate() {
        let (a, b) = part.split_once(':').ok_or_else(bad)?;
        let (a, b): (f64, f64) = (
            a.trim().parse().map_err(|_| bad())?,
            b.trim().parse().map_err(|_| bad())?,
        );
        if !(a.is_finite() && b.is_finite() && a < b) {
            return Err(bad());
        }
        limits.min[i] = a;
        limits.max[i] = b;
    }
    Ok(limits)
}

pub fn rewrite(args: RewriteArgs) -> anyhow::Result<ExitCode> {
    if args.input == args.out {
        anyhow::bail!("--out is the input file: the rewrite never overwrites the program it reads");
    }
    let model: Box<dyn Compensation> = match (&args.map, &args.volumetric) {
        (Some(_), Some(_)) => anyhow::bail!("give one compensation: --map or --volumetric"),
        (Some(path), None) => Box::new(MapModel::new(ErrorMap::load(path)?)),
        (None, Some(path)) => {
            let m = crate::volumetric::load_model(path)?;
            if !m.file.fit {
                anyhow::bail!(
                    "{}: the model is marked unfit for compensation (its residuals exceed the instruments' uncertainty)",
                    path.display()
                );
            }
            Box::new(m)
        }
        (None, None) => {
            anyhow::bail!("give the compensation to apply: --map MAP or --volumetric MODEL")
        }
    };
    let options = Options {
        tolerance_mm: args.tolerance_um / 1000.0,
        max_correction_mm: args.max_correction_um / 1000.0,
        limits: args.limits.as_deref().map(parse_limits).transpose()?,
        start: args
            .start
            .as_deref()
            .map(|s| parse_pose("--start", s))
            .transpose()?,
        work_offsets: match &args.offsets {
            Some(p) => read_offsets(p)?,
            None => [[0.0; N_AXIS]; 6],
        },
    };
    let text = std::fs::read_to_string(&args.input)
        .with_context(|| format!("reading {}", args.input.display()))?;
    let started = Instant::now();
    let (out, report) = rewrite_program(&text, model.as_ref(), options)
        .with_context(|| format!("{}", args.input.display()))?;
    let elapsed_s = started.elapsed().as_secs_f64();
    // Written beside the target and renamed: a failed write never leaves half a program.
    let tmp = args.out.with_extension("rewrite-tmp");
    std::fs::write(&tmp, &out).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, &args.out).with_context(|| format!("writing {}", args.out.display()))?;
    let notes: Vec<_> = report
        .notes
        .iter()
        .map(|n| json!({ "line": n.line, "note": n.text }))
        .collect();
    if args.json {
        println!(
            "{}",
            json!({
                "input": args.input.display().to_string(), "output": args.out.display().to_string(),
                "compensation": model.describe(), "tolerance_um": args.tolerance_um,
                "input_lines": report.input_lines, "output_lines": report.output_lines,
                "moves_compensated": report.moves_compensated, "segments_added": report.segments_added,
                "largest_correction_um": report.largest_correction_um,
                "largest_correction_line": report.largest_correction_line,
                "offsets_given": args.offsets.is_some(), "notes": notes, "elapsed_s": elapsed_s,
            })
        );
    } else {
        println!(
            "{} -> {} with {}",
            args.input.display(),
            args.out.display(),
            model.describe()
        );
        println!(
            "{} lines in, {} out: {} moves corrected, {} segments added; largest correction {:.2} um (line {}); tolerance {} um; {:.3} s",
            report.input_lines,
            report.output_lines,
            report.moves_compensated,
            report.segments_added,
            report.largest_correction_um,
            report.largest_correction_line,
            args.tolerance_um,
            elapsed_s
        );
        if args.offsets.is_none() {
            println!("work offsets: none given (--offsets FILE with the controller's `$#` reply); the program's coordinates are taken as machine coordinates");
        }
        for n in &report.notes {
            println!("line {}: {}", n.line, n.text);
        }
    }
    Ok(ExitCode::SUCCESS)
}

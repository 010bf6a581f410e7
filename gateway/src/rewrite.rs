//! `gateway rewrite` (3-axis): flags to `procedure::rewrite`'s request, the program and
//! the `$#` reply read through the bounded reader, the rewritten program written
//! atomically to `--out` (never over an input).

use procedure::rewrite::{RewriteRequest, PROGRAM_ARTIFACT};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct RewriteArgs {
    /// The program to rewrite (never overwritten).
    pub input: PathBuf,
    /// The error map (a version file written by `gateway map`).
    #[arg(long)]
    pub map: Option<PathBuf>,
    /// With --map: the job of the machine the program is for; the map is refused
    /// unless it was measured on that machine, controller, board and camera.
    #[arg(long, requires = "map")]
    pub config: Option<PathBuf>,
    /// A volumetric model file (`gateway volumetric identify`): X, Y and Z corrected.
    #[arg(long)]
    pub volumetric: Option<PathBuf>,
    /// The location errors of an A/C tilting table (`gateway rotary identify` or
    /// `measure`): a 5-axis program (X Y Z A C) rewritten so the tool tip and
    /// direction land where programmed (the same rewrite as `gateway rotary rewrite`).
    #[arg(long)]
    pub rotary: Option<PathBuf>,
    /// With --rotary: the machine constants (JSON); default: those recorded in the
    /// errors file.
    #[arg(long, requires = "rotary")]
    pub machine: Option<PathBuf>,
    /// With --machine: use it even where it differs from the recorded constants.
    #[arg(long, requires = "machine")]
    pub force_machine: bool,
    #[arg(long)]
    pub out: PathBuf,
    /// With --map: apply the map as scanned, without its recorded reference
    /// (MAP.reference.json, written by `gateway reference` after a homing).
    #[arg(long, requires = "map")]
    pub no_reference: bool,
    /// Largest distance of the executed path from the compensated path, um.
    #[arg(long, default_value_t = 0.5)]
    pub tolerance_um: f64,
    /// Largest correction accepted at any point, um (default 200).
    #[arg(long)]
    pub max_correction_um: Option<f64>,
    /// The controller's `$#` reply saved to a file: its G54..G59 offsets.
    #[arg(long)]
    pub offsets: Option<PathBuf>,
    /// Machine position when the program starts, "X,Y[,Z]" mm (else the first
    /// moves must name every compensated axis).
    #[arg(long)]
    pub start: Option<String>,
    /// Soft limits, "XMIN:XMAX,YMIN:YMAX[,ZMIN:ZMAX]" machine mm.
    #[arg(long)]
    pub limits: Option<String>,
}

/// The program through the bounded line reader (64 KiB a line).
fn read(path: &Path) -> anyhow::Result<String> {
    procedure::rewrite::read_program(path).map_err(anyhow::Error::msg)
}

fn read_offsets(path: &Path) -> anyhow::Result<String> {
    procedure::rewrite::read_offsets_file(path).map_err(anyhow::Error::msg)
}

/// `X,Y[,Z]` (mm) as numbers; the count and the bounds are the request's.
fn parse_pose(s: &str) -> anyhow::Result<Vec<f64>> {
    s.split(',')
        .map(|p| p.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| anyhow::anyhow!("--start `{s}`: expected X,Y or X,Y,Z in mm"))
}

/// `XMIN:XMAX,YMIN:YMAX[,ZMIN:ZMAX]` (mm) as ranges; the count and the bounds are the
/// request's.
fn parse_limits(s: &str) -> anyhow::Result<Vec<[f64; 2]>> {
    let bad = || anyhow::anyhow!("--limits `{s}`: expected XMIN:XMAX,YMIN:YMAX[,ZMIN:ZMAX] in mm");
    s.split(',')
        .map(|part| {
            let (a, b) = part.split_once(':').ok_or_else(bad)?;
            Ok([
                a.trim().parse().map_err(|_| bad())?,
                b.trim().parse().map_err(|_| bad())?,
            ])
        })
        .collect()
}

pub fn rewrite(args: RewriteArgs, json: bool) -> anyhow::Result<ExitCode> {
    if let Some(errors) = args.rotary {
        // The 5-axis rewrite has its own program rules (absolute mm, no arcs); the
        // 3-axis options do not apply to it.
        let other = [
            (args.map.is_some(), "--map"),
            (args.volumetric.is_some(), "--volumetric"),
            (args.offsets.is_some(), "--offsets"),
            (args.start.is_some(), "--start"),
            (args.limits.is_some(), "--limits"),
            (args.max_correction_um.is_some(), "--max-correction-um"),
        ];
        if let Some((_, flag)) = other.iter().find(|(given, _)| *given) {
            anyhow::bail!(
                "--rotary rewrites a 5-axis program on its own; {flag} does not apply to it"
            );
        }
        return crate::rotary::run(
            crate::rotary::RotaryCmd::Rewrite {
                input: args.input,
                errors,
                out: args.out,
                machine: args.machine,
                force_machine: args.force_machine,
                tolerance_um: args.tolerance_um,
            },
            json,
        );
    }
    let mut request = RewriteRequest::new(read(&args.input)?);
    request.program_name = args.input.display().to_string();
    request.no_reference = args.no_reference;
    request.tolerance_um = args.tolerance_um;
    if let Some(m) = args.max_correction_um {
        request.max_correction_um = m;
    }
    request.offsets = args.offsets.as_deref().map(read_offsets).transpose()?;
    request.start = args.start.as_deref().map(parse_pose).transpose()?;
    request.limits = args.limits.as_deref().map(parse_limits).transpose()?;
    let inputs: Vec<&Path> = [
        Some(args.input.as_path()),
        args.map.as_deref(),
        args.config.as_deref(),
        args.volumetric.as_deref(),
        args.offsets.as_deref(),
    ]
    .into_iter()
    .flatten()
    .collect();
    let mut sink = crate::front::CliSink::new("", true)
        .inputs(&inputs)
        .artifact_to(PROGRAM_ARTIFACT, args.out.clone());
    if let Some(path) = &args.volumetric {
        request.volumetric =
            Some(procedure::volumetric::read_file(path).map_err(anyhow::Error::msg)?);
        request.volumetric_name = Some(path.display().to_string());
    }
    let kind = procedure::kinds::kind("rewrite")?;
    let mut outcome = match (&args.map, &args.volumetric) {
        (Some(_), Some(_)) => anyhow::bail!("give one compensation: --map or --volumetric"),
        (None, None) => {
            anyhow::bail!("give the compensation to apply: --map MAP or --volumetric MODEL")
        }
        (map, _) => crate::front::run_outcome(kind, &request, &mut sink, |f| {
            let f = f.input(&args.input);
            let f = match map {
                Some(map) => f.map_file(map),
                None => f,
            };
            match &args.config {
                Some(job) => f.job_file(job),
                None => f,
            }
        })?,
    };
    if let Some(r) = outcome.result.as_mut() {
        r["output"] = json!(args.out.display().to_string());
    }
    crate::front::print(&outcome, json, |r| kind.summary(r))
}

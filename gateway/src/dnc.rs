//! `gateway dnc`: a Fanuc program (and the controller's stored subprograms) read through
//! the bounded reader into `procedure::dnc`'s request, rewritten with the map and
//! drip-fed to the controller's tape port; `--out` keeps the tape sent (written
//! atomically, never over an input).

use procedure::dnc::{DncRequest, TAPE_ARTIFACT};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct DncArgs {
    /// The program (Fanuc dialect, ISO code; its subprograms after M30).
    pub input: PathBuf,
    /// The error map (a version file written by `gateway map`).
    #[arg(long)]
    pub map: Option<PathBuf>,
    /// Send the program without correction (the baseline); no map.
    #[arg(long, conflicts_with = "map")]
    pub uncompensated: bool,
    /// The job of the machine: its `[stage] driver = "dnc"` names the tape port, and
    /// the map is refused unless it was measured on that machine.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// The serial port wired to the controller's tape port (instead of the job's).
    #[arg(long)]
    pub port: Option<String>,
    /// With --port: the baud rate set on the controller.
    #[arg(long, default_value_t = 9600, requires = "port")]
    pub baud: u32,
    /// The subprograms stored in the controller that the program calls (M98).
    #[arg(long)]
    pub subprograms: Option<PathBuf>,
    /// Write the rewritten tape here (never over an input).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Only rewrite (with --out): send nothing.
    #[arg(long, requires = "out")]
    pub no_send: bool,
    /// With --map: apply the map as scanned, without its recorded reference.
    #[arg(long, requires = "map")]
    pub no_reference: bool,
    /// Largest distance of the executed path from the compensated path, um.
    #[arg(long, default_value_t = 0.5)]
    pub tolerance_um: f64,
    /// Machine position when the program starts, "X,Y[,Z]" mm.
    #[arg(long)]
    pub start: Option<String>,
    /// The controller's stored work offsets G54[;G55...], each "X,Y,Z" mm.
    #[arg(long)]
    pub work_offsets: Option<String>,
    /// Parameter 3401#0 DPI = 1: numbers without a point are whole mm/inches.
    #[arg(long)]
    pub calculator_input: bool,
    /// Least input increment, mm (IS-B 0.001, IS-C 0.0001).
    #[arg(long, default_value_t = 0.001)]
    pub increment_mm: f64,
    /// The block-skip switch is off: `/` blocks run (rewritten as ordinary blocks).
    #[arg(long)]
    pub no_block_skip: bool,
    /// Longest block the controller takes, characters.
    #[arg(long, default_value_t = 128)]
    pub max_block_chars: usize,
    /// Pad blocks to an even length (TV check on).
    #[arg(long)]
    pub tv_pad: bool,
}

fn read(path: &Path) -> anyhow::Result<String> {
    procedure::rewrite::read_program(path).map_err(anyhow::Error::msg)
}

fn numbers(flag: &str, s: &str) -> anyhow::Result<Vec<f64>> {
    s.split(',')
        .map(|p| p.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| anyhow::anyhow!("{flag} `{s}`: expected numbers separated by commas"))
}

pub fn dnc(args: DncArgs, json: bool) -> anyhow::Result<ExitCode> {
    if args.map.is_none() && !args.uncompensated {
        anyhow::bail!("give the error map (--map MAP), or --uncompensated for the baseline");
    }
    let mut request = DncRequest::new(read(&args.input)?);
    request.program_name = args.input.display().to_string();
    request.subprograms = args.subprograms.as_deref().map(read).transpose()?;
    request.port = args.port.clone();
    request.baud = args.baud;
    request.send = !args.no_send;
    request.uncompensated = args.uncompensated;
    request.no_reference = args.no_reference;
    request.tolerance_um = args.tolerance_um;
    request.start = args
        .start
        .as_deref()
        .map(|s| numbers("--start", s))
        .transpose()?;
    if let Some(s) = &args.work_offsets {
        let mut offsets = Vec::new();
        for part in s.split(';') {
            let v = numbers("--work-offsets", part)?;
            let [x, y, z] = v[..] else {
                anyhow::bail!("--work-offsets `{part}`: expected X,Y,Z in mm");
            };
            offsets.push([x, y, z]);
        }
        request.work_offsets = Some(offsets);
    }
    request.calculator_input = args.calculator_input;
    request.increment_mm = args.increment_mm;
    request.block_skip = !args.no_block_skip;
    request.max_block_chars = args.max_block_chars;
    request.tv_pad = args.tv_pad;
    let inputs: Vec<&Path> = [
        Some(args.input.as_path()),
        args.map.as_deref(),
        args.config.as_deref(),
        args.subprograms.as_deref(),
    ]
    .into_iter()
    .flatten()
    .collect();
    let mut sink = crate::front::CliSink::new("tape lines", json).inputs(&inputs);
    if let Some(out) = &args.out {
        sink = sink.artifact_to(TAPE_ARTIFACT, out.clone());
    }
    let kind = procedure::kinds::kind("dnc")?;
    let mut outcome = crate::front::run_outcome(kind, &request, &mut sink, |f| {
        let f = f.input(&args.input);
        let f = match &args.map {
            Some(map) => f.map_file(map),
            None => f,
        };
        match &args.config {
            Some(job) => f.job_file(job),
            None => f,
        }
    })?;
    if let (Some(r), Some(out)) = (outcome.result.as_mut(), &args.out) {
        r["output"] = serde_json::json!(out.display().to_string());
    }
    crate::front::print(&outcome, json, |r| kind.summary(r))
}

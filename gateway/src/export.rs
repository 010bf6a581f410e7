//! `gateway export`: flags to `procedure::export`'s request; the tables it hands over
//! (all of them, or none when one is beyond the tolerance) written beside `--out`.

use procedure::export::{ExportFormat, ExportRequest};
use protocol::errormap::ErrorMap;
use serde_json::{json, Value};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct ExportArgs {
    #[arg(long)]
    pub map: PathBuf,
    #[arg(long)]
    pub format: String,
    /// Output file (`_x`/`_y` are added for the per-axis formats).
    #[arg(long)]
    pub out: PathBuf,
    #[arg(long, default_value_t = 1.0)]
    pub tolerance_um: f64,
    /// LinuxCNC entries per joint (2..256).
    #[arg(long, default_value_t = DEFAULT_ENTRIES)]
    pub entries: usize,
    /// Beckhoff grid interval, mm.
    #[arg(long, default_value_t = 1.0)]
    pub interval_mm: f64,
    #[command(flatten)]
    pub controller: procedure::export::ControllerOptions,
}

pub fn export(args: ExportArgs, json: bool) -> anyhow::Result<ExitCode> {
    let cli = |e: procedure::RequestError| anyhow::anyhow!(e.for_cli());
    let name = args
        .out
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .ok_or_else(|| anyhow::anyhow!("--out {}: must name a file", args.out.display()))?;
    let request = ExportRequest {
        format: ExportFormat::parse(&args.format).map_err(cli)?,
        name,
        tolerance_um: args.tolerance_um,
        entries: args.entries as u64,
        interval_mm: args.interval_mm,
        controller: args.controller,
    };
    request.check().map_err(cli)?;
    let map = ErrorMap::load(&args.map)?;
    request.check_map(&map).map_err(cli)?;
    // Each table goes beside --out, under the name the procedure gave it.
    let mut sink = crate::front::CliSink::new("", true).inputs(&[args.map.as_path()]);
    for name in request.artifact_names() {
        let path = args.out.with_file_name(&name);
        sink = sink.artifact_to(&name, path);
    }
    let mut outcome = procedure::export::run(&request, map, &mut sink);
    // `file`: where the table was written.
    if let Some(r) = outcome.result.as_mut() {
        let tables: Vec<&mut Value> = if r.get("tables").is_some() {
            r["tables"].as_array_mut().into_iter().flatten().collect()
        } else {
            vec![r]
        };
        for t in tables {
            if let Some(name) = t["file"].as_str() {
                t["file"] = json!(args.out.with_file_name(name).display().to_string());
            }
        }
    }
    crate::front::print(&outcome, json, procedure::export::summary)
}

/// The default number of LinuxCNC entries.
pub const DEFAULT_ENTRIES: usize = errormap::export::LINUXCNC_MAX_ENTRIES;

//! `gateway export`: the export procedure on `--map`; the tables it hands over (all of
//! them, or none when one is beyond the tolerance) written beside `--out`.

use procedure::export::ExportRequest;
use serde_json::{json, Value};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct ExportArgs {
    #[arg(long)]
    pub map: PathBuf,
    /// Output file (`_x`/`_y` are added for the per-axis formats).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub request: ExportRequest,
}

pub fn export(args: ExportArgs, json: bool) -> anyhow::Result<ExitCode> {
    let mut request = args.request;
    request.name = args
        .out
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .ok_or_else(|| anyhow::anyhow!("--out {}: must name a file", args.out.display()))?;
    // Each table goes beside --out, under the name the procedure gave it.
    let mut sink = crate::front::CliSink::new("", true).inputs(&[args.map.as_path()]);
    for name in request.artifact_names() {
        let path = args.out.with_file_name(&name);
        sink = sink.artifact_to(&name, path);
    }
    let kind = procedure::kinds::kind("export").map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut outcome =
        crate::front::run_outcome(kind, &request, &mut sink, |f| f.map_file(&args.map))?;
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
    crate::front::print(&outcome, json, |r| kind.summary(r))
}

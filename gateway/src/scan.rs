//! `gateway map`: the scan procedure with its journal file (a stopped scan resumes from
//! OUT/NAME.scan.jsonl) and the map written as a new version OUT/NAME.vN.json.

use anyhow::Context;
use devices::open_devices_async;
use errormap::scan::ScanSpec;
use job::Job;
use procedure::map::{FileJournal, FolderShelf};
use procedure::request::MapRequest;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct MapArgs {
    #[arg(long)]
    pub config: PathBuf,
    /// Folder of the map versions.
    #[arg(long)]
    pub out: PathBuf,
    /// Map name (default: the job file's name).
    #[arg(long)]
    pub name: Option<String>,
    #[arg(long, default_value_t = ScanSpec::default().grid_step_mm)]
    pub grid_step_mm: f64,
    #[arg(long, default_value_t = ScanSpec::default().line_step_mm)]
    pub line_step_mm: f64,
    #[arg(long, default_value_t = ScanSpec::default().passes)]
    pub passes: u32,
    /// Tool point minus camera centre, in machine axes, "X,Y" mm.
    #[arg(long, default_value = "0,0")]
    pub tool_offset_mm: String,
    #[arg(long)]
    pub json: bool,
}

pub fn map(args: MapArgs) -> anyhow::Result<ExitCode> {
    let job = Job::load(&args.config)?;
    let name = args.name.unwrap_or_else(|| {
        args.config
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "map".into())
    });
    let request = MapRequest {
        name,
        grid_step_mm: args.grid_step_mm,
        line_step_mm: args.line_step_mm,
        passes: args.passes,
        tool_offset_mm: crate::front::parse_xy(&args.tool_offset_mm).map_err(|_| {
            anyhow::anyhow!(
                "--tool-offset-mm `{}`: expected X,Y in mm",
                args.tool_offset_mm
            )
        })?,
    };
    request.check().map_err(|e| anyhow::anyhow!(e.for_cli()))?;
    let (job, out, json) = (&job, args.out.as_path(), args.json);
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let rt = crate::front::runtime()?;
    let mut devices = rt.block_on(open_devices_async(job))?;
    let mut journal = FileJournal::new(out.join(format!("{}.scan.jsonl", request.name)));
    let mut shelf = FolderShelf::new(out);
    let mut sink = crate::front::CliSink::new("frames", json);
    let outcome = rt.block_on(procedure::map::run(
        &request,
        job,
        &mut devices,
        &mut journal,
        &mut shelf,
        &mut sink,
        crate::front::ctrl_c(),
    ));
    sink.finish();
    crate::front::print(&outcome, json, procedure::map::summary)
}

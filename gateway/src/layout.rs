//! `gateway layout partition`: a cutting layout split into tool/window groups (Source C),
//! overlaps between groups resolved, the shifted layout written.

use anyhow::Context;
use clap::Subcommand;
use layout_io::Format;
use procedure::request::{CutRequest, LayoutFormat, LayoutRequest, PictureFormat};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// The layout file and how it is partitioned (shared by `partition` and `cut`).
#[derive(clap::Args)]
pub struct PartitionArgs {
    /// The layout (.dxf, .svg or .json).
    layout: PathBuf,
    #[command(flatten)]
    request: LayoutRequest,
}

#[derive(Subcommand)]
pub enum LayoutCmd {
    /// Group the parts per tool lane and cutting window (steps S1-S7), shift the groups
    /// apart by the gap (S8), find the overlaps between groups and resolve them by moving
    /// parts to neighbouring groups, and write the shifted layout (format from OUT's
    /// extension: .dxf, .svg or .json). Nothing is written when an overlap cannot be
    /// resolved.
    Partition {
        #[command(flatten)]
        args: PartitionArgs,
        /// Where to write the shifted layout.
        #[arg(long)]
        out: PathBuf,
        /// Also draw the result (.svg or .png), coloured by group.
        #[arg(long)]
        picture: Option<PathBuf>,
    },
    /// Partition the layout as `partition` does and cut it on a conveyor cutter: the
    /// conveyor's GRBL controller feeds the material stop by stop, each knife head's GRBL
    /// controller cuts its group of the stop (all heads at once), the next feed waits for
    /// every head. Without --conveyor, on the emulated cutter (k + 1 GRBL emulators on
    /// pseudo-terminals), whose log of every knife stroke --log writes. Every point is
    /// checked against its head's reach and the cutting area before anything moves.
    Cut {
        /// The layout (.dxf, .svg or .json).
        layout: PathBuf,
        #[command(flatten)]
        request: CutRequest,
        /// The emulated cutter's stroke log (JSON lines: one stroke each, then the feeds).
        #[arg(long)]
        log: Option<PathBuf>,
    },
}

fn format_of(path: &Path) -> anyhow::Result<Format> {
    Format::from_path(&path.to_string_lossy()).with_context(|| {
        format!(
            "{}: the extension must be .dxf, .svg or .json",
            path.display()
        )
    })
}

/// The request with the layout file read (through the bounded reader) and checked.
fn with_layout(mut request: LayoutRequest, input: &Path) -> anyhow::Result<LayoutRequest> {
    request.format = LayoutFormat::of(format_of(input)?);
    request.layout =
        procedure::layout::load_layout_file(input, &request).map_err(anyhow::Error::msg)?;
    request.check().map_err(|e| anyhow::anyhow!(e.for_cli()))?;
    Ok(request)
}

pub fn run(cmd: LayoutCmd, json: bool) -> anyhow::Result<ExitCode> {
    let (args, out, picture) = match cmd {
        LayoutCmd::Partition { args, out, picture } => (args, out, picture),
        LayoutCmd::Cut {
            layout,
            mut request,
            log,
        } => {
            request.partition = with_layout(request.partition, &layout)?;
            let mut sink = crate::front::CliSink::new("stops", json).inputs(&[&layout]);
            if let Some(path) = &log {
                sink = sink.artifact_to("strokes.jsonl", path.clone());
            }
            let kind = procedure::kinds::kind("cut")?;
            let outcome = crate::front::run_outcome(kind, &request, &mut sink, |f| f)?;
            return crate::front::print(&outcome, json, |r| {
                let mut text = kind.summary(r);
                if let Some(path) = log.as_ref().filter(|_| r["emulated"] == true) {
                    text += &format!("log written to {}", path.display());
                }
                text
            });
        }
    };
    let mut request = with_layout(args.request, &args.layout)?;
    request.out_format = Some(LayoutFormat::of(format_of(&out)?));
    let mut sink = crate::front::CliSink::new("", true)
        .inputs(&[args.layout.as_path()])
        .artifact_to(&format!("layout.{}", ext_of(&out)), out.clone());
    if let Some(path) = &picture {
        let kind = match ext_of(path).as_str() {
            "svg" => PictureFormat::Svg,
            "png" => PictureFormat::Png,
            _ => anyhow::bail!(
                "--picture {}: the extension must be .svg or .png",
                path.display()
            ),
        };
        request.picture = Some(kind);
        sink = sink.artifact_to(&format!("picture.{}", ext_of(path)), path.clone());
    }
    let written = format!("written {}", out.display());
    crate::front::run_kind_then("layout", &request, &mut sink, json, &written, |f| f)
}

fn ext_of(path: &Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase()
}

//! `gateway layout partition`: a cutting layout split into tool/window groups (Source C),
//! overlaps between groups resolved, the shifted layout written.

use anyhow::Context;
use clap::Subcommand;
use layout_io::Format;
use procedure::request::{CutRequest, HeadReach, LayoutFormat, LayoutRequest, PictureFormat};
use std::path::PathBuf;
use std::process::ExitCode;

/// The layout and how it is partitioned (shared by `partition` and `cut`).
#[derive(clap::Args)]
pub struct PartitionArgs {
    /// The layout (.dxf, .svg or .json).
    layout: PathBuf,
    /// Number of tools k (equal lanes across the width).
    #[arg(long)]
    tools: usize,
    /// Cutting window length L' along the feed (X), mm.
    #[arg(long)]
    window_mm: f64,
    /// Gap between groups, mm.
    #[arg(long)]
    gap_mm: f64,
    /// Material width W, mm, edge at Y = 0 (default: the JSON file's width_mm, else
    /// the layout's extent across).
    #[arg(long)]
    width_mm: Option<f64>,
    /// Parts of different groups closer than this after the shifts are overlaps, mm
    /// (default: the gap). Between 0.001 mm and the gap.
    #[arg(long)]
    clearance_mm: Option<f64>,
    /// Force a part into a group (group ids as printed, 1-based); repeatable.
    #[arg(long = "assign", value_name = "PART=GROUP")]
    assign: Vec<String>,
    /// When moving parts leaves overlaps, move later windows (along X) or upper lanes
    /// (along Y) further apart than S8's one gap until none is left (reported as
    /// `widenings`); without it such overlaps are an error.
    #[arg(long)]
    widen: bool,
    /// Chord tolerance for arcs and splines read from the layout, mm.
    #[arg(long, default_value_t = 0.01)]
    chord_tolerance_mm: f64,
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
        #[arg(long)]
        json: bool,
    },
    /// Partition the layout as `partition` does and cut it on a conveyor cutter: the
    /// conveyor's GRBL controller feeds the material stop by stop, each knife head's GRBL
    /// controller cuts its group of the stop (all heads at once), the next feed waits for
    /// every head. Without --conveyor, on the emulated cutter (k + 1 GRBL emulators on
    /// pseudo-terminals), whose log of every knife stroke --log writes. Every point is
    /// checked against its head's reach and the cutting area before anything moves.
    Cut {
        #[command(flatten)]
        args: PartitionArgs,
        /// The conveyor's controller (its X axis feeds the material); with --head for
        /// each tool, in lane order. Default: the emulated cutter.
        #[arg(long, requires = "head")]
        conveyor: Option<String>,
        /// A knife head's controller (X along the feed from the cutting area's start, Y
        /// across from its origin, Z the knife); repeat once per tool.
        #[arg(long, requires = "conveyor")]
        head: Vec<String>,
        /// With --head: each head's origin (material Y of its machine Y 0) and Y travel,
        /// `ORIGIN:REACH` in mm, in head order; default: built for the partition.
        #[arg(long = "head-reach", value_name = "ORIGIN:REACH")]
        head_reach: Vec<String>,
        #[arg(long, default_value_t = 115_200)]
        baud: u32,
        /// Knife feed along the contours, mm/min.
        #[arg(long, default_value_t = 12_000.0)]
        feed_mm_min: f64,
        /// The emulated cutter's stroke log (JSON lines: one stroke each, then the feeds).
        #[arg(long)]
        log: Option<PathBuf>,
        #[arg(long)]
        json: bool,
    },
}

impl LayoutCmd {
    pub fn json(&self) -> bool {
        match self {
            LayoutCmd::Partition { json, .. } | LayoutCmd::Cut { json, .. } => *json,
        }
    }
}

fn format_of(path: &std::path::Path) -> anyhow::Result<Format> {
    Format::from_path(&path.to_string_lossy()).with_context(|| {
        format!(
            "{}: the extension must be .dxf, .svg or .json",
            path.display()
        )
    })
}

/// The request the flags describe (the layout file read through the bounded reader).
fn request(args: &PartitionArgs) -> anyhow::Result<LayoutRequest> {
    let input = &args.layout;
    let format = format_of(input)?;
    let text = protocol::config::read_data_file(input)
        .with_context(|| format!("reading {}", input.display()))?;
    let request = LayoutRequest {
        layout: text,
        format: LayoutFormat::of(format),
        tools: args.tools as u64,
        window_mm: args.window_mm,
        gap_mm: args.gap_mm,
        width_mm: args.width_mm,
        clearance_mm: args.clearance_mm,
        assign: args.assign.clone(),
        widen: args.widen,
        chord_tolerance_mm: args.chord_tolerance_mm,
        out_format: None,
        picture: None,
    };
    request.check().map_err(|e| anyhow::anyhow!(e.for_cli()))?;
    Ok(request)
}

/// `--head-reach ORIGIN:REACH` in mm.
fn parse_reach(text: &str) -> anyhow::Result<HeadReach> {
    let (origin, reach) = text
        .split_once(':')
        .with_context(|| format!("--head-reach `{text}`: write ORIGIN:REACH in mm"))?;
    let num = |v: &str, what: &str| -> anyhow::Result<f64> {
        v.trim()
            .parse()
            .with_context(|| format!("--head-reach `{text}`: the {what} is not a number"))
    };
    Ok(HeadReach {
        origin_y_mm: num(origin, "origin")?,
        reach_y_mm: num(reach, "reach")?,
    })
}

pub fn run(cmd: LayoutCmd) -> anyhow::Result<ExitCode> {
    let (args, out, picture, json) = match cmd {
        LayoutCmd::Partition {
            args,
            out,
            picture,
            json,
        } => (args, out, picture, json),
        LayoutCmd::Cut {
            args,
            conveyor,
            head,
            head_reach,
            baud,
            feed_mm_min,
            log,
            json,
        } => {
            let request = CutRequest {
                partition: request(&args)?,
                conveyor,
                heads: head,
                head_reach: head_reach
                    .iter()
                    .map(|t| parse_reach(t))
                    .collect::<anyhow::Result<_>>()?,
                baud,
                feed_mm_min,
            };
            request.check().map_err(|e| anyhow::anyhow!(e.for_cli()))?;
            let mut sink = crate::front::CliSink::new("stops", json).inputs(&[&args.layout]);
            if let Some(path) = &log {
                sink = sink.artifact_to("strokes.jsonl", path.clone());
            }
            let rt = tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()?;
            let outcome = rt.block_on(procedure::cut::run(&request, &mut sink));
            sink.finish();
            return crate::front::print(&outcome, json, |r| {
                let mut text = procedure::cut::summary(r);
                if let Some(path) = log.as_ref().filter(|_| r["emulated"] == true) {
                    text += &format!("log written to {}", path.display());
                }
                text
            });
        }
    };
    let mut request = request(&args)?;
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
    let outcome = procedure::layout::partition(&request, &mut sink);
    crate::front::print(&outcome, json, |r| {
        format!("{}written {}", procedure::layout::summary(r), out.display())
    })
}

fn ext_of(path: &std::path::Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase()
}

//! `gateway layout partition`: a cutting layout split into tool/window groups (Source C),
//! overlaps between groups resolved, the shifted layout written.

use anyhow::Context;
use clap::Subcommand;
use layout::{Figures, Params, Partition, Resolution};
use layout_io::{Format, Layout, ReadOptions};
use serde_json::json;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

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

fn parse_assign(text: &str) -> anyhow::Result<(String, usize)> {
    let (part, group) = text
        .rsplit_once('=')
        .with_context(|| format!("--assign `{text}`: write PART=GROUP"))?;
    let group: usize = group
        .trim()
        .trim_start_matches(['G', 'g'])
        .parse()
        .with_context(|| format!("--assign `{text}`: the group is a number (1, 2, ...)"))?;
    Ok((part.to_string(), group))
}

/// The layout read and partitioned, overlaps resolved: (layout, partition, moves,
/// partition time in ms).
fn partitioned(args: &PartitionArgs) -> anyhow::Result<(Layout, Partition, Resolution, f64)> {
    let input = &args.layout;
    let in_format = format_of(input)?;
    let forced = args
        .assign
        .iter()
        .map(|a| parse_assign(a))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let bytes = std::fs::read(input).with_context(|| format!("reading {}", input.display()))?;
    let options = ReadOptions {
        chord_tolerance_mm: args.chord_tolerance_mm,
        ..ReadOptions::default()
    };
    let doc = Layout::read(&bytes, in_format, &options)
        .with_context(|| format!("{}", input.display()))?;
    let params = Params {
        tools: args.tools,
        window_mm: args.window_mm,
        gap_mm: args.gap_mm,
        width_mm: args.width_mm.or(doc.width_mm),
        clearance_mm: args.clearance_mm,
    };
    let t0 = Instant::now();
    let mut partition = layout::partition(&doc.parts, &params)?;
    let pinned = layout::assign(&doc.parts, &mut partition, &forced)?;
    let resolution = if args.widen {
        layout::resolve_widening(&doc.parts, &mut partition, &pinned)?
    } else {
        layout::resolve(&doc.parts, &mut partition, &pinned)?
    };
    let elapsed_ms = t0.elapsed().as_secs_f64() * 1e3;
    Ok((doc, partition, resolution, elapsed_ms))
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
            return crate::cutter::run(crate::cutter::CutCmd {
                partitioned: partitioned(&args)?,
                conveyor,
                heads: head,
                head_reach,
                baud,
                feed_mm_min,
                log,
                json,
            })
        }
    };
    let out_format = format_of(&out)?;
    let (doc, partition, resolution, elapsed_ms) = partitioned(&args)?;

    let shifted = doc.translated(&partition.offsets())?;
    let written = shifted.write(out_format)?;
    std::fs::write(&out, written).with_context(|| format!("writing {}", out.display()))?;
    if let Some(path) = &picture {
        let pic = layout::Picture {
            parts: &doc.parts,
            partition: &partition,
            moves: &resolution.moves,
        };
        let (w, h) = pic.size(1600);
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("")
            .to_ascii_lowercase();
        let bytes = match ext.as_str() {
            "svg" => plot::render_svg(&pic, w, h)?.into_bytes(),
            "png" => plot::render_png(&pic, w, h)?,
            _ => anyhow::bail!(
                "--picture {}: the extension must be .svg or .png",
                path.display()
            ),
        };
        std::fs::write(path, bytes).with_context(|| format!("writing {}", path.display()))?;
    }

    if json {
        println!(
            "{}",
            report(&doc, &partition, &resolution, elapsed_ms, &out)
        );
    } else {
        let figures = layout::figures(&doc.parts, &partition);
        print_text(&doc, &partition, &resolution, &figures, elapsed_ms, &out);
    }
    Ok(ExitCode::SUCCESS)
}

/// The layout crate's report with the CLI's own figures: where the layout was written
/// and how long the partition took.
fn report(
    doc: &Layout,
    partition: &Partition,
    resolution: &Resolution,
    elapsed_ms: f64,
    out: &std::path::Path,
) -> serde_json::Value {
    let mut v = serde_json::to_value(layout::report(&doc.parts, partition, resolution))
        .unwrap_or(serde_json::Value::Null);
    if let Some(o) = v.as_object_mut() {
        o.insert("out".into(), json!(out.display().to_string()));
        o.insert("partition_ms".into(), json!(elapsed_ms));
    }
    v
}

fn print_text(
    doc: &Layout,
    partition: &Partition,
    resolution: &Resolution,
    figures: &Figures,
    elapsed_ms: f64,
    out: &std::path::Path,
) {
    println!(
        "{} parts, {} tools, window {} mm, gap {} mm, width {} mm: {:.3} ms",
        doc.parts.len(),
        partition.tools,
        partition.window_mm,
        partition.gap_mm,
        partition.width_mm,
        elapsed_ms
    );
    println!("group  tool  window  dx_mm  dy_mm  parts");
    for g in partition.groups.iter().filter(|g| !g.parts.is_empty()) {
        println!(
            "{:>5}  {:>4}  {:>6}  {:>5}  {:>5}  {}",
            g.id,
            g.tool,
            g.window,
            g.dx_mm,
            g.dy_mm,
            g.parts.len()
        );
    }
    println!(
        "overlaps between groups after S8: {}",
        resolution.found.len()
    );
    for m in &resolution.moves {
        println!(
            "  moved `{}` from group {} to group {} (too close to `{}`)",
            doc.parts[m.part].id,
            m.from_group,
            m.to_group,
            m.because_of
                .map(|b| doc.parts[b].id.as_str())
                .unwrap_or("-")
        );
    }
    for w in &resolution.widenings {
        println!(
            "  widened: every {} from {} on moved {:.3} mm further",
            w.between, w.from, w.extra_mm
        );
    }
    let row = |name: &str, m: &layout::Material| {
        println!(
            "{name:<18} length {:>10.3} mm  width {:>9.3} mm  area {:>12.1} mm2  utilisation {:>6.2} %",
            m.length_mm,
            m.width_mm,
            m.area_mm2,
            m.utilisation * 100.0
        )
    };
    row("no gap", &figures.no_gap);
    row("partitioned", &figures.partitioned);
    row("gap every part", &figures.gap_every_part);
    match figures.added_length_fraction {
        Some(f) => println!(
            "length added: {:.3} mm by the groups, {:.3} mm with a gap around every part ({:.1} %)",
            figures.added_length_partitioned_mm,
            figures.added_length_every_part_mm,
            f * 100.0
        ),
        None => println!(
            "length added: {:.3} mm by the groups",
            figures.added_length_partitioned_mm
        ),
    }
    println!("written {}", out.display());
}

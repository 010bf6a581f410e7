//! `gateway layout cut`: a partitioned layout cut on a conveyor cutter (source C), the
//! emulated one by default or real GRBL controllers (one for the conveyor, one per head).

use anyhow::Context;
use drivers::grbl::{GrblOptions, StreamOptions};
use indicatif::{ProgressBar, ProgressStyle};
use layout::cut::{plan, CutSettings, CutterSpec, HeadSpec, Stop};
use layout::{Partition, Resolution};
use layout_io::Layout;
use serde_json::json;
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

pub struct CutCmd {
    pub partitioned: (Layout, Partition, Resolution, f64),
    pub conveyor: Option<String>,
    pub heads: Vec<String>,
    pub head_reach: Vec<String>,
    pub baud: u32,
    pub feed_mm_min: f64,
    pub log: Option<PathBuf>,
    pub json: bool,
}

fn parse_reach(text: &str) -> anyhow::Result<HeadSpec> {
    let (origin, reach) = text
        .split_once(':')
        .with_context(|| format!("--head-reach `{text}`: write ORIGIN:REACH in mm"))?;
    let num = |v: &str, what: &str| -> anyhow::Result<f64> {
        let x: f64 = v
            .trim()
            .parse()
            .with_context(|| format!("--head-reach `{text}`: the {what} is not a number"))?;
        anyhow::ensure!(
            x.is_finite(),
            "--head-reach `{text}`: the {what} is not finite"
        );
        Ok(x)
    };
    let spec = HeadSpec {
        origin_y_mm: num(origin, "origin")?,
        reach_y_mm: num(reach, "reach")?,
    };
    anyhow::ensure!(
        spec.reach_y_mm > 0.0,
        "--head-reach `{text}`: the reach must be positive"
    );
    Ok(spec)
}

pub fn run(cmd: CutCmd) -> anyhow::Result<ExitCode> {
    let (doc, partition, resolution, _) = &cmd.partitioned;
    anyhow::ensure!(
        cmd.feed_mm_min > 0.0 && cmd.feed_mm_min.is_finite(),
        "--feed-mm-min must be a positive feed"
    );
    let cutter = if cmd.head_reach.is_empty() {
        CutterSpec::for_partition(&doc.parts, partition)
    } else {
        anyhow::ensure!(
            cmd.head_reach.len() == partition.tools,
            "--head-reach given {} times for {} tools",
            cmd.head_reach.len(),
            partition.tools
        );
        CutterSpec {
            window_mm: partition.window_mm,
            heads: cmd
                .head_reach
                .iter()
                .map(|t| parse_reach(t))
                .collect::<anyhow::Result<_>>()?,
        }
    };
    if cmd.conveyor.is_some() {
        anyhow::ensure!(
            cmd.heads.len() == partition.tools,
            "--head given {} times for {} tools (one controller per head, in lane order)",
            cmd.heads.len(),
            partition.tools
        );
    }
    let stops = plan(&doc.parts, partition, &cutter)?;
    let settings = CutSettings {
        feed_mm_min: cmd.feed_mm_min,
        ..CutSettings::default()
    };
    let bar = if cmd.json {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(stops.len() as u64)
    };
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} stops")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let started = Instant::now();
    let (run, log) = rt.block_on(async {
        let stream = StreamOptions {
            status_interval: Duration::from_millis(20),
            ..StreamOptions::default()
        };
        let progress = |done: usize, _| bar.set_position(done as u64);
        match &cmd.conveyor {
            Some(conveyor) => {
                let opts = GrblOptions::default();
                let mut links = devices::open_cutter(conveyor, &cmd.heads, cmd.baud, &opts)
                    .await
                    .context("connecting to the cutter's controllers")?;
                let run = runner::cutter::run_cut(
                    &stops,
                    links.conveyor.as_mut(),
                    &mut links.heads,
                    &settings,
                    &stream,
                    progress,
                )
                .await;
                anyhow::Ok((run, None))
            }
            None => {
                let geometry = runner::cutter::emulated_geometry(&cutter, &stops);
                let mut emulated = devices::open_emulated_cutter(&geometry)
                    .await
                    .context("the emulated cutter")?;
                let stream = StreamOptions {
                    status_interval: Duration::from_millis(2),
                    ..stream
                };
                let run = runner::cutter::run_cut(
                    &stops,
                    emulated.conveyor.as_mut(),
                    &mut emulated.heads,
                    &settings,
                    &stream,
                    progress,
                )
                .await;
                Ok((run, emulated.log()))
            }
        }
    })?;
    bar.finish_and_clear();
    if let (Some(path), Some(log)) = (&cmd.log, &log) {
        write_log(path, log)?;
    }
    let run = run?;
    let wall_s = started.elapsed().as_secs_f64();
    let report = json!({
        "parts": doc.parts.len(),
        "groups": partition.groups.iter().filter(|g| !g.parts.is_empty()).count(),
        "moves": resolution.moves.len(),
        "cutter": cutter,
        "stops": stops.iter().map(stop_json).collect::<Vec<_>>(),
        "heads": run.heads,
        "strokes": log.as_ref().map(|l| l.strokes.len()),
        "machine_time_s": log.as_ref().map(|l| l.machine_time_s()),
        "wall_time_s": wall_s,
        "log": cmd.log.as_ref().filter(|_| log.is_some()).map(|p| p.display().to_string()),
    });
    if cmd.json {
        println!("{report}");
        return Ok(ExitCode::SUCCESS);
    }
    println!(
        "{} parts in {} groups cut at {} conveyor stops{}",
        doc.parts.len(),
        report["groups"],
        stops.len(),
        if log.is_some() {
            " on the emulated cutter"
        } else {
            ""
        }
    );
    for (i, s) in stops.iter().enumerate() {
        let groups: Vec<String> = s
            .jobs
            .iter()
            .map(|j| format!("head {} G-{}", j.tool, j.group))
            .collect();
        println!(
            "  stop {:>3}: conveyor {:>10.3} mm  {}",
            i + 1,
            s.conveyor_mm,
            groups.join(", ")
        );
    }
    for (t, h) in run.heads.iter().enumerate() {
        println!(
            "head {t}: {} groups, {} contours, {:.1} mm of knife path",
            h.groups, h.contours, h.cut_length_mm
        );
    }
    if let Some(l) = &log {
        println!(
            "{} strokes, machine time {:.1} s (conveyor {:.1} s)",
            l.strokes.len(),
            l.machine_time_s(),
            l.conveyor_s
        );
    }
    if let (Some(path), Some(_)) = (&cmd.log, &log) {
        println!("log written to {}", path.display());
    }
    Ok(ExitCode::SUCCESS)
}

fn stop_json(s: &Stop) -> serde_json::Value {
    json!({
        "conveyor_mm": s.conveyor_mm,
        "jobs": s.jobs.iter().map(|j| json!({
            "tool": j.tool, "group": j.group, "window": j.window,
            "contours": j.contours.len(), "cut_length_mm": j.cut_length_mm(),
        })).collect::<Vec<_>>(),
    })
}

/// The stroke log as JSON lines: `{"stroke": ...}` for each stroke, then
/// `{"feeds": [...], "conveyor_s": .., "machine_time_s": ..}`.
fn write_log(path: &std::path::Path, log: &world::cutter::CutLog) -> anyhow::Result<()> {
    let mut f = std::io::BufWriter::new(
        std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?,
    );
    for s in &log.strokes {
        writeln!(f, "{}", json!({ "stroke": s }))?;
    }
    writeln!(
        f,
        "{}",
        json!({"feeds": log.feeds, "conveyor_s": log.conveyor_s, "head_busy": log.head_busy,
               "machine_time_s": log.machine_time_s()})
    )?;
    f.flush()
        .with_context(|| format!("writing {}", path.display()))
}

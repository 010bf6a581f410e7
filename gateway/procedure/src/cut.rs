//! A partitioned layout cut on a conveyor cutter (source C): the plan checked against
//! every head's reach and the cutting area before anything moves, the conveyor fed stop
//! by stop and every head's group cut at once, on the emulated cutter (whose stroke log
//! is an artifact) or on real GRBL controllers.

use crate::command_line::FileArg;
use crate::request::CutRequest;
use crate::{Artifact, Outcome, Sink};
use drivers::grbl::{GrblOptions, StreamOptions};
use layout::cut::{plan, CutSettings, CutterSpec, HeadSpec, Stop};
use serde::{Deserialize, Serialize};
use std::time::{Duration, Instant};

/// One head's reach on the cutter.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct CutterHead {
    /// Material Y of the head's machine Y 0.
    pub origin_y_mm: f64,
    /// Its Y travel.
    pub reach_y_mm: f64,
}

/// The cutter the layout was cut on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Cutter {
    /// The cutting area's length (normally the partition's window).
    pub window_mm: f64,
    #[schema(inline)]
    pub heads: Vec<CutterHead>,
}

/// One head's group cut at a stop.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct StopJob {
    /// The head.
    pub tool: usize,
    /// The group's id (G-1, G-2, ...).
    pub group: usize,
    pub window: usize,
    /// Contours cut.
    pub contours: usize,
    /// Knife path length (contours only).
    pub cut_length_mm: f64,
}

/// A conveyor stop and what every head cut there.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct CutStop {
    /// Material X under the cutting area's start edge.
    pub conveyor_mm: f64,
    #[schema(inline)]
    pub jobs: Vec<StopJob>,
}

impl From<&Stop> for CutStop {
    fn from(s: &Stop) -> Self {
        Self {
            conveyor_mm: s.conveyor_mm,
            jobs: (s.jobs.iter())
                .map(|j| StopJob {
                    tool: j.tool,
                    group: j.group,
                    window: j.window,
                    contours: j.contours.len(),
                    cut_length_mm: j.cut_length_mm(),
                })
                .collect(),
        }
    }
}

/// What one head cut in all.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct HeadCut {
    pub groups: usize,
    pub contours: usize,
    /// Knife path length.
    pub cut_length_mm: f64,
}

/// `layout cut`'s result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct CutResult {
    pub parts: usize,
    /// Groups with parts.
    pub groups: usize,
    /// Parts moved to another group to resolve overlaps.
    pub moves: usize,
    #[schema(inline)]
    pub cutter: Cutter,
    /// Whether it was cut on the emulated cutter (else on real controllers).
    pub emulated: bool,
    #[schema(inline)]
    pub stops: Vec<CutStop>,
    /// Per head.
    #[schema(inline)]
    pub heads: Vec<HeadCut>,
    /// The emulated cutter's strokes (null on real controllers).
    pub strokes: Option<usize>,
    /// The emulated cutter's machine time (null on real controllers).
    pub machine_time_s: Option<f64>,
    /// The emulated conveyor's share of it (null on real controllers).
    pub conveyor_s: Option<f64>,
    /// The cut's wall-clock time.
    pub wall_time_s: f64,
}

/// A stroke of the stroke log.
#[derive(Serialize)]
struct StrokeLine<'a> {
    stroke: &'a world::cutter::Stroke,
}

/// The stroke log's last line: the feeds and the times.
#[derive(Serialize)]
struct LogEnd<'a> {
    feeds: &'a [f64],
    conveyor_s: f64,
    /// `(feeds_before, head, seconds)`.
    head_busy: &'a [(u64, usize, f64)],
    machine_time_s: f64,
}

/// The stroke log as JSON lines: `{"stroke": ...}` for each stroke, then
/// `{"feeds": [...], "conveyor_s": .., "head_busy": [...], "machine_time_s": ..}`.
fn log_lines(log: &world::cutter::CutLog) -> Result<String, crate::Error> {
    fn line<T: Serialize>(text: &mut String, v: &T) -> Result<(), crate::Error> {
        let json = serde_json::to_string(v)
            .map_err(|e| crate::Error::Output(format!("strokes.jsonl: {e}")))?;
        text.push_str(&json);
        text.push('\n');
        Ok(())
    }
    let mut text = String::new();
    for stroke in &log.strokes {
        line(&mut text, &StrokeLine { stroke })?;
    }
    let end = LogEnd {
        feeds: &log.feeds,
        conveyor_s: log.conveyor_s,
        head_busy: &log.head_busy,
        machine_time_s: log.machine_time_s(),
    };
    line(&mut text, &end)?;
    Ok(text)
}

/// Partitions the layout (as `layout::partition` does) and cuts it. Progress counts
/// stops; the emulated cutter's stroke log is the artifact `strokes.jsonl`.
pub async fn run(request: &CutRequest, sink: &mut dyn Sink) -> Outcome<CutResult> {
    let p = match crate::layout::partitioned(&request.partition) {
        Ok(p) => p,
        Err(e) => return Outcome::failed(e),
    };
    let (doc, partition, resolution) = (&p.doc, &p.partition, &p.resolution);
    let cutter = if request.head_reach.is_empty() {
        CutterSpec::for_partition(&doc.parts, partition)
    } else {
        CutterSpec {
            window_mm: partition.window_mm,
            heads: request
                .head_reach
                .iter()
                .map(|h| HeadSpec {
                    origin_y_mm: h.origin_y_mm,
                    reach_y_mm: h.reach_y_mm,
                })
                .collect(),
        }
    };
    let stops = match plan(&doc.parts, partition, &cutter) {
        Ok(s) => s,
        Err(e) => return Outcome::failed(e.to_string()),
    };
    let settings = CutSettings {
        feed_mm_min: request.feed_mm_min,
        ..CutSettings::default()
    };
    let stream = StreamOptions {
        status_interval: Duration::from_millis(20),
        ..StreamOptions::default()
    };
    let started = Instant::now();
    let progress = std::cell::RefCell::new(&mut *sink);
    let on_progress =
        |done: usize, of: usize| progress.borrow_mut().progress(done as u64, of as u64);
    let (run, log) = match &request.conveyor {
        Some(conveyor) => {
            let opts = GrblOptions::default();
            let mut links =
                match devices::open_cutter(conveyor, &request.heads, request.baud, &opts).await {
                    Ok(l) => l,
                    Err(e) => {
                        return Outcome::failed(format!(
                            "connecting to the cutter's controllers: {e}"
                        ))
                    }
                };
            let run = runner::cutter::run_cut(
                &stops,
                links.conveyor.as_mut(),
                &mut links.heads,
                &settings,
                &stream,
                on_progress,
            )
            .await;
            (run, None)
        }
        None => {
            let geometry = runner::cutter::emulated_geometry(&cutter, &stops);
            let mut emulated = match devices::open_emulated_cutter(&geometry).await {
                Ok(e) => e,
                Err(e) => return Outcome::failed(format!("the emulated cutter: {e}")),
            };
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
                on_progress,
            )
            .await;
            (run, emulated.log())
        }
    };
    if let Some(log) = &log {
        let lines = match log_lines(log) {
            Ok(l) => l,
            Err(e) => return Outcome::failed(e),
        };
        let a = Artifact {
            name: "strokes.jsonl".into(),
            title: None,
            media_type: "application/jsonl",
            bytes: lines.into_bytes(),
        };
        if let Err(e) = sink.artifact(a) {
            return Outcome::failed(e);
        }
    }
    let run = match run {
        Ok(r) => r,
        Err(e) => return Outcome::failed(e.to_string()),
    };
    let result = CutResult {
        parts: doc.parts.len(),
        groups: partition
            .groups
            .iter()
            .filter(|g| !g.parts.is_empty())
            .count(),
        moves: resolution.moves.len(),
        cutter: Cutter {
            window_mm: cutter.window_mm,
            heads: (cutter.heads.iter())
                .map(|h| CutterHead {
                    origin_y_mm: h.origin_y_mm,
                    reach_y_mm: h.reach_y_mm,
                })
                .collect(),
        },
        emulated: log.is_some(),
        stops: stops.iter().map(CutStop::from).collect(),
        heads: (run.heads.iter())
            .map(|h| HeadCut {
                groups: h.groups,
                contours: h.contours,
                cut_length_mm: h.cut_length_mm,
            })
            .collect(),
        strokes: log.as_ref().map(|l| l.strokes.len()),
        machine_time_s: log.as_ref().map(|l| l.machine_time_s()),
        conveyor_s: log.as_ref().map(|l| l.conveyor_s),
        wall_time_s: started.elapsed().as_secs_f64(),
    };
    let mut metrics = serde_json::Map::new();
    metrics.insert("parts".into(), result.parts.into());
    metrics.insert("groups".into(), result.groups.into());
    metrics.insert("strokes".into(), result.strokes.into());
    Outcome::succeeded(result, metrics)
}

/// [`run`] as a registered kind.
pub struct Cut;

impl crate::registry::Procedure for Cut {
    const KIND: &'static str = "cut";
    const TITLE: &'static str =
        "Partition a layout and cut it on the conveyor cutter, every head's group at once";
    const COMMAND: &'static str = "layout cut";
    const LABEL: &'static str = "Layout cut";
    const HELP: &'static str = "Splits the layout as a partition does and cuts it on the emulated conveyor cutter, every head's group at once.";
    const USES: crate::registry::Uses = crate::registry::Uses::NOTHING;
    type Request = CutRequest;
    type Result = CutResult;
    const FILES: &'static [FileArg] = &[
        FileArg::positional(
            "layout",
            "The layout (.dxf, .svg or .json).",
            |path, plan| crate::layout::layout_file(path, "partition/", plan),
        ),
        FileArg::flag(
            "log",
            "The emulated cutter's stroke log (JSON lines: one stroke each, then the feeds).",
            |path, plan| {
                plan.artifacts
                    .push(("strokes.jsonl".into(), path.to_path_buf()));
                Ok(())
            },
        ),
    ];
    const STEPS: &'static str = "stops";

    async fn run(request: CutRequest, cx: &mut dyn crate::Context) -> Outcome<CutResult> {
        run(&request, cx.sink()).await
    }

    fn summary(result: &CutResult) -> String {
        summary(result)
    }

    /// The service cuts on the emulated cutter: real controllers are named by their
    /// ports on the box that owns them (`gateway layout cut --conveyor PORT --head
    /// PORT ...`), never by a request from the network.
    const COMMAND_LINE_ONLY: &'static [&'static str] = &["conveyor", "heads"];

    fn admit(
        request: &CutRequest,
        _facts: &crate::registry::Facts,
    ) -> Result<(), crate::RequestError> {
        if request.conveyor.is_some() || !request.heads.is_empty() {
            let field = if request.conveyor.is_some() {
                "conveyor"
            } else {
                "heads"
            };
            return Err(crate::RequestError::new(
                field,
                "the service cuts on the emulated cutter; a cut on real controllers runs from the command line of the box their ports are on (gateway layout cut --conveyor PORT --head PORT ...)",
            ));
        }
        Ok(())
    }
}

/// The cut as text (the CLI's output without `--json`).
pub fn summary(r: &CutResult) -> String {
    use std::fmt::Write;
    let mut t = String::new();
    let _ = writeln!(
        t,
        "{} parts in {} groups cut at {} conveyor stops{}",
        r.parts,
        r.groups,
        r.stops.len(),
        if r.emulated {
            " on the emulated cutter"
        } else {
            ""
        }
    );
    for (i, s) in r.stops.iter().enumerate() {
        let groups: Vec<String> = (s.jobs.iter())
            .map(|j| format!("head {} G-{}", j.tool, j.group))
            .collect();
        let _ = writeln!(
            t,
            "  stop {:>3}: conveyor {:>10.3} mm  {}",
            i + 1,
            s.conveyor_mm,
            groups.join(", ")
        );
    }
    for (k, h) in r.heads.iter().enumerate() {
        let _ = writeln!(
            t,
            "head {k}: {} groups, {} contours, {:.1} mm of knife path",
            h.groups, h.contours, h.cut_length_mm
        );
    }
    if let Some(strokes) = r.strokes {
        let _ = writeln!(
            t,
            "{strokes} strokes, machine time {:.1} s (conveyor {:.1} s)",
            r.machine_time_s.unwrap_or(f64::NAN),
            r.conveyor_s.unwrap_or(f64::NAN)
        );
    }
    t
}

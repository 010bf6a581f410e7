//! Cutting a partitioned layout on a conveyor cutter over its GRBL links (source C): the
//! conveyor's controller feeds the material to each stop of the plan
//! (`layout::cut::plan`), then every head with work at that stop streams its group's
//! program over its own link, all heads at once, and the next feed waits until every
//! head is idle again (a head never cuts while the material moves). The controllers are
//! opened by `devices` (`devices::open_cutter`, `devices::open_emulated_cutter`); the
//! heads run their programs through [`Stage::stream_program`] (the `program_streaming`
//! capability).

use drivers::{Axis, AxisValues, DriverError, Stage, StreamOptions};
use layout::cut::{CutSettings, Stop};

/// The conveyor's feed rate between stops, mm/min.
pub const CONVEYOR_FEED_MM_MIN: f64 = 20_000.0;

/// What was cut.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct CutRun {
    pub stops: usize,
    /// Per head: groups and contours cut, knife path length (mm).
    pub heads: Vec<HeadFigures>,
}

#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct HeadFigures {
    pub groups: usize,
    pub contours: usize,
    pub cut_length_mm: f64,
}

/// Where the cut stopped, and what was cut before.
#[derive(Debug, thiserror::Error)]
#[error("stop {stop} (conveyor at {conveyor_mm:.3} mm): {what}")]
pub struct CutFailure {
    /// 0-based stop index.
    pub stop: usize,
    pub conveyor_mm: f64,
    pub what: String,
    /// Stops finished before it.
    pub done: usize,
}

/// Runs the plan: for each stop, the conveyor to its position and idle, then each head
/// with a job streams it (concurrently) until executed (`stream.wait_until_executed`
/// should stay true: the next feed must not start under a cutting knife). `progress(stop_done, stops)`.
/// A refused line or a link error on one head ends the cut after that stop: the other
/// heads finish their groups of the stop (the material does not move under them), and
/// the conveyor is not fed again.
pub async fn run_cut(
    stops: &[Stop],
    conveyor: &mut dyn Stage,
    heads: &mut [Box<dyn Stage>],
    settings: &CutSettings,
    stream: &StreamOptions,
    mut progress: impl FnMut(usize, usize),
) -> Result<CutRun, CutFailure> {
    let mut figures = vec![HeadFigures::default(); heads.len()];
    for (i, stop) in stops.iter().enumerate() {
        let fail = |what: String| CutFailure {
            stop: i,
            conveyor_mm: stop.conveyor_mm,
            what,
            done: i,
        };
        if let Some(job) = stop.jobs.iter().find(|j| j.tool >= heads.len()) {
            return Err(fail(format!(
                "tool {} has no head link ({} heads)",
                job.tool,
                heads.len()
            )));
        }
        feed(conveyor, stop.conveyor_mm)
            .await
            .map_err(|e| fail(format!("conveyor: {e}")))?;
        // A head's groups at this stop, one after the other, in one program.
        let mut programs: Vec<Option<String>> = vec![None; heads.len()];
        for j in &stop.jobs {
            programs[j.tool]
                .get_or_insert_with(String::new)
                .push_str(&j.program(settings));
        }
        let streams = heads.iter_mut().enumerate().filter_map(|(t, head)| {
            let program = programs[t].take()?;
            Some(async move {
                let r = head.stream_program(&program, stream, &mut |_| {}).await;
                (t, r)
            })
        });
        let results = futures_util::future::join_all(streams).await;
        let mut errors = Vec::new();
        for (t, r) in results {
            if let Err(e) = r {
                errors.push(format!("head {t}: {e}"));
            }
        }
        if !errors.is_empty() {
            return Err(fail(errors.join("; ")));
        }
        for j in &stop.jobs {
            let f = &mut figures[j.tool];
            f.groups += 1;
            f.contours += j.contours.len();
            f.cut_length_mm += j.cut_length_mm();
        }
        progress(i + 1, stops.len());
    }
    Ok(CutRun {
        stops: stops.len(),
        heads: figures,
    })
}

/// The conveyor to `at` (its X axis), and idle.
async fn feed(conveyor: &mut dyn Stage, at: f64) -> Result<(), DriverError> {
    conveyor
        .move_to(
            AxisValues::default().with(Axis::X, at),
            CONVEYOR_FEED_MM_MIN,
        )
        .await?;
    conveyor.wait_idle().await
}

/// The emulated cutter for a plan: the heads of `spec`, the conveyor's travel from the
/// material's start (or the first stop, if before it) to 1 mm past the last stop. The
/// links send 3 decimals, so a point the plan puts exactly on the far edge of a head's
/// travel can arrive 0.5 um past it: each travel has 10 um more than the plan allows.
pub fn emulated_geometry(
    spec: &layout::cut::CutterSpec,
    stops: &[Stop],
) -> world::cutter::CutterGeometry {
    let first = stops.iter().map(|s| s.conveyor_mm).fold(0.0f64, f64::min);
    let last = stops.iter().map(|s| s.conveyor_mm).fold(0.0f64, f64::max);
    world::cutter::CutterGeometry {
        window_mm: spec.window_mm + TRAVEL_MARGIN_MM,
        heads: spec
            .heads
            .iter()
            .map(|h| world::cutter::HeadGeometry {
                origin_y_mm: h.origin_y_mm,
                reach_y_mm: h.reach_y_mm + TRAVEL_MARGIN_MM,
            })
            .collect(),
        conveyor_min_mm: first - if first < 0.0 { 1.0 } else { 0.0 },
        conveyor_max_mm: last + 1.0,
    }
}

const TRAVEL_MARGIN_MM: f64 = 0.01;

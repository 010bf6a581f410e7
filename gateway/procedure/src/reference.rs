//! The reference after homing: home (when the job homes), one frame at the map's
//! reference point, and the machine zero's shift recorded as the map's current
//! reference (an [`errormap::reference::MapReference`], kept beside the map as
//! `MAP.reference.json` by the CLI). `rewrite`, `proxy` and `verify --spot-check` apply
//! it ([`choose`], [`apply`]) and say which one they use and how old it is.

use crate::command_line::{self, FileArg};
use crate::request::ReferenceRequest;
use crate::{Artifact, Error, Outcome, Sink};
use devices::Devices;
use errormap::reference::{AxisScale, Circumstances, MapReference};
use errormap::MapModel;
use job::Job;
use protocol::errormap::ErrorMap;
use runner::JobError;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::SystemTime;

/// The record's artifact (the CLI writes it to [`reference_path`]).
pub const REFERENCE_ARTIFACT: &str = "reference.json";

/// The most bytes a reference record may have (it has a few hundred).
pub const MAX_RECORD_BYTES: u64 = 64 << 10;

/// Where a map's current reference is kept: beside it, `NAME.vN.reference.json` for
/// `NAME.vN.json`.
pub fn reference_path(map: &Path) -> PathBuf {
    let name = map
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let stem = name.strip_suffix(".json").unwrap_or(&name);
    map.with_file_name(format!("{stem}.reference.json"))
}

/// A record's text parsed and checked; `what` names it in errors.
pub fn parse_record(text: &str, what: &str) -> Result<MapReference, Error> {
    // A byte-order mark is dropped, as every other reader does.
    let text = text.strip_prefix('\u{FEFF}').unwrap_or(text);
    let r: MapReference = serde_json::from_str(text)
        .map_err(|e| Error::input(what, format!("not a reference record: {e}")))?;
    r.check().map_err(|e| Error::input(what, e))?;
    Ok(r)
}

/// The record at `path` through the bounded reader, or None when there is none.
pub fn read_record(path: &Path) -> Result<Option<MapReference>, Error> {
    if !path.exists() {
        return Ok(None);
    }
    let what = format!("reference {}", path.display());
    let bytes = protocol::config::read_bytes_bounded(path, MAX_RECORD_BYTES, "a reference record")
        .map_err(|e| Error::input(&what, e))?;
    let text = String::from_utf8(bytes).map_err(|_| Error::input(&what, "not UTF-8 text"))?;
    parse_record(&text, &what).map(Some)
}

/// The record as written (pretty JSON, a newline at the end).
pub fn record_json(r: &MapReference) -> String {
    let mut t = serde_json::to_string_pretty(r).expect("a reference serializes");
    t.push('\n');
    t
}

/// The largest shift a reference frame may report, um: `max_shift_um`, and on a plain
/// dot grid at most half a pitch (the frame gives the position only modulo the pitch: a
/// shift of half a pitch is another lattice point). A coded board reads its absolute
/// position, so only `max_shift_um` bounds it.
pub fn shift_bound_um(job: &Job, max_shift_um: f64) -> f64 {
    match job.board.code {
        Some(_) => max_shift_um,
        None => max_shift_um.min(job.board.pitch_mm * 500.0),
    }
}

/// Seconds since 1970 of `t`, and the same as RFC 3339.
pub(crate) fn at(t: SystemTime) -> (u64, String) {
    (crate::context::unix_s(t), errormap::scan::rfc3339(t))
}

/// Which reference a program is compensated with.
#[derive(Debug, Clone, PartialEq)]
pub enum Choice {
    /// The map's current reference.
    Recorded(MapReference),
    /// None is recorded: the map applies as scanned (a warning says what that costs).
    NoneRecorded,
    /// The operator asked for none (`--no-reference`).
    NotWanted,
}

/// The choice from the map's current record as the context found it: `no_reference`
/// (the operator's flag) wins; else the record if there is one. A record that is there
/// but cannot be read (damaged, another map's) is an error: the operator records a new
/// one, or asks for none.
pub fn choose(
    current: Result<Option<MapReference>, Error>,
    no_reference: bool,
) -> Result<Choice, Error> {
    Ok(match (current, no_reference) {
        (_, true) => Choice::NotWanted,
        (Ok(Some(r)), false) => Choice::Recorded(r),
        (Ok(None), false) => Choice::NoneRecorded,
        (Err(e), false) => return Err(e),
    })
}

/// The context's map and the reference that applies to it, for a kind that applies a
/// map without measuring (rewrite, dnc): refused when the map was measured on another
/// machine than the context's (when it knows one), the reference by [`choose`].
pub async fn active_map(
    cx: &mut dyn crate::Context,
    no_reference: bool,
) -> Result<(ErrorMap, Choice), Error> {
    let active = cx.map().map_err(|e| Error::Input(e.to_string()))?;
    if let Some(here) = (cx.identity().await).map_err(|e| Error::Device(e.to_string()))? {
        crate::check_identity(&active.map, &here, &active.name)?;
    }
    let choice = choose(active.reference, no_reference)?;
    Ok((active.map, choice))
}

/// What applying a choice gave: the model, one line saying which reference and how old
/// (for a program's header, a log, a sender), a warning when there is none, and the
/// record's fields for a result (none when no record applies).
pub struct Applied {
    pub model: MapModel,
    pub describe: String,
    pub warning: Option<String>,
    pub record: Option<AppliedReference>,
}

/// The recorded reference a map was applied with, as a result shows it (`rewrite`,
/// `dnc`, `proxy`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct AppliedReference {
    /// When it was recorded (RFC 3339).
    pub measured_at: String,
    /// Its age when applied, s.
    pub age_s: u64,
    /// Its number since the scan, from 1.
    pub reference_count: u64,
    /// The machine zero's shift it applies, um.
    pub shift_um: [f64; 2],
    /// The controller's homing count, when it reports one.
    pub homing_count: Option<u64>,
    /// The machine's temperature, when known, degrees C.
    pub temperature_c: Option<f64>,
}

/// A reference after homing: the shift measured, the record kept.
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ReferenceResult {
    /// The camera's error at the reference point (observed - nominal), um.
    pub seen_um: [f64; 2],
    /// The machine zero's shift since the scan, um: what the map is shifted by.
    pub shift_um: [f64; 2],
    /// The zero's drift since the previous record, um (null: none).
    pub drift_since_previous_um: Option<[f64; 2]>,
    /// When the previous record was measured (null: none).
    pub previous_measured_at: Option<String>,
    /// The map's reference point, machine mm.
    pub reference_mm: [f64; 2],
    /// When it was measured (RFC 3339).
    pub measured_at: String,
    /// References of this map so far, this one included.
    pub reference_count: u64,
    /// The controller's homing count, when it reports one.
    pub homing_count: Option<u64>,
    /// The machine's temperature, when known, degrees C.
    pub temperature_c: Option<f64>,
    /// The simulated machine's time of the reference, s (null on a real machine).
    pub machine_time_s: Option<f64>,
    /// Each axis's growth since the scan (`at_mm`, `seen_um`, `ppm`, and `ppm_per_h`
    /// when a previous record allows it); null when the map is too short to measure it.
    #[schema(value_type = Option<Object>)]
    pub scale: Option<Box<AxisScale>>,
    /// Whether it homed first (false: measured in use, where the machine is).
    pub homed: bool,
    /// The record itself, as kept beside the map.
    #[schema(value_type = Object)]
    pub record: MapReference,
    /// Where the record was kept (a file, the map's profile).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub written_to: Option<String>,
    /// The map's previous record could not be read and was replaced: why.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub replaced_damaged_record: Option<String>,
}

/// The map's model under `choice` (a record of another map refused).
pub fn apply(map: ErrorMap, choice: &Choice, now: SystemTime) -> Result<Applied, Error> {
    let model = MapModel::new(map);
    let (now_s, _) = at(now);
    Ok(match choice {
        Choice::Recorded(r) => Applied {
            model: r
                .apply(model, now_s)
                .map_err(|e| Error::Mismatch(format!("the map's reference record: {e}")))?,
            describe: r.describe(now_s),
            warning: None,
            record: Some(AppliedReference {
                measured_at: r.measured_at.clone(),
                age_s: r.age_s(now_s),
                reference_count: r.reference_count,
                shift_um: r.shift_um,
                homing_count: r.homing_count,
                temperature_c: r.temperature_c,
            }),
        },
        Choice::NoneRecorded => Applied {
            model,
            describe: "no reference recorded: the map applies as scanned".into(),
            warning: Some(
                "no reference is recorded for this map: it applies as scanned, and each \
                 homing since the scan moved the machine's zero by a few um (run `gateway \
                 reference` after every homing; --no-reference silences this)"
                    .into(),
            ),
            record: None,
        },
        Choice::NotWanted => Applied {
            model,
            describe: "no reference (--no-reference): the map applies as scanned".into(),
            warning: None,
            record: None,
        },
    })
}

/// Runs the reference: refused before any motion when the map was measured on another
/// machine, controller, board or camera (`what` names the map). `previous` is the
/// record it replaces (its count goes on, the drift since it is reported). The record
/// goes to the sink as [`REFERENCE_ARTIFACT`] only when the shift is sane. The result:
/// [`ReferenceResult`] (`scale`: each axis's growth since the scan, measured at the
/// map's far end along each axis when the map reaches `MIN_SCALE_BASELINE_MM` from the
/// reference point; with its rate since `previous`).
#[allow(clippy::too_many_arguments)]
pub async fn run(
    request: &ReferenceRequest,
    job: &Job,
    devices: &mut Devices,
    map: &ErrorMap,
    what: &str,
    previous: Option<&MapReference>,
    now: SystemTime,
    sink: &mut dyn Sink,
) -> Outcome<ReferenceResult> {
    if let Err(e) = request.check() {
        return Outcome::failed(e.to_string());
    }
    if let Err(e) = crate::check_identity(map, &crate::identity(job, devices), what) {
        return Outcome::failed(e);
    }
    // A record of another map is not continued (nor an error here: it is replaced).
    let previous = previous.filter(|p| p.check_map(map).is_ok());
    let bound_um = shift_bound_um(job, request.max_shift_um);
    let t0 = crate::machine_time_s(devices);
    sink.progress(0, 1);
    // Averaged frames at the reference point and the scale points when the map has
    // them (the scale is a difference of tenths of a micrometre); one frame otherwise.
    let scale_points = errormap::reference::scale_points_mm(map);
    let frames = match scale_points {
        Some(_) => runner::reference::FRAMES_PER_POINT,
        None => 1,
    };
    let stage = devices.stage.as_mut();
    let camera = devices.camera.as_mut();
    let measured = match request.no_home {
        // In use: where the machine is, no homing (it homed before).
        true => runner::reference::measure_mean_at(job, stage, camera, map.reference_mm, frames)
            .await
            .map(|seen_um| runner::reference::ReferenceFrame {
                command_mm: map.reference_mm,
                seen_um,
            }),
        false => {
            runner::reference::measure_reference_mean(job, stage, camera, map.reference_mm, frames)
                .await
        }
    };
    let frame = match measured {
        Ok(f) => f,
        Err(e) => {
            let lost = matches!(e, JobError::Driver(_));
            let error = format!("the reference frame: {e}");
            return Outcome::stopped(false, error, None, Default::default(), lost);
        }
    };
    // Each axis's growth since the scan (thermal), at the map's far end along each axis
    // (issue 39): two more frames, when the map is long enough.
    let scale_seen = match scale_points {
        Some(at_mm) => {
            match runner::reference::measure_scale(
                job,
                stage,
                camera,
                map.reference_mm,
                at_mm,
                frames,
            )
            .await
            {
                Ok(seen) => Some((at_mm, seen)),
                Err(e) => {
                    let lost = matches!(e, JobError::Driver(_));
                    let error = format!("the scale frames: {e}");
                    return Outcome::stopped(false, error, None, Default::default(), lost);
                }
            }
        }
        None => None,
    };
    sink.progress(1, 1);
    let machine_time_s = t0.zip(crate::machine_time_s(devices)).map(|(a, b)| b - a);
    let (now_s, now_text) = at(now);
    let record = match MapReference::new(
        map,
        frame.seen_um,
        bound_um,
        Circumstances {
            measured_at: now_text,
            measured_unix_s: now_s,
            // No controller this gateway drives reports its homings, nor a temperature.
            homing_count: None,
            temperature_c: None,
            previous_count: previous.map_or(0, |p| p.reference_count),
        },
    )
    .and_then(|r| match scale_seen {
        Some((at_mm, seen)) => r.with_scale(map, at_mm, seen, previous),
        None => Ok(r),
    }) {
        Ok(r) => r,
        Err(e) => return Outcome::failed(format!("{what}: {e}")),
    };
    let drift = previous.map(|p| p.drift_um(frame.seen_um));
    if let Err(e) = sink.artifact(Artifact {
        name: REFERENCE_ARTIFACT.into(),
        title: None,
        media_type: "application/json",
        bytes: record_json(&record).into_bytes(),
    }) {
        return Outcome::failed(format!("recording the reference: {e}"));
    }
    let mut metrics = serde_json::Map::new();
    metrics.insert("reference_count".into(), record.reference_count.into());
    metrics.insert("machine_time_s".into(), machine_time_s.into());
    metrics.insert("shift_x_um".into(), record.shift_um[0].into());
    metrics.insert("shift_y_um".into(), record.shift_um[1].into());
    if let Some(s) = &record.scale {
        metrics.insert("scale_x_ppm".into(), s.ppm[0].into());
        metrics.insert("scale_y_ppm".into(), s.ppm[1].into());
    }
    let result = ReferenceResult {
        seen_um: record.seen_um,
        shift_um: record.shift_um,
        drift_since_previous_um: drift,
        previous_measured_at: previous.map(|p| p.measured_at.clone()),
        reference_mm: record.reference_mm,
        measured_at: record.measured_at.clone(),
        reference_count: record.reference_count,
        homing_count: record.homing_count,
        temperature_c: record.temperature_c,
        machine_time_s,
        scale: record.scale.clone(),
        homed: !request.no_home,
        record,
        written_to: None,
        replaced_damaged_record: None,
    };
    Outcome::succeeded(result, metrics)
}

/// The result as text (the CLI's output without `--json`).
pub fn summary(r: &ReferenceResult) -> String {
    let mut t = format!(
        "reference #{}{} at ({:.3}, {:.3}) mm, {}: the camera sees ({:+.2}, {:+.2}) um; \
         the machine's zero moved by ({:+.2}, {:+.2}) um since the scan\n",
        r.reference_count,
        if r.homed { "" } else { " (in use, no homing)" },
        r.reference_mm[0],
        r.reference_mm[1],
        r.measured_at,
        r.seen_um[0],
        r.seen_um[1],
        r.shift_um[0],
        r.shift_um[1],
    );
    if let Some(d) = r.drift_since_previous_um {
        t += &format!(
            "since the previous reference ({}): ({:+.2}, {:+.2}) um\n",
            r.previous_measured_at.as_deref().unwrap_or("?"),
            d[0],
            d[1]
        );
    }
    if let Some(s) = &r.scale {
        t += &format!(
            "the axes grew by ({:+.2}, {:+.2}) ppm since the scan (seen at X {:.3} and Y {:.3} mm)",
            s.ppm[0], s.ppm[1], s.at_mm[0], s.at_mm[1],
        );
        if let Some(rate) = s.ppm_per_h {
            t += &format!(
                ", growing by ({:+.2}, {:+.2}) ppm/h since the previous reference",
                rate[0], rate[1]
            );
        }
        t += "\n";
    }
    if let Some(s) = r.machine_time_s {
        t += &format!("machine time {s:.1} s\n");
    }
    if let Some(p) = &r.written_to {
        t += &format!("recorded in {p}: rewrite, proxy and verify --spot-check use it\n");
    }
    t
}

/// The reference after homing as a registered procedure: the previous record is the
/// map's current one (its count goes on, the drift since it is reported; a damaged one
/// is replaced, said in the result), the new record kept by the context.
pub struct Reference;

impl crate::registry::Procedure for Reference {
    const KIND: &'static str = "reference";
    const TITLE: &'static str = "Reference after homing: one frame at the map's reference point records how far the zero moved";
    const COMMAND: &'static str = "reference";
    const LABEL: &'static str = "Machine zero check";
    const HELP: &'static str =
        "Finds the machine zero on the board again after homing and checks how far it moved.";
    const FIELD_HELP: &'static [(&'static str, &'static str)] = &[
        (
            "max_shift_um",
            "Largest accepted move of the machine zero; more means the board or the camera moved.",
        ),
        (
            "no_home",
            "Measure again where the machine is, without homing: every few minutes while the machine warms up.",
        ),
    ];
    const USES: crate::registry::Uses = crate::registry::Uses::DEVICES_AND_MAP;
    type Request = ReferenceRequest;
    type Result = ReferenceResult;
    const FILES: &'static [FileArg] = command_line::JOB_AND_MAP;

    async fn run(
        request: ReferenceRequest,
        cx: &mut dyn crate::Context,
    ) -> Outcome<ReferenceResult> {
        let stop = cx.stop();
        let now = cx.now();
        let active = crate::or_fail!(cx.map());
        let (previous, replaced) = match &active.reference {
            Ok(p) => (p.clone(), None),
            Err(e) => (None, Some(e.clone())),
        };
        let bench = crate::or_fail!(cx.bench().await);
        let measured = stop
            .unless(run(
                &request,
                bench.job,
                bench.devices,
                &active.map,
                &active.name,
                previous.as_ref(),
                now,
                bench.sink,
            ))
            .await;
        let Some(mut outcome) = measured else {
            let _ = bench.devices.stage.stop().await;
            return Outcome::cancelled("stopped before the reference was recorded");
        };
        if !outcome.is_success() {
            return outcome;
        }
        let Some(result) = outcome.result.as_mut() else {
            return outcome;
        };
        match cx.keep_reference(&result.record) {
            Ok(kept) => result.written_to = Some(kept),
            Err(e) => return Outcome::failed(format!("recording the reference: {e}")),
        }
        if let Some(e) = replaced {
            result.replaced_damaged_record = Some(e.to_string());
        }
        outcome
    }

    fn summary(result: &ReferenceResult) -> String {
        summary(result)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_record_sits_beside_its_map() {
        assert_eq!(
            reference_path(Path::new("maps/demo.v2.json")),
            Path::new("maps/demo.v2.reference.json")
        );
        assert_eq!(
            reference_path(Path::new("m")),
            Path::new("m.reference.json")
        );
    }

    #[test]
    fn the_choice_follows_the_flag_then_the_record() {
        assert_eq!(choose(Ok(None), false), Ok(Choice::NoneRecorded));
        assert_eq!(choose(Ok(None), true), Ok(Choice::NotWanted));
        let e = parse_record("{}", "r").unwrap_err();
        assert!(
            e.to_string().starts_with("r: not a reference record"),
            "{e}"
        );
        // A record that cannot be read is an error, unless none is wanted.
        assert_eq!(choose(Err(e.clone()), false), Err(e.clone()));
        assert_eq!(choose(Err(e), true), Ok(Choice::NotWanted));
    }
}

//! The error-map scan: the plan checked against the machine's area, resumed from the
//! journal of a stopped scan of the same plan, run, and the map kept as a new version.
//!
//! The journal and the map's home are the front end's: the CLI keeps a journal file
//! beside the versions, the service keeps the samples as the job's measurements and the
//! map as an `error_map` profile version. Both resume the same way: a stopped scan's
//! samples are taken back only for the same job, machine, camera, board and plan (the
//! journal's [`journal::Header`]), and the map is written only when every frame is in.

use crate::command_line::{self, FileArg, Plan};
use crate::request::MapRequest;
use crate::{Outcome, Sink};
use devices::Devices;
use errormap::scan::journal;
use errormap::scan::{rfc3339, MapBuilder, Sample, ScanPlan};
use job::Job;
use protocol::errormap::{next_version_path, ErrorMap};
use runner::scan::ScanError;
use runner::JobError;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::cell::{Cell, RefCell};
use std::future::Future;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Instant, SystemTime};

pub use crate::context::{MapShelf, ScanJournal};

/// A scan's result: the plan's shape, then the map kept, or (a stopped scan) how many
/// frames are kept for the next run.
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
pub struct MapResult {
    /// The map's name.
    pub name: String,
    /// The plan in one line (grid, lines, passes): a stopped scan resumes only for the
    /// same plan.
    pub plan: String,
    /// Frames of the whole plan.
    pub frames: usize,
    /// Frames taken back from the journal of a stopped scan.
    pub resumed_frames: usize,
    /// Grid nodes along X and Y.
    pub grid: [usize; 2],
    /// Points of the dense line along X and of the one along Y.
    pub lines: [usize; 2],
    /// Passes over each point from each side.
    pub passes: u32,
    /// A stopped scan: frames taken (kept for the next scan of this plan).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frames_taken: Option<usize>,
    /// Where the journal's samples came from (the front end's words: the service's job
    /// id); free-form.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub resumed_from_job: Option<Value>,
    /// Why a stopped scan's samples were not taken back (free-form, the front end's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub not_resumed: Option<Value>,
    /// The map's version (absent: the scan stopped).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub version: Option<u32>,
    /// Where the map was kept (a file, a profile version).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kept_as: Option<String>,
    /// The map's expanded uncertainty (k = 2), um.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uncertainty_um: Option<f64>,
    /// The simulated machine's time of the scan, s (null on a real machine; absent: the
    /// scan stopped).
    #[serde(
        default,
        deserialize_with = "crate::summary::present",
        skip_serializing_if = "Option::is_none"
    )]
    #[schema(value_type = Option<f64>)]
    pub machine_time_s: Option<Option<f64>>,
    /// The scan's wall time, s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wall_time_s: Option<f64>,
}

/// One scan frame as the sink gets it ([`sample_of`] reads it back): the plan's point
/// index and what the camera saw there.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct ScanMeasurement {
    index: usize,
    ex_um: f64,
    ey_um: f64,
    yaw_urad: f64,
}

/// Runs (or resumes) a scan and keeps the map ([`MapResult`]); a stopped scan's result
/// says how many frames are kept for the next run.
pub async fn run(
    request: &MapRequest,
    job: &Job,
    devices: &mut Devices,
    journal: &mut dyn ScanJournal,
    shelf: &mut dyn MapShelf,
    sink: &mut dyn Sink,
    stop: impl Future<Output = ()>,
) -> Outcome<MapResult> {
    let started = Instant::now();
    let limits = match runner::soft_limits(devices.stage.info()) {
        Ok(l) => l,
        Err(e) => return Outcome::failed(e.to_string()),
    };
    let (lo, hi) = runner::scan::scan_area(job, &limits);
    // The frames the request implies, refused before the plan is built.
    if let Err(e) = request.check_area(lo, hi) {
        return Outcome::failed(e.to_string());
    }
    // On the stage's own steps: the nodes' errors are then not off by its rounding.
    let plan = match ScanPlan::on_steps(lo, hi, request.spec(), stage_steps_mm(devices)) {
        Ok(p) => p,
        Err(e) => return Outcome::failed(format!("the scan plan: {e}")),
    };
    let identity = crate::identity(job, devices);
    let header = journal::Header::new(&job_name(job), identity.clone(), &plan);
    let mut builder = MapBuilder::new();
    let resumed = match journal.resume(&header, &plan) {
        Ok(samples) => {
            for (i, s) in &samples {
                if let Err(e) = builder.record(&plan, *i, *s) {
                    return Outcome::failed(format!("the scan journal: {e}"));
                }
            }
            builder.done()
        }
        Err(e) => return Outcome::failed(format!("the scan journal: {e}")),
    };
    let total = plan.points.len();
    let shape = MapResult {
        name: request.name.clone(),
        plan: plan.fingerprint(),
        frames: total,
        resumed_frames: resumed,
        grid: [plan.xs.len(), plan.ys.len()],
        lines: [plan.x_line.len(), plan.y_line.len()],
        passes: request.passes,
        frames_taken: None,
        resumed_from_job: None,
        not_resumed: None,
        version: None,
        kept_as: None,
        uncertainty_um: None,
        machine_time_s: None,
        wall_time_s: None,
    };
    sink.progress(resumed as u64, total as u64);
    let cancelled = Cell::new(false);
    // Measurements and progress both go to the one sink.
    let shared_sink = RefCell::new(&mut *sink);
    let run = runner::scan::run_scan_frames(
        job,
        devices,
        &plan,
        &mut builder,
        &mut |i, s| {
            journal.append(i, s)?;
            let m = ScanMeasurement {
                index: i,
                ex_um: s.error_um[0],
                ey_um: s.error_um[1],
                yaw_urad: s.yaw_urad,
            };
            let m = serde_json::to_value(m).map_err(|e| e.to_string())?;
            shared_sink
                .borrow_mut()
                .measurement(&m)
                .map_err(String::from)
        },
        &mut |done, of| shared_sink.borrow_mut().progress(done as u64, of as u64),
        // A live view's frame: one that cannot be made is skipped.
        &mut |seen| {
            if let Ok(thumb) = crate::frame::thumbnail(seen) {
                shared_sink.borrow_mut().frame(&thumb);
            }
        },
        async {
            stop.await;
            cancelled.set(true);
        },
    )
    .await;
    let reference = match run {
        Ok(r) => r,
        Err(e) => {
            let mut result = shape;
            result.frames_taken = Some(builder.done());
            note_resume(&mut result, journal.resumed_from());
            let lost = matches!(
                e,
                ScanError::Reference(JobError::Driver(_))
                    | ScanError::Point {
                        source: JobError::Driver(_),
                        ..
                    }
            );
            let error = format!(
                "{e}; {} of {total} frames are kept and the next scan of this plan resumes there",
                builder.done()
            );
            return Outcome::stopped(
                cancelled.get(),
                error,
                Some(result),
                Default::default(),
                lost,
            );
        }
    };
    let version = match shelf.next_version(&request.name) {
        Ok(v) => v,
        Err(e) => return Outcome::failed(format!("the map's version: {e}")),
    };
    let Some(map) = builder.finish(
        &plan,
        identity,
        version,
        rfc3339(SystemTime::now()),
        request.tool_offset_mm,
        job.board_at_machine_zero_mm,
        reference.command_mm,
    ) else {
        return Outcome::failed("the scan ended without every frame");
    };
    let kept_as = match shelf.keep(&request.name, &map) {
        Ok(k) => k,
        Err(e) => {
            return Outcome::failed(format!(
                "the map was measured but not kept: {e}; the journal still holds every frame"
            ))
        }
    };
    journal.close();
    let mut result = shape;
    note_resume(&mut result, journal.resumed_from());
    result.version = Some(version);
    result.kept_as = Some(kept_as);
    result.uncertainty_um = Some(map.uncertainty_um);
    result.machine_time_s = Some(crate::machine_time_s(devices));
    result.wall_time_s = Some(started.elapsed().as_secs_f64());
    let metrics = [
        ("frames", result.frames.into()),
        ("uncertainty_um", map.uncertainty_um.into()),
        ("version", version.into()),
    ];
    let metrics = metrics.into_iter().map(|(k, v)| (k.into(), v)).collect();
    Outcome::succeeded(result, metrics)
}

/// The stage's smallest step on X and Y, mm (0 where it does not say).
fn stage_steps_mm(devices: &Devices) -> [f64; 2] {
    let info = devices.stage.info();
    [drivers::Axis::X, drivers::Axis::Y].map(|a| info.axis(a).map_or(0.0, |i| i.resolution_mm))
}

/// The job as a journal names it: its file's name (where it is may change between a
/// stopped scan and its resumption).
pub fn job_name(job: &Job) -> String {
    Path::new(&job.source)
        .file_name()
        .map_or_else(|| job.source.clone(), |n| n.to_string_lossy().into_owned())
}

/// Where a scan's samples came from (`resumed_from_job`), or why a stopped scan was not
/// resumed (`not_resumed`), in its result.
fn note_resume(result: &mut MapResult, from: Option<Value>) {
    match from {
        Some(Value::Object(o)) if o.contains_key("not_resumed") => {
            result.not_resumed = Some(o["not_resumed"].clone())
        }
        Some(from) => result.resumed_from_job = Some(from),
        None => {}
    }
}

/// The journal file ([`journal`]'s format): a header naming the job, machine and plan,
/// then one checksummed line per sample, written to the disk as each comes. A resume
/// cuts a torn last line off (the file is replaced atomically by its whole lines) before
/// anything is appended.
pub struct FileJournal {
    path: PathBuf,
    file: Option<std::fs::File>,
}

impl FileJournal {
    pub fn new(path: PathBuf) -> Self {
        Self { path, file: None }
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl ScanJournal for FileJournal {
    fn resume(
        &mut self,
        header: &journal::Header,
        plan: &ScanPlan,
    ) -> Result<Vec<(usize, Sample)>, crate::Error> {
        let shown = self.path.display();
        let write = |bytes: &[u8]| {
            // The journal replaces the one it read (never a link to another file read).
            protocol::config::replace_output(&self.path, bytes, &[])
                .map_err(|e| crate::Error::Output(format!("writing {shown}: {e}")))
        };
        let samples = match read_journal(&self.path, plan) {
            Ok(bytes) => {
                let read = journal::read(header, plan, &bytes).map_err(|e| {
                    crate::Error::Input(format!("{shown}: {e} (remove it to start a new scan)"))
                })?;
                if read.whole_bytes == 0 {
                    // Not even the header was whole: nothing was kept.
                    write(header.line().as_bytes())?;
                } else if read.torn_bytes > 0 {
                    // A line cut while it was written: the whole lines replace the file
                    // before anything is appended (never a sample glued to a torn one).
                    write(&bytes[..read.whole_bytes])?;
                }
                read.samples
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                write(header.line().as_bytes())?;
                Vec::new()
            }
            Err(e) => return Err(crate::Error::input(shown, e)),
        };
        let file = std::fs::OpenOptions::new()
            .append(true)
            .open(&self.path)
            .map_err(|e| crate::Error::Output(format!("opening {shown}: {e}")))?;
        self.file = Some(file);
        Ok(samples)
    }

    fn append(&mut self, index: usize, sample: &Sample) -> Result<(), crate::Error> {
        let file = (self.file.as_mut())
            .ok_or_else(|| crate::Error::Output("the journal is not open".into()))?;
        // One write of the whole line, then to the disk: an interruption leaves whole
        // lines and at most one torn last line.
        file.write_all(journal::line(index, sample).as_bytes())
            .and_then(|()| file.sync_data())
            .map_err(|e| crate::Error::Output(format!("{}: {e}", self.path.display())))
    }

    fn close(&mut self) {
        self.file = None;
        std::fs::remove_file(&self.path).ok();
    }
}

/// A journal file's bytes through the bounded reader, of at most what a journal of
/// `plan` can hold (a header of a few hundred bytes, sample lines of about 90).
fn read_journal(path: &Path, plan: &ScanPlan) -> std::io::Result<Vec<u8>> {
    let cap = 64 * 1024 + 256 * plan.points.len() as u64;
    protocol::config::read_bytes_bounded(path, cap, "a scan journal of this plan")
}

/// Map versions in a folder, `NAME.vN.json`, never overwritten.
pub struct FolderShelf {
    dir: PathBuf,
    next: Option<(u32, PathBuf)>,
}

impl FolderShelf {
    pub fn new(dir: &Path) -> Self {
        Self {
            dir: dir.to_path_buf(),
            next: None,
        }
    }
}

impl MapShelf for FolderShelf {
    fn next_version(&mut self, name: &str) -> Result<u32, crate::Error> {
        let (v, path) =
            next_version_path(&self.dir, name).map_err(|e| crate::Error::Output(e.to_string()))?;
        self.next = Some((v, path));
        Ok(v)
    }

    fn keep(&mut self, _: &str, map: &ErrorMap) -> Result<String, crate::Error> {
        let (_, path) = (self.next.take())
            .ok_or_else(|| crate::Error::Output("no version was reserved".into()))?;
        map.save_new(&path)
            .map_err(|e| crate::Error::Output(e.to_string()))?;
        Ok(path.display().to_string())
    }
}

/// A scan sample from a measurement the map procedure handed to its sink.
/// (The sink's measurements are JSON: [`crate::Sink::measurement`].)
pub fn sample_of(measurement: &Value) -> Option<(usize, Sample)> {
    let m = ScanMeasurement::deserialize(measurement).ok()?;
    let sample = Sample {
        error_um: [m.ex_um, m.ey_um],
        yaw_urad: m.yaw_urad,
    };
    let finite = sample.error_um.iter().all(|v| v.is_finite()) && sample.yaw_urad.is_finite();
    finite.then_some((m.index, sample))
}

/// The result as text (the CLI's output without `--json`).
pub fn summary(r: &MapResult) -> String {
    let Some(version) = r.version else {
        let taken = r.frames_taken.map_or("-".into(), |n| n.to_string());
        return format!(
            "{taken} of {} frames are kept for the next scan of this plan\n",
            r.frames
        );
    };
    format!(
        "map {} (version {version}): {} x {} grid, lines of {} and {} points, {} passes, {} frames ({} resumed), uncertainty {:.3} um (k = 2), {:.1} s\n",
        r.kept_as.as_deref().unwrap_or(""),
        r.grid[0],
        r.grid[1],
        r.lines[0],
        r.lines[1],
        r.passes,
        r.frames,
        r.resumed_frames,
        r.uncertainty_um.unwrap_or(f64::NAN),
        r.wall_time_s.unwrap_or(0.0)
    )
}

/// The error-map scan as a registered procedure.
pub struct Map;

impl crate::registry::Procedure for Map {
    const KIND: &'static str = "map";
    const TITLE: &'static str =
        "Error map: scan the travel once, so programs run accurately without the camera";
    const COMMAND: &'static str = "map";
    const LABEL: &'static str = "Error map scan";
    const HELP: &'static str = "Scans the board over the travel and makes a new version of the error map (not used until you activate it). A stopped scan continues where it stopped when started again with the same settings.";
    const FIELD_HELP: &'static [(&'static str, &'static str)] = &[
        ("name", "The error map this scan makes a new version of."),
        (
            "grid_step_mm",
            "Distance between map points: smaller is finer and slower.",
        ),
        (
            "line_step_mm",
            "Distance between pictures along each scanned line.",
        ),
        ("passes", "How often each point is measured from each side."),
        (
            "tool_offset_mm",
            "Tool point minus camera centre on the machine axes: X and Y, e.g. 0; 0.",
        ),
    ];
    const USES: crate::registry::Uses = crate::registry::Uses::DEVICES;
    type Request = MapRequest;
    type Result = MapResult;
    const FILES: &'static [FileArg] = &[
        FileArg::required("config", "The job file of the machine.", |path, plan| {
            // The map is named after the job file unless --name says otherwise.
            if let Some(stem) = path.file_stem() {
                plan.set("name", stem.to_string_lossy().into_owned());
            }
            command_line::job(path, plan)
        }),
        FileArg::required(
            "out",
            "Folder of the map versions (and the scan's journal).",
            command_line::out_folder,
        ),
        FileArg::flag(
            "name",
            "Map name (default: the job file's name).",
            |name, plan: &mut Plan| {
                plan.set("name", name.to_string_lossy().into_owned());
                Ok(())
            },
        )
        .value_name("NAME"),
    ];
    const STEPS: &'static str = "frames";

    async fn run(request: MapRequest, cx: &mut dyn crate::Context) -> Outcome<MapResult> {
        let stop = cx.stop();
        let (mut journal, mut shelf) = match (cx.scan_journal(&request.name), cx.map_shelf()) {
            (Ok(j), Ok(s)) => (j, s),
            (Err(e), _) | (_, Err(e)) => return Outcome::failed(e.to_string()),
        };
        let bench = crate::or_fail!(cx.bench().await);
        run(
            &request,
            bench.job,
            bench.devices,
            journal.as_mut(),
            shelf.as_mut(),
            bench.sink,
            stop.requested(),
        )
        .await
    }

    fn summary(result: &MapResult) -> String {
        summary(result)
    }

    fn admit(
        request: &MapRequest,
        facts: &crate::registry::Facts,
    ) -> Result<(), crate::RequestError> {
        match facts.scan_area {
            Some((lo, hi)) => request.check_area(lo, hi).map(|_| ()),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use errormap::scan::ScanSpec;
    use protocol::errormap::Identity;

    fn plan() -> ScanPlan {
        // 2 x 2 grid nodes and lines of 3 points, both sides, 2 passes: 40 frames.
        let spec = ScanSpec {
            grid_step_mm: 10.0,
            line_step_mm: 5.0,
            passes: 2,
        };
        ScanPlan::new([0.0, 0.0], [10.0, 10.0], spec).unwrap()
    }

    fn header(plan: &ScanPlan) -> journal::Header {
        let identity = Identity {
            machine: "sim".into(),
            controller: "sim".into(),
            board: "b".into(),
            certificate_sha256: "00".into(),
            camera: "cam".into(),
        };
        journal::Header::new("job.toml", identity, plan)
    }

    /// What the camera saw at point `k` (a slope, a backlash, a wobble between passes).
    fn sample(plan: &ScanPlan, k: usize) -> Sample {
        let p = plan.points[k];
        Sample {
            error_um: [
                0.1 * p.command_mm[0] + if p.pass == 0 { 0.2 } else { -0.3 },
                -0.07 * p.command_mm[1] + 0.01 * k as f64,
            ],
            yaw_urad: 3.0 - 0.5 * p.pass as f64,
        }
    }

    fn map_of(plan: &ScanPlan, samples: &[(usize, Sample)]) -> Option<ErrorMap> {
        let mut b = MapBuilder::new();
        for (i, s) in samples {
            b.record(plan, *i, *s).unwrap();
        }
        b.finish(
            plan,
            header(plan).identity,
            1,
            "t".into(),
            [0.0; 2],
            [5.0; 2],
            [5.0, 5.0],
        )
    }

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("map-journal-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    /// Resume from `path` (as a new run would) and measure what is missing: the first
    /// `through_journal` missing frames are appended to the journal (the others only go
    /// to the map). The samples the journal kept, and the map.
    fn resume_and_finish(
        path: &Path,
        plan: &ScanPlan,
        through_journal: usize,
    ) -> Result<(usize, Option<ErrorMap>), String> {
        let mut j = FileJournal::new(path.to_path_buf());
        let kept = j.resume(&header(plan), plan)?;
        let mut all = kept.clone();
        let mut appended = 0;
        for k in 0..plan.points.len() {
            if !kept.iter().any(|(i, _)| *i == k) {
                let s = sample(plan, k);
                if appended < through_journal {
                    j.append(k, &s)?;
                    appended += 1;
                }
                all.push((k, s));
            }
        }
        Ok((kept.len(), map_of(plan, &all)))
    }

    #[test]
    fn a_scan_interrupted_at_any_byte_of_its_journal_resumes_to_the_same_map() {
        let plan = plan();
        let dir = scratch("every-byte");
        let path = dir.join("m.scan.jsonl");
        // The uninterrupted scan.
        let (kept, want) = resume_and_finish(&path, &plan, usize::MAX).unwrap();
        assert_eq!(kept, 0);
        let want = want.expect("every frame");
        let whole = std::fs::read(&path).unwrap();
        let samples = FileJournal::new(path.clone())
            .resume(&header(&plan), &plan)
            .unwrap();
        assert_eq!(map_of(&plan, &samples).as_ref(), Some(&want));
        let ends: Vec<usize> = (0..whole.len())
            .filter(|&k| whole[k] == b'\n')
            .map(|k| k + 1)
            .collect();
        // Cut at every byte (0: the file was created and nothing written yet), resumed
        // and finished: the journal kept exactly its whole lines, the next sample
        // appended after them is a whole line of its own, and the map is the same.
        for cut in 0..=whole.len() {
            std::fs::write(&path, &whole[..cut]).unwrap();
            let (kept, map) =
                resume_and_finish(&path, &plan, 1).unwrap_or_else(|e| panic!("cut at {cut}: {e}"));
            let lines = ends.iter().filter(|&&e| e <= cut).count();
            assert_eq!(kept, lines.saturating_sub(1), "cut at {cut}");
            assert_eq!(map.as_ref(), Some(&want), "cut at {cut}");
            let again = std::fs::read(&path).unwrap();
            let next = ends[lines.max(1).min(ends.len() - 1)];
            assert!(
                again == whole[..next],
                "cut at {cut}: the resumed journal differs"
            );
        }
        // Cut twice (a resumed scan interrupted again), resumed to the end through the
        // journal: the same file, byte for byte, and the same map from it.
        for (a, b) in [(0, 300), (500, 700), (whole.len() / 2, whole.len() - 3)] {
            std::fs::write(&path, &whole[..a]).unwrap();
            resume_and_finish(&path, &plan, usize::MAX).unwrap();
            let text = std::fs::read(&path).unwrap();
            std::fs::write(&path, &text[..b]).unwrap();
            resume_and_finish(&path, &plan, usize::MAX).unwrap();
            assert!(
                std::fs::read(&path).unwrap() == whole,
                "cuts at {a} and {b}"
            );
            let read = FileJournal::new(path.clone())
                .resume(&header(&plan), &plan)
                .unwrap();
            assert_eq!(map_of(&plan, &read).as_ref(), Some(&want));
        }
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn a_journal_of_another_scan_is_refused_and_left_alone() {
        let plan = plan();
        let dir = scratch("other");
        let path = dir.join("m.scan.jsonl");
        let mut j = FileJournal::new(path.clone());
        j.resume(&header(&plan), &plan).unwrap();
        j.append(0, &sample(&plan, 0)).unwrap();
        drop(j);
        let before = std::fs::read(&path).unwrap();
        let mut other = header(&plan);
        other.identity.camera = "another camera".into();
        let e = FileJournal::new(path.clone())
            .resume(&other, &plan)
            .unwrap_err();
        // Another scan's journal is an input refused, not an output that failed.
        assert!(matches!(e, crate::Error::Input(_)), "{e:?}");
        let e = e.to_string();
        assert!(
            e.contains("its camera is `cam`, this scan's is `another camera`")
                && e.contains("remove it to start a new scan"),
            "{e}"
        );
        assert!(std::fs::read(&path).unwrap() == before);
        // A FIFO is refused before it is opened (never a hang).
        let fifo = dir.join("fifo.scan.jsonl");
        if std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .is_ok_and(|s| s.success())
        {
            let e = FileJournal::new(fifo)
                .resume(&header(&plan), &plan)
                .unwrap_err()
                .to_string();
            assert!(e.contains("not a regular file"), "{e}");
        }
        std::fs::remove_dir_all(&dir).ok();
    }
}

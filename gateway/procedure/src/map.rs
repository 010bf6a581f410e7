//! The error-map scan: the plan checked against the machine's area, resumed from the
//! journal of a stopped scan of the same plan, run, and the map kept as a new version.
//!
//! The journal and the map's home are the front end's: the CLI keeps a journal file
//! beside the versions, the service keeps the samples as the job's measurements and the
//! map as an `error_map` profile version. Both resume the same way: a stopped scan's
//! samples are taken back only for the same plan (its fingerprint), and the map is
//! written only when every frame is in.

use crate::request::MapRequest;
use crate::{Outcome, Sink};
use devices::Devices;
use errormap::scan::journal;
use errormap::scan::{rfc3339, MapBuilder, Sample, ScanPlan};
use job::Job;
use protocol::errormap::{next_version_path, ErrorMap};
use runner::scan::ScanError;
use runner::JobError;
use serde_json::{json, Value};
use std::cell::{Cell, RefCell};
use std::future::Future;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Instant, SystemTime};

/// Where a scan's samples are kept as they come, and where a stopped scan's are found.
pub trait ScanJournal {
    /// The samples a stopped scan of this plan kept (empty for a new scan); an error
    /// when what is there belongs to another plan or is damaged.
    fn resume(&mut self, plan: &ScanPlan) -> Result<Vec<(usize, Sample)>, String>;
    /// Keeps one sample (a failure stops the scan with the stage stopped).
    fn append(&mut self, index: usize, sample: &Sample) -> Result<(), String>;
    /// The map is kept: the journal has done its job.
    fn close(&mut self);
}

/// Where the finished map goes.
pub trait MapShelf {
    /// The version the next map of `name` gets.
    fn next_version(&mut self, name: &str) -> Result<u32, String>;
    /// Keeps the map; returns where it went (a path, a profile), for the result.
    fn keep(&mut self, name: &str, map: &ErrorMap) -> Result<String, String>;
}

/// Runs (or resumes) a scan and keeps the map. The result: `name`, `version`, `kept_as`,
/// `frames`, `resumed_frames`, `grid`, `lines`, `passes`, `uncertainty_um`,
/// `machine_time_s` (simulated machines), `wall_time_s`; a stopped scan's result says
/// how many frames are kept for the next run.
pub async fn run(
    request: &MapRequest,
    job: &Job,
    devices: &mut Devices,
    journal: &mut dyn ScanJournal,
    shelf: &mut dyn MapShelf,
    sink: &mut dyn Sink,
    stop: impl Future<Output = ()>,
) -> Outcome {
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
    let plan = match ScanPlan::new(lo, hi, request.spec()) {
        Ok(p) => p,
        Err(e) => return Outcome::failed(format!("the scan plan: {e}")),
    };
    let identity = crate::identity(job, devices);
    let mut builder = MapBuilder::new();
    let resumed = match journal.resume(&plan) {
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
    let shape = json!({
        "name": request.name, "plan": plan.fingerprint(), "frames": total, "resumed_frames": resumed,
        "grid": [plan.xs.len(), plan.ys.len()],
        "lines": [plan.x_line.len(), plan.y_line.len()], "passes": request.passes,
    });
    sink.progress(resumed as u64, total as u64);
    let cancelled = Cell::new(false);
    // Measurements and progress both go to the one sink.
    let shared_sink = RefCell::new(&mut *sink);
    let run = runner::scan::run_scan(
        job,
        devices,
        &plan,
        &mut builder,
        &mut |i, s| {
            journal.append(i, s)?;
            shared_sink.borrow_mut().measurement(&json!({"index": i, "ex_um": s.error_um[0], "ey_um": s.error_um[1], "yaw_urad": s.yaw_urad}))
        },
        &mut |done, of| shared_sink.borrow_mut().progress(done as u64, of as u64),
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
            result["frames_taken"] = json!(builder.done());
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
    let obj = result.as_object_mut().expect("an object");
    obj.insert("version".into(), json!(version));
    obj.insert("kept_as".into(), json!(kept_as));
    obj.insert("uncertainty_um".into(), json!(map.uncertainty_um));
    obj.insert(
        "machine_time_s".into(),
        json!(crate::machine_time_s(devices)),
    );
    obj.insert("wall_time_s".into(), json!(started.elapsed().as_secs_f64()));
    let metrics = crate::metrics_from(&result, &["frames", "uncertainty_um", "version"]);
    Outcome::succeeded(result, metrics)
}

/// The journal file: a header naming the plan, then one line per sample, flushed as
/// each comes.
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
    fn resume(&mut self, plan: &ScanPlan) -> Result<Vec<(usize, Sample)>, String> {
        let shown = self.path.display();
        let samples = if self.path.exists() {
            let text = protocol::config::read_data_file(&self.path)
                .map_err(|e| format!("{shown}: {e}"))?;
            journal::read(plan, &text)
                .map_err(|e| format!("{shown}: {e} (remove it to start a new scan)"))?
        } else {
            protocol::config::write_output(&self.path, journal::header(plan).as_bytes(), &[])
                .map_err(|e| format!("writing {shown}: {e}"))?;
            Vec::new()
        };
        let file = std::fs::OpenOptions::new()
            .append(true)
            .open(&self.path)
            .map_err(|e| format!("opening {shown}: {e}"))?;
        self.file = Some(file);
        Ok(samples)
    }

    fn append(&mut self, index: usize, sample: &Sample) -> Result<(), String> {
        let file = self.file.as_mut().ok_or("the journal is not open")?;
        file.write_all(journal::line(index, sample).as_bytes())
            .and_then(|()| file.flush())
            .map_err(|e| format!("{}: {e}", self.path.display()))
    }

    fn close(&mut self) {
        self.file = None;
        std::fs::remove_file(&self.path).ok();
    }
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
    fn next_version(&mut self, name: &str) -> Result<u32, String> {
        let (v, path) = next_version_path(&self.dir, name).map_err(|e| e.to_string())?;
        self.next = Some((v, path));
        Ok(v)
    }

    fn keep(&mut self, _: &str, map: &ErrorMap) -> Result<String, String> {
        let (_, path) = self.next.take().ok_or("no version was reserved")?;
        map.save_new(&path).map_err(|e| e.to_string())?;
        Ok(path.display().to_string())
    }
}

/// A scan sample from a measurement the map procedure handed to its sink.
pub fn sample_of(measurement: &Value) -> Option<(usize, Sample)> {
    let index = measurement.get("index")?.as_u64()? as usize;
    let f = |k: &str| measurement.get(k)?.as_f64().filter(|v| v.is_finite());
    Some((
        index,
        Sample {
            error_um: [f("ex_um")?, f("ey_um")?],
            yaw_urad: f("yaw_urad")?,
        },
    ))
}

/// The result as text (the CLI's output without `--json`).
pub fn summary(r: &Value) -> String {
    if r.get("version").is_none() {
        return format!(
            "{} of {} frames are kept for the next scan of this plan\n",
            r["frames_taken"], r["frames"]
        );
    }
    format!(
        "map {} (version {}): {} x {} grid, lines of {} and {} points, {} passes, {} frames ({} resumed), uncertainty {:.3} um (k = 2), {:.1} s\n",
        r["kept_as"].as_str().unwrap_or(""),
        r["version"],
        r["grid"][0],
        r["grid"][1],
        r["lines"][0],
        r["lines"][1],
        r["passes"],
        r["frames"],
        r["resumed_frames"],
        r["uncertainty_um"].as_f64().unwrap_or(f64::NAN),
        r["wall_time_s"].as_f64().unwrap_or(0.0)
    )
}

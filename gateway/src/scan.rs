//! `gateway map`: the scan with its journal, progress bar and versioned output.

use anyhow::Context;
use devices::open_devices_async;
use errormap::scan::{journal, rfc3339, without_link, MapBuilder, ScanPlan, ScanSpec};
use indicatif::{ProgressBar, ProgressStyle};
use job::Job;
use protocol::errormap::{next_version_path, Identity};
use runner::scan::{run_scan, scan_area};
use serde_json::json;
use std::io::Write;
use std::path::Path;
use std::process::ExitCode;
use std::time::{Instant, SystemTime};

pub fn map(
    job: &Job,
    spec: ScanSpec,
    out: &Path,
    name: &str,
    tool_offset_mm: [f64; 2],
    json_out: bool,
) -> anyhow::Result<ExitCode> {
    let started = Instant::now();
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    let mut devices = rt.block_on(open_devices_async(job))?;
    let stage_name = without_link(&devices.stage.info().name);
    let limits = runner::soft_limits(devices.stage.info())?;
    let (lo, hi) = scan_area(job, &limits);
    let plan = ScanPlan::new(lo, hi, spec).context("the scan plan")?;
    let identity = Identity {
        machine: stage_name.clone(),
        controller: stage_name,
        board: job.board.name.clone(),
        certificate_sha256: job.board.fingerprint_sha256(),
        camera: devices.camera.info().model.clone(),
    };
    // Resume from the journal of a stopped scan of the same plan.
    let journal_path = out.join(format!("{name}.scan.jsonl"));
    let mut builder = MapBuilder::new();
    let resumed = if journal_path.exists() {
        let text = std::fs::read_to_string(&journal_path)
            .with_context(|| format!("reading {}", journal_path.display()))?;
        let samples = journal::read(&plan, &text).map_err(|e| {
            anyhow::anyhow!(
                "{}: {e} (remove it to start a new scan)",
                journal_path.display()
            )
        })?;
        for (i, s) in &samples {
            builder.record(&plan, *i, *s)?;
        }
        samples.len()
    } else {
        std::fs::write(&journal_path, journal::header(&plan))
            .with_context(|| format!("writing {}", journal_path.display()))?;
        0
    };
    let mut journal_file = std::fs::OpenOptions::new()
        .append(true)
        .open(&journal_path)
        .with_context(|| format!("opening {}", journal_path.display()))?;
    let total = plan.points.len();
    let bar = if json_out {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(total as u64)
    };
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} scanning [{bar:30}] {pos}/{len} frames, {elapsed} so far, about {eta} left",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    bar.set_position(resumed as u64);
    bar.reset_eta();
    let interrupted = async {
        if tokio::signal::ctrl_c().await.is_err() {
            std::future::pending::<()>().await;
        }
    };
    let result = rt.block_on(run_scan(
        job,
        &mut devices,
        &plan,
        &mut builder,
        &mut |i, s| {
            journal_file
                .write_all(journal::line(i, s).as_bytes())
                .and_then(|()| journal_file.flush())
                .map_err(|e| format!("{}: {e}", journal_path.display()))
        },
        &mut |done, _| bar.set_position(done as u64),
        interrupted,
    ));
    bar.finish_and_clear();
    let reference = match result {
        Ok(r) => r,
        Err(e) => {
            anyhow::bail!(
                "{e}; {} of {total} frames are kept in {} and the next run resumes there",
                builder.done(),
                journal_path.display()
            )
        }
    };
    let (version, path) = next_version_path(out, name)?;
    let map = builder
        .finish(
            &plan,
            identity,
            version,
            rfc3339(SystemTime::now()),
            tool_offset_mm,
            job.board_at_machine_zero_mm,
            reference.command_mm,
        )
        .expect("every plan point was measured");
    map.save_new(&path)?;
    std::fs::remove_file(&journal_path).ok();
    let machine_time_s = devices
        .rig
        .as_ref()
        .map(|rig| world::lock(rig).machine().now_s());
    if json_out {
        println!(
            "{}",
            json!({
                "map": path.display().to_string(), "version": version, "frames": total,
                "resumed_frames": resumed, "grid": [plan.xs.len(), plan.ys.len()],
                "lines": [plan.x_line.len(), plan.y_line.len()], "passes": spec.passes,
                "uncertainty_um": map.uncertainty_um, "wall_time_s": started.elapsed().as_secs_f64(),
                "machine_time_s": machine_time_s,
            })
        );
    } else {
        println!(
            "map {} (version {version}): {} x {} grid, lines of {} and {} points, {} passes, {total} frames ({resumed} resumed), uncertainty {:.3} um (k = 2), {:.1} s",
            path.display(),
            plan.xs.len(),
            plan.ys.len(),
            plan.x_line.len(),
            plan.y_line.len(),
            spec.passes,
            map.uncertainty_um,
            started.elapsed().as_secs_f64()
        );
    }
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::UNIX_EPOCH;

    #[test]
    fn stage_names_lose_their_link_and_times_are_rfc3339() {
        assert_eq!(without_link("GRBL 1.1h at /dev/pts/3"), "GRBL 1.1h");
        assert_eq!(
            without_link("CANopen CiA 402 on slcan /dev/pts/4 @ 1000000 bit/s"),
            "CANopen CiA 402"
        );
        assert_eq!(without_link("sim stage"), "sim stage");
        assert_eq!(without_link("GRBL 1.1h (GRBL at /dev/pts/3)"), "GRBL 1.1h");
        assert_eq!(
            without_link("sim stage (ordinary C5 ballscrew X-Y stage, 200 x 150 mm)"),
            "sim stage (ordinary C5 ballscrew X-Y stage, 200 x 150 mm)"
        );
        let t = UNIX_EPOCH + std::time::Duration::from_secs(1_795_381_200);
        assert_eq!(rfc3339(t), "2026-11-22T21:00:00Z");
        assert_eq!(rfc3339(UNIX_EPOCH), "1970-01-01T00:00:00Z");
    }
}

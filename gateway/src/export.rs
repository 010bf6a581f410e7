//! `gateway export`: the map as a controller's own compensation table.

use anyhow::Context;
use errormap::export::{beckhoff_plane, linuxcnc_joint, plain_csv, LINUXCNC_MAX_ENTRIES};
use errormap::MapModel;
use protocol::errormap::ErrorMap;
use serde_json::json;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

pub struct ExportArgs {
    pub map: PathBuf,
    pub format: String,
    pub out: PathBuf,
    pub tolerance_um: f64,
    pub entries: usize,
    pub interval_mm: f64,
    pub json: bool,
}

/// `OUT` with `_x`/`_y` before its extension (one table per axis).
fn per_axis(out: &Path, axis: &str) -> PathBuf {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let name = match out.extension() {
        Some(e) => format!("{stem}_{axis}.{}", e.to_string_lossy()),
        None => format!("{stem}_{axis}"),
    };
    out.with_file_name(name)
}

fn write(path: &Path, text: &str) -> anyhow::Result<()> {
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}

pub fn export(args: ExportArgs) -> anyhow::Result<ExitCode> {
    let model = MapModel::new(ErrorMap::load(&args.map)?);
    let report = match args.format.as_str() {
        "linuxcnc" => {
            let mut joints = Vec::new();
            for (axis, name) in [(0, "x"), (1, "y")] {
                let t = linuxcnc_joint(&model, axis, args.entries, args.tolerance_um)?;
                let path = per_axis(&args.out, name);
                write(&path, &t.text)?;
                if !args.json {
                    println!(
                        "{}: joint {} ([JOINT_{axis}] COMP_FILE = {}, COMP_FILE_TYPE = 0), {} entries taken at {}{:.3} mm; interpolation {:.2} um from the map; not held: {:.2} um of its error that depends on {}",
                        path.display(), name.to_uppercase(), path.display(), t.entries,
                        if axis == 0 { "Y = " } else { "X = " }, t.taken_at_mm,
                        t.interpolation_error_um, t.cross_terms_um,
                        if axis == 0 { "Y" } else { "X" }
                    );
                }
                joints.push(json!({
                    "file": path.display().to_string(), "joint": axis, "entries": t.entries,
                    "taken_at_mm": t.taken_at_mm, "interpolation_error_um": t.interpolation_error_um,
                    "cross_terms_not_held_um": t.cross_terms_um,
                }));
            }
            json!({ "format": "linuxcnc", "tables": joints })
        }
        "beckhoff" => {
            let mut tables = Vec::new();
            for (axis, name) in [(0, "x"), (1, "y")] {
                let t = beckhoff_plane(&model, axis, args.interval_mm, args.tolerance_um)?;
                let path = per_axis(&args.out, name);
                write(&path, &t.text)?;
                if !args.json {
                    println!(
                        "{}: plane compensation of {} over X and Y, {} points every {} mm; interpolation {:.2} um from the map; not held: {:.2} um of backlash (one table for both directions)",
                        path.display(), name.to_uppercase(), t.points, args.interval_mm,
                        t.interpolation_error_um, t.backlash_lost_um
                    );
                }
                tables.push(json!({
                    "file": path.display().to_string(), "axis": name, "points": t.points,
                    "interpolation_error_um": t.interpolation_error_um,
                    "backlash_not_held_um": t.backlash_lost_um,
                }));
            }
            json!({ "format": "beckhoff", "tables": tables })
        }
        "csv" => {
            let text = plain_csv(&model)?;
            write(&args.out, &text)?;
            if !args.json {
                println!(
                    "{}: the model at every node of the map's grid, both directions",
                    args.out.display()
                );
            }
            json!({ "format": "csv", "file": args.out.display().to_string(), "rows": text.lines().count() - 1 })
        }
        other => anyhow::bail!("--format `{other}`: linuxcnc, beckhoff or csv"),
    };
    if args.json {
        println!("{report}");
    }
    Ok(ExitCode::SUCCESS)
}

/// The default number of LinuxCNC entries.
pub const DEFAULT_ENTRIES: usize = LINUXCNC_MAX_ENTRIES;

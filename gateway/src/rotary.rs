//! `gateway rotary`: the A/C tilting table of source B: identification of its eight
//! location errors from measured ball centres.

use anyhow::Context;
use clap::Subcommand;
use rotary::{identify, parse_centres, Identification, MachineConstants};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Subcommand)]
pub enum RotaryCmd {
    /// Identify the eight location errors from ball centres measured elsewhere (a CMM,
    /// as in the paper): a CSV `axis,step,angle_deg,ball,x_mm,y_mm,z_mm` of the C sweep
    /// (at A = 0) and the A sweep (at C = 0), machine coordinates.
    Identify {
        /// The centres file.
        #[arg(long)]
        centres: PathBuf,
        /// The machine constants (JSON: a_axis_y_mm, a_axis_z_mm, ac_offset_y_mm,
        /// ac_offset_z_mm, tool_length_mm); default: the built-in 340A-style mill.
        #[arg(long)]
        machine: Option<PathBuf>,
        /// Write the chart of centres and fitted circles (rotary-sweeps.svg and .png)
        /// into this folder.
        #[arg(long)]
        plot: Option<PathBuf>,
        /// Print one JSON object instead of the table.
        #[arg(long)]
        json: bool,
    },
}

impl RotaryCmd {
    pub fn json(&self) -> bool {
        match self {
            RotaryCmd::Identify { json, .. } => *json,
        }
    }
}

pub fn run(cmd: RotaryCmd) -> anyhow::Result<ExitCode> {
    match cmd {
        RotaryCmd::Identify {
            centres,
            machine,
            plot,
            json,
        } => {
            let constants = load_constants(machine.as_deref())?;
            let text = std::fs::read_to_string(&centres)
                .with_context(|| format!("reading {}", centres.display()))?;
            let rows = parse_centres(&text).with_context(|| format!("{}", centres.display()))?;
            let id = identify(&rows, &constants)
                .with_context(|| format!("identifying from {}", centres.display()))?;
            let plot_files = match &plot {
                Some(dir) => Some(write_plot(dir, &rows, &id)?),
                None => None,
            };
            if json {
                println!("{}", identification_json(&id, &constants, plot_files));
            } else {
                print_table(&id);
                if let Some((svg, png)) = plot_files {
                    println!("chart: {} and {}", svg.display(), png.display());
                }
            }
            Ok(ExitCode::SUCCESS)
        }
    }
}

/// The machine constants from a JSON file, or the defaults.
pub fn load_constants(path: Option<&Path>) -> anyhow::Result<MachineConstants> {
    let Some(path) = path else {
        return Ok(MachineConstants::default());
    };
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let de = &mut serde_json::Deserializer::from_str(&text);
    let k: MachineConstants = serde_path_to_error::deserialize(de)
        .map_err(|e| anyhow::anyhow!("{}: {} (at {})", path.display(), e.inner(), e.path()))?;
    k.check()
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    Ok(k)
}

fn write_plot(
    dir: &Path,
    rows: &[rotary::CentreRow],
    id: &Identification,
) -> anyhow::Result<(PathBuf, PathBuf)> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let chart = rotary::chart::SweepChart {
        rows,
        identification: id,
        magnification: 1000.0,
    };
    let svg = dir.join("rotary-sweeps.svg");
    let png = dir.join("rotary-sweeps.png");
    std::fs::write(&svg, plot::render_svg(&chart, 1000, 460)?)
        .with_context(|| format!("writing {}", svg.display()))?;
    std::fs::write(&png, plot::render_png(&chart, 1000, 460)?)
        .with_context(|| format!("writing {}", png.display()))?;
    Ok((svg, png))
}

/// The output JSON: the eight errors at the top level under their paper names, their
/// standard uncertainties (k = 1) under `uncertainty`, and the fits.
pub fn identification_json(
    id: &Identification,
    constants: &MachineConstants,
    plot: Option<(PathBuf, PathBuf)>,
) -> serde_json::Value {
    let mut out = serde_json::Map::new();
    for (name, v) in id.errors.named() {
        out.insert(name.into(), json!(v));
    }
    let mut u = serde_json::Map::new();
    for (name, v) in id.uncertainty.named() {
        u.insert(name.into(), json!(v));
    }
    out.insert("uncertainty".into(), serde_json::Value::Object(u));
    out.insert("coverage_factor".into(), json!(1));
    let circles: Vec<serde_json::Value> = id
        .circles
        .iter()
        .map(|(axis, ball, c)| {
            json!({
                "axis": axis.to_string(),
                "ball": ball,
                "centre_mm": c.centre,
                "normal": c.normal,
                "radius_mm": c.radius_mm,
                "rms_plane_um": c.rms_plane_mm * 1e3,
                "rms_radial_um": c.rms_radial_mm * 1e3,
                "points": c.points,
            })
        })
        .collect();
    out.insert("circles".into(), json!(circles));
    out.insert("c_axis".into(), json!(id.c_axis));
    out.insert("a_axis".into(), json!(id.a_axis));
    out.insert("machine".into(), json!(constants));
    if let Some((svg, png)) = plot {
        out.insert(
            "plot".into(),
            json!({ "svg": svg.display().to_string(), "png": png.display().to_string() }),
        );
    }
    serde_json::Value::Object(out)
}

fn print_table(id: &Identification) {
    println!("{:<14} {:>12} {:>12}", "error", "value", "u (k=1)");
    for ((name, v), (_, u)) in id.errors.named().iter().zip(id.uncertainty.named()) {
        println!("{name:<14} {v:>12.6} {u:>12.6}");
    }
    for (axis, ball, c) in &id.circles {
        println!(
            "circle {axis} ball {ball}: radius {:.4} mm, rms {:.3} um radial, {:.3} um out of plane, {} centres",
            c.radius_mm,
            c.rms_radial_mm * 1e3,
            c.rms_plane_mm * 1e3,
            c.points
        );
    }
    for (name, line) in [("C", &id.c_axis), ("A", &id.a_axis)] {
        println!(
            "{name} axis: circle centres {:.3} mm apart, their line {:.5} deg from the normals",
            line.centre_separation_mm, line.centre_line_deviation_deg
        );
    }
}

//! `gateway volumetric ...`: the 21-error volumetric model from files (identify, eval,
//! contributions, ISG export) and the emulated machine's campaign (simulate-campaign).

use anyhow::{bail, Context};
use clap::Subcommand;
use protocol::volumetric::{
    parse_model, parse_points, write_isg_csv, write_isg_lis, write_model, Structure, AXES,
};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use volumetric::ballbar::BallbarChart;
use volumetric::contributions::{contributions, plane_map, ContributionChart, Plane};
use volumetric::identify::{identify, Campaign};
use volumetric::Model;

#[derive(Subcommand)]
pub enum VolumetricCmd {
    /// Identify the model from a campaign directory (laser_X.csv, level_X.csv, ...,
    /// ballbar_XY.csv ... or squareness.csv, camera.csv if measured) and write the
    /// model file.
    Identify {
        #[arg(long)]
        campaign: PathBuf,
        /// FXYZ, XFYZ, XYFZ or XYZF.
        #[arg(long)]
        structure: String,
        #[arg(long)]
        out: PathBuf,
        /// The tool point in the last tool carriage's frame, `x,y,z` mm (tool length).
        #[arg(long, default_value = "0,0,0")]
        tool_offset_mm: String,
        /// The workpiece reference point in the last workpiece carriage's frame, mm.
        #[arg(long, default_value = "0,0,0")]
        work_offset_mm: String,
        /// Write the ball-bar plots (ballbar_XY.svg/.png, ...) into this directory.
        #[arg(long)]
        plots: Option<PathBuf>,
        #[arg(long)]
        json: bool,
    },
    /// The volumetric error at each point of POINTS.csv (`x_mm,y_mm,z_mm`).
    Eval {
        #[arg(long)]
        model: PathBuf,
        #[arg(long)]
        points: PathBuf,
        /// Use the first-order closed form instead of the full HTM product.
        #[arg(long)]
        first_order: bool,
        #[arg(long)]
        json: bool,
    },
    /// Each error's contribution over the volume (ranked, CSV + SVG) and the error map
    /// of the three middle planes (CSV + SVG), into DIR.
    Contributions {
        #[arg(long)]
        model: PathBuf,
        #[arg(long)]
        out: PathBuf,
        /// Grid points per axis.
        #[arg(long, default_value_t = 11)]
        grid: usize,
        #[arg(long)]
        json: bool,
    },
    /// Write the emulated machine's measurement campaign into DIR.
    SimulateCampaign {
        #[arg(long)]
        out: PathBuf,
        #[arg(long, default_value = "XYFZ")]
        structure: String,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        #[arg(long)]
        json: bool,
    },
    /// Export the model for the ISG kernel (Beckhoff TF5280) into DIR: volcomp.csv in the
    /// ISG CSV format (blocks `C0Y B0Z A0Z P0X P0Y P0Z`, `X EXX ... ECX`, ..., mm and
    /// rad) and the compensation list volcomp.lis that names it.
    ExportIsg {
        #[arg(long)]
        model: PathBuf,
        #[arg(long)]
        out: PathBuf,
        #[arg(long)]
        json: bool,
    },
}

impl VolumetricCmd {
    pub fn json(&self) -> bool {
        match self {
            VolumetricCmd::Identify { json, .. }
            | VolumetricCmd::Eval { json, .. }
            | VolumetricCmd::Contributions { json, .. }
            | VolumetricCmd::SimulateCampaign { json, .. }
            | VolumetricCmd::ExportIsg { json, .. } => *json,
        }
    }
}

fn structure(s: &str) -> anyhow::Result<Structure> {
    Structure::parse(s)
        .ok_or_else(|| anyhow::anyhow!("--structure `{s}`: expected FXYZ, XFYZ, XYFZ or XYZF"))
}

fn parse_xyz(flag: &str, text: &str) -> anyhow::Result<[f64; 3]> {
    let v: Vec<f64> = text
        .split(',')
        .map(|p| p.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| anyhow::anyhow!("{flag} `{text}`: expected x,y,z in mm"))?;
    match v[..] {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok([x, y, z]),
        _ => bail!("{flag} `{text}`: expected three finite numbers x,y,z in mm"),
    }
}

fn read(path: &Path) -> anyhow::Result<String> {
    std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))
}

/// Reads and checks a model file.
pub fn load_model(path: &Path) -> anyhow::Result<Model> {
    let file = parse_model(&read(path)?).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    Model::new(file).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// Translations (E_X?, E_Y?, E_Z?) in µm, angles in µrad.
fn display_unit(name: &str, micron: &'static str) -> (f64, &'static str) {
    let is_length = name.len() == 4 && matches!(&name[2..3], "X" | "Y" | "Z");
    if is_length {
        (1e3, micron)
    } else {
        (1e6, "urad")
    }
}

fn write(path: &Path, text: impl AsRef<[u8]>) -> anyhow::Result<()> {
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}

pub fn run(cmd: VolumetricCmd) -> anyhow::Result<ExitCode> {
    match cmd {
        VolumetricCmd::Identify {
            campaign,
            structure: s,
            out,
            tool_offset_mm,
            work_offset_mm,
            plots,
            json,
        } => {
            let s = structure(&s)?;
            let tool = parse_xyz("--tool-offset-mm", &tool_offset_mm)?;
            let work = parse_xyz("--work-offset-mm", &work_offset_mm)?;
            // Every file the campaign may hold; the identification says which are due.
            let mut files = Vec::new();
            let mut names: Vec<String> = Vec::new();
            for a in AXES {
                names.push(format!("laser_{a}.csv"));
                names.push(format!("level_{a}.csv"));
            }
            for p in ["XY", "XZ", "YZ"] {
                names.push(format!("ballbar_{p}.csv"));
            }
            names.push("squareness.csv".into());
            names.push("camera.csv".into());
            for n in names {
                let path = campaign.join(&n);
                if path.exists() {
                    files.push((n, read(&path)?));
                }
            }
            let c = Campaign::from_files(&files)
                .map_err(|e| anyhow::anyhow!("{}/{e}", campaign.display()))?;
            let mut id =
                identify(s, &c).map_err(|e| anyhow::anyhow!("{}: {e}", campaign.display()))?;
            id.model.file.tool_offset_mm = tool;
            id.model.file.work_offset_mm = work;
            write(&out, write_model(&id.model.file))?;
            if let Some(dir) = &plots {
                std::fs::create_dir_all(dir)
                    .with_context(|| format!("creating {}", dir.display()))?;
                for b in &id.ballbar {
                    let chart = BallbarChart(b);
                    write(
                        &dir.join(format!("ballbar_{}.svg", b.plane)),
                        plot::render_svg(&chart, 800, 800)?,
                    )?;
                    write(
                        &dir.join(format!("ballbar_{}.png", b.plane)),
                        plot::render_png(&chart, 800, 800)?,
                    )?;
                }
            }
            let fit = id.model.file.fit;
            if json {
                let q: Vec<_> = id
                    .quality
                    .iter()
                    .map(|q| {
                        let (scale, unit) = display_unit(q.name, "um");
                        json!({"name": q.name, "unit": unit, "residual": q.residual * scale,
                               "uncertainty": q.uncertainty * scale, "stated": q.stated * scale, "fit": q.fit()})
                    })
                    .collect();
                let ballbar: Vec<_> = id
                    .ballbar
                    .iter()
                    .map(|b| {
                        json!({"plane": b.plane, "circular_deviation_um": b.circular_deviation_mm * 1e3,
                               "iso_squareness_urad": b.iso_squareness_rad * 1e6,
                               "squareness_urad": b.squareness_rad * 1e6,
                               "uncertainty_urad": b.uncertainty_rad * 1e6,
                               "model_residual_rms_um": b.model_residual_rms_mm * 1e3})
                    })
                    .collect();
                let camera = id.camera.as_ref().map(|c| {
                    let per: Vec<_> = (0..2)
                        .flat_map(|a| (0..2).map(move |k| (a, k)))
                        .map(|(a, k)| {
                            json!({"name": c.names[a][k],
                                   "uncertainty_urad": c.sigma[a][k].iter().fold(0.0f64, |m, v| m.max(*v)) * 1e6,
                                   "largest_change_from_instruments_urad": c.change[a][k] * 1e6})
                        })
                        .collect();
                    json!({"points": c.points, "heights_mm": c.heights_mm,
                           "residual_rms_um": c.residual_rms_mm * 1e3, "stated_um": c.stated_mm * 1e3,
                           "repeatability_um": c.repeatability_mm * 1e3,
                           "board_rotation_urad": c.board_rotation_rad.iter().map(|v| v * 1e6).collect::<Vec<_>>(),
                           "fit": c.fit(), "angles": per})
                });
                println!(
                    "{}",
                    json!({"model": out, "structure": s.name(), "fit_for_compensation": fit, "errors": q,
                           "ballbar": ballbar, "camera": camera})
                );
            } else {
                println!(
                    "{:<6} {:>10} {:>12} {:>8}  unit",
                    "error", "residual", "uncertainty", "stated"
                );
                for q in &id.quality {
                    let (scale, unit) = display_unit(q.name, "µm");
                    println!(
                        "{:<6} {:>10.3} {:>12.3} {:>8.3}  {unit}{}",
                        q.name,
                        q.residual * scale,
                        q.uncertainty * scale,
                        q.stated * scale,
                        if q.fit() {
                            ""
                        } else {
                            "  EXCEEDS the stated uncertainty"
                        }
                    );
                }
                for b in &id.ballbar {
                    println!(
                        "ball bar {}: circular deviation {:.2} µm, ISO squareness reading {:.2} µrad, model squareness {:.2} ± {:.2} µrad, residual {:.3} µm RMS",
                        b.plane,
                        b.circular_deviation_mm * 1e3,
                        b.iso_squareness_rad * 1e6,
                        b.squareness_rad * 1e6,
                        b.uncertainty_rad * 1e6,
                        b.model_residual_rms_mm * 1e3
                    );
                }
                if let Some(c) = &id.camera {
                    println!(
                        "camera: {} points at heights {:?} mm, residual {:.3} µm RMS (stated {:.3}), {}",
                        c.points,
                        c.heights_mm,
                        c.residual_rms_mm * 1e3,
                        c.stated_mm * 1e3,
                        if c.fit() { "consistent" } else { "INCONSISTENT with the model" }
                    );
                    for a in 0..2 {
                        for k in 0..2 {
                            println!(
                                "  {}: uncertainty {:.3} µrad combined, largest change from the instruments {:.3} µrad",
                                c.names[a][k],
                                c.sigma[a][k].iter().fold(0.0f64, |m, v| m.max(*v)) * 1e6,
                                c.change[a][k] * 1e6
                            );
                        }
                    }
                }
                println!(
                    "model written to {} ({})",
                    out.display(),
                    if fit {
                        "fit for compensation"
                    } else {
                        "UNFIT for compensation: residuals exceed the instruments' stated uncertainty"
                    }
                );
            }
            Ok(if fit {
                ExitCode::SUCCESS
            } else {
                ExitCode::from(2)
            })
        }
        VolumetricCmd::Eval {
            model,
            points,
            first_order,
            json,
        } => {
            let m = load_model(&model)?;
            let pts = parse_points(&read(&points)?)
                .map_err(|e| anyhow::anyhow!("{}: {e}", points.display()))?;
            let mut rows = Vec::with_capacity(pts.len());
            for (i, q) in pts.iter().enumerate() {
                let e = m.error(*q, first_order).map_err(|e| {
                    anyhow::anyhow!(
                        "{}: point {} (line {}): {e}",
                        points.display(),
                        i + 1,
                        i + 2
                    )
                })?;
                rows.push((q, e));
            }
            if json {
                let out: Vec<_> = rows
                    .iter()
                    .map(|(q, e)| {
                        json!({"x_mm": q[0], "y_mm": q[1], "z_mm": q[2],
                        "ex_um": e[0] * 1e3, "ey_um": e[1] * 1e3, "ez_um": e[2] * 1e3})
                    })
                    .collect();
                println!("{}", json!({"first_order": first_order, "points": out}));
            } else {
                println!("x_mm,y_mm,z_mm,ex_um,ey_um,ez_um");
                for (q, e) in rows {
                    println!(
                        "{},{},{},{:.4},{:.4},{:.4}",
                        q[0],
                        q[1],
                        q[2],
                        e[0] * 1e3,
                        e[1] * 1e3,
                        e[2] * 1e3
                    );
                }
            }
            Ok(ExitCode::SUCCESS)
        }
        VolumetricCmd::Contributions {
            model,
            out,
            grid,
            json,
        } => {
            if grid < 2 {
                bail!("--grid {grid}: at least 2 points per axis");
            }
            let m = load_model(&model)?;
            std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
            let (c, tmax, trms) = contributions(&m, grid)?;
            let mut csv = String::from("rank,error,max_um,rms_um\n");
            for (i, x) in c.iter().enumerate() {
                csv += &format!("{},{},{:.4},{:.4}\n", i + 1, x.name, x.max_um, x.rms_um);
            }
            write(&out.join("contributions.csv"), csv)?;
            let chart = ContributionChart(&c);
            write(
                &out.join("contributions.svg"),
                plot::render_svg(&chart, 900, 700)?,
            )?;
            write(
                &out.join("contributions.png"),
                plot::render_png(&chart, 900, 700)?,
            )?;
            for plane in [Plane::Xy, Plane::Xz, Plane::Yz] {
                let map = plane_map(&m, plane, grid)?;
                let (a, b, _) = plane.axes();
                let mut csv = format!(
                    "{}_mm,{}_mm,ex_um,ey_um,ez_um\n",
                    AXES[a].to_ascii_lowercase(),
                    AXES[b].to_ascii_lowercase()
                );
                for (i, u) in map.u.iter().enumerate() {
                    for (j, v) in map.v.iter().enumerate() {
                        let e = map.errors[i][j];
                        csv += &format!("{u},{v},{:.4},{:.4},{:.4}\n", e[0], e[1], e[2]);
                    }
                }
                write(&out.join(format!("map_{}.csv", plane.name())), csv)?;
                let name = format!("map_{}", plane.name());
                write(
                    &out.join(format!("{name}.svg")),
                    plot::render_svg(&map, 800, 650)?,
                )?;
                write(
                    &out.join(format!("{name}.png")),
                    plot::render_png(&map, 800, 650)?,
                )?;
            }
            if json {
                let list: Vec<_> = c
                    .iter()
                    .map(|x| json!({"error": x.name, "max_um": x.max_um, "rms_um": x.rms_um}))
                    .collect();
                println!(
                    "{}",
                    json!({"out": out, "total_max_um": tmax, "total_rms_um": trms, "contributions": list})
                );
            } else {
                println!(
                    "total (first order): max {tmax:.2} µm, RMS {trms:.2} µm over a {grid}³ grid"
                );
                for (i, x) in c.iter().enumerate() {
                    println!(
                        "{:>2}. {:<6} max {:>8.3} µm  RMS {:>8.3} µm",
                        i + 1,
                        x.name,
                        x.max_um,
                        x.rms_um
                    );
                }
                println!("written to {}", out.display());
            }
            Ok(ExitCode::SUCCESS)
        }
        VolumetricCmd::SimulateCampaign {
            out,
            structure: s,
            seed,
            json,
        } => {
            let s = structure(&s)?;
            std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
            let machine = world::volumetric::VolumetricMachine::new(s, seed);
            let mut files = machine.campaign(seed);
            let plan = world::volumetric::CameraPlan::default_for(machine.travel_mm);
            files.push(("camera.csv".into(), machine.camera_campaign(&plan, seed).0));
            for (name, text) in &files {
                write(&out.join(name), text)?;
            }
            let names: Vec<&str> = files.iter().map(|f| f.0.as_str()).collect();
            if json {
                println!(
                    "{}",
                    json!({"out": out, "structure": s.name(), "seed": seed, "files": names})
                );
            } else {
                println!(
                    "{} campaign (seed {seed}) written to {}: {}",
                    s,
                    out.display(),
                    names.join(", ")
                );
            }
            Ok(ExitCode::SUCCESS)
        }
        VolumetricCmd::ExportIsg { model, out, json } => {
            let m = load_model(&model)?;
            std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
            write(&out.join("volcomp.csv"), write_isg_csv(&m.file))?;
            write(
                &out.join("volcomp.lis"),
                write_isg_lis(&m.file, "volcomp.csv"),
            )?;
            if json {
                println!(
                    "{}",
                    json!({"out": out, "files": ["volcomp.csv", "volcomp.lis"]})
                );
            } else {
                println!("ISG tables written to {}", out.display());
            }
            Ok(ExitCode::SUCCESS)
        }
    }
}

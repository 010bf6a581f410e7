//! `gateway volumetric ...`: the registered volumetric kinds (identify, eval,
//! contributions, simulate-campaign, export-isg) with their files read through the
//! bounded reader and their artifacts written where the flags say.

use crate::front::{run_kind_then, run_outcome, CliSink};
use clap::Subcommand;
use procedure::volumetric::{
    VolumetricCampaignRequest, VolumetricContributionsRequest, VolumetricEvalRequest,
    VolumetricExportIsgRequest, VolumetricIdentifyRequest, CAMPAIGN_FILES, MODEL_ARTIFACT,
};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

// Parsed once per run: the size of a variant does not matter.
#[allow(clippy::large_enum_variant)]
#[derive(Subcommand)]
pub enum VolumetricCmd {
    /// Identify the model from a campaign directory (laser_X.csv, level_X.csv, ...,
    /// ballbar_XY.csv ... or squareness.csv, camera.csv if measured) and write the
    /// model file. Exit code 2: identified, but unfit for compensation.
    Identify {
        #[arg(long)]
        campaign: PathBuf,
        #[arg(long)]
        out: PathBuf,
        #[command(flatten)]
        request: VolumetricIdentifyRequest,
        /// Write the ball-bar plots (ballbar_XY.svg/.png, ...) into this directory.
        #[arg(long)]
        plots: Option<PathBuf>,
    },
    /// The volumetric error at each point of POINTS.csv (`x_mm,y_mm,z_mm`).
    Eval {
        #[arg(long)]
        model: PathBuf,
        #[arg(long)]
        points: PathBuf,
        #[command(flatten)]
        request: VolumetricEvalRequest,
    },
    /// Each error's contribution over the volume (ranked, CSV + SVG) and the error map
    /// of the three middle planes (CSV + SVG), into DIR.
    Contributions {
        #[arg(long)]
        model: PathBuf,
        #[arg(long)]
        out: PathBuf,
        #[command(flatten)]
        request: VolumetricContributionsRequest,
    },
    /// Write the emulated machine's measurement campaign into DIR.
    SimulateCampaign {
        #[arg(long)]
        out: PathBuf,
        #[command(flatten)]
        request: VolumetricCampaignRequest,
    },
    /// Export the model for the ISG kernel (Beckhoff TF5280) into DIR: volcomp.csv in the
    /// ISG CSV format (blocks `C0Y B0Z A0Z P0X P0Y P0Z`, `X EXX ... ECX`, ..., mm and
    /// rad) and the compensation list volcomp.lis that names it.
    ExportIsg {
        #[arg(long)]
        model: PathBuf,
        #[arg(long)]
        out: PathBuf,
    },
}

fn read(path: &Path) -> anyhow::Result<String> {
    procedure::volumetric::read_file(path).map_err(anyhow::Error::msg)
}

fn named(path: &Path) -> String {
    path.display().to_string()
}

pub fn run(cmd: VolumetricCmd, json: bool) -> anyhow::Result<ExitCode> {
    match cmd {
        VolumetricCmd::Identify {
            campaign,
            out,
            mut request,
            plots,
        } => {
            request.plots = plots.is_some();
            request.campaign_name = named(&campaign);
            // Each file a campaign may hold, when the folder has it.
            for name in CAMPAIGN_FILES {
                let path = campaign.join(name);
                if path.exists() {
                    *request.file_mut(name).expect("a campaign file") = Some(read(&path)?);
                }
            }
            let mut sink = CliSink::new("", true)
                .inputs(&[campaign.as_path()])
                .artifact_to(MODEL_ARTIFACT, out.clone());
            if let Some(dir) = &plots {
                sink = sink.into_folder(dir)?;
            }
            let kind = procedure::kinds::kind("volumetric-identify")?;
            let outcome = run_outcome(kind, &request, &mut sink, |f| f)?;
            let fit = outcome
                .result
                .as_ref()
                .is_some_and(|r| r["fit_for_compensation"] == true);
            let code = crate::front::print(&outcome, json, |r| {
                let verdict = if fit {
                    "fit for compensation"
                } else {
                    "UNFIT for compensation: residuals exceed the instruments' stated uncertainty"
                };
                let summary = kind.summary(r);
                format!("{summary}model written to {} ({verdict})", out.display())
            })?;
            Ok(if code == ExitCode::SUCCESS && !fit {
                ExitCode::from(2)
            } else {
                code
            })
        }
        VolumetricCmd::Eval {
            model,
            points,
            mut request,
        } => {
            (request.model, request.model_name) = (read(&model)?, named(&model));
            (request.points, request.points_name) = (read(&points)?, named(&points));
            let mut sink = CliSink::new("", true);
            run_kind_then("volumetric-eval", &request, &mut sink, json, "", |f| f)
        }
        VolumetricCmd::Contributions {
            model,
            out,
            mut request,
        } => {
            (request.model, request.model_name) = (read(&model)?, named(&model));
            let mut sink = CliSink::new("", true)
                .inputs(&[model.as_path()])
                .into_folder(&out)?;
            let written = format!("written to {}", out.display());
            run_kind_then(
                "volumetric-contributions",
                &request,
                &mut sink,
                json,
                &written,
                |f| f,
            )
        }
        VolumetricCmd::SimulateCampaign { out, request } => {
            let mut sink = CliSink::new("", true).into_folder(&out)?;
            let written = format!("\nwritten to {}", out.display());
            run_kind_then(
                "volumetric-campaign",
                &request,
                &mut sink,
                json,
                &written,
                |f| f,
            )
        }
        VolumetricCmd::ExportIsg { model, out } => {
            let request = VolumetricExportIsgRequest {
                model: read(&model)?,
                model_name: named(&model),
            };
            let mut sink = CliSink::new("", true)
                .inputs(&[model.as_path()])
                .into_folder(&out)?;
            let written = format!("\nISG tables written to {}", out.display());
            run_kind_then(
                "volumetric-export-isg",
                &request,
                &mut sink,
                json,
                &written,
                |f| f,
            )
        }
    }
}

//! `gateway volumetric ...`: flags to the requests of `procedure::volumetric` (identify,
//! eval, contributions, simulate-campaign, export-isg), files read through the bounded
//! reader, artifacts written by the CLI's sink, results printed.

use crate::front::CliSink;
use clap::Subcommand;
use procedure::volumetric::{
    CampaignFiles, VolumetricCampaignRequest, VolumetricContributionsRequest,
    VolumetricEvalRequest, VolumetricIdentifyRequest, CAMPAIGN_FILES, MODEL_ARTIFACT,
};
use procedure::{Outcome, RequestError};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use volumetric::Model;

#[derive(Subcommand)]
pub enum VolumetricCmd {
    /// Identify the model from a campaign directory (laser_X.csv, level_X.csv, ...,
    /// ballbar_XY.csv ... or squareness.csv, camera.csv if measured) and write the
    /// model file.
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

/// Reads and checks a model file (through the bounded reader).
pub fn load_model(path: &Path) -> anyhow::Result<Model> {
    procedure::volumetric::read_model(&path.display().to_string(), &read(path)?)
        .map_err(anyhow::Error::msg)
}

fn cli(e: RequestError) -> anyhow::Error {
    anyhow::anyhow!(e.for_cli())
}

/// Sets `key` of the outcome's result (where the CLI wrote what the procedure named).
fn located(mut outcome: Outcome, key: &str, path: &Path) -> Outcome {
    if let Some(o) = outcome.result.as_mut().and_then(Value::as_object_mut) {
        o.insert(key.into(), json!(path.display().to_string()));
    }
    outcome
}

/// The campaign folder: each file the procedure asks for, read through the bounded
/// reader if it is there.
struct FolderCampaign(PathBuf);

impl CampaignFiles for FolderCampaign {
    fn place(&self) -> String {
        self.0.display().to_string()
    }
    fn read(&mut self, name: &str) -> Result<Option<String>, String> {
        let path = self.0.join(name);
        if !path.exists() {
            return Ok(None);
        }
        read(&path).map(Some).map_err(|e| format!("{e:#}"))
    }
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
            request.check().map_err(cli)?;
            let inputs: Vec<PathBuf> = CAMPAIGN_FILES.iter().map(|n| campaign.join(n)).collect();
            let inputs: Vec<&Path> = inputs.iter().map(PathBuf::as_path).collect();
            let mut sink = CliSink::new("", true)
                .inputs(&inputs)
                .artifact_to(MODEL_ARTIFACT, out.clone());
            if let Some(dir) = &plots {
                sink = sink.into_folder(dir)?;
            }
            let outcome =
                procedure::volumetric::identify(&request, &mut FolderCampaign(campaign), &mut sink);
            let outcome = located(outcome, "model", &out);
            let fit = outcome
                .result
                .as_ref()
                .is_some_and(|r| r["fit_for_compensation"] == true);
            let code = crate::front::print(&outcome, json, |r| {
                let mut text = procedure::volumetric::identify_summary(r);
                text += &format!(
                    "model written to {} ({})",
                    out.display(),
                    if fit {
                        "fit for compensation"
                    } else {
                        "UNFIT for compensation: residuals exceed the instruments' stated uncertainty"
                    }
                );
                text
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
            request,
        } => {
            let m = load_model(&model)?;
            let text = read(&points)?;
            request.check_points(&text).map_err(cli)?;
            let outcome =
                procedure::volumetric::eval(&request, &m, &points.display().to_string(), &text);
            crate::front::print(&outcome, json, |r| {
                procedure::volumetric::eval_lines(r)
                    .collect::<Vec<_>>()
                    .join("\n")
            })
        }
        VolumetricCmd::Contributions {
            model,
            out,
            request,
        } => {
            request.check().map_err(cli)?;
            let m = load_model(&model)?;
            let mut sink = CliSink::new("", true)
                .inputs(&[model.as_path()])
                .into_folder(&out)?;
            let outcome = procedure::volumetric::contributions(&request, &m, &mut sink);
            let outcome = located(outcome, "out", &out);
            crate::front::print(&outcome, json, |r| {
                let text = procedure::volumetric::contributions_summary(r);
                format!("{text}written to {}", out.display())
            })
        }
        VolumetricCmd::SimulateCampaign { out, request } => {
            request.check().map_err(cli)?;
            let mut sink = CliSink::new("", true).into_folder(&out)?;
            let outcome = procedure::volumetric::simulate_campaign(&request, &mut sink);
            let outcome = located(outcome, "out", &out);
            crate::front::print(&outcome, json, |r| {
                let names: Vec<&str> = r["files"]
                    .as_array()
                    .into_iter()
                    .flatten()
                    .filter_map(Value::as_str)
                    .collect();
                format!(
                    "{} campaign (seed {}) written to {}: {}",
                    r["structure"].as_str().unwrap_or(""),
                    request.seed,
                    out.display(),
                    names.join(", ")
                )
            })
        }
        VolumetricCmd::ExportIsg { model, out } => {
            let m = load_model(&model)?;
            let mut sink = CliSink::new("", true)
                .inputs(&[model.as_path()])
                .into_folder(&out)?;
            let outcome = procedure::volumetric::export_isg(&m, &mut sink);
            let outcome = located(outcome, "out", &out);
            crate::front::print(&outcome, json, |_| {
                format!("ISG tables written to {}", out.display())
            })
        }
    }
}

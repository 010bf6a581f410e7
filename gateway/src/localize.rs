//! `gateway localize`: one image of the board localized (`procedure::localize`).

use procedure::localize::LocalizeRequest;
use protocol::Board;
use serde_json::{json, Value};
use std::path::PathBuf;
use std::process::ExitCode;
use vision::localize::{LocalizeSettings, PixelAxes};

#[derive(clap::Args)]
pub struct LocalizeArgs {
    /// PNG file, 8- or 16-bit greyscale.
    pub image: PathBuf,
    /// Board file (TOML).
    #[arg(long)]
    pub board: PathBuf,
    /// Expected board coordinate at the image centre, "X,Y" in mm.
    #[arg(long)]
    pub near: String,
    #[arg(long, default_value_t = LocalizeSettings::default().method.to_string())]
    pub method: String,
    /// Nominal scale; the measured scale must agree within 10 %.
    #[arg(long)]
    pub um_per_px: Option<f64>,
    /// Board directions of the image +x and +y axes.
    #[arg(long, default_value = "+x,-y")]
    pub pixel_axes: String,
    /// How far the true position may be from --near, mm.
    #[arg(long, default_value_t = LocalizeSettings::default().hint_tolerance_mm)]
    pub hint_tolerance_mm: f64,
    /// Refuse when the fit's RMS residual exceeds this, um.
    #[arg(long, default_value_t = LocalizeSettings::default().max_residual_um)]
    pub max_residual_um: f64,
    /// Fewest identified on-board points accepted.
    #[arg(long, default_value_t = LocalizeSettings::default().min_points)]
    pub min_points: usize,
    #[arg(long)]
    pub json: bool,
}

pub fn localize(args: LocalizeArgs) -> anyhow::Result<ExitCode> {
    let LocalizeArgs {
        image,
        board,
        near,
        method,
        um_per_px,
        pixel_axes,
        hint_tolerance_mm,
        max_residual_um,
        min_points,
        json,
    } = args;
    let board = Board::load(&board)?;
    let img = vision::image_io::load_png(&image)?;
    let request = LocalizeRequest {
        near: crate::front::parse_xy(&near)?,
        method: crate::front::parse_method(&method)?,
        um_per_px,
        pixel_axes: pixel_axes
            .parse::<PixelAxes>()
            .map_err(|e| anyhow::anyhow!("--pixel-axes `{pixel_axes}`: {e}"))?,
        hint_tolerance_mm,
        max_residual_um,
        min_points: min_points as u64,
    };
    request
        .check_for(&board)
        .map_err(|e| anyhow::anyhow!(e.for_cli()))?;
    let source = image.display().to_string();
    let mut outcome = procedure::localize::run(&request, &img, &board, &source);
    if let Some(Value::Object(frame)) = outcome.result.as_mut().and_then(|r| r.get_mut("image")) {
        frame.insert("path".into(), json!(source));
    }
    crate::front::print(&outcome, json, procedure::localize::summary)
}

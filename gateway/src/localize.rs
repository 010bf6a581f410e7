//! `gateway localize`: one image of the board localized (`procedure::localize`).

use procedure::localize::LocalizeRequest;
use protocol::Board;
use serde_json::{json, Value};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct LocalizeArgs {
    /// PNG file, 8- or 16-bit greyscale.
    pub image: PathBuf,
    /// Board file (TOML).
    #[arg(long)]
    pub board: PathBuf,
    #[command(flatten)]
    pub request: LocalizeRequest,
}

pub fn localize(args: LocalizeArgs, json: bool) -> anyhow::Result<ExitCode> {
    let LocalizeArgs {
        image,
        board,
        request,
    } = args;
    let board = Board::load(&board)?;
    let img = vision::image_io::load_png(&image)?;
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

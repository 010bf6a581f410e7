//! `gateway localize`: one image of the board localized (the registered `localize`
//! kind), the frame read through the bounded reader.

use base64::Engine;
use procedure::localize::LocalizeRequest;
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
        mut request,
    } = args;
    let bytes = protocol::config::read_bytes_bounded(
        &image,
        vision::image_io::MAX_IMAGE_BYTES,
        "an image file",
    )
    .map_err(|e| anyhow::anyhow!("{}: cannot open: {e}", image.display()))?;
    request.image = base64::engine::general_purpose::STANDARD.encode(bytes);
    request.image_name = image.display().to_string();
    let mut sink = crate::front::CliSink::new("", true);
    crate::front::run_kind("localize", &request, &mut sink, json, |f| {
        f.board_file(&board)
    })
}

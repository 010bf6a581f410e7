//! `gateway board make`: the registered `board-make` kind, its artwork and certificate
//! template written into the output folder.

use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Subcommand)]
pub enum BoardCmd {
    /// Write the board's artwork (SVG and DXF at 1:1, mm, a PDF test print) and the
    /// certificate template (CSV) into OUT, named after the board file.
    Make {
        /// The board file (TOML).
        board: PathBuf,
        #[arg(long, short)]
        out: PathBuf,
    },
}

pub fn run(cmd: BoardCmd, json: bool) -> anyhow::Result<ExitCode> {
    let BoardCmd::Make { board, out } = cmd;
    let name = board
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "board".to_string());
    // Every output checked before any is written (never over the board, its
    // certificate or anything else read): a refused run leaves nothing behind. The board
    // is read first so that its certificate counts as read; the names are
    // procedure::board::make's.
    protocol::Board::load(&board)?;
    for ext in ["svg", "dxf", "pdf", "certificate-template.csv"] {
        let file = out.join(format!("{name}.{ext}"));
        protocol::config::check_output(&file, &[board.as_path()])
            .map_err(|e| anyhow::anyhow!("writing {}: {e}", file.display()))?;
    }
    let mut sink = crate::front::CliSink::new("", true)
        .inputs(&[board.as_path()])
        .into_folder(&out)?;
    let written = format!("\nwritten to {}", out.display());
    let request = procedure::board::BoardMakeRequest {};
    crate::front::run_kind_then("board-make", &request, &mut sink, json, &written, |f| {
        f.board_file(&board)
    })
}

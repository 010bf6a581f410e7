//! `gateway board make`: a board's artwork for the lab that makes it, the test print and
//! the certificate template, written by the formats crate `board_art` (sized there
//! before anything is made) and handed to the sink.

use crate::command_line::{self, FileArg};
use crate::{Outcome, Sink};
pub use board_art::{dxf, pdf, svg, template};
use protocol::Board;
use serde::{Deserialize, Serialize};
use serde_json::Map;

/// What `board make` made.
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
pub struct BoardMakeResult {
    /// The board's name (its file's `name`).
    pub board: String,
    /// Its dots, columns times rows.
    pub dots: u64,
    /// Whether it carries a position code (issue 28).
    pub coded: bool,
    /// The files made, in the order written (artwork, test print, certificate template).
    pub files: Vec<String>,
}

/// `gateway board make`: the four files handed to the sink as artifacts named after
/// the board file (`NAME.svg`, `NAME.dxf`, `NAME.pdf`, `NAME.certificate-template.csv`),
/// each streamed ([`Sink::artifact_streamed`]): a front that writes files never holds
/// one whole (issue 38: a 2000 x 2000 board took 1.5 GB).
pub fn make(board: &Board, name: &str, sink: &mut dyn Sink) -> Outcome<BoardMakeResult> {
    // Sized before anything is made: refused naming the limit.
    if let Err(e) = board_art::check(board) {
        return Outcome::failed(format!("board `{}`: {e}", board.name));
    }
    // Every output checked before any is written: a refused run leaves nothing behind.
    let names: Vec<String> = (board_art::FILES.iter())
        .map(|(ext, _, _)| format!("{name}.{ext}"))
        .collect();
    if let Err(e) = sink.check_outputs(&names) {
        return Outcome::failed(e);
    }
    for ((_, media_type, writer), file) in board_art::FILES.iter().zip(&names) {
        let (file, media_type) = (file.clone(), *media_type);
        if let Err(e) = sink.artifact_streamed(file, media_type, &mut |out| writer(board, out)) {
            return Outcome::failed(e);
        }
    }
    let dots = u64::from(board.cols) * u64::from(board.rows);
    let result = BoardMakeResult {
        board: board.name.clone(),
        dots,
        coded: board.code.is_some(),
        files: names,
    };
    Outcome::succeeded(result, Map::new())
}

/// Make the board's artwork: nothing to choose (the board is the context's: the CLI's
/// board file, the service's machine's board).
#[derive(
    Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize, utoipa::ToSchema,
)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields)]
pub struct BoardMakeRequest {}

impl crate::registry::Checked for BoardMakeRequest {
    fn check(&self) -> Result<(), crate::RequestError> {
        Ok(())
    }
}

/// [`make`] as a registered kind.
pub struct BoardMake;

impl crate::registry::Procedure for BoardMake {
    const KIND: &'static str = "board-make";
    const TITLE: &'static str =
        "Make the calibration board's artwork (SVG, DXF, a PDF test print) and certificate template";
    const COMMAND: &'static str = "board make";
    const LABEL: &'static str = "Board artwork";
    const HELP: &'static str = "Draws the machine's calibration board for the lab that makes it (SVG, DXF, a PDF test print) and its certificate template.";
    const USES: crate::registry::Uses = crate::registry::Uses::NOTHING;
    type Request = BoardMakeRequest;
    type Result = BoardMakeResult;
    const FILES: &'static [FileArg] = &[
        FileArg::positional("board", "The board file (TOML).", command_line::board),
        FileArg::required("out", "The output folder.", command_line::artifacts_folder).short('o'),
    ];

    async fn run(
        _request: BoardMakeRequest,
        cx: &mut dyn crate::Context,
    ) -> Outcome<BoardMakeResult> {
        let board = crate::or_fail!(cx.board());
        make(&board.board, &board.name, cx.sink())
    }

    fn summary(result: &BoardMakeResult) -> String {
        summary(result)
    }
}

/// The result as text.
pub fn summary(r: &BoardMakeResult) -> String {
    format!(
        "{} ({} dots{}): {}",
        r.board,
        r.dots,
        if r.coded { ", coded" } else { "" },
        r.files.join(", ")
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::Value;

    #[test]
    fn make_hands_over_the_four_files_named_after_the_board() {
        let mut b = Board::nominal(
            "t",
            0.5,
            0.25,
            protocol::Polarity::DarkOnLight,
            6,
            4,
            [0.0, 0.0],
        );
        b.set_code(protocol::board_code::CodeScheme::Additive, 28, [0.2, 0.3]);
        let mut sink = crate::Collect(Vec::new());
        let outcome = make(&b, "t", &mut sink);
        assert!(outcome.is_success(), "{:?}", outcome.error());
        let names: Vec<&str> = sink.0.iter().map(|a| a.name.as_str()).collect();
        assert_eq!(
            names,
            ["t.svg", "t.dxf", "t.pdf", "t.certificate-template.csv"]
        );
        assert_eq!(sink.0[0].bytes, svg(&b).into_bytes());
        let result = outcome.result.unwrap();
        assert_eq!(result.files, names);
        assert_eq!(
            summary(&result),
            "t (24 dots, coded): t.svg, t.dxf, t.pdf, t.certificate-template.csv"
        );
    }

    /// Issue 38: `board make` streams each file to the sink (a front that writes files
    /// never holds one whole): nothing comes through `Sink::artifact`, and each file
    /// arrives in pieces far smaller than itself.
    #[test]
    fn make_streams_each_file_to_the_sink() {
        #[derive(Default)]
        struct Streams {
            whole: usize,
            files: Vec<(String, usize, usize)>,
        }
        impl Sink for Streams {
            fn progress(&mut self, _: u64, _: u64) {}
            fn measurement(&mut self, _: &Value) -> Result<(), crate::Error> {
                Ok(())
            }
            fn artifact(&mut self, _: crate::Artifact) -> Result<(), crate::Error> {
                self.whole += 1;
                Ok(())
            }
            fn artifact_streamed(
                &mut self,
                name: String,
                _: &'static str,
                write: &mut dyn FnMut(&mut dyn std::io::Write) -> std::io::Result<()>,
            ) -> Result<(), crate::Error> {
                struct Largest(usize, usize);
                impl std::io::Write for Largest {
                    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
                        self.0 += buf.len();
                        self.1 = self.1.max(buf.len());
                        Ok(buf.len())
                    }
                    fn flush(&mut self) -> std::io::Result<()> {
                        Ok(())
                    }
                }
                let mut out = Largest(0, 0);
                write(&mut out).unwrap();
                self.files.push((name, out.0, out.1));
                Ok(())
            }
        }
        let b = Board::nominal(
            "t",
            0.5,
            0.25,
            protocol::Polarity::DarkOnLight,
            300,
            200,
            [0.0, 0.0],
        );
        let mut sink = Streams::default();
        assert!(make(&b, "t", &mut sink).is_success());
        assert_eq!(sink.whole, 0);
        assert_eq!(sink.files.len(), 4);
        for (name, bytes, largest) in &sink.files {
            assert!(
                *largest <= 1 << 16 && *bytes > 8 * largest,
                "{name}: {bytes} {largest}"
            );
        }
    }

    /// Issue 38: a 7071 x 7071 board was made until memory ran out (the board file now
    /// refuses it); a board whose certificate could not be read back is refused before
    /// anything is made or handed over.
    #[test]
    fn a_board_too_large_for_its_files_is_refused_before_anything_is_made() {
        let b = Board::nominal(
            "huge",
            0.5,
            0.25,
            protocol::Polarity::DarkOnLight,
            1000,
            1000,
            [0.0, 0.0],
        );
        let mut sink = crate::Collect(Vec::new());
        let outcome = make(&b, "huge", &mut sink);
        let e = outcome.error().unwrap_or_default().to_string();
        assert!(e.contains("certificate template"), "{e}");
        assert!(sink.0.is_empty());
    }
}

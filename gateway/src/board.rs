//! `gateway board make`: a board's artwork for the lab that makes it (DXF and SVG at
//! 1:1, millimetres, board +y up) and the certificate template the metrology lab fills
//! in (`i,j,x_mm,y_mm`, nominal positions to be replaced by the measured ones). Coded
//! boards (issue 28, docs/coded-board.md) get each dot at its code size.

use protocol::Board;
use serde_json::json;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Subcommand)]
pub enum BoardCmd {
    /// Write BOARD's artwork (NAME.svg, NAME.dxf, 1:1 in mm) and its certificate
    /// template (NAME.certificate-template.csv) into the folder OUT.
    Make {
        /// Board file (TOML).
        board: PathBuf,
        /// Output folder (created if missing).
        #[arg(long, short)]
        out: PathBuf,
    },
}

pub fn run(cmd: BoardCmd, json: bool) -> anyhow::Result<ExitCode> {
    let BoardCmd::Make { board: path, out } = cmd;
    let board = Board::load(&path)?;
    let name = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "board".to_string());
    std::fs::create_dir_all(&out)?;
    let inputs = vec![path.clone()];
    let files = [
        (format!("{name}.svg"), svg(&board)),
        (format!("{name}.dxf"), dxf(&board)),
        (format!("{name}.certificate-template.csv"), template(&board)),
    ];
    let mut written = Vec::new();
    for (file, text) in &files {
        let p = out.join(file);
        crate::front::write_atomic(&p, text.as_bytes(), &inputs)?;
        written.push(p.display().to_string());
    }
    let dots = u64::from(board.cols) * u64::from(board.rows);
    if json {
        crate::front::emit(&format!(
            "{}\n",
            json!({ "board": board.name, "dots": dots, "coded": board.code.is_some(), "files": written })
        ))?;
    } else {
        crate::front::emit(&format!(
            "{} ({} dots{}): wrote {}\n",
            board.name,
            dots,
            if board.code.is_some() { ", coded" } else { "" },
            written.join(", ")
        ))?;
    }
    Ok(ExitCode::SUCCESS)
}

/// Every dot: nominal centre (mm) and diameter (mm).
fn dots(board: &Board) -> impl Iterator<Item = ([f64; 2], f64)> + '_ {
    (0..board.rows as i64).flat_map(move |j| {
        (0..board.cols as i64).map(move |i| (board.nominal_xy(i, j), board.dot_diameter_at(i, j)))
    })
}

/// A margin of one pitch around the dots.
fn frame(board: &Board) -> ([f64; 2], [f64; 2]) {
    let (lo, hi) = board.extent();
    let m = board.pitch_mm;
    ([lo[0] - m, lo[1] - m], [hi[0] + m, hi[1] + m])
}

fn svg(board: &Board) -> String {
    let (lo, hi) = frame(board);
    let (w, h) = (hi[0] - lo[0], hi[1] - lo[1]);
    let (fg, bg) = match board.polarity {
        protocol::Polarity::DarkOnLight => ("black", "white"),
        protocol::Polarity::BrightOnDark => ("white", "black"),
    };
    let mut s = format!(
        "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}mm\" height=\"{h}mm\" viewBox=\"0 0 {w} {h}\">\n<rect width=\"{w}\" height=\"{h}\" fill=\"{bg}\"/>\n<g fill=\"{fg}\">\n"
    );
    for (c, d) in dots(board) {
        // SVG y runs down; the board's +y runs up.
        let _ = writeln!(
            s,
            "<circle cx=\"{:.4}\" cy=\"{:.4}\" r=\"{:.4}\"/>",
            c[0] - lo[0],
            hi[1] - c[1],
            d / 2.0
        );
    }
    s.push_str("</g>\n</svg>\n");
    s
}

fn dxf(board: &Board) -> String {
    // AutoCAD R12 style: a header with millimetre units, one CIRCLE per dot on layer DOTS.
    let mut s = String::from(
        "0\nSECTION\n2\nHEADER\n9\n$INSUNITS\n70\n4\n0\nENDSEC\n0\nSECTION\n2\nENTITIES\n",
    );
    for (c, d) in dots(board) {
        let _ = write!(
            s,
            "0\nCIRCLE\n8\nDOTS\n10\n{:.4}\n20\n{:.4}\n30\n0.0\n40\n{:.4}\n",
            c[0],
            c[1],
            d / 2.0
        );
    }
    s.push_str("0\nENDSEC\n0\nEOF\n");
    s
}

fn template(board: &Board) -> String {
    let mut s = format!(
        "# Certificate of `{}`: replace each nominal x_mm,y_mm by the measured position\n# (lines starting with # are ignored; unlisted points are taken as nominal)\ni,j,x_mm,y_mm\n",
        board.name
    );
    for j in 0..board.rows as i64 {
        for i in 0..board.cols as i64 {
            let n = board.nominal_xy(i, j);
            let _ = writeln!(s, "{i},{j},{:.6},{:.6}", n[0], n[1]);
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn artwork_has_every_dot_at_its_code_size_and_the_template_reads_back() {
        let mut b = Board::nominal(
            "t",
            0.5,
            0.25,
            protocol::Polarity::DarkOnLight,
            6,
            4,
            [0.0, 0.0],
        );
        b.set_code(28, [0.2, 0.3]);
        let s = svg(&b);
        assert_eq!(s.matches("<circle").count(), 24);
        assert!(s.contains("r=\"0.1500\"") && s.contains("r=\"0.1000\""));
        let d = dxf(&b);
        assert_eq!(d.matches("CIRCLE").count(), 24);
        assert!(d.ends_with("EOF\n"));
        let mut c = b.clone();
        c.apply_certificate("t.csv", &template(&b)).unwrap();
        assert_eq!(c.certified_points, 24);
        assert_eq!(c.true_xy(5, 3), b.true_xy(5, 3));
    }
}

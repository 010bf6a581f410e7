//! A board's artwork for the lab that makes it (DXF and SVG at 1:1, millimetres, board
//! +y up) and the certificate template the metrology lab fills in (`i,j,x_mm,y_mm`,
//! nominal positions to be replaced by the measured ones). Coded boards
//! (docs/coded-board.md) get each dot at its code size.

use crate::{Artifact, Outcome, Sink};
use protocol::Board;
use serde_json::{json, Map, Value};
use std::fmt::Write as _;

/// `gateway board make`: the three files handed to the sink as artifacts named after
/// the board file (`NAME.svg`, `NAME.dxf`, `NAME.certificate-template.csv`).
pub fn make(board: &Board, name: &str, sink: &mut dyn Sink) -> Outcome {
    let files = [
        (format!("{name}.svg"), "image/svg+xml", svg(board)),
        (format!("{name}.dxf"), "image/vnd.dxf", dxf(board)),
        (
            format!("{name}.certificate-template.csv"),
            "text/csv",
            template(board),
        ),
    ];
    let mut names = Vec::new();
    for (file, media_type, text) in files {
        names.push(file.clone());
        let artifact = Artifact {
            name: file,
            title: None,
            media_type,
            bytes: text.into_bytes(),
        };
        if let Err(e) = sink.artifact(artifact) {
            return Outcome::failed(e);
        }
    }
    let dots = u64::from(board.cols) * u64::from(board.rows);
    Outcome::succeeded(
        json!({"board": board.name, "dots": dots, "coded": board.code.is_some(), "files": names}),
        Map::new(),
    )
}

/// The result as text.
pub fn summary(r: &Value) -> String {
    let files: Vec<&str> = r["files"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(Value::as_str)
        .collect();
    format!(
        "{} ({} dots{}): {}",
        r["board"].as_str().unwrap_or(""),
        r["dots"],
        if r["coded"] == true { ", coded" } else { "" },
        files.join(", ")
    )
}

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

/// The artwork as SVG at 1:1 (mm), board +y up.
pub fn svg(board: &Board) -> String {
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

/// The artwork as DXF (R12 entities, mm: `$INSUNITS` 4), a CIRCLE per dot.
pub fn dxf(board: &Board) -> String {
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

/// The certificate template the metrology lab fills in (`i,j,x_mm,y_mm`).
pub fn template(board: &Board) -> String {
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

    #[test]
    fn the_artwork_has_a_circle_per_dot_and_the_template_a_row_per_dot() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let board = Board::load(&dir.join("../../config/boards/coded-0.5mm.toml")).unwrap();
        let mut sink = crate::Collect(Vec::new());
        let outcome = make(&board, "coded", &mut sink);
        assert!(outcome.is_success(), "{:?}", outcome.error());
        let dots = (board.cols * board.rows) as usize;
        let text = |n: &str| {
            let a = sink.0.iter().find(|a| a.name == n).unwrap();
            String::from_utf8(a.bytes.clone()).unwrap()
        };
        assert_eq!(text("coded.svg").matches("<circle").count(), dots);
        assert_eq!(text("coded.dxf").matches("\nCIRCLE\n").count(), dots);
        // Two dot sizes on a coded board.
        let radii: std::collections::BTreeSet<String> = text("coded.svg")
            .split(" r=\"")
            .skip(1)
            .map(|r| r.split('"').next().unwrap().to_string())
            .collect();
        assert_eq!(radii.len(), 2, "{radii:?}");
        let csv = text("coded.certificate-template.csv");
        assert_eq!(
            csv.lines().filter(|l| !l.starts_with('#')).count(),
            dots + 1
        );
    }
}

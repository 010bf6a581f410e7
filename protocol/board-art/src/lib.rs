//! A calibration board's artwork for the lab that makes it (DXF and SVG at 1:1,
//! millimetres, board +y up), a PDF for a test print at 1:1 on an office printer, and
//! the certificate template the metrology lab fills in (`i,j,x_mm,y_mm`, nominal
//! positions to be replaced by the measured ones). Coded boards (docs/coded-board.md)
//! get each dot at its code size. Sans-IO: each writer streams its file into any
//! `io::Write` a dot at a time (`board make` writes straight into the file beside its
//! final name, so memory stays at [`WORKING_MEMORY_BYTES`] whatever the board's size);
//! [`check`] sizes the files before any is made and refuses what no file or format can
//! hold.

use protocol::{Board, Polarity};
use std::io::{self, Write};

/// The most bytes all four files together may take on disk.
pub const MAX_OUTPUT_BYTES: u64 = 1 << 30;

/// What the writers hold while they write, whatever the board's size: a piece of the
/// PDF's content stream ([`PDF_DOTS_PER_PIECE`] dots of about 330 bytes), the deflate
/// state (about 300 KiB) and the caller's write buffer (64 KiB in
/// `protocol::config::write_output_with`), rounded up.
pub const WORKING_MEMORY_BYTES: u64 = 1 << 20;

/// The largest page side a PDF reader must open: 14 400 pt (200 in, 5 080 mm; PDF 1.7,
/// annex C.2, without UserUnit).
pub const MAX_PDF_PAGE_PT: f64 = 14_400.0;

/// The smallest dot drawn, mm: below a micrometre no process makes a dot (the board
/// file's own floor).
pub const MIN_DOT_MM: f64 = protocol::board::MIN_DOT_MM;

/// Why a board's artwork cannot be made (each names the limit).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ArtError {
    #[error("the test print's page would be {w_mm:.0} x {h_mm:.0} mm, more than the {limit_mm:.0} mm ({MAX_PDF_PAGE_PT} pt) a PDF page may have: a board this size is made from the DXF or SVG, not printed at 1:1")]
    PageTooLarge { w_mm: f64, h_mm: f64, limit_mm: f64 },
    #[error("a dot of {0:e} mm prints as nothing (at least {MIN_DOT_MM} mm)")]
    DotTooSmall(f64),
    #[error("the certificate template of {dots} dots would take about {bytes} bytes, more than the {cap} a certificate may have to be read back (the lab could not return it): make the board smaller or in parts")]
    CertificateTooLarge { dots: u64, bytes: u64, cap: u64 },
    #[error("the artwork of {dots} dots would take about {bytes} bytes, more than the {cap} bytes `board make` writes")]
    TooLarge { dots: u64, bytes: u64, cap: u64 },
}

/// Upper bounds of each file's bytes, from the board's size alone (nothing made).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sizes {
    pub svg: u64,
    pub dxf: u64,
    /// The PDF's content stream before compression (an upper bound of the file: the
    /// dots' operators deflate to a fraction of it).
    pub pdf: u64,
    pub template: u64,
}

impl Sizes {
    pub fn total(&self) -> u64 {
        self.svg + self.dxf + self.pdf + self.template
    }
}

/// The four files' sizes, or why they cannot be made: checked before any is.
pub fn check(board: &Board) -> Result<Sizes, ArtError> {
    let dots = u64::from(board.cols) * u64::from(board.rows);
    let smallest = match &board.code {
        Some(c) => c.dot_diameters_mm[0].min(c.dot_diameters_mm[1]),
        None => board.dot_diameter_mm,
    };
    if !(smallest >= MIN_DOT_MM) {
        return Err(ArtError::DotTooSmall(smallest));
    }
    let (lo, hi) = frame(board);
    let (w_mm, h_mm) = (hi[0] - lo[0], hi[1] - lo[1] + CAPTION_MM);
    let limit_mm = MAX_PDF_PAGE_PT / f64::from(PT_PER_MM);
    if !(w_mm <= limit_mm && h_mm <= limit_mm) {
        return Err(ArtError::PageTooLarge {
            w_mm,
            h_mm,
            limit_mm,
        });
    }
    // A coordinate's characters: sign, integer digits (the page is at most 5 080 mm),
    // point and decimals.
    let coord = |decimals: u64| 1 + 4 + 1 + decimals;
    let index = |n: u32| u64::from(n.max(1)).ilog10() as u64 + 1;
    let template = 200 + dots * (index(board.cols) + index(board.rows) + 2 * coord(6) + 4);
    let cap = protocol::config::MAX_FILE_BYTES;
    if template > cap {
        return Err(ArtError::CertificateTooLarge {
            dots,
            bytes: template,
            cap,
        });
    }
    let sizes = Sizes {
        svg: 300 + dots * (36 + 3 * coord(4)),
        dxf: 100 + dots * (50 + 3 * coord(4)),
        pdf: 1000 + dots * (5 * (6 * coord(4) + 4) + 8),
        template,
    };
    if sizes.total() > MAX_OUTPUT_BYTES {
        return Err(ArtError::TooLarge {
            dots,
            bytes: sizes.total(),
            cap: MAX_OUTPUT_BYTES,
        });
    }
    Ok(sizes)
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

/// The four files of a board, in the order `board make` writes them: the name's
/// extension (after `NAME.`), the media type, and the writer that streams the file.
pub const FILES: [(&str, &str, Writer); 4] = [
    ("svg", "image/svg+xml", write_svg),
    ("dxf", "image/vnd.dxf", write_dxf),
    ("pdf", "application/pdf", write_pdf),
    ("certificate-template.csv", "text/csv", write_template),
];

/// A file's writer: the file streamed into `out` a dot at a time (nothing of the size
/// of the file is held in memory).
pub type Writer = fn(&Board, &mut dyn Write) -> io::Result<()>;

/// A writer's bytes collected in memory (small boards, tests, the service's store).
fn collect(board: &Board, write: Writer) -> Vec<u8> {
    let mut bytes = Vec::new();
    write(board, &mut bytes).expect("writing into memory does not fail");
    bytes
}

/// The artwork as SVG at 1:1 (mm), board +y up ([`write_svg`] in memory).
pub fn svg(board: &Board) -> String {
    String::from_utf8(collect(board, write_svg)).expect("the SVG is ASCII")
}

/// [`svg`] streamed into `out`.
pub fn write_svg(board: &Board, out: &mut dyn Write) -> io::Result<()> {
    let (lo, hi) = frame(board);
    let (w, h) = (hi[0] - lo[0], hi[1] - lo[1]);
    let (fg, bg) = match board.polarity {
        Polarity::DarkOnLight => ("black", "white"),
        Polarity::BrightOnDark => ("white", "black"),
    };
    write!(
        out,
        "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}mm\" height=\"{h}mm\" viewBox=\"0 0 {w} {h}\">\n<rect width=\"{w}\" height=\"{h}\" fill=\"{bg}\"/>\n<g fill=\"{fg}\">\n"
    )?;
    for (c, d) in dots(board) {
        // SVG y runs down; the board's +y runs up.
        writeln!(
            out,
            "<circle cx=\"{:.4}\" cy=\"{:.4}\" r=\"{:.4}\"/>",
            c[0] - lo[0],
            hi[1] - c[1],
            d / 2.0
        )?;
    }
    out.write_all(b"</g>\n</svg>\n")
}

/// The artwork as DXF (R12 entities, mm: `$INSUNITS` 4), a CIRCLE per dot
/// ([`write_dxf`] in memory).
pub fn dxf(board: &Board) -> String {
    String::from_utf8(collect(board, write_dxf)).expect("the DXF is ASCII")
}

/// [`dxf`] streamed into `out`.
pub fn write_dxf(board: &Board, out: &mut dyn Write) -> io::Result<()> {
    // AutoCAD R12 style: a header with millimetre units, one CIRCLE per dot on layer DOTS.
    out.write_all(
        b"0\nSECTION\n2\nHEADER\n9\n$INSUNITS\n70\n4\n0\nENDSEC\n0\nSECTION\n2\nENTITIES\n",
    )?;
    for (c, d) in dots(board) {
        write!(
            out,
            "0\nCIRCLE\n8\nDOTS\n10\n{:.4}\n20\n{:.4}\n30\n0.0\n40\n{:.4}\n",
            c[0],
            c[1],
            d / 2.0
        )?;
    }
    out.write_all(b"0\nENDSEC\n0\nEOF\n")
}

/// Millimetres to PDF points.
pub const PT_PER_MM: f32 = 72.0 / 25.4;
/// Height of the caption strip under the artwork, mm.
pub const CAPTION_MM: f64 = 8.0;

/// A test print: one page the size of the artwork (plus a caption), dots at 1:1 in mm
/// (the content is drawn in mm through one scale transform, so each coordinate keeps
/// f32's precision, 0.01 um at 200 mm), Deflate-compressed. Printed at "actual size"
/// it checks the optics and the code before a lab makes the glass. ([`write_pdf`] in
/// memory.)
pub fn pdf(board: &Board) -> Vec<u8> {
    collect(board, write_pdf)
}

/// Counts the bytes written through it: the PDF's cross-reference table needs each
/// object's offset, and the content stream's length is known only once it is written.
struct Counted<'a> {
    out: &'a mut dyn Write,
    at: u64,
}

impl Write for Counted<'_> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let n = self.out.write(buf)?;
        self.at += n as u64;
        Ok(n)
    }
    fn flush(&mut self) -> io::Result<()> {
        self.out.flush()
    }
}

/// Dots drawn into one piece of the content stream before it is compressed and
/// written (a piece is about 300 bytes a dot).
pub const PDF_DOTS_PER_PIECE: usize = 1024;

/// [`pdf`] streamed into `out`: the objects written in order and their offsets counted,
/// the content stream deflated as it is drawn, its `/Length` an indirect object written
/// after it (PDF 1.7, 7.3.8.2), so no part of the file is held whole.
pub fn write_pdf(board: &Board, out: &mut dyn Write) -> io::Result<()> {
    use pdf_writer::{Content, Name, Str};
    let (lo, hi) = frame(board);
    let (w, h) = (hi[0] - lo[0], hi[1] - lo[1] + CAPTION_MM);
    let (fg, bg) = match board.polarity {
        Polarity::DarkOnLight => (0.0, 1.0),
        Polarity::BrightOnDark => (1.0, 0.0),
    };
    let mut out = Counted { out, at: 0 };
    // A binary comment on the second line tells transfer programs the file is binary.
    out.write_all(b"%PDF-1.7\n%\x80\x80\x80\x80\n")?;
    // Objects 1 to 6: catalog, page tree, page, content, font, the content's length.
    let mut offsets = [0u64; 6];
    offsets[0] = out.at;
    out.write_all(b"1 0 obj\n<<\n  /Type /Catalog\n  /Pages 2 0 R\n>>\nendobj\n")?;
    offsets[1] = out.at;
    out.write_all(b"2 0 obj\n<<\n  /Type /Pages\n  /Kids [3 0 R]\n  /Count 1\n>>\nendobj\n")?;
    offsets[2] = out.at;
    write!(
        out,
        "3 0 obj\n<<\n  /Type /Page\n  /MediaBox [0 0 {} {}]\n  /Parent 2 0 R\n  /Contents 4 0 R\n  /Resources <<\n    /Font <<\n      /F1 5 0 R\n    >>\n  >>\n>>\nendobj\n",
        pdf_number(w as f32 * PT_PER_MM),
        pdf_number(h as f32 * PT_PER_MM)
    )?;
    offsets[3] = out.at;
    out.write_all(b"4 0 obj\n<<\n  /Length 6 0 R\n  /Filter /FlateDecode\n>>\nstream\n")?;
    let stream_start = out.at;
    let mut z = flate2::write::ZlibEncoder::new(&mut out, flate2::Compression::new(6));
    let mut c = Content::new();
    c.save_state();
    c.transform([PT_PER_MM, 0.0, 0.0, PT_PER_MM, 0.0, 0.0]);
    // The board's background (a bright-on-dark board prints its dark field).
    c.set_fill_gray(bg);
    c.rect(0.0, CAPTION_MM as f32, w as f32, (hi[1] - lo[1]) as f32);
    c.fill_nonzero();
    c.set_fill_gray(fg);
    // A circle as four cubic Beziers (0.027 % radial error); the dots drawn a piece at
    // a time, each piece deflated as soon as it is drawn.
    const K: f32 = 0.552_284_8;
    let mut in_piece = 0;
    for (centre, d) in dots(board) {
        let x = (centre[0] - lo[0]) as f32;
        let y = (centre[1] - lo[1] + CAPTION_MM) as f32;
        let r = (d / 2.0) as f32;
        let k = K * r;
        c.move_to(x + r, y);
        c.cubic_to(x + r, y + k, x + k, y + r, x, y + r);
        c.cubic_to(x - k, y + r, x - r, y + k, x - r, y);
        c.cubic_to(x - r, y - k, x - k, y - r, x, y - r);
        c.cubic_to(x + k, y - r, x + r, y - k, x + r, y);
        c.close_path();
        in_piece += 1;
        if in_piece == PDF_DOTS_PER_PIECE {
            z.write_all(&std::mem::replace(&mut c, Content::new()).finish())?;
            z.write_all(b"\n")?;
            in_piece = 0;
        }
    }
    c.fill_nonzero();
    c.restore_state();
    let caption = format!(
        "{}: {} x {} dots, pitch {} mm{} - print at actual size (100 %), then measure the pitch",
        board.name,
        board.cols,
        board.rows,
        board.pitch_mm,
        if board.code.is_some() { ", coded" } else { "" }
    );
    c.set_fill_gray(0.0);
    c.begin_text();
    c.set_font(Name(b"F1"), 9.0);
    c.next_line(3.0 * PT_PER_MM, 3.0 * PT_PER_MM);
    // The base-14 fonts read single bytes: anything outside ASCII becomes '?'.
    let ascii: Vec<u8> = caption
        .chars()
        .map(|ch| if ch.is_ascii() { ch as u8 } else { b'?' })
        .collect();
    c.show(Str(&ascii));
    c.end_text();
    z.write_all(&c.finish())?;
    z.finish()?;
    let length = out.at - stream_start;
    out.write_all(b"\nendstream\nendobj\n")?;
    offsets[4] = out.at;
    out.write_all(
        b"5 0 obj\n<<\n  /Type /Font\n  /Subtype /Type1\n  /BaseFont /Helvetica\n>>\nendobj\n",
    )?;
    offsets[5] = out.at;
    write!(out, "6 0 obj\n{length}\nendobj\n")?;
    // The cross-reference table: entries of exactly 20 bytes (7.5.4).
    let xref = out.at;
    out.write_all(b"xref\n0 7\n0000000000 65535 f\r\n")?;
    for at in offsets {
        write!(out, "{at:010} 00000 n\r\n")?;
    }
    write!(
        out,
        "trailer\n<<\n  /Size 7\n  /Root 1 0 R\n>>\nstartxref\n{xref}\n%%EOF"
    )?;
    out.flush()
}

/// A number as PDF writes it: no exponent, at most 3 decimals, no trailing zeros.
fn pdf_number(v: f32) -> String {
    let s = format!("{v:.3}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    s.to_string()
}

/// The certificate template the metrology lab fills in (`i,j,x_mm,y_mm`)
/// ([`write_template`] in memory).
pub fn template(board: &Board) -> String {
    String::from_utf8(collect(board, write_template)).expect("the template is UTF-8")
}

/// [`template`] streamed into `out`.
pub fn write_template(board: &Board, out: &mut dyn Write) -> io::Result<()> {
    write!(
        out,
        "# Certificate of `{}`: replace each nominal x_mm,y_mm by the measured position\n# (lines starting with # are ignored; unlisted points are taken as nominal)\ni,j,x_mm,y_mm\n",
        board.name
    )?;
    for j in 0..board.rows as i64 {
        for i in 0..board.cols as i64 {
            let n = board.nominal_xy(i, j);
            writeln!(out, "{i},{j},{:.6},{:.6}", n[0], n[1])?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The page size (points) and the content's operator lines, read back by hand:
    /// the MediaBox, the one Flate stream inflated.
    fn read_pdf(pdf: &[u8]) -> ([f64; 2], Vec<String>) {
        let text = String::from_utf8_lossy(pdf);
        let mb = text.split("/MediaBox [").nth(1).expect("a MediaBox");
        let v: Vec<f64> = mb
            .split(']')
            .next()
            .unwrap()
            .split_whitespace()
            .map(|x| x.parse().unwrap())
            .collect();
        let start = pdf.windows(7).position(|w| w == b"stream\n").unwrap() + 7;
        let end = pdf.windows(10).position(|w| w == b"\nendstream").unwrap();
        let raw = miniz_oxide::inflate::decompress_to_vec_zlib(&pdf[start..end]).unwrap();
        let ops = String::from_utf8(raw)
            .unwrap()
            .lines()
            .map(str::to_string)
            .collect();
        ([v[2] - v[0], v[3] - v[1]], ops)
    }

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
        b.set_code(protocol::board_code::CodeScheme::Additive, 28, [0.2, 0.3]);
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
        let sizes = check(&board).unwrap();
        let dots = (board.cols * board.rows) as usize;
        let (svg_text, dxf_text, pdf_bytes, csv) =
            (svg(&board), dxf(&board), pdf(&board), template(&board));
        // The estimates made before are upper bounds of what was made.
        assert!(svg_text.len() as u64 <= sizes.svg, "{sizes:?}");
        assert!(dxf_text.len() as u64 <= sizes.dxf, "{sizes:?}");
        assert!(csv.len() as u64 <= sizes.template, "{sizes:?}");
        let text = |n: &str| match n {
            "coded.svg" => svg_text.clone(),
            _ => csv.clone(),
        };
        assert_eq!(svg_text.matches("<circle").count(), dots);
        assert_eq!(dxf_text.matches("\nCIRCLE\n").count(), dots);
        let (page_pt, ops) = read_pdf(&pdf_bytes);
        let raw: usize = ops.iter().map(|l| l.len() + 1).sum();
        assert!(raw as u64 <= sizes.pdf, "{raw} {sizes:?}");
        // The page: the artwork and a pitch of margin each side, plus the caption.
        let (lo, hi) = board.extent();
        let m = board.pitch_mm;
        let expect = [
            (hi[0] - lo[0] + 2.0 * m) * 72.0 / 25.4,
            (hi[1] - lo[1] + 2.0 * m + CAPTION_MM) * 72.0 / 25.4,
        ];
        assert!(
            (page_pt[0] - expect[0]).abs() < 0.01,
            "{page_pt:?} {expect:?}"
        );
        assert!(
            (page_pt[1] - expect[1]).abs() < 0.01,
            "{page_pt:?} {expect:?}"
        );
        // One closed path of four curves per dot.
        assert_eq!(ops.iter().filter(|l| l.ends_with(" m")).count(), dots);
        assert_eq!(ops.iter().filter(|l| l.ends_with(" c")).count(), 4 * dots);
        // The first dot, (0, 0), starts at its right edge, in mm from the page's corner.
        let first = ops.iter().find(|l| l.ends_with(" m")).unwrap();
        let xy: Vec<f64> = first
            .split(' ')
            .take(2)
            .map(|v| v.parse().unwrap())
            .collect();
        let c = board.nominal_xy(0, 0);
        let r = board.dot_diameter_at(0, 0) / 2.0;
        assert!((xy[0] - (c[0] - (lo[0] - m) + r)).abs() < 1e-4, "{first}");
        assert!(
            (xy[1] - (c[1] - (lo[1] - m) + CAPTION_MM)).abs() < 1e-4,
            "{first}"
        );
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

    /// The hand-written PDF's structure: every cross-reference entry points at its
    /// object, `startxref` at the table, the indirect `/Length` is the stream's length
    /// (what a reader checks before it opens the file).
    #[test]
    fn the_streamed_pdf_has_its_objects_where_its_cross_reference_says() {
        let mut b = Board::nominal("t", 0.5, 0.25, Polarity::BrightOnDark, 90, 40, [0.0, 0.0]);
        b.set_code(protocol::board_code::CodeScheme::Additive, 28, [0.2, 0.3]);
        let pdf = pdf(&b);
        assert!(pdf.starts_with(b"%PDF-1.7\n") && pdf.ends_with(b"%%EOF"));
        let text = String::from_utf8_lossy(&pdf);
        let startxref: usize = text
            .rsplit("startxref\n")
            .next()
            .unwrap()
            .lines()
            .next()
            .unwrap()
            .parse()
            .unwrap();
        assert!(pdf[startxref..].starts_with(b"xref\n0 7\n"));
        let entries = &pdf[startxref + 9..];
        for n in 1..=6 {
            let entry = &entries[20 * n..20 * n + 20];
            assert!(entry.ends_with(b" 00000 n\r\n"), "{n}");
            let at: usize = std::str::from_utf8(&entry[..10]).unwrap().parse().unwrap();
            assert!(
                pdf[at..].starts_with(format!("{n} 0 obj\n").as_bytes()),
                "object {n}"
            );
        }
        let start = pdf.windows(7).position(|w| w == b"stream\n").unwrap() + 7;
        let end = pdf.windows(10).position(|w| w == b"\nendstream").unwrap();
        let length: usize = text
            .split("6 0 obj\n")
            .nth(1)
            .unwrap()
            .lines()
            .next()
            .unwrap()
            .parse()
            .unwrap();
        assert_eq!(end - start, length);
        // Several pieces of the content stream: every dot still there, once.
        let (_, ops) = read_pdf(&pdf);
        const { assert!(90 * 40 > 3 * PDF_DOTS_PER_PIECE) };
        assert_eq!(ops.iter().filter(|l| l.ends_with(" m")).count(), 90 * 40);
        assert_eq!(ops.iter().filter(|l| l.as_str() == "f").count(), 2);
    }

    /// The writers stream: into a writer that takes at most 64 KiB at a time and counts
    /// what it is given, each file arrives in pieces and whole, the same bytes as in
    /// memory.
    #[test]
    fn each_file_is_written_as_a_stream_of_small_pieces() {
        struct Pieces {
            bytes: u64,
            largest: usize,
            pieces: u64,
            all: Vec<u8>,
        }
        impl Write for Pieces {
            fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
                let n = buf.len().min(1 << 16);
                self.bytes += n as u64;
                self.largest = self.largest.max(n);
                self.pieces += 1;
                self.all.extend_from_slice(&buf[..n]);
                Ok(n)
            }
            fn flush(&mut self) -> io::Result<()> {
                Ok(())
            }
        }
        let b = Board::nominal("t", 0.5, 0.25, Polarity::DarkOnLight, 200, 100, [0.0, 0.0]);
        let memory = [
            svg(&b).into_bytes(),
            dxf(&b).into_bytes(),
            pdf(&b),
            template(&b).into_bytes(),
        ];
        for ((ext, _, write), whole) in FILES.iter().zip(memory) {
            let mut p = Pieces {
                bytes: 0,
                largest: 0,
                pieces: 0,
                all: Vec::new(),
            };
            write(&b, &mut p).unwrap();
            assert_eq!(p.all, whole, "{ext}");
            assert!(p.pieces > 100, "{ext}: {} pieces", p.pieces);
            assert!(
                p.bytes as usize == whole.len() && whole.len() > 4 * p.largest,
                "{ext}"
            );
        }
    }

    /// Issue 38: a 7071 x 7071 board aborted at 4.7 GB after 40 s; a 1e300 mm pitch made
    /// an infinite page, a 1e-300 mm dot a file of circles of radius 0. Each is refused
    /// before anything is made, naming the limit.
    #[test]
    fn what_no_file_or_format_can_hold_is_refused_before_anything_is_made() {
        let board = |pitch, dot, cols, rows| {
            Board::nominal(
                "t",
                pitch,
                dot,
                Polarity::DarkOnLight,
                cols,
                rows,
                [0.0, 0.0],
            )
        };
        // (The board file refuses 7071 x 7071 points itself: 1000 x 1000 is allowed.)
        let e = check(&board(0.5, 0.25, 1000, 1000)).unwrap_err();
        assert!(matches!(e, ArtError::CertificateTooLarge { .. }), "{e}");
        assert!(e.to_string().contains("16777216"), "{e}");
        let e = check(&board(1e300, 0.25, 10, 10)).unwrap_err();
        assert!(matches!(e, ArtError::PageTooLarge { .. }), "{e}");
        // A 10 m board: beyond a PDF page, whatever its dots.
        let e = check(&board(100.0, 10.0, 101, 3)).unwrap_err();
        assert!(e.to_string().contains("5080 mm"), "{e}");
        let e = check(&board(0.5, 1e-300, 10, 10)).unwrap_err();
        assert!(matches!(e, ArtError::DotTooSmall(_)), "{e}");
        // The default board is well inside every limit.
        check(&board(0.5, 0.25, 421, 321)).unwrap();
    }
}

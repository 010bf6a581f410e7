//! Calibration boards: a planar grid of dots whose true positions are certified.
//!
//! File format (TOML):
//! ```toml
//! [board]
//! name = "0.5 mm dot grid"
//! pitch_mm = 0.5            # grid pitch, both directions
//! dot_diameter_mm = 0.25
//! polarity = "dark-on-light" # or "bright-on-dark"
//! cols = 420                # points along board +x (index i)
//! rows = 320                # points along board +y (index j)
//! origin_mm = [0.0, 0.0]    # board coordinate of point (i=0, j=0)
//! certified = "plate.csv"   # optional certificate, relative to this file
//!
//! [board.code]              # optional: a coded board (docs/coded-board.md)
//! scheme = "random-two-size"
//! seed = 28                 # bit(i, j) = top bit of SplitMix64(seed + (j << 32 | i))
//! dot_diameters_mm = [0.2, 0.3] # a 0 dot, a 1 dot; dot_diameter_mm lies between
//! ```
//! The certificate is CSV with a header `i,j,x_mm,y_mm`: the true (measured by a
//! metrology lab) coordinate of each listed point. Points not listed are taken at their
//! nominal position, so a board without a certificate is a perfect nominal grid.

use crate::board_code::{BoardCode, CodeScheme, CodeSection, MIN_SIZE_RATIO};
use crate::config::{ConfigDoc, ConfigError, Location, Xy};
use crate::text::escape_text;
use serde::{Deserialize, Serialize};
use std::path::Path;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Polarity {
    /// Dark dots printed on a light plate (front-lit chrome on glass, paper targets).
    DarkOnLight,
    /// Bright dots on a dark field (back-lit glass with holes in the chrome).
    BrightOnDark,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct BoardFile {
    board: BoardSection,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct BoardSection {
    #[serde(default)]
    name: String,
    pitch_mm: f64,
    dot_diameter_mm: f64,
    polarity: Polarity,
    cols: u32,
    rows: u32,
    #[serde(default)]
    origin_mm: Xy,
    #[serde(default)]
    certified: Option<String>,
    #[serde(default)]
    code: Option<CodeSection>,
}

/// A loaded board: geometry plus the true coordinate of every point.
#[derive(Clone, Debug, PartialEq)]
pub struct Board {
    pub name: String,
    pub pitch_mm: f64,
    pub dot_diameter_mm: f64,
    pub polarity: Polarity,
    pub cols: u32,
    pub rows: u32,
    pub origin_mm: [f64; 2],
    /// True coordinates, row-major (`j * cols + i`); equal to nominal where uncertified.
    certified: Vec<[f64; 2]>,
    /// How many points the certificate listed (0 for a nominal board).
    pub certified_points: usize,
    /// The position code of a coded board (dots of two sizes); None for a plain grid.
    pub code: Option<BoardCode>,
}

/// The pitch a board file may give, mm: below 10 um no camera of this gateway resolves
/// the dots; past a metre the board is no calibration board.
pub const MIN_PITCH_MM: f64 = 0.01;
pub const MAX_PITCH_MM: f64 = 1000.0;
/// The smallest dot, mm: below a micrometre no process makes a dot.
pub const MIN_DOT_MM: f64 = 0.001;
/// The most points a board file may have: each point's true position is held
/// (16 bytes), 64 MB at most; the largest board here has 135 000.
pub const MAX_POINTS: u64 = 4_000_000;
/// How far from zero a board's corners may lie, mm (as a job's board offset).
pub const MAX_ORIGIN_MM: f64 = 10_000.0;

/// Largest certificate deviation from nominal that is believed, as a fraction of pitch:
/// anything larger is a typo or a certificate for another board.
const MAX_CERT_DEVIATION_OF_PITCH: f64 = 0.1;

impl Board {
    /// A perfect nominal grid (no certificate).
    pub fn nominal(
        name: &str,
        pitch_mm: f64,
        dot_diameter_mm: f64,
        polarity: Polarity,
        cols: u32,
        rows: u32,
        origin_mm: [f64; 2],
    ) -> Self {
        let mut b = Board {
            name: name.to_string(),
            pitch_mm,
            dot_diameter_mm,
            polarity,
            cols,
            rows,
            origin_mm,
            certified: Vec::new(),
            certified_points: 0,
            code: None,
        };
        b.certified = (0..rows)
            .flat_map(|j| (0..cols).map(move |i| (i, j)))
            .map(|(i, j)| b.nominal_xy(i as i64, j as i64))
            .collect();
        b
    }

    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        Self::from_doc(&ConfigDoc::read(path)?)
    }

    pub fn from_doc(doc: &ConfigDoc) -> Result<Self, ConfigError> {
        let f: BoardFile = doc.parse()?;
        let s = f.board;
        doc.in_range(
            "board.pitch_mm",
            s.pitch_mm,
            MIN_PITCH_MM,
            MAX_PITCH_MM,
            "mm",
        )?;
        if !(s.dot_diameter_mm >= MIN_DOT_MM && s.dot_diameter_mm < s.pitch_mm) {
            return Err(doc.invalid(
                "board.dot_diameter_mm",
                format!(
                    "`{}`: must be at least {MIN_DOT_MM} mm (no process makes a smaller dot) and smaller than the pitch ({} mm)",
                    s.dot_diameter_mm, s.pitch_mm
                ),
            ));
        }
        if s.cols < 2 || s.rows < 2 {
            let key = if s.cols < 2 {
                "board.cols"
            } else {
                "board.rows"
            };
            return Err(doc.invalid(key, "a board needs at least 2 x 2 points"));
        }
        let points = u64::from(s.cols) * u64::from(s.rows);
        if points > MAX_POINTS {
            return Err(doc.invalid(
                "board.cols",
                format!(
                    "{} x {} = {points} points, more than the {MAX_POINTS} a board may have (each point's true position is held: {} MB)",
                    s.cols,
                    s.rows,
                    points * 16 / 1_000_000
                ),
            ));
        }
        for (i, v) in s.origin_mm.0.iter().enumerate() {
            doc.in_range(
                &format!("board.origin_mm[{i}]"),
                *v,
                -MAX_ORIGIN_MM,
                MAX_ORIGIN_MM,
                "mm",
            )
            .map_err(|_| {
                doc.invalid(
                    "board.origin_mm",
                    format!("`{v}`: each coordinate must be a finite number within -{MAX_ORIGIN_MM}..={MAX_ORIGIN_MM} mm"),
                )
            })?;
        }
        // The far corner too: on a machine, not only its origin.
        let far = [
            s.origin_mm.0[0] + f64::from(s.cols - 1) * s.pitch_mm,
            s.origin_mm.0[1] + f64::from(s.rows - 1) * s.pitch_mm,
        ];
        if !far.iter().all(|v| v.abs() <= MAX_ORIGIN_MM) {
            return Err(doc.invalid(
                "board.cols",
                format!(
                    "the board's far corner ({:.0}, {:.0}) mm lies beyond {MAX_ORIGIN_MM} mm from zero: no machine holds it",
                    far[0], far[1]
                ),
            ));
        }
        let mut board = Board::nominal(
            &s.name,
            s.pitch_mm,
            s.dot_diameter_mm,
            s.polarity,
            s.cols,
            s.rows,
            s.origin_mm.0,
        );
        if let Some(c) = &s.code {
            let scheme = check_code(doc, c, s.pitch_mm, s.dot_diameter_mm)?;
            board.set_code(scheme, c.seed, c.dot_diameters_mm);
        }
        if let Some(rel) = &s.certified {
            let cert = doc.read_relative("board.certified", rel)?;
            board.apply_certificate(&cert.name, &cert.text)?;
        }
        Ok(board)
    }

    /// Make this board a coded one (dots of two sizes carrying `seed`'s code).
    pub fn set_code(&mut self, scheme: CodeScheme, seed: u64, dot_diameters_mm: [f64; 2]) {
        self.code = Some(BoardCode::generate(
            scheme,
            seed,
            dot_diameters_mm,
            self.cols,
            self.rows,
        ));
    }

    /// Diameter of dot (i, j), mm: its code size on a coded board.
    #[inline]
    pub fn dot_diameter_at(&self, i: i64, j: i64) -> f64 {
        match &self.code {
            Some(c) => c.diameter_mm(i, j),
            None => self.dot_diameter_mm,
        }
    }

    /// Largest dot diameter on the board, mm.
    pub fn max_dot_diameter_mm(&self) -> f64 {
        match &self.code {
            Some(c) => c.dot_diameters_mm[0].max(c.dot_diameters_mm[1]),
            None => self.dot_diameter_mm,
        }
    }

    /// Read a certificate (`i,j,x_mm,y_mm` CSV) into the board; errors name file and line.
    pub fn apply_certificate(&mut self, file: &str, text: &str) -> Result<(), ConfigError> {
        let err = |line: usize, msg: String| ConfigError::Invalid {
            location: Location {
                file: file.to_string(),
                line: Some(line),
                column: None,
                key: None,
            },
            message: msg,
        };
        // A byte-order mark (some spreadsheets write one) is not part of the header.
        let text = text.strip_prefix('\u{FEFF}').unwrap_or(text);
        let mut seen = vec![false; self.certified.len()];
        let mut count = 0;
        for (n, raw) in text.lines().enumerate() {
            let line_no = n + 1;
            let line = raw.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let fields: Vec<&str> = line.split(',').map(str::trim).collect();
            let shown = |k: usize| escape_text(fields[k]);
            if fields.len() != 4 {
                return Err(err(
                    line_no,
                    format!("expected 4 fields i,j,x_mm,y_mm, got {}", fields.len()),
                ));
            }
            if fields[0] == "i" {
                continue; // header
            }
            let i: u32 = fields[0].parse().map_err(|_| {
                err(
                    line_no,
                    format!("column i: `{}` is not a point index", shown(0)),
                )
            })?;
            let j: u32 = fields[1].parse().map_err(|_| {
                err(
                    line_no,
                    format!("column j: `{}` is not a point index", shown(1)),
                )
            })?;
            let x: f64 = fields[2].parse().map_err(|_| {
                err(
                    line_no,
                    format!("column x_mm: `{}` is not a number", shown(2)),
                )
            })?;
            let y: f64 = fields[3].parse().map_err(|_| {
                err(
                    line_no,
                    format!("column y_mm: `{}` is not a number", shown(3)),
                )
            })?;
            if i >= self.cols || j >= self.rows {
                return Err(err(
                    line_no,
                    format!(
                        "point ({i},{j}) is outside the {}x{} board",
                        self.cols, self.rows
                    ),
                ));
            }
            let nom = self.nominal_xy(i as i64, j as i64);
            let dev = ((x - nom[0]).powi(2) + (y - nom[1]).powi(2)).sqrt();
            if !(dev <= MAX_CERT_DEVIATION_OF_PITCH * self.pitch_mm) {
                return Err(err(
                    line_no,
                    format!(
                        "point ({i},{j}) certified at ({x}, {y}) is {dev:.4} mm from nominal ({:.4}, {:.4}): not this board",
                        nom[0], nom[1]
                    ),
                ));
            }
            let k = self.index(i, j);
            if seen[k] {
                return Err(err(line_no, format!("point ({i},{j}) is listed twice")));
            }
            seen[k] = true;
            self.certified[k] = [x, y];
            count += 1;
        }
        if count == 0 {
            return Err(ConfigError::Invalid {
                location: Location {
                    file: file.to_string(),
                    line: None,
                    column: None,
                    key: None,
                },
                message: "the certificate lists no points: a certificate is a header \
                          `i,j,x_mm,y_mm` and one line per measured point (leave \
                          `certified` out for a nominal board)"
                    .to_string(),
            });
        }
        self.certified_points = count;
        Ok(())
    }

    #[inline]
    fn index(&self, i: u32, j: u32) -> usize {
        j as usize * self.cols as usize + i as usize
    }

    /// Nominal coordinate of point (i, j); defined for any integers (off-board too).
    #[inline]
    pub fn nominal_xy(&self, i: i64, j: i64) -> [f64; 2] {
        [
            self.origin_mm[0] + i as f64 * self.pitch_mm,
            self.origin_mm[1] + j as f64 * self.pitch_mm,
        ]
    }

    /// True (certified) coordinate of point (i, j), or None off the board.
    #[inline]
    pub fn true_xy(&self, i: i64, j: i64) -> Option<[f64; 2]> {
        if i < 0 || j < 0 || i >= self.cols as i64 || j >= self.rows as i64 {
            return None;
        }
        Some(self.certified[self.index(i as u32, j as u32)])
    }

    /// Set a point's true coordinate (used by generators of synthetic plates).
    pub fn set_true_xy(&mut self, i: u32, j: u32, xy: [f64; 2]) {
        let k = self.index(i, j);
        self.certified[k] = xy;
    }

    /// Board extent: (min corner, max corner) of the nominal grid, in mm.
    pub fn extent(&self) -> ([f64; 2], [f64; 2]) {
        (
            self.origin_mm,
            self.nominal_xy(self.cols as i64 - 1, self.rows as i64 - 1),
        )
    }

    /// Write the certificate CSV of every point that differs from nominal.
    /// SHA-256 (hex) of the board's geometry and certificate: what an error map records
    /// so that it is refused with any other board or certificate.
    pub fn fingerprint_sha256(&self) -> String {
        use sha2::{Digest, Sha256};
        let mut h = Sha256::new();
        h.update(format!(
            "{} pitch {} dot {} {:?} {}x{} origin {:?}\n",
            self.name,
            self.pitch_mm,
            self.dot_diameter_mm,
            self.polarity,
            self.cols,
            self.rows,
            self.origin_mm
        ));
        if let Some(c) = &self.code {
            // Plain boards hash as before, so their maps stay valid; so do boards of the
            // first scheme (its name is the one this line always had).
            h.update(format!(
                "code {} seed {} sizes {:?}\n",
                c.scheme.name(),
                c.seed,
                c.dot_diameters_mm
            ));
        }
        h.update(self.certificate_csv());
        h.finalize().iter().map(|b| format!("{b:02x}")).collect()
    }

    pub fn certificate_csv(&self) -> String {
        let mut out = String::from("i,j,x_mm,y_mm\n");
        for j in 0..self.rows {
            for i in 0..self.cols {
                let t = self.certified[self.index(i, j)];
                let n = self.nominal_xy(i as i64, j as i64);
                // Compared as written (6 decimals, a nanometre): a point within half a
                // nanometre of nominal is written as nominal, so it is left out, and the
                // file reads back to the same certificate.
                let (tx, ty) = (format!("{:.6}", t[0]), format!("{:.6}", t[1]));
                if (tx.as_str(), ty.as_str())
                    != (
                        format!("{:.6}", n[0]).as_str(),
                        format!("{:.6}", n[1]).as_str(),
                    )
                {
                    out.push_str(&format!("{i},{j},{tx},{ty}\n"));
                }
            }
        }
        out
    }
}

/// The `[board.code]` section: a known scheme (returned), two sizes that can be told
/// apart, both inside the pitch, the nominal dot diameter between them.
fn check_code(
    doc: &ConfigDoc,
    c: &CodeSection,
    pitch_mm: f64,
    dot_diameter_mm: f64,
) -> Result<CodeScheme, ConfigError> {
    let Some(scheme) = CodeScheme::from_name(&c.scheme) else {
        return Err(doc.invalid(
            "board.code.scheme",
            format!(
                "unknown code scheme `{}`: `keyed-two-size` (new boards) or \
                 `random-two-size` (boards printed before issue 38)",
                escape_text(&c.scheme)
            ),
        ));
    };
    let [d0, d1] = c.dot_diameters_mm;
    let key = "board.code.dot_diameters_mm";
    if !(d0.is_finite() && d1.is_finite() && d0 >= MIN_DOT_MM && d1 >= MIN_DOT_MM) {
        return Err(doc.invalid(
            key,
            format!("both diameters must be numbers of at least {MIN_DOT_MM} mm (no process makes a smaller dot)"),
        ));
    }
    if !(d1 >= MIN_SIZE_RATIO * d0) {
        return Err(doc.invalid(
            key,
            format!(
                "the 1 dot ({d1} mm) must be at least {MIN_SIZE_RATIO} times the 0 dot ({d0} mm) so the sizes can be told apart"
            ),
        ));
    }
    if !(d1 <= 0.8 * pitch_mm) {
        return Err(doc.invalid(
            key,
            format!(
                "the 1 dot ({d1} mm) must be at most 0.8 of the pitch ({} mm): neighbours would merge",
                0.8 * pitch_mm
            ),
        ));
    }
    if !(d0 < dot_diameter_mm && dot_diameter_mm < d1) {
        return Err(doc.invalid(
            "board.dot_diameter_mm",
            format!(
                "on a coded board the nominal dot diameter lies between the two code sizes ({d0} and {d1} mm)"
            ),
        ));
    }
    Ok(scheme)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn doc(text: &str) -> ConfigDoc {
        ConfigDoc::from_text("b.toml", text, Path::new("."))
    }

    const GOOD: &str = "[board]\npitch_mm = 0.5\ndot_diameter_mm = 0.25\npolarity = \"dark-on-light\"\ncols = 10\nrows = 8\norigin_mm = [1.0, 2.0]\n";

    /// Issue 38: every number of a board file has a floor and a ceiling that make
    /// physical sense; NaN, inf, subnormal, negative and absurd values are refused
    /// naming the key (a 1e300 mm pitch made an infinite page, a 1e-300 mm dot circles
    /// of radius 0, 7071 x 7071 points took gigabytes, a 1e308 origin a vague error).
    #[test]
    fn every_number_of_a_board_file_is_bounded_and_named() {
        let cases: &[(&str, &str, &str)] = &[
            ("pitch_mm = 0.5", "pitch_mm = nan", "board.pitch_mm"),
            ("pitch_mm = 0.5", "pitch_mm = inf", "board.pitch_mm"),
            ("pitch_mm = 0.5", "pitch_mm = -0.5", "board.pitch_mm"),
            ("pitch_mm = 0.5", "pitch_mm = 4e-320", "board.pitch_mm"),
            ("pitch_mm = 0.5", "pitch_mm = 1e300", "board.pitch_mm"),
            ("pitch_mm = 0.5", "pitch_mm = 0.005", "board.pitch_mm"),
            (
                "dot_diameter_mm = 0.25",
                "dot_diameter_mm = 1e-300",
                "board.dot_diameter_mm",
            ),
            (
                "dot_diameter_mm = 0.25",
                "dot_diameter_mm = nan",
                "board.dot_diameter_mm",
            ),
            (
                "dot_diameter_mm = 0.25",
                "dot_diameter_mm = -0.25",
                "board.dot_diameter_mm",
            ),
            (
                "dot_diameter_mm = 0.25",
                "dot_diameter_mm = 0.5",
                "board.dot_diameter_mm",
            ),
            ("cols = 10", "cols = 7071", "board.cols"), // with rows = 7071 below
            ("cols = 10", "cols = 1", "board.cols"),
            (
                "origin_mm = [1.0, 2.0]",
                "origin_mm = [1e308, 2.0]",
                "board.origin_mm",
            ),
            (
                "origin_mm = [1.0, 2.0]",
                "origin_mm = [1.0, nan]",
                "board.origin_mm",
            ),
            (
                "origin_mm = [1.0, 2.0]",
                "origin_mm = [-1e5, 2.0]",
                "board.origin_mm",
            ),
            (
                "origin_mm = [1.0, 2.0]",
                "origin_mm = [9999.0, 2.0]",
                "board.cols",
            ),
        ];
        for (from, to, key) in cases {
            let mut text = GOOD.replace(from, to);
            if to.contains("7071") {
                text = text.replace("rows = 8", "rows = 7071");
            }
            let e = Board::from_doc(&doc(&text)).unwrap_err();
            let loc = e.location().and_then(|l| l.key.clone()).unwrap_or_default();
            assert!(loc.starts_with(key), "{to}: {e}");
        }
        // At the bounds: accepted.
        for (from, to) in [
            ("pitch_mm = 0.5", "pitch_mm = 0.01"),
            ("dot_diameter_mm = 0.25", "dot_diameter_mm = 0.001"),
            ("origin_mm = [1.0, 2.0]", "origin_mm = [-10000.0, 9000.0]"),
        ] {
            let text = GOOD.replace(from, to).replace(
                "pitch_mm = 0.01\ndot_diameter_mm = 0.25",
                "pitch_mm = 0.01\ndot_diameter_mm = 0.005",
            );
            Board::from_doc(&doc(&text)).unwrap_or_else(|e| panic!("{to}: {e}"));
        }
        // The code's sizes: a subnormal dot refused naming them.
        let coded = GOOD.to_string()
            + "[board.code]\nscheme = \"keyed-two-size\"\nseed = 1\ndot_diameters_mm = [4e-320, 0.3]\n";
        let e = Board::from_doc(&doc(&coded)).unwrap_err().to_string();
        assert!(e.contains("board.code.dot_diameters_mm"), "{e}");
    }

    const CODED: &str = "[board]\npitch_mm = 0.5\ndot_diameter_mm = 0.25\npolarity = \"dark-on-light\"\ncols = 10\nrows = 8\norigin_mm = [1.0, 2.0]\n[board.code]\nscheme = \"random-two-size\"\nseed = 28\ndot_diameters_mm = [0.2, 0.3]\n";

    #[test]
    fn a_coded_board_loads_and_a_plain_one_keeps_its_fingerprint() {
        let plain = Board::from_doc(&doc(GOOD)).unwrap();
        assert!(plain.code.is_none());
        assert_eq!(plain.dot_diameter_at(3, 3), 0.25);
        let coded = Board::from_doc(&doc(CODED)).unwrap();
        let c = coded.code.as_ref().unwrap();
        assert_eq!(c.seed, 28);
        for (i, j) in [(0, 0), (3, 4), (9, 7)] {
            let d = coded.dot_diameter_at(i, j);
            let want = if crate::board_code::code_bit(CodeScheme::Additive, 28, i as u32, j as u32)
            {
                0.3
            } else {
                0.2
            };
            assert_eq!(d, want);
        }
        assert_eq!(coded.max_dot_diameter_mm(), 0.3);
        assert_ne!(plain.fingerprint_sha256(), coded.fingerprint_sha256());
        // The plain fingerprint is the one maps recorded before coded boards existed.
        let again = Board::nominal("", 0.5, 0.25, Polarity::DarkOnLight, 10, 8, [1.0, 2.0]);
        assert_eq!(plain.fingerprint_sha256(), again.fingerprint_sha256());
    }

    /// Issue 38: new boards name the keyed scheme; boards of the first scheme read (and
    /// fingerprint) as before; the two are different boards.
    #[test]
    fn a_keyed_board_loads_and_an_old_one_reads_as_before() {
        let old = Board::from_doc(&doc(CODED)).unwrap();
        assert_eq!(old.code.as_ref().unwrap().scheme, CodeScheme::Additive);
        let keyed = Board::from_doc(&doc(
            &CODED.replace("\"random-two-size\"", "\"keyed-two-size\"")
        ))
        .unwrap();
        let c = keyed.code.as_ref().unwrap();
        assert_eq!(c.scheme, CodeScheme::Keyed);
        let differ = (0..10)
            .flat_map(|i| (0..8).map(move |j| (i, j)))
            .filter(|&(i, j)| {
                let want = crate::board_code::code_bit(CodeScheme::Keyed, 28, i, j);
                assert_eq!(c.bit(i.into(), j.into()), Some(want));
                c.bit(i.into(), j.into()) != old.code.as_ref().unwrap().bit(i.into(), j.into())
            })
            .count();
        assert!(differ > 20, "{differ}");
        assert_ne!(keyed.fingerprint_sha256(), old.fingerprint_sha256());
    }

    #[test]
    fn a_bad_code_section_is_refused_naming_the_key() {
        for (from, to, key) in [
            ("\"random-two-size\"", "\"qr\"", "board.code.scheme"),
            ("[0.2, 0.3]", "[0.2, 0.22]", "board.code.dot_diameters_mm"),
            ("[0.2, 0.3]", "[0.2, 0.45]", "board.code.dot_diameters_mm"),
            ("[0.2, 0.3]", "[-0.2, 0.3]", "board.code.dot_diameters_mm"),
            // A third value was dropped silently (issue 38).
            ("[0.2, 0.3]", "[0.2, 0.3, 0.4]", "[0 dot, 1 dot]"),
            (
                "dot_diameter_mm = 0.25",
                "dot_diameter_mm = 0.35",
                "board.dot_diameter_mm",
            ),
            ("seed = 28", "seed = -1", "board.code.seed"),
            ("seed = 28", "seed = 28\ncolour = 1", "colour"),
        ] {
            let bad = CODED.replace(from, to);
            let e = Board::from_doc(&doc(&bad)).unwrap_err().to_string();
            assert!(e.contains(key), "{to}: {e}");
        }
    }

    #[test]
    fn an_origin_with_a_third_value_is_refused_not_dropped() {
        let bad = GOOD.replace("origin_mm = [1.0, 2.0]", "origin_mm = [1.0, 2.0, 3.0]");
        let e = Board::from_doc(&doc(&bad)).unwrap_err().to_string();
        assert!(
            e.contains("b.toml:7") && e.contains("board.origin_mm") && e.contains("two numbers"),
            "{e}"
        );
    }

    #[test]
    fn loads_nominal_board() {
        let b = Board::from_doc(&doc(GOOD)).unwrap();
        assert_eq!(b.true_xy(2, 3), Some([2.0, 3.5]));
        assert_eq!(b.true_xy(10, 0), None);
        assert_eq!(b.true_xy(-1, 0), None);
        assert_eq!(b.extent().1, [5.5, 5.5]);
    }

    #[test]
    fn rejects_bad_geometry_with_key_and_line() {
        let bad = GOOD.replace("dot_diameter_mm = 0.25", "dot_diameter_mm = 0.6");
        let e = Board::from_doc(&doc(&bad)).unwrap_err().to_string();
        assert!(
            e.starts_with("b.toml:3: key `board.dot_diameter_mm`"),
            "{e}"
        );
        let bad = GOOD.replace("\"dark-on-light\"", "\"plaid\"");
        let e = Board::from_doc(&doc(&bad)).unwrap_err().to_string();
        assert!(e.contains("b.toml:4") && e.contains("polarity"), "{e}");
    }

    #[test]
    fn certificate_overrides_listed_points_and_rejects_nonsense() {
        let mut b = Board::from_doc(&doc(GOOD)).unwrap();
        b.apply_certificate("c.csv", "i,j,x_mm,y_mm\n2,3,2.0004,3.4998\n")
            .unwrap();
        assert_eq!(b.true_xy(2, 3), Some([2.0004, 3.4998]));
        assert_eq!(b.true_xy(3, 3), Some([2.5, 3.5]));
        assert_eq!(b.certified_points, 1);
        let e = b
            .apply_certificate("c.csv", "i,j,x_mm,y_mm\n2,3,7.0,3.5\n")
            .unwrap_err();
        assert!(e.to_string().starts_with("c.csv:2:"), "{e}");
        let e = b
            .apply_certificate("c.csv", "1,1,1.5,2.5\n1,1,1.5,2.5\n")
            .unwrap_err();
        assert!(e.to_string().contains("listed twice"), "{e}");
        let e = b.apply_certificate("c.csv", "1,x,1.5,2.5\n").unwrap_err();
        assert!(e.to_string().contains("column j"), "{e}");
    }

    #[test]
    fn certificate_round_trips() {
        let mut b = Board::from_doc(&doc(GOOD)).unwrap();
        b.set_true_xy(4, 5, [3.0003, 4.4999]);
        let csv = b.certificate_csv();
        let mut c = Board::from_doc(&doc(GOOD)).unwrap();
        c.apply_certificate("x", &csv).unwrap();
        assert_eq!(b.true_xy(4, 5), c.true_xy(4, 5));
    }
    #[test]
    fn an_empty_certificate_is_refused() {
        let mut b = Board::from_doc(&doc(GOOD)).unwrap();
        for text in ["", "\n\n", "i,j,x_mm,y_mm\n", "# only a comment\n"] {
            let e = b.apply_certificate("c.csv", text).unwrap_err().to_string();
            assert!(
                e.starts_with("c.csv") && e.contains("no points"),
                "{text:?}: {e}"
            );
        }
    }

    #[test]
    fn a_certificate_with_a_byte_order_mark_is_read() {
        let mut b = Board::from_doc(&doc(GOOD)).unwrap();
        b.apply_certificate("c.csv", "\u{FEFF}i,j,x_mm,y_mm\n2,3,2.0004,3.4998\n")
            .unwrap();
        assert_eq!(b.true_xy(2, 3), Some([2.0004, 3.4998]));
    }

    #[test]
    fn invisible_characters_in_a_certificate_are_shown_escaped() {
        let mut b = Board::from_doc(&doc(GOOD)).unwrap();
        let e = b
            .apply_certificate("c.csv", "i,j,x_mm,y_mm\n2\u{200B},3,2.0,3.5\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("`2\\u{200B}`"), "{e}");
        let e = b
            .apply_certificate("c.csv", "i,j,x_mm,y_mm\n2,3,2.0\u{7},3.5\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("`2.0\\x07`"), "{e}");
    }
}

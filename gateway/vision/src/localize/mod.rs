//! Board localization: from one camera frame of the certified dot board, the board
//! coordinate under the image centre (= where the tool really is).
//!
//! Pipeline ([`localize`]):
//! 1. [`detect_dots`]: sub-pixel centres of every complete dot (`detect`).
//! 2. Identification (`identify`): lattice basis, integer indices, mapping of lattice
//!    axes to board axes through the nominal [`PixelAxes`], and the integer offset on the
//!    board chosen so the implied position lands nearest the hint. Refused when that is
//!    not unambiguous. On a coded board (`code`) the offset and the orientation are read
//!    from the dots' sizes instead, with no hint: a hint, when given, is only checked
//!    against the absolute result, and an orientation other than the nominal pixel axes
//!    is refused naming the one the code shows.
//! 3. [`Method::Fit`]: homography + radial distortion fitted to the certified
//!    coordinates of all identified dots, evaluated at the image centre (`fit`).
//!    [`Method::FourPoint`]: the patent's formula on the cell around the centre
//!    (`four_point`), kept exactly as written for comparison.
//! 4. Every doubtful case is refused with a [`LocalizeError`] that says what was wrong,
//!    with the numbers: a wrong position is worse than none, since the controller would
//!    move the tool by it.
//!
//! Nothing here knows how the frame was made: the simulated camera and renderer are used
//! only by the tests and the benchmark.

pub mod code;
pub mod detect;
mod fit;
mod four_point;
mod identify;

pub use detect::{detect_dots, Dot};

use protocol::{Board, MonoImage};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// How the image-centre coordinate is computed from the identified points.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// The patent's four-point interpolation on the cell around the centre (claims 3-5).
    FourPoint,
    /// Homography + radial distortion fitted to every identified point (default).
    #[default]
    Fit,
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Method::FourPoint => "four-point",
            Method::Fit => "fit",
        })
    }
}

impl FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().as_str() {
            "four-point" | "fourpoint" | "4-point" => Ok(Method::FourPoint),
            "fit" => Ok(Method::Fit),
            other => Err(format!(
                "unknown localization method `{other}`: expected `fit` or `four-point`"
            )),
        }
    }
}

/// A signed board axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BoardAxis {
    PlusX,
    MinusX,
    PlusY,
    MinusY,
}

impl BoardAxis {
    /// Unit vector on the board.
    pub fn unit(self) -> [i64; 2] {
        match self {
            BoardAxis::PlusX => [1, 0],
            BoardAxis::MinusX => [-1, 0],
            BoardAxis::PlusY => [0, 1],
            BoardAxis::MinusY => [0, -1],
        }
    }

    fn is_x(self) -> bool {
        matches!(self, BoardAxis::PlusX | BoardAxis::MinusX)
    }

    fn as_str(self) -> &'static str {
        match self {
            BoardAxis::PlusX => "+x",
            BoardAxis::MinusX => "-x",
            BoardAxis::PlusY => "+y",
            BoardAxis::MinusY => "-y",
        }
    }

    fn parse(s: &str) -> Option<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "+x" | "x" => Some(BoardAxis::PlusX),
            "-x" => Some(BoardAxis::MinusX),
            "+y" | "y" => Some(BoardAxis::PlusY),
            "-y" => Some(BoardAxis::MinusY),
            _ => None,
        }
    }
}

/// Nominal orientation of the camera: which board direction the image +x and +y axes
/// point along. Written `"+x,-y"` (image +x along board +x, image rows going towards
/// board -y: a camera above the board; the default), `"+x,+y"` (mirrored: a camera
/// looking up at the board from below), `"+y,+x"`, `"-x,-y"`, ...
///
/// Needed because a square grid looks the same turned by 90° or mirrored: the image
/// alone cannot tell which way the board runs. The real mount may differ from nominal
/// by a few degrees (measured, and accepted up to ±10°).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct PixelAxes {
    image_x: BoardAxis,
    image_y: BoardAxis,
}

impl PixelAxes {
    /// Err unless the two axes are perpendicular (one along x, one along y).
    pub fn new(image_x: BoardAxis, image_y: BoardAxis) -> Result<Self, String> {
        if image_x.is_x() == image_y.is_x() {
            return Err(format!(
                "pixel axes `{},{}` are not perpendicular: image x and y must point along different board axes",
                image_x.as_str(),
                image_y.as_str()
            ));
        }
        Ok(Self { image_x, image_y })
    }

    /// Board direction of image +x.
    pub fn image_x(&self) -> BoardAxis {
        self.image_x
    }

    /// Board direction of image +y.
    pub fn image_y(&self) -> BoardAxis {
        self.image_y
    }

    /// A pixel vector expressed in board-aligned pixel axes (component 0 along board
    /// +x, component 1 along board +y), by the nominal orientation only.
    pub fn to_board_aligned(&self, p: [f64; 2]) -> [f64; 2] {
        let (ex, ey) = (self.image_x.unit(), self.image_y.unit());
        [
            p[0] * ex[0] as f64 + p[1] * ey[0] as f64,
            p[0] * ex[1] as f64 + p[1] * ey[1] as f64,
        ]
    }
}

impl Default for PixelAxes {
    fn default() -> Self {
        Self {
            image_x: BoardAxis::PlusX,
            image_y: BoardAxis::MinusY,
        }
    }
}

impl fmt::Display for PixelAxes {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{},{}", self.image_x.as_str(), self.image_y.as_str())
    }
}

impl FromStr for PixelAxes {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad =
            || format!("pixel axes `{s}`: expected two signed board axes like `+x,-y` or `+y,+x`");
        let mut it = s.split(',');
        let (Some(a), Some(b), None) = (it.next(), it.next(), it.next()) else {
            return Err(bad());
        };
        let (Some(a), Some(b)) = (BoardAxis::parse(a), BoardAxis::parse(b)) else {
            return Err(bad());
        };
        PixelAxes::new(a, b)
    }
}

impl Serialize for PixelAxes {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

impl<'de> Deserialize<'de> for PixelAxes {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        s.parse().map_err(serde::de::Error::custom)
    }
}

/// Largest accepted rotation of the camera from its nominal orientation: beyond about
/// 45° a square grid cannot be told from one turned by 90°, and real mounts are square
/// to within a degree or two.
pub const MAX_ROTATION_DEG: f64 = 10.0;

/// Largest accepted relative difference between the measured and nominal scale.
pub const MAX_SCALE_DEVIATION: f64 = 0.10;

/// Accepted range of measured dot diameter / board dot diameter (printing and blur do
/// not change a dot's area much; a ratio outside this is the wrong board file).
pub const DOT_SIZE_RATIO: (f64, f64) = (0.7, 1.4);

/// What the localizer needs besides the frame and the board.
#[derive(Clone, Debug, PartialEq)]
pub struct LocalizeParams {
    pub method: Method,
    pub pixel_axes: PixelAxes,
    /// Nominal scale (micrometres on the board per pixel) if known; the measured scale
    /// must agree within 10 %, else the frame is refused.
    pub um_per_px: Option<f64>,
    /// Expected board coordinate at the image centre (from the commanded target), mm.
    /// Required on a plain dot grid (it picks the grid offset); optional on a coded
    /// board, where it is only checked against the decoded position.
    pub hint_mm: Option<[f64; 2]>,
    /// How far the true position may be from the hint, mm. On a plain grid it must be
    /// under half the pitch (otherwise two grid offsets fit and the answer is ambiguous
    /// by construction); on a coded board any positive distance.
    pub hint_tolerance_mm: f64,
    /// Refuse when the fit's RMS residual exceeds this, micrometres.
    pub max_residual_um: f64,
    /// Fewest identified on-board points accepted (at least 4).
    pub min_points: usize,
}

/// The tunable part of [`LocalizeParams`], as a job's `[localize]` section gives it.
/// These defaults are the only ones: the job file, the CLI and [`LocalizeParams::new`]
/// all take them from here.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LocalizeSettings {
    pub method: Method,
    /// See [`LocalizeParams::hint_tolerance_mm`].
    pub hint_tolerance_mm: f64,
    /// See [`LocalizeParams::max_residual_um`].
    pub max_residual_um: f64,
    /// See [`LocalizeParams::min_points`].
    pub min_points: usize,
}

impl Default for LocalizeSettings {
    /// Fit method, 0.1 mm hint tolerance, 2 um residual limit, 8 points.
    fn default() -> Self {
        Self {
            method: Method::Fit,
            hint_tolerance_mm: 0.1,
            max_residual_um: 2.0,
            min_points: 8,
        }
    }
}

impl LocalizeParams {
    /// Defaults ([`LocalizeSettings::default`]), camera above the board (`+x,-y`),
    /// scale unknown.
    pub fn new(hint_mm: [f64; 2]) -> Self {
        Self::with_settings(hint_mm, &LocalizeSettings::default())
    }

    /// The given settings, camera above the board (`+x,-y`), scale unknown.
    pub fn with_settings(hint_mm: [f64; 2], settings: &LocalizeSettings) -> Self {
        Self {
            method: settings.method,
            pixel_axes: PixelAxes::default(),
            um_per_px: None,
            hint_mm: Some(hint_mm),
            hint_tolerance_mm: settings.hint_tolerance_mm,
            max_residual_um: settings.max_residual_um,
            min_points: settings.min_points,
        }
    }
}

/// A localization result.
#[derive(Clone, Debug, Serialize)]
pub struct Observation {
    /// Board coordinate at the image centre, mm.
    pub x_mm: f64,
    pub y_mm: f64,
    pub method: Method,
    /// Points used (fit inliers; 4 for the four-point method).
    pub points: usize,
    /// RMS residual of the fit over its inliers, um (data quality, for both methods).
    pub residual_rms_um: f64,
    /// Measured scale at the image centre, um per pixel.
    pub um_per_px: f64,
    /// Measured rotation of the image +x axis from its nominal board direction,
    /// degrees, counter-clockwise on the board.
    pub rotation_deg: f64,
    /// Identified points the robust fit rejected as outliers.
    pub rejected: usize,
    /// On a coded board: how the code was read (None on a plain grid).
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub code: Option<CodeRead>,
}

/// How a coded board's code was read in one frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CodeRead {
    /// Dots whose size was read (bits compared with the board).
    pub bits: usize,
    /// Of those, dots that disagree with the board at the decoded position (misread,
    /// dirty or damaged dots, outvoted).
    pub errors: usize,
    /// Disagreeing dots at the second-best board position or orientation (the margin
    /// is `second - errors`; capped at the search cut-off).
    pub second: usize,
    /// Board index of the dot nearest the image centre.
    pub i: i64,
    pub j: i64,
}

/// Why a frame was refused. Every message says what was wrong, with the numbers.
#[derive(Debug, thiserror::Error)]
pub enum LocalizeError {
    #[error("no calibration board in the image: {reason}")]
    NoBoard { reason: String },
    #[error("only {found} calibration points usable, at least {need} needed ({off_board} more fell off the board, {rejected} were rejected as outliers by the fit)")]
    TooFewPoints {
        found: usize,
        need: usize,
        off_board: usize,
        rejected: usize,
    },
    #[error("cannot tell which board points are in view (hint ({:.4}, {:.4}) mm, tolerance {tolerance_mm} mm): {detail}", hint_mm[0], hint_mm[1])]
    Ambiguous {
        hint_mm: [f64; 2],
        tolerance_mm: f64,
        detail: String,
    },
    #[error("the view is off the board: all {points} identified points have indices outside the board's {cols} x {rows} points (they span i {i_min}..{i_max}, j {j_min}..{j_max})")]
    OffBoard {
        points: usize,
        cols: u32,
        rows: u32,
        i_min: i64,
        i_max: i64,
        j_min: i64,
        j_max: i64,
    },
    #[error("fit residual {rms_um:.3} um RMS over {points} points exceeds the limit of {limit_um} um (dirty board, wrong certificate or a bad frame)")]
    ResidualTooLarge {
        rms_um: f64,
        limit_um: f64,
        points: usize,
    },
    #[error("measured scale {measured_um_per_px:.4} um/px differs from the nominal {nominal_um_per_px} um/px by {:.1} % (more than {:.0} %): wrong lens, camera or board", 100.0 * (measured_um_per_px / nominal_um_per_px - 1.0), 100.0 * MAX_SCALE_DEVIATION)]
    ScaleMismatch {
        measured_um_per_px: f64,
        nominal_um_per_px: f64,
    },
    #[error("measured dot diameter {measured_mm:.4} mm does not match the board's {board_mm} mm (ratio {:.2}, accepted {:.1}..{:.1}): wrong board file?", measured_mm / board_mm, DOT_SIZE_RATIO.0, DOT_SIZE_RATIO.1)]
    DotSizeMismatch { measured_mm: f64, board_mm: f64 },
    #[error("camera is rotated {measured_deg:.2} degrees from its nominal pixel axes (limit ±{limit_deg}): check the pixel_axes setting")]
    RotationOutOfRange { measured_deg: f64, limit_deg: f64 },
    #[error("four-point method: the cell around the image centre (board points i {i}..{}, j {j}..{}) is not fully identified: {missing}", i + 1, j + 1)]
    CellIncomplete { i: i64, j: i64, missing: String },
    #[error("the identified points do not determine a position: {0}")]
    Degenerate(String),
    #[error("bad localization parameters: {0}")]
    BadParams(String),
    #[error("the board's code cannot be read: {detail}")]
    CodeUnreadable { detail: String },
    #[error("the board's code shows the camera's pixel axes as `{decoded}`, not the configured `{configured}`: the camera is turned or mirrored (fix pixel_axes)")]
    OrientationMismatch {
        configured: PixelAxes,
        decoded: PixelAxes,
    },
    #[error("the board's code puts the image centre at ({:.4}, {:.4}) mm, {distance_mm:.4} mm from the hint ({:.4}, {:.4}) mm (tolerance {tolerance_mm} mm)", found_mm[0], found_mm[1], hint_mm[0], hint_mm[1])]
    HintMismatch {
        found_mm: [f64; 2],
        hint_mm: [f64; 2],
        distance_mm: f64,
        tolerance_mm: f64,
    },
}

fn check_params(board: &Board, p: &LocalizeParams) -> Result<(), LocalizeError> {
    let bad = |m: String| Err(LocalizeError::BadParams(m));
    if p.min_points < 4 {
        return bad(format!(
            "min_points is {}, at least 4 are needed",
            p.min_points
        ));
    }
    if let Some(h) = p.hint_mm {
        if !(h[0].is_finite() && h[1].is_finite()) {
            return bad(format!(
                "hint ({}, {}) mm is not a finite position",
                h[0], h[1]
            ));
        }
    }
    if !(p.hint_tolerance_mm.is_finite() && p.hint_tolerance_mm > 0.0) {
        return bad(format!(
            "hint tolerance {} mm must be a positive number",
            p.hint_tolerance_mm
        ));
    }
    if !(p.max_residual_um.is_finite() && p.max_residual_um > 0.0) {
        return bad(format!(
            "residual limit {} um must be a positive number",
            p.max_residual_um
        ));
    }
    if let Some(u) = p.um_per_px {
        if !(u.is_finite() && u > 0.0) {
            return bad(format!("nominal scale {u} um/px must be a positive number"));
        }
    }
    if !(board.pitch_mm.is_finite() && board.pitch_mm > 0.0) {
        return bad(format!(
            "board pitch {} mm must be positive",
            board.pitch_mm
        ));
    }
    if board.code.is_some() {
        return Ok(());
    }
    let Some(hint_mm) = p.hint_mm else {
        return bad(format!(
            "a plain dot grid (`{}`) gives the position only modulo its {} mm pitch: a hint (the expected position) is needed",
            board.name, board.pitch_mm
        ));
    };
    if p.hint_tolerance_mm >= 0.5 * board.pitch_mm {
        return Err(LocalizeError::Ambiguous {
            hint_mm,
            tolerance_mm: p.hint_tolerance_mm,
            detail: format!(
                "a tolerance of at least half the pitch ({} mm) admits two grid offsets, so any view is ambiguous by construction; give a hint within less than {} mm",
                0.5 * board.pitch_mm,
                0.5 * board.pitch_mm
            ),
        });
    }
    Ok(())
}

/// The board coordinate under the image centre, or a refusal.
pub fn localize(
    img: &MonoImage,
    board: &Board,
    p: &LocalizeParams,
) -> Result<Observation, LocalizeError> {
    check_params(board, p)?;
    let centre = img.centre();
    let dot_px = p.um_per_px.map(|u| board.dot_diameter_mm * 1000.0 / u);
    let dots = match &board.code {
        Some(c) => {
            let r = c.dot_diameters_mm[1] / c.dot_diameters_mm[0];
            detect::detect_dots_two_sizes(img, board.polarity, dot_px, r * r)
        }
        None => detect::detect_dots_sized(img, board.polarity, dot_px),
    };
    if dots.is_empty() {
        return Err(LocalizeError::NoBoard {
            reason: format!(
                "no {} dots found in the {}x{} frame",
                match board.polarity {
                    protocol::Polarity::DarkOnLight => "dark",
                    protocol::Polarity::BrightOnDark => "bright",
                },
                img.width,
                img.height
            ),
        });
    }
    if dots.len() < p.min_points {
        return Err(LocalizeError::TooFewPoints {
            found: dots.len(),
            need: p.min_points,
            off_board: 0,
            rejected: 0,
        });
    }

    // Lattice and scale.
    let pts: Vec<[f64; 2]> = dots.iter().map(|d| [d.x, d.y]).collect();
    let mut areas: Vec<f64> = dots.iter().map(|d| d.area_px).collect();
    let area = detect::median(&mut areas).unwrap_or(1.0);
    let d_px = 2.0 * (area / std::f64::consts::PI).sqrt();
    let nb = identify::neighbours(&pts, 2.0 * d_px);
    let lat = identify::estimate_lattice(&pts, &nb)
        .map_err(|reason| LocalizeError::NoBoard { reason })?;
    let spacing = 0.5 * (lat.u[0].hypot(lat.u[1]) + lat.v[0].hypot(lat.v[1]));
    let um_lattice = board.pitch_mm * 1000.0 / spacing;
    if let Some(nominal) = p.um_per_px {
        if (um_lattice / nominal - 1.0).abs() > MAX_SCALE_DEVIATION {
            return Err(LocalizeError::ScaleMismatch {
                measured_um_per_px: um_lattice,
                nominal_um_per_px: nominal,
            });
        }
    }
    let dot_mm = d_px * um_lattice / 1000.0;
    let ratio = dot_mm / board.dot_diameter_mm;
    if !(DOT_SIZE_RATIO.0..=DOT_SIZE_RATIO.1).contains(&ratio) {
        return Err(LocalizeError::DotSizeMismatch {
            measured_mm: dot_mm,
            board_mm: board.dot_diameter_mm,
        });
    }
    // Lattice angle (image coordinates, y down) as a rotation on the board, the same
    // convention as `Observation::rotation_deg`: the sign flips with the handedness of
    // the pixel axes.
    let (ex, ey) = (p.pixel_axes.image_x.unit(), p.pixel_axes.image_y.unit());
    let handed = -(ex[0] * ey[1] - ex[1] * ey[0]) as f64;
    let rot = handed * lat.theta.to_degrees();
    if rot.abs() > MAX_ROTATION_DEG {
        return Err(LocalizeError::RotationOutOfRange {
            measured_deg: rot,
            limit_deg: MAX_ROTATION_DEG,
        });
    }

    // Lattice indices, then board indices.
    let (idx, aff) = identify::index_dots(&pts, &nb, &lat, centre).ok_or_else(|| {
        LocalizeError::Degenerate(format!(
            "the {} dots could not be indexed on one grid",
            pts.len()
        ))
    })?;
    let identified = idx.iter().filter(|i| i.is_some()).count();
    if identified < p.min_points {
        return Err(LocalizeError::TooFewPoints {
            found: identified,
            need: p.min_points,
            off_board: 0,
            rejected: 0,
        });
    }
    let ac = aff
        .inverse(centre)
        .ok_or_else(|| LocalizeError::Degenerate("the dot grid has no extent".to_string()))?;
    // Board index offset of the image centre from the reference dot, in pitches.
    let off = [
        ac[0] * ex[0] as f64 + ac[1] * ey[0] as f64,
        ac[0] * ex[1] as f64 + ac[1] * ey[1] as f64,
    ];
    let (ij0, code_read) = match &board.code {
        None => (choose_offset(board, p, off)?, None),
        Some(c) => {
            let mm_per_px = um_lattice / 1000.0;
            let diam: Vec<Option<f64>> = dots
                .iter()
                .zip(&idx)
                .map(|(d, ab)| {
                    ab.map(|_| 2.0 * (d.area_px / std::f64::consts::PI).sqrt() * mm_per_px)
                })
                .collect();
            let bits = code::classify(&diam, c.dot_diameters_mm);
            let obs: Vec<([i64; 2], bool)> = idx
                .iter()
                .zip(&bits)
                .filter_map(|(ab, b)| Some(((*ab)?, (*b)?)))
                .collect();
            let d = code::decode(c, &obs).map_err(|e| LocalizeError::CodeUnreadable {
                detail: match e {
                    code::DecodeError::TooFewBits { bits } => format!(
                        "only {bits} dot sizes read, at least {} needed",
                        code::MIN_BITS
                    ),
                    code::DecodeError::NoMatch { bits, best, limit } => format!(
                        "no board position matches the {bits} dot sizes read: the best disagrees in {best} dots, at most {limit} accepted (dirty or damaged board, or another board's code)"
                    ),
                    code::DecodeError::NotAlone {
                        bits,
                        best,
                        second,
                    } => format!(
                        "two board positions match the {bits} dot sizes read almost equally ({best} and {second} dots disagree, a margin of {} needed)",
                        code::MIN_MARGIN
                    ),
                },
            })?;
            if d.axes != [ex, ey] {
                let axis = |u: [i64; 2]| match u {
                    [1, 0] => BoardAxis::PlusX,
                    [-1, 0] => BoardAxis::MinusX,
                    [0, 1] => BoardAxis::PlusY,
                    _ => BoardAxis::MinusY,
                };
                return Err(LocalizeError::OrientationMismatch {
                    configured: p.pixel_axes,
                    decoded: PixelAxes {
                        image_x: axis(d.axes[0]),
                        image_y: axis(d.axes[1]),
                    },
                });
            }
            let read = CodeRead {
                bits: d.bits,
                errors: d.errors,
                second: d.second,
                i: d.ij0[0],
                j: d.ij0[1],
            };
            (d.ij0, Some(read))
        }
    };
    let board_ij = |ab: [i64; 2]| -> [i64; 2] {
        [
            ij0[0] + ab[0] * ex[0] + ab[1] * ey[0],
            ij0[1] + ab[0] * ex[1] + ab[1] * ey[1],
        ]
    };

    let mut corr = Vec::new();
    let mut corr_ij = Vec::new();
    let mut off_board = 0;
    let (mut i_min, mut i_max, mut j_min, mut j_max) = (i64::MAX, i64::MIN, i64::MAX, i64::MIN);
    for (d, ab) in pts.iter().zip(&idx) {
        let Some(ab) = ab else { continue };
        let ij = board_ij(*ab);
        (i_min, i_max, j_min, j_max) = (
            i_min.min(ij[0]),
            i_max.max(ij[0]),
            j_min.min(ij[1]),
            j_max.max(ij[1]),
        );
        match board.true_xy(ij[0], ij[1]) {
            Some(mm) => {
                corr.push(fit::Corr { px: *d, mm });
                corr_ij.push(ij);
            }
            None => off_board += 1,
        }
    }
    if corr.is_empty() {
        return Err(LocalizeError::OffBoard {
            points: off_board,
            cols: board.cols,
            rows: board.rows,
            i_min,
            i_max,
            j_min,
            j_max,
        });
    }
    if corr.len() < p.min_points {
        return Err(LocalizeError::TooFewPoints {
            found: corr.len(),
            need: p.min_points,
            off_board,
            rejected: 0,
        });
    }

    let f = fit::fit(&corr, centre).ok_or_else(|| {
        LocalizeError::Degenerate(format!(
            "the model could not be fitted to the {} points (collinear?)",
            corr.len()
        ))
    })?;
    if f.n_inliers < p.min_points {
        return Err(LocalizeError::TooFewPoints {
            found: f.n_inliers,
            need: p.min_points,
            off_board,
            rejected: corr.len() - f.n_inliers,
        });
    }
    let rms_um = f.rms_mm * 1000.0;
    if rms_um > p.max_residual_um {
        return Err(LocalizeError::ResidualTooLarge {
            rms_um,
            limit_um: p.max_residual_um,
            points: f.n_inliers,
        });
    }
    let jac = f.model.jacobian(centre);
    let um_per_px = (jac[0][0] * jac[1][1] - jac[0][1] * jac[1][0]).abs().sqrt() * 1000.0;
    if let Some(nominal) = p.um_per_px {
        if (um_per_px / nominal - 1.0).abs() > MAX_SCALE_DEVIATION {
            return Err(LocalizeError::ScaleMismatch {
                measured_um_per_px: um_per_px,
                nominal_um_per_px: nominal,
            });
        }
    }
    // Rotation: board direction of image +x against its nominal direction.
    let dir = jac[0];
    let nom = [ex[0] as f64, ex[1] as f64];
    let rotation_deg = (nom[0] * dir[1] - nom[1] * dir[0])
        .atan2(nom[0] * dir[0] + nom[1] * dir[1])
        .to_degrees();
    let rejected = corr.len() - f.n_inliers;
    let fit_xy = f.model.map(centre);

    let (xy, points) = match p.method {
        Method::Fit => (fit_xy, f.n_inliers),
        Method::FourPoint => {
            let xy = four_point_at(board, p, centre, fit_xy, &corr, &corr_ij, &f.inlier)?;
            (xy, 4)
        }
    };
    if let (Some(_), Some(hint_mm)) = (&code_read, p.hint_mm) {
        let distance_mm = (xy[0] - hint_mm[0]).hypot(xy[1] - hint_mm[1]);
        if !(distance_mm <= p.hint_tolerance_mm) {
            return Err(LocalizeError::HintMismatch {
                found_mm: xy,
                hint_mm,
                distance_mm,
                tolerance_mm: p.hint_tolerance_mm,
            });
        }
    }
    Ok(Observation {
        x_mm: xy[0],
        y_mm: xy[1],
        method: p.method,
        points,
        residual_rms_um: rms_um,
        um_per_px,
        rotation_deg,
        rejected,
        code: code_read,
    })
}

/// Integer board index of the reference dot (lattice index (0, 0)) such that the image
/// centre, `off` pitches from it along board x and y, lands nearest the hint; refused
/// when the nearest choice is beyond the tolerance or a second one is within it.
fn choose_offset(
    board: &Board,
    p: &LocalizeParams,
    off: [f64; 2],
) -> Result<[i64; 2], LocalizeError> {
    let pitch = board.pitch_mm;
    let hint_mm = p
        .hint_mm
        .ok_or_else(|| LocalizeError::BadParams("a plain dot grid needs a hint".to_string()))?;
    // Real-valued index of the hint minus the centre's offset from the reference dot.
    let want = [
        (hint_mm[0] - board.origin_mm[0]) / pitch - off[0],
        (hint_mm[1] - board.origin_mm[1]) / pitch - off[1],
    ];
    if !(want[0].abs() < 1e12 && want[1].abs() < 1e12) {
        return Err(LocalizeError::BadParams(format!(
            "hint ({}, {}) mm is absurdly far from the board",
            hint_mm[0], hint_mm[1]
        )));
    }
    let implied = |ij: [i64; 2]| -> [f64; 2] {
        [
            board.origin_mm[0] + (ij[0] as f64 + off[0]) * pitch,
            board.origin_mm[1] + (ij[1] as f64 + off[1]) * pitch,
        ]
    };
    let dist = |ij: [i64; 2]| {
        let q = implied(ij);
        (q[0] - hint_mm[0]).hypot(q[1] - hint_mm[1])
    };
    let best = [want[0].round() as i64, want[1].round() as i64];
    let d1 = dist(best);
    if d1 > p.hint_tolerance_mm {
        let q = implied(best);
        return Err(LocalizeError::Ambiguous {
            hint_mm,
            tolerance_mm: p.hint_tolerance_mm,
            detail: format!(
                "the nearest grid-consistent position ({:.4}, {:.4}) mm is {:.4} mm from the hint, beyond the tolerance: the stage is further off than expected",
                q[0], q[1], d1
            ),
        });
    }
    for di in -1..=1 {
        for dj in -1..=1 {
            if (di, dj) == (0, 0) {
                continue;
            }
            let other = [best[0] + di, best[1] + dj];
            let d2 = dist(other);
            if d2 <= p.hint_tolerance_mm {
                let q = implied(other);
                return Err(LocalizeError::Ambiguous {
                    hint_mm,
                    tolerance_mm: p.hint_tolerance_mm,
                    detail: format!(
                        "two grid offsets fit: positions {:.4} mm and {:.4} mm from the hint (second at ({:.4}, {:.4}) mm)",
                        d1, d2, q[0], q[1]
                    ),
                });
            }
        }
    }
    Ok(best)
}

/// The four-point result: the cell containing the image centre (located with the fit)
/// and the patent's formula on its 4 corners.
fn four_point_at(
    board: &Board,
    p: &LocalizeParams,
    centre: [f64; 2],
    fit_xy: [f64; 2],
    corr: &[fit::Corr],
    corr_ij: &[[i64; 2]],
    inlier: &[bool],
) -> Result<[f64; 2], LocalizeError> {
    let i = ((fit_xy[0] - board.origin_mm[0]) / board.pitch_mm).floor() as i64;
    let j = ((fit_xy[1] - board.origin_mm[1]) / board.pitch_mm).floor() as i64;
    let want = [[i, j], [i + 1, j + 1], [i + 1, j], [i, j + 1]];
    let mut corners = Vec::with_capacity(4);
    let mut missing = Vec::new();
    for ij in want {
        match corr_ij.iter().position(|&c| c == ij) {
            Some(k) if inlier[k] => corners.push(four_point::Corner {
                px: p.pixel_axes.to_board_aligned(corr[k].px),
                mm: corr[k].mm,
            }),
            Some(_) => missing.push(format!(
                "({},{}) rejected as an outlier by the fit",
                ij[0], ij[1]
            )),
            None => missing.push(format!("({},{}) not identified", ij[0], ij[1])),
        }
    }
    let corners: [four_point::Corner; 4] = match corners.try_into() {
        Ok(c) => c,
        Err(_) => {
            return Err(LocalizeError::CellIncomplete {
                i,
                j,
                missing: missing.join(", "),
            })
        }
    };
    four_point::four_point(&corners, p.pixel_axes.to_board_aligned(centre)).ok_or_else(|| {
        LocalizeError::Degenerate(format!(
            "the cell at ({i},{j}) has a diagonal with no extent"
        ))
    })
}

#[cfg(test)]
mod testkit;
#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_coded;

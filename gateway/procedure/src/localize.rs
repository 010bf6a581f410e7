//! One frame of the board localized: the board coordinate under the image centre. The
//! frame is the request's (a PNG file, base64); the board is the context's (the CLI's
//! `--board` file, the service's machine's board); the request also carries the hint
//! and the localizer's settings, each bounded and named. On a
//! coded board (issue 28) the hint is optional and only checked against the position
//! the board's code gives; a plain dot grid needs it.

use crate::command_line::{self, FileArg};
use crate::request::{count, number, RequestError};
use crate::Outcome;
use protocol::{Board, MonoImage};
use serde::{Deserialize, Serialize};
use std::time::Instant;
use vision::localize::{localize, CodeRead, LocalizeParams, LocalizeSettings, Method, PixelAxes};

/// A frame localized: the board coordinate under the image centre and how it was found.
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
pub struct LocalizeResult {
    /// The board coordinate at the image centre, mm.
    pub x_mm: f64,
    pub y_mm: f64,
    /// Identified on-board points used.
    pub points: usize,
    /// The localization method.
    #[schema(value_type = crate::request::MethodName, inline)]
    pub method: Method,
    /// How long the localization took, ms.
    pub elapsed_ms: f64,
    /// The fit's RMS residual, um.
    pub residual_rms_um: f64,
    /// The measured scale, um per pixel.
    pub um_per_px: f64,
    /// The board's rotation in the image, degrees.
    pub rotation_deg: f64,
    /// The frame.
    #[schema(inline)]
    pub image: FrameInfo,
    /// How a coded board's code was read (`bits`, `errors`, `second`, `i`, `j`); absent
    /// on a plain dot grid.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    #[schema(value_type = Option<Object>)]
    pub code: Option<CodeRead>,
}

/// The frame a localization read.
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
pub struct FrameInfo {
    /// Pixels.
    pub width: u32,
    pub height: u32,
    /// 8 or 16.
    pub bit_depth: u8,
    /// How the request named it (its file name); absent from [`run`]'s own result.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub name: Option<String>,
}

/// The largest board coordinate accepted as a hint, mm.
pub const MAX_COORDINATE_MM: f64 = 1e5;
/// The nominal scale's range, um per pixel (a microscope's tenth of a micrometre to a
/// wide lens's centimetre).
pub const UM_PER_PX: (f64, f64) = (1e-3, 1e4);
/// The hint tolerance's range, mm (the board further caps it below half its pitch).
pub const HINT_TOLERANCE_MM: (f64, f64) = (1e-4, 50.0);
/// The most identified points a request may ask for.
pub const MAX_MIN_POINTS: u64 = 1_000_000;

fn default_hint_tolerance() -> f64 {
    LocalizeSettings::default().hint_tolerance_mm
}
fn default_max_residual() -> f64 {
    LocalizeSettings::default().max_residual_um
}
fn default_min_points() -> u64 {
    LocalizeSettings::default().min_points as u64
}

/// The largest frame accepted in a request: a PNG file of 48 MiB (64 MiB of base64).
pub const MAX_IMAGE_BASE64: usize = 64 << 20;

fn default_image_name() -> String {
    "frame.png".into()
}

/// A localization of one frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields)]
pub struct LocalizeRequest {
    /// The frame: a PNG file, 8- or 16-bit greyscale (base64).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(skip))]
    #[schema(format = Byte, max_length = 67108864)]
    pub image: String,
    /// How messages name the frame (its file name).
    #[serde(default = "default_image_name")]
    #[cfg_attr(feature = "cli", arg(skip = default_image_name()))]
    #[schema(default = default_image_name)]
    pub image_name: String,
    /// The expected board coordinate at the image centre, `X,Y` mm: required on a plain
    /// dot grid (it picks the grid offset), only checked on a coded board.
    #[serde(default)]
    #[cfg_attr(
        feature = "cli",
        arg(long, allow_hyphen_values = true, value_parser = crate::request::xy_mm)
    )]
    #[schema(value_type = Option<Vec<f64>>, min_items = 2, max_items = 2)]
    pub near: Option<[f64; 2]>,
    /// Localization method: fit or four-point (the patent's formula).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, default_value = "fit"))]
    #[schema(value_type = crate::request::MethodName, inline)]
    pub method: Method,
    /// The nominal scale; the measured scale must agree within 10 %.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long))]
    #[schema(minimum = 0.001, maximum = 10000.0)]
    pub um_per_px: Option<f64>,
    /// The board directions of the image +x and +y axes (`+x,-y`: a camera above).
    #[serde(default)]
    #[cfg_attr(
        feature = "cli",
        arg(long, default_value = "+x,-y", allow_hyphen_values = true)
    )]
    #[schema(value_type = String, default = "+x,-y")]
    pub pixel_axes: PixelAxes,
    /// How far the true position may be from `near`, mm (below half the pitch on a plain
    /// grid).
    #[serde(default = "default_hint_tolerance")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_hint_tolerance()))]
    #[schema(default = default_hint_tolerance, minimum = 0.0001, maximum = 50.0)]
    pub hint_tolerance_mm: f64,
    /// Refuse when the fit's RMS residual exceeds this, um.
    #[serde(default = "default_max_residual")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_max_residual()))]
    #[schema(default = default_max_residual, minimum = 0.001)]
    pub max_residual_um: f64,
    /// Fewest identified on-board points accepted.
    #[serde(default = "default_min_points")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_min_points()))]
    #[schema(default = default_min_points, minimum = 4, maximum = 1000000)]
    pub min_points: u64,
}

impl LocalizeRequest {
    /// The defaults ([`LocalizeSettings::default`], a camera above the board, scale
    /// unknown) with the hint `near`.
    pub fn new(near: [f64; 2]) -> Self {
        Self {
            image: String::new(),
            image_name: default_image_name(),
            near: Some(near),
            method: Method::default(),
            um_per_px: None,
            pixel_axes: PixelAxes::default(),
            hint_tolerance_mm: default_hint_tolerance(),
            max_residual_um: default_max_residual(),
            min_points: default_min_points(),
        }
    }

    /// Every bound that holds whatever the board.
    pub fn check(&self) -> Result<(), RequestError> {
        if self.image.len() > MAX_IMAGE_BASE64 {
            return Err(RequestError::new(
                "image",
                format!(
                    "{} bytes of base64; at most {MAX_IMAGE_BASE64} are accepted (a PNG file of 48 MiB)",
                    self.image.len()
                ),
            ));
        }
        for (k, v) in self.near.iter().flatten().enumerate() {
            number(
                &format!("near[{k}]"),
                *v,
                -MAX_COORDINATE_MM,
                MAX_COORDINATE_MM,
            )?;
        }
        if let Some(u) = self.um_per_px {
            number("um_per_px", u, UM_PER_PX.0, UM_PER_PX.1)?;
        }
        number(
            "hint_tolerance_mm",
            self.hint_tolerance_mm,
            HINT_TOLERANCE_MM.0,
            HINT_TOLERANCE_MM.1,
        )?;
        number(
            "max_residual_um",
            self.max_residual_um,
            1e-3,
            job::MAX_RESIDUAL_UM,
        )?;
        count("min_points", self.min_points, 4, MAX_MIN_POINTS)?;
        Ok(())
    }

    /// The bounds the board sets: a hint tolerance below half its pitch (else a dot
    /// could be mistaken for its neighbour), no more points than it has.
    pub fn check_for(&self, board: &Board) -> Result<(), RequestError> {
        self.check()?;
        let half_pitch = board.pitch_mm / 2.0;
        if board.code.is_none() && self.near.is_none() {
            return Err(RequestError::new(
                "near",
                format!(
                    "required on a plain dot grid (`{}`): its frames give the position only modulo the {} mm pitch (a coded board needs no hint)",
                    board.name, board.pitch_mm
                ),
            ));
        }
        if board.code.is_none() && !(self.hint_tolerance_mm < half_pitch) {
            return Err(RequestError::new(
                "hint_tolerance_mm",
                format!(
                    "must be below half the board pitch ({half_pitch} mm), or dots could be mistaken for their neighbours; got {}",
                    self.hint_tolerance_mm
                ),
            ));
        }
        let on_board = u64::from(board.cols) * u64::from(board.rows);
        if self.min_points > on_board {
            return Err(RequestError::new(
                "min_points",
                format!(
                    "the board has {on_board} points, fewer than the {} asked for",
                    self.min_points
                ),
            ));
        }
        Ok(())
    }

    /// The localizer's parameters.
    pub fn params(&self) -> LocalizeParams {
        let settings = LocalizeSettings {
            method: self.method,
            hint_tolerance_mm: self.hint_tolerance_mm,
            max_residual_um: self.max_residual_um,
            min_points: self.min_points as usize,
        };
        let mut p = LocalizeParams::with_settings([0.0, 0.0], &settings);
        p.hint_mm = self.near;
        p.um_per_px = self.um_per_px;
        p.pixel_axes = self.pixel_axes;
        p
    }
}

/// The request's frame: its PNG bytes (base64) decoded, named in messages by
/// `image_name`.
pub fn frame(request: &LocalizeRequest) -> Result<MonoImage, RequestError> {
    use base64::Engine;
    let bytes = base64::engine::general_purpose::STANDARD
        .decode(request.image.trim())
        .map_err(|e| RequestError::new("image", format!("not base64: {e}")))?;
    vision::image_io::decode_png(&bytes, &request.image_name)
        .map_err(|e| RequestError::new("image", e.to_string()))
}

/// Localizes the request's frame on the context's board.
pub struct Localize;

impl crate::registry::Procedure for Localize {
    const KIND: &'static str = "localize";
    const TITLE: &'static str =
        "Localize one frame of the board: the board position under its centre";
    const COMMAND: &'static str = "localize";
    const LABEL: &'static str = "Localize a frame";
    const HELP: &'static str = "Finds where on the machine's board a camera frame was taken: the board position under the frame's centre.";
    const USES: crate::registry::Uses = crate::registry::Uses::NOTHING;
    type Request = LocalizeRequest;
    type Result = LocalizeResult;
    const FILES: &'static [FileArg] = &[
        FileArg::positional(
            "image",
            "PNG file, 8- or 16-bit greyscale.",
            |path, plan| {
                use base64::Engine;
                let bytes = protocol::config::read_bytes_bounded(
                    path,
                    vision::image_io::MAX_IMAGE_BYTES,
                    "an image file",
                )
                .map_err(|e| {
                    crate::Error::Input(format!("{}: cannot open: {e}", path.display()))
                })?;
                plan.set(
                    "image",
                    base64::engine::general_purpose::STANDARD.encode(bytes),
                );
                plan.set("image_name", path.display().to_string());
                plan.inputs.push(path.to_path_buf());
                Ok(())
            },
        ),
        FileArg::required("board", "Board file (TOML).", command_line::board),
    ];

    async fn run(request: LocalizeRequest, cx: &mut dyn crate::Context) -> Outcome<LocalizeResult> {
        let board = crate::or_fail!(cx.board());
        let image = crate::or_fail!(frame(&request));
        let mut outcome = run(&request, &image, &board.board, &request.image_name);
        if let Some(r) = outcome.result.as_mut() {
            r.image.name = Some(request.image_name.clone());
        }
        outcome
    }

    fn summary(result: &LocalizeResult) -> String {
        summary(result)
    }
}

/// As a job, the request carries its frame.
impl crate::registry::Checked for LocalizeRequest {
    fn check(&self) -> Result<(), RequestError> {
        if self.image.is_empty() {
            return Err(RequestError::new(
                "image",
                "no frame was given: choose a PNG file of the board",
            ));
        }
        LocalizeRequest::check(self)
    }
}

/// Localizes `image` (`source` names it in messages) on `board`. The result: `x_mm`,
/// `y_mm`, `points`, `method`, `elapsed_ms`, `residual_rms_um`, `um_per_px`,
/// `rotation_deg` and `image` {`width`, `height`, `bit_depth`} (a front end that read
/// the frame from a file adds its `path`). A request out of bounds or a refused frame
/// fails with the reason.
pub fn run(
    request: &LocalizeRequest,
    image: &MonoImage,
    board: &Board,
    source: &str,
) -> Outcome<LocalizeResult> {
    if let Err(e) = request.check_for(board) {
        return Outcome::failed(e.to_string());
    }
    let t0 = Instant::now();
    let obs = match localize(image, board, &request.params()) {
        Ok(o) => o,
        Err(e) => return Outcome::failed(format!("{source}: {e}")),
    };
    let elapsed_ms = t0.elapsed().as_secs_f64() * 1000.0;
    let result = LocalizeResult {
        x_mm: obs.x_mm,
        y_mm: obs.y_mm,
        points: obs.points,
        method: obs.method,
        elapsed_ms,
        residual_rms_um: obs.residual_rms_um,
        um_per_px: obs.um_per_px,
        rotation_deg: obs.rotation_deg,
        image: FrameInfo {
            width: image.width,
            height: image.height,
            bit_depth: image.bit_depth(),
            name: None,
        },
        // A coded board: how its code was read (plain grids keep their result as before).
        code: obs.code,
    };
    let metrics = [
        ("x_mm", result.x_mm.into()),
        ("y_mm", result.y_mm.into()),
        ("points", result.points.into()),
        ("residual_rms_um", result.residual_rms_um.into()),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v))
    .collect();
    Outcome::succeeded(result, metrics)
}

/// The localization as text (the CLI's output without `--json`).
pub fn summary(r: &LocalizeResult) -> String {
    // The method as the localizer names it (`Fit`, `FourPoint`).
    format!(
        "board coordinate at the image centre: X {:.5} mm  Y {:.5} mm\n\
         method {:?}, {} points, residual {:.3} um rms, scale {:.4} um/px, rotation {:.4} deg, {:.3} ms\n",
        r.x_mm,
        r.y_mm,
        r.method,
        r.points,
        r.residual_rms_um,
        r.um_per_px,
        r.rotation_deg,
        r.elapsed_ms
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn board() -> Board {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        Board::load(&dir.join("../../config/boards/dot-grid-0.5mm.toml")).unwrap()
    }

    #[test]
    fn the_defaults_pass() {
        let r = LocalizeRequest::new([10.0, 20.0]);
        r.check_for(&board()).unwrap();
        let p = r.params();
        assert_eq!(p.hint_mm, Some([10.0, 20.0]));
        assert_eq!(p.min_points, LocalizeSettings::default().min_points);
    }

    #[test]
    fn nan_and_absurd_values_are_refused_naming_the_field() {
        let ok = LocalizeRequest::new([10.0, 20.0]);
        let field = |f: &dyn Fn(&mut LocalizeRequest)| {
            let mut r = ok.clone();
            f(&mut r);
            r.check_for(&board()).unwrap_err().field
        };
        assert_eq!(field(&|r| r.near = Some([1.0, f64::NAN])), "near[1]");
        assert_eq!(field(&|r| r.near = Some([1e300, 1.0])), "near[0]");
        assert_eq!(field(&|r| r.um_per_px = Some(0.0)), "um_per_px");
        assert_eq!(field(&|r| r.um_per_px = Some(f64::INFINITY)), "um_per_px");
        assert_eq!(
            field(&|r| r.hint_tolerance_mm = f64::NAN),
            "hint_tolerance_mm"
        );
        assert_eq!(field(&|r| r.hint_tolerance_mm = 0.0), "hint_tolerance_mm");
        // Half the 0.5 mm pitch admits two grid offsets.
        assert_eq!(field(&|r| r.hint_tolerance_mm = 0.25), "hint_tolerance_mm");
        assert_eq!(field(&|r| r.max_residual_um = -1.0), "max_residual_um");
        assert_eq!(field(&|r| r.max_residual_um = 1e9), "max_residual_um");
        assert_eq!(field(&|r| r.min_points = 3), "min_points");
        assert_eq!(field(&|r| r.min_points = MAX_MIN_POINTS), "min_points");
        let mut r = ok.clone();
        r.near = Some([f64::NAN, 0.0]);
        assert!(r.check().unwrap_err().for_cli().starts_with("--near: "));
    }

    #[test]
    fn near_is_required_on_a_plain_grid_only() {
        let mut r = LocalizeRequest::new([10.0, 20.0]);
        r.near = None;
        let e = r.check_for(&board()).unwrap_err();
        assert_eq!(e.field, "near");
        assert!(e.to_string().contains("plain dot grid"), "{e}");
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let coded = Board::load(&dir.join("../../config/boards/coded-0.5mm.toml")).unwrap();
        r.check_for(&coded).unwrap();
        assert_eq!(r.params().hint_mm, None);
        // On a coded board the hint tolerance is not bounded by the pitch.
        r.hint_tolerance_mm = 2.0;
        r.check_for(&coded).unwrap();
        let r: LocalizeRequest = serde_json::from_value(json!({})).unwrap();
        assert_eq!(r.near, None);
    }

    #[test]
    fn a_request_reads_from_json_with_its_defaults() {
        let r: LocalizeRequest = serde_json::from_value(
            json!({"near": [1.0, 2.0], "method": "four-point", "pixel_axes": "+y,+x"}),
        )
        .unwrap();
        assert_eq!(r.method, Method::FourPoint);
        assert_eq!(r.pixel_axes.to_string(), "+y,+x");
        assert_eq!(r.min_points, default_min_points());
        assert!(
            serde_json::from_value::<LocalizeRequest>(json!({"near": [1, 2], "x": 1})).is_err()
        );
    }

    #[test]
    fn a_blank_frame_is_refused_naming_the_source() {
        let image = MonoImage::new(64, 48, protocol::Pixels::Mono8(vec![200; 64 * 48])).unwrap();
        let o = run(
            &LocalizeRequest::new([1.0, 1.0]),
            &image,
            &board(),
            "blank.png",
        );
        assert!(o.error().unwrap().starts_with("blank.png: "), "{o:?}");
    }

    #[test]
    fn the_summary_reads_the_result() {
        let r = json!({"x_mm": 1.0, "y_mm": 2.0, "points": 9, "method": "four-point",
            "elapsed_ms": 3.0, "residual_rms_um": 0.1, "um_per_px": 4.0, "rotation_deg": 0.5,
            "image": {"width": 640, "height": 480, "bit_depth": 8}});
        let t = summary(&serde_json::from_value(r).unwrap());
        assert!(t.starts_with("board coordinate at the image centre: X 1.00000 mm  Y 2.00000 mm\n"));
        assert!(t.contains("method FourPoint, 9 points"), "{t}");
    }
}

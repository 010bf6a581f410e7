//! The 21-error volumetric model of a 3-axis machine (source D) from files: identified
//! from a measurement campaign, evaluated at points, each error's contribution over the
//! volume, the emulated machine's campaign, and the model as the ISG kernel's tables.
//!
//! Inputs are the requests' own fields: the text of each file (the CLI reads the files
//! through the bounded reader, the page uploads them), at most [`MAX_FILE_BYTES`] each;
//! the products go to the [`Sink`] as artifacts. A campaign is up to eleven named files
//! ([`CAMPAIGN_FILES`]); [`identify`] decides which are due.
//!
//! Paths are the front end's: a result names its artifacts (`model`: [`MODEL_ARTIFACT`]),
//! and the CLI replaces the name with the path it wrote or adds the folder (`out`).

use crate::command_line::{self, FileArg};
use crate::request::{count, number, RequestError};
use crate::{Artifact, Outcome, Sink};
use protocol::volumetric::{
    parse_model, parse_points, write_isg_csv, write_isg_lis, write_model, Structure, AXES,
};
use serde::{Deserialize, Serialize};
use std::fmt::Write;
use volumetric::ballbar::BallbarChart;
use volumetric::contributions::{
    contributions as contributions_over, plane_map, ContributionChart, Plane,
};
use volumetric::identify::Campaign;
use volumetric::Model;

/// A volumetric model or campaign file's text through the bounded reader
/// ([`protocol::config::DataKind::Volumetric`]); the error names the file.
pub fn read_file(path: &std::path::Path) -> Result<String, crate::Error> {
    Ok(protocol::config::read_kind(
        path,
        protocol::config::DataKind::Volumetric,
    )?)
}

/// The largest file text a request carries (a model, a points file, a campaign file).
pub const MAX_FILE_BYTES: usize = 16 << 20;

/// A file's text in a request: at most [`MAX_FILE_BYTES`]; `required` ones not empty.
fn file_text(field: &str, text: &str, required: bool) -> Result<(), RequestError> {
    if required && text.trim().is_empty() {
        return Err(RequestError::new(field, "no file was given"));
    }
    if text.len() > MAX_FILE_BYTES {
        return Err(RequestError::new(
            field,
            format!(
                "{} bytes; at most {MAX_FILE_BYTES} are accepted",
                text.len()
            ),
        ));
    }
    Ok(())
}

fn default_model_name() -> String {
    "model.vol.csv".into()
}
fn default_campaign_name() -> String {
    "campaign".into()
}
fn default_points_name() -> String {
    "points.csv".into()
}

/// The model file [`identify`] produces.
pub const MODEL_ARTIFACT: &str = "model.vol.csv";

/// The largest offset of the tool point or the workpiece reference, mm.
pub const MAX_OFFSET_MM: f64 = 10_000.0;

/// The most points [`eval`] evaluates: its result holds one object per point (about
/// 0.5 kB each), so 100 000 points stay near 50 MB.
pub const MAX_EVAL_POINTS: usize = 100_000;

/// The memory [`contributions`] may ask for: its `grid`³ points of the volume (24 bytes
/// each) and one plane map at a time (`grid`² cells of about 320 bytes: the values, the
/// CSV row and the SVG's cell and arrow). 256 MiB allows a grid of 219 points per axis.
pub const MAX_CONTRIBUTIONS_BYTES: u64 = 256 << 20;

/// The bytes [`contributions`] needs for a `grid` of `n` points per axis (see
/// [`MAX_CONTRIBUTIONS_BYTES`]).
pub fn contributions_bytes(n: u64) -> u128 {
    let n = u128::from(n);
    n * n * n * 24 + n * n * 320
}

fn structure_of(field: &str, text: &str) -> Result<Structure, RequestError> {
    Structure::parse(text).ok_or_else(|| {
        RequestError::new(
            field,
            format!("`{text}`: expected FXYZ, XFYZ, XYFZ or XYZF"),
        )
    })
}

fn offsets(field: &str, v: &[f64; 3]) -> Result<(), RequestError> {
    for (k, c) in v.iter().enumerate() {
        number(&format!("{field}[{k}]"), *c, -MAX_OFFSET_MM, MAX_OFFSET_MM)?;
    }
    Ok(())
}

/// Identify the model from a campaign.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields)]
pub struct VolumetricIdentifyRequest {
    /// The machine's structure: FXYZ, XFYZ, XYFZ or XYZF.
    #[cfg_attr(feature = "cli", arg(long))]
    pub structure: String,
    /// The tool point in the last tool carriage's frame, `x,y,z` mm (the tool length).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, default_value = "0,0,0", value_parser = xyz_mm, allow_hyphen_values = true))]
    #[schema(value_type = Vec<f64>, min_items = 3, max_items = 3)]
    pub tool_offset_mm: [f64; 3],
    /// The workpiece reference point in the last workpiece carriage's frame, `x,y,z` mm.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, default_value = "0,0,0", value_parser = xyz_mm, allow_hyphen_values = true))]
    #[schema(value_type = Vec<f64>, min_items = 3, max_items = 3)]
    pub work_offset_mm: [f64; 3],
    /// Also draw the ball-bar circles (`ballbar_XY.svg`/`.png`, ...); the CLI's: with
    /// `--plots DIR`.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(skip))]
    pub plots: bool,
    /// How messages name the campaign (its folder).
    #[serde(default = "default_campaign_name")]
    #[cfg_attr(feature = "cli", arg(skip = default_campaign_name()))]
    #[schema(default = default_campaign_name)]
    pub campaign_name: String,
    /// The laser's positioning errors along X (`laser_X.csv`).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(skip))]
    #[schema(format = Binary)]
    pub laser_x: Option<String>,
    /// The electronic level's pitch/roll along X (`level_X.csv`).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(skip))]
    #[schema(format = Binary)]
    pub level_x: Option<String>,
    /// The laser's positioning errors along Y (`laser_Y.csv`).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(skip))]
    #[schema(format = Binary)]
    pub laser_y: Option<String>,
    /// The electronic level's along Y (`level_Y.csv`).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(skip))]
    #[schema(format = Binary)]
    pub level_y: Option<String>,
    /// The laser's positioning errors along Z (`laser_Z.csv`).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(skip))]
    #[schema(format = Binary)]
    pub laser_z: Option<String>,
    /// The electronic level's along Z (`level_Z.csv`).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(skip))]
    #[schema(format = Binary)]
    pub level_z: Option<String>,
    /// The ball bar's circle in the XY plane (`ballbar_XY.csv`).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(skip))]
    #[schema(format = Binary)]
    pub ballbar_xy: Option<String>,
    /// The ball bar's circle in the XZ plane (`ballbar_XZ.csv`).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(skip))]
    #[schema(format = Binary)]
    pub ballbar_xz: Option<String>,
    /// The ball bar's circle in the YZ plane (`ballbar_YZ.csv`).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(skip))]
    #[schema(format = Binary)]
    pub ballbar_yz: Option<String>,
    /// The squareness measurements (instead of the ball-bar circles) (`squareness.csv`).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(skip))]
    #[schema(format = Binary)]
    pub squareness: Option<String>,
    /// The camera's board measurements at several heights (if measured) (`camera.csv`).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(skip))]
    #[schema(format = Binary)]
    pub camera: Option<String>,
}

/// `x,y,z` in mm (a command-line value); the error is the value's
/// ([`crate::Error::Input`]).
#[cfg(feature = "cli")]
pub fn xyz_mm(text: &str) -> Result<[f64; 3], crate::Error> {
    let v: Vec<f64> = text
        .split(',')
        .map(|p| p.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| crate::Error::Input(format!("`{text}`: expected x,y,z in mm")))?;
    v.try_into()
        .map_err(|_| crate::Error::Input(format!("`{text}`: expected three numbers x,y,z in mm")))
}

impl VolumetricIdentifyRequest {
    pub fn check(&self) -> Result<(), RequestError> {
        structure_of("structure", &self.structure)?;
        offsets("tool_offset_mm", &self.tool_offset_mm)?;
        offsets("work_offset_mm", &self.work_offset_mm)?;
        for (name, text) in CAMPAIGN_FILES.iter().zip(self.files()) {
            if let Some(text) = text {
                file_text(&field_of(name), text, false)?;
            }
        }
        Ok(())
    }

    /// The campaign's files in [`CAMPAIGN_FILES`] order.
    fn files(&self) -> [&Option<String>; 11] {
        [
            &self.laser_x,
            &self.level_x,
            &self.laser_y,
            &self.level_y,
            &self.laser_z,
            &self.level_z,
            &self.ballbar_xy,
            &self.ballbar_xz,
            &self.ballbar_yz,
            &self.squareness,
            &self.camera,
        ]
    }

    /// The field holding the campaign file `name` (one of [`CAMPAIGN_FILES`]).
    pub fn file_mut(&mut self, name: &str) -> Option<&mut Option<String>> {
        let at = CAMPAIGN_FILES.iter().position(|n| *n == name)?;
        Some(
            [
                &mut self.laser_x,
                &mut self.level_x,
                &mut self.laser_y,
                &mut self.level_y,
                &mut self.laser_z,
                &mut self.level_z,
                &mut self.ballbar_xy,
                &mut self.ballbar_xz,
                &mut self.ballbar_yz,
                &mut self.squareness,
                &mut self.camera,
            ]
            .into_iter()
            .nth(at)
            .expect("one field per file"),
        )
    }
}

/// A campaign file's field: `laser_X.csv` is `laser_x`.
fn field_of(name: &str) -> String {
    name.trim_end_matches(".csv").to_ascii_lowercase()
}

/// The files a campaign may hold; [`identify`] says which are due (laser and level per
/// axis; three ball-bar circles or `squareness.csv`; `camera.csv` if measured).
pub const CAMPAIGN_FILES: [&str; 11] = [
    "laser_X.csv",
    "level_X.csv",
    "laser_Y.csv",
    "level_Y.csv",
    "laser_Z.csv",
    "level_Z.csv",
    "ballbar_XY.csv",
    "ballbar_XZ.csv",
    "ballbar_YZ.csv",
    "squareness.csv",
    "camera.csv",
];

fn artifact(name: impl Into<String>, media_type: &'static str, bytes: Vec<u8>) -> Artifact {
    Artifact {
        name: name.into(),
        title: None,
        media_type,
        bytes,
    }
}

/// Translations (E_X?, E_Y?, E_Z?) in µm, angles in µrad.
fn display_unit(name: &str) -> (f64, &'static str) {
    let is_length = name.len() == 4 && matches!(&name[2..3], "X" | "Y" | "Z");
    if is_length {
        (1e3, "um")
    } else {
        (1e6, "urad")
    }
}

/// How well one of the 21 errors is known (translations in um, angles in urad).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct IdentifiedError {
    /// `E_XX`, ... `E_C0X`.
    pub name: String,
    /// `um` (a translation) or `urad` (an angle): the unit of the three figures.
    pub unit: String,
    /// RMS of (run - mean).
    pub residual: f64,
    /// Largest standard uncertainty of the identified value.
    pub uncertainty: f64,
    /// The instrument's stated uncertainty.
    pub stated: f64,
    /// Whether the residual is within the stated uncertainty.
    pub fit: bool,
}

/// The ball bar's reading of one plane and the model's squareness.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct BallbarPlane {
    /// `XY`, `XZ` or `YZ`.
    pub plane: String,
    /// ISO 230-4 circular deviation about the least-squares centre.
    pub circular_deviation_um: f64,
    /// The raw squareness reading of the test (`-2 b2 / R`).
    pub iso_squareness_urad: f64,
    /// The model's squareness constant.
    pub squareness_urad: f64,
    /// Its standard uncertainty.
    pub uncertainty_urad: f64,
    /// RMS of the readings minus the fitted model's prediction.
    pub model_residual_rms_um: f64,
}

/// One angle the camera combined with the instruments.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct CameraAngle {
    /// `E_AX`, `E_BX`, `E_AY` or `E_BY`.
    pub name: String,
    /// The combined value's largest standard uncertainty.
    pub uncertainty_urad: f64,
    /// The largest change from the instruments' value.
    pub largest_change_from_instruments_urad: f64,
}

/// The camera's board measurements at several heights, combined with the instruments.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct CameraFigures {
    pub points: usize,
    /// Heights of Z, the reference first.
    pub heights_mm: Vec<f64>,
    /// RMS of the fitted camera differences' residuals.
    pub residual_rms_um: f64,
    /// Its stated bound (`sqrt(2) U`).
    pub stated_um: f64,
    /// RMS of the runs about their mean.
    pub repeatability_um: f64,
    /// The board's rotation change per raised height.
    pub board_rotation_urad: Vec<f64>,
    /// Whether the camera is consistent with the model.
    pub fit: bool,
    #[schema(inline)]
    pub angles: Vec<CameraAngle>,
}

/// `volumetric identify`'s result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct VolumetricIdentifyResult {
    /// The model file (the artifact [`MODEL_ARTIFACT`]; the CLI: the path it wrote).
    pub model: String,
    /// FXYZ, XFYZ, XYFZ or XYZF.
    pub structure: String,
    /// Whether every error is within its stated uncertainty (else the CLI exits 2).
    pub fit_for_compensation: bool,
    /// The 21 errors.
    #[schema(inline)]
    pub errors: Vec<IdentifiedError>,
    /// The ball-bar planes (none with `squareness.csv`).
    #[schema(inline)]
    pub ballbar: Vec<BallbarPlane>,
    /// Null without `camera.csv`.
    #[schema(inline)]
    pub camera: Option<CameraFigures>,
}

/// Identifies the model from the campaign. The model file ([`MODEL_ARTIFACT`], marked
/// fit or unfit for compensation) and, with `plots`, the ball-bar charts go to the sink.
/// The result: `model` (the artifact), `structure`, `fit_for_compensation`, `errors`
/// (per error: `name`, `unit`, `residual`, `uncertainty`, `stated`, `fit`), `ballbar`,
/// `camera` (null without `camera.csv`). An unfit model is a success: the front end
/// says so (the CLI's exit code 2).
pub fn identify(
    request: &VolumetricIdentifyRequest,
    sink: &mut dyn Sink,
) -> Outcome<VolumetricIdentifyResult> {
    let structure = match request.check() {
        Ok(()) => structure_of("structure", &request.structure).expect("checked"),
        Err(e) => return Outcome::failed(e.to_string()),
    };
    let place = &request.campaign_name;
    let files: Vec<(String, String)> = CAMPAIGN_FILES
        .iter()
        .zip(request.files())
        .filter_map(|(name, text)| Some((name.to_string(), text.clone()?)))
        .collect();
    let parsed = match Campaign::from_files(&files) {
        Ok(c) => c,
        Err(e) => return Outcome::failed(format!("{place}/{e}")),
    };
    drop(files);
    let mut id = match volumetric::identify::identify(structure, &parsed) {
        Ok(id) => id,
        Err(e) => return Outcome::failed(format!("{place}: {e}")),
    };
    id.model.file.tool_offset_mm = request.tool_offset_mm;
    id.model.file.work_offset_mm = request.work_offset_mm;
    let model = artifact(
        MODEL_ARTIFACT,
        "text/csv",
        write_model(&id.model.file).into_bytes(),
    );
    if let Err(e) = sink.artifact(model) {
        return Outcome::failed(e);
    }
    if request.plots {
        for b in &id.ballbar {
            let chart = BallbarChart(b);
            let drawn = plot::render_svg(&chart, 800, 800)
                .map(String::into_bytes)
                .and_then(|svg| Ok((svg, plot::render_png(&chart, 800, 800)?)));
            let (svg, png) = match drawn {
                Ok(d) => d,
                Err(e) => return Outcome::failed(format!("ballbar_{}: {e}", b.plane)),
            };
            let mut svg = artifact(format!("ballbar_{}.svg", b.plane), "image/svg+xml", svg);
            svg.title = Some(format!("Ball bar, {} plane", b.plane));
            for a in [
                svg,
                artifact(format!("ballbar_{}.png", b.plane), "image/png", png),
            ] {
                if let Err(e) = sink.artifact(a) {
                    return Outcome::failed(e);
                }
            }
        }
    }
    let errors = (id.quality.iter())
        .map(|q| {
            let (scale, unit) = display_unit(q.name);
            IdentifiedError {
                name: q.name.into(),
                unit: unit.into(),
                residual: q.residual * scale,
                uncertainty: q.uncertainty * scale,
                stated: q.stated * scale,
                fit: q.fit(),
            }
        })
        .collect();
    let ballbar = (id.ballbar.iter())
        .map(|b| BallbarPlane {
            plane: b.plane.into(),
            circular_deviation_um: b.circular_deviation_mm * 1e3,
            iso_squareness_urad: b.iso_squareness_rad * 1e6,
            squareness_urad: b.squareness_rad * 1e6,
            uncertainty_urad: b.uncertainty_rad * 1e6,
            model_residual_rms_um: b.model_residual_rms_mm * 1e3,
        })
        .collect();
    let camera = id.camera.as_ref().map(|c| CameraFigures {
        points: c.points,
        heights_mm: c.heights_mm.clone(),
        residual_rms_um: c.residual_rms_mm * 1e3,
        stated_um: c.stated_mm * 1e3,
        repeatability_um: c.repeatability_mm * 1e3,
        board_rotation_urad: c.board_rotation_rad.iter().map(|v| v * 1e6).collect(),
        fit: c.fit(),
        angles: (0..2)
            .flat_map(|a| (0..2).map(move |k| (a, k)))
            .map(|(a, k)| CameraAngle {
                name: c.names[a][k].into(),
                uncertainty_urad: c.sigma[a][k].iter().fold(0.0f64, |m, v| m.max(*v)) * 1e6,
                largest_change_from_instruments_urad: c.change[a][k] * 1e6,
            })
            .collect(),
    });
    let result = VolumetricIdentifyResult {
        model: MODEL_ARTIFACT.into(),
        structure: structure.name().into(),
        fit_for_compensation: id.model.file.fit,
        errors,
        ballbar,
        camera,
    };
    let mut metrics = serde_json::Map::new();
    metrics.insert(
        "fit_for_compensation".into(),
        result.fit_for_compensation.into(),
    );
    Outcome::succeeded(result, metrics)
}

/// The identification as text: a table of the 21 errors, the ball-bar circles, the
/// camera's figures.
pub fn identify_summary(r: &VolumetricIdentifyResult) -> String {
    let mut t = String::new();
    let _ = writeln!(
        t,
        "{:<6} {:>10} {:>12} {:>8}  unit",
        "error", "residual", "uncertainty", "stated"
    );
    for q in &r.errors {
        let unit = if q.unit == "um" { "µm" } else { &q.unit };
        let _ = writeln!(
            t,
            "{:<6} {:>10.3} {:>12.3} {:>8.3}  {unit}{}",
            q.name,
            q.residual,
            q.uncertainty,
            q.stated,
            if q.fit {
                ""
            } else {
                "  EXCEEDS the stated uncertainty"
            }
        );
    }
    for b in &r.ballbar {
        let _ = writeln!(
            t,
            "ball bar {}: circular deviation {:.2} µm, ISO squareness reading {:.2} µrad, model squareness {:.2} ± {:.2} µrad, residual {:.3} µm RMS",
            b.plane,
            b.circular_deviation_um,
            b.iso_squareness_urad,
            b.squareness_urad,
            b.uncertainty_urad,
            b.model_residual_rms_um
        );
    }
    if let Some(c) = &r.camera {
        let _ = writeln!(
            t,
            "camera: {} points at heights {:?} mm, residual {:.3} µm RMS (stated {:.3}), {}",
            c.points,
            c.heights_mm,
            c.residual_rms_um,
            c.stated_um,
            if c.fit {
                "consistent"
            } else {
                "INCONSISTENT with the model"
            }
        );
        for a in &c.angles {
            let _ = writeln!(
                t,
                "  {}: uncertainty {:.3} µrad combined, largest change from the instruments {:.3} µrad",
                a.name, a.uncertainty_urad, a.largest_change_from_instruments_urad
            );
        }
    }
    t
}

/// Reads and checks a model file; `name` names it in messages.
pub fn read_model(name: &str, text: &str) -> Result<Model, crate::Error> {
    let file = parse_model(text).map_err(|e| crate::Error::input(name, e))?;
    Model::new(file).map_err(|e| crate::Error::input(name, e))
}

/// The volumetric error at each point of a points file (`x_mm,y_mm,z_mm`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields)]
pub struct VolumetricEvalRequest {
    /// The model file's text (`gateway volumetric identify`'s).
    #[cfg_attr(feature = "cli", arg(skip))]
    #[schema(format = Binary)]
    pub model: String,
    /// How messages name the model (its file name).
    #[serde(default = "default_model_name")]
    #[cfg_attr(feature = "cli", arg(skip = default_model_name()))]
    #[schema(default = default_model_name)]
    pub model_name: String,
    /// The points file's text (CSV `x_mm,y_mm,z_mm`).
    #[cfg_attr(feature = "cli", arg(skip))]
    #[schema(format = Binary)]
    pub points: String,
    /// How messages name the points file.
    #[serde(default = "default_points_name")]
    #[cfg_attr(feature = "cli", arg(skip = default_points_name()))]
    #[schema(default = default_points_name)]
    pub points_name: String,
    /// Use the first-order closed form instead of the full HTM product.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long))]
    pub first_order: bool,
}

impl VolumetricEvalRequest {
    pub fn check(&self) -> Result<(), RequestError> {
        file_text("model", &self.model, true)?;
        file_text("points", &self.points, true)?;
        self.check_points(&self.points).map(|_| ())
    }

    /// The points a points file holds, counted before it is parsed; refused past
    /// [`MAX_EVAL_POINTS`] naming `points`.
    pub fn check_points(&self, text: &str) -> Result<usize, RequestError> {
        let rows = text
            .lines()
            .map(str::trim)
            .filter(|l| !l.is_empty() && !l.starts_with('#'))
            .count()
            .saturating_sub(1);
        if rows > MAX_EVAL_POINTS {
            return Err(RequestError::new(
                "points",
                format!("{rows} points; at most {MAX_EVAL_POINTS} are evaluated at once (split the file)"),
            ));
        }
        Ok(rows)
    }
}

/// The volumetric error at one point.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct EvalPoint {
    pub x_mm: f64,
    pub y_mm: f64,
    pub z_mm: f64,
    pub ex_um: f64,
    pub ey_um: f64,
    pub ez_um: f64,
}

/// `volumetric eval`'s result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct VolumetricEvalResult {
    /// Whether the first-order closed form was used (else the full HTM product).
    pub first_order: bool,
    /// One per point of the points file, in its order.
    #[schema(inline)]
    pub points: Vec<EvalPoint>,
}

/// The error at every point ([`VolumetricEvalResult`]); a point outside the model's
/// travel fails it, named by its number and line.
pub fn eval(request: &VolumetricEvalRequest) -> Outcome<VolumetricEvalResult> {
    if let Err(e) = request.check() {
        return Outcome::failed(e.to_string());
    }
    let model = crate::or_fail!(read_model(&request.model_name, &request.model));
    let (points_name, points) = (&request.points_name, &request.points);
    let pts = match parse_points(points) {
        Ok(p) => p,
        Err(e) => return Outcome::failed(format!("{points_name}: {e}")),
    };
    let mut rows = Vec::with_capacity(pts.len());
    for (i, q) in pts.iter().enumerate() {
        let e = match model.error(*q, request.first_order) {
            Ok(e) => e,
            Err(e) => {
                return Outcome::failed(format!(
                    "{points_name}: point {} (line {}): {e}",
                    i + 1,
                    i + 2
                ))
            }
        };
        rows.push(EvalPoint {
            x_mm: q[0],
            y_mm: q[1],
            z_mm: q[2],
            ex_um: e[0] * 1e3,
            ey_um: e[1] * 1e3,
            ez_um: e[2] * 1e3,
        });
    }
    let mut metrics = serde_json::Map::new();
    metrics.insert("points".into(), rows.len().into());
    Outcome::succeeded(
        VolumetricEvalResult {
            first_order: request.first_order,
            points: rows,
        },
        metrics,
    )
}

/// The evaluation as CSV lines (`x_mm,y_mm,z_mm,ex_um,ey_um,ez_um`, header first).
pub fn eval_lines(r: &VolumetricEvalResult) -> impl Iterator<Item = String> + '_ {
    std::iter::once("x_mm,y_mm,z_mm,ex_um,ey_um,ez_um".to_string()).chain(r.points.iter().map(
        |p| {
            format!(
                "{},{},{},{:.4},{:.4},{:.4}",
                p.x_mm, p.y_mm, p.z_mm, p.ex_um, p.ey_um, p.ez_um
            )
        },
    ))
}

fn default_grid() -> u64 {
    11
}

/// Each error's contribution over the volume and the error maps of the middle planes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields)]
pub struct VolumetricContributionsRequest {
    /// The model file's text (`gateway volumetric identify`'s).
    #[cfg_attr(feature = "cli", arg(skip))]
    #[schema(format = Binary)]
    pub model: String,
    /// How messages name the model (its file name).
    #[serde(default = "default_model_name")]
    #[cfg_attr(feature = "cli", arg(skip = default_model_name()))]
    #[schema(default = default_model_name)]
    pub model_name: String,
    /// Grid points per axis (from 2; the memory the grid needs is bounded).
    #[serde(default = "default_grid")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_grid()))]
    #[schema(default = default_grid, minimum = 2, maximum = 219)]
    pub grid: u64,
}

impl Default for VolumetricContributionsRequest {
    fn default() -> Self {
        Self {
            model: String::new(),
            model_name: default_model_name(),
            grid: default_grid(),
        }
    }
}

impl VolumetricContributionsRequest {
    /// At least 2 points per axis; the memory the grid implies
    /// ([`contributions_bytes`]) at most [`MAX_CONTRIBUTIONS_BYTES`].
    pub fn check(&self) -> Result<(), RequestError> {
        file_text("model", &self.model, true)?;
        count("grid", self.grid, 2, u64::from(u32::MAX))?;
        let bytes = contributions_bytes(self.grid);
        if bytes > u128::from(MAX_CONTRIBUTIONS_BYTES) {
            let largest = (2..)
                .take_while(|n| contributions_bytes(*n) <= u128::from(MAX_CONTRIBUTIONS_BYTES))
                .last()
                .unwrap_or(2);
            return Err(RequestError::new(
                "grid",
                format!(
                    "a grid of {} points per axis needs about {} MiB; at most {} MiB are accepted (a grid of at most {largest})",
                    self.grid,
                    bytes >> 20,
                    MAX_CONTRIBUTIONS_BYTES >> 20
                ),
            ));
        }
        Ok(())
    }
}

/// One error's contribution over the volume.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Contribution {
    /// `E_XX`, ... `E_C0X`.
    pub error: String,
    pub max_um: f64,
    pub rms_um: f64,
}

/// `volumetric contributions`' result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct VolumetricContributionsResult {
    /// Grid points per axis.
    pub grid: usize,
    /// The total error (first order) over the grid.
    pub total_max_um: f64,
    pub total_rms_um: f64,
    /// The 21 errors, the largest first.
    #[schema(inline)]
    pub contributions: Vec<Contribution>,
}

/// The 21 contributions over a `grid`³ grid (ranked: `contributions.csv`, `.svg`,
/// `.png`) and the exact error over the XY, XZ and YZ planes through the middle
/// (`map_XY.csv`, `.svg`, `.png`, ...), as artifacts. The result: `grid`,
/// `total_max_um`, `total_rms_um`, `contributions` (`error`, `max_um`, `rms_um`).
pub fn contributions(
    request: &VolumetricContributionsRequest,
    sink: &mut dyn Sink,
) -> Outcome<VolumetricContributionsResult> {
    if let Err(e) = request.check() {
        return Outcome::failed(e.to_string());
    }
    let model = &crate::or_fail!(read_model(&request.model_name, &request.model));
    let grid = request.grid as usize;
    let (c, tmax, trms) = match contributions_over(model, grid) {
        Ok(c) => c,
        Err(e) => return Outcome::failed(e.to_string()),
    };
    let mut csv = String::from("rank,error,max_um,rms_um\n");
    for (i, x) in c.iter().enumerate() {
        let _ = writeln!(csv, "{},{},{:.4},{:.4}", i + 1, x.name, x.max_um, x.rms_um);
    }
    let chart = ContributionChart(&c);
    let charts = plot::render_svg(&chart, 900, 700)
        .and_then(|svg| Ok((svg, plot::render_png(&chart, 900, 700)?)));
    let (svg, png) = match charts {
        Ok(d) => d,
        Err(e) => return Outcome::failed(format!("contributions: {e}")),
    };
    let mut svg = artifact("contributions.svg", "image/svg+xml", svg.into_bytes());
    svg.title = Some("Contribution of each error".into());
    for a in [
        artifact("contributions.csv", "text/csv", csv.into_bytes()),
        svg,
        artifact("contributions.png", "image/png", png),
    ] {
        if let Err(e) = sink.artifact(a) {
            return Outcome::failed(e);
        }
    }
    for plane in [Plane::Xy, Plane::Xz, Plane::Yz] {
        let map = match plane_map(model, plane, grid) {
            Ok(m) => m,
            Err(e) => return Outcome::failed(e.to_string()),
        };
        let (a, b, _) = plane.axes();
        let mut csv = format!(
            "{}_mm,{}_mm,ex_um,ey_um,ez_um\n",
            AXES[a].to_ascii_lowercase(),
            AXES[b].to_ascii_lowercase()
        );
        for (i, u) in map.u.iter().enumerate() {
            for (j, v) in map.v.iter().enumerate() {
                let e = map.errors[i][j];
                let _ = writeln!(csv, "{u},{v},{:.4},{:.4},{:.4}", e[0], e[1], e[2]);
            }
        }
        let name = format!("map_{}", plane.name());
        let drawn = plot::render_svg(&map, 800, 650)
            .and_then(|svg| Ok((svg, plot::render_png(&map, 800, 650)?)));
        let (svg, png) = match drawn {
            Ok(d) => d,
            Err(e) => return Outcome::failed(format!("{name}: {e}")),
        };
        let mut svg = artifact(format!("{name}.svg"), "image/svg+xml", svg.into_bytes());
        svg.title = Some(format!("Volumetric error, {} plane", plane.name()));
        for a in [
            artifact(format!("{name}.csv"), "text/csv", csv.into_bytes()),
            svg,
            artifact(format!("{name}.png"), "image/png", png),
        ] {
            if let Err(e) = sink.artifact(a) {
                return Outcome::failed(e);
            }
        }
    }
    let contributions = (c.iter())
        .map(|x| Contribution {
            error: x.name.into(),
            max_um: x.max_um,
            rms_um: x.rms_um,
        })
        .collect();
    let mut metrics = serde_json::Map::new();
    metrics.insert("total_max_um".into(), tmax.into());
    metrics.insert("total_rms_um".into(), trms.into());
    let result = VolumetricContributionsResult {
        grid,
        total_max_um: tmax,
        total_rms_um: trms,
        contributions,
    };
    Outcome::succeeded(result, metrics)
}

/// The contributions as text: the total, then each error ranked.
pub fn contributions_summary(r: &VolumetricContributionsResult) -> String {
    let mut t = format!(
        "total (first order): max {:.2} µm, RMS {:.2} µm over a {}³ grid\n",
        r.total_max_um, r.total_rms_um, r.grid
    );
    for (i, x) in r.contributions.iter().enumerate() {
        let _ = writeln!(
            t,
            "{:>2}. {:<6} max {:>8.3} µm  RMS {:>8.3} µm",
            i + 1,
            x.error,
            x.max_um,
            x.rms_um
        );
    }
    t
}

fn default_campaign_structure() -> String {
    "XYFZ".into()
}
fn default_campaign_seed() -> u64 {
    1
}

/// The emulated machine's measurement campaign.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields)]
pub struct VolumetricCampaignRequest {
    /// The emulated machine's structure: FXYZ, XFYZ, XYFZ or XYZF.
    #[serde(default = "default_campaign_structure")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_campaign_structure()))]
    pub structure: String,
    /// The seed of the emulated machine's errors and the instruments' noise.
    #[serde(default = "default_campaign_seed")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_campaign_seed()))]
    pub seed: u64,
}

impl Default for VolumetricCampaignRequest {
    fn default() -> Self {
        Self {
            structure: default_campaign_structure(),
            seed: default_campaign_seed(),
        }
    }
}

impl VolumetricCampaignRequest {
    pub fn check(&self) -> Result<(), RequestError> {
        structure_of("structure", &self.structure).map(|_| ())
    }
}

/// `volumetric simulate-campaign`'s result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct VolumetricCampaignResult {
    /// The emulated machine's structure.
    pub structure: String,
    /// The seed of its errors and the instruments' noise.
    pub seed: u64,
    /// The campaign's files (artifacts), in [`CAMPAIGN_FILES`] order.
    pub files: Vec<String>,
}

/// The emulated machine's campaign (laser, level and ball-bar files, and the camera's
/// at several heights), one artifact per file.
pub fn simulate_campaign(
    request: &VolumetricCampaignRequest,
    sink: &mut dyn Sink,
) -> Outcome<VolumetricCampaignResult> {
    let structure = match structure_of("structure", &request.structure) {
        Ok(s) => s,
        Err(e) => return Outcome::failed(e.to_string()),
    };
    let machine = world::volumetric::VolumetricMachine::new(structure, request.seed);
    let mut files = machine.campaign(request.seed);
    let plan = world::volumetric::CameraPlan::default_for(machine.travel_mm);
    files.push((
        "camera.csv".into(),
        machine.camera_campaign(&plan, request.seed).0,
    ));
    let names: Vec<String> = files.iter().map(|f| f.0.clone()).collect();
    for (name, text) in files {
        if let Err(e) = sink.artifact(artifact(name, "text/csv", text.into_bytes())) {
            return Outcome::failed(e);
        }
    }
    Outcome::succeeded(
        VolumetricCampaignResult {
            structure: structure.name().into(),
            seed: request.seed,
            files: names,
        },
        Default::default(),
    )
}

/// The ISG kernel's (Beckhoff TF5280) files.
pub const ISG_FILES: [&str; 2] = ["volcomp.csv", "volcomp.lis"];

/// The model for the ISG kernel.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields)]
pub struct VolumetricExportIsgRequest {
    /// The model file's text (`gateway volumetric identify`'s).
    #[schema(format = Binary)]
    #[cfg_attr(feature = "cli", arg(skip))]
    pub model: String,
    /// How messages name the model (its file name).
    #[serde(default = "default_model_name")]
    #[schema(default = default_model_name)]
    #[cfg_attr(feature = "cli", arg(skip = default_model_name()))]
    pub model_name: String,
}

impl VolumetricExportIsgRequest {
    pub fn check(&self) -> Result<(), RequestError> {
        file_text("model", &self.model, true)
    }
}

/// `volumetric export-isg`'s result: the files and what their tables hold.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct VolumetricIsgResult {
    /// [`ISG_FILES`] (artifacts).
    pub files: Vec<String>,
    /// The model's structure.
    pub structure: String,
    /// Whether the model was fit for compensation when identified.
    pub fit_for_compensation: bool,
    /// Table positions along X.
    pub x_points: usize,
    pub y_points: usize,
    pub z_points: usize,
}

/// The model for the ISG kernel: `volcomp.csv` (blocks `C0Y B0Z A0Z P0X P0Y P0Z`,
/// `X EXX ... ECX`, ..., mm and rad) and the compensation list `volcomp.lis` naming it.
pub fn export_isg(
    request: &VolumetricExportIsgRequest,
    sink: &mut dyn Sink,
) -> Outcome<VolumetricIsgResult> {
    let model = &crate::or_fail!(read_model(&request.model_name, &request.model));
    let [csv, lis] = ISG_FILES;
    for a in [
        artifact(csv, "text/csv", write_isg_csv(&model.file).into_bytes()),
        artifact(
            lis,
            "text/plain",
            write_isg_lis(&model.file, csv).into_bytes(),
        ),
    ] {
        if let Err(e) = sink.artifact(a) {
            return Outcome::failed(e);
        }
    }
    // What the tables hold: the structure and each axis's positions.
    let f = &model.file;
    let points: Vec<usize> = f.tables.iter().map(|t| t.positions_mm.len()).collect();
    Outcome::succeeded(
        VolumetricIsgResult {
            files: ISG_FILES.map(String::from).to_vec(),
            structure: f.structure.name().into(),
            fit_for_compensation: f.fit,
            x_points: points[0],
            y_points: points[1],
            z_points: points[2],
        },
        Default::default(),
    )
}

/// `--model FILE`: the model's text and name.
const MODEL_FILE: FileArg = FileArg::required("model", "The model file.", |path, plan| {
    plan.text(path, "model", Some("model_name"), read_file)
});

/// `--campaign DIR`: each file a campaign may hold, when the folder has it.
fn campaign_folder(
    dir: &std::path::Path,
    plan: &mut command_line::Plan,
) -> Result<(), crate::Error> {
    for name in CAMPAIGN_FILES {
        let path = dir.join(name);
        if path.exists() {
            plan.text(&path, &field_of(name), None, read_file)?;
        }
    }
    plan.set("campaign_name", dir.display().to_string());
    Ok(())
}

/// Declares a registered kind for a file-to-file volumetric procedure.
macro_rules! volumetric_kind {
    ($name:ident, $request:ty, $result:ty, $kind:literal, $title:literal, $command:literal,
     $label:literal, $help:literal, |$r:ident, $sink:ident| $run:expr, $summary:expr,
     files: $files:expr, exit: $exit:expr) => {
        #[doc = concat!("`gateway ", $command, "` as a registered kind.")]
        pub struct $name;

        impl crate::registry::Procedure for $name {
            const KIND: &'static str = $kind;
            const TITLE: &'static str = $title;
            const COMMAND: &'static str = $command;
            const LABEL: &'static str = $label;
            const HELP: &'static str = $help;
            const USES: crate::registry::Uses = crate::registry::Uses::NOTHING;
            type Request = $request;
            type Result = $result;
            const FILES: &'static [FileArg] = $files;

            fn exit_code(result: &$result) -> u8 {
                $exit(result)
            }

            async fn run($r: $request, cx: &mut dyn crate::Context) -> Outcome<$result> {
                let $sink = cx.sink();
                $run
            }

            fn summary(result: &$result) -> String {
                $summary(result)
            }
        }

        impl crate::registry::Checked for $request {
            fn check(&self) -> Result<(), RequestError> {
                <$request>::check(self)
            }
        }
    };
}

volumetric_kind!(
    VolumetricIdentify,
    VolumetricIdentifyRequest,
    VolumetricIdentifyResult,
    "volumetric-identify",
    "Identify the 21-error volumetric model from a measurement campaign",
    "volumetric identify",
    "Volumetric model from a campaign",
    "Identifies the machine's 21 geometric errors (positioning, straightness, pitch, yaw, roll and squareness of each axis) from a measurement campaign: laser, level, ball bar and camera files. Says whether the model is fit for compensation.",
    |r, sink| identify(&r, sink),
    identify_summary,
    files: &[
        FileArg::required("campaign", "The campaign directory (laser_X.csv, level_X.csv, ..., ballbar_XY.csv ... or squareness.csv, camera.csv if measured).", campaign_folder),
        FileArg::required("out", "The model file.", |path, plan| {
            plan.artifacts.push((MODEL_ARTIFACT.into(), path.to_path_buf()));
            Ok(())
        }),
        FileArg::flag("plots", "Write the ball-bar plots (ballbar_XY.svg/.png, ...) into this directory.", |path, plan| {
            plan.set("plots", true);
            command_line::artifacts_folder(path, plan)
        }),
    ],
    // Identified but unfit for compensation: the shop must not apply it.
    exit: |r: &VolumetricIdentifyResult| if r.fit_for_compensation { 0 } else { 2 }
);
volumetric_kind!(
    VolumetricEval,
    VolumetricEvalRequest,
    VolumetricEvalResult,
    "volumetric-eval",
    "The volumetric error at each point of a points file",
    "volumetric eval",
    "Volumetric error at points",
    "Computes the machine's volumetric error at each point of a points file (X, Y, Z in mm) from its model.",
    |r, _sink| eval(&r),
    |r: &VolumetricEvalResult| eval_lines(r).collect::<Vec<_>>().join("\n"),
    files: &[MODEL_FILE, FileArg::required("points", "The points (`x_mm,y_mm,z_mm`).", |path, plan| {
        plan.text(path, "points", Some("points_name"), read_file)
    })],
    exit: |_| 0
);
volumetric_kind!(
    VolumetricContributions,
    VolumetricContributionsRequest,
    VolumetricContributionsResult,
    "volumetric-contributions",
    "Each volumetric error's contribution over the volume, and the middle planes' maps",
    "volumetric contributions",
    "Volumetric error contributions",
    "Ranks each of the 21 errors by its share of the volumetric error over the working volume, and maps the error on the three middle planes.",
    |r, sink| contributions(&r, sink),
    contributions_summary,
    files: &[MODEL_FILE, FileArg::required("out", "The output folder.", command_line::artifacts_folder)],
    exit: |_| 0
);
volumetric_kind!(
    VolumetricCampaign,
    VolumetricCampaignRequest,
    VolumetricCampaignResult,
    "volumetric-campaign",
    "The emulated machine's measurement campaign (laser, level, ball bar, camera files)",
    "volumetric simulate-campaign",
    "Simulated volumetric campaign",
    "Writes the measurement files the emulated machine would give (laser, level, ball bar, camera), to try the volumetric identification without a machine.",
    |r, sink| simulate_campaign(&r, sink),
    campaign_summary,
    files: &[FileArg::required("out", "The output folder.", command_line::artifacts_folder)],
    exit: |_| 0
);
volumetric_kind!(
    VolumetricExportIsg,
    VolumetricExportIsgRequest,
    VolumetricIsgResult,
    "volumetric-export-isg",
    "Export the volumetric model as the ISG kernel's tables (Beckhoff TF5280)",
    "volumetric export-isg",
    "Volumetric tables for the ISG kernel",
    "Writes the volumetric model as the ISG kernel's compensation tables (Beckhoff TwinCAT CNC, TF5280) and the list that names them.",
    |r, sink| export_isg(&r, sink),
    |r: &VolumetricIsgResult| r.files.join(", "),
    files: &[MODEL_FILE, FileArg::required("out", "The output folder.", command_line::artifacts_folder)],
    exit: |_| 0
);

/// The simulated campaign as text.
pub fn campaign_summary(r: &VolumetricCampaignResult) -> String {
    format!(
        "{} campaign (seed {}): {}",
        r.structure,
        r.seed,
        r.files.join(", ")
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Discard;

    use crate::Collect as Keep;

    fn zero_model() -> Model {
        let mut m = Model::zero(Structure::Xyfz, [500.0, 400.0, 400.0]);
        m.file.tables[0].errors[1][0] = 0.010;
        m
    }

    fn contributions_of(grid: u64) -> VolumetricContributionsRequest {
        VolumetricContributionsRequest {
            model: write_model(&zero_model().file),
            grid,
            ..Default::default()
        }
    }

    fn identify_request(structure: &str) -> VolumetricIdentifyRequest {
        serde_json::from_value(serde_json::json!({ "structure": structure })).unwrap()
    }

    #[test]
    fn a_grid_past_the_memory_cap_is_refused_naming_the_field() {
        let e = contributions_of(1000).check().unwrap_err();
        assert_eq!(e.field, "grid");
        assert!(e.for_cli().starts_with("--grid: "), "{e}");
        assert!(e.message.contains("at most 219"), "{e}");
        contributions_of(219).check().unwrap();
        assert_eq!(contributions_of(1).check().unwrap_err().field, "grid");
        assert_eq!(
            contributions_of(u64::MAX).check().unwrap_err().field,
            "grid"
        );
        // Refused by the procedure too, before anything is computed.
        let out = contributions(&contributions_of(1000), &mut Discard);
        assert!(out.error().unwrap().starts_with("grid: "));
    }

    #[test]
    fn bad_structures_offsets_and_too_many_points_are_named() {
        let mut r = identify_request("XZFY");
        let e = r.check().unwrap_err();
        assert_eq!(
            e.for_cli(),
            "--structure: `XZFY`: expected FXYZ, XFYZ, XYFZ or XYZF"
        );
        r.structure = "xyfz".into();
        r.tool_offset_mm[2] = f64::NAN;
        assert_eq!(r.check().unwrap_err().field, "tool_offset_mm[2]");
        let parsed: Result<VolumetricCampaignRequest, _> =
            serde_json::from_value(serde_json::json!({"structure": "XYFZ", "seeds": 2}));
        assert!(parsed.is_err());
        let mut text = String::from("x_mm,y_mm,z_mm\n");
        for _ in 0..=MAX_EVAL_POINTS {
            text.push_str("1,1,1\n");
        }
        let e = VolumetricEvalRequest::default()
            .check_points(&text)
            .unwrap_err();
        assert_eq!(e.field, "points");
        // Files are the request's: a missing one is named, an oversized one refused.
        let e = VolumetricEvalRequest::default().check().unwrap_err();
        assert_eq!(e.field, "model");
        let mut r = identify_request("XYFZ");
        *r.file_mut("ballbar_XZ.csv").unwrap() = Some("x".repeat(MAX_FILE_BYTES + 1));
        assert_eq!(r.check().unwrap_err().field, "ballbar_xz");
    }

    #[test]
    fn a_campaign_identified_evaluated_and_exported() {
        let mut sink = Keep::default();
        let out = simulate_campaign(
            &VolumetricCampaignRequest {
                structure: "XFYZ".into(),
                seed: 9,
            },
            &mut sink,
        );
        assert!(out.is_success(), "{:?}", out.error());
        let files: Vec<(String, String)> = sink
            .0
            .iter()
            .map(|a| (a.name.clone(), String::from_utf8(a.bytes.clone()).unwrap()))
            .collect();
        assert!(files.iter().any(|f| f.0 == "ballbar_XY.csv"));
        let mut request = identify_request("XFYZ");
        request.tool_offset_mm = [0.0, 0.0, 50.0];
        request.plots = true;
        let empty = request.clone();
        for (name, text) in files {
            *request.file_mut(&name).unwrap() = Some(text);
        }
        let mut sink = Keep::default();
        let out = identify(&request, &mut sink);
        assert!(out.is_success(), "{:?}", out.error());
        let r = out.result.unwrap();
        assert!(r.fit_for_compensation);
        assert_eq!(r.errors.len(), 21);
        // The stored result reads back; an unfit model is the command's exit code 2.
        let kind = crate::kinds::find("volumetric-identify").unwrap();
        let stored = serde_json::to_value(&r).unwrap();
        assert_eq!(kind.exit_code(&stored), 0);
        assert_eq!(kind.summary(&stored), identify_summary(&r));
        let unfit = VolumetricIdentifyResult {
            fit_for_compensation: false,
            ..r.clone()
        };
        assert_eq!(kind.exit_code(&serde_json::to_value(&unfit).unwrap()), 2);
        let names: Vec<&str> = sink.0.iter().map(|a| a.name.as_str()).collect();
        assert_eq!(names[0], MODEL_ARTIFACT);
        assert!(names.contains(&"ballbar_XZ.png"), "{names:?}");
        assert!(identify_summary(&r).contains("ball bar XY"));
        let text = String::from_utf8(sink.0[0].bytes.clone()).unwrap();
        let model = read_model("m", &text).unwrap();
        assert_eq!(model.file.tool_offset_mm, [0.0, 0.0, 50.0]);
        let points = |p: &str| VolumetricEvalRequest {
            model: text.clone(),
            points: p.into(),
            points_name: "p.csv".into(),
            ..Default::default()
        };
        let out = eval(&points("x_mm,y_mm,z_mm\n0,0,0\n250,200,100\n"));
        let r = out.result.unwrap();
        assert_eq!(r.points.len(), 2);
        assert_eq!(eval_lines(&r).count(), 3);
        let out = eval(&points("x_mm,y_mm,z_mm\n0,0,0\n1e6,0,0\n"));
        assert!(out.error().unwrap().starts_with("p.csv: point 2 (line 3)"));
        let mut sink = Keep::default();
        let export = VolumetricExportIsgRequest {
            model: text.clone(),
            ..Default::default()
        };
        assert!(export_isg(&export, &mut sink).is_success());
        assert_eq!(sink.0.len(), 2);
        // A campaign without its files names what is missing.
        let out = identify(&empty, &mut Discard);
        assert!(
            out.error().unwrap().starts_with("campaign/"),
            "{:?}",
            out.error()
        );
    }

    #[test]
    fn contributions_of_a_small_grid() {
        let mut sink = Keep::default();
        let out = contributions(&contributions_of(5), &mut sink);
        let r = out.result.unwrap();
        assert_eq!(r.contributions[0].error, "E_XX");
        assert!((r.total_max_um - 10.0).abs() < 1e-9);
        assert_eq!(sink.0.len(), 12);
        let csv = &sink
            .0
            .iter()
            .find(|a| a.name == "map_XY.csv")
            .unwrap()
            .bytes;
        assert_eq!(csv.iter().filter(|b| **b == b'\n').count(), 26);
        assert!(contributions_summary(&r).contains("over a 5³ grid"));
    }
}

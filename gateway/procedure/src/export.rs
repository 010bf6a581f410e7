//! The error map as a controller's own compensation table: LinuxCNC (a `COMP_FILE` per
//! joint), Beckhoff/ISG (a plane compensation list per axis over X and Y) or a plain CSV
//! of the model on the map's grid. Each table says what its format cannot hold, and a
//! table further from the map than the tolerance is refused.
//!
//! All or nothing: every table is computed and checked against the tolerance before the
//! first is handed to the sink, so a refused export leaves no new `_x` table beside a
//! stale `_y`.

use crate::command_line::{self, FileArg};
use crate::request::{count, number, RequestError};
use crate::{Artifact, Outcome, Sink};
use errormap::export::{
    beckhoff_plane, controller::ControllerTables, fanuc_pitch, haas, heidenhain, heidenhain_64,
    heidenhain_com, linuxcnc_joint, plain_csv, siemens, CecMultiplier, FanucOptions, FanucSection,
    SiemensOptions, TvCheck, ValueSign, LINUXCNC_MAX_ENTRIES,
};
use errormap::MapModel;
use protocol::errormap::ErrorMap;
use serde::{Deserialize, Serialize};
use std::fmt::Write;

/// The memory an export may ask for (see [`ExportRequest::check_map`]).
pub const MAX_EXPORT_BYTES: u64 = 256 << 20;

/// Bytes per point of a Beckhoff table while it is built: its line of text (about 50
/// bytes) and its value in the grid, both tables held until both are checked.
const BECKHOFF_BYTES_PER_POINT: u64 = 2 * 64;

/// The controller's format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum ExportFormat {
    Linuxcnc,
    Beckhoff,
    Csv,
    #[serde(rename = "siemens-eec")]
    SiemensEec,
    #[serde(rename = "siemens-cec")]
    SiemensCec,
    #[serde(rename = "fanuc-pitch")]
    FanucPitch,
    Heidenhain,
    #[serde(rename = "heidenhain-64")]
    #[cfg_attr(feature = "cli", value(name = "heidenhain-64"))]
    Heidenhain64,
    Haas,
}

impl ExportFormat {
    pub const ALL: [ExportFormat; 9] = [
        ExportFormat::Linuxcnc,
        ExportFormat::Beckhoff,
        ExportFormat::Csv,
        ExportFormat::SiemensEec,
        ExportFormat::SiemensCec,
        ExportFormat::FanucPitch,
        ExportFormat::Heidenhain,
        ExportFormat::Heidenhain64,
        ExportFormat::Haas,
    ];

    pub fn parse(text: &str) -> Result<ExportFormat, RequestError> {
        Self::ALL
            .into_iter()
            .find(|f| f.as_str() == text)
            .ok_or_else(|| {
                let names: Vec<&str> = Self::ALL.iter().map(|f| f.as_str()).collect();
                RequestError::new("format", format!("`{text}`: {}", names.join(", ")))
            })
    }

    pub fn as_str(self) -> &'static str {
        match self {
            ExportFormat::Linuxcnc => "linuxcnc",
            ExportFormat::Beckhoff => "beckhoff",
            ExportFormat::Csv => "csv",
            ExportFormat::SiemensEec => "siemens-eec",
            ExportFormat::SiemensCec => "siemens-cec",
            ExportFormat::FanucPitch => "fanuc-pitch",
            ExportFormat::Heidenhain => "heidenhain",
            ExportFormat::Heidenhain64 => "heidenhain-64",
            ExportFormat::Haas => "haas",
        }
    }
}

fn default_siemens_axes() -> String {
    "X1,Y1".into()
}
fn default_cec_tables() -> u64 {
    8
}
fn default_fanuc_unit() -> f64 {
    1.0
}
fn default_one() -> u32 {
    1
}
fn default_fanuc_max_increment() -> u32 {
    127
}
fn default_fanuc_record_base() -> u32 {
    10000
}

/// The options of the industrial controllers' tables: their limits as set on the
/// machine, and what their manuals leave open, each with the default docs/error-map.md
/// states.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields)]
pub struct ControllerOptions {
    /// Points per table: Siemens MD38000/MD18342 (default 200, the 828D's), Fanuc
    /// compensation points per axis (default 128), Heidenhain .COM entries (default 256).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long))]
    pub points: Option<u64>,
    /// Siemens machine axis names of X and Y.
    #[serde(default = "default_siemens_axes")]
    #[cfg_attr(feature = "cli", arg(long, default_value = "X1,Y1"))]
    pub siemens_axes: String,
    /// Siemens CEC tables available (828D: 8).
    #[serde(default = "default_cec_tables")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 8))]
    pub cec_tables: u64,
    /// Siemens CEC products of two tables: off, own-output-added or own-output-not-added
    /// (whether the multiplier table also adds its own output: open in the manual).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, default_value = "off"))]
    pub cec_multiplier: CecMultiplier,
    /// Fanuc: the unit of a value and of the interval 3624, um (open in the manuals).
    #[serde(default = "default_fanuc_unit")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 1.0))]
    pub fanuc_unit_um: f64,
    /// Fanuc: step-ending, step-starting or ramp (which section a point covers: open).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, default_value = "step-ending"))]
    pub fanuc_section: FanucSection,
    /// Fanuc: the magnification 3623.
    #[serde(default = "default_one")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 1))]
    pub fanuc_magnification: u32,
    /// Fanuc: the largest value of one point, units (open in the manuals).
    #[serde(default = "default_fanuc_max_increment")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 127))]
    pub fanuc_max_increment: u32,
    /// Fanuc: pitch data of point n as record N(base + n) (open in the manuals).
    #[serde(default = "default_fanuc_record_base")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 10000))]
    pub fanuc_record_base: u32,
    /// Fanuc TV check padding: off, without-eob or with-eob.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, default_value = "without-eob"))]
    pub fanuc_tv_check: TvCheck,
    /// Fanuc, Heidenhain, Haas: correction (minus the error) or error (open in the
    /// manuals; Siemens's is fixed: the error).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, default_value = "correction"))]
    pub value_sign: ValueSign,
    /// Haas: encoder steps per inch of X and Y (Parameters 5 and 19), to check the
    /// +-127 steps a value may hold; unchecked (and said so) without.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, value_delimiter = ','))]
    pub haas_steps_per_inch: Vec<f64>,
}

impl Default for ControllerOptions {
    fn default() -> Self {
        Self {
            points: None,
            siemens_axes: default_siemens_axes(),
            cec_tables: default_cec_tables(),
            cec_multiplier: CecMultiplier::default(),
            fanuc_unit_um: default_fanuc_unit(),
            fanuc_section: FanucSection::default(),
            fanuc_magnification: default_one(),
            fanuc_max_increment: default_fanuc_max_increment(),
            fanuc_record_base: default_fanuc_record_base(),
            fanuc_tv_check: TvCheck::default(),
            value_sign: ValueSign::default(),
            haas_steps_per_inch: Vec::new(),
        }
    }
}

impl ControllerOptions {
    pub fn check(&self) -> Result<(), RequestError> {
        if let Some(p) = self.points {
            count("points", p, 2, 100_000)?;
        }
        let axes: Vec<&str> = self.siemens_axes.split(',').collect();
        if axes.len() != 2 {
            return Err(RequestError::new(
                "siemens_axes",
                format!("{:?}: the names of X and Y, as X1,Y1", self.siemens_axes),
            ));
        }
        count("cec_tables", self.cec_tables, 0, 64)?;
        number("fanuc_unit_um", self.fanuc_unit_um, 0.001, 100.0)?;
        count(
            "fanuc_magnification",
            self.fanuc_magnification.into(),
            1,
            100,
        )?;
        count(
            "fanuc_max_increment",
            self.fanuc_max_increment.into(),
            1,
            99_999,
        )?;
        count(
            "fanuc_record_base",
            self.fanuc_record_base.into(),
            1,
            90_000,
        )?;
        match self.haas_steps_per_inch[..] {
            [] => Ok(()),
            [x, y] => {
                number("haas_steps_per_inch", x, 1.0, 1e7)?;
                number("haas_steps_per_inch", y, 1.0, 1e7)
            }
            _ => Err(RequestError::new(
                "haas_steps_per_inch",
                "the steps per inch of X and Y, as 138718,138718",
            )),
        }
    }

    fn siemens(&self, cec: bool) -> SiemensOptions {
        let mut axes = self.siemens_axes.split(',').map(|s| s.trim().to_string());
        let d = SiemensOptions::default();
        SiemensOptions {
            axes: [
                axes.next().unwrap_or(d.axes[0].clone()),
                axes.next().unwrap_or(d.axes[1].clone()),
            ],
            points: self.points.map_or(d.points, |p| p as usize),
            cec_tables: if cec { self.cec_tables as usize } else { 0 },
            multiplier: self.cec_multiplier,
        }
    }

    fn fanuc(&self) -> FanucOptions {
        let d = FanucOptions::default();
        FanucOptions {
            unit_um: self.fanuc_unit_um,
            sign: self.value_sign,
            section: self.fanuc_section,
            magnification: self.fanuc_magnification,
            max_increment: self.fanuc_max_increment,
            points: self.points.map_or(d.points, |p| p as usize),
            record_base: self.fanuc_record_base,
            tv_check: self.fanuc_tv_check,
        }
    }
}

fn default_name() -> String {
    "table".into()
}
fn default_tolerance() -> f64 {
    1.0
}
fn default_entries() -> u64 {
    LINUXCNC_MAX_ENTRIES as u64
}
fn default_interval() -> f64 {
    1.0
}

/// An export of the error map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields)]
pub struct ExportRequest {
    /// The controller's table format.
    #[cfg_attr(feature = "cli", arg(long, value_enum))]
    #[schema(inline)]
    pub format: ExportFormat,
    /// The table's file name; the per-axis formats add `_x`/`_y` before its extension
    /// (on the command line, the name of `--out`).
    #[serde(default = "default_name")]
    #[cfg_attr(feature = "cli", arg(skip = default_name()))]
    #[schema(default = default_name)]
    pub name: String,
    /// The largest difference accepted between a table and the map, um.
    #[serde(default = "default_tolerance")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_tolerance()))]
    #[schema(default = default_tolerance, minimum = 0.001, maximum = 1000.0)]
    pub tolerance_um: f64,
    /// LinuxCNC entries per joint (2..256).
    #[serde(default = "default_entries")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_entries()))]
    #[schema(default = default_entries, minimum = 2, maximum = 256)]
    pub entries: u64,
    /// Beckhoff grid interval, mm.
    #[serde(default = "default_interval")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_interval()))]
    #[schema(default = default_interval, minimum = 0.1, maximum = 10000.0)]
    pub interval_mm: f64,
    /// The industrial controllers' options (siemens-*, fanuc-pitch, heidenhain*, haas).
    #[serde(default)]
    #[cfg_attr(feature = "cli", command(flatten))]
    #[schema(value_type = Object)]
    pub controller: ControllerOptions,
}

impl ExportRequest {
    pub fn new(format: ExportFormat) -> Self {
        Self {
            format,
            name: default_name(),
            tolerance_um: default_tolerance(),
            entries: default_entries(),
            interval_mm: default_interval(),
            controller: ControllerOptions::default(),
        }
    }

    pub fn check(&self) -> Result<(), RequestError> {
        let n = &self.name;
        if n.is_empty() || n.len() > 255 || n == "." || n == ".." || n.contains(['/', '\\', '\0']) {
            return Err(RequestError::new(
                "name",
                format!("{n:?}: a plain file name of 1 to 255 bytes"),
            ));
        }
        number("tolerance_um", self.tolerance_um, 1e-3, 1e3)?;
        count("entries", self.entries, 2, LINUXCNC_MAX_ENTRIES as u64)?;
        number("interval_mm", self.interval_mm, 0.1, 1e4)?;
        self.controller.check()
    }

    /// The artifacts the export produces, in order: `NAME_x`, `NAME_y` (the extension
    /// kept) for the per-axis formats, `NAME` for the CSV.
    pub fn artifact_names(&self) -> Vec<String> {
        let axes = || ["x", "y"].iter().map(|axis| per_axis(&self.name, axis));
        match self.format {
            ExportFormat::Csv | ExportFormat::FanucPitch => vec![self.name.clone()],
            ExportFormat::SiemensCec => axes().chain([per_axis(&self.name, "cec")]).collect(),
            ExportFormat::Heidenhain => heidenhain::com_file_names(&self.stem()).to_vec(),
            _ => axes().collect(),
        }
    }

    /// The name without its extension (the Heidenhain tables' stem).
    fn stem(&self) -> String {
        match self.name.rsplit_once('.') {
            Some((stem, _)) if !stem.is_empty() => stem.to_string(),
            _ => self.name.clone(),
        }
    }

    /// The memory the tables of this map would take, estimated from the map's extent
    /// before any is built, refused past [`MAX_EXPORT_BYTES`]: a Beckhoff table has a
    /// point every `interval_mm` over the map (named when too fine); a LinuxCNC joint is
    /// checked every 0.05 mm of the map and a CSV has a row per node (`map` named when
    /// the map itself is too large).
    pub fn check_map(&self, map: &ErrorMap) -> Result<u64, RequestError> {
        let g = &map.grid;
        let (lo, hi) = ([g.xs.first(), g.ys.first()], [g.xs.last(), g.ys.last()]);
        let span = |k: usize| match (lo[k], hi[k]) {
            (Some(a), Some(b)) => (b - a).max(0.0),
            _ => 0.0,
        };
        let (field, bytes) = match self.format {
            ExportFormat::Beckhoff => {
                let points: f64 = (0..2)
                    .map(|k| (span(k) / self.interval_mm).floor() + 1.0)
                    .product();
                ("interval_mm", points * BECKHOFF_BYTES_PER_POINT as f64)
            }
            ExportFormat::Linuxcnc => ("map", (span(0).max(span(1)) / 0.05 + 2.0) * 8.0),
            ExportFormat::Csv => ("map", (g.xs.len() * g.ys.len()) as f64 * 100.0),
            // A few tables of at most `points` lines, and the check on a grid of at most
            // 2000 x 2000 points evaluated one at a time.
            _ => {
                let points = self.controller.points.unwrap_or(256) as f64;
                // Products of CEC tables fit the residual at every pair of points.
                let products = self.format == ExportFormat::SiemensCec
                    && self.controller.cec_multiplier != CecMultiplier::Off;
                let pairs = if products { points * points * 8.0 } else { 0.0 };
                ("points", points * 10.0 * 64.0 + pairs)
            }
        };
        if !(bytes <= MAX_EXPORT_BYTES as f64) {
            return Err(RequestError::new(
                field,
                format!(
                    "the {} tables of this {:.1} x {:.1} mm map would take about {:.0} MiB; at most {} MiB are accepted{}",
                    self.format.as_str(),
                    span(0),
                    span(1),
                    bytes / (1u64 << 20) as f64,
                    MAX_EXPORT_BYTES >> 20,
                    if field == "interval_mm" { " (a coarser interval)" } else { "" }
                ),
            ));
        }
        Ok(bytes as u64)
    }
}

/// `NAME` with `_x`/`_y` before its extension.
pub fn per_axis(name: &str, axis: &str) -> String {
    match name.rsplit_once('.') {
        Some((stem, ext)) if !stem.is_empty() => format!("{stem}_{axis}.{ext}"),
        _ => format!("{name}_{axis}"),
    }
}

/// A LinuxCNC joint's `COMP_FILE`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct LinuxcncTable {
    /// The table (the artifact; the CLI: the path it wrote).
    pub file: String,
    /// The joint: 0 (X) or 1 (Y).
    pub joint: usize,
    pub entries: usize,
    /// The other axis's position the table was taken at.
    pub taken_at_mm: f64,
    /// The table's largest distance from the map along its line.
    pub interpolation_error_um: f64,
    /// The joint's error that depends on the other axis, which a joint's table cannot hold.
    pub cross_terms_not_held_um: f64,
}

/// A Beckhoff/ISG plane compensation list of one axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct BeckhoffTable {
    /// The table (the artifact; the CLI: the path it wrote).
    pub file: String,
    /// `x` or `y`.
    pub axis: String,
    pub points: usize,
    /// The table's largest distance from the map.
    pub interpolation_error_um: f64,
    /// The backlash one table for both directions cannot hold.
    pub backlash_not_held_um: f64,
}

/// A file of an industrial controller's tables.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct TableFile {
    /// The artifact (the CLI: the path it wrote).
    pub file: String,
}

/// What the controller's tables leave of the map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Residual {
    /// The map's error less the tables', largest and RMS over the map's grid.
    pub max_um: f64,
    pub rms_um: f64,
    /// The share of the map's error the tables express (0..1).
    pub share: f64,
    /// The map's own error, largest and RMS.
    pub map_max_um: f64,
    pub map_rms_um: f64,
    /// Where the residual is largest (X, Y).
    pub worst_at_mm: [f64; 2],
}

/// The tables of an industrial controller (Siemens, Fanuc, Heidenhain, Haas).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ControllerResult {
    /// The files, in the artifacts' order.
    #[schema(inline)]
    pub tables: Vec<TableFile>,
    /// What was chosen for each table (points, spacing, reference), one line each.
    pub chosen: Vec<String>,
    /// The machine data to set on the control, one line each.
    pub settings: Vec<String>,
    #[schema(inline)]
    pub residual: Residual,
    /// The map's error (X, Y) at the control's zero, which its tables hold as 0.
    pub zero_not_held_um: [f64; 2],
}

/// `export`'s result, by format (`format` names it).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(tag = "format")]
pub enum ExportResult {
    /// A `COMP_FILE` per joint.
    #[serde(rename = "linuxcnc")]
    Linuxcnc {
        #[schema(inline)]
        tables: Vec<LinuxcncTable>,
    },
    /// A plane compensation list per axis over X and Y.
    #[serde(rename = "beckhoff")]
    Beckhoff {
        /// The grid interval.
        interval_mm: f64,
        #[schema(inline)]
        tables: Vec<BeckhoffTable>,
    },
    /// The model at every node of the map's grid.
    #[serde(rename = "csv")]
    Csv {
        /// The file (the artifact; the CLI: the path it wrote).
        file: String,
        rows: usize,
    },
    #[serde(rename = "siemens-eec")]
    SiemensEec(#[schema(inline)] ControllerResult),
    #[serde(rename = "siemens-cec")]
    SiemensCec(#[schema(inline)] ControllerResult),
    #[serde(rename = "fanuc-pitch")]
    FanucPitch(#[schema(inline)] ControllerResult),
    #[serde(rename = "heidenhain")]
    Heidenhain(#[schema(inline)] ControllerResult),
    #[serde(rename = "heidenhain-64")]
    Heidenhain64(#[schema(inline)] ControllerResult),
    #[serde(rename = "haas")]
    Haas(#[schema(inline)] ControllerResult),
}

/// Builds every table, checks each against the tolerance, and only then hands them to
/// the sink ([`ExportRequest::artifact_names`]). The result: `format` and `tables`
/// (per table: `file` (the artifact), the figures, what the format does not hold) or,
/// for the CSV, `file` and `rows`.
pub fn run(request: &ExportRequest, map: ErrorMap, sink: &mut dyn Sink) -> Outcome<ExportResult> {
    if let Err(e) = request.check() {
        return Outcome::failed(e.to_string());
    }
    if let Err(e) = request.check_map(&map) {
        return Outcome::failed(e.to_string());
    }
    let model = MapModel::new(map);
    let names = request.artifact_names();
    let tolerance = request.tolerance_um;
    let mut texts = Vec::new();
    let result = match request.format {
        ExportFormat::Linuxcnc => {
            let mut joints = Vec::new();
            for (axis, file) in names.iter().enumerate() {
                let t = match linuxcnc_joint(&model, axis, request.entries as usize, tolerance) {
                    Ok(t) => t,
                    Err(e) => return Outcome::failed(e.to_string()),
                };
                joints.push(LinuxcncTable {
                    file: file.clone(),
                    joint: axis,
                    entries: t.entries,
                    taken_at_mm: t.taken_at_mm,
                    interpolation_error_um: t.interpolation_error_um,
                    cross_terms_not_held_um: t.cross_terms_um,
                });
                texts.push(t.text);
            }
            ExportResult::Linuxcnc { tables: joints }
        }
        ExportFormat::Beckhoff => {
            let mut tables = Vec::new();
            for (axis, file) in names.iter().enumerate() {
                let t = match beckhoff_plane(&model, axis, request.interval_mm, tolerance) {
                    Ok(t) => t,
                    Err(e) => return Outcome::failed(e.to_string()),
                };
                tables.push(BeckhoffTable {
                    file: file.clone(),
                    axis: ["x", "y"][axis].into(),
                    points: t.points,
                    interpolation_error_um: t.interpolation_error_um,
                    backlash_not_held_um: t.backlash_lost_um,
                });
                texts.push(t.text);
            }
            ExportResult::Beckhoff {
                interval_mm: request.interval_mm,
                tables,
            }
        }
        ExportFormat::Csv => {
            let text = match plain_csv(&model) {
                Ok(t) => t,
                Err(e) => return Outcome::failed(e.to_string()),
            };
            let rows = text.lines().count().saturating_sub(1);
            texts.push(text);
            ExportResult::Csv {
                file: names[0].clone(),
                rows,
            }
        }
        f => {
            let tables = match controller_tables(request, &model) {
                Ok(t) => t,
                Err(e) => return Outcome::failed(e),
            };
            let result = controller_result(f, &names, &tables);
            texts = tables.files.into_iter().map(|(_, text)| text).collect();
            result
        }
    };
    // Every table is within the tolerance: now they are handed over.
    for (name, text) in names.into_iter().zip(texts) {
        let media_type = if request.format == ExportFormat::Csv {
            "text/csv"
        } else {
            "text/plain"
        };
        if let Err(e) = sink.artifact(Artifact {
            name,
            title: None,
            media_type,
            bytes: text.into_bytes(),
        }) {
            return Outcome::failed(e);
        }
    }
    Outcome::succeeded(result, Default::default())
}

/// The tables of an industrial controller's format, in the order of the artifacts.
fn controller_tables(
    request: &ExportRequest,
    model: &MapModel,
) -> Result<ControllerTables, crate::Error> {
    let c = &request.controller;
    let sign = c.value_sign;
    let out = match request.format {
        ExportFormat::SiemensEec => siemens(model, &c.siemens(false), false),
        ExportFormat::SiemensCec => siemens(model, &c.siemens(true), true),
        ExportFormat::FanucPitch => fanuc_pitch(model, &c.fanuc()),
        ExportFormat::Heidenhain => heidenhain_com(
            model,
            &request.stem(),
            c.points
                .map_or(heidenhain::HEIDENHAIN_COM_MAX_ENTRIES, |p| p as usize),
            sign,
        ),
        ExportFormat::Heidenhain64 => heidenhain_64(model, sign),
        ExportFormat::Haas => haas(
            model,
            sign,
            match c.haas_steps_per_inch[..] {
                [x, y] => Some([x, y]),
                _ => None,
            },
        ),
        other => unreachable!("{} is not a controller's own table", other.as_str()),
    };
    out.map_err(|e| crate::Error::Refused(e.to_string()))
}

fn controller_result(format: ExportFormat, names: &[String], t: &ControllerTables) -> ExportResult {
    let f = &t.fit;
    let result = ControllerResult {
        tables: (names.iter())
            .map(|n| TableFile { file: n.clone() })
            .collect(),
        chosen: t.tables.clone(),
        settings: t.settings.clone(),
        residual: Residual {
            max_um: f.max_um,
            rms_um: f.rms_um,
            share: f.share,
            map_max_um: f.map_max_um,
            map_rms_um: f.map_rms_um,
            worst_at_mm: f.worst_at_mm,
        },
        zero_not_held_um: t.zero_not_held_um,
    };
    match format {
        ExportFormat::SiemensEec => ExportResult::SiemensEec(result),
        ExportFormat::SiemensCec => ExportResult::SiemensCec(result),
        ExportFormat::FanucPitch => ExportResult::FanucPitch(result),
        ExportFormat::Heidenhain => ExportResult::Heidenhain(result),
        ExportFormat::Heidenhain64 => ExportResult::Heidenhain64(result),
        ExportFormat::Haas => ExportResult::Haas(result),
        other => unreachable!("{} is not a controller's own table", other.as_str()),
    }
}

/// The export of the error map as a registered procedure.
pub struct Export;

impl crate::registry::Procedure for Export {
    const KIND: &'static str = "export";
    const TITLE: &'static str = "Export the error map as the controller's own compensation tables";
    const COMMAND: &'static str = "export";
    const LABEL: &'static str = "Controller tables";
    const HELP: &'static str = "Writes the active error map as the controller's own compensation tables (LinuxCNC, Beckhoff, Siemens, Fanuc, Heidenhain, Haas or CSV), so that every program, jog and probing cycle is corrected inside the control. Each table says what its format cannot hold; none is handed over when one is further from the map than the tolerance.";
    const FIELD_HELP: &'static [(&'static str, &'static str)] = &[(
        "name",
        "The table's file name; per-axis formats add _x and _y before its extension.",
    )];
    const USES: crate::registry::Uses = crate::registry::Uses::MAP;
    type Request = ExportRequest;
    type Result = ExportResult;
    const FILES: &'static [FileArg] = &[
        FileArg::required("map", "The error map to export.", command_line::map),
        FileArg::required(
            "out",
            "Output file (`_x`/`_y` are added for the per-axis formats).",
            |path, plan| {
                // The tables are named after --out and written beside it.
                let name = path.file_name().ok_or_else(|| {
                    crate::Error::Input(format!("--out {}: must name a file", path.display()))
                })?;
                plan.set("name", name.to_string_lossy().into_owned());
                let beside = path.parent().filter(|p| !p.as_os_str().is_empty());
                command_line::artifacts_folder(beside.unwrap_or(std::path::Path::new(".")), plan)
            },
        ),
    ];

    async fn run(request: ExportRequest, cx: &mut dyn crate::Context) -> Outcome<ExportResult> {
        let active = crate::or_fail!(cx.map());
        run(&request, active.map, cx.sink())
    }

    fn summary(result: &ExportResult) -> String {
        summary(result)
    }
}

impl crate::registry::Checked for ExportRequest {
    fn check(&self) -> Result<(), RequestError> {
        ExportRequest::check(self)
    }
}

/// The export as text, one line per table (its `file` as the front end left it).
pub fn summary(r: &ExportResult) -> String {
    let mut t = String::new();
    let (format, c) = match r {
        ExportResult::Linuxcnc { tables } => {
            for j in tables {
                let axis = j.joint;
                let (name, other) = if axis == 0 { ("X", "Y") } else { ("Y", "X") };
                let _ = writeln!(
                    t,
                    "{}: joint {name} ([JOINT_{axis}] COMP_FILE = {}, COMP_FILE_TYPE = 0), {} entries taken at {other} = {:.3} mm; interpolation {:.2} um from the map; not held: {:.2} um of its error that depends on {other}",
                    j.file, j.file, j.entries, j.taken_at_mm,
                    j.interpolation_error_um, j.cross_terms_not_held_um,
                );
            }
            return t;
        }
        ExportResult::Beckhoff {
            interval_mm,
            tables,
        } => {
            for p in tables {
                let _ = writeln!(
                    t,
                    "{}: plane compensation of {} over X and Y, {} points every {interval_mm} mm; interpolation {:.2} um from the map; not held: {:.2} um of backlash (one table for both directions)",
                    p.file, p.axis.to_uppercase(), p.points,
                    p.interpolation_error_um, p.backlash_not_held_um,
                );
            }
            return t;
        }
        ExportResult::Csv { file, .. } => {
            let _ = writeln!(
                t,
                "{file}: the model at every node of the map's grid, both directions"
            );
            return t;
        }
        ExportResult::SiemensEec(c) => (ExportFormat::SiemensEec, c),
        ExportResult::SiemensCec(c) => (ExportFormat::SiemensCec, c),
        ExportResult::FanucPitch(c) => (ExportFormat::FanucPitch, c),
        ExportResult::Heidenhain(c) => (ExportFormat::Heidenhain, c),
        ExportResult::Heidenhain64(c) => (ExportFormat::Heidenhain64, c),
        ExportResult::Haas(c) => (ExportFormat::Haas, c),
    };
    let files: Vec<&str> = c.tables.iter().map(|f| f.file.as_str()).collect();
    let _ = writeln!(t, "{}: {}", format.as_str(), files.join(", "));
    for line in &c.chosen {
        let _ = writeln!(t, "  {line}");
    }
    for s in &c.settings {
        let _ = writeln!(t, "  set: {s}");
    }
    let f = &c.residual;
    let _ = writeln!(
        t,
        "  left of the map: max {:.2} um, rms {:.2} um (the map: max {:.2}, rms {:.2} um); the tables express {:.2} % of it",
        f.max_um, f.rms_um, f.map_max_um, f.map_rms_um, 100.0 * f.share,
    );
    let z = c.zero_not_held_um;
    if z[0] != 0.0 || z[1] != 0.0 {
        let _ = writeln!(
            t,
            "  not held: the map's ({:.2}, {:.2}) um at the control's zero, where its table is 0 (the reference sets it)",
            z[0], z[1],
        );
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::errormap::{Grid, Identity, Measured, Node, Stat, SCHEMA};

    use crate::Collect as Keep;

    /// A map over `extent_mm` x 0.75 `extent_mm` whose X error grows 0.1 um per mm of
    /// X and whose Y error is a wave along Y (which two entries cannot follow).
    fn map(extent_mm: f64) -> ErrorMap {
        let xs: Vec<f64> = (0..=8).map(|i| i as f64 * extent_mm / 8.0).collect();
        let ys: Vec<f64> = (0..=6).map(|i| i as f64 * 0.75 * extent_mm / 6.0).collect();
        let stat = |mean| Stat {
            mean,
            sd: 0.0,
            n: 1,
        };
        let nodes = ys
            .iter()
            .flat_map(|&y| xs.iter().map(move |&x| (x, y)))
            .map(|(x, y)| {
                let m = Measured {
                    ex_um: stat(0.1 * x),
                    ey_um: stat(3.0 * (y * 0.3).sin()),
                    yaw_urad: stat(0.0),
                };
                Node {
                    forward: m,
                    reverse: m,
                }
            })
            .collect();
        ErrorMap {
            schema: SCHEMA.into(),
            version: 1,
            created: "2026-11-22T00:00:00Z".into(),
            identity: Identity {
                machine: "m".into(),
                controller: "c".into(),
                board: "b".into(),
                certificate_sha256: String::new(),
                camera: "cam".into(),
            },
            tool_offset_mm: [0.0, 0.0],
            board_at_machine_zero_mm: [0.0, 0.0],
            reference_mm: [0.0, 0.0],
            grid: Grid { xs, ys, nodes },
            x_lines: Vec::new(),
            y_lines: Vec::new(),
            uncertainty_um: 0.0,
        }
    }

    #[test]
    fn bounds_are_named() {
        let mut r = ExportRequest::new(ExportFormat::Beckhoff);
        r.tolerance_um = f64::NAN;
        let e = r.check().unwrap_err();
        assert_eq!(
            e.for_cli(),
            "--tolerance-um: must be a number from 0.001 to 1000, got NaN"
        );
        r.tolerance_um = 1.0;
        r.entries = 1000;
        assert_eq!(r.check().unwrap_err().field, "entries");
        r.entries = 256;
        r.name = "../x".into();
        assert_eq!(r.check().unwrap_err().field, "name");
        assert_eq!(ExportFormat::parse("fanuc").unwrap_err().flag(), "--format");
        r.name = "t.txt".into();
        r.interval_mm = 0.1;
        assert_eq!(
            r.check_map(&map(10_000.0)).unwrap_err().field,
            "interval_mm"
        );
        // Refused before any table is built.
        let out = run(&r, map(10_000.0), &mut Keep::default());
        assert!(out.error().unwrap().starts_with("interval_mm: "));
        assert_eq!(r.artifact_names(), ["t_x.txt", "t_y.txt"]);
    }

    #[test]
    fn every_table_or_none() {
        let mut r = ExportRequest::new(ExportFormat::Linuxcnc);
        r.name = "comp.tbl".into();
        let mut sink = Keep::default();
        let out = run(&r, map(40.0), &mut sink);
        // 256 entries follow both.
        assert!(out.is_success(), "{:?}", out.error());
        let names: Vec<_> = sink.0.iter().map(|a| a.name.as_str()).collect();
        assert_eq!(names, ["comp_x.tbl", "comp_y.tbl"]);
        assert!(summary(out.result.as_ref().unwrap()).contains("comp_y.tbl: joint Y"));
        // Too few entries for Y's wave: refused, and X is not handed over either.
        r.entries = 2;
        let mut sink = Keep::default();
        let out = run(&r, map(40.0), &mut sink);
        assert!(out.error().is_some());
        assert!(sink.0.is_empty());
        let mut sink = Keep::default();
        let out = run(&ExportRequest::new(ExportFormat::Csv), map(40.0), &mut sink);
        assert!(matches!(
            out.result,
            Some(ExportResult::Csv { rows: 63, .. })
        ));
        assert_eq!(sink.0[0].name, "table");
    }

    #[test]
    fn controller_formats_hand_over_the_files_they_name() {
        for format in ExportFormat::ALL {
            assert_eq!(ExportFormat::parse(format.as_str()), Ok(format));
            let mut r = ExportRequest::new(format);
            r.name = "comp.txt".into();
            let mut sink = Keep::default();
            let out = run(&r, map(40.0), &mut sink);
            assert!(out.is_success(), "{}: {:?}", format.as_str(), out.error());
            let names: Vec<_> = sink.0.iter().map(|a| a.name.clone()).collect();
            assert_eq!(names, r.artifact_names(), "{}", format.as_str());
            let text = summary(out.result.as_ref().unwrap());
            assert!(text.contains("comp"), "{}: {text}", format.as_str());
        }
        let r = ExportRequest::new(ExportFormat::SiemensCec);
        assert_eq!(r.artifact_names(), ["table_x", "table_y", "table_cec"]);
        // The options travel as JSON under `controller`, checked with their field named.
        let json = serde_json::json!({
            "format": "fanuc-pitch",
            "controller": { "fanuc_section": "ramp", "fanuc_unit_um": 0.0 }
        });
        let r: ExportRequest = serde_json::from_value(json).unwrap();
        assert_eq!(r.controller.fanuc_section, FanucSection::Ramp);
        assert_eq!(r.check().unwrap_err().field, "fanuc_unit_um");
        // A value past the range of one point (0.01 um units): refused, nothing handed.
        let mut r = ExportRequest::new(ExportFormat::FanucPitch);
        r.controller.fanuc_max_increment = 1;
        r.controller.fanuc_unit_um = 0.01;
        let mut sink = Keep::default();
        let out = run(&r, map(40.0), &mut sink);
        assert!(
            out.error().unwrap().contains("a point holds"),
            "{:?}",
            out.error()
        );
        assert!(sink.0.is_empty());
    }
}

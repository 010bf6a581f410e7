//! The typed requests of every procedure: one serde type per capability, unknown fields
//! refused, every bound checked once in [`Request::parse`] (or `check` for a request
//! built from command-line flags) with the field named. The CLI's flags and the API's
//! JSON body both become these types; nothing downstream re-reads raw JSON.
//!
//! Field names are the JSON names; [`RequestError::flag`] gives the CLI's spelling
//! (`grid_step_mm` -> `--grid-step-mm`). With the `cli` feature the same types are the
//! command line's flags (`clap::Args`): each parameter, its help, default and bound is
//! declared once, here, for both front ends.

use errormap::scan::{ScanSpec, MAX_SCAN_FRAMES};
use serde::{Deserialize, Serialize};
use serde_json::Value;
use vision::localize::Method;

/// A request refused: which field and why.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{field}: {message}")]
pub struct RequestError {
    /// The field's JSON name (`grid_step_mm`, `assign[2]`), or `params` for the whole.
    pub field: String,
    pub message: String,
}

impl RequestError {
    pub fn new(field: impl Into<String>, message: impl Into<String>) -> Self {
        Self {
            field: field.into(),
            message: message.into(),
        }
    }

    /// The field as the command line spells it: `--grid-step-mm`.
    pub fn flag(&self) -> String {
        let base = self.field.split('[').next().unwrap_or(&self.field);
        format!("--{}", base.replace('_', "-"))
    }

    /// The message as the CLI shows it: `--grid-step-mm: must be ...`.
    pub fn for_cli(&self) -> String {
        format!("{}: {}", self.flag(), self.message)
    }
}

/// A finite number within `lo..=hi`.
pub(crate) fn number(field: &str, v: f64, lo: f64, hi: f64) -> Result<(), RequestError> {
    if !(v.is_finite() && v >= lo && v <= hi) {
        return Err(RequestError::new(
            field,
            format!("must be a number from {lo} to {hi}, got {}", shown(v)),
        ));
    }
    Ok(())
}

/// A number as a person reads it: `1e-300`, not three hundred zeros.
fn shown(v: f64) -> String {
    if v != 0.0 && v.is_finite() && !(1e-4..1e9).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

/// An integer within `lo..=hi`.
pub(crate) fn count(field: &str, v: u64, lo: u64, hi: u64) -> Result<(), RequestError> {
    if !(lo..=hi).contains(&v) {
        return Err(RequestError::new(
            field,
            format!("must be an integer from {lo} to {hi}, got {v}"),
        ));
    }
    Ok(())
}

/// A profile name: 1 to 64 letters, digits, `-` or `_`.
pub fn check_name(field: &str, name: &str) -> Result<(), RequestError> {
    let ok = !name.is_empty()
        && name.len() <= 64
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_');
    if !ok {
        return Err(RequestError::new(
            field,
            format!("must be 1 to 64 letters, digits, '-' or '_', got {name:?}"),
        ));
    }
    Ok(())
}

/// The localization methods as the API's schema names them (`vision::localize::Method`
/// in the request).
#[derive(utoipa::ToSchema)]
#[schema(as = MethodName)]
#[allow(dead_code)]
#[serde(rename_all = "kebab-case")]
pub(crate) enum MethodName {
    Fit,
    FourPoint,
}

/// A compensation run over the job's targets (all, or the first `targets`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields)]
pub struct CompensateRequest {
    /// Only the first N targets of the job.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long))]
    #[schema(minimum = 1, maximum = 1000000)]
    pub targets: Option<u64>,
    /// Localization method: fit or four-point (the patent's formula); default: the job
    /// file's.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long))]
    #[schema(value_type = Option<MethodName>, inline)]
    pub method: Option<Method>,
}

impl CompensateRequest {
    pub fn check(&self) -> Result<(), RequestError> {
        if let Some(n) = self.targets {
            count("targets", n, 1, 1_000_000)?;
        }
        Ok(())
    }
}

fn default_map_name() -> String {
    "map".into()
}
fn default_grid_step() -> f64 {
    ScanSpec::default().grid_step_mm
}
fn default_line_step() -> f64 {
    ScanSpec::default().line_step_mm
}
fn default_passes() -> u32 {
    ScanSpec::default().passes
}

/// An error-map scan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields)]
pub struct MapRequest {
    /// The map's name: the profile it becomes a new version of (on the command line, the
    /// file's name, by default the job file's).
    #[serde(default = "default_map_name")]
    #[cfg_attr(feature = "cli", arg(skip = default_map_name()))]
    #[schema(default = default_map_name, pattern = "^[A-Za-z0-9_-]{1,64}$")]
    pub name: String,
    /// The grid's step over the travel, mm (at least 0.25: half the board pitch).
    #[serde(default = "default_grid_step")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_grid_step()))]
    #[schema(default = default_grid_step, minimum = 0.25, maximum = 10000.0)]
    pub grid_step_mm: f64,
    /// The step of the dense lines along each axis, mm (at least 0.05).
    #[serde(default = "default_line_step")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_line_step()))]
    #[schema(default = default_line_step, minimum = 0.05, maximum = 10000.0)]
    pub line_step_mm: f64,
    /// Times each point is measured from each side (1 to 10).
    #[serde(default = "default_passes")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_passes()))]
    #[schema(default = default_passes, minimum = 1, maximum = 10)]
    pub passes: u32,
    /// Tool point minus camera centre, machine axes, `X,Y` mm.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, default_value = "0,0", value_parser = xy_mm))]
    #[schema(default = json!([0.0, 0.0]))]
    pub tool_offset_mm: [f64; 2],
}

/// `X,Y` in mm (a command-line value); the error is the value's ([`crate::Error::Input`]).
#[cfg(feature = "cli")]
pub fn xy_mm(text: &str) -> Result<[f64; 2], crate::Error> {
    let parts: Vec<&str> = text.split(',').collect();
    match parts.as_slice() {
        [x, y] => match (x.trim().parse(), y.trim().parse()) {
            (Ok(x), Ok(y)) => Ok([x, y]),
            _ => Err(crate::Error::Input(format!("`{text}`: expected X,Y in mm"))),
        },
        _ => Err(crate::Error::Input(format!("`{text}`: expected X,Y in mm"))),
    }
}

impl Default for MapRequest {
    fn default() -> Self {
        Self {
            name: default_map_name(),
            grid_step_mm: default_grid_step(),
            line_step_mm: default_line_step(),
            passes: default_passes(),
            tool_offset_mm: [0.0, 0.0],
        }
    }
}

/// The finest steps a scan accepts: half the board pitch on the grid (nodes closer than
/// that see the same dots), 0.05 mm on the dense lines (a hundredth of a 5 mm lead).
pub const MIN_GRID_STEP_MM: f64 = 0.25;
pub const MIN_LINE_STEP_MM: f64 = 0.05;

impl MapRequest {
    pub fn spec(&self) -> ScanSpec {
        ScanSpec {
            grid_step_mm: self.grid_step_mm,
            line_step_mm: self.line_step_mm,
            passes: self.passes,
        }
    }

    pub fn check(&self) -> Result<(), RequestError> {
        check_name("name", &self.name)?;
        number(
            "grid_step_mm",
            self.grid_step_mm,
            MIN_GRID_STEP_MM,
            10_000.0,
        )?;
        number(
            "line_step_mm",
            self.line_step_mm,
            MIN_LINE_STEP_MM,
            10_000.0,
        )?;
        count("passes", self.passes.into(), 1, 10)?;
        for (k, v) in self.tool_offset_mm.iter().enumerate() {
            number(&format!("tool_offset_mm[{k}]"), *v, -500.0, 500.0)?;
        }
        Ok(())
    }

    /// The frames this scan takes over `lo..hi` (machine mm), computed without building
    /// the plan, refused past [`MAX_SCAN_FRAMES`] naming the step that makes it so.
    pub fn check_area(&self, lo: [f64; 2], hi: [f64; 2]) -> Result<u64, RequestError> {
        let (grid, lines) = errormap::scan::frames(lo, hi, self.spec());
        let frames = grid + lines;
        if frames > MAX_SCAN_FRAMES as f64 {
            let field = if grid >= lines {
                "grid_step_mm"
            } else {
                "line_step_mm"
            };
            return Err(RequestError::new(
                field,
                format!(
                    "the scan over {:.1} x {:.1} mm would take {frames:.0} frames; at most {MAX_SCAN_FRAMES} are accepted (a coarser step)",
                    hi[0] - lo[0],
                    hi[1] - lo[1]
                ),
            ));
        }
        Ok(frames as u64)
    }
}

fn default_seed() -> u64 {
    1
}
fn default_drift_threshold() -> f64 {
    2.0
}

/// A check of the error map with the camera at random points.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields)]
pub struct VerifyRequest {
    /// Points to check (default 20, or 5 for a spot check).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long))]
    #[schema(minimum = 1, maximum = 1000)]
    pub points: Option<u64>,
    /// The seed of the random points.
    #[serde(default = "default_seed")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_seed()))]
    #[schema(default = default_seed)]
    pub seed: u64,
    /// A drift check: `rescan` when any point is off by more than the threshold.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long))]
    pub spot_check: bool,
    /// The drift that asks for a re-scan, um.
    #[serde(default = "default_drift_threshold")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_drift_threshold()))]
    #[schema(default = default_drift_threshold, minimum = 0.001, maximum = 1000.0)]
    pub drift_threshold_um: f64,
    /// With a spot check: home and re-reference instead of using the map's recorded
    /// reference (the reference after the last homing).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long))]
    pub no_reference: bool,
    /// Which check of a series this is (from 0): each round checks fresh points.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(skip))]
    #[schema(minimum = 0, maximum = 1000000)]
    pub round: u64,
    /// Checks in a row, each on fresh points (a periodic spot check: the result says
    /// `rescan` when any check was past the threshold).
    #[serde(default = "default_repeat")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_repeat()))]
    #[schema(default = default_repeat, minimum = 1, maximum = 1000000)]
    pub repeat: u64,
    /// Seconds between two checks of `repeat`.
    #[serde(default = "default_every_s")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_every_s()))]
    #[schema(default = default_every_s, minimum = 0.0, maximum = 604800.0)]
    pub every_s: f64,
}

fn default_repeat() -> u64 {
    1
}

fn default_every_s() -> f64 {
    600.0
}

/// At most a week between two checks of a series (a longer pause is a mistyped value).
const WEEK_S: f64 = 7.0 * 24.0 * 3600.0;

impl Default for VerifyRequest {
    fn default() -> Self {
        Self {
            points: None,
            seed: default_seed(),
            spot_check: false,
            drift_threshold_um: default_drift_threshold(),
            no_reference: false,
            round: 0,
            repeat: default_repeat(),
            every_s: default_every_s(),
        }
    }
}

impl VerifyRequest {
    pub fn check(&self) -> Result<(), RequestError> {
        if let Some(n) = self.points {
            count("points", n, 1, 1000)?;
        }
        number("drift_threshold_um", self.drift_threshold_um, 1e-3, 1000.0)?;
        count("round", self.round, 0, 1_000_000)?;
        count("repeat", self.repeat, 1, 1_000_000)?;
        number("every_s", self.every_s, 0.0, WEEK_S)?;
        Ok(())
    }

    pub fn point_count(&self) -> usize {
        self.points.unwrap_or(if self.spot_check { 5 } else { 20 }) as usize
    }
}

/// The axis an ISO 230-2 test moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum TestAxis {
    #[serde(alias = "x")]
    X,
    #[serde(alias = "y")]
    Y,
}

impl TestAxis {
    pub fn index(self) -> usize {
        match self {
            TestAxis::X => 0,
            TestAxis::Y => 1,
        }
    }
}

/// ISO 230-2's test cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum CycleName {
    #[default]
    Linear,
    #[serde(alias = "pilgrim")]
    #[cfg_attr(feature = "cli", value(alias = "pilgrim"))]
    PilgrimStep,
}

impl CycleName {
    pub fn kind(self) -> iso230::plan::CycleKind {
        match self {
            CycleName::Linear => iso230::plan::CycleKind::Linear,
            CycleName::PilgrimStep => iso230::plan::CycleKind::PilgrimStep,
        }
    }
    pub fn as_str(self) -> &'static str {
        match self {
            CycleName::Linear => "linear",
            CycleName::PilgrimStep => "pilgrim-step",
        }
    }
}

fn default_runs() -> u64 {
    5
}
fn default_overrun() -> f64 {
    1.0
}
fn default_certificate_uncertainty() -> f64 {
    1.0
}

/// At most this many measurements in one ISO 230-2 test (positions x runs x 2).
pub const MAX_ISO230_MEASUREMENTS: u64 = 100_000;

/// An ISO 230-2 positioning test of one axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields)]
pub struct Iso230Request {
    /// The axis to test: x or y.
    #[cfg_attr(feature = "cli", arg(long, value_enum, ignore_case = true))]
    #[schema(inline)]
    pub axis: TestAxis,
    /// Target positions (default: the standard's minimum, 5 and 5 per metre).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long))]
    #[schema(minimum = 5, maximum = 10000)]
    pub positions: Option<u64>,
    /// Runs in each direction (at least 5).
    #[serde(default = "default_runs")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_runs()))]
    #[schema(default = default_runs, minimum = 5, maximum = 1000)]
    pub runs: u64,
    /// The test cycle: linear or pilgrim-step.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value_t))]
    #[schema(inline, default = json!("linear"))]
    pub cycle: CycleName,
    /// How far beyond the end targets the axis goes before reversing, mm.
    #[serde(default = "default_overrun")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_overrun()))]
    #[schema(default = default_overrun, minimum = 0.0, maximum = 50.0)]
    pub overrun_mm: f64,
    /// The measurement travel's start on the axis, machine mm (default: the usable
    /// travel's).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, allow_negative_numbers = true))]
    #[schema(minimum = -100000.0, maximum = 100000.0)]
    pub from_mm: Option<f64>,
    /// The measurement travel's end on the axis, machine mm.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, allow_negative_numbers = true))]
    #[schema(minimum = -100000.0, maximum = 100000.0)]
    pub to_mm: Option<f64>,
    /// Where the other axis is held, machine mm (default: the map's dense line along
    /// the axis, else the middle of the usable travel).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, allow_negative_numbers = true))]
    #[schema(minimum = -100000.0, maximum = 100000.0)]
    pub at_mm: Option<f64>,
    /// The board certificate's expanded uncertainty (k = 2) of a dot position, um.
    #[serde(default = "default_certificate_uncertainty")]
    #[cfg_attr(
        feature = "cli",
        arg(long, default_value_t = default_certificate_uncertainty())
    )]
    #[schema(default = default_certificate_uncertainty, minimum = 0.0, maximum = 1000.0)]
    pub certificate_uncertainty_um: f64,
    /// Test with the machine's error map acting (its active profile; on the command line,
    /// `--map`).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(skip))]
    pub with_map: bool,
    /// A test of the same axis before compensation, overlaid on the charts: its
    /// measurements file (`axis,position_index,target_mm,run,direction,deviation_um`).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(skip))]
    #[schema(format = Binary, max_length = 16777216)]
    pub before: Option<String>,
}

impl Iso230Request {
    pub fn new(axis: TestAxis) -> Self {
        Self {
            axis,
            positions: None,
            runs: default_runs(),
            cycle: CycleName::default(),
            overrun_mm: default_overrun(),
            from_mm: None,
            to_mm: None,
            at_mm: None,
            certificate_uncertainty_um: default_certificate_uncertainty(),
            with_map: false,
            before: None,
        }
    }

    pub fn check(&self) -> Result<(), RequestError> {
        if let Some(n) = self.positions {
            count("positions", n, 5, 10_000)?;
        }
        count("runs", self.runs, 5, 1000)?;
        if let Some(n) = self.positions {
            let m = n * self.runs * 2;
            if m > MAX_ISO230_MEASUREMENTS {
                return Err(RequestError::new(
                    "positions",
                    format!("{n} positions x {} runs x 2 directions = {m} measurements; at most {MAX_ISO230_MEASUREMENTS} are accepted", self.runs),
                ));
            }
        }
        number("overrun_mm", self.overrun_mm, 0.0, 50.0)?;
        for (field, v) in [
            ("from_mm", self.from_mm),
            ("to_mm", self.to_mm),
            ("at_mm", self.at_mm),
        ] {
            if let Some(v) = v {
                number(field, v, -1e5, 1e5)?;
            }
        }
        if let (Some(a), Some(b)) = (self.from_mm, self.to_mm) {
            if b <= a {
                return Err(RequestError::new(
                    "to_mm",
                    format!("must be past from_mm ({a} mm), got {b}"),
                ));
            }
        }
        number(
            "certificate_uncertainty_um",
            self.certificate_uncertainty_um,
            0.0,
            1000.0,
        )?;
        Ok(())
    }
}

/// A layout file's format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum LayoutFormat {
    #[default]
    Json,
    Dxf,
    Svg,
}

impl LayoutFormat {
    pub fn format(self) -> layout_io::Format {
        match self {
            LayoutFormat::Json => layout_io::Format::Json,
            LayoutFormat::Dxf => layout_io::Format::Dxf,
            LayoutFormat::Svg => layout_io::Format::Svg,
        }
    }
    pub fn of(format: layout_io::Format) -> Self {
        match format {
            layout_io::Format::Json => LayoutFormat::Json,
            layout_io::Format::Dxf => LayoutFormat::Dxf,
            layout_io::Format::Svg => LayoutFormat::Svg,
        }
    }
}

fn default_chord_tolerance() -> f64 {
    0.01
}

/// The largest layout text a request carries (the service's body limit is lower).
pub const MAX_LAYOUT_BYTES: usize = 64 << 20;

/// A cutting layout partitioned into tool and window groups for a multi-tool cutter.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields)]
pub struct LayoutRequest {
    /// The layout file's text (the CLI reads it from the file it is given).
    #[cfg_attr(feature = "cli", arg(skip))]
    #[schema(format = Binary)]
    pub layout: String,
    /// The layout's format (on the command line, the file's extension).
    #[cfg_attr(feature = "cli", arg(skip))]
    #[schema(inline)]
    pub format: LayoutFormat,
    /// Number of tools k (equal lanes across the width).
    #[cfg_attr(feature = "cli", arg(long))]
    #[schema(minimum = 1, maximum = 64)]
    pub tools: u64,
    /// Cutting window length L' along the feed (X), mm.
    #[cfg_attr(feature = "cli", arg(long))]
    #[schema(minimum = 0.001, maximum = 100000.0)]
    pub window_mm: f64,
    /// Gap between groups, mm.
    #[cfg_attr(feature = "cli", arg(long))]
    #[schema(minimum = 0.001, maximum = 1000.0)]
    pub gap_mm: f64,
    /// Material width W, mm, edge at Y = 0 (default: the JSON file's width_mm, else the
    /// layout's extent across).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long))]
    #[schema(minimum = 0.001, maximum = 100000.0)]
    pub width_mm: Option<f64>,
    /// Width of the material the partitioned layout is written on, mm, from the lanes'
    /// lower edge (default: the layout's width W). A part that the shifts take past it
    /// refuses the run, named.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long))]
    #[schema(minimum = 0.001, maximum = 100000.0)]
    pub material_width_mm: Option<f64>,
    /// Parts of different groups closer than this after the shifts are overlaps, mm
    /// (default: the gap). Between 0.001 mm and the gap.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long))]
    #[schema(minimum = 0.001)]
    pub clearance_mm: Option<f64>,
    /// Force a part into a group, `PART=GROUP` (group ids as printed, 1-based, `G3`
    /// also accepted); repeatable.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, value_name = "PART=GROUP"))]
    pub assign: Vec<String>,
    /// When moving parts leaves overlaps, move later windows (along X) or upper lanes
    /// (along Y) further apart than the one gap of the partition until none is left
    /// (reported as `widenings`); without it such overlaps are an error.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long))]
    pub widen: bool,
    /// Chord tolerance for arcs and splines read from the layout, mm.
    #[serde(default = "default_chord_tolerance")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_chord_tolerance()))]
    #[schema(default = default_chord_tolerance, minimum = 0.0001, maximum = 10.0)]
    pub chord_tolerance_mm: f64,
    /// The shifted layout's format (default: the input's; on the command line, the
    /// output file's extension).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(skip))]
    #[schema(inline)]
    pub out_format: Option<LayoutFormat>,
    /// Also draw the partition, coloured by group: `svg` or `png`.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(skip))]
    #[schema(inline)]
    pub picture: Option<PictureFormat>,
}

/// A picture's format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum PictureFormat {
    Svg,
    Png,
}

impl LayoutRequest {
    pub fn check(&self) -> Result<(), RequestError> {
        if self.layout.len() > MAX_LAYOUT_BYTES {
            return Err(RequestError::new(
                "layout",
                format!(
                    "{} bytes; at most {MAX_LAYOUT_BYTES} are accepted",
                    self.layout.len()
                ),
            ));
        }
        count("tools", self.tools, 1, 64)?;
        number("window_mm", self.window_mm, 1e-3, 1e5)?;
        number("gap_mm", self.gap_mm, 1e-3, 1e3)?;
        if let Some(w) = self.width_mm {
            number("width_mm", w, 1e-3, 1e5)?;
        }
        if let Some(m) = self.material_width_mm {
            number("material_width_mm", m, 1e-3, 1e5)?;
        }
        if let Some(c) = self.clearance_mm {
            number("clearance_mm", c, 1e-3, self.gap_mm)?;
        }
        number("chord_tolerance_mm", self.chord_tolerance_mm, 1e-4, 10.0)?;
        self.assignments()?;
        Ok(())
    }

    /// The forced assignments, each `PART=GROUP` parsed; a malformed one is named.
    pub fn assignments(&self) -> Result<Vec<(String, usize)>, RequestError> {
        self.assign
            .iter()
            .enumerate()
            .map(|(k, text)| {
                let field = format!("assign[{k}]");
                let (part, group) = text.rsplit_once('=').ok_or_else(|| {
                    RequestError::new(&field, format!("`{text}`: write PART=GROUP"))
                })?;
                if part.is_empty() {
                    return Err(RequestError::new(
                        &field,
                        format!("`{text}`: the part id is empty"),
                    ));
                }
                let group: usize = group
                    .trim()
                    .trim_start_matches(['G', 'g'])
                    .parse()
                    .ok()
                    .filter(|g| *g >= 1)
                    .ok_or_else(|| {
                        RequestError::new(
                            &field,
                            format!(
                                "`{text}`: the group is a number from 1 (1, 2, ... or G1, G2, ...)"
                            ),
                        )
                    })?;
                Ok((part.to_string(), group))
            })
            .collect()
    }
}

/// A head's place across the material: the material Y of its machine Y 0 and its travel.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct HeadReach {
    pub origin_y_mm: f64,
    pub reach_y_mm: f64,
}

/// `ORIGIN:REACH` in mm (the command line's spelling); the error is the value's
/// ([`crate::Error::Input`]).
impl std::str::FromStr for HeadReach {
    type Err = crate::Error;
    fn from_str(text: &str) -> Result<Self, crate::Error> {
        let (origin, reach) = text
            .split_once(':')
            .ok_or_else(|| crate::Error::Input(format!("`{text}`: write ORIGIN:REACH in mm")))?;
        let num = |v: &str, what: &str| {
            v.trim()
                .parse::<f64>()
                .map_err(|_| crate::Error::Input(format!("`{text}`: the {what} is not a number")))
        };
        Ok(HeadReach {
            origin_y_mm: num(origin, "origin")?,
            reach_y_mm: num(reach, "reach")?,
        })
    }
}

fn default_baud() -> u32 {
    115_200
}
fn default_knife_feed() -> f64 {
    12_000.0
}

/// A partitioned layout cut on a conveyor cutter (source C): the emulated one, or real
/// GRBL controllers (one for the conveyor, one per head in lane order).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields)]
pub struct CutRequest {
    /// The layout and how it is partitioned (as a `layout` job's).
    #[cfg_attr(feature = "cli", command(flatten))]
    #[schema(inline)]
    pub partition: LayoutRequest,
    /// The conveyor's controller (its X axis feeds the material); with a head's for
    /// each tool, in lane order. Default: the emulated cutter.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, requires = "heads"))]
    pub conveyor: Option<String>,
    /// A knife head's controller (X along the feed from the cutting area's start, Y
    /// across from its origin, Z the knife); one per tool, in lane order.
    #[serde(default)]
    #[cfg_attr(
        feature = "cli",
        arg(long = "head", value_name = "PORT", requires = "conveyor")
    )]
    pub heads: Vec<String>,
    /// Each head's origin (material Y of its machine Y 0) and Y travel, `ORIGIN:REACH`
    /// in mm, in head order; default: built for the partition.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, value_name = "ORIGIN:REACH"))]
    pub head_reach: Vec<HeadReach>,
    /// The controllers' baud rate.
    #[serde(default = "default_baud")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_baud()))]
    #[schema(default = default_baud, minimum = 1200, maximum = 4000000)]
    pub baud: u32,
    /// Knife feed along the contours, mm/min.
    #[serde(default = "default_knife_feed")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_knife_feed()))]
    #[schema(default = default_knife_feed, minimum = 1.0, maximum = 100000.0)]
    pub feed_mm_min: f64,
}

impl CutRequest {
    pub fn check(&self) -> Result<(), RequestError> {
        self.partition.check()?;
        number("feed_mm_min", self.feed_mm_min, 1.0, 100_000.0)?;
        count("baud", self.baud.into(), 1200, 4_000_000)?;
        let tools = self.partition.tools as usize;
        if !self.head_reach.is_empty() && self.head_reach.len() != tools {
            return Err(RequestError::new(
                "head_reach",
                format!("given {} times for {tools} tools", self.head_reach.len()),
            ));
        }
        for (k, h) in self.head_reach.iter().enumerate() {
            number(
                &format!("head_reach[{k}].origin_y_mm"),
                h.origin_y_mm,
                -1e5,
                1e5,
            )?;
            number(
                &format!("head_reach[{k}].reach_y_mm"),
                h.reach_y_mm,
                1e-3,
                1e5,
            )?;
        }
        match (&self.conveyor, self.heads.len()) {
            (None, 0) => Ok(()),
            (None, _) => Err(RequestError::new(
                "heads",
                "heads are given with the conveyor's controller",
            )),
            (Some(_), n) if n != tools => Err(RequestError::new(
                "heads",
                format!(
                    "given {n} times for {tools} tools (one controller per head, in lane order)"
                ),
            )),
            (Some(_), _) => Ok(()),
        }
    }
}

fn default_rotary_name() -> String {
    "rotary".into()
}

/// A measurement of the A/C table through the machine's rotary link.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields)]
pub struct RotaryRequest {
    /// The rotary profile the identified errors become a version of.
    #[serde(default = "default_rotary_name")]
    #[schema(default = default_rotary_name, pattern = "^[A-Za-z0-9_-]{1,64}$")]
    #[cfg_attr(feature = "cli", arg(skip = default_rotary_name()))]
    pub name: String,
}

impl Default for RotaryRequest {
    fn default() -> Self {
        Self {
            name: default_rotary_name(),
        }
    }
}

impl RotaryRequest {
    pub fn check(&self) -> Result<(), RequestError> {
        check_name("name", &self.name)
    }
}

/// A request's params as the request type (serde's error turned into the field named).
pub(crate) fn from_json<T: serde::de::DeserializeOwned>(params: &Value) -> Result<T, RequestError> {
    serde_path_to_error::deserialize(params).map_err(|e| {
        let path = e.path().to_string();
        let message = e.into_inner().to_string();
        // serde names an unknown or a missing field only in its message: that field is
        // the one to name.
        let named = ["unknown field `", "missing field `"]
            .iter()
            .find_map(|p| message.strip_prefix(p))
            .and_then(|rest| rest.split('`').next())
            // A field named by the empty string is shown as the params object's.
            .filter(|f| !f.is_empty());
        let field = match (path.as_str(), named) {
            (".", Some(f)) => f.to_string(),
            // An unknown field is already the path's last step.
            (p, Some(f)) if p == f || p.ends_with(&format!(".{f}")) => p.to_string(),
            (p, Some(f)) => format!("{p}.{f}"),
            (".", None) => "params".to_string(),
            (p, None) => p.to_string(),
        };
        // A key that is the empty string leaves no name: the params object is named.
        let field = if field.is_empty() || field.ends_with('.') {
            "params".to_string()
        } else {
            field
        };
        RequestError::new(field, message)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kinds::{schemas, Request};
    use serde_json::json;

    /// The schemas the page builds its forms from say what the checks do: each default
    /// is serde's, each required field is refused when absent, each bound is accepted and
    /// just past it refused naming the field.
    /// A head's reach is `ORIGIN:REACH` in mm; what is not says which part and why, as
    /// an input error (the command line's message).
    #[test]
    fn a_head_reach_is_origin_colon_reach() {
        let h: HeadReach = "-2.5:20".parse().unwrap();
        assert_eq!((h.origin_y_mm, h.reach_y_mm), (-2.5, 20.0));
        let e = "1x".parse::<HeadReach>().unwrap_err();
        assert!(matches!(e, crate::Error::Input(_)), "{e:?}");
        assert_eq!(e.to_string(), "`1x`: write ORIGIN:REACH in mm");
        let e = "a:2".parse::<HeadReach>().unwrap_err();
        assert_eq!(e.to_string(), "`a:2`: the origin is not a number");
    }

    #[test]
    fn the_schemas_bounds_and_defaults_are_the_checks() {
        let layout = json!({"layout": "", "format": "json", "tools": 2, "window_mm": 100.0,
            "gap_mm": 5.0});
        let model = protocol::volumetric::write_model(
            &volumetric::Model::zero(protocol::volumetric::Structure::Xyfz, [5.0; 3]).file,
        );
        let base = |kind: &str| match kind {
            "iso230" => json!({"axis": "x"}),
            "layout" => layout.clone(),
            "cut" => json!({ "partition": layout }),
            "volumetric-identify" => json!({"structure": "XYFZ"}),
            "volumetric-eval" => json!({"model": model, "points": "x_mm,y_mm,z_mm\n"}),
            "volumetric-contributions" | "volumetric-export-isg" => json!({ "model": model }),
            "localize" => json!({"image": "iVBORw0K"}),
            "export" => json!({"format": "csv"}),
            "rewrite" => json!({"program": ""}),
            "dnc" => json!({"program": ""}),
            "iso230-evaluate" => json!({"measurements": ""}),
            "rotary-identify" => json!({"centres": ""}),
            "rotary-rewrite" => json!({"program": "", "errors": ""}),
            // Re-referencing in use needs both (each names itself at its bounds).
            "proxy" => json!({"reference_every_s": 300.0, "clear_z_mm": -5.0}),
            _ => json!({}),
        };
        let mut bounds = 0;
        for (kind, schema) in schemas() {
            let schema = serde_json::to_value(schema).unwrap();
            let parsed = Request::parse(kind, &base(kind)).unwrap().params();
            for field in schema["required"].as_array().into_iter().flatten() {
                let field = field.as_str().unwrap();
                let mut params = base(kind);
                params.as_object_mut().unwrap().remove(field);
                let e = Request::parse(kind, &params).unwrap_err();
                assert_eq!(e.field, field, "{kind}: {e}");
            }
            let no_fields = serde_json::Map::new();
            let fields = schema["properties"].as_object().unwrap_or(&no_fields);
            for (field, p) in fields {
                if let Some(d) = p.get("default") {
                    assert_eq!(&parsed[field], d, "{kind}.{field}: default");
                }
                let types = &p["type"];
                let integer = types == "integer"
                    || types
                        .as_array()
                        .is_some_and(|t| t.contains(&json!("integer")));
                for (bound, outward) in [("minimum", -1.0), ("maximum", 1.0)] {
                    let Some(b) = p.get(bound).and_then(Value::as_f64) else {
                        continue;
                    };
                    let at = |v: f64| {
                        let mut params = base(kind);
                        params[field] = if integer { json!(v as i64) } else { json!(v) };
                        Request::parse(kind, &params)
                    };
                    at(b).unwrap_or_else(|e| panic!("{kind}.{field} at its {bound} {b}: {e}"));
                    let past = if integer {
                        b + outward
                    } else {
                        b + outward * (b.abs() * 1e-9).max(1e-12)
                    };
                    let e = at(past).unwrap_err();
                    assert_eq!(&e.field, field, "{kind}.{field} = {past}: {e}");
                    bounds += 1;
                }
            }
        }
        assert!(bounds >= 30, "{bounds} bounds tried");
    }

    #[test]
    fn a_tiny_grid_step_is_refused_naming_the_field() {
        let e = Request::parse("map", &json!({"grid_step_mm": 1e-300})).unwrap_err();
        assert_eq!(e.field, "grid_step_mm");
        assert_eq!(e.flag(), "--grid-step-mm");
        assert!(e.message.ends_with("got 1e-300"), "{e}");
        let e = Request::parse("map", &json!({"grid_step_mm": "x"})).unwrap_err();
        assert_eq!(e.field, "grid_step_mm");
    }

    #[test]
    fn unknown_fields_and_kinds_are_refused() {
        let e = Request::parse("verify", &json!({"pionts": 3})).unwrap_err();
        assert_eq!(e.field, "pionts", "{e}");
        let e = Request::parse("layout", &json!({"format": "json"})).unwrap_err();
        assert_eq!(e.field, "layout", "{e}");
        let e = Request::parse("nope", &json!({})).unwrap_err();
        assert_eq!(e.field, "kind");
        let e = Request::parse("map", &json!([1])).unwrap_err();
        assert_eq!(e.field, "params");
        // Found by the fuzzer: a key that is the empty string.
        let e = Request::parse("compensate", &json!({"": 1})).unwrap_err();
        assert_eq!(e.field, "params");
        assert!(e.message.contains("unknown field ``"), "{e}");
    }

    #[test]
    fn the_frames_a_scan_implies_are_bounded_before_any_plan_is_built() {
        let r = MapRequest {
            grid_step_mm: MIN_GRID_STEP_MM,
            ..MapRequest::default()
        };
        r.check().unwrap();
        let e = r.check_area([0.0, 0.0], [1000.0, 1000.0]).unwrap_err();
        assert_eq!(e.field, "grid_step_mm");
        let ok = MapRequest::default()
            .check_area([0.05, 0.05], [199.95, 149.95])
            .unwrap();
        assert_eq!(ok, 1376);
    }

    #[test]
    fn a_bad_assignment_is_reported() {
        let mut r = LayoutRequest {
            layout: String::new(),
            format: LayoutFormat::Json,
            tools: 2,
            window_mm: 100.0,
            gap_mm: 5.0,
            width_mm: None,
            material_width_mm: None,
            clearance_mm: None,
            assign: vec!["a=2".into(), "b".into()],
            widen: false,
            chord_tolerance_mm: 0.01,
            out_format: None,
            picture: None,
        };
        let e = r.check().unwrap_err();
        assert_eq!(e.field, "assign[1]");
        r.assign = vec!["a=G0".into()];
        assert_eq!(r.check().unwrap_err().field, "assign[0]");
        r.assign = vec!["a=G2".into()];
        assert_eq!(r.assignments().unwrap(), vec![("a".to_string(), 2)]);
    }

    #[test]
    fn iso230_measurements_are_bounded() {
        let mut r = Iso230Request::new(TestAxis::X);
        r.positions = Some(10_000);
        r.runs = 1000;
        assert_eq!(r.check().unwrap_err().field, "positions");
        let r: Iso230Request = from_json(&json!({"axis": "x", "cycle": "pilgrim"})).unwrap();
        assert_eq!(r.axis, TestAxis::X);
        assert_eq!(r.cycle, CycleName::PilgrimStep);
    }
}

fn default_max_shift() -> f64 {
    errormap::reference::MAX_SHIFT_UM
}

/// The reference after homing: home (when the job homes), one frame at the map's
/// reference point, and how far the machine's zero moved recorded as the map's current
/// reference, which rewritten programs and spot checks then apply.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields)]
pub struct ReferenceRequest {
    /// The largest machine-zero shift accepted, um (homing moves it by a few um; more
    /// means the camera is on another board point, the board or the camera moved).
    #[serde(default = "default_max_shift")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_max_shift()))]
    #[schema(default = default_max_shift, minimum = 0.1, maximum = 500.0)]
    pub max_shift_um: f64,
    /// Measure where the machine is, without homing first: a re-reference in use (every
    /// few minutes while the screws warm), on a machine homed before. The shift and each
    /// axis's scale are measured as after a homing; the orientation check of the homing
    /// is not repeated.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long))]
    pub no_home: bool,
}

impl Default for ReferenceRequest {
    fn default() -> Self {
        Self {
            max_shift_um: default_max_shift(),
            no_home: false,
        }
    }
}

impl ReferenceRequest {
    pub fn check(&self) -> Result<(), RequestError> {
        number(
            "max_shift_um",
            self.max_shift_um,
            0.1,
            errormap::reference::MAX_SHIFT_UM,
        )
    }

    /// Parses and checks the API's params object.
    pub fn parse(params: &Value) -> Result<Self, RequestError> {
        if !params.is_object() {
            return Err(RequestError::new("params", "must be a JSON object"));
        }
        let r: Self = from_json(params)?;
        r.check()?;
        Ok(r)
    }
}

#[cfg(test)]
mod reference_request_tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn the_reference_request_defaults_and_bounds_are_its_schema() {
        use utoipa::PartialSchema;
        let schema = serde_json::to_value(ReferenceRequest::schema()).unwrap();
        let p = &schema["properties"]["max_shift_um"];
        let r = ReferenceRequest::parse(&json!({})).unwrap();
        assert_eq!(json!(r.max_shift_um), p["default"]);
        for (bound, outward) in [("minimum", -1e-9), ("maximum", 1e-9)] {
            let b = p[bound].as_f64().unwrap();
            ReferenceRequest::parse(&json!({ "max_shift_um": b })).unwrap();
            let e = ReferenceRequest::parse(&json!({ "max_shift_um": b + outward * b.max(1.0) }))
                .unwrap_err();
            assert_eq!(e.field, "max_shift_um");
        }
        let e = ReferenceRequest::parse(&json!({"max_shift": 3})).unwrap_err();
        assert_eq!(e.field, "max_shift");
        assert_eq!(
            ReferenceRequest::parse(&json!([])).unwrap_err().field,
            "params"
        );
    }
}

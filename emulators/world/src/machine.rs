//! The simulated imperfect X-Y stage: the truth every emulated device shares.
//!
//! The controller side is what a real controller knows: integer encoder/step counts per
//! axis, moved with trapezoidal speed profiles on a simulated clock: each axis on its
//! own profile (per-axis drives), or both on one straight line (a coordinated
//! controller, [`SimMachine::start_move`]). The physical side is where the carriage (and the camera on it) really is,
//! which differs from the counts as an ordinary ballscrew stage does:
//!
//! * ballscrew cumulative lead error within the configured JIS class tolerance (SPEC A
//!   table), plus a periodic (per-revolution) lead error;
//! * straightness of each axis (a bow of the path across the axis);
//! * yaw and pitch of each carriage, seen at the camera through Abbe arms;
//! * squareness between X and Y;
//! * backlash (lost motion of the nut) on every reversal;
//! * a homing (return-to-zero) error redrawn at every homing;
//! * thermal expansion of the screws growing with time since power-on;
//! * settling noise redrawn at every arrival;
//! * quantisation of positions to encoder counts.
//!
//! Nothing here is visible to the gateway except through what a device would report
//! (counts) and what the camera sees (frames rendered at [`SimMachine::camera_pose`]).

use crate::camera::CameraPose;
use crate::rng::Rng;
use protocol::config::{ConfigDoc, ConfigError};
use serde::Deserialize;
use std::f64::consts::PI;
use std::path::Path;

const ARCSEC: f64 = PI / (180.0 * 3600.0);

/// Ballscrew accuracy classes of the SPEC A table (JIS C0, C1, C2, C3, C5).
#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq)]
pub enum LeadClass {
    C0,
    C1,
    C2,
    C3,
    C5,
}

/// Travel tolerance (um) of a ballscrew class over a travel (mm): the SPEC A table.
pub fn lead_tolerance_um(class: LeadClass, travel_mm: f64) -> Option<f64> {
    const ROWS: [(f64, [f64; 5]); 10] = [
        (100.0, [3.0, 3.5, 5.0, 8.0, 18.0]),
        (200.0, [3.5, 4.5, 7.0, 10.0, 20.0]),
        (315.0, [4.0, 6.0, 8.0, 12.0, 23.0]),
        (400.0, [5.0, 7.0, 9.0, 13.0, 25.0]),
        (500.0, [6.0, 8.0, 10.0, 15.0, 27.0]),
        (630.0, [6.0, 9.0, 11.0, 16.0, 30.0]),
        (800.0, [7.0, 10.0, 13.0, 18.0, 35.0]),
        (1000.0, [8.0, 11.0, 15.0, 21.0, 40.0]),
        (1250.0, [9.0, 13.0, 18.0, 24.0, 46.0]),
        (1600.0, [11.0, 15.0, 21.0, 29.0, 54.0]),
    ];
    let col = match class {
        LeadClass::C0 => 0,
        LeadClass::C1 => 1,
        LeadClass::C2 => 2,
        LeadClass::C3 => 3,
        LeadClass::C5 => 4,
    };
    ROWS.iter()
        .find(|(upto, _)| travel_mm <= *upto)
        .map(|(_, v)| v[col])
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisConfig {
    pub travel_mm: f64,
    pub counts_per_mm: f64,
    pub max_feed_mm_min: f64,
    pub accel_mm_s2: f64,
    pub lead_mm: f64,
    pub lead_class: LeadClass,
    /// Fraction of the class tolerance the drawn lead error uses (0..1).
    #[serde(default = "default_lead_use")]
    pub lead_tolerance_use: f64,
    #[serde(default)]
    pub periodic_um: f64,
    #[serde(default)]
    pub straightness_um: f64,
    #[serde(default)]
    pub yaw_arcsec: f64,
    #[serde(default)]
    pub pitch_arcsec: f64,
    /// In-plane distance from the camera to the axis's screw line (yaw lever).
    #[serde(default)]
    pub abbe_arm_mm: f64,
    #[serde(default)]
    pub backlash_um: f64,
    #[serde(default)]
    pub homing_repeatability_um: f64,
    #[serde(default)]
    pub settle_noise_um: f64,
    /// A stepper that stalls: full steps lost during chosen moves (issue 28).
    #[serde(default)]
    pub stall: Option<StallConfig>,
}

/// Lost steps of an open-loop stepper axis: during move number `at_move` of this axis
/// (counted from power-on, 1 = the first move longer than the loss: a stepper stalls at
/// speed, not in a correction of a few micrometres), and then every `every` such moves
/// (0: once),
/// the motor stalls for `full_steps` full steps of `step_mm`; the carriage ends that
/// much short of where the controller believes it is, and stays offset (the controller
/// never learns it: its counts are its commands).
///
/// ```toml
/// [axes.x.stall]
/// full_steps = 80   # 2 mm at 0.025 mm a step (5 mm lead, 200 steps a turn)
/// step_mm = 0.025
/// at_move = 12
/// every = 0
/// ```
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct StallConfig {
    pub full_steps: u32,
    pub step_mm: f64,
    pub at_move: u64,
    #[serde(default)]
    pub every: u64,
}

impl StallConfig {
    /// Does move number `n` (1-based) of the axis stall?
    pub fn stalls_on(&self, n: u64) -> bool {
        n == self.at_move
            || (self.every > 0 && n > self.at_move && (n - self.at_move).is_multiple_of(self.every))
    }

    pub fn lost_mm(&self) -> f64 {
        self.full_steps as f64 * self.step_mm
    }
}

fn default_lead_use() -> f64 {
    0.8
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ThermalConfig {
    /// Final temperature rise of the screws after warm-up, kelvin.
    pub screw_rise_k: f64,
    pub time_constant_s: f64,
    #[serde(default = "default_expansion")]
    pub expansion_per_k: f64,
}

fn default_expansion() -> f64 {
    11.7e-6
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MachineSection {
    #[serde(default)]
    pub name: String,
    pub seed: u64,
    /// True board coordinate under the camera at the home switches (machine zero, before
    /// the homing error).
    #[serde(deserialize_with = "protocol::config::two_numbers")]
    pub board_at_home_mm: [f64; 2],
    #[serde(default)]
    pub squareness_arcsec: f64,
    /// Height of the camera's optical axis point above the screws (pitch lever).
    #[serde(default)]
    pub camera_height_mm: f64,
    /// Where the tool point sits relative to the camera's centre, machine axes, mm: a
    /// rigid arm on the carriage, so the carriage's yaw moves the tool by
    /// `yaw x (-oy, ox)` more than the camera (Abbe). The trace records the tool.
    #[serde(default, deserialize_with = "protocol::config::two_numbers")]
    pub tool_offset_mm: [f64; 2],
    /// A machine without homing (issue 28): at power-on the carriage is this far (mm,
    /// machine axes) from the home switches, and the controller takes wherever it is as
    /// its zero, already "homed". None: the controller must home first.
    #[serde(default, deserialize_with = "protocol::config::optional_two_numbers")]
    pub power_on_at_mm: Option<[f64; 2]>,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxesConfig {
    pub x: AxisConfig,
    pub y: AxisConfig,
}

/// A simulated machine file (`config/machines/*.toml`).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MachineConfig {
    pub machine: MachineSection,
    pub axes: AxesConfig,
    pub thermal: Option<ThermalConfig>,
}

impl MachineConfig {
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        Self::from_doc(&ConfigDoc::read(path)?)
    }

    /// Parse and check a machine file: every number finite and within a physically
    /// meaningful range (errors name the key, its line and the allowed range), so that
    /// a typo is refused here rather than surfacing later as a frame without a board.
    pub fn from_doc(doc: &ConfigDoc) -> Result<Self, ConfigError> {
        let cfg: MachineConfig = doc.parse()?;
        let m = &cfg.machine;
        for (i, v) in m.board_at_home_mm.iter().enumerate() {
            doc.in_range(
                &format!("machine.board_at_home_mm[{i}]"),
                *v,
                -10_000.0,
                10_000.0,
                "mm",
            )
            .map_err(|_| {
                doc.invalid(
                    "machine.board_at_home_mm",
                    format!(
                        "`{v}`: each coordinate must be a finite number within -10000..=10000 mm"
                    ),
                )
            })?;
        }
        doc.in_range(
            "machine.squareness_arcsec",
            m.squareness_arcsec,
            -3600.0,
            3600.0,
            "arcsec",
        )?;
        for v in m.tool_offset_mm {
            doc.in_range("machine.tool_offset_mm", v, -1000.0, 1000.0, "mm")?;
        }
        doc.in_range(
            "machine.camera_height_mm",
            m.camera_height_mm,
            -1000.0,
            1000.0,
            "mm",
        )?;
        for (name, a) in [("x", &cfg.axes.x), ("y", &cfg.axes.y)] {
            let key = |k: &str| format!("axes.{name}.{k}");
            // Floors: a stage moves at least a millimetre, counts at least once a
            // millimetre, moves a millimetre within a minute, accelerates by 1 mm/s² at
            // least; no ballscrew has a lead under 0.1 mm (a subnormal made every move
            // infinite or every count zero).
            doc.in_range(
                &key("travel_mm"),
                a.travel_mm,
                1.0,
                1600.0,
                "mm (the ballscrew tolerance table's longest travel)",
            )?;
            doc.in_range(
                &key("counts_per_mm"),
                a.counts_per_mm,
                1.0,
                1e6,
                "counts/mm",
            )?;
            doc.in_range(
                &key("max_feed_mm_min"),
                a.max_feed_mm_min,
                1.0,
                200_000.0,
                "mm/min",
            )?;
            doc.in_range(&key("accel_mm_s2"), a.accel_mm_s2, 1.0, 100_000.0, "mm/s²")?;
            doc.in_range(&key("lead_mm"), a.lead_mm, 0.1, 100.0, "mm")?;
            doc.in_range(
                &key("lead_tolerance_use"),
                a.lead_tolerance_use,
                0.0,
                1.0,
                "of the class tolerance",
            )?;
            let non_negative = [
                ("periodic_um", a.periodic_um, 100.0, "um"),
                ("straightness_um", a.straightness_um, 1000.0, "um"),
                ("yaw_arcsec", a.yaw_arcsec, 3600.0, "arcsec"),
                ("pitch_arcsec", a.pitch_arcsec, 3600.0, "arcsec"),
                ("backlash_um", a.backlash_um, 1000.0, "um"),
                (
                    "homing_repeatability_um",
                    a.homing_repeatability_um,
                    1000.0,
                    "um",
                ),
                ("settle_noise_um", a.settle_noise_um, 100.0, "um"),
            ];
            for (k, v, hi, unit) in non_negative {
                doc.in_range(&key(k), v, 0.0, hi, unit)?;
            }
            doc.in_range(&key("abbe_arm_mm"), a.abbe_arm_mm, -1000.0, 1000.0, "mm")?;
            if let Some(stall) = &a.stall {
                doc.in_range(
                    &key("stall.step_mm"),
                    stall.step_mm,
                    1e-4,
                    10.0,
                    "mm (one full step of the motor: at least 0.1 um)",
                )?;
                if !(stall.lost_mm() <= a.travel_mm) {
                    return Err(doc.invalid(
                        &key("stall.full_steps"),
                        format!(
                            "{} full steps of {} mm lose {} mm, more than the {} mm travel",
                            stall.full_steps,
                            stall.step_mm,
                            stall.lost_mm(),
                            a.travel_mm
                        ),
                    ));
                }
            }
        }
        if let Some(at) = m.power_on_at_mm {
            // From the home switches, either way: at most the travel.
            for (v, a) in at.into_iter().zip([&cfg.axes.x, &cfg.axes.y]) {
                doc.in_range(
                    "machine.power_on_at_mm",
                    v,
                    -a.travel_mm,
                    a.travel_mm,
                    "mm from the home switches (within the travel)",
                )?;
            }
        }
        if let Some(t) = &cfg.thermal {
            doc.in_range("thermal.screw_rise_k", t.screw_rise_k, -50.0, 50.0, "K")?;
            doc.in_range("thermal.time_constant_s", t.time_constant_s, 1.0, 1e6, "s")?;
            doc.in_range(
                "thermal.expansion_per_k",
                t.expansion_per_k,
                0.0,
                1e-4,
                "/K",
            )?;
        }
        Ok(cfg)
    }
}

/// A smooth random curve on [0, 1]: a few sinusoids with random phases, peak ~ 1.
#[derive(Clone, Debug)]
struct Wander {
    terms: Vec<(f64, f64, f64)>, // (amplitude, cycles over the travel, phase)
}

impl Wander {
    fn new(rng: &mut Rng, n: usize, max_cycles: f64) -> Self {
        let mut terms: Vec<(f64, f64, f64)> = (0..n)
            .map(|k| {
                let cycles = rng.range(0.3, max_cycles.max(0.4)) + k as f64 * 0.2;
                (
                    rng.range(0.5, 1.0) / (k + 1) as f64,
                    cycles,
                    rng.range(0.0, 2.0 * PI),
                )
            })
            .collect();
        // Normalise so the peak over [0, 1] is 1.
        let peak = (0..=400)
            .map(|i| {
                let u = i as f64 / 400.0;
                terms
                    .iter()
                    .map(|(a, c, p)| a * (2.0 * PI * c * u + p).sin())
                    .sum::<f64>()
                    .abs()
            })
            .fold(0.0, f64::max)
            .max(1e-9);
        for t in &mut terms {
            t.0 /= peak;
        }
        Self { terms }
    }

    fn at(&self, u: f64) -> f64 {
        self.terms
            .iter()
            .map(|(a, c, p)| a * (2.0 * PI * c * u + p).sin())
            .sum()
    }
}

/// The drawn (fixed for the machine's life) error curves of one axis.
#[derive(Clone, Debug)]
struct AxisErrors {
    lead_slope_um: f64, // lead error at full travel
    lead_wander_um: f64,
    lead_wander: Wander,
    periodic_phase: f64,
    straightness: Wander,
    yaw: Wander,
    pitch: Wander,
}

impl AxisErrors {
    fn draw(rng: &mut Rng, a: &AxisConfig) -> Self {
        let tol =
            lead_tolerance_um(a.lead_class, a.travel_mm).unwrap_or(0.0) * a.lead_tolerance_use;
        let sign = if rng.uniform() < 0.5 { -1.0 } else { 1.0 };
        Self {
            lead_slope_um: sign * tol * rng.range(0.6, 0.75),
            lead_wander_um: tol * 0.25,
            lead_wander: Wander::new(rng, 3, 3.0),
            periodic_phase: rng.range(0.0, 2.0 * PI),
            straightness: Wander::new(rng, 2, 1.2),
            yaw: Wander::new(rng, 2, 1.5),
            pitch: Wander::new(rng, 2, 1.5),
        }
    }

    /// Cumulative lead error at nut displacement `u` mm (um).
    fn lead_um(&self, a: &AxisConfig, u: f64) -> f64 {
        let s = (u / a.travel_mm).clamp(-0.1, 1.1);
        self.lead_slope_um * s
            + self.lead_wander_um * self.lead_wander.at(s)
            + a.periodic_um * (2.0 * PI * u / a.lead_mm + self.periodic_phase).sin()
    }
}

/// Per-axis physical state.
#[derive(Clone, Debug)]
struct AxisState {
    /// Controller position, counts from machine zero.
    counts: i64,
    /// Where the home switch really trips, mm (the homing error), redrawn per homing.
    home_offset_mm: f64,
    /// Carriage position along the axis, mm (after lead error, thermal, backlash).
    carriage_mm: f64,
    settle_um: f64,
    /// Steps lost so far (stalls), mm: the nut is this far from where the counts say.
    lost_mm: f64,
    /// Moves of this axis started since power-on (for the stall model).
    axis_moves: u64,
}

/// A trapezoidal speed profile along a path of `length` mm (a triangle when the path
/// is too short to reach the feed), from rest to rest.
#[derive(Clone, Debug, PartialEq)]
struct PathProfile {
    length: f64,
    v: f64,
    a: f64,
    duration: f64,
}

impl PathProfile {
    fn new(length: f64, feed_mm_s: f64, accel: f64) -> Self {
        let t_acc = feed_mm_s / accel;
        let d_acc = 0.5 * accel * t_acc * t_acc;
        let (v, duration) = if 2.0 * d_acc >= length {
            let tv = (length / accel).sqrt();
            (accel * tv, 2.0 * tv)
        } else {
            (feed_mm_s, 2.0 * t_acc + (length - 2.0 * d_acc) / feed_mm_s)
        };
        Self {
            length,
            v,
            a: accel,
            duration,
        }
    }

    /// Distance along the path after `t` seconds.
    fn distance_at(&self, t: f64) -> f64 {
        if t >= self.duration {
            return self.length;
        }
        let t_acc = self.v / self.a;
        if t < t_acc {
            0.5 * self.a * t * t
        } else if t < self.duration - t_acc {
            0.5 * self.a * t_acc * t_acc + self.v * (t - t_acc)
        } else {
            let r = self.duration - t;
            self.length - 0.5 * self.a * r * r
        }
    }

    /// Speed along the path after `t` seconds, mm/s.
    fn speed_at(&self, t: f64) -> f64 {
        if t >= self.duration || t < 0.0 {
            return 0.0;
        }
        let t_acc = self.v / self.a;
        if t < t_acc {
            self.a * t
        } else if t < self.duration - t_acc {
            self.v
        } else {
            self.a * (self.duration - t)
        }
    }
}

/// One axis's move in progress on the simulated clock: the axis goes from `from` to
/// `to` in proportion to the distance covered along its path. For a move of this axis
/// alone the path is the axis's own travel (`length = |to - from|`); for a coordinated
/// move ([`SimMachine::start_move`]) every axis shares the straight line's profile
/// (`length` = the line's length), so they keep to the line and arrive together.
#[derive(Clone, Debug)]
struct AxisMotion {
    from: f64,
    to: f64,
    path: PathProfile,
    elapsed: f64,
    /// The move this profile belongs to: axes of one coordinated move share it.
    group: u64,
    /// Steps this move loses (signed, mm), applied as it ends.
    stall_mm: f64,
}

impl AxisMotion {
    fn point_at(&self, t: f64) -> f64 {
        if self.path.length == 0.0 {
            return self.to;
        }
        let f = self.path.distance_at(t) / self.path.length;
        self.from + f * (self.to - self.from)
    }

    /// This axis's speed after `t` seconds, mm/s.
    fn speed_at(&self, t: f64) -> f64 {
        if self.path.length == 0.0 {
            return 0.0;
        }
        self.path.speed_at(t) * (self.to - self.from).abs() / self.path.length
    }

    fn left(&self) -> f64 {
        self.path.duration - self.elapsed
    }
}

/// Why the simulated controller refused a command (what a real controller would say).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MachineRefusal {
    #[error("axis {axis}: target {target_mm:.4} mm is outside the travel 0..{travel_mm} mm")]
    OutOfTravel {
        axis: char,
        target_mm: f64,
        travel_mm: f64,
    },
    #[error("the machine is not homed")]
    NotHomed,
    #[error("feed {0} mm/min is not positive")]
    BadFeed(f64),
    #[error("acceleration {0} mm/s² is not positive")]
    BadAccel(f64),
}

/// The simulated machine. Deterministic for a given config (seed).
///
/// Motion is per axis: each axis has its own optional profile and its own homed flag,
/// so drives of one axis each ([`SimMachine::start_axis_move`],
/// [`SimMachine::stop_axis`], [`SimMachine::home_axis`]) move, stop and home
/// independently. A coordinated controller's straight line
/// ([`SimMachine::start_move`]) is every axis on the line's one profile.
#[derive(Clone, Debug)]
pub struct SimMachine {
    cfg: MachineConfig,
    rng: Rng,
    errors: [AxisErrors; 2],
    axes: [AxisState; 2],
    motion: [Option<AxisMotion>; 2],
    homed: [bool; 2],
    /// Simulated seconds since power-on.
    now_s: f64,
    homings: u32,
    /// Moves started so far (each coordinated move counts once): the group of the next.
    moves: u64,
    /// The executed path, when recording (`start_trace`): truth for tests only.
    trace: Option<Vec<TraceRow>>,
}

/// One point of the executed path: the controller's position and where the tool really
/// is, both in machine coordinates (the true tool point minus the nominal offset between
/// board and machine, so a perfect machine has `true_mm == cmd_mm`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TraceRow {
    pub t_s: f64,
    pub cmd_mm: [f64; 2],
    pub true_mm: [f64; 2],
}

/// Longest path between two trace rows, mm.
pub const TRACE_STEP_MM: f64 = 0.05;

impl SimMachine {
    pub fn new(cfg: MachineConfig) -> Self {
        let mut rng = Rng::new(cfg.machine.seed);
        let mut err_rng = rng.fork(1);
        let errors = [
            AxisErrors::draw(&mut err_rng, &cfg.axes.x),
            AxisErrors::draw(&mut err_rng, &cfg.axes.y),
        ];
        let axis = AxisState {
            counts: 0,
            home_offset_mm: 0.0,
            carriage_mm: 0.0,
            settle_um: 0.0,
            lost_mm: 0.0,
            axis_moves: 0,
        };
        let mut axes = [axis.clone(), axis];
        let power_on = cfg.machine.power_on_at_mm;
        if let Some(at) = power_on {
            for k in 0..2 {
                axes[k].home_offset_mm = at[k];
                axes[k].carriage_mm = at[k];
            }
        }
        Self {
            cfg,
            rng,
            errors,
            axes,
            motion: [None, None],
            homed: [power_on.is_some(); 2],
            now_s: 0.0,
            homings: 0,
            moves: 0,
            trace: None,
        }
    }

    /// Record the executed path from now on: a row at least every [`TRACE_STEP_MM`] of
    /// motion and at the end of every move (truth for tests; the gateway never sees it).
    pub fn start_trace(&mut self) {
        let row = self.trace_row();
        self.trace = Some(vec![row]);
    }

    /// The rows recorded since the last call (empty when not recording).
    pub fn take_trace(&mut self) -> Vec<TraceRow> {
        self.trace.as_mut().map(std::mem::take).unwrap_or_default()
    }

    fn trace_row(&self) -> TraceRow {
        let o = self.cfg.machine.board_at_home_mm;
        let tool = self.tool_point_mm();
        TraceRow {
            t_s: self.now_s,
            cmd_mm: self.position_mm(),
            true_mm: [tool[0] - o[0], tool[1] - o[1]],
        }
    }

    /// Where the tool point really is on the board: the camera's true centre plus the
    /// tool arm turned by the carriage's yaw.
    pub(crate) fn tool_point_mm(&self) -> [f64; 2] {
        let pose = self.camera_pose();
        let [ox, oy] = self.cfg.machine.tool_offset_mm;
        let (s, c) = pose.rotation_rad.sin_cos();
        [
            pose.centre_mm[0] + c * ox - s * oy - ox,
            pose.centre_mm[1] + s * ox + c * oy - oy,
        ]
    }

    pub fn config(&self) -> &MachineConfig {
        &self.cfg
    }

    /// The configuration of axis `k` (0 = X, 1 = Y). Panics on another index.
    pub fn axis_config(&self, k: usize) -> &AxisConfig {
        self.axis_cfg(k)
    }

    fn axis_cfg(&self, k: usize) -> &AxisConfig {
        match k {
            0 => &self.cfg.axes.x,
            1 => &self.cfg.axes.y,
            _ => panic!("the machine has axes 0 (X) and 1 (Y), not {k}"),
        }
    }

    pub fn now_s(&self) -> f64 {
        self.now_s
    }

    /// Both axes homed.
    pub fn is_homed(&self) -> bool {
        self.homed.iter().all(|h| *h)
    }

    pub fn is_axis_homed(&self, k: usize) -> bool {
        self.homed[k]
    }

    /// Any axis moving.
    pub fn is_moving(&self) -> bool {
        self.motion.iter().any(Option::is_some)
    }

    pub fn is_axis_moving(&self, k: usize) -> bool {
        self.motion[k].is_some()
    }

    /// Homings so far (of both axes or of one).
    pub fn homings(&self) -> u32 {
        self.homings
    }

    /// Controller position in counts (what the encoders say).
    pub fn counts(&self) -> [i64; 2] {
        [self.axes[0].counts, self.axes[1].counts]
    }

    /// Controller position in mm (counts / counts_per_mm).
    pub fn position_mm(&self) -> [f64; 2] {
        [
            self.axes[0].counts as f64 / self.cfg.axes.x.counts_per_mm,
            self.axes[1].counts as f64 / self.cfg.axes.y.counts_per_mm,
        ]
    }

    /// Home both axes: approach the switches from the negative side, take the trip point
    /// (a new random homing error each time) as machine zero. Takes simulated time (the
    /// clock runs on by the longer axis's run back to its switch).
    pub fn home(&mut self) {
        let from = self.position_mm();
        let dist = from[0].abs().max(from[1].abs());
        self.now_s += 1.0 + dist / (self.cfg.axes.x.max_feed_mm_min / 60.0);
        for k in 0..2 {
            self.set_home(k);
        }
        self.motion = [None, None];
        self.homings += 1;
    }

    /// Home axis `k` alone, as a drive of that axis does: its move (if any) ends, a new
    /// homing error is drawn for this axis only, its counts become 0 and it is homed;
    /// the other axis is untouched (it keeps moving, homed or not). The clock does not
    /// run here: the return value is how long the run back to the switch takes
    /// (1 s + the distance at the axis's maximum feed), for the drive to stay busy
    /// that long on its own clock.
    pub fn home_axis(&mut self, k: usize) -> f64 {
        let a = self.axis_cfg(k);
        let took = 1.0 + self.position_mm()[k].abs() / (a.max_feed_mm_min / 60.0);
        self.motion[k] = None;
        self.set_home(k);
        self.homings += 1;
        took
    }

    /// Axis `k` at its switch: draw its homing error, counts 0, the nut pushing the
    /// carriage from the negative side, homed.
    fn set_home(&mut self, k: usize) {
        let sigma = self.axis_cfg(k).homing_repeatability_um;
        let h = self.rng.normal() * sigma / 1000.0;
        let st = &mut self.axes[k];
        st.counts = 0;
        st.home_offset_mm = h;
        // At the switch the lost steps no longer matter: zero is where the switch is.
        st.lost_mm = 0.0;
        // The switch is reached moving negative, then the axis backs off positive
        // to zero: the nut ends pushing the carriage from the negative side.
        let b = self.axis_cfg(k).backlash_um / 1000.0;
        let n = self.nut_mm(k, 0);
        self.axes[k].carriage_mm = n - b / 2.0;
        self.axes[k].settle_um = 0.0;
        self.homed[k] = true;
    }

    /// Check a target of axis `k` against the travel; the target quantised to counts.
    fn checked_target(&self, k: usize, target_mm: f64) -> Result<f64, MachineRefusal> {
        let a = self.axis_cfg(k);
        if !(target_mm >= 0.0 && target_mm <= a.travel_mm) {
            return Err(MachineRefusal::OutOfTravel {
                axis: ['X', 'Y'][k],
                target_mm,
                travel_mm: a.travel_mm,
            });
        }
        Ok((target_mm * a.counts_per_mm).round() / a.counts_per_mm)
    }

    /// Start a coordinated straight-line move to a controller position (mm, machine
    /// coordinates), as a coordinated controller (GRBL) does: both axes on one
    /// trapezoid along the line (feed and acceleration the lower of the two axes'),
    /// so they keep to the line and arrive together. A move in progress is first run
    /// to its end. The position is quantised to counts as a real controller does.
    /// Returns the move's duration, s.
    pub fn start_move(
        &mut self,
        target_mm: [f64; 2],
        feed_mm_min: f64,
    ) -> Result<f64, MachineRefusal> {
        if !self.is_homed() {
            return Err(MachineRefusal::NotHomed);
        }
        if !(feed_mm_min.is_finite() && feed_mm_min > 0.0) {
            return Err(MachineRefusal::BadFeed(feed_mm_min));
        }
        let to = [
            self.checked_target(0, target_mm[0])?,
            self.checked_target(1, target_mm[1])?,
        ];
        self.finish_motion();
        let feed = (feed_mm_min.min(
            self.cfg
                .axes
                .x
                .max_feed_mm_min
                .min(self.cfg.axes.y.max_feed_mm_min),
        )) / 60.0;
        let accel = self.cfg.axes.x.accel_mm_s2.min(self.cfg.axes.y.accel_mm_s2);
        let from = self.position_mm();
        let length = ((to[0] - from[0]).powi(2) + (to[1] - from[1]).powi(2)).sqrt();
        let path = PathProfile::new(length, feed, accel);
        let d = path.duration;
        self.moves += 1;
        for k in 0..2 {
            let stall_mm = self.stall_of(k, to[k] - from[k]);
            self.motion[k] = Some(AxisMotion {
                from: from[k],
                to: to[k],
                path: path.clone(),
                elapsed: 0.0,
                group: self.moves,
                stall_mm,
            });
        }
        Ok(d)
    }

    /// Start a move of axis `k` alone to `target_mm` (quantised to counts) at up to
    /// `feed_mm_min` (bounded by the axis's maximum feed), accelerating at the axis's
    /// own acceleration, from rest where the axis is now (a move of this axis in
    /// progress is replaced; the other axis carries on). Returns the duration, s.
    pub fn start_axis_move(
        &mut self,
        k: usize,
        target_mm: f64,
        feed_mm_min: f64,
    ) -> Result<f64, MachineRefusal> {
        let accel = self.axis_cfg(k).accel_mm_s2;
        self.start_axis_move_accel(k, target_mm, feed_mm_min, accel)
    }

    /// [`SimMachine::start_axis_move`] accelerating and decelerating at `accel_mm_s2`
    /// (bounded by the axis's own acceleration): a drive's own ramp.
    pub fn start_axis_move_accel(
        &mut self,
        k: usize,
        target_mm: f64,
        feed_mm_min: f64,
        accel_mm_s2: f64,
    ) -> Result<f64, MachineRefusal> {
        if !self.homed[k] {
            return Err(MachineRefusal::NotHomed);
        }
        if !(feed_mm_min.is_finite() && feed_mm_min > 0.0) {
            return Err(MachineRefusal::BadFeed(feed_mm_min));
        }
        if !(accel_mm_s2.is_finite() && accel_mm_s2 > 0.0) {
            return Err(MachineRefusal::BadAccel(accel_mm_s2));
        }
        let to = self.checked_target(k, target_mm)?;
        let a = self.axis_cfg(k);
        let feed = feed_mm_min.min(a.max_feed_mm_min) / 60.0;
        let accel = accel_mm_s2.min(a.accel_mm_s2);
        let from = self.position_mm()[k];
        let path = PathProfile::new((to - from).abs(), feed, accel);
        let d = path.duration;
        self.moves += 1;
        let stall_mm = self.stall_of(k, to - from);
        self.motion[k] = Some(AxisMotion {
            from,
            to,
            path,
            elapsed: 0.0,
            group: self.moves,
            stall_mm,
        });
        Ok(d)
    }

    /// Advance the simulated clock; every axis's motion progresses, the carriages
    /// follow the nuts. An axis arriving gets its settling noise. While a trace is
    /// recorded the motion advances in steps of at most [`TRACE_STEP_MM`] of path (the
    /// same end state: the carriages follow the nuts monotonically within a move).
    pub fn advance(&mut self, dt_s: f64) {
        let dt = dt_s.max(0.0);
        if self.trace.is_none() || !self.is_moving() {
            self.advance_by(dt);
            return;
        }
        let fastest = self
            .cfg
            .axes
            .x
            .max_feed_mm_min
            .max(self.cfg.axes.y.max_feed_mm_min)
            / 60.0;
        let step = TRACE_STEP_MM / (fastest * std::f64::consts::SQRT_2);
        let mut left = dt;
        while left > 0.0 && self.is_moving() {
            let h = left.min(step);
            let moving = self.motion.iter().filter(|m| m.is_some()).count();
            self.advance_by(h);
            left -= h;
            let ended = self.motion.iter().filter(|m| m.is_some()).count() < moving;
            let row = self.trace_row();
            let moved = self
                .trace
                .as_ref()
                .and_then(|t| t.last())
                .is_none_or(|last| row.cmd_mm != last.cmd_mm);
            if moved || ended {
                if let Some(t) = self.trace.as_mut() {
                    t.push(row);
                }
            }
        }
        if left > 0.0 {
            self.advance_by(left);
        }
    }

    fn advance_by(&mut self, dt: f64) {
        self.now_s += dt;
        for k in 0..2 {
            let Some(mut m) = self.motion[k].take() else {
                continue;
            };
            m.elapsed += dt;
            let p = m.point_at(m.elapsed);
            self.set_axis_counts_from_mm(k, p);
            if m.elapsed >= m.path.duration {
                if m.stall_mm != 0.0 {
                    // The motor stalled during the move: the carriage ends short.
                    self.axes[k].lost_mm += m.stall_mm;
                    self.set_axis_counts_from_mm(k, p);
                }
                let s = self.axis_cfg(k).settle_noise_um;
                self.axes[k].settle_um = self.rng.normal() * s;
            } else {
                self.motion[k] = Some(m);
            }
        }
    }

    /// Run every move in progress to its end (advancing the clock by the longest rest).
    pub fn finish_motion(&mut self) {
        let rest = self
            .motion
            .iter()
            .flatten()
            .map(AxisMotion::left)
            .reduce(f64::max);
        if let Some(rest) = rest {
            self.advance(rest.max(0.0) + 1e-9);
        }
    }

    /// Seconds left of axis `k`'s move (0 when still).
    pub fn axis_time_left_s(&self, k: usize) -> f64 {
        self.motion[k].as_ref().map_or(0.0, |m| m.left().max(0.0))
    }

    /// The speed along the path now, mm/min (0 when still): what a controller's step
    /// generator is putting out at this moment (lower than the programmed feed while
    /// accelerating or decelerating). For axes on separate moves, the speed of the
    /// carriage over the table (the axes' speeds combined).
    pub fn speed_mm_min(&self) -> f64 {
        let moving: Vec<&AxisMotion> = self.motion.iter().flatten().collect();
        match moving.as_slice() {
            [] => 0.0,
            [m, rest @ ..] if rest.iter().all(|o| o.group == m.group) => {
                m.path.speed_at(m.elapsed) * 60.0
            }
            _ => {
                moving
                    .iter()
                    .map(|m| m.speed_at(m.elapsed).powi(2))
                    .sum::<f64>()
                    .sqrt()
                    * 60.0
            }
        }
    }

    /// Axis `k`'s speed now, mm/min (0 when still).
    pub fn axis_speed_mm_min(&self, k: usize) -> f64 {
        self.motion[k]
            .as_ref()
            .map_or(0.0, |m| m.speed_at(m.elapsed) * 60.0)
    }

    /// Stop now (feed hold): the axes stop where they are (no deceleration modelled).
    pub fn stop(&mut self) {
        self.motion = [None, None];
    }

    /// Stop axis `k` where it is (no deceleration modelled); the other axis carries on.
    pub fn stop_axis(&mut self, k: usize) {
        self.motion[k] = None;
    }

    fn set_counts_from_mm(&mut self, p: [f64; 2]) {
        for k in 0..2 {
            self.set_axis_counts_from_mm(k, p[k]);
        }
    }

    fn set_axis_counts_from_mm(&mut self, k: usize, p: f64) {
        let cpm = self.axis_cfg(k).counts_per_mm;
        self.axes[k].counts = (p * cpm).round() as i64;
        let n = self.nut_mm(k, self.axes[k].counts);
        let b = self.axis_cfg(k).backlash_um / 1000.0;
        let c = &mut self.axes[k].carriage_mm;
        // Lost motion: the nut drives the carriage only once the gap is taken up.
        if n > *c + b / 2.0 {
            *c = n - b / 2.0;
        } else if n < *c - b / 2.0 {
            *c = n + b / 2.0;
        }
    }

    /// Steps lost by a move of axis `k` by `delta_mm`: against the direction of motion.
    /// Moves are counted for [`StallConfig::at_move`] only when longer than the loss.
    fn stall_of(&mut self, k: usize, delta_mm: f64) -> f64 {
        let Some(st) = self.axis_cfg(k).stall.clone() else {
            return 0.0;
        };
        // A stepper stalls at speed: only moves longer than the loss count.
        if delta_mm.abs() <= st.lost_mm() {
            return 0.0;
        }
        self.axes[k].axis_moves += 1;
        if st.stalls_on(self.axes[k].axis_moves) {
            -delta_mm.signum() * st.lost_mm()
        } else {
            0.0
        }
    }

    /// Steps lost so far on axis `k`, mm (truth, for tests and reports).
    pub fn lost_mm(&self, k: usize) -> f64 {
        self.axes[k].lost_mm
    }

    /// Where the nut really is for a controller count: lead error and thermal growth
    /// measured from the (randomly offset) home position.
    fn nut_mm(&self, k: usize, counts: i64) -> f64 {
        let a = self.axis_cfg(k);
        let u =
            counts as f64 / a.counts_per_mm + self.axes[k].home_offset_mm + self.axes[k].lost_mm;
        let thermal = match &self.cfg.thermal {
            Some(t) => {
                t.expansion_per_k
                    * t.screw_rise_k
                    * (1.0 - (-self.now_s / t.time_constant_s).exp())
                    * u
            }
            None => 0.0,
        };
        u + self.errors[k].lead_um(a, u) / 1000.0 + thermal
    }

    /// Where the camera really looks on the board, and its extra rotation (yaw). The
    /// gateway never calls this; the rig renders frames at this pose and hands it out
    /// only as [`crate::rig::SimRig::truth`], the one door to the truth.
    pub(crate) fn camera_pose(&self) -> CameraPose {
        let (x, y) = (self.axes[0].carriage_mm, self.axes[1].carriage_mm);
        let ax = &self.cfg.axes.x;
        let ay = &self.cfg.axes.y;
        let (ex, ey) = (&self.errors[0], &self.errors[1]);
        let ux = (x / ax.travel_mm).clamp(-0.1, 1.1);
        let uy = (y / ay.travel_mm).clamp(-0.1, 1.1);
        let yaw_x = ax.yaw_arcsec * ARCSEC * ex.yaw.at(ux);
        let yaw_y = ay.yaw_arcsec * ARCSEC * ey.yaw.at(uy);
        let pitch_x = ax.pitch_arcsec * ARCSEC * ex.pitch.at(ux);
        let pitch_y = ay.pitch_arcsec * ARCSEC * ey.pitch.at(uy);
        let h = self.cfg.machine.camera_height_mm;
        let sq = self.cfg.machine.squareness_arcsec * ARCSEC;
        let um = 1e-3;
        let true_x = x
            + y * sq
            + ay.straightness_um * um * ey.straightness.at(uy)
            + yaw_x * ax.abbe_arm_mm
            + pitch_x * h
            + self.axes[0].settle_um * um;
        let true_y = y
            + ax.straightness_um * um * ex.straightness.at(ux)
            + yaw_y * ay.abbe_arm_mm
            + pitch_y * h
            + self.axes[1].settle_um * um;
        let o = self.cfg.machine.board_at_home_mm;
        CameraPose {
            centre_mm: [o[0] + true_x, o[1] + true_y],
            rotation_rad: yaw_x + yaw_y,
        }
    }

    /// Uncompensated error (um) at a controller position, approached from the negative
    /// side, without noise: for reports and tests of the error model only.
    pub fn static_error_um(&self, at_mm: [f64; 2]) -> [f64; 2] {
        let mut m = self.clone();
        m.rng = Rng::new(0);
        for k in 0..2 {
            m.axes[k].settle_um = 0.0;
            let b = m.axis_cfg(k).backlash_um / 1000.0;
            let c = ((at_mm[k] - 1.0).max(0.0) * m.axis_cfg(k).counts_per_mm).round() as i64;
            m.axes[k].carriage_mm = m.nut_mm(k, c) - b / 2.0;
        }
        m.set_counts_from_mm(at_mm);
        let p = m.camera_pose().centre_mm;
        let o = self.cfg.machine.board_at_home_mm;
        [
            (p[0] - o[0] - at_mm[0]) * 1000.0,
            (p[1] - o[1] - at_mm[1]) * 1000.0,
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) fn config() -> MachineConfig {
        let text = include_str!("../../../config/machines/c5-stage.toml");
        MachineConfig::from_doc(&ConfigDoc::from_text("c5-stage.toml", text, Path::new(".")))
            .unwrap()
    }

    fn load_with(from: &str, to: &str) -> Result<MachineConfig, ConfigError> {
        let text = include_str!("../../../config/machines/c5-stage.toml");
        assert!(text.contains(from), "{from}");
        let text = text.replacen(from, to, 1);
        MachineConfig::from_doc(&ConfigDoc::from_text("m.toml", &text, Path::new(".")))
    }

    /// Issue 38: every number of the machine file, each given a subnormal, a negative
    /// value, NaN, inf and an absurd magnitude, is refused naming its key and range
    /// (where zero means something, a subnormal is that zero to 1e-300 and accepted).
    #[test]
    fn every_number_of_the_machine_file_is_bounded_and_named() {
        let keys: &[(&str, &str, &str, bool)] = &[
            // (the seed's line, its key's prefix, the dotted key, zero allowed)
            ("travel_mm = 200.0", "travel_mm", "axes.x.travel_mm", false),
            (
                "counts_per_mm = 2000.0",
                "counts_per_mm",
                "axes.x.counts_per_mm",
                false,
            ),
            (
                "max_feed_mm_min = 6000.0",
                "max_feed_mm_min",
                "axes.x.max_feed_mm_min",
                false,
            ),
            (
                "accel_mm_s2 = 800.0",
                "accel_mm_s2",
                "axes.x.accel_mm_s2",
                false,
            ),
            ("lead_mm = 5.0", "lead_mm", "axes.x.lead_mm", false),
            (
                "lead_tolerance_use = 0.9",
                "lead_tolerance_use",
                "axes.x.lead_tolerance_use",
                true,
            ),
            (
                "periodic_um = 2.0",
                "periodic_um",
                "axes.x.periodic_um",
                true,
            ),
            (
                "straightness_um = 5.0",
                "straightness_um",
                "axes.x.straightness_um",
                true,
            ),
            ("yaw_arcsec = 8.0", "yaw_arcsec", "axes.x.yaw_arcsec", true),
            (
                "pitch_arcsec = 6.0",
                "pitch_arcsec",
                "axes.x.pitch_arcsec",
                true,
            ),
            (
                "abbe_arm_mm = 45.0",
                "abbe_arm_mm",
                "axes.x.abbe_arm_mm",
                true,
            ),
            (
                "backlash_um = 8.0",
                "backlash_um",
                "axes.x.backlash_um",
                true,
            ),
            (
                "homing_repeatability_um = 3.0",
                "homing_repeatability_um",
                "axes.x.homing_repeatability_um",
                true,
            ),
            (
                "settle_noise_um = 0.08",
                "settle_noise_um",
                "axes.x.settle_noise_um",
                true,
            ),
            (
                "squareness_arcsec = 25.0",
                "squareness_arcsec",
                "machine.squareness_arcsec",
                true,
            ),
            (
                "camera_height_mm = 60.0",
                "camera_height_mm",
                "machine.camera_height_mm",
                true,
            ),
            (
                "screw_rise_k = 2.0",
                "screw_rise_k",
                "thermal.screw_rise_k",
                true,
            ),
            (
                "time_constant_s = 1800.0",
                "time_constant_s",
                "thermal.time_constant_s",
                false,
            ),
        ];
        // Signed quantities (an arm, an angle, a rise) may be negative.
        let signed = [
            "abbe_arm_mm",
            "squareness_arcsec",
            "camera_height_mm",
            "screw_rise_k",
        ];
        for (line, name, key, zero) in keys {
            let mut bad = vec!["nan", "inf", "-inf", "1e308", "1e100"];
            if !zero {
                bad.extend(["4e-320", "0.0", "-1.0"]);
            } else if !signed.contains(name) {
                bad.push("-1.0");
            }
            for v in bad {
                let e = load_with(line, &format!("{name} = {v}"))
                    .map(|_| panic!("{name} = {v} accepted"))
                    .unwrap_err()
                    .to_string();
                assert!(
                    e.contains(&format!("key `{key}`")) && e.contains("..="),
                    "{name} = {v}: {e}"
                );
            }
        }
        // The stall's step, its floor 0.1 um; the seed's numbers are each accepted.
        let stall = "[axes.y]";
        for v in ["4e-320", "-0.025", "1e-5", "nan", "20.0"] {
            let e = load_with(
                stall,
                &format!("[axes.x.stall]\nfull_steps = 1\nstep_mm = {v}\nat_move = 3\n\n{stall}"),
            )
            .map(|_| panic!("step_mm = {v} accepted"))
            .unwrap_err()
            .to_string();
            assert!(e.contains("axes.x.stall.step_mm"), "{v}: {e}");
        }
        load_with(
            stall,
            &format!("[axes.x.stall]\nfull_steps = 1\nstep_mm = 1e-4\nat_move = 3\n\n{stall}"),
        )
        .unwrap();
    }

    #[test]
    fn non_finite_and_unphysical_values_are_refused_at_load_naming_key_and_range() {
        let cases = [
            (
                "abbe_arm_mm = 45.0",
                "abbe_arm_mm = nan",
                "axes.x.abbe_arm_mm",
            ),
            (
                "abbe_arm_mm = 45.0",
                "abbe_arm_mm = 1e9",
                "axes.x.abbe_arm_mm",
            ),
            (
                "squareness_arcsec = 25.0",
                "squareness_arcsec = nan",
                "machine.squareness_arcsec",
            ),
            (
                "camera_height_mm = 60.0",
                "camera_height_mm = inf",
                "machine.camera_height_mm",
            ),
            (
                "board_at_home_mm = [5.0, 5.0]",
                "board_at_home_mm = [5.0, nan]",
                "machine.board_at_home_mm",
            ),
            (
                "screw_rise_k = 2.0",
                "screw_rise_k = nan",
                "thermal.screw_rise_k",
            ),
            (
                "time_constant_s = 1800.0",
                "time_constant_s = inf",
                "thermal.time_constant_s",
            ),
            (
                "[thermal]",
                "[thermal]\nexpansion_per_k = nan",
                "thermal.expansion_per_k",
            ),
            (
                "backlash_um = 8.0",
                "backlash_um = 5e6",
                "axes.x.backlash_um",
            ),
            (
                "settle_noise_um = 0.08",
                "settle_noise_um = inf",
                "axes.x.settle_noise_um",
            ),
            (
                "accel_mm_s2 = 800.0",
                "accel_mm_s2 = 1e300",
                "axes.x.accel_mm_s2",
            ),
            (
                "lead_tolerance_use = 0.9",
                "lead_tolerance_use = nan",
                "axes.x.lead_tolerance_use",
            ),
        ];
        for (from, to, key) in cases {
            let e = load_with(from, to).unwrap_err().to_string();
            assert!(e.contains(&format!("key `{key}`")), "{to}: {e}");
            assert!(e.contains("..="), "{to}: the message names the range: {e}");
            assert!(e.starts_with("m.toml:"), "{e}");
        }
        let e = load_with("abbe_arm_mm = 45.0", "abbe_arm_mm = nan")
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a finite number"), "{e}");
        // Issue 38: these ended in "no dark dots found" or a turned, mirrored image.
        let home = "board_at_home_mm = [5.0, 5.0]";
        for (to, key) in [
            ("power_on_at_mm = [nan, 3.0]", "machine.power_on_at_mm"),
            ("power_on_at_mm = [3.0, inf]", "machine.power_on_at_mm"),
            ("power_on_at_mm = [1e308, 3.0]", "machine.power_on_at_mm"),
        ] {
            let e = load_with(home, &format!("{home}\n{to}"))
                .unwrap_err()
                .to_string();
            assert!(e.contains(&format!("key `{key}`")), "{to}: {e}");
            assert!(e.contains("..="), "{to}: {e}");
        }
        let e = load_with(home, &format!("{home}\npower_on_at_mm = [1.0, 2.0, 3.0]"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("two numbers"), "{e}");
        let axis = "[axes.x]";
        for (step, key) in [
            ("nan", "axes.x.stall.step_mm"),
            ("-0.025", "axes.x.stall.step_mm"),
            ("inf", "axes.x.stall.step_mm"),
            ("5.0", "axes.x.stall.full_steps"),
        ] {
            let stall = format!("[axes.x.stall]\nfull_steps = 80\nstep_mm = {step}\nat_move = 3\n");
            let text = include_str!("../../../config/machines/c5-stage.toml");
            let at = text.find("[axes.y]").unwrap();
            let text = format!("{}{stall}\n{}", &text[..at], &text[at..]);
            assert!(text.contains(axis));
            let e = MachineConfig::from_doc(&ConfigDoc::from_text("m.toml", &text, Path::new(".")))
                .unwrap_err()
                .to_string();
            assert!(e.contains(&format!("key `{key}`")), "{step}: {e}");
        }
        // A third coordinate is refused, not dropped.
        let e = load_with(
            "board_at_home_mm = [5.0, 5.0]",
            "board_at_home_mm = [5.0, 5.0, 1.0]",
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("key `machine.board_at_home_mm`") && e.contains("two numbers"),
            "{e}"
        );
    }

    #[test]
    fn tolerance_table_lookup() {
        assert_eq!(lead_tolerance_um(LeadClass::C5, 200.0), Some(20.0));
        assert_eq!(lead_tolerance_um(LeadClass::C0, 250.0), Some(4.0));
        assert_eq!(lead_tolerance_um(LeadClass::C3, 2000.0), None);
    }

    #[test]
    fn default_stage_is_an_ordinary_20_to_50_um_stage() {
        let m = SimMachine::new(config());
        let mut worst: f64 = 0.0;
        for i in 0..=20 {
            for j in 0..=15 {
                let e = m.static_error_um([i as f64 * 10.0, j as f64 * 10.0]);
                worst = worst.max(e[0].abs()).max(e[1].abs());
            }
        }
        assert!((20.0..=50.0).contains(&worst), "worst error {worst} um");
        // Lead error alone stays inside the C5 tolerance for its travel.
        let a = &m.cfg.axes.x;
        let tol = lead_tolerance_um(a.lead_class, a.travel_mm).unwrap();
        for i in 0..=200 {
            let e = m.errors[0].lead_um(a, i as f64) - a.periodic_um * 0.0;
            assert!(
                e.abs() <= tol + a.periodic_um,
                "lead error {e} um at {i} mm"
            );
        }
    }

    #[test]
    fn a_stalling_stepper_ends_short_and_a_machine_may_start_anywhere() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let mut cfg =
            MachineConfig::load(&dir.join("../../config/machines/c5-stage.toml")).unwrap();
        cfg.machine.power_on_at_mm = Some([37.0, 81.0]);
        cfg.axes.y.stall = Some(StallConfig {
            full_steps: 80,
            step_mm: 0.025,
            at_move: 2,
            every: 2,
        });
        let mut m = SimMachine::new(cfg);
        // No homing: the controller's zero is where it powered on.
        assert!(m.is_homed());
        let p0 = m.camera_pose().centre_mm;
        assert!(
            (p0[0] - 42.0).abs() < 0.1 && (p0[1] - 86.0).abs() < 0.1,
            "{p0:?}"
        );
        let moves = |m: &mut SimMachine, to: [f64; 2]| {
            m.start_move(to, 3000.0).unwrap();
            m.finish_motion();
            m.lost_mm(1)
        };
        assert_eq!(moves(&mut m, [10.0, 10.0]), 0.0);
        // The second move of Y stalls 80 steps = 2 mm against its motion (+Y).
        assert!((moves(&mut m, [10.0, 30.0]) + 2.0).abs() < 1e-12);
        assert!((moves(&mut m, [10.0, 40.0]) + 2.0).abs() < 1e-12);
        // ... and every second move after: now moving -Y, it ends 2 mm short the other way.
        assert!(moves(&mut m, [10.0, 20.0]).abs() < 1e-12);
        assert_eq!(m.lost_mm(0), 0.0);
        let pose = m.camera_pose().centre_mm;
        assert!((pose[1] - (86.0 + 20.0)).abs() < 0.1, "{pose:?}");
        m.home();
        assert_eq!(m.lost_mm(1), 0.0);
    }

    #[test]
    fn same_seed_same_machine_and_homing_error_is_redrawn() {
        let mut a = SimMachine::new(config());
        let mut b = SimMachine::new(config());
        a.home();
        b.home();
        assert_eq!(a.camera_pose(), b.camera_pose());
        let first = a.camera_pose().centre_mm;
        a.home();
        assert_ne!(
            first,
            a.camera_pose().centre_mm,
            "homing error must change per homing"
        );
        let d = (first[0] - a.camera_pose().centre_mm[0]).abs() * 1000.0;
        assert!(d < 30.0, "homing change {d} um is implausible");
    }

    #[test]
    fn moves_quantise_take_time_and_need_homing() {
        let mut m = SimMachine::new(config());
        assert_eq!(
            m.start_move([1.0, 1.0], 1000.0),
            Err(MachineRefusal::NotHomed)
        );
        m.home();
        for bad in [f64::NAN, f64::INFINITY, 0.0, -1.0] {
            assert!(matches!(
                m.start_move([1.0, 1.0], bad),
                Err(MachineRefusal::BadFeed(_))
            ));
        }
        let t0 = m.now_s();
        let d = m.start_move([10.00013, 5.0], 3000.0).unwrap();
        assert!(d > 0.2 && m.is_moving());
        m.advance(d / 2.0);
        assert!(m.is_moving());
        let mid = m.position_mm();
        assert!(mid[0] > 0.5 && mid[0] < 9.5, "{mid:?}");
        m.finish_motion();
        assert!(!m.is_moving());
        assert!(m.now_s() - t0 >= d);
        let cpm = m.config().axes.x.counts_per_mm;
        assert_eq!(m.counts()[0], (10.00013 * cpm).round() as i64);
        assert!(matches!(
            m.start_move([-1.0, 0.0], 1000.0),
            Err(MachineRefusal::OutOfTravel { axis: 'X', .. })
        ));
    }

    #[test]
    fn backlash_shows_on_reversal() {
        let mut cfg = config();
        cfg.axes.x.settle_noise_um = 0.0;
        cfg.axes.y.settle_noise_um = 0.0;
        cfg.thermal = None;
        let b = cfg.axes.x.backlash_um;
        let mut m = SimMachine::new(cfg);
        m.home();
        m.start_move([50.0, 20.0], 3000.0).unwrap();
        m.finish_motion();
        let from_below = m.camera_pose().centre_mm[0];
        m.start_move([60.0, 20.0], 3000.0).unwrap();
        m.finish_motion();
        m.start_move([50.0, 20.0], 3000.0).unwrap();
        m.finish_motion();
        let from_above = m.camera_pose().centre_mm[0];
        let lost = (from_above - from_below) * 1000.0;
        assert!(
            (lost - b).abs() < 0.01,
            "lost motion {lost} um, backlash {b} um"
        );
    }

    /// The coordinated move's figures before the machine became per-axis: counts,
    /// speed and camera pose at fixed times through four moves and a homing, hashed
    /// (recorded from the single straight-line `Motion` this replaced).
    #[test]
    fn coordinated_moves_and_homing_are_bit_for_bit_unchanged() {
        let mut m = SimMachine::new(config());
        m.home();
        let mut trace = Vec::new();
        for (to, feed) in [
            ([50.0, 20.0], 3000.0),
            ([10.5, 140.25], 6000.0),
            ([10.5, 30.0], 800.0),
            ([199.0, 3.0], 20000.0),
        ] {
            let d = m.start_move(to, feed).unwrap();
            for _ in 0..7 {
                m.advance(d / 6.5);
                let p = m.camera_pose();
                trace.push((
                    m.counts(),
                    m.speed_mm_min().to_bits(),
                    p.centre_mm,
                    p.rotation_rad,
                ));
            }
        }
        m.home();
        let p = m.camera_pose();
        trace.push((m.counts(), m.now_s().to_bits(), p.centre_mm, p.rotation_rad));
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        for t in &trace {
            let words = [
                t.0[0] as u64,
                t.0[1] as u64,
                t.1,
                t.2[0].to_bits(),
                t.2[1].to_bits(),
                t.3.to_bits(),
            ];
            for v in words {
                h = (h ^ v).wrapping_mul(0x100_0000_01b3);
            }
        }
        assert_eq!(h, 0x412a_9816_8927_f7c0, "last: {:?}", trace.last());
    }

    /// The old straight-line formula: distance along the line on one trapezoid.
    fn old_line_point(from: [f64; 2], to: [f64; 2], feed: f64, accel: f64, t: f64) -> [f64; 2] {
        let length = ((to[0] - from[0]).powi(2) + (to[1] - from[1]).powi(2)).sqrt();
        let t_acc = feed / accel;
        let d_acc = 0.5 * accel * t_acc * t_acc;
        let (v, duration) = if 2.0 * d_acc >= length {
            let tv = (length / accel).sqrt();
            (accel * tv, 2.0 * tv)
        } else {
            (feed, 2.0 * t_acc + (length - 2.0 * d_acc) / feed)
        };
        if length == 0.0 {
            return to;
        }
        let t_acc = v / accel;
        let s = if t >= duration {
            length
        } else if t < t_acc {
            0.5 * accel * t * t
        } else if t < duration - t_acc {
            0.5 * accel * t_acc * t_acc + v * (t - t_acc)
        } else {
            let r = duration - t;
            length - 0.5 * accel * r * r
        };
        let f = s / length;
        [
            from[0] + f * (to[0] - from[0]),
            from[1] + f * (to[1] - from[1]),
        ]
    }

    #[test]
    fn coordinated_move_follows_the_old_straight_line_formula() {
        let mut m = SimMachine::new(config());
        m.home();
        let c = m.config().clone();
        let cpm = [c.axes.x.counts_per_mm, c.axes.y.counts_per_mm];
        let accel = c.axes.x.accel_mm_s2.min(c.axes.y.accel_mm_s2);
        let vmax = c.axes.x.max_feed_mm_min.min(c.axes.y.max_feed_mm_min);
        for (to, feed) in [
            ([120.0, 80.0], 4000.0),
            ([120.0, 10.0], 9000.0),
            ([0.3, 10.2], 1500.0),
            ([0.3, 10.2], 1500.0),
        ] {
            let from = m.position_mm();
            let d = m.start_move(to, feed).unwrap();
            let mut t = 0.0;
            for _ in 0..40 {
                m.advance(d / 37.0);
                t += d / 37.0;
                let p = old_line_point(from, to, feed.min(vmax) / 60.0, accel, t);
                let want = [
                    (p[0] * cpm[0]).round() as i64,
                    (p[1] * cpm[1]).round() as i64,
                ];
                assert_eq!(m.counts(), want, "{from:?} -> {to:?} at {t} s");
            }
            assert!(!m.is_moving());
        }
    }

    #[test]
    fn axes_move_on_their_own_profiles_and_end_at_their_own_times() {
        let mut m = SimMachine::new(config());
        assert_eq!(
            m.start_axis_move(0, 10.0, 1000.0),
            Err(MachineRefusal::NotHomed)
        );
        m.home_axis(0);
        assert!(m.is_axis_homed(0) && !m.is_axis_homed(1) && !m.is_homed());
        assert_eq!(
            m.start_axis_move(1, 10.0, 1000.0),
            Err(MachineRefusal::NotHomed)
        );
        assert_eq!(
            m.start_move([1.0, 1.0], 1000.0),
            Err(MachineRefusal::NotHomed)
        );
        m.home_axis(1);
        assert!(m.is_homed());
        assert!(matches!(
            m.start_axis_move(1, 150.5, 1000.0),
            Err(MachineRefusal::OutOfTravel { axis: 'Y', .. })
        ));
        let dx = m.start_axis_move(0, 100.0, 6000.0).unwrap();
        let dy = m.start_axis_move(1, 100.0, 1200.0).unwrap();
        assert!(dy > 2.0 * dx, "{dx} {dy}");
        // Y's own feed, X's own (higher) one.
        m.advance(dx / 2.0);
        assert!((m.axis_speed_mm_min(0) - 6000.0).abs() < 1e-6);
        assert!((m.axis_speed_mm_min(1) - 1200.0).abs() < 1e-6);
        m.advance(dx / 2.0 + 1e-9);
        assert!(!m.is_axis_moving(0) && m.is_axis_moving(1) && m.is_moving());
        assert_eq!(m.counts()[0], 200_000);
        assert!(m.counts()[1] > 0 && m.counts()[1] < 200_000);
        m.finish_motion();
        assert!(!m.is_moving());
        assert_eq!(m.counts(), [200_000, 200_000]);
        assert!(
            (m.now_s() - dy).abs() < 1e-6,
            "the slower axis sets the end"
        );
    }

    #[test]
    fn stopping_or_homing_one_axis_leaves_the_other_moving() {
        let mut m = SimMachine::new(config());
        m.home();
        m.start_axis_move(0, 50.0, 3000.0).unwrap();
        m.start_axis_move(1, 40.0, 3000.0).unwrap();
        m.advance(0.2);
        m.stop_axis(0);
        let x = m.counts()[0];
        assert!(!m.is_axis_moving(0) && m.is_axis_moving(1));
        m.finish_motion();
        assert_eq!(m.counts(), [x, 80_000]);
        // Homing X draws X's homing error only and does not touch Y's move.
        m.start_axis_move(1, 10.0, 3000.0).unwrap();
        let y_offset = m.axes[1].home_offset_mm;
        let took = m.home_axis(0);
        assert!(took > 1.0);
        assert_eq!(m.counts()[0], 0);
        assert!(m.is_axis_moving(1));
        assert_eq!(m.axes[1].home_offset_mm, y_offset);
        m.finish_motion();
        assert_eq!(m.counts()[1], 20_000);
        // A per-axis move with a drive's own (gentler) ramp takes longer.
        let fast = m.start_axis_move(0, 20.0, 3000.0).unwrap();
        m.finish_motion();
        let slow = m.start_axis_move_accel(0, 40.0, 3000.0, 100.0).unwrap();
        assert!(slow > fast + 0.3, "{slow} {fast}");
        assert!(matches!(
            m.start_axis_move_accel(0, 40.0, 3000.0, 0.0),
            Err(MachineRefusal::BadAccel(_))
        ));
    }

    #[test]
    fn the_trace_follows_the_path_in_small_steps_and_does_not_change_it() {
        let mut cfg = config();
        cfg.thermal = None;
        cfg.machine.tool_offset_mm = [30.0, -10.0];
        let mut plain = SimMachine::new(cfg.clone());
        let mut traced = SimMachine::new(cfg);
        for m in [&mut plain, &mut traced] {
            m.home();
        }
        traced.start_trace();
        for m in [&mut plain, &mut traced] {
            m.start_move([40.0, 25.0], 3000.0).unwrap();
            m.advance(0.3);
            m.finish_motion();
            m.start_move([12.0, 60.0], 1200.0).unwrap();
            m.finish_motion();
        }
        assert_eq!(plain.position_mm(), traced.position_mm());
        assert_eq!(plain.tool_point_mm(), traced.tool_point_mm());
        let rows = traced.take_trace();
        assert!(rows.len() > 1000, "{} rows", rows.len());
        for w in rows.windows(2) {
            let step = (w[1].cmd_mm[0] - w[0].cmd_mm[0]).hypot(w[1].cmd_mm[1] - w[0].cmd_mm[1]);
            assert!(
                step <= TRACE_STEP_MM + 1e-9,
                "step {step} mm at t = {}",
                w[0].t_s
            );
            assert!(w[1].t_s >= w[0].t_s);
        }
        // Each move's end is a row, exactly on its target.
        for end in [[40.0, 25.0], [12.0, 60.0]] {
            assert!(rows.iter().any(|r| r.cmd_mm == end), "no row at {end:?}");
        }
        // The tool differs from the camera by the yaw acting on the arm (Abbe).
        let cam = traced.camera_pose();
        let tool = traced.tool_point_mm();
        let expected = [-cam.rotation_rad * -10.0, cam.rotation_rad * 30.0];
        for k in 0..2 {
            let d = tool[k] - cam.centre_mm[k];
            // First order in the yaw (the rotation is exact: second-order terms remain).
            assert!(
                (d - expected[k]).abs() < 1e-8,
                "axis {k}: {d} vs {}",
                expected[k]
            );
        }
        assert!(traced.take_trace().is_empty(), "rows are taken once");
    }
}

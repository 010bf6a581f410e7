//! The live pass-through between the operator's G-code sender and a GRBL controller:
//! a pseudo-terminal that answers the sender as GRBL 1.1 would, every line rewritten on
//! its way to the controller, with an error map (on the job's GRBL controller, real or
//! emulated, once the map's identity is checked against the job's devices) or for a
//! rotary table's location errors (on a grblHAL controller with A and C). Sender
//! sessions are served one after another; each ends with an account of its lines.

use crate::command_line::{self, FileArg};
use crate::request::{count, number, RequestError};
use crate::Outcome;
use errormap::reference::{Circumstances, MapReference};
use errormap::MapModel;
use job::{GrblLink, Job, StageSpec};
use protocol::errormap::ErrorMap;
use proxy::{
    serve_with_camera, AfterHoming, Ending, FiveAxisRewriter, InUse, LineAccount, Proxy,
    ReferenceFrames, Rereference, SenderPort,
};
use rewrite::{Approach, Compensation, Options, Pose, Rewriter, N_AXIS};
use rotary::{LocationErrors, MachineConstants};
use serde::{Deserialize, Serialize};
use std::cell::RefCell;
use std::future::Future;
use std::path::Path;
use std::sync::RwLock;
use std::time::Duration;

/// How long to wait for a controller's banner after opening its port (an Arduino resets
/// when the port opens and needs about two seconds).
const BANNER_WAIT: Duration = Duration::from_millis(2500);

/// The largest correction a move may get by default with an error map, um.
pub const MAP_MAX_CORRECTION_UM: f64 = 200.0;
/// ... and for a rotary table, whose A-axis offsets reach tenths of a millimetre, um.
pub const ROTARY_MAX_CORRECTION_UM: f64 = 2000.0;
/// An emulated controller's clock: simulated seconds per wall second, at most.
pub const MAX_TIME_SCALE: f64 = 1e4;

fn default_tolerance() -> f64 {
    0.5
}
fn default_baud() -> u32 {
    115_200
}
fn default_time_scale() -> String {
    "1".into()
}

/// How the pass-through rewrites and runs (on the command line, these are its flags).
/// With an error map (the service's active one; on the command line `--config JOB --map
/// MAP`) on the job's GRBL controller, or with a rotary table's errors on the grblHAL
/// controller at `controller`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields)]
pub struct ProxyRequest {
    /// Largest distance of the executed path from the compensated path, um.
    #[serde(default = "default_tolerance")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_tolerance()))]
    #[schema(default = default_tolerance, minimum = 0.01, maximum = 1000.0)]
    pub tolerance_um: f64,
    /// The largest correction a move may get, um (default 200 um with a map, 2000 um for
    /// a rotary table, whose A-axis offsets reach tenths of a millimetre).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long))]
    #[schema(minimum = 0.001, maximum = 100000.0)]
    pub max_correction_um: Option<f64>,
    /// The rotary table's controller's baud rate (a job's controller has its own).
    #[serde(default = "default_baud")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_baud()))]
    #[schema(default = default_baud, minimum = 1200, maximum = 4000000)]
    pub baud: u32,
    /// An emulated controller's clock: simulated seconds per wall second, or
    /// `unconstrained`.
    #[serde(default = "default_time_scale")]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_time_scale()))]
    #[schema(default = default_time_scale)]
    pub time_scale: String,
    /// Serve one sender session, then end.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long))]
    pub once: bool,
    /// Apply the map as scanned, without its recorded reference (the reference after
    /// the last homing).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, requires = "map"))]
    pub no_reference: bool,
    /// Also create a symlink to the sender's port at this path.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long))]
    pub link: Option<String>,
    /// The rotary table's errors (the JSON `gateway rotary measure` or `identify`
    /// writes): the pass-through corrects for them on the controller at `controller`.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(skip))]
    #[schema(format = Binary, max_length = 16777216)]
    pub rotary: Option<String>,
    /// How messages name the rotary errors (their file name).
    #[serde(default = "default_rotary_name")]
    #[cfg_attr(feature = "cli", arg(skip = default_rotary_name()))]
    #[schema(default = default_rotary_name)]
    pub rotary_name: String,
    /// The rotary table's machine constants; default: those recorded with the errors.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(skip))]
    #[schema(value_type = Option<Object>)]
    pub machine: Option<MachineConstants>,
    /// The rotary table's controller's serial port (a grblHAL build with A and C).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, requires = "rotary"))]
    pub controller: Option<String>,
    /// Re-reference the map in use every this many seconds as well as after the
    /// sender's homing (the shift and each axis's scale, as `gateway reference
    /// --no-home` measures them: the screws grow as the machine warms). A due one starts
    /// when every line is answered, the controller is idle and the tool is at or above
    /// `clear_z_mm`; it needs the job's camera. Default: only after a homing.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, requires = "clear_z_mm"))]
    #[schema(minimum = 30.0, maximum = 86400.0)]
    pub reference_every_s: Option<f64>,
    /// Machine Z (mm, the controller's `MPos`) at or above which the tool is clear of
    /// the work and the clamps: a re-reference in use moves X and Y only there, and
    /// never Z. No default: only the shop knows its fixtures.
    #[serde(default)]
    #[cfg_attr(
        feature = "cli",
        arg(long, requires = "reference_every_s", allow_hyphen_values = true)
    )]
    #[schema(minimum = -10000.0, maximum = 10000.0)]
    pub clear_z_mm: Option<f64>,
}

/// The largest rotary errors file a request carries.
const MAX_ERRORS_BYTES: usize = 16 << 20;

fn default_rotary_name() -> String {
    "errors.json".into()
}

impl Default for ProxyRequest {
    fn default() -> Self {
        Self {
            tolerance_um: default_tolerance(),
            max_correction_um: None,
            baud: default_baud(),
            time_scale: default_time_scale(),
            once: false,
            no_reference: false,
            link: None,
            rotary: None,
            rotary_name: default_rotary_name(),
            machine: None,
            controller: None,
            reference_every_s: None,
            clear_z_mm: None,
        }
    }
}

impl ProxyRequest {
    pub fn check(&self) -> Result<(), RequestError> {
        // The rewriters' own floor: 0.01 um.
        number("tolerance_um", self.tolerance_um, 0.01, 1000.0)?;
        if let Some(m) = self.max_correction_um {
            number("max_correction_um", m, 1e-3, 1e5)?;
        }
        count("baud", self.baud.into(), 1200, 4_000_000)?;
        self.clock()?;
        match (&self.rotary, &self.controller) {
            (Some(_), None) => {
                return Err(RequestError::new(
                    "controller",
                    "the rotary table's pass-through needs its grblHAL controller's port",
                ));
            }
            (None, Some(_)) => {
                return Err(RequestError::new(
                    "controller",
                    "a controller port is for the rotary table's errors (`rotary`)",
                ))
            }
            _ => {}
        }
        if self
            .rotary
            .as_ref()
            .is_some_and(|t| t.len() > MAX_ERRORS_BYTES)
        {
            return Err(RequestError::new("rotary", "more than 16 MiB of errors"));
        }
        match (self.reference_every_s, self.clear_z_mm) {
            (Some(every), Some(z)) => {
                number("reference_every_s", every, 30.0, 86_400.0)?;
                number("clear_z_mm", z, -10_000.0, 10_000.0)?;
                if self.rotary.is_some() {
                    return Err(RequestError::new(
                        "reference_every_s",
                        "re-referencing in use is for an error map, not a rotary table's errors",
                    ));
                }
                if self.no_reference {
                    return Err(RequestError::new(
                        "reference_every_s",
                        "re-referencing in use records references: not with no_reference",
                    ));
                }
            }
            (Some(_), None) => {
                return Err(RequestError::new(
                    "clear_z_mm",
                    "re-referencing in use needs the machine Z at or above which the tool is \
                     clear of the work and the clamps",
                ))
            }
            (None, Some(_)) => {
                return Err(RequestError::new(
                    "clear_z_mm",
                    "is for re-referencing in use (reference_every_s)",
                ))
            }
            (None, None) => {}
        }
        if let Some(link) = &self.link {
            if link.is_empty() || link.len() > 4096 || link.contains('\0') {
                return Err(RequestError::new(
                    "link",
                    "must be a path (1 to 4096 bytes)",
                ));
            }
        }
        Ok(())
    }

    /// The emulated controller's clock, checked.
    pub fn clock(&self) -> Result<world::Clock, RequestError> {
        let clock = self
            .time_scale
            .parse::<world::Clock>()
            .map_err(|e| RequestError::new("time_scale", e.to_string()))?;
        if let world::Clock::Scaled(k) = clock {
            number("time_scale", k, 1e-3, MAX_TIME_SCALE)?;
        }
        Ok(clock)
    }

    fn max_correction_mm(&self, default_um: f64) -> f64 {
        self.max_correction_um.unwrap_or(default_um) / 1000.0
    }
}

/// What the pass-through corrects for, read by the front end.
pub enum Correction {
    /// An error map, on the job's GRBL controller. `job_source` and `map_source` name
    /// them in messages.
    Map {
        job: Box<Job>,
        job_source: String,
        map: Box<ErrorMap>,
        map_source: String,
        /// The map's current reference, none recorded, or none wanted
        /// ([`crate::reference::choose`]).
        reference: crate::reference::Choice,
    },
    /// A rotary table's location errors (`source` names them), on the grblHAL controller
    /// at `controller`.
    Rotary {
        errors: LocationErrors,
        constants: MachineConstants,
        source: String,
        controller: String,
    },
}

impl Correction {
    /// The correction the request and the context choose: the rotary table's errors
    /// (their recorded constants; `machine`, when given, must agree with them), or the
    /// context's job, its error map and the map's recorded reference (unless
    /// `no_reference`: [`crate::reference::choose`]).
    pub fn of(request: &ProxyRequest, cx: &mut dyn crate::Context) -> Result<Self, crate::Error> {
        if let Some(text) = &request.rotary {
            let name = &request.rotary_name;
            let at = |e: String| crate::Error::input(name, e);
            let stored = MachineConstants::from_errors_json(text).map_err(at)?;
            let differs = |e: String| crate::Error::Mismatch(format!("{name}: {e}"));
            return Ok(Correction::Rotary {
                errors: LocationErrors::from_json(text).map_err(|e| at(e.to_string()))?,
                constants: MachineConstants::for_errors(stored, request.machine, false)
                    .map_err(differs)?,
                source: name.clone(),
                controller: request.controller.clone().unwrap_or_default(),
            });
        }
        let job = cx.job().map_err(|e| {
            crate::Error::Input(format!(
                "{e}: the pass-through runs with a job's GRBL controller and its error map \
                 (`--config JOB --map MAP`), or with a rotary table's errors on its grblHAL \
                 controller (`--rotary ERRORS --controller PORT`)"
            ))
        })?;
        let active = cx.map().map_err(|e| crate::Error::Input(e.to_string()))?;
        Ok(Correction::Map {
            job_source: job.source.clone(),
            job: Box::new(job),
            map: Box::new(active.map),
            map_source: active.name,
            reference: crate::reference::choose(active.reference, request.no_reference)?,
        })
    }
}

/// What the pass-through gives: its result is the last session's account; its partial
/// results (the sink's) are the ready message, each earlier session's account and each
/// reference recorded after the sender's homing. One type, so the summary reads each.
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(untagged)]
pub enum ProxyResult {
    /// The sender's port is ready.
    Ready(#[schema(inline)] ProxyReady),
    /// A reference recorded after the sender's homing.
    Reference(#[schema(inline)] ProxyReference),
    /// A session's account.
    Session(#[schema(inline)] ProxySession),
}

/// The sender's port is ready (before any session).
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ProxyReady {
    /// The pseudo-terminal to point the G-code sender at.
    pub sender_port: String,
    /// The controller's port.
    pub controller: String,
    /// The compensation in one line.
    pub compensation: String,
    /// The same (older readers' name).
    pub map: String,
    /// Which reference the map runs with (null: no map).
    pub reference: Option<String>,
    /// What running without a recorded reference costs.
    pub reference_warning: Option<String>,
    /// What happens after the sender's homing (null: not applicable).
    pub after_homing: Option<String>,
    /// A symlink to `sender_port` (the command line's `--link`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub link: Option<String>,
}

/// A reference the pass-through recorded after the sender's homing.
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ProxyReference {
    /// Where it was kept (a file beside the map, the map's profile).
    pub reference_recorded: String,
    /// Its number since the scan.
    pub reference_count: u64,
    /// The machine zero's shift, um.
    pub shift_um: [f64; 2],
}

/// A session's account.
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ProxySession {
    /// How it ended: `sender left`, `controller lost`, `stopped`.
    pub ending: String,
    /// The sender's lines by fate.
    #[schema(inline)]
    pub lines: LineFates,
    /// Lines the sender sent.
    pub lines_received: u64,
    /// Pieces sent to the controller.
    pub pieces_sent: u64,
    /// Times the controller's buffer ran dry while lines waited.
    pub starvation_events: u64,
    /// The rewrite of one line, ms.
    #[schema(inline)]
    pub rewrite_ms: Quantiles,
    /// From a line's arrival to its first piece out, ms.
    #[schema(inline)]
    pub first_piece_out_ms: Quantiles,
    /// Largest |command - nominal|, um.
    pub largest_correction_um: f64,
    /// Pieces added by splitting moves.
    pub segments_added: usize,
}

/// Line numbers of the sender's program as ranges (`1-3, 7`, or `none`).
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
pub struct LineFates {
    /// Acknowledged by the controller.
    pub acknowledged: String,
    /// Refused by the controller.
    pub refused: String,
    /// In the controller when the session ended.
    pub in_controller: String,
    /// Never sent.
    pub not_sent: String,
}

/// The median and the 99th percentile, ms.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Quantiles {
    pub median: f64,
    pub p99: f64,
}

/// What a front end does while the pass-through runs.
pub trait ProxyFront {
    /// The sender's port is ready (before any session).
    fn ready(&mut self, hello: &ProxyReady) -> Result<(), crate::Error>;
    /// A session ended and another follows: its account (as [`Outcome::result`] is for
    /// the last one).
    fn session(&mut self, account: &ProxySession) -> Result<(), crate::Error>;
    /// The pass-through re-referenced the map after the sender's homing: keep the record
    /// as the map's current reference (the CLI writes it beside the map).
    fn reference(&mut self, record: &MapReference) -> Result<(), crate::Error> {
        let _ = record;
        Ok(())
    }
}

/// An error map whose reference the pass-through changes after a homing, while the
/// rewriter holds it.
pub struct SharedMap {
    model: RwLock<MapModel>,
    axes: Vec<usize>,
}

impl SharedMap {
    pub fn new(model: MapModel) -> Self {
        let axes = model.axes().to_vec();
        Self {
            model: RwLock::new(model),
            axes,
        }
    }

    pub fn read(&self) -> std::sync::RwLockReadGuard<'_, MapModel> {
        self.model.read().unwrap_or_else(|e| e.into_inner())
    }

    /// The map with a new reference from now on (the rewriter reads it at its next
    /// line).
    pub fn replace(&self, model: MapModel) {
        *self.model.write().unwrap_or_else(|e| e.into_inner()) = model;
    }
}

/// The pass-through's re-reference of `map` (the one the session runs with, unshifted):
/// the points `gateway reference` measures (the reference point, then each axis's scale
/// point when the map reaches far enough: [`errormap::reference::scale_points_mm`]),
/// averaged over as many arrivals, approached by `approach_mm`. Its hook makes the
/// record from the means as `gateway reference` does (continuing `previous`, the
/// reference in force, and replacing it), applies it to `shared`, then hands it to
/// `recorded` (with its description) before the machine returns.
pub fn map_rereference<'a>(
    map: &'a ErrorMap,
    shared: &'a SharedMap,
    approach_mm: f64,
    bound_um: f64,
    in_use: Option<InUse>,
    previous: &'a RefCell<Option<MapReference>>,
    mut recorded: impl FnMut(&MapReference, &str) -> Result<(), crate::Error> + 'a,
) -> Rereference<'a> {
    let scale_at = errormap::reference::scale_points_mm(map);
    let r = map.reference_mm;
    let (points_mm, arrivals) = match scale_at {
        Some(at) => (
            vec![r, [at[0], r[1]], [r[0], at[1]]],
            runner::reference::FRAMES_PER_POINT,
        ),
        None => (vec![r], 1),
    };
    let hook = move |means: &[[f64; 2]]| -> Result<String, String> {
        let (now_s, now_text) = crate::reference::at(std::time::SystemTime::now());
        let before = previous.borrow().clone();
        let before = before.filter(|p| p.check_map(map).is_ok());
        let record = MapReference::new(
            map,
            means[0],
            bound_um,
            Circumstances {
                measured_at: now_text,
                measured_unix_s: now_s,
                homing_count: None,
                temperature_c: None,
                previous_count: before.as_ref().map_or(0, |p| p.reference_count),
            },
        )
        .and_then(|record| match (scale_at, means) {
            (Some(at), [_, x, y]) => record.with_scale(map, at, [x[0], y[1]], before.as_ref()),
            _ => Ok(record),
        })
        .map_err(|e| e.to_string())?;
        let model = record
            .apply(MapModel::new(map.clone()), now_s)
            .map_err(|e| e.to_string())?;
        let describe = record.describe(now_s);
        shared.replace(model);
        recorded(&record, &describe).map_err(|e| e.to_string())?;
        *previous.borrow_mut() = Some(record);
        Ok(describe)
    };
    Rereference {
        points_mm,
        approach_mm,
        arrivals,
        in_use,
        hook: Box::new(hook),
    }
}

/// When a session's first re-reference in use is due (its clock starts at 0):
/// `every_s` after the reference in force was measured, at once when that is older.
pub fn first_due_s(every_s: f64, previous: Option<&MapReference>) -> f64 {
    let now_s = crate::context::unix_s(std::time::SystemTime::now());
    let age = previous.map_or(f64::INFINITY, |p| p.age_s(now_s) as f64);
    (every_s - age).clamp(0.0, every_s)
}

impl Compensation for SharedMap {
    fn describe(&self) -> String {
        Compensation::describe(&*self.read())
    }
    fn axes(&self) -> &[usize] {
        &self.axes
    }
    fn feature_length_mm(&self) -> f64 {
        Compensation::feature_length_mm(&*self.read())
    }
    fn command_for(&self, nominal: &Pose, approach: &[Approach; N_AXIS]) -> Result<Pose, String> {
        Compensation::command_for(&*self.read(), nominal, approach)
    }
    fn command_near(
        &self,
        nominal: &Pose,
        approach: &[Approach; N_AXIS],
        guess: &Pose,
    ) -> Result<Pose, String> {
        Compensation::command_near(&*self.read(), nominal, approach, guess)
    }
    fn tool_for(&self, command: &Pose, approach: &[Approach; N_AXIS]) -> Result<Pose, String> {
        Compensation::tool_for(&*self.read(), command, approach)
    }
}

/// The job's camera measuring the re-reference's frames for the pass-through.
pub struct CameraFrames<'a> {
    pub camera: Box<dyn drivers::Camera>,
    pub job: &'a Job,
}

impl ReferenceFrames for CameraFrames<'_> {
    fn measure(
        &mut self,
        at_mm: [f64; 2],
    ) -> std::pin::Pin<Box<dyn Future<Output = Result<[f64; 2], String>> + '_>> {
        Box::pin(async move {
            let z = self.job.board_at_machine_zero_mm;
            let target = [at_mm[0] + z[0], at_mm[1] + z[1]];
            let frame = self.camera.grab().await.map_err(|e| e.to_string())?;
            let at = runner::measure::At {
                path: &[],
                target_mm: target,
                index: 0,
                measurement: 0,
                free_on_coded_board: true,
            };
            let o = runner::measure::localize_frame(self.job, &frame, at)
                .map_err(|e| format!("the reference frame: {e}"))?;
            Ok([(o.x_mm - target[0]) * 1000.0, (o.y_mm - target[1]) * 1000.0])
        })
    }
}

/// Runs the pass-through: checks the request; with a map, checks its identity against
/// the job's devices and needs the job's stage to be a GRBL controller (an emulated one
/// is started on the request's clock); opens the controller's port, creates the
/// sender's pseudo-terminal (with a symlink at `sender_link`), tells the front it is
/// ready, and serves sender sessions until `stop` (Ctrl-C), the controller is lost, or
/// (with `once`) after the first. Every session but the last goes to the front as it
/// ends; the last one's account is the result (a lost controller fails the outcome,
/// with that account).
pub async fn run(
    request: &ProxyRequest,
    correction: Correction,
    sender_link: Option<&Path>,
    front: &mut dyn ProxyFront,
    stop: impl Future<Output = ()>,
) -> Outcome<ProxySession> {
    if let Err(e) = request.check() {
        return Outcome::failed(e.to_string());
    }
    let stop = std::pin::pin!(stop);
    match correction {
        Correction::Map {
            job,
            job_source,
            map,
            map_source,
            reference,
        } => {
            // The map must belong to this machine, controller, board certificate and
            // camera: the one identity check of every procedure, on the job's devices
            // (opened, asked, closed) before the controller's port is opened.
            let here = match crate::identity_of_job(&job).await {
                Ok(h) => h,
                Err(e) => return Outcome::failed(e),
            };
            if let Err(e) = crate::check_identity(&map, &here, &map_source) {
                return Outcome::failed(e);
            }
            let applied =
                match crate::reference::apply(*map, &reference, std::time::SystemTime::now()) {
                    Ok(a) => a,
                    Err(e) => return Outcome::failed(format!("{map_source}: {e}")),
                };
            let shared = SharedMap::new(applied.model);
            let map_copy = shared.read().map().clone();
            let bound_um =
                crate::reference::shift_bound_um(&job, errormap::reference::MAX_SHIFT_UM);
            let previous = RefCell::new(match &reference {
                crate::reference::Choice::Recorded(r) => Some(r.clone()),
                _ => None,
            });
            let current = RefCell::new(applied.describe.clone());
            let StageSpec::Grbl { link, baud } = &job.stage else {
                return Outcome::failed(format!(
                    "{job_source}: the pass-through needs a GRBL controller (stage kind `grbl`); other controllers take the map as a table (gateway export)"
                ));
            };
            let options = Options {
                tolerance_mm: request.tolerance_um / 1000.0,
                max_correction_mm: request.max_correction_mm(MAP_MAX_CORRECTION_UM),
                ..Options::default()
            };
            // Kept until the sessions end: the emulated controller and its machine.
            let (port, emulator) = match link {
                GrblLink::Port(p) => (p.clone(), None),
                GrblLink::Emulate(machine) => {
                    let clock = match request.clock() {
                        Ok(c) => c,
                        Err(e) => return Outcome::failed(e.to_string()),
                    };
                    match devices::spawn_grbl_emulator(&job, machine, clock) {
                        Ok((emulator, rig)) => (emulator.path().to_string(), Some((emulator, rig))),
                        Err(e) => return Outcome::failed(e.to_string()),
                    }
                }
            };
            // The job's camera re-references the map after the sender's homing; without
            // one, motion after a homing is refused until a reference is recorded.
            let wanted = reference != crate::reference::Choice::NotWanted;
            let camera = match wanted {
                true => devices::open_camera(&job.camera, emulator.as_ref().map(|(_, rig)| rig))
                    .await
                    .map_err(|e| e.to_string()),
                false => Err("--no-reference".into()),
            };
            let (mut frames, camera_note) = match camera {
                Ok(camera) => (Some(CameraFrames { camera, job: &job }), None),
                Err(e) => (None, Some(e)),
            };
            let in_use = request.reference_every_s.zip(request.clear_z_mm);
            if let (Some(_), Some(e)) = (in_use, &camera_note) {
                return Outcome::failed(format!(
                    "--reference-every-s: re-referencing in use needs the job's camera: {e}"
                ));
            }
            let scale = match errormap::reference::scale_points_mm(&map_copy) {
                Some(_) => " (its shift and each axis's scale)",
                None => "",
            };
            let after_homing_note = match (&camera_note, wanted, in_use) {
                (_, false, _) => None,
                (None, true, None) => Some(format!("after the sender's homing the gateway re-references the map{scale} with the camera")),
                (None, true, Some((every, z))) => Some(format!(
                    "the gateway re-references the map{scale} with the camera after the sender's homing, and every {every:.0} s in use when the controller is idle and the tool at or above machine Z {z:.3}"
                )),
                (Some(e), true, _) => Some(format!(
                    "no camera ({e}): after the sender's homing, motion is refused (error:9) until a reference is recorded"
                )),
            };
            let served = Served {
                port: &port,
                baud: *baud,
                describe: &shared.describe(),
                reference: Some((&applied.describe, applied.warning.as_deref())),
                after_homing: after_homing_note.as_deref(),
                sender_link,
                once: request.once,
            };
            let front = RefCell::new(front);
            let have_camera = frames.is_some();
            let make = || {
                let rewriter = Rewriter::new(&shared, options.clone())
                    .map_err(|e| crate::Error::Refused(e.to_string()))?;
                let mut proxy = Proxy::new(rewriter, &shared);
                proxy.greet(&format!("map {}", current.borrow()));
                proxy.after_homing(match (wanted, have_camera) {
                    (false, _) => AfterHoming::Pass,
                    (true, false) => AfterHoming::Refuse,
                    (true, true) => AfterHoming::Reference(map_rereference(
                        &map_copy,
                        &shared,
                        job.policy.approach_mm,
                        bound_um,
                        in_use.map(|(every_s, clear_z_mm)| InUse {
                            every_s,
                            clear_z_mm,
                            first_due_s: first_due_s(every_s, previous.borrow().as_ref()),
                        }),
                        &previous,
                        |record, describe| {
                            *current.borrow_mut() = describe.to_string();
                            front.borrow_mut().reference(record)
                        },
                    )),
                });
                Ok(proxy)
            };
            let frames = frames.as_mut().map(|f| f as &mut dyn ReferenceFrames);
            sessions(served, &front, stop, make, frames).await
        }
        Correction::Rotary {
            errors,
            constants,
            source,
            controller,
        } => {
            let model = rotary::RotaryMachine::with_errors(constants, errors);
            let options = rotary::rewrite::RewriteOptions {
                tolerance_mm: request.tolerance_um / 1000.0,
                max_correction_mm: request.max_correction_mm(ROTARY_MAX_CORRECTION_UM),
                ..Default::default()
            };
            let served = Served {
                port: &controller,
                baud: request.baud,
                describe: &format!("rotary table errors {source}"),
                reference: None,
                after_homing: None,
                sender_link,
                once: request.once,
            };
            let front = RefCell::new(front);
            let make = || {
                Ok(Proxy::with_rewriter(Box::new(FiveAxisRewriter::new(
                    rotary::rewrite::RotaryRewriter::new(&model, options),
                ))))
            };
            sessions(served, &front, stop, make, None).await
        }
    }
}

/// Where and how the sessions are served.
struct Served<'a> {
    port: &'a str,
    baud: u32,
    describe: &'a str,
    /// With a map: which reference it runs with, and a warning when none is recorded.
    reference: Option<(&'a str, Option<&'a str>)>,
    /// What happens after the sender's homing, when it matters.
    after_homing: Option<&'a str>,
    sender_link: Option<&'a Path>,
    once: bool,
}

/// Serves sender sessions one after another (or one with `once`) until `stop` or the
/// controller is lost, each with a fresh pass-through from `make`.
async fn sessions<'m>(
    s: Served<'_>,
    front: &RefCell<&mut dyn ProxyFront>,
    mut stop: std::pin::Pin<&mut impl Future<Output = ()>>,
    mut make: impl FnMut() -> Result<Proxy<'m>, crate::Error>,
    mut frames: Option<&mut dyn ReferenceFrames>,
) -> Outcome<ProxySession> {
    let mut controller = match drivers::open_grbl_line(s.port, s.baud, BANNER_WAIT).await {
        Ok((c, _banner)) => c,
        Err(e) => return Outcome::failed(e.to_string()),
    };
    let mut sender = match SenderPort::create(s.sender_link) {
        Ok(p) => p,
        Err(e) => return Outcome::failed(format!("creating the sender's pseudo-terminal: {e}")),
    };
    let hello = ProxyReady {
        sender_port: sender.path().into(),
        controller: s.port.into(),
        compensation: s.describe.into(),
        map: s.describe.into(),
        reference: s.reference.map(|r| r.0.into()),
        reference_warning: s.reference.and_then(|r| r.1).map(Into::into),
        after_homing: s.after_homing.map(Into::into),
        link: None,
    };
    if let Err(e) = front.borrow_mut().ready(&hello) {
        return Outcome::failed(e);
    }
    loop {
        let mut proxy = match make() {
            Ok(p) => p,
            Err(e) => return Outcome::failed(e),
        };
        proxy.start();
        // A reborrow for this session (`as_deref_mut` would keep the trait object's
        // own lifetime, which the next iteration cannot borrow again).
        #[allow(clippy::option_as_ref_deref)]
        let frames_now = frames
            .as_mut()
            .map(|f| -> &mut dyn ReferenceFrames { &mut **f });
        let ending = serve_with_camera(
            &mut proxy,
            &mut sender,
            &mut controller,
            stop.as_mut(),
            frames_now,
        )
        .await;
        let (account, lost) = session_account(&proxy, &ending);
        let metrics = [
            ("lines_received", account.lines_received.into()),
            ("pieces_sent", account.pieces_sent.into()),
            ("starvation_events", account.starvation_events.into()),
            (
                "largest_correction_um",
                account.largest_correction_um.into(),
            ),
            ("segments_added", account.segments_added.into()),
        ];
        let metrics = metrics.into_iter().map(|(k, v)| (k.into(), v)).collect();
        if let Some(why) = lost {
            return Outcome::stopped(
                false,
                format!("controller lost: {why}"),
                Some(account),
                metrics,
                true,
            );
        }
        if matches!(ending, Ending::Stopped(_)) || s.once {
            return Outcome::succeeded(account, metrics);
        }
        if let Err(e) = front.borrow_mut().session(&account) {
            return Outcome::failed(e);
        }
    }
}

/// Line numbers as ranges: `1-3, 7`, or `none`.
fn ranges(lines: &[u64]) -> String {
    let mut out: Vec<String> = Vec::new();
    let mut k = 0;
    while k < lines.len() {
        let start = lines[k];
        let mut end = start;
        while k + 1 < lines.len() && lines[k + 1] == end + 1 {
            k += 1;
            end = lines[k];
        }
        out.push(if start == end {
            start.to_string()
        } else {
            format!("{start}-{end}")
        });
        k += 1;
    }
    if out.is_empty() {
        "none".into()
    } else {
        out.join(", ")
    }
}

impl LineFates {
    fn of(a: &LineAccount) -> Self {
        Self {
            acknowledged: ranges(&a.acknowledged),
            refused: ranges(&a.refused),
            in_controller: ranges(&a.in_controller),
            not_sent: ranges(&a.not_sent),
        }
    }
}

impl Quantiles {
    /// Of seconds, in ms.
    fn of_s(v: &[f64]) -> Self {
        Self {
            median: quantile_ms(v, 0.5),
            p99: quantile_ms(v, 0.99),
        }
    }
}

/// The `q` quantile of seconds, in ms (0 for none).
fn quantile_ms(v: &[f64], q: f64) -> f64 {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    if v.is_empty() {
        0.0
    } else {
        v[((v.len() - 1) as f64 * q).round() as usize] * 1000.0
    }
}

/// A session's account, and why the controller was lost if it was.
fn session_account(proxy: &Proxy<'_>, ending: &Ending) -> (ProxySession, Option<String>) {
    let stats = proxy.stats();
    let (lat, work) = (&stats.latencies_s, &stats.processing_s);
    let (what, lines, lost) = match ending {
        Ending::SenderLeft(a) => ("sender left", a, None),
        Ending::ControllerLost { why, lines } => ("controller lost", lines, Some(why.clone())),
        Ending::Stopped(a) => ("stopped", a, None),
    };
    let (largest, added) = proxy.rewriter().summary();
    let account = ProxySession {
        ending: what.into(),
        lines: LineFates::of(lines),
        lines_received: stats.lines,
        pieces_sent: stats.pieces_sent,
        starvation_events: stats.starvation_events,
        rewrite_ms: Quantiles::of_s(work),
        first_piece_out_ms: Quantiles::of_s(lat),
        largest_correction_um: largest,
        segments_added: added,
    };
    (account, lost)
}

/// The pass-through as a registered kind: the sender's port opens on the box running it
/// (the command line's, or the service's box) and serves until stopped (Ctrl-C, the
/// job's cancel) or, with `once`, after one session. Its partial results are the ready
/// message (the sender's port), each session but the last, and each reference recorded
/// after the sender's homing; its result is the last session's account.
pub struct PassThrough;

impl crate::registry::Checked for ProxyRequest {
    fn check(&self) -> Result<(), RequestError> {
        ProxyRequest::check(self)
    }
}

impl crate::registry::Procedure for PassThrough {
    const KIND: &'static str = "proxy";
    const TITLE: &'static str = "Pass-through: a port that answers as a GRBL controller to the G-code sender you already use (UGS, CNCjs, bCNC), every line rewritten with the error map (or a rotary table's errors) and streamed to the controller. Status reports show the programmed position";
    const COMMAND: &'static str = "proxy";
    const LABEL: &'static str = "Pass-through for a G-code sender";
    const HELP: &'static str = "Opens a port on the gateway box that answers as a GRBL controller to the G-code sender the shop already uses, and streams every line to the machine rewritten with the active error map, until the job is cancelled. Its first line names the port to point the sender at.";
    const FIELD_HELP: &'static [(&'static str, &'static str)] = &[
        ("once", "End after the sender's first session."),
        (
            "no_reference",
            "Apply the map as scanned, without the reference recorded after the last homing.",
        ),
    ];
    const USES: crate::registry::Uses = crate::registry::Uses::LINK;
    const COMMAND_LINE_ONLY: &'static [&'static str] =
        &["link", "controller", "rotary", "rotary_name", "machine"];
    type Request = ProxyRequest;
    type Result = ProxyResult;
    const FILES: &'static [FileArg] = &[
        FileArg::flag(
            "config",
            "The job file (its stage must be a GRBL controller, real or emulated); with --map.",
            command_line::job,
        )
        .requires(&["map"]),
        FileArg::flag(
            "map",
            "The error map (a version file written by `gateway map`).",
            command_line::map,
        )
        .requires(&["config"]),
        FileArg::flag(
            "rotary",
            "The rotary table's errors (the JSON `gateway rotary measure` or `identify` writes); with --controller.",
            |path, plan| {
                plan.text(path, "rotary", Some("rotary_name"), crate::rotary::read_errors_file)
            },
        )
        .conflicts(&["config", "map"])
        .requires(&["controller"]),
        FileArg::flag(
            "machine",
            "The machine constants of the rotary table (JSON), default those recorded with the errors.",
            |path, plan| {
                plan.set("machine", crate::rotary::read_machine_file(path)?);
                plan.inputs.push(path.to_path_buf());
                Ok(())
            },
        )
        .requires(&["rotary"]),
    ];

    async fn run(request: ProxyRequest, cx: &mut dyn crate::Context) -> Outcome<ProxyResult> {
        let correction = match Correction::of(&request, cx) {
            Ok(c) => c,
            Err(e) => return Outcome::failed(e),
        };
        let stop = cx.stop();
        let link = request.link.clone();
        let mut front = ContextFront {
            cx,
            link: link.clone(),
        };
        run(
            &request,
            correction,
            link.as_deref().map(Path::new),
            &mut front,
            stop.requested(),
        )
        .await
        .map_result(ProxyResult::Session)
    }

    fn uses_map(request: &ProxyRequest) -> bool {
        request.rotary.is_none()
    }

    fn summary(result: &ProxyResult) -> String {
        match result {
            ProxyResult::Ready(hello) => ready_summary(hello, hello.link.as_deref().map(Path::new)),
            ProxyResult::Reference(r) => format!(
                "after the sender's homing: reference #{} recorded in {}, machine zero shift ({:+.2}, {:+.2}) um\n",
                r.reference_count, r.reference_recorded, r.shift_um[0], r.shift_um[1]
            ),
            ProxyResult::Session(account) => summary(account),
        }
    }
}

/// The pass-through's front: its partial results go to the context's sink, the
/// references it records to the context (beside the map, or the map's profile).
struct ContextFront<'a> {
    cx: &'a mut dyn crate::Context,
    link: Option<String>,
}

impl ProxyFront for ContextFront<'_> {
    fn ready(&mut self, hello: &ProxyReady) -> Result<(), crate::Error> {
        let hello = ProxyReady {
            link: self.link.clone(),
            ..hello.clone()
        };
        self.partial(&ProxyResult::Ready(hello))
    }

    fn session(&mut self, account: &ProxySession) -> Result<(), crate::Error> {
        self.partial(&ProxyResult::Session(account.clone()))
    }

    fn reference(&mut self, record: &MapReference) -> Result<(), crate::Error> {
        let kept = (self.cx.keep_reference(record))
            .map_err(|e| crate::Error::Output(format!("recording the reference: {e}")))?;
        self.partial(&ProxyResult::Reference(ProxyReference {
            reference_recorded: kept,
            reference_count: record.reference_count,
            shift_um: record.shift_um,
        }))
    }
}

impl ContextFront<'_> {
    /// A partial result to the sink (its JSON).
    fn partial(&mut self, result: &ProxyResult) -> Result<(), crate::Error> {
        let v = serde_json::to_value(result)
            .map_err(|e| crate::Error::Output(format!("a partial result: {e}")))?;
        self.cx.sink().partial_result(&v);
        Ok(())
    }
}

/// The ready message as text: the sender's port (and `link`, a symlink to it), the
/// controller and the compensation.
pub fn ready_summary(hello: &ProxyReady, link: Option<&Path>) -> String {
    let mut t = format!("sender port: {}\n", hello.sender_port);
    if let Some(l) = link {
        t += &format!("link: {}\n", l.display());
    }
    t += &format!(
        "controller: {}; compensation: {}\n",
        hello.controller, hello.compensation
    );
    if let Some(r) = &hello.reference {
        t += &format!("map {r}\n");
    }
    if let Some(w) = &hello.reference_warning {
        t += &format!("warning: {w}\n");
    }
    if let Some(a) = &hello.after_homing {
        t += &format!("{a}\n");
    }
    t
}

/// A session's account as text (the CLI's output without `--json`).
pub fn summary(r: &ProxySession) -> String {
    format!(
        "session ended ({}): {} lines received, {} pieces sent, {} starvation events\n  \
         rewrite per line: median {:.3} ms, p99 {:.3} ms; arrival to first piece out: median {:.3} ms, p99 {:.3} ms\n  \
         acknowledged: {}\n  refused: {}\n  in the controller when it ended: {}\n  never sent: {}\n",
        r.ending,
        r.lines_received,
        r.pieces_sent,
        r.starvation_events,
        r.rewrite_ms.median,
        r.rewrite_ms.p99,
        r.first_piece_out_ms.median,
        r.first_piece_out_ms.p99,
        r.lines.acknowledged,
        r.lines.refused,
        r.lines.in_controller,
        r.lines.not_sent,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn the_defaults_pass() {
        let r = ProxyRequest::default();
        r.check().unwrap();
        assert_eq!(r.clock().unwrap(), world::Clock::Scaled(1.0));
        assert_eq!(r.max_correction_mm(MAP_MAX_CORRECTION_UM), 0.2);
        assert_eq!(r.max_correction_mm(ROTARY_MAX_CORRECTION_UM), 2.0);
        let r: ProxyRequest =
            serde_json::from_value(json!({"time_scale": "unconstrained", "once": true})).unwrap();
        assert_eq!(r.clock().unwrap(), world::Clock::Unconstrained);
        assert!(serde_json::from_value::<ProxyRequest>(json!({"tolerance": 1})).is_err());
    }

    #[test]
    fn nan_and_absurd_values_are_refused_naming_the_field() {
        let field = |f: &dyn Fn(&mut ProxyRequest)| {
            let mut r = ProxyRequest::default();
            f(&mut r);
            r.check().unwrap_err().field
        };
        assert_eq!(field(&|r| r.tolerance_um = f64::NAN), "tolerance_um");
        assert_eq!(field(&|r| r.tolerance_um = 0.0), "tolerance_um");
        assert_eq!(field(&|r| r.tolerance_um = 1e9), "tolerance_um");
        assert_eq!(
            field(&|r| r.max_correction_um = Some(f64::NAN)),
            "max_correction_um"
        );
        assert_eq!(
            field(&|r| r.max_correction_um = Some(-5.0)),
            "max_correction_um"
        );
        assert_eq!(
            field(&|r| r.max_correction_um = Some(f64::INFINITY)),
            "max_correction_um"
        );
        assert_eq!(field(&|r| r.baud = 0), "baud");
        assert_eq!(field(&|r| r.baud = u32::MAX), "baud");
        assert_eq!(field(&|r| r.time_scale = "fast".into()), "time_scale");
        assert_eq!(field(&|r| r.time_scale = "NaN".into()), "time_scale");
        assert_eq!(field(&|r| r.time_scale = "1e300".into()), "time_scale");
        let r = ProxyRequest {
            time_scale: "0".into(),
            ..ProxyRequest::default()
        };
        assert!(r
            .check()
            .unwrap_err()
            .for_cli()
            .starts_with("--time-scale: "));
    }

    /// Re-referencing in use needs the interval and the clear height together, an error
    /// map, and references recorded; each refusal names the field.
    #[test]
    fn re_referencing_in_use_needs_the_clear_height_and_a_map() {
        let in_use = ProxyRequest {
            reference_every_s: Some(300.0),
            clear_z_mm: Some(-5.0),
            ..ProxyRequest::default()
        };
        assert!(in_use.check().is_ok());
        let field = |f: &dyn Fn(&mut ProxyRequest)| {
            let mut r = in_use.clone();
            f(&mut r);
            r.check().unwrap_err().field
        };
        assert_eq!(field(&|r| r.clear_z_mm = None), "clear_z_mm");
        assert_eq!(field(&|r| r.reference_every_s = None), "clear_z_mm");
        assert_eq!(
            field(&|r| r.reference_every_s = Some(5.0)),
            "reference_every_s"
        );
        assert_eq!(
            field(&|r| r.reference_every_s = Some(f64::NAN)),
            "reference_every_s"
        );
        assert_eq!(field(&|r| r.clear_z_mm = Some(f64::INFINITY)), "clear_z_mm");
        assert_eq!(field(&|r| r.no_reference = true), "reference_every_s");
        assert_eq!(
            field(&|r| {
                r.rotary = Some("{}".into());
                r.controller = Some("/dev/ttyACM0".into());
            }),
            "reference_every_s"
        );
    }

    /// The rotary table's pass-through needs its controller's port, and a port alone
    /// (without the errors) is refused, each naming the field.
    #[test]
    fn the_request_chooses_the_pass_through() {
        let rotary = ProxyRequest {
            rotary: Some("{}".into()),
            ..ProxyRequest::default()
        };
        assert_eq!(rotary.check().unwrap_err().field, "controller");
        let both = ProxyRequest {
            controller: Some("/dev/ttyACM0".into()),
            ..rotary.clone()
        };
        assert!(both.check().is_ok());
        let port_alone = ProxyRequest {
            controller: Some("/dev/ttyACM0".into()),
            ..ProxyRequest::default()
        };
        assert_eq!(port_alone.check().unwrap_err().field, "controller");
        let link = ProxyRequest {
            link: Some(String::new()),
            ..ProxyRequest::default()
        };
        assert_eq!(link.check().unwrap_err().field, "link");
    }

    #[test]
    fn line_numbers_read_as_ranges() {
        assert_eq!(ranges(&[]), "none");
        assert_eq!(ranges(&[1, 2, 3, 5, 7, 8]), "1-3, 5, 7-8");
    }

    #[test]
    fn the_texts_read_the_json() {
        let hello = json!({"sender_port": "/dev/pts/7", "controller": "/dev/ttyACM0",
            "compensation": "map m", "map": "map m"});
        let hello: ProxyResult = serde_json::from_value(hello).unwrap();
        let ProxyResult::Ready(hello) = hello else {
            panic!("{hello:?}")
        };
        assert_eq!(
            ready_summary(&hello, Some(Path::new("/tmp/ttyG"))),
            "sender port: /dev/pts/7\nlink: /tmp/ttyG\ncontroller: /dev/ttyACM0; compensation: map m\n"
        );
        let r = json!({"ending": "sender left", "lines": {"acknowledged": "1-3",
            "refused": "none", "in_controller": "none", "not_sent": "none"},
            "lines_received": 3, "pieces_sent": 9, "starvation_events": 0,
            "rewrite_ms": {"median": 0.1, "p99": 0.2},
            "first_piece_out_ms": {"median": 0.3, "p99": 0.4},
            "largest_correction_um": 5.0, "segments_added": 6});
        let r: ProxyResult = serde_json::from_value(r).unwrap();
        let ProxyResult::Session(r) = r else {
            panic!("{r:?}")
        };
        let t = summary(&r);
        assert!(t.starts_with(
            "session ended (sender left): 3 lines received, 9 pieces sent, 0 starvation events\n"
        ));
        assert!(t.contains("  acknowledged: 1-3\n  refused: none\n"), "{t}");
        let recorded = json!({"reference_recorded": "m.v1.reference.json",
            "reference_count": 2, "shift_um": [1.0, -2.0]});
        let recorded: ProxyResult = serde_json::from_value(recorded).unwrap();
        assert!(
            matches!(recorded, ProxyResult::Reference(_)),
            "{recorded:?}"
        );
    }
}

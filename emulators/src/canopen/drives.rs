//! Several CiA 402 drive nodes on one bus, each driving one axis of the shared
//! simulated machine: frames and the wall time go in, frames come out (sans-IO).
//!
//! Motion. Each node runs its own profile-position demand (a trapezoid from its
//! profile velocity 0x6081, acceleration 0x6083 and deceleration 0x6084, velocity
//! capped by 0x607F). The machine's mechanics cannot exceed its own feed and
//! acceleration: where a demand asks for more, the axis lags, and when the lag passes
//! the following-error window (0x6065) the drive faults with EMCY 0x8611, as a real
//! servo drive does. Each node drives its own machine axis on the axis's own profile
//! ([`SimMachine::start_axis_move`]), timed so that the axis arrives when the node's
//! mechanics profile would; a node starting, halting, quick-stopping, faulting or
//! homing touches its own axis only, and the other axis's move runs on. A target
//! outside the software position limits (0x607D), or outside the machine's travel
//! (the limit switch), faults with EMCY 0x8612.
//!
//! Time: heartbeats, event timers and inhibit times run on the wall time passed in.
//! Motion runs on [`Clock::Scaled`] (simulated seconds per wall second) or
//! [`Clock::Unconstrained`], where a motion completes right after the frames that
//! reported its start, so tests never wait on wall time for motion.
//!
//! [`SimMachine::start_axis_move`]: world::machine::SimMachine::start_axis_move

use super::node::{Effect, Homing, Live, Node, HOMING_METHODS};
use protocol::can::CanFrame;
use protocol::canopen::emcy::codes;
use protocol::canopen::nmt::NmtCommand;
use protocol::canopen::od::ObjectDictionary;
use protocol::canopen::{classify, Function, NodeId};
use protocol::cia402::{self, cw, obj, PpAction, SetPoint, State};
use protocol::config::ConfigError;
use std::sync::Arc;
use world::machine::MachineRefusal;
use world::Clock;
use world::{lock, SharedRig};

/// The EDS of the emulated drive, compiled in (`config/canopen/drive.eds`).
pub const DRIVE_EDS: &str = include_str!("../../../config/canopen/drive.eds");
pub const DRIVE_EDS_NAME: &str = "config/canopen/drive.eds";

/// A 1-D move from rest to rest: accelerate, cruise, decelerate (or a triangle).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Trapezoid {
    pub dist: f64,
    v: f64,
    a: f64,
    d: f64,
    t_a: f64,
    t_c: f64,
    t_d: f64,
}

impl Trapezoid {
    pub fn new(dist: f64, v: f64, a: f64, d: f64) -> Self {
        let (v, a, d) = (v.max(1e-9), a.max(1e-9), d.max(1e-9));
        let dist = dist.abs();
        let (s_a, s_d) = (v * v / (2.0 * a), v * v / (2.0 * d));
        if s_a + s_d <= dist {
            Self {
                dist,
                v,
                a,
                d,
                t_a: v / a,
                t_c: (dist - s_a - s_d) / v,
                t_d: v / d,
            }
        } else {
            let vp = (2.0 * dist * a * d / (a + d)).sqrt();
            Self {
                dist,
                v: vp,
                a,
                d,
                t_a: vp / a,
                t_c: 0.0,
                t_d: vp / d,
            }
        }
    }

    pub fn duration(&self) -> f64 {
        self.t_a + self.t_c + self.t_d
    }

    /// Speed after `t` seconds (units per second).
    pub fn speed(&self, t: f64) -> f64 {
        if t <= 0.0 || t >= self.duration() {
            0.0
        } else if t < self.t_a {
            self.a * t
        } else if t < self.t_a + self.t_c {
            self.v
        } else {
            self.d * (self.duration() - t)
        }
    }

    /// Distance covered after `t` seconds.
    pub fn at(&self, t: f64) -> f64 {
        if t <= 0.0 {
            return 0.0;
        }
        if t < self.t_a {
            return 0.5 * self.a * t * t;
        }
        let s_a = 0.5 * self.v * self.t_a;
        if t < self.t_a + self.t_c {
            return s_a + self.v * (t - self.t_a);
        }
        let r = self.duration() - t;
        if r <= 0.0 {
            return self.dist;
        }
        self.dist - 0.5 * self.d * r * r
    }
}

/// One node's motion in progress.
#[derive(Clone, Debug)]
struct Demand {
    from: i64,
    to: i64,
    /// Machine time the set-point was taken.
    t0: f64,
    /// What the drive commands.
    demand: Trapezoid,
    /// What the mechanics can follow.
    mech: Trapezoid,
    /// Machine time the lag passes the following-error window, if it does.
    fault_at: Option<f64>,
}

impl Demand {
    fn sign(&self) -> f64 {
        if self.to >= self.from {
            1.0
        } else {
            -1.0
        }
    }
}

#[derive(Clone, Debug, Default)]
struct Aux {
    demand: Option<Demand>,
    /// Internal absolute target (base of relative set-points), counts.
    last_target: i64,
}

/// Counters for tests, the benchmark and the stand-alone binary.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SetStats {
    pub frames_in: u64,
    pub frames_out: u64,
    pub sdo_requests: u64,
    pub emcys: u64,
    pub set_points: u64,
}

/// Which nodes, on which axes.
#[derive(Clone, Debug)]
pub struct DriveSetConfig {
    pub clock: Clock,
    /// (node id, machine axis 0 = X / 1 = Y).
    pub nodes: Vec<(u8, usize)>,
    /// EDS text and the name it is reported under.
    pub eds: (String, String),
}

impl DriveSetConfig {
    /// X on node `x`, Y on node `y`, the built-in EDS.
    pub fn xy(x: u8, y: u8, clock: Clock) -> Self {
        Self {
            clock,
            nodes: vec![(x, 0), (y, 1)],
            eds: (DRIVE_EDS_NAME.into(), DRIVE_EDS.into()),
        }
    }
}

/// The drive nodes of one bus.
pub struct DriveSet {
    rig: SharedRig,
    clock: Clock,
    nodes: Vec<Node>,
    aux: Vec<Aux>,
    out: Vec<CanFrame>,
    last_wall: Option<f64>,
    tpdo_deadline: Option<f64>,
    stats: SetStats,
}

impl DriveSet {
    /// Nodes powered on (boot-up sent, Pre-operational). Each node's object dictionary
    /// comes from the EDS; the software position limits are commissioned to the
    /// machine's travel and the feed constant to its resolution.
    pub fn new(rig: SharedRig, cfg: &DriveSetConfig, now: f64) -> Result<Self, ConfigError> {
        let (name, text) = &cfg.eds;
        let machine = lock(&rig).machine().config().clone();
        let mut nodes = Vec::new();
        for &(id, axis) in &cfg.nodes {
            let node = NodeId::new(id).ok_or_else(|| ConfigError::Invalid {
                location: protocol::config::Location {
                    file: name.clone(),
                    line: None,
                    column: None,
                    key: None,
                },
                message: format!("node id {id} is outside 1..127"),
            })?;
            let od = Arc::new(ObjectDictionary::from_eds(name, text, node)?);
            let a = if axis == 0 {
                &machine.axes.x
            } else {
                &machine.axes.y
            };
            let cpm = a.counts_per_mm;
            let enc = |v: i64, n: usize| v.to_le_bytes()[..n].to_vec();
            let commissioning = vec![
                ((obj::SOFTWARE_LIMITS, 1), enc(0, 4)),
                (
                    (obj::SOFTWARE_LIMITS, 2),
                    enc((a.travel_mm * cpm).round() as i64, 4),
                ),
                (
                    (obj::FEED_CONSTANT, 1),
                    enc((a.lead_mm * cpm).round() as i64, 4),
                ),
                ((obj::FEED_CONSTANT, 2), enc(1, 4)),
                (
                    (obj::MAX_PROFILE_VELOCITY, 0),
                    enc((a.max_feed_mm_min / 60.0 * cpm * 2.0).round() as i64, 4),
                ),
            ];
            nodes.push(Node::new(node, axis.min(1), od, &commissioning));
        }
        let mut set = Self {
            rig,
            clock: cfg.clock,
            aux: vec![Aux::default(); nodes.len()],
            nodes,
            out: Vec::new(),
            last_wall: Some(now),
            tpdo_deadline: None,
            stats: SetStats::default(),
        };
        for n in &mut set.nodes {
            n.reset_node(now, &mut set.out);
        }
        Ok(set)
    }

    pub fn stats(&self) -> &SetStats {
        &self.stats
    }

    pub fn node_ids(&self) -> Vec<u8> {
        self.nodes.iter().map(|n| n.id.get()).collect()
    }

    /// Fault injection: a node falls silent (no heartbeat, no answers), or comes back.
    pub fn set_silent(&mut self, node: u8, silent: bool) {
        if let Some(n) = self.nodes.iter_mut().find(|n| n.id.get() == node) {
            n.silent = silent;
        }
    }

    /// A node's power state and statusword (for tests and the binary's report).
    pub fn node_state(&self, node: u8) -> Option<(State, u16)> {
        self.nodes
            .iter()
            .find(|n| n.id.get() == node)
            .map(|n| (n.state, n.statusword()))
    }

    /// Frames to put on the bus.
    pub fn take_output(&mut self) -> Vec<CanFrame> {
        self.stats.frames_out += self.out.len() as u64;
        std::mem::take(&mut self.out)
    }

    /// When the set next needs [`DriveSet::poll`] (heartbeats, event timers, inhibit
    /// times), wall time.
    pub fn next_deadline(&self) -> Option<f64> {
        self.nodes
            .iter()
            .filter_map(Node::heartbeat_deadline)
            .chain(self.tpdo_deadline)
            .reduce(f64::min)
    }

    /// Whether motion runs on the scaled clock and needs regular polls.
    pub fn needs_tick(&self) -> bool {
        matches!(self.clock, Clock::Scaled(_))
            && (self.aux.iter().any(|a| a.demand.is_some())
                || self
                    .nodes
                    .iter()
                    .any(|n| matches!(n.homing, Homing::Running { .. })))
    }

    /// A frame from the bus at wall time `now`.
    pub fn receive(&mut self, frame: &CanFrame, now: f64) {
        self.tick(now);
        self.stats.frames_in += 1;
        if let Some(id) = frame.id().as_standard() {
            self.refresh_live();
            match classify(id) {
                Function::Nmt => {
                    if let Some((c, target)) = NmtCommand::parse(frame) {
                        for n in &mut self.nodes {
                            if NmtCommand::addresses(target, n.id) {
                                n.nmt_command(c, now, &mut self.out);
                            }
                        }
                        // Leaving Operational or a reset stops what the node drove.
                        for k in 0..self.nodes.len() {
                            if self.nodes[k].state != State::OperationEnabled {
                                self.stop_axis(k);
                            }
                        }
                    }
                }
                Function::Sync => {
                    for n in &mut self.nodes {
                        n.sync(now, &mut self.out);
                    }
                }
                Function::SdoRx(node) if !frame.is_remote() => {
                    if let Some(k) = self.index_of(node) {
                        self.stats.sdo_requests += 1;
                        if let Some(r) = self.nodes[k].sdo_request(frame.data()) {
                            self.out.push(r);
                        }
                        self.apply_effects(k, now);
                    }
                }
                _ => {
                    for k in 0..self.nodes.len() {
                        if self.nodes[k].pdo_frame(frame, now, &mut self.out) {
                            self.apply_effects(k, now);
                        }
                    }
                }
            }
        }
        self.report(now);
        if self.clock == Clock::Unconstrained {
            self.complete_all();
            self.report(now);
        }
    }

    /// Timers and scaled-clock motion up to wall time `now`.
    pub fn poll(&mut self, now: f64) {
        self.tick(now);
        for n in &mut self.nodes {
            n.poll_heartbeat(now, &mut self.out);
        }
        self.report(now);
    }

    fn index_of(&self, node: NodeId) -> Option<usize> {
        self.nodes.iter().position(|n| n.id == node)
    }

    fn report(&mut self, now: f64) {
        self.refresh_live();
        let mut next: Option<f64> = None;
        for n in &mut self.nodes {
            let before = n.emcys_sent;
            if let Some(t) = n.emit_tpdos(now, &mut self.out) {
                next = Some(next.map_or(t, |x| x.min(t)));
            }
            self.stats.emcys += n.emcys_sent - before;
        }
        self.tpdo_deadline = next;
        self.stats.emcys = self.nodes.iter().map(|n| n.emcys_sent).sum();
    }

    // ------------------------------------------------------------------- time

    fn tick(&mut self, now: f64) {
        let dt = self.last_wall.map_or(0.0, |t| (now - t).max(0.0));
        self.last_wall = Some(now);
        if let Clock::Scaled(k) = self.clock {
            self.advance(dt * k);
        }
    }

    /// Run homing and motion for `dt` simulated seconds.
    fn advance(&mut self, dt: f64) {
        // Homing: the machine already homed the axis; the drive is busy for as long as
        // the run back to the switch takes. The other axes' moves run meanwhile.
        for k in 0..self.nodes.len() {
            if let Homing::Running { left_s } = self.nodes[k].homing {
                if left_s <= dt {
                    self.homing_done(k);
                } else {
                    self.nodes[k].homing = Homing::Running {
                        left_s: left_s - dt,
                    };
                }
            }
        }
        if self.aux.iter().all(|a| a.demand.is_none()) {
            return;
        }
        let mut left = dt;
        for _ in 0..16 {
            let now_s = lock(&self.rig).machine().now_s();
            match self.next_event() {
                Some((at, fault)) if at <= now_s + left => {
                    let step = ((at - now_s).max(0.0) + fault.map_or(1e-9, |_| 0.0)).min(left);
                    lock(&self.rig).machine_mut().advance(step);
                    left -= step;
                    if let Some(k) = fault {
                        self.following_error(k);
                    }
                    self.check_completion();
                }
                _ => {
                    lock(&self.rig).machine_mut().advance(left);
                    break;
                }
            }
        }
        self.check_completion();
    }

    /// Unconstrained clock: run everything started to its end (or to a fault).
    fn complete_all(&mut self) {
        for _ in 0..64 {
            let mut busy = false;
            for k in 0..self.nodes.len() {
                if matches!(self.nodes[k].homing, Homing::Running { .. }) {
                    self.homing_done(k);
                    busy = true;
                }
            }
            if self.aux.iter().all(|a| a.demand.is_none()) {
                if busy {
                    continue;
                }
                return;
            }
            // The next arrival or following-error fault, in machine time order.
            if let Some((at, fault)) = self.next_event() {
                let mut r = lock(&self.rig);
                let now_s = r.machine().now_s();
                let step = (at - now_s).max(0.0) + fault.map_or(1e-9, |_| 0.0);
                r.machine_mut().advance(step);
                drop(r);
                if let Some(k) = fault {
                    self.following_error(k);
                }
            }
            self.check_completion();
        }
    }

    /// The next thing to happen to a moving node, machine time: its axis arriving
    /// (`None`), or the lag of a node passing its following-error window before its
    /// axis arrives (`Some(node)`).
    fn next_event(&self) -> Option<(f64, Option<usize>)> {
        let r = lock(&self.rig);
        let now_s = r.machine().now_s();
        self.aux
            .iter()
            .enumerate()
            .filter_map(|(k, a)| {
                let d = a.demand.as_ref()?;
                let end = now_s + r.machine().axis_time_left_s(self.nodes[k].axis);
                Some(match d.fault_at {
                    Some(at) if at < end => (at, Some(k)),
                    _ => (end, None),
                })
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
    }

    /// Nodes whose axis has arrived finish their set-point (and take the next one).
    fn check_completion(&mut self) {
        for k in 0..self.nodes.len() {
            let moving = lock(&self.rig).machine().is_axis_moving(self.nodes[k].axis);
            if !moving && self.aux[k].demand.take().is_some() {
                self.nodes[k].target_reached = true;
                if self.nodes[k].state == State::QuickStopActive {
                    self.quick_stop_done(k);
                    continue;
                }
                if let Some(sp) = self.nodes[k].pp.on_motion_done() {
                    self.start_set_point(k, sp);
                }
            }
        }
    }

    fn refresh_live(&mut self) {
        let (counts, now_s) = {
            let r = lock(&self.rig);
            (r.machine().counts(), r.machine().now_s())
        };
        for (n, a) in self.nodes.iter_mut().zip(&self.aux) {
            let position = counts[n.axis].clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32;
            let (demand, fe) = match &a.demand {
                Some(d) => {
                    let t = now_s - d.t0;
                    let dem = d.from as f64 + d.sign() * d.demand.at(t);
                    let mech = d.from as f64 + d.sign() * d.mech.at(t);
                    (dem.round() as i32, (dem - mech).round() as i32)
                }
                None => (position, 0),
            };
            n.live = Live {
                position,
                demand,
                following_error: fe,
                moving: a.demand.is_some() || matches!(n.homing, Homing::Running { .. }),
            };
        }
    }

    // ----------------------------------------------------------------- effects

    fn apply_effects(&mut self, k: usize, now: f64) {
        for e in self.nodes[k].take_effects() {
            match e {
                Effect::Controlword { prev } => self.controlword(k, prev, now),
                Effect::Mode => {
                    self.stop_axis(k);
                    let n = &mut self.nodes[k];
                    n.pp.reset();
                    n.homing = Homing::Idle;
                }
            }
        }
    }

    fn controlword(&mut self, k: usize, prev: u16, _now: f64) {
        let word = self.nodes[k].cw;
        let old = self.nodes[k].state;
        let option = self.quick_stop_option(k);
        let new = cia402::device_transition(old, prev, word, option);
        if old == State::Fault && new == State::SwitchOnDisabled {
            self.nodes[k].clear_fault(&mut self.out);
        }
        self.nodes[k].state = new;
        if old == State::OperationEnabled && new == State::QuickStopActive {
            // Slow down on the ramp the option code names (or coast), then, for
            // option codes 0-4, go on to Switch on disabled (see `check_completion`).
            match option.ramp() {
                Some(ramp) => {
                    let dec = self.nodes[k].int(ramp, 0).max(1) as f64;
                    self.ramp_down(k, dec);
                }
                None => {
                    self.stop_axis(k);
                    self.nodes[k].state = State::SwitchOnDisabled;
                }
            }
            self.quick_stop_done(k);
            let n = &mut self.nodes[k];
            n.pp.reset();
            if matches!(n.homing, Homing::Running { .. }) {
                n.homing = Homing::Idle;
            }
            return;
        }
        if new != State::OperationEnabled {
            if old == State::OperationEnabled || old == State::QuickStopActive {
                self.stop_axis(k);
            }
            let n = &mut self.nodes[k];
            n.pp.reset();
            if matches!(n.homing, Homing::Running { .. }) {
                n.homing = Homing::Idle;
            }
            return;
        }
        if word & cw::HALT != 0 {
            if self.aux[k].demand.is_some() {
                self.stop_axis(k);
            }
            return;
        }
        let rising = word & cw::NEW_SET_POINT != 0 && prev & cw::NEW_SET_POINT == 0;
        match self.nodes[k].mode() {
            1 => {
                let target = self.nodes[k].int(obj::TARGET_POSITION, 0) as i32;
                let busy = self.aux[k].demand.is_some();
                if let PpAction::Start(sp) = self.nodes[k].pp.on_controlword(word, target, busy) {
                    self.start_set_point(k, sp);
                }
            }
            6 if rising => self.start_homing(k),
            6 if word & cw::HOMING_START == 0 => {
                if matches!(self.nodes[k].homing, Homing::Running { .. }) {
                    self.nodes[k].homing = Homing::Idle;
                }
            }
            _ => {}
        }
    }

    fn quick_stop_option(&self, k: usize) -> cia402::QuickStopOption {
        cia402::QuickStopOption(self.nodes[k].int(obj::QUICK_STOP_OPTION, 0) as i16)
    }

    /// Quick stop active with the axis still: option codes 0-4 go on to Switch on
    /// disabled (transition 12); 5-8 stay.
    fn quick_stop_done(&mut self, k: usize) {
        if self.nodes[k].state == State::QuickStopActive
            && self.aux[k].demand.is_none()
            && !self.quick_stop_option(k).stays_active()
        {
            self.nodes[k].state = State::SwitchOnDisabled;
        }
    }

    /// Slow axis `k` down from its present demand speed at `dec` (counts/s^2) to a stop;
    /// the other axes carry on.
    fn ramp_down(&mut self, k: usize, dec: f64) {
        let Some(d) = &self.aux[k].demand else {
            return;
        };
        let (here, now_s) = {
            let r = lock(&self.rig);
            (
                r.machine().counts()[self.nodes[k].axis],
                r.machine().now_s(),
            )
        };
        let v = d.demand.speed(now_s - d.t0);
        let sign = d.sign();
        let dist = (v * v / (2.0 * dec)).round();
        if dist < 1.0 {
            self.stop_axis(k);
            return;
        }
        let to = here + (sign * dist) as i64;
        // Already at speed: an instant "acceleration", then the deceleration alone.
        let ramp = Trapezoid::new(dist, v, 1e12, dec);
        self.aux[k].demand = Some(Demand {
            from: here,
            to,
            t0: now_s,
            demand: ramp,
            mech: ramp,
            fault_at: None,
        });
        self.aux[k].last_target = to;
        self.drive_axis(k);
    }

    /// Stop axis `k` where it is (halt, quick stop, disable, fault); the other axes
    /// carry on.
    fn stop_axis(&mut self, k: usize) {
        if self.aux[k].demand.take().is_some() {
            self.nodes[k].target_reached = true;
            let axis = self.nodes[k].axis;
            let mut r = lock(&self.rig);
            r.machine_mut().stop_axis(axis);
            self.aux[k].last_target = r.machine().counts()[axis];
        }
    }

    fn start_set_point(&mut self, k: usize, sp: SetPoint) {
        self.stats.set_points += 1;
        let target = if sp.relative {
            self.aux[k].last_target + i64::from(sp.target)
        } else {
            i64::from(sp.target)
        };
        let n = &self.nodes[k];
        let (lo, hi) = (
            n.int(obj::SOFTWARE_LIMITS, 1),
            n.int(obj::SOFTWARE_LIMITS, 2),
        );
        if target < lo || target > hi {
            self.nodes[k].internal_limit = true;
            self.fault(k, codes::REFERENCE_LIMIT);
            return;
        }
        let (from, machine_v, machine_a) = {
            let mut r = lock(&self.rig);
            if !r.machine().is_axis_homed(n.axis) {
                // Not homed: the power-on position is the reference (counts are 0).
                r.machine_mut().home_axis(n.axis);
            }
            let c = r.machine().config();
            let a = if n.axis == 0 { &c.axes.x } else { &c.axes.y };
            (
                r.machine().counts()[n.axis],
                a.max_feed_mm_min / 60.0 * a.counts_per_mm,
                a.accel_mm_s2 * a.counts_per_mm,
            )
        };
        let v = n
            .int(obj::PROFILE_VELOCITY, 0)
            .min(n.int(obj::MAX_PROFILE_VELOCITY, 0))
            .max(1) as f64;
        let acc = n.int(obj::PROFILE_ACCELERATION, 0).max(1) as f64;
        let dec = n.int(obj::PROFILE_DECELERATION, 0).max(1) as f64;
        let dist = (target - from) as f64;
        let demand = Trapezoid::new(dist, v, acc, dec);
        let mech = Trapezoid::new(
            dist,
            v.min(machine_v),
            acc.min(machine_a),
            dec.min(machine_a),
        );
        let window = n.int(obj::FOLLOWING_ERROR_WINDOW, 0);
        let t0 = lock(&self.rig).machine().now_s();
        let fault_at = if window <= 0 || window >= i64::from(u32::MAX) {
            None
        } else {
            // First moment the demand runs ahead of the mechanics by more than the window.
            let end = mech.duration();
            let steps = ((end / 0.001).ceil() as usize).clamp(1, 2_000_000);
            (0..=steps)
                .map(|i| end * i as f64 / steps as f64)
                .find(|&t| demand.at(t) - mech.at(t) > window as f64)
                .map(|t| t0 + t)
        };
        let node = &mut self.nodes[k];
        node.target_reached = false;
        node.following_error = false;
        node.internal_limit = false;
        self.aux[k].last_target = target;
        self.aux[k].demand = Some(Demand {
            from,
            to: target,
            t0,
            demand,
            mech,
            fault_at,
        });
        self.drive_axis(k);
    }

    /// Move node `k`'s axis from where it is to the node's target on the axis's own
    /// profile, timed to arrive when the node's mechanics profile does.
    fn drive_axis(&mut self, k: usize) {
        let Some(d) = &self.aux[k].demand else {
            return;
        };
        let axis = self.nodes[k].axis;
        let mut r = lock(&self.rig);
        let a = r.machine().axis_config(axis).clone();
        let here = r.machine().counts()[axis];
        if d.to == here {
            r.machine_mut().stop_axis(axis);
            return;
        }
        let t_left = d.mech.duration() - (r.machine().now_s() - d.t0);
        let length = (d.to - here).abs() as f64 / a.counts_per_mm;
        let vmax = a.max_feed_mm_min / 60.0;
        // The axis's trapezoid takes L/f + f/a: pick f so that equals t_left.
        let disc = (a.accel_mm_s2 * t_left).powi(2) - 4.0 * a.accel_mm_s2 * length;
        let feed = if t_left > 0.0 && disc >= 0.0 {
            ((a.accel_mm_s2 * t_left - disc.sqrt()) / 2.0).clamp(1e-6, vmax)
        } else {
            vmax
        };
        let to = d.to as f64 / a.counts_per_mm;
        if let Err(MachineRefusal::OutOfTravel { .. }) =
            r.machine_mut().start_axis_move(axis, to, feed * 60.0)
        {
            drop(r);
            // The carriage would hit the limit switch.
            self.nodes[k].internal_limit = true;
            self.fault(k, codes::REFERENCE_LIMIT);
        }
    }

    fn following_error(&mut self, k: usize) {
        self.nodes[k].following_error = true;
        self.fault(k, codes::FOLLOWING_ERROR);
    }

    /// Fault reaction: stop the axis, enter Fault, send the EMCY.
    fn fault(&mut self, k: usize, code: u16) {
        self.nodes[k].fault(code, &mut self.out);
        let fe = self.nodes[k].following_error;
        let lim = self.nodes[k].internal_limit;
        self.stop_axis(k);
        // The statusword keeps showing why until the fault is reset.
        self.nodes[k].following_error = fe;
        self.nodes[k].internal_limit = lim;
        self.nodes[k].target_reached = true;
    }

    // ------------------------------------------------------------------ homing

    /// Home node `k`'s axis alone (the machine takes the switch as the axis's zero, a
    /// new homing error drawn for it); the drive is busy for as long as the run back
    /// to the switch takes, and the other axes' moves run on.
    fn start_homing(&mut self, k: usize) {
        let method = self.nodes[k].int(obj::HOMING_METHOD, 0) as i8;
        if !HOMING_METHODS.contains(&method) {
            self.nodes[k].homing = Homing::Error;
            return;
        }
        self.stop_axis(k);
        let took = lock(&self.rig).machine_mut().home_axis(self.nodes[k].axis);
        self.nodes[k].homing = Homing::Running {
            left_s: if self.clock == Clock::Unconstrained {
                0.0
            } else {
                took
            },
        };
        self.nodes[k].homed = false;
    }

    fn homing_done(&mut self, k: usize) {
        let n = &mut self.nodes[k];
        n.homing = Homing::Attained;
        n.homed = true;
        n.target_reached = true;
        self.aux[k].last_target = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::canopen::emcy::Emcy;
    use protocol::canopen::sdo::{ClientStep, SdoClient};
    use protocol::config::ConfigDoc;
    use protocol::{Board, Polarity};
    use std::path::Path;
    use world::camera::CameraModel;
    use world::machine::MachineConfig;

    fn rig() -> SharedRig {
        let m = include_str!("../../../config/machines/c5-stage.toml");
        let m = MachineConfig::from_doc(&ConfigDoc::from_text("c5-stage.toml", m, Path::new(".")))
            .unwrap();
        let c = include_str!("../../../config/cameras/mono-1.3mp.toml");
        let c =
            CameraModel::from_doc(&ConfigDoc::from_text("cam.toml", c, Path::new("."))).unwrap();
        let b = Board::nominal("t", 0.5, 0.25, Polarity::DarkOnLight, 40, 30, [0.0, 0.0]);
        world::shared_rig(m, b, c)
    }

    /// A master on the bus: SDO by the protocol crate's client, PDOs by hand.
    struct Host {
        set: DriveSet,
        t: f64,
        seen: Vec<CanFrame>,
    }

    impl Host {
        fn new() -> Self {
            Self::with_clock(Clock::Unconstrained)
        }

        fn with_clock(clock: Clock) -> Self {
            let set = DriveSet::new(rig(), &DriveSetConfig::xy(1, 2, clock), 0.0).unwrap();
            let mut h = Host {
                set,
                t: 0.0,
                seen: Vec::new(),
            };
            h.seen = h.set.take_output();
            h
        }

        fn send(&mut self, f: CanFrame) -> Vec<CanFrame> {
            self.t += 0.001;
            self.set.receive(&f, self.t);
            let out = self.set.take_output();
            self.seen.extend(out.iter().copied());
            out
        }

        fn sdo(&mut self, node: u8, first: CanFrame, c: &mut SdoClient) -> ClientStep {
            let mut f = first;
            loop {
                let out = self.send(f);
                let resp = out
                    .iter()
                    .find(|r| r.id().raw() == 0x580 + u32::from(node))
                    .expect("SDO response");
                match c.on_response(resp.data(), self.t) {
                    ClientStep::Send(n) => f = n,
                    other => return other,
                }
            }
        }

        fn read(&mut self, node: u8, index: u16, sub: u8) -> Vec<u8> {
            let mut c = SdoClient::new(NodeId::new(node).unwrap(), 1.0);
            let f = c.upload(index, sub, self.t);
            match self.sdo(node, f, &mut c) {
                ClientStep::Uploaded(v) => v,
                other => panic!("read {index:04X}:{sub}: {other:?}"),
            }
        }

        fn write(&mut self, node: u8, index: u16, sub: u8, data: &[u8]) -> ClientStep {
            let mut c = SdoClient::new(NodeId::new(node).unwrap(), 1.0);
            let f = c.download(index, sub, data, self.t);
            self.sdo(node, f, &mut c)
        }

        /// Let the inhibit times pass and the deferred TPDOs go out.
        fn settle(&mut self) {
            self.t += 0.05;
            self.set.poll(self.t);
            let out = self.set.take_output();
            self.seen.extend(out);
        }

        /// Latest statusword + position from TPDO2 (the EDS default mapping).
        fn tpdo2(&self, node: u8) -> Option<(u16, i32)> {
            self.seen
                .iter()
                .rev()
                .find(|f| f.id().raw() == 0x280 + u32::from(node))
                .map(|f| {
                    let d = f.data();
                    (
                        u16::from_le_bytes([d[0], d[1]]),
                        i32::from_le_bytes([d[2], d[3], d[4], d[5]]),
                    )
                })
        }

        fn enable(&mut self, node: u8) {
            self.send(NmtCommand::Start.frame(NodeId::new(node)));
            for c in [0x06u8, 0x07, 0x0F] {
                self.send(CanFrame::std(0x200 + u16::from(node), &[c, 0, 1]));
            }
            assert_eq!(
                self.set.node_state(node).unwrap().0,
                State::OperationEnabled
            );
        }

        fn move_to(&mut self, node: u8, counts: i32) {
            let t = counts.to_le_bytes();
            let id = 0x300 + u16::from(node);
            self.send(CanFrame::std(id, &[0x0F, 0, t[0], t[1], t[2], t[3]]));
            self.send(CanFrame::std(id, &[0x3F, 0, t[0], t[1], t[2], t[3]]));
            self.send(CanFrame::std(id, &[0x0F, 0, t[0], t[1], t[2], t[3]]));
        }
    }

    /// Quick stop of node 1 half a second into a long move, with quick stop option code
    /// `option`: how far it ran on after the quick stop, and its state once still.
    fn quick_stop_with(option: i16) -> (i64, State, Host) {
        let mut h = Host::with_clock(Clock::Scaled(1.0));
        assert!(matches!(
            h.write(1, 0x605A, 0, &option.to_le_bytes()),
            ClientStep::Downloaded
        ));
        h.enable(1);
        h.move_to(1, 300_000);
        h.t += 0.5;
        h.set.poll(h.t);
        h.send(CanFrame::std(0x201, &[0x02, 0, 1]));
        // Where the axis was when the drive took the quick stop.
        let at_stop = lock(&h.set.rig).machine().counts()[0];
        if option != 0 {
            assert_eq!(h.set.node_state(1).unwrap().0, State::QuickStopActive);
        }
        for _ in 0..100 {
            h.t += 0.05;
            h.set.poll(h.t);
        }
        let still = lock(&h.set.rig).machine().counts()[0];
        (still - at_stop, h.set.node_state(1).unwrap().0, h)
    }

    #[test]
    fn quick_stop_follows_the_option_code() {
        // 2 (the EDS default): the quick stop ramp 0x6085, then Switch on disabled.
        let (run_on_qs, state, mut h) = quick_stop_with(2);
        assert!(run_on_qs > 0, "it slows down rather than stopping dead");
        assert_eq!(state, State::SwitchOnDisabled);
        // Enable operation does not bring a drive of option 0-4 back from quick stop.
        h.send(CanFrame::std(0x201, &[0x0F, 0, 1]));
        assert_ne!(h.set.node_state(1).unwrap().0, State::OperationEnabled);
        // 1: the slower profile deceleration 0x6084 (1.6e6 against 4e6 counts/s^2):
        // 2.5 times the distance from the same speed.
        let (run_on_profile, state, _) = quick_stop_with(1);
        assert_eq!(state, State::SwitchOnDisabled);
        let ratio = run_on_profile as f64 / run_on_qs as f64;
        assert!(
            (ratio - 2.5).abs() < 0.01,
            "{run_on_profile} vs {run_on_qs}"
        );
        // 6: the quick stop ramp, then it stays in Quick stop active, and enable
        // operation (transition 16) resumes.
        let (_, state, mut h) = quick_stop_with(6);
        assert_eq!(state, State::QuickStopActive);
        h.send(CanFrame::std(0x201, &[0x0F, 0, 1]));
        assert_eq!(h.set.node_state(1).unwrap().0, State::OperationEnabled);
        // 0: the drive function is disabled at once: no run-on, Switch on disabled.
        let (run_on, state, _) = quick_stop_with(0);
        assert_eq!((run_on, state), (0, State::SwitchOnDisabled));
    }

    #[test]
    fn boots_pre_operational_and_serves_its_dictionary() {
        let mut h = Host::new();
        let boot: Vec<String> = h.seen.iter().map(ToString::to_string).collect();
        assert_eq!(boot, ["701#00", "702#00"]);
        assert_eq!(h.read(1, 0x1000, 0), 0x0002_0192u32.to_le_bytes());
        assert_eq!(h.read(2, 0x6502, 0), 0x21u32.to_le_bytes());
        assert_eq!(h.read(2, 0x1800, 1), 0x182u32.to_le_bytes());
        assert_eq!(h.read(2, 0x1A01, 2), 0x6064_0020u32.to_le_bytes());
        assert_eq!(h.read(1, 0x1008, 0), b"CiA 402 drive emulator");
        // Software limits commissioned to the travel (200 mm at 2000 counts/mm).
        assert_eq!(h.read(1, 0x607D, 2), 400_000i32.to_le_bytes());
        // Refusals carry CiA 301 abort codes.
        let r = h.write(1, 0x6041, 0, &[0, 0]);
        assert!(
            matches!(r, ClientStep::Failed { ref error, .. } if error.code().0 == 0x0601_0002),
            "{r:?}"
        );
        let r = h.write(1, 0x6098, 0, &[35]);
        assert!(
            matches!(r, ClientStep::Failed { ref error, .. } if error.code().0 == 0x0609_0030),
            "{r:?}"
        );
        // A mapping cannot change while its PDO is valid.
        let r = h.write(1, 0x1A00, 0, &[0]);
        assert!(
            matches!(r, ClientStep::Failed { ref error, .. } if error.code().0 == 0x0800_0022),
            "{r:?}"
        );
        // No PDOs before Operational.
        assert!(h.seen.iter().all(|f| f.id().raw() & 0x780 != 0x180));
    }

    #[test]
    fn enables_and_moves_by_the_set_point_handshake() {
        let mut h = Host::new();
        h.enable(1);
        h.move_to(1, 20_000);
        h.settle();
        let (sw, pos) = h.tpdo2(1).unwrap();
        assert_eq!(pos, 20_000);
        assert_eq!(sw & 0x0400, 0x0400, "target reached: {sw:#06x}");
        assert_eq!(sw & 0x1000, 0, "ack dropped with bit 4");
        assert_eq!(h.set.stats().set_points, 1);
        assert_eq!(lock(&h.set.rig).machine().counts()[0], 20_000);
        // Relative set-point.
        let id = 0x301;
        let d = 500i32.to_le_bytes();
        h.send(CanFrame::std(id, &[0x5F, 0, d[0], d[1], d[2], d[3]]));
        h.send(CanFrame::std(id, &[0x0F, 0, d[0], d[1], d[2], d[3]]));
        h.settle();
        assert_eq!(h.tpdo2(1).unwrap().1, 20_500);
    }

    #[test]
    fn following_error_and_limit_fault_with_emcy_and_reset() {
        let mut h = Host::new();
        h.enable(2);
        // Ask for twice the machine's feed with a tight window: the axis lags.
        assert_eq!(
            h.write(2, 0x6081, 0, &400_000u32.to_le_bytes()),
            ClientStep::Downloaded
        );
        assert_eq!(
            h.write(2, 0x6065, 0, &200u32.to_le_bytes()),
            ClientStep::Downloaded
        );
        h.move_to(2, 200_000);
        let emcy: Vec<Emcy> = h
            .seen
            .iter()
            .filter_map(Emcy::parse)
            .map(|(_, e)| e)
            .collect();
        assert_eq!(emcy.iter().map(|e| e.code).collect::<Vec<_>>(), [0x8611]);
        let (state, sw) = h.set.node_state(2).unwrap();
        assert_eq!(state, State::Fault);
        assert_ne!(sw & 0x2000, 0, "following error bit");
        let stopped = lock(&h.set.rig).machine().counts()[1];
        assert!(
            stopped > 0 && stopped < 200_000,
            "stopped where it faulted: {stopped}"
        );
        assert_eq!(h.read(2, 0x603F, 0), 0x8611u16.to_le_bytes());
        // Fault reset: rising edge of bit 7, then EMCY 0x0000.
        h.send(CanFrame::std(0x202, &[0x00, 0, 1]));
        h.send(CanFrame::std(0x202, &[0x80, 0, 1]));
        assert_eq!(h.set.node_state(2).unwrap().0, State::SwitchOnDisabled);
        let last = h.seen.iter().rev().find_map(Emcy::parse).unwrap().1;
        assert_eq!(last.code, 0);
        // Beyond the software limit (150 mm travel = 300000 counts).
        h.send(CanFrame::std(0x202, &[0x00, 0, 1]));
        h.enable(2);
        h.move_to(2, 300_001);
        let last = h.seen.iter().rev().find_map(Emcy::parse).unwrap().1;
        assert_eq!(last.code, 0x8612);
        assert_ne!(
            h.set.node_state(2).unwrap().1 & 0x0800,
            0,
            "internal limit bit"
        );
    }

    #[test]
    fn synchronous_and_remote_tpdos_and_a_short_rpdo() {
        let mut h = Host::new();
        h.send(NmtCommand::Start.frame(NodeId::new(1)));
        // TPDO3 (following error + error code, disabled in the EDS): every 2nd SYNC.
        assert_eq!(h.write(1, 0x1802, 2, &[2]), ClientStep::Downloaded);
        assert_eq!(
            h.write(1, 0x1802, 1, &0x381u32.to_le_bytes()),
            ClientStep::Downloaded
        );
        let count = |h: &Host| h.seen.iter().filter(|f| f.id().raw() == 0x381).count();
        h.send(protocol::canopen::sync_frame());
        assert_eq!(count(&h), 0);
        h.send(protocol::canopen::sync_frame());
        assert_eq!(count(&h), 1);
        // An RTR for TPDO1 is answered with its data now.
        let rtr = CanFrame::remote(protocol::can::CanId::Standard(0x181), 3).unwrap();
        let out = h.send(rtr);
        assert!(
            out.iter()
                .any(|f| f.id().raw() == 0x181 && f.data().len() == 3),
            "{out:?}"
        );
        // RPDO1 maps 3 bytes; 2 are too few: EMCY 0x8210, nothing written.
        h.send(CanFrame::std(0x201, &[0x06, 0x00]));
        let last = h.seen.iter().rev().find_map(Emcy::parse).unwrap().1;
        assert_eq!(last.code, 0x8210);
        assert_eq!(h.set.node_state(1).unwrap().0, State::SwitchOnDisabled);
    }

    #[test]
    fn homing_mode_homes_the_machine() {
        let mut h = Host::new();
        h.enable(1);
        assert_eq!(h.write(1, 0x6060, 0, &[6]), ClientStep::Downloaded);
        assert_eq!(h.read(1, 0x6061, 0), [6]);
        h.send(CanFrame::std(0x201, &[0x0F, 0, 6]));
        h.send(CanFrame::std(0x201, &[0x1F, 0, 6]));
        let sw = h.set.node_state(1).unwrap().1;
        assert_eq!(
            sw & 0x3400,
            0x1400,
            "homing attained and target reached: {sw:#06x}"
        );
        // Node 1 homed its own axis (X) alone.
        let m = lock(&h.set.rig);
        assert!(m.machine().is_axis_homed(0) && !m.machine().is_axis_homed(1));
        drop(m);
        // The TPDO showed homing in progress before it was attained.
        let sws: Vec<u16> = h
            .seen
            .iter()
            .filter(|f| f.id().raw() == 0x181)
            .map(|f| u16::from_le_bytes([f.data()[0], f.data()[1]]))
            .collect();
        assert!(sws.iter().any(|s| s & 0x3400 == 0), "{sws:x?}");
    }

    #[test]
    fn trapezoid_reaches_its_distance_in_its_duration() {
        let t = Trapezoid::new(100.0, 10.0, 5.0, 2.5);
        // 10 at 5 -> 2 s, 10 m; decel 4 s, 20 m; cruise 70 m at 10 -> 7 s.
        assert!((t.duration() - 13.0).abs() < 1e-9);
        assert!((t.at(2.0) - 10.0).abs() < 1e-9);
        assert!((t.at(13.0) - 100.0).abs() < 1e-9);
        assert!((t.at(20.0) - 100.0).abs() < 1e-9);
        let tri = Trapezoid::new(1.0, 10.0, 2.0, 2.0);
        assert!((tri.duration() - 2.0 * 0.5f64.sqrt()).abs() < 1e-9);
        assert!((tri.at(tri.duration() / 2.0) - 0.5).abs() < 1e-9);
    }

    /// Nodes 1 and 2 enabled on a scaled clock, both sent on long moves; then `act` on
    /// node 1 half a second in. Node 2 must follow its own profile throughout (within
    /// a few counts) and arrive at its target; returns the host and node 1's position.
    fn node_2_runs_on_while(act: impl FnOnce(&mut Host)) -> (Host, i64) {
        let mut h = Host::with_clock(Clock::Scaled(1.0));
        h.enable(1);
        h.enable(2);
        h.move_to(1, 300_000);
        h.move_to(2, 250_000);
        let d = h.set.aux[1].demand.clone().expect("node 2 moving");
        let own = |h: &Host| {
            let now = lock(&h.set.rig).machine().now_s();
            d.from as f64 + d.mech.at(now - d.t0)
        };
        let check = |h: &Host, what: &str| {
            let y = lock(&h.set.rig).machine().counts()[1] as f64;
            assert!(
                (y - own(h)).abs() <= 3.0,
                "{what}: node 2 at {y}, its own profile at {}",
                own(h)
            );
        };
        for _ in 0..10 {
            h.t += 0.05;
            h.set.poll(h.t);
            check(&h, "before");
        }
        act(&mut h);
        check(&h, "at the stop of node 1");
        for _ in 0..100 {
            h.t += 0.05;
            h.set.poll(h.t);
            check(&h, "after");
        }
        h.settle();
        assert_eq!(lock(&h.set.rig).machine().counts()[1], 250_000);
        let (sw, pos) = h.tpdo2(2).unwrap();
        assert_eq!((sw & 0x0400, pos), (0x0400, 250_000), "node 2 reached");
        let x = lock(&h.set.rig).machine().counts()[0];
        (h, x)
    }

    #[test]
    fn a_halt_of_one_node_leaves_the_others_move_running_to_its_target() {
        let (h, x) = node_2_runs_on_while(|h| {
            h.send(CanFrame::std(0x201, &[0x0F, 0x01, 1]));
        });
        assert!(x > 0 && x < 100_000, "node 1 halted at {x}");
        assert_eq!(h.set.node_state(1).unwrap().0, State::OperationEnabled);
    }

    #[test]
    fn a_quick_stop_of_one_node_leaves_the_others_move_running_to_its_target() {
        let (h, x) = node_2_runs_on_while(|h| {
            h.send(CanFrame::std(0x201, &[0x02, 0, 1]));
        });
        assert!(x > 0 && x < 100_000, "node 1 stopped at {x}");
        assert_eq!(h.set.node_state(1).unwrap().0, State::SwitchOnDisabled);
    }

    #[test]
    fn homing_one_node_leaves_the_others_move_running_to_its_target() {
        let (h, x) = node_2_runs_on_while(|h| {
            assert_eq!(h.write(1, 0x6060, 0, &[6]), ClientStep::Downloaded);
            h.send(CanFrame::std(0x201, &[0x0F, 0, 6]));
            h.send(CanFrame::std(0x201, &[0x1F, 0, 6]));
        });
        assert_eq!(x, 0, "node 1 back at its switch");
        let sw = h.set.node_state(1).unwrap().1;
        assert_eq!(sw & 0x3400, 0x1400, "node 1 homing attained: {sw:#06x}");
        let m = lock(&h.set.rig);
        assert!(m.machine().is_axis_homed(0) && m.machine().is_axis_homed(1));
    }
}

//! A GRBL 1.1 controller as a sans-IO state machine: bytes and the wall time go in,
//! bytes come out, and motion happens on the shared simulated machine.
//!
//! What it models, as the firmware does it (gnea/grbl 1.1h):
//! * the serial receive interrupt: real-time bytes are acted on wherever they occur and
//!   never buffered; other bytes go into a 128-byte RX buffer, and bytes arriving to a
//!   full buffer are dropped;
//! * the main loop: one line at a time is taken out of the RX buffer (filtered,
//!   upper-cased), executed, and answered with exactly one `ok` or `error:N`; it stops
//!   taking lines while the planner is full, during a dwell, homing, a feed hold or a
//!   critical alarm, so the RX buffer fills as on the device;
//! * a planner of 15 usable blocks executed in order on [`SimMachine`], each block a
//!   straight move with trapezoidal acceleration (no junction blending between blocks);
//! * states Idle, Run, Hold, Jog, Home, Alarm, Check, Door, Sleep, soft reset with
//!   `ALARM:3` when motion is interrupted, soft-limit and homing alarms, check mode;
//! * `$` commands `$ $$ $x= $# $G $I $N $Nx= $C $X $H $J= $RST= $SLP`.
//!
//! Its reported position (MPos) comes from the machine's step counters divided by
//! `$100`/`$101`, never from the truth. Time: [`Clock::Scaled`] runs motion at a multiple
//! of the wall clock; [`Clock::Unconstrained`] completes motion as soon as anything
//! depends on it (right after a status report, when the planner needs room, at a buffer
//! sync), so tests never wait on wall time for motion.

use protocol::grbl::codes::{alarm, status as st};
use protocol::grbl::gcode::{filter_bytes, Action, Interpreter, Rate, MAX_AXES, MM_PER_INCH};
use protocol::grbl::realtime::{classify, Realtime, RxByte};
use protocol::grbl::settings::Settings;
use protocol::grbl::status::{MachineState, PositionKind, StatusReport};
use protocol::grbl::{GRBL_VERSION, PLANNER_BLOCKS};
use std::collections::VecDeque;
use world::axes::{lock_axes, AxesRefusal, SharedAxes};
use world::machine::MachineRefusal;
use world::{lock, Clock, SharedRig};

/// Build date GRBL 1.1h reports in `[VER:]`.
pub const BUILD_DATE: &str = "20190830";
/// Compile-time options the emulated build reports in `[OPT:]` by default: variable
/// spindle (V), line numbers (N: `Ln:` in status reports), homing forces the origin (Z,
/// as the emulator's homing does). GRBL 1.1h's default build is [`DEFAULT_BUILD_OPTIONS`].
pub const BUILD_OPTIONS: &str = "VNZ";
/// What GRBL 1.1h built with its default config.h reports: variable spindle only.
pub const DEFAULT_BUILD_OPTIONS: &str = "V";

/// Build-time options of the emulated controller.
#[derive(Clone, Debug)]
pub struct GrblConfig {
    pub clock: Clock,
    /// RX buffer size, bytes (GRBL: 128).
    pub rx_buffer: usize,
    /// Stop answering lines after this many responses (fault injection: the pty runner
    /// uses it to make the port disappear at a known point of a stream).
    pub answer_limit: Option<u64>,
    /// The `[OPT:]` flags ([`BUILD_OPTIONS`]); without `N`, status reports carry no
    /// `Ln:` field, as on a build without line numbers.
    pub build_options: &'static str,
}

impl Default for GrblConfig {
    fn default() -> Self {
        Self {
            clock: Clock::Unconstrained,
            rx_buffer: 128,
            answer_limit: None,
            build_options: BUILD_OPTIONS,
        }
    }
}

/// Counters for tests and the stand-alone binary.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct DeviceStats {
    /// `ok`/`error` responses sent (streaming lines answered).
    pub responses: u64,
    pub errors: u64,
    /// Bytes dropped because the RX buffer was full.
    pub rx_dropped: u64,
    /// Most blocks seen in the planner at once.
    pub planner_high_water: usize,
    /// Most bytes seen in the RX buffer at once.
    pub rx_high_water: usize,
    pub alarms: u64,
    pub resets: u64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum State {
    Idle,
    Cycle,
    /// Feed hold; `complete` once the axes have stopped (`Hold:0`).
    Hold,
    Jog,
    Homing,
    Alarm,
    Check,
    Door,
    Sleep,
}

/// Every axis slot X Y Z A B C; a controller with fewer axes leaves the rest at 0.
type Position = [f64; MAX_AXES];
type Actions = Action<MAX_AXES>;

/// The machine the controller drives: the X-Y stage (with a phantom Z), or a machine of
/// N independent axes (the 5-axis rotary machine, ...).
enum Machine {
    Rig(SharedRig),
    Axes(SharedAxes),
}

#[derive(Clone, Debug)]
struct Block {
    target: Position,
    rate: Rate,
    line_number: Option<u32>,
    jog: bool,
    /// A probing move: (G38.2/G38.4: a miss is an alarm, toward the work: G38.2/G38.3).
    probe: Option<(bool, bool)>,
}

#[derive(Clone, Debug)]
struct Running {
    block: Block,
    elapsed: f64,
    duration: f64,
}

/// A line being executed whose remaining actions wait for a condition.
#[derive(Clone, Debug)]
struct Pending {
    actions: VecDeque<Actions>,
    /// True while waiting for the M0 pause to be resumed.
    paused: bool,
}

#[derive(Clone, Copy, Debug)]
enum BusyKind {
    Dwell,
    Homing,
}

/// The emulated controller.
pub struct GrblDevice {
    machine: Machine,
    cfg: GrblConfig,
    settings: Settings,
    default_settings: Settings,
    interp: Interpreter<MAX_AXES>,
    state: State,
    /// Hard/soft limit alarm: everything blocked until a soft reset.
    critical: bool,
    /// The line whose move raised a soft-limit alarm, still to be answered (at the
    /// reset, as GRBL's `gc_execute_line` returns only then).
    soft_limit_line_open: bool,
    rx: VecDeque<u8>,
    line: Vec<u8>,
    pending: Option<Pending>,
    planner: VecDeque<Block>,
    running: Option<Running>,
    /// A feed hold or jog cancel decelerating the axes to a stop (`Hold:1`; a
    /// cancelled jog stays `Jog` until stopped).
    decel: Option<Running>,
    /// Remaining simulated seconds of a dwell or homing cycle.
    busy: Option<(f64, BusyKind)>,
    status_requested: bool,
    wco_counter: u8,
    ovr_counter: u8,
    overrides: [u16; 3],
    /// Phantom Z axis (the stage has none): step count only.
    z_steps: i64,
    /// The N-axis machine's motor steps per unit: `$100`.. as built. GRBL counts steps,
    /// so a later `$100` change keeps the step count (the position in mm changes) and
    /// moves by the new number of steps per mm.
    motor_steps: Position,
    startup_lines: [String; 2],
    build_info: String,
    last_wall: Option<f64>,
    out: Vec<u8>,
    stats: DeviceStats,
}

impl GrblDevice {
    /// A controller configured for the rig's machine: `$100/$101` are its counts per
    /// mm, `$110/$111` its maximum feeds, `$120/$121` its accelerations, `$130/$131` its
    /// travels; homing and soft limits enabled, homing towards negative X and Y with the
    /// origin at home (so machine space is 0..travel, as on the simulated stage).
    pub fn new(rig: SharedRig, cfg: GrblConfig) -> Self {
        let mut s = Settings::defaults();
        {
            let r = lock(&rig);
            let c = r.machine().config();
            for (k, a) in [&c.axes.x, &c.axes.y].into_iter().enumerate() {
                let k = k as u16;
                s.insert(100 + k, a.counts_per_mm);
                s.insert(110 + k, a.max_feed_mm_min);
                s.insert(120 + k, a.accel_mm_s2);
                s.insert(130 + k, a.travel_mm);
            }
        }
        s.insert(102, 400.0);
        s.insert(112, 1000.0);
        s.insert(122, 50.0);
        s.insert(132, 50.0);
        s.insert(22, 1.0);
        s.insert(20, 1.0);
        s.insert(23, 3.0);
        s.insert(25, 3000.0);
        Self::build(Machine::Rig(rig), cfg, s)
    }

    /// A controller with as many axes as the machine has (grblHAL's X Y Z A B C): `$10x`
    /// `$11x` `$13x` from the machine's axes (`$100`.. 1000 steps per unit, travels in
    /// machine coordinates from the axis minimum), no homing (the axes start at 0, the
    /// machine's reference), soft limits off (the machine refuses a move out of travel
    /// with a hard-limit alarm). Probing moves (G38.2-G38.5) probe what the machine
    /// carries.
    pub fn with_axes(machine: SharedAxes, cfg: GrblConfig) -> Self {
        let axes = lock_axes(&machine).axes();
        let mut s = Settings::defaults_for_axes(axes);
        {
            let m = lock_axes(&machine);
            for k in 0..axes {
                let l = m.limits(k);
                let k = k as u16;
                s.insert(100 + k, 1000.0);
                s.insert(110 + k, l.max_rate);
                s.insert(130 + k, l.max - l.min);
            }
        }
        Self::build(Machine::Axes(machine), cfg, s)
    }

    fn build(machine: Machine, cfg: GrblConfig, s: Settings) -> Self {
        let axes = s.axes();
        let motor_steps = std::array::from_fn(|k| s.steps_per_mm(k).unwrap_or(250.0));
        let mut d = Self {
            machine,
            cfg,
            default_settings: s.clone(),
            settings: s,
            interp: Interpreter::with_axes().restrict_axes(axes),
            state: State::Idle,
            critical: false,
            soft_limit_line_open: false,
            rx: VecDeque::new(),
            line: Vec::new(),
            pending: None,
            planner: VecDeque::new(),
            running: None,
            decel: None,
            busy: None,
            status_requested: false,
            wco_counter: 0,
            ovr_counter: 0,
            overrides: [100, 100, 100],
            z_steps: 0,
            motor_steps,
            startup_lines: [String::new(), String::new()],
            build_info: String::new(),
            last_wall: None,
            out: Vec::new(),
            stats: DeviceStats::default(),
        };
        d.interp.arc_tolerance = d.settings.arc_tolerance_mm();
        d
    }

    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    pub fn stats(&self) -> &DeviceStats {
        &self.stats
    }

    pub fn set_clock(&mut self, clock: Clock) {
        self.cfg.clock = clock;
    }

    /// Whether the answer limit (fault injection) has been reached.
    pub fn answer_limit_reached(&self) -> bool {
        self.cfg
            .answer_limit
            .is_some_and(|n| self.stats.responses >= n)
    }

    /// Power on: boot as GRBL does (Alarm if homing is enabled) and print the banner.
    pub fn power_on(&mut self, now: f64) {
        self.last_wall = Some(now);
        self.state = if self.settings.homing_enabled() {
            State::Alarm
        } else {
            State::Idle
        };
        self.boot_messages();
    }

    /// Bytes arrived on the serial line at wall time `now` (seconds, any origin).
    pub fn receive(&mut self, bytes: &[u8], now: f64) {
        self.tick(now);
        for &b in bytes {
            match classify(b) {
                RxByte::Buffered(b) => {
                    if self.rx.len() >= self.cfg.rx_buffer {
                        // On the device the main loop empties the buffer far faster than
                        // the wire fills it; bytes are lost only when it cannot.
                        self.main_loop();
                    }
                    if self.rx.len() < self.cfg.rx_buffer {
                        self.rx.push_back(b);
                        self.stats.rx_high_water = self.stats.rx_high_water.max(self.rx.len());
                    } else {
                        self.stats.rx_dropped += 1;
                    }
                }
                RxByte::Discarded => {}
                RxByte::Realtime(r) => {
                    // Lines that arrived before this byte were, on the device, read by
                    // the main loop before the interrupt fired.
                    self.main_loop();
                    self.realtime(r);
                }
            }
        }
        self.main_loop();
        self.answer_status();
    }

    /// Let time pass without input (motion, dwells, lines waiting for planner room).
    pub fn poll(&mut self, now: f64) {
        self.tick(now);
        self.main_loop();
        self.answer_status();
    }

    /// Whether something is going on that needs [`poll`](Self::poll) to be called as the
    /// time passes (motion, dwell, homing, a status report still owed).
    pub fn needs_poll(&self) -> bool {
        self.running.is_some()
            || self.decel.is_some()
            || !self.planner.is_empty()
            || self.busy.is_some()
            || self.status_requested
    }

    /// Output produced so far (taken).
    pub fn take_output(&mut self) -> Vec<u8> {
        std::mem::take(&mut self.out)
    }

    // ------------------------------------------------------------------ output

    fn send(&mut self, line: &str) {
        self.out.extend_from_slice(line.as_bytes());
        self.out.extend_from_slice(b"\r\n");
    }

    fn respond(&mut self, result: Result<(), u8>) {
        self.stats.responses += 1;
        match result {
            Ok(()) => self.send("ok"),
            Err(code) => {
                self.stats.errors += 1;
                self.send(&format!("error:{code}"));
            }
        }
    }

    fn boot_messages(&mut self) {
        self.out
            .extend_from_slice(format!("\r\nGrbl {GRBL_VERSION} ['$' for help]\r\n").as_bytes());
        if matches!(self.state, State::Alarm | State::Sleep) {
            self.state = State::Alarm;
            self.send("[MSG:'$H'|'$X' to unlock]");
        } else {
            self.run_startup_lines();
        }
    }

    fn run_startup_lines(&mut self) {
        for i in 0..2 {
            let l = self.startup_lines[i].clone();
            if l.is_empty() {
                continue;
            }
            let r = self.execute_gcode_now(&l);
            let status = match r {
                Ok(()) => "ok".to_string(),
                Err(c) => format!("error:{c}"),
            };
            self.send(&format!(">{l}:{status}"));
        }
    }

    // ------------------------------------------------------------------ time

    fn tick(&mut self, now: f64) {
        let dt = match self.last_wall {
            Some(t) => (now - t).max(0.0),
            None => 0.0,
        };
        self.last_wall = Some(now);
        if let Clock::Scaled(k) = self.cfg.clock {
            self.advance(dt * k);
        }
    }

    /// Run motion and busy periods for `dt` simulated seconds (infinite: to the end).
    fn advance(&mut self, mut dt: f64) {
        loop {
            if let Some(mut d) = self.decel.take() {
                let step = dt.min((d.duration - d.elapsed).max(0.0));
                self.machine_advance(step);
                d.elapsed += step;
                dt -= step;
                if d.elapsed >= d.duration || !self.machine_moving() {
                    self.machine_finish();
                    self.decel_done();
                    continue;
                }
                self.decel = Some(d);
                return;
            }
            if let Some((left, kind)) = self.busy {
                // A dwell lets the machine's clock run; a homing cycle already ran
                // on the machine's clock when it started.
                let dwell = matches!(kind, BusyKind::Dwell);
                if dt < left {
                    self.busy = Some((left - dt, kind));
                    if dwell {
                        self.machine_advance(dt);
                    }
                    return;
                }
                dt -= left;
                if dwell {
                    self.machine_advance(left);
                }
                self.busy = None;
                if let BusyKind::Homing = kind {
                    self.homing_done();
                }
                continue;
            }
            if matches!(
                self.state,
                State::Hold | State::Door | State::Alarm | State::Sleep
            ) {
                return;
            }
            if let Some(mut run) = self.running.take() {
                let left = (run.duration - run.elapsed).max(0.0);
                let step = dt.min(left);
                self.machine_advance(step);
                run.elapsed += step;
                dt -= step;
                if run.elapsed >= run.duration || !self.machine_moving() {
                    self.machine_finish();
                    self.planner.pop_front();
                    if let Some((fail, _)) = run.block.probe {
                        if !self.probe_done(fail) {
                            return;
                        }
                    }
                } else {
                    self.running = Some(run);
                    return;
                }
                continue;
            }
            if self.planner.is_empty() {
                if matches!(self.state, State::Cycle | State::Jog) {
                    self.state = State::Idle;
                }
                return;
            }
            if !self.start_block() {
                return;
            }
            if dt <= 0.0 && dt.is_finite() {
                return;
            }
        }
    }

    /// Start executing the block at the head of the planner. False if it could not
    /// start (an alarm was raised).
    fn start_block(&mut self) -> bool {
        let Some(block) = self.planner.front().cloned() else {
            return false;
        };
        if let Machine::Axes(m) = &self.machine {
            return self.start_axes_block(m.clone(), block);
        }
        let spm = [self.steps_per_mm(0), self.steps_per_mm(1)];
        let max = self.max_rate_towards(&block.target);
        let duration = {
            let mut r = lock(self.rig());
            let cfg = r.machine().config().clone();
            let cpm = [cfg.axes.x.counts_per_mm, cfg.axes.y.counts_per_mm];
            // Steps commanded by GRBL, turned into where the motor takes the axis.
            let to = [
                block.target[0] * spm[0] / cpm[0],
                block.target[1] * spm[1] / cpm[1],
            ];
            // Jog motions are exempt from the feed and rapid overrides (GRBL 1.1
            // jogging docs); other blocks take the override in force when they start
            // and again whenever it changes (see `set_override`).
            let feed = match (block.rate, block.jog) {
                (Rate::Feed(f), true) => f.min(max),
                (Rate::Rapid, true) => max,
                (Rate::Rapid, false) => max * f64::from(self.overrides[1]) / 100.0,
                (Rate::Feed(f), false) => (f * f64::from(self.overrides[0]) / 100.0).min(max),
            };
            if !r.machine().is_homed() {
                // Unlocked without homing: the power-on position is the reference.
                r.machine_mut().home();
            }
            match r.machine_mut().start_move(to, feed.max(1e-3)) {
                Ok(d) => d,
                Err(MachineRefusal::OutOfTravel { .. }) => {
                    drop(r);
                    // The carriage would run into the end of travel: the limit switch.
                    self.alarm(alarm::HARD_LIMIT, true);
                    return false;
                }
                Err(_) => 0.0,
            }
        };
        self.z_steps =
            (block.target[2] * self.settings.steps_per_mm(2).unwrap_or(250.0)).round() as i64;
        if self.state == State::Idle {
            self.state = if block.jog { State::Jog } else { State::Cycle };
        }
        self.running = Some(Running {
            block,
            elapsed: 0.0,
            duration,
        });
        true
    }

    /// Unconstrained clock: complete everything now.
    fn complete_all(&mut self) {
        if self.cfg.clock == Clock::Unconstrained {
            self.advance(f64::INFINITY);
        }
    }

    /// Unconstrained clock: complete the executing block (to make planner room).
    fn complete_one(&mut self) {
        if self.cfg.clock != Clock::Unconstrained {
            return;
        }
        if self.running.is_none() && !self.start_block() {
            return;
        }
        if let Some(run) = &self.running {
            let left = run.duration - run.elapsed;
            self.advance(left.max(0.0) + 1e-12);
        }
    }

    fn steps_per_mm(&self, axis: usize) -> f64 {
        self.settings.steps_per_mm(axis).unwrap_or(250.0)
    }

    /// Machine position from the step counters (X, Y from the machine, Z phantom).
    fn mpos_3(&self) -> Position {
        let rig = match &self.machine {
            Machine::Rig(rig) => rig,
            Machine::Axes(m) => {
                // The step counters: each axis at a whole number of steps.
                let p = lock_axes(m).position();
                return std::array::from_fn(|k| {
                    (p[k] * self.motor_steps[k]).round() / self.steps_per_mm(k)
                });
            }
        };
        // The machine's counts are the step pulses GRBL sent (a move goes to
        // `target * $100` pulses, `machine_move`): GRBL's step counter. Its position is
        // that count over `$100` now, so a `$100` change keeps the count (as the
        // firmware does) and a move reports where it was commanded, whatever the
        // motor's own resolution.
        let counts = lock(rig).machine().counts();
        [
            counts[0] as f64 / self.steps_per_mm(0),
            counts[1] as f64 / self.steps_per_mm(1),
            self.z_steps as f64 / self.steps_per_mm(2),
            0.0,
            0.0,
            0.0,
        ]
    }

    fn rig(&self) -> &SharedRig {
        match &self.machine {
            Machine::Rig(rig) => rig,
            Machine::Axes(_) => unreachable!("only the X-Y stage's paths ask for the rig"),
        }
    }

    fn machine_advance(&self, dt: f64) {
        match &self.machine {
            Machine::Rig(rig) => lock(rig).machine_mut().advance(dt),
            Machine::Axes(m) => lock_axes(m).advance(dt),
        }
    }

    fn machine_moving(&self) -> bool {
        match &self.machine {
            Machine::Rig(rig) => lock(rig).machine().is_moving(),
            Machine::Axes(m) => lock_axes(m).is_moving(),
        }
    }

    fn machine_finish(&self) {
        match &self.machine {
            Machine::Rig(rig) => lock(rig).machine_mut().finish_motion(),
            Machine::Axes(m) => lock_axes(m).finish_motion(),
        }
    }

    fn machine_stop(&self) {
        match &self.machine {
            Machine::Rig(rig) => lock(rig).machine_mut().stop(),
            Machine::Axes(m) => lock_axes(m).stop(),
        }
    }

    /// A block on the N-axis machine: a straight move, or a probing move that ends at
    /// the trigger point.
    fn start_axes_block(&mut self, m: SharedAxes, block: Block) -> bool {
        let max = self.max_rate_towards(&block.target);
        let feed = match (block.rate, block.jog) {
            (Rate::Feed(f), true) => f.min(max),
            (Rate::Rapid, true) => max,
            (Rate::Rapid, false) => max * f64::from(self.overrides[1]) / 100.0,
            (Rate::Feed(f), false) => (f * f64::from(self.overrides[0]) / 100.0).min(max),
        };
        if let Some((_, toward)) = block.probe {
            // GRBL checks the pin before moving: already triggered toward the work, or
            // not touching for a move away, is ALARM:4 (no probe report).
            if self.probe_pin() == toward {
                let owed = self.pending.is_some();
                self.alarm(alarm::PROBE_FAIL_INITIAL, false);
                if owed {
                    self.respond(Ok(()));
                }
                return false;
            }
        }
        // The steps GRBL commands, turned into where the motors take the axes.
        let to: Position =
            std::array::from_fn(|k| block.target[k] * self.steps_per_mm(k) / self.motor_steps[k]);
        let feed = self.motor_feed(&m, &to, &block.target, feed);
        let started = {
            let mut g = lock_axes(&m);
            match block.probe {
                Some((_, toward)) => g.start_probe(to, feed.max(1e-3), toward),
                None => g.start_move(to, feed.max(1e-3)),
            }
        };
        let duration = match started {
            Ok(d) => d,
            Err(AxesRefusal::OutOfTravel { .. }) => {
                self.alarm(alarm::HARD_LIMIT, true);
                return false;
            }
        };
        if self.state == State::Idle {
            self.state = if block.jog { State::Jog } else { State::Cycle };
        }
        self.running = Some(Running {
            block,
            elapsed: 0.0,
            duration,
        });
        true
    }

    /// The probe input as the controller reads it: the probe touching, inverted by `$6`.
    fn probe_pin(&self) -> bool {
        let touching = match &self.machine {
            Machine::Rig(_) => false,
            Machine::Axes(m) => lock_axes(m).probe_touching(),
        };
        touching != self.settings.get(6).is_some_and(|v| v != 0.0)
    }

    /// A probing move ended: record where (`[PRB:...]`, reported at once as GRBL 1.1
    /// does), and for G38.2/G38.4 without contact raise `ALARM:4`. False when an alarm
    /// stopped everything.
    fn probe_done(&mut self, fail_is_error: bool) -> bool {
        let touched = match &self.machine {
            Machine::Rig(_) => false,
            Machine::Axes(m) => lock_axes(m).probe_triggered(),
        };
        let at = self.mpos_3();
        // GRBL's `mc_probe_cycle`: the probe position is where it triggered, or for
        // G38.3/G38.5 where the move ended; a G38.2/G38.4 miss keeps the previous one
        // and raises the alarm before the `[PRB:...:0]` report.
        let failed = !touched && fail_is_error;
        if !failed {
            self.interp.probe = (at, touched);
        } else {
            self.interp.probe.1 = false;
        }
        if touched {
            // The planned position continues from where the probe stopped.
            self.interp.position = at;
        }
        if failed {
            // Not a critical alarm: GRBL still reports the probe, then answers the line.
            let owed = self.pending.is_some();
            self.alarm(alarm::PROBE_FAIL_CONTACT, false);
            self.report_probe();
            if owed {
                self.respond(Ok(()));
            }
            return false;
        }
        self.report_probe();
        true
    }

    // ------------------------------------------------------------------ main loop

    fn blocked(&self) -> bool {
        self.critical
            || self.busy.is_some()
            || self.decel.is_some()
            || matches!(
                self.state,
                State::Hold | State::Door | State::Sleep | State::Homing
            )
            || self.answer_limit_reached()
    }

    fn main_loop(&mut self) {
        loop {
            if self.blocked() {
                return;
            }
            if self.pending.is_some() {
                if !self.continue_pending() {
                    return;
                }
                continue;
            }
            // Take bytes out of the RX buffer into the line until an end of line.
            let mut eol = false;
            while let Some(b) = self.rx.pop_front() {
                if b == b'\n' || b == b'\r' {
                    eol = true;
                    break;
                }
                self.line.push(b);
            }
            if !eol {
                return;
            }
            let raw = std::mem::take(&mut self.line);
            self.execute_line(&raw);
        }
    }

    fn execute_line(&mut self, raw: &[u8]) {
        let (text, overflow) = filter_bytes(raw);
        if overflow {
            return self.respond(Err(st::OVERFLOW));
        }
        if text.is_empty() {
            return self.respond(Ok(()));
        }
        if text.starts_with('$') {
            return self.system_command(&text);
        }
        if matches!(self.state, State::Alarm | State::Jog) {
            return self.respond(Err(st::SYSTEM_GC_LOCK));
        }
        match self.run_gcode(&text) {
            Err(code) => self.respond(Err(code)),
            Ok(actions) => {
                self.pending = Some(Pending {
                    actions: actions.into(),
                    paused: false,
                });
                if self.continue_pending() {
                    // Done (answered inside).
                }
            }
        }
    }

    /// Run a startup line or `$N` validation line at once (no planner waits).
    fn execute_gcode_now(&mut self, text: &str) -> Result<(), u8> {
        let actions = self.run_gcode(text)?;
        for a in actions {
            if let Action::Move { .. } | Action::Probe { .. } = a {
                self.plan(a);
            }
        }
        Ok(())
    }

    /// Execute a G-code line (filtered, upper case) as GRBL 1.1h's `gc_execute_line`
    /// does, where it differs from the shared interpreter:
    /// * `G10 L2`/`L20` without `P` applies to the active system (GRBL fails only when
    ///   both `L` and `P` are missing; a missing `P` reads as `P0`), and `G10` with `P`
    ///   but without `L` is an unsupported `L0` (`error:20`);
    /// * the tool number is the line's `T` word, 0 when it has none (GRBL copies the
    ///   block's zeroed value on every line);
    /// * a spindle or coolant change outside check mode reports `Ov:`/`A:` in the next
    ///   status report (`sys.report_ovr_counter = 0`).
    fn run_gcode(&mut self, text: &str) -> Result<Vec<Actions>, u8> {
        let words = word_letters(text);
        let g10 = g_words(text).any(|g| g == 10.0);
        let mut line = std::borrow::Cow::Borrowed(text);
        if g10 && words.contains(&'L') && !words.contains(&'P') {
            line = std::borrow::Cow::Owned(format!("{text}P0"));
        } else if g10 && words.contains(&'P') && !words.contains(&'L') {
            // GRBL's order: the other errors (no axis words, P out of range) first,
            // then the unsupported L.
            let trial = self.interp.clone().execute(&format!("{text}L2"), false);
            return Err(trial.err().unwrap_or(st::UNSUPPORTED_COMMAND));
        }
        let before = (
            self.interp.modal.spindle,
            self.interp.modal.flood,
            self.interp.spindle_speed,
        );
        let actions = self.interp.execute(&line, false)?;
        if !words.contains(&'T') {
            self.interp.tool = 0;
        }
        let after = (
            self.interp.modal.spindle,
            self.interp.modal.flood,
            self.interp.spindle_speed,
        );
        let spindle_on = after.0 != protocol::grbl::gcode::Spindle::Off;
        let changed =
            before.0 != after.0 || before.1 != after.1 || (spindle_on && before.2 != after.2);
        if changed && self.state != State::Check {
            self.ovr_counter = 0;
        }
        Ok(actions)
    }

    /// Continue the pending line's actions. Returns true when the line is finished
    /// (answered) and the main loop may take the next one.
    fn continue_pending(&mut self) -> bool {
        let Some(mut p) = self.pending.take() else {
            return true;
        };
        if p.paused {
            // Resumed from M0 (the hold ended).
            p.paused = false;
        }
        while let Some(a) = p.actions.front().cloned() {
            let check = self.state == State::Check;
            let motion = match &a {
                Action::Move { target, jog, .. } => Some((*target, *jog)),
                Action::Probe { target, .. } => Some((*target, false)),
                _ => None,
            };
            if let Some((target, jog)) = motion {
                // Check mode parses and tracks position but moves nothing.
                if !check && !jog {
                    if self.settings.soft_limits() && self.violates_travel(&target) {
                        self.soft_limit_alarm();
                        return false;
                    }
                    if self.planner.len() >= PLANNER_BLOCKS {
                        self.complete_one();
                        if self.critical {
                            return false;
                        }
                        if self.planner.len() >= PLANNER_BLOCKS {
                            self.pending = Some(p);
                            return false;
                        }
                    }
                    let probe = matches!(a, Action::Probe { .. });
                    self.plan(a);
                    if probe {
                        // GRBL's probe cycle runs to its end inside the line: the
                        // `[PRB:...]` report comes before the line's `ok`.
                        p.actions.pop_front();
                        p.actions.push_front(Action::Sync);
                        continue;
                    }
                }
                p.actions.pop_front();
                continue;
            }
            let needs_sync = matches!(
                a,
                Action::Sync | Action::Dwell(_) | Action::Pause | Action::ProgramEnd
            );
            if needs_sync && !check && (!self.planner.is_empty() || self.running.is_some()) {
                self.complete_all();
                if !self.planner.is_empty() || self.running.is_some() || self.critical {
                    self.pending = Some(p);
                    return false;
                }
            }
            p.actions.pop_front();
            match a {
                Action::Dwell(s) if !check && s > 0.0 && self.cfg.clock != Clock::Unconstrained => {
                    self.busy = Some((s, BusyKind::Dwell));
                    self.pending = Some(p);
                    return false;
                }
                // Unconstrained, the dwell ends at once, but its time passes on the
                // machine's clock as a move's does (the screws warm meanwhile).
                Action::Dwell(s) if !check && s > 0.0 => self.machine_advance(s),
                Action::Pause if !check => {
                    self.state = State::Hold;
                    p.paused = true;
                    self.pending = Some(p);
                    return false;
                }
                Action::ProgramEnd => {
                    if !check {
                        // GRBL: WCO refresh, spindle and coolant set off (report Ov:).
                        self.wco_counter = 0;
                        self.ovr_counter = 0;
                    }
                    self.send("[MSG:Pgm End]")
                }
                Action::WcoChanged => self.wco_counter = 0,
                _ => {}
            }
        }
        self.respond(Ok(()));
        true
    }

    fn plan(&mut self, a: Actions) {
        let block = match a {
            Action::Move {
                target,
                rate,
                line_number,
                jog,
            } => Block {
                target,
                rate,
                line_number,
                jog,
                probe: None,
            },
            Action::Probe {
                target,
                feed,
                fail_is_error,
                toward,
            } => Block {
                target,
                rate: Rate::Feed(feed),
                line_number: None,
                jog: false,
                probe: Some((fail_is_error, toward)),
            },
            _ => return,
        };
        self.planner.push_back(block);
        self.stats.planner_high_water = self.stats.planner_high_water.max(self.planner.len());
        // Auto cycle start.
        if self.running.is_none()
            && self.decel.is_none()
            && matches!(self.state, State::Idle | State::Cycle | State::Jog)
        {
            self.start_block();
        }
    }

    fn violates_travel(&self, target: &Position) -> bool {
        (0..self.interp.axes).any(|k| {
            let (lo, hi) = self
                .settings
                .travel_range(k, true)
                .unwrap_or((f64::NEG_INFINITY, f64::INFINITY));
            target[k] < lo || target[k] > hi
        })
    }

    // ------------------------------------------------------------------ alarms, reset

    fn stop_motion(&mut self) {
        self.machine_stop();
        self.running = None;
        self.decel = None;
        self.planner.clear();
        self.busy = None;
    }

    fn sync_position(&mut self) {
        self.interp.position = self.mpos_3();
    }

    fn alarm(&mut self, code: u8, critical: bool) {
        self.stop_motion();
        self.pending = None;
        self.sync_position();
        self.state = State::Alarm;
        self.stats.alarms += 1;
        self.send(&format!("ALARM:{code}"));
        if critical {
            self.critical = true;
            self.send("[MSG:Reset to continue]");
        }
    }

    fn soft_limit_alarm(&mut self) {
        // GRBL holds the running cycle to a stop (position kept), then resets and
        // raises the critical alarm inside the offending line (limits_soft_check), and
        // waits there for a reset: that line is answered `ok` once the reset comes,
        // before the banner (checked on the firmware).
        self.alarm(alarm::SOFT_LIMIT, true);
        self.soft_limit_line_open = true;
    }

    fn soft_reset(&mut self) {
        self.stats.resets += 1;
        // GRBL's mc_reset: in a cycle, homing or jog, or with a hold still decelerating
        // (not once it is complete, `Hold:0`), the position may be lost: ALARM:3.
        let moving = self.running.is_some()
            || self.decel.is_some()
            || matches!(self.state, State::Cycle | State::Jog | State::Homing);
        if moving && !self.critical {
            let code = if self.state == State::Homing {
                alarm::HOMING_FAIL_RESET
            } else {
                alarm::ABORT_CYCLE
            };
            self.stop_motion();
            self.state = State::Alarm;
            self.stats.alarms += 1;
            self.send(&format!("ALARM:{code}"));
        }
        self.stop_motion();
        if std::mem::take(&mut self.soft_limit_line_open) {
            self.respond(Ok(()));
        }
        self.critical = false;
        self.pending = None;
        self.rx.clear();
        self.line.clear();
        self.status_requested = false;
        self.wco_counter = 0;
        self.ovr_counter = 0;
        self.overrides = [100, 100, 100];
        self.interp.reset();
        // GRBL's main loop clears the probe position on every reset.
        self.interp.probe = ([0.0; MAX_AXES], false);
        self.sync_position();
        if !matches!(self.state, State::Alarm | State::Sleep) {
            self.state = State::Idle;
        }
        self.boot_messages();
    }

    // ------------------------------------------------------------------ real-time

    fn realtime(&mut self, r: Realtime) {
        match r {
            Realtime::SoftReset => self.soft_reset(),
            Realtime::StatusQuery => self.status_requested = true,
            Realtime::FeedHold | Realtime::SafetyDoor => {
                if matches!(self.state, State::Alarm | State::Check | State::Sleep) || self.critical
                {
                    return;
                }
                if r == Realtime::SafetyDoor {
                    self.send("[MSG:Check Door]");
                }
                match self.state {
                    State::Jog => self.jog_cancel(),
                    State::Cycle | State::Idle | State::Hold => {
                        self.hold_motion();
                        self.state = if r == Realtime::SafetyDoor {
                            State::Door
                        } else {
                            State::Hold
                        };
                    }
                    _ => {}
                }
            }
            Realtime::CycleStart => {
                // A hold resumes only once complete (Hold:0).
                if matches!(self.state, State::Hold | State::Door) && self.decel.is_none() {
                    self.state = if self.planner.is_empty() {
                        State::Idle
                    } else {
                        State::Cycle
                    };
                    if let Some(p) = &mut self.pending {
                        p.paused = false;
                    }
                    if self.state == State::Cycle && self.running.is_none() {
                        self.start_block();
                    }
                }
            }
            Realtime::JogCancel => {
                if self.state == State::Jog {
                    self.jog_cancel();
                }
            }
            Realtime::FeedOverrideReset => self.set_override(0, 100),
            Realtime::FeedOverrideCoarsePlus => self.set_override(0, self.overrides[0] as i32 + 10),
            Realtime::FeedOverrideCoarseMinus => {
                self.set_override(0, self.overrides[0] as i32 - 10)
            }
            Realtime::FeedOverrideFinePlus => self.set_override(0, self.overrides[0] as i32 + 1),
            Realtime::FeedOverrideFineMinus => self.set_override(0, self.overrides[0] as i32 - 1),
            Realtime::RapidOverrideReset => self.set_override(1, 100),
            Realtime::RapidOverrideMedium => self.set_override(1, 50),
            Realtime::RapidOverrideLow => self.set_override(1, 25),
            Realtime::SpindleOverrideReset => self.set_override(2, 100),
            Realtime::SpindleOverrideCoarsePlus => {
                self.set_override(2, self.overrides[2] as i32 + 10)
            }
            Realtime::SpindleOverrideCoarseMinus => {
                self.set_override(2, self.overrides[2] as i32 - 10)
            }
            Realtime::SpindleOverrideFinePlus => self.set_override(2, self.overrides[2] as i32 + 1),
            Realtime::SpindleOverrideFineMinus => {
                self.set_override(2, self.overrides[2] as i32 - 1)
            }
            Realtime::SpindleStop | Realtime::FloodToggle | Realtime::MistToggle => {
                if r == Realtime::FloodToggle
                    && matches!(
                        self.state,
                        State::Idle | State::Cycle | State::Hold | State::Jog
                    )
                {
                    self.interp.modal.flood = !self.interp.modal.flood;
                    self.ovr_counter = 0;
                }
            }
        }
    }

    fn set_override(&mut self, which: usize, v: i32) {
        let (lo, hi) = if which == 1 { (25, 100) } else { (10, 200) };
        let v = v.clamp(lo, hi) as u16;
        if self.overrides[which] != v {
            self.overrides[which] = v;
            self.ovr_counter = 0;
            if which < 2 {
                self.replan_running();
            }
        }
    }

    /// GRBL re-plans the whole planner on every feed or rapid override change, so the
    /// move already running changes speed "within tens of milliseconds" (GRBL 1.1
    /// interface docs): here the running block continues from where the axes are, to
    /// the same target, at the new rate. Jogs are exempt, held motion restarts at the
    /// new rate when resumed anyway. (The simulated stage starts the rest of the move
    /// from rest, a brief dip in speed a real GRBL does not have.)
    fn replan_running(&mut self) {
        let affected =
            self.state == State::Cycle && self.running.as_ref().is_some_and(|run| !run.block.jog);
        if affected {
            self.running = None;
            self.machine_stop();
            self.start_block();
        }
    }

    /// Feed hold: the axes decelerate to a stop along the block with its acceleration
    /// (GRBL: `$120`.. limited by the direction, v^2 / 2a further on); the rest of the
    /// block runs from there on resume.
    fn hold_motion(&mut self) {
        if self.decel.is_some() {
            return;
        }
        let Some(run) = self.running.take() else {
            return;
        };
        let from = self.mpos_3();
        let rate = self.current_rate();
        self.machine_stop();
        let axes = self.interp.axes;
        let delta: Vec<f64> = (0..axes).map(|k| run.block.target[k] - from[k]).collect();
        let left = delta.iter().map(|d| d * d).sum::<f64>().sqrt();
        if left <= 0.0 || rate <= 0.0 {
            return;
        }
        // The block's acceleration: each axis's limit over its share of the direction.
        let accel = (0..axes)
            .filter(|&k| delta[k] != 0.0)
            .map(|k| {
                let a = self.settings.get(120 + k as u16).unwrap_or(10.0);
                a / (delta[k].abs() / left)
            })
            .fold(f64::INFINITY, f64::min);
        let v = rate / 60.0;
        let dist = (v * v / (2.0 * accel)).min(left);
        let mut to = from;
        for k in 0..axes {
            to[k] = from[k] + delta[k] / left * dist;
        }
        // A linear ramp from v to 0 takes as long as the distance at v / 2.
        if let Some(duration) = self.machine_move(to, rate / 2.0) {
            self.decel = Some(Running {
                block: Block {
                    target: to,
                    rate: Rate::Feed(rate / 2.0),
                    line_number: run.block.line_number,
                    jog: run.block.jog,
                    probe: None,
                },
                elapsed: 0.0,
                duration,
            });
        }
        if self.cfg.clock == Clock::Unconstrained {
            self.advance(f64::INFINITY);
        }
    }

    /// Jog cancel: decelerate as a hold does, then drop every jog block (Idle).
    fn jog_cancel(&mut self) {
        self.hold_motion();
        if self.decel.is_none() {
            self.decel_done_jog();
        }
    }

    /// The deceleration ended: a hold is complete (`Hold:0`), a cancelled jog Idle.
    fn decel_done(&mut self) {
        if self.state == State::Jog {
            self.decel_done_jog();
        }
    }

    fn decel_done_jog(&mut self) {
        self.stop_motion();
        self.sync_position();
        self.state = State::Idle;
    }

    /// The most a move from here to `target` may run (GRBL's planner:
    /// `limit_value_by_axis_maximum`, each axis's `$11x` over its share of the
    /// direction).
    fn max_rate_towards(&self, target: &Position) -> f64 {
        let here = self.mpos_3();
        let axes = self.interp.axes;
        let delta: Vec<f64> = (0..axes).map(|k| target[k] - here[k]).collect();
        let len = delta.iter().map(|d| d * d).sum::<f64>().sqrt();
        let max = (0..axes)
            .filter(|&k| delta[k] != 0.0)
            .filter_map(|k| {
                let m = self.settings.max_rate_mm_min(k)?;
                Some(m / (delta[k].abs() / len))
            })
            .fold(f64::INFINITY, f64::min);
        if max.is_finite() {
            max
        } else {
            500.0
        }
    }

    /// The axes' rate now, in GRBL units per minute (0 at rest).
    fn current_rate(&self) -> f64 {
        match &self.machine {
            Machine::Rig(rig) => {
                let r = lock(rig);
                // The motor's mm per minute as GRBL's: pulses at the motor's resolution
                // over `$100`.
                let cpm = r.machine().config().axes.x.counts_per_mm;
                r.machine().speed_mm_min() * cpm / self.steps_per_mm(0)
            }
            Machine::Axes(m) => {
                let r = lock_axes(m).rate();
                // Machine units to GRBL units along X (the axes share one scale).
                r * self.motor_steps[0] / self.steps_per_mm(0)
            }
        }
    }

    /// Start a plain move of the machine to `target` (GRBL coordinates) at `feed`;
    /// its duration, or None if the machine refused it.
    fn machine_move(&mut self, target: Position, feed: f64) -> Option<f64> {
        match &self.machine {
            Machine::Rig(rig) => {
                let mut r = lock(rig);
                let cfg = r.machine().config().clone();
                let cpm = [cfg.axes.x.counts_per_mm, cfg.axes.y.counts_per_mm];
                let to = [
                    target[0] * self.steps_per_mm(0) / cpm[0],
                    target[1] * self.steps_per_mm(1) / cpm[1],
                ];
                r.machine_mut().start_move(to, feed.max(1e-3)).ok()
            }
            Machine::Axes(m) => {
                let to: Position =
                    std::array::from_fn(|k| target[k] * self.steps_per_mm(k) / self.motor_steps[k]);
                let feed = self.motor_feed(m, &to, &target, feed);
                lock_axes(m).start_move(to, feed.max(1e-3)).ok()
            }
        }
    }

    /// A feed in GRBL units per minute as the N-axis machine's rate along the motors'
    /// path to `to` (the same when `$100`.. are as built).
    fn motor_feed(&self, m: &SharedAxes, to: &Position, target: &Position, feed: f64) -> f64 {
        let from = lock_axes(m).position();
        let here = self.mpos_3();
        let len = |a: &Position, b: &Position| {
            (0..MAX_AXES)
                .map(|k| (a[k] - b[k]).powi(2))
                .sum::<f64>()
                .sqrt()
        };
        let (lm, lg) = (len(to, &from), len(target, &here));
        if lm > 0.0 && lg > 0.0 {
            feed * lm / lg
        } else {
            feed
        }
    }

    // ------------------------------------------------------------------ status

    fn answer_status(&mut self) {
        if !self.status_requested
            || self.critical
            || self.state == State::Homing
            || self.busy.is_some_and(|b| matches!(b.1, BusyKind::Homing))
        {
            return;
        }
        self.status_requested = false;
        let line = self.status_line();
        self.send(&line);
        if self.cfg.clock == Clock::Unconstrained {
            // The report shows the moment it was asked (a full planner shows as
            // full); then everything queued runs to its end, and the main loop takes
            // what was waiting, until nothing moves any more.
            for _ in 0..100_000 {
                if self.running.is_none() && self.planner.is_empty() && self.busy.is_none() {
                    break;
                }
                self.complete_all();
                self.main_loop();
            }
        }
    }

    fn status_line(&mut self) -> String {
        let state = match self.state {
            State::Idle => MachineState::Idle,
            State::Cycle => MachineState::Run,
            State::Hold => MachineState::Hold(u8::from(self.decel.is_some())),
            State::Jog => MachineState::Jog,
            State::Homing => MachineState::Home,
            State::Alarm => MachineState::Alarm,
            State::Check => MachineState::Check,
            State::Door => MachineState::Door(0),
            State::Sleep => MachineState::Sleep,
        };
        let inches = self.settings.report_inches();
        let scale = if inches { 1.0 / MM_PER_INCH } else { 1.0 };
        let mpos = self.mpos_3();
        let wco = self.interp.wco();
        let mpos_kind = self.settings.reports_mpos();
        // Rotary axes report degrees whatever `$13` says.
        let unit = |k: usize| if k < 3 { scale } else { 1.0 };
        let position: Vec<f64> = (0..self.interp.axes)
            .map(|k| if mpos_kind { mpos[k] } else { mpos[k] - wco[k] } * unit(k))
            .collect();
        let mut r = StatusReport::new(state, position);
        if self.probe_pin() {
            r.pins = Some("P".into());
        }
        r.position_kind = if mpos_kind {
            PositionKind::Machine
        } else {
            PositionKind::Work
        };
        if self.settings.reports_buffer() {
            let blocks = PLANNER_BLOCKS.saturating_sub(self.planner.len()) as u16;
            r.buffer = Some((blocks, (self.cfg.rx_buffer - self.rx.len()) as u16));
        }
        // GRBL reports the real-time rate of its step generator (`st_get_realtime_rate`),
        // not the programmed feed: lower while accelerating, 0 when nothing moves.
        let feed = if self.running.is_some() || self.decel.is_some() {
            self.current_rate()
        } else {
            0.0
        };
        if self.cfg.build_options.contains('N') {
            r.line_number = self
                .running
                .as_ref()
                .or(self.decel.as_ref())
                .and_then(|run| run.block.line_number);
        }
        let spindle_on = self.interp.modal.spindle != protocol::grbl::gcode::Spindle::Off;
        r.feed = Some(feed * scale);
        r.spindle = Some(if spindle_on {
            self.interp.spindle_speed
        } else {
            0.0
        });
        let busy = matches!(
            self.state,
            State::Homing | State::Cycle | State::Hold | State::Jog | State::Door
        );
        if self.wco_counter > 0 {
            self.wco_counter -= 1;
        } else {
            self.wco_counter = if busy { 29 } else { 9 };
            if self.ovr_counter == 0 {
                self.ovr_counter = 1;
            }
            r.wco = Some((0..self.interp.axes).map(|k| wco[k] * unit(k)).collect());
        }
        if self.ovr_counter > 0 {
            self.ovr_counter -= 1;
        } else {
            self.ovr_counter = if busy { 19 } else { 9 };
            r.overrides = Some(self.overrides);
            let mut a = String::new();
            match self.interp.modal.spindle {
                protocol::grbl::gcode::Spindle::Cw => a.push('S'),
                protocol::grbl::gcode::Spindle::Ccw => a.push('C'),
                protocol::grbl::gcode::Spindle::Off => {}
            }
            if self.interp.modal.flood {
                a.push('F');
            }
            if !a.is_empty() {
                r.accessories = Some(a);
            }
        }
        let line = r.to_line(if inches { 4 } else { 3 });
        if !inches {
            return line;
        }
        // GRBL prints rates in inches with one decimal (N_DECIMAL_RATEVALUE_INCH).
        match line.find("|FS:") {
            Some(i) => {
                let rest = &line[i + 4..];
                let end = rest.find(',').unwrap_or(0);
                format!("{}|FS:{:.1}{}", &line[..i], feed * scale, &rest[end..])
            }
            None => line,
        }
    }

    // ------------------------------------------------------------------ $ commands

    fn system_command(&mut self, line: &str) {
        let r = self.system_command_inner(line);
        // `$H` answers when homing ends; `$C` off and `$RST` reset after their `ok`.
        match r {
            Some(Ok(After::Nothing)) => self.respond(Ok(())),
            Some(Ok(After::Reset)) => {
                self.respond(Ok(()));
                self.soft_reset();
            }
            Some(Err(code)) => self.respond(Err(code)),
            None => {}
        }
    }

    fn system_command_inner(&mut self, line: &str) -> Option<Result<After, u8>> {
        let b = line.as_bytes();
        let rest = &line[1..];
        let ok = Some(Ok(After::Nothing));
        match b.get(1).copied() {
            None => {
                self.send(
                    "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]",
                );
                ok
            }
            Some(b'J') => {
                if !matches!(self.state, State::Idle | State::Jog) {
                    return Some(Err(st::IDLE_ERROR));
                }
                if b.get(2) != Some(&b'=') {
                    return Some(Err(st::INVALID_STATEMENT));
                }
                let mut trial = self.interp.clone();
                let body = &line[3..];
                let words = word_letters(body);
                let actions = match trial.execute(body, true) {
                    // GRBL checks a jog's F word before what the block asks for (a
                    // `$J=G4P1` is error:22); only the parse comes first.
                    Err(c) if !words.contains(&'F') && !JOG_PARSE_ERRORS.contains(&c) => {
                        return Some(Err(st::UNDEFINED_FEED_RATE))
                    }
                    Err(c) => return Some(Err(c)),
                    // S and T words are unused in a jog (GRBL: error:36).
                    Ok(_) if words.contains(&'S') || words.contains(&'T') => {
                        return Some(Err(st::UNUSED_WORDS))
                    }
                    Ok(a) => a,
                };
                for a in &actions {
                    if let Action::Move { target, .. } = a {
                        if self.settings.soft_limits() && self.violates_travel(target) {
                            return Some(Err(st::TRAVEL_EXCEEDED));
                        }
                    }
                }
                self.interp = trial;
                for a in actions {
                    if self.planner.len() >= PLANNER_BLOCKS {
                        self.complete_one();
                    }
                    self.plan(a);
                }
                ok
            }
            Some(b'$' | b'G' | b'C' | b'X') => {
                if b.len() != 2 {
                    return Some(Err(st::INVALID_STATEMENT));
                }
                match b[1] {
                    b'$' => {
                        if matches!(self.state, State::Cycle | State::Hold) {
                            return Some(Err(st::IDLE_ERROR));
                        }
                        let lines: Vec<String> = self
                            .settings
                            .iter()
                            .filter_map(|(n, _)| self.settings.line(n))
                            .collect();
                        for l in lines {
                            self.send(&l);
                        }
                        ok
                    }
                    b'G' => {
                        let s = format!(
                            "[GC:{}]",
                            self.interp.parser_state_with(self.settings.report_inches())
                        );
                        self.send(&s);
                        ok
                    }
                    b'C' => {
                        if self.state == State::Check {
                            self.send("[MSG:Disabled]");
                            Some(Ok(After::Reset))
                        } else if self.state != State::Idle {
                            Some(Err(st::IDLE_ERROR))
                        } else {
                            self.state = State::Check;
                            self.send("[MSG:Enabled]");
                            ok
                        }
                    }
                    _ => {
                        if self.state == State::Alarm {
                            self.send("[MSG:Caution: Unlocked]");
                            self.state = State::Idle;
                            self.sync_position();
                        }
                        ok
                    }
                }
            }
            Some(c) => {
                if !matches!(self.state, State::Idle | State::Alarm) {
                    return Some(Err(st::IDLE_ERROR));
                }
                match c {
                    b'#' => {
                        if b.len() != 2 {
                            return Some(Err(st::INVALID_STATEMENT));
                        }
                        self.report_parameters();
                        ok
                    }
                    b'H' => {
                        if !self.settings.homing_enabled() {
                            return Some(Err(st::SETTING_DISABLED));
                        }
                        if b.len() != 2 {
                            return Some(Err(st::INVALID_STATEMENT));
                        }
                        self.start_homing();
                        None
                    }
                    b'S' => {
                        if rest != "SLP" {
                            return Some(Err(st::INVALID_STATEMENT));
                        }
                        // GRBL answers the line, then sleeps (its `[MSG:Sleeping]`
                        // comes from the real-time loop, after the `ok`).
                        self.respond(Ok(()));
                        self.stop_motion();
                        self.state = State::Sleep;
                        self.send("[MSG:Sleeping]");
                        None
                    }
                    b'I' => {
                        if b.len() == 2 {
                            let info =
                                format!("[VER:{GRBL_VERSION}.{BUILD_DATE}:{}]", self.build_info);
                            self.send(&info);
                            let opt = format!(
                                "[OPT:{},{},{}]",
                                self.cfg.build_options, PLANNER_BLOCKS, self.cfg.rx_buffer
                            );
                            self.send(&opt);
                            ok
                        } else if b[2] == b'=' {
                            self.build_info = line[3..].to_string();
                            ok
                        } else {
                            Some(Err(st::INVALID_STATEMENT))
                        }
                    }
                    b'R' => {
                        let target = match rest {
                            "RST=$" => 0,
                            "RST=#" => 1,
                            "RST=*" => 2,
                            _ => return Some(Err(st::INVALID_STATEMENT)),
                        };
                        if target != 1 {
                            self.settings = self.default_settings.clone();
                        }
                        if target != 0 {
                            self.interp.stored = [[0.0; MAX_AXES]; 8];
                        }
                        if target == 2 {
                            self.startup_lines = [String::new(), String::new()];
                        }
                        self.send("[MSG:Restoring defaults]");
                        Some(Ok(After::Reset))
                    }
                    b'N' if b.len() == 2 => {
                        let lines: Vec<String> = (0..2)
                            .map(|i| format!("$N{i}={}", self.startup_lines[i]))
                            .collect();
                        for l in lines {
                            self.send(&l);
                        }
                        ok
                    }
                    _ => {
                        let (is_startup, body) = match c {
                            b'N' => (true, &line[2..]),
                            _ => (false, &line[1..]),
                        };
                        if is_startup && self.state != State::Idle {
                            return Some(Err(st::IDLE_ERROR));
                        }
                        let (num, value) = match body.split_once('=') {
                            Some(x) => x,
                            None => {
                                return Some(Err(if parse_grbl_float(body).is_some() {
                                    st::INVALID_STATEMENT
                                } else {
                                    st::BAD_NUMBER_FORMAT
                                }))
                            }
                        };
                        let Some(n) = parse_grbl_float(num) else {
                            return Some(Err(st::BAD_NUMBER_FORMAT));
                        };
                        if is_startup {
                            let n = n.trunc() as usize;
                            if value.len() > 79 - 3 {
                                return Some(Err(st::LINE_LENGTH_EXCEEDED));
                            }
                            if let Err(code) = self.execute_gcode_now(value) {
                                return Some(Err(code));
                            }
                            // GRBL 1.1h checks no range: `$N2=` and beyond answer `ok`
                            // and write past its two startup lines in EEPROM (here:
                            // nowhere).
                            if let Some(slot) = self.startup_lines.get_mut(n) {
                                *slot = value.to_string();
                            }
                            return ok;
                        }
                        let Some(v) = parse_grbl_float(value) else {
                            return Some(Err(st::BAD_NUMBER_FORMAT));
                        };
                        if n > 255.0 {
                            return Some(Err(st::INVALID_STATEMENT));
                        }
                        match self.settings.write(n as u16, v) {
                            Ok(()) => {
                                self.interp.arc_tolerance = self.settings.arc_tolerance_mm();
                                if n as u16 == 13 {
                                    // GRBL: "Make sure WCO is immediately updated."
                                    self.wco_counter = 0;
                                }
                                ok
                            }
                            Err(code) => Some(Err(code)),
                        }
                    }
                }
            }
        }
    }

    fn report_parameters(&mut self) {
        let inches = self.settings.report_inches();
        let (scale, dec) = if inches {
            (1.0 / MM_PER_INCH, 4)
        } else {
            (1.0, 3)
        };
        let axes = self.interp.axes;
        let f = |v: &Position| {
            v[..axes]
                .iter()
                .enumerate()
                .map(|(k, x)| format!("{:.dec$}", if k < 3 { x * scale } else { *x }))
                .collect::<Vec<_>>()
                .join(",")
        };
        let names = ["G54", "G55", "G56", "G57", "G58", "G59", "G28", "G30"];
        let mut lines: Vec<String> = names
            .iter()
            .zip(self.interp.stored.iter())
            .map(|(n, v)| format!("[{n}:{}]", f(v)))
            .collect();
        lines.push(format!("[G92:{}]", f(&self.interp.coord_offset)));
        lines.push(format!(
            "[TLO:{:.dec$}]",
            self.interp.tool_length_offset * scale
        ));
        lines.push(self.probe_line());
        for l in lines {
            self.send(&l);
        }
    }

    /// `[PRB:x,y,z,...:1|0]`: the last probe's machine position (one number per axis,
    /// in the report units) and whether it touched.
    fn probe_line(&self) -> String {
        let inches = self.settings.report_inches();
        let (scale, dec) = if inches {
            (1.0 / MM_PER_INCH, 4)
        } else {
            (1.0, 3)
        };
        let (p, ok) = self.interp.probe;
        let values: Vec<String> = p[..self.interp.axes]
            .iter()
            .enumerate()
            .map(|(k, x)| format!("{:.dec$}", if k < 3 { x * scale } else { *x }))
            .collect();
        format!("[PRB:{}:{}]", values.join(","), u8::from(ok))
    }

    fn report_probe(&mut self) {
        let l = self.probe_line();
        self.send(&l);
    }

    fn start_homing(&mut self) {
        self.state = State::Homing;
        if let Machine::Axes(_) = self.machine {
            // The N-axis machine's axes start at their reference: homing only syncs.
            self.homing_done();
            return;
        }
        let took = {
            let mut r = lock(self.rig());
            let t0 = r.machine().now_s();
            r.machine_mut().home();
            r.machine().now_s() - t0
        };
        self.z_steps = 0;
        match self.cfg.clock {
            Clock::Unconstrained => self.homing_done(),
            Clock::Scaled(_) => {
                // The machine already ran its homing; the controller stays busy for
                // as long as that took on the emulated clock.
                self.busy = Some((took, BusyKind::Homing));
            }
        }
    }

    fn homing_done(&mut self) {
        self.state = State::Idle;
        self.sync_position();
        self.respond(Ok(()));
        self.run_startup_lines();
    }
}

enum After {
    Nothing,
    Reset,
}

/// Errors GRBL finds while parsing a block's words, before its checks of what the
/// block asks for.
const JOG_PARSE_ERRORS: [u8; 8] = [
    st::EXPECTED_COMMAND_LETTER,
    st::BAD_NUMBER_FORMAT,
    st::NEGATIVE_VALUE,
    st::UNSUPPORTED_COMMAND,
    st::MODAL_GROUP_VIOLATION,
    st::COMMAND_VALUE_NOT_INTEGER,
    st::WORD_REPEATED,
    st::INVALID_LINE_NUMBER,
];

/// The letters of a filtered G-code line's words.
fn word_letters(text: &str) -> Vec<char> {
    text.chars().filter(|c| c.is_ascii_uppercase()).collect()
}

/// The values of a filtered line's G words (`10`, `38.2`, ...).
fn g_words(text: &str) -> impl Iterator<Item = f64> + '_ {
    text.match_indices('G').filter_map(move |(i, _)| {
        let rest = &text[i + 1..];
        let end = rest
            .find(|c: char| !(c.is_ascii_digit() || c == '.'))
            .unwrap_or(rest.len());
        rest[..end].parse().ok()
    })
}

/// GRBL's `read_float` on a whole string.
fn parse_grbl_float(s: &str) -> Option<f64> {
    let ok = !s.is_empty()
        && s.chars()
            .enumerate()
            .all(|(i, c)| c.is_ascii_digit() || c == '.' || (i == 0 && (c == '-' || c == '+')))
        && s.chars().any(|c| c.is_ascii_digit())
        && s.matches('.').count() <= 1;
    if ok {
        s.parse().ok()
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::config::ConfigDoc;
    use protocol::grbl::response::{LineDecoder, Response};
    use protocol::{Board, Polarity};
    use std::path::Path;
    use world::camera::CameraModel;
    use world::machine::MachineConfig;

    pub(crate) fn rig() -> SharedRig {
        let m = include_str!("../../../config/machines/c5-stage.toml");
        let m = MachineConfig::from_doc(&ConfigDoc::from_text("c5-stage.toml", m, Path::new(".")))
            .unwrap();
        let c = include_str!("../../../config/cameras/mono-1.3mp.toml");
        let c =
            CameraModel::from_doc(&ConfigDoc::from_text("cam.toml", c, Path::new("."))).unwrap();
        let b = Board::nominal("t", 0.5, 0.25, Polarity::DarkOnLight, 40, 30, [0.0, 0.0]);
        world::shared_rig(m, b, c)
    }

    struct Host {
        dev: GrblDevice,
        dec: LineDecoder,
        t: f64,
    }

    impl Host {
        fn new(clock: Clock) -> Self {
            let mut dev = GrblDevice::new(
                rig(),
                GrblConfig {
                    clock,
                    ..Default::default()
                },
            );
            dev.power_on(0.0);
            let mut h = Host {
                dev,
                dec: LineDecoder::new(),
                t: 0.0,
            };
            h.read();
            h
        }
        fn read(&mut self) -> Vec<Response> {
            let mut out = Vec::new();
            self.dec.feed(&self.dev.take_output(), &mut out);
            out
        }
        fn send(&mut self, bytes: &[u8]) -> Vec<Response> {
            self.dev.receive(bytes, self.t);
            self.read()
        }
        fn status(&mut self) -> StatusReport {
            let r = self.send(b"?");
            match r.last() {
                Some(Response::Status(s)) => s.clone(),
                other => panic!("no status: {other:?}"),
            }
        }
        fn pass(&mut self, dt: f64) -> Vec<Response> {
            self.t += dt;
            self.dev.poll(self.t);
            self.read()
        }
    }

    #[test]
    fn boots_locked_then_unlocks_homes_and_moves_by_its_step_counters() {
        let mut dev = GrblDevice::new(rig(), GrblConfig::default());
        dev.power_on(0.0);
        let boot = String::from_utf8(dev.take_output()).unwrap();
        assert_eq!(
            boot,
            "\r\nGrbl 1.1h ['$' for help]\r\n[MSG:'$H'|'$X' to unlock]\r\n"
        );
        let mut h = Host {
            dev,
            dec: LineDecoder::new(),
            t: 0.0,
        };
        assert_eq!(h.send(b"G0X1\n"), vec![Response::Error(9)]);
        assert_eq!(h.status().state, MachineState::Alarm);
        assert_eq!(h.send(b"$H\n"), vec![Response::Ok]);
        assert_eq!(h.send(b"G1X10.00013Y5F3000\n"), vec![Response::Ok]);
        // Unconstrained clock: the first report shows the move starting, then it runs.
        let s = h.status();
        assert_eq!((s.state, s.position[0]), (MachineState::Run, 0.0));
        let s = h.status();
        assert_eq!(s.state, MachineState::Idle);
        // 2000 steps/mm: 10.00013 mm is 20000.26 steps -> 20000 steps -> 10.000 mm.
        assert_eq!(s.position, vec![10.0, 5.0, 0.0]);
        let counts = h.dev.rig().lock().unwrap().machine().counts();
        assert_eq!(counts, [20000, 10000]);
    }

    /// GRBL counts the pulses it sends: with `$100` unlike the motor's own resolution
    /// the position reported is the commanded one (the firmware's 2.000 after `G1 X2`),
    /// and a later `$100` change keeps the count (issue 38).
    #[test]
    fn reported_position_follows_the_command_after_a_steps_per_mm_change() {
        let mut h = Host::new(Clock::Unconstrained);
        h.send(b"$X\n");
        let cpm = h
            .dev
            .rig()
            .lock()
            .unwrap()
            .machine()
            .config()
            .axes
            .x
            .counts_per_mm;
        assert_eq!(h.send(b"$100=500\n"), vec![Response::Ok]);
        assert_eq!(h.send(b"G1X2F3000\n"), vec![Response::Ok]);
        let _ = h.status();
        let s = h.status();
        assert_eq!(s.state, MachineState::Idle);
        assert_eq!(s.position[0], 2.0, "reported after G1 X2 with $100=500");
        // 1000 pulses at the motor's own resolution.
        let counts = h.dev.rig().lock().unwrap().machine().counts();
        assert_eq!(counts[0], 1000);
        assert!(cpm != 500.0);
        assert_eq!(h.send(b"$100=250\n"), vec![Response::Ok]);
        assert_eq!(h.status().position[0], 4.0, "the count kept: 1000 / 250");
    }

    #[test]
    fn realtime_bytes_act_mid_line_and_unknown_extended_bytes_vanish() {
        let mut h = Host::new(Clock::Unconstrained);
        let r = h.send(b"$X\nG1X1?Y1\xFEF100\n");
        // The `?` inside the line is answered, and the line around it is intact.
        assert!(
            matches!(
                r.as_slice(),
                [
                    Response::Message(_),
                    Response::Ok,
                    Response::Ok,
                    Response::Status(_)
                ]
            ),
            "{r:?}"
        );
        assert_eq!(h.status().position, vec![1.0, 1.0, 0.0]);
    }

    #[test]
    fn rx_buffer_overflow_drops_bytes_like_the_device() {
        let mut h = Host::new(Clock::Scaled(1.0));
        h.send(b"$X\n$10=3\n");
        // A long move keeps the planner busy; 16 more moves fill the planner and
        // then the RX buffer; the rest of 400 bytes is dropped.
        let mut prog = Vec::new();
        for i in 0..40 {
            prog.extend_from_slice(format!("G1X{}F100\n", 10 + i).as_bytes());
        }
        assert!(prog.len() > 300);
        let r = h.send(&prog);
        assert_eq!(
            r.iter().filter(|x| **x == Response::Ok).count(),
            PLANNER_BLOCKS
        );
        assert_eq!(h.dev.stats().planner_high_water, PLANNER_BLOCKS);
        assert!(h.dev.stats().rx_dropped > 0);
        let s = h.status();
        assert_eq!(s.buffer.map(|b| b.0), Some(0), "{s:?}");
        assert_eq!(s.buffer.map(|b| b.1), Some(0), "RX buffer full");
        assert_eq!(s.state, MachineState::Run);
    }

    #[test]
    fn soft_limit_alarm_blocks_until_reset() {
        let mut h = Host::new(Clock::Unconstrained);
        h.send(b"$H\n");
        let r = h.send(b"G0X500\nG0X1\n");
        assert_eq!(
            r,
            vec![
                Response::Alarm(2),
                Response::Message("Reset to continue".into())
            ]
        );
        assert!(h.send(b"?").is_empty(), "no status in the critical alarm");
        // The offending line is answered once the reset ends the alarm's wait, before
        // the banner (GRBL 1.1h, issue 38); the line after it was flushed.
        let r = h.send(&[0x18]);
        assert_eq!(r[0], Response::Ok, "{r:?}");
        assert!(matches!(&r[1], Response::Banner { .. }), "{r:?}");
        assert_eq!(r[2], Response::Message("'$H'|'$X' to unlock".into()));
        assert_eq!(h.status().state, MachineState::Alarm);
    }

    #[test]
    fn jog_cancel_hold_resume_and_reset_during_motion() {
        let mut h = Host::new(Clock::Scaled(1.0));
        assert!(h.send(b"$H\n").is_empty(), "homing takes time");
        assert_eq!(h.pass(60.0), vec![Response::Ok]);
        assert_eq!(h.send(b"$J=G91X100F600\n"), vec![Response::Ok]);
        assert_eq!(h.send(b"$J=X500F600\n"), vec![Response::Error(15)]);
        h.pass(1.0);
        let s = h.status();
        assert_eq!(s.state, MachineState::Jog);
        assert!(s.position[0] > 5.0 && s.position[0] < 20.0, "{s:?}");
        h.send(&[0x85]);
        let s = h.status();
        assert_eq!(s.state, MachineState::Jog, "decelerating");
        h.pass(1.0);
        let s = h.status();
        assert_eq!(s.state, MachineState::Idle);
        let stopped = s.position[0];
        h.pass(1.0);
        assert_eq!(h.status().position[0], stopped, "jog cancelled");
        // G-code, hold, resume.
        assert_eq!(h.send(b"G1X150F600\n"), vec![Response::Ok]);
        h.pass(1.0);
        h.send(b"!");
        assert_eq!(h.status().state, MachineState::Hold(1), "decelerating");
        h.pass(1.0);
        let held = h.status();
        assert_eq!(held.state, MachineState::Hold(0));
        h.pass(1.0);
        assert_eq!(h.status().position, held.position, "no motion while held");
        h.send(b"~");
        h.pass(1.0);
        let s = h.status();
        assert_eq!(s.state, MachineState::Run);
        assert!(s.position[0] > held.position[0]);
        // Reset while moving: ALARM:3, position kept by the counters but not trusted.
        let r = h.send(&[0x18]);
        assert_eq!(r[0], Response::Alarm(3));
        assert!(matches!(r[1], Response::Banner { .. }));
    }

    struct FreeAxes;
    impl world::axes::Workpiece for FreeAxes {
        fn axes(&self) -> usize {
            3
        }
        fn limits(&self, _: usize) -> world::axes::AxisLimits {
            world::axes::AxisLimits {
                min: -1000.0,
                max: 1000.0,
                max_rate: 1000.0,
            }
        }
        fn probe_contact(
            &mut self,
            _: &world::axes::AxesPosition,
            _: &world::axes::AxesPosition,
        ) -> Option<world::axes::AxesPosition> {
            None
        }
        fn probe_touching(&self, _: &world::axes::AxesPosition) -> bool {
            false
        }
    }

    fn text(dev: &mut GrblDevice, bytes: &[u8], t: f64) -> String {
        dev.receive(bytes, t);
        String::from_utf8(dev.take_output()).unwrap()
    }

    fn x_of(report: &str) -> f64 {
        let r = StatusReport::parse(report.lines().last().unwrap()).unwrap();
        r.position[0]
    }

    /// GRBL 1.1h decelerates a feed hold and a jog cancel with the block's
    /// acceleration: v^2 / 2a further on (F1000, $120=100: 1.389 mm), `Hold:1` on the
    /// way, `Hold:0` at rest; a resume runs the rest of the block.
    #[test]
    fn a_feed_hold_and_a_jog_cancel_decelerate_with_the_configured_acceleration() {
        let m = world::axes::AxesMachine::new(Box::new(FreeAxes)).shared();
        let mut dev = GrblDevice::with_axes(
            m,
            GrblConfig {
                clock: Clock::Scaled(1.0),
                ..Default::default()
            },
        );
        dev.power_on(0.0);
        dev.take_output();
        for l in ["$100=250\n", "$110=1000\n", "$120=100\n", "G1X20F1000\n"] {
            assert_eq!(text(&mut dev, l.as_bytes(), 0.0), "ok\r\n");
        }
        dev.poll(0.6);
        let at = text(&mut dev, b"?!", 0.6);
        assert!(at.starts_with("<Hold:1|"), "{at}");
        let x0 = x_of(&at);
        assert!((x0 - 10.0).abs() < 0.01, "{at}");
        assert_eq!(text(&mut dev, b"~", 0.61), "", "no resume before Hold:0");
        dev.poll(0.65);
        let mid = text(&mut dev, b"?", 0.65);
        assert!(mid.starts_with("<Hold:1|"), "{mid}");
        dev.poll(2.0);
        let held = text(&mut dev, b"?", 2.0);
        assert!(held.starts_with("<Hold:0|"), "{held}");
        assert!((x_of(&held) - x0 - 1.389).abs() < 0.01, "{held}");
        text(&mut dev, b"~", 2.0);
        dev.poll(5.0);
        let end = text(&mut dev, b"?", 5.0);
        assert!(end.starts_with("<Idle|MPos:20.000,"), "{end}");
        // A jog cancelled at speed stops as far on, then Idle; the next jog starts there.
        assert_eq!(text(&mut dev, b"$J=X0F1000\n", 5.0), "ok\r\n");
        dev.poll(5.6);
        let at = text(&mut dev, b"?\x85", 5.6);
        assert!(at.starts_with("<Jog|"), "{at}");
        dev.poll(7.0);
        let stopped = text(&mut dev, b"?", 7.0);
        assert!(stopped.starts_with("<Idle|"), "{stopped}");
        assert!(
            (x_of(&at) - x_of(&stopped) - 1.389).abs() < 0.01,
            "{stopped}"
        );
        assert_eq!(text(&mut dev, b"$J=G91X1F1000\n", 7.0), "ok\r\n");
        dev.poll(9.0);
        let after = text(&mut dev, b"?", 9.0);
        assert!(
            (x_of(&after) - x_of(&stopped) - 1.0).abs() < 0.005,
            "{after}"
        );
    }

    /// Homed, then a 150 mm move at F600 (10 mm/s) running for 1 s.
    fn moving_at_f600(jog: bool) -> (Host, f64) {
        let mut h = Host::new(Clock::Scaled(1.0));
        h.send(b"$H\n");
        h.pass(60.0);
        let line: &[u8] = if jog {
            b"$J=X150F600\n"
        } else {
            b"G1X150F600\n"
        };
        assert_eq!(h.send(line), vec![Response::Ok]);
        h.pass(1.0);
        let x = h.status().position[0];
        (h, x)
    }

    #[test]
    fn a_feed_override_changes_the_move_already_running_and_fs_shows_the_real_rate() {
        let (mut plain, x0) = moving_at_f600(false);
        assert!(
            (plain.status().feed.unwrap() - 600.0).abs() < 1e-6,
            "cruising at F600"
        );
        plain.pass(2.0);
        let full = plain.status().position[0] - x0;
        let (mut h, x0) = moving_at_f600(false);
        // Five -10 % steps: 50 %, applied to the move under way.
        h.send(&[0x92; 5]);
        h.pass(2.0);
        let s = h.status();
        let halved = s.position[0] - x0;
        assert!((full - 20.0).abs() < 0.1, "{full}");
        assert!((halved - 10.0).abs() < 0.2, "{halved} mm in 2 s at 50 %");
        assert!((s.feed.unwrap() - 300.0).abs() < 1e-6, "{s:?}");
        assert_eq!(s.overrides.map(|o| o[0]), Some(50), "{s:?}");
        // Back to 100 % mid-move: full speed again.
        h.send(&[0x90]);
        h.pass(1.0);
        assert!((h.status().feed.unwrap() - 600.0).abs() < 1e-6);
        // Nothing moving: FS:0.
        h.pass(60.0);
        let s = h.status();
        assert_eq!((s.state, s.feed), (MachineState::Idle, Some(0.0)));
    }

    #[test]
    fn jog_motions_ignore_the_feed_override() {
        let (mut h, x0) = moving_at_f600(true);
        h.send(&[0x92; 5]);
        h.pass(2.0);
        let s = h.status();
        assert_eq!(s.state, MachineState::Jog);
        assert!((s.position[0] - x0 - 20.0).abs() < 0.1, "{s:?}");
        assert!((s.feed.unwrap() - 600.0).abs() < 1e-6, "{s:?}");
    }

    #[test]
    fn dollar_g_prints_the_feed_in_mm_unless_13_asks_for_inches() {
        let mut h = Host::new(Clock::Unconstrained);
        h.send(b"$X\n");
        assert_eq!(h.send(b"G20F10\n"), vec![Response::Ok]);
        let gc = |h: &mut Host| {
            h.send(b"$G\n")
                .iter()
                .find_map(|r| match r {
                    Response::ParserState(text) => Some(text.clone()),
                    _ => None,
                })
                .expect("a [GC:] line")
        };
        // 10 in/min is stored as 254 mm/min and reported so, G20 or not.
        assert!(gc(&mut h).ends_with("T0 F254 S0"), "{}", gc(&mut h));
        assert_eq!(h.send(b"$13=1\n"), vec![Response::Ok]);
        assert!(gc(&mut h).ends_with("T0 F10.0 S0"), "{}", gc(&mut h));
    }

    #[test]
    fn check_mode_settings_and_reports() {
        let mut h = Host::new(Clock::Unconstrained);
        h.send(b"$X\n");
        assert_eq!(
            h.send(b"$C\n"),
            vec![Response::Message("Enabled".into()), Response::Ok]
        );
        assert_eq!(
            h.send(b"G1X50F100\nG1X1Q1\n"),
            vec![Response::Ok, Response::Error(20)]
        );
        assert_eq!(h.status().position[0], 0.0, "check mode moves nothing");
        let r = h.send(b"$C\n");
        assert_eq!(r[0], Response::Message("Disabled".into()));
        assert_eq!(r[1], Response::Ok);
        assert!(matches!(r[2], Response::Banner { .. }));
        let r = h.send(b"$I\n");
        assert_eq!(
            r[1],
            Response::Options {
                flags: "VNZ".into(),
                planner_blocks: 15,
                rx_buffer: 128
            }
        );
        let r = h.send(b"$$\n");
        assert!(
            r.contains(&Response::Setting {
                number: 100,
                value: "2000.000".into()
            }),
            "{r:?}"
        );
        assert_eq!(r.last(), Some(&Response::Ok));
        assert_eq!(h.send(b"$100=abc\n"), vec![Response::Error(2)]);
        assert_eq!(h.send(b"$999=1\n"), vec![Response::Error(3)]);
        assert_eq!(
            h.send(b"$Q\n"),
            vec![Response::Error(2)],
            "GRBL reads an unknown letter as a bad setting number"
        );
        assert_eq!(h.send(b"$10=0\n"), vec![Response::Ok]);
        let s = h.status();
        assert_eq!(s.position_kind, PositionKind::Work);
        let r = h.send(b"$G\n");
        assert_eq!(
            r[0],
            Response::ParserState("G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0".into())
        );
        let long = format!("G1X{}\n", "1".repeat(90));
        assert_eq!(h.send(long.as_bytes()), vec![Response::Error(11)]);
        assert_eq!(
            h.send(b"\r\n"),
            vec![Response::Ok, Response::Ok],
            "CR LF is two lines"
        );
    }
}

#[cfg(test)]
mod five_axis_tests {
    use super::*;
    use protocol::grbl::response::{LineDecoder, Response};
    use world::axes::AxesMachine;
    use world::rotary::{RotaryMachineSim, RotaryWorkpiece, TouchProbe};

    /// The paper's machine with a noiseless probe (trigger points exact to the step).
    fn sim() -> RotaryMachineSim {
        let mut s = RotaryMachineSim::paper(7);
        s.probe = TouchProbe {
            noise_mm: 0.0,
            ..TouchProbe::default()
        };
        s
    }

    struct Host {
        dev: GrblDevice,
        dec: LineDecoder,
    }

    impl Host {
        fn new() -> Self {
            let m = AxesMachine::new(Box::new(RotaryWorkpiece { sim: sim() })).shared();
            let mut dev = GrblDevice::with_axes(m, GrblConfig::default());
            dev.power_on(0.0);
            let mut h = Host {
                dev,
                dec: LineDecoder::new(),
            };
            h.send(b"");
            h
        }
        fn send(&mut self, bytes: &[u8]) -> Vec<Response> {
            self.dev.receive(bytes, 0.0);
            let mut out = Vec::new();
            self.dec.feed(&self.dev.take_output(), &mut out);
            out
        }
        fn status(&mut self) -> StatusReport {
            self.send(b"?");
            match self.send(b"?").pop() {
                Some(Response::Status(s)) => s,
                other => panic!("no status: {other:?}"),
            }
        }
    }

    fn prb(r: &[Response]) -> (Vec<f64>, String) {
        r.iter()
            .find_map(|r| match r {
                Response::Parameter { name, value } if name == "PRB" => {
                    let (v, ok) = value.rsplit_once(':').unwrap();
                    Some((
                        v.split(',').map(|x| x.parse().unwrap()).collect(),
                        ok.into(),
                    ))
                }
                _ => None,
            })
            .unwrap_or_else(|| panic!("no PRB in {r:?}"))
    }

    #[test]
    fn six_axis_status_settings_and_rotary_moves() {
        let mut h = Host::new();
        assert_eq!(h.send(b"G0 X10 A30 C-90\n"), vec![Response::Ok]);
        assert_eq!(h.status().position, vec![10.0, 0.0, 0.0, 30.0, 0.0, -90.0]);
        let settings = h.send(b"$$\n");
        let has = |n: &str| {
            settings
                .iter()
                .any(|r| matches!(r, Response::Setting { number, .. } if number.to_string() == n))
        };
        assert!(has("105") && has("135") && !has("106"));
        // G20: X in inches, A in degrees.
        assert_eq!(
            h.send(b"G20 G0 X1 A10\nG21\n"),
            vec![Response::Ok, Response::Ok]
        );
        let s = h.status().position;
        assert_eq!((s[0], s[3]), (25.4, 10.0));
    }

    #[test]
    fn g38_2_touches_the_ball_top_and_reports_six_axes_before_ok() {
        let mut h = Host::new();
        let truth = sim();
        let c = truth.ball_centre(0, 0.0, 0.0);
        let l = truth.geometry.tool_length_mm;
        let (x, y) = (c.x, c.y);
        let r = h.send(format!("G0 X{x:.3} Y{y:.3} Z{:.3}\n", c.z + l + 30.0).as_bytes());
        assert_eq!(r, vec![Response::Ok]);
        let r = h.send(format!("G38.2 Z{:.3} F100\n", c.z + l).as_bytes());
        assert_eq!(r.last(), Some(&Response::Ok));
        let (p, ok) = prb(&r);
        assert_eq!(ok, "1");
        assert_eq!(p.len(), 6);
        // Gauge point at contact: centre + ball radius + stylus radius + tool length,
        // less the pre-travel; the stylus centre is at most 0.0005 from (x, y) of the
        // centre, so the contact height is off by < 1e-6.
        let expected = c.z + 13.0 + 1.5 + l - 0.0008;
        assert!((p[2] - expected).abs() <= 0.0006, "{} vs {expected}", p[2]);
        let s = h.status();
        assert_eq!(
            s.pins.as_deref(),
            Some("P"),
            "still touching after pre-travel"
        );
        // G38.2 again from there: the probe is already triggered, ALARM:4, no report.
        let r = h.send(b"G38.2 Z0 F100\n");
        assert_eq!(r, vec![Response::Alarm(4), Response::Ok]);
        // Away from the ball: contact lost just above the touching height.
        h.send(b"$X\n");
        let r = h.send(format!("G38.4 Z{:.3} F100\n", c.z + l + 20.0).as_bytes());
        let (p2, ok) = prb(&r);
        assert_eq!(ok, "1");
        assert!((p2[2] - (c.z + 14.5 + l)).abs() <= 0.0006, "{}", p2[2]);
    }

    #[test]
    fn a_miss_is_alarm_5_with_g38_2_and_silent_with_g38_3() {
        let mut h = Host::new();
        assert_eq!(h.send(b"G0 X0 Y150 Z100\n"), vec![Response::Ok]);
        let r = h.send(b"G38.3 Z50 F200\n");
        let (p, ok) = prb(&r);
        assert_eq!((ok.as_str(), p[2]), ("0", 50.0));
        assert_eq!(r.last(), Some(&Response::Ok));
        let r = h.send(b"G38.2 Z0 F200\n");
        assert_eq!(r[0], Response::Alarm(5));
        let (p, ok) = prb(&r);
        // The failed probe keeps the previous probe position.
        assert_eq!((ok.as_str(), p[2]), ("0", 50.0));
        assert_eq!(r.last(), Some(&Response::Ok));
        assert_eq!(h.status().state, MachineState::Alarm);
        // $6 inverts the pin: nothing touches, yet the pin reads triggered.
        h.send(b"$X\n$6=1\n");
        assert_eq!(h.status().pins.as_deref(), Some("P"));
    }
}

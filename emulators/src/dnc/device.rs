//! A closed controller's tape port as a sans-IO state machine: bytes and the wall time
//! go in, flow-control codes come out, blocks run on the shared simulated machine.
//!
//! Protocol B of the Fanuc remote buffer as its manual describes the CNC reading
//! (`../shared/notes/legacy-controllers.md`, [RB-52], figures of the Fanuc 0 [B2B-H]):
//! * Cycle start (the operator's, in DNC/remote mode) sends DC1: "send".
//! * Free space in the buffer falls below [`DncConfig::dc3_free`] -> DC3; it rises to
//!   [`DncConfig::dc1_free`] again -> DC1 and the host resumes with the next character.
//! * An alarm sends DC3 + NAK, a reset DC3 + SYN; reading ends and the buffer is
//!   cleared. Nothing else ever comes back: no echo, no status, no position.
//! * The tape: a leader (anything before the first `%`, NULs included) is skipped; data
//!   from the first `%` to the next LF (a title) is skipped; then ISO blocks ended by LF
//!   (CRs and NULs are dropped) up to the closing `%`. Blocks after M02/M30 are read
//!   and not executed.
//!
//! Overrun: after DC3 a sender may send only a few more characters (Fanuc reader port:
//! 10, alarm 087 beyond). A pseudo-terminal has no wire (a sender writes as fast as
//! memory, and the DC3 reaches it a moment after it is written), so the judge here is
//! causal: the port layer tells [`DncDevice::sender_progress`] how many characters the
//! sender has written in all and how many of the controller's characters wait unread.
//! Once the DC3 waits where the sender can see it, the sender may write no more than
//! the free space the buffer then has (at least [`DncConfig::overrun_allowance`])
//! before DC1: more is an overrun alarm (the buffer would overflow), whether it read
//! the DC3 or not. That is the remote buffer's rule (protocol B: Fanuc 0, DC3 at 1024
//! free, "overrun < 1024"); the reader port's 10 characters after DC3 cannot be judged
//! without a wire's timing, so a sender is held to the buffer's room. What a sender
//! wrote before it could see the DC3 waits on the line (the device takes only what
//! fits), as characters on a wire would. [`DncStats::max_after_dc3`] is the most
//! written after a DC3 was visible.
//!
//! Stored subprograms ([`DncDevice::store_program`]) are called by M98 from the tape,
//! as a Fanuc calls programs from its memory while running DNC.

use protocol::fanuc::{arc_points, parse_line, Action, FanucError, Interpreter, Line, Options};
use std::collections::{HashMap, VecDeque};
use world::{lock, Clock, SharedRig};

pub const DC1: u8 = 0x11;
pub const DC3: u8 = 0x13;
pub const NAK: u8 = 0x15;
pub const SYN: u8 = 0x16;

/// The controller's settings; defaults as stated in each field.
#[derive(Clone, Debug)]
pub struct DncConfig {
    pub clock: Clock,
    /// Receive buffer, characters. Not stated in the public manuals: default 4096.
    pub buffer: usize,
    /// DC3 when the free space falls below this (Fanuc 0 figure: 1024).
    pub dc3_free: usize,
    /// DC1 when the free space is at least this again (Fanuc 0 figure: 2048).
    pub dc1_free: usize,
    /// The least room a sender is given after DC3, characters, when the buffer's free
    /// space is smaller (Fanuc reader port: 10 characters after DC3, alarm 087 beyond).
    pub overrun_allowance: usize,
    /// How programs read (DPI, least increment, block skip, nesting).
    pub program: Options,
    /// The operator presses cycle start whenever the control is idle (after power-on,
    /// after a tape ended, after a reset). Off: only [`DncDevice::cycle_start`] does.
    pub auto_start: bool,
    /// The operator's reference return before the first tape: the machine is homed at
    /// power-on.
    pub home_at_power_on: bool,
    /// Arcs run as chords within this, mm (the simulated stage moves in straight lines).
    pub arc_tolerance_mm: f64,
    /// Tests' pacing: machine seconds granted per frame the simulated camera grabs,
    /// in place of the wall clock (`clock` then only says the time is the emulator's).
    /// The camera sees the same frames in each dwell however loaded the machine is and
    /// however fast it renders. None (the default): the clock.
    pub seconds_per_frame: Option<f64>,
}

impl Default for DncConfig {
    fn default() -> Self {
        Self {
            clock: Clock::Scaled(1.0),
            buffer: 4096,
            dc3_free: 1024,
            dc1_free: 2048,
            overrun_allowance: 10,
            program: Options::default(),
            auto_start: true,
            home_at_power_on: true,
            arc_tolerance_mm: 0.0001,
            seconds_per_frame: None,
        }
    }
}

/// What the controller counted; the test's view (a real control shows only its alarm).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DncStats {
    /// Characters taken from the line.
    pub received: u64,
    /// Tape lines read (between the title and the closing `%`).
    pub lines: u64,
    /// Blocks executed (tape and stored programs).
    pub blocks: u64,
    /// FNV-1a 64 of every tape line read (its text without CR/LF, then `\n`).
    pub checksum: u64,
    pub dc1_sent: u64,
    pub dc3_sent: u64,
    /// Most characters a sender wrote after a DC3 waited where it could see it
    /// (characters already on their way included).
    pub max_after_dc3: u64,
    /// Most characters ever in the buffer.
    pub max_fill: usize,
    /// Tapes read to their closing `%`.
    pub tapes: u64,
    /// Alarms, in words, in order.
    pub alarms: Vec<String>,
    pub resets: u64,
    /// The interpreter's machine position (X Y Z, mm) after the last block taken.
    pub position: [f64; 3],
    /// Motion and dwells still to run.
    pub busy: bool,
    /// With [`DncConfig::seconds_per_frame`]: the camera's frames whose time has run
    /// (a camera that waits for this before its next frame sees every slice of time).
    pub frames_run: u64,
}

const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;

/// FNV-1a 64 of tape lines as [`DncStats::checksum`] counts them.
pub fn checksum_lines<'a>(lines: impl IntoIterator<Item = &'a str>) -> u64 {
    let mut h = FNV_OFFSET;
    for l in lines {
        h = fnv(h, l.as_bytes());
        h = fnv(h, b"\n");
    }
    h
}

fn fnv(mut h: u64, bytes: &[u8]) -> u64 {
    for b in bytes {
        h ^= u64::from(*b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    /// Not reading: waiting for cycle start.
    Idle,
    /// Skipping the leader up to the first `%`.
    Leader,
    /// Skipping the title up to the first LF.
    Title,
    Program,
    /// After M02/M30: reading to the closing `%` without executing.
    Ended,
    Alarm,
}

#[derive(Clone, Debug)]
enum Step {
    Move { to: [f64; 2], feed: f64 },
    Dwell { seconds: f64 },
}

#[derive(Clone, Debug)]
struct Frame {
    program: u32,
    next: usize,
    repeats_left: u32,
}

/// The controller.
pub struct DncDevice {
    rig: SharedRig,
    cfg: DncConfig,
    phase: Phase,
    buffer: VecDeque<u8>,
    /// DC3 in effect.
    stopped: bool,
    /// Characters written by the sender when the DC3 was first seen waiting for it,
    /// and the room it is given from then on.
    at_dc3: Option<(u64, usize)>,
    interp: Interpreter,
    steps: VecDeque<Step>,
    /// Simulated seconds left of the step running.
    running_left: f64,
    frames: Vec<Frame>,
    stored: HashMap<u32, Vec<String>>,
    line_no: usize,
    budget_s: f64,
    last_wall: Option<f64>,
    /// The camera's frames counted so far (`seconds_per_frame`).
    last_frames: u64,
    out: Vec<u8>,
    stats: DncStats,
}

impl DncDevice {
    pub fn new(rig: SharedRig, cfg: DncConfig) -> Self {
        let position = {
            let mut r = lock(&rig);
            if matches!(cfg.clock, Clock::Scaled(_)) || cfg.seconds_per_frame.is_some() {
                // The emulator advances the machine by the wall clock.
                r.time_owned_by_wall_clock();
            }
            let m = r.machine_mut();
            if cfg.home_at_power_on && !m.is_homed() {
                m.home();
            }
            let p = m.position_mm();
            [p[0], p[1], 0.0]
        };
        Self {
            interp: Interpreter::new(cfg.program.clone(), position),
            rig,
            cfg,
            phase: Phase::Idle,
            buffer: VecDeque::new(),
            stopped: false,
            at_dc3: None,
            steps: VecDeque::new(),
            running_left: 0.0,
            frames: Vec::new(),
            stored: HashMap::new(),
            line_no: 0,
            budget_s: 0.0,
            last_wall: None,
            last_frames: 0,
            out: Vec::new(),
            stats: DncStats {
                position,
                checksum: FNV_OFFSET,
                ..DncStats::default()
            },
        }
    }

    /// Store a program in memory (for M98): its text, starting with its `O` block
    /// (`%` lines and a leader before it allowed). Returns its number.
    pub fn store_program(&mut self, text: &str) -> Result<u32, FanucError> {
        let mut number = None;
        let mut lines = Vec::new();
        for (i, raw) in text.split('\n').enumerate() {
            let raw = raw.trim_end_matches(['\r', '\0']);
            match parse_line(raw, i + 1)? {
                Line::Percent if number.is_some() => break,
                Line::Block(b) if number.is_none() => match b.program_number() {
                    Some(o) => number = Some(o),
                    None => {
                        return Err(FanucError::new(
                            i + 1,
                            raw,
                            "a stored program starts with its O number",
                        ))
                    }
                },
                _ if number.is_some() => lines.push(raw.to_string()),
                _ => {}
            }
        }
        let o = number.ok_or_else(|| FanucError::new(1, "", "no O number in the program"))?;
        self.stored.insert(o, lines);
        Ok(o)
    }

    /// Power on: DC1 at once when the operator's cycle start is automatic.
    pub fn power_on(&mut self, now: f64) {
        self.last_wall = Some(now);
        if self.cfg.auto_start {
            self.cycle_start();
        }
    }

    /// The operator presses cycle start: an idle control starts reading (DC1).
    /// Pressed again while it waits for a tape's first characters, it sends DC1 again
    /// (for a sender that opened its port after the first one and lost it).
    pub fn cycle_start(&mut self) {
        if self.phase == Phase::Leader && !self.stopped && self.buffer.is_empty() {
            self.send_dc1();
            return;
        }
        if self.phase == Phase::Idle {
            self.phase = Phase::Leader;
            if self.cfg.buffer - self.buffer.len() >= self.cfg.dc1_free {
                self.send_dc1();
            }
        }
    }

    /// The operator presses reset: motion stops, the buffer is cleared, the alarm is
    /// cleared, reading ends (DC3 + SYN).
    pub fn reset(&mut self) {
        self.clear();
        self.out.extend_from_slice(&[DC3, SYN]);
        self.stats.dc3_sent += 1;
        self.stats.resets += 1;
        self.phase = Phase::Idle;
        if self.cfg.auto_start {
            self.cycle_start();
        }
    }

    fn clear(&mut self) {
        self.buffer.clear();
        self.steps.clear();
        self.frames.clear();
        self.running_left = 0.0;
        self.stopped = true;
        self.at_dc3 = None;
        let mut r = lock(&self.rig);
        let m = r.machine_mut();
        m.stop();
        let p = m.position_mm();
        self.interp.position = [p[0], p[1], self.interp.position[2]];
    }

    fn alarm(&mut self, message: String) {
        self.clear();
        self.out.extend_from_slice(&[DC3, NAK]);
        self.stats.dc3_sent += 1;
        self.stats.alarms.push(message);
        self.phase = Phase::Alarm;
    }

    fn send_dc3(&mut self) {
        self.out.push(DC3);
        self.stats.dc3_sent += 1;
        self.stopped = true;
        self.at_dc3 = None;
    }

    fn send_dc1(&mut self) {
        self.out.push(DC1);
        self.stats.dc1_sent += 1;
        self.stopped = false;
        self.at_dc3 = None;
    }

    /// Characters are taken into the buffer (while idle too: they wait there for
    /// cycle start); an alarmed control discards them.
    fn reading(&self) -> bool {
        self.phase != Phase::Alarm
    }

    /// How many characters the device takes from the line now: the free space while
    /// it reads (what does not fit waits on the line), else any amount (discarded).
    /// Before its DC3, no more than brings the buffer to the DC3 point: a controller
    /// takes a wire's characters one by one and sends DC3 at that point, so a port layer
    /// that reads in batches must not fill the buffer past it before the DC3 goes out
    /// (the sender would be judged against the room left after the whole batch).
    pub fn room(&self) -> usize {
        if !self.reading() {
            return 4096;
        }
        let free = self.cfg.buffer - self.buffer.len();
        if self.stopped || free < self.cfg.dc3_free {
            free
        } else {
            // Free falls below `dc3_free` with this many characters.
            free - self.cfg.dc3_free + 1
        }
    }

    /// Characters arrived at wall time `now` (seconds, any origin).
    pub fn receive(&mut self, bytes: &[u8], now: f64) {
        self.catch_up(now);
        self.stats.received += bytes.len() as u64;
        if !self.reading() {
            return;
        }
        if let Some(b) = bytes.iter().find(|b| **b >= 0x80) {
            self.alarm(format!(
                "TH alarm: character 0x{b:02X} is not ISO code (7 bits; parity is the line's)"
            ));
            return;
        }
        if self.buffer.len() + bytes.len() > self.cfg.buffer {
            self.alarm("overrun: the receive buffer overflowed".into());
            return;
        }
        self.buffer.extend(bytes);
        self.stats.max_fill = self.stats.max_fill.max(self.buffer.len());
        if !self.stopped && self.cfg.buffer - self.buffer.len() < self.cfg.dc3_free {
            self.send_dc3();
        }
        self.execute();
    }

    /// The port layer's view of the sender: `written` characters written in all (read
    /// by the device or waiting on the line) and `unread` characters the device sent
    /// that the sender has not read yet. See the module's overrun rule.
    pub fn sender_progress(&mut self, written: u64, unread: u64) {
        if !self.stopped || !self.reading() {
            return;
        }
        if unread > 0 && self.at_dc3.is_none() {
            // The DC3 is where the sender can see it: from here on, what it writes
            // must fit in the room the buffer has.
            let free = self.cfg.buffer - self.buffer.len();
            self.at_dc3 = Some((written, free.max(self.cfg.overrun_allowance)));
        }
        if let Some((at, room)) = self.at_dc3 {
            let after = written.saturating_sub(at);
            self.stats.max_after_dc3 = self.stats.max_after_dc3.max(after);
            if after > room as u64 {
                let read = if unread > 0 { "did not read" } else { "read" };
                self.alarm(format!(
                    "overrun: the sender {read} DC3 and sent {after} characters into {room} free"
                ));
            }
        }
    }

    /// Advance to wall time `now`: motion runs, blocks are taken from the buffer.
    pub fn poll(&mut self, now: f64) {
        self.catch_up(now);
        self.execute();
    }

    /// Something runs or waits to run.
    pub fn needs_poll(&self) -> bool {
        self.running_left > 0.0 || !self.steps.is_empty() || !self.buffer.is_empty()
    }

    pub fn take_output(&mut self) -> Vec<u8> {
        std::mem::take(&mut self.out)
    }

    pub fn stats(&self) -> &DncStats {
        &self.stats
    }

    fn catch_up(&mut self, now: f64) {
        let dt = self.last_wall.map_or(0.0, |t| (now - t).max(0.0));
        self.last_wall = Some(now);
        if let Some(per_frame) = self.cfg.seconds_per_frame {
            let frames = lock(&self.rig).frames();
            let new = frames.saturating_sub(self.last_frames);
            self.last_frames = frames;
            self.budget_s += new as f64 * per_frame;
            self.stats.frames_run = frames;
            return;
        }
        if let Clock::Scaled(k) = self.cfg.clock {
            self.budget_s += dt * k;
        }
    }

    /// Run steps and take blocks while simulated time allows.
    fn execute(&mut self) {
        let unconstrained = self.cfg.clock == Clock::Unconstrained;
        loop {
            if self.running_left > 0.0 {
                let dt = if unconstrained {
                    self.running_left
                } else {
                    self.running_left.min(self.budget_s)
                };
                lock(&self.rig).machine_mut().advance(dt);
                self.running_left -= dt;
                if !unconstrained {
                    self.budget_s -= dt;
                }
                if self.running_left > 1e-12 {
                    break;
                }
                self.running_left = 0.0;
                if unconstrained {
                    lock(&self.rig).machine_mut().finish_motion();
                }
            }
            if let Some(step) = self.steps.pop_front() {
                self.start(step);
                continue;
            }
            if !self.take_block() {
                break;
            }
        }
        if self.running_left == 0.0 && self.steps.is_empty() && !unconstrained {
            // Idle time passes without a budget to save up.
            let idle = std::mem::take(&mut self.budget_s);
            lock(&self.rig).machine_mut().advance(idle);
        }
        self.stats.busy = self.running_left > 0.0 || !self.steps.is_empty();
    }

    fn start(&mut self, step: Step) {
        match step {
            Step::Dwell { seconds } => self.running_left = seconds,
            Step::Move { to, feed } => {
                let started = lock(&self.rig).machine_mut().start_move(to, feed);
                match started {
                    Ok(d) => self.running_left = d,
                    Err(e) => self.alarm(format!("overtravel: {e}")),
                }
            }
        }
    }

    /// Take the next block (stored program first, else the tape) and queue its steps.
    /// False when there is none yet.
    fn take_block(&mut self) -> bool {
        if matches!(self.phase, Phase::Alarm | Phase::Idle) {
            return false;
        }
        if let Some(frame) = self.frames.last_mut() {
            let lines = &self.stored[&frame.program];
            let Some(text) = lines.get(frame.next).cloned() else {
                let o = frame.program;
                self.alarm(format!("O{o:04}: ended without M99"));
                return false;
            };
            frame.next += 1;
            // Line numbers of a stored program count its O block as line 1.
            let line = frame.next + 1;
            self.run_text(&text, line);
            return true;
        }
        match self.phase {
            Phase::Leader => {
                // Anything before the first `%` (NULs, feed holes) is the leader.
                match self.buffer.iter().position(|b| *b == b'%') {
                    Some(p) => {
                        self.take_bytes(p + 1);
                        self.phase = Phase::Title;
                    }
                    None if self.buffer.is_empty() => return false,
                    None => {
                        self.take_bytes(self.buffer.len());
                    }
                }
                return true;
            }
            Phase::Title => {
                // From the first `%` to the next LF: skipped.
                return match self.buffer.iter().position(|b| *b == b'\n') {
                    Some(p) => {
                        self.take_bytes(p + 1);
                        self.phase = Phase::Program;
                        true
                    }
                    None => {
                        let n = self.buffer.len();
                        self.take_bytes(n);
                        false
                    }
                };
            }
            _ => {}
        }
        let Some(end) = self.buffer.iter().position(|b| *b == b'\n') else {
            if self.buffer.len() >= self.cfg.buffer {
                self.alarm(format!(
                    "a block longer than the {}-character buffer",
                    self.cfg.buffer
                ));
            }
            return false;
        };
        let bytes = self.take_bytes(end + 1);
        let text: String = bytes[..end]
            .iter()
            .filter(|b| !matches!(b, b'\r' | 0))
            .map(|b| *b as char)
            .collect();
        self.line_no += 1;
        if text.trim() == "%" {
            self.tape_end();
            return true;
        }
        self.stats.lines += 1;
        self.stats.checksum = fnv(fnv(self.stats.checksum, text.as_bytes()), b"\n");
        if self.phase == Phase::Program {
            let line = self.line_no;
            self.run_text(&text, line);
        }
        true
    }

    fn take_bytes(&mut self, n: usize) -> Vec<u8> {
        let taken: Vec<u8> = self.buffer.drain(..n).collect();
        if self.stopped
            && self.reading()
            && self.cfg.buffer - self.buffer.len() >= self.cfg.dc1_free
        {
            self.send_dc1();
        }
        taken
    }

    /// The closing `%`: the program is read. The control is idle (its cycle start
    /// pressed again at once when automatic); what follows in the buffer is the next
    /// tape's leader.
    fn tape_end(&mut self) {
        self.stats.tapes += 1;
        self.line_no = 0;
        self.frames.clear();
        if self.cfg.auto_start {
            self.phase = Phase::Leader;
        } else {
            if !self.stopped {
                self.send_dc3();
            }
            self.phase = Phase::Idle;
        }
    }

    fn run_text(&mut self, text: &str, line: usize) {
        let block = match parse_line(text, line) {
            Ok(Line::Block(b)) => b,
            Ok(Line::Percent) => {
                self.alarm(format!("block {line}: `%` inside a program"));
                return;
            }
            Ok(Line::Blank) => return,
            Err(e) => {
                self.alarm(e.to_string());
                return;
            }
        };
        if block.skip && self.cfg.program.block_skip {
            return;
        }
        let before = self.interp.position;
        let actions = match self.interp.execute(&block, line, text) {
            Ok(a) => a,
            Err(e) => {
                self.alarm(e.to_string());
                return;
            }
        };
        self.stats.blocks += 1;
        self.stats.position = self.interp.position;
        let mut from = before;
        for a in actions {
            match &a {
                Action::Rapid { to } => {
                    self.push_move(&mut from, *to, 1e9);
                }
                Action::Linear { to, feed } => self.push_move(&mut from, *to, *feed),
                Action::Arc { feed, .. } => {
                    for p in arc_points(from, &a, self.cfg.arc_tolerance_mm) {
                        self.push_move(&mut from, p, *feed);
                    }
                }
                Action::Dwell { seconds } => {
                    self.steps.push_back(Step::Dwell { seconds: *seconds })
                }
                Action::Call { program, repeats } => {
                    if !self.stored.contains_key(program) {
                        self.alarm(format!("block {line}: O{program:04} is not in memory"));
                        return;
                    }
                    if self.frames.len() >= self.cfg.program.max_nesting {
                        self.alarm(format!(
                            "block {line}: subprograms nested deeper than {}",
                            self.cfg.program.max_nesting
                        ));
                        return;
                    }
                    self.frames.push(Frame {
                        program: *program,
                        next: 0,
                        repeats_left: *repeats,
                    });
                }
                Action::Return => match self.frames.last_mut() {
                    Some(f) if f.repeats_left > 1 => {
                        f.repeats_left -= 1;
                        f.next = 0;
                    }
                    Some(_) => {
                        self.frames.pop();
                    }
                    None => {
                        self.alarm(format!(
                            "block {line}: M99 in the main program (a tape cannot loop back)"
                        ));
                        return;
                    }
                },
                Action::End => {
                    self.frames.clear();
                    self.phase = Phase::Ended;
                }
            }
        }
    }

    fn push_move(&mut self, from: &mut [f64; 3], to: [f64; 3], feed: f64) {
        // The simulated stage has X and Y; Z is interpreted and tracked, not moved.
        if (to[0] - from[0]).abs() > 1e-12 || (to[1] - from[1]).abs() > 1e-12 {
            self.steps.push_back(Step::Move {
                to: [to[0], to[1]],
                feed,
            });
        }
        *from = to;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::Board;
    use world::camera::CameraModel;
    use world::machine::MachineConfig;

    fn device(cfg: DncConfig) -> DncDevice {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config");
        let rig = world::shared_rig(
            MachineConfig::load(&root.join("machines/c5-stage.toml")).unwrap(),
            Board::load(&root.join("boards/dot-grid-0.5mm.toml")).unwrap(),
            CameraModel::load(&root.join("cameras/mono-1.3mp.toml")).unwrap(),
        );
        DncDevice::new(rig, cfg)
    }

    fn unconstrained() -> DncConfig {
        DncConfig {
            clock: Clock::Unconstrained,
            ..DncConfig::default()
        }
    }

    #[test]
    fn a_tape_runs_with_a_stored_subprogram_a_dwell_and_an_arc() {
        let mut d = device(unconstrained());
        d.store_program("%\nO8003\nG91G01X1.F1000.\nM99\n%\n")
            .unwrap();
        d.power_on(0.0);
        assert_eq!(d.take_output(), vec![DC1]);
        let tape = "\0\0%TITLE\nO1\nG90G00X10.Y10.\nM98P38003\nG04P500\n\
                    G90G02X23.Y10.R5.F600.\n/G00X50.\nM30\nG00X99.\n%\n";
        d.receive(tape.as_bytes(), 0.0);
        let s = d.stats().clone();
        assert!(s.alarms.is_empty(), "{:?}", s.alarms);
        assert_eq!(s.tapes, 1);
        // O1 ... M30 and the block after it are read; the skipped and the one after
        // M30 do not run; the subprogram's two blocks run three times.
        assert_eq!(s.lines, 8);
        assert_eq!(s.blocks, 6 + 3 * 2);
        assert_eq!(s.position, [23.0, 10.0, 0.0]);
        let p = lock(&d.rig).machine().position_mm();
        assert!(
            (p[0] - 23.0).abs() < 1e-9 && (p[1] - 10.0).abs() < 1e-9,
            "{p:?}"
        );
        assert!(
            d.take_output().is_empty(),
            "nothing but flow control comes back"
        );
    }

    #[test]
    fn a_refused_block_alarms_with_nak_and_reset_answers_syn() {
        let mut d = device(unconstrained());
        d.power_on(0.0);
        d.take_output();
        d.receive(b"%\nG90G00X10.\nG68X1.Y1.R45.\n", 0.0);
        assert_eq!(d.take_output(), vec![DC3, NAK]);
        assert!(
            d.stats().alarms[0].contains("block 2"),
            "{:?}",
            d.stats().alarms
        );
        // Characters while alarmed are discarded.
        d.receive(b"G00X20.\n", 0.0);
        assert_eq!(d.stats().position, [10.0, 0.0, 0.0]);
        d.reset();
        assert_eq!(d.take_output(), vec![DC3, SYN, DC1]);
    }

    #[test]
    fn the_buffer_marks_send_dc3_and_dc1_and_an_ignored_dc3_alarms() {
        let cfg = DncConfig {
            clock: Clock::Scaled(1.0),
            buffer: 100,
            dc3_free: 30,
            dc1_free: 60,
            ..DncConfig::default()
        };
        let mut d = device(cfg);
        d.power_on(0.0);
        d.take_output();
        // 10-character blocks, each a 1 mm move: nothing ends at t = 0.
        d.receive(b"%\n", 0.0);
        let block = b"G91X1.F60\n";
        let mut written = 0u64;
        assert!(d.take_output().is_empty());
        while d.take_output().is_empty() {
            d.receive(block, 0.0);
            written += block.len() as u64;
        }
        // DC3 once the free space fell below 30: the first block left the buffer to
        // run, the next eight fill 80 of 100.
        assert_eq!(d.stats().dc3_sent, 1);
        assert_eq!(written, 90);
        // It waits for the sender with 20 free: 20 more characters fit, no alarm.
        d.sender_progress(written, 1);
        d.sender_progress(written + 20, 0);
        assert!(d.stats().alarms.is_empty());
        // More than the room: overrun alarm, NAK.
        d.sender_progress(written + 21, 0);
        assert_eq!(d.take_output(), vec![DC3, NAK]);
        assert!(
            d.stats().alarms[0].contains("overrun"),
            "{:?}",
            d.stats().alarms
        );
    }
}

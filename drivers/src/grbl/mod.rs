//! A GRBL 1.1 stage driver, speaking the serial protocol exactly as a good G-code sender
//! does: send-response for commands and settings, character counting for programs,
//! status polling (`?`) for position and end of motion, real-time bytes for hold,
//! resume, jog cancel and reset.
//!
//! * Connect, as the careful senders do: first a greeting. Opening the port often
//!   resets the board (an Arduino resets on DTR) and a booting GRBL drops what it
//!   receives, so nothing is sent but `?` (real-time, harmless) until either the
//!   start-up banner (`Grbl 1.1h ['$' for help]`, `GrblHAL 1.1f [...]`) or a status
//!   report (a controller already running) arrives; whatever a boot prints before its
//!   banner is passed over (a first power-up's `error:7` and settings dump, `[MSG:]`
//!   lines). No greeting within [`greeting_window`] provokes one with a soft reset
//!   (0x18); still none, a last `$I` is tried; nothing GRBL's by `connect_timeout` is
//!   an error naming what the device did send.
//!   Then `$I` (answered in any state, also in Alarm) must give `[VER:]`; a banner or
//!   an `error:7` arriving meanwhile (a boot in progress) makes it ask again after the
//!   banner. Then `$$` for steps/mm, rates and travel, and one status report.
//! * Moves: `G21G53G1X..Y..F..` with 4 decimals (GRBL parses floats; the machine
//!   quantises to its steps), absolute in machine coordinates whatever the modal state.
//! * Every wait is bounded (`tokio::time` deadlines); alarms come back as
//!   [`DriverError::Alarm`], `error:N` as [`DriverError::Refused`] with GRBL's meaning.

mod link;
mod stream;

pub use crate::program::{StreamError, StreamOptions, StreamReport};
pub use link::Transport;
pub use link_spec::grbl::GrblOptions;

#[cfg(test)]
mod tests;

use crate::error::DriverError;
use crate::stage::{
    Axis, AxisInfo, AxisValues, Capabilities, ProbeHit, ProbeMode, Stage, StageInfo, StageState,
    StageStatus,
};
use async_trait::async_trait;
use link::Link;
use protocol::grbl::command::Command;
use protocol::grbl::gcode::BlockWriter;
use protocol::grbl::response::Response;
use protocol::grbl::settings::Settings;
use protocol::grbl::status::{MachineState, StatusReport};
use protocol::grbl::stream::DEFAULT_RX_BUFFER;
use protocol::grbl::{alarm_text, error_text, Realtime, PLANNER_BLOCKS};
use std::time::Duration;
use tokio::time::Instant;

/// What `$I` told.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BuildInfo {
    /// e.g. `1.1h.20190830`.
    pub version: String,
    /// `[OPT:]` flags, e.g. `VNZ`.
    pub options: String,
    pub planner_blocks: usize,
    pub rx_buffer: usize,
}

/// A GRBL controller driven over a byte link.
pub struct GrblStage {
    link: Link,
    info: StageInfo,
    settings: Settings,
    build: BuildInfo,
    opts: GrblOptions,
    /// Serial port to reopen on reconnect (only read where serial ports are built in).
    #[cfg_attr(not(feature = "serial"), allow(dead_code))]
    port: Option<(String, u32)>,
    last_wco: Option<Vec<f64>>,
    last_alarm: Option<u8>,
    /// A hard/soft limit alarm: GRBL ignores everything but a soft reset.
    needs_reset: bool,
    /// GRBL booted or reset into its alarm lock ("'$H'|'$X' to unlock").
    locked: bool,
    /// Last absolute target sent, exactly (GRBL reports positions to 1 um only).
    commanded: Option<[f64; 3]>,
    /// A motion line was answered `ok` (queued) and not yet waited for.
    motion_queued: bool,
    /// Position fields of the status reports (3 on GRBL 1.1, up to 6 on grblHAL).
    reported_axes: usize,
    /// `$H` was sent and its `ok` not read: GRBL answers no `?` during the cycle, so
    /// a stop must not ask first (the caller dropped the wait, e.g. on Ctrl-C).
    homing: bool,
}

/// How often `?` is sent while waiting for a controller to greet.
const GREETING_POLL: Duration = Duration::from_millis(250);

/// How long to wait for a greeting before provoking one with a soft reset: long enough
/// for an Arduino's boot loader and GRBL's first power-up (1.5 s), and at most 40 % of
/// the connect timeout, so the banner after the reset still has time to come.
pub fn greeting_window(connect_timeout: Duration) -> Duration {
    (connect_timeout * 2 / 5).min(Duration::from_millis(2500))
}

fn with_deadline(d: Duration) -> Instant {
    Instant::now() + d
}

impl GrblStage {
    /// Open a serial port (USB adapter or pseudo-terminal) and connect.
    #[cfg(feature = "serial")]
    pub async fn open(path: &str, baud: u32, opts: GrblOptions) -> Result<GrblStage, DriverError> {
        let io = open_port(path, baud)?;
        let mut s = Self::connect(io, format!("GRBL at {path}"), opts).await?;
        s.port = Some((path.to_string(), baud));
        Ok(s)
    }

    /// Connect over any transport (the handshake described in the module docs).
    pub async fn connect(
        io: Box<dyn Transport>,
        device: String,
        opts: GrblOptions,
    ) -> Result<GrblStage, DriverError> {
        let mut s = GrblStage {
            link: Link::new(io, device),
            info: StageInfo {
                name: String::new(),
                axes: Vec::new(),
            },
            settings: Settings::default(),
            build: BuildInfo::default(),
            opts,
            port: None,
            last_wco: None,
            last_alarm: None,
            needs_reset: false,
            locked: false,
            commanded: None,
            motion_queued: false,
            homing: false,
            reported_axes: 3,
        };
        s.handshake().await?;
        Ok(s)
    }

    async fn handshake(&mut self) -> Result<(), DriverError> {
        let deadline = with_deadline(self.opts.connect_timeout);
        let device = self.link.device.clone();
        let after_ms = self.opts.connect_timeout.as_millis() as u64;
        let timeout = move |link: &Link, what: &str, expected: &str| DriverError::Timeout {
            device: device.clone(),
            what: format!(
                "{what} (is this a GRBL 1.1 controller at the right baud rate? it {})",
                link.heard_summary(expected)
            ),
            after_ms,
        };
        self.link.listen();
        // A device that greeted neither way gets one `$I` in the last fifth of the time:
        // a GRBL that answers it is taken, anything else is named in the error.
        let greet_by = Instant::now() + self.opts.connect_timeout * 4 / 5;
        let greeted = self.greet(greet_by.min(deadline)).await?;
        let (what, expected) = match greeted {
            true => ("$I", "a version report `[VER:...]`"),
            false => (
                "a greeting: no start-up banner and no status report, even after a soft \
                 reset (0x18), nor an answer to `$I`",
                "a start-up banner `Grbl 1.1...`, a status report `<...>` or a version \
                 report `[VER:...]`",
            ),
        };
        // $I until [VER:] + ok. A banner means the board (re)booted and may have dropped
        // the $I: ask again unless its answer follows the banner promptly. `error:7`
        // (EEPROM read fail) is never an answer to $I: it is a first power-up's boot
        // talking, whose banner is still to come.
        self.link.write(&Command::BuildInfo.encode()).await?;
        let mut build = BuildInfo {
            rx_buffer: DEFAULT_RX_BUFFER,
            planner_blocks: PLANNER_BLOCKS,
            ..Default::default()
        };
        let mut have_version = false;
        let mut resend_at: Option<Instant> = None;
        loop {
            let wait_until = resend_at.map_or(deadline, |t| t.min(deadline));
            let Some(r) = self.link.next(wait_until).await? else {
                if resend_at.is_some_and(|t| Instant::now() >= t) && Instant::now() < deadline {
                    resend_at = None;
                    self.link.write(&Command::BuildInfo.encode()).await?;
                    continue;
                }
                return Err(timeout(&self.link, what, expected));
            };
            match r {
                Response::Version { version, .. } => {
                    build.version = version;
                    have_version = true;
                    resend_at = None;
                }
                Response::Options {
                    flags,
                    planner_blocks,
                    rx_buffer,
                } => {
                    build.options = flags;
                    build.planner_blocks = planner_blocks as usize;
                    build.rx_buffer = rx_buffer as usize;
                }
                Response::Ok if have_version => break,
                Response::Ok => {}
                Response::Error(7) if !have_version => {
                    // A boot in progress: its banner will come; ask again then (or
                    // after a while, should the banner be lost).
                    resend_at = Some(deadline);
                }
                Response::Error(code) => return Err(self.refused("$I", code)),
                Response::Banner { .. } => {
                    self.on_banner();
                    have_version = false;
                    resend_at = Some(Instant::now() + Duration::from_millis(300));
                }
                Response::Message(m) => self.note_message(&m),
                Response::Alarm(n) => self.note_alarm(n),
                _ => {}
            }
        }
        self.build = build;
        // Settings.
        self.link.write(&Command::ViewSettings.encode()).await?;
        let mut settings = Settings::default();
        loop {
            let Some(r) = self.link.next(deadline).await? else {
                return Err(timeout(&self.link, "$$", "a setting line `$N=value`"));
            };
            match r {
                Response::Setting { number, value } => {
                    if let Ok(v) = value.parse::<f64>() {
                        settings.insert(number, v);
                    }
                }
                // An `ok` before any setting line answers something older.
                Response::Ok if settings.is_empty() => {}
                Response::Ok => break,
                Response::Error(code) => return Err(self.refused("$$", code)),
                Response::Message(m) => self.note_message(&m),
                _ => {}
            }
        }
        for n in [100, 101, 110, 111, 130, 131] {
            if settings.get(n).is_none() {
                return Err(DriverError::Protocol {
                    device: self.link.device.clone(),
                    message: format!("$$ did not list ${n}"),
                });
            }
        }
        self.settings = settings;
        // First status: state, WCO, and how many axes it reports.
        let s = self.status_report().await?;
        self.reported_axes = s.position.len().clamp(3, 6);
        self.info = self.stage_info();
        if s.state == MachineState::Alarm && self.last_alarm.is_none() {
            self.locked = true;
        }
        Ok(())
    }

    /// Wait for the controller to greet: `Ok(true)` once its start-up banner or a status
    /// report has arrived, `Ok(false)` if neither came by `deadline`. Sends only `?`
    /// (every [`GREETING_POLL`]) and, after [`greeting_window`] without a greeting, one
    /// soft reset. Everything else a boot prints is passed over (messages and alarms
    /// are noted).
    async fn greet(&mut self, deadline: Instant) -> Result<bool, DriverError> {
        let started = Instant::now();
        let reset_at = (started + greeting_window(self.opts.connect_timeout)).min(deadline);
        let mut reset_sent = false;
        let mut poll_at = started;
        loop {
            let now = Instant::now();
            if now >= deadline {
                return Ok(false);
            }
            if !reset_sent && now >= reset_at {
                self.link.write(&[Realtime::SoftReset.byte()]).await?;
                reset_sent = true;
            } else if !reset_sent && now >= poll_at {
                self.link.write(&[Realtime::StatusQuery.byte()]).await?;
                poll_at = now + GREETING_POLL;
            }
            let wait_until = match reset_sent {
                true => deadline,
                false => poll_at.min(reset_at),
            };
            let Some(r) = self.link.next(wait_until).await? else {
                continue;
            };
            match r {
                Response::Banner { .. } => {
                    self.on_banner();
                    return Ok(true);
                }
                // A running controller answered `?`. After the reset only its banner
                // counts (a report then may answer an earlier `?`).
                Response::Status(s) if !reset_sent => {
                    if let Some(w) = &s.wco {
                        self.last_wco = Some(w.clone());
                    }
                    return Ok(true);
                }
                Response::Message(m) => self.note_message(&m),
                Response::Alarm(n) => self.note_alarm(n),
                // A boot's `error:7`, its settings dump, blank lines, noise.
                _ => {}
            }
        }
    }

    fn stage_info(&self) -> StageInfo {
        let force_origin = self.build.options.contains('Z');
        let homing = self.settings.homing_enabled();
        let axes = Axis::ALL
            .into_iter()
            .take(self.axis_count())
            .enumerate()
            .filter_map(|(k, axis)| {
                // Without homing, machine zero is wherever the controller powered up:
                // every reachable position lies within one travel of it either way.
                let (min_mm, max_mm) = match homing {
                    true => self.settings.travel_range(k, force_origin)?,
                    false => {
                        let t = self.settings.max_travel_mm(k)?;
                        (-t, t)
                    }
                };
                Some(AxisInfo {
                    axis,
                    min_mm,
                    max_mm,
                    resolution_mm: 1.0 / self.settings.steps_per_mm(k)?,
                    max_feed_mm_min: self.settings.max_rate_mm_min(k)?,
                })
            })
            .collect();
        StageInfo {
            name: format!("GRBL {} ({})", self.build.version, self.link.device),
            axes,
        }
    }

    /// Axes of the controller: as many as `$$` lists ($103.. for A) or the status
    /// reports carry, whichever is more (X Y Z, then A B C).
    pub fn axis_count(&self) -> usize {
        self.settings.axes().max(self.reported_axes).min(6)
    }

    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// Change a setting (`$n=value`, written to the controller's EEPROM) and keep what
    /// the driver derives from the settings (travel limits, resolution, rates) in step.
    pub async fn set_setting(&mut self, number: u16, value: f64) -> Result<(), DriverError> {
        if !value.is_finite() {
            return Err(DriverError::Unsupported {
                device: self.device(),
                message: format!("${number}={value}: not a number GRBL can store"),
            });
        }
        self.command(&Command::WriteSetting(number, value)).await?;
        self.settings.insert(number, value);
        self.info = self.stage_info();
        Ok(())
    }

    pub fn build_info(&self) -> &BuildInfo {
        &self.build
    }

    pub fn options(&self) -> &GrblOptions {
        &self.opts
    }

    fn device(&self) -> String {
        self.link.device.clone()
    }

    fn refused(&self, what: &str, code: u8) -> DriverError {
        DriverError::Refused {
            device: self.device(),
            what: what.to_string(),
            code: code.into(),
            message: error_text(code).to_string(),
        }
    }

    fn alarm_error(&self, code: u8) -> DriverError {
        let mut message = alarm_text(code).to_string();
        if self.needs_reset {
            message.push_str("; GRBL needs a soft reset");
        }
        DriverError::Alarm {
            device: self.device(),
            code: code.into(),
            message,
        }
    }

    /// Hard and soft limit alarms are critical in GRBL: it then answers nothing (not
    /// even `?`) until a soft reset.
    fn note_alarm(&mut self, code: u8) {
        self.last_alarm = Some(code);
        if code == 1 || code == 2 {
            self.needs_reset = true;
        }
    }

    fn note_message(&mut self, m: &str) {
        match m {
            "Reset to continue" => self.needs_reset = true,
            "'$H'|'$X' to unlock" => self.locked = true,
            "Caution: Unlocked" => self.locked = false,
            _ => {}
        }
    }

    /// A banner arrived: GRBL reset (by us, by a button, or by the port's DTR line).
    fn on_banner(&mut self) {
        self.needs_reset = false;
        self.homing = false;
        self.commanded = None;
        self.motion_queued = false;
        self.last_wco = None;
    }

    /// Handle a response that is not the one being waited for. Returns an error for an
    /// alarm (motion stopped).
    fn unsolicited(&mut self, r: &Response) -> Result<(), DriverError> {
        match r {
            Response::Alarm(n) => {
                self.note_alarm(*n);
                Err(self.alarm_error(*n))
            }
            Response::Message(m) => {
                self.note_message(m);
                Ok(())
            }
            Response::Banner { .. } => {
                self.on_banner();
                Ok(())
            }
            Response::Status(s) => {
                if let Some(w) = &s.wco {
                    self.last_wco = Some(w.clone());
                }
                Ok(())
            }
            _ => Ok(()),
        }
    }

    /// Send one line and wait for its `ok`/`error` (send-response). Returns the
    /// informational lines that came before the `ok`.
    pub async fn command(&mut self, cmd: &Command) -> Result<Vec<Response>, DriverError> {
        self.command_with(cmd, self.opts.command_timeout).await
    }

    async fn command_with(
        &mut self,
        cmd: &Command,
        timeout: Duration,
    ) -> Result<Vec<Response>, DriverError> {
        if self.needs_reset {
            return Err(self.alarm_error(self.last_alarm.unwrap_or(0)));
        }
        let what = cmd.text();
        self.link.listen();
        self.link.write(&cmd.encode()).await?;
        let deadline = with_deadline(timeout);
        let mut info = Vec::new();
        loop {
            let Some(r) = self.link.next(deadline).await? else {
                // What came instead (a garbled `ok`, noise) is named: a reply lost and
                // a reply corrupted read differently to whoever fixes the link.
                return Err(DriverError::Timeout {
                    device: self.device(),
                    what: format!("`{what}` (it {})", self.link.heard_summary("`ok`")),
                    after_ms: timeout.as_millis() as u64,
                });
            };
            match r {
                Response::Ok => return Ok(info),
                Response::Error(code) => return Err(self.refused(&format!("`{what}`"), code)),
                Response::Banner { .. } => {
                    self.on_banner();
                    return Err(DriverError::Protocol {
                        device: self.device(),
                        message: format!(
                            "GRBL reset while `{what}` was pending; it was not executed"
                        ),
                    });
                }
                Response::Alarm(_) => {
                    self.unsolicited(&r)?;
                }
                Response::Message(ref m) => {
                    self.note_message(m);
                    info.push(r);
                }
                Response::Status(_) => {
                    self.unsolicited(&r)?;
                }
                other => info.push(other),
            }
        }
    }

    /// One status report (`?`).
    pub async fn status_report(&mut self) -> Result<StatusReport, DriverError> {
        if self.needs_reset {
            // GRBL answers nothing in a critical alarm but a reset.
            return Err(self.alarm_error(self.last_alarm.unwrap_or(0)));
        }
        self.link.listen();
        self.link.write(&[Realtime::StatusQuery.byte()]).await?;
        let deadline = with_deadline(self.opts.command_timeout);
        loop {
            let Some(r) = self.link.next(deadline).await? else {
                return Err(DriverError::Timeout {
                    device: self.device(),
                    what: format!(
                        "status request `?` (it {})",
                        self.link.heard_summary("a status report `<...>`")
                    ),
                    after_ms: self.opts.command_timeout.as_millis() as u64,
                });
            };
            match r {
                Response::Status(s) => {
                    if let Some(w) = &s.wco {
                        self.last_wco = Some(w.clone());
                    }
                    return Ok(s);
                }
                other => self.unsolicited(&other)?,
            }
        }
    }

    /// Machine position from a report; with WPos reports, polls until a `WCO:` has
    /// been seen (GRBL sends it at least every 30 reports).
    async fn machine_position(&mut self, mut s: StatusReport) -> Result<Vec<f64>, DriverError> {
        for _ in 0..40 {
            if let Some(p) = s.machine_position(self.last_wco.as_deref()) {
                return Ok(p);
            }
            s = self.status_report().await?;
        }
        Err(DriverError::Protocol {
            device: self.device(),
            message: "WPos reported but no WCO in 40 status reports".into(),
        })
    }

    /// Write a real-time byte.
    pub async fn realtime(&mut self, r: Realtime) -> Result<(), DriverError> {
        self.link.write(&[r.byte()]).await
    }

    /// Feed hold (`!`): decelerate and keep position; [`resume`](Self::resume) continues.
    pub async fn feed_hold(&mut self) -> Result<(), DriverError> {
        self.realtime(Realtime::FeedHold).await
    }

    /// Cycle start (`~`). GRBL resumes only a hold that is complete (`Hold:0`): a cycle
    /// start while the feed hold still decelerates (`Hold:1`) is ignored (GRBL 1.1's
    /// `protocol_exec_rt_system`), so the driver first waits for the hold to complete,
    /// within the command timeout.
    pub async fn resume(&mut self) -> Result<(), DriverError> {
        self.poll_until(
            |s| *s != MachineState::Hold(1),
            self.opts.command_timeout,
            "a feed hold to complete before the cycle start (still Hold:1)",
        )
        .await?;
        self.realtime(Realtime::CycleStart).await
    }

    /// Asks `?` every `poll_interval` until the state satisfies `done`, up to `timeout`
    /// (GRBL reports only when asked: there is no event to wait for).
    async fn poll_until(
        &mut self,
        done: impl Fn(&MachineState) -> bool,
        timeout: Duration,
        what: &str,
    ) -> Result<(), DriverError> {
        let deadline = with_deadline(timeout);
        while !done(&self.status_report().await?.state) {
            if Instant::now() >= deadline {
                return Err(DriverError::Timeout {
                    device: self.device(),
                    what: what.into(),
                    after_ms: timeout.as_millis() as u64,
                });
            }
            tokio::time::sleep(self.opts.poll_interval).await;
        }
        Ok(())
    }

    /// Soft reset (ctrl-x): flushes GRBL's buffers; returns once the banner is back.
    /// Motion interrupted by it raises `ALARM:3` on the device (position unsure).
    pub async fn soft_reset(&mut self) -> Result<(), DriverError> {
        self.link.write(&[Realtime::SoftReset.byte()]).await?;
        let deadline = with_deadline(self.opts.command_timeout);
        loop {
            let Some(r) = self.link.next(deadline).await? else {
                return Err(DriverError::Timeout {
                    device: self.device(),
                    what: "soft reset (no banner)".into(),
                    after_ms: self.opts.command_timeout.as_millis() as u64,
                });
            };
            match r {
                Response::Banner { .. } => {
                    self.on_banner();
                    return Ok(());
                }
                Response::Alarm(n) => self.last_alarm = Some(n),
                Response::Message(m) => self.note_message(&m),
                _ => {}
            }
        }
    }

    /// Kill the alarm lock (`$X`).
    pub async fn unlock(&mut self) -> Result<(), DriverError> {
        if self.needs_reset {
            self.soft_reset().await?;
        }
        self.command(&Command::Unlock).await?;
        self.locked = false;
        self.last_alarm = None;
        Ok(())
    }

    /// Jog (`$J=`): relative or absolute (machine coordinates), cancelled by
    /// [`jog_cancel`](Self::jog_cancel). Targets are checked against the soft limits.
    pub async fn jog(
        &mut self,
        target: AxisValues,
        feed_mm_min: f64,
        relative: bool,
    ) -> Result<(), DriverError> {
        let mut absolute = AxisValues::default();
        let here = if relative {
            Some(self.position().await?)
        } else {
            None
        };
        for (a, v) in target.iter() {
            let base = here.as_ref().and_then(|h| h.get(a)).unwrap_or(0.0);
            absolute.set(a, if relative { base + v } else { v });
        }
        self.info.check_limits(&absolute)?;
        let mut w = BlockWriter::new()
            .g(21.0)
            .g(if relative { 91.0 } else { 53.0 });
        for (a, v) in target.iter() {
            w = w.word(a.letter(), v, self.opts.decimals);
        }
        w = w.word('F', feed_mm_min, 0);
        self.commanded = None;
        self.motion_queued = false;
        self.command(&Command::Jog(w.to_string())).await.map(|_| ())
    }

    /// Cancel a jog (0x85) and wait until GRBL is idle again.
    pub async fn jog_cancel(&mut self) -> Result<(), DriverError> {
        self.realtime(Realtime::JogCancel).await?;
        self.wait_idle().await
    }

    /// Soft limits of the stage (from `$130..$132` and the homing direction).
    pub fn limits(&self) -> &StageInfo {
        &self.info
    }

    /// Reopen the serial port after it disappeared and connect again, retrying until
    /// `connect_timeout`. Nothing that was in flight is resent.
    #[cfg(feature = "serial")]
    pub async fn reconnect(&mut self) -> Result<(), DriverError> {
        let Some((path, baud)) = self.port.clone() else {
            return Err(DriverError::Unsupported {
                device: self.device(),
                message: "not opened from a port path; cannot reconnect".into(),
            });
        };
        let deadline = with_deadline(self.opts.connect_timeout);
        loop {
            let last = match open_port(&path, baud) {
                Ok(io) => {
                    self.link = Link::new(io, self.link.device.clone());
                    self.needs_reset = false;
                    self.commanded = None;
                    self.motion_queued = false;
                    self.last_wco = None;
                    return self.handshake().await;
                }
                Err(e) => e.to_string(),
            };
            if Instant::now() >= deadline {
                return Err(DriverError::Timeout {
                    device: self.device(),
                    what: format!("reconnect ({last})"),
                    after_ms: self.opts.connect_timeout.as_millis() as u64,
                });
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }
}

#[cfg(feature = "serial")]
fn open_port(path: &str, baud: u32) -> Result<Box<dyn Transport>, DriverError> {
    use tokio_serial::SerialPort;
    use tokio_serial::SerialPortBuilderExt;
    let err = |e: tokio_serial::Error| DriverError::Transport {
        device: format!("GRBL at {path}"),
        message: format!("cannot open serial port {path} at {baud} baud: {e}"),
    };
    let port = tokio_serial::new(path, baud)
        .open_native_async()
        .map_err(err)?;
    // Whatever was received before we opened (an old banner, answers to a previous
    // client) is not ours: discard it so the handshake reads only its own answers.
    port.clear(tokio_serial::ClearBuffer::Input).map_err(err)?;
    Ok(Box::new(port))
}

#[async_trait]
impl Stage for GrblStage {
    fn info(&self) -> &StageInfo {
        &self.info
    }

    /// GRBL 1.1 runs streamed programs (character counting, see [`GrblStage::stream_program`])
    /// with G38.2-G38.5 probing; it has no compensation table. It drives X, Y and Z;
    /// grblHAL builds add A, B, C (rotary).
    fn capabilities(&self) -> Capabilities {
        Capabilities {
            program_streaming: true,
            table_upload: false,
            probing: true,
            rotary_axes: Capabilities::rotary_among(self.info.axes.iter().map(|a| a.axis)),
            tape_only: false,
        }
    }

    /// Character counting: [`GrblStage::stream_program`].
    async fn stream_program(
        &mut self,
        program: &str,
        opts: &StreamOptions,
        progress: &mut (dyn FnMut(protocol::grbl::stream::StreamProgress) + Send),
    ) -> Result<StreamReport, StreamError> {
        GrblStage::stream_program(self, program, opts, progress).await
    }

    /// `G38.2`..`G38.5` in work coordinates (GRBL allows G53 only with G0/G1): the
    /// machine target less the last reported work offset. GRBL answers `[PRB:...]`
    /// then `ok`; a miss with G38.2/G38.4 is `ALARM:5`, a probe already in the state
    /// looked for `ALARM:4`, both errors here.
    async fn probe(
        &mut self,
        target: AxisValues,
        feed: f64,
        mode: ProbeMode,
    ) -> Result<ProbeHit, DriverError> {
        self.info.check_limits(&target)?;
        crate::stage::check_feed(&self.device(), feed)?;
        if target.is_empty() {
            return Err(DriverError::Unsupported {
                device: self.device(),
                message: "a probing move needs at least one axis target".into(),
            });
        }
        let code = match (mode.toward, mode.must_trigger) {
            (true, true) => 38.2,
            (true, false) => 38.3,
            (false, true) => 38.4,
            (false, false) => 38.5,
        };
        let wco = self.last_wco.clone().unwrap_or_default();
        let mut w = BlockWriter::new().g(21.0).g(90.0).g(code);
        for (a, v) in target.iter() {
            let offset = wco.get(a.index()).copied().unwrap_or(0.0);
            w = w.word(a.letter(), v - offset, self.opts.decimals);
        }
        w = w.word('F', feed, 0);
        let info = self
            .command_with(&Command::Gcode(w.to_string()), self.opts.motion_timeout)
            .await?;
        self.commanded = None;
        self.motion_queued = false;
        let report = info
            .iter()
            .find_map(|r| match r {
                Response::Parameter { name, value } if name == "PRB" => {
                    Some(protocol::grbl::probe::ProbeReport::parse_value(value))
                }
                _ => None,
            })
            .ok_or_else(|| DriverError::Protocol {
                device: self.device(),
                message: format!("`{w}` answered without a [PRB:...] report"),
            })?
            .map_err(|e| DriverError::Protocol {
                device: self.device(),
                message: e.to_string(),
            })?;
        let mut position = AxisValues::default();
        for (a, x) in Axis::ALL.into_iter().zip(&report.position) {
            position.set(a, *x);
        }
        Ok(ProbeHit {
            position,
            touched: report.touched,
        })
    }

    /// `$H` (needs `$22=1`; GRBL answers `error:5` otherwise). Clears a critical
    /// alarm with a soft reset first.
    async fn home(&mut self) -> Result<(), DriverError> {
        if self.needs_reset {
            self.soft_reset().await?;
        }
        self.homing = true;
        let homed = self
            .command_with(&Command::Home, self.opts.motion_timeout)
            .await;
        self.homing = false;
        homed?;
        self.locked = false;
        self.last_alarm = None;
        self.commanded = None;
        self.motion_queued = false;
        Ok(())
    }

    async fn move_to(&mut self, target: AxisValues, feed_mm_min: f64) -> Result<(), DriverError> {
        self.info.check_limits(&target)?;
        crate::stage::check_feed(&self.device(), feed_mm_min)?;
        if target.is_empty() {
            return Ok(());
        }
        let mut w = BlockWriter::new().g(21.0).g(53.0).g(1.0);
        for (a, v) in target.iter() {
            w = w.word(a.letter(), v, self.opts.decimals);
        }
        w = w.word('F', feed_mm_min, 0);
        self.command(&Command::Gcode(w.to_string())).await?;
        self.motion_queued = true;
        let mut c = self.commanded.unwrap_or([f64::NAN; 3]);
        for (a, v) in target.iter() {
            if a.index() < 3 {
                c[a.index()] = v;
            }
        }
        self.commanded = Some(c);
        Ok(())
    }

    /// Relative move from the last commanded target when every axis of it is known
    /// (exact), else from the reported position (1 um resolution).
    async fn move_by(&mut self, delta: AxisValues, feed_mm_min: f64) -> Result<(), DriverError> {
        let known = self.commanded.filter(|c| {
            delta
                .iter()
                .all(|(a, _)| a.index() < 3 && c[a.index()].is_finite())
        });
        let here = match known {
            Some(c) => AxisValues::default()
                .with(Axis::X, c[0])
                .with(Axis::Y, c[1])
                .with(Axis::Z, c[2]),
            None => self.position().await?,
        };
        let mut target = AxisValues::default();
        for (a, d) in delta.iter() {
            let p = here.get(a).ok_or_else(|| DriverError::Unsupported {
                device: self.device(),
                message: format!("no position for axis {a}"),
            })?;
            target.set(a, p + d);
        }
        self.move_to(target, feed_mm_min).await
    }

    async fn position(&mut self) -> Result<AxisValues, DriverError> {
        let s = self.status_report().await?;
        let p = self.machine_position(s).await?;
        let mut v = AxisValues::default();
        for (k, a) in Axis::ALL.into_iter().enumerate() {
            if let Some(x) = p.get(k) {
                v.set(a, *x);
            }
        }
        Ok(v)
    }

    /// Poll `?` until Idle with an empty planner; an alarm is an error.
    async fn wait_idle(&mut self) -> Result<(), DriverError> {
        if std::mem::take(&mut self.motion_queued) {
            // A motion line's `ok` means queued, not started: real GRBL 1.1h may still
            // report Idle before its planner starts the block, and without `Bf:` in the
            // reports ($10) that Idle looks final. A dwell is answered only once every
            // queued motion has ended (GRBL synchronizes the planner for G4).
            self.command_with(&Command::Gcode("G4P0".into()), self.opts.motion_timeout)
                .await?;
        }
        let deadline = with_deadline(self.opts.motion_timeout);
        loop {
            let s = self.status_report().await?;
            match s.state {
                MachineState::Idle | MachineState::Check => {
                    let empty = s
                        .buffer
                        .is_none_or(|(blocks, _)| blocks as usize >= self.build.planner_blocks);
                    if empty {
                        return Ok(());
                    }
                }
                MachineState::Alarm => {
                    let code = self.last_alarm.unwrap_or(0);
                    return Err(if code == 0 {
                        DriverError::InvalidState {
                            device: self.device(),
                            message: "GRBL is in its alarm lock: home or unlock ($X) first".into(),
                        }
                    } else {
                        self.alarm_error(code)
                    });
                }
                MachineState::Sleep => {
                    return Err(DriverError::InvalidState {
                        device: self.device(),
                        message: "GRBL is asleep: soft reset first".into(),
                    });
                }
                _ => {}
            }
            if Instant::now() >= deadline {
                return Err(DriverError::Timeout {
                    device: self.device(),
                    what: format!("end of motion (state {})", s.state.name()),
                    after_ms: self.opts.motion_timeout.as_millis() as u64,
                });
            }
            tokio::time::sleep(self.opts.poll_interval).await;
        }
    }

    /// Stop now: a jog is cancelled; a running program is held (decelerating, position
    /// kept) and then GRBL is reset to flush what was queued.
    async fn stop(&mut self) -> Result<(), DriverError> {
        // A homing cycle answers no `?` and ignores a feed hold: only a reset ends it
        // (GRBL answers `ALARM:6`, homing reset, and stays locked until homed again).
        if self.needs_reset || self.homing {
            return self.soft_reset().await;
        }
        let s = self.status_report().await?;
        match s.state {
            MachineState::Jog => self.jog_cancel().await,
            MachineState::Home => self.soft_reset().await,
            MachineState::Run | MachineState::Hold(_) => {
                self.feed_hold().await?;
                self.poll_until(
                    |s| matches!(s, MachineState::Hold(0) | MachineState::Idle),
                    self.opts.motion_timeout,
                    "feed hold to complete",
                )
                .await?;
                self.soft_reset().await
            }
            _ => Ok(()),
        }
    }

    async fn status(&mut self) -> Result<StageStatus, DriverError> {
        if self.needs_reset {
            let code = self.last_alarm.unwrap_or(0);
            return Ok(StageStatus {
                state: StageState::Alarm(format!(
                    "ALARM:{code}: {}; reset to continue",
                    alarm_text(code)
                )),
                position: AxisValues::default(),
            });
        }
        let s = self.status_report().await?;
        let state = match s.state {
            MachineState::Idle | MachineState::Check => StageState::Idle,
            MachineState::Run | MachineState::Jog => StageState::Moving,
            MachineState::Home => StageState::Homing,
            MachineState::Hold(_) | MachineState::Door(_) => StageState::Hold,
            MachineState::Alarm => match self.last_alarm {
                Some(code) => StageState::Alarm(format!("ALARM:{code}: {}", alarm_text(code))),
                None => StageState::NotHomed,
            },
            MachineState::Sleep => StageState::Alarm("Sleep".into()),
        };
        let p = self.machine_position(s).await?;
        let mut position = AxisValues::default();
        for (k, a) in Axis::ALL.into_iter().enumerate() {
            if let Some(x) = p.get(k) {
                position.set(a, *x);
            }
        }
        Ok(StageStatus { state, position })
    }
}

//! A LinuxCNC machine as a [`Stage`], through `linuxcncrsh`, LinuxCNC's text remote
//! shell (TCP, port 5007 by default; the machine's INI has `[DISPLAY] DISPLAY =
//! linuxcncrsh`, or the shell runs beside the operator's GUI).
//!
//! * Connect: `hello <connect password> <client> 1.0` must give `HELLO ACK` (`HELLO
//!   NAK`: the password is wrong); `set echo off`, `set verbose on` (from then on every
//!   command gets exactly one reply line); `set enable <enable password>` (`NAK`: the
//!   password is wrong); `set set_wait done` (an MDI command is answered only when its
//!   motion has ended); then the machine out of estop and on (`set estop off`,
//!   `set machine on`), each confirmed by a `get`.
//! * An `ACK` means accepted, not done and not valid: LinuxCNC reports what went wrong
//!   later, through its error channel. After every command `get error` is polled until
//!   `ERROR OK`, and what it said becomes [`DriverError::InvalidState`] quoting LinuxCNC
//!   (for example `Linear move on line 0 would exceed X's positive limit`).
//! * Home: `set mode manual`, `set teleop_enable off` if on (a homed LinuxCNC runs in
//!   world mode and homes only in joint mode), `set home -1` (all joints, in the INI's
//!   `HOME_SEQUENCE`), then `get joint_homed` polled until the driven joints say `YES`
//!   (a re-homing clears them as it starts).
//! * Move: `set mode mdi`, then one block `G21 G90 G53 G1 X.. Y.. F..`: millimetres,
//!   absolute, in machine coordinates whatever the work offsets (G53), at the feed
//!   asked. `G21` and `G90` stay in effect afterwards (they are modal in LinuxCNC too).
//! * Position: `get abs_act_pos` (machine coordinates, 6 decimals, X Y Z A B C).
//! * Stop: `set abort`. While a move is being waited for, the shell answers nothing on
//!   this connection (it waits for the end of motion), so the abort goes through a
//!   second session (`hello`, `set enable`, `set abort`), which takes control away from
//!   this one; this session enables itself again before its next command.
//! * Control: linuxcncrsh gives control to the last session that sent `set enable`. A
//!   command refused because another session has taken control is reported as such
//!   (the driver asks `get enable`), never retried behind the operator's back.
//! * Every exchange has a deadline (`command_timeout`; homing and moves
//!   `motion_timeout`); a reply still owed after a deadline (or a dropped wait) is read
//!   and discarded before the next command, so replies never slip out of step.

pub mod reply;

pub use link_spec::linuxcnc::{LinuxcncAxis, LinuxcncOptions};

use crate::error::DriverError;
use crate::stage::{
    check_feed, Axis, AxisInfo, AxisValues, Capabilities, Stage, StageInfo, StageState, StageStatus,
};
use async_trait::async_trait;
use protocol::text::escape_bytes;
use reply::{numbers, Line, LineSplitter, Reply};
use std::collections::VecDeque;
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::time::Instant;

/// The most `get error` messages read after one command (LinuxCNC queues a few; a
/// stream that never ends is a fault of its own).
const MAX_ERRORS_DRAINED: usize = 16;

/// How close `get abs_cmd_pos` (6 decimals) must be to a move's target for the move to
/// have arrived: LinuxCNC's trajectory ends exactly on the target it parsed.
const ARRIVAL_TOLERANCE_MM: f64 = 2e-6;

/// How long a commanded position short of a move's target may stay unchanged before the
/// move counts as stopped there (LinuxCNC's servo thread runs every millisecond; a
/// loaded computer delays it by tens of milliseconds, not seconds).
const STILL_SHORT: Duration = Duration::from_secs(2);

/// The TCP session with the shell: lines in, commands out.
struct Session {
    stream: TcpStream,
    splitter: LineSplitter,
    lines: VecDeque<Line>,
    device: String,
    /// Replies the shell still owes for commands whose wait was given up (a deadline,
    /// a dropped future): read and discarded before the next command.
    owed: usize,
}

impl Session {
    async fn connect(address: &str, device: &str, timeout: Duration) -> Result<Self, DriverError> {
        let stream = match tokio::time::timeout(timeout, TcpStream::connect(address)).await {
            Err(_) => {
                return Err(DriverError::Timeout {
                    device: device.to_string(),
                    what: format!("a TCP connection to {address} (is the host up?)"),
                    after_ms: timeout.as_millis() as u64,
                })
            }
            Ok(Err(e)) if e.kind() == std::io::ErrorKind::ConnectionRefused => {
                return Err(DriverError::Transport {
                    device: device.to_string(),
                    message: format!(
                        "nothing listens at {address} (connection refused): is LinuxCNC running with linuxcncrsh (`[DISPLAY] DISPLAY = linuxcncrsh`, or `linuxcncrsh` started beside the GUI) on that port?"
                    ),
                })
            }
            Ok(Err(e)) => {
                return Err(DriverError::Transport {
                    device: device.to_string(),
                    message: format!("cannot connect to {address}: {e}"),
                })
            }
            Ok(Ok(s)) => s,
        };
        let _ = stream.set_nodelay(true);
        Ok(Self {
            stream,
            splitter: LineSplitter::new(),
            lines: VecDeque::new(),
            device: device.to_string(),
            owed: 0,
        })
    }

    fn transport(&self, message: String) -> DriverError {
        DriverError::Transport {
            device: self.device.clone(),
            message,
        }
    }

    async fn send(&mut self, command: &str) -> Result<(), DriverError> {
        let bytes = format!("{command}\r\n");
        self.stream
            .write_all(bytes.as_bytes())
            .await
            .map_err(|e| self.transport(format!("write failed: {e}")))
    }

    /// The next line, or `None` at the deadline.
    async fn line(&mut self, deadline: Instant) -> Result<Option<Line>, DriverError> {
        loop {
            if let Some(l) = self.lines.pop_front() {
                return Ok(Some(l));
            }
            let mut buf = [0u8; 2048];
            let n =
                match tokio::time::timeout_at(deadline, self.stream.read(&mut buf)).await {
                    Err(_) => return Ok(None),
                    Ok(Err(e)) => return Err(self.transport(format!("read failed: {e}"))),
                    Ok(Ok(0)) => return Err(self.transport(
                        "LinuxCNC closed the connection (linuxcncrsh ended, or LinuxCNC shut down)"
                            .into(),
                    )),
                    Ok(Ok(n)) => n,
                };
            let mut out = Vec::new();
            self.splitter.feed(&buf[..n], &mut out);
            self.lines.extend(out);
        }
    }

    fn timeout(&self, what: &str, after: Duration) -> DriverError {
        DriverError::Timeout {
            device: self.device.clone(),
            what: format!("`{what}`"),
            after_ms: after.as_millis() as u64,
        }
    }

    /// Send one command and read its one reply line (echo off, verbose on). Replies
    /// owed from before are read first, within the same deadline.
    async fn exchange(&mut self, command: &str, timeout: Duration) -> Result<Line, DriverError> {
        let deadline = Instant::now() + timeout;
        while self.owed > 0 {
            match self.line(deadline).await? {
                Some(_) => self.owed -= 1,
                None => return Err(self.timeout(command, timeout)),
            }
        }
        self.send(command).await?;
        self.owed += 1;
        match self.line(deadline).await? {
            Some(l) => {
                self.owed -= 1;
                Ok(l)
            }
            None => Err(self.timeout(command, timeout)),
        }
    }
}

/// A LinuxCNC machine driven through `linuxcncrsh`.
pub struct LinuxcncStage {
    session: Session,
    address: String,
    info: StageInfo,
    opts: LinuxcncOptions,
    axes: Vec<LinuxcncAxis>,
    /// This session holds control (`set enable`); false after a stop went through a
    /// second session.
    enabled: bool,
    /// The server's name and protocol version from `HELLO ACK`.
    server: String,
}

fn quoted(text: &str) -> String {
    escape_bytes(text.as_bytes())
}

impl LinuxcncStage {
    /// Connect to `address` (`host:port`) and make the machine ready to move (see the
    /// module docs). `axes` are the axes the gateway drives with the job's limits.
    pub async fn open(
        address: &str,
        options: LinuxcncOptions,
        axes: Vec<LinuxcncAxis>,
    ) -> Result<LinuxcncStage, DriverError> {
        let device = format!("LinuxCNC at {address}");
        check_options(&device, &options, &axes)?;
        let session = Self::handshake(address, &device, &options).await?;
        let info = StageInfo {
            name: device,
            axes: axes
                .iter()
                .map(|a| AxisInfo {
                    axis: a.axis,
                    min_mm: a.min_mm,
                    max_mm: a.max_mm,
                    resolution_mm: 10f64.powi(-(options.decimals as i32)),
                    max_feed_mm_min: a.max_feed_mm_min,
                })
                .collect(),
        };
        let mut stage = LinuxcncStage {
            session: session.0,
            address: address.to_string(),
            info,
            opts: options,
            axes,
            enabled: true,
            server: session.1,
        };
        stage.info.name = format!("{} ({})", stage.info.name, stage.server);
        stage.set("set set_wait done").await?;
        stage.drain_errors("connect").await?;
        if stage.get_word("get estop", "ESTOP").await? != "OFF" {
            stage.set("set estop off").await?;
            stage.confirm("get estop", "ESTOP", "OFF").await?;
        }
        if stage.get_word("get machine", "MACHINE").await? != "ON" {
            stage.set("set machine on").await?;
            stage.confirm("get machine", "MACHINE", "ON").await?;
        }
        Ok(stage)
    }

    /// `hello`, echo off, verbose on, `set enable`: the session and the server's name.
    async fn handshake(
        address: &str,
        device: &str,
        opts: &LinuxcncOptions,
    ) -> Result<(Session, String), DriverError> {
        let mut s = Session::connect(address, device, opts.connect_timeout).await?;
        let deadline = Instant::now() + opts.connect_timeout;
        let timed_out = |what: &str| DriverError::Timeout {
            device: device.to_string(),
            what: format!("`{what}` (is this linuxcncrsh?)"),
            after_ms: opts.connect_timeout.as_millis() as u64,
        };
        s.send(&format!(
            "hello {} {} 1.0",
            opts.connect_password, opts.client_name
        ))
        .await?;
        let mut other = Vec::new();
        let server = loop {
            let Some(l) = s.line(deadline).await? else {
                return Err(timed_out("hello"));
            };
            match Reply::parse(&l.text) {
                Reply::HelloAck { server } => break server,
                Reply::HelloNak => {
                    return Err(DriverError::Refused {
                        device: device.to_string(),
                        what: "the connection".into(),
                        code: 0,
                        message: "HELLO NAK: the connect password is wrong (the job's `connect_password` must be linuxcncrsh's --connectpw, default EMC)".into(),
                    })
                }
                _ if other.len() < 4 => other.push(quoted(&l.text)),
                _ => {
                    return Err(DriverError::Protocol {
                        device: device.to_string(),
                        message: format!(
                            "no HELLO ACK/NAK to `hello`; it said: {}",
                            other.join(" | ")
                        ),
                    })
                }
            }
        };
        // The shell echoes every line while echo is on (the default), and answers a
        // `set` only in verbose mode: skip whatever comes until verbose is confirmed.
        s.send("set echo off").await?;
        s.send("set verbose on").await?;
        loop {
            let Some(l) = s.line(deadline).await? else {
                return Err(timed_out("set verbose on"));
            };
            if let Reply::SetAck { command } = Reply::parse(&l.text) {
                if command == "VERBOSE" {
                    break;
                }
            }
        }
        let l = s
            .exchange(
                &format!("set enable {}", opts.enable_password),
                opts.command_timeout,
            )
            .await?;
        match Reply::parse(&l.text) {
            Reply::SetAck { command } if command == "ENABLE" => {}
            Reply::SetNak { .. } => {
                return Err(DriverError::Refused {
                    device: device.to_string(),
                    what: "control (`set enable`)".into(),
                    code: 0,
                    message: "SET ENABLE NAK: the enable password is wrong (the job's `enable_password` must be linuxcncrsh's --enablepw, default EMCTOO)".into(),
                })
            }
            _ => {
                return Err(DriverError::Protocol {
                    device: device.to_string(),
                    message: format!("`set enable` answered {}", quoted(&l.text)),
                })
            }
        }
        Ok((s, server))
    }

    /// The server's name and protocol version (`HELLO ACK`).
    pub fn server(&self) -> &str {
        &self.server
    }

    fn device(&self) -> String {
        self.info.name.clone()
    }

    fn protocol(&self, message: String) -> DriverError {
        DriverError::Protocol {
            device: self.device(),
            message,
        }
    }

    /// Take control again if a stop went through another session.
    async fn ensure_enabled(&mut self) -> Result<(), DriverError> {
        if self.enabled {
            return Ok(());
        }
        let cmd = format!("set enable {}", self.opts.enable_password);
        let l = self
            .session
            .exchange(&cmd, self.opts.command_timeout)
            .await?;
        match Reply::parse(&l.text) {
            Reply::SetAck { .. } => {
                self.enabled = true;
                Ok(())
            }
            _ => Err(DriverError::Refused {
                device: self.device(),
                what: "control (`set enable`)".into(),
                code: 0,
                message: format!("answered {}", quoted(&l.text)),
            }),
        }
    }

    /// A `set` command answered `ACK`, then LinuxCNC's error channel drained (an ACK
    /// is no proof of success).
    async fn set(&mut self, command: &str) -> Result<(), DriverError> {
        self.set_within(command, self.opts.command_timeout).await
    }

    /// A `set` refused with no reason at all (nothing on LinuxCNC's error channel, this
    /// session in control, the machine on) is asked again every poll interval until the
    /// command timeout: LinuxCNC's task refuses `set run` and `set mdi` so for a moment
    /// after a program has ended while its status already reads idle (seen with other
    /// work on the machine's cores). A refused command did nothing, so asking again
    /// moves nothing twice; any other refusal is returned at once.
    async fn set_within(&mut self, command: &str, timeout: Duration) -> Result<(), DriverError> {
        let settle_until = Instant::now() + self.opts.command_timeout;
        loop {
            self.ensure_enabled().await?;
            let l = self.session.exchange(command, timeout).await?;
            match Reply::parse(&l.text) {
                Reply::SetAck { .. } => return self.drain_errors(command).await,
                Reply::SetNak { .. } => {
                    let (refused, reasonless) = self.refusal(command).await;
                    if !reasonless || Instant::now() >= settle_until {
                        return Err(refused);
                    }
                    tokio::time::sleep(self.opts.poll_interval).await;
                }
                _ => return Err(self.protocol(format!("`{command}` answered {}", quoted(&l.text)))),
            }
        }
    }

    /// Why a `set` was refused: what LinuxCNC's error channel says, whether this
    /// session still has control, whether the machine is on; and whether it gave no
    /// reason at all (none of these).
    async fn refusal(&mut self, command: &str) -> (DriverError, bool) {
        let errors = match self.read_errors().await {
            Ok(e) => e,
            Err(e) => return (e, false),
        };
        if !errors.is_empty() {
            return (self.linuxcnc_said(command, &errors), false);
        }
        match self.get_word("get enable", "ENABLE").await {
            Ok(w) if w == "OFF" => {
                self.enabled = false;
                return (DriverError::InvalidState {
                    device: self.device(),
                    message: format!(
                        "`{command}` refused: another linuxcncrsh session has taken control of this LinuxCNC (`set enable`); the gateway does not take it back by itself: end the other session and start the job again"
                    ),
                }, false);
            }
            Err(e) => return (e, false),
            _ => {}
        }
        let (why, reasonless) = match self.get_word("get machine", "MACHINE").await {
            Ok(w) if w != "ON" => (
                "the machine is not on (estop or machine off, from the operator or a fault)",
                false,
            ),
            Err(e) => return (e, false),
            _ => ("LinuxCNC gave no reason (a bad argument, or a state that does not allow it: a program running, a mode change refused)", true),
        };
        let refused = DriverError::InvalidState {
            device: self.device(),
            message: format!("`{command}` refused (SET NAK): {why}"),
        };
        (refused, reasonless)
    }

    fn linuxcnc_said(&self, command: &str, errors: &[String]) -> DriverError {
        DriverError::InvalidState {
            device: self.device(),
            message: format!("LinuxCNC reports after `{command}`: {}", errors.join("; ")),
        }
    }

    /// Read `get error` until `ERROR OK`: the messages LinuxCNC queued.
    async fn read_errors(&mut self) -> Result<Vec<String>, DriverError> {
        let mut errors = Vec::new();
        for _ in 0..MAX_ERRORS_DRAINED {
            let l = self
                .session
                .exchange("get error", self.opts.command_timeout)
                .await?;
            match Reply::parse(&l.text) {
                Reply::Value { key, words } if key == "ERROR" => {
                    if words.len() == 1 && words[0].eq_ignore_ascii_case("OK") {
                        return Ok(errors);
                    }
                    errors.push(quoted(&words.join(" ")));
                }
                _ => return Err(self.protocol(format!("`get error` answered {}", quoted(&l.text)))),
            }
        }
        errors.push(format!("(more than {MAX_ERRORS_DRAINED} messages)"));
        Ok(errors)
    }

    async fn drain_errors(&mut self, after: &str) -> Result<(), DriverError> {
        let errors = self.read_errors().await?;
        if errors.is_empty() {
            Ok(())
        } else {
            Err(self.linuxcnc_said(after, &errors))
        }
    }

    /// A `get` answered `<KEY> words...`.
    async fn get(&mut self, command: &str, key: &str) -> Result<Vec<String>, DriverError> {
        let l = self
            .session
            .exchange(command, self.opts.command_timeout)
            .await?;
        match Reply::parse(&l.text) {
            Reply::Value { key: k, words } if k == key => Ok(words),
            _ => Err(self.protocol(format!("`{command}` answered {}", quoted(&l.text)))),
        }
    }

    /// The first word of a `get`, upper-cased.
    async fn get_word(&mut self, command: &str, key: &str) -> Result<String, DriverError> {
        let words = self.get(command, key).await?;
        words
            .first()
            .map(|w| w.to_ascii_uppercase())
            .ok_or_else(|| self.protocol(format!("`{command}` answered `{key}` alone")))
    }

    /// A state change is confirmed by a `get` (an ACK means accepted, not done): polled
    /// until it shows `want` or the command timeout passes.
    async fn confirm(&mut self, command: &str, key: &str, want: &str) -> Result<(), DriverError> {
        let deadline = Instant::now() + self.opts.command_timeout;
        loop {
            let got = self.get_word(command, key).await?;
            if got == want {
                return Ok(());
            }
            self.drain_errors(command).await?;
            if Instant::now() >= deadline {
                return Err(DriverError::InvalidState {
                    device: self.device(),
                    message: format!(
                        "`{command}` still says {key} {got} (wanted {want}) after {} ms",
                        self.opts.command_timeout.as_millis()
                    ),
                });
            }
            tokio::time::sleep(self.opts.poll_interval).await;
        }
    }

    async fn mode(&mut self, mode: &str) -> Result<(), DriverError> {
        let upper = mode.to_ascii_uppercase();
        if self.get_word("get mode", "MODE").await? == upper {
            return Ok(());
        }
        self.set(&format!("set mode {mode}")).await?;
        self.confirm("get mode", "MODE", &upper).await
    }

    /// Whether every driven joint is homed (`JOINT_HOMED YES YES NO ...`).
    async fn homed(&mut self) -> Result<bool, DriverError> {
        let words = self.get("get joint_homed", "JOINT_HOMED").await?;
        let mut all = true;
        for a in &self.axes {
            match words.get(a.joint as usize).map(|w| w.to_ascii_uppercase()) {
                Some(w) if w == "YES" => {}
                Some(w) if w == "NO" => all = false,
                _ => {
                    return Err(self.protocol(format!(
                        "`get joint_homed` has no YES/NO for joint {}: {}",
                        a.joint,
                        quoted(&words.join(" "))
                    )))
                }
            }
        }
        Ok(all)
    }

    /// The block that moves to `target` in machine coordinates.
    fn move_block(&self, target: &AxisValues, feed_mm_min: f64) -> String {
        let d = self.opts.decimals;
        let mut block = String::from("G21 G90 G53 G1");
        for (a, v) in target.iter() {
            block.push_str(&format!(" {}{:.*}", a.letter(), d, v));
        }
        block.push_str(&format!(" F{:.*}", 3, feed_mm_min));
        block
    }

    /// A position reply (`get abs_act_pos`, `get abs_cmd_pos`: X Y Z A B C, machine
    /// coordinates): its words as they came and their numbers, at least X, Y and Z.
    async fn positions(
        &mut self,
        command: &str,
        key: &str,
    ) -> Result<(Vec<String>, Vec<f64>), DriverError> {
        let words = self.get(command, key).await?;
        let v = numbers(&words).filter(|v| v.len() >= 3).ok_or_else(|| {
            self.protocol(format!("`{command}` answered {}", quoted(&words.join(" "))))
        })?;
        Ok((words, v))
    }

    /// After a move's `ACK`: poll `get abs_cmd_pos` (the trajectory's commanded position,
    /// machine coordinates) until every axis of the move is at its target as sent
    /// (within [`ARRIVAL_TOLERANCE_MM`]), up to `motion_timeout`. LinuxCNC's `set_wait
    /// done` usually answers at the end of the motion; on a loaded computer (its servo
    /// thread late) its task has answered while the motion still ran, and a frame taken
    /// then saw the stage short of the target. A move that ends elsewhere (an abort from
    /// elsewhere, a fault: the commanded position still for [`STILL_SHORT`]) is an error
    /// quoting where it stopped, never a silent arrival.
    async fn confirm_arrival(&mut self, target: &AxisValues) -> Result<(), DriverError> {
        let d = self.opts.decimals;
        // the target as LinuxCNC parsed it: the block's digits
        let sent: Vec<(Axis, f64)> = target
            .iter()
            .map(|(a, v)| (a, format!("{v:.d$}").parse::<f64>().unwrap_or(v)))
            .collect();
        let deadline = Instant::now() + self.opts.motion_timeout;
        let mut last: Option<(Vec<f64>, Instant)> = None;
        loop {
            let (words, v) = self.positions("get abs_cmd_pos", "ABS_CMD_POS").await?;
            let arrived = sent.iter().all(|&(a, t)| {
                v.get(a.index())
                    .is_some_and(|c| (c - t).abs() <= ARRIVAL_TOLERANCE_MM)
            });
            if arrived {
                return Ok(());
            }
            self.drain_errors("get abs_cmd_pos").await?;
            // Still short of the target for STILL_SHORT: the motion stopped there.
            let now = Instant::now();
            let since = match &last {
                Some((p, at)) if *p == v => *at,
                _ => now,
            };
            if now >= deadline || now - since >= STILL_SHORT {
                let target = sent
                    .iter()
                    .map(|(a, t)| format!("{}{t}", a.letter()))
                    .collect::<Vec<_>>()
                    .join(" ");
                return Err(DriverError::InvalidState {
                    device: self.device(),
                    message: format!(
                        "the move was answered as done, but LinuxCNC's commanded position (ABS_CMD_POS {}) stopped short of the target {target}",
                        words.join(" "),
                    ),
                });
            }
            last = Some((v, since));
            tokio::time::sleep(self.opts.poll_interval).await;
        }
    }

    /// Run a program file that is on the LinuxCNC machine (`set mode auto`,
    /// `set open FILE`, `set run`), waiting for its end (`set_wait done`) up to
    /// `motion_timeout`.
    pub async fn run_program(&mut self, path: &str) -> Result<(), DriverError> {
        if path.contains(['\r', '\n']) {
            return Err(DriverError::Unsupported {
                device: self.device(),
                message: "a program path cannot hold a line break".into(),
            });
        }
        self.mode("auto").await?;
        self.set(&format!("set open {path}")).await?;
        self.set_within("set run", self.opts.motion_timeout).await?;
        self.wait_idle().await
    }
}

/// Refuse options and axes that cannot work before anything is sent.
fn check_options(
    device: &str,
    opts: &LinuxcncOptions,
    axes: &[LinuxcncAxis],
) -> Result<(), DriverError> {
    let bad = |message: String| DriverError::Unsupported {
        device: device.to_string(),
        message,
    };
    let word = |what: &str, w: &str, max: usize| {
        if w.is_empty() || w.len() > max || !w.bytes().all(|b| b.is_ascii_graphic()) {
            Err(bad(format!(
                "{what} must be 1 to {max} printable ASCII characters without blanks (linuxcncrsh reads it as one word)"
            )))
        } else {
            Ok(())
        }
    };
    // linuxcncrsh compares passwords in 16-byte buffers and keeps 79 bytes of a name.
    word("the connect password", &opts.connect_password, 15)?;
    word("the enable password", &opts.enable_password, 15)?;
    word("the client name", &opts.client_name, 79)?;
    if opts.enable_password.eq_ignore_ascii_case("off") {
        return Err(bad(
            "the enable password cannot be `off` (linuxcncrsh reads it as giving up control)"
                .into(),
        ));
    }
    if axes.is_empty() {
        return Err(bad("no axes to drive".into()));
    }
    for (i, a) in axes.iter().enumerate() {
        crate::stage::check_axis_config(
            device,
            &format!("axis {}", a.axis),
            a.min_mm,
            a.max_mm,
            Some(a.max_feed_mm_min),
        )?;
        if a.joint > 8 {
            return Err(bad(format!(
                "axis {}: joint {} (LinuxCNC has joints 0 to 8)",
                a.axis, a.joint
            )));
        }
        if axes[..i]
            .iter()
            .any(|b| b.axis == a.axis || b.joint == a.joint)
        {
            return Err(bad(format!(
                "axis {} or joint {} is given twice",
                a.axis, a.joint
            )));
        }
    }
    Ok(())
}

#[async_trait]
impl Stage for LinuxcncStage {
    fn info(&self) -> &StageInfo {
        &self.info
    }

    fn capabilities(&self) -> Capabilities {
        Capabilities {
            // Programs run from files on the machine (`run_program`), not streamed.
            program_streaming: false,
            // COMP_FILE tables exist, but are loaded only when LinuxCNC starts.
            table_upload: false,
            probing: false,
            rotary_axes: Capabilities::rotary_among(self.axes.iter().map(|a| a.axis)),
            tape_only: false,
        }
    }

    async fn home(&mut self) -> Result<(), DriverError> {
        self.mode("manual").await?;
        // Once homed, LinuxCNC runs in world (teleop) mode, and homes only in joint
        // mode ("must be in joint mode to home").
        if self.get_word("get teleop_enable", "TELEOP_ENABLE").await? == "YES" {
            self.set("set teleop_enable off").await?;
            self.confirm("get teleop_enable", "TELEOP_ENABLE", "NO")
                .await?;
        }
        self.set("set home -1").await?;
        let deadline = Instant::now() + self.opts.motion_timeout;
        loop {
            if self.homed().await? {
                break;
            }
            self.drain_errors("set home -1").await?;
            if Instant::now() >= deadline {
                return Err(self
                    .session
                    .timeout("set home -1 (all joints homed)", self.opts.motion_timeout));
            }
            tokio::time::sleep(self.opts.poll_interval).await;
        }
        self.mode("mdi").await
    }

    async fn move_to(&mut self, target: AxisValues, feed_mm_min: f64) -> Result<(), DriverError> {
        self.info.check_limits(&target)?;
        check_feed(&self.info.name, feed_mm_min)?;
        if target.is_empty() {
            return Ok(());
        }
        self.mode("mdi").await?;
        let block = self.move_block(&target, feed_mm_min);
        // set_wait done: the ACK comes when the motion has ended, as a rule.
        self.set_within(&format!("set mdi {block}"), self.opts.motion_timeout)
            .await?;
        self.confirm_arrival(&target).await
    }

    async fn position(&mut self) -> Result<AxisValues, DriverError> {
        let (_, v) = self.positions("get abs_act_pos", "ABS_ACT_POS").await?;
        let mut p = AxisValues::default();
        for a in &self.axes {
            let i = a.axis.index();
            let value = *v
                .get(i)
                .ok_or_else(|| self.protocol(format!("`get abs_act_pos` has no {}", a.axis)))?;
            p.set(a.axis, value);
        }
        Ok(p)
    }

    async fn wait_idle(&mut self) -> Result<(), DriverError> {
        let deadline = Instant::now() + self.opts.motion_timeout;
        loop {
            let status = self
                .get_word("get program_status", "PROGRAM_STATUS")
                .await?;
            self.drain_errors("get program_status").await?;
            if status == "IDLE" {
                return Ok(());
            }
            if Instant::now() >= deadline {
                return Err(self
                    .session
                    .timeout("get program_status (IDLE)", self.opts.motion_timeout));
            }
            tokio::time::sleep(self.opts.poll_interval).await;
        }
    }

    async fn stop(&mut self) -> Result<(), DriverError> {
        if self.session.owed == 0 {
            self.set("set abort").await?;
            return self.wait_idle().await;
        }
        // This session is waiting for a motion to end: abort through a second one.
        let mut other = Self::handshake(&self.address, &self.info.name, &self.opts)
            .await?
            .0;
        let l = other
            .exchange("set abort", self.opts.command_timeout)
            .await?;
        if !matches!(Reply::parse(&l.text), Reply::SetAck { .. }) {
            return Err(self.protocol(format!(
                "`set abort` (second session) answered {}",
                quoted(&l.text)
            )));
        }
        // Give control up again (the closed socket's number must not keep it).
        let _ = other
            .exchange("set enable off", self.opts.command_timeout)
            .await;
        drop(other);
        self.enabled = false;
        // The move's reply comes now that its motion ended; then the errors the abort
        // left (if any) are read and dropped: a stop is not a failure.
        let _ = self.read_errors().await?;
        self.ensure_enabled().await?;
        self.wait_idle().await
    }

    async fn status(&mut self) -> Result<StageStatus, DriverError> {
        let position = self.position().await?;
        let state = if self.get_word("get estop", "ESTOP").await? == "ON" {
            StageState::Alarm("emergency stop (ESTOP ON)".into())
        } else if self.get_word("get machine", "MACHINE").await? != "ON" {
            StageState::Alarm("machine off (MACHINE OFF)".into())
        } else if !self.homed().await? {
            StageState::NotHomed
        } else {
            match self
                .get_word("get program_status", "PROGRAM_STATUS")
                .await?
                .as_str()
            {
                "IDLE" => StageState::Idle,
                "PAUSED" => StageState::Hold,
                _ => StageState::Moving,
            }
        };
        Ok(StageStatus { state, position })
    }
}

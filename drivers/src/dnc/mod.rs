//! A closed controller through its tape port: DNC drip-feed with DC1/DC3 flow control
//! (Fanuc remote buffer protocol B, Haas setting 14 = XON/XOFF, and the like; see
//! docs/dnc.md).
//!
//! * [`DncSender`] sends a tape (any `%`-delimited ISO text: a program, or a
//!   compensation table file) honouring the control's flow control: it waits for DC1
//!   before the first character (the operator's cycle start), writes at most
//!   [`DncOptions::chunk`] characters at a time and looks for DC3 before each write
//!   (`bytes_to_read`, so no read races the write), pauses on DC3 until DC1, and stops
//!   with an error naming the block on NAK (alarm) or SYN (reset). Progress is reported
//!   per block, and the caller's callback can stop the tape at a block boundary. On a
//!   real port it also waits for the kernel's output queue to drain before each write,
//!   so no more than one chunk is on its way when DC3 comes (a UART FIFO adds to that:
//!   set it to 1, as DNC vendors advise), and it never runs more than [`PACE_AHEAD`]
//!   ahead of the baud rate (a pseudo-terminal has no line to hold it back). Every
//!   wait has a deadline.
//! * [`DncStage`] is the [`Stage`] of such a machine: it has no position read-back, no
//!   status and no end of motion (capability `tape_only`), so `position`, `status` and
//!   `wait_idle` refuse saying so; `home` tells the operator to do the reference return
//!   on the panel; `move_to` sends a one-block tape; `stream_program` sends a program.

pub use link_spec::dnc::{DncAxis, DncOptions, EndOfBlock};

use crate::error::DriverError;
use crate::program::{StreamError, StreamOptions, StreamReport};
use crate::stage::{check_feed, AxisInfo, AxisValues, Capabilities, Stage, StageInfo, StageStatus};
use async_trait::async_trait;
use protocol::grbl::stream::StreamProgress;
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::time::Instant;
use tokio_serial::{SerialPort, SerialPortBuilderExt, SerialStream};

pub const DC1: u8 = 0x11;
pub const DC3: u8 = 0x13;
pub const NAK: u8 = 0x15;
pub const SYN: u8 = 0x16;

/// How far the sender may run ahead of the line's baud rate (see `DncSender::pace`).
pub const PACE_AHEAD: Duration = Duration::from_millis(2);

/// A tape checked and framed for the line: 7-bit characters, one block per line, the
/// first and last non-blank lines `%`.
#[derive(Clone, Debug, PartialEq)]
pub struct Tape {
    /// The blocks (lines without their end) in order, `%` lines included.
    pub lines: Vec<String>,
}

impl Tape {
    /// Checks `text` (a program or a table file): every character 7-bit ASCII, no
    /// control character but TAB inside a line, `%` alone on the first and last
    /// non-blank lines. Errors name the line.
    pub fn new(text: &str) -> Result<Tape, String> {
        let mut lines: Vec<String> = Vec::new();
        for (i, raw) in text.split('\n').enumerate() {
            let line = raw.trim_end_matches('\r');
            if let Some(c) = line
                .chars()
                .find(|c| !c.is_ascii() || (c.is_ascii_control() && *c != '\t'))
            {
                return Err(format!(
                    "line {}: character {c:?} cannot go on an ISO tape",
                    i + 1
                ));
            }
            lines.push(line.to_string());
        }
        while lines.last().is_some_and(|l| l.trim().is_empty()) {
            lines.pop();
        }
        let first = lines.iter().position(|l| !l.trim().is_empty());
        match first {
            Some(f) if lines[f].trim() == "%" && lines.len() > f + 1 => {
                lines.drain(..f);
            }
            _ => return Err("a tape starts with a line `%`".into()),
        }
        if lines.last().map(|l| l.trim()) != Some("%") {
            return Err(format!(
                "line {}: a tape ends with a line `%`",
                lines.len() + first.unwrap_or(0)
            ));
        }
        Ok(Tape { lines })
    }
}

/// Where a tape is.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct TapeProgress {
    /// Lines of the tape (`%` lines included).
    pub total: usize,
    /// Lines written whole.
    pub sent: usize,
    /// Characters written.
    pub bytes: u64,
    /// DC3s honoured (pauses).
    pub pauses: u64,
}

/// What the caller's progress callback says after each block.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Flow {
    Continue,
    /// Stop sending after this block (the control keeps what it has; the operator
    /// presses reset to end it).
    Stop,
}

/// Why a tape did not go through whole: the cause and the last line written.
#[derive(Debug, thiserror::Error)]
#[error("{cause} (after line {sent} of {total} was sent)", sent = progress.sent, total = progress.total)]
pub struct TapeError {
    pub cause: DriverError,
    pub progress: TapeProgress,
}

/// A tape port as ISO code runs on it: 7 data bits, even parity, 2 stop bits, no
/// hardware flow control (DC1/DC3 only).
fn open_iso_port(port: &str, baud: u32, device: &str) -> Result<SerialStream, DriverError> {
    tokio_serial::new(port, baud)
        .data_bits(tokio_serial::DataBits::Seven)
        .parity(tokio_serial::Parity::Even)
        .stop_bits(tokio_serial::StopBits::Two)
        .flow_control(tokio_serial::FlowControl::None)
        .open_native_async()
        .map_err(|e| DriverError::Transport {
            device: device.into(),
            message: format!("opening {port} at {baud} baud: {e}"),
        })
}

/// The gateway as a controller to a DNC sender (the operator's DNC software) on a port
/// of its own (ISO code framing, as [`DncSender::open`]).
pub struct DncReceiver {
    port: SerialStream,
    device: String,
}

/// The longest line a sender may send, characters (a block, its comments, CR).
pub const MAX_LIVE_LINE: usize = 4096;

impl DncReceiver {
    pub async fn open(port: &str, baud: u32) -> Result<Self, DriverError> {
        let device = format!("DNC sender port {port}");
        let port = open_iso_port(port, baud, &device)?;
        Ok(Self { port, device })
    }

    pub fn from_stream(port: SerialStream, device: String) -> Self {
        Self { port, device }
    }

    async fn code(&mut self, codes: &[u8]) -> Result<(), DriverError> {
        let device = self.device.clone();
        self.port
            .write_all(codes)
            .await
            .map_err(|e| DriverError::Transport {
                device,
                message: e.to_string(),
            })
    }

    /// Reads the sender's tape line by line, each line handed to `on_line`, whose lines
    /// go on to `tape` (a controller's drip-feed, [`DncSender::send_live`]), until the
    /// closing `%`. Flow control as a controller applies it: DC1 first; DC3 when fewer
    /// than `low` lines of room are left in `tape`, DC1 when `high` are free again (what
    /// the sender wrote meanwhile waits on its line). A line `on_line` refuses ends the
    /// reading as a controller's alarm does: DC3 NAK to the sender (its DNC software
    /// reports the controller's alarm), the error names the line; nothing of it reaches
    /// `tape`. Returns the lines read.
    pub async fn receive(
        &mut self,
        tape: &tokio::sync::mpsc::Sender<String>,
        low: usize,
        high: usize,
        on_line: &mut dyn FnMut(&str) -> Result<Vec<String>, String>,
    ) -> Result<usize, DriverError> {
        let gone = |device: &str| DriverError::InvalidState {
            device: device.into(),
            message: "the controller's side stopped taking the tape".into(),
        };
        self.code(&[DC1]).await?;
        let (mut line, mut lines, mut percents) = (Vec::new(), 0usize, 0usize);
        let mut buf = [0u8; 256];
        loop {
            if tape.capacity() < low {
                self.code(&[DC3]).await?;
                // Wait for room, taking nothing meanwhile; then the sender may go on.
                let room = tape
                    .reserve_many(high.min(tape.max_capacity()))
                    .await
                    .map_err(|_| gone(&self.device))?;
                drop(room);
                self.code(&[DC1]).await?;
            }
            let n = self
                .port
                .read(&mut buf)
                .await
                .map_err(|e| DriverError::Transport {
                    device: self.device.clone(),
                    message: e.to_string(),
                })?;
            if n == 0 {
                // A port opened raw (VMIN 0) reads nothing when nothing waits; a line that
                // is gone reads an error (EIO). Look again a moment later.
                tokio::time::sleep(Duration::from_millis(1)).await;
                continue;
            }
            for &b in &buf[..n] {
                match b {
                    // The leader, and flow-control codes a sender may echo.
                    0 | DC1 | DC3 => continue,
                    b'\n' => {}
                    _ => {
                        if line.len() >= MAX_LIVE_LINE {
                            self.code(&[DC3, NAK]).await?;
                            return Err(DriverError::InvalidState {
                                device: self.device.clone(),
                                message: format!(
                                    "line {}: longer than {MAX_LIVE_LINE} characters (the gateway sent DC3 NAK: the sender sees the controller's alarm)",
                                    lines + 1
                                ),
                            });
                        }
                        line.push(b);
                        continue;
                    }
                }
                lines += 1;
                let text = String::from_utf8_lossy(&line).into_owned();
                line.clear();
                let out = match on_line(&text) {
                    Ok(out) => out,
                    Err(message) => {
                        self.code(&[DC3, NAK]).await?;
                        return Err(DriverError::InvalidState {
                            device: self.device.clone(),
                            message: format!(
                                "{message} (the gateway sent DC3 NAK: the sender sees the controller's alarm; the controller has the blocks before it: press RESET on its panel)"
                            ),
                        });
                    }
                };
                for l in out {
                    tape.send(l).await.map_err(|_| gone(&self.device))?;
                }
                if text.trim_end_matches('\r') == "%" {
                    percents += 1;
                    if percents == 2 {
                        return Ok(lines);
                    }
                }
            }
        }
    }
}

/// Where a tape's lines come from: all at hand, or arriving one by one.
enum Lines<'a> {
    Tape(std::slice::Iter<'a, String>),
    Live(&'a mut tokio::sync::mpsc::Receiver<String>),
}

impl Lines<'_> {
    async fn next(&mut self) -> Option<String> {
        match self {
            Lines::Tape(lines) => lines.next().cloned(),
            Lines::Live(rx) => rx.recv().await,
        }
    }
}

/// The drip-feed sender on one serial port.
pub struct DncSender {
    port: SerialStream,
    device: String,
    options: DncOptions,
    /// The last flow-control code was DC1 (the control reads).
    reading: bool,
    /// One character's time on the line (11 bits at the baud rate).
    char_time: Duration,
    /// When the line will have carried everything written so far (the pacing).
    line_free_at: Instant,
}

impl DncSender {
    /// Open the port. ISO code on a PC port: 7 data bits, even parity, 2 stop bits
    /// (Fanuc's framing: 1 start, 7 data + parity, 2 stop; docs/dnc.md gives the other
    /// families'), no hardware flow control: DC1/DC3 only.
    pub async fn open(port: &str, baud: u32, options: DncOptions) -> Result<Self, DriverError> {
        let device = format!("tape port {port}");
        if options.chunk == 0 {
            return Err(DriverError::InvalidState {
                device,
                message: "chunk must be at least 1 character".into(),
            });
        }
        let stream = open_iso_port(port, baud, &device)?;
        Ok(Self::from_stream(stream, device, baud, options))
    }

    /// A sender on an open stream (tests: a pseudo-terminal).
    pub fn from_stream(port: SerialStream, device: String, baud: u32, options: DncOptions) -> Self {
        // 11 bits per character (start, 7 data, parity, 2 stop).
        let char_time = Duration::from_secs_f64(11.0 / f64::from(baud.max(1)));
        Self {
            port,
            device,
            reading: !options.wait_for_dc1,
            options,
            char_time,
            line_free_at: Instant::now(),
        }
    }

    fn transport(&self, e: std::io::Error) -> DriverError {
        DriverError::Transport {
            device: self.device.clone(),
            message: e.to_string(),
        }
    }

    /// Take one code from the control.
    fn take(&mut self, byte: u8) -> Result<(), DriverError> {
        match byte {
            DC1 => self.reading = true,
            DC3 => self.reading = false,
            NAK => {
                self.reading = false;
                return Err(DriverError::Alarm {
                    device: self.device.clone(),
                    code: u32::from(NAK),
                    message: "the controller raised an alarm (NAK) and stopped reading: read \
                              the alarm on its screen, press RESET, fix the cause, then \
                              select DNC mode and press CYCLE START before sending again"
                        .into(),
                });
            }
            SYN => {
                self.reading = false;
                return Err(DriverError::InvalidState {
                    device: self.device.clone(),
                    message: "the controller was reset (SYN) and stopped reading: select \
                              DNC mode and press CYCLE START, then send the tape again"
                        .into(),
                });
            }
            // Anything else (a parity-marked copy, line noise) is not flow control.
            _ => {}
        }
        Ok(())
    }

    /// Everything the control has sent so far, without waiting.
    fn drain_codes(&mut self) -> Result<(), DriverError> {
        self.drain(false)
    }

    /// [`Self::drain_codes`]; with `stale`, a NAK or SYN only means "not reading".
    fn drain(&mut self, stale: bool) -> Result<(), DriverError> {
        let mut buf = [0u8; 64];
        while self
            .port
            .bytes_to_read()
            .map_err(|e| self.transport(e.into()))?
            > 0
        {
            let n = match self.port.try_read(&mut buf) {
                Ok(n) => n,
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => break,
                Err(e) => return Err(self.transport(e)),
            };
            if n == 0 {
                return Err(self.transport(std::io::Error::other("the port closed")));
            }
            for b in &buf[..n] {
                if stale && matches!(*b, NAK | SYN) {
                    self.reading = false;
                } else {
                    self.take(*b)?;
                }
            }
        }
        Ok(())
    }

    /// Wait for DC1, at most until `deadline`; with `stale` (before a tape's first
    /// character), a NAK or SYN only means "not reading".
    async fn wait_dc1(
        &mut self,
        deadline: Instant,
        what: &str,
        stale: bool,
    ) -> Result<(), DriverError> {
        let mut buf = [0u8; 64];
        while !self.reading {
            let n = match tokio::time::timeout_at(deadline, self.port.read(&mut buf)).await {
                Err(_) => {
                    return Err(DriverError::Timeout {
                        device: self.device.clone(),
                        what: what.into(),
                        after_ms: 0,
                    })
                }
                Ok(Err(e)) => return Err(self.transport(e)),
                Ok(Ok(0)) => return Err(self.transport(std::io::Error::other("the port closed"))),
                Ok(Ok(n)) => n,
            };
            for b in &buf[..n] {
                if stale && matches!(*b, NAK | SYN) {
                    self.reading = false;
                } else {
                    self.take(*b)?;
                }
            }
        }
        Ok(())
    }

    /// On a real port: wait until the kernel has put every written character on the
    /// line (a pseudo-terminal reports 0 at once).
    async fn wait_sent(&mut self, deadline: Instant) -> Result<(), DriverError> {
        while self
            .port
            .bytes_to_write()
            .map_err(|e| self.transport(e.into()))?
            > 0
        {
            if Instant::now() >= deadline {
                return Err(DriverError::Timeout {
                    device: self.device.clone(),
                    what: "the port's output queue to drain (is the line connected?)".into(),
                    after_ms: 0,
                });
            }
            tokio::time::sleep(self.char_time).await;
        }
        Ok(())
    }

    /// Never more than [`PACE_AHEAD`] ahead of the line: a real port's output queue
    /// holds the sender back by itself (`wait_sent`); a pseudo-terminal takes
    /// everything at once, and a sender that ran ahead of the baud rate could not stop
    /// within the controller's room when DC3 comes.
    async fn pace(&mut self) {
        let ahead = self.line_free_at.saturating_duration_since(Instant::now());
        // Sleeps last a timer tick (about 1 ms) at least: run down to half the lead.
        if ahead > PACE_AHEAD {
            tokio::time::sleep(ahead - PACE_AHEAD / 2).await;
        }
    }

    /// Send `tape`; `progress` is told after each line and may stop the tape there.
    pub async fn send_tape(
        &mut self,
        tape: &Tape,
        progress: &mut (dyn FnMut(&TapeProgress) -> Flow + Send),
    ) -> Result<TapeProgress, TapeError> {
        let mut p = TapeProgress {
            total: tape.lines.len(),
            ..TapeProgress::default()
        };
        match self
            .send_lines(Lines::Tape(tape.lines.iter()), &mut p, progress)
            .await
        {
            Ok(()) => Ok(p),
            Err(cause) => Err(TapeError { cause, progress: p }),
        }
    }

    /// Send a tape whose lines arrive on `lines` (each without its end of block, `%`
    /// first and last: the source checks them; a live DNC sender's program rewritten
    /// through the gateway) until the channel closes; flow control as [`Self::send_tape`].
    /// `TapeProgress::total` counts the lines arrived so far.
    pub async fn send_live(
        &mut self,
        lines: &mut tokio::sync::mpsc::Receiver<String>,
        progress: &mut (dyn FnMut(&TapeProgress) -> Flow + Send),
    ) -> Result<TapeProgress, TapeError> {
        let mut p = TapeProgress::default();
        match self.send_lines(Lines::Live(lines), &mut p, progress).await {
            Ok(()) => Ok(p),
            Err(cause) => Err(TapeError { cause, progress: p }),
        }
    }

    async fn send_lines(
        &mut self,
        mut lines: Lines<'_>,
        p: &mut TapeProgress,
        progress: &mut (dyn FnMut(&TapeProgress) -> Flow + Send),
    ) -> Result<(), DriverError> {
        let start = self.options.start_timeout;
        // Codes from before this tape (an old alarm's NAK, a reset's SYN) are history:
        // the control's next DC1 says it reads again.
        self.drain(true)?;
        self.wait_dc1(
            Instant::now() + start,
            &format!(
                "DC1 within {} s: select DNC (remote) mode on the controller and press CYCLE START",
                start.as_secs()
            ),
            true,
        )
        .await?;
        let eob: &[u8] = match self.options.end_of_block {
            EndOfBlock::Lf => b"\n",
            EndOfBlock::CrLf => b"\r\n",
        };
        let leader = vec![0u8; self.options.leader_nuls];
        let mut pending: Vec<u8> = leader;
        let live = matches!(lines, Lines::Live(_));
        let mut i = 0;
        while let Some(line) = lines.next().await {
            if live {
                p.total = i + 1;
            }
            pending.extend_from_slice(line.as_bytes());
            pending.extend_from_slice(eob);
            let mut at = 0;
            while at < pending.len() {
                self.drain_codes()?;
                if !self.reading {
                    p.pauses += 1;
                    let resume = self.options.resume_timeout;
                    self.wait_dc1(
                        Instant::now() + resume,
                        &format!(
                            "DC1 within {} s after DC3 (the controller stopped reading: feed hold, a stop or a long dwell?)",
                            resume.as_secs()
                        ),
                        false,
                    )
                    .await?;
                }
                self.wait_sent(Instant::now() + self.options.resume_timeout)
                    .await?;
                self.pace().await;
                let end = (at + self.options.chunk).min(pending.len());
                self.port
                    .write_all(&pending[at..end])
                    .await
                    .map_err(|e| self.transport(e))?;
                p.bytes += (end - at) as u64;
                self.line_free_at =
                    self.line_free_at.max(Instant::now()) + self.char_time * (end - at) as u32;
                at = end;
            }
            pending.clear();
            p.sent = i + 1;
            if progress(p) == Flow::Stop && (live || i + 1 < p.total) {
                return Err(DriverError::InvalidState {
                    device: self.device.clone(),
                    message: format!(
                        "the tape was stopped after line {} of {}: the controller keeps what it \
                         read; press RESET on its panel to end the program",
                        i + 1,
                        p.total
                    ),
                });
            }
            i += 1;
        }
        self.port.flush().await.map_err(|e| self.transport(e))?;
        // A NAK for the last characters may already be here.
        self.drain_codes()
    }
}

/// A machine behind a tape port as a [`Stage`].
pub struct DncStage {
    sender: DncSender,
    info: StageInfo,
}

impl DncStage {
    pub async fn open(
        port: &str,
        baud: u32,
        options: DncOptions,
        axes: Vec<DncAxis>,
    ) -> Result<Self, DriverError> {
        let sender = DncSender::open(port, baud, options).await?;
        Ok(Self::new(sender, port, axes))
    }

    pub fn new(sender: DncSender, port: &str, axes: Vec<DncAxis>) -> Self {
        let info = StageInfo {
            name: format!("closed controller (DNC tape port {port})"),
            axes: axes
                .iter()
                .map(|a| AxisInfo {
                    axis: a.axis,
                    min_mm: a.min_mm,
                    max_mm: a.max_mm,
                    resolution_mm: 0.001,
                    max_feed_mm_min: a.max_feed_mm_min,
                })
                .collect(),
        };
        Self { sender, info }
    }

    /// The sender, to send tapes of any kind (a program, a compensation table file).
    pub fn sender(&mut self) -> &mut DncSender {
        &mut self.sender
    }

    fn no(&self, what: &str) -> DriverError {
        DriverError::Unsupported {
            device: self.info.name.clone(),
            message: format!(
                "{what}: a tape port sends nothing back but flow control, alarm and reset \
                 (capability `tape_only`); the camera is the only sensor"
            ),
        }
    }
}

#[async_trait]
impl Stage for DncStage {
    fn info(&self) -> &StageInfo {
        &self.info
    }

    /// Programs only (the tape), nothing back.
    fn capabilities(&self) -> Capabilities {
        Capabilities {
            program_streaming: true,
            tape_only: true,
            ..Capabilities::default()
        }
    }

    async fn home(&mut self) -> Result<(), DriverError> {
        Err(DriverError::InvalidState {
            device: self.info.name.clone(),
            message: "homing is the operator's on a closed controller: do the reference \
                      return on its panel (REF/ZRN mode, every axis), then select DNC mode \
                      and press CYCLE START"
                .into(),
        })
    }

    /// A one-block tape `G90 G01 X.. Y.. F..` in the control's active work system,
    /// decimal points always written. Returns once the tape is sent, not when the move
    /// has ended (nothing says so).
    async fn move_to(&mut self, target: AxisValues, feed_mm_min: f64) -> Result<(), DriverError> {
        self.info.check_limits(&target)?;
        check_feed(&self.info.name, feed_mm_min)?;
        let mut block = String::from("G90G01");
        for (a, v) in target.iter() {
            block.push_str(&format!("{a}{v:.3}"));
        }
        block.push_str(&format!("F{feed_mm_min:.1}"));
        let tape = Tape {
            lines: vec!["%".into(), block, "%".into()],
        };
        self.sender
            .send_tape(&tape, &mut |_| Flow::Continue)
            .await
            .map(|_| ())
            .map_err(|e| e.cause)
    }

    async fn position(&mut self) -> Result<AxisValues, DriverError> {
        Err(self.no("no position read-back"))
    }

    async fn wait_idle(&mut self) -> Result<(), DriverError> {
        Err(self.no("no end of motion can be read"))
    }

    async fn stop(&mut self) -> Result<(), DriverError> {
        Err(DriverError::InvalidState {
            device: self.info.name.clone(),
            message: "a tape port cannot stop the machine: press FEED HOLD or RESET on the \
                      controller's panel"
                .into(),
        })
    }

    async fn status(&mut self) -> Result<StageStatus, DriverError> {
        Err(self.no("no status"))
    }

    /// The program as a tape (`%` added at both ends when missing). `progress.sent`
    /// counts lines written; nothing is ever acknowledged or known executed.
    async fn stream_program(
        &mut self,
        program: &str,
        _opts: &StreamOptions,
        progress: &mut (dyn FnMut(StreamProgress) + Send),
    ) -> Result<StreamReport, StreamError> {
        let started = std::time::Instant::now();
        let framed;
        let text = if program.trim_start().starts_with('%') {
            program
        } else {
            framed = format!("%\n{}\n%\n", program.trim_end());
            &framed
        };
        let fail = |cause, sent| StreamError {
            cause,
            line: None,
            text: None,
            progress: StreamProgress {
                sent,
                ..StreamProgress::default()
            },
            acknowledged_after: Vec::new(),
        };
        let tape = Tape::new(text).map_err(|m| {
            fail(
                DriverError::Protocol {
                    device: self.info.name.clone(),
                    message: m,
                },
                0,
            )
        })?;
        let total = tape.lines.len();
        let sent = self
            .sender
            .send_tape(&tape, &mut |p| {
                progress(StreamProgress {
                    total,
                    sent: p.sent,
                    ..StreamProgress::default()
                });
                Flow::Continue
            })
            .await
            .map_err(|e| fail(e.cause, e.progress.sent))?;
        Ok(StreamReport {
            progress: StreamProgress {
                total,
                sent: sent.sent,
                ..StreamProgress::default()
            },
            max_in_flight_bytes: self.sender.options.chunk,
            rx_buffer: 0,
            min_free_blocks: None,
            elapsed: started.elapsed(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tapes_are_checked_and_framed() {
        let t = Tape::new("\n%\nO1000\r\nG01X1.F100.\nM30\n%\n\n").unwrap();
        assert_eq!(t.lines, vec!["%", "O1000", "G01X1.F100.", "M30", "%"]);
        assert!(Tape::new("G01X1.\n%").unwrap_err().contains("starts with"));
        assert!(Tape::new("%\nG01X1.\n").unwrap_err().contains("ends with"));
        assert!(Tape::new("%\nG01X1.\u{e9}\n%")
            .unwrap_err()
            .contains("line 2"));
    }
}

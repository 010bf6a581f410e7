//! One Modbus link (a TCP connection or an RTU serial line) shared by the drives on
//! it, with what tokio-modbus leaves to its user:
//!
//! * every request has a deadline (the async client has none: a request without reply
//!   would hang forever);
//! * after a timeout or a garbled reply the connection is rebuilt before anything else
//!   is sent: TCP gets a new socket (a late reply to the old request then arrives on a
//!   closed socket, never as the answer to a new one); RTU, which has no transaction
//!   ids, reopens the port and discards whatever arrives until the line has been quiet
//!   for `rtu_quiet` (so replies up to `timeout + rtu_quiet` late are thrown away; set
//!   `timeout` above the drives' worst response time);
//! * RTU frames are spaced by the line's silent interval (3.5 characters; 1.75 ms
//!   above 19200 baud), which real drives need to find frame boundaries;
//! * failures are classified: an exception is the device's answer (never retried);
//!   no reply, a bad CRC, a mismatched reply or a broken link are retried up to
//!   `retries` times on the rebuilt connection, then reported with what was seen.
//!
//! Retrying is safe for reads and for writes that set a state (command bits, stop);
//! a move trigger is not, and [`super::ModbusAxis`] never retries one blindly.

use crate::error::DriverError;
pub use link_spec::modbus::{Endpoint, ModbusOptions, Parity};
use protocol::modbus::frame::{rtu_crc_ok, rtu_response_len, Exception, FrameLen};
use protocol::text::hex_bytes;
use std::fmt;
use std::io;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context as TaskContext, Poll};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, ReadBuf};
use tokio::time::Instant;
use tokio_modbus::client::{Client, Context};
use tokio_modbus::prelude::{Request, Response, SlaveContext};
use tokio_modbus::Slave;

/// One request.
#[derive(Clone, Debug)]
pub enum Op<'a> {
    ReadHolding(u16, u16),
    ReadInput(u16, u16),
    WriteSingle(u16, u16),
    WriteMultiple(u16, &'a [u16]),
}

/// Why an attempt gave no usable answer.
#[derive(Clone, Debug, PartialEq)]
pub enum Failure {
    /// The device answered with an exception.
    Exception(Exception),
    /// Nothing (complete) came back in time.
    NoReply,
    /// Bytes came back that were not a valid reply (bad CRC, wrong transaction,
    /// wrong unit or function): said in words.
    Garbled(String),
    /// The link failed.
    Link(String),
}

impl Failure {
    fn describe(&self) -> String {
        match self {
            Failure::Exception(e) => e.to_string(),
            Failure::NoReply => "no reply".into(),
            Failure::Garbled(s) => s.clone(),
            Failure::Link(s) => s.clone(),
        }
    }
}

/// Counters of a bus.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct BusStats {
    pub requests: u64,
    pub exceptions: u64,
    pub timeouts: u64,
    pub garbled: u64,
    pub link_errors: u64,
    pub retries: u64,
    /// Connections rebuilt after a failure.
    pub reconnects: u64,
}

/// A link shared by the axes on it.
pub type SharedBus = Arc<tokio::sync::Mutex<ModbusBus>>;

pub struct ModbusBus {
    endpoint: Endpoint,
    opts: ModbusOptions,
    ctx: Option<Context>,
    /// Bytes received since the last request was sent (for "what came back").
    rx: Arc<Mutex<Vec<u8>>>,
    /// RTU: when the line last carried a frame (for the silent interval).
    last_frame: Option<Instant>,
    /// RTU: a failure happened; discard stale input before the next request.
    drain: bool,
    opened_once: bool,
    stats: BusStats,
}

impl ModbusBus {
    /// A bus that connects on first use.
    pub fn new(endpoint: Endpoint, opts: ModbusOptions) -> Self {
        Self {
            endpoint,
            opts,
            ctx: None,
            rx: Arc::new(Mutex::new(Vec::new())),
            last_frame: None,
            drain: false,
            opened_once: false,
            stats: BusStats::default(),
        }
    }

    pub fn shared(self) -> SharedBus {
        Arc::new(tokio::sync::Mutex::new(self))
    }

    pub fn endpoint(&self) -> &Endpoint {
        &self.endpoint
    }

    pub fn options(&self) -> &ModbusOptions {
        &self.opts
    }

    pub fn stats(&self) -> BusStats {
        self.stats.clone()
    }

    fn gap(&self) -> Duration {
        match (&self.endpoint, self.opts.rtu_gap) {
            (Endpoint::Tcp(_), _) => Duration::ZERO,
            (_, Some(g)) => g,
            (Endpoint::Rtu { baud, .. }, None) => {
                if *baud > 19_200 {
                    Duration::from_micros(1750)
                } else {
                    // 3.5 characters of 11 bits.
                    Duration::from_secs_f64(3.5 * 11.0 / (*baud).max(1) as f64)
                }
            }
        }
    }

    fn link_error(&self, message: String) -> DriverError {
        DriverError::Transport {
            device: self.endpoint.to_string(),
            message,
        }
    }

    /// Open the socket or port if it is not open (bounded by `connect_timeout`).
    pub async fn connect(&mut self) -> Result<(), DriverError> {
        if self.ctx.is_some() {
            return Ok(());
        }
        let tap_log = self.rx.clone();
        let after = self.opts.connect_timeout;
        let ctx = match &self.endpoint {
            Endpoint::Tcp(addr) => {
                let s = tokio::time::timeout(after, tokio::net::TcpStream::connect(addr))
                    .await
                    .map_err(|_| DriverError::Timeout {
                        device: self.endpoint.to_string(),
                        what: "connect".into(),
                        after_ms: after.as_millis() as u64,
                    })?
                    .map_err(|e| self.link_error(format!("cannot connect: {e}")))?;
                let _ = s.set_nodelay(true);
                tokio_modbus::client::tcp::attach(Tap {
                    inner: s,
                    log: tap_log,
                })
            }
            Endpoint::Rtu { path, baud, parity } => {
                let mut port = open_port(path, *baud, *parity).map_err(|e| self.link_error(e))?;
                if self.drain {
                    discard_stale_input(
                        &mut port,
                        self.opts.rtu_quiet.unwrap_or(self.opts.timeout),
                    )
                    .await;
                }
                use tokio_serial::SerialPort;
                port.clear(tokio_serial::ClearBuffer::Input)
                    .map_err(|e| self.link_error(format!("cannot clear {path}: {e}")))?;
                tokio_modbus::client::rtu::attach(Tap {
                    inner: port,
                    log: tap_log,
                })
            }
        };
        self.drain = false;
        if self.opened_once {
            self.stats.reconnects += 1;
        }
        self.opened_once = true;
        self.ctx = Some(ctx);
        Ok(())
    }

    /// Drop the connection: the next request opens a new one.
    pub fn disconnect(&mut self) {
        self.ctx = None;
        if matches!(self.endpoint, Endpoint::Rtu { .. }) {
            self.drain = true;
        }
    }

    /// One attempt, no retry. Registers read (empty for writes) or why not.
    pub async fn attempt(&mut self, unit: u8, op: &Op<'_>) -> Result<Vec<u16>, Failure> {
        if let Err(e) = self.connect().await {
            self.stats.link_errors += 1;
            return Err(Failure::Link(e.to_string()));
        }
        // Only sleep when there is something to wait for: tokio's timer works in whole
        // milliseconds, so even an elapsed deadline would cost a tick.
        if let Some(t) = self.last_frame {
            let gap = self.gap();
            if !gap.is_zero() && Instant::now() < t + gap {
                tokio::time::sleep_until(t + gap).await;
            }
        }
        self.rx.lock().unwrap_or_else(|p| p.into_inner()).clear();
        let req = match *op {
            Op::ReadHolding(a, n) => Request::ReadHoldingRegisters(a, n),
            Op::ReadInput(a, n) => Request::ReadInputRegisters(a, n),
            Op::WriteSingle(a, v) => Request::WriteSingleRegister(a, v),
            Op::WriteMultiple(a, v) => Request::WriteMultipleRegisters(a, v.into()),
        };
        self.stats.requests += 1;
        let Some(ctx) = self.ctx.as_mut() else {
            return Err(Failure::Link("not connected".into()));
        };
        ctx.set_slave(Slave(unit));
        let result = tokio::time::timeout(self.opts.timeout, ctx.call(req)).await;
        self.last_frame = Some(Instant::now());
        let failure = match result {
            Ok(Ok(Ok(resp))) => {
                return Ok(match resp {
                    Response::ReadHoldingRegisters(v) | Response::ReadInputRegisters(v) => v,
                    _ => Vec::new(),
                })
            }
            Ok(Ok(Err(code))) => {
                self.stats.exceptions += 1;
                return Err(Failure::Exception(Exception::from_code(code.into())));
            }
            Ok(Err(tokio_modbus::Error::Protocol(e))) => {
                self.stats.garbled += 1;
                Failure::Garbled(format!("a reply that is not ours ({e})"))
            }
            Ok(Err(tokio_modbus::Error::Transport(e))) => {
                if e.kind() == io::ErrorKind::InvalidData {
                    self.stats.garbled += 1;
                    Failure::Garbled(format!("undecodable reply ({e})"))
                } else {
                    self.stats.link_errors += 1;
                    Failure::Link(link_failure(&self.endpoint, &e))
                }
            }
            Err(_) => {
                self.stats.timeouts += 1;
                self.explain_silence()
            }
        };
        // Whatever the old connection still delivers must never be read as the
        // answer to a later request.
        self.disconnect();
        Err(failure)
    }

    /// After a timeout: nothing came, or something that was not a valid reply.
    fn explain_silence(&self) -> Failure {
        let got = self.rx.lock().unwrap_or_else(|p| p.into_inner()).clone();
        explain_bytes(&got, &self.endpoint)
    }

    /// A request with retries on the rebuilt connection. `device` and `what` name the
    /// drive and the register for the error.
    pub async fn call(
        &mut self,
        unit: u8,
        op: &Op<'_>,
        device: &str,
        what: &str,
    ) -> Result<Vec<u16>, DriverError> {
        let mut tried = Vec::new();
        for attempt in 0..=self.opts.retries {
            if attempt > 0 {
                self.stats.retries += 1;
            }
            match self.attempt(unit, op).await {
                Ok(v) => return Ok(v),
                Err(Failure::Exception(e)) => return Err(exception_error(device, what, e)),
                Err(f) => tried.push(f),
            }
        }
        Err(self.gave_up(device, what, &tried))
    }

    /// The error after every attempt failed: its kind follows the last failure.
    pub fn gave_up(&self, device: &str, what: &str, tried: &[Failure]) -> DriverError {
        let list: Vec<String> = tried.iter().map(Failure::describe).collect();
        let summary = format!("{what}: {} attempts: {}", tried.len(), list.join("; "));
        match tried.last() {
            Some(Failure::NoReply) | None => DriverError::Timeout {
                device: device.to_string(),
                what: summary,
                after_ms: self.opts.timeout.as_millis() as u64,
            },
            // What happened first, then what was being done.
            Some(Failure::Link(last)) => DriverError::Transport {
                device: device.to_string(),
                message: if tried
                    .iter()
                    .all(|f| matches!(f, Failure::Link(s) if s == last))
                {
                    format!("{last}: {what}: {} attempts", tried.len())
                } else {
                    format!("{last}; {summary}")
                },
            },
            _ => DriverError::Protocol {
                device: device.to_string(),
                message: summary,
            },
        }
    }
}

/// What the bytes received before a timeout were: nothing, an RTU frame with a bad CRC
/// (the frame's bytes, then any that followed it), or bytes that make no reply. The
/// count said is always the count of the bytes shown (cut with the total past 16).
fn explain_bytes(got: &[u8], endpoint: &Endpoint) -> Failure {
    if got.is_empty() {
        return Failure::NoReply;
    }
    if let Endpoint::Rtu { .. } = endpoint {
        if let FrameLen::Bytes(n) = rtu_response_len(got) {
            if n <= got.len() && !rtu_crc_ok(&got[..n]) {
                let mut m = format!(
                    "a reply with a bad CRC ({n} bytes: {})",
                    hex_bytes(&got[..n])
                );
                let rest = &got[n..];
                if !rest.is_empty() {
                    m.push_str(&format!(
                        ", then {} more bytes ({})",
                        rest.len(),
                        hex_bytes(rest)
                    ));
                }
                return Failure::Garbled(m);
            }
        }
    }
    Failure::Garbled(format!(
        "{} bytes that make no valid reply ({})",
        got.len(),
        hex_bytes(got)
    ))
}

/// A link failure in words, what happened first and the system's error after it:
/// `Modbus RTU /dev/ttyUSB0 @19200: the port was closed or unplugged (Input/output
/// error (os error 5))` rather than a bare `Inappropriate ioctl for device`.
fn link_failure(endpoint: &Endpoint, e: &io::Error) -> String {
    use io::ErrorKind as K;
    let gone = matches!(
        e.kind(),
        K::BrokenPipe
            | K::ConnectionReset
            | K::ConnectionAborted
            | K::UnexpectedEof
            | K::NotConnected
    );
    let what = match endpoint {
        Endpoint::Rtu { .. } => {
            // EIO, ENXIO, ENODEV, ENOTTY: what a serial port or pty answers once its
            // adapter is unplugged or the other side closed it.
            let port_gone = gone || matches!(e.raw_os_error(), Some(5 | 6 | 19 | 25));
            if port_gone {
                "the port was closed or unplugged"
            } else {
                "the port failed"
            }
        }
        Endpoint::Tcp(_) => {
            if gone {
                "the drive closed the connection"
            } else {
                "the connection failed"
            }
        }
    };
    format!("{endpoint}: {what} ({e})")
}

/// An exception response as the typed refusal, naming the register.
pub fn exception_error(device: &str, what: &str, e: Exception) -> DriverError {
    DriverError::Refused {
        device: device.to_string(),
        what: what.to_string(),
        code: e.code() as u32,
        message: e.name().to_string(),
    }
}

/// Read and throw away input until the line has been quiet for `quiet` (at most four
/// quiet periods in all, so a babbling line cannot stall us).
async fn discard_stale_input(port: &mut tokio_serial::SerialStream, quiet: Duration) {
    let give_up = Instant::now() + quiet * 4;
    let mut buf = [0u8; 256];
    loop {
        let until = (Instant::now() + quiet).min(give_up);
        match tokio::time::timeout_at(until, port.read(&mut buf)).await {
            Ok(Ok(n)) if n > 0 && Instant::now() < give_up => continue,
            _ => break,
        }
    }
}

fn open_port(path: &str, baud: u32, parity: Parity) -> Result<tokio_serial::SerialStream, String> {
    use tokio_serial::SerialPortBuilderExt;
    tokio_serial::new(path, baud)
        .parity(match parity {
            Parity::None => tokio_serial::Parity::None,
            Parity::Even => tokio_serial::Parity::Even,
            Parity::Odd => tokio_serial::Parity::Odd,
        })
        .data_bits(tokio_serial::DataBits::Eight)
        .stop_bits(tokio_serial::StopBits::One)
        .open_native_async()
        .map_err(|e| format!("cannot open serial port {path} at {baud} baud: {e}"))
}

/// A transport that keeps a copy of what it receives (bounded), so a timed-out
/// request can say what did arrive.
struct Tap<T> {
    inner: T,
    log: Arc<Mutex<Vec<u8>>>,
}

impl<T> fmt::Debug for Tap<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("Tap")
    }
}

impl<T: AsyncRead + Unpin> AsyncRead for Tap<T> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut TaskContext<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let before = buf.filled().len();
        let r = Pin::new(&mut self.inner).poll_read(cx, buf);
        if let Poll::Ready(Ok(())) = &r {
            let mut log = self.log.lock().unwrap_or_else(|p| p.into_inner());
            if log.len() < 512 {
                log.extend_from_slice(&buf.filled()[before..]);
            }
        }
        r
    }
}

impl<T: AsyncWrite + Unpin> AsyncWrite for Tap<T> {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut TaskContext<'_>,
        b: &[u8],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.inner).poll_write(cx, b)
    }
    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut TaskContext<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_flush(cx)
    }
    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut TaskContext<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rtu() -> Endpoint {
        Endpoint::Rtu {
            path: "/dev/ttyX".into(),
            baud: 19_200,
            parity: Parity::Even,
        }
    }

    #[test]
    fn a_bad_crc_message_shows_the_bytes_it_counts() {
        // An exception reply (5 bytes) with a wrong CRC, and 3 stray bytes after it.
        let got = [0x01, 0x83, 0x02, 0x00, 0x00, 0xAA, 0xBB, 0xCC];
        let Failure::Garbled(m) = explain_bytes(&got, &rtu()) else {
            panic!("garbled")
        };
        assert!(m.contains("(5 bytes: 01 83 02 00 00)"), "{m}");
        assert!(m.contains("3 more bytes (AA BB CC)"), "{m}");
        // Exactly the frame: no tail.
        let Failure::Garbled(m) = explain_bytes(&got[..5], &rtu()) else {
            panic!("garbled")
        };
        assert_eq!(m, "a reply with a bad CRC (5 bytes: 01 83 02 00 00)");
        // Many bytes: the count and the shown bytes agree (cut with the total).
        let noise = [0x55u8; 40];
        let Failure::Garbled(m) =
            explain_bytes(&noise, &Endpoint::Tcp("127.0.0.1:502".parse().unwrap()))
        else {
            panic!("garbled")
        };
        assert!(
            m.starts_with("40 bytes that make no valid reply (55 55"),
            "{m}"
        );
        assert!(m.ends_with("… (40 bytes))"), "{m}");
    }

    #[test]
    fn a_lost_port_says_what_happened_before_the_system_error() {
        let e = io::Error::from_raw_os_error(25); // ENOTTY: the pty's other side is gone
        let m = link_failure(&rtu(), &e);
        assert!(
            m.starts_with("Modbus RTU /dev/ttyX @19200: the port was closed or unplugged ("),
            "{m}"
        );
        let e = io::Error::from(io::ErrorKind::BrokenPipe);
        let m = link_failure(&Endpoint::Tcp("127.0.0.1:502".parse().unwrap()), &e);
        assert!(
            m.starts_with("Modbus TCP 127.0.0.1:502: the drive closed the connection ("),
            "{m}"
        );
        let bus = ModbusBus::new(rtu(), ModbusOptions::default());
        let d = bus.gave_up(
            "unit 1",
            "read status",
            &[Failure::Link(link_failure(
                &rtu(),
                &io::Error::from_raw_os_error(5),
            ))],
        );
        assert!(
            d.to_string()
                .starts_with("unit 1: link failed: Modbus RTU /dev/ttyX @19200: the port was closed or unplugged"),
            "{d}"
        );
    }
}

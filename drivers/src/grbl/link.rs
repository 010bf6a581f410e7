//! The byte link to a GRBL controller: writes, and responses read with a deadline.

use crate::error::DriverError;
use protocol::grbl::response::{LineDecoder, Response};
use protocol::text::escape_bytes;
use std::collections::VecDeque;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::time::Instant;

/// Anything that carries GRBL's bytes: a serial port, one end of a pseudo-terminal, an
/// in-memory duplex in tests.
pub trait Transport: AsyncRead + AsyncWrite + Send + Unpin {}
impl<T: AsyncRead + AsyncWrite + Send + Unpin> Transport for T {}

pub(crate) struct Link {
    io: Box<dyn Transport>,
    decoder: LineDecoder,
    inbox: VecDeque<Response>,
    /// Recent lines that were not GRBL messages (for "is this GRBL?" errors), escaped.
    pub(crate) foreign: Vec<String>,
    /// GRBL responses received since [`Link::listen`], by kind, in order of first
    /// arrival: what a device that never sends the awaited answer did send.
    heard: Vec<(&'static str, usize)>,
    pub(crate) device: String,
}

impl Link {
    pub(crate) fn new(io: Box<dyn Transport>, device: String) -> Self {
        Self {
            io,
            decoder: LineDecoder::new(),
            inbox: VecDeque::new(),
            foreign: Vec::new(),
            heard: Vec::new(),
            device,
        }
    }

    fn transport(&self, message: String) -> DriverError {
        DriverError::Transport {
            device: self.device.clone(),
            message,
        }
    }

    pub(crate) async fn write(&mut self, bytes: &[u8]) -> Result<(), DriverError> {
        self.io
            .write_all(bytes)
            .await
            .map_err(|e| self.transport(format!("write failed: {e}")))?;
        self.io
            .flush()
            .await
            .map_err(|e| self.transport(format!("write failed: {e}")))
    }

    /// The next response, reading as needed until `deadline`. `Ok(None)` on timeout.
    pub(crate) async fn next(
        &mut self,
        deadline: Instant,
    ) -> Result<Option<Response>, DriverError> {
        loop {
            if let Some(r) = self.inbox.pop_front() {
                if let Response::Other(s) = &r {
                    // Already escaped and cut by the decoder.
                    if self.foreign.len() < 8 {
                        self.foreign.push(s.clone());
                    }
                } else {
                    let kind = kind(&r);
                    match self.heard.iter_mut().find(|(k, _)| *k == kind) {
                        Some((_, n)) => *n += 1,
                        None => self.heard.push((kind, 1)),
                    }
                }
                return Ok(Some(r));
            }
            let mut buf = [0u8; 1024];
            let n = match tokio::time::timeout_at(deadline, self.io.read(&mut buf)).await {
                Err(_) => return Ok(None),
                Ok(Err(e)) => return Err(self.transport(format!("read failed: {e}"))),
                Ok(Ok(0)) => {
                    return Err(self.transport("the port closed (device unplugged?)".into()))
                }
                Ok(Ok(n)) => n,
            };
            let mut out = Vec::new();
            self.decoder.feed(&buf[..n], &mut out);
            if out.is_empty()
                && !self.decoder.pending().is_empty()
                && self.foreign.len() < 8
                && self.decoder.pending().len() > 64
            {
                self.foreign.push(format!(
                    "{} (no line end yet)",
                    escape_bytes(self.decoder.pending())
                ));
            }
            self.inbox.extend(out);
        }
    }

    /// Start counting the responses received, and forget the foreign lines kept (for
    /// [`Link::heard_summary`]).
    pub(crate) fn listen(&mut self) {
        self.heard.clear();
        self.foreign.clear();
    }

    /// What the device sent while `expected` never came, as a verb phrase for an error
    /// message: "sent nothing", "answered only `ok` 37 times, never a status report",
    /// "sent `\x80\xA5...` (no line end)"; device bytes escaped and cut.
    pub(crate) fn heard_summary(&self, expected: &str) -> String {
        let mut foreign: Vec<String> = self.foreign.iter().map(|s| format!("`{s}`")).collect();
        let pending = self.decoder.pending();
        if !pending.is_empty() {
            foreign.push(format!("`{}` (no line end)", escape_bytes(pending)));
        }
        let heard: Vec<String> = self
            .heard
            .iter()
            .map(|(k, n)| match n {
                1 => format!("{k} once"),
                n => format!("{k} {n} times"),
            })
            .collect();
        match (foreign.is_empty(), heard.is_empty()) {
            (true, true) => "sent nothing".into(),
            (true, false) => format!("answered only {}, never {expected}", heard.join(", ")),
            (false, true) => format!("sent {}", foreign.join(", ")),
            (false, false) => format!(
                "sent {}, and {}, never {expected}",
                foreign.join(", "),
                heard.join(", ")
            ),
        }
    }
}

/// How a response is named in a message.
fn kind(r: &Response) -> &'static str {
    match r {
        Response::Ok => "`ok`",
        Response::Error(_) => "`error:N`",
        Response::Alarm(_) => "`ALARM:N`",
        Response::Status(_) => "a status report",
        Response::Banner { .. } => "a start-up banner",
        Response::Message(_) => "a `[MSG:]` message",
        Response::Version { .. } => "a version report",
        Response::Options { .. } => "a build options report",
        Response::Setting { .. } => "a setting line",
        _ => "other GRBL lines",
    }
}

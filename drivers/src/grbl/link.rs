//! The byte link to a GRBL controller: writes, and responses read with a deadline.

use crate::error::DriverError;
use protocol::grbl::response::{LineDecoder, Response};
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
    /// Recent lines that were not GRBL messages (for "is this GRBL?" errors).
    pub(crate) foreign: Vec<String>,
    pub(crate) device: String,
}

impl Link {
    pub(crate) fn new(io: Box<dyn Transport>, device: String) -> Self {
        Self {
            io,
            decoder: LineDecoder::new(),
            inbox: VecDeque::new(),
            foreign: Vec::new(),
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
                    if self.foreign.len() < 8 {
                        self.foreign.push(s.chars().take(80).collect());
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
                self.foreign
                    .push(String::from_utf8_lossy(&self.decoder.pending()[..64]).into_owned());
            }
            self.inbox.extend(out);
        }
    }

    /// What was received that was not GRBL, for an error message.
    pub(crate) fn foreign_summary(&self) -> String {
        let mut parts: Vec<String> = self.foreign.iter().map(|s| format!("`{s}`")).collect();
        let pending = self.decoder.pending();
        if !pending.is_empty() {
            parts.push(format!(
                "`{}` (no line end)",
                String::from_utf8_lossy(&pending[..pending.len().min(64)])
            ));
        }
        if parts.is_empty() {
            "nothing".into()
        } else {
            parts.join(", ")
        }
    }
}

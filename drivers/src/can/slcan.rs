//! A CAN bus through an SLCAN (Lawicel ASCII) adapter on a serial port: CANable,
//! USBtin, Lawicel CANUSB, or the project's emulator on a pseudo-terminal.
//!
//! Opening closes the channel (`C`), sets the bitrate (`Sn`) and opens it (`O`),
//! checking the adapter's answers, so a port that is not an SLCAN adapter is told
//! apart from one that is. Frames go out as `t/T/r/R` lines; adapter answers (`z`,
//! CR, BEL) are counted, not awaited, as slcand and python-can do, so sending never
//! waits on the adapter. Malformed lines are skipped and counted.

use super::{BusStats, CanBus};
use crate::error::DriverError;
use crate::grbl::Transport;
use async_trait::async_trait;
use protocol::can::CanFrame;
use protocol::slcan::{bitrate_code, Command, Message, MessageDecoder, BITRATES};
use std::collections::VecDeque;
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

/// How long the adapter has to answer the opening commands.
pub const OPEN_TIMEOUT: Duration = Duration::from_secs(2);

pub struct SlcanBus {
    io: Box<dyn Transport>,
    name: String,
    decoder: MessageDecoder,
    inbox: VecDeque<CanFrame>,
    answers: VecDeque<Message>,
    stats: BusStats,
    buf: Box<[u8; 4096]>,
}

impl SlcanBus {
    /// Open an adapter by serial port path. The serial baud rate does not matter to
    /// USB adapters and pseudo-terminals; 115200 is used.
    pub async fn open(port: &str, bitrate: u32) -> Result<Self, DriverError> {
        use tokio_serial::SerialPortBuilderExt;
        let io = tokio_serial::new(port, 115_200)
            .open_native_async()
            .map_err(|e| DriverError::Transport {
                device: format!("slcan {port}"),
                message: format!("cannot open the serial port: {e}"),
            })?;
        Self::over(Box::new(io), &format!("slcan {port}"), bitrate).await
    }

    /// Use any byte link (a port, a pseudo-terminal, an in-memory pipe).
    pub async fn over(
        io: Box<dyn Transport>,
        name: &str,
        bitrate: u32,
    ) -> Result<Self, DriverError> {
        Self::over_with_timeout(io, name, bitrate, OPEN_TIMEOUT).await
    }

    /// As [`SlcanBus::over`], with the time the adapter has to answer each opening
    /// command.
    pub async fn over_with_timeout(
        io: Box<dyn Transport>,
        name: &str,
        bitrate: u32,
        timeout: Duration,
    ) -> Result<Self, DriverError> {
        let code = bitrate_code(bitrate).ok_or_else(|| DriverError::Unsupported {
            device: name.to_string(),
            message: format!(
                "bitrate {bitrate} bit/s has no SLCAN `S` code; use one of {BITRATES:?}"
            ),
        })?;
        let mut bus = SlcanBus {
            io,
            name: format!("{name} @ {bitrate} bit/s"),
            decoder: MessageDecoder::new(),
            inbox: VecDeque::new(),
            answers: VecDeque::new(),
            stats: BusStats::default(),
            buf: Box::new([0; 4096]),
        };
        // `C` may be refused (BEL) by an adapter that is already closed: either is fine.
        bus.command(&Command::Close, timeout, true).await?;
        bus.command(&Command::Bitrate(code), timeout, false).await?;
        bus.command(&Command::Open, timeout, false).await?;
        Ok(bus)
    }

    async fn write(&mut self, bytes: &[u8]) -> Result<(), DriverError> {
        let r = async {
            self.io.write_all(bytes).await?;
            self.io.flush().await
        }
        .await;
        r.map_err(|e| DriverError::Transport {
            device: self.name.clone(),
            message: format!("write failed: {e}"),
        })
    }

    /// Send a command and wait for its answer (CR, or BEL if `bel_ok`).
    async fn command(
        &mut self,
        c: &Command,
        timeout: Duration,
        bel_ok: bool,
    ) -> Result<(), DriverError> {
        let deadline = tokio::time::Instant::now() + timeout;
        self.answers.clear();
        self.write(&c.encode()).await?;
        loop {
            while let Some(m) = self.answers.pop_front() {
                match m {
                    Message::Ok => return Ok(()),
                    Message::Error if bel_ok => return Ok(()),
                    Message::Error => {
                        return Err(DriverError::Refused {
                            device: self.name.clone(),
                            what: format!("{:?}", String::from_utf8_lossy(&c.encode()).trim_end()),
                            code: 7,
                            message: "the adapter answered BEL (error)".into(),
                        })
                    }
                    _ => {}
                }
            }
            match tokio::time::timeout_at(deadline, self.fill()).await {
                Ok(r) => r?,
                Err(_) => {
                    return Err(DriverError::Timeout {
                        device: self.name.clone(),
                        what: format!(
                        "SLCAN command {:?} (is this an SLCAN adapter? {} malformed lines seen)",
                        String::from_utf8_lossy(&c.encode()).trim_end(),
                        self.decoder.malformed()
                    ),
                        after_ms: timeout.as_millis() as u64,
                    })
                }
            }
        }
    }

    /// Read once and decode (cancel-safe: the only await is the read).
    async fn fill(&mut self) -> Result<(), DriverError> {
        let n = self
            .io
            .read(&mut self.buf[..])
            .await
            .map_err(|e| DriverError::Transport {
                device: self.name.clone(),
                message: format!("read failed: {e}"),
            })?;
        if n == 0 {
            return Err(DriverError::Transport {
                device: self.name.clone(),
                message: "the adapter closed the port".into(),
            });
        }
        let mut msgs = Vec::new();
        self.decoder.feed(&self.buf[..n], &mut msgs);
        self.stats.malformed = self.decoder.malformed();
        for m in msgs {
            match m {
                Message::Frame { frame, .. } => {
                    self.stats.frames_received += 1;
                    self.inbox.push_back(frame);
                }
                Message::Error => {
                    self.stats.adapter_errors += 1;
                    self.answers.push_back(m);
                }
                other => self.answers.push_back(other),
            }
        }
        // Transmit acknowledgements are not awaited; keep only a few for `command`.
        while self.answers.len() > 16 {
            self.answers.pop_front();
        }
        Ok(())
    }
}

#[async_trait]
impl CanBus for SlcanBus {
    fn name(&self) -> &str {
        &self.name
    }

    async fn send(&mut self, frame: &CanFrame) -> Result<(), DriverError> {
        self.write(&Command::Transmit(*frame).encode()).await?;
        self.stats.frames_sent += 1;
        Ok(())
    }

    async fn recv(&mut self) -> Result<CanFrame, DriverError> {
        loop {
            if let Some(f) = self.inbox.pop_front() {
                return Ok(f);
            }
            self.fill().await?;
        }
    }

    fn stats(&self) -> BusStats {
        self.stats.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::duplex;

    fn rt() -> tokio::runtime::Runtime {
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap()
    }

    /// A scripted adapter: answers the three opening commands one by one (a byte of
    /// `answers` each), then sends `then`.
    async fn adapter(
        mut io: tokio::io::DuplexStream,
        answers: &'static [u8],
        then: Vec<u8>,
    ) -> Vec<u8> {
        let mut got = Vec::new();
        let mut buf = [0u8; 256];
        let mut answered = 0;
        while answered < 3 {
            let n = io.read(&mut buf).await.unwrap();
            got.extend_from_slice(&buf[..n]);
            while answered < got.iter().filter(|&&b| b == b'\r').count().min(3) {
                io.write_all(&answers[answered..answered + 1])
                    .await
                    .unwrap();
                answered += 1;
            }
        }
        io.write_all(&then).await.unwrap();
        // Keep the link up until the host has read everything.
        while let Ok(n) = io.read(&mut buf).await {
            if n == 0 {
                break;
            }
            got.extend_from_slice(&buf[..n]);
        }
        got
    }

    #[test]
    fn opens_with_close_bitrate_open_and_skips_malformed_lines() {
        rt().block_on(async {
            let (host, dev) = duplex(4096);
            let mut stream = Vec::new();
            for (i, junk) in [
                &b"t12\r"[..],
                b"\xFF\xFE\r",
                b"T1FFFFFFFF0\r",
                b"zz\r",
                b"t7FF9\r",
            ]
            .iter()
            .enumerate()
            {
                stream.extend_from_slice(junk);
                stream.extend_from_slice(format!("t70{i}105\r").as_bytes());
            }
            let script = tokio::spawn(adapter(dev, b"\x07\r\r", stream));
            let mut bus = SlcanBus::over(Box::new(host), "test", 500_000)
                .await
                .unwrap();
            for i in 0..5u16 {
                let f = bus.recv().await.unwrap();
                assert_eq!(f, CanFrame::std(0x700 + i, &[0x05]));
            }
            assert_eq!(bus.stats().malformed, 5);
            assert_eq!(bus.stats().adapter_errors, 1, "the BEL answering `C`");
            bus.send(&CanFrame::std(0x000, &[0x01, 0x00]))
                .await
                .unwrap();
            drop(bus);
            let sent = script.await.unwrap();
            assert_eq!(sent, b"C\rS6\rO\rt00020100\r");
        });
    }

    #[test]
    fn a_port_that_is_not_an_adapter_times_out_or_is_refused() {
        rt().block_on(async {
            let (host, dev) = duplex(4096);
            let script = tokio::spawn(adapter(dev, b"\r\x07\r", Vec::new()));
            let e = SlcanBus::over(Box::new(host), "test", 1_000_000)
                .await
                .err()
                .unwrap();
            assert!(matches!(e, DriverError::Refused { .. }), "{e}");
            assert!(e.to_string().contains("\"S8\""), "{e}");
            script.abort();
            let silent = Duration::from_millis(100);
            let e = SlcanBus::over_with_timeout(Box::new(duplex(64).0), "test", 1_000_000, silent)
                .await
                .err()
                .unwrap();
            assert!(
                matches!(
                    e,
                    DriverError::Timeout { .. } | DriverError::Transport { .. }
                ),
                "{e}"
            );
            let e = SlcanBus::over(Box::new(duplex(64).0), "test", 83_333)
                .await
                .err()
                .unwrap();
            assert!(e.to_string().contains("no SLCAN `S` code"), "{e}");
        });
    }
}

//! The GRBL emulator on a real pseudo-terminal: any program that opens the printed
//! `/dev/pts/N` path (or the optional symlink) talks to it exactly as to a USB-serial
//! GRBL board.
//!
//! The runner holds the slave side open itself, so clients may come and go without the
//! master seeing a hang-up; closing the runner ([`GrblPty::hang_up`]) closes both sides,
//! which is what a client sees when a USB adapter is unplugged.

use super::device::{DeviceStats, GrblDevice};
use crate::pty::PtyPort;
use std::io;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::oneshot;
use tokio_serial::{SerialPort, SerialStream};

/// A running emulator on a pseudo-terminal.
pub struct GrblPty {
    port: PtyPort,
    stats: Arc<Mutex<DeviceStats>>,
}

fn io_err(e: tokio_serial::Error) -> io::Error {
    io::Error::other(e.to_string())
}

impl GrblPty {
    /// Create a pseudo-terminal, power the device on (banner) and serve it. Must be
    /// called inside a tokio runtime. With `link`, a symlink to the slave path is
    /// created there (replacing an old one), so clients can use a stable name.
    pub fn spawn(device: GrblDevice, link: Option<&Path>) -> io::Result<GrblPty> {
        let stats = Arc::new(Mutex::new(DeviceStats::default()));
        let counters = stats.clone();
        let port = PtyPort::spawn(link, move |master, slave, stop| {
            serve(device, master, slave, stop, counters)
        })?;
        Ok(GrblPty { port, stats })
    }

    /// The slave path (`/dev/pts/N`) clients open.
    pub fn path(&self) -> &str {
        self.port.path()
    }

    /// The symlink, if one was asked for.
    pub fn link(&self) -> Option<&Path> {
        self.port.link()
    }

    /// Close the pseudo-terminal: the port disappears for its client.
    pub async fn hang_up(self) {
        self.port.hang_up().await
    }

    pub fn stats(&self) -> DeviceStats {
        self.stats.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }

    /// Wait until the runner ends by itself (after the device's answer limit).
    pub async fn closed(&mut self) {
        self.port.closed().await
    }
}

async fn serve(
    mut dev: GrblDevice,
    mut master: SerialStream,
    slave: SerialStream,
    mut stop: oneshot::Receiver<()>,
    stats: Arc<Mutex<DeviceStats>>,
) {
    let t0 = Instant::now();
    let now = move || t0.elapsed().as_secs_f64();
    dev.power_on(now());
    let mut buf = [0u8; 4096];
    // While something moves on a scaled clock, the device is polled this often.
    let mut tick = tokio::time::interval(Duration::from_millis(2));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    loop {
        let out = dev.take_output();
        if !out.is_empty() && master.write_all(&out).await.is_err() {
            break;
        }
        *stats.lock().unwrap_or_else(|p| p.into_inner()) = dev.stats().clone();
        if dev.answer_limit_reached() {
            // Fault injection: hang up, but only once the client has read every
            // answer, so the point of failure is known exactly. Bytes written to the
            // master reach the slave's input queue a moment later, so the queue must
            // be seen empty twice, a few milliseconds apart (bounded wait).
            let mut empty_checks = 0;
            for _ in 0..2000 {
                tokio::time::sleep(Duration::from_millis(2)).await;
                if slave.bytes_to_read().unwrap_or(0) == 0 {
                    empty_checks += 1;
                    if empty_checks == 3 {
                        break;
                    }
                } else {
                    empty_checks = 0;
                }
            }
            break;
        }
        tokio::select! {
            r = master.read(&mut buf) => match r {
                Ok(0) => break,
                Ok(n) => dev.receive(&buf[..n], now()),
                Err(_) => break,
            },
            _ = tick.tick(), if dev.needs_poll() => dev.poll(now()),
            _ = &mut stop => break,
        }
    }
    drop(master);
    drop(slave);
}

/// How a [`ForeignPty`] behaves: devices that are not GRBL, for the driver's tests of
/// "wrong device" errors.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Foreign {
    /// Never sends anything.
    Silent,
    /// Echoes every byte back (a loopback plug, or a modem with echo on).
    Echo,
    /// Answers every line with a line of another firmware.
    Chatter,
}

/// A pseudo-terminal with a device on it that is not GRBL.
pub struct ForeignPty {
    path: String,
    stop: Option<oneshot::Sender<()>>,
}

impl ForeignPty {
    pub fn spawn(kind: Foreign) -> io::Result<ForeignPty> {
        let (mut master, slave) = SerialStream::pair().map_err(io_err)?;
        let path = slave
            .name()
            .ok_or_else(|| io::Error::other("the pseudo-terminal has no slave path"))?;
        let (tx, mut rx) = oneshot::channel::<()>();
        tokio::spawn(async move {
            let mut buf = [0u8; 1024];
            loop {
                tokio::select! {
                    r = master.read(&mut buf) => match r {
                        Ok(n) if n > 0 => {
                            let reply: Vec<u8> = match kind {
                                Foreign::Silent => Vec::new(),
                                Foreign::Echo => buf[..n].to_vec(),
                                Foreign::Chatter => {
                                    if buf[..n].contains(&b'\n') { b"echo:Unknown command: \"$I\"\r\nok T:21.3 /0.0\r\n".to_vec() } else { Vec::new() }
                                }
                            };
                            if !reply.is_empty() && master.write_all(&reply).await.is_err() {
                                break;
                            }
                        }
                        _ => break,
                    },
                    _ = &mut rx => break,
                }
            }
            drop(slave);
        });
        Ok(ForeignPty {
            path,
            stop: Some(tx),
        })
    }

    pub fn path(&self) -> &str {
        &self.path
    }
}

impl Drop for ForeignPty {
    fn drop(&mut self) {
        if let Some(tx) = self.stop.take() {
            let _ = tx.send(());
        }
    }
}

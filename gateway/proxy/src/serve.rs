//! The pass-through's I/O: the sender's pseudo-terminal and the controller's port,
//! bytes moved through [`Proxy`] as they come.

use crate::core::{LineAccount, Proxy};
use std::future::Future;
use std::io;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_serial::{SerialPort, SerialStream};

/// The pseudo-terminal a sender connects to. The gateway keeps only the master side, so
/// a sender closing its port is seen (the master reads fail) and the session ends with
/// a feed hold.
pub struct SenderPort {
    master: SerialStream,
    path: String,
    link: Option<PathBuf>,
}

impl SenderPort {
    /// A new pseudo-terminal; with `link`, a symlink to its slave path there (replacing
    /// an old one), a stable name to give the sender.
    pub fn create(link: Option<&Path>) -> io::Result<SenderPort> {
        let (master, slave) = SerialStream::pair().map_err(|e| io::Error::other(e.to_string()))?;
        let path = slave
            .name()
            .ok_or_else(|| io::Error::other("the pseudo-terminal has no slave path"))?;
        drop(slave);
        if let Some(l) = link {
            if l.symlink_metadata().is_ok() {
                std::fs::remove_file(l)?;
            }
            std::os::unix::fs::symlink(&path, l)?;
        }
        Ok(SenderPort {
            master,
            path,
            link: link.map(Path::to_path_buf),
        })
    }

    /// The slave path (`/dev/pts/N`) the sender opens.
    pub fn path(&self) -> &str {
        &self.path
    }

    pub fn link(&self) -> Option<&Path> {
        self.link.as_deref()
    }
}

impl Drop for SenderPort {
    fn drop(&mut self) {
        if let Some(l) = &self.link {
            let _ = std::fs::remove_file(l);
        }
    }
}

/// Open the controller's port and wait for its banner (an Arduino resets when its port
/// opens and talks after about two seconds; a controller that was already running says
/// nothing, so `banner_wait` bounds the wait). What it said at start-up is not the
/// sender's and is returned, not passed on.
pub async fn open_controller(
    port: &str,
    baud: u32,
    banner_wait: Duration,
) -> io::Result<(SerialStream, String)> {
    use tokio_serial::SerialPortBuilderExt;
    let mut controller = tokio_serial::new(port, baud)
        .open_native_async()
        .map_err(|e| io::Error::other(format!("opening the controller at {port}: {e}")))?;
    let mut banner = Vec::new();
    let mut buf = [0u8; 256];
    let deadline = tokio::time::Instant::now() + banner_wait;
    while !String::from_utf8_lossy(&banner).contains("Grbl") {
        match tokio::time::timeout_at(deadline, controller.read(&mut buf)).await {
            Ok(Ok(n)) if n > 0 => banner.extend_from_slice(&buf[..n]),
            Ok(Ok(_)) => return Err(io::Error::other(format!("the controller at {port} closed"))),
            Ok(Err(e)) => return Err(e),
            Err(_) => break,
        }
    }
    Ok((
        controller,
        String::from_utf8_lossy(&banner).trim().to_string(),
    ))
}

/// How a session ended, with where every line stood.
#[derive(Debug)]
pub enum Ending {
    /// The sender closed its port after sending lines (a feed hold was sent if lines
    /// were still pending).
    SenderLeft(LineAccount),
    /// The controller's port closed or failed (the sender got an alarm).
    ControllerLost { why: String, lines: LineAccount },
    /// Asked to stop (Ctrl-C, service shutdown).
    Stopped(LineAccount),
}

/// How long to wait before looking again for a sender while none has the port open.
const NO_SENDER_RETRY: Duration = Duration::from_millis(20);

/// How often the gateway asks the controller for its status while lines are on their
/// way (GRBL's docs suggest at most 5 Hz for senders; the gateway's own is on top).
const STATUS_POLL: Duration = Duration::from_millis(200);

/// Serve one sender session: until the sender leaves (after it sent something), the
/// controller is lost, or `stop` fires.
pub async fn serve(
    proxy: &mut Proxy<'_>,
    sender: &mut SenderPort,
    controller: &mut SerialStream,
    stop: impl Future<Output = ()>,
) -> Ending {
    let started = Instant::now();
    let now = || started.elapsed().as_secs_f64();
    let mut from_sender = [0u8; 4096];
    let mut from_controller = [0u8; 4096];
    let mut heard_sender = false;
    let mut poll = tokio::time::interval(STATUS_POLL);
    poll.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    tokio::pin!(stop);
    let ending = loop {
        // Whatever the last step produced goes out first.
        let out = proxy.take_to_controller();
        if !out.is_empty() {
            if let Err(e) = controller.write_all(&out).await {
                break lost(proxy, sender, format!("writing to the controller: {e}")).await;
            }
        }
        let back = proxy.take_to_sender();
        if !back.is_empty() {
            // A sender that is not there loses what was meant for it; the controller
            // side goes on.
            let _ = sender.master.write_all(&back).await;
        }
        tokio::select! {
            biased;
            _ = &mut stop => break Ending::Stopped(proxy.account()),
            _ = poll.tick() => proxy.poll_status(),
            r = controller.read(&mut from_controller) => match r {
                Ok(0) => break lost(proxy, sender, "the port closed".into()).await,
                Ok(n) => proxy.from_controller(&from_controller[..n], now()),
                Err(e) => break lost(proxy, sender, e.to_string()).await,
            },
            r = sender.master.read(&mut from_sender) => match r {
                Ok(n) if n > 0 => {
                    heard_sender = true;
                    proxy.from_sender(&from_sender[..n], now());
                }
                // No sender has the port open (EIO on the master) or it just closed.
                _ => {
                    if heard_sender {
                        let lines = proxy.sender_lost();
                        let hold = proxy.take_to_controller();
                        if !hold.is_empty() {
                            let _ = controller.write_all(&hold).await;
                        }
                        break Ending::SenderLeft(lines);
                    }
                    tokio::time::sleep(NO_SENDER_RETRY).await;
                }
            },
        }
    };
    ending
}

async fn lost(proxy: &mut Proxy<'_>, sender: &mut SenderPort, why: String) -> Ending {
    let lines = proxy.controller_lost(&why);
    let back = proxy.take_to_sender();
    let _ = sender.master.write_all(&back).await;
    Ending::ControllerLost { why, lines }
}

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
    /// A new pseudo-terminal; with `link`, a symlink to its slave path there, a stable
    /// name to give the sender. An old symlink there is replaced (atomically); anything
    /// else there (a regular file, a folder) is refused and left alone.
    pub fn create(link: Option<&Path>) -> io::Result<SenderPort> {
        let (master, slave) = SerialStream::pair().map_err(|e| io::Error::other(e.to_string()))?;
        let path = slave
            .name()
            .ok_or_else(|| io::Error::other("the pseudo-terminal has no slave path"))?;
        drop(slave);
        if let Some(l) = link {
            place_link(&path, l)?;
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

/// A symlink at `link` to `target`: made beside it under a unique name and renamed
/// over an old symlink; never over anything that is not a symlink.
fn place_link(target: &str, link: &Path) -> io::Result<()> {
    if let Ok(m) = link.symlink_metadata() {
        if !m.file_type().is_symlink() {
            return Err(io::Error::new(
                io::ErrorKind::AlreadyExists,
                format!(
                    "{} exists and is not a symlink: not replaced (give a new path to --link)",
                    link.display()
                ),
            ));
        }
    }
    let name = link
        .file_name()
        .ok_or_else(|| io::Error::other(format!("{}: no file name", link.display())))?;
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(name);
    tmp_name.push(format!(".{}.link-tmp", std::process::id()));
    let tmp = link.with_file_name(tmp_name);
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(target, &tmp)?;
    // Checked again just before: a file put there meanwhile is not replaced.
    if link
        .symlink_metadata()
        .is_ok_and(|m| !m.file_type().is_symlink())
    {
        let _ = std::fs::remove_file(&tmp);
        return Err(io::Error::new(
            io::ErrorKind::AlreadyExists,
            format!(
                "{} exists and is not a symlink: not replaced",
                link.display()
            ),
        ));
    }
    std::fs::rename(&tmp, link).inspect_err(|_| {
        let _ = std::fs::remove_file(&tmp);
    })
}

impl Drop for SenderPort {
    /// The link goes only if it is still the symlink to this port.
    fn drop(&mut self) {
        if let Some(l) = &self.link {
            let ours = l
                .symlink_metadata()
                .is_ok_and(|m| m.file_type().is_symlink())
                && std::fs::read_link(l).is_ok_and(|t| t == Path::new(&self.path));
            if ours {
                let _ = std::fs::remove_file(l);
            }
        }
    }
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

/// Bytes for the sender kept while it does not read them; past this, what does not fit
/// is dropped (as a serial line's buffers would), and the controller side goes on.
pub const SENDER_OUTBOX: usize = 1 << 20;

/// How long the last words to a sender (the controller was lost) may take.
const LAST_WORDS: Duration = Duration::from_millis(500);

/// Serve one sender session: until the sender leaves (after it opened the port or sent
/// something), the controller is lost, or `stop` fires.
///
/// Nothing a sender does can make it hold without bound: bytes are read from the sender
/// only while [`Proxy::accepts_sender_bytes`], and what it does not read is kept up to
/// [`SENDER_OUTBOX`] bytes. A sender that opened the port and closed it without sending
/// anything ends the session too (seen from the pseudo-terminal: its reads wait while
/// a sender has it open and fail at once while none has).
pub async fn serve(
    proxy: &mut Proxy<'_>,
    sender: &mut SenderPort,
    controller: &mut SerialStream,
    stop: impl Future<Output = ()>,
) -> Ending {
    serve_with_camera(proxy, sender, controller, stop, None).await
}

/// Measures a re-reference's frame: the camera's error at `at_mm` (machine mm, a point
/// of the plan), um (the stage is at rest there).
pub trait ReferenceFrames {
    fn measure(
        &mut self,
        at_mm: [f64; 2],
    ) -> std::pin::Pin<Box<dyn Future<Output = Result<[f64; 2], String>> + '_>>;
}

/// [`serve`], with `frames` measuring the re-reference's frames when the pass-through
/// asks for them, after the sender's homing and in use ([`Proxy::frame_due`]; without
/// `frames` the measurement fails: after a homing motion is then refused until the
/// machine is referenced).
pub async fn serve_with_camera(
    proxy: &mut Proxy<'_>,
    sender: &mut SenderPort,
    controller: &mut SerialStream,
    stop: impl Future<Output = ()>,
    mut frames: Option<&mut dyn ReferenceFrames>,
) -> Ending {
    use std::task::Poll;
    use tokio::io::AsyncRead;
    let started = Instant::now();
    let now = || started.elapsed().as_secs_f64();
    let mut from_sender = [0u8; 4096];
    let mut from_controller = [0u8; 4096];
    let mut heard_sender = false;
    // A sender has the port open: reads waited and none failed for two poll periods.
    let mut sender_seen = false;
    let read_waited = std::cell::Cell::new(false);
    let mut read_failures = 0u32;
    let mut quiet_periods = 0u32;
    let mut outbox: Vec<u8> = Vec::new();
    let (mut sender_rx, mut sender_tx) = tokio::io::split(&mut sender.master);
    let mut poll = tokio::time::interval(STATUS_POLL);
    poll.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    tokio::pin!(stop);
    let ending = loop {
        if let Some(at_mm) = proxy.frame_due() {
            // The stage is at rest at a point of the re-reference: one frame (the sender
            // waits for its next answer meanwhile, as it would for a slow controller).
            let seen = match frames.as_mut() {
                Some(f) => f.measure(at_mm).await,
                None => Err("no camera to measure the reference with".into()),
            };
            proxy.frame_measured(seen);
        }
        // Whatever the last step produced goes out first.
        let out = proxy.take_to_controller();
        if !out.is_empty() {
            if let Err(e) = controller.write_all(&out).await {
                break lost(
                    proxy,
                    &mut sender_tx,
                    outbox,
                    format!("writing to the controller: {e}"),
                )
                .await;
            }
        }
        let back = proxy.take_to_sender();
        let room = SENDER_OUTBOX.saturating_sub(outbox.len());
        outbox.extend_from_slice(&back[..back.len().min(room)]);
        let reading = proxy.accepts_sender_bytes();
        tokio::select! {
            biased;
            _ = &mut stop => break Ending::Stopped(proxy.account()),
            _ = poll.tick() => {
                proxy.poll_status();
                proxy.tick(now());
                // Two poll periods in a row in which a read waited and none failed.
                quiet_periods = match read_waited.take() && read_failures == 0 {
                    true => quiet_periods + 1,
                    false => 0,
                };
                sender_seen |= quiet_periods >= 2;
                read_failures = 0;
            }
            r = controller.read(&mut from_controller) => match r {
                Ok(0) => break lost(proxy, &mut sender_tx, outbox, "the port closed".into()).await,
                Ok(n) => proxy.from_controller(&from_controller[..n], now()),
                Err(e) => break lost(proxy, &mut sender_tx, outbox, e.to_string()).await,
            },
            // A sender that is not there loses what was meant for it.
            r = sender_tx.write(&outbox), if !outbox.is_empty() => match r {
                Ok(n) if n > 0 => {
                    outbox.drain(..n);
                }
                _ => outbox.clear(),
            },
            r = std::future::poll_fn(|cx| {
                let mut buf = tokio::io::ReadBuf::new(&mut from_sender);
                match std::pin::Pin::new(&mut sender_rx).poll_read(cx, &mut buf) {
                    Poll::Pending => {
                        read_waited.set(true);
                        Poll::Pending
                    }
                    Poll::Ready(r) => Poll::Ready(r.map(|()| buf.filled().len())),
                }
            }), if reading => match r {
                Ok(n) if n > 0 => {
                    heard_sender = true;
                    proxy.from_sender(&from_sender[..n], now());
                }
                // No sender has the port open (EIO on the master) or it just closed.
                _ => {
                    read_failures += 1;
                    if heard_sender || sender_seen {
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

async fn lost(
    proxy: &mut Proxy<'_>,
    sender: &mut (impl tokio::io::AsyncWrite + Unpin),
    mut outbox: Vec<u8>,
    why: String,
) -> Ending {
    let lines = proxy.controller_lost(&why);
    outbox.extend_from_slice(&proxy.take_to_sender());
    let _ = tokio::time::timeout(LAST_WORDS, sender.write_all(&outbox)).await;
    Ending::ControllerLost { why, lines }
}

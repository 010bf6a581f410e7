//! The DNC controller on a pseudo-terminal. The port layer judges the sender as the
//! device's overrun rule asks (`DncDevice::sender_progress`): characters written in all
//! are those the device took plus those waiting on the master side
//! (`bytes_to_read` of the master), and the sender has read the controller's DC3 when
//! nothing the controller sent waits on the slave side (`bytes_to_read` of the slave,
//! which the runner holds open).
//!
//! The operator's panel is [`DncPty::reset`] and [`DncPty::cycle_start`]; the counters
//! are watched through [`DncPty::wait_for`] (no polling on wall time).

use super::device::{DncDevice, DncStats};
use crate::pty::PtyPort;
use std::io;
use std::path::Path;
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::{mpsc, oneshot, watch};
use tokio_serial::{SerialPort, SerialStream};

/// A button on the controller's panel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Panel {
    Reset,
    CycleStart,
}

/// A running controller on a pseudo-terminal.
pub struct DncPty {
    port: PtyPort,
    stats: watch::Receiver<DncStats>,
    panel: mpsc::UnboundedSender<Panel>,
}

impl DncPty {
    /// Create a pseudo-terminal, power the controller on and serve it (inside a tokio
    /// runtime). With `link`, a symlink to the slave path is made there.
    pub fn spawn(device: DncDevice, link: Option<&Path>) -> io::Result<DncPty> {
        let (tx, rx) = watch::channel(device.stats().clone());
        let (panel, panel_rx) = mpsc::unbounded_channel();
        let port = PtyPort::spawn(link, move |master, slave, stop| {
            serve(device, master, slave, stop, tx, panel_rx)
        })?;
        Ok(DncPty {
            port,
            stats: rx,
            panel,
        })
    }

    /// The slave path (`/dev/pts/N`) senders open.
    pub fn path(&self) -> &str {
        self.port.path()
    }

    pub fn link(&self) -> Option<&Path> {
        self.port.link()
    }

    pub fn stats(&self) -> DncStats {
        self.stats.borrow().clone()
    }

    /// Wait until the counters satisfy `done` (or the controller has ended).
    /// The counters as they change (for a task that waits on them while the test
    /// holds the controller).
    pub fn watch(&self) -> watch::Receiver<DncStats> {
        self.stats.clone()
    }

    pub async fn wait_for(&mut self, done: impl Fn(&DncStats) -> bool) -> DncStats {
        let seen = self.stats.wait_for(|s| done(s)).await.map(|s| s.clone());
        seen.unwrap_or_else(|_| self.stats.borrow().clone())
    }

    /// The operator presses reset.
    pub fn reset(&self) {
        let _ = self.panel.send(Panel::Reset);
    }

    /// The operator presses cycle start.
    pub fn cycle_start(&self) {
        let _ = self.panel.send(Panel::CycleStart);
    }

    /// Wait until the runner ends (or is stopped).
    pub async fn closed(&mut self) {
        self.port.closed().await
    }

    pub async fn hang_up(self) {
        self.port.hang_up().await
    }
}

async fn serve(
    mut dev: DncDevice,
    mut master: SerialStream,
    slave: SerialStream,
    mut stop: oneshot::Receiver<()>,
    stats: watch::Sender<DncStats>,
    mut panel: mpsc::UnboundedReceiver<Panel>,
) {
    let t0 = Instant::now();
    let now = move || t0.elapsed().as_secs_f64();
    dev.power_on(now());
    let mut buf = vec![0u8; 4096];
    let mut taken: u64 = 0;
    // Motion runs on the scaled clock and the sender is watched this often.
    let mut tick = tokio::time::interval(Duration::from_millis(2));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    loop {
        let out = dev.take_output();
        if !out.is_empty() && master.write_all(&out).await.is_err() {
            break;
        }
        let waiting = master.bytes_to_read().unwrap_or(0) as u64;
        let unread = slave.bytes_to_read().unwrap_or(0) as u64;
        dev.sender_progress(taken + waiting, unread);
        let out = dev.take_output();
        if !out.is_empty() && master.write_all(&out).await.is_err() {
            break;
        }
        if *stats.borrow() != *dev.stats() {
            stats.send_replace(dev.stats().clone());
        }
        let room = dev.room().min(buf.len());
        tokio::select! {
            r = master.read(&mut buf[..room]), if room > 0 => match r {
                Ok(0) => break,
                Ok(n) => {
                    taken += n as u64;
                    dev.receive(&buf[..n], now());
                }
                Err(_) => break,
            },
            _ = tick.tick() => dev.poll(now()),
            Some(p) = panel.recv() => match p {
                Panel::Reset => dev.reset(),
                Panel::CycleStart => dev.cycle_start(),
            },
            _ = &mut stop => break,
        }
    }
    drop(master);
    drop(slave);
}

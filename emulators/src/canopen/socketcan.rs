//! The drive nodes on a Linux SocketCAN interface (`vcan0`, `can0`): every frame on
//! the interface reaches the nodes, and theirs go out on it, so any SocketCAN master
//! on the same interface (the gateway's driver, `candump`, python-can's `socketcan`)
//! talks to them as to drives on a real bus.
//!
//! A set serves one attachment at a time: this, or the SLCAN pseudo-terminal.

use super::pty::SharedSet;
use protocol::can::{CanFrame, CanId};
use socketcan::{EmbeddedFrame, ExtendedId, Id, StandardId};
use std::io;
use std::time::{Duration, Instant};
use tokio::sync::oneshot;
use tokio::task::JoinHandle;
use world::lock;

/// The drive set served on a SocketCAN interface.
pub struct SocketCanPort {
    interface: String,
    stop: Option<oneshot::Sender<()>>,
    task: Option<JoinHandle<()>>,
}

impl SocketCanPort {
    /// Open `interface` and serve `set` on it (inside a tokio runtime). Fails where the
    /// kernel has no CAN support or the interface does not exist.
    pub fn spawn(set: SharedSet, interface: &str) -> io::Result<SocketCanPort> {
        let socket = socketcan::tokio::CanSocket::open(interface)?;
        let (tx, rx) = oneshot::channel();
        let task = tokio::spawn(serve(set, socket, rx));
        Ok(SocketCanPort {
            interface: interface.to_string(),
            stop: Some(tx),
            task: Some(task),
        })
    }

    pub fn interface(&self) -> &str {
        &self.interface
    }

    /// Wait until the runner ends (it serves until stopped or the socket fails).
    pub async fn closed(&mut self) {
        if let Some(t) = self.task.take() {
            let _ = t.await;
        }
    }
}

impl Drop for SocketCanPort {
    fn drop(&mut self) {
        if let Some(tx) = self.stop.take() {
            let _ = tx.send(());
        }
    }
}

fn to_socketcan(f: &CanFrame) -> Option<socketcan::CanFrame> {
    let id: Id = match f.id() {
        CanId::Standard(i) => StandardId::new(i)?.into(),
        CanId::Extended(i) => ExtendedId::new(i)?.into(),
    };
    if f.is_remote() {
        socketcan::CanFrame::new_remote(id, usize::from(f.dlc()))
    } else {
        socketcan::CanFrame::new(id, f.data())
    }
}

fn from_socketcan(f: &socketcan::CanFrame) -> Option<CanFrame> {
    let id = match f.id() {
        Id::Standard(i) => CanId::Standard(i.as_raw()),
        Id::Extended(i) => CanId::Extended(i.as_raw()),
    };
    match f {
        socketcan::CanFrame::Data(_) => CanFrame::new(id, f.data()).ok(),
        socketcan::CanFrame::Remote(_) => CanFrame::remote(id, f.dlc() as u8).ok(),
        socketcan::CanFrame::Error(_) => None,
    }
}

async fn serve(
    set: SharedSet,
    socket: socketcan::tokio::CanSocket,
    mut stop: oneshot::Receiver<()>,
) {
    let t0 = Instant::now();
    let now = move || t0.elapsed().as_secs_f64();
    let mut tick = tokio::time::interval(Duration::from_millis(2));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    loop {
        let (out, deadline, needs_tick) = {
            let mut s = lock(&set);
            (s.take_output(), s.next_deadline(), s.needs_tick())
        };
        for f in out.iter().filter_map(to_socketcan) {
            if socket.write_frame(f).await.is_err() {
                return;
            }
        }
        let wake = deadline.map(|d| {
            tokio::time::Instant::from_std(t0 + Duration::from_secs_f64(d.clamp(0.0, 1e6)))
        });
        tokio::select! {
            r = socket.read_frame() => match r {
                Ok(f) => {
                    if let Some(f) = from_socketcan(&f) {
                        lock(&set).receive(&f, now());
                    }
                }
                Err(_) => return,
            },
            _ = async { tokio::time::sleep_until(wake.expect("guarded")).await }, if wake.is_some() => lock(&set).poll(now()),
            _ = tick.tick(), if needs_tick => lock(&set).poll(now()),
            _ = &mut stop => return,
        }
    }
}

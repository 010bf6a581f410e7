//! The drive nodes behind an emulated SLCAN USB adapter on a real pseudo-terminal: any
//! program that opens the printed `/dev/pts/N` path (python-can's `slcan` interface,
//! `slcand`, the gateway's driver) talks to it exactly as to a Lawicel-style adapter
//! plugged into a CAN bus with the drives on it.
//!
//! The adapter answers every command (CR, BEL, `z`/`Z`, `F`, `V`, `N`), forwards
//! frames only while its channel is open, appends millisecond timestamps after `Z1`,
//! and answers malformed lines with BEL (counted, never fatal).

use super::drives::DriveSet;
use crate::pty::PtyPort;
use protocol::can::CanFrame;
use protocol::slcan::{Command, CommandDecoder, Message};
use std::io;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::oneshot;
use tokio_serial::SerialStream;
use world::lock;

/// The drive set, shared between the serving task and the test or binary around it.
pub type SharedSet = Arc<Mutex<DriveSet>>;

/// Adapter-side SLCAN state, sans-IO.
#[derive(Debug, Default)]
pub struct SlcanAdapter {
    open: bool,
    listen_only: bool,
    bitrate: Option<u8>,
    timestamps: bool,
    decoder: CommandDecoder,
    /// Frames the host sent while the channel was open.
    pub frames_from_host: u64,
    /// Commands refused with BEL (malformed, or not valid in the channel's state).
    pub refused: u64,
}

impl SlcanAdapter {
    pub fn is_open(&self) -> bool {
        self.open
    }

    pub fn bitrate_code(&self) -> Option<u8> {
        self.bitrate
    }

    /// Bytes from the host: frames for the bus go to `to_bus`, answers to `reply`.
    pub fn host_bytes(&mut self, bytes: &[u8], to_bus: &mut Vec<CanFrame>, reply: &mut Vec<u8>) {
        let mut cmds = Vec::new();
        self.decoder.feed(bytes, &mut cmds);
        for c in cmds {
            let ok = match c {
                Err(_) => false,
                Ok(Command::Open) | Ok(Command::ListenOnly) if self.open => false,
                Ok(Command::Open) => {
                    self.open = true;
                    self.listen_only = false;
                    true
                }
                Ok(Command::ListenOnly) => {
                    self.open = true;
                    self.listen_only = true;
                    true
                }
                // Closing a closed channel is accepted (python-can and slcand send `C`
                // first, whatever the state).
                Ok(Command::Close) => {
                    self.open = false;
                    true
                }
                Ok(Command::Bitrate(_)) | Ok(Command::BitTiming(..)) if self.open => false,
                Ok(Command::Bitrate(n)) => {
                    self.bitrate = Some(n);
                    true
                }
                Ok(Command::BitTiming(..)) => {
                    self.bitrate = None;
                    true
                }
                Ok(Command::Transmit(f)) => {
                    if self.open && !self.listen_only {
                        to_bus.push(f);
                        self.frames_from_host += 1;
                        reply.extend(
                            Message::Transmitted {
                                extended: f.id().is_extended(),
                            }
                            .encode(),
                        );
                        continue;
                    }
                    false
                }
                Ok(Command::Status) => {
                    if self.open {
                        reply.extend(Message::Status(0).encode());
                        continue;
                    }
                    false
                }
                Ok(Command::Version) => {
                    reply.extend(
                        Message::Version {
                            hardware: 0x10,
                            software: 0x12,
                        }
                        .encode(),
                    );
                    continue;
                }
                Ok(Command::Serial) => {
                    reply.extend(Message::Serial("EMU1".into()).encode());
                    continue;
                }
                Ok(Command::Timestamps(on)) => {
                    self.timestamps = on;
                    true
                }
                Ok(Command::AcceptanceCode(_)) | Ok(Command::AcceptanceMask(_)) => true,
            };
            if ok {
                reply.extend(Message::Ok.encode());
            } else {
                self.refused += 1;
                reply.extend(Message::Error.encode());
            }
        }
    }

    /// A frame seen on the bus at `now_ms` (adapter clock): forwarded if open.
    pub fn bus_frame(&self, frame: &CanFrame, now_ms: u64, out: &mut Vec<u8>) {
        if self.open {
            let timestamp_ms = self.timestamps.then_some((now_ms % 60_000) as u16);
            out.extend(
                Message::Frame {
                    frame: *frame,
                    timestamp_ms,
                }
                .encode(),
            );
        }
    }
}

/// Counters of a running adapter.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct AdapterStats {
    pub frames_from_host: u64,
    pub refused: u64,
    pub open: bool,
}

/// A running SLCAN adapter with drives behind it, on a pseudo-terminal.
pub struct SlcanPty {
    port: PtyPort,
    set: SharedSet,
    stats: Arc<Mutex<AdapterStats>>,
}

impl SlcanPty {
    /// Create the pseudo-terminal and serve `set` on it (inside a tokio runtime). With
    /// `link`, a symlink to the slave path is made there. `set` should have been made
    /// with `now = 0`: the adapter's clock starts at spawn.
    pub fn spawn(set: SharedSet, link: Option<&Path>) -> io::Result<SlcanPty> {
        let stats = Arc::new(Mutex::new(AdapterStats::default()));
        let (drives, counters) = (set.clone(), stats.clone());
        let port = PtyPort::spawn(link, move |master, slave, stop| {
            serve(drives, master, slave, stop, counters)
        })?;
        Ok(SlcanPty { port, set, stats })
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

    /// The drives (for fault injection and inspection).
    pub fn set(&self) -> &SharedSet {
        &self.set
    }

    pub fn adapter_stats(&self) -> AdapterStats {
        self.stats.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }

    /// Wait until the runner ends (it serves until stopped or the port fails).
    pub async fn closed(&mut self) {
        self.port.closed().await
    }
}

async fn serve(
    set: SharedSet,
    mut master: SerialStream,
    slave: SerialStream,
    mut stop: oneshot::Receiver<()>,
    stats: Arc<Mutex<AdapterStats>>,
) {
    let t0 = Instant::now();
    let now = move || t0.elapsed().as_secs_f64();
    let mut adapter = SlcanAdapter::default();
    let mut buf = [0u8; 4096];
    let mut reply = Vec::new();
    // While something moves on a scaled clock, the drives are polled this often.
    let mut tick = tokio::time::interval(Duration::from_millis(2));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    loop {
        let (deadline, needs_tick) = {
            let mut s = lock(&set);
            let ms = (now() * 1000.0) as u64;
            for f in s.take_output() {
                adapter.bus_frame(&f, ms, &mut reply);
            }
            (s.next_deadline(), s.needs_tick())
        };
        if !reply.is_empty() {
            if master.write_all(&reply).await.is_err() {
                break;
            }
            reply.clear();
        }
        {
            let mut st = stats.lock().unwrap_or_else(|p| p.into_inner());
            st.frames_from_host = adapter.frames_from_host;
            st.refused = adapter.refused;
            st.open = adapter.is_open();
        }
        let wake = deadline.map(|d| {
            tokio::time::Instant::from_std(t0 + Duration::from_secs_f64(d.clamp(0.0, 1e6)))
        });
        tokio::select! {
            r = master.read(&mut buf) => match r {
                Ok(0) => break,
                Ok(n) => {
                    let mut frames = Vec::new();
                    adapter.host_bytes(&buf[..n], &mut frames, &mut reply);
                    let mut s = lock(&set);
                    for f in &frames {
                        s.receive(f, now());
                    }
                }
                Err(_) => break,
            },
            _ = async { tokio::time::sleep_until(wake.expect("guarded")).await }, if wake.is_some() => lock(&set).poll(now()),
            _ = tick.tick(), if needs_tick => lock(&set).poll(now()),
            _ = &mut stop => break,
        }
    }
    drop(master);
    drop(slave);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn adapter_answers_like_a_lawicel_adapter() {
        let mut a = SlcanAdapter::default();
        let (mut bus, mut reply) = (Vec::new(), Vec::new());
        a.host_bytes(
            b"C\rS8\rt6010\rO\rS6\rV\rF\rt60124000\rX\r",
            &mut bus,
            &mut reply,
        );
        assert_eq!(reply, b"\r\r\x07\r\x07V1012\rF00\rz\r\x07");
        assert_eq!(bus, vec![CanFrame::std(0x601, &[0x40, 0x00])]);
        assert_eq!(a.refused, 3);
        assert_eq!(a.bitrate_code(), Some(8));
        let mut out = Vec::new();
        a.bus_frame(&CanFrame::std(0x701, &[0x7F]), 61_000, &mut out);
        assert_eq!(out, b"t70117F\r");
        a.host_bytes(b"Z1\r", &mut bus, &mut reply);
        out.clear();
        a.bus_frame(&CanFrame::std(0x701, &[0x7F]), 61_000, &mut out);
        assert_eq!(out, b"t70117F03E8\r");
    }
}

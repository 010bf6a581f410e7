//! Serving the emulated drives on real links: Modbus TCP on a socket (port 0 for a
//! free one) and Modbus RTU on a pseudo-terminal, with this crate's own framing so that
//! faults can be injected into exactly the reply a test names.
//!
//! * TCP: MBAP framing; a request for a unit not served is answered with exception
//!   0x0B (gateway target device failed to respond), as a TCP-to-RTU gateway does;
//!   unit 0 and 255 address the only unit when exactly one is served. Each connection
//!   is served in order; connections are independent.
//! * RTU: frames are delimited by their function code's length and checked by CRC;
//!   a frame with a bad CRC is dropped (the sender times out, as on a real line),
//!   bytes that start no frame are skipped one by one, and a partial frame followed by
//!   silence is discarded. Several unit ids share the line; other ids are ignored,
//!   broadcasts (unit 0) are executed and never answered.
//! * Faults ([`FaultRule`]): drop a reply (the request was executed), corrupt it (RTU:
//!   a flipped CRC bit; TCP: a wrong transaction id), or send it late.

use super::device::{DriveSet, ModbusStats};
use crate::pty::PtyPort;
use protocol::modbus::frame::{rtu_crc_ok, rtu_frame, rtu_request_len, FrameLen, Mbap};
use std::io;
use std::net::SocketAddr;
use std::path::Path;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::oneshot;
use tokio::task::JoinHandle;
use tokio_serial::SerialStream;

/// What a fault does to a reply.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Fault {
    /// Lose the request on its way: not executed, not answered.
    DropRequest,
    /// Execute the request, send nothing.
    DropReply,
    /// Execute, send a reply the client must reject (RTU: bad CRC; TCP: another
    /// transaction id).
    CorruptReply,
    /// Execute, send the reply after this long.
    SlowReply(Duration),
}

/// When a fault applies: to every `every`-th request matching `function` (any if
/// `None`), at most `times` times (unlimited if `None`).
#[derive(Clone, Debug, PartialEq)]
pub struct FaultRule {
    pub fault: Fault,
    pub function: Option<u8>,
    pub every: u64,
    pub times: Option<u64>,
    seen: u64,
    applied: u64,
}

impl FaultRule {
    pub fn new(fault: Fault) -> Self {
        Self {
            fault,
            function: None,
            every: 1,
            times: None,
            seen: 0,
            applied: 0,
        }
    }

    /// Only requests with this function code.
    pub fn on_function(mut self, f: u8) -> Self {
        self.function = Some(f);
        self
    }

    pub fn every(mut self, n: u64) -> Self {
        self.every = n.max(1);
        self
    }

    pub fn times(mut self, n: u64) -> Self {
        self.times = Some(n);
        self
    }

    fn decide(&mut self, function: u8) -> Option<Fault> {
        if self.function.is_some_and(|f| f != function)
            || self.times.is_some_and(|t| self.applied >= t)
        {
            return None;
        }
        self.seen += 1;
        if self.seen.is_multiple_of(self.every) {
            self.applied += 1;
            Some(self.fault)
        } else {
            None
        }
    }
}

/// The drives plus the faults to inject, shared by every server of a process.
pub struct ModbusDevice {
    set: Mutex<DriveSet>,
    faults: Mutex<Vec<FaultRule>>,
    t0: Instant,
}

impl ModbusDevice {
    pub fn new(set: DriveSet) -> Arc<Self> {
        Arc::new(Self {
            set: Mutex::new(set),
            faults: Mutex::new(Vec::new()),
            t0: Instant::now(),
        })
    }

    pub fn drives(&self) -> MutexGuard<'_, DriveSet> {
        self.set.lock().unwrap_or_else(|p| p.into_inner())
    }

    pub fn stats(&self) -> ModbusStats {
        self.drives().stats().clone()
    }

    /// Replace the fault rules (takes effect from the next request).
    pub fn set_faults(&self, rules: Vec<FaultRule>) {
        *self.faults.lock().unwrap_or_else(|p| p.into_inner()) = rules;
    }

    /// Execute one request; the reply PDU and the fault to apply to it.
    fn serve(&self, unit: u8, pdu: &[u8]) -> Option<(Vec<u8>, Option<Fault>)> {
        let now = self.t0.elapsed().as_secs_f64();
        let mut set = self.drives();
        if !set.serves(unit) && unit != 0 {
            return None;
        }
        let function = pdu.first().copied().unwrap_or(0);
        let fault = {
            let mut rules = self.faults.lock().unwrap_or_else(|p| p.into_inner());
            rules.iter_mut().find_map(|r| r.decide(function))
        };
        if fault.is_some() {
            set.stats_mut().faults_applied += 1;
        }
        if fault == Some(Fault::DropRequest) {
            return None;
        }
        let reply = set.handle(unit, pdu, now)?;
        Some((reply, fault))
    }
}

/// A Modbus TCP server on a socket.
pub struct ModbusTcp {
    addr: SocketAddr,
    stop: Option<oneshot::Sender<()>>,
    task: Option<JoinHandle<()>>,
}

impl ModbusTcp {
    /// Listen on `bind` (port 0: any free port) and serve until dropped. Inside a
    /// tokio runtime.
    pub async fn bind(device: Arc<ModbusDevice>, bind: SocketAddr) -> io::Result<ModbusTcp> {
        let listener = TcpListener::bind(bind).await?;
        let addr = listener.local_addr()?;
        let (tx, mut rx) = oneshot::channel::<()>();
        let task = tokio::spawn(async move {
            let mut conns: Vec<JoinHandle<()>> = Vec::new();
            loop {
                tokio::select! {
                    r = listener.accept() => match r {
                        Ok((s, _)) => {
                            let _ = s.set_nodelay(true);
                            conns.retain(|c| !c.is_finished());
                            conns.push(tokio::spawn(serve_tcp_connection(device.clone(), s)));
                        }
                        Err(_) => tokio::time::sleep(Duration::from_millis(5)).await,
                    },
                    _ = &mut rx => break,
                }
            }
            for c in conns {
                c.abort();
            }
        });
        Ok(ModbusTcp {
            addr,
            stop: Some(tx),
            task: Some(task),
        })
    }

    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// Stop accepting and close every connection.
    pub async fn shutdown(mut self) {
        if let Some(tx) = self.stop.take() {
            let _ = tx.send(());
        }
        if let Some(t) = self.task.take() {
            let _ = t.await;
        }
    }
}

impl Drop for ModbusTcp {
    fn drop(&mut self) {
        if let Some(tx) = self.stop.take() {
            let _ = tx.send(());
        }
    }
}

async fn serve_tcp_connection(device: Arc<ModbusDevice>, mut s: TcpStream) {
    let mut head = [0u8; Mbap::LEN];
    let mut pdu = vec![0u8; 260];
    loop {
        if s.read_exact(&mut head).await.is_err() {
            return;
        }
        let Some(h) = Mbap::parse(&head) else { return };
        // Not Modbus (protocol id) or an impossible length: the stream cannot be
        // resynchronised, so close it as servers do.
        if h.protocol != 0 || !(2..=254).contains(&h.length) {
            return;
        }
        let n = h.length as usize - 1;
        if s.read_exact(&mut pdu[..n]).await.is_err() {
            return;
        }
        let unit = {
            let set = device.drives();
            let ids = set.unit_ids();
            if (h.unit == 0 || h.unit == 0xFF) && ids.len() == 1 {
                ids[0]
            } else {
                h.unit
            }
        };
        let served = device.drives().serves(unit);
        let (reply, fault) = if served {
            match device.serve(unit, &pdu[..n]) {
                Some(r) => r,
                None => continue,
            }
        } else {
            (vec![pdu[0] | 0x80, 0x0B], None)
        };
        let mut tid = h.transaction;
        match fault {
            Some(Fault::DropReply | Fault::DropRequest) => continue,
            Some(Fault::CorruptReply) => tid = tid.wrapping_add(0x5A5A),
            Some(Fault::SlowReply(d)) => tokio::time::sleep(d).await,
            None => {}
        }
        if s.write_all(&Mbap::frame(tid, h.unit, &reply))
            .await
            .is_err()
        {
            return;
        }
    }
}

/// A Modbus RTU line on a new pseudo-terminal.
pub struct ModbusRtu {
    port: PtyPort,
}

impl ModbusRtu {
    /// Create the pseudo-terminal and serve on it (inside a tokio runtime). With
    /// `link`, a symlink to the slave path is made there (replacing an old one).
    pub fn spawn(device: Arc<ModbusDevice>, link: Option<&Path>) -> io::Result<ModbusRtu> {
        let port = PtyPort::spawn(link, move |master, slave, stop| {
            serve_rtu(device, master, slave, stop)
        })?;
        Ok(ModbusRtu { port })
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

    /// Wait until the runner ends (by itself or stopped).
    pub async fn closed(&mut self) {
        self.port.closed().await
    }
}

/// Silence after which a partial frame is discarded. Real lines use 3.5 character
/// times; a pseudo-terminal delivers a frame at once, so any pause this long means
/// the sender gave up in the middle of a frame.
const FRAME_SILENCE: Duration = Duration::from_millis(20);

async fn serve_rtu(
    device: Arc<ModbusDevice>,
    mut master: SerialStream,
    slave: SerialStream,
    mut stop: oneshot::Receiver<()>,
) {
    let mut buf: Vec<u8> = Vec::with_capacity(512);
    let mut chunk = [0u8; 512];
    loop {
        // Take every complete frame out of the buffer.
        loop {
            if buf.len() < 2 {
                break;
            }
            let n = match rtu_request_len(&buf) {
                FrameLen::NeedMore => break,
                FrameLen::Unknown => {
                    buf.remove(0);
                    continue;
                }
                FrameLen::Bytes(n) if n > 256 => {
                    buf.remove(0);
                    continue;
                }
                FrameLen::Bytes(n) => n,
            };
            if buf.len() < n {
                break;
            }
            if !rtu_crc_ok(&buf[..n]) {
                device.drives().stats_mut().crc_errors += 1;
                buf.remove(0);
                continue;
            }
            let frame: Vec<u8> = buf.drain(..n).collect();
            let unit = frame[0];
            let Some((reply, fault)) = device.serve(unit, &frame[1..n - 2]) else {
                continue;
            };
            let mut out = rtu_frame(unit, &reply);
            match fault {
                Some(Fault::DropReply | Fault::DropRequest) => continue,
                Some(Fault::CorruptReply) => {
                    let last = out.len() - 1;
                    out[last] ^= 0x01;
                }
                Some(Fault::SlowReply(d)) => tokio::time::sleep(d).await,
                None => {}
            }
            if master.write_all(&out).await.is_err() {
                return;
            }
        }
        let read = async {
            if buf.is_empty() {
                Ok(master.read(&mut chunk).await)
            } else {
                tokio::time::timeout(FRAME_SILENCE, master.read(&mut chunk)).await
            }
        };
        tokio::select! {
            r = read => match r {
                Ok(Ok(0)) | Ok(Err(_)) => break,
                Ok(Ok(n)) => buf.extend_from_slice(&chunk[..n]),
                Err(_) => buf.clear(),
            },
            _ = &mut stop => break,
        }
    }
    drop(master);
    drop(slave);
}

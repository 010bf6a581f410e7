//! A CANopen master's view of one bus: a task that owns the [`CanBus`], routes every
//! frame by COB-ID to the node it belongs to, runs one SDO client per node (requests
//! queue per node, one transfer at a time as CiA 301 allows), decodes TPDOs by the
//! mappings the axis drivers configured, keeps each node's EMCY history and heartbeat,
//! and supervises heartbeats: when a node falls silent, every node on the bus that
//! registered a stop frame is sent it at once, so the whole stage stops, and the loss
//! is reported to every caller until the node is heard again.
//!
//! Several axes share one bus, so they share one [`Network`] (it is cheap to clone).

use crate::can::{BusStats, CanBus};
use crate::error::DriverError;
use protocol::can::CanFrame;
use protocol::canopen::emcy::Emcy;
use protocol::canopen::nmt::{HeartbeatConsumer, HeartbeatLost, NmtCommand, NmtState};
use protocol::canopen::pdo::{self, MapEntry};
use protocol::canopen::sdo::{AbortCode, ClientStep, SdoClient, SdoError};
use protocol::canopen::{classify, Function, NodeId};
use std::collections::{BTreeMap, VecDeque};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;
use tokio::sync::{mpsc, oneshot, Notify};
use tokio::time::Instant;

/// What the master knows about one node.
#[derive(Clone, Debug, Default)]
pub struct NodeView {
    /// Latest value of every object received in a TPDO.
    pub values: BTreeMap<(u16, u8), Vec<u8>>,
    /// TPDOs received, per TPDO number (index 0 = TPDO1).
    pub tpdo_count: [u64; 4],
    /// The last data of each TPDO as received (values of one TPDO belong together).
    pub tpdo_data: [Option<Vec<u8>>; 4],
    /// Statuswords in the order they arrived (TPDO count at arrival, value), the last
    /// 64: a waiter sees every step, even several arriving in one read.
    pub statuswords: VecDeque<(u64, u16)>,
    /// EMCY messages received, oldest first (the last 32).
    pub emcy: VecDeque<Emcy>,
    pub emcy_count: u64,
    /// Last heartbeat state heard.
    pub nmt: Option<NmtState>,
    /// Boot-up messages heard (a node that reboots loses its PDO configuration).
    pub boot_ups: u64,
    /// Set while the node's heartbeat is lapsed.
    pub heartbeat_lost: Option<HeartbeatLost>,
}

impl NodeView {
    pub fn u16(&self, index: u16, sub: u8) -> Option<u16> {
        let v = self.values.get(&(index, sub))?;
        Some(u16::from_le_bytes([*v.first()?, *v.get(1)?]))
    }

    pub fn i32(&self, index: u16, sub: u8) -> Option<i32> {
        let v = self.values.get(&(index, sub))?;
        Some(i32::from_le_bytes(v.get(..4)?.try_into().ok()?))
    }

    pub fn i8(&self, index: u16, sub: u8) -> Option<i8> {
        Some(*self.values.get(&(index, sub))?.first()? as i8)
    }

    /// TPDOs received in all (the sequence number of [`NodeView::statuswords`]).
    pub fn tpdo_total(&self) -> u64 {
        self.tpdo_count.iter().sum()
    }

    /// Statuswords received after TPDO count `since`.
    pub fn statuswords_since(&self, since: u64) -> impl Iterator<Item = u16> + '_ {
        self.statuswords
            .iter()
            .filter(move |(k, _)| *k > since)
            .map(|(_, s)| *s)
    }

    /// The latest EMCY that reports an error (not an error reset).
    pub fn last_error(&self) -> Option<Emcy> {
        self.emcy.iter().rev().find(|e| !e.is_reset()).copied()
    }
}

/// Counters of the network.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct NetStats {
    pub bus: BusStats,
    pub sdo_transfers: u64,
    pub sdo_aborts: u64,
    pub heartbeat_losses: u64,
    pub stop_frames_sent: u64,
    /// Times the bus task found itself woken late (busy runtime) and restarted its
    /// timeout windows rather than judge them.
    pub stalls: u64,
}

#[derive(Default)]
struct NetState {
    nodes: BTreeMap<u8, NodeView>,
    /// The bus failed; every call fails with this.
    closed: Option<String>,
    stats: NetStats,
}

struct Shared {
    state: Mutex<NetState>,
    changed: Notify,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, NetState> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }
}

enum SdoOp {
    Upload,
    Download(Vec<u8>),
}

struct SdoRequest {
    index: u16,
    sub: u8,
    op: SdoOp,
    reply: oneshot::Sender<Result<Vec<u8>, DriverError>>,
}

enum Cmd {
    Send(CanFrame, oneshot::Sender<Result<(), DriverError>>),
    Sdo(NodeId, SdoRequest),
    MapTpdo {
        node: NodeId,
        n: usize,
        cob_id: u16,
        entries: Vec<MapEntry>,
    },
    StopFrame(NodeId, CanFrame),
    WatchHeartbeat(NodeId, Duration),
}

/// A handle on the bus task. Clones share the task; it ends when the last is dropped.
#[derive(Clone)]
pub struct Network {
    name: Arc<str>,
    tx: mpsc::UnboundedSender<Cmd>,
    shared: Arc<Shared>,
    pub sdo_timeout: Duration,
}

fn node_name(node: NodeId) -> String {
    format!("CANopen node {}", node.get())
}

impl Network {
    /// Start the bus task (inside a tokio runtime).
    pub fn start(bus: Box<dyn CanBus>, sdo_timeout: Duration) -> Network {
        let name: Arc<str> = bus.name().into();
        let shared = Arc::new(Shared {
            state: Mutex::new(NetState::default()),
            changed: Notify::new(),
        });
        let (tx, rx) = mpsc::unbounded_channel();
        tokio::spawn(run(bus, rx, shared.clone(), sdo_timeout));
        Network {
            name,
            tx,
            shared,
            sdo_timeout,
        }
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    fn closed_error(&self) -> DriverError {
        let why = self
            .shared
            .lock()
            .closed
            .clone()
            .unwrap_or_else(|| "the bus task has stopped".into());
        DriverError::Transport {
            device: self.name.to_string(),
            message: why,
        }
    }

    fn cmd(&self, c: Cmd) -> Result<(), DriverError> {
        self.tx.send(c).map_err(|_| self.closed_error())
    }

    /// Put a frame on the bus.
    pub async fn send(&self, frame: CanFrame) -> Result<(), DriverError> {
        let (tx, rx) = oneshot::channel();
        self.cmd(Cmd::Send(frame, tx))?;
        rx.await.map_err(|_| self.closed_error())?
    }

    pub async fn nmt(&self, cmd: NmtCommand, node: Option<NodeId>) -> Result<(), DriverError> {
        self.send(cmd.frame(node)).await
    }

    async fn sdo(
        &self,
        node: NodeId,
        index: u16,
        sub: u8,
        op: SdoOp,
    ) -> Result<Vec<u8>, DriverError> {
        let (reply, rx) = oneshot::channel();
        self.cmd(Cmd::Sdo(
            node,
            SdoRequest {
                index,
                sub,
                op,
                reply,
            },
        ))?;
        // The task answers every request (its own SDO timeout); this bound only guards
        // against a task that died with requests queued behind a long transfer.
        match tokio::time::timeout(self.sdo_timeout * 64 + Duration::from_secs(1), rx).await {
            Ok(Ok(r)) => r,
            Ok(Err(_)) => Err(self.closed_error()),
            Err(_) => Err(DriverError::Timeout {
                device: node_name(node),
                what: format!("queued SDO transfer of 0x{index:04X}:{sub:02X}"),
                after_ms: (self.sdo_timeout * 64).as_millis() as u64,
            }),
        }
    }

    /// Read an object by SDO. Aborts are [`DriverError::Refused`] with the abort code.
    pub async fn sdo_read(
        &self,
        node: NodeId,
        index: u16,
        sub: u8,
    ) -> Result<Vec<u8>, DriverError> {
        self.sdo(node, index, sub, SdoOp::Upload).await
    }

    /// Write an object by SDO. Aborts are [`DriverError::Refused`] with the abort code.
    pub async fn sdo_write(
        &self,
        node: NodeId,
        index: u16,
        sub: u8,
        data: &[u8],
    ) -> Result<(), DriverError> {
        self.sdo(node, index, sub, SdoOp::Download(data.to_vec()))
            .await
            .map(|_| ())
    }

    /// Decode TPDO `n` (1..=4) of `node`, arriving on `cob_id`, by this mapping.
    pub fn map_tpdo(
        &self,
        node: NodeId,
        n: usize,
        cob_id: u16,
        entries: Vec<MapEntry>,
    ) -> Result<(), DriverError> {
        self.cmd(Cmd::MapTpdo {
            node,
            n,
            cob_id,
            entries,
        })
    }

    /// The frame that stops `node` when any node on the bus loses its heartbeat.
    pub fn set_stop_frame(&self, node: NodeId, frame: CanFrame) -> Result<(), DriverError> {
        self.cmd(Cmd::StopFrame(node, frame))
    }

    /// Supervise `node`'s heartbeat: silent longer than `timeout` is a loss.
    pub fn watch_heartbeat(&self, node: NodeId, timeout: Duration) -> Result<(), DriverError> {
        self.cmd(Cmd::WatchHeartbeat(node, timeout))
    }

    /// Look at a node's view.
    pub fn view<R>(&self, node: NodeId, f: impl FnOnce(&NodeView) -> R) -> R {
        let s = self.shared.lock();
        match s.nodes.get(&node.get()) {
            Some(v) => f(v),
            None => f(&NodeView::default()),
        }
    }

    /// Put a value read by SDO into the process image (before any TPDO brought it).
    pub fn seed_value(&self, node: NodeId, index: u16, sub: u8, bytes: Vec<u8>) {
        let mut s = self.shared.lock();
        s.nodes
            .entry(node.get())
            .or_default()
            .values
            .entry((index, sub))
            .or_insert(bytes);
    }

    /// Put a value read by SDO into the process image, replacing what a TPDO brought
    /// (the newer of the two).
    pub fn store_value(&self, node: NodeId, index: u16, sub: u8, bytes: Vec<u8>) {
        let mut s = self.shared.lock();
        s.nodes
            .entry(node.get())
            .or_default()
            .values
            .insert((index, sub), bytes);
    }

    /// Nodes whose heartbeat is lapsed now.
    pub fn lost_nodes(&self) -> Vec<(u8, HeartbeatLost)> {
        let s = self.shared.lock();
        s.nodes
            .iter()
            .filter_map(|(k, v)| v.heartbeat_lost.clone().map(|l| (*k, l)))
            .collect()
    }

    pub fn stats(&self) -> NetStats {
        self.shared.lock().stats.clone()
    }

    /// Fail if the bus is gone.
    pub fn check_open(&self) -> Result<(), DriverError> {
        if self.shared.lock().closed.is_some() || self.tx.is_closed() {
            return Err(self.closed_error());
        }
        Ok(())
    }

    /// Wait until `f` on a node's view gives a value, or `deadline`. `Ok(None)` on
    /// timeout; an error if the bus failed meanwhile.
    pub async fn wait_for<R>(
        &self,
        node: NodeId,
        deadline: Instant,
        f: impl FnMut(&NodeView) -> Option<R>,
    ) -> Result<Option<R>, DriverError> {
        self.wait(node, deadline, false, f).await
    }

    /// As [`Network::wait_for`], also ending (`Ok(None)`) as soon as any node's
    /// heartbeat is lost.
    pub async fn wait_for_or_loss<R>(
        &self,
        node: NodeId,
        deadline: Instant,
        f: impl FnMut(&NodeView) -> Option<R>,
    ) -> Result<Option<R>, DriverError> {
        self.wait(node, deadline, true, f).await
    }

    async fn wait<R>(
        &self,
        node: NodeId,
        deadline: Instant,
        end_on_loss: bool,
        mut f: impl FnMut(&NodeView) -> Option<R>,
    ) -> Result<Option<R>, DriverError> {
        loop {
            let notified = self.shared.changed.notified();
            tokio::pin!(notified);
            notified.as_mut().enable();
            self.check_open()?;
            if let Some(r) = self.view(node, &mut f) {
                return Ok(Some(r));
            }
            if end_on_loss && !self.lost_nodes().is_empty() {
                return Ok(None);
            }
            if tokio::time::timeout_at(deadline, notified).await.is_err() {
                return Ok(None);
            }
        }
    }
}

struct SdoChannel {
    client: SdoClient,
    current: Option<SdoRequest>,
    queue: VecDeque<SdoRequest>,
}

struct Task {
    bus: Box<dyn CanBus>,
    shared: Arc<Shared>,
    t0: Instant,
    sdo_timeout: Duration,
    sdo: BTreeMap<u8, SdoChannel>,
    tpdo_maps: BTreeMap<u16, (NodeId, usize, Vec<MapEntry>)>,
    stop_frames: BTreeMap<u8, CanFrame>,
    heartbeats: HeartbeatConsumer,
}

async fn run(
    bus: Box<dyn CanBus>,
    mut rx: mpsc::UnboundedReceiver<Cmd>,
    shared: Arc<Shared>,
    sdo_timeout: Duration,
) {
    let mut t = Task {
        bus,
        shared,
        t0: Instant::now(),
        sdo_timeout,
        sdo: BTreeMap::new(),
        tpdo_maps: BTreeMap::new(),
        stop_frames: BTreeMap::new(),
        heartbeats: HeartbeatConsumer::new(),
    };
    let failure = loop {
        let sdo_busy = t.sdo.values().any(|c| c.current.is_some());
        let hb = t
            .heartbeats
            .next_deadline()
            .map(|d| t.t0 + Duration::from_secs_f64(d.max(0.0)));
        let poll_at = if sdo_busy {
            Some(Instant::now() + Duration::from_millis(5))
        } else {
            None
        };
        let wake = [hb, poll_at].into_iter().flatten().min();
        let r = tokio::select! {
            // Frames first: a backlog that arrived while the task was not scheduled
            // is read before any timeout is judged.
            biased;
            f = t.bus.recv() => match f {
                Ok(frame) => t.route(frame).await,
                Err(e) => Err(e),
            },
            c = rx.recv() => match c {
                Some(c) => t.command(c).await,
                None => break None,
            },
            _ = async { tokio::time::sleep_until(wake.expect("guarded")).await }, if wake.is_some() => {
                t.timers(wake.expect("guarded")).await
            }
        };
        t.publish_stats();
        if let Err(e) = r {
            break Some(e);
        }
    };
    if let Some(e) = failure {
        let message = match &e {
            DriverError::Transport { message, .. } => message.clone(),
            other => other.to_string(),
        };
        t.shared.lock().closed = Some(message);
        // Every waiting caller learns at once.
        for ch in t.sdo.values_mut() {
            for r in ch.current.take().into_iter().chain(ch.queue.drain(..)) {
                let _ = r.reply.send(Err(DriverError::Transport {
                    device: t.bus.name().to_string(),
                    message: e.to_string(),
                }));
            }
        }
        t.shared.changed.notify_waiters();
        // Answer what is still sent to us until every handle is gone.
        while let Some(c) = rx.recv().await {
            let err = || DriverError::Transport {
                device: t.bus.name().to_string(),
                message: e.to_string(),
            };
            match c {
                Cmd::Send(_, reply) => {
                    let _ = reply.send(Err(err()));
                }
                Cmd::Sdo(_, r) => {
                    let _ = r.reply.send(Err(err()));
                }
                _ => {}
            }
        }
    }
}

impl Task {
    fn now(&self) -> f64 {
        self.t0.elapsed().as_secs_f64()
    }

    fn publish_stats(&mut self) {
        let bus = self.bus.stats();
        self.shared.lock().stats.bus = bus;
    }

    async fn command(&mut self, c: Cmd) -> Result<(), DriverError> {
        match c {
            Cmd::Send(f, reply) => {
                let r = self.bus.send(&f).await;
                let failed = r.as_ref().err().map(ToString::to_string);
                let _ = reply.send(r);
                if let Some(m) = failed {
                    return Err(DriverError::Transport {
                        device: self.bus.name().to_string(),
                        message: m,
                    });
                }
            }
            Cmd::Sdo(node, req) => {
                let timeout = self.sdo_timeout.as_secs_f64();
                let ch = self.sdo.entry(node.get()).or_insert_with(|| SdoChannel {
                    client: SdoClient::new(node, timeout),
                    current: None,
                    queue: VecDeque::new(),
                });
                ch.queue.push_back(req);
                self.start_next_sdo(node).await?;
            }
            Cmd::MapTpdo {
                node,
                n,
                cob_id,
                entries,
            } => {
                self.tpdo_maps
                    .retain(|_, (nd, k, _)| !(*nd == node && *k == n));
                self.tpdo_maps.insert(cob_id, (node, n, entries));
            }
            Cmd::StopFrame(node, f) => {
                self.stop_frames.insert(node.get(), f);
            }
            Cmd::WatchHeartbeat(node, timeout) => {
                let now = self.now();
                self.heartbeats.watch(node, timeout.as_secs_f64(), now);
                let mut s = self.shared.lock();
                s.nodes.entry(node.get()).or_default().heartbeat_lost = None;
            }
        }
        Ok(())
    }

    async fn start_next_sdo(&mut self, node: NodeId) -> Result<(), DriverError> {
        let now = self.now();
        let Some(ch) = self.sdo.get_mut(&node.get()) else {
            return Ok(());
        };
        if ch.current.is_some() {
            return Ok(());
        }
        let Some(req) = ch.queue.pop_front() else {
            return Ok(());
        };
        let frame = match &req.op {
            SdoOp::Upload => ch.client.upload(req.index, req.sub, now),
            SdoOp::Download(d) => ch.client.download(req.index, req.sub, d, now),
        };
        ch.current = Some(req);
        self.bus.send(&frame).await
    }

    async fn finish_sdo(&mut self, node: NodeId, step: ClientStep) -> Result<(), DriverError> {
        let result = match step {
            ClientStep::Send(f) => return self.bus.send(&f).await,
            ClientStep::Ignored => return Ok(()),
            ClientStep::Uploaded(v) => Ok(v),
            ClientStep::Downloaded => Ok(Vec::new()),
            ClientStep::Failed { error, send } => {
                if let Some(f) = send {
                    self.bus.send(&f).await?;
                }
                self.shared.lock().stats.sdo_aborts += 1;
                Err(sdo_error(node, &error, self.sdo_timeout))
            }
        };
        let Some(ch) = self.sdo.get_mut(&node.get()) else {
            return Ok(());
        };
        if let Some(req) = ch.current.take() {
            let _ = req.reply.send(result);
        }
        self.shared.lock().stats.sdo_transfers += 1;
        self.start_next_sdo(node).await
    }

    async fn timers(&mut self, scheduled: Instant) -> Result<(), DriverError> {
        let now = self.now();
        // Woken much later than asked: this task (or the whole runtime) was busy, so
        // silence and missing answers may be ours. Restart the windows instead of
        // judging them; a node that is really gone is found one timeout later.
        let late = Instant::now()
            .saturating_duration_since(scheduled)
            .as_secs_f64();
        let threshold = self
            .heartbeats
            .min_timeout()
            .map_or(0.05, |t| (t / 4.0).max(0.02));
        if late > threshold {
            self.heartbeats.restart_windows(now);
            for ch in self.sdo.values_mut() {
                ch.client.extend(now);
            }
            self.shared.lock().stats.stalls += 1;
            return Ok(());
        }
        let nodes: Vec<u8> = self.sdo.keys().copied().collect();
        for k in nodes {
            let step = self.sdo.get_mut(&k).and_then(|ch| ch.client.poll(now));
            if let Some(step) = step {
                self.finish_sdo(NodeId::new(k).expect("node ids are valid"), step)
                    .await?;
            }
        }
        let mut lost = self.heartbeats.check(now);
        if !lost.is_empty() {
            self.confirm_silence().await?;
            lost.retain(|l| self.heartbeats.is_lost(l.node));
        }
        if !lost.is_empty() {
            {
                let mut s = self.shared.lock();
                for l in &lost {
                    s.stats.heartbeat_losses += 1;
                    s.nodes.entry(l.node.get()).or_default().heartbeat_lost = Some(l.clone());
                }
            }
            // Stop everything on the bus: a stage with a dead axis must not go on moving.
            let frames: Vec<CanFrame> = self.stop_frames.values().copied().collect();
            for f in frames {
                self.bus.send(&f).await?;
                self.shared.lock().stats.stop_frames_sent += 1;
            }
            self.shared.changed.notify_waiters();
        }
        Ok(())
    }

    /// Before a lapse is declared: stay responsive for a short quiet period, reading
    /// the bus and letting every other task run. A heartbeat that was only waiting for
    /// this task (or for the producer's task, in-process) to be scheduled is heard now,
    /// and clears the lapse; a node that is really gone stays silent.
    async fn confirm_silence(&mut self) -> Result<(), DriverError> {
        const STEP: Duration = Duration::from_millis(5);
        let mut quiet = 0;
        // Bounded: at most 300 rounds (1.5 s of 5 ms sleeps, more if the task is starved).
        for _ in 0..300 {
            if quiet >= 10 {
                break;
            }
            let t = Instant::now();
            tokio::select! {
                biased;
                f = self.bus.recv() => self.route(f?).await?,
                _ = tokio::time::sleep(STEP) => {
                    // Only a sleep that ended on time shows we were being scheduled.
                    quiet = if t.elapsed() < STEP + Duration::from_millis(10) { quiet + 1 } else { 0 };
                }
            }
        }
        Ok(())
    }

    async fn route(&mut self, frame: CanFrame) -> Result<(), DriverError> {
        let Some(id) = frame.id().as_standard() else {
            return Ok(());
        };
        let now = self.now();
        match classify(id) {
            Function::SdoTx(node) if !frame.is_remote() => {
                let step = self
                    .sdo
                    .get_mut(&node.get())
                    .map(|ch| ch.client.on_response(frame.data(), now));
                if let Some(step) = step {
                    self.finish_sdo(node, step).await?;
                }
            }
            Function::Heartbeat(node) => {
                let heard = self.heartbeats.on_frame(&frame, now);
                if let Some((_, state)) = protocol::canopen::nmt::parse_heartbeat(&frame) {
                    let mut s = self.shared.lock();
                    let v = s.nodes.entry(node.get()).or_default();
                    v.nmt = Some(state);
                    if state == NmtState::BootUp {
                        v.boot_ups += 1;
                    }
                    if heard.is_some() {
                        v.heartbeat_lost = None;
                    }
                }
            }
            Function::Emcy(node) => {
                if let Some((_, e)) = Emcy::parse(&frame) {
                    let mut s = self.shared.lock();
                    let v = s.nodes.entry(node.get()).or_default();
                    v.emcy.push_back(e);
                    v.emcy_count += 1;
                    while v.emcy.len() > 32 {
                        v.emcy.pop_front();
                    }
                }
            }
            _ => {
                if let Some((node, n, entries)) = self.tpdo_maps.get(&id) {
                    if let Ok(parts) = pdo::unpack(entries, frame.data()) {
                        let mut s = self.shared.lock();
                        let v = s.nodes.entry(node.get()).or_default();
                        for (e, bytes) in parts {
                            v.values.insert((e.index, e.sub), bytes.to_vec());
                        }
                        v.tpdo_count[n - 1] += 1;
                        v.tpdo_data[n - 1] = Some(frame.data().to_vec());
                        if let Some(sw) = v
                            .u16(0x6041, 0)
                            .filter(|_| entries.iter().any(|e| e.index == 0x6041))
                        {
                            let seq = v.tpdo_count.iter().sum();
                            v.statuswords.push_back((seq, sw));
                            while v.statuswords.len() > 64 {
                                v.statuswords.pop_front();
                            }
                        }
                    }
                }
            }
        }
        self.shared.changed.notify_waiters();
        Ok(())
    }
}

fn sdo_error(node: NodeId, e: &SdoError, timeout: Duration) -> DriverError {
    let (index, sub, code, server) = match e {
        SdoError::Aborted { index, sub, code } => (*index, *sub, *code, true),
        SdoError::ClientAbort { index, sub, code } => (*index, *sub, *code, false),
    };
    let what = format!("SDO access to 0x{index:04X}:{sub:02X}");
    if !server && code == AbortCode::TIMEOUT {
        return DriverError::Timeout {
            device: node_name(node),
            what,
            after_ms: timeout.as_millis() as u64,
        };
    }
    if server {
        DriverError::Refused {
            device: node_name(node),
            what,
            code: code.0,
            message: code.description().to_string(),
        }
    } else {
        DriverError::Protocol {
            device: node_name(node),
            message: format!("{what}: aborted by the master: {code}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sdo_aborts_show_the_code_in_hex_with_the_standards_name() {
        let node = NodeId::new(3).unwrap();
        let e = SdoError::Aborted {
            index: 0x6060,
            sub: 0,
            code: AbortCode::NO_OBJECT,
        };
        let m = sdo_error(node, &e, Duration::from_millis(100)).to_string();
        assert_eq!(
            m,
            "CANopen node 3 refused SDO access to 0x6060:00: code 0x06020000: \
             object does not exist in the object dictionary"
        );
        let e = SdoError::Aborted {
            index: 0x607A,
            sub: 0,
            code: AbortCode::VALUE_TOO_HIGH,
        };
        let m = sdo_error(node, &e, Duration::from_millis(100)).to_string();
        assert!(
            m.contains("code 0x06090031: value of parameter written too high"),
            "{m}"
        );
    }
}

//! The MQTT northbound of `gateway serve`: the box as a Sparkplug B edge node.
//!
//! One edge node (`[mqtt] edge_node_id`) in one group (`group_id`); one device per
//! machine (its id). Per MQTT session:
//!
//! 1. a new bdSeq (the store's setting `sparkplug.bdseq`, one more than the last, 255
//!    wraps to 0, so a restart continues the sequence) and the NDEATH will carrying it
//!    (QoS 1, not retained) in the CONNECT; clean session;
//! 2. on the CONNACK: subscribe to the node's NCMD topic; NBIRTH (seq 0, QoS 0, metrics
//!    `bdSeq`, `Node Control/Rebirth` = false, `Properties/...`); one DBIRTH per machine
//!    (its state and job metrics, and the result metrics declared so far);
//! 3. DDATA on every machine state change (the changed metrics), and one DDATA per
//!    outbox row of the store (a finished job's summary, written in the same transaction
//!    as the job's end): metrics `Result/...`, each with the row's own timestamp and
//!    `is_historical` when the row was written before this session connected. A row is
//!    marked published only when the broker has provably received it: after a batch the
//!    node re-subscribes to its NCMD topic (harmless) and, the broker handling a
//!    connection's packets in order, its SUBACK confirms every publish before it. A row
//!    whose confirmation was lost with the connection is sent again in the next session
//!    (`Result/Outbox Id` lets a host application drop that rare duplicate);
//! 4. an NCMD with `Node Control/Rebirth` = true: NBIRTH (seq 0, same bdSeq) and every
//!    DBIRTH again;
//! 5. shutdown: NDEATH (QoS 1) published, then DISCONNECT.
//!
//! While the broker is unreachable the node retries with a backoff from 0.5 s doubling
//! to 10 s; the outbox stays in SQLite meanwhile.

use rumqttc::{AsyncClient, Event, EventLoop, LastWill, MqttOptions, Outgoing, Packet, QoS};
use serde::Deserialize;
use serde_json::Value;
use sparkplug::topic::{check_id, MessageType, Topic};
use sparkplug::{DataType, EdgeSequence, Metric, Payload};
use std::collections::{BTreeMap, VecDeque};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use store::Store;
use tokio::sync::{watch, Notify};
use tracing::{info, warn};

/// `[mqtt]` of BOX.toml.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MqttConfig {
    /// The broker's host name or address.
    pub host: String,
    #[serde(default = "default_port")]
    pub port: u16,
    /// Sparkplug group id.
    pub group_id: String,
    /// Sparkplug edge node id (this box).
    pub edge_node_id: String,
    /// MQTT client id (default `gateway-{edge_node_id}`).
    pub client_id: Option<String>,
    /// MQTT keep-alive, seconds.
    #[serde(default = "default_keep_alive")]
    pub keep_alive_s: u64,
    pub username: Option<String>,
    pub password: Option<String>,
}

fn default_port() -> u16 {
    1883
}

fn default_keep_alive() -> u64 {
    30
}

impl MqttConfig {
    /// Checks the ids (Sparkplug's rules) and the numbers, naming the key.
    pub fn check(&self) -> Result<(), String> {
        if self.host.trim().is_empty() {
            return Err("[mqtt] host: empty".into());
        }
        check_id("group id", &self.group_id).map_err(|e| format!("[mqtt] group_id: {e}"))?;
        check_id("edge node id", &self.edge_node_id)
            .map_err(|e| format!("[mqtt] edge_node_id: {e}"))?;
        if !(5..=3600).contains(&self.keep_alive_s) {
            return Err(format!(
                "[mqtt] keep_alive_s: {} s, must be 5..3600",
                self.keep_alive_s
            ));
        }
        if self.password.is_some() && self.username.is_none() {
            return Err("[mqtt] password: given without a username".into());
        }
        Ok(())
    }
}

/// One machine's state as the northbound publishes it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DeviceState {
    pub machine: String,
    pub state: String,
    pub job_id: Option<i64>,
    pub progress_done: u64,
    pub progress_total: u64,
}

/// The running northbound.
pub struct Northbound {
    stop: watch::Sender<bool>,
    task: tokio::task::JoinHandle<()>,
    connected: Arc<AtomicBool>,
    published: watch::Receiver<u64>,
}

impl Northbound {
    /// Whether an MQTT session is up (CONNACK received, not lost since).
    pub fn connected(&self) -> bool {
        self.connected.load(Ordering::SeqCst)
    }

    /// Outbox rows confirmed received by the broker since the start (for tests and the
    /// service's own status).
    pub fn published(&self) -> watch::Receiver<u64> {
        self.published.clone()
    }

    /// Publishes NDEATH and disconnects (if connected), then ends.
    pub async fn shutdown(self) {
        let _ = self.stop.send(true);
        let _ = self.task.await;
    }
}

/// The store setting holding the last bdSeq used.
pub const BDSEQ_SETTING: &str = "sparkplug.bdseq";

/// Rows published per batch (one confirmation each).
const BATCH: usize = 100;

/// Starts the northbound on the current runtime.
pub fn spawn(
    config: MqttConfig,
    store: Arc<Mutex<Store>>,
    machines: Vec<String>,
    states: watch::Receiver<Vec<DeviceState>>,
    outbox_ready: Arc<Notify>,
) -> Northbound {
    let (stop, stop_rx) = watch::channel(false);
    let connected = Arc::new(AtomicBool::new(false));
    let (published_tx, published) = watch::channel(0u64);
    let node = Node {
        published: published_tx,
        config,
        store,
        machines,
        states,
        outbox_ready,
        stop: stop_rx,
        connected: connected.clone(),
    };
    let task = tokio::spawn(node.run());
    Northbound {
        stop,
        task,
        connected,
        published,
    }
}

struct Node {
    published: watch::Sender<u64>,
    config: MqttConfig,
    store: Arc<Mutex<Store>>,
    machines: Vec<String>,
    states: watch::Receiver<Vec<DeviceState>>,
    outbox_ready: Arc<Notify>,
    stop: watch::Receiver<bool>,
    connected: Arc<AtomicBool>,
}

enum End {
    Stopped,
    Lost { was_up: bool, why: String },
}

fn now_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_millis() as u64)
        .unwrap_or(0)
}

/// The store's RFC 3339 time in ms since the epoch (now if unreadable).
fn rfc3339_ms(text: &str) -> u64 {
    chrono::DateTime::parse_from_rfc3339(text)
        .map(|t| t.timestamp_millis().max(0) as u64)
        .unwrap_or_else(|_| now_ms())
}

fn lock(store: &Mutex<Store>) -> std::sync::MutexGuard<'_, Store> {
    store.lock().unwrap_or_else(|p| p.into_inner())
}

impl Node {
    async fn run(mut self) {
        let mut backoff = Duration::from_millis(500);
        loop {
            if *self.stop.borrow() {
                return;
            }
            let bdseq = self.next_bdseq();
            match self.session(bdseq).await {
                End::Stopped => return,
                End::Lost { was_up, why } => {
                    self.connected.store(false, Ordering::SeqCst);
                    warn!(broker = %self.config.host, port = self.config.port, %why, "MQTT session lost; retrying");
                    if was_up {
                        backoff = Duration::from_millis(500);
                    }
                    tokio::select! {
                        _ = tokio::time::sleep(backoff) => {}
                        _ = self.stop.changed() => return,
                    }
                    backoff = (backoff * 2).min(Duration::from_secs(10));
                }
            }
        }
    }

    /// One more than the stored bdSeq, stored before it is used (a crash never reuses
    /// one).
    fn next_bdseq(&self) -> u8 {
        let mut store = lock(&self.store);
        let previous = store
            .get_setting(BDSEQ_SETTING)
            .ok()
            .flatten()
            .and_then(|v| v.parse::<u8>().ok());
        let bdseq = sparkplug::next_bdseq(previous);
        if let Err(e) = store.set_setting(BDSEQ_SETTING, &bdseq.to_string()) {
            warn!(error = %e, "could not store the bdSeq");
        }
        bdseq
    }

    fn topic(&self, t: MessageType, device: Option<&str>) -> String {
        let c = &self.config;
        match device {
            Some(d) => Topic::device(&c.group_id, t, &c.edge_node_id, d),
            None => Topic::node(&c.group_id, t, &c.edge_node_id),
        }
        .map(|t| t.to_string())
        // Ids were checked at start (MqttConfig::check, machine ids).
        .unwrap_or_default()
    }

    fn ndeath(bdseq: u8) -> Vec<u8> {
        Payload {
            timestamp: Some(now_ms()),
            metrics: vec![Metric::int64(sparkplug::BDSEQ, i64::from(bdseq))],
            ..Payload::default()
        }
        .encode_to_bytes()
    }

    async fn session(&mut self, bdseq: u8) -> End {
        let c = &self.config;
        let id = c
            .client_id
            .clone()
            .unwrap_or_else(|| format!("gateway-{}", c.edge_node_id));
        let mut options = MqttOptions::new(id, c.host.clone(), c.port);
        options.set_keep_alive(Duration::from_secs(c.keep_alive_s));
        options.set_clean_session(true);
        options.set_last_will(LastWill::new(
            self.topic(MessageType::NDeath, None),
            Self::ndeath(bdseq),
            QoS::AtLeastOnce,
            false,
        ));
        if let Some(user) = &c.username {
            options.set_credentials(user.clone(), c.password.clone().unwrap_or_default());
        }
        let (client, mut events) = AsyncClient::new(options, 4 * BATCH + 64);
        // Up to the CONNACK.
        loop {
            tokio::select! {
                _ = self.stop.changed() => return End::Stopped,
                e = events.poll() => match e {
                    Ok(Event::Incoming(Packet::ConnAck(_))) => break,
                    Ok(_) => {}
                    Err(e) => return End::Lost { was_up: false, why: e.to_string() },
                },
            }
        }
        self.connected.store(true, Ordering::SeqCst);
        info!(broker = %c.host, port = c.port, bdseq, "MQTT session up");
        let mut s = Session {
            client,
            bdseq,
            seq: EdgeSequence::default(),
            connected_at_ms: now_ms(),
            declared: BTreeMap::new(),
            last_state: BTreeMap::new(),
            barriers: VecDeque::new(),
            awaiting: BTreeMap::new(),
            batch_in_flight: false,
        };
        let ncmd = self.topic(MessageType::NCmd, None);
        s.subscribe(&ncmd, None);
        self.births(&mut s);
        self.publish_outbox(&mut s, &ncmd);
        let mut poll_outbox = tokio::time::interval(Duration::from_secs(1));
        loop {
            tokio::select! {
                _ = self.stop.changed() => {
                    self.goodbye(&mut s, &mut events).await;
                    return End::Stopped;
                }
                e = events.poll() => match e {
                    Ok(Event::Incoming(Packet::Publish(p))) if p.topic == ncmd => {
                        match Payload::decode_bytes(&p.payload) {
                            Ok(cmd) if sparkplug::asks_rebirth(&cmd) => {
                                info!("rebirth asked by NCMD");
                                self.births(&mut s);
                            }
                            Ok(_) => {}
                            Err(e) => warn!(error = %e, "an NCMD that is not a Sparkplug B payload; ignored"),
                        }
                    }
                    Ok(Event::Outgoing(Outgoing::Subscribe(pkid))) => s.sent_subscribe(pkid),
                    Ok(Event::Incoming(Packet::SubAck(ack))) => {
                        if let Some(rows) = s.confirmed(ack.pkid) {
                            let mut store = lock(&self.store);
                            let n = rows.len() as u64;
                            for id in rows {
                                if let Err(e) = store.outbox_done(id) {
                                    warn!(row = id, error = %e, "could not mark an outbox row published");
                                }
                            }
                            drop(store);
                            self.published.send_modify(|c| *c += n);
                            s.batch_in_flight = false;
                            self.publish_outbox(&mut s, &ncmd);
                        }
                    }
                    Ok(_) => {}
                    Err(e) => return End::Lost { was_up: true, why: e.to_string() },
                },
                r = self.states.changed() => {
                    if r.is_ok() {
                        self.state_data(&mut s);
                    }
                }
                _ = self.outbox_ready.notified() => self.publish_outbox(&mut s, &ncmd),
                _ = poll_outbox.tick() => self.publish_outbox(&mut s, &ncmd),
            }
        }
    }

    /// NBIRTH and every DBIRTH (a session's start, or a rebirth).
    fn births(&mut self, s: &mut Session) {
        let now = now_ms();
        let nbirth = Payload {
            timestamp: Some(now),
            seq: Some(s.seq.birth()),
            metrics: vec![
                Metric::int64(sparkplug::BDSEQ, i64::from(s.bdseq)),
                Metric::boolean(sparkplug::REBIRTH, false),
                Metric::string(
                    "Properties/Software",
                    concat!("gateway ", env!("CARGO_PKG_VERSION")),
                ),
                Metric::uint64("Properties/Machines", self.machines.len() as u64),
            ],
            ..Payload::default()
        };
        s.publish(self.topic(MessageType::NBirth, None), &nbirth);
        let states = self.states.borrow_and_update().clone();
        for m in self.machines.clone() {
            let state = states
                .iter()
                .find(|d| d.machine == m)
                .cloned()
                .unwrap_or(DeviceState {
                    machine: m.clone(),
                    state: "opening".into(),
                    ..DeviceState::default()
                });
            for metric in state_metrics(&state) {
                s.declare(&m, metric);
            }
            s.last_state.insert(m.clone(), state);
            self.dbirth(s, &m);
        }
    }

    fn dbirth(&self, s: &mut Session, device: &str) {
        let now = now_ms();
        let metrics: Vec<Metric> = s
            .declared
            .get(device)
            .map(|d| {
                d.values()
                    .map(|m| Metric {
                        timestamp: Some(now),
                        is_historical: None,
                        ..m.clone()
                    })
                    .collect()
            })
            .unwrap_or_default();
        let payload = Payload {
            timestamp: Some(now),
            seq: Some(s.seq.next_seq()),
            metrics,
            ..Payload::default()
        };
        s.publish(self.topic(MessageType::DBirth, Some(device)), &payload);
    }

    /// DDATA with the state metrics that changed, per machine.
    fn state_data(&mut self, s: &mut Session) {
        let states = self.states.borrow_and_update().clone();
        let now = now_ms();
        for state in states {
            if !self.machines.contains(&state.machine) {
                continue;
            }
            let old = s.last_state.get(&state.machine).map(state_metrics);
            let changed: Vec<Metric> = state_metrics(&state)
                .into_iter()
                .enumerate()
                .filter(|(i, m)| old.as_ref().and_then(|o| o.get(*i)) != Some(m))
                .map(|(_, m)| m)
                .collect();
            if changed.is_empty() {
                continue;
            }
            for m in &changed {
                s.declare(&state.machine, m.clone());
            }
            let payload = Payload {
                timestamp: Some(now),
                seq: Some(s.seq.next_seq()),
                metrics: changed
                    .into_iter()
                    .map(|m| Metric {
                        timestamp: Some(now),
                        ..m
                    })
                    .collect(),
                ..Payload::default()
            };
            s.publish(
                self.topic(MessageType::DData, Some(&state.machine)),
                &payload,
            );
            s.last_state.insert(state.machine.clone(), state);
        }
    }

    /// One DDATA per pending outbox row, then the confirming re-subscribe.
    fn publish_outbox(&mut self, s: &mut Session, ncmd: &str) {
        if s.batch_in_flight {
            return;
        }
        let rows = match lock(&self.store).outbox_pending(BATCH) {
            Ok(rows) => rows,
            Err(e) => {
                warn!(error = %e, "reading the outbox");
                return;
            }
        };
        if rows.is_empty() {
            return;
        }
        let mut ids = Vec::new();
        for row in rows {
            let at = rfc3339_ms(&row.created_at);
            let historical = at < s.connected_at_ms;
            let mut metrics = vec![
                Metric::uint64("Result/Outbox Id", row.id.max(0) as u64),
                match row.job_id {
                    Some(j) => Metric::int64("Result/Job Id", j),
                    None => Metric::null("Result/Job Id", DataType::Int64),
                },
            ];
            for (k, v) in &row.metrics {
                metrics.push(json_metric(&format!("Result/{k}"), v));
            }
            let new_names = metrics.iter().any(|m| {
                !s.declared
                    .get(&row.machine)
                    .is_some_and(|d| d.contains_key(m.name.as_deref().unwrap_or("")))
            });
            for m in &metrics {
                s.declare(&row.machine, m.clone());
            }
            if new_names {
                // A host application expects every DDATA metric in the device's birth.
                self.dbirth(s, &row.machine);
            }
            let payload = Payload {
                timestamp: Some(now_ms()),
                seq: Some(s.seq.next_seq()),
                metrics: metrics
                    .into_iter()
                    .map(|m| Metric {
                        timestamp: Some(at),
                        is_historical: historical.then_some(true),
                        ..m
                    })
                    .collect(),
                ..Payload::default()
            };
            // A row whose publish could not be queued stays pending (not confirmed).
            if s.publish(self.topic(MessageType::DData, Some(&row.machine)), &payload) {
                ids.push(row.id);
            }
        }
        s.subscribe(ncmd, Some(ids));
        s.batch_in_flight = true;
    }

    async fn goodbye(&mut self, s: &mut Session, events: &mut EventLoop) {
        let _ = s.client.try_publish(
            self.topic(MessageType::NDeath, None),
            QoS::AtLeastOnce,
            false,
            Self::ndeath(s.bdseq),
        );
        let _ = s.client.try_disconnect();
        // Until the DISCONNECT is out (bounded: a dead broker does not hold shutdown).
        let _ = tokio::time::timeout(Duration::from_secs(2), async {
            loop {
                match events.poll().await {
                    Ok(Event::Outgoing(Outgoing::Disconnect)) | Err(_) => break,
                    Ok(_) => {}
                }
            }
        })
        .await;
        self.connected.store(false, Ordering::SeqCst);
    }
}

/// The state metrics of a device, in a fixed order.
fn state_metrics(d: &DeviceState) -> Vec<Metric> {
    vec![
        Metric::string("State", &d.state),
        match d.job_id {
            Some(j) => Metric::int64("Job/Id", j),
            None => Metric::null("Job/Id", DataType::Int64),
        },
        Metric::uint64("Job/Progress Done", d.progress_done),
        Metric::uint64("Job/Progress Total", d.progress_total),
    ]
}

/// A JSON value as a metric: integers Int64, other numbers Double, booleans Boolean,
/// strings String, null a null String, arrays and objects their JSON text.
fn json_metric(name: &str, v: &Value) -> Metric {
    match v {
        Value::Bool(b) => Metric::boolean(name, *b),
        Value::Number(n) => match n.as_i64() {
            Some(i) => Metric::int64(name, i),
            None => Metric::double(name, n.as_f64().unwrap_or(f64::NAN)),
        },
        Value::String(t) => Metric::string(name, t),
        Value::Null => Metric::null(name, DataType::String),
        other => Metric::string(name, &other.to_string()),
    }
}

/// One MQTT session's state.
struct Session {
    client: AsyncClient,
    bdseq: u8,
    seq: EdgeSequence,
    connected_at_ms: u64,
    /// Per device, the metrics declared in its birth (latest value of each).
    declared: BTreeMap<String, BTreeMap<String, Metric>>,
    last_state: BTreeMap<String, DeviceState>,
    /// Subscribes requested, in order: the outbox rows each one confirms (None: the
    /// session's own subscription).
    barriers: VecDeque<Option<Vec<i64>>>,
    /// Sent subscribes by packet id, waiting for their SUBACK.
    awaiting: BTreeMap<u16, Option<Vec<i64>>>,
    batch_in_flight: bool,
}

impl Session {
    /// Queues a QoS 0 publish (Sparkplug's QoS for births and data); false when the
    /// client's queue is full.
    fn publish(&mut self, topic: String, payload: &Payload) -> bool {
        match self
            .client
            .try_publish(topic, QoS::AtMostOnce, false, payload.encode_to_bytes())
        {
            Ok(()) => true,
            Err(e) => {
                warn!(error = %e, "MQTT request queue full; the message is not sent");
                false
            }
        }
    }

    fn subscribe(&mut self, topic: &str, rows: Option<Vec<i64>>) {
        if self.client.try_subscribe(topic, QoS::AtLeastOnce).is_ok() {
            self.barriers.push_back(rows);
        }
    }

    /// The client sent a SUBSCRIBE with `pkid` (requests go out in order).
    fn sent_subscribe(&mut self, pkid: u16) {
        if let Some(rows) = self.barriers.pop_front() {
            self.awaiting.insert(pkid, rows);
        }
    }

    /// The rows a SUBACK confirms (None when it confirms none, or is unknown).
    fn confirmed(&mut self, pkid: u16) -> Option<Vec<i64>> {
        self.awaiting.remove(&pkid).flatten()
    }

    fn declare(&mut self, device: &str, metric: Metric) {
        let name = metric.name.clone().unwrap_or_default();
        self.declared
            .entry(device.to_string())
            .or_default()
            .insert(name, metric);
    }
}

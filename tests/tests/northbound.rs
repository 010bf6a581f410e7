//! The MQTT northbound against a real Mosquitto broker (Debian's `mosquitto`, started by
//! each test on a free loopback port with its own configuration): the plant's side is a
//! plain MQTT subscriber to `spBv1.0/#` decoding Sparkplug B payloads. Checked: NBIRTH /
//! DBIRTH contents and seq order, DDATA on state changes and for stored results, rebirth
//! on NCMD, NDEATH with the NBIRTH's bdSeq on shutdown and (as the broker's will) when
//! the connection is cut, and results kept through a broker outage, each published once,
//! flagged historical; and an independent plant (Python paho-mqtt, the specification's
//! proto compiled by protoc) decoding the births and death. No sleeps: every wait is for
//! a message (or a line of the plant's), bounded only to fail.

use northbound::{DeviceState, MqttConfig};
use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};
use sparkplug::{MetricValue, Payload};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use store::Store;
use tokio::sync::{mpsc, watch, Notify};

/// Long enough for any step on a loaded machine; only a failure waits this long.
const BOUND: Duration = Duration::from_secs(60);

/// A Mosquitto broker on `port` (a free one if 0), stopped when dropped.
struct Broker {
    child: Child,
    port: u16,
    _dir: tempfile::TempDir,
}

impl Broker {
    fn start(port: u16) -> Broker {
        let port = if port == 0 {
            std::net::TcpListener::bind("127.0.0.1:0")
                .unwrap()
                .local_addr()
                .unwrap()
                .port()
        } else {
            port
        };
        let dir = tempfile::tempdir().unwrap();
        let conf = dir.path().join("mosquitto.conf");
        std::fs::write(
            &conf,
            format!("listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\n"),
        )
        .unwrap();
        let binary = ["/usr/sbin/mosquitto", "/usr/bin/mosquitto"]
            .into_iter()
            .find(|p| std::path::Path::new(p).exists())
            .unwrap_or_else(|| {
                panic!("mosquitto is not installed (apt-get install mosquitto; .ci/run does)")
            });
        let child = Command::new(binary)
            .arg("-c")
            .arg(&conf)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start mosquitto");
        Broker {
            child,
            port,
            _dir: dir,
        }
    }

    fn stop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Broker {
    fn drop(&mut self) {
        self.stop();
    }
}

/// A decoded Sparkplug message as the plant sees it.
#[derive(Debug, Clone)]
struct Message {
    topic: String,
    payload: Payload,
}

impl Message {
    fn kind(&self) -> &str {
        self.topic.split('/').nth(2).unwrap_or("")
    }
    fn device(&self) -> Option<&str> {
        self.topic.split('/').nth(4)
    }
    fn value(&self, name: &str) -> Option<&MetricValue> {
        self.payload.metric(name).and_then(|m| m.value.as_ref())
    }
}

/// The plant's subscriber: every message on `spBv1.0/#`, decoded. Connects (retrying
/// while the broker starts) and returns once subscribed.
async fn plant(port: u16) -> (AsyncClient, mpsc::UnboundedReceiver<Message>) {
    let (tx, rx) = mpsc::unbounded_channel();
    let (ready_tx, mut ready) = mpsc::unbounded_channel();
    // A client id of its own: a second plant with the same id would take the first
    // one's session over, and the two would throw each other off.
    static N: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
    let n = N.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let mut options = MqttOptions::new(format!("plant-{port}-{n}"), "127.0.0.1", port);
    options.set_keep_alive(Duration::from_secs(5));
    let (client, mut events) = AsyncClient::new(options, 100);
    let sub = client.clone();
    tokio::spawn(async move {
        loop {
            match events.poll().await {
                Ok(Event::Incoming(Packet::ConnAck(_))) => {
                    let _ = sub.subscribe("spBv1.0/#", QoS::AtLeastOnce).await;
                }
                Ok(Event::Incoming(Packet::SubAck(_))) => {
                    let _ = ready_tx.send(());
                }
                Ok(Event::Incoming(Packet::Publish(p))) => {
                    let payload = Payload::decode_bytes(&p.payload).expect("a Sparkplug B payload");
                    if tx
                        .send(Message {
                            topic: p.topic.clone(),
                            payload,
                        })
                        .is_err()
                    {
                        return;
                    }
                }
                Ok(_) => {}
                // The broker is not up yet (or gone): rumqttc reconnects on the next poll.
                Err(_) => tokio::task::yield_now().await,
            }
        }
    });
    tokio::time::timeout(BOUND, ready.recv())
        .await
        .expect("the plant subscribed");
    (client, rx)
}

async fn next(rx: &mut mpsc::UnboundedReceiver<Message>) -> Message {
    tokio::time::timeout(BOUND, rx.recv())
        .await
        .expect("a message within the bound")
        .expect("the subscriber runs")
}

/// The next message of `kind` (others before it are returned too, in order).
async fn until(rx: &mut mpsc::UnboundedReceiver<Message>, kind: &str) -> (Message, Vec<Message>) {
    let mut before = Vec::new();
    loop {
        let m = next(rx).await;
        if m.kind() == kind {
            return (m, before);
        }
        before.push(m);
    }
}

/// The plant's host application asks edge node box-1 of plant-a for a rebirth (NCMD
/// `Node Control/Rebirth` = true).
async fn ask_rebirth(plant: &AsyncClient) {
    let ncmd = Payload {
        timestamp: Some(1),
        metrics: vec![sparkplug::Metric::boolean("Node Control/Rebirth", true)],
        ..Payload::default()
    };
    plant
        .publish(
            "spBv1.0/plant-a/NCMD/box-1",
            QoS::AtLeastOnce,
            false,
            ncmd.encode_to_bytes(),
        )
        .await
        .unwrap();
}

fn config(port: u16) -> MqttConfig {
    MqttConfig {
        host: "127.0.0.1".into(),
        port,
        group_id: "plant-a".into(),
        edge_node_id: "box-1".into(),
        client_id: None,
        keep_alive_s: 5,
        username: None,
        password: None,
    }
}

fn state(machine: &str, state: &str, job: Option<i64>) -> DeviceState {
    DeviceState {
        machine: machine.into(),
        state: state.into(),
        job_id: job,
        progress_done: 0,
        progress_total: 0,
    }
}

fn seq(m: &Message) -> u64 {
    m.payload.seq.expect("a seq")
}

fn uint(m: &Message, name: &str) -> u64 {
    match m.value(name) {
        Some(MetricValue::LongValue(v)) => *v,
        other => panic!("{name}: {other:?} in {m:?}"),
    }
}

/// A job's summary row in the outbox (the job made first: rows name real jobs); returns
/// the row id and the job id.
fn result_row(store: &Arc<Mutex<Store>>, machine: &str, rms: f64) -> (i64, i64) {
    let mut metrics = serde_json::Map::new();
    metrics.insert("rms_um".into(), serde_json::json!(rms));
    metrics.insert("targets".into(), serde_json::json!(30));
    let mut store = store.lock().unwrap();
    let job = store
        .enqueue(machine, "compensate", &serde_json::json!({}))
        .unwrap()
        .id;
    (
        store.outbox_push(machine, Some(job), &metrics).unwrap(),
        job,
    )
}

#[test]
fn births_data_rebirth_and_death_on_a_real_broker() {
    let broker = Broker::start(0);
    let rt = system_tests::runtime();
    rt.block_on(async {
        let (plant_client, mut rx) = plant(broker.port).await;
        let store = Arc::new(Mutex::new(Store::open_in_memory().unwrap()));
        let (states_tx, states) = watch::channel(vec![
            state("m1", "idle", None),
            state("m2", "opening", None),
        ]);
        let ready = Arc::new(Notify::new());
        let nb = northbound::spawn(
            config(broker.port),
            store.clone(),
            vec!["m1".into(), "m2".into()],
            states,
            ready.clone(),
        );
        // NBIRTH: seq 0, bdSeq 0 (a fresh store), rebirth false.
        let (nbirth, _) = until(&mut rx, "NBIRTH").await;
        assert_eq!(nbirth.topic, "spBv1.0/plant-a/NBIRTH/box-1");
        assert_eq!(seq(&nbirth), 0);
        assert_eq!(uint(&nbirth, "bdSeq"), 0);
        assert_eq!(
            nbirth.value("Node Control/Rebirth"),
            Some(&MetricValue::BooleanValue(false))
        );
        let d1 = next(&mut rx).await;
        let d2 = next(&mut rx).await;
        assert_eq!(
            (d1.kind(), d1.device(), seq(&d1)),
            ("DBIRTH", Some("m1"), 1)
        );
        assert_eq!(
            (d2.kind(), d2.device(), seq(&d2)),
            ("DBIRTH", Some("m2"), 2)
        );
        assert_eq!(
            d1.value("State"),
            Some(&MetricValue::StringValue("idle".into()))
        );
        assert_eq!(
            d2.value("State"),
            Some(&MetricValue::StringValue("opening".into()))
        );
        assert_eq!(d1.payload.metric("Job/Id").unwrap().is_null, Some(true));

        // A state change: DDATA with only what changed.
        states_tx
            .send(vec![
                state("m1", "busy", Some(7)),
                state("m2", "opening", None),
            ])
            .unwrap();
        let dd = next(&mut rx).await;
        assert_eq!((dd.kind(), dd.device(), seq(&dd)), ("DDATA", Some("m1"), 3));
        assert_eq!(
            dd.value("State"),
            Some(&MetricValue::StringValue("busy".into()))
        );
        assert_eq!(dd.payload.metric("Job/Id").unwrap().as_i64(), Some(7));
        assert!(
            dd.payload.metric("Job/Progress Total").is_none(),
            "unchanged: not sent"
        );

        // A result: its metrics are new for m1, so a DBIRTH declares them first.
        let (row, job) = result_row(&store, "m1", 0.25);
        ready.notify_one();
        let (data, before) = until(&mut rx, "DDATA").await;
        assert_eq!(before.len(), 1);
        assert_eq!((before[0].kind(), seq(&before[0])), ("DBIRTH", 4));
        assert!(before[0].payload.metric("Result/rms_um").is_some());
        assert_eq!(seq(&data), 5);
        assert_eq!(uint(&data, "Result/Outbox Id"), row as u64);
        assert_eq!(
            data.value("Result/rms_um"),
            Some(&MetricValue::DoubleValue(0.25))
        );
        assert_eq!(
            data.payload.metric("Result/targets").unwrap().as_i64(),
            Some(30)
        );
        assert_eq!(
            data.payload.metric("Result/Job Id").unwrap().as_i64(),
            Some(job)
        );
        // Live: not historical.
        assert_eq!(data.payload.metrics[0].is_historical, None);
        let mut published = nb.published();
        tokio::time::timeout(BOUND, published.wait_for(|n| *n >= 1))
            .await
            .unwrap()
            .unwrap();
        assert!(store.lock().unwrap().outbox_pending(10).unwrap().is_empty());

        // Rebirth on NCMD: NBIRTH seq 0 with the same bdSeq, then every DBIRTH.
        ask_rebirth(&plant_client).await;
        let (reborn, _) = until(&mut rx, "NBIRTH").await;
        assert_eq!((seq(&reborn), uint(&reborn, "bdSeq")), (0, 0));
        let d1 = next(&mut rx).await;
        assert_eq!((d1.kind(), seq(&d1)), ("DBIRTH", 1));
        assert_eq!(
            d1.value("State"),
            Some(&MetricValue::StringValue("busy".into()))
        );
        let d2 = next(&mut rx).await;
        assert_eq!((d2.kind(), seq(&d2)), ("DBIRTH", 2));

        // Shutdown: NDEATH with the NBIRTH's bdSeq, no seq.
        nb.shutdown().await;
        let (death, _) = until(&mut rx, "NDEATH").await;
        assert_eq!(death.topic, "spBv1.0/plant-a/NDEATH/box-1");
        assert_eq!(uint(&death, "bdSeq"), 0);
        assert_eq!(death.payload.seq, None);
        // The next session of the same box (a restart) continues the sequence.
        assert_eq!(
            store
                .lock()
                .unwrap()
                .get_setting(northbound::BDSEQ_SETTING)
                .unwrap()
                .as_deref(),
            Some("0")
        );
    });
}

/// A TCP relay between the gateway and the broker that the test can cut (both sockets
/// dropped, no DISCONNECT: the broker then publishes the gateway's will) and close
/// (connections refused until opened again).
struct Relay {
    port: u16,
    cut: mpsc::UnboundedSender<()>,
    open: watch::Sender<bool>,
}

async fn relay(broker_port: u16) -> Relay {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let port = listener.local_addr().unwrap().port();
    let (cut, mut cut_rx) = mpsc::unbounded_channel::<()>();
    let (open, open_rx) = watch::channel(true);
    tokio::spawn(async move {
        loop {
            let Ok((mut inbound, _)) = listener.accept().await else {
                return;
            };
            if !*open_rx.borrow() {
                continue;
            }
            let Ok(mut outbound) = tokio::net::TcpStream::connect(("127.0.0.1", broker_port)).await
            else {
                continue;
            };
            // Cuts asked while no connection was up do not apply to this one.
            while cut_rx.try_recv().is_ok() {}
            tokio::select! {
                _ = tokio::io::copy_bidirectional(&mut inbound, &mut outbound) => {}
                _ = cut_rx.recv() => {}
            }
            // Both sockets dropped here.
        }
    });
    Relay { port, cut, open }
}

#[test]
fn a_cut_connection_sends_the_will_and_the_next_session_a_new_bdseq() {
    let broker = Broker::start(0);
    let rt = system_tests::runtime();
    rt.block_on(async {
        let (_plant, mut rx) = plant(broker.port).await;
        let relay = relay(broker.port).await;
        let store = Arc::new(Mutex::new(Store::open_in_memory().unwrap()));
        let (_states_tx, states) = watch::channel(vec![state("m1", "idle", None)]);
        let nb = northbound::spawn(
            config(relay.port),
            store.clone(),
            vec!["m1".into()],
            states,
            Arc::new(Notify::new()),
        );
        let (first, _) = until(&mut rx, "NBIRTH").await;
        assert_eq!(uint(&first, "bdSeq"), 0);
        relay.cut.send(()).unwrap();
        // The broker's will for the lost connection: NDEATH with bdSeq 0.
        let (will, _) = until(&mut rx, "NDEATH").await;
        assert_eq!(uint(&will, "bdSeq"), 0);
        // The gateway reconnects (through the relay again) with bdSeq 1.
        let (second, _) = until(&mut rx, "NBIRTH").await;
        assert_eq!((uint(&second, "bdSeq"), seq(&second)), (1, 0));
        nb.shutdown().await;
        let (death, _) = until(&mut rx, "NDEATH").await;
        assert_eq!(uint(&death, "bdSeq"), 1);
    });
}

#[test]
fn results_made_while_the_broker_is_down_arrive_once_flagged_historical() {
    let mut broker = Broker::start(0);
    let port = broker.port;
    let rt = system_tests::runtime();
    rt.block_on(async {
        let (first_plant, mut rx) = plant(port).await;
        // The gateway reaches the broker through a relay, so that after the outage the
        // plant is back (subscribed) before the gateway is: QoS 0 data with nobody
        // subscribed is dropped by any broker.
        let relay = relay(port).await;
        let store = Arc::new(Mutex::new(Store::open_in_memory().unwrap()));
        let (_states_tx, states) = watch::channel(vec![state("m1", "idle", None)]);
        let ready = Arc::new(Notify::new());
        let nb = northbound::spawn(
            config(relay.port),
            store.clone(),
            vec!["m1".into()],
            states,
            ready.clone(),
        );
        let mut published = nb.published();
        until(&mut rx, "NBIRTH").await;
        // One live result first.
        let (live, _) = result_row(&store, "m1", 0.5);
        ready.notify_one();
        let (d, _) = until(&mut rx, "DDATA").await;
        assert_eq!(uint(&d, "Result/Outbox Id"), live as u64);
        tokio::time::timeout(BOUND, published.wait_for(|n| *n == 1))
            .await
            .unwrap()
            .unwrap();

        // The broker goes away; three results are stored meanwhile.
        relay.open.send(false).unwrap();
        broker.stop();
        relay.cut.send(()).unwrap();
        drop(rx);
        let _ = first_plant.try_disconnect();
        let rows: Vec<i64> = (2..=4)
            .map(|j| result_row(&store, "m1", 0.1 * j as f64).0)
            .collect();
        ready.notify_one();
        // Back on the same port; the plant reconnects too.
        let _broker = Broker::start(port);
        let (plant_client, mut rx) = plant(port).await;
        relay.open.send(true).unwrap();
        let mut got = Vec::new();
        while got.len() < rows.len() {
            let m = next(&mut rx).await;
            if m.kind() == "DDATA" {
                for metric in &m.payload.metrics {
                    assert_eq!(metric.is_historical, Some(true), "{m:?}");
                }
                got.push(uint(&m, "Result/Outbox Id") as i64);
            }
        }
        assert_eq!(got, rows, "every stored result, in order");
        tokio::time::timeout(BOUND, published.wait_for(|n| *n == 4))
            .await
            .unwrap()
            .unwrap();
        assert!(store.lock().unwrap().outbox_pending(10).unwrap().is_empty());
        // Nothing again: anything published before the answer to a rebirth request
        // arrives before its NBIRTH.
        ask_rebirth(&plant_client).await;
        let (_, before) = until(&mut rx, "NBIRTH").await;
        assert!(
            before
                .iter()
                .all(|m| m.kind() != "DDATA" || m.payload.metric("Result/Outbox Id").is_none()),
            "a result published twice: {before:?}"
        );
        nb.shutdown().await;
    });
}

/// The service with `[mqtt]`: its machine is born on the broker, a compensation job run
/// through the API shows as state changes and ends as a DDATA with the job's summary.
#[test]
fn the_service_publishes_its_machines_and_a_jobs_result() {
    let broker = Broker::start(0);
    let rt = system_tests::runtime_two_workers();
    rt.block_on(async {
        let (_plant, mut rx) = plant(broker.port).await;
        let dir = tempfile::tempdir().unwrap();
        let mut config = service::BoxConfig::demo(dir.path());
        config.mqtt = Some(config_for_service(broker.port));
        let s = service::start(config).await.expect("the service starts");
        let (nbirth, _) = until(&mut rx, "NBIRTH").await;
        assert_eq!(uint(&nbirth, "Properties/Machines"), 1);
        let (dbirth, _) = until(&mut rx, "DBIRTH").await;
        assert_eq!(dbirth.device(), Some("demo"));
        let r = reqwest::Client::new()
            .post(format!(
                "http://{}/api/v1/machines/demo/jobs",
                s.local_addr()
            ))
            .bearer_auth(s.token())
            .json(&serde_json::json!({"kind": "compensate", "params": {"targets": 1}}))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), reqwest::StatusCode::ACCEPTED);
        let job: serde_json::Value = r.json().await.unwrap();
        let id = job["id"].as_i64().unwrap();
        // State changes while it runs, then its result.
        let mut busy = false;
        let result = loop {
            let m = next(&mut rx).await;
            if m.kind() == "DDATA" && m.device() == Some("demo") {
                if m.value("State") == Some(&MetricValue::StringValue("busy".into())) {
                    busy = true;
                }
                if m.payload.metric("Result/Outbox Id").is_some() {
                    break m;
                }
            }
        };
        assert!(busy, "the machine was seen busy");
        assert_eq!(
            result.payload.metric("Result/Job Id").unwrap().as_i64(),
            Some(id)
        );
        assert_eq!(
            result
                .payload
                .metric("Result/targets_planned")
                .unwrap()
                .as_i64(),
            Some(1)
        );
        assert_eq!(s.mqtt_connected(), Some(true));
        s.shutdown().await;
        let (death, _) = until(&mut rx, "NDEATH").await;
        assert_eq!(uint(&death, "bdSeq"), uint(&nbirth, "bdSeq"));
    });
}

fn config_for_service(port: u16) -> MqttConfig {
    MqttConfig {
        edge_node_id: "box-service".into(),
        ..config(port)
    }
}

/// The births and death decoded by an independent plant: Python paho-mqtt subscribed to
/// the real broker, the payloads decoded with the specification's `sparkplug_b.proto`
/// compiled by protoc (`tests/interop/sparkplug/plant.py`; none of our code): topics,
/// seq, bdSeq, the metric names, Sparkplug datatypes and values as that decoder reads them.
#[test]
fn an_independent_plant_decodes_births_and_death_with_the_specifications_proto() {
    if let Some(why) = system_tests::python_missing(
        "paho.mqtt, grpc_tools, google.protobuf",
        "paho-mqtt==2.1.0 grpcio-tools==1.85.1",
    ) {
        panic!(
            "a peer of this test is missing (install every test peer with tests/install-peers.sh, \
             README: Set-up): the independent plant cannot run: {why}"
        );
    }
    use std::io::BufRead;
    let broker = Broker::start(0);
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/interop/sparkplug/plant.py");
    let mut child = system_tests::Kill(
        Command::new("python3")
            .args([
                script,
                "--port",
                &broker.port.to_string(),
                "--group",
                "plant-a",
                "--until",
                "NDEATH",
            ])
            .stdout(Stdio::piped())
            .spawn()
            .expect("python3 runs"),
    );
    // The plant's lines through a channel, so every wait is bounded.
    let (tx, rx) = std::sync::mpsc::channel();
    let stdout = child.0.stdout.take().unwrap();
    std::thread::spawn(move || {
        for l in std::io::BufReader::new(stdout)
            .lines()
            .map_while(Result::ok)
        {
            if tx.send(l).is_err() {
                return;
            }
        }
    });
    let line = || -> serde_json::Value {
        let l = rx.recv_timeout(BOUND).expect("the plant printed a line");
        serde_json::from_str(&l).unwrap_or_else(|e| panic!("{e}: {l}"))
    };
    assert_eq!(line()["subscribed"], true);
    // Worker threads: the northbound runs while this thread reads the plant's lines.
    let rt = system_tests::runtime_two_workers();
    let store = Arc::new(Mutex::new(Store::open_in_memory().unwrap()));
    let (_states_tx, states) = watch::channel(vec![state("m1", "idle", None)]);
    let nb = rt.block_on(async {
        northbound::spawn(
            config(broker.port),
            store.clone(),
            vec!["m1".into()],
            states,
            Arc::new(Notify::new()),
        )
    });
    let nbirth = line();
    let dbirth = line();
    rt.block_on(nb.shutdown());
    let ndeath = line();
    let status = child.0.wait().unwrap();
    assert!(status.success(), "the plant exited with {status}");

    let metric = |m: &serde_json::Value, name: &str| -> serde_json::Value {
        m["payload"]["metrics"]
            .as_array()
            .unwrap()
            .iter()
            .find(|x| x["name"] == name)
            .unwrap_or_else(|| panic!("no metric {name:?} in {m}"))
            .clone()
    };
    assert_eq!(nbirth["topic"], "spBv1.0/plant-a/NBIRTH/box-1");
    assert_eq!(nbirth["payload"]["seq"], "0", "{nbirth}");
    assert!(
        nbirth["payload"]["timestamp"]
            .as_str()
            .unwrap()
            .parse::<u64>()
            .unwrap()
            > 0
    );
    // Sparkplug datatypes: Int64 = 4, Boolean = 11, String = 12.
    let bd = metric(&nbirth, "bdSeq");
    assert_eq!(
        (bd["datatype"].as_u64(), bd["long_value"].as_str()),
        (Some(4), Some("0")),
        "{bd}"
    );
    let rebirth = metric(&nbirth, "Node Control/Rebirth");
    assert_eq!(
        (rebirth["datatype"].as_u64(), &rebirth["boolean_value"]),
        (Some(11), &serde_json::json!(false))
    );
    assert_eq!(dbirth["topic"], "spBv1.0/plant-a/DBIRTH/box-1/m1");
    assert_eq!(dbirth["payload"]["seq"], "1");
    let state = metric(&dbirth, "State");
    assert_eq!(
        (state["datatype"].as_u64(), &state["string_value"]),
        (Some(12), &serde_json::json!("idle"))
    );
    assert_eq!(ndeath["topic"], "spBv1.0/plant-a/NDEATH/box-1");
    assert!(
        ndeath["payload"].get("seq").is_none(),
        "NDEATH has no seq: {ndeath}"
    );
    assert_eq!(metric(&ndeath, "bdSeq")["long_value"], "0");
}

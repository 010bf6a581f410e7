//! The service (issue 15): machines and their job queues, the authenticated
//! HTTP/WebSocket API and the web page, over the SQLite store, in one process.
//!
//! [`start`] opens the store in `data_dir` (jobs that were running when the last process
//! died become `interrupted`; queued jobs stay queued), creates the bearer token at first
//! start, spawns one worker per machine and serves the API. [`Running::shutdown`] stops
//! the running jobs safely (runner cancel: the stage told to stop, results saved as
//! cancelled) and waits for the workers.

pub mod api;
pub mod config;
pub mod context;
mod serve;
pub mod sink;
pub mod state;
mod supervise;
pub mod tls;
pub mod worker;

pub use config::{BoxConfig, ConfigError, JobSource, MachineConfig, ServiceConfig, TlsSource};
pub use tls::TlsIdentity;

use state::{lock, Machine, MachineState, Shared, Status};
use std::net::SocketAddr;
use std::path::Path;
use std::sync::{Arc, Mutex};
use store::Store;
use tokio::sync::{broadcast, watch};
use tracing::info;

/// Events buffered per WebSocket client before it is dropped as too slow.
const EVENT_BUFFER: usize = 1024;

/// A started service.
pub struct Running {
    addr: SocketAddr,
    token: String,
    shared: Arc<Shared>,
    stop: watch::Sender<bool>,
    /// The accept loop; ends when its connections have ended after the stop signal.
    server: tokio::task::JoinHandle<()>,
    /// One per machine worker thread, completed when it has ended.
    workers: Vec<tokio::sync::oneshot::Receiver<()>>,
    /// The MQTT northbound, when `[mqtt]` is configured.
    northbound: Option<northbound::Northbound>,
    /// The certificate presented, when serving HTTPS.
    tls: Option<TlsIdentity>,
}

impl Running {
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// The page's address: `https://ADDR/` or, with `tls = "off"`, `http://ADDR/`.
    pub fn url(&self) -> String {
        let scheme = if self.tls.is_some() { "https" } else { "http" };
        format!("{scheme}://{}/", self.addr)
    }

    /// The certificate served (None: plain HTTP).
    pub fn tls(&self) -> Option<&TlsIdentity> {
        self.tls.as_ref()
    }

    pub fn token(&self) -> &str {
        &self.token
    }

    /// Whether the MQTT northbound has a session up (None: no `[mqtt]`).
    pub fn mqtt_connected(&self) -> Option<bool> {
        self.northbound.as_ref().map(|n| n.connected())
    }

    /// The store the service uses (tests and tools read or seed it directly).
    pub fn store(&self) -> Arc<Mutex<Store>> {
        self.shared.store.clone()
    }

    /// As SIGTERM: running jobs stopped safely and saved, workers ended, the HTTP
    /// server and every WebSocket closed.
    pub async fn shutdown(self) {
        let _ = self.stop.send(true);
        // NDEATH and DISCONNECT after the workers have saved their jobs' ends (below).
        let northbound = self.northbound;
        for w in self.workers {
            let _ = w.await;
        }
        let _ = self.server.await;
        if let Some(n) = northbound {
            n.shutdown().await;
        }
        info!("service stopped");
    }
}

/// Why the service did not start: what it was doing and the cause.
#[derive(Debug, thiserror::Error)]
pub enum StartError {
    #[error("{what}: {source}")]
    Io {
        what: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{what}: {source}")]
    Store {
        what: String,
        #[source]
        source: store::StoreError,
    },
    #[error("{0}")]
    Config(String),
}

fn io(what: impl Into<String>) -> impl FnOnce(std::io::Error) -> StartError {
    let what = what.into();
    move |source| StartError::Io { what, source }
}

fn in_store(what: impl Into<String>) -> impl FnOnce(store::StoreError) -> StartError {
    let what = what.into();
    move |source| StartError::Store { what, source }
}

/// Reads the token file, or creates it with a fresh random 256-bit token (hex, mode 0600).
pub fn load_or_create_token(path: &Path) -> Result<String, StartError> {
    if let Ok(text) = protocol::config::read_data_file(path) {
        let token = text.trim().to_string();
        if !(token.len() >= 32 && token.bytes().all(|b| b.is_ascii_graphic())) {
            return Err(StartError::Config(format!(
                "{}: the token must be at least 32 printable characters",
                path.display()
            )));
        }
        return Ok(token);
    }
    let mut bytes = [0u8; 32];
    getrandom::fill(&mut bytes).map_err(|e| StartError::Config(format!("random token: {e}")))?;
    let token: String = bytes.iter().map(|b| format!("{b:02x}")).collect();
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(io(dir.display().to_string()))?;
    }
    write_private(path, &token).map_err(io(format!("{}: writing the token", path.display())))?;
    info!(file = %path.display(), "created a new API token (not logged; read it from the file)");
    Ok(token)
}

#[cfg(unix)]
fn write_private(path: &Path, text: &str) -> std::io::Result<()> {
    use std::io::Write;
    use std::os::unix::fs::OpenOptionsExt;
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(0o600)
        .open(path)?;
    f.write_all(text.as_bytes())?;
    f.write_all(b"\n")
}

#[cfg(not(unix))]
fn write_private(path: &Path, text: &str) -> std::io::Result<()> {
    std::fs::write(path, format!("{text}\n"))
}

/// The store's file and its WAL companions readable and writable by their owner only
/// (mode 0600; SQLite creates them with the process's umask): they hold every job's
/// parameters, results and files.
#[cfg(unix)]
fn owner_only(db: &Path) -> std::io::Result<()> {
    use std::os::unix::fs::PermissionsExt;
    for suffix in ["", "-wal", "-shm"] {
        let mut path = db.as_os_str().to_owned();
        path.push(suffix);
        match std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o600)) {
            Err(e) if e.kind() == std::io::ErrorKind::NotFound && !suffix.is_empty() => {}
            other => other?,
        }
    }
    Ok(())
}

#[cfg(not(unix))]
fn owner_only(_db: &Path) -> std::io::Result<()> {
    Ok(())
}

/// Starts the service: store, token, workers, HTTP server.
pub async fn start(config: BoxConfig) -> Result<Running, StartError> {
    // Checked here too: a config may be built in code, not read from BOX.toml.
    config
        .service
        .check_plain_http()
        .map_err(|m| StartError::Config(format!("service.tls: {m}")))?;
    let data_dir = &config.service.data_dir;
    std::fs::create_dir_all(data_dir).map_err(io(format!("data_dir {}", data_dir.display())))?;
    let db = data_dir.join("gateway.sqlite");
    let mut store = Store::open(&db).map_err(in_store(db.display().to_string()))?;
    owner_only(&db).map_err(io(format!("{}: restricting it to its owner", db.display())))?;
    let interrupted = store
        .recover()
        .map_err(in_store("recovering interrupted jobs"))?;
    for job in &interrupted {
        info!(job_id = job.id, machine = %job.machine, "job was running when the service stopped: interrupted");
    }
    let token = load_or_create_token(&config.service.token_file)?;
    let tls = match &config.service.tls {
        TlsSource::Off => None,
        source => Some(
            tls::load(
                source,
                data_dir,
                &config.service.tls_names,
                config.service.listen,
            )
            .map_err(StartError::Config)?,
        ),
    };

    let mut machines = Vec::new();
    for m in &config.machines {
        let job = m
            .job
            .load()
            .map_err(|e| StartError::Config(format!("machine {:?}: job file: {e}", m.id)))?;
        let (stage, camera) = worker::describe(&job);
        // A rotary job file is read at start too, so a bad one stops the service here.
        let rotary = match &m.rotary {
            None => None,
            Some(source) => Some(worker::describe_rotary(&source.load().map_err(|e| {
                StartError::Config(format!("machine {:?}: rotary job file: {e}", m.id))
            })?)),
        };
        machines.push(Arc::new(Machine {
            id: m.id.clone(),
            description: m.description.clone(),
            stage,
            camera,
            map_profile: m.map_profile.clone(),
            rotary,
            status: Mutex::new(Status {
                state: MachineState::Opening,
                detail: None,
                job: None,
            }),
            wake: tokio::sync::Notify::new(),
            cancel: Mutex::new(None),
            scan_area: Mutex::new(None),
            frame: Mutex::new(None),
        }));
    }
    let (stop, shutdown) = watch::channel(false);
    let (events, _) = broadcast::channel(EVENT_BUFFER);
    let shared = Arc::new(Shared {
        store: Arc::new(Mutex::new(store)),
        machines,
        events,
        token: token.clone(),
        shutdown: shutdown.clone(),
        bad_tokens: Mutex::new(Default::default()),
        bad_token_delay_cap_ms: config.service.bad_token_delay_cap_ms,
        device_states: watch::channel(Vec::new()).0,
        outbox_ready: Arc::new(tokio::sync::Notify::new()),
    });
    shared.publish_states();
    let northbound = config.mqtt.clone().map(|mqtt| {
        info!(broker = %mqtt.host, port = mqtt.port, group = %mqtt.group_id, edge = %mqtt.edge_node_id, "MQTT northbound (Sparkplug B)");
        northbound::spawn(
            mqtt,
            shared.store.clone(),
            shared.machines.iter().map(|m| m.id.clone()).collect(),
            shared.device_states.subscribe(),
            shared.outbox_ready.clone(),
        )
    });
    for job in &interrupted {
        // The store's lock is released before the event (emit_job reads the store).
        let record = lock(&shared.store)
            .job(job.id)
            .map_err(in_store("reading an interrupted job"))?;
        shared.emit_job(&record.unwrap_or_else(|| job.clone()));
    }

    let listener = tokio::net::TcpListener::bind(config.service.listen)
        .await
        .map_err(io(format!("listen on {}", config.service.listen)))?;
    let addr = listener.local_addr().map_err(io("the listening address"))?;
    let app = api::router(
        shared.clone(),
        api::BodyLimits {
            default: config.service.max_body_bytes,
            job: config.service.max_job_body_bytes,
        },
        &config.service.cors_origins,
    );
    // Header/idle timeouts and the connection cap: see serve.rs.
    let limits = serve::Limits {
        header_timeout: config.service.header_timeout,
        idle_timeout: config.service.idle_timeout,
        max_connections: config.service.max_connections,
    };
    let server = tokio::spawn(serve::serve(
        listener,
        app,
        limits,
        tls.as_ref().map(|t| t.config.clone()),
        shutdown.clone(),
    ));
    // Each machine has its own thread and single-threaded runtime: the runner's
    // futures are not `Send`, device emulators and bus tasks live on the runtime that
    // opened them, and a busy machine never slows the API down.
    let mut workers = Vec::new();
    for (c, m) in config.machines.iter().zip(shared.machines.iter()) {
        let (done, finished) = tokio::sync::oneshot::channel();
        let (shared, m, c) = (shared.clone(), m.clone(), c.clone());
        std::thread::Builder::new()
            .name(format!("machine-{}", m.id))
            .spawn(move || {
                match tokio::runtime::Builder::new_current_thread()
                    .enable_all()
                    .build()
                {
                    Ok(rt) => rt.block_on(worker::run(shared, m, c)),
                    Err(e) => {
                        tracing::error!(machine = %m.id, error = %e, "no runtime for the machine")
                    }
                }
                let _ = done.send(());
            })
            .map_err(io("machine worker thread"))?;
        workers.push(finished);
    }
    let tls = tls.map(|t| t.identity);
    match &tls {
        Some(id) => info!(
            url = %format!("https://{addr}/"),
            certificate = %id.cert_file.display(),
            made_now = id.made_now,
            sha256 = %id.cert_sha256,
            spki_sha256 = %id.spki_sha256_base64,
            "HTTPS: before typing the token, check that the browser shows this certificate's SHA-256 fingerprint"
        ),
        None => info!(url = %format!("http://{addr}/"), "plain HTTP (service.tls = \"off\")"),
    }
    info!(%addr, machines = config.machines.len(), "service listening");
    Ok(Running {
        addr,
        token,
        shared,
        stop,
        server,
        workers,
        northbound,
        tls,
    })
}

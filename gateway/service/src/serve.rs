//! The HTTP server's accept loop: hyper's HTTP/1 connections over the axum router, with
//! the connection limits of `[service]` (`header_timeout_s`, `idle_timeout_s`,
//! `max_connections`).
//!
//! # Policy
//!
//! Every connection is in one phase:
//! - *head*: waiting for a request head. The first one must be complete within
//!   `header_timeout` of the accept; on a keep-alive connection the next one within
//!   `header_timeout` of its first byte. Else the connection is closed.
//! - *idle*: a keep-alive connection between requests (its last response written).
//!   Closed after `idle_timeout` without a byte of a new request.
//! - *busy*: a request is being answered (from its complete head to the end of its
//!   response body). Never evicted. Request bodies are only read by the handlers,
//!   behind the bearer check, so only a token holder can be slow here; the wrong-token
//!   delay is capped by `bad_token_delay_cap_ms`. A token holder's body, too, must have
//!   arrived whole within `idle_timeout` of its head (60 s by default: 16 MiB at about
//!   2.3 Mbit/s); else the request is answered 408 `body_timeout` and the connection
//!   closed, so a body sent a byte a second holds nothing for long.
//! - *upgraded*: a WebSocket (`/api/v1/events`, authenticated). Never timed out nor
//!   evicted; it ends with its client or at shutdown.
//!
//! Every open connection, WebSockets included, takes one of `max_connections` slots.
//! A new connection is always accepted while the process has file descriptors; at the
//! cap it evicts (closes at once) the connection that has been waiting longest for a
//! request, i.e. the one in the *head* or *idle* phase for the longest time. Only when
//! no connection is waiting (all busy or upgraded: token holders) is the new connection
//! closed right away. So idle or slow-header connections, however many, cannot lock a
//! client out: its connection is the newest, it sends its request head at once and,
//! busy, cannot be evicted; an attacker would have to open `max_connections` new
//! connections between its connect and its request head. The timeouts then free the
//! slots the evictions did not. (A soft threshold with shorter header timeouts would only
//! shorten the wait for a slot; eviction makes it none.)
//!
//! hyper's own `header_read_timeout` is not used: it restarts when a keep-alive
//! connection goes idle, which would close idle connections after `header_timeout`
//! rather than `idle_timeout`. The phases above are kept by the per-connection task,
//! with the service (request start, response end, upgrade) and the socket (first byte
//! of a head) reporting changes.
//!
//! Graceful shutdown: accepting stops, waiting connections are closed, a request being
//! answered ends with its response, then the connection closes; WebSockets close on the
//! same shutdown signal (api.rs).

use axum::body::{Body, Bytes, HttpBody};
use axum::extract::ConnectInfo;
use axum::http::{header, Request, Response, StatusCode};
use axum::Router;
use hyper::body::{Frame, Incoming, SizeHint};
use hyper_util::rt::TokioIo;
use std::collections::HashMap;
use std::convert::Infallible;
use std::future::Future;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::task::{Context, Poll};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{watch, Notify};
use tokio::task::JoinSet;
use tokio::time::Instant;
use tracing::{debug, warn};

/// The connection limits (from `[service]`).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Limits {
    pub header_timeout: Duration,
    pub idle_timeout: Duration,
    pub max_connections: usize,
}

/// Serves `app` on `listener` until `shutdown` turns true (or its sender is dropped),
/// then waits for the connections to end (see the module's doc).
pub(crate) async fn serve(
    listener: TcpListener,
    app: Router,
    limits: Limits,
    tls: Option<Arc<rustls::ServerConfig>>,
    mut shutdown: watch::Receiver<bool>,
) {
    let tls = tls.map(tokio_rustls::TlsAcceptor::from);
    warn_if_few_descriptors(limits.max_connections);
    let registry = Arc::new(Registry {
        conns: Mutex::new(HashMap::new()),
        next_id: AtomicU64::new(0),
        limits,
        at_cap: AtomicBool::new(false),
    });
    let mut tasks = JoinSet::new();
    let stop = shutdown.clone();
    loop {
        tokio::select! {
            _ = async { let _ = shutdown.wait_for(|s| *s).await; } => break,
            Some(ended) = tasks.join_next(), if !tasks.is_empty() => {
                if let Err(e) = ended {
                    warn!(error = %e, "connection task failed");
                }
            }
            accepted = listener.accept() => match accepted {
                Ok((stream, peer)) => {
                    let Some(conn) = registry.admit() else {
                        debug!(%peer, "connection limit: every connection busy; closed");
                        continue;
                    };
                    let _ = stream.set_nodelay(true);
                    let io = Tracked { stream, conn: conn.clone(), registry: registry.clone() };
                    tasks.spawn(open_connection(io, peer, conn, app.clone(), limits, tls.clone(), stop.clone()));
                }
                Err(e) if is_connection_error(&e) => {}
                Err(e) => {
                    // Out of file descriptors, most likely: back off instead of spinning.
                    warn!(error = %e, "accept failed");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                }
            },
        }
    }
    drop(listener);
    while let Some(ended) = tasks.join_next().await {
        if let Err(e) = ended {
            warn!(error = %e, "connection task failed");
        }
    }
}

fn is_connection_error(e: &std::io::Error) -> bool {
    use std::io::ErrorKind::*;
    matches!(
        e.kind(),
        ConnectionRefused | ConnectionAborted | ConnectionReset
    )
}

/// Says so at start when the open-file limit cannot hold `max_connections` plus the
/// handles of the store, the devices and the MQTT link.
fn warn_if_few_descriptors(max_connections: usize) {
    #[cfg(target_os = "linux")]
    {
        let Ok(limits) =
            protocol::config::read_data_file(std::path::Path::new("/proc/self/limits"))
        else {
            return;
        };
        let soft = limits
            .lines()
            .find(|l| l.starts_with("Max open files"))
            .and_then(|l| l.split_whitespace().nth(3))
            .and_then(|v| v.parse::<usize>().ok());
        if let Some(soft) = soft {
            if soft < max_connections + 256 {
                warn!(
                    open_file_limit = soft,
                    max_connections,
                    "the open-file limit leaves too little room for max_connections: raise it (LimitNOFILE) or lower max_connections"
                );
            }
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = max_connections;
}

/// The open connections (their sockets: WebSockets included).
struct Registry {
    conns: Mutex<HashMap<u64, Arc<Conn>>>,
    next_id: AtomicU64,
    limits: Limits,
    /// Whether the cap was reached (logged once per episode: until the count falls
    /// below three quarters of the cap).
    at_cap: AtomicBool,
}

impl Registry {
    /// A slot for a new connection: at the cap, the connection waiting longest is
    /// evicted for it; None when every connection is busy or upgraded.
    fn admit(&self) -> Option<Arc<Conn>> {
        let mut conns = lock(&self.conns);
        if conns.len() >= self.limits.max_connections {
            if !self.at_cap.swap(true, Ordering::Relaxed) {
                warn!(
                    max_connections = self.limits.max_connections,
                    "connection limit reached: new connections close the ones waiting longest for a request"
                );
            }
            // A candidate may turn busy between the look and the eviction: look again.
            loop {
                let victim = conns
                    .values()
                    .filter_map(|c| c.waiting_since().map(|since| (since, c)))
                    .min_by_key(|(since, c)| (*since, c.id))
                    .map(|(_, c)| c.clone());
                match victim {
                    None => return None,
                    Some(c) if c.close_if_waiting() => {
                        debug!(connection = c.id, "evicted: connection limit");
                        break;
                    }
                    Some(_) => {}
                }
            }
        } else if conns.len() < self.limits.max_connections * 3 / 4 {
            // Logged again only after the pressure has clearly gone.
            self.at_cap.store(false, Ordering::Relaxed);
        }
        let id = self.next_id.fetch_add(1, Ordering::Relaxed);
        let now = Instant::now();
        let conn = Arc::new(Conn {
            id,
            phase: Mutex::new(Phase::Head {
                since: now,
                deadline: now + self.limits.header_timeout,
            }),
            changed: Notify::new(),
            limits: self.limits,
        });
        conns.insert(id, conn.clone());
        Some(conn)
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

#[derive(Debug, Clone, Copy)]
enum Phase {
    /// Waiting for a request head since `since`; closed at `deadline`.
    Head { since: Instant, deadline: Instant },
    /// Between requests since `since`; closed at `deadline` unless a head begins.
    Idle { since: Instant, deadline: Instant },
    /// This many requests being answered.
    Busy(usize),
    /// A WebSocket.
    Upgraded,
    /// Timed out or evicted: the connection is being dropped, no request may start.
    Closing,
}

/// One connection's phase, shared by its task, its service and its socket.
struct Conn {
    id: u64,
    phase: Mutex<Phase>,
    /// Wakes the connection's task when the phase changed.
    changed: Notify,
    limits: Limits,
}

impl Conn {
    fn set(&self, phase: &mut Phase, to: Phase) {
        *phase = to;
        self.changed.notify_one();
    }

    /// When the connection closes unless something happens.
    fn deadline(&self) -> Option<Instant> {
        match *lock(&self.phase) {
            Phase::Head { deadline, .. } | Phase::Idle { deadline, .. } => Some(deadline),
            _ => None,
        }
    }

    fn is_closing(&self) -> bool {
        matches!(*lock(&self.phase), Phase::Closing)
    }

    /// Since when the connection has been waiting for a request (None: not waiting).
    fn waiting_since(&self) -> Option<Instant> {
        match *lock(&self.phase) {
            Phase::Head { since, .. } | Phase::Idle { since, .. } => Some(since),
            _ => None,
        }
    }

    /// Marks a waiting connection closing (true), if it is still waiting and, with
    /// `past`, its deadline is not after `past`.
    fn close_waiting(&self, past: Option<Instant>) -> bool {
        let mut phase = lock(&self.phase);
        match *phase {
            Phase::Head { deadline, .. } | Phase::Idle { deadline, .. }
                if past.is_none_or(|now| deadline <= now) =>
            {
                self.set(&mut phase, Phase::Closing);
                true
            }
            _ => false,
        }
    }

    fn close_if_waiting(&self) -> bool {
        self.close_waiting(None)
    }

    /// A request head is complete: busy until the returned guard is dropped (with the
    /// response body). None when the connection is closing.
    fn begin(self: &Arc<Self>) -> Option<BusyGuard> {
        let mut phase = lock(&self.phase);
        match *phase {
            Phase::Closing => return None,
            Phase::Busy(n) => self.set(&mut phase, Phase::Busy(n + 1)),
            Phase::Upgraded => {}
            Phase::Head { .. } | Phase::Idle { .. } => self.set(&mut phase, Phase::Busy(1)),
        }
        Some(BusyGuard(self.clone()))
    }

    fn upgraded(&self) {
        let mut phase = lock(&self.phase);
        if !matches!(*phase, Phase::Closing) {
            self.set(&mut phase, Phase::Upgraded);
        }
    }

    /// Bytes arrived: on an idle connection, a request head has begun.
    fn on_bytes(&self) {
        let mut phase = lock(&self.phase);
        if let Phase::Idle { since, .. } = *phase {
            let deadline = Instant::now() + self.limits.header_timeout;
            self.set(&mut phase, Phase::Head { since, deadline });
        }
    }
}

/// A request being answered; dropped with its response body.
struct BusyGuard(Arc<Conn>);

impl Drop for BusyGuard {
    fn drop(&mut self) {
        let conn = &self.0;
        let mut phase = lock(&conn.phase);
        match *phase {
            Phase::Busy(n) if n > 1 => conn.set(&mut phase, Phase::Busy(n - 1)),
            Phase::Busy(_) => {
                let now = Instant::now();
                let deadline = now + conn.limits.idle_timeout;
                conn.set(
                    &mut phase,
                    Phase::Idle {
                        since: now,
                        deadline,
                    },
                );
            }
            _ => {}
        }
    }
}

/// The socket of a connection: reports the bytes that begin a request head, and frees
/// the connection's slot when dropped (after the connection, or with its WebSocket).
struct Tracked {
    stream: TcpStream,
    conn: Arc<Conn>,
    registry: Arc<Registry>,
}

impl Drop for Tracked {
    fn drop(&mut self) {
        lock(&self.registry.conns).remove(&self.conn.id);
    }
}

impl AsyncRead for Tracked {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        let this = self.get_mut();
        let before = buf.filled().len();
        let read = Pin::new(&mut this.stream).poll_read(cx, buf);
        if matches!(read, Poll::Ready(Ok(()))) && buf.filled().len() > before {
            this.conn.on_bytes();
        }
        read
    }
}

impl AsyncWrite for Tracked {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.get_mut().stream).poll_write(cx, buf)
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.get_mut().stream).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.stream.is_write_vectored()
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.get_mut().stream).poll_flush(cx)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.get_mut().stream).poll_shutdown(cx)
    }
}

/// An accepted connection: with TLS, its handshake first, which belongs to the *head*
/// phase (done within `header_timeout` of the accept, else closed; evictable; closed at
/// shutdown), then the connection as over plain TCP.
async fn open_connection(
    io: Tracked,
    peer: SocketAddr,
    conn: Arc<Conn>,
    app: Router,
    limits: Limits,
    tls: Option<tokio_rustls::TlsAcceptor>,
    mut shutdown: watch::Receiver<bool>,
) {
    let Some(acceptor) = tls else {
        return connection(io, peer, conn, app, limits, shutdown).await;
    };
    let deadline = conn.deadline();
    let closed = async {
        while !conn.is_closing() {
            conn.changed.notified().await;
        }
    };
    tokio::select! {
        handshake = acceptor.accept(io) => match handshake {
            Ok(stream) => connection(stream, peer, conn, app, limits, shutdown).await,
            Err(e) => debug!(connection = conn.id, %peer, error = %e, "TLS handshake failed"),
        },
        _ = sleep_until(deadline) => {
            debug!(connection = conn.id, %peer, "closed: no TLS handshake in time");
        }
        _ = closed => {}
        _ = async { let _ = shutdown.wait_for(|s| *s).await; } => {}
    }
}

/// One connection, from accept (or its TLS handshake) to its end (or to its upgrade: the
/// WebSocket then owns the socket).
async fn connection<Io>(
    io: Io,
    peer: SocketAddr,
    conn: Arc<Conn>,
    app: Router,
    limits: Limits,
    mut shutdown: watch::Receiver<bool>,
) where
    Io: AsyncRead + AsyncWrite + Unpin + Send + 'static,
{
    let service = ConnService {
        app,
        peer,
        conn: conn.clone(),
    };
    let mut http = hyper::server::conn::http1::Builder::new();
    // The header and idle timeouts are the phases' (see the module's doc).
    http.keep_alive(true).header_read_timeout(None);
    let served = http
        .serve_connection(TokioIo::new(io), service)
        .with_upgrades();
    tokio::pin!(served);
    let mut shutting_down = false;
    loop {
        if conn.is_closing() {
            // Dropping the connection closes the socket.
            return;
        }
        let deadline = conn.deadline();
        tokio::select! {
            ended = served.as_mut() => {
                if let Err(e) = ended {
                    debug!(connection = conn.id, %peer, error = %e, "connection ended");
                }
                return;
            }
            _ = sleep_until(deadline) => {
                if conn.close_waiting(Some(Instant::now())) {
                    debug!(
                        connection = conn.id, %peer,
                        header_timeout_s = limits.header_timeout.as_secs_f64(),
                        idle_timeout_s = limits.idle_timeout.as_secs_f64(),
                        "closed: no request in time"
                    );
                    return;
                }
            }
            _ = conn.changed.notified() => {}
            _ = async { let _ = shutdown.wait_for(|s| *s).await; }, if !shutting_down => {
                shutting_down = true;
                if conn.close_if_waiting() {
                    return;
                }
                // The request being answered ends first.
                served.as_mut().graceful_shutdown();
            }
        }
    }
}

async fn sleep_until(deadline: Option<Instant>) {
    match deadline {
        Some(d) => tokio::time::sleep_until(d).await,
        None => std::future::pending().await,
    }
}

/// The router as one connection's hyper service: the peer's address as
/// `ConnectInfo<SocketAddr>` (as `into_make_service_with_connect_info`), the
/// connection's phase kept.
struct ConnService {
    app: Router,
    peer: SocketAddr,
    conn: Arc<Conn>,
}

type ResponseFuture =
    Pin<Box<dyn Future<Output = Result<Response<TrackedBody>, Infallible>> + Send>>;

impl hyper::service::Service<Request<Incoming>> for ConnService {
    type Response = Response<TrackedBody>;
    type Error = Infallible;
    type Future = ResponseFuture;

    fn call(&self, mut req: Request<Incoming>) -> ResponseFuture {
        let Some(busy) = self.conn.begin() else {
            // Timed out or evicted just now: the connection is being dropped anyway.
            let mut response = Response::new(TrackedBody {
                inner: Body::empty(),
                _busy: None,
            });
            *response.status_mut() = StatusCode::SERVICE_UNAVAILABLE;
            response.headers_mut().insert(
                header::CONNECTION,
                header::HeaderValue::from_static("close"),
            );
            return Box::pin(std::future::ready(Ok(response)));
        };
        req.extensions_mut().insert(ConnectInfo(self.peer));
        let late = Arc::new(AtomicBool::new(false));
        let timeout = self.conn.limits.idle_timeout;
        let req = req.map(|inner| DeadlineBody {
            inner,
            deadline: Box::pin(tokio::time::sleep(timeout)),
            late: late.clone(),
        });
        let mut app = self.app.clone();
        let conn = self.conn.clone();
        Box::pin(async move {
            let mut response = match tower_service::Service::call(&mut app, req).await {
                Ok(response) => response,
                Err(never) => match never {},
            };
            if late.load(Ordering::Relaxed) {
                // Whatever the handler made of its cut body: the client is told why.
                response = body_timeout(timeout);
            }
            if response.status() == StatusCode::SWITCHING_PROTOCOLS {
                conn.upgraded();
            }
            Ok(response.map(|inner| TrackedBody {
                inner,
                _busy: Some(busy),
            }))
        })
    }
}

/// A request body that must have arrived whole by its deadline: past it, the next read
/// fails (the handler refuses the request) and `late` says why.
struct DeadlineBody {
    inner: Incoming,
    deadline: Pin<Box<tokio::time::Sleep>>,
    late: Arc<AtomicBool>,
}

impl HttpBody for DeadlineBody {
    type Data = Bytes;
    type Error = Box<dyn std::error::Error + Send + Sync>;

    fn poll_frame(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, Self::Error>>> {
        let this = self.get_mut();
        match Pin::new(&mut this.inner).poll_frame(cx) {
            Poll::Ready(frame) => Poll::Ready(frame.map(|f| f.map_err(Into::into))),
            Poll::Pending => match this.deadline.as_mut().poll(cx) {
                Poll::Ready(()) => {
                    this.late.store(true, Ordering::Relaxed);
                    Poll::Ready(Some(Err("the request body did not arrive in time".into())))
                }
                Poll::Pending => Poll::Pending,
            },
        }
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> SizeHint {
        self.inner.size_hint()
    }
}

/// 408 for a body that was not whole by its deadline; the connection is closed (the
/// rest of the body is never read).
fn body_timeout(timeout: Duration) -> Response<Body> {
    let message = format!(
        "the request body did not arrive within {} s of its head (service.idle_timeout_s in BOX.toml)",
        timeout.as_secs_f64()
    );
    let body = serde_json::json!({"error": "body_timeout", "message": message}).to_string();
    let mut response = Response::new(Body::from(body));
    *response.status_mut() = StatusCode::REQUEST_TIMEOUT;
    let headers = response.headers_mut();
    headers.insert(
        header::CONTENT_TYPE,
        header::HeaderValue::from_static("application/json"),
    );
    headers.insert(
        header::CONNECTION,
        header::HeaderValue::from_static("close"),
    );
    headers.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        header::HeaderValue::from_static("nosniff"),
    );
    response
}

/// The page's files (`/`, `/app.js`, `/style.css`), built into the binary: each with a
/// strong `ETag` (a hash of its text) and `Cache-Control: no-cache`, so a browser asks
/// again at each load and gets 304 without a body while the file is unchanged (a new
/// build's page is used at once); gzip-compressed (once, at first use) for a client
/// that accepts it.
pub(crate) struct PageFile {
    content_type: &'static str,
    text: &'static str,
    etag: String,
    gzip: Vec<u8>,
}

impl PageFile {
    fn new(content_type: &'static str, text: &'static str) -> PageFile {
        use std::hash::{Hash, Hasher};
        use std::io::Write;
        // SipHash with fixed keys: the same text gives the same tag in every process of
        // a build.
        let mut hasher = std::hash::DefaultHasher::new();
        text.hash(&mut hasher);
        let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
        let gzip = gz
            .write_all(text.as_bytes())
            .and_then(|()| gz.finish())
            .unwrap_or_default();
        PageFile {
            content_type,
            text,
            etag: format!("\"{:016x}-{}\"", hasher.finish(), text.len()),
            gzip,
        }
    }

    /// The answer to a GET with these request headers.
    pub(crate) fn answer(&self, request: &header::HeaderMap) -> Response<Body> {
        let etag = header::HeaderValue::from_str(&self.etag).expect("an ASCII tag");
        let matches = request
            .get_all(header::IF_NONE_MATCH)
            .iter()
            .filter_map(|v| v.to_str().ok())
            .flat_map(|v| v.split(','))
            .map(|t| t.trim().trim_start_matches("W/"))
            .any(|t| t == "*" || t == self.etag);
        let gzip = !self.gzip.is_empty() && accepts_gzip(request);
        let mut response = if matches {
            let mut r = Response::new(Body::empty());
            *r.status_mut() = StatusCode::NOT_MODIFIED;
            r
        } else if gzip {
            let mut r = Response::new(Body::from(self.gzip.clone()));
            r.headers_mut().insert(
                header::CONTENT_ENCODING,
                header::HeaderValue::from_static("gzip"),
            );
            r
        } else {
            Response::new(Body::from(self.text))
        };
        let headers = response.headers_mut();
        headers.insert(
            header::CONTENT_TYPE,
            header::HeaderValue::from_static(self.content_type),
        );
        headers.insert(header::ETAG, etag);
        headers.insert(
            header::CACHE_CONTROL,
            header::HeaderValue::from_static("no-cache"),
        );
        headers.insert(
            header::VARY,
            header::HeaderValue::from_static("accept-encoding"),
        );
        response
    }
}

/// Whether `Accept-Encoding` accepts gzip (RFC 9110 12.5.3: `gzip` or `*`, with a
/// q-value above 0).
fn accepts_gzip(request: &header::HeaderMap) -> bool {
    request
        .get_all(header::ACCEPT_ENCODING)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','))
        .any(|coding| {
            let mut parts = coding.split(';');
            let name = parts.next().unwrap_or("").trim().to_ascii_lowercase();
            let q = parts
                .filter_map(|p| p.trim().strip_prefix("q="))
                .find_map(|q| q.trim().parse::<f64>().ok())
                .unwrap_or(1.0);
            (name == "gzip" || name == "x-gzip" || name == "*") && q > 0.0
        })
}

/// The page's three files.
pub(crate) static PAGE_FILES: std::sync::LazyLock<[PageFile; 3]> = std::sync::LazyLock::new(|| {
    [
        PageFile::new("text/html; charset=utf-8", webpage::INDEX_HTML),
        PageFile::new("text/javascript; charset=utf-8", webpage::APP_JS),
        PageFile::new("text/css; charset=utf-8", webpage::STYLE_CSS),
    ]
});

/// A response body holding its request's busy guard until hyper has taken its last
/// frame.
struct TrackedBody {
    inner: Body,
    _busy: Option<BusyGuard>,
}

impl HttpBody for TrackedBody {
    type Data = Bytes;
    type Error = axum::Error;

    fn poll_frame(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, axum::Error>>> {
        Pin::new(&mut self.get_mut().inner).poll_frame(cx)
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> SizeHint {
        self.inner.size_hint()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::routing::get;

    /// The peer's address reaches the handlers as `ConnectInfo<SocketAddr>` (a handler
    /// extracting it answers 500 without it).
    #[tokio::test]
    async fn handlers_get_the_peer_address() {
        let app = Router::new().route(
            "/peer",
            get(|ConnectInfo(peer): ConnectInfo<SocketAddr>| async move { peer.to_string() }),
        );
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let (stop, shutdown) = watch::channel(false);
        let limits = Limits {
            header_timeout: Duration::from_secs(10),
            idle_timeout: Duration::from_secs(60),
            max_connections: 4,
        };
        let server = tokio::spawn(serve(listener, app, limits, None, shutdown));
        let answer = reqwest::get(format!("http://{addr}/peer")).await.unwrap();
        assert_eq!(answer.status(), 200);
        let peer: SocketAddr = answer.text().await.unwrap().parse().unwrap();
        assert!(peer.ip().is_loopback());
        let _ = stop.send(true);
        server.await.unwrap();
    }

    fn headers(pairs: &[(header::HeaderName, &'static str)]) -> header::HeaderMap {
        pairs
            .iter()
            .map(|(k, v)| (k.clone(), header::HeaderValue::from_static(v)))
            .collect()
    }

    /// The page's script: gzip when accepted (and it inflates to the file), its tag
    /// answered 304 without a body, plain text otherwise.
    #[tokio::test]
    async fn page_files_are_tagged_revalidated_and_compressed() {
        use std::io::Read;
        let file = &PAGE_FILES[1];
        let plain = file.answer(&header::HeaderMap::new());
        assert_eq!(plain.status(), StatusCode::OK);
        assert_eq!(plain.headers()[header::CACHE_CONTROL], "no-cache");
        assert!(plain.headers().get(header::CONTENT_ENCODING).is_none());
        let etag = plain.headers()[header::ETAG].to_str().unwrap().to_string();
        let body = axum::body::to_bytes(plain.into_body(), usize::MAX)
            .await
            .unwrap();
        assert_eq!(body, webpage::APP_JS.as_bytes());

        let zipped = file.answer(&headers(&[(header::ACCEPT_ENCODING, "gzip, deflate, br")]));
        assert_eq!(zipped.headers()[header::CONTENT_ENCODING], "gzip");
        let body = axum::body::to_bytes(zipped.into_body(), usize::MAX)
            .await
            .unwrap();
        assert!(
            body.len() * 3 < webpage::APP_JS.len(),
            "{} bytes",
            body.len()
        );
        let mut text = String::new();
        flate2::read::GzDecoder::new(&body[..])
            .read_to_string(&mut text)
            .unwrap();
        assert_eq!(text, webpage::APP_JS);
        // gzip refused with q=0: plain.
        let refused = file.answer(&headers(&[(header::ACCEPT_ENCODING, "gzip;q=0, identity")]));
        assert!(refused.headers().get(header::CONTENT_ENCODING).is_none());

        let mut again = header::HeaderMap::new();
        again.insert(header::IF_NONE_MATCH, etag.parse().unwrap());
        let unchanged = file.answer(&again);
        assert_eq!(unchanged.status(), StatusCode::NOT_MODIFIED);
        let body = axum::body::to_bytes(unchanged.into_body(), usize::MAX)
            .await
            .unwrap();
        assert!(body.is_empty());
        // Another file's tag is not this one's.
        let other = PAGE_FILES[2].answer(&again);
        assert_eq!(other.status(), StatusCode::OK);
    }

    /// A connection that never starts its TLS handshake is closed at `header_timeout`
    /// of its accept (the clock is tokio's paused one: no wall time is waited).
    #[tokio::test(start_paused = true)]
    async fn a_tls_handshake_never_begun_is_closed_at_the_header_timeout() {
        use tokio::io::AsyncReadExt;
        let dir = tempfile::tempdir().unwrap();
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let tls =
            crate::tls::load(&crate::config::TlsSource::SelfSigned, dir.path(), &[], addr).unwrap();
        let app = Router::new().route("/", get(|| async { "ok" }));
        let (stop, shutdown) = watch::channel(false);
        let limits = Limits {
            header_timeout: Duration::from_secs(10),
            idle_timeout: Duration::from_secs(60),
            max_connections: 1,
        };
        let server = tokio::spawn(serve(listener, app, limits, Some(tls.config), shutdown));
        let opened = Instant::now();
        let mut silent = TcpStream::connect(addr).await.unwrap();
        let mut answer = Vec::new();
        let _ = silent.read_to_end(&mut answer).await;
        assert!(answer.is_empty());
        let waited = Instant::now() - opened;
        assert!(
            waited >= Duration::from_secs(10) && waited < Duration::from_secs(11),
            "{waited:?}"
        );
        let _ = stop.send(true);
        server.await.unwrap();
    }

    /// A request whose body stops arriving is answered 408 `body_timeout` when its
    /// deadline passes (the clock is tokio's paused one: no wall time is waited).
    #[tokio::test(start_paused = true)]
    async fn a_body_that_stops_arriving_is_answered_408() {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let app = Router::new().route(
            "/upload",
            axum::routing::post(|body: String| async move { body.len().to_string() }),
        );
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let (stop, shutdown) = watch::channel(false);
        let limits = Limits {
            header_timeout: Duration::from_secs(10),
            idle_timeout: Duration::from_secs(60),
            max_connections: 4,
        };
        let server = tokio::spawn(serve(listener, app, limits, None, shutdown));
        let mut client = TcpStream::connect(addr).await.unwrap();
        client
            .write_all(b"POST /upload HTTP/1.1\r\nhost: x\r\ncontent-length: 100\r\n\r\nabc")
            .await
            .unwrap();
        let mut answer = Vec::new();
        client.read_to_end(&mut answer).await.unwrap();
        let answer = String::from_utf8_lossy(&answer);
        assert!(answer.starts_with("HTTP/1.1 408"), "{answer}");
        assert!(answer.contains("\"body_timeout\""), "{answer}");
        assert!(answer.contains("service.idle_timeout_s"), "{answer}");

        // A whole body is answered as before.
        let mut client = TcpStream::connect(addr).await.unwrap();
        client
            .write_all(b"POST /upload HTTP/1.1\r\nhost: x\r\nconnection: close\r\ncontent-length: 3\r\n\r\nabc")
            .await
            .unwrap();
        let mut answer = Vec::new();
        client.read_to_end(&mut answer).await.unwrap();
        let answer = String::from_utf8_lossy(&answer);
        assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
        assert!(answer.ends_with("\r\n\r\n3"), "{answer}");
        let _ = stop.send(true);
        server.await.unwrap();
    }
}

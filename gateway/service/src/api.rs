//! The HTTP/WebSocket API (v1): routes, bearer-token auth, JSON errors, OpenAPI.

use crate::state::{lock, MachineState, Shared};
use axum::extract::rejection::{JsonRejection, PathRejection, QueryRejection};
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{ConnectInfo, DefaultBodyLimit, Path, Query, Request, State};
use axum::http::{header, HeaderMap, HeaderValue, Method, StatusCode};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use futures_util::{SinkExt, StreamExt};
use serde::Deserialize;
use serde_json::{json, Value};
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;
use store::{JobFilter, JobId, JobState, ProfileKind, StoreError};
use subtle::ConstantTimeEq;
use tokio::sync::broadcast::error::RecvError;
use tracing::warn;
use utoipa::OpenApi;

type AppState = Arc<Shared>;

/// An error answer: `{"error": code, "message": ...}`.
#[derive(Debug)]
pub struct ApiError {
    pub status: StatusCode,
    pub code: &'static str,
    pub message: String,
    /// The request field that was wrong, when one was.
    pub field: Option<String>,
}

impl ApiError {
    fn new(status: StatusCode, code: &'static str, message: impl Into<String>) -> ApiError {
        ApiError {
            status,
            code,
            message: message.into(),
            field: None,
        }
    }
    fn not_found(code: &'static str, message: impl Into<String>) -> ApiError {
        ApiError::new(StatusCode::NOT_FOUND, code, message)
    }
}

impl ApiError {
    /// Names the request field that was wrong (`params.grid_step_mm`).
    fn with_field(mut self, field: String) -> ApiError {
        self.field = Some(field);
        self
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let mut body = json!({"error": self.code, "message": self.message});
        if let Some(f) = self.field {
            body["field"] = json!(f);
        }
        (self.status, Json(body)).into_response()
    }
}

impl From<StoreError> for ApiError {
    fn from(e: StoreError) -> ApiError {
        let message = e.to_string();
        match e {
            StoreError::UnknownJob(_) => ApiError::not_found("unknown_job", message),
            StoreError::UnknownProfile { .. } | StoreError::UnknownProfileName { .. } => {
                ApiError::not_found("unknown_profile", message)
            }
            StoreError::WrongState { .. } => {
                ApiError::new(StatusCode::CONFLICT, "wrong_state", message)
            }
            StoreError::NothingToRollBack { .. } => {
                ApiError::new(StatusCode::CONFLICT, "nothing_to_roll_back", message)
            }
            StoreError::ProfileKindMismatch { .. } => {
                ApiError::new(StatusCode::CONFLICT, "profile_kind_mismatch", message)
            }
            StoreError::InvalidInput { .. } => {
                ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, "invalid_input", message)
            }
            _ => {
                warn!(error = %message, "store error");
                ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, "internal", message)
            }
        }
    }
}

impl From<JsonRejection> for ApiError {
    fn from(r: JsonRejection) -> ApiError {
        let status = r.status();
        let code = match status {
            StatusCode::PAYLOAD_TOO_LARGE => "body_too_large",
            StatusCode::UNPROCESSABLE_ENTITY => "invalid_body",
            StatusCode::UNSUPPORTED_MEDIA_TYPE => "unsupported_media_type",
            _ => "bad_json",
        };
        ApiError::new(status, code, r.body_text())
    }
}

impl From<PathRejection> for ApiError {
    fn from(r: PathRejection) -> ApiError {
        ApiError::new(StatusCode::BAD_REQUEST, "bad_path", r.body_text())
    }
}

impl From<QueryRejection> for ApiError {
    fn from(r: QueryRejection) -> ApiError {
        ApiError::new(StatusCode::BAD_REQUEST, "bad_query", r.body_text())
    }
}

type ApiResult<T> = Result<T, ApiError>;

/// Query keys that look like a credential; refused so tokens never land in access logs.
const TOKEN_KEYS: &[&str] = &["token", "access_token", "bearer", "api_key", "auth"];

async fn refuse_query_token(State(shared): State<AppState>, req: Request, next: Next) -> Response {
    if let Some(query) = req.uri().query() {
        for pair in query.split('&') {
            let key = pair.split('=').next().unwrap_or("").to_ascii_lowercase();
            let holds_token = pair.contains(shared.token.as_str());
            if TOKEN_KEYS.contains(&key.as_str()) || holds_token {
                return ApiError::new(
                    StatusCode::BAD_REQUEST,
                    "token_in_query",
                    "a token in the query string is refused (it would end up in logs); send it in the Authorization header",
                )
                .into_response();
            }
        }
    }
    next.run(req).await
}

/// The token a request presents: the bearer header, or the WebSocket subprotocol
/// `bearer.<token>` (browsers cannot set headers on a WebSocket).
fn presented_token(headers: &HeaderMap) -> Option<String> {
    if let Some(v) = headers.get(header::AUTHORIZATION) {
        // RFC 9110: the scheme is case-insensitive (`bearer`, `BEARER`).
        let (scheme, token) = v.to_str().ok()?.trim().split_once(' ')?;
        return scheme
            .eq_ignore_ascii_case("bearer")
            .then(|| token.trim().to_string());
    }
    let protocols = headers.get(header::SEC_WEBSOCKET_PROTOCOL)?.to_str().ok()?;
    protocols
        .split(',')
        .map(str::trim)
        .find_map(|p| p.strip_prefix("bearer."))
        .map(str::to_string)
}

async fn require_token(State(shared): State<AppState>, req: Request, next: Next) -> Response {
    let peer = req
        .extensions()
        .get::<ConnectInfo<SocketAddr>>()
        .map(|c| c.0.ip());
    let Some(token) = presented_token(req.headers()) else {
        return ApiError::new(
            StatusCode::UNAUTHORIZED,
            "missing_token",
            "this route needs the header `Authorization: Bearer <token>`",
        )
        .into_response();
    };
    let good: bool = token.as_bytes().ct_eq(shared.token.as_bytes()).into();
    if good {
        if let Some(peer) = peer {
            shared
                .bad_tokens
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .remove(&peer);
        }
        return next.run(req).await;
    }
    // Guessing is slowed down: each wrong token from a peer waits twice as long as the
    // previous one, up to the configured cap.
    let failures = peer.map_or(1, |peer| {
        let mut map = shared.bad_tokens.lock().unwrap_or_else(|p| p.into_inner());
        let n = map.entry(peer).or_insert(0);
        *n = n.saturating_add(1);
        *n
    });
    warn!(peer = ?peer, failures, path = %req.uri().path(), "wrong bearer token");
    let delay = (10u64 << failures.min(16)).min(shared.bad_token_delay_cap_ms);
    tokio::time::sleep(Duration::from_millis(delay)).await;
    ApiError::new(
        StatusCode::UNAUTHORIZED,
        "bad_token",
        "the bearer token is wrong",
    )
    .into_response()
}

/// The largest profile body accepted (an error map with dense lines is a few hundred kB,
/// above the service's request limit).
pub const MAX_PROFILE_BYTES: usize = 16 * 1024 * 1024;

/// The request body limits, per route.
#[derive(Debug, Clone, Copy)]
pub struct BodyLimits {
    /// Every route but the two below (`service.max_body_bytes`).
    pub default: usize,
    /// A job's submission, which may carry a layout (`service.max_job_body_bytes`).
    pub job: usize,
}

impl BodyLimits {
    /// The limit of a route and where it is set.
    fn of(&self, path: &str) -> (usize, &'static str) {
        if path.starts_with("/api/v1/machines/") && path.ends_with("/jobs") {
            (self.job, "service.max_job_body_bytes in BOX.toml")
        } else if path.contains("/profiles/") {
            (MAX_PROFILE_BYTES, "fixed")
        } else {
            (self.default, "service.max_body_bytes in BOX.toml")
        }
    }
}

/// A 413 says which limit was passed and where it is set, whatever refused the body.
async fn name_the_body_limit(limits: BodyLimits, req: Request, next: Next) -> Response {
    let path = req.uri().path().to_string();
    let response = next.run(req).await;
    if response.status() != StatusCode::PAYLOAD_TOO_LARGE {
        return response;
    }
    let (limit, set_by) = limits.of(&path);
    ApiError::new(
        StatusCode::PAYLOAD_TOO_LARGE,
        "body_too_large",
        format!("the request body is larger than {limit} bytes, the limit of {path} ({set_by})"),
    )
    .into_response()
}

/// The page's policy: its own scripts, styles and connections only (images also from
/// `blob:`, the charts it fetches with the token), never framed. An SVG is served
/// sandboxed: opened on its own it can run nothing in the service's origin.
const PAGE_POLICY: &str = "default-src 'self'; script-src 'self'; style-src 'self'; \
    img-src 'self' blob: data:; connect-src 'self'; object-src 'none'; base-uri 'none'; \
    form-action 'self'; frame-ancestors 'none'";
const SVG_POLICY: &str = "default-src 'none'; style-src 'unsafe-inline'; sandbox";

async fn security_headers(req: Request, next: Next) -> Response {
    let mut response = next.run(req).await;
    let headers = response.headers_mut();
    let svg = headers
        .get(header::CONTENT_TYPE)
        .is_some_and(|v| v.as_bytes().starts_with(b"image/svg+xml"));
    let policy = if svg { SVG_POLICY } else { PAGE_POLICY };
    for (name, value) in [
        (header::CONTENT_SECURITY_POLICY, policy),
        (header::X_CONTENT_TYPE_OPTIONS, "nosniff"),
        (header::X_FRAME_OPTIONS, "DENY"),
        (header::REFERRER_POLICY, "no-referrer"),
    ] {
        headers.insert(name, HeaderValue::from_static(value));
    }
    response
}

/// The router of the whole service.
pub fn router(shared: AppState, limits: BodyLimits, cors_origins: &[String]) -> Router {
    let api = Router::new()
        .route("/api/v1/openapi.json", get(openapi))
        .route("/api/v1/machines", get(machines))
        .route("/api/v1/machines/{machine}", get(machine))
        .route(
            "/api/v1/machines/{machine}/jobs",
            post(enqueue).layer(DefaultBodyLimit::max(limits.job)),
        )
        .route("/api/v1/jobs", get(jobs))
        .route("/api/v1/jobs/{id}", get(job))
        .route("/api/v1/jobs/{id}/cancel", post(cancel))
        .route("/api/v1/jobs/{id}/move", post(move_job))
        .route("/api/v1/machines/{machine}/queue", get(queue))
        .route("/api/v1/machines/{machine}/frame", get(frame_png))
        .route("/api/v1/machines/{machine}/frame.json", get(frame_json))
        .route("/api/v1/jobs/{id}/measurements", get(measurements))
        .route("/api/v1/jobs/{id}/charts", get(charts))
        .route("/api/v1/jobs/{id}/charts/{file}", get(chart))
        .route("/api/v1/jobs/{id}/files", get(files))
        .route("/api/v1/jobs/{id}/files/{name}", get(file))
        .route("/api/v1/machines/{machine}/profiles", get(profiles))
        .route(
            "/api/v1/machines/{machine}/profiles/{name}",
            post(add_profile),
        )
        .route(
            "/api/v1/machines/{machine}/profiles/{name}/{version}",
            get(profile),
        )
        .route(
            "/api/v1/machines/{machine}/profiles/{name}/{version}/heatmap.svg",
            get(heatmap),
        )
        .route(
            "/api/v1/machines/{machine}/profiles/{name}/{version}/diff",
            get(diff),
        )
        .route(
            "/api/v1/machines/{machine}/profiles/{name}/{version}/activate",
            post(activate),
        )
        .route(
            "/api/v1/machines/{machine}/profiles/{name}/rollback",
            post(rollback),
        )
        .route("/api/v1/events", get(events))
        .route_layer(middleware::from_fn_with_state(
            shared.clone(),
            require_token,
        ));
    let mut app = Router::new()
        .route("/healthz", get(|| async { Json(json!({"status": "ok"})) }))
        // The page's files: ETag, Cache-Control and gzip (serve.rs).
        .route(
            "/",
            get(|h: HeaderMap| async move { crate::serve::PAGE_FILES[0].answer(&h) }),
        )
        .route(
            "/app.js",
            get(|h: HeaderMap| async move { crate::serve::PAGE_FILES[1].answer(&h) }),
        )
        .route(
            "/style.css",
            get(|h: HeaderMap| async move { crate::serve::PAGE_FILES[2].answer(&h) }),
        )
        .merge(api)
        .fallback(|| async { ApiError::not_found("not_found", "no such route") })
        .layer(middleware::from_fn_with_state(
            shared.clone(),
            refuse_query_token,
        ))
        .layer(DefaultBodyLimit::max(limits.default))
        .layer(middleware::from_fn(move |req, next| {
            name_the_body_limit(limits, req, next)
        }))
        .layer(middleware::from_fn(security_headers))
        .with_state(shared);
    let origins: Vec<HeaderValue> = cors_origins
        .iter()
        .filter_map(|o| HeaderValue::from_str(o).ok())
        .collect();
    if !origins.is_empty() {
        app = app.layer(
            tower_http::cors::CorsLayer::new()
                .allow_origin(origins)
                .allow_methods([Method::GET, Method::POST])
                .allow_headers([header::AUTHORIZATION, header::CONTENT_TYPE]),
        );
    }
    app
}

#[derive(OpenApi)]
#[openapi(
    info(title = "gateway service", description = "Machines, job queues, profiles and events of a gateway box."),
    paths(openapi, machines, machine, enqueue, queue, frame_png, frame_json, jobs, job, cancel, move_job, measurements, charts, chart,
          files, file,
          profiles, add_profile, profile, diff, heatmap, activate, rollback, events),
    modifiers(&BearerAuth, &JobParams)
)]
pub struct ApiDoc;

/// Each job kind's params as `components.schemas["job.<kind>"]`: the request types the
/// API checks (`procedure::kinds::schemas`), from which the page builds its forms; and
/// its result, the job's `outcome.result`, as `job.<kind>.result`.
struct JobParams;
impl utoipa::Modify for JobParams {
    fn modify(&self, openapi: &mut utoipa::openapi::OpenApi) {
        let components = openapi.components.get_or_insert_with(Default::default);
        for (kind, schema) in procedure::kinds::schemas() {
            components.schemas.insert(format!("job.{kind}"), schema);
        }
        for kind in procedure::KINDS {
            components
                .schemas
                .insert(format!("job.{}.result", kind.name), kind.result_schema());
            components.schemas.extend(kind.referenced_schemas());
        }
    }
}

struct BearerAuth;
impl utoipa::Modify for BearerAuth {
    fn modify(&self, openapi: &mut utoipa::openapi::OpenApi) {
        use utoipa::openapi::security::{HttpAuthScheme, HttpBuilder, SecurityScheme};
        let components = openapi.components.get_or_insert_with(Default::default);
        components.add_security_scheme(
            "bearer",
            SecurityScheme::Http(HttpBuilder::new().scheme(HttpAuthScheme::Bearer).build()),
        );
        openapi.security = Some(vec![utoipa::openapi::security::SecurityRequirement::new(
            "bearer",
            Vec::<String>::new(),
        )]);
    }
}

/// The OpenAPI 3 document of this API.
#[utoipa::path(get, path = "/api/v1/openapi.json", responses((status = 200, description = "OpenAPI document")))]
async fn openapi() -> Json<utoipa::openapi::OpenApi> {
    Json(ApiDoc::openapi())
}

fn find_machine<'a>(shared: &'a Shared, id: &str) -> ApiResult<&'a Arc<crate::state::Machine>> {
    shared
        .machine(id)
        .ok_or_else(|| ApiError::not_found("unknown_machine", format!("no machine {id:?}")))
}

/// Every machine with its state, running job and queue length.
#[utoipa::path(get, path = "/api/v1/machines", responses((status = 200, description = "[Machine]")))]
async fn machines(State(shared): State<AppState>) -> Json<Value> {
    let list: Vec<Value> = shared
        .machines
        .iter()
        .map(|m| shared.machine_json(m))
        .collect();
    Json(Value::Array(list))
}

/// One machine.
#[utoipa::path(get, path = "/api/v1/machines/{machine}", params(("machine" = String, Path)),
    responses((status = 200, description = "Machine"), (status = 404, description = "unknown machine")))]
async fn machine(
    State(shared): State<AppState>,
    path: Result<Path<String>, PathRejection>,
) -> ApiResult<Json<Value>> {
    let Path(id) = path?;
    let m = find_machine(&shared, &id)?;
    Ok(Json(shared.machine_json(m)))
}

/// The body of `POST /api/v1/machines/{machine}/jobs`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JobRequest {
    pub kind: String,
    #[serde(default = "empty_object")]
    pub params: Value,
    #[serde(default)]
    pub if_idle: bool,
}

fn empty_object() -> Value {
    json!({})
}

/// Queue a job (202 with the queued JobRecord); with `"if_idle": true`, 409 when the
/// machine is busy or has a queue.
#[utoipa::path(post, path = "/api/v1/machines/{machine}/jobs", params(("machine" = String, Path)),
    request_body(content = Object, description = "{\"kind\": \"compensate\", \"params\": {\"targets\": 1}, \"if_idle\": false}"),
    responses((status = 202, description = "JobRecord (queued)"), (status = 404, description = "unknown machine"),
        (status = 400, description = "invalid_params: the field named by `field` was refused"),
        (status = 409, description = "machine_busy"), (status = 413, description = "body too large"),
        (status = 422, description = "invalid job")))]
async fn enqueue(
    State(shared): State<AppState>,
    path: Result<Path<String>, PathRejection>,
    body: Result<Json<JobRequest>, JsonRejection>,
) -> ApiResult<(StatusCode, Json<Value>)> {
    let Path(id) = path?;
    let m = find_machine(&shared, &id)?.clone();
    let Json(request) = body?;
    // The one check of a request: parsed into its procedure's type, every bound checked,
    // the field named; what is stored is the normalized request (defaults written out).
    let invalid = |e: procedure::RequestError| {
        // `params` itself, or one of its fields.
        let field = match e.field.as_str() {
            "params" => "params".to_string(),
            f => format!("params.{f}"),
        };
        ApiError::new(
            StatusCode::BAD_REQUEST,
            "invalid_params",
            format!("{field}: {}", e.message),
        )
        .with_field(field)
    };
    let parsed = procedure::Request::parse(&request.kind, &request.params).map_err(|e| {
        if e.field == "kind" {
            ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, "invalid_job", e.message)
        } else {
            invalid(e)
        }
    })?;
    let facts = procedure::registry::Facts {
        scan_area: *m.scan_area.lock().unwrap_or_else(|p| p.into_inner()),
    };
    let params = parsed.params();
    // The kind's own refusals when queued (a map too fine for the machine's travel, an
    // uploaded file its job's reader would refuse), off the async threads: a layout may
    // be megabytes.
    let kind = parsed.registered();
    let admitted = {
        let params = params.clone();
        tokio::task::spawn_blocking(move || kind.admit(&params, &facts))
            .await
            .map_err(|e| {
                ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, "internal", e.to_string())
            })?
    };
    admitted.map_err(invalid)?;
    if parsed.registered().uses.rotary && m.rotary.is_none() {
        return Err(ApiError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            "invalid_job",
            format!(
                "machine {:?} has no rotary table: give its [[machine]] a `rotary` job file in BOX.toml",
                m.id
            ),
        ));
    }
    let record = {
        let mut store = lock(&shared.store);
        if request.if_idle {
            let state = m.status.lock().unwrap_or_else(|p| p.into_inner()).state;
            let queued = store.queued(&m.id)?.len();
            if state == MachineState::Busy || queued > 0 {
                return Err(ApiError::new(
                    StatusCode::CONFLICT,
                    "machine_busy",
                    format!(
                        "machine {:?} is {} with {queued} job(s) queued",
                        m.id,
                        state.as_str()
                    ),
                ));
            }
        }
        store.enqueue(&m.id, &request.kind, &params)?
    };
    shared.emit_job(&record);
    shared.emit_machine(&m);
    m.wake.notify_one();
    Ok((
        StatusCode::ACCEPTED,
        Json(serde_json::to_value(record).unwrap_or(Value::Null)),
    ))
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct JobsQuery {
    machine: Option<String>,
    state: Option<String>,
    limit: Option<usize>,
    before: Option<JobId>,
}

/// Jobs, newest first, filtered by machine and state, paged with `before` (an id).
#[utoipa::path(get, path = "/api/v1/jobs",
    params(("machine" = Option<String>, Query), ("state" = Option<String>, Query),
           ("limit" = Option<usize>, Query), ("before" = Option<i64>, Query)),
    responses((status = 200, description = "[JobRecord]"), (status = 400, description = "bad query")))]
async fn jobs(
    State(shared): State<AppState>,
    query: Result<Query<JobsQuery>, QueryRejection>,
) -> ApiResult<Json<Value>> {
    let Query(q) = query?;
    let state = match q.state.as_deref() {
        None | Some("") => None,
        Some(s) => Some(JobState::parse(s).ok_or_else(|| {
            ApiError::new(
                StatusCode::BAD_REQUEST,
                "bad_query",
                format!("state={s:?} is not a job state"),
            )
        })?),
    };
    let filter = JobFilter {
        machine: q.machine.filter(|m| !m.is_empty()),
        state,
        limit: Some(q.limit.unwrap_or(100).clamp(1, 1000)),
        before_id: q.before,
    };
    let list = lock(&shared.store).jobs(&filter)?;
    Ok(Json(Value::Array(
        list.into_iter().map(list_entry).collect(),
    )))
}

/// A job as a list shows it (as its events carry it: [`crate::state::light_job`]).
fn list_entry(record: store::JobRecord) -> Value {
    crate::state::light_job(&record)
}

fn job_record(shared: &Shared, id: JobId) -> ApiResult<store::JobRecord> {
    lock(&shared.store)
        .job(id)?
        .ok_or_else(|| ApiError::not_found("unknown_job", format!("no job {id}")))
}

/// One job.
#[utoipa::path(get, path = "/api/v1/jobs/{id}", params(("id" = i64, Path)),
    responses((status = 200, description = "JobRecord"), (status = 404, description = "unknown job")))]
async fn job(
    State(shared): State<AppState>,
    path: Result<Path<JobId>, PathRejection>,
) -> ApiResult<Json<Value>> {
    let Path(id) = path?;
    let record = job_record(&shared, id)?;
    // The result as a person reads it: the same summary the CLI prints.
    let summary = record
        .result
        .as_ref()
        .and_then(|r| procedure::summary(&record.kind, r));
    let mut v = serde_json::to_value(record).unwrap_or(Value::Null);
    v["summary"] = json!(summary);
    Ok(Json(v))
}

/// Cancel a job: a queued one at once; a running one is stopped by its runner (the
/// stage told to stop, every measurement kept), answered once it has finished.
#[utoipa::path(post, path = "/api/v1/jobs/{id}/cancel", params(("id" = i64, Path)),
    responses((status = 200, description = "JobRecord"), (status = 404, description = "unknown job"),
        (status = 409, description = "the job has finished")))]
async fn cancel(
    State(shared): State<AppState>,
    path: Result<Path<JobId>, PathRejection>,
) -> ApiResult<Json<Value>> {
    let Path(id) = path?;
    let record = job_record(&shared, id)?;
    let machine = shared.machine(&record.machine).cloned();
    if record.state == JobState::Queued {
        let cancelled = lock(&shared.store).cancel_queued(id);
        if let Ok(r) = cancelled {
            shared.emit_job(&r);
            if let Some(m) = &machine {
                shared.emit_machine(m);
            }
            return Ok(Json(serde_json::to_value(r).unwrap_or(Value::Null)));
        }
        // It started meanwhile: cancel it as a running job.
    }
    let record = job_record(&shared, id)?;
    if record.state.is_final() {
        return Err(ApiError::new(
            StatusCode::CONFLICT,
            "job_finished",
            format!(
                "job {id} is {}; only queued or running jobs can be cancelled",
                record.state
            ),
        ));
    }
    let mut events = shared.events.subscribe();
    let notify = machine.as_ref().and_then(|m| {
        m.cancel
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .as_ref()
            .filter(|(running, _)| *running == id)
            .map(|(_, n)| n.clone())
    });
    if let Some(n) = notify {
        n.notify_one();
        // Answer with the final record: wait for the worker to save it (bounded).
        let _ = tokio::time::timeout(Duration::from_secs(30), async {
            loop {
                match events.recv().await {
                    Ok(text) => {
                        if let Ok(v) = serde_json::from_str::<Value>(&text) {
                            let job = &v["job"];
                            if v["type"] == "job"
                                && job["id"] == id
                                && JobState::parse(job["state"].as_str().unwrap_or(""))
                                    .is_some_and(JobState::is_final)
                            {
                                return;
                            }
                        }
                    }
                    Err(RecvError::Lagged(_)) => {
                        if job_record(&shared, id)
                            .map(|r| r.state.is_final())
                            .unwrap_or(true)
                        {
                            return;
                        }
                    }
                    Err(RecvError::Closed) => return,
                }
            }
        })
        .await;
    }
    Ok(Json(
        serde_json::to_value(job_record(&shared, id)?).unwrap_or(Value::Null),
    ))
}

/// A machine's queued jobs in the order they will run (the first runs next).
#[utoipa::path(get, path = "/api/v1/machines/{machine}/queue", params(("machine" = String, Path)),
    responses((status = 200, description = "[JobRecord] in run order"), (status = 404, description = "unknown_machine")))]
async fn queue(
    State(shared): State<AppState>,
    path: Result<Path<String>, PathRejection>,
) -> ApiResult<Json<Value>> {
    let Path(id) = path?;
    let m = find_machine(&shared, &id)?;
    let list = lock(&shared.store).queued(&m.id)?;
    Ok(Json(serde_json::to_value(list).unwrap_or(Value::Null)))
}

/// The machine's last frame (memory only), or 404 `no_frame`.
fn last_frame(shared: &Shared, id: &str) -> ApiResult<Arc<crate::state::LastFrame>> {
    let m = find_machine(shared, id)?;
    let frame = m.frame.lock().unwrap_or_else(|p| p.into_inner()).clone();
    frame.ok_or_else(|| {
        ApiError::not_found(
            "no_frame",
            format!("machine {id:?} has shown no camera frame since the service started"),
        )
    })
}

/// The camera's last frame a job took on this machine: an 8-bit grey PNG at most 320
/// pixels wide (`frame.json` is its overlay).
#[utoipa::path(get, path = "/api/v1/machines/{machine}/frame", params(("machine" = String, Path)),
    responses((status = 200, description = "image/png", content_type = "image/png"),
        (status = 404, description = "unknown_machine, no_frame")))]
async fn frame_png(
    State(shared): State<AppState>,
    path: Result<Path<String>, PathRejection>,
) -> ApiResult<Response> {
    let Path(id) = path?;
    let f = last_frame(&shared, &id)?;
    Ok((
        [
            (header::CONTENT_TYPE, "image/png"),
            (header::CACHE_CONTROL, "no-store"),
        ],
        f.png.clone(),
    )
        .into_response())
}

/// The last frame's overlay: `job_id`, `at`, and `overlay` (`width`, `height`, `dots`
/// in the thumbnail's pixels, `centre_px`, the measured point `centre_mm`, `target_mm`,
/// `deviation_um`, `sequence`).
#[utoipa::path(get, path = "/api/v1/machines/{machine}/frame.json", params(("machine" = String, Path)),
    responses((status = 200, description = "{job_id, at, overlay}"),
        (status = 404, description = "unknown_machine, no_frame")))]
async fn frame_json(
    State(shared): State<AppState>,
    path: Result<Path<String>, PathRejection>,
) -> ApiResult<Json<Value>> {
    let Path(id) = path?;
    let f = last_frame(&shared, &id)?;
    Ok(Json(
        json!({"machine": id, "job_id": f.job, "at": f.at, "overlay": f.overlay}),
    ))
}

/// Where `POST /api/v1/jobs/{id}/move` puts the job, read from `{"before": id | null}`
/// or `{"position": n}` (exactly one), each wrong field named.
fn queue_place(body: &Value) -> ApiResult<store::QueuePlace> {
    let invalid = |field: &str, message: String| {
        ApiError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            "invalid_body",
            format!("{field}: {message}"),
        )
        .with_field(field.to_string())
    };
    let object = body.as_object().ok_or_else(|| {
        invalid(
            "body",
            "an object: {\"before\": job id or null} or {\"position\": n}".into(),
        )
    })?;
    if let Some(key) = object
        .keys()
        .find(|k| !["before", "position"].contains(&k.as_str()))
    {
        return Err(invalid(
            key,
            "unknown field; give `before` or `position`".into(),
        ));
    }
    match (object.get("before"), object.get("position")) {
        (Some(_), Some(_)) => Err(invalid("position", "give `before` or `position`, not both".into())),
        (None, None) => Err(invalid("before", "missing: give `before` (a queued job's id, or null for last) or `position` (0 runs next)".into())),
        (Some(Value::Null), None) => Ok(store::QueuePlace::Before(None)),
        (Some(v), None) => v
            .as_i64()
            .map(|id| store::QueuePlace::Before(Some(id)))
            .ok_or_else(|| invalid("before", format!("a job id or null, got {v}"))),
        (None, Some(v)) => v
            .as_u64()
            .and_then(|p| usize::try_from(p).ok())
            .map(store::QueuePlace::Position)
            .ok_or_else(|| invalid("position", format!("an integer from 0, got {v}"))),
    }
}

/// Move a queued job in its machine's queue: before another queued job of the same
/// machine (`{"before": id}`, `null`: last) or to an index (`{"position": 0}` runs
/// next). Answers the machine's queue in its new order.
#[utoipa::path(post, path = "/api/v1/jobs/{id}/move", params(("id" = i64, Path)),
    request_body(content = Object, description = "{\"before\": 12} | {\"before\": null} | {\"position\": 0}"),
    responses((status = 200, description = "{machine, queue: [JobRecord]} in run order"),
        (status = 404, description = "unknown_job"),
        (status = 409, description = "not_queued: the job is running or finished"),
        (status = 422, description = "invalid_body: `field` names what is wrong (`before` not queued on this machine, `position` past the queue)")))]
async fn move_job(
    State(shared): State<AppState>,
    path: Result<Path<JobId>, PathRejection>,
    body: Result<Json<Value>, JsonRejection>,
) -> ApiResult<Json<Value>> {
    let Path(id) = path?;
    let Json(body) = body?;
    let record = job_record(&shared, id)?;
    let place = queue_place(&body)?;
    let not_queued = |state: JobState| {
        ApiError::new(
            StatusCode::CONFLICT,
            "not_queued",
            format!("job {id} is {state}; only a queued job can be moved"),
        )
    };
    if record.state != JobState::Queued {
        return Err(not_queued(record.state));
    }
    let moved = {
        let mut store = lock(&shared.store);
        if let store::QueuePlace::Position(p) = place {
            let len = store.queued(&record.machine)?.len();
            if p >= len {
                return Err(ApiError::new(
                    StatusCode::UNPROCESSABLE_ENTITY,
                    "invalid_body",
                    format!(
                        "position: machine {:?} has {len} queued job(s): 0 to {}",
                        record.machine,
                        len.saturating_sub(1)
                    ),
                )
                .with_field("position".into()));
            }
        }
        store.move_queued(id, place)
    };
    let queue = match moved {
        Ok(queue) => queue,
        Err(StoreError::WrongState { state, .. }) => return Err(not_queued(state)),
        Err(StoreError::InvalidInput {
            what: "before",
            why,
        }) => {
            return Err(ApiError::new(
                StatusCode::UNPROCESSABLE_ENTITY,
                "invalid_body",
                format!("before: {why}"),
            )
            .with_field("before".into()))
        }
        Err(e) => return Err(e.into()),
    };
    if let Some(m) = shared.machine(&record.machine) {
        shared.emit_machine(m);
    }
    Ok(Json(json!({"machine": record.machine, "queue": queue})))
}

/// The job's measurements, in the order taken; the header `X-Last-Measurement-Row` is
/// the `row` of the newest one's event (a client appends only events after it).
#[utoipa::path(get, path = "/api/v1/jobs/{id}/measurements", params(("id" = i64, Path)),
    responses((status = 200, description = "[object]; header X-Last-Measurement-Row"), (status = 404, description = "unknown job")))]
async fn measurements(
    State(shared): State<AppState>,
    path: Result<Path<JobId>, PathRejection>,
) -> ApiResult<Response> {
    let Path(id) = path?;
    job_record(&shared, id)?;
    // One hold of the lock: the list and its last row are the same snapshot.
    let (list, last) = {
        let store = lock(&shared.store);
        (store.measurements(id)?, store.last_measurement_row(id)?)
    };
    let mut response = Json(Value::Array(list)).into_response();
    if let Some(last) = last {
        response
            .headers_mut()
            .insert("x-last-measurement-row", HeaderValue::from(last));
    }
    Ok(response)
}

/// A job's charts: the SVG files it wrote with a caption (`name` without `.svg`,
/// title); a record stored before files were kept has them in its result's `charts`.
fn job_charts(shared: &Shared, record: &store::JobRecord) -> ApiResult<Vec<(String, String)>> {
    let files = lock(&shared.store).job_files(record.id)?;
    let mut charts: Vec<(String, String)> = files
        .into_iter()
        .filter(|f| f.media_type == "image/svg+xml")
        .filter_map(|f| Some((f.name.strip_suffix(".svg")?.to_string(), f.title?)))
        .collect();
    if let Some(old) = record
        .result
        .as_ref()
        .and_then(|r| r.get("charts"))
        .and_then(Value::as_object)
    {
        charts.extend(
            old.iter().filter_map(|(name, c)| {
                Some((name.clone(), c.get("title")?.as_str()?.to_string()))
            }),
        );
    }
    Ok(charts)
}

/// The job's charts: `[{"name", "title", "url"}]`.
#[utoipa::path(get, path = "/api/v1/jobs/{id}/charts", params(("id" = i64, Path)),
    responses((status = 200, description = "[{name, title, url}]"), (status = 404, description = "unknown job")))]
async fn charts(
    State(shared): State<AppState>,
    path: Result<Path<JobId>, PathRejection>,
) -> ApiResult<Json<Value>> {
    let Path(id) = path?;
    let record = job_record(&shared, id)?;
    let list: Vec<Value> = job_charts(&shared, &record)?
        .into_iter()
        .map(|(name, title)| json!({"name": name, "title": title, "url": format!("/api/v1/jobs/{id}/charts/{name}.svg")}))
        .collect();
    Ok(Json(Value::Array(list)))
}

/// One chart of a job as SVG.
#[utoipa::path(get, path = "/api/v1/jobs/{id}/charts/{file}", params(("id" = i64, Path), ("file" = String, Path, description = "<name>.svg")),
    responses((status = 200, description = "image/svg+xml", content_type = "image/svg+xml"), (status = 404, description = "unknown job or chart")))]
async fn chart(
    State(shared): State<AppState>,
    path: Result<Path<(JobId, String)>, PathRejection>,
) -> ApiResult<Response> {
    let Path((id, file)) = path?;
    let record = job_record(&shared, id)?;
    let unknown =
        || ApiError::not_found("unknown_chart", format!("job {id} has no chart {file:?}"));
    let name = file.strip_suffix(".svg").ok_or_else(unknown)?;
    let kept = lock(&shared.store).job_file(id, &file)?;
    let svg = match kept {
        Some((media_type, body)) if media_type == "image/svg+xml" => body,
        _ => record
            .result
            .as_ref()
            .and_then(|r| r.get("charts")?.get(name)?.get("svg")?.as_str())
            .map(|svg| svg.as_bytes().to_vec())
            .ok_or_else(unknown)?,
    };
    Ok(([(header::CONTENT_TYPE, "image/svg+xml")], svg).into_response())
}

/// The files the job wrote (charts, tables, reports, a layout job's shifted layout):
/// `[{"name", "title", "media_type", "size", "url"}]`.
#[utoipa::path(get, path = "/api/v1/jobs/{id}/files", params(("id" = i64, Path)),
    responses((status = 200, description = "[{name, title, media_type, size, url}]"), (status = 404, description = "unknown job")))]
async fn files(
    State(shared): State<AppState>,
    path: Result<Path<JobId>, PathRejection>,
) -> ApiResult<Json<Value>> {
    let Path(id) = path?;
    job_record(&shared, id)?;
    let list: Vec<Value> = lock(&shared.store)
        .job_files(id)?
        .into_iter()
        .map(|f| {
            let url = format!("/api/v1/jobs/{id}/files/{}", f.name);
            let mut v = serde_json::to_value(f).unwrap_or(Value::Null);
            v["url"] = json!(url);
            v
        })
        .collect();
    Ok(Json(Value::Array(list)))
}

/// One file of a job with its media type: pictures shown, anything else downloaded.
#[utoipa::path(get, path = "/api/v1/jobs/{id}/files/{name}", params(("id" = i64, Path), ("name" = String, Path)),
    responses((status = 200, description = "the file"), (status = 404, description = "unknown job or file")))]
async fn file(
    State(shared): State<AppState>,
    path: Result<Path<(JobId, String)>, PathRejection>,
) -> ApiResult<Response> {
    let Path((id, name)) = path?;
    job_record(&shared, id)?;
    let (media_type, body) = lock(&shared.store).job_file(id, &name)?.ok_or_else(|| {
        ApiError::not_found("unknown_file", format!("job {id} has no file {name:?}"))
    })?;
    let content_type = HeaderValue::from_str(&media_type)
        .unwrap_or(HeaderValue::from_static("application/octet-stream"));
    let mut response = ([(header::CONTENT_TYPE, content_type)], body).into_response();
    if !matches!(media_type.as_str(), "image/svg+xml" | "image/png") {
        // The name is a plain file name (the store refuses any other).
        if let Ok(v) = HeaderValue::from_str(&format!("attachment; filename=\"{name}\"")) {
            response
                .headers_mut()
                .insert(header::CONTENT_DISPOSITION, v);
        }
    }
    Ok(response)
}

/// The machine's profile versions.
#[utoipa::path(get, path = "/api/v1/machines/{machine}/profiles", params(("machine" = String, Path)),
    responses((status = 200, description = "[ProfileVersion]"), (status = 404, description = "unknown machine")))]
async fn profiles(
    State(shared): State<AppState>,
    path: Result<Path<String>, PathRejection>,
) -> ApiResult<Json<Value>> {
    let Path(id) = path?;
    find_machine(&shared, &id)?;
    let list = lock(&shared.store).profiles(&id)?;
    Ok(Json(serde_json::to_value(list).unwrap_or(Value::Null)))
}

/// The body of `POST /api/v1/machines/{machine}/profiles/{name}`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProfileUpload {
    /// "error_map", "volumetric" or "rotary".
    pub kind: String,
    /// error_map: a map version file's JSON (`gateway map`); rotary: the errors JSON
    /// (`gateway rotary identify`); volumetric: `{"text": "<model file>"}`.
    pub body: Value,
    #[serde(default)]
    pub note: Option<String>,
}

/// Checks a profile body with the reader of its kind; the error names what is wrong.
pub fn check_profile(kind: &str, body: &Value) -> Result<ProfileKind, String> {
    match kind {
        "error_map" => protocol::errormap::ErrorMap::from_json("body", &body.to_string())
            .map(|_| ProfileKind::ErrorMap)
            .map_err(|e| e.to_string()),
        "rotary" => rotary::LocationErrors::from_json(&body.to_string())
            .map(|_| ProfileKind::Rotary)
            .map_err(|e| format!("body: {e}")),
        "volumetric" => {
            let text = body
                .get("text")
                .and_then(Value::as_str)
                .ok_or("body.text: the volumetric model file's text is missing")?;
            protocol::volumetric::parse_model(text)
                .map(|_| ProfileKind::Volumetric)
                .map_err(|e| format!("body.text: {e}"))
        }
        other => Err(format!(
            "kind {other:?}: one of \"error_map\", \"volumetric\", \"rotary\""
        )),
    }
}

/// Add a profile version (not active until activated): the body is checked by the
/// reader of its kind first, so nothing unreadable is stored.
#[utoipa::path(post, path = "/api/v1/machines/{machine}/profiles/{name}",
    params(("machine" = String, Path), ("name" = String, Path)),
    request_body(content = Object, description = "{\"kind\": \"error_map\", \"body\": {...}, \"note\": \"...\"}"),
    responses((status = 201, description = "ProfileVersion"), (status = 404, description = "unknown machine"),
        (status = 409, description = "the name holds another kind"), (status = 422, description = "invalid profile")))]
async fn add_profile(
    State(shared): State<AppState>,
    path: Result<Path<(String, String)>, PathRejection>,
    body: axum::body::Body,
) -> ApiResult<(StatusCode, Json<Value>)> {
    let Path((machine, name)) = path?;
    find_machine(&shared, &machine)?;
    // Read here with the profile's own limit (the service's body limit is for requests).
    let bytes = axum::body::to_bytes(body, MAX_PROFILE_BYTES)
        .await
        .map_err(|_| {
            ApiError::new(
                StatusCode::PAYLOAD_TOO_LARGE,
                "body_too_large",
                format!("a profile body is at most {MAX_PROFILE_BYTES} bytes"),
            )
        })?;
    let upload: ProfileUpload = serde_json::from_slice(&bytes).map_err(|e| {
        ApiError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            "invalid_json",
            format!("body: {e}"),
        )
    })?;
    if !crate::config::valid_id(&name) {
        return Err(ApiError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            "invalid_profile",
            format!("profile name {name:?}: letters, digits, '-', '_' and '.' only"),
        ));
    }
    let kind = check_profile(&upload.kind, &upload.body)
        .map_err(|m| ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, "invalid_profile", m))?;
    let p = lock(&shared.store).add_profile(
        &machine,
        &name,
        kind,
        &upload.body,
        None,
        upload.note.as_deref(),
    )?;
    Ok((
        StatusCode::CREATED,
        Json(serde_json::to_value(p).unwrap_or(Value::Null)),
    ))
}

fn profile_of(
    shared: &Shared,
    machine: &str,
    name: &str,
    version: u32,
) -> ApiResult<(store::ProfileVersion, Value)> {
    find_machine(shared, machine)?;
    lock(&shared.store)
        .profile(machine, name, version)?
        .ok_or_else(|| {
            ApiError::not_found(
                "unknown_profile",
                format!("machine {machine:?} has no profile {name:?} version {version}"),
            )
        })
}

/// One profile version with its body.
#[utoipa::path(get, path = "/api/v1/machines/{machine}/profiles/{name}/{version}",
    params(("machine" = String, Path), ("name" = String, Path), ("version" = u32, Path)),
    responses((status = 200, description = "{profile, body}"), (status = 404, description = "unknown machine or profile")))]
async fn profile(
    State(shared): State<AppState>,
    path: Result<Path<(String, String, u32)>, PathRejection>,
) -> ApiResult<Json<Value>> {
    let Path((machine, name, version)) = path?;
    let (profile, body) = profile_of(&shared, &machine, &name, version)?;
    Ok(Json(json!({"profile": profile, "body": body})))
}

/// `?against=N`: the version a diff compares with (default: the one before).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct DiffQuery {
    against: Option<u32>,
}

/// Numbers of a JSON body by their dotted path (`errors.dx_mm`, `centres[3].x`).
fn numbers(prefix: String, v: &Value, into: &mut Vec<(String, f64)>) {
    match v {
        Value::Number(n) => into.extend(n.as_f64().map(|x| (prefix, x))),
        Value::Object(o) => {
            for (k, inner) in o {
                let path = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                numbers(path, inner, into);
            }
        }
        Value::Array(a) => {
            for (k, inner) in a.iter().enumerate() {
                numbers(format!("{prefix}[{k}]"), inner, into);
            }
        }
        _ => {}
    }
}

/// What changed from one version of a profile to another: an error map node by node
/// (max and rms of the change, where the largest is, identity fields that differ), any
/// other profile as its numbers that changed (largest change first, at most 100).
#[utoipa::path(get, path = "/api/v1/machines/{machine}/profiles/{name}/{version}/diff",
    params(("machine" = String, Path), ("name" = String, Path), ("version" = u32, Path),
        ("against" = Option<u32>, Query, description = "the version compared with (default: the one before)")),
    responses((status = 200, description = "{from, to, kind, ...}"), (status = 404, description = "unknown machine or profile"),
        (status = 422, description = "not_comparable: grids differ")))]
async fn diff(
    State(shared): State<AppState>,
    path: Result<Path<(String, String, u32)>, PathRejection>,
    query: Result<Query<DiffQuery>, QueryRejection>,
) -> ApiResult<Json<Value>> {
    let Path((machine, name, version)) = path?;
    let Query(q) = query?;
    let against = match q.against {
        Some(v) => v,
        None if version > 1 => version - 1,
        None => {
            return Err(ApiError::not_found(
                "unknown_profile",
                format!("{name:?} version 1 has no version before it; give ?against=N"),
            ))
        }
    };
    let (old_profile, old) = profile_of(&shared, &machine, &name, against)?;
    let (new_profile, new) = profile_of(&shared, &machine, &name, version)?;
    let mut answer = json!({"profile": name, "machine": machine, "from": against,
        "to": version, "kind": new_profile.kind});
    if old_profile.kind == ProfileKind::ErrorMap && new_profile.kind == ProfileKind::ErrorMap {
        let as_map = |body: &Value, v: u32| {
            crate::sink::profile_map(body).map_err(|e| {
                ApiError::new(
                    StatusCode::UNPROCESSABLE_ENTITY,
                    "not_comparable",
                    format!("version {v}: {e}"),
                )
            })
        };
        let d = errormap::diff::compare(&as_map(&old, against)?, &as_map(&new, version)?)
            .map_err(|e| ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, "not_comparable", e))?;
        answer["summary"] = json!(format!(
            "v{against} -> v{version}: the compensated tool point moves by at most {:.2} µm (rms {:.2} µm over {} points, both approaches of each axis), most at X {:.1} Y {:.1} mm ({}); dense lines {:.2} µm, yaw {:.1} µrad, backlash {:.2} µm, squareness {:+.1} µrad{}",
            d.max_um, d.rms_um, d.nodes, d.max_at_mm[0], d.max_at_mm[1], d.max_approach,
            d.lines_max_um, d.yaw_max_urad, d.backlash_max_um, d.squareness_change_urad,
            if d.identity_changed.is_empty() { String::new() }
            else { format!("; identity changed: {}", d.identity_changed.join(", ")) }
        ));
        answer["map"] = json!(d);
        return Ok(Json(answer));
    }
    let (mut a, mut b) = (Vec::new(), Vec::new());
    numbers(String::new(), &old, &mut a);
    numbers(String::new(), &new, &mut b);
    let before: std::collections::HashMap<_, _> = a.into_iter().collect();
    let mut changed: Vec<Value> = b
        .iter()
        .filter_map(|(k, v)| {
            let was = *before.get(k)?;
            (was != *v).then(|| json!({"field": k, "from": was, "to": v, "change": v - was}))
        })
        .collect();
    changed.sort_by(|x, y| {
        let m = |v: &Value| v["change"].as_f64().unwrap_or(0.0).abs();
        m(y).total_cmp(&m(x))
    });
    answer["summary"] = json!(format!(
        "v{against} -> v{version}: {} numbers changed",
        changed.len()
    ));
    changed.truncate(100);
    answer["changed"] = json!(changed);
    Ok(Json(answer))
}

/// The heat map of an error-map profile (SVG), when its body carries one.
#[utoipa::path(get, path = "/api/v1/machines/{machine}/profiles/{name}/{version}/heatmap.svg",
    params(("machine" = String, Path), ("name" = String, Path), ("version" = u32, Path)),
    responses((status = 200, description = "image/svg+xml", content_type = "image/svg+xml"), (status = 404, description = "unknown profile or no heat map")))]
async fn heatmap(
    State(shared): State<AppState>,
    path: Result<Path<(String, String, u32)>, PathRejection>,
) -> ApiResult<Response> {
    let Path((machine, name, version)) = path?;
    let (profile, body) = profile_of(&shared, &machine, &name, version)?;
    let no_heatmap = || {
        ApiError::not_found(
            "no_heatmap",
            format!("profile {name:?} version {version} has no heat map"),
        )
    };
    // A drawing kept with the profile, else one drawn from the error map itself.
    let svg = match body.get("heatmap_svg").and_then(Value::as_str) {
        Some(svg) => svg.to_string(),
        None if profile.kind == ProfileKind::ErrorMap => {
            let map = protocol::errormap::ErrorMap::from_json("profile", &body.to_string())
                .map_err(|_| no_heatmap())?;
            let chart = errormap::heatmap::HeatMap {
                map: &map,
                title: format!("Error map {name} v{version}"),
            };
            plot::render_svg(&chart, 900, 600).map_err(|e| {
                ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, "internal", e.to_string())
            })?
        }
        None => return Err(no_heatmap()),
    };
    Ok(([(header::CONTENT_TYPE, "image/svg+xml")], svg).into_response())
}

/// Make a profile version the active one of its name and the one in use for its kind
/// (`in_use`: jobs apply it), also when it was active but displaced by another profile.
#[utoipa::path(post, path = "/api/v1/machines/{machine}/profiles/{name}/{version}/activate",
    params(("machine" = String, Path), ("name" = String, Path), ("version" = u32, Path)),
    responses((status = 200, description = "ProfileVersion"), (status = 404, description = "unknown machine or profile")))]
async fn activate(
    State(shared): State<AppState>,
    path: Result<Path<(String, String, u32)>, PathRejection>,
) -> ApiResult<Json<Value>> {
    let Path((machine, name, version)) = path?;
    profile_of(&shared, &machine, &name, version)?;
    let p = lock(&shared.store).activate(&machine, &name, version)?;
    Ok(Json(serde_json::to_value(p).unwrap_or(Value::Null)))
}

/// Back to the version active before the current one.
#[utoipa::path(post, path = "/api/v1/machines/{machine}/profiles/{name}/rollback",
    params(("machine" = String, Path), ("name" = String, Path)),
    responses((status = 200, description = "ProfileVersion"), (status = 404, description = "unknown machine or profile"),
        (status = 409, description = "nothing to roll back to")))]
async fn rollback(
    State(shared): State<AppState>,
    path: Result<Path<(String, String)>, PathRejection>,
) -> ApiResult<Json<Value>> {
    let Path((machine, name)) = path?;
    find_machine(&shared, &machine)?;
    let p = lock(&shared.store).rollback(&machine, &name)?;
    Ok(Json(serde_json::to_value(p).unwrap_or(Value::Null)))
}

/// The event stream (WebSocket): `hello`, then `machine`, `job`, `progress`,
/// `measurement` messages. Auth: the bearer header or the subprotocols
/// `["gateway.v1", "bearer.<token>"]` (answered `gateway.v1`).
#[utoipa::path(get, path = "/api/v1/events", responses((status = 101, description = "WebSocket upgrade")))]
async fn events(
    State(shared): State<AppState>,
    ws: Result<WebSocketUpgrade, axum::extract::ws::rejection::WebSocketUpgradeRejection>,
) -> Response {
    match ws {
        Ok(ws) => ws
            .protocols(["gateway.v1"])
            .on_upgrade(move |socket| client(socket, shared)),
        Err(r) => {
            ApiError::new(StatusCode::BAD_REQUEST, "not_websocket", r.body_text()).into_response()
        }
    }
}

async fn client(socket: WebSocket, shared: AppState) {
    let mut events = shared.events.subscribe();
    let mut shutdown = shared.shutdown.clone();
    let (mut tx, mut rx) = socket.split();
    let machines: Vec<Value> = shared
        .machines
        .iter()
        .map(|m| shared.machine_json(m))
        .collect();
    let hello = json!({"type": "hello", "machines": machines}).to_string();
    if tx.send(Message::Text(hello.into())).await.is_err() {
        return;
    }
    // A client that cannot keep up (the broadcast buffer overtook it, or a send
    // stalls) is dropped; the service never waits on it.
    let send_timeout = Duration::from_secs(5);
    loop {
        tokio::select! {
            event = events.recv() => match event {
                Ok(text) => {
                    let sent = tokio::time::timeout(send_timeout, tx.send(Message::Text(text.to_string().into()))).await;
                    if !matches!(sent, Ok(Ok(()))) {
                        break;
                    }
                }
                Err(RecvError::Lagged(n)) => {
                    warn!(missed = n, "event client too slow; dropped");
                    let _ = tx.send(Message::Close(None)).await;
                    break;
                }
                Err(RecvError::Closed) => break,
            },
            incoming = rx.next() => match incoming {
                None | Some(Err(_)) | Some(Ok(Message::Close(_))) => break,
                Some(Ok(_)) => {}
            },
            _ = async { let _ = shutdown.wait_for(|s| *s).await; } => {
                let _ = tx.send(Message::Close(None)).await;
                break;
            }
        }
    }
}

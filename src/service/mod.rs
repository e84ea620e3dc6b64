//! The depth service (`semdepth serve`): the HTTP and WebSocket API of
//! `../shared/docs/api.md` over sessions and calibrations, with durable
//! SQLite storage. Everything async lives under this module; the vision
//! code it calls is pure and runs on the blocking pool.
//!
//! - [`serve`]: runs the server on a given listener until a shutdown future
//!   resolves (tests pass a port-0 listener).
//! - [`listener`]: the accept loop (header deadline, connection cap).
//! - [`state`]: configuration, and the handle every route gets.
//! - [`db`]: the one owner of calibrations and sessions, written through to storage.
//! - [`storage`]: SQLite on its own threads (group commit), migrations and
//!   the stored, versioned form of a session's objects.
//! - [`pipeline`]: decode and track one pair, in session order, bounded.
//! - [`wire`]: SDP1, the WebSocket pair message, parsed and encoded.
//! - [`budget`]: the memory budget for bodies, messages and decoded images in flight.
//! - [`calibrations`], [`sessions`], [`ws`], [`ops`]: the routes.
//! - [`live`]: the browser page at `/`, latest frames as PNG, result events.
//! - [`api`], [`error`]: the wire types (requests, responses, versioned) and
//!   the one error type.
//! - [`merge_patch`]: JSON merge patches (the parameters of a session's PATCH) and their schemas.
//! - [`stamp`]: time stamps and ids.
//! - [`metrics`]: Prometheus counters and histograms.

use std::future::Future;
use std::sync::{Arc, OnceLock};
use std::time::Duration;

use axum::extract::{DefaultBodyLimit, Request};
use axum::http::{header, HeaderName};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::Router;
use subtle::ConstantTimeEq;
use tokio::net::TcpListener;
use tower_http::request_id::{MakeRequestUuid, PropagateRequestIdLayer, SetRequestIdLayer};
use tower_http::trace::TraceLayer;
use utoipa::openapi::security::{HttpAuthScheme, HttpBuilder, SecurityScheme};
use utoipa::openapi::OpenApi as OpenApiDoc;
use utoipa::{Modify, OpenApi};
use utoipa_axum::router::OpenApiRouter;

pub mod api;
pub mod budget;
pub mod calibrations;
pub mod db;
pub mod error;
pub mod listener;
pub mod live;
pub mod merge_patch;
pub mod metrics;
pub mod ops;
pub mod pipeline;
pub mod sessions;
pub mod stamp;
pub mod state;
pub mod storage;
pub mod wire;
pub mod ws;

use error::ApiError;
use state::{AppState, Inner, ServiceConfig};
use storage::{Storage, StorageOptions};

/// Why the server could not start or stop cleanly.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    /// A setting is out of range.
    #[error("invalid configuration: {0}")]
    Config(String),
    /// The database could not be opened, migrated or read.
    #[error("storage: {0}")]
    Storage(#[from] storage::StorageError),
    /// The listener failed.
    #[error("server: {0}")]
    Io(#[from] std::io::Error),
}

/// Header carrying the request id (set when absent, echoed in the response).
const REQUEST_ID: HeaderName = HeaderName::from_static("x-request-id");

/// Runs the service on `listener` until `shutdown` resolves; then stops
/// accepting, finishes requests and pairs in flight, closes WebSockets with
/// a close frame, and flushes storage.
pub async fn serve(
    listener: TcpListener,
    config: ServiceConfig,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<(), ServeError> {
    config.validate().map_err(ServeError::Config)?;
    let path = config.db_path.clone();
    let options = StorageOptions {
        max_db_bytes: config.max_db_bytes,
        default_retention: Some(config.default_retention),
        min_free_disk_bytes: config.min_free_disk_bytes,
        ..StorageOptions::default()
    };
    let storage = tokio::task::spawn_blocking(move || Storage::open(&path, options))
        .await
        .map_err(|e| ServeError::Io(std::io::Error::other(e)))??;
    let state = load_state(config, storage).await?;
    let app = app(state.clone());
    let cancel = state.shutdown.clone();
    tokio::spawn(async move {
        shutdown.await;
        cancel.cancel();
    });
    if let Some(expiry) = state.config.session_expiry {
        tokio::spawn(expire_sessions(state.clone(), expiry));
    }
    tracing::info!(
        address = %listener.local_addr()?,
        database = %state.config.db_path,
        token = if state.config.token.is_some() { "required" } else { "none" },
        workers = state.config.workers,
        session_expiry_h = state.config.session_expiry.map_or(0.0, |d| d.as_secs_f64() / 3600.0),
        "semdepth listening"
    );
    let stop = state.shutdown.clone();
    let limits = listener::Limits {
        header_timeout: state.config.header_timeout,
        max_connections: state.config.max_connections,
    };
    listener::serve(listener, app, limits, stop).await;
    // HTTP connections are drained; the WebSocket tasks finish their queued
    // pairs and send close frames.
    state.sockets.close();
    state.sockets.wait().await;
    state.db.close().await?;
    tracing::info!("semdepth stopped");
    Ok(())
}

/// Deletes sessions idle for `expiry` (not those marked `keep`), checking
/// every tenth of it (1 s to 1 min), until shutdown.
async fn expire_sessions(state: AppState, expiry: Duration) {
    let period = (expiry / 10).clamp(Duration::from_secs(1), Duration::from_secs(60));
    loop {
        tokio::select! {
            _ = state.shutdown.cancelled() => return,
            _ = tokio::time::sleep(period) => {}
        }
        let ids = match state.db.sessions_matching(Some(expiry), None, false) {
            Ok(ids) => ids,
            Err(e) => {
                tracing::warn!(error = %e.parts().1, "session expiry: cannot list sessions");
                continue;
            }
        };
        for id in ids {
            match state.db.delete_session(&id).await {
                Ok(()) => {
                    tracing::info!(session = %id, idle_h = expiry.as_secs_f64() / 3600.0, "session expired")
                }
                Err(e) if e.status() == axum::http::StatusCode::NOT_FOUND => {}
                Err(e) => {
                    tracing::warn!(session = %id, error = %e.parts().1, "session expiry: delete failed")
                }
            }
        }
    }
}

/// Restores calibrations and sessions from storage.
async fn load_state(config: ServiceConfig, storage: Storage) -> Result<AppState, ServeError> {
    let metrics = metrics::Metrics::new();
    let limits = db::DbLimits {
        max_sessions: config.max_sessions,
        default_retention: config.default_retention,
        live_view_bytes: config.live_view_bytes,
    };
    let db = db::Db::open(storage, limits, metrics.active_sessions.clone()).await?;
    let workers = config.workers;
    let config_budget = config.max_inflight_bytes;
    let event_streams = config.max_event_streams;
    Ok(AppState(Arc::new(Inner {
        config,
        db,
        workers: Arc::new(tokio::sync::Semaphore::new(workers)),
        metrics,
        shutdown: tokio_util::sync::CancellationToken::new(),
        sockets: tokio_util::task::TaskTracker::new(),
        display: tokio::sync::Semaphore::new(1),
        budget: budget::MemoryBudget::new(config_budget),
        event_streams: Arc::new(tokio::sync::Semaphore::new(event_streams)),
    })))
}

/// The complete application: routes, auth, limits, request ids, tracing.
pub fn app(state: AppState) -> Router {
    let config = &state.config;
    let (router, _) = routes(config.token.clone().map(Arc::from)).split_for_parts();
    let timeout = config.request_timeout;
    let max_body = config.max_body_bytes;
    router
        .merge(live::ui_router())
        .fallback(route_not_found)
        .method_not_allowed_fallback(method_not_allowed)
        .layer(middleware::from_fn(move |req: Request, next: Next| {
            request_timeout(timeout, req, next)
        }))
        .layer(DefaultBodyLimit::max(max_body))
        .layer(middleware::from_fn({
            let state = state.clone();
            move |req: Request, next: Next| body_limits(state.clone(), req, next)
        }))
        .layer(middleware::from_fn(error::log_client_errors))
        .layer(PropagateRequestIdLayer::new(REQUEST_ID))
        .layer(TraceLayer::new_for_http().make_span_with(|req: &Request| {
            let id = req
                .headers()
                .get(REQUEST_ID)
                .and_then(|v| v.to_str().ok())
                .unwrap_or("-");
            tracing::info_span!("request", method = %req.method(), path = %req.uri().path(), request_id = %id)
        }))
        .layer(SetRequestIdLayer::new(REQUEST_ID, MakeRequestUuid))
        .layer(middleware::from_fn(probes_only_beyond_the_cap))
        .with_state(state)
}

/// On a connection accepted beyond `--max-connections` (one of
/// [`listener::OPS_RESERVED`]), answers the probes and refuses the rest with
/// 503 `busy`, closing the connection.
async fn probes_only_beyond_the_cap(req: Request, next: Next) -> Response {
    let reserved = req
        .extensions()
        .get::<listener::ConnectionSlot>()
        .is_some_and(|slot| slot.reserved());
    if reserved && !listener::OPS_PATHS.contains(&req.uri().path()) {
        let mut response = ApiError::Busy(
            "every connection the server keeps (--max-connections) is in use; beyond them only /healthz, /readyz and /metrics are answered".into(),
        )
        .into_response();
        response
            .headers_mut()
            .insert(header::CONNECTION, axum::http::HeaderValue::from_static("close"));
        return response;
    }
    next.run(req).await
}

/// All routes with their OpenAPI descriptions; `/v1` behind the token.
fn routes(token: Option<Arc<str>>) -> OpenApiRouter<AppState> {
    let v1 = OpenApiRouter::new()
        .merge(calibrations::router())
        .merge(sessions::router())
        .merge(ws::router())
        .merge(live::router())
        .layer(middleware::from_fn(move |req: Request, next: Next| {
            require_token(token.clone(), req, next)
        }));
    OpenApiRouter::with_openapi(ApiDoc::openapi())
        .merge(v1)
        .merge(ops::router())
}

/// The OpenAPI document generated from the routes.
pub fn openapi() -> OpenApiDoc {
    let (_, mut api) = routes(None).split_for_parts();
    SecurityAddon.modify(&mut api);
    LinksAddon.modify(&mut api);
    // PATCH /v1/sessions/{id} takes merge patches of the parameters.
    merge_patch::add_schemas(
        &mut api,
        &["InitParams", "TrackerParams"],
        "SessionPatch",
        &["init", "tracker"],
    );
    api
}

/// The OpenAPI document as pretty JSON (what `/openapi.json` serves and
/// `openapi/openapi.json` holds).
pub fn openapi_json_text() -> &'static str {
    static TEXT: OnceLock<String> = OnceLock::new();
    TEXT.get_or_init(|| {
        let mut text = openapi()
            .to_pretty_json()
            .unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"));
        text.push('\n');
        text
    })
}

/// The OpenAPI document as YAML (`openapi/openapi.yaml`).
pub fn openapi_yaml_text() -> String {
    openapi().to_yaml().unwrap_or_else(|e| format!("error: {e}\n"))
}

#[derive(OpenApi)]
#[openapi(
    info(
        title = "semdepth",
        description = "Depth (z) of a tracked object from SEM stereo pairs: region-based active contours after Dahmen et al., ICINCO 2009. Pixel coordinates: x right, y down, the centre of the top-left pixel is (0, 0). Every error is {\"error\": {\"code\", \"message\"}}.",
        license(name = "MIT OR Apache-2.0")
    ),
    tags(
        (name = "calibrations", description = "Disparity-to-z mappings (durable)"),
        (name = "sessions", description = "Tracked objects: upload or stream pairs, read results"),
        (name = "depth", description = "One-shot measurement without a session"),
        (name = "operations", description = "Health, readiness, metrics, this document"),
    ),
    components(schemas(wire::PairHeader, ws::SkippedReply, ws::StreamErrorReply, wire::Encoding, ws::Policy, live::Side, live::PngImage))
)]
struct ApiDoc;

/// Declares the optional bearer token on every `/v1` operation.
struct SecurityAddon;

/// An OpenAPI link: `(operation, status, link name, target, parameters)`.
type Link = (
    &'static str,
    &'static str,
    &'static str,
    &'static str,
    &'static [(&'static str, &'static str)],
);

/// OpenAPI links from the operations that create a resource to those that
/// take its id, so that a client generator, or a stateful fuzzer such as
/// schemathesis, follows a session from its creation to its pairs, objects
/// and samples. A calibration's samples are a list addressed by index
/// (removing one renumbers the rest), so no link names one.
const LINKS: &[Link] = {
    // The id of what the operation created (a session, a calibration).
    const CREATED: &[(&str, &str)] = &[("id", "$response.body#/id")];
    const SESSION_OF_PATH: &[(&str, &str)] = &[("id", "$request.path.id")];
    const FRAME: &[(&str, &str)] = &[("id", "$response.body#/id"), ("side", "left")];
    const FRAME_OF_PATH: &[(&str, &str)] = &[("id", "$request.path.id"), ("side", "left")];
    const OBJECT: &[(&str, &str)] = &[("id", "$request.path.id"), ("name", "$request.body#/name")];
    const VERSION: &[(&str, &str)] = &[
        ("id", "$response.body#/id"),
        ("version", "$response.body#/version"),
    ];
    &[
        ("create_session", "201", "GetSession", "get_session", CREATED),
        ("create_session", "201", "PatchSession", "patch_session", CREATED),
        ("create_session", "201", "UploadPair", "upload_pair", CREATED),
        ("create_session", "201", "AddObject", "add_object", CREATED),
        (
            "create_session",
            "201",
            "AddSessionCalibrationSample",
            "add_session_calibration_sample",
            CREATED,
        ),
        (
            "create_session",
            "201",
            "LatestFrame",
            "latest_frame_image",
            FRAME,
        ),
        ("create_session", "201", "Results", "session_results", CREATED),
        (
            "create_session",
            "201",
            "ReinitSession",
            "reinit_session",
            CREATED,
        ),
        ("create_session", "201", "ResetSession", "reset_session", CREATED),
        (
            "create_session",
            "201",
            "DeleteSession",
            "delete_session",
            CREATED,
        ),
        (
            "upload_pair",
            "200",
            "LatestFrame",
            "latest_frame_image",
            FRAME_OF_PATH,
        ),
        (
            "upload_pair",
            "200",
            "Results",
            "session_results",
            SESSION_OF_PATH,
        ),
        (
            "upload_pair",
            "200",
            "AddSessionCalibrationSample",
            "add_session_calibration_sample",
            SESSION_OF_PATH,
        ),
        ("add_object", "201", "ReinitObject", "reinit_object", OBJECT),
        ("add_object", "201", "DeleteObject", "delete_object", OBJECT),
        (
            "create_calibration",
            "201",
            "GetCalibration",
            "get_calibration",
            CREATED,
        ),
        (
            "create_calibration",
            "201",
            "AddCalibrationSample",
            "add_calibration_sample",
            CREATED,
        ),
        (
            "create_calibration",
            "201",
            "GetCalibrationVersion",
            "get_calibration_version",
            VERSION,
        ),
        (
            "create_calibration",
            "201",
            "DeleteCalibration",
            "delete_calibration",
            CREATED,
        ),
    ]
};

struct LinksAddon;

/// The operations of a path item that the service has (no PUT, HEAD...
/// beyond these).
fn operations_mut(
    item: &mut utoipa::openapi::PathItem,
) -> impl Iterator<Item = &mut utoipa::openapi::path::Operation> {
    [
        &mut item.get,
        &mut item.post,
        &mut item.put,
        &mut item.patch,
        &mut item.delete,
    ]
    .into_iter()
    .flatten()
}

impl Modify for LinksAddon {
    fn modify(&self, api: &mut OpenApiDoc) {
        use utoipa::openapi::link::LinkBuilder;
        use utoipa::openapi::RefOr;
        for item in api.paths.paths.values_mut() {
            for op in operations_mut(item) {
                let Some(id) = op.operation_id.clone() else {
                    continue;
                };
                for (_, status, name, target, parameters) in LINKS.iter().filter(|l| l.0 == id) {
                    let Some(RefOr::T(response)) = op.responses.responses.get_mut(*status) else {
                        continue;
                    };
                    let link = parameters
                        .iter()
                        .fold(LinkBuilder::new().operation_id(*target), |link, (p, v)| {
                            link.parameter(*p, *v)
                        })
                        .build();
                    response.links.insert(name.to_string(), RefOr::T(link));
                }
            }
        }
    }
}

impl Modify for SecurityAddon {
    fn modify(&self, api: &mut OpenApiDoc) {
        let components = api.components.get_or_insert_with(Default::default);
        components.add_security_scheme(
            "bearer",
            SecurityScheme::Http(HttpBuilder::new().scheme(HttpAuthScheme::Bearer).build()),
        );
        for (path, item) in api.paths.paths.iter_mut() {
            if !path.starts_with("/v1") {
                continue;
            }
            for op in operations_mut(item) {
                // Either the token (when the server has one) or nothing.
                op.security = Some(vec![
                    utoipa::openapi::security::SecurityRequirement::new("bearer", Vec::<String>::new()),
                    utoipa::openapi::security::SecurityRequirement::default(),
                ]);
            }
        }
    }
}

/// The credentials of an `Authorization` value of the Bearer scheme,
/// whose name is matched case-insensitively (RFC 7235 2.1: `bearer` and
/// `BEARER` are `Bearer`).
fn bearer_credentials(value: &str) -> Option<&str> {
    let (scheme, credentials) = value.split_once(' ')?;
    scheme
        .eq_ignore_ascii_case("bearer")
        .then(|| credentials.trim_start_matches(' '))
}

async fn require_token(token: Option<Arc<str>>, req: Request, next: Next) -> Response {
    if let Some(expected) = token {
        let given = req
            .headers()
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(bearer_credentials);
        let ok = given.is_some_and(|g| bool::from(g.as_bytes().ct_eq(expected.as_bytes())));
        if !ok {
            return ApiError::Unauthorized(
                "unauthorized",
                "missing or wrong bearer token (expected Authorization: Bearer <token>)".into(),
            )
            .into_response();
        }
    }
    next.run(req).await
}

/// Refuses a body whose declared length is over the limit before reading
/// any of it (the streaming limit alone would wait for the bytes), then
/// holds its bytes of the memory budget (the declared length, or the limit
/// when it comes chunked) until the answer, and answers 503 `busy` with
/// `Retry-After` before reading it when they are not free. Error answers to
/// requests with a body say `Connection: close`: the body may be unread, so
/// the connection ends, and a pooled client must not reuse it.
async fn body_limits(state: AppState, req: Request, next: Next) -> Response {
    let limit = state.config.max_body_bytes;
    let declared = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok());
    let chunked = req.headers().contains_key(header::TRANSFER_ENCODING);
    let has_body = declared.is_some_and(|n| n > 0) || chunked;
    let mut response = match declared {
        Some(n) if n > limit as u64 => ApiError::TooLarge("body_too_large", format!("request body of {n} bytes exceeds the limit of {limit} bytes (raise --max-body-mib to allow more)"))
        .into_response(),
        _ => {
            let bytes = match declared {
                Some(n) => n as usize,
                None if chunked => limit,
                None => 0,
            };
            match state.budget.try_reserve(bytes, "this request's body") {
                Ok(held) => {
                    let response = next.run(req).await;
                    drop(held);
                    response
                }
                Err(e) => {
                    if matches!(e, ApiError::Busy(_)) {
                        state.metrics.refused_busy.inc();
                    }
                    e.into_response()
                }
            }
        }
    };
    let status = response.status();
    if has_body && (status.is_client_error() || status.is_server_error()) {
        response
            .headers_mut()
            .insert(header::CONNECTION, header::HeaderValue::from_static("close"));
    }
    response
}

async fn request_timeout(limit: Duration, req: Request, next: Next) -> Response {
    match tokio::time::timeout(limit, next.run(req)).await {
        Ok(response) => response,
        Err(_) => ApiError::Timeout(
            "request_timeout",
            format!(
                "the request took longer than {} s (upload faster or raise --request-timeout)",
                limit.as_secs_f64()
            ),
        )
        .into_response(),
    }
}

async fn route_not_found(req: Request) -> ApiError {
    ApiError::NotFound(
        "route_not_found",
        format!(
            "no route {} {} (see /openapi.json)",
            req.method(),
            req.uri().path()
        ),
    )
}

async fn method_not_allowed(req: Request) -> ApiError {
    ApiError::MethodNotAllowed(
        "method_not_allowed",
        format!(
            "method {} is not allowed on {} (see /openapi.json)",
            req.method(),
            req.uri().path()
        ),
    )
}

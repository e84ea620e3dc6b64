//! Operations endpoints: `/healthz`, `/readyz`, `/metrics`, `/openapi.json`.

use axum::extract::State;
use axum::http::{header, StatusCode};
use axum::response::IntoResponse;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::api::model::Health;
use super::error::ApiJson;
use super::state::AppState;

/// The operations routes (no token needed).
pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(healthz))
        .routes(routes!(readyz))
        .routes(routes!(metrics))
        .routes(routes!(openapi_json))
}

/// Liveness: the process answers.
#[utoipa::path(
    get,
    path = "/healthz",
    operation_id = "healthz",
    tag = "operations",
    responses((status = 200, description = "Alive", body = Health))
)]
pub async fn healthz() -> ApiJson<Health> {
    ApiJson(Health {
        status: "ok".into(),
        version: env!("CARGO_PKG_VERSION").into(),
        reason: None,
    })
}

/// Readiness: storage answers a query, and its writes succeed (after a
/// failed write, a write that needs room is tried).
#[utoipa::path(
    get,
    path = "/readyz",
    operation_id = "readyz",
    tag = "operations",
    responses(
        (status = 200, description = "Ready", body = Health),
        (status = 503, description = "Storage unavailable", body = Health),
    )
)]
pub async fn readyz(State(state): State<AppState>) -> (StatusCode, ApiJson<Health>) {
    let reason = if state.shutdown.is_cancelled() {
        Some("shutting down".to_string())
    } else {
        state.db.ping().await.err().map(|e| e.to_string())
    };
    let (status, text) = match reason {
        None => (StatusCode::OK, "ok"),
        Some(_) => (StatusCode::SERVICE_UNAVAILABLE, "unavailable"),
    };
    (
        status,
        ApiJson(Health {
            status: text.into(),
            version: env!("CARGO_PKG_VERSION").into(),
            reason,
        }),
    )
}

/// Prometheus metrics (OpenMetrics text).
#[utoipa::path(
    get,
    path = "/metrics",
    operation_id = "metrics",
    tag = "operations",
    responses((status = 200, description = "Metrics in the OpenMetrics text format", body = String, content_type = "application/openmetrics-text"))
)]
pub async fn metrics(State(state): State<AppState>) -> impl IntoResponse {
    let bytes = i64::try_from(state.db.bytes()).unwrap_or(i64::MAX);
    state.metrics.storage_bytes.set(bytes);
    let inflight = i64::try_from(state.budget.used_bytes()).unwrap_or(i64::MAX);
    state.metrics.inflight_bytes.set(inflight);
    (
        [(
            header::CONTENT_TYPE,
            "application/openmetrics-text; version=1.0.0; charset=utf-8",
        )],
        state.metrics.render(),
    )
}

/// This API's OpenAPI description.
#[utoipa::path(
    get,
    path = "/openapi.json",
    operation_id = "openapi_json",
    tag = "operations",
    responses((status = 200, description = "The OpenAPI 3.1 document", body = Object))
)]
pub async fn openapi_json() -> impl IntoResponse {
    (
        [(header::CONTENT_TYPE, "application/json")],
        super::openapi_json_text(),
    )
}

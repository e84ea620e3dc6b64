//! The one error type of the HTTP API: a status and a JSON body
//! `{"error": {"code": "snake_case", "message": "..."}}` (contract,
//! "Conventions"), plus extractors that turn axum's own rejections (bad JSON,
//! wrong content type, bad query) into it.

use axum::body::Bytes;
use axum::extract::rejection::{JsonRejection, PathRejection, QueryRejection};
use axum::extract::{FromRequest, FromRequestParts, Request};
use axum::http::request::Parts;
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use serde::de::DeserializeOwned;
use serde::Serialize;
use utoipa::ToSchema;

use semdepth_core::calib::CalibError;
use semdepth_core::imageio::ImageInputError;
use semdepth_core::init::InitError;
use semdepth_core::tracker::TrackError;

use super::storage::StorageError;

/// An API error: HTTP status, machine-readable code and a message saying
/// what was wrong and what was expected.
#[derive(Debug, Clone)]
pub struct ApiError {
    /// HTTP status of the response.
    pub status: StatusCode,
    /// snake_case code, stable for scripts to match on.
    pub code: String,
    /// Human-readable explanation.
    pub message: String,
}

/// The JSON body of every error response.
#[derive(Debug, Serialize, serde::Deserialize, ToSchema)]
#[schema(example = json!({"error": {"code": "session_not_found", "message": "no session with id \"s_42\""}}))]
pub struct ErrorBody {
    /// The error.
    pub error: ErrorDetail,
}

/// Code and message of an error.
#[derive(Clone, Debug, Serialize, serde::Deserialize, ToSchema)]
pub struct ErrorDetail {
    /// snake_case code, e.g. `invalid_json`, `session_not_found`, `image_undecodable`.
    pub code: String,
    /// What was wrong and what was expected.
    pub message: String,
}

impl ApiError {
    /// An error with an explicit status.
    pub fn new(status: StatusCode, code: impl Into<String>, message: impl Into<String>) -> Self {
        Self {
            status,
            code: code.into(),
            message: message.into(),
        }
    }

    /// 400: the request is malformed or a value is out of range.
    pub fn bad_request(code: impl Into<String>, message: impl Into<String>) -> Self {
        Self::new(StatusCode::BAD_REQUEST, code, message)
    }

    /// 404 for an unknown id of the named kind ("session", "calibration").
    pub fn not_found(kind: &str, id: &str) -> Self {
        Self::new(
            StatusCode::NOT_FOUND,
            format!("{kind}_not_found"),
            format!("no {kind} with id {id:?}"),
        )
    }

    /// 409: the request conflicts with the current state.
    pub fn conflict(code: impl Into<String>, message: impl Into<String>) -> Self {
        Self::new(StatusCode::CONFLICT, code, message)
    }

    /// 503 `shutting_down`: a semaphore the work waits on was closed.
    pub fn shutting_down() -> Self {
        Self::new(
            StatusCode::SERVICE_UNAVAILABLE,
            "shutting_down",
            "the server is shutting down",
        )
    }

    /// 500: a fault of the server, not of the request.
    pub fn internal(message: impl Into<String>) -> Self {
        Self::new(StatusCode::INTERNAL_SERVER_ERROR, "internal_error", message)
    }

    /// 422 `invalid_hint` for a hint (`init.roi`, `init.point`) that is
    /// out of range or does not fit the images, the message naming the
    /// field; other initialisation errors are 400 `invalid_parameter`.
    pub fn hint(e: InitError) -> Self {
        match &e {
            InitError::InvalidHint { field, message } => Self::new(
                StatusCode::UNPROCESSABLE_ENTITY,
                e.code(),
                format!("invalid init.{field}: {message}"),
            ),
            other => Self::bad_request("invalid_parameter", format!("init: {other}")),
        }
    }

    /// The JSON body.
    pub fn body(&self) -> ErrorBody {
        ErrorBody {
            error: ErrorDetail {
                code: self.code.clone(),
                message: self.message.clone(),
            },
        }
    }
}

impl std::fmt::Display for ApiError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} {}: {}", self.status.as_u16(), self.code, self.message)
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        if self.status.is_server_error() {
            tracing::error!(code = %self.code, message = %self.message, "server error");
        }
        let mut response = (self.status, axum::Json(self.body())).into_response();
        if self.status.is_client_error() {
            response.extensions_mut().insert(ClientError {
                code: self.code.clone(),
                message: self.message.clone(),
            });
        }
        if self.status == StatusCode::SERVICE_UNAVAILABLE && self.code == "busy" {
            response.headers_mut().insert(
                header::RETRY_AFTER,
                HeaderValue::from(super::budget::RETRY_AFTER_S),
            );
        }
        if self.status == StatusCode::UNAUTHORIZED {
            response
                .headers_mut()
                .insert(header::WWW_AUTHENTICATE, HeaderValue::from_static("Bearer"));
        }
        response
    }
}

/// A 4xx answer's code and message, attached to the response for the
/// request log (see [`log_client_errors`]).
#[derive(Clone, Debug)]
pub struct ClientError {
    code: String,
    message: String,
}

/// Most client errors logged per [`CLIENT_ERROR_WINDOW`]; the rest are
/// counted and the count logged when the next window opens, so that a
/// misbehaving client cannot flood the log.
const CLIENT_ERRORS_PER_WINDOW: u32 = 20;
const CLIENT_ERROR_WINDOW: std::time::Duration = std::time::Duration::from_secs(10);

/// Logs (at info, rate-limited) every 4xx answer to a request that changes
/// something (not GET, HEAD or OPTIONS), with its code and message: what a
/// lab's script did wrong shows in the server's log too.
pub async fn log_client_errors(req: axum::extract::Request, next: axum::middleware::Next) -> Response {
    use axum::http::Method;
    let mutating = !matches!(*req.method(), Method::GET | Method::HEAD | Method::OPTIONS);
    let response = next.run(req).await;
    if !mutating || !response.status().is_client_error() {
        return response;
    }
    static WINDOW: std::sync::Mutex<Option<(std::time::Instant, u32)>> = std::sync::Mutex::new(None);
    let (log, suppressed) = {
        let Ok(mut window) = WINDOW.lock() else {
            return response;
        };
        let now = std::time::Instant::now();
        match window.as_mut() {
            Some((start, count)) if now.duration_since(*start) < CLIENT_ERROR_WINDOW => {
                *count += 1;
                (*count <= CLIENT_ERRORS_PER_WINDOW, 0)
            }
            other => {
                let suppressed = other
                    .as_ref()
                    .map_or(0, |(_, c)| c.saturating_sub(CLIENT_ERRORS_PER_WINDOW));
                *window = Some((now, 1));
                (true, suppressed)
            }
        }
    };
    if suppressed > 0 {
        tracing::info!(suppressed, "client errors not logged in the last window");
    }
    if log {
        let status = response.status().as_u16();
        match response.extensions().get::<ClientError>() {
            Some(e) => tracing::info!(status, code = %e.code, detail = %e.message, "client error"),
            None => tracing::info!(status, "client error"),
        }
    }
    response
}

impl From<ImageInputError> for ApiError {
    fn from(e: ImageInputError) -> Self {
        let status = match e {
            ImageInputError::TooLarge { .. } | ImageInputError::MemoryLimit { .. } => {
                StatusCode::PAYLOAD_TOO_LARGE
            }
            _ => StatusCode::BAD_REQUEST,
        };
        Self::new(status, e.code(), e.to_string())
    }
}

impl From<TrackError> for ApiError {
    fn from(e: TrackError) -> Self {
        match e {
            TrackError::Input(e) => e.into(),
            e @ TrackError::SizeChanged { .. } => Self::bad_request("pair_size_changed", e.to_string()),
            // The session's hints do not fit the uploaded images.
            TrackError::Hint(e) => Self::hint(e),
        }
    }
}

impl From<semdepth_core::session::SessionError> for ApiError {
    fn from(e: semdepth_core::session::SessionError) -> Self {
        use semdepth_core::session::SessionError as E;
        let status = match &e {
            E::InvalidName(_) => StatusCode::BAD_REQUEST,
            E::UnknownObject(_) => StatusCode::NOT_FOUND,
            E::DuplicateName(_) | E::ObjectCount(_) => StatusCode::CONFLICT,
        };
        Self::new(status, e.code(), e.to_string())
    }
}

impl From<CalibError> for ApiError {
    fn from(e: CalibError) -> Self {
        // Every calibration error is about the submitted values or samples,
        // or names a sample that is not there.
        let status = match e {
            CalibError::NoSuchSample { .. } => StatusCode::NOT_FOUND,
            _ => StatusCode::UNPROCESSABLE_ENTITY,
        };
        Self::new(status, e.code(), e.to_string())
    }
}

impl From<StorageError> for ApiError {
    fn from(e: StorageError) -> Self {
        Self::new(
            StatusCode::SERVICE_UNAVAILABLE,
            e.code(),
            format!("storage failed: {e}"),
        )
    }
}

impl From<JsonRejection> for ApiError {
    fn from(rejection: JsonRejection) -> Self {
        match rejection {
            JsonRejection::MissingJsonContentType(_) => unsupported_json_media_type(),
            JsonRejection::JsonSyntaxError(e) => Self::bad_request("invalid_json", e.body_text()),
            JsonRejection::JsonDataError(e) => Self::bad_request("invalid_json", e.body_text()),
            JsonRejection::BytesRejection(e) => body_rejection(e.status(), e.body_text()),
            other => Self::bad_request("invalid_json", other.body_text()),
        }
    }
}

/// `Json<T>` whose rejections are [`ApiError`]s (400 with the serde message,
/// naming an unknown field; 415 without a JSON content type).
///
/// Every request body of this API is a JSON object, so anything else (an
/// array, a string, a number) is refused with 400 `invalid_json`; serde alone
/// would accept an array for a struct whose fields all have defaults.
#[derive(Debug, Clone, Copy, Default)]
pub struct ApiJson<T>(pub T);

impl<T, S> FromRequest<S> for ApiJson<T>
where
    T: DeserializeOwned,
    S: Send + Sync,
{
    type Rejection = ApiError;

    async fn from_request(req: Request, state: &S) -> Result<Self, Self::Rejection> {
        let bytes = json_object_bytes(req, state).await?;
        let axum::Json(value) = axum::Json::<T>::from_bytes(&bytes)?;
        Ok(Self(value))
    }
}

/// [`ApiJson`] that also hands over the body's top-level object as JSON,
/// for a handler that must tell a field left out from one given with its
/// default value.
#[derive(Debug, Clone)]
pub struct ApiJsonFields<T>(pub T, pub serde_json::Map<String, serde_json::Value>);

impl<T, S> FromRequest<S> for ApiJsonFields<T>
where
    T: DeserializeOwned,
    S: Send + Sync,
{
    type Rejection = ApiError;

    async fn from_request(req: Request, state: &S) -> Result<Self, Self::Rejection> {
        let bytes = json_object_bytes(req, state).await?;
        // Typed first: its errors name the offending field.
        let axum::Json(value) = axum::Json::<T>::from_bytes(&bytes)?;
        let axum::Json(fields) =
            axum::Json::<serde_json::Map<String, serde_json::Value>>::from_bytes(&bytes)?;
        Ok(Self(value, fields))
    }
}

/// The body of a request that must be a JSON object: 415 without a JSON
/// content type, 400 for anything but an object (an empty body passes, for
/// serde to refuse or default).
async fn json_object_bytes<S: Send + Sync>(req: Request, state: &S) -> Result<Bytes, ApiError> {
    if !has_json_content_type(req.headers()) {
        return Err(unsupported_json_media_type());
    }
    let bytes = Bytes::from_request(req, state)
        .await
        .map_err(|e| body_rejection(e.status(), e.body_text()))?;
    match bytes.iter().find(|b| !b.is_ascii_whitespace()) {
        Some(b'{') | None => Ok(bytes),
        Some(_) => Err(ApiError::bad_request(
            "invalid_json",
            "expected a JSON object ({...}) as the request body",
        )),
    }
}

/// `application/json` or `application/*+json`, parameters ignored (what
/// axum's `Json` accepts).
fn has_json_content_type(headers: &axum::http::HeaderMap) -> bool {
    let Some(value) = headers.get(header::CONTENT_TYPE).and_then(|v| v.to_str().ok()) else {
        return false;
    };
    let essence = value
        .split(';')
        .next()
        .unwrap_or_default()
        .trim()
        .to_ascii_lowercase();
    match essence.split_once('/') {
        Some((kind, subtype)) => kind == "application" && (subtype == "json" || subtype.ends_with("+json")),
        None => false,
    }
}

fn unsupported_json_media_type() -> ApiError {
    ApiError::new(
        StatusCode::UNSUPPORTED_MEDIA_TYPE,
        "unsupported_media_type",
        "expected a JSON body with Content-Type: application/json",
    )
}

/// A body that could not be read: 413 past the limit, else 400.
fn body_rejection(status: StatusCode, text: String) -> ApiError {
    if status == StatusCode::PAYLOAD_TOO_LARGE {
        ApiError::new(status, "body_too_large", text)
    } else {
        ApiError::bad_request("body_unreadable", text)
    }
}

impl<T: Serialize> IntoResponse for ApiJson<T> {
    fn into_response(self) -> Response {
        axum::Json(self.0).into_response()
    }
}

/// `Query<T>` whose rejections are [`ApiError`]s.
#[derive(Debug, Clone, Copy, Default)]
pub struct ApiQuery<T>(pub T);

impl<T, S> FromRequestParts<S> for ApiQuery<T>
where
    T: DeserializeOwned,
    S: Send + Sync,
{
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, Self::Rejection> {
        axum::extract::Query::<T>::from_request_parts(parts, state)
            .await
            .map(|q| Self(q.0))
            .map_err(|e: QueryRejection| ApiError::bad_request("invalid_query", e.body_text()))
    }
}

/// `Path<T>` whose rejections are [`ApiError`]s.
#[derive(Debug, Clone)]
pub struct ApiPath<T>(pub T);

impl<T, S> FromRequestParts<S> for ApiPath<T>
where
    T: DeserializeOwned + Send,
    S: Send + Sync,
{
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, Self::Rejection> {
        axum::extract::Path::<T>::from_request_parts(parts, state)
            .await
            .map(|p| Self(p.0))
            .map_err(|e: PathRejection| ApiError::bad_request("invalid_path", e.body_text()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::service::api::model::SessionCreate;

    async fn extract(content_type: Option<&str>, body: &'static str) -> Result<SessionCreate, ApiError> {
        let mut builder = Request::builder().method("POST").uri("/v1/sessions");
        if let Some(ct) = content_type {
            builder = builder.header(header::CONTENT_TYPE, ct);
        }
        let request = builder.body(axum::body::Body::from(body)).unwrap();
        ApiJson::<SessionCreate>::from_request(request, &())
            .await
            .map(|j| j.0)
    }

    #[tokio::test]
    async fn json_bodies_must_be_objects_with_a_json_content_type() {
        assert!(extract(Some("application/json"), " {\"name\": \"a\"}")
            .await
            .is_ok());
        assert!(extract(Some("Application/JSON; charset=utf-8"), "{}")
            .await
            .is_ok());
        assert!(extract(Some("application/merge-patch+json"), "{}").await.is_ok());
        // serde alone would take an array for a struct whose fields have defaults.
        for body in ["[null, null]", "[]", "\"x\"", "1", "null"] {
            let e = extract(Some("application/json"), body).await.unwrap_err();
            assert_eq!(
                (e.status, e.code.as_str()),
                (StatusCode::BAD_REQUEST, "invalid_json"),
                "{body}"
            );
        }
        let e = extract(Some("application/json"), "").await.unwrap_err();
        assert_eq!(
            (e.status, e.code.as_str()),
            (StatusCode::BAD_REQUEST, "invalid_json")
        );
        for ct in [None, Some("text/plain"), Some("application/jsonx"), Some("json")] {
            let e = extract(ct, "{}").await.unwrap_err();
            assert_eq!(e.status, StatusCode::UNSUPPORTED_MEDIA_TYPE, "{ct:?}");
        }
    }
}

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

/// How long a client told `busy` waits before it retries, seconds (the
/// `Retry-After` header).
pub const RETRY_AFTER_S: u32 = 1;

/// An API error: its kind (the HTTP status), a snake_case code stable for
/// scripts to match on, and a message saying what was wrong and what was
/// expected.
#[derive(Debug, Clone)]
pub enum ApiError {
    /// 400: the request is malformed or a value is out of range.
    BadRequest(&'static str, String),
    /// 401: no bearer token, or the wrong one.
    Unauthorized(&'static str, String),
    /// 404: an unknown id, route, version or sample.
    NotFound(&'static str, String),
    /// 405: a known route with another method.
    MethodNotAllowed(&'static str, String),
    /// 408: the request took too long.
    Timeout(&'static str, String),
    /// 409: the request conflicts with the current state.
    Conflict(&'static str, String),
    /// 413: a body, message or image beyond its limit.
    TooLarge(&'static str, String),
    /// 415: a body of the wrong type.
    UnsupportedMediaType(&'static str, String),
    /// 422: values that parse but cannot be used (a hint outside the
    /// image, a degenerate calibration).
    Unprocessable(&'static str, String),
    /// 426: a WebSocket route without an upgrade.
    UpgradeRequired(&'static str, String),
    /// 503 with `Retry-After`: the memory for work in flight is in use.
    Busy(String),
    /// 503: storage failed, the disk is nearly full, or the server is
    /// shutting down.
    Unavailable(&'static str, String),
    /// 500: a fault of the server, not of the request.
    Internal(String),
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
    /// An error of the kind `status` stands for (an axum rejection's own
    /// status; any other client error is a 400, any other server error a 500).
    pub fn with_status(status: StatusCode, code: &'static str, message: impl Into<String>) -> Self {
        let message = message.into();
        match status {
            StatusCode::UNAUTHORIZED => Self::Unauthorized(code, message),
            StatusCode::NOT_FOUND => Self::NotFound(code, message),
            StatusCode::METHOD_NOT_ALLOWED => Self::MethodNotAllowed(code, message),
            StatusCode::REQUEST_TIMEOUT => Self::Timeout(code, message),
            StatusCode::CONFLICT => Self::Conflict(code, message),
            StatusCode::PAYLOAD_TOO_LARGE => Self::TooLarge(code, message),
            StatusCode::UNSUPPORTED_MEDIA_TYPE => Self::UnsupportedMediaType(code, message),
            StatusCode::UNPROCESSABLE_ENTITY => Self::Unprocessable(code, message),
            StatusCode::UPGRADE_REQUIRED => Self::UpgradeRequired(code, message),
            StatusCode::SERVICE_UNAVAILABLE => Self::Unavailable(code, message),
            s if s.is_server_error() => Self::Internal(message),
            _ => Self::BadRequest(code, message),
        }
    }

    /// 400: the request is malformed or a value is out of range.
    pub fn bad_request(code: &'static str, message: impl Into<String>) -> Self {
        Self::BadRequest(code, message.into())
    }

    /// 404 `session_not_found`.
    pub fn session_not_found(id: &str) -> Self {
        Self::NotFound("session_not_found", format!("no session with id {id:?}"))
    }

    /// 404 `calibration_not_found`.
    pub fn calibration_not_found(id: &str) -> Self {
        Self::NotFound("calibration_not_found", format!("no calibration with id {id:?}"))
    }

    /// 409: the request conflicts with the current state.
    pub fn conflict(code: &'static str, message: impl Into<String>) -> Self {
        Self::Conflict(code, message.into())
    }

    /// 503 `shutting_down`: a semaphore the work waits on was closed.
    pub fn shutting_down() -> Self {
        Self::Unavailable("shutting_down", "the server is shutting down".into())
    }

    /// 500: a fault of the server, not of the request.
    pub fn internal(message: impl Into<String>) -> Self {
        Self::Internal(message.into())
    }

    /// 422 `invalid_hint` for a hint (`init.roi`, `init.point`) that is
    /// out of range or does not fit the images, the message naming the
    /// field; 422 `hint_matches_nothing` for a `point` or `polarity` that
    /// no region of the first pair satisfies, and `objects_share_a_region`
    /// for two objects whose hints name one region; other initialisation
    /// errors are 400 `invalid_parameter`.
    pub fn hint(e: InitError) -> Self {
        match &e {
            InitError::InvalidHint { field, message } => {
                Self::Unprocessable(e.code(), format!("invalid init.{field}: {message}"))
            }
            InitError::HintMatchesNothing { .. } | InitError::SameRegion { .. } => {
                Self::Unprocessable(e.code(), format!("init: {e}"))
            }
            other => Self::bad_request("invalid_parameter", format!("init: {other}")),
        }
    }

    /// The HTTP status.
    pub fn status(&self) -> StatusCode {
        match self {
            Self::BadRequest(..) => StatusCode::BAD_REQUEST,
            Self::Unauthorized(..) => StatusCode::UNAUTHORIZED,
            Self::NotFound(..) => StatusCode::NOT_FOUND,
            Self::MethodNotAllowed(..) => StatusCode::METHOD_NOT_ALLOWED,
            Self::Timeout(..) => StatusCode::REQUEST_TIMEOUT,
            Self::Conflict(..) => StatusCode::CONFLICT,
            Self::TooLarge(..) => StatusCode::PAYLOAD_TOO_LARGE,
            Self::UnsupportedMediaType(..) => StatusCode::UNSUPPORTED_MEDIA_TYPE,
            Self::Unprocessable(..) => StatusCode::UNPROCESSABLE_ENTITY,
            Self::UpgradeRequired(..) => StatusCode::UPGRADE_REQUIRED,
            Self::Busy(_) | Self::Unavailable(..) => StatusCode::SERVICE_UNAVAILABLE,
            Self::Internal(_) => StatusCode::INTERNAL_SERVER_ERROR,
        }
    }

    /// The code and the message.
    pub fn parts(&self) -> (&'static str, &str) {
        match self {
            Self::BadRequest(code, m)
            | Self::Unauthorized(code, m)
            | Self::NotFound(code, m)
            | Self::MethodNotAllowed(code, m)
            | Self::Timeout(code, m)
            | Self::Conflict(code, m)
            | Self::TooLarge(code, m)
            | Self::UnsupportedMediaType(code, m)
            | Self::Unprocessable(code, m)
            | Self::UpgradeRequired(code, m)
            | Self::Unavailable(code, m) => (code, m),
            Self::Busy(m) => ("busy", m),
            Self::Internal(m) => ("internal_error", m),
        }
    }

    /// The snake_case code.
    pub fn code(&self) -> &'static str {
        self.parts().0
    }

    /// This error with `prefix` before its message (`left image: ...`).
    pub fn prefixed(mut self, prefix: &str) -> Self {
        match &mut self {
            Self::BadRequest(_, m)
            | Self::Unauthorized(_, m)
            | Self::NotFound(_, m)
            | Self::MethodNotAllowed(_, m)
            | Self::Timeout(_, m)
            | Self::Conflict(_, m)
            | Self::TooLarge(_, m)
            | Self::UnsupportedMediaType(_, m)
            | Self::Unprocessable(_, m)
            | Self::UpgradeRequired(_, m)
            | Self::Unavailable(_, m)
            | Self::Busy(m)
            | Self::Internal(m) => *m = format!("{prefix}: {m}"),
        }
        self
    }

    /// The JSON body.
    pub fn body(&self) -> ErrorBody {
        let (code, message) = self.parts();
        ErrorBody {
            error: ErrorDetail {
                code: code.into(),
                message: message.into(),
            },
        }
    }
}

impl std::fmt::Display for ApiError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (code, message) = self.parts();
        write!(f, "{} {code}: {message}", self.status().as_u16())
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let (status, (code, message)) = (self.status(), self.parts());
        let mut response = (status, axum::Json(self.body())).into_response();
        let headers = response.headers_mut();
        if status.is_server_error() {
            tracing::error!(code, message, "server error");
        }
        match &self {
            Self::Busy(_) => {
                headers.insert(header::RETRY_AFTER, HeaderValue::from(RETRY_AFTER_S));
            }
            Self::Unauthorized(..) => {
                headers.insert(header::WWW_AUTHENTICATE, HeaderValue::from_static("Bearer"));
            }
            _ => {}
        }
        if status.is_client_error() {
            response.extensions_mut().insert(ClientError {
                code,
                message: message.to_owned(),
            });
        }
        response
    }
}

/// A 4xx answer's code and message, attached to the response for the
/// request log (see [`log_client_errors`]).
#[derive(Clone, Debug)]
pub struct ClientError {
    code: &'static str,
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
        Self::with_status(status, e.code(), e.to_string())
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
        Self::with_status(status, e.code(), e.to_string())
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
        Self::with_status(status, e.code(), e.to_string())
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
        let (bytes, _) = json_object_body(req, state).await?;
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
        let (bytes, fields) = json_object_body(req, state).await?;
        // Typed first: its errors name the offending field.
        let axum::Json(value) = axum::Json::<T>::from_bytes(&bytes)?;
        let fields = match fields {
            Some(fields) => fields,
            None => axum::Json::<JsonObject>::from_bytes(&bytes)?.0,
        };
        Ok(Self(value, fields))
    }
}

/// A JSON object's members.
type JsonObject = serde_json::Map<String, serde_json::Value>;

/// The body of a request that must be a JSON object, and its members when
/// it parses as one: 415 without a JSON content type, 400 for anything but
/// an object or for an array where the API takes none (an empty or
/// malformed body passes, for serde to refuse or default with its own
/// message).
async fn json_object_body<S: Send + Sync>(
    req: Request,
    state: &S,
) -> Result<(Bytes, Option<JsonObject>), ApiError> {
    if !has_json_content_type(req.headers()) {
        return Err(unsupported_json_media_type());
    }
    let bytes = Bytes::from_request(req, state)
        .await
        .map_err(|e| body_rejection(e.status(), e.body_text()))?;
    match bytes.iter().find(|b| !b.is_ascii_whitespace()) {
        Some(b'{') => {}
        None => return Ok((bytes, None)),
        Some(_) => {
            return Err(ApiError::bad_request(
                "invalid_json",
                "expected a JSON object ({...}) as the request body",
            ))
        }
    }
    let fields = serde_json::from_slice::<JsonObject>(&bytes).ok();
    if let Some(path) = fields.as_ref().and_then(|f| misplaced_array(f, "")) {
        return Err(ApiError::bad_request(
            "invalid_json",
            format!("{path}: expected an object or a single value, got an array"),
        ));
    }
    Ok((bytes, fields))
}

/// The request-body fields whose values are arrays: of numbers (`roi`,
/// `point`), of `[x, y]` pairs (`outline`, `exclude`) or of objects
/// (`objects`, `samples`).
const ARRAY_FIELDS: [&str; 6] = ["roi", "point", "outline", "exclude", "objects", "samples"];

/// The path of the first array in `object` where the API takes no array.
/// serde reads a struct from an array of its fields in order, so without
/// this check `"tracker": []` would pass as the default parameters.
pub(crate) fn misplaced_array(object: &JsonObject, path: &str) -> Option<String> {
    use serde_json::Value;
    for (key, value) in object {
        let here = if path.is_empty() {
            key.clone()
        } else {
            format!("{path}.{key}")
        };
        match value {
            Value::Object(inner) => {
                if let Some(p) = misplaced_array(inner, &here) {
                    return Some(p);
                }
            }
            Value::Array(items) if ARRAY_FIELDS.contains(&key.as_str()) => {
                let of_objects = matches!(key.as_str(), "objects" | "samples");
                let of_pairs = matches!(key.as_str(), "outline" | "exclude");
                for (i, item) in items.iter().enumerate() {
                    let at = format!("{here}[{i}]");
                    match item {
                        Value::Array(pair) if of_pairs => {
                            if let Some(j) = pair.iter().position(|v| v.is_array() || v.is_object()) {
                                return Some(format!("{at}[{j}]"));
                            }
                        }
                        Value::Array(_) => return Some(at),
                        Value::Object(inner) if of_objects => {
                            if let Some(p) = misplaced_array(inner, &at) {
                                return Some(p);
                            }
                        }
                        _ => {}
                    }
                }
            }
            Value::Array(_) => return Some(here),
            _ => {}
        }
    }
    None
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
    ApiError::UnsupportedMediaType(
        "unsupported_media_type",
        "expected a JSON body with Content-Type: application/json".into(),
    )
}

/// A body that could not be read: 413 past the limit, else 400.
fn body_rejection(status: StatusCode, text: String) -> ApiError {
    if status == StatusCode::PAYLOAD_TOO_LARGE {
        ApiError::with_status(status, "body_too_large", text)
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
                (e.status(), e.code()),
                (StatusCode::BAD_REQUEST, "invalid_json"),
                "{body}"
            );
        }
        let e = extract(Some("application/json"), "").await.unwrap_err();
        assert_eq!((e.status(), e.code()), (StatusCode::BAD_REQUEST, "invalid_json"));
        for ct in [None, Some("text/plain"), Some("application/jsonx"), Some("json")] {
            let e = extract(ct, "{}").await.unwrap_err();
            assert_eq!(e.status(), StatusCode::UNSUPPORTED_MEDIA_TYPE, "{ct:?}");
        }
    }

    #[tokio::test]
    async fn an_array_where_an_object_belongs_is_refused_at_any_depth() {
        let ok = r#"{"init": {"roi": [0, 0, 20, 20], "point": [5, 5]},
                     "objects": [{"name": "a", "roi": [0, 0, 20, 20]}]}"#;
        assert!(extract(Some("application/json"), ok).await.is_ok());
        for (body, path) in [
            (r#"{"tracker": []}"#, "tracker"),
            (r#"{"tracker": {"rigid": [8.0]}}"#, "tracker.rigid"),
            (r#"{"objects": [["a"]]}"#, "objects[0]"),
            (
                r#"{"objects": [{"name": "a", "roi": [[0], 0, 20, 20]}]}"#,
                "objects[0].roi[0]",
            ),
        ] {
            let e = extract(Some("application/json"), body).await.unwrap_err();
            assert_eq!(
                (e.status(), e.code()),
                (StatusCode::BAD_REQUEST, "invalid_json"),
                "{body}"
            );
            assert!(
                e.to_string().ends_with(&format!(
                    "invalid_json: {path}: expected an object or a single value, got an array"
                )),
                "{body}: {e}"
            );
        }
    }
}

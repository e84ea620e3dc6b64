//! The live view: the browser page served at `/` (static files embedded in
//! the binary), each session's latest pair as PNG with its contours drawn,
//! and a server-sent event stream of its results.
//!
//! Viewers never slow tracking: a committed pair replaces the session's
//! [`LiveFrame`](super::db::LiveFrame) in a watch channel (no queue, no wait), the event stream
//! sends the newest result at most every [`EVENT_INTERVAL`] and skips what a
//! slow viewer missed, and PNGs are encoded on the blocking pool one at a
//! time, outside the tracking workers' slots. The images of the sessions
//! updated longest ago are let go when the live frames together exceed
//! `--live-view-mib`; their results stay.

use std::convert::Infallible;
use std::time::Duration;

use axum::extract::State;
use axum::http::{header, HeaderName, HeaderValue};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use futures_util::Stream;
use serde::Deserialize;
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::{router::OpenApiRouter, routes};

use super::api::Status;
use semdepth_core::display::{render_png, shrink_factor, Overlay, LOST_COLOUR, PALETTE};

use super::error::{ApiError, ApiPath, ApiQuery, ErrorBody};
use super::state::AppState;

/// Frame index of the pair an image shows.
const X_FRAME: HeaderName = HeaderName::from_static("x-frame");
/// Width of the pair's images before shrinking, pixels.
const X_FRAME_WIDTH: HeaderName = HeaderName::from_static("x-frame-width");
/// Height of the pair's images before shrinking, pixels.
const X_FRAME_HEIGHT: HeaderName = HeaderName::from_static("x-frame-height");
/// The shrink factor: image pixel i averages frame pixels i f ..= i f + f - 1.
const X_FRAME_SCALE: HeaderName = HeaderName::from_static("x-frame-scale");

/// Shortest time between two events of one viewer's stream.
pub const EVENT_INTERVAL: Duration = Duration::from_millis(100);

/// The live view's routes under `/v1` (behind the token).
pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(latest_frame))
        .routes(routes!(session_events))
}

/// Which image of a pair.
#[derive(Clone, Copy, Debug, Deserialize, ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum Side {
    /// The left image (first of the pair).
    Left,
    /// The right image.
    Right,
}

/// A PNG file (OpenAPI: a binary string).
#[derive(ToSchema)]
#[schema(value_type = String, format = Binary)]
pub struct PngImage(pub Vec<u8>);

/// Query of `GET /v1/sessions/{id}/frames/latest/{side}`.
#[derive(Clone, Copy, Debug, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct FrameImageQuery {
    /// Shrink (by an integer factor, averaging) until the longest side is
    /// at most this, 16..=16384; default: full size.
    #[param(minimum = 16, maximum = 16384)]
    pub max_side: Option<u32>,
    /// Draw the pair's contours (a colour per object; red when the pair is
    /// not tracked). Default false.
    #[serde(default)]
    pub overlay: bool,
}

/// The session's latest pair's left or right image as PNG (8-bit; 16-bit
/// images stretched between their 0.1 and 99.9 percentiles), optionally
/// shrunk and with the contours drawn: what the tracker saw, for clients
/// without JavaScript too.
#[utoipa::path(
    get,
    path = "/v1/sessions/{id}/frames/latest/{side}",
    operation_id = "latest_frame_image",
    tag = "sessions",
    params(
        ("id" = String, Path, description = "Session id"),
        ("side" = Side, Path, description = "`left` or `right`"),
        FrameImageQuery,
    ),
    responses(
        (status = 200, description = "The image", content_type = "image/png", body = PngImage, headers(
            ("x-frame" = u64, description = "Frame index of the pair shown"),
            ("x-frame-width" = u32, description = "Width of the pair's images before shrinking, pixels"),
            ("x-frame-height" = u32, description = "Height of the pair's images before shrinking, pixels"),
            ("x-frame-scale" = u32, description = "Shrink factor f: image pixel i averages frame pixels i f ..= i f + f - 1"),
        )),
        (status = 400, description = "Invalid query (max_side out of range) or path (side not left or right, an id that is not UTF-8)", body = ErrorBody),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
        (status = 404, description = "No such session (`session_not_found`), or no pair to show (`no_frame`: none processed since the server started, or its images let go to keep within --live-view-mib)", body = ErrorBody),
        (status = 503, description = "The server is shutting down", body = ErrorBody),
    )
)]
pub async fn latest_frame(
    State(state): State<AppState>,
    ApiPath((id, side)): ApiPath<(String, Side)>,
    ApiQuery(query): ApiQuery<FrameImageQuery>,
) -> Result<Response, ApiError> {
    if let Some(m) = query.max_side {
        if !(16..=16384).contains(&m) {
            return Err(ApiError::bad_request(
                "invalid_query",
                format!("invalid max_side {m} (expected 16..=16384)"),
            ));
        }
    }
    let session = state.db.session(&id)?;
    let live = session.live_frame();
    let no_frame =
        |why: &str| ApiError::NotFound("no_frame", format!("session {id} has no pair to show: {why}"));
    let live = live.ok_or_else(|| no_frame("none was processed since the server started"))?;
    let images = live.images.clone().ok_or_else(|| {
        no_frame("its latest pair's images were let go to keep the live view within --live-view-mib")
    })?;
    let _turn = state
        .display
        .acquire()
        .await
        .map_err(|_| ApiError::shutting_down())?;
    let frame_index = live.result.result.frame;
    let (width, height) = (images[0].width, images[0].height);
    let scale = shrink_factor(width, height, query.max_side);
    let png = tokio::task::spawn_blocking(move || {
        let (frame, shown) = match side {
            Side::Left => (&images[0], live.result.result.left.as_ref()),
            Side::Right => (&images[1], live.result.result.right.as_ref()),
        };
        let colour = match live.result.result.status {
            Status::Initialised | Status::Tracked => PALETTE[0],
            _ => LOST_COLOUR,
        };
        let overlays: Vec<Overlay> = shown
            .filter(|_| query.overlay)
            .map(|r| Overlay {
                contour: &r.contour,
                colour,
            })
            .into_iter()
            .collect();
        render_png(frame, query.max_side, &overlays)
    })
    .await
    .map_err(|e| ApiError::internal(format!("rendering task failed: {e}")))?
    .map_err(ApiError::internal)?;
    Ok((
        [
            (header::CONTENT_TYPE, HeaderValue::from_static("image/png")),
            (header::CACHE_CONTROL, HeaderValue::from_static("no-store")),
            (X_FRAME, HeaderValue::from(frame_index)),
            (X_FRAME_WIDTH, HeaderValue::from(width)),
            (X_FRAME_HEIGHT, HeaderValue::from(height)),
            (X_FRAME_SCALE, HeaderValue::from(scale)),
        ],
        png,
    )
        .into_response())
}

/// Server-sent events: the session's latest result (event `result`, data a
/// FrameResult with contours) at once when there is one, then each newer
/// one, at most every 100 ms; a viewer that reads slowly gets the newest and
/// misses those between. Ends when the session is deleted or the server
/// stops.
#[utoipa::path(
    get,
    path = "/v1/sessions/{id}/events",
    operation_id = "session_events",
    tag = "sessions",
    params(("id" = String, Path, description = "Session id")),
    responses(
        (status = 200, description = "An endless text/event-stream of `result` events", content_type = "text/event-stream", body = String),
        (status = 400, description = "Invalid path: the id is not UTF-8", body = ErrorBody),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
        (status = 404, description = "No such session", body = ErrorBody),
        (status = 503, description = "`busy`: --max-event-streams streams are open; retry after the `Retry-After` seconds", body = ErrorBody),
    )
)]
pub async fn session_events(
    State(state): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Sse<impl Stream<Item = Result<Event, Infallible>>>, ApiError> {
    let session = state.db.session(&id)?;
    // Held for as long as the stream is open.
    let permit = state.event_streams.clone().try_acquire_owned().map_err(|_| {
        ApiError::Busy(format!(
            "{} event streams are open, the most this server keeps (--max-event-streams); retry later",
            state.config.max_event_streams
        ))
    })?;
    let mut rx = session.subscribe_live();
    if rx.borrow().is_some() {
        rx.mark_changed();
    }
    drop(session);
    let stop = state.shutdown.clone();
    let events = futures_util::stream::unfold(
        (rx, stop, true, permit),
        |(mut rx, stop, first, permit)| async move {
            if !first {
                tokio::select! {
                    _ = stop.cancelled() => return None,
                    _ = tokio::time::sleep(EVENT_INTERVAL) => {}
                }
            }
            tokio::select! {
                _ = stop.cancelled() => return None,
                // The sender is gone with the session.
                changed = rx.changed() => changed.ok()?,
            }
            let live = rx.borrow_and_update().clone()?;
            let event = Event::default()
                .event("result")
                .json_data(&live.result)
                .unwrap_or_else(|e| Event::default().event("error").data(e.to_string()));
            Some((Ok(event), (rx, stop, false, permit)))
        },
    );
    Ok(Sse::new(events).keep_alive(KeepAlive::new().interval(Duration::from_secs(15))))
}

/// The page and its files, outside `/v1` (they hold no data; the page asks
/// for the token when the server wants one).
pub fn ui_router() -> Router<AppState> {
    Router::new()
        .route("/", get(|| async { ui_file("index.html") }))
        .route(
            "/ui/{file}",
            get(|axum::extract::Path(file): axum::extract::Path<String>| async move { ui_file(&file) }),
        )
}

/// The embedded files of the page.
const UI_FILES: [(&str, &str, &str); 4] = [
    (
        "index.html",
        "text/html; charset=utf-8",
        include_str!("ui/index.html"),
    ),
    (
        "app.js",
        "text/javascript; charset=utf-8",
        include_str!("ui/app.js"),
    ),
    (
        "style.css",
        "text/css; charset=utf-8",
        include_str!("ui/style.css"),
    ),
    ("icon.svg", "image/svg+xml", include_str!("ui/icon.svg")),
];

fn ui_file(name: &str) -> Response {
    let Some((_, kind, text)) = UI_FILES.iter().find(|(n, _, _)| *n == name) else {
        return ApiError::NotFound(
            "route_not_found",
            format!("no file /ui/{name} (the page's files are index.html, app.js, style.css and icon.svg)"),
        )
        .into_response();
    };
    (
        [
            (header::CONTENT_TYPE, HeaderValue::from_static(kind)),
            (header::CACHE_CONTROL, HeaderValue::from_static("no-cache")),
            (
                header::X_CONTENT_TYPE_OPTIONS,
                HeaderValue::from_static("nosniff"),
            ),
            (
                header::CONTENT_SECURITY_POLICY,
                HeaderValue::from_static(
                    "default-src 'self'; img-src 'self' blob:; connect-src 'self'; frame-ancestors 'none'",
                ),
            ),
        ],
        *text,
    )
        .into_response()
}

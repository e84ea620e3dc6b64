//! `GET /v1/sessions/{id}/stream`: WebSocket streaming of stereo pairs.
//!
//! Each binary message is one pair in the SDP1 format ([`super::wire`]). Each pair is
//! answered by one text message, the FrameResult plus `seq`, or
//! `{"seq": n|null, "error": {...}}` for a malformed message (the socket stays
//! open). A text message `{"reinit": {"init": {...}}}` names the object anew
//! (see [`control`]), answered `{"seq": null, "reinit": <the session>}`.
//!
//! Three tasks per socket: the reader (never waits on processing, so
//! ping/pong stays prompt; tungstenite answers pings while reading), the
//! processor (one pair at a time, in order; pairs already waiting are
//! tracked in the same blocking task, see
//! [`track_stream_batch`](super::pipeline::track_stream_batch)) and the
//! writer (replies in order, a tracked pair's once it is committed, while
//! the processor tracks the next). Between reader
//! and processor sits a bounded queue: with `policy=latest` at most one pair
//! waits and a newer one replaces it (the replaced one is answered
//! `{"seq": n, "status": "skipped"}`); with `policy=all` up to
//! `ws_queue` pairs wait and then the reader stops reading, which slows the
//! sender down through TCP (pongs then wait for at most one pair's
//! processing).

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use axum::extract::ws::{close_code, CloseFrame, Message, WebSocket, WebSocketUpgrade};
use axum::extract::State;
use axum::response::Response;
use futures_util::{SinkExt, StreamExt};
use serde::{Deserialize, Serialize};
use tokio::sync::{mpsc, Notify};
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::db::Session;
use super::error::{ApiError, ApiPath, ApiQuery, ErrorBody};
use super::pipeline::{acknowledge, track_stream_batch, PairQueue, StreamPair, TrackedPair};
use super::state::AppState;
use super::wire::parse_pair_message;

/// The stream route.
pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new().routes(routes!(stream_session))
}

/// Queue policy of a stream.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Policy {
    /// Skip the oldest waiting pairs when pairs arrive faster than they are processed.
    #[default]
    Latest,
    /// Process every pair; the sender is slowed down through the socket.
    All,
}

/// Query of the stream route.
#[derive(Clone, Debug, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct StreamQuery {
    /// `latest` (default) or `all`.
    #[serde(default)]
    pub policy: Policy,
    /// Include the contours in each reply (default true; false empties
    /// their arrays).
    #[serde(default = "super::api::model::yes")]
    pub contours: bool,
}

/// Reply for a pair that was skipped under `policy=latest`.
#[derive(Clone, Debug, Serialize, Deserialize, ToSchema)]
pub struct SkippedReply {
    /// The skipped pair's seq.
    pub seq: u64,
    /// Always `skipped`.
    pub status: String,
}

/// Reply for a malformed message or a pair that could not be processed.
#[derive(Clone, Debug, Serialize, Deserialize, ToSchema)]
pub struct StreamErrorReply {
    /// The pair's seq when the header could be read.
    pub seq: Option<u64>,
    /// What was wrong.
    pub error: super::error::ErrorDetail,
}

/// Reply to a `reinit` text message: the session with its new hints.
#[derive(Clone, Debug, Serialize, ToSchema)]
pub struct ReinitReply {
    /// Always null (the message is no pair).
    pub seq: Option<u64>,
    /// The session, awaiting its next first pair (or its object's).
    pub reinit: super::api::model::SessionView,
}

/// A text message on a stream: `{"reinit": {"init": {...}}}`, with
/// `"object": NAME` in a session of several objects, names the object anew
/// as `POST /v1/sessions/{id}/reinit` (or `.../objects/{name}/reinit`)
/// does: the next pair tracked initialises with the new hints (a pair
/// already waiting in the queue included). Anything else is refused.
async fn control(state: &AppState, id: &str, text: &str) -> Result<super::api::model::SessionView, ApiError> {
    use serde_json::Value;
    let expected = "(expected {\"reinit\": {\"init\": {...hints}}} or one binary SDP1 message per pair)";
    let value: Value = serde_json::from_str(text)
        .map_err(|e| ApiError::bad_request("invalid_json", format!("text message: {e} {expected}")))?;
    let Some(reinit) = value
        .as_object()
        .filter(|o| o.len() == 1)
        .and_then(|o| o.get("reinit"))
        .and_then(Value::as_object)
    else {
        return Err(ApiError::bad_request(
            "expected_binary",
            format!("text message that is no reinit {expected}"),
        ));
    };
    let bad = |m: String| ApiError::bad_request("invalid_json", m);
    if let Some(key) = reinit.keys().find(|k| !matches!(k.as_str(), "init" | "object")) {
        return Err(bad(format!(
            "reinit: unknown field `{key}` (expected init, object)"
        )));
    }
    if let Some(path) = super::error::misplaced_array(reinit, "reinit") {
        return Err(bad(format!(
            "{path}: expected an object or a single value, got an array"
        )));
    }
    let name = match reinit.get("object") {
        None => None,
        Some(Value::String(name)) => Some(name.as_str()),
        Some(other) => return Err(bad(format!("reinit.object: {other} (expected an object's name)"))),
    };
    let body = super::api::model::SessionReinit {
        init: match reinit.get("init") {
            Some(init) => {
                serde_json::from_value(init.clone()).map_err(|e| bad(format!("reinit.init: {e}")))?
            }
            None => Default::default(),
        },
    };
    super::sessions::reinit(state, id, name, &body, reinit).await
}

/// Stream stereo pairs over a WebSocket.
#[utoipa::path(
    get,
    path = "/v1/sessions/{id}/stream",
    operation_id = "stream_session",
    tag = "sessions",
    params(("id" = String, Path, description = "Session id"), StreamQuery),
    responses(
        (status = 101, description = "Switching to the WebSocket protocol: binary SDP1 pair messages in, one JSON text reply per pair out; a text message {\"reinit\": {\"init\": {...hints}, \"object\": NAME}} names the object anew (the next pair tracked initialises with the hints), answered {\"seq\": null, \"reinit\": <the session>}"),
        (status = 400, description = "Not a WebSocket upgrade, invalid query, or an id that is not UTF-8", body = ErrorBody),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
        (status = 404, description = "No such session", body = ErrorBody),
    )
)]
pub async fn stream_session(
    State(state): State<AppState>,
    ApiPath(id): ApiPath<String>,
    ApiQuery(query): ApiQuery<StreamQuery>,
    slot: Option<axum::Extension<super::listener::ConnectionSlot>>,
    upgrade: Result<WebSocketUpgrade, axum::extract::ws::rejection::WebSocketUpgradeRejection>,
) -> Result<Response, ApiError> {
    let session = state.db.session(&id)?;
    let upgrade = upgrade.map_err(|e| {
        let status = if e.status().is_client_error() {
            e.status()
        } else {
            axum::http::StatusCode::BAD_REQUEST
        };
        ApiError::with_status(
            status,
            "websocket_upgrade_required",
            format!("{} (expected a WebSocket upgrade request)", e.body_text()),
        )
    })?;
    let limit = state.config.max_ws_message_bytes;
    let tracker = state.sockets.clone();
    Ok(upgrade
        .max_message_size(limit)
        .max_frame_size(limit)
        .on_upgrade(move |socket| {
            tracker.track_future(async move {
                // The stream counts against the connection cap while open.
                let _slot = slot;
                run_stream(state, session, query, socket).await
            })
        }))
}

/// The `latest` queue: at most one waiting pair; a newer one replaces it.
struct LatestSlot {
    slot: Mutex<VecDeque<StreamPair>>,
    ready: Notify,
}

impl LatestSlot {
    /// Takes the waiting pair, if any.
    fn take(&self) -> Option<StreamPair> {
        self.slot.lock().ok().and_then(|mut s| s.pop_front())
    }
}

/// The reader's end of the queue.
enum QueueIn {
    /// See [`LatestSlot`].
    Latest(Arc<LatestSlot>),
    /// Bounded channel: the reader waits when it is full.
    All(mpsc::Sender<StreamPair>),
}

/// The processor's end of the queue.
enum QueueOut {
    /// See [`LatestSlot`].
    Latest(Arc<LatestSlot>),
    /// Ends when the reader drops its sender.
    All(mpsc::Receiver<StreamPair>),
}

impl QueueOut {
    /// Waits for the next pair; `None` once the reader is gone (`all`) or
    /// `done` is cancelled and nothing waits (`latest`).
    async fn next(&mut self, done: &tokio_util::sync::CancellationToken) -> Option<StreamPair> {
        match self {
            QueueOut::All(rx) => rx.recv().await,
            QueueOut::Latest(latest) => loop {
                match latest.take() {
                    Some(job) => return Some(job),
                    None if done.is_cancelled() => return None,
                    None => {
                        tokio::select! {
                            _ = latest.ready.notified() => {}
                            _ = done.cancelled() => {}
                        }
                    }
                }
            },
        }
    }
}

impl PairQueue for QueueOut {
    fn try_next(&mut self) -> Option<StreamPair> {
        match self {
            QueueOut::All(rx) => rx.try_recv().ok(),
            QueueOut::Latest(latest) => latest.take(),
        }
    }
}

/// How long a stream the server ends with an error keeps its socket open
/// after the close frame, so that the client reads the close before the
/// connection goes.
const CLOSE_LINGER: std::time::Duration = std::time::Duration::from_secs(2);

/// What the writer sends next, in order.
enum Reply {
    /// A reply ready now (an error, a skipped pair).
    Now(Message),
    /// A tracked pair's: its result once committed, else its error.
    Tracked {
        seq: u64,
        received: Instant,
        tracked: Box<Result<TrackedPair, ApiError>>,
    },
}

/// The reply to a tracked pair: its result (without contours unless asked
/// for), or its error with its `seq`; None when it cannot be serialised
/// (logged).
fn tracked_reply(
    seq: u64,
    outcome: Result<super::api::model::FrameResult, ApiError>,
    contours: bool,
) -> Option<Message> {
    let text = match outcome {
        Ok(result) if contours => serde_json::to_string(&result),
        Ok(result) => serde_json::to_string(&result.without_contours()),
        Err(e) => serde_json::to_string(&StreamErrorReply {
            seq: Some(seq),
            error: e.body().error,
        }),
    };
    match text {
        Ok(text) => Some(Message::Text(text.into())),
        Err(e) => {
            tracing::error!(error = %e, "serialising a stream reply");
            None
        }
    }
}

/// The close frame that tells the peer why its stream ends: 1009 for a
/// message or frame over the limit, 1002 for a protocol violation; `None`
/// when the connection itself failed (nothing can be sent).
fn close_frame_for(e: axum::Error, limit_bytes: usize) -> Option<CloseFrame> {
    use tokio_tungstenite::tungstenite::Error;
    let e = e.into_inner().downcast::<Error>().ok()?;
    match *e {
        Error::Capacity(_) => Some(CloseFrame {
            code: close_code::SIZE,
            reason: format!("message too big (limit {limit_bytes} bytes)").into(),
        }),
        Error::Protocol(p) => {
            // A close reason is at most 123 bytes.
            let mut reason = format!("protocol error: {p}");
            while reason.len() > 123 {
                reason.pop();
            }
            Some(CloseFrame {
                code: close_code::PROTOCOL,
                reason: reason.into(),
            })
        }
        _ => None,
    }
}

async fn run_stream(state: AppState, session: Arc<Session>, query: StreamQuery, socket: WebSocket) {
    let (policy, contours) = (query.policy, query.contours);
    state.metrics.active_websockets.inc();
    let (mut sink, mut stream) = socket.split();
    let (reply_tx, mut reply_rx) = mpsc::channel::<Reply>(64);
    let done = tokio_util::sync::CancellationToken::new();
    // Why the reader stopped, when the peer broke the protocol: the close
    // frame says so.
    let broken: Arc<Mutex<Option<CloseFrame>>> = Arc::default();

    // Writer: sends replies in order, a tracked pair's once it is committed
    // (meanwhile the processor already tracks the next), then a close frame
    // once every sender is gone.
    let writer = {
        let (state, session, broken) = (state.clone(), session.clone(), broken.clone());
        tokio::spawn(async move {
            while let Some(reply) = reply_rx.recv().await {
                let message = match reply {
                    Reply::Now(message) => message,
                    Reply::Tracked {
                        seq,
                        received,
                        tracked,
                    } => {
                        let outcome = match *tracked {
                            Ok(tracked) => acknowledge(&state, &session, tracked, received).await,
                            Err(e) => Err(e),
                        };
                        match tracked_reply(seq, outcome, contours) {
                            Some(message) => message,
                            None => continue,
                        }
                    }
                };
                if sink.send(message).await.is_err() {
                    return;
                }
            }
            let broke = broken.lock().ok().and_then(|mut b| b.take());
            let lingers = broke.is_some();
            let frame = broke.unwrap_or_else(|| {
                let (code, reason) = if state.shutdown.is_cancelled() {
                    (close_code::AWAY, "server shutting down")
                } else {
                    (close_code::NORMAL, "")
                };
                CloseFrame {
                    code,
                    reason: reason.into(),
                }
            });
            let _ = sink.send(Message::Close(Some(frame))).await;
            if lingers {
                // The server ends this stream (1009, 1002, 1008), often while
                // the client is still sending: closing the socket now, with
                // its bytes unread, would send a reset that can overtake the
                // close frame and destroy it unread (RFC 6455 7.1.1 has the
                // server wait for the client's close). The stream cannot be
                // read after its error, so the socket is held open, unread,
                // for a bounded time in which the client reads the close.
                tokio::select! {
                    _ = tokio::time::sleep(CLOSE_LINGER) => {}
                    _ = state.shutdown.cancelled() => {}
                }
            }
            let _ = sink.close().await;
        })
    };

    // Processor: one pair at a time, in order (in batches of waiting pairs).
    let (queue_in, queue_out) = match policy {
        Policy::Latest => {
            let slot = Arc::new(LatestSlot {
                slot: Mutex::new(VecDeque::new()),
                ready: Notify::new(),
            });
            (QueueIn::Latest(slot.clone()), QueueOut::Latest(slot))
        }
        Policy::All => {
            let (tx, rx) = mpsc::channel(state.config.ws_queue);
            (QueueIn::All(tx), QueueOut::All(rx))
        }
    };
    let processor = {
        let (state, session, done, reply_tx) =
            (state.clone(), session.clone(), done.clone(), reply_tx.clone());
        tokio::spawn(async move {
            let mut queue = queue_out;
            while let Some(job) = queue.next(&done).await {
                let (reply_tx, done) = (reply_tx.clone(), done.clone());
                // Runs on the blocking pool: sends without awaiting.
                let deliver = move |seq, received, tracked: Result<TrackedPair, ApiError>| {
                    if matches!(&tracked, Err(e) if e.code() == "session_not_found") {
                        done.cancel();
                    }
                    reply_tx
                        .blocking_send(Reply::Tracked {
                            seq,
                            received,
                            tracked: Box::new(tracked),
                        })
                        .is_ok()
                };
                let (returned, go_on) = track_stream_batch(&state, &session, job, queue, deliver).await;
                queue = returned;
                if !go_on {
                    break;
                }
            }
        })
    };

    // Reader (this task).
    let idle = state.config.ws_idle_timeout;
    let say_why = |frame: CloseFrame| {
        if let Ok(mut b) = broken.lock() {
            *b = Some(frame);
        }
    };
    loop {
        let message = tokio::select! {
            _ = state.shutdown.cancelled() => break,
            _ = done.cancelled() => break,
            m = tokio::time::timeout(idle, stream.next()) => match m {
                Ok(m) => m,
                // Nothing whole arrived (a half-sent frame, a client gone
                // silent): the stream ends and says why.
                Err(_) => {
                    tracing::info!(session = %session.id(), idle_s = idle.as_secs_f64(), "stream idle; closing");
                    say_why(CloseFrame {
                        code: close_code::POLICY,
                        reason: format!("no message for {} s (idle timeout)", idle.as_secs_f64()).into(),
                    });
                    break;
                }
            },
        };
        let message = match message {
            Some(Ok(m)) => m,
            // Closed by the peer or a protocol error (e.g. a message over the size limit).
            Some(Err(e)) => {
                tracing::info!(session = %session.id(), error = %e, "stream ended with an error");
                if let Some(frame) = close_frame_for(e, state.config.max_ws_message_bytes) {
                    say_why(frame);
                }
                break;
            }
            None => break,
        };
        let received = Instant::now();
        match message {
            Message::Binary(bytes) => match parse_pair_message(&bytes) {
                Ok(message) => {
                    // The message and its decoded images wait within the memory
                    // budget; meanwhile this socket is not read (back-pressure).
                    let needed = bytes.len() + message.input.decoded_bytes();
                    let held = tokio::select! {
                        held = state.budget.reserve(needed) => match held {
                            Ok(held) => held,
                            Err(_) => break,
                        },
                        _ = state.shutdown.cancelled() => break,
                        _ = done.cancelled() => break,
                    };
                    let pair = StreamPair {
                        input: message.input,
                        provenance: message.provenance,
                        received,
                        seq: message.seq,
                        held,
                    };
                    match &queue_in {
                        QueueIn::Latest(latest) => {
                            let replaced = latest.slot.lock().ok().and_then(|mut s| {
                                let old = s.pop_front();
                                s.push_back(pair);
                                old
                            });
                            latest.ready.notify_one();
                            if let Some(old) = replaced {
                                state.metrics.pairs_skipped.inc();
                                let reply = SkippedReply {
                                    seq: old.seq,
                                    status: "skipped".into(),
                                };
                                if let Ok(text) = serde_json::to_string(&reply) {
                                    if reply_tx
                                        .send(Reply::Now(Message::Text(text.into())))
                                        .await
                                        .is_err()
                                    {
                                        break;
                                    }
                                }
                            }
                        }
                        QueueIn::All(tx) => {
                            let sent = tokio::select! {
                                r = tx.send(pair) => r.is_ok(),
                                _ = state.shutdown.cancelled() => false,
                            };
                            if !sent {
                                break;
                            }
                        }
                    }
                }
                Err((seq, e)) => {
                    state.metrics.failed(e.code());
                    let reply = StreamErrorReply {
                        seq,
                        error: e.body().error,
                    };
                    if let Ok(text) = serde_json::to_string(&reply) {
                        if reply_tx
                            .send(Reply::Now(Message::Text(text.into())))
                            .await
                            .is_err()
                        {
                            break;
                        }
                    }
                }
            },
            Message::Text(text) => {
                let reply = match control(&state, session.id(), &text).await {
                    Ok(view) => serde_json::to_string(&ReinitReply {
                        seq: None,
                        reinit: view,
                    }),
                    Err(e) => serde_json::to_string(&StreamErrorReply {
                        seq: None,
                        error: e.body().error,
                    }),
                };
                if let Ok(text) = reply {
                    if reply_tx
                        .send(Reply::Now(Message::Text(text.into())))
                        .await
                        .is_err()
                    {
                        break;
                    }
                }
            }
            Message::Close(_) => break,
            // Pongs to pings are queued by the protocol layer and flushed
            // by the next read or write.
            Message::Ping(_) | Message::Pong(_) => {}
        }
    }
    // Let the processor finish what was already queued, then close.
    drop(queue_in);
    done.cancel();
    let _ = processor.await;
    drop(reply_tx);
    let _ = writer.await;
    state.metrics.active_websockets.dec();
}

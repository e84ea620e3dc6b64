//! Shared state of a running service: configuration, the [`Db`] of
//! calibrations and sessions, the bounded worker pool, the memory budget
//! and the shutdown signal.

use std::sync::Arc;
use std::time::Duration;

use tokio::sync::Semaphore;
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;

use semdepth_core::imageio::DecodeLimits;

use super::db::Db;
use super::metrics::Metrics;

/// Address `semdepth serve` listens on by default.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:8080";
/// Default database file, relative to the working directory.
pub const DEFAULT_DB_PATH: &str = "data/semdepth.sqlite3";
/// Default request body limit, MiB: two 4096x3072 16-bit images are 50 MB
/// raw; PNG of noisy data can be slightly larger than raw, multipart adds
/// little.
pub const DEFAULT_MAX_BODY_MIB: usize = 128;
/// Default WebSocket message (one pair) limit, MiB.
pub const DEFAULT_MAX_MESSAGE_MIB: usize = 128;
/// Default maximum number of sessions.
pub const DEFAULT_MAX_SESSIONS: usize = 256;
/// Default number of results kept per session.
pub const DEFAULT_RETENTION: u64 = 100_000;
/// Default longest time of one HTTP request, seconds.
pub const DEFAULT_REQUEST_TIMEOUT_S: f64 = 60.0;

/// Default for [`ServiceConfig::header_timeout`], seconds.
pub const DEFAULT_HEADER_TIMEOUT_S: f64 = 10.0;

/// Default for [`ServiceConfig::ws_idle_timeout`], seconds.
pub const DEFAULT_WS_IDLE_TIMEOUT_S: f64 = 300.0;

/// Default for [`ServiceConfig::live_view_bytes`], MiB: the latest pairs
/// of about 80 sessions at 1024x768, 16 bits per sample.
pub const DEFAULT_LIVE_VIEW_MIB: usize = 256;

/// Default for [`ServiceConfig::max_inflight_bytes`], MiB: well inside the
/// compose file's 2 GB limit, with room for the live view's frames and the
/// sessions.
pub const DEFAULT_MAX_INFLIGHT_MIB: usize = 768;

/// Default for [`ServiceConfig::min_free_disk_bytes`], MiB.
pub const DEFAULT_MIN_FREE_DISK_MIB: u64 = 512;

/// Default for [`ServiceConfig::max_connections`]: well inside a 1024
/// file-descriptor limit, with room for the database and its journal.
pub const DEFAULT_MAX_CONNECTIONS: usize = 512;
/// Default for [`ServiceConfig::max_event_streams`]: an eighth of the
/// connections, so that viewers never crowd out the clients that measure.
pub const DEFAULT_MAX_EVENT_STREAMS: usize = 64;
/// Default number of pairs waiting per WebSocket under `policy=all`.
pub const DEFAULT_WS_QUEUE: usize = 4;
/// Default time after which a session without activity is deleted, hours
/// (sessions marked `keep` stay): a week, so that a weekend's pause does
/// not lose an experiment, and scripts' forgotten sessions do not pile up
/// to the session limit.
pub const DEFAULT_SESSION_EXPIRY_H: f64 = 168.0;

/// Everything `semdepth serve` can be configured with (flags and
/// environment variables map onto it in `cli::serve_cmd`).
#[derive(Clone, Debug)]
pub struct ServiceConfig {
    /// SQLite database path, or `:memory:`.
    pub db_path: String,
    /// Bearer token required on `/v1` when set.
    pub token: Option<String>,
    /// Largest request body in bytes (a 4096x3072 16-bit pair as PNG must fit).
    pub max_body_bytes: usize,
    /// Largest WebSocket message (one pair) in bytes.
    pub max_ws_message_bytes: usize,
    /// Limits applied when decoding each image.
    pub decode_limits: DecodeLimits,
    /// Most sessions held at once.
    pub max_sessions: usize,
    /// Pairs processed at once across all sessions (worker threads busy).
    pub workers: usize,
    /// Results kept per session unless the session says otherwise.
    pub default_retention: u64,
    /// Longest time one HTTP request (upload and processing) may take.
    pub request_timeout: Duration,
    /// Pairs that may wait per WebSocket before the policy applies.
    pub ws_queue: usize,
    /// Sessions idle this long (no pair, no change) are deleted unless
    /// marked `keep`; None: never.
    pub session_expiry: Option<Duration>,
    /// Largest size of the database file in bytes; None: the disk's.
    pub max_db_bytes: Option<u64>,
    /// Longest time a client may take to send a request's headers; the
    /// connection is closed after it (a slow-header client holds nothing).
    pub header_timeout: Duration,
    /// Most connections open at once, WebSockets included; beyond it new
    /// connections are closed at once, unread.
    pub max_connections: usize,
    /// Most `GET /v1/sessions/{id}/events` streams open at once; one more
    /// is answered 503 `busy` naming the cap.
    pub max_event_streams: usize,
    /// A WebSocket on which no whole message arrives for this long is
    /// closed (1008, saying so): a half-sent frame holds nothing for good.
    pub ws_idle_timeout: Duration,
    /// Most bytes of decoded images kept for the live view (each session's
    /// latest pair); beyond it the images of the sessions updated longest
    /// ago are let go.
    pub live_view_bytes: usize,
    /// Most bytes of request bodies, stream messages and images decoded
    /// from them held at once; a request beyond it is answered 503 `busy`,
    /// a stream waits.
    pub max_inflight_bytes: usize,
    /// Free bytes kept on the database's file system: below them new
    /// results are refused (503 `disk_nearly_full`) before the disk fills,
    /// and `/readyz` says so. 0: none.
    pub min_free_disk_bytes: u64,
}

impl Default for ServiceConfig {
    fn default() -> Self {
        Self {
            db_path: DEFAULT_DB_PATH.into(),
            token: None,
            max_body_bytes: DEFAULT_MAX_BODY_MIB << 20,
            max_ws_message_bytes: DEFAULT_MAX_MESSAGE_MIB << 20,
            decode_limits: DecodeLimits::default(),
            max_sessions: DEFAULT_MAX_SESSIONS,
            workers: std::thread::available_parallelism().map_or(2, |n| n.get()),
            default_retention: DEFAULT_RETENTION,
            request_timeout: Duration::from_secs_f64(DEFAULT_REQUEST_TIMEOUT_S),
            ws_queue: DEFAULT_WS_QUEUE,
            session_expiry: Some(Duration::from_secs_f64(DEFAULT_SESSION_EXPIRY_H * 3600.0)),
            max_db_bytes: None,
            header_timeout: Duration::from_secs_f64(DEFAULT_HEADER_TIMEOUT_S),
            max_connections: DEFAULT_MAX_CONNECTIONS,
            max_event_streams: DEFAULT_MAX_EVENT_STREAMS,
            ws_idle_timeout: Duration::from_secs_f64(DEFAULT_WS_IDLE_TIMEOUT_S),
            live_view_bytes: DEFAULT_LIVE_VIEW_MIB << 20,
            max_inflight_bytes: DEFAULT_MAX_INFLIGHT_MIB << 20,
            min_free_disk_bytes: DEFAULT_MIN_FREE_DISK_MIB << 20,
        }
    }
}

/// The placeholder token of `docker/semdepth.env.example`, refused as a
/// real token.
pub const EXAMPLE_TOKEN: &str = "change-me-to-a-long-random-string";

impl ServiceConfig {
    /// Checks ranges; the message names the setting and what was expected.
    pub fn validate(&self) -> Result<(), String> {
        if self.max_body_bytes < 1024 {
            return Err(format!(
                "invalid max body {} bytes (expected at least 1024)",
                self.max_body_bytes
            ));
        }
        if self.max_ws_message_bytes < 1024 {
            return Err(format!(
                "invalid max WebSocket message {} bytes (expected at least 1024)",
                self.max_ws_message_bytes
            ));
        }
        let largest = self.max_body_bytes.max(self.max_ws_message_bytes);
        if self.max_inflight_bytes < largest {
            return Err(format!(
                "invalid max in-flight memory {} MiB (expected at least the largest body or message, {} MiB)",
                self.max_inflight_bytes >> 20,
                largest.div_ceil(1 << 20)
            ));
        }
        if !(1..=1024).contains(&self.workers) {
            return Err(format!("invalid workers {} (expected 1..=1024)", self.workers));
        }
        if self.max_sessions == 0 {
            return Err("invalid max sessions 0 (expected at least 1)".into());
        }
        if self.default_retention == 0 {
            return Err("invalid retention 0 (expected at least 1)".into());
        }
        if self.max_connections < 2 {
            return Err(format!(
                "invalid max connections {} (expected at least 2)",
                self.max_connections
            ));
        }
        if self.max_event_streams == 0 {
            return Err("invalid max event streams 0 (expected at least 1)".into());
        }
        if self.header_timeout.is_zero() {
            return Err("invalid header timeout 0 s (expected more than 0)".into());
        }
        if self.ws_idle_timeout.is_zero() {
            return Err("invalid WebSocket idle timeout 0 s (expected more than 0)".into());
        }
        if !(1..=64).contains(&self.ws_queue) {
            return Err(format!(
                "invalid WebSocket queue {} (expected 1..=64)",
                self.ws_queue
            ));
        }
        if let Some(t) = &self.token {
            if t.is_empty() {
                return Err("empty token (expected a non-empty string, or no token)".into());
            }
            if t == EXAMPLE_TOKEN {
                return Err(format!(
                    "the token is the example from docker/semdepth.env.example ({EXAMPLE_TOKEN:?}), which anyone can read (expected a long random one, e.g. python3 -c 'import secrets; print(secrets.token_urlsafe(32))')"
                ));
            }
        }
        Ok(())
    }
}

/// Handle to the service's state; cheap to clone.
#[derive(Clone)]
pub struct AppState(pub Arc<Inner>);

impl std::ops::Deref for AppState {
    type Target = Inner;

    fn deref(&self) -> &Inner {
        &self.0
    }
}

/// The service's state.
pub struct Inner {
    /// Configuration at start-up.
    pub config: ServiceConfig,
    /// Calibrations and sessions, written through to storage.
    pub db: Db,
    /// Bounds the pairs processed at once (`config.workers` permits).
    pub workers: Arc<Semaphore>,
    /// Prometheus metrics.
    pub metrics: Metrics,
    /// Cancelled when the server starts shutting down.
    pub shutdown: CancellationToken,
    /// WebSocket tasks, awaited on shutdown.
    pub sockets: TaskTracker,
    /// One live-view image rendered at a time (outside `workers`).
    pub display: Semaphore,
    /// Bytes of request bodies, stream messages and decoded images in flight.
    pub budget: super::budget::MemoryBudget,
    /// One permit per open event stream (`config.max_event_streams`).
    pub event_streams: Arc<Semaphore>,
}

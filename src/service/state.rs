//! Shared state of a running service: configuration, storage, the
//! calibrations and sessions held in memory (write-through to storage), the
//! bounded worker pool and the shutdown signal.

use std::collections::BTreeMap;
use std::sync::{Arc, RwLock};
use std::time::Duration;

use tokio::sync::{Mutex, OwnedMutexGuard, Semaphore};
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;

use semdepth_core::calib::{Calibration, MetaWatch};
use semdepth_core::imageio::DecodeLimits;
use semdepth_core::tracker::{StereoTracker, TrackerParams};

use super::api::model::SessionView;
use super::error::ApiError;
use super::metrics::Metrics;
use super::storage::{CalibrationRecord, ObjectRecord, SessionRecord, Storage};

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
    /// Durable storage (its own threads).
    pub storage: Storage,
    /// All calibrations, by id (write-through to storage).
    pub calibrations: RwLock<BTreeMap<String, CalibrationRecord>>,
    /// All sessions, the session limit and their write-through to storage.
    pub sessions: super::registry::Registry,
    /// Serialises read-modify-write of calibrations (appending samples).
    pub calibration_writes: Mutex<()>,
    /// Serialises attaching a calibration to a session (creation, PATCH)
    /// with deleting a calibration, so that no session is left pointing
    /// at a deleted one. Taken before any session's core.
    pub calibration_links: Mutex<()>,
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
}

/// One tracked object: its metadata and tracker behind one async lock, so
/// that its pairs are processed strictly in order.
pub struct Session {
    /// Opaque id.
    pub id: String,
    /// Everything mutable; held for the whole processing of a pair. Taken
    /// through [`Session::lock_core`], which first catches it up with
    /// storage when a pair failed to store.
    pub core: Arc<Mutex<SessionCore>>,
    /// Set when a pair of this session failed to store: the core has moved
    /// on without it and is reloaded from storage before its next use.
    pub behind: std::sync::atomic::AtomicBool,
    /// The latest committed pair and its result, for the live view: outside
    /// the core's lock, so viewers never wait for (or delay) a pair.
    pub live: tokio::sync::watch::Sender<Option<Arc<super::live::LiveFrame>>>,
}

impl Session {
    /// A session around `core`.
    pub fn new(id: String, core: SessionCore) -> Self {
        Session {
            id,
            core: Arc::new(Mutex::new(core)),
            behind: Default::default(),
            live: tokio::sync::watch::Sender::new(None),
        }
    }

    /// The core, reloaded from storage first when a pair failed to store
    /// (tracker state and frame count as stored: nothing runs ahead of
    /// storage, and the next frame number follows the last stored one).
    pub async fn lock_core(&self, storage: &Storage) -> Result<OwnedMutexGuard<SessionCore>, ApiError> {
        use std::sync::atomic::Ordering;
        let mut core = self.core.clone().lock_owned().await;
        if self.behind.swap(false, Ordering::AcqRel) && !core.deleted {
            match storage.reload_session(&self.id).await {
                Ok(Some(record)) => {
                    core.reload(record);
                    tracing::warn!(session = %self.id, frames = core.session.frames(), "session reloaded from storage after a failed write");
                }
                Ok(None) => {}
                Err(e) => {
                    self.behind.store(true, Ordering::Release);
                    return Err(e.into());
                }
            }
        }
        Ok(core)
    }
}

/// The mutable part of a session.
pub struct SessionCore {
    /// Label.
    pub name: Option<String>,
    /// Calibration in use.
    pub calibration_id: Option<String>,
    /// Most results kept (None: server default).
    pub retention: Option<u64>,
    /// Exempt from the idle-session expiry.
    pub keep: bool,
    /// `awaiting_first_pair`, `tracking` or `lost`.
    pub state: String,
    /// RFC 3339 UTC.
    pub created_at: String,
    /// RFC 3339 UTC.
    pub updated_at: String,
    /// The objects and their trackers (parameters, contour and pose,
    /// frame counts).
    pub session: semdepth_core::session::Session,
    /// Disparity of the latest pair that was not lost.
    pub latest_disparity_px: Option<[f64; 2]>,
    /// Set when the session is deleted, so that streams still holding it stop.
    pub deleted: bool,
    /// The last pixel size the pairs' metadata gave, to warn once per
    /// magnification change (in memory: a restart warns again).
    pub meta_watch: MetaWatch,
}

impl SessionCore {
    /// A new session of `objects`.
    pub fn new(
        name: Option<String>,
        calibration_id: Option<String>,
        retention: Option<u64>,
        keep: bool,
        objects: semdepth_core::session::Session,
        now: String,
    ) -> Self {
        Self {
            name,
            calibration_id,
            retention,
            keep,
            state: "awaiting_first_pair".into(),
            created_at: now.clone(),
            updated_at: now,
            session: objects,
            latest_disparity_px: None,
            deleted: false,
            meta_watch: MetaWatch::default(),
        }
    }

    /// A session restored from storage.
    pub fn restore(r: SessionRecord, latest_disparity_px: Option<[f64; 2]>) -> Self {
        Self {
            name: r.name,
            calibration_id: r.calibration_id,
            retention: r.retention,
            keep: r.keep,
            state: r.state,
            created_at: r.created_at,
            updated_at: r.updated_at,
            session: session_of(r.objects, r.frames),
            latest_disparity_px,
            deleted: false,
            meta_watch: MetaWatch::default(),
        }
    }

    /// This core as `record` stores it, keeping what is not stored (the
    /// latest disparity and the metadata watch).
    pub fn reload(&mut self, record: SessionRecord) {
        let meta_watch = std::mem::take(&mut self.meta_watch);
        *self = SessionCore::restore(record, self.latest_disparity_px);
        self.meta_watch = meta_watch;
    }

    /// Forgets the object so that the next pair initialises again, with
    /// `params` when given (new hints); the frame count and the results stay.
    pub fn restart(&mut self, params: Option<TrackerParams>) {
        for object in self.session.objects_mut() {
            if let Some(params) = &params {
                object.tracker.set_params(params.clone());
            }
            object.tracker.reset();
        }
        self.state = "awaiting_first_pair".into();
    }

    /// The first object's tracker (a one-object session's only one).
    pub fn primary(&self) -> &StereoTracker {
        &self.session.objects()[0].tracker
    }

    /// The objects as stored.
    pub fn object_records(&self) -> Vec<ObjectRecord> {
        self.session
            .objects()
            .iter()
            .map(|o| ObjectRecord {
                name: o.name.clone(),
                params: o.tracker.params().clone(),
                frames: o.tracker.frames(),
                tracker_state: o.tracker.state().cloned(),
            })
            .collect()
    }

    /// The durable form.
    pub fn record(&self, id: &str) -> SessionRecord {
        SessionRecord {
            id: id.to_string(),
            name: self.name.clone(),
            calibration_id: self.calibration_id.clone(),
            objects: self.object_records(),
            retention: self.retention,
            frames: self.session.frames(),
            state: self.state.clone(),
            created_at: self.created_at.clone(),
            updated_at: self.updated_at.clone(),
            keep: self.keep,
        }
    }

    /// The API form.
    pub fn view(&self, id: &str, default_retention: u64) -> SessionView {
        SessionView::new(&self.record(id), self.latest_disparity_px, default_retention)
    }
}

impl Inner {
    /// The calibration with this id, or 404.
    pub fn calibration(&self, id: &str) -> Result<CalibrationRecord, ApiError> {
        self.calibrations
            .read()
            .map_err(|_| ApiError::internal("calibration table lock poisoned"))?
            .get(id)
            .cloned()
            .ok_or_else(|| ApiError::calibration_not_found(id))
    }

    /// The calibration for computing z and its version, if the id names one.
    pub fn calibration_model(&self, id: Option<&str>) -> Option<(Calibration, u64)> {
        let id = id?;
        let table = self.calibrations.read().ok()?;
        table.get(id).map(|r| (r.calibration.clone(), r.version))
    }
}

/// The library session of stored objects (names checked when they were
/// stored; a set that no longer forms a session, which storage refuses to
/// read, would fall back to its first object).
fn session_of(objects: Vec<ObjectRecord>, frames: u64) -> semdepth_core::session::Session {
    let build = |objects: Vec<ObjectRecord>| {
        objects
            .into_iter()
            .map(|o| semdepth_core::session::SessionObject {
                name: o.name,
                tracker: StereoTracker::from_state(o.params, o.tracker_state, o.frames),
            })
            .collect::<Vec<_>>()
    };
    let first = objects.first().cloned();
    semdepth_core::session::Session::new(build(objects), frames).unwrap_or_else(|e| {
        tracing::error!("stored objects do not form a session ({e}); keeping the first");
        let params = first.map(|o| o.params).unwrap_or_default();
        let mut session = semdepth_core::session::Session::single(params);
        session.set_frames(frames);
        session
    })
}

/// Current time, RFC 3339 UTC with microsecond precision.
pub fn now_rfc3339() -> String {
    let now = time::OffsetDateTime::now_utc();
    let now = now
        .replace_nanosecond(now.nanosecond() / 1_000 * 1_000)
        .unwrap_or(now);
    now.format(&time::format_description::well_known::Rfc3339)
        .unwrap_or_else(|_| "1970-01-01T00:00:00Z".into())
}

/// A new opaque id with a one-letter kind prefix (`s_…`, `c_…`). UUIDv7:
/// ids sort in creation order, which lists use to break ties of equal
/// timestamps.
pub fn new_id(prefix: &str) -> String {
    format!("{prefix}_{}", uuid::Uuid::now_v7().simple())
}

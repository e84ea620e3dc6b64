//! The sessions a running service holds: the table, the session limit,
//! each session's core behind its own lock, the write-through to storage,
//! and each session's latest committed pair for the live view.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, RwLock};
use std::time::{Duration, Instant};

use prometheus_client::metrics::gauge::Gauge;
use tokio::sync::{watch, Mutex, OwnedMutexGuard};

use semdepth_core::calib::MetaWatch;
use semdepth_core::imageio::GrayFrame;
use semdepth_core::tracker::{StereoTracker, TrackerParams};

use crate::service::api::model::{FrameResult, SessionView};
use crate::service::api::SessionState;
use crate::service::error::ApiError;
use crate::service::stamp::{new_id, now_rfc3339};
use crate::service::storage::{ObjectRecord, SessionRecord, Storage};

/// The sessions held, by id, with the limit on their number and the
/// storage every change is written to before it is answered.
pub struct Registry {
    sessions: RwLock<HashMap<String, Arc<Session>>>,
    /// Slots reserved by creations still writing to storage; with the
    /// table's size, held under `max_sessions`.
    pending: std::sync::Mutex<usize>,
    max_sessions: usize,
    default_retention: u64,
    storage: Storage,
    /// The sessions-held gauge of the metrics.
    active: Gauge,
}

impl Registry {
    /// A registry of the sessions restored from storage.
    pub fn new(
        restored: Vec<Arc<Session>>,
        max_sessions: usize,
        default_retention: u64,
        storage: Storage,
        active: Gauge,
    ) -> Self {
        active.set(restored.len() as i64);
        Self {
            sessions: RwLock::new(restored.into_iter().map(|s| (s.id.clone(), s)).collect()),
            pending: Default::default(),
            max_sessions,
            default_retention,
            storage,
            active,
        }
    }

    /// Every session held, in no order.
    pub fn all(&self) -> Result<Vec<Arc<Session>>, ApiError> {
        Ok(self
            .sessions
            .read()
            .map_err(|_| ApiError::internal("session table lock poisoned"))?
            .values()
            .cloned()
            .collect())
    }

    /// The view of every session (caught up with storage), oldest first.
    pub async fn views(&self) -> Result<Vec<SessionView>, ApiError> {
        let mut views = Vec::new();
        for s in self.all()? {
            let core = s.lock_core(&self.storage).await?;
            if !core.deleted {
                views.push(core.view(&s.id, self.default_retention));
            }
        }
        // UUIDv7 ids sort in creation order.
        views.sort_by(|a, b| a.id.cmp(&b.id));
        Ok(views)
    }

    fn pending(&self) -> Result<std::sync::MutexGuard<'_, usize>, ApiError> {
        self.pending
            .lock()
            .map_err(|_| ApiError::internal("session slot lock poisoned"))
    }

    /// A slot for a new session, or 409 `session_limit_reached` when the
    /// sessions held and those being created fill `max_sessions`: checked
    /// and reserved in one step, so concurrent creations never exceed it.
    fn reserve(&self) -> Result<SessionSlot<'_>, ApiError> {
        let mut pending = self.pending()?;
        let held = self
            .sessions
            .read()
            .map_err(|_| ApiError::internal("session table lock poisoned"))?
            .len();
        if held + *pending >= self.max_sessions {
            return Err(ApiError::conflict(
                "session_limit_reached",
                format!(
                    "the server holds its maximum of {} sessions (delete one first)",
                    self.max_sessions
                ),
            ));
        }
        *pending += 1;
        Ok(SessionSlot {
            registry: self,
            filled: false,
        })
    }

    /// The session with this id, or 404.
    pub fn get(&self, id: &str) -> Result<Arc<Session>, ApiError> {
        self.sessions
            .read()
            .map_err(|_| ApiError::internal("session table lock poisoned"))?
            .get(id)
            .cloned()
            .ok_or_else(|| ApiError::session_not_found(id))
    }

    /// The session with this id with its core locked (caught up with
    /// storage first), or 404 when it is unknown or deleted.
    pub async fn core(&self, id: &str) -> Result<OwnedMutexGuard<SessionCore>, ApiError> {
        self.claim(&*self.get(id)?).await
    }

    /// `session`'s core, locked and caught up with storage, or 404 once it
    /// is deleted.
    pub async fn claim(&self, session: &Session) -> Result<OwnedMutexGuard<SessionCore>, ApiError> {
        let core = session.lock_core(&self.storage).await?;
        if core.deleted {
            return Err(ApiError::session_not_found(&session.id));
        }
        Ok(core)
    }

    /// Ids of the sessions whose calibration is `id`.
    pub async fn using_calibration(&self, id: &str) -> Result<Vec<String>, ApiError> {
        let mut users = Vec::new();
        for s in self.all()? {
            let core = s.core.lock().await;
            if !core.deleted && core.calibration_id.as_deref() == Some(id) {
                users.push(s.id.clone());
            }
        }
        users.sort();
        Ok(users)
    }

    /// Creates a session of `core` under the session limit and writes it to
    /// storage before it is listed: its view, or 409
    /// `session_limit_reached`, or the storage error (nothing is kept).
    pub async fn create(&self, core: SessionCore) -> Result<SessionView, ApiError> {
        let slot = self.reserve()?;
        let id = new_id("s");
        let view = core.view(&id, self.default_retention);
        self.storage.upsert_session(core.record(&id)).await?;
        slot.fill(Arc::new(Session::new(id, core)))?;
        Ok(view)
    }

    /// Applies `change` to the session's core (locked and caught up with
    /// storage; 404 when unknown or deleted), stamps it updated and writes
    /// it through to storage. When `change` fails nothing is written, and
    /// when it or storage fails the core is put back as it was: the session
    /// in memory is always the one stored. Returns the session's view.
    pub async fn update(
        &self,
        id: &str,
        change: impl FnOnce(&mut SessionCore) -> Result<(), ApiError>,
    ) -> Result<SessionView, ApiError> {
        let mut core = self.core(id).await?;
        let before = core.record(id);
        if let Err(e) = change(&mut core) {
            core.reload(before);
            return Err(e);
        }
        core.updated_at = now_rfc3339();
        if let Err(e) = self.storage.upsert_session(core.record(id)).await {
            core.reload(before);
            return Err(e.into());
        }
        Ok(core.view(id, self.default_retention))
    }

    /// Deletes the session with this id and its results: waits for a pair
    /// in flight, and streams still holding it stop. 404 when unknown.
    pub async fn remove(&self, id: &str) -> Result<(), ApiError> {
        let session = self.get(id)?;
        let mut core = session.core.lock().await;
        if core.deleted {
            return Err(ApiError::session_not_found(id));
        }
        self.storage.delete_session(id).await?;
        core.deleted = true;
        drop(core);
        self.sessions
            .write()
            .map_err(|_| ApiError::internal("session table lock poisoned"))?
            .remove(id);
        self.active.dec();
        Ok(())
    }

    /// Ids of the sessions that match: last active at least `idle_for` ago
    /// (when given), named with `name_prefix` (when given), and not marked
    /// `keep` unless `include_kept`. A session busy with a pair is active.
    pub fn matching(
        &self,
        idle_for: Option<Duration>,
        name_prefix: Option<&str>,
        include_kept: bool,
    ) -> Result<Vec<String>, ApiError> {
        let now = time::OffsetDateTime::now_utc();
        let all: Vec<Arc<Session>> = self
            .sessions
            .read()
            .map_err(|_| ApiError::internal("session table lock poisoned"))?
            .values()
            .cloned()
            .collect();
        let mut out = Vec::new();
        for session in all {
            let Ok(core) = session.core.try_lock() else {
                continue;
            };
            if core.deleted || (core.keep && !include_kept) {
                continue;
            }
            if let Some(prefix) = name_prefix {
                if !core.name.as_deref().is_some_and(|n| n.starts_with(prefix)) {
                    continue;
                }
            }
            if let Some(idle_for) = idle_for {
                let last = time::OffsetDateTime::parse(
                    &core.updated_at,
                    &time::format_description::well_known::Rfc3339,
                );
                // An unreadable time is no reason to delete.
                let Ok(last) = last else { continue };
                if now - last < idle_for {
                    continue;
                }
            }
            out.push(session.id.clone());
        }
        out.sort();
        Ok(out)
    }

    /// Makes `frame` the session's latest pair, then lets go of the oldest
    /// sessions' images while all live frames hold more than `budget` bytes
    /// (the newest is always kept).
    pub fn publish(&self, session: &Session, mut frame: LiveFrame, budget: usize) {
        if budget == 0 {
            frame.images = None;
        }
        session.live.send_replace(Some(Arc::new(frame)));
        let Ok(sessions) = self.all() else {
            return;
        };
        let mut held: Vec<(Instant, usize, Arc<Session>)> = sessions
            .into_iter()
            .filter_map(|s| {
                let (at, bytes) = s.live.borrow().as_ref().map(|f| (f.at, f.image_bytes()))?;
                (bytes > 0).then_some((at, bytes, s))
            })
            .collect();
        let mut total: usize = held.iter().map(|(_, b, _)| b).sum();
        if total <= budget {
            return;
        }
        held.sort_by_key(|(at, _, _)| *at);
        for (_, bytes, s) in held.iter().take(held.len().saturating_sub(1)) {
            if total <= budget {
                break;
            }
            // Not a new pair: viewers are not told.
            s.live.send_if_modified(|live| {
                if let Some(f) = live {
                    *live = Some(Arc::new(LiveFrame {
                        result: f.result.clone(),
                        images: None,
                        at: f.at,
                    }));
                }
                false
            });
            total -= bytes;
        }
    }
}

/// A slot under the session limit, reserved by [`Registry::reserve`]
/// until the session is inserted ([`SessionSlot::fill`]) or the slot is
/// dropped (the creation failed).
struct SessionSlot<'a> {
    registry: &'a Registry,
    filled: bool,
}

impl SessionSlot<'_> {
    /// Inserts the session into the table in place of the reservation.
    fn fill(mut self, session: Arc<Session>) -> Result<(), ApiError> {
        let mut pending = self.registry.pending()?;
        self.registry
            .sessions
            .write()
            .map_err(|_| ApiError::internal("session table lock poisoned"))?
            .insert(session.id.clone(), session);
        *pending -= 1;
        self.filled = true;
        self.registry.active.inc();
        Ok(())
    }
}

impl Drop for SessionSlot<'_> {
    fn drop(&mut self) {
        if !self.filled {
            if let Ok(mut pending) = self.registry.pending() {
                *pending -= 1;
            }
        }
    }
}

/// One tracked object: its metadata and tracker behind one async lock, so
/// that its pairs are processed strictly in order.
pub struct Session {
    id: String,
    /// Everything mutable; held for the whole processing of a pair. Taken
    /// through [`Session::lock_core`], which first catches it up with
    /// storage when a pair failed to store.
    core: Arc<Mutex<SessionCore>>,
    /// Set when a pair of this session failed to store: the core has moved
    /// on without it and is reloaded from storage before its next use.
    behind: AtomicBool,
    /// The latest committed pair and its result, for the live view: outside
    /// the core's lock, so viewers never wait for (or delay) a pair.
    live: watch::Sender<Option<Arc<LiveFrame>>>,
}

impl Session {
    /// A session around `core`.
    pub fn new(id: String, core: SessionCore) -> Self {
        Session {
            id,
            core: Arc::new(Mutex::new(core)),
            behind: Default::default(),
            live: watch::Sender::new(None),
        }
    }

    /// Opaque id.
    pub fn id(&self) -> &str {
        &self.id
    }

    /// Marks the session to be reloaded from storage before its next use:
    /// a pair of it failed to store, so the core has moved on without it.
    pub fn fell_behind(&self) {
        self.behind.store(true, Ordering::Release);
    }

    /// The latest committed pair, if any was since the server started.
    pub fn live_frame(&self) -> Option<Arc<LiveFrame>> {
        self.live.borrow().clone()
    }

    /// A receiver of each newly committed pair.
    pub fn subscribe_live(&self) -> watch::Receiver<Option<Arc<LiveFrame>>> {
        self.live.subscribe()
    }

    /// The core, reloaded from storage first when a pair failed to store
    /// (tracker state and frame count as stored: nothing runs ahead of
    /// storage, and the next frame number follows the last stored one).
    async fn lock_core(&self, storage: &Storage) -> Result<OwnedMutexGuard<SessionCore>, ApiError> {
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
    /// Where it stands.
    pub state: SessionState,
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
            state: SessionState::AwaitingFirstPair,
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
        self.state = SessionState::AwaitingFirstPair;
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
            state: self.state,
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

/// A session's latest committed pair: its result and, unless let go to keep
/// within the budget, its images as decoded.
pub struct LiveFrame {
    /// The result as acknowledged (contours included).
    pub result: FrameResult,
    /// Left and right images; None once let go.
    pub images: Option<Arc<[GrayFrame; 2]>>,
    /// When it was committed.
    pub at: Instant,
}

impl LiveFrame {
    fn image_bytes(&self) -> usize {
        self.images
            .as_ref()
            .map_or(0, |i| i.iter().map(|f| f.data.len() * 2).sum())
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

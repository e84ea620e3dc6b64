//! The sessions a running service holds: the table, the session limit and
//! the write-through to storage, behind a small API. Handlers parse, call
//! it and map the result; they never take the table's locks or write a
//! session to storage themselves.

use std::collections::HashMap;
use std::sync::{Arc, RwLock};
use std::time::Duration;

use prometheus_client::metrics::gauge::Gauge;
use tokio::sync::OwnedMutexGuard;

use super::api::model::SessionView;
use super::error::ApiError;
use super::state::{new_id, now_rfc3339, Session, SessionCore};
use super::storage::Storage;

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
        let session = self.get(id)?;
        let core = session.lock_core(&self.storage).await?;
        if core.deleted {
            return Err(ApiError::session_not_found(id));
        }
        Ok(core)
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

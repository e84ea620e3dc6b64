//! The one owner of the service's durable state: the calibrations, the
//! sessions and their storage behind a small API, so that handlers never
//! take a lock or write to storage themselves. Every change is committed
//! to storage before it is answered; the tables in memory always hold what
//! is stored.
//!
//! - [`calibrations`]: the calibration table and its refits.
//! - [`sessions`]: the session table, each session's core and live frame.

pub mod calibrations;
pub mod sessions;

use std::sync::Arc;
use std::time::Duration;

use prometheus_client::metrics::gauge::Gauge;
use tokio::sync::{Mutex, OwnedMutexGuard};

use semdepth_core::calib::{CalibError, Calibration};

use super::api::model::{FrameResult, SessionView};
use super::error::ApiError;
use super::storage::{CalibrationRecord, PairRecord, Storage, StorageError};
use calibrations::Calibrations;
use sessions::Registry;
pub use sessions::{LiveFrame, Session, SessionCore};

/// Limits of what the [`Db`] holds.
#[derive(Clone, Copy, Debug)]
pub struct DbLimits {
    /// Most sessions held at once.
    pub max_sessions: usize,
    /// Results kept per session unless the session says otherwise.
    pub default_retention: u64,
    /// Most bytes of decoded images kept for the live view.
    pub live_view_bytes: usize,
}

/// Calibrations and sessions, written through to storage.
pub struct Db {
    storage: Storage,
    calibrations: Calibrations,
    sessions: Registry,
    /// Serialises attaching a calibration to a session (creation, PATCH)
    /// with deleting a calibration, so that no session is left pointing at
    /// a deleted one. Taken before any session's core.
    links: Mutex<()>,
    live_view_bytes: usize,
}

impl Db {
    /// The calibrations and sessions of `storage`, restored. `active` is
    /// the metrics' gauge of sessions held.
    pub async fn open(storage: Storage, limits: DbLimits, active: Gauge) -> Result<Db, StorageError> {
        let calibrations = storage.calibrations().await?;
        let mut sessions = Vec::new();
        for record in storage.sessions().await? {
            let latest = match record.frames.checked_sub(1) {
                Some(last) => storage
                    .results(&record.id, last, 1)
                    .await?
                    .first()
                    .and_then(|(_, json)| serde_json::from_str::<FrameResult>(json).ok())
                    .and_then(|r| r.result.disparity_px),
                None => None,
            };
            let id = record.id.clone();
            sessions.push(Arc::new(Session::new(id, SessionCore::restore(record, latest))));
        }
        tracing::info!(
            calibrations = calibrations.len(),
            sessions = sessions.len(),
            "restored from storage"
        );
        Ok(Db {
            calibrations: Calibrations::new(calibrations, storage.clone()),
            sessions: Registry::new(
                sessions,
                limits.max_sessions,
                limits.default_retention,
                storage.clone(),
                active,
            ),
            storage,
            links: Mutex::new(()),
            live_view_bytes: limits.live_view_bytes,
        })
    }

    // ---- calibrations ----

    /// The calibration with this id, or 404.
    pub fn calibration(&self, id: &str) -> Result<CalibrationRecord, ApiError> {
        self.calibrations.get(id)
    }

    /// The calibration for computing z and its version, if the id names one.
    pub fn calibration_model(&self, id: Option<&str>) -> Option<(Calibration, u64)> {
        self.calibrations.model(id)
    }

    /// Every calibration, oldest first.
    pub fn calibrations(&self) -> Result<Vec<CalibrationRecord>, ApiError> {
        self.calibrations.all()
    }

    /// Version `version` of calibration `id` as it was, or 404.
    pub async fn calibration_version(&self, id: &str, version: u64) -> Result<CalibrationRecord, ApiError> {
        self.calibrations.version(id, version).await
    }

    /// Stores a new calibration.
    pub async fn create_calibration(
        &self,
        name: Option<String>,
        calibration: Calibration,
    ) -> Result<CalibrationRecord, ApiError> {
        self.calibrations.create(name, calibration).await
    }

    /// Deletes calibration `id`: 404 when unknown, 409 `calibration_in_use`
    /// naming the sessions that use it.
    pub async fn delete_calibration(&self, id: &str) -> Result<(), ApiError> {
        let _links = self.links.lock().await;
        self.calibrations.get(id)?;
        let users = self.sessions.using_calibration(id).await?;
        if !users.is_empty() {
            return Err(ApiError::conflict(
                "calibration_in_use",
                format!(
                    "calibration {id:?} is used by session(s) {} (detach it with PATCH /v1/sessions/{{id}} first)",
                    users.join(", ")
                ),
            ));
        }
        self.calibrations.remove(id).await
    }

    /// Changes the samples of the fitted calibration `id` (see
    /// [`Calibrations::refit`]).
    pub async fn refit_calibration(
        &self,
        id: &str,
        change: impl FnOnce(&mut Calibration) -> Result<(), CalibError>,
    ) -> Result<CalibrationRecord, ApiError> {
        self.calibrations.refit(id, change).await
    }

    // ---- sessions ----

    /// The session with this id, or 404.
    pub fn session(&self, id: &str) -> Result<Arc<Session>, ApiError> {
        self.sessions.get(id)
    }

    /// Every session held, in no order.
    pub fn sessions(&self) -> Result<Vec<Arc<Session>>, ApiError> {
        self.sessions.all()
    }

    /// The view of every session, oldest first.
    pub async fn session_views(&self) -> Result<Vec<SessionView>, ApiError> {
        self.sessions.views().await
    }

    /// The session's core, locked and caught up with storage, or 404 when
    /// it is unknown or deleted.
    pub async fn session_core(&self, id: &str) -> Result<OwnedMutexGuard<SessionCore>, ApiError> {
        self.sessions.core(id).await
    }

    /// `session`'s core, locked and caught up with storage (held for the
    /// whole processing of a pair), or 404 once it is deleted.
    pub async fn claim(&self, session: &Session) -> Result<OwnedMutexGuard<SessionCore>, ApiError> {
        self.sessions.claim(session).await
    }

    /// Creates a session of `core` under the session limit; its calibration,
    /// if any, must exist (404) and is not deleted meanwhile.
    pub async fn create_session(&self, core: SessionCore) -> Result<SessionView, ApiError> {
        let _links = self.attaching(core.calibration_id.as_deref()).await?;
        self.sessions.create(core).await
    }

    /// Applies `change` to the session `id` and stores it (see
    /// [`Registry::update`]). `attach`: the calibration the change attaches,
    /// which must exist (404) and is not deleted meanwhile.
    pub async fn update_session(
        &self,
        id: &str,
        attach: Option<&str>,
        change: impl FnOnce(&mut SessionCore) -> Result<(), ApiError>,
    ) -> Result<SessionView, ApiError> {
        self.sessions.get(id)?; // 404 for the session before the calibration
        let _links = self.attaching(attach).await?;
        self.sessions.update(id, change).await
    }

    /// The links lock, held while calibration `id` is attached, after
    /// checking that it exists.
    async fn attaching(&self, id: Option<&str>) -> Result<Option<tokio::sync::MutexGuard<'_, ()>>, ApiError> {
        let Some(id) = id else { return Ok(None) };
        let guard = self.links.lock().await;
        self.calibrations.get(id)?;
        Ok(Some(guard))
    }

    /// Deletes the session and its results (see [`Registry::remove`]).
    pub async fn delete_session(&self, id: &str) -> Result<(), ApiError> {
        self.sessions.remove(id).await
    }

    /// Ids of the sessions that match (see [`Registry::matching`]).
    pub fn sessions_matching(
        &self,
        idle_for: Option<Duration>,
        name_prefix: Option<&str>,
        include_kept: bool,
    ) -> Result<Vec<String>, ApiError> {
        self.sessions.matching(idle_for, name_prefix, include_kept)
    }

    /// Stored results of session `id` from frame `since`, oldest first, at
    /// most `limit`: (frame, result JSON).
    pub async fn results(&self, id: &str, since: u64, limit: usize) -> Result<Vec<(u64, String)>, ApiError> {
        Ok(self.storage.results(id, since, limit).await?)
    }

    /// Queues a pair's result and its session's new state for storage; the
    /// future resolves once they are committed.
    pub fn record_pair(
        &self,
        record: PairRecord,
    ) -> impl std::future::Future<Output = Result<(), StorageError>> + Send + 'static {
        self.storage.record_pair(record)
    }

    /// Makes `frame` the latest pair of session `id` for the live view
    /// (nothing when it was deleted meanwhile), within the live view's
    /// memory.
    pub fn publish(&self, id: &str, frame: LiveFrame) {
        if let Ok(session) = self.sessions.get(id) {
            self.sessions.publish(&session, frame, self.live_view_bytes);
        }
    }

    // ---- storage ----

    /// Storage answers a query and its writes succeed.
    pub async fn ping(&self) -> Result<(), StorageError> {
        self.storage.ping().await
    }

    /// Size of the database file, bytes.
    pub fn bytes(&self) -> u64 {
        self.storage.db_bytes()
    }

    /// Writes what is queued and closes storage.
    pub async fn close(&self) -> Result<(), StorageError> {
        self.storage.close().await
    }
}

//! Durable SQLite storage for the service: calibrations, sessions (with the
//! tracker state needed to continue them after a restart) and per-pair results.
//!
//! # Threads
//!
//! SQLite calls block, so none of them runs on the async executor. A dedicated
//! OS thread (`semdepth-storage-writer`) owns the only read-write connection
//! (bundled SQLite, WAL journal, `foreign_keys=ON`, `busy_timeout` 5 s) and
//! receives commands over one `std::sync::mpsc` channel; every command carries a
//! `tokio::sync::oneshot` sender for its reply, so async callers simply await
//! it. One channel and one writer preserve the order of all writes.
//!
//! Reads (`calibrations`, `sessions`, `results`, `ping`) of a file database go
//! to a second, read-only connection on its own thread
//! (`semdepth-storage-reader`), so they never queue behind writes: WAL lets a
//! reader see the last committed state while the writer commits. A read sees
//! every write whose future has resolved, and nothing uncommitted. An
//! in-memory database (`":memory:"`, or the empty path, a private temporary
//! database) exists only inside its one connection — a second connection would
//! open a different, empty database — so there the writer thread serves the
//! reads too, in queue order.
//!
//! # Durability
//!
//! - Calibrations and session create/update/delete each commit in their own
//!   transaction with `PRAGMA synchronous=FULL` before the caller's future
//!   resolves: they survive power loss.
//! - Pair records (a result plus the session's tracker snapshot after every
//!   pair) use group commit: after receiving a command the writer drains
//!   whatever else is already queued (up to [`StorageOptions::max_batch`]
//!   commands) and commits all consecutive pair records in one transaction with
//!   `synchronous=NORMAL`. In WAL mode a committed transaction then survives a
//!   process crash or SIGKILL; only an OS crash or power loss may lose the last
//!   batches (the WAL is synced at each checkpoint). Each caller's future
//!   resolves only after its batch commits, so nothing the service acknowledged
//!   is lost to a kill, while tracking of the next pair proceeds in parallel.
//!   [`Storage::record_pair`] queues at call time, so call order is commit order.
//!   If a batch fails, its records are retried one transaction each so that one
//!   bad record only fails its own caller.
//! - `PRAGMA synchronous` can only change outside a transaction; the writer sets
//!   it before each transaction when the level differs from the previous one.
//! - [`Storage::close`] waits for every queued write, checkpoints the WAL
//!   (`TRUNCATE`) and closes both connections. Dropping the last handle without
//!   `close` also lets the writer finish what was queued, then exit.
//!
//! # Schema versioning
//!
//! `PRAGMA user_version` holds the schema version. `MIGRATIONS` is an ordered
//! list of SQL scripts; script `i` takes version `i` to `i + 1` and runs in its
//! own transaction together with the version bump. A database whose version is
//! newer than [`SCHEMA_VERSION`] is refused with [`StorageError::SchemaTooNew`]
//! before anything (not even the journal mode) changes: the version is read
//! from the file header first, then again through SQLite (the header may be
//! stale while a WAL holds newer pages) with checkpoint-on-close disabled.
//!
//! JSON columns (calibration bodies, tracker parameters and states) are
//! re-parsed when read; a column that no longer parses is reported as
//! [`StorageError::Corrupt`] naming the row, never a panic. Values that could
//! not be read back (a non-finite number, which JSON stores as `null`) are
//! refused when written ([`StorageError::Unstorable`]).

mod columns;
mod schema;
mod snapshot;
#[cfg(test)]
mod tests;
mod threads;

use crate::service::api::SessionState;
use rusqlite::config::DbConfig;
use rusqlite::{params, Connection, OpenFlags, OptionalExtension};
use semdepth_core::calib::Calibration;
use std::collections::HashSet;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::time::Duration;
use tokio::sync::oneshot;

use columns::{calibration_json, calibration_of, from_i64, snapshot_checked, to_i64};
use schema::{check_version, migrate, probe_header, user_version, MIGRATIONS};
use threads::{
    keep_calibration_version, load_calibrations, load_sessions, prepare_pair, reader_main, writer_main,
    AliveGuard, DiskGuard, Inner, ReadJob, ReaderMsg, Stats, Synchronous, WriteJob, WriterConn, WriterMsg,
    ROOM_PROBE,
};

pub use snapshot::ObjectRecord;

/// Schema version this build creates and understands (`PRAGMA user_version`).
pub const SCHEMA_VERSION: i64 = MIGRATIONS.len() as i64;

/// How long a statement waits for a lock held by another connection.
pub const BUSY_TIMEOUT: Duration = Duration::from_secs(5);

/// Tuning of a [`Storage`].
#[derive(Clone, Debug)]
pub struct StorageOptions {
    /// Most pair records committed in one transaction (default 256).
    pub max_batch: usize,
    /// Largest size of the database file in bytes (SQLite's
    /// `max_page_count`); writes beyond it fail as on a full disk. None: no
    /// limit but the disk's.
    pub max_db_bytes: Option<u64>,
    /// Results kept for a session without a retention of its own (the
    /// server's `--retention`); None: all.
    pub default_retention: Option<u64>,
    /// Free bytes kept on the database's file system: below them, results
    /// are refused ([`StorageError::DiskNearlyFull`]) before the disk fills.
    /// 0: none.
    pub min_free_disk_bytes: u64,
}

impl Default for StorageOptions {
    fn default() -> Self {
        Self {
            max_batch: 256,
            max_db_bytes: None,
            default_retention: None,
            min_free_disk_bytes: 0,
        }
    }
}

/// Everything that can go wrong in storage. [`StorageError::code`] gives a
/// stable snake_case code for API errors and metrics.
#[derive(Debug, thiserror::Error)]
pub enum StorageError {
    /// SQLite failed (I/O error, full disk, lock held past the busy timeout,
    /// constraint violation such as a duplicate id, ...).
    #[error("storage: SQLite error: {0}")]
    Sqlite(#[from] rusqlite::Error),
    /// The database was written by a newer version of the program.
    #[error(
        "storage: the database has schema version {found} but this build supports up to \
         {supported}; refusing to open it (use a newer semdepth, or another database file)"
    )]
    SchemaTooNew {
        /// `user_version` found in the file.
        found: i64,
        /// Newest version this build knows ([`SCHEMA_VERSION`]).
        supported: i64,
    },
    /// A stored value does not parse (JSON column, negative count); the message
    /// names the row and column.
    #[error("storage: corrupt record: {0}")]
    Corrupt(String),
    /// A record cannot be stored so that it reads back (e.g. a non-finite
    /// number in a JSON column, or an integer beyond SQLite's range).
    #[error("storage: record cannot be stored: {0}")]
    Unstorable(String),
    /// The storage was closed, or its writer thread is gone.
    #[error("storage: closed")]
    Closed,
    /// An earlier pair of the session could not be stored, so this one is
    /// refused too: stored frames stay contiguous, and the session goes on
    /// from its last stored pair.
    #[error("storage: an earlier pair of session {0:?} could not be stored, so this one is not stored either (the session goes on from its last stored pair)")]
    Behind(String),
    /// The database's file system has less free space than is kept free.
    #[error(
        "storage: the disk holding the database has {free_mib} MiB free, below the {min_mib} MiB \
         kept free (--min-free-disk-mib); new results are refused until space is freed (delete \
         sessions, lower their retention, or free the disk)"
    )]
    DiskNearlyFull {
        /// Free MiB.
        free_mib: u64,
        /// MiB kept free.
        min_mib: u64,
    },
    /// The last write failed (for readiness), with SQLite's message.
    #[error("storage: writes are failing: {0}")]
    WritesFailing(String),
    /// Creating the database's directory or starting a thread failed.
    #[error("storage: I/O error: {0}")]
    Io(#[from] std::io::Error),
}

impl From<StorageError> for crate::service::error::ApiError {
    fn from(e: StorageError) -> Self {
        Self::Unavailable(e.code(), format!("storage failed: {e}"))
    }
}

impl StorageError {
    /// Stable snake_case code of the error kind.
    pub fn code(&self) -> &'static str {
        match self {
            Self::Sqlite(_) => "storage_error",
            Self::SchemaTooNew { .. } => "schema_too_new",
            Self::Corrupt(_) => "storage_corrupt",
            Self::Unstorable(_) => "unstorable_record",
            Self::Closed => "storage_closed",
            Self::Behind(_) => "storage_behind",
            Self::DiskNearlyFull { .. } => "disk_nearly_full",
            Self::WritesFailing(_) => "storage_writes_failing",
            Self::Io(_) => "storage_io",
        }
    }
}

/// A stored calibration.
#[derive(Clone, Debug, PartialEq)]
pub struct CalibrationRecord {
    /// Unique id.
    pub id: String,
    /// Optional human-readable name.
    pub name: Option<String>,
    /// The calibration (stored as its JSON form, re-validated when read).
    pub calibration: Calibration,
    /// Creation time (RFC 3339 text, chosen by the caller); kept by updates.
    pub created_at: String,
    /// Time of the last change (RFC 3339 text, chosen by the caller).
    pub updated_at: String,
    /// 1 when created, one more with every change; every version is kept
    /// (see [`Storage::calibration_version`]).
    pub version: u64,
}

/// A stored session: its configuration and where its tracking stands.
#[derive(Clone, Debug, PartialEq)]
pub struct SessionRecord {
    /// Unique id.
    pub id: String,
    /// Optional human-readable name.
    pub name: Option<String>,
    /// Calibration applied to its results, if any. Not a foreign key: the
    /// calibration may have been deleted since.
    pub calibration_id: Option<String>,
    /// Its objects: names, tracker parameters and states (the `params` and
    /// `tracker_state` columns, see [`snapshot`]).
    pub objects: Vec<ObjectRecord>,
    /// Most results kept for this session (None: keep all).
    pub retention: Option<u64>,
    /// Pairs processed so far.
    pub frames: u64,
    /// `"awaiting_first_pair"`, `"tracking"` or `"lost"`.
    pub state: SessionState,
    /// Creation time (RFC 3339 text, chosen by the caller); kept by upserts of
    /// an existing session.
    pub created_at: String,
    /// Time of the last change (RFC 3339 text, chosen by the caller).
    pub updated_at: String,
    /// Exempt from the idle-session expiry.
    pub keep: bool,
}

/// What is stored after every pair: its result and the session's new state.
#[derive(Clone, Debug, PartialEq)]
pub struct PairRecord {
    /// Session the pair belongs to.
    pub session_id: String,
    /// Frame index of the pair within the session (0 for the first).
    pub frame: u64,
    /// The FrameResult as the API returns it, already serialised by the caller.
    pub result_json: String,
    /// The session's pair count after this pair.
    pub frames: u64,
    /// The session's state after this pair.
    pub state: SessionState,
    /// The objects' trackers after this pair (their states are stored).
    pub objects: Vec<ObjectRecord>,
    /// Time of this pair (RFC 3339 text), stored as the session's `updated_at`.
    pub updated_at: String,
}

/// Handle to the storage threads. Cheap to clone (all clones share the same
/// threads); `Send + Sync`. See the module documentation for the design.
#[derive(Clone)]
pub struct Storage {
    inner: Arc<Inner>,
}

impl std::fmt::Debug for Storage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (batches, records) = self.batch_stats();
        f.debug_struct("Storage")
            .field("path", &self.inner.path)
            .field("separate_reader", &self.inner.reader.is_some())
            .field("closed", &self.inner.closed.load(Ordering::Acquire))
            .field("batches", &batches)
            .field("records", &records)
            .finish()
    }
}

impl Storage {
    /// Opens (creating parent directories and the file) or ":memory:"; migrates; starts the thread(s).
    ///
    /// `path` is a file name taken literally (no `file:` URIs); `":memory:"`
    /// or `""` give a private database that lives until the storage closes.
    /// This blocks (file I/O, migrations): call it at startup or from
    /// `spawn_blocking`.
    pub fn open(path: &str, options: StorageOptions) -> Result<Storage, StorageError> {
        let memory = path.is_empty() || path == ":memory:";
        if !memory {
            if let Some(parent) = Path::new(path).parent() {
                if !parent.as_os_str().is_empty() {
                    std::fs::create_dir_all(parent)?;
                }
            }
            if Path::new(path).exists() {
                probe_header(path)?;
            }
        }

        let flags = OpenFlags::SQLITE_OPEN_READ_WRITE
            | OpenFlags::SQLITE_OPEN_CREATE
            | OpenFlags::SQLITE_OPEN_NO_MUTEX;
        let conn = Connection::open_with_flags(path, flags)?;
        conn.busy_timeout(BUSY_TIMEOUT)?;
        // The header may be stale (a newer version in the WAL) or the file may
        // have appeared since: check again, and until then do not let closing
        // this connection checkpoint a refused database's WAL into it.
        conn.set_db_config(DbConfig::SQLITE_DBCONFIG_NO_CKPT_ON_CLOSE, true)?;
        check_version(user_version(&conn)?)?;
        conn.set_db_config(DbConfig::SQLITE_DBCONFIG_NO_CKPT_ON_CLOSE, false)?;
        conn.pragma_update(None, "foreign_keys", true)?;
        if !memory {
            let mode: String = conn.pragma_update_and_check(None, "journal_mode", "WAL", |r| r.get(0))?;
            if !mode.eq_ignore_ascii_case("wal") {
                tracing::warn!(
                    path,
                    journal_mode = mode.as_str(),
                    "SQLite refused WAL mode; reads may wait for writes"
                );
            }
        }
        let disk_guard = (!memory && options.min_free_disk_bytes > 0).then(|| DiskGuard {
            dir: Path::new(path)
                .parent()
                .filter(|p| !p.as_os_str().is_empty())
                .unwrap_or(Path::new("."))
                .to_path_buf(),
            min_free: options.min_free_disk_bytes,
        });
        let mut writer = WriterConn {
            conn,
            synchronous: None,
            default_retention: options
                .default_retention
                .map(|r| i64::try_from(r).unwrap_or(i64::MAX)),
            disk_guard: disk_guard.clone(),
            behind: HashSet::new(),
        };
        writer.set_synchronous(Synchronous::Full)?;
        migrate(&mut writer.conn)?;
        if let Some(bytes) = options.max_db_bytes {
            let page: i64 = writer.conn.pragma_query_value(None, "page_size", |r| r.get(0))?;
            let pages = i64::try_from(bytes).unwrap_or(i64::MAX) / page.max(1);
            writer.conn.pragma_update(None, "max_page_count", pages.max(1))?;
        }

        let reader = if memory {
            None
        } else {
            let flags = OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX;
            let conn = Connection::open_with_flags(path, flags)?;
            conn.busy_timeout(BUSY_TIMEOUT)?;
            conn.pragma_update(None, "query_only", true)?;
            Some(conn)
        };

        let stats = Arc::new(Stats::default());
        let writer_alive = Arc::new(AtomicBool::new(true));
        let (writer_tx, writer_rx) = mpsc::channel();
        {
            let stats = stats.clone();
            let alive = AliveGuard(writer_alive.clone());
            let max_batch = options.max_batch.max(1);
            std::thread::Builder::new()
                .name("semdepth-storage-writer".into())
                .spawn(move || writer_main(writer, writer_rx, max_batch, &stats, alive))?;
        }
        let reader_tx = match reader {
            None => None,
            Some(conn) => {
                let (tx, rx) = mpsc::channel();
                std::thread::Builder::new()
                    .name("semdepth-storage-reader".into())
                    .spawn(move || reader_main(conn, rx))?;
                Some(tx)
            }
        };
        Ok(Storage {
            inner: Arc::new(Inner {
                path: path.to_owned(),
                writer: writer_tx,
                reader: reader_tx,
                closed: AtomicBool::new(false),
                writer_alive,
                stats,
                disk_guard,
            }),
        })
    }

    /// Stores a new calibration (durably). A duplicate id is a
    /// [`StorageError::Sqlite`] constraint error.
    pub async fn insert_calibration(&self, rec: CalibrationRecord) -> Result<(), StorageError> {
        let body = calibration_json(&rec)?;
        let version = to_i64(rec.version, "calibration", &rec.id, "version")?;
        self.durable(move |c| {
            c.execute(
                "INSERT INTO calibrations (id, name, body, created_at, updated_at, version)
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6)",
                params![rec.id, rec.name, body, rec.created_at, rec.updated_at, version],
            )?;
            keep_calibration_version(c, &rec.id, version, &body, &rec.updated_at)?;
            Ok(())
        })
        .await
    }

    /// Replaces a calibration's name, body, `updated_at` and version
    /// (durably), and keeps the new version beside the earlier ones; its
    /// `created_at` is kept. False if the id is unknown.
    pub async fn update_calibration(&self, rec: CalibrationRecord) -> Result<bool, StorageError> {
        let body = calibration_json(&rec)?;
        let version = to_i64(rec.version, "calibration", &rec.id, "version")?;
        self.durable(move |c| {
            let n = c.execute(
                "UPDATE calibrations SET name = ?2, body = ?3, updated_at = ?4, version = ?5 WHERE id = ?1",
                params![rec.id, rec.name, body, rec.updated_at, version],
            )?;
            if n > 0 {
                keep_calibration_version(c, &rec.id, version, &body, &rec.updated_at)?;
            }
            Ok(n > 0)
        })
        .await
    }

    /// Version `version` of calibration `id` as it was then (its record,
    /// `updated_at` the time of that version); None when either is unknown.
    pub async fn calibration_version(
        &self,
        id: &str,
        version: u64,
    ) -> Result<Option<CalibrationRecord>, StorageError> {
        let id = id.to_owned();
        let v = to_i64(version, "calibration", &id, "version")?;
        self.read(move |c| {
            let row = c
                .query_row(
                    "SELECT c.name, v.body, c.created_at, v.created_at
                     FROM calibration_versions v JOIN calibrations c ON c.id = v.id
                     WHERE v.id = ?1 AND v.version = ?2",
                    params![id, v],
                    |r| {
                        Ok((
                            r.get::<_, Option<String>>(0)?,
                            r.get::<_, String>(1)?,
                            r.get::<_, String>(2)?,
                            r.get::<_, String>(3)?,
                        ))
                    },
                )
                .optional()?;
            let Some((name, body, created_at, updated_at)) = row else {
                return Ok(None);
            };
            let calibration = calibration_of(&body)
                .map_err(|e| StorageError::Corrupt(format!("calibration {id:?}: column body: {e}")))?;
            Ok(Some(CalibrationRecord {
                id,
                name,
                calibration,
                created_at,
                updated_at,
                version,
            }))
        })
        .await
    }

    /// Deletes a calibration (durably). False if the id is unknown. Sessions
    /// referring to it keep their `calibration_id`.
    pub async fn delete_calibration(&self, id: &str) -> Result<bool, StorageError> {
        let id = id.to_owned();
        self.durable(move |c| {
            c.execute("DELETE FROM calibration_versions WHERE id = ?1", [&id])?;
            Ok(c.execute("DELETE FROM calibrations WHERE id = ?1", [&id])? > 0)
        })
        .await
    }

    /// All calibrations, ordered by `created_at`, then id.
    pub async fn calibrations(&self) -> Result<Vec<CalibrationRecord>, StorageError> {
        self.read(load_calibrations).await
    }

    /// Creates a session or replaces every field of an existing one except
    /// `created_at` (durably). Its results are kept.
    pub async fn upsert_session(&self, rec: SessionRecord) -> Result<(), StorageError> {
        let (params_json, tracker_json) = snapshot_checked(&rec.objects, "session", &rec.id)?;
        let retention = match rec.retention {
            Some(r) => Some(to_i64(r, "session", &rec.id, "retention")?),
            None => None,
        };
        let frames = to_i64(rec.frames, "session", &rec.id, "frames")?;
        self.durable(move |c| {
            // Not INSERT OR REPLACE: that deletes the row, cascading to its results.
            c.execute(
                "INSERT INTO sessions (id, name, calibration_id, params, retention, frames,
                                       state, tracker_state, created_at, updated_at, keep)
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11)
                 ON CONFLICT (id) DO UPDATE SET
                     name = excluded.name, calibration_id = excluded.calibration_id,
                     params = excluded.params, retention = excluded.retention,
                     frames = excluded.frames, state = excluded.state,
                     tracker_state = excluded.tracker_state, updated_at = excluded.updated_at,
                     keep = excluded.keep",
                params![
                    rec.id,
                    rec.name,
                    rec.calibration_id,
                    params_json,
                    retention,
                    frames,
                    rec.state.name(),
                    tracker_json,
                    rec.created_at,
                    rec.updated_at,
                    rec.keep
                ],
            )?;
            Ok(())
        })
        .await
    }

    /// Deletes a session and all its results (durably). False if the id is unknown.
    pub async fn delete_session(&self, id: &str) -> Result<bool, StorageError> {
        let id = id.to_owned();
        self.durable(move |c| Ok(c.execute("DELETE FROM sessions WHERE id = ?1", [id])? > 0))
            .await
    }

    /// All sessions, ordered by `created_at`, then id. A JSON column that does
    /// not parse is a [`StorageError::Corrupt`] naming the session.
    pub async fn sessions(&self) -> Result<Vec<SessionRecord>, StorageError> {
        self.read(|c| load_sessions(c, None)).await
    }

    /// Queues the record NOW (at call time, so call order = commit order) and returns a future that resolves after its batch commits.
    ///
    /// Stores (or replaces) the result of `frame`, updates the session's
    /// `frames`, `state`, `tracker_state` and `updated_at`, then applies the
    /// session's retention: results with `frame <= rec.frame - retention` are
    /// deleted. A record for a session that does not exist (deleted meanwhile)
    /// is dropped and the future resolves to `Ok`.
    pub fn record_pair(
        &self,
        rec: PairRecord,
    ) -> impl std::future::Future<Output = Result<(), StorageError>> + Send + 'static {
        let queued = prepare_pair(rec).and_then(|pair| {
            let (tx, rx) = oneshot::channel();
            self.send_write(WriterMsg::Pair(pair, tx)).map(|()| rx)
        });
        async move {
            match queued {
                Ok(rx) => rx.await.unwrap_or(Err(StorageError::Closed)),
                Err(e) => Err(e),
            }
        }
    }

    /// Results of a session with frame >= since, oldest first, at most `limit`: (frame, result_json).
    pub async fn results(
        &self,
        session_id: &str,
        since: u64,
        limit: usize,
    ) -> Result<Vec<(u64, String)>, StorageError> {
        let session_id = session_id.to_owned();
        // Frames are stored as i64, so clamping these bounds changes nothing.
        let since = i64::try_from(since).unwrap_or(i64::MAX);
        let limit = i64::try_from(limit).unwrap_or(i64::MAX);
        self.read(move |c| {
            let mut stmt = c.prepare_cached(
                "SELECT frame, body FROM results
                 WHERE session_id = ?1 AND frame >= ?2 ORDER BY frame LIMIT ?3",
            )?;
            let rows = stmt.query_map(params![session_id, since, limit], |r| {
                Ok((r.get::<_, i64>(0)?, r.get::<_, String>(1)?))
            })?;
            let mut out = Vec::new();
            for row in rows {
                let (frame, body) = row?;
                out.push((from_i64(frame, "results of session", &session_id, "frame")?, body));
            }
            Ok(out)
        })
        .await
    }

    /// The session as stored, after every pair queued before this call was
    /// written or refused; from then on its pairs are stored again (see
    /// [`StorageError::Behind`]). None when the session is not stored.
    pub async fn reload_session(&self, id: &str) -> Result<Option<SessionRecord>, StorageError> {
        let id = id.to_owned();
        let (tx, rx) = oneshot::channel();
        let job: WriteJob = Box::new(move |w: &mut WriterConn| {
            let found = load_sessions(&w.conn, Some(&id)).map(|mut one| one.pop());
            if found.is_ok() {
                w.behind.remove(&id);
            }
            let _ = tx.send(found);
        });
        self.send_write(WriterMsg::Durable(job))?;
        rx.await.unwrap_or(Err(StorageError::Closed))
    }

    /// A trivial query proving the database answers (for /readyz).
    ///
    /// Fails with [`StorageError::Closed`] when the storage is closed or the
    /// writer thread is gone (the service could no longer store anything),
    /// otherwise reads the schema catalogue through the read path.
    pub async fn ping(&self) -> Result<(), StorageError> {
        if !self.inner.writer_alive.load(Ordering::Acquire) {
            return Err(StorageError::Closed);
        }
        if let Some(guard) = &self.inner.disk_guard {
            guard
                .check()
                .map_err(|e| StorageError::WritesFailing(e.to_string()))?;
        }
        if let Some(reason) = self.inner.stats.failure() {
            // Try a write that needs room (two pages), rolled back by
            // deleting it; it succeeds once space is freed.
            self.durable(|c| {
                c.execute(ROOM_PROBE, [])?;
                c.execute("DELETE FROM write_probe", [])?;
                Ok(())
            })
            .await
            .map_err(|_| StorageError::WritesFailing(reason))?;
            self.inner.stats.write_succeeded();
        }
        self.read(|c| {
            c.query_row("SELECT count(*) FROM sqlite_schema", [], |r| r.get::<_, i64>(0))?;
            Ok(())
        })
        .await
    }

    /// Waits for every queued write to commit, checkpoints the WAL (TRUNCATE), stops the thread(s). Later calls return Closed.
    ///
    /// Reads already queued are answered first. If another process keeps the
    /// database open the checkpoint may be partial; that loses nothing.
    pub async fn close(&self) -> Result<(), StorageError> {
        if self.inner.closed.swap(true, Ordering::AcqRel) {
            return Err(StorageError::Closed);
        }
        if let Some(reader) = &self.inner.reader {
            let (tx, rx) = oneshot::channel();
            if reader.send(ReaderMsg::Stop(tx)).is_ok() {
                let _ = rx.await;
            }
        }
        let (tx, rx) = oneshot::channel();
        self.inner
            .writer
            .send(WriterMsg::Close(tx))
            .map_err(|_| StorageError::Closed)?;
        rx.await.unwrap_or(Err(StorageError::Closed))
    }

    /// Size of the database file (page count times page size, free pages
    /// included, the WAL not) after the last committed batch of pairs.
    pub fn db_bytes(&self) -> u64 {
        self.inner.stats.db_bytes.load(Ordering::Relaxed)
    }

    /// Counters for metrics: (pair batches committed, pair records committed).
    pub fn batch_stats(&self) -> (u64, u64) {
        (
            self.inner.stats.batches.load(Ordering::Relaxed),
            self.inner.stats.records.load(Ordering::Relaxed),
        )
    }

    /// Runs `f` in its own `synchronous=FULL` transaction on the writer thread.
    async fn durable<T, F>(&self, f: F) -> Result<T, StorageError>
    where
        T: Send + 'static,
        F: FnOnce(&Connection) -> Result<T, StorageError> + Send + 'static,
    {
        let (tx, rx) = oneshot::channel();
        let job: WriteJob = Box::new(move |w: &mut WriterConn| {
            let _ = tx.send(w.durable(f));
        });
        self.send_write(WriterMsg::Durable(job))?;
        rx.await.unwrap_or(Err(StorageError::Closed))
    }

    /// Runs `f` on the read connection (the writer's for in-memory databases).
    async fn read<T, F>(&self, f: F) -> Result<T, StorageError>
    where
        T: Send + 'static,
        F: FnOnce(&Connection) -> Result<T, StorageError> + Send + 'static,
    {
        if self.inner.closed.load(Ordering::Acquire) {
            return Err(StorageError::Closed);
        }
        let (tx, rx) = oneshot::channel();
        let job: ReadJob = Box::new(move |c: &Connection| {
            let _ = tx.send(f(c));
        });
        match &self.inner.reader {
            Some(reader) => reader
                .send(ReaderMsg::Job(job))
                .map_err(|_| StorageError::Closed)?,
            None => self.send_write(WriterMsg::Read(job))?,
        }
        rx.await.unwrap_or(Err(StorageError::Closed))
    }

    fn send_write(&self, msg: WriterMsg) -> Result<(), StorageError> {
        if self.inner.closed.load(Ordering::Acquire) {
            return Err(StorageError::Closed);
        }
        self.inner.writer.send(msg).map_err(|_| StorageError::Closed)
    }

    #[cfg(test)]
    fn crash_writer_for_test(&self) {
        let _ = self.inner.writer.send(WriterMsg::Panic);
    }
}

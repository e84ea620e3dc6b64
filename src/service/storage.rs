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

use std::collections::HashSet;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{mpsc, Arc};
use std::time::Duration;

use rusqlite::config::DbConfig;
use rusqlite::{params, Connection, OpenFlags, OptionalExtension, TransactionBehavior};
use tokio::sync::oneshot;

use semdepth_core::calib::Calibration;

use super::api::CalibrationBody;

pub use super::snapshot::ObjectRecord;
use super::snapshot::{encode_definitions, encode_states_checked};

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

/// The free space kept on the database's file system.
#[derive(Clone, Debug)]
struct DiskGuard {
    /// The database's directory.
    dir: std::path::PathBuf,
    /// Bytes kept free.
    min_free: u64,
}

impl DiskGuard {
    /// Ok while more than `min_free` bytes are free for unprivileged writes.
    fn check(&self) -> Result<(), StorageError> {
        let st = rustix::fs::statvfs(&self.dir).map_err(std::io::Error::from)?;
        let free = st.f_bavail.saturating_mul(st.f_frsize);
        if free < self.min_free {
            return Err(StorageError::DiskNearlyFull {
                free_mib: free >> 20,
                min_mib: self.min_free >> 20,
            });
        }
        Ok(())
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
    /// `tracker_state` columns, see [`super::snapshot`]).
    pub objects: Vec<ObjectRecord>,
    /// Most results kept for this session (None: keep all).
    pub retention: Option<u64>,
    /// Pairs processed so far.
    pub frames: u64,
    /// `"awaiting_first_pair"`, `"tracking"` or `"lost"`.
    pub state: String,
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
    pub state: String,
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
                    rec.state,
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

/// A write that needs room for two pages, into the table kept for it: how
/// `/readyz` and the pair writer tell whether a full database has room again.
const ROOM_PROBE: &str = "INSERT INTO write_probe (body) VALUES (zeroblob(8192))";

/// Ordered migrations: `MIGRATIONS[i]` takes `user_version` i to i + 1.
const MIGRATIONS: &[&str] = &[
    // 0 -> 1: initial schema.
    "CREATE TABLE calibrations (
         id TEXT PRIMARY KEY NOT NULL,
         name TEXT,
         body TEXT NOT NULL,            -- JSON of the Calibration
         created_at TEXT NOT NULL,
         updated_at TEXT NOT NULL
     );
     CREATE TABLE sessions (
         id TEXT PRIMARY KEY NOT NULL,
         name TEXT,
         calibration_id TEXT,           -- no FK: the calibration may be deleted
         params TEXT NOT NULL,          -- JSON of the TrackerParams
         retention INTEGER,             -- most results kept; NULL keeps all
         frames INTEGER NOT NULL,
         state TEXT NOT NULL,
         tracker_state TEXT,            -- JSON of the TrackerState
         created_at TEXT NOT NULL,
         updated_at TEXT NOT NULL
     );
     CREATE TABLE results (
         session_id TEXT NOT NULL REFERENCES sessions (id) ON DELETE CASCADE,
         frame INTEGER NOT NULL,
         body TEXT NOT NULL,            -- JSON of the FrameResult
         PRIMARY KEY (session_id, frame)
     ) WITHOUT ROWID;",
    // 1 -> 2: sessions exempt from the idle expiry.
    "ALTER TABLE sessions ADD COLUMN keep INTEGER NOT NULL DEFAULT 0;",
    // 2 -> 3: calibration versions; what exists becomes version 1.
    "ALTER TABLE calibrations ADD COLUMN version INTEGER NOT NULL DEFAULT 1;
     CREATE TABLE calibration_versions (
         id TEXT NOT NULL,
         version INTEGER NOT NULL,
         body TEXT NOT NULL,            -- JSON of the Calibration at that version
         created_at TEXT NOT NULL,
         PRIMARY KEY (id, version)
     ) WITHOUT ROWID;
     INSERT INTO calibration_versions (id, version, body, created_at)
         SELECT id, 1, body, updated_at FROM calibrations;",
    // 3 -> 4: a table for /readyz's write probe.
    "CREATE TABLE write_probe (body BLOB);",
];

struct Inner {
    path: String,
    writer: mpsc::Sender<WriterMsg>,
    /// None for in-memory databases: the writer serves reads.
    reader: Option<mpsc::Sender<ReaderMsg>>,
    closed: AtomicBool,
    writer_alive: Arc<AtomicBool>,
    stats: Arc<Stats>,
    /// The free space kept on the database's file system (None: memory).
    disk_guard: Option<DiskGuard>,
}

#[derive(Default)]
struct Stats {
    batches: AtomicU64,
    records: AtomicU64,
    /// The last pair write's error, until a write succeeds.
    write_failure: std::sync::Mutex<Option<String>>,
    /// Size of the database file after the last committed batch, bytes.
    db_bytes: AtomicU64,
}

/// Clears the flag when the writer thread ends, also by panic.
struct AliveGuard(Arc<AtomicBool>);

impl Drop for AliveGuard {
    fn drop(&mut self) {
        self.0.store(false, Ordering::Release);
    }
}

type Reply<T> = oneshot::Sender<Result<T, StorageError>>;
type ReadJob = Box<dyn FnOnce(&Connection) + Send>;
type WriteJob = Box<dyn FnOnce(&mut WriterConn) + Send>;

enum WriterMsg {
    /// A calibration or session change, in its own FULL transaction.
    Durable(WriteJob),
    /// A pair record for the next group commit.
    Pair(PreparedPair, Reply<()>),
    /// A read (in-memory databases only).
    Read(ReadJob),
    /// Checkpoint, close the connection and stop.
    Close(Reply<()>),
    #[cfg(test)]
    Panic,
}

enum ReaderMsg {
    Job(ReadJob),
    Stop(oneshot::Sender<()>),
}

/// A [`PairRecord`] converted for SQLite on the caller's thread.
struct PreparedPair {
    session_id: String,
    frame: i64,
    result_json: String,
    frames: i64,
    state: String,
    tracker_json: Option<String>,
    updated_at: String,
}

fn prepare_pair(rec: PairRecord) -> Result<PreparedPair, StorageError> {
    let id = &rec.session_id;
    Ok(PreparedPair {
        frame: to_i64(rec.frame, "pair of session", id, "frame")?,
        frames: to_i64(rec.frames, "pair of session", id, "frames")?,
        tracker_json: Some(states_checked(&rec.objects, "pair of session", id)?),
        session_id: rec.session_id,
        result_json: rec.result_json,
        state: rec.state,
        updated_at: rec.updated_at,
    })
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Synchronous {
    Normal,
    Full,
}

/// The write connection and its current `synchronous` level.
struct WriterConn {
    conn: Connection,
    synchronous: Option<Synchronous>,
    /// [`StorageOptions::default_retention`].
    default_retention: Option<i64>,
    /// Checked before every batch of results.
    disk_guard: Option<DiskGuard>,
    /// Sessions with a pair that failed to store: their later pairs are
    /// refused until [`Storage::reload_session`].
    behind: HashSet<String>,
}

impl WriterConn {
    fn set_synchronous(&mut self, level: Synchronous) -> rusqlite::Result<()> {
        if !self.conn.is_autocommit() {
            // A transaction survived an earlier failure; the pragma would be ignored.
            let _ = self.conn.execute_batch("ROLLBACK");
        }
        if self.synchronous != Some(level) {
            let value = match level {
                Synchronous::Normal => "NORMAL",
                Synchronous::Full => "FULL",
            };
            self.synchronous = None;
            self.conn.pragma_update(None, "synchronous", value)?;
            self.synchronous = Some(level);
        }
        Ok(())
    }

    fn durable<T>(
        &mut self,
        f: impl FnOnce(&Connection) -> Result<T, StorageError>,
    ) -> Result<T, StorageError> {
        self.set_synchronous(Synchronous::Full)?;
        let tx = self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)?;
        let value = f(&tx)?;
        tx.commit()?;
        Ok(value)
    }

    /// True when [`ROOM_PROBE`] fits (tried in a transaction that is rolled
    /// back).
    fn has_room(&mut self) -> bool {
        let Ok(tx) = self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)
        else {
            return false;
        };
        let fits = tx.execute(ROOM_PROBE, []).is_ok();
        fits && tx.rollback().is_ok()
    }

    fn commit_pairs<'a>(
        &mut self,
        pairs: impl Iterator<Item = &'a PreparedPair>,
    ) -> Result<(), StorageError> {
        if let Some(guard) = &self.disk_guard {
            guard.check()?;
        }
        self.set_synchronous(Synchronous::Normal)?;
        let tx = self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)?;
        for pair in pairs {
            apply_pair(&tx, pair, self.default_retention)?;
        }
        tx.commit()?;
        Ok(())
    }

    /// Commits the pending pair records as one batch and answers their
    /// callers. A session whose pair fails has its later pairs refused
    /// ([`StorageError::Behind`]) until it is reloaded.
    fn flush_pairs(&mut self, pending: &mut Vec<(PreparedPair, Reply<()>)>, stats: &Stats) {
        if pending.is_empty() {
            return;
        }
        let mut batch = Vec::with_capacity(pending.len());
        for (pair, reply) in pending.drain(..) {
            if self.behind.contains(&pair.session_id) {
                let _ = reply.send(Err(StorageError::Behind(pair.session_id)));
            } else {
                batch.push((pair, reply));
            }
        }
        if batch.is_empty() {
            return;
        }
        // After a failed write, pairs wait for room: a write that needs two
        // pages (as `/readyz` probes) must fit first. Otherwise a pair a
        // little smaller than the one refused may fit where it did not, and
        // a full database stores and refuses pairs by turns.
        if let Some(reason) = stats.failure().filter(|_| !self.has_room()) {
            for (pair, reply) in batch {
                self.behind.insert(pair.session_id.clone());
                let _ = reply.send(Err(StorageError::WritesFailing(reason.clone())));
            }
            return;
        }
        match self.commit_pairs(batch.iter().map(|(p, _)| p)) {
            Ok(()) => {
                stats.add_batch(batch.len());
                stats.write_succeeded();
                self.measure_size(stats);
                for (_, reply) in batch {
                    let _ = reply.send(Ok(()));
                }
            }
            Err(_) => {
                // Isolate the failure: one transaction per record, and
                // nothing more of a session once one of its pairs failed.
                for (pair, reply) in batch {
                    if self.behind.contains(&pair.session_id) {
                        let _ = reply.send(Err(StorageError::Behind(pair.session_id)));
                        continue;
                    }
                    let result = self.commit_pairs(std::iter::once(&pair));
                    match &result {
                        Ok(()) => {
                            stats.add_batch(1);
                            stats.write_succeeded();
                        }
                        Err(e) => {
                            stats.write_failed(e);
                            self.behind.insert(pair.session_id.clone());
                        }
                    }
                    let _ = reply.send(result);
                }
            }
        }
    }

    /// Records the file's size (page count times page size) in `stats`.
    fn measure_size(&self, stats: &Stats) {
        let size = self.conn.query_row(
            "SELECT page_count * page_size FROM pragma_page_count(), pragma_page_size()",
            [],
            |r| r.get::<_, i64>(0),
        );
        if let Ok(size) = size {
            stats
                .db_bytes
                .store(u64::try_from(size).unwrap_or(0), Ordering::Relaxed);
        }
    }

    fn shutdown(self) -> Result<(), StorageError> {
        // (busy, WAL frames, checkpointed frames); busy = 1 only when another
        // process holds the database: the WAL then stays, losing nothing.
        let checkpoint = self
            .conn
            .query_row("PRAGMA wal_checkpoint(TRUNCATE)", [], |r| r.get::<_, i64>(0));
        let closed = self.conn.close().map_err(|(_, e)| e);
        checkpoint?;
        closed?;
        Ok(())
    }
}

impl Stats {
    /// The last failed write's error, until a write succeeds.
    fn failure(&self) -> Option<String> {
        self.write_failure.lock().ok().and_then(|f| f.clone())
    }

    fn write_succeeded(&self) {
        if let Ok(mut f) = self.write_failure.lock() {
            *f = None;
        }
    }

    fn write_failed(&self, e: &StorageError) {
        if let Ok(mut f) = self.write_failure.lock() {
            *f = Some(e.to_string());
        }
    }

    fn add_batch(&self, records: usize) {
        self.batches.fetch_add(1, Ordering::Relaxed);
        self.records.fetch_add(records as u64, Ordering::Relaxed);
    }
}

fn writer_main(
    mut w: WriterConn,
    rx: mpsc::Receiver<WriterMsg>,
    max_batch: usize,
    stats: &Stats,
    _alive: AliveGuard,
) {
    w.measure_size(stats);
    let mut pairs: Vec<(PreparedPair, Reply<()>)> = Vec::new();
    let mut batch: Vec<WriterMsg> = Vec::new();
    while let Ok(first) = rx.recv() {
        batch.push(first);
        while batch.len() < max_batch {
            match rx.try_recv() {
                Ok(msg) => batch.push(msg),
                Err(_) => break,
            }
        }
        for msg in batch.drain(..) {
            match msg {
                WriterMsg::Pair(pair, reply) => pairs.push((pair, reply)),
                WriterMsg::Durable(job) => {
                    w.flush_pairs(&mut pairs, stats);
                    job(&mut w);
                }
                WriterMsg::Read(job) => {
                    w.flush_pairs(&mut pairs, stats);
                    job(&w.conn);
                }
                WriterMsg::Close(reply) => {
                    w.flush_pairs(&mut pairs, stats);
                    let _ = reply.send(w.shutdown());
                    // Whatever was queued after Close is dropped: those callers get Closed.
                    return;
                }
                #[cfg(test)]
                WriterMsg::Panic => panic!("storage writer crash requested by a test"),
            }
        }
        w.flush_pairs(&mut pairs, stats);
    }
}

fn reader_main(conn: Connection, rx: mpsc::Receiver<ReaderMsg>) {
    while let Ok(msg) = rx.recv() {
        match msg {
            ReaderMsg::Job(job) => job(&conn),
            ReaderMsg::Stop(ack) => {
                drop(conn);
                let _ = ack.send(());
                return;
            }
        }
    }
}

/// Stores one pair: the session's row, the result, and the pruning of
/// results beyond the session's retention (`default_retention` when it has
/// none of its own).
fn apply_pair(c: &Connection, p: &PreparedPair, default_retention: Option<i64>) -> Result<(), StorageError> {
    // The changes happen on the first step, so one row read is enough.
    let retention: Option<Option<i64>> = c
        .prepare_cached(
            "UPDATE sessions SET frames = ?2, state = ?3, tracker_state = ?4, updated_at = ?5
             WHERE id = ?1 RETURNING retention",
        )?
        .query_row(
            params![p.session_id, p.frames, p.state, p.tracker_json, p.updated_at],
            |r| r.get(0),
        )
        .optional()?;
    let Some(retention) = retention else {
        return Ok(()); // the session is gone
    };
    c.prepare_cached(
        "INSERT INTO results (session_id, frame, body) VALUES (?1, ?2, ?3)
         ON CONFLICT (session_id, frame) DO UPDATE SET body = excluded.body",
    )?
    .execute(params![p.session_id, p.frame, p.result_json])?;
    if let Some(keep) = retention.or(default_retention).filter(|k| *k >= 0) {
        // frame >= 0 and keep >= 0, so this cannot overflow.
        let cutoff = p.frame - keep;
        if cutoff >= 0 {
            c.prepare_cached("DELETE FROM results WHERE session_id = ?1 AND frame <= ?2")?
                .execute(params![p.session_id, cutoff])?;
        }
    }
    Ok(())
}

/// Stores a calibration's body as version `version` beside the others.
fn keep_calibration_version(
    c: &Connection,
    id: &str,
    version: i64,
    body: &str,
    at: &str,
) -> rusqlite::Result<usize> {
    c.execute(
        "INSERT OR REPLACE INTO calibration_versions (id, version, body, created_at) VALUES (?1, ?2, ?3, ?4)",
        params![id, version, body, at],
    )
}

fn load_calibrations(c: &Connection) -> Result<Vec<CalibrationRecord>, StorageError> {
    let mut stmt = c.prepare_cached(
        "SELECT id, name, body, created_at, updated_at, version FROM calibrations ORDER BY created_at, id",
    )?;
    let rows = stmt.query_map([], |r| {
        Ok((
            r.get::<_, String>(0)?,
            r.get::<_, Option<String>>(1)?,
            r.get::<_, String>(2)?,
            r.get::<_, String>(3)?,
            r.get::<_, String>(4)?,
            r.get::<_, i64>(5)?,
        ))
    })?;
    let mut out = Vec::new();
    for row in rows {
        let (id, name, body, created_at, updated_at, version) = row?;
        let calibration = calibration_of(&body)
            .map_err(|e| StorageError::Corrupt(format!("calibration {id:?}: column body: {e}")))?;
        let version = from_i64(version, "calibration", &id, "version")?;
        out.push(CalibrationRecord {
            id,
            name,
            calibration,
            created_at,
            updated_at,
            version,
        });
    }
    Ok(out)
}

/// Every stored session, or only the one with id `only`.
fn load_sessions(c: &Connection, only: Option<&str>) -> Result<Vec<SessionRecord>, StorageError> {
    let mut stmt = c.prepare_cached(
        "SELECT id, name, calibration_id, params, retention, frames, state, tracker_state,
                created_at, updated_at, keep
         FROM sessions WHERE ?1 IS NULL OR id = ?1 ORDER BY created_at, id",
    )?;
    let rows = stmt.query_map(params![only], |r| {
        Ok((
            (
                r.get::<_, String>(0)?,
                r.get::<_, Option<String>>(1)?,
                r.get::<_, Option<String>>(2)?,
                r.get::<_, String>(3)?,
                r.get::<_, Option<i64>>(4)?,
            ),
            (
                r.get::<_, i64>(5)?,
                r.get::<_, String>(6)?,
                r.get::<_, Option<String>>(7)?,
                r.get::<_, String>(8)?,
                r.get::<_, String>(9)?,
                r.get::<_, bool>(10)?,
            ),
        ))
    })?;
    let mut out = Vec::new();
    for row in rows {
        let (
            (id, name, calibration_id, params, retention),
            (frames, state, tracker_state, created_at, updated_at, keep),
        ) = row?;
        let retention = match retention {
            Some(v) => Some(from_i64(v, "session", &id, "retention")?),
            None => None,
        };
        let frames = from_i64(frames, "session", &id, "frames")?;
        let decoded = super::snapshot::decode(&params, tracker_state.as_deref(), frames)
            .map_err(|e| StorageError::Corrupt(format!("session {id:?}: {e}")))?;
        for note in &decoded.notes {
            tracing::warn!(session = %id, "{note}");
        }
        let objects = decoded.objects;
        out.push(SessionRecord {
            id,
            name,
            calibration_id,
            objects,
            retention,
            frames,
            state,
            created_at,
            updated_at,
            keep,
        });
    }
    Ok(out)
}

/// Checks the `user_version` in the file's header (big-endian i32 at offset
/// 60) without opening it in SQLite, which would leave `-wal`/`-shm` files next
/// to a WAL database we must refuse. A file too short or without the SQLite
/// magic is left for SQLite to judge.
fn probe_header(path: &str) -> Result<(), StorageError> {
    use std::io::Read;
    let mut header = Vec::with_capacity(100);
    std::fs::File::open(path)?.take(100).read_to_end(&mut header)?;
    if header.len() < 100 || !header.starts_with(b"SQLite format 3\0") {
        return Ok(());
    }
    let found = i32::from_be_bytes([header[60], header[61], header[62], header[63]]);
    check_version(i64::from(found))
}

fn user_version(c: &Connection) -> rusqlite::Result<i64> {
    c.pragma_query_value(None, "user_version", |r| r.get(0))
}

fn check_version(found: i64) -> Result<(), StorageError> {
    if found > SCHEMA_VERSION {
        return Err(StorageError::SchemaTooNew {
            found,
            supported: SCHEMA_VERSION,
        });
    }
    if found < 0 {
        return Err(StorageError::Corrupt(format!(
            "database user_version is negative ({found})"
        )));
    }
    Ok(())
}

/// Applies the missing migrations, each in its own transaction with its version bump.
fn migrate(conn: &mut Connection) -> Result<(), StorageError> {
    loop {
        let tx = conn.transaction_with_behavior(TransactionBehavior::Immediate)?;
        // Read again under the write lock: another process may have migrated.
        let version = user_version(&tx)?;
        check_version(version)?;
        if version == SCHEMA_VERSION {
            tx.commit()?;
            return Ok(());
        }
        tx.execute_batch(MIGRATIONS[version as usize])?;
        tx.pragma_update(None, "user_version", version + 1)?;
        tx.commit()?;
    }
}

fn calibration_json(rec: &CalibrationRecord) -> Result<String, StorageError> {
    let body = serde_json::to_string(&CalibrationBody::from(&rec.calibration))
        .map_err(|e| StorageError::Unstorable(format!("calibration {:?}: body: {e}", rec.id)))?;
    // The body is validated again when read: refuse now what would not read back.
    calibration_of(&body).map_err(|e| {
        StorageError::Unstorable(format!("calibration {:?}: body would not read back: {e}", rec.id))
    })?;
    Ok(body)
}

/// The calibration a stored body holds, rebuilt from its parameters.
fn calibration_of(body: &str) -> Result<Calibration, String> {
    let body: CalibrationBody = serde_json::from_str(body).map_err(|e| e.to_string())?;
    Calibration::try_from(body).map_err(|e| e.to_string())
}

/// The `params` and `tracker_state` columns of a session's objects,
/// checked to read back as they are (JSON has no NaN or infinity:
/// serde_json writes them as `null`, which would not read back).
fn snapshot_checked(
    objects: &[ObjectRecord],
    kind: &str,
    id: &str,
) -> Result<(String, String), StorageError> {
    let params = encode_definitions(objects)
        .map_err(|e| StorageError::Unstorable(format!("{kind} {id:?}: params: {e}")))?;
    match super::snapshot::decode(&params, None, 0) {
        Ok(d) if d.notes.is_empty() => {}
        Ok(d) => {
            return Err(StorageError::Unstorable(format!(
                "{kind} {id:?}: params would not read back (non-finite number?): {}",
                d.notes.join("; ")
            )))
        }
        Err(e) => return Err(StorageError::Unstorable(format!("{kind} {id:?}: {e}"))),
    }
    Ok((params, states_checked(objects, kind, id)?))
}

/// The `tracker_state` column alone (stored after every pair), checked to
/// read back as [`snapshot_checked`] checks it.
fn states_checked(objects: &[ObjectRecord], kind: &str, id: &str) -> Result<String, StorageError> {
    encode_states_checked(objects).map_err(|e| {
        StorageError::Unstorable(format!(
            "{kind} {id:?}: tracker_state would not read back (non-finite number?): {e}"
        ))
    })
}

fn to_i64(value: u64, kind: &str, id: &str, what: &str) -> Result<i64, StorageError> {
    i64::try_from(value).map_err(|_| {
        StorageError::Unstorable(format!(
            "{kind} {id:?}: {what} = {value} exceeds SQLite's integer range"
        ))
    })
}

fn from_i64(value: i64, kind: &str, id: &str, what: &str) -> Result<u64, StorageError> {
    u64::try_from(value)
        .map_err(|_| StorageError::Corrupt(format!("{kind} {id:?}: {what} is negative ({value})")))
}

#[cfg(test)]
mod tests {
    use super::*;
    use semdepth_core::calib::{build, CalibrationSpec, GeometricSpec};
    use semdepth_core::fit::Pose;
    use semdepth_core::geometry::HalfPlane;
    use semdepth_core::scatter::{DisparityRun, Measured};
    use semdepth_core::tracker::{Phase, TrackerParams, TrackerState};

    fn calibration(pixel_size_um: f64) -> Calibration {
        build(CalibrationSpec::Geometric(GeometricSpec {
            pixel_size_um: Some(pixel_size_um),
            pixel_size: None,
            vergence_deg: Some(6.0),
            vergence: None,
            reference_disparity_px: 0.0,
            tilt_axis_deg: 90.0,
        }))
        .unwrap()
    }

    fn calibration_record(id: &str, created_at: &str, pixel_size_um: f64) -> CalibrationRecord {
        CalibrationRecord {
            id: id.into(),
            name: Some(format!("cal {id}")),
            calibration: calibration(pixel_size_um),
            created_at: created_at.into(),
            updated_at: created_at.into(),
            version: 1,
        }
    }

    /// A tracker state that differs for every `i`.
    fn tracker_state(i: u64) -> TrackerState {
        let f = i as f64;
        TrackerState {
            template: vec![[-3.0, -2.0], [3.0, -2.0], [0.0, 4.0 + 0.125 * f]],
            left: Pose {
                x: 10.0 + f,
                y: 20.0 - 0.5 * f,
                theta: 0.01 * f,
            },
            right: Pose {
                x: 36.25 + f,
                y: 24.5,
                theta: 0.1,
            },
            reference_contrast: 0.4,
            first_disparity_axis_px: 26.25,
            first_disparity_px: Some([26.25, 0.5]),
            width: 64,
            height: 48,
            phase: match i % 7 {
                6 => Phase::Searching {
                    missed: (i % 3) as u32,
                },
                5 => Phase::Reinitialising,
                _ => Phase::Tracking {
                    velocity_measured: i % 5 != 4,
                },
            },
            left_velocity: [1.0, -0.5, 0.01],
            left_sector_contrasts: vec![0.1, 0.2, 1.0 / 3.0],
            right_sector_contrasts: vec![0.3, f],
            left_sector_inner: vec![120.5, 99.0 + f, 0.0],
            right_sector_inner: vec![101.25, f],
            template_cuts: vec![HalfPlane::new([1.0, 0.0], -3.5 - f)],
            outline: vec![[-4.0, -3.0], [4.0, -3.0], [0.0, 5.0 + 0.125 * f]],
            prefilter_sigma_px: 0.5 * f,
            refused_inits: (i % 2) as u32,
            uncertain_run: (i % 2 == 1).then_some(0.5 * f),
            first_disparity_std_px: 0.25 * f,
            disparity_run: {
                let mut run = DisparityRun::default();
                for k in 0..i % 4 {
                    run.push(Measured {
                        frame: i + k,
                        disparity_px: 26.25 + 0.5 * k as f64,
                        std_px: 0.05 + 0.01 * f,
                    });
                }
                run
            },
        }
    }

    fn session(id: &str, created_at: &str, retention: Option<u64>) -> SessionRecord {
        SessionRecord {
            id: id.into(),
            name: Some(format!("session {id}")),
            calibration_id: Some("cal-a".into()),
            objects: vec![ObjectRecord {
                name: "object".into(),
                params: TrackerParams {
                    max_disparity_px: 48.0,
                    ..TrackerParams::default()
                },
                frames: 0,
                tracker_state: None,
            }],
            retention,
            frames: 0,
            state: "awaiting_first_pair".into(),
            created_at: created_at.into(),
            updated_at: created_at.into(),
            keep: false,
        }
    }

    fn result_json(session_id: &str, frame: u64) -> String {
        format!(
            r#"{{"session":"{session_id}","frame":{frame},"z_um":{}}}"#,
            frame as f64 * 0.25
        )
    }

    fn pair(session_id: &str, frame: u64) -> PairRecord {
        PairRecord {
            session_id: session_id.into(),
            frame,
            result_json: result_json(session_id, frame),
            frames: frame + 1,
            state: if frame % 7 == 6 { "lost" } else { "tracking" }.into(),
            objects: vec![ObjectRecord {
                name: "object".into(),
                params: TrackerParams {
                    max_disparity_px: 48.0,
                    ..TrackerParams::default()
                },
                frames: frame + 1,
                tracker_state: Some(tracker_state(frame)),
            }],
            updated_at: format!("2024-05-01T00:{:02}:{:02}Z", frame / 60 % 60, frame % 60),
        }
    }

    /// The session after `n` pairs recorded with [`pair`].
    fn after_pairs(mut s: SessionRecord, n: u64) -> SessionRecord {
        let last = pair(&s.id, n - 1);
        s.frames = last.frames;
        s.state = last.state;
        s.objects = last.objects;
        s.updated_at = last.updated_at;
        s
    }

    /// A database path in a directory that does not exist yet.
    fn db_path(dir: &tempfile::TempDir) -> String {
        dir.path()
            .join("nested/data/semdepth.db")
            .to_str()
            .unwrap()
            .to_owned()
    }

    fn open(path: &str) -> Storage {
        Storage::open(path, StorageOptions::default()).unwrap()
    }

    fn raw(path: &str) -> Connection {
        let c = Connection::open(path).unwrap();
        c.busy_timeout(BUSY_TIMEOUT).unwrap();
        c
    }

    fn frames_of(results: &[(u64, String)]) -> Vec<u64> {
        results.iter().map(|(f, _)| *f).collect()
    }

    fn is_closed<T: std::fmt::Debug>(r: Result<T, StorageError>) -> bool {
        matches!(r, Err(StorageError::Closed))
    }

    #[tokio::test]
    async fn calibrations_survive_reopen_update_and_delete() {
        let dir = tempfile::tempdir().unwrap();
        let path = db_path(&dir);
        let a = calibration_record("cal-a", "2024-01-02T00:00:00Z", 0.5);
        let mut b = calibration_record("cal-b", "2024-01-01T00:00:00Z", 0.25);
        b.name = None;
        let s = open(&path);
        s.insert_calibration(a.clone()).await.unwrap();
        s.insert_calibration(b.clone()).await.unwrap();
        let dup = s.insert_calibration(a.clone()).await.unwrap_err();
        assert_eq!(dup.code(), "storage_error", "{dup}");
        s.close().await.unwrap();

        let s = open(&path);
        // Ordered by created_at: b was created first.
        assert_eq!(s.calibrations().await.unwrap(), vec![b.clone(), a.clone()]);

        let mut a2 = calibration_record("cal-a", "2030-01-01T00:00:00Z", 2.0);
        a2.name = Some("renamed".into());
        a2.updated_at = "2024-02-01T00:00:00Z".into();
        assert!(s.update_calibration(a2.clone()).await.unwrap());
        let unknown = calibration_record("nope", "2024-01-01T00:00:00Z", 1.0);
        assert!(!s.update_calibration(unknown).await.unwrap());
        assert!(s.delete_calibration("cal-b").await.unwrap());
        assert!(!s.delete_calibration("cal-b").await.unwrap());
        assert!(!s.delete_calibration("nope").await.unwrap());
        s.close().await.unwrap();

        let s = open(&path);
        let expected = CalibrationRecord {
            created_at: a.created_at.clone(), // an update keeps created_at
            ..a2
        };
        assert_eq!(s.calibrations().await.unwrap(), vec![expected]);
        s.close().await.unwrap();
        let version: i64 = raw(&path)
            .pragma_query_value(None, "user_version", |r| r.get(0))
            .unwrap();
        assert_eq!(version, SCHEMA_VERSION);
    }

    #[tokio::test]
    async fn sessions_and_pairs_survive_reopen() {
        let dir = tempfile::tempdir().unwrap();
        let path = db_path(&dir);
        let s = open(&path);
        let first = session("s-1", "2024-05-01T00:00:00Z", None);
        let second = session("s-0", "2024-05-02T00:00:00Z", Some(100));
        s.upsert_session(first.clone()).await.unwrap();
        s.upsert_session(second.clone()).await.unwrap();
        for frame in 0..10 {
            s.record_pair(pair("s-1", frame)).await.unwrap();
        }
        s.close().await.unwrap();

        let s = open(&path);
        assert_eq!(s.sessions().await.unwrap(), vec![after_pairs(first, 10), second]);
        let all = s.results("s-1", 0, 100).await.unwrap();
        assert_eq!(frames_of(&all), (0..10).collect::<Vec<_>>());
        for (frame, body) in &all {
            assert_eq!(body, &result_json("s-1", *frame));
        }
        assert_eq!(frames_of(&s.results("s-1", 3, 4).await.unwrap()), [3, 4, 5, 6]);
        assert_eq!(frames_of(&s.results("s-1", 8, 100).await.unwrap()), [8, 9]);
        assert!(s.results("s-1", 10, 100).await.unwrap().is_empty());
        assert!(s.results("s-1", u64::MAX, 100).await.unwrap().is_empty());
        assert!(s.results("s-1", 0, 0).await.unwrap().is_empty());
        assert!(s.results("s-0", 0, 100).await.unwrap().is_empty());
        assert!(s.results("unknown", 0, 100).await.unwrap().is_empty());
        s.ping().await.unwrap();
        s.close().await.unwrap();
    }

    #[tokio::test]
    async fn retention_keeps_only_the_newest_results() {
        let dir = tempfile::tempdir().unwrap();
        let path = db_path(&dir);
        let s = open(&path);
        s.upsert_session(session("kept", "2024-05-01T00:00:00Z", Some(5)))
            .await
            .unwrap();
        s.upsert_session(session("all", "2024-05-01T00:00:01Z", None))
            .await
            .unwrap();
        for frame in 0..20 {
            let a = s.record_pair(pair("kept", frame));
            let b = s.record_pair(pair("all", frame));
            a.await.unwrap();
            b.await.unwrap();
        }
        let kept = s.results("kept", 0, 100).await.unwrap();
        assert_eq!(frames_of(&kept), [15, 16, 17, 18, 19]);
        let all = s.results("all", 0, 100).await.unwrap();
        assert_eq!(frames_of(&all), (0..20).collect::<Vec<_>>());
        s.close().await.unwrap();
        let rows: i64 = raw(&path)
            .query_row(
                "SELECT count(*) FROM results WHERE session_id = 'kept'",
                [],
                |r| r.get(0),
            )
            .unwrap();
        assert_eq!(rows, 5);
    }

    /// Once a pair fails for want of room, a much smaller one is refused
    /// too until two pages are free: a full database does not store and
    /// refuse pairs by turns (the first refused pair, 40 KB, leaves room a
    /// small pair would fit in).
    #[tokio::test]
    async fn a_full_database_refuses_smaller_pairs_until_room_is_freed() {
        let dir = tempfile::tempdir().unwrap();
        let path = db_path(&dir);
        let options = StorageOptions {
            max_db_bytes: Some(600 * 1024),
            ..StorageOptions::default()
        };
        let s = Storage::open(&path, options).unwrap();
        for id in ["big", "small"] {
            s.upsert_session(session(id, "2024-05-01T00:00:00Z", None))
                .await
                .unwrap();
        }
        let mut frame = 0;
        let refusal = loop {
            let mut big = pair("big", frame);
            big.result_json = format!(r#"{{"frame":{frame},"pad":"{}"}}"#, "x".repeat(40 * 1024));
            match s.record_pair(big).await {
                Ok(()) => frame += 1,
                Err(e) => break e,
            }
            assert!(frame < 100, "the size limit never took effect");
        };
        assert!(refusal.to_string().contains("full"), "{refusal}");
        // Each try as the service makes it: the session reloaded from what
        // is stored, then its pair.
        for _ in 0..3 {
            s.reload_session("small").await.unwrap();
            let e = s.record_pair(pair("small", 0)).await.unwrap_err();
            assert_eq!(e.code(), "storage_writes_failing", "{e}");
        }
        assert!(s.results("small", 0, 10).await.unwrap().is_empty());
        assert!(s.delete_session("big").await.unwrap());
        s.reload_session("small").await.unwrap();
        s.record_pair(pair("small", 0)).await.unwrap();
        assert_eq!(frames_of(&s.results("small", 0, 10).await.unwrap()), [0]);
        s.close().await.unwrap();
    }

    /// A session without a retention of its own keeps the server's
    /// default number of results, not all of them (the documented
    /// `--retention`; before, such sessions kept every result, and four
    /// streams filled a 9.5 GB disk in 19 minutes).
    #[tokio::test]
    async fn sessions_without_their_own_retention_keep_the_default() {
        let dir = tempfile::tempdir().unwrap();
        let path = db_path(&dir);
        let options = StorageOptions {
            default_retention: Some(4),
            ..StorageOptions::default()
        };
        let s = Storage::open(&path, options).unwrap();
        s.upsert_session(session("default", "2024-05-01T00:00:00Z", None))
            .await
            .unwrap();
        s.upsert_session(session("own", "2024-05-01T00:00:01Z", Some(6)))
            .await
            .unwrap();
        for frame in 0..12 {
            let a = s.record_pair(pair("default", frame));
            let b = s.record_pair(pair("own", frame));
            a.await.unwrap();
            b.await.unwrap();
        }
        assert_eq!(
            frames_of(&s.results("default", 0, 100).await.unwrap()),
            [8, 9, 10, 11]
        );
        assert_eq!(
            frames_of(&s.results("own", 0, 100).await.unwrap()),
            (6..12).collect::<Vec<_>>()
        );
        s.close().await.unwrap();
    }

    #[tokio::test]
    async fn group_commit_batches_in_order() {
        let dir = tempfile::tempdir().unwrap();
        let path = db_path(&dir);
        let s = open(&path);
        let base = session("g", "2024-05-01T00:00:00Z", None);
        s.upsert_session(base.clone()).await.unwrap();
        assert_eq!(s.batch_stats(), (0, 0));

        // Hold the write lock so that the queue fills up deterministically
        // while the writer waits in its busy handler.
        let blocker = raw(&path);
        blocker.execute_batch("BEGIN IMMEDIATE").unwrap();
        let mut futures: Vec<_> = (0..500).map(|f| s.record_pair(pair("g", f))).collect();
        // Three rewrites of one frame: the last queued must win.
        for body in ["\"a\"", "\"b\"", "\"c\""] {
            let mut p = pair("g", 499);
            p.result_json = body.into();
            futures.push(s.record_pair(p));
        }
        blocker.execute_batch("COMMIT").unwrap();
        drop(blocker);

        for r in futures_util::future::join_all(futures).await {
            r.unwrap();
        }
        let (batches, records) = s.batch_stats();
        assert_eq!(records, 503);
        assert!(batches < records, "{batches} batches for {records} records");
        // At most max_batch (256) commands per batch.
        assert!(batches >= 2, "{batches} batches");

        let results = s.results("g", 0, 1000).await.unwrap();
        assert_eq!(frames_of(&results), (0..500).collect::<Vec<_>>());
        for (frame, body) in &results[..499] {
            assert_eq!(body, &result_json("g", *frame));
        }
        assert_eq!(results[499].1, "\"c\"");
        assert_eq!(s.sessions().await.unwrap(), vec![after_pairs(base, 500)]);
        s.close().await.unwrap();
    }

    #[tokio::test]
    async fn small_max_batch_is_respected() {
        let dir = tempfile::tempdir().unwrap();
        let path = db_path(&dir);
        let s = Storage::open(
            &path,
            StorageOptions {
                max_batch: 10,
                ..StorageOptions::default()
            },
        )
        .unwrap();
        s.upsert_session(session("m", "2024-05-01T00:00:00Z", None))
            .await
            .unwrap();
        let blocker = raw(&path);
        blocker.execute_batch("BEGIN IMMEDIATE").unwrap();
        let futures: Vec<_> = (0..100).map(|f| s.record_pair(pair("m", f))).collect();
        blocker.execute_batch("COMMIT").unwrap();
        for r in futures_util::future::join_all(futures).await {
            r.unwrap();
        }
        let (batches, records) = s.batch_stats();
        assert_eq!(records, 100);
        assert!(batches >= 10, "{batches} batches of at most 10");
        s.close().await.unwrap();
    }

    fn write_future_schema(path: &str, journal_mode: &str) {
        let c = raw(path);
        let _: String = c
            .pragma_update_and_check(None, "journal_mode", journal_mode, |r| r.get(0))
            .unwrap();
        c.execute_batch(
            "CREATE TABLE future (x TEXT); INSERT INTO future VALUES ('from the future');
             PRAGMA user_version = 999;",
        )
        .unwrap();
    }

    /// A database written by a build of schema version 1 (before `keep` and
    /// calibration versions) opens, migrates, reads its sessions as not
    /// kept and its calibrations as version 1, which stays readable after
    /// a change.
    #[tokio::test]
    async fn version_1_databases_migrate() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("v1.db");
        let path = path.to_str().unwrap();
        let old = calibration_record("c_old", "2025-01-01T00:00:00Z", 0.5);
        {
            let c = Connection::open(path).unwrap();
            c.execute_batch(MIGRATIONS[0]).unwrap();
            c.execute(
                "INSERT INTO calibrations (id, name, body, created_at, updated_at) VALUES (?1, ?2, ?3, ?4, ?4)",
                params![old.id, old.name, calibration_json(&old).unwrap(), old.created_at],
            )
            .unwrap();
            c.execute_batch(
                "INSERT INTO sessions (id, name, calibration_id, params, retention, frames, state,
                                       tracker_state, created_at, updated_at)
                 VALUES ('s_old', 'old', NULL, '{}', NULL, 0, 'awaiting_first_pair', NULL,
                         '2025-01-01T00:00:00Z', '2025-01-01T00:00:00Z');
                 PRAGMA user_version = 1;",
            )
            .unwrap();
        }
        let storage = Storage::open(path, StorageOptions::default()).unwrap();
        let sessions = storage.sessions().await.unwrap();
        assert_eq!(sessions.len(), 1);
        assert_eq!(sessions[0].id, "s_old");
        assert!(!sessions[0].keep);
        let mut kept = sessions[0].clone();
        kept.keep = true;
        storage.upsert_session(kept).await.unwrap();
        assert!(storage.sessions().await.unwrap()[0].keep);
        assert_eq!(storage.calibrations().await.unwrap(), vec![old.clone()]);
        let changed = CalibrationRecord {
            calibration: calibration(0.25),
            updated_at: "2025-02-01T00:00:00Z".into(),
            version: 2,
            ..old.clone()
        };
        assert!(storage.update_calibration(changed.clone()).await.unwrap());
        assert_eq!(storage.calibrations().await.unwrap(), vec![changed.clone()]);
        assert_eq!(storage.calibration_version("c_old", 1).await.unwrap(), Some(old));
        assert_eq!(
            storage.calibration_version("c_old", 2).await.unwrap(),
            Some(changed)
        );
        assert_eq!(storage.calibration_version("c_old", 3).await.unwrap(), None);
        storage.close().await.unwrap();
    }

    fn dir_listing(dir: &Path) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }

    #[tokio::test]
    async fn schema_too_new_is_refused_and_the_file_left_alone() {
        for mode in ["DELETE", "WAL"] {
            let dir = tempfile::tempdir().unwrap();
            let path = dir.path().join("future.db");
            let path = path.to_str().unwrap();
            write_future_schema(path, mode);
            let before = std::fs::read(path).unwrap();
            let listing = dir_listing(dir.path());

            let err = Storage::open(path, StorageOptions::default()).unwrap_err();
            assert!(
                matches!(
                    err,
                    StorageError::SchemaTooNew {
                        found: 999,
                        supported: SCHEMA_VERSION
                    }
                ),
                "{mode}: {err:?}"
            );
            assert_eq!(err.code(), "schema_too_new");
            assert!(err.to_string().contains("999"), "{err}");
            assert!(std::fs::read(path).unwrap() == before, "{mode}: file changed");
            assert_eq!(dir_listing(dir.path()), listing, "{mode}");
        }
    }

    #[tokio::test]
    async fn schema_too_new_only_in_the_wal_is_refused_too() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("future.db");
        let path = path.to_str().unwrap();
        // A live newer process whose version bump is still in its WAL: the
        // file header says version 0.
        let newer = raw(path);
        newer.pragma_update(None, "wal_autocheckpoint", 0).unwrap();
        let mode: String = newer
            .pragma_update_and_check(None, "journal_mode", "WAL", |r| r.get(0))
            .unwrap();
        assert_eq!(mode, "wal");
        newer
            .execute_batch(
                "CREATE TABLE future (x TEXT); INSERT INTO future VALUES ('in the WAL');
                 PRAGMA user_version = 999;",
            )
            .unwrap();
        let before = std::fs::read(path).unwrap();
        assert!(probe_header(path).is_ok(), "the header should look old");

        let err = Storage::open(path, StorageOptions::default()).unwrap_err();
        assert!(
            matches!(err, StorageError::SchemaTooNew { found: 999, .. }),
            "{err:?}"
        );
        assert!(std::fs::read(path).unwrap() == before, "file changed");
        let rows: i64 = newer
            .query_row("SELECT count(*) FROM future", [], |r| r.get(0))
            .unwrap();
        assert_eq!(rows, 1);
    }

    #[tokio::test]
    async fn memory_database_supports_the_whole_api() {
        let s = open(":memory:");
        let a = calibration_record("cal-a", "2024-01-01T00:00:00Z", 0.5);
        s.insert_calibration(a.clone()).await.unwrap();
        let mut a2 = a.clone();
        a2.calibration = calibration(0.75);
        assert!(s.update_calibration(a2.clone()).await.unwrap());
        assert_eq!(s.calibrations().await.unwrap(), vec![a2]);

        let base = session("mem", "2024-05-01T00:00:00Z", Some(3));
        s.upsert_session(base.clone()).await.unwrap();
        let futures: Vec<_> = (0..8).map(|f| s.record_pair(pair("mem", f))).collect();
        for r in futures_util::future::join_all(futures).await {
            r.unwrap();
        }
        assert_eq!(s.sessions().await.unwrap(), vec![after_pairs(base, 8)]);
        assert_eq!(frames_of(&s.results("mem", 0, 10).await.unwrap()), [5, 6, 7]);
        assert_eq!(frames_of(&s.results("mem", 6, 1).await.unwrap()), [6]);
        s.ping().await.unwrap();
        assert_eq!(s.batch_stats().1, 8);

        assert!(s.delete_session("mem").await.unwrap());
        assert!(s.results("mem", 0, 10).await.unwrap().is_empty());
        assert!(s.sessions().await.unwrap().is_empty());
        assert!(s.delete_calibration("cal-a").await.unwrap());
        assert!(s.calibrations().await.unwrap().is_empty());
        s.close().await.unwrap();
        assert!(is_closed(s.ping().await));

        // A second in-memory storage is a different, fresh database.
        let other = open(":memory:");
        assert!(other.sessions().await.unwrap().is_empty());
        other.close().await.unwrap();
    }

    #[tokio::test]
    async fn delete_session_removes_results_and_drops_later_pairs() {
        let dir = tempfile::tempdir().unwrap();
        let path = db_path(&dir);
        let s = open(&path);
        let gone = session("gone", "2024-05-01T00:00:00Z", None);
        let kept = session("kept", "2024-05-01T00:00:01Z", None);
        s.upsert_session(gone).await.unwrap();
        s.upsert_session(kept.clone()).await.unwrap();
        for frame in 0..4 {
            s.record_pair(pair("gone", frame)).await.unwrap();
            s.record_pair(pair("kept", frame)).await.unwrap();
        }
        assert!(s.delete_session("gone").await.unwrap());
        assert!(!s.delete_session("gone").await.unwrap());
        assert!(s.results("gone", 0, 100).await.unwrap().is_empty());

        // A pair finishing after the delete is accepted and dropped.
        s.record_pair(pair("gone", 4)).await.unwrap();
        s.record_pair(pair("never-existed", 0)).await.unwrap();
        assert!(s.results("gone", 0, 100).await.unwrap().is_empty());
        assert!(s.results("never-existed", 0, 100).await.unwrap().is_empty());
        assert_eq!(s.sessions().await.unwrap(), vec![after_pairs(kept, 4)]);
        assert_eq!(s.results("kept", 0, 100).await.unwrap().len(), 4);
        s.close().await.unwrap();

        let c = raw(&path);
        let count = |sql: &str| -> i64 { c.query_row(sql, [], |r| r.get(0)).unwrap() };
        assert_eq!(
            count("SELECT count(*) FROM results WHERE session_id <> 'kept'"),
            0
        );
        assert_eq!(count("SELECT count(*) FROM sessions"), 1);
    }

    #[tokio::test]
    async fn upsert_session_updates_fields_but_keeps_results_and_created_at() {
        let dir = tempfile::tempdir().unwrap();
        let path = db_path(&dir);
        let s = open(&path);
        let base = session("u", "2024-05-01T00:00:00Z", None);
        s.upsert_session(base.clone()).await.unwrap();
        for frame in 0..3 {
            s.record_pair(pair("u", frame)).await.unwrap();
        }
        let mut changed = after_pairs(base.clone(), 3);
        changed.name = None;
        changed.calibration_id = None;
        changed.objects[0].params.min_contrast_ratio = 0.5;
        changed.retention = Some(2);
        changed.created_at = "2099-01-01T00:00:00Z".into();
        changed.updated_at = "2024-06-01T00:00:00Z".into();
        s.upsert_session(changed.clone()).await.unwrap();
        assert_eq!(
            s.sessions().await.unwrap(),
            vec![SessionRecord {
                created_at: base.created_at,
                ..changed
            }]
        );
        // Not INSERT OR REPLACE: the results did not cascade away.
        assert_eq!(frames_of(&s.results("u", 0, 10).await.unwrap()), [0, 1, 2]);
        // The new retention applies from the next pair on.
        s.record_pair(pair("u", 3)).await.unwrap();
        assert_eq!(frames_of(&s.results("u", 0, 10).await.unwrap()), [2, 3]);
        s.close().await.unwrap();
    }

    #[tokio::test]
    async fn corrupt_json_columns_are_reported_not_panicked() {
        let dir = tempfile::tempdir().unwrap();
        let path = db_path(&dir);
        let s = open(&path);
        s.insert_calibration(calibration_record("cal-ok", "2024-01-01T00:00:00Z", 0.5))
            .await
            .unwrap();
        s.insert_calibration(calibration_record("cal-bad", "2024-01-02T00:00:00Z", 0.5))
            .await
            .unwrap();
        s.upsert_session(session("fine", "2024-05-01T00:00:00Z", None))
            .await
            .unwrap();
        s.upsert_session(session("broken", "2024-05-02T00:00:00Z", None))
            .await
            .unwrap();
        s.record_pair(pair("broken", 0)).await.unwrap();
        s.close().await.unwrap();

        let c = raw(&path);
        c.execute(
            "UPDATE sessions SET tracker_state = '{\"template\": [garbage' WHERE id = 'broken'",
            [],
        )
        .unwrap();
        // Valid JSON but not a valid calibration (it is re-validated).
        c.execute(
            "UPDATE calibrations SET body = '{\"model\":\"geometric\",\"pixel_size_um\":-1,\"vergence_deg\":6}'
             WHERE id = 'cal-bad'",
            [],
        )
        .unwrap();
        drop(c);

        let s = open(&path);
        let err = s.sessions().await.unwrap_err();
        let StorageError::Corrupt(msg) = &err else {
            panic!("expected Corrupt, got {err:?}");
        };
        assert!(msg.contains("broken") && msg.contains("tracker_state"), "{msg}");
        assert_eq!(err.code(), "storage_corrupt");
        let err = s.calibrations().await.unwrap_err();
        assert!(
            matches!(&err, StorageError::Corrupt(m) if m.contains("cal-bad")),
            "{err:?}"
        );
        // The storage still works after reporting it.
        s.ping().await.unwrap();
        assert_eq!(s.results("broken", 0, 10).await.unwrap().len(), 1);
        s.close().await.unwrap();

        let c = raw(&path);
        c.execute("UPDATE sessions SET params = 'nope' WHERE id = 'fine'", [])
            .unwrap();
        c.execute("UPDATE sessions SET tracker_state = NULL WHERE id = 'broken'", [])
            .unwrap();
        drop(c);
        let s = open(&path);
        let err = s.sessions().await.unwrap_err();
        assert!(
            matches!(&err, StorageError::Corrupt(m) if m.contains("fine") && m.contains("params")),
            "{err:?}"
        );
        s.close().await.unwrap();
    }

    #[tokio::test]
    async fn non_finite_values_are_refused_before_storing() {
        let s = open(":memory:");
        let mut bad = session("nan", "2024-05-01T00:00:00Z", None);
        bad.objects[0].tracker_state = Some(tracker_state(1));
        bad.objects[0].tracker_state.as_mut().unwrap().left.x = f64::NAN;
        let err = s.upsert_session(bad).await.unwrap_err();
        assert_eq!(err.code(), "unstorable_record", "{err}");
        assert!(s.sessions().await.unwrap().is_empty());

        let base = session("ok", "2024-05-01T00:00:00Z", None);
        s.upsert_session(base.clone()).await.unwrap();
        let mut p = pair("ok", 0);
        p.objects[0]
            .tracker_state
            .as_mut()
            .unwrap()
            .right_sector_contrasts[0] = f64::INFINITY;
        let err = s.record_pair(p).await.unwrap_err();
        assert!(
            matches!(err, StorageError::Unstorable(ref m) if m.contains("ok")),
            "{err}"
        );
        let mut p = pair("ok", 0);
        p.frame = u64::MAX;
        assert_eq!(s.record_pair(p).await.unwrap_err().code(), "unstorable_record");
        assert_eq!(s.sessions().await.unwrap(), vec![base]);
        assert!(s.results("ok", 0, 10).await.unwrap().is_empty());
        s.close().await.unwrap();
    }

    #[tokio::test]
    async fn acknowledged_pairs_survive_without_close() {
        let dir = tempfile::tempdir().unwrap();
        let path = db_path(&dir);
        let s = open(&path);
        let base = session("k", "2024-05-01T00:00:00Z", None);
        s.upsert_session(base.clone()).await.unwrap();
        for frame in 0..5 {
            s.record_pair(pair("k", frame)).await.unwrap();
        }
        // Like a kill: no close, no checkpoint, the connections are never closed.
        std::mem::forget(s);
        assert!(dir.path().join("nested/data/semdepth.db-wal").exists());

        let s = open(&path);
        assert_eq!(s.sessions().await.unwrap(), vec![after_pairs(base, 5)]);
        assert_eq!(s.results("k", 0, 10).await.unwrap().len(), 5);
        s.close().await.unwrap();
    }

    #[tokio::test]
    async fn calls_after_close_return_closed() {
        let dir = tempfile::tempdir().unwrap();
        let path = db_path(&dir);
        let s = open(&path);
        let clone = s.clone();
        s.upsert_session(session("c", "2024-05-01T00:00:00Z", None))
            .await
            .unwrap();
        // Queued before close: committed by it.
        let pending = s.record_pair(pair("c", 0));
        s.close().await.unwrap();
        pending.await.unwrap();
        // The WAL was checkpointed and truncated (or removed with the last connection).
        let wal = dir.path().join("nested/data/semdepth.db-wal");
        assert!(!wal.exists() || std::fs::metadata(&wal).unwrap().len() == 0);

        assert!(is_closed(clone.close().await));
        assert!(is_closed(clone.ping().await));
        assert!(is_closed(clone.sessions().await));
        assert!(is_closed(clone.calibrations().await));
        assert!(is_closed(clone.results("c", 0, 10).await));
        assert!(is_closed(clone.record_pair(pair("c", 1)).await));
        assert!(is_closed(clone.delete_session("c").await));
        assert!(is_closed(
            clone.insert_calibration(calibration_record("x", "t", 1.0)).await
        ));
        assert_eq!(clone.batch_stats(), (1, 1));

        let s = open(&path);
        assert_eq!(s.results("c", 0, 10).await.unwrap().len(), 1);
        s.close().await.unwrap();
    }

    #[tokio::test]
    async fn a_crashed_writer_gives_closed_not_a_panic() {
        let dir = tempfile::tempdir().unwrap();
        let path = db_path(&dir);
        let s = open(&path);
        s.upsert_session(session("p", "2024-05-01T00:00:00Z", None))
            .await
            .unwrap();
        s.record_pair(pair("p", 0)).await.unwrap();
        let pending = s.record_pair(pair("p", 1));
        s.crash_writer_for_test();
        let after = s.record_pair(pair("p", 2));
        // Pair 1 commits if the writer took it before the crash request, else
        // its batch died with the writer: either way the caller is told.
        let pending = pending.await;
        assert!(
            matches!(pending, Ok(()) | Err(StorageError::Closed)),
            "{pending:?}"
        );
        assert!(is_closed(after.await));
        assert!(is_closed(s.record_pair(pair("p", 3)).await));
        assert!(is_closed(s.delete_session("p").await));
        assert!(is_closed(s.ping().await));
        assert!(is_closed(s.close().await));
        drop(s);

        let s = open(&path);
        let expected: &[u64] = if pending.is_ok() { &[0, 1] } else { &[0] };
        assert_eq!(frames_of(&s.results("p", 0, 10).await.unwrap()), expected);
        s.close().await.unwrap();
    }

    #[test]
    fn handles_and_futures_are_send() {
        fn send_sync<T: Send + Sync + Clone + 'static>() {}
        fn send<T: Send>(_: &T) {}
        send_sync::<Storage>();
        let s = open(":memory:");
        let c = calibration_record("a", "t", 1.0);
        send(&s.insert_calibration(c.clone()));
        send(&s.update_calibration(c));
        send(&s.delete_calibration("a"));
        send(&s.calibrations());
        send(&s.upsert_session(session("s", "t", None)));
        send(&s.delete_session("s"));
        send(&s.sessions());
        send(&s.record_pair(pair("s", 0)));
        send(&s.results("s", 0, 1));
        send(&s.ping());
        send(&s.close());
    }

    #[test]
    fn error_codes_are_distinct() {
        let errors = [
            StorageError::Sqlite(rusqlite::Error::InvalidQuery),
            StorageError::SchemaTooNew {
                found: 2,
                supported: 1,
            },
            StorageError::Corrupt(String::new()),
            StorageError::Unstorable(String::new()),
            StorageError::Closed,
            StorageError::Io(std::io::Error::other("x")),
        ];
        let mut codes: Vec<_> = errors.iter().map(StorageError::code).collect();
        assert_eq!(codes[0], "storage_error");
        codes.sort();
        codes.dedup();
        assert_eq!(codes.len(), errors.len());
    }
}

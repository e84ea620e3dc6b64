//! The storage's threads: the one writer (group commit of pair records,
//! the free-disk guard) and the reader, and the queries they run.

use crate::service::api::SessionState;
use rusqlite::{params, Connection, OptionalExtension, TransactionBehavior};
use std::collections::HashSet;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{mpsc, Arc};
use tokio::sync::oneshot;

use super::columns::{calibration_of, from_i64, states_checked, to_i64};
use super::{CalibrationRecord, PairRecord, SessionRecord, StorageError};

/// The free space kept on the database's file system.
#[derive(Clone, Debug)]
pub(super) struct DiskGuard {
    /// The database's directory.
    pub(super) dir: std::path::PathBuf,
    /// Bytes kept free.
    pub(super) min_free: u64,
}

impl DiskGuard {
    /// Ok while more than `min_free` bytes are free for unprivileged writes.
    pub(super) fn check(&self) -> Result<(), StorageError> {
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

/// A write that needs room for two pages, into the table kept for it: how
/// `/readyz` and the pair writer tell whether a full database has room again.
pub(super) const ROOM_PROBE: &str = "INSERT INTO write_probe (body) VALUES (zeroblob(8192))";

pub(super) struct Inner {
    pub(super) path: String,
    pub(super) writer: mpsc::Sender<WriterMsg>,
    /// None for in-memory databases: the writer serves reads.
    pub(super) reader: Option<mpsc::Sender<ReaderMsg>>,
    pub(super) closed: AtomicBool,
    pub(super) writer_alive: Arc<AtomicBool>,
    pub(super) stats: Arc<Stats>,
    /// The free space kept on the database's file system (None: memory).
    pub(super) disk_guard: Option<DiskGuard>,
}

#[derive(Default)]
pub(super) struct Stats {
    pub(super) batches: AtomicU64,
    pub(super) records: AtomicU64,
    /// The last pair write's error, until a write succeeds.
    pub(super) write_failure: std::sync::Mutex<Option<String>>,
    /// Size of the database file after the last committed batch, bytes.
    pub(super) db_bytes: AtomicU64,
}

/// Clears the flag when the writer thread ends, also by panic.
pub(super) struct AliveGuard(pub(super) Arc<AtomicBool>);

impl Drop for AliveGuard {
    fn drop(&mut self) {
        self.0.store(false, Ordering::Release);
    }
}

pub(super) type Reply<T> = oneshot::Sender<Result<T, StorageError>>;

pub(super) type ReadJob = Box<dyn FnOnce(&Connection) + Send>;

pub(super) type WriteJob = Box<dyn FnOnce(&mut WriterConn) + Send>;

pub(super) enum WriterMsg {
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

pub(super) enum ReaderMsg {
    Job(ReadJob),
    Stop(oneshot::Sender<()>),
}

/// A [`PairRecord`] converted for SQLite on the caller's thread.
pub(super) struct PreparedPair {
    pub(super) session_id: String,
    pub(super) frame: i64,
    pub(super) result_json: String,
    pub(super) frames: i64,
    pub(super) state: &'static str,
    pub(super) tracker_json: Option<String>,
    pub(super) updated_at: String,
}

pub(super) fn prepare_pair(rec: PairRecord) -> Result<PreparedPair, StorageError> {
    let id = &rec.session_id;
    Ok(PreparedPair {
        frame: to_i64(rec.frame, "pair of session", id, "frame")?,
        frames: to_i64(rec.frames, "pair of session", id, "frames")?,
        tracker_json: Some(states_checked(&rec.objects, "pair of session", id)?),
        session_id: rec.session_id,
        result_json: rec.result_json,
        state: rec.state.name(),
        updated_at: rec.updated_at,
    })
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Synchronous {
    Normal,
    Full,
}

/// The write connection and its current `synchronous` level.
pub(super) struct WriterConn {
    pub(super) conn: Connection,
    pub(super) synchronous: Option<Synchronous>,
    /// [`StorageOptions::default_retention`].
    pub(super) default_retention: Option<i64>,
    /// Checked before every batch of results.
    pub(super) disk_guard: Option<DiskGuard>,
    /// Sessions with a pair that failed to store: their later pairs are
    /// refused until [`Storage::reload_session`].
    pub(super) behind: HashSet<String>,
}

impl WriterConn {
    pub(super) fn set_synchronous(&mut self, level: Synchronous) -> rusqlite::Result<()> {
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

    pub(super) fn durable<T>(
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
    pub(super) fn has_room(&mut self) -> bool {
        let Ok(tx) = self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)
        else {
            return false;
        };
        let fits = tx.execute(ROOM_PROBE, []).is_ok();
        fits && tx.rollback().is_ok()
    }

    pub(super) fn commit_pairs<'a>(
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
    pub(super) fn flush_pairs(&mut self, pending: &mut Vec<(PreparedPair, Reply<()>)>, stats: &Stats) {
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
    pub(super) fn measure_size(&self, stats: &Stats) {
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

    pub(super) fn shutdown(self) -> Result<(), StorageError> {
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
    pub(super) fn failure(&self) -> Option<String> {
        self.write_failure.lock().ok().and_then(|f| f.clone())
    }

    pub(super) fn write_succeeded(&self) {
        if let Ok(mut f) = self.write_failure.lock() {
            *f = None;
        }
    }

    pub(super) fn write_failed(&self, e: &StorageError) {
        if let Ok(mut f) = self.write_failure.lock() {
            *f = Some(e.to_string());
        }
    }

    pub(super) fn add_batch(&self, records: usize) {
        self.batches.fetch_add(1, Ordering::Relaxed);
        self.records.fetch_add(records as u64, Ordering::Relaxed);
    }
}

pub(super) fn writer_main(
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

pub(super) fn reader_main(conn: Connection, rx: mpsc::Receiver<ReaderMsg>) {
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
pub(super) fn apply_pair(
    c: &Connection,
    p: &PreparedPair,
    default_retention: Option<i64>,
) -> Result<(), StorageError> {
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
pub(super) fn keep_calibration_version(
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

pub(super) fn load_calibrations(c: &Connection) -> Result<Vec<CalibrationRecord>, StorageError> {
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
pub(super) fn load_sessions(c: &Connection, only: Option<&str>) -> Result<Vec<SessionRecord>, StorageError> {
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
        let state = SessionState::from_name(&state).ok_or_else(|| {
            StorageError::Corrupt(format!(
                "session {id:?}: column state: {state:?} (expected awaiting_first_pair, tracking or lost)"
            ))
        })?;
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

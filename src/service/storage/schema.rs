//! The schema and its migrations, checked against the file before anything
//! changes.

use rusqlite::{Connection, TransactionBehavior};

use super::{StorageError, SCHEMA_VERSION};

/// Ordered migrations: `MIGRATIONS[i]` takes `user_version` i to i + 1.
pub(super) const MIGRATIONS: &[&str] = &[
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

/// Checks the `user_version` in the file's header (big-endian i32 at offset
/// 60) without opening it in SQLite, which would leave `-wal`/`-shm` files next
/// to a WAL database we must refuse. A file too short or without the SQLite
/// magic is left for SQLite to judge.
pub(super) fn probe_header(path: &str) -> Result<(), StorageError> {
    use std::io::Read;
    let mut header = Vec::with_capacity(100);
    std::fs::File::open(path)?.take(100).read_to_end(&mut header)?;
    if header.len() < 100 || !header.starts_with(b"SQLite format 3\0") {
        return Ok(());
    }
    let found = i32::from_be_bytes([header[60], header[61], header[62], header[63]]);
    check_version(i64::from(found))
}

pub(super) fn user_version(c: &Connection) -> rusqlite::Result<i64> {
    c.pragma_query_value(None, "user_version", |r| r.get(0))
}

pub(super) fn check_version(found: i64) -> Result<(), StorageError> {
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
pub(super) fn migrate(conn: &mut Connection) -> Result<(), StorageError> {
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

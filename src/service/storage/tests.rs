use super::*;
use crate::service::api::SessionState;
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
pub(super) fn tracker_state(i: u64) -> TrackerState {
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
        grey_quantiles: (i % 4 != 3).then_some([
            [60.5 + f, 62.0, 63.5, 65.0, 66.25, 67.0, 69.5, 72.0, 90.0 + f],
            [61.0; 9],
        ]),
        template_cuts: vec![HalfPlane::new([1.0, 0.0], -3.5 - f)],
        outline: vec![[-4.0, -3.0], [4.0, -3.0], [0.0, 5.0 + 0.125 * f]],
        prefilter_sigma_px: 0.5 * f,
        refused_inits: (i % 2) as u32,
        uncertain_run: (i % 2 == 1).then_some(0.5 * f),
        first_disparity_std_px: 0.25 * f,
        edge_support: (!i.is_multiple_of(3)).then_some(0.125 * f),
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
        state: SessionState::AwaitingFirstPair,
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
        state: if frame % 7 == 6 {
            SessionState::Lost
        } else {
            SessionState::Tracking
        },
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

    // A state that is none of the three.
    let c = raw(&path);
    c.execute("DELETE FROM sessions WHERE id = 'fine'", []).unwrap();
    c.execute("UPDATE sessions SET state = 'dancing' WHERE id = 'broken'", [])
        .unwrap();
    drop(c);
    let s = open(&path);
    let err = s.sessions().await.unwrap_err();
    assert!(
        matches!(&err, StorageError::Corrupt(m) if m.contains("broken") && m.contains("dancing")),
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

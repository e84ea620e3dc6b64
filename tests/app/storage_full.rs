//! Issue #21, items 3, 4 and 8: with the database at its size limit (the
//! same SQLite error as a full disk), uploads get a 503, the session's frame
//! counter stays with what is stored, `/readyz` says why it is not ready,
//! and when room is freed everything goes on with contiguous frame numbers,
//! also after a restart.

use crate::discs;
use crate::server;

use crate::server::{frames_form, get_json, get_text, new_session, test_config, TestServer};
use serde_json::Value;

/// The stored frame numbers of a session, in order.
async fn stored_frames(base: &str, sid: &str) -> Vec<u64> {
    let page = get_json(&format!(
        "{base}/v1/sessions/{sid}/results?limit=10000&contours=false"
    ))
    .await;
    page["results"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["frame"].as_u64().unwrap())
        .collect()
}

async fn session_frames(base: &str, sid: &str) -> u64 {
    get_json(&format!("{base}/v1/sessions/{sid}")).await["frames"]
        .as_u64()
        .unwrap()
}

async fn upload(http: &reqwest::Client, base: &str, sid: &str, step: usize) -> (u16, Value) {
    let (left, right) = discs::scene_pair([0.25 * (step % 8) as f64, 0.0]);
    let r = http
        .post(format!("{base}/v1/sessions/{sid}/frames"))
        .multipart(frames_form(&left, &right))
        .send()
        .await
        .unwrap();
    (r.status().as_u16(), r.json().await.unwrap())
}

async fn readyz(http: &reqwest::Client, base: &str) -> (u16, Value) {
    let r = http.get(format!("{base}/readyz")).send().await.unwrap();
    (r.status().as_u16(), r.json().await.unwrap())
}

/// Item 8: with less free disk than `--min-free-disk-mib` keeps (here more
/// than any disk has), results are refused with a 503 naming the free space
/// and the limit before the disk fills; the session stays at its stored
/// frames, and `/readyz` says why it is not ready.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn results_are_refused_before_the_disk_fills() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = test_config(&dir.path().join("db.sqlite3"));
    config.min_free_disk_bytes = u64::MAX / 2;
    let server = TestServer::start_unready(config).await;
    let http = reqwest::Client::new();
    let base = server.base.clone();
    let sid = new_session(&base).await;
    let (status, body) = upload(&http, &base, &sid, 0).await;
    assert_eq!(status, 503, "{body}");
    assert_eq!(body["error"]["code"], "disk_nearly_full", "{body}");
    let message = body["error"]["message"].as_str().unwrap();
    assert!(
        message.contains("MiB free") && message.contains("--min-free-disk-mib"),
        "{message}"
    );
    assert_eq!(session_frames(&base, &sid).await, 0);
    assert!(stored_frames(&base, &sid).await.is_empty());
    let (status, ready) = readyz(&http, &base).await;
    assert_eq!(status, 503, "{ready}");
    assert!(ready.to_string().contains("--min-free-disk-mib"), "{ready}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_database_never_lets_a_session_run_ahead_of_storage() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("db.sqlite3");
    let mut config = test_config(&db);
    // About 130 results of this small scene (the empty schema takes ~100 KB).
    config.max_db_bytes = Some(640 * 1024);
    let server = TestServer::start(config.clone()).await;
    let http = reqwest::Client::new();
    let base = server.base.clone();

    // A session whose results will be deleted to make room.
    let ballast = new_session(&base).await;
    for step in 0..12 {
        let (status, body) = upload(&http, &base, &ballast, step).await;
        assert_eq!(status, 200, "{body}");
    }

    // Fill the database: the first refused upload is a 503 naming the cause.
    let sid = new_session(&base).await;
    let mut stored = 0u64;
    let refusal = loop {
        let (status, body) = upload(&http, &base, &sid, stored as usize).await;
        if status != 200 {
            break (status, body);
        }
        assert_eq!(body["frame"].as_u64(), Some(stored), "{body}");
        stored += 1;
        assert!(stored < 500, "the size limit never took effect");
    };
    eprintln!("{stored} pairs stored before the limit: {}", refusal.1);
    assert_eq!(refusal.0, 503, "{}", refusal.1);
    let message = refusal.1["error"]["message"].as_str().unwrap().to_string();
    assert!(message.contains("full"), "{message}");

    // More uploads are refused too, and the session does not move on.
    for step in 0..3 {
        let (status, body) = upload(&http, &base, &sid, step).await;
        assert_eq!(status, 503, "{body}");
    }
    assert_eq!(session_frames(&base, &sid).await, stored);
    assert_eq!(stored_frames(&base, &sid).await, (0..stored).collect::<Vec<_>>());
    // The size is reported, and stays within the limit.
    let metrics = get_text(&format!("{base}/metrics")).await;
    let bytes: u64 = metrics
        .lines()
        .find_map(|l| l.strip_prefix("semdepth_storage_bytes "))
        .expect("semdepth_storage_bytes in /metrics")
        .parse()
        .unwrap();
    assert!((500 * 1024..=640 * 1024).contains(&bytes), "{bytes} bytes");
    let (status, body) = readyz(&http, &base).await;
    assert_eq!(status, 503, "{body}");
    assert!(body["reason"].as_str().unwrap().contains("full"), "{body}");

    // Room again: readiness recovers and the session goes on from its last
    // stored frame.
    let r = http
        .delete(format!("{base}/v1/sessions/{ballast}"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 204);
    let (status, body) = readyz(&http, &base).await;
    assert_eq!((status, body["status"].as_str()), (200, Some("ok")), "{body}");
    for _ in 0..3 {
        let (status, body) = upload(&http, &base, &sid, stored as usize).await;
        assert_eq!(status, 200, "{body}");
        assert_eq!(body["frame"].as_u64(), Some(stored), "{body}");
        stored += 1;
    }
    assert_eq!(stored_frames(&base, &sid).await, (0..stored).collect::<Vec<_>>());

    // A restart finds memory and disk in agreement.
    server.stop().await.unwrap();
    let server = TestServer::start(config).await;
    let base = server.base.clone();
    assert_eq!(session_frames(&base, &sid).await, stored);
    let (status, body) = upload(&http, &base, &sid, stored as usize).await;
    assert_eq!((status, body["frame"].as_u64()), (200, Some(stored)), "{body}");
    server.stop().await.unwrap();
}

/// Issue #18 (the session layer): a change to a session that storage
/// refuses leaves the session as stored, in memory too. With the database
/// full, objects are added until one addition does not fit: it is a 503,
/// the session keeps the objects stored before it, a PATCH refused the
/// same way changes nothing, and a restart finds the same session.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_change_storage_refuses_leaves_the_session_as_stored() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("db.sqlite3");
    let mut config = test_config(&db);
    config.max_db_bytes = Some(400 * 1024);
    let server = TestServer::start(config.clone()).await;
    let http = reqwest::Client::new();
    let base = server.base.clone();
    let sid = new_session(&base).await;
    // Fill the database with results.
    let filler = new_session(&base).await;
    let mut step = 0;
    while upload(&http, &base, &filler, step).await.0 == 200 {
        step += 1;
        assert!(step < 500, "the size limit never took effect");
    }
    // Each object stores its parameters with the session's row: the row
    // soon needs a page the database cannot have.
    let objects = |view: &Value| -> Vec<String> {
        view["objects"]
            .as_array()
            .unwrap()
            .iter()
            .map(|o| o["name"].as_str().unwrap().to_string())
            .collect()
    };
    let (mut refused, mut added) = (None, vec!["object".to_string()]);
    for k in 0..15 {
        let r = http
            .post(format!("{base}/v1/sessions/{sid}/objects"))
            .json(&serde_json::json!({"name": format!("part{k}"), "roi": [10, 10, 40, 40]}))
            .send()
            .await
            .unwrap();
        let (status, body) = server::json_of(r).await;
        if status != 201 {
            assert_eq!(status, 503, "{body}");
            refused = Some(format!("part{k}"));
            break;
        }
        added.push(format!("part{k}"));
    }
    let refused = refused.expect("an object that does not fit the full database");
    let view = get_json(&format!("{base}/v1/sessions/{sid}")).await;
    let kept = objects(&view);
    assert!(!kept.contains(&refused), "{kept:?} holds the refused {refused}");
    assert_eq!(kept, added);
    // A PATCH that grows the row is refused the same way and changes nothing.
    let long_name = "n".repeat(200);
    let r = http
        .patch(format!("{base}/v1/sessions/{sid}"))
        .json(&serde_json::json!({"name": long_name, "tracker": {"occlusion": {"sectors": 32}}}))
        .send()
        .await
        .unwrap();
    let (status, body) = server::json_of(r).await;
    let after = get_json(&format!("{base}/v1/sessions/{sid}")).await;
    eprintln!("adding {refused}: 503; a PATCH: {status}");
    if status == 503 {
        assert_eq!(after["name"], view["name"], "{after}");
        assert_eq!(after["tracker"], view["tracker"], "{after}");
    } else {
        assert_eq!(status, 200, "{body}");
        assert_eq!(after["name"].as_str(), Some(long_name.as_str()));
    }
    // Memory and disk agree across a restart.
    server.stop().await.unwrap();
    let server = TestServer::start(config).await;
    let restarted = get_json(&format!("{}/v1/sessions/{sid}", server.base)).await;
    assert_eq!(objects(&restarted), kept);
    assert_eq!(restarted["name"], after["name"]);
    assert_eq!(restarted["tracker"], after["tracker"]);
    server.stop().await.unwrap();
}

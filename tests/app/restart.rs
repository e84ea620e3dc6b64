//! Durability across restarts (issue #4): stream half a sequence, stop the
//! server (gracefully in-process, and by SIGKILL of a child process), start
//! it again on the same database and continue. Calibrations and earlier
//! results are all there, the session keeps tracking with its earlier
//! contour (the next pair is "tracked", not re-initialised, and its
//! disparity matches the ground truth), and nothing acknowledged before the
//! kill is lost.

use crate::discs;

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use crate::server::{
    frames_form, get_json, next_reply, offset_free_rms, post_json, sdp1_raw, synth_pairs, test_config,
    upload, TestServer,
};
use futures_util::{SinkExt, StreamExt};
use semdepth_core::synth::{Preset, Shape, SynthPair};
use serde_json::{json, Value};
use tokio_tungstenite::tungstenite::Message;

/// Disparity RMS limit over the whole sequence, before and after the
/// restart (px, offset removed): the same budget as the other service tests.
const MAX_DISPARITY_RMS_PX: f64 = 0.15;

/// Checks the stored results against the truth: frames 0..n, in order,
/// with accurate disparities.
fn check_results(results: &[Value], pairs: &[SynthPair]) {
    assert_eq!(results.len(), pairs.len());
    let mut errors = Vec::new();
    for (i, (r, pair)) in results.iter().zip(pairs).enumerate() {
        assert_eq!(r["frame"], i as u64);
        let expected = if i == 0 { "initialised" } else { "tracked" };
        assert_eq!(r["status"], expected, "frame {i}: {r}");
        errors.push(r["disparity_px"][0].as_f64().unwrap() - pair.truth.disparity_px[0]);
    }
    let rms = offset_free_rms(&errors);
    eprintln!("disparity RMS across the restart: {rms:.4} px");
    assert!(rms <= MAX_DISPARITY_RMS_PX, "disparity RMS {rms} px");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn graceful_restart_continues_the_stream_where_it_stopped() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("db.sqlite3");
    let pairs = synth_pairs(Preset::Noisy, Shape::Blob, 31, 12);
    let (first, second) = pairs.split_at(6);

    let server = TestServer::start(test_config(&db)).await;
    let cal = post_json(
        &format!("{}/v1/calibrations", server.base),
        json!({"name": "kept", "model": "geometric", "pixel_size_um": 0.25, "vergence_deg": 8.0}),
    )
    .await;
    let session = post_json(
        &format!("{}/v1/sessions", server.base),
        json!({"name": "survivor", "calibration_id": cal["id"], "tracker": {"max_disparity_px": 48.0}}),
    )
    .await;
    let sid = session["id"].as_str().unwrap().to_string();
    let (mut ws, _) = tokio_tungstenite::connect_async(server.stream_url(&sid, "all"))
        .await
        .unwrap();
    for (i, pair) in first.iter().enumerate() {
        ws.send(Message::Binary(sdp1_raw(i as u64, pair).into()))
            .await
            .unwrap();
        let r = next_reply(&mut ws).await;
        assert_eq!(r["seq"], i as u64);
    }
    // Stop with the socket still open: it gets a close frame (1001).
    let stopping = tokio::spawn(server.stop());
    let close = loop {
        match tokio::time::timeout(Duration::from_secs(30), ws.next())
            .await
            .unwrap()
        {
            Some(Ok(Message::Close(frame))) => break frame,
            Some(Ok(_)) => continue,
            other => panic!("expected a close frame, got {other:?}"),
        }
    };
    assert_eq!(close.map(|f| u16::from(f.code)), Some(1001));
    stopping.await.unwrap().unwrap();

    // Same database, new server.
    let server = TestServer::start(test_config(&db)).await;
    let cals = get_json(&format!("{}/v1/calibrations", server.base)).await;
    assert_eq!(
        cals["calibrations"][0], cal,
        "calibration changed across the restart"
    );
    let s = get_json(&format!("{}/v1/sessions/{sid}", server.base)).await;
    assert_eq!(
        (s["state"].as_str(), s["frames"].as_u64()),
        (Some("tracking"), Some(6)),
        "{s}"
    );
    assert_eq!(s["tracker"]["max_disparity_px"], 48.0);
    assert_eq!(s["name"], "survivor");

    let (mut ws, _) = tokio_tungstenite::connect_async(server.stream_url(&sid, "all"))
        .await
        .unwrap();
    for (i, pair) in second.iter().enumerate() {
        ws.send(Message::Binary(sdp1_raw(100 + i as u64, pair).into()))
            .await
            .unwrap();
        let r = next_reply(&mut ws).await;
        assert_eq!(
            (r["seq"].as_u64(), r["frame"].as_u64()),
            (Some(100 + i as u64), Some(6 + i as u64))
        );
        assert!(r["z_um"].is_number(), "{r}");
    }
    ws.close(None).await.unwrap();
    let page = get_json(&format!("{}/v1/sessions/{sid}/results", server.base)).await;
    check_results(page["results"].as_array().unwrap(), &pairs);
    server.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hints_from_a_reinit_survive_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("db.sqlite3");
    let http = reqwest::Client::new();
    let upload_scene = |base: String, sid: String, motion: [f64; 2]| {
        let (left, right) = discs::scene_pair(motion);
        let request = http
            .post(format!("{base}/v1/sessions/{sid}/frames"))
            .multipart(frames_form(&left, &right));
        async move {
            let r = request.send().await.unwrap();
            assert_eq!(r.status(), 200);
            r.json::<Value>().await.unwrap()
        }
    };
    let on = |r: &Value, disc: [f64; 3], motion: [f64; 2]| {
        discs::distance(&r["left"]["centroid"], disc[0] + motion[0], disc[1] + motion[1])
    };

    let server = TestServer::start(test_config(&db)).await;
    let session = post_json(
        &format!("{}/v1/sessions", server.base),
        json!({"init": {"roi": discs::ROI_B, "polarity": "brighter"}}),
    )
    .await;
    let sid = session["id"].as_str().unwrap().to_string();
    let first = upload_scene(server.base.clone(), sid.clone(), [0.0, 0.0]).await;
    assert_eq!(first["status"], "initialised", "{first}");
    assert!(on(&first, discs::DISC_B, [0.0, 0.0]) < 1.0, "{first}");
    let reinit = post_json(
        &format!("{}/v1/sessions/{sid}/reinit", server.base),
        json!({"init": {"roi": discs::ROI_A, "point": [90.0, 130.0]}}),
    )
    .await;
    server.stop().await.unwrap();

    // Same database, new server: the new hints and the reset are there.
    let server = TestServer::start(test_config(&db)).await;
    let s = get_json(&format!("{}/v1/sessions/{sid}", server.base)).await;
    assert_eq!(s, reinit, "the session changed across the restart");
    assert_eq!(
        (
            s["state"].as_str(),
            s["frames"].as_u64(),
            s["init"]["polarity"].as_str()
        ),
        (Some("awaiting_first_pair"), Some(1), Some("any")),
        "{s}"
    );
    assert_eq!(
        (s["init"]["roi"].clone(), s["init"]["point"].clone()),
        (json!(discs::ROI_A), json!([90.0, 130.0]))
    );
    let next = upload_scene(server.base.clone(), sid.clone(), [1.5, -1.0]).await;
    assert_eq!(
        (next["frame"].as_u64(), next["status"].as_str()),
        (Some(1), Some("initialised")),
        "{next}"
    );
    assert!(on(&next, discs::DISC_A, [1.5, -1.0]) < 1.0, "{next}");
    let page = get_json(&format!("{}/v1/sessions/{sid}/results", server.base)).await;
    assert_eq!(page["results"][0], first, "the result before the reinit changed");
    server.stop().await.unwrap();
}

/// A `semdepth serve` child process.
struct ChildServer {
    child: Child,
    base: String,
}

impl ChildServer {
    fn start(db: &std::path::Path) -> Self {
        let mut child = Command::new(env!("CARGO_BIN_EXE_semdepth"))
            .args(["serve", "--listen", "127.0.0.1:0", "--db"])
            .arg(db)
            .env("SEMDEPTH_LOG", "info")
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        // The server logs its address; read lines until it does.
        let stderr = child.stderr.take().unwrap();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let mut sent = false;
            for line in BufReader::new(stderr).lines() {
                let Ok(line) = line else { break };
                if !sent {
                    if let Some(addr) = line.split("address=").nth(1) {
                        let _ = tx.send(addr.split_whitespace().next().unwrap_or("").to_string());
                        sent = true;
                    }
                }
            }
        });
        let addr = rx
            .recv_timeout(Duration::from_secs(30))
            .expect("server did not log its address");
        Self {
            child,
            base: format!("http://{addr}"),
        }
    }

    /// SIGKILL: no shutdown code runs.
    fn kill(mut self) {
        self.child.kill().unwrap();
        self.child.wait().unwrap();
    }

    /// SIGTERM, then wait for a clean exit.
    fn terminate(mut self) -> std::process::ExitStatus {
        let pid = self.child.id().to_string();
        Command::new("kill").args(["-TERM", &pid]).status().unwrap();
        for _ in 0..300 {
            if let Some(status) = self.child.try_wait().unwrap() {
                return status;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        self.child.kill().unwrap();
        panic!("server did not exit within 30 s of SIGTERM");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nothing_acknowledged_is_lost_when_the_process_is_killed() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("db.sqlite3");
    let pairs = synth_pairs(Preset::Clean, Shape::Sphere, 32, 10);
    let (first, second) = pairs.split_at(5);
    let http = reqwest::Client::new();

    let server = ChildServer::start(&db);
    let cal = post_json(
        &format!("{}/v1/calibrations", server.base),
        json!({"model": "fit", "samples": [{"disparity_px": 0.0, "z_um": 0.0}, {"disparity_px": 4.0, "z_um": 10.0}]}),
    )
    .await;
    let session = post_json(
        &format!("{}/v1/sessions", server.base),
        json!({"calibration_id": cal["id"]}),
    )
    .await;
    let sid = session["id"].as_str().unwrap().to_string();
    let mut acknowledged = Vec::new();
    for pair in first {
        let r = upload(&http, &server.base, &sid, pair).await;
        acknowledged.push(r);
    }
    // Killed right after the last acknowledgement: no flush, no checkpoint.
    server.kill();

    let server = ChildServer::start(&db);
    let cals = get_json(&format!("{}/v1/calibrations", server.base)).await;
    assert_eq!(cals["calibrations"][0], cal);
    let page = get_json(&format!("{}/v1/sessions/{sid}/results", server.base)).await;
    let stored = page["results"].as_array().unwrap();
    assert_eq!(stored.len(), acknowledged.len(), "acknowledged results were lost");
    for (s, a) in stored.iter().zip(&acknowledged) {
        assert_eq!(s, a, "a stored result differs from what was acknowledged");
    }
    for pair in second {
        let r = upload(&http, &server.base, &sid, pair).await;
        assert_eq!(r["status"], "tracked", "{r}");
    }
    let page = get_json(&format!("{}/v1/sessions/{sid}/results", server.base)).await;
    check_results(page["results"].as_array().unwrap(), &pairs);
    // SIGTERM shuts down cleanly (exit status 0).
    let status = server.terminate();
    assert!(status.success(), "exit status {status:?} after SIGTERM");
}

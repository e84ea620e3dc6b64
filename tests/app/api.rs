//! The HTTP contract end to end (issue #4): a real server on 127.0.0.1 port
//! 0 with a temporary SQLite file, driven by a real HTTP client, on
//! synthetic sequences whose true disparities are known.

use crate::common;
use crate::discs;
use crate::server;

use crate::server::{
    frames_form, get_json, get_text, json_of, offset_free_rms, pair_form, post_json, synth_pairs,
    test_config, TestServer,
};
use semdepth::service::state::ServiceConfig;
use semdepth_core::synth::{Preset, Shape};
use serde_json::{json, Value};

/// Disparity RMS limit (px, offset removed) for a clean sequence uploaded
/// over REST: the tracker reaches about 0.04 px on clean data (issue #3);
/// PNG round trip of 8-bit data costs nothing, so the same budget as the
/// noisy conditions (0.15 px) is generous.
const MAX_DISPARITY_RMS_PX: f64 = 0.15;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn calibration_session_upload_results_end_to_end() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("db.sqlite3"))).await;
    let http = reqwest::Client::new();
    let base = &server.base;

    // A fitted calibration: z = 2 d + 1 exactly.
    let (status, cal) = json_of(
        http.post(format!("{base}/v1/calibrations"))
            .json(&json!({"name": "lin", "model": "fit", "degree": 1,
                "samples": [{"disparity_px": 0.0, "z_um": 1.0}, {"disparity_px": 10.0, "z_um": 21.0}]}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 201, "{cal}");
    let cal_id = cal["id"].as_str().unwrap().to_string();
    let c = cal["coefficients"].as_array().unwrap();
    assert!(
        (c[0].as_f64().unwrap() - 1.0).abs() < 1e-9 && (c[1].as_f64().unwrap() - 2.0).abs() < 1e-9,
        "{cal}"
    );
    assert_eq!(cal["r_squared"], 1.0);
    assert!(cal["created_at"].as_str().unwrap().ends_with('Z'));

    // A geometric one, listed after the fit.
    let (status, geo) = json_of(
        http.post(format!("{base}/v1/calibrations"))
            .json(&json!({"model": "geometric", "pixel_size_um": 0.5, "vergence_deg": 6.0}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 201, "{geo}");
    let (_, list) = json_of(http.get(format!("{base}/v1/calibrations")).send().await.unwrap()).await;
    let ids: Vec<&str> = list["calibrations"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["id"].as_str().unwrap())
        .collect();
    assert_eq!(ids, vec![cal_id.as_str(), geo["id"].as_str().unwrap()]);

    // A session with that calibration.
    let (status, session) = json_of(
        http.post(format!("{base}/v1/sessions"))
            .json(&json!({"name": "blob", "calibration_id": cal_id}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 201, "{session}");
    assert_eq!(session["state"], "awaiting_first_pair");
    let sid = session["id"].as_str().unwrap().to_string();

    // Upload a clean sequence pair by pair.
    let pairs = synth_pairs(Preset::Clean, Shape::Blob, 7, 8);
    let mut errors = Vec::new();
    for (i, pair) in pairs.iter().enumerate() {
        let (status, r) = json_of(
            http.post(format!("{base}/v1/sessions/{sid}/frames"))
                .multipart(pair_form(pair))
                .send()
                .await
                .unwrap(),
        )
        .await;
        assert_eq!(status, 200, "{r}");
        assert_eq!(r["session_id"], sid.as_str());
        assert_eq!(r["frame"], i as u64);
        assert_eq!(r["status"], if i == 0 { "initialised" } else { "tracked" }, "{r}");
        let d = r["disparity_px"][0].as_f64().unwrap();
        errors.push(d - pair.truth.disparity_px[0]);
        // z from the calibration on the disparity across the default axis (x).
        let z = r["z_um"].as_f64().unwrap();
        assert!(
            (z - (1.0 + 2.0 * r["disparity_axis_px"].as_f64().unwrap())).abs() < 1e-9,
            "{r}"
        );
        assert!(r["left"]["contour"].as_array().unwrap().len() >= 16);
        for key in ["decode", "track", "total"] {
            assert!(r["timing_ms"][key].as_f64().unwrap() >= 0.0);
        }
    }
    let rms = offset_free_rms(&errors);
    eprintln!(
        "REST clean blob disparity RMS {rms:.4} px over {} pairs",
        errors.len()
    );
    assert!(
        rms <= MAX_DISPARITY_RMS_PX,
        "disparity RMS {rms} px > {MAX_DISPARITY_RMS_PX}"
    );

    // The session now tracks and counts its pairs.
    let (_, s) = json_of(
        http.get(format!("{base}/v1/sessions/{sid}"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(
        (s["state"].as_str(), s["frames"].as_u64()),
        (Some("tracking"), Some(8)),
        "{s}"
    );

    // Results as JSON (paged) and CSV.
    let (status, page) = json_of(
        http.get(format!("{base}/v1/sessions/{sid}/results?since=3&limit=2"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 200, "{page}");
    let frames: Vec<u64> = page["results"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["frame"].as_u64().unwrap())
        .collect();
    assert_eq!(frames, vec![3, 4]);
    assert_eq!(page["next_since"], 5);
    let csv = http
        .get(format!("{base}/v1/sessions/{sid}/results?format=csv"))
        .send()
        .await
        .unwrap();
    assert!(csv.headers()["content-type"]
        .to_str()
        .unwrap()
        .starts_with("text/csv"));
    let csv = csv.text().await.unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), 9, "{csv}");
    assert!(lines[0].starts_with("frame,"));
    assert!(lines[1].starts_with("0,") && lines[8].starts_with("7,"));

    // A calibration sample from the latest disparity refits the calibration.
    let (status, refit) = json_of(
        http.post(format!("{base}/v1/sessions/{sid}/calibration-samples"))
            .json(&json!({"calibration_id": cal_id, "z_um": 100.0}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 200, "{refit}");
    let samples = refit["samples"].as_array().unwrap();
    assert_eq!(samples.len(), 3);
    let last_d = s["latest_disparity_px"][0].as_f64().unwrap();
    assert!((samples[2]["disparity_px"].as_f64().unwrap() - last_d).abs() < 1e-9);

    // Appending directly works too; geometric calibrations refuse samples.
    let (status, _) = json_of(
        http.post(format!("{base}/v1/calibrations/{cal_id}/samples"))
            .json(&json!({"disparity_px": 5.0, "z_um": 11.0}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 200);
    let geo_id = geo["id"].as_str().unwrap();
    let (status, err) = json_of(
        http.post(format!("{base}/v1/calibrations/{geo_id}/samples"))
            .json(&json!({"disparity_px": 5.0, "z_um": 11.0}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(
        (status, err["error"]["code"].as_str()),
        (409, Some("not_a_fit_calibration"))
    );

    // The calibration in use cannot be deleted; after detaching it can.
    let r = http
        .delete(format!("{base}/v1/calibrations/{cal_id}"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 409);
    let (status, patched) = json_of(
        http.patch(format!("{base}/v1/sessions/{sid}"))
            .json(&json!({"calibration_id": null, "name": "renamed"}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 200, "{patched}");
    assert_eq!(
        (patched["calibration_id"].clone(), patched["name"].clone()),
        (Value::Null, json!("renamed"))
    );
    let r = http
        .delete(format!("{base}/v1/calibrations/{cal_id}"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 204);
    let r = http
        .get(format!("{base}/v1/calibrations/{cal_id}"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 404);

    // Without a calibration z is null; reset makes the next pair initialise.
    let (_, r) = json_of(
        http.post(format!("{base}/v1/sessions/{sid}/frames"))
            .multipart(pair_form(&pairs[0]))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(r["z_um"], Value::Null);
    let (status, s) = json_of(
        http.post(format!("{base}/v1/sessions/{sid}/reset"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!((status, s["state"].as_str()), (200, Some("awaiting_first_pair")));
    let (_, r) = json_of(
        http.post(format!("{base}/v1/sessions/{sid}/frames"))
            .multipart(pair_form(&pairs[1]))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(
        (r["status"].as_str(), r["frame"].as_u64()),
        (Some("initialised"), Some(9)),
        "{r}"
    );

    // One-shot depth with the geometric calibration.
    let (status, r) = json_of(
        http.post(format!("{base}/v1/depth?calibration_id={geo_id}"))
            .multipart(pair_form(&pairs[2]))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 200, "{r}");
    assert_eq!(
        (r["status"].as_str(), r["session_id"].clone()),
        (Some("initialised"), Value::Null)
    );
    assert!((r["disparity_px"][0].as_f64().unwrap() - pairs[2].truth.disparity_px[0]).abs() < 1.0);
    assert!(r["z_um"].is_number());

    // Metrics count what happened.
    let metrics = get_text(&format!("{base}/metrics")).await;
    assert!(
        metrics.contains("semdepth_pairs_processed_total{status=\"tracked\"}"),
        "{metrics}"
    );
    assert!(metrics.contains("semdepth_active_sessions 1"), "{metrics}");

    // Delete the session: gone, and so are its results.
    let r = http
        .delete(format!("{base}/v1/sessions/{sid}"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 204);
    let r = http
        .get(format!("{base}/v1/sessions/{sid}/results"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 404);
    server.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn concurrent_sessions_keep_their_own_results() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("db.sqlite3"))).await;
    let http = reqwest::Client::new();
    let base = server.base.clone();
    let cases = [(Shape::Blob, 11u64), (Shape::Sphere, 12), (Shape::Tip, 13)];
    let mut tasks = Vec::new();
    for (shape, seed) in cases {
        let (http, base) = (http.clone(), base.clone());
        tasks.push(tokio::spawn(async move {
            let (_, s) = json_of(
                http.post(format!("{base}/v1/sessions"))
                    .json(&json!({}))
                    .send()
                    .await
                    .unwrap(),
            )
            .await;
            let sid = s["id"].as_str().unwrap().to_string();
            let pairs = synth_pairs(Preset::Clean, shape, seed, 6);
            for pair in &pairs {
                let r = http
                    .post(format!("{base}/v1/sessions/{sid}/frames"))
                    .multipart(pair_form(pair))
                    .send()
                    .await
                    .unwrap();
                assert_eq!(r.status(), 200);
            }
            (sid, pairs)
        }));
    }
    for task in tasks {
        let (sid, pairs) = task.await.unwrap();
        let (_, page) = json_of(
            http.get(format!("{base}/v1/sessions/{sid}/results"))
                .send()
                .await
                .unwrap(),
        )
        .await;
        let results = page["results"].as_array().unwrap();
        assert_eq!(results.len(), pairs.len());
        for (r, pair) in results.iter().zip(&pairs) {
            assert_eq!(r["session_id"], sid.as_str());
            // Each session's left centroid follows its own object (the
            // three objects sit at different places with different motion).
            let c = &r["left"]["centroid"];
            let t = pair.truth.left.centroid;
            let err =
                ((c[0].as_f64().unwrap() - t[0]).powi(2) + (c[1].as_f64().unwrap() - t[1]).powi(2)).sqrt();
            assert!(
                err < 1.0,
                "session {sid} frame {}: centroid off by {err} px",
                r["frame"]
            );
        }
    }
    server.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn token_is_required_on_v1_when_configured() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = test_config(&dir.path().join("db.sqlite3"));
    config.token = Some("s3cret".into());
    let server = TestServer::start(config).await;
    let http = reqwest::Client::new();
    let base = &server.base;
    let r = http.get(format!("{base}/v1/sessions")).send().await.unwrap();
    assert_eq!(r.status(), 401);
    assert_eq!(r.headers()["www-authenticate"], "Bearer");
    let (_, body) = json_of(r).await;
    assert_eq!(body["error"]["code"], "unauthorized");
    let r = http
        .get(format!("{base}/v1/sessions"))
        .bearer_auth("wrong")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 401);
    let r = http
        .get(format!("{base}/v1/sessions"))
        .bearer_auth("s3cret")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    // The scheme's name is case-insensitive (RFC 7235; issue #66); the
    // token is not.
    for (value, status) in [
        ("bearer s3cret", 200),
        ("BEARER s3cret", 200),
        ("Bearer  s3cret", 200),
        ("bearer wrong", 401),
        ("bearer S3CRET", 401),
        ("Basic s3cret", 401),
        ("bearers3cret", 401),
    ] {
        let r = http
            .get(format!("{base}/v1/sessions"))
            .header("authorization", value)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), status, "Authorization: {value}");
    }
    // Operations endpoints stay open for probes.
    let r = http.get(format!("{base}/healthz")).send().await.unwrap();
    assert_eq!(r.status(), 200);
    server.stop().await.unwrap();
}

/// Uploads the two-disc scene moved by `motion` to a session; returns the
/// status and the answer.
async fn upload_scene(http: &reqwest::Client, base: &str, sid: &str, motion: [f64; 2]) -> (u16, Value) {
    let (left, right) = discs::scene_pair(motion);
    json_of(
        http.post(format!("{base}/v1/sessions/{sid}/frames"))
            .multipart(frames_form(&left, &right))
            .send()
            .await
            .unwrap(),
    )
    .await
}

/// Asserts a measured result of the two-disc scene: its frame and status,
/// the left centroid on `disc` (moved by `motion`) and the scene's disparity.
fn assert_on_disc(r: &Value, frame: u64, status: &str, disc: [f64; 3], motion: [f64; 2]) {
    assert_eq!(
        (r["frame"].as_u64(), r["status"].as_str()),
        (Some(frame), Some(status)),
        "{r}"
    );
    let d = discs::distance(&r["left"]["centroid"], disc[0] + motion[0], disc[1] + motion[1]);
    assert!(
        d < 1.0,
        "frame {frame}: left centroid {} is {d:.2} px off the disc",
        r["left"]["centroid"]
    );
    let disparity = r["disparity_axis_px"].as_f64().unwrap();
    assert!(
        (disparity - discs::DISPARITY_PX).abs() < 0.3,
        "frame {frame}: disparity {disparity:.3} px, expected {}",
        discs::DISPARITY_PX
    );
}

/// Issue #65: a hint that names nothing is refused, not replaced. A
/// `polarity` no region has (both discs are bright) is 422
/// `hint_matches_nothing` on the first pair, naming the hint and what was
/// found instead; the pair is not counted and the session stays, so new
/// hints take the next pair (a point, a lasso round the smaller disc, a
/// point on the larger that is not the object). Two objects whose hints
/// resolve to one disc are 422 `objects_share_a_region`, naming both.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hints_that_name_nothing_or_one_region_twice_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("db.sqlite3"))).await;
    let http = reqwest::Client::new();
    let base = &server.base;
    let session = |body: Value| {
        let http = http.clone();
        async move {
            let (status, s) = json_of(
                http.post(format!("{base}/v1/sessions"))
                    .json(&body)
                    .send()
                    .await
                    .unwrap(),
            )
            .await;
            assert_eq!(status, 201, "{s}");
            s["id"].as_str().unwrap().to_string()
        }
    };
    let message = |r: &Value, code: &str| {
        assert_eq!(r["error"]["code"], code, "{r}");
        r["error"]["message"].as_str().unwrap().to_string()
    };

    let sid = session(json!({"init": {"polarity": "darker"}})).await;
    let (status, r) = upload_scene(&http, base, &sid, [0.0, 0.0]).await;
    assert_eq!(status, 422, "{r}");
    let m = message(&r, "hint_matches_nothing");
    for needle in ["polarity darker", "found instead", "centred at"] {
        assert!(m.contains(needle), "message should mention {needle:?}: {m}");
    }
    let (_, s) = json_of(
        http.get(format!("{base}/v1/sessions/{sid}"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(
        (s["frames"].as_u64(), s["state"].as_str()),
        (Some(0), Some("awaiting_first_pair")),
        "{s}"
    );
    // A point on the background of the scene names nothing either.
    let reinit = |sid: String, init: Value| {
        let http = http.clone();
        async move {
            let r = http
                .post(format!("{base}/v1/sessions/{sid}/reinit"))
                .json(&json!({"init": init}))
                .send();
            assert_eq!(r.await.unwrap().status(), 200);
        }
    };
    reinit(sid.clone(), json!({"point": [300.0, 220.0]})).await;
    let (status, r) = upload_scene(&http, base, &sid, [0.0, 0.0]).await;
    assert_eq!(status, 422, "{r}");
    assert!(
        message(&r, "hint_matches_nothing").contains("point (300, 220)"),
        "{r}"
    );
    // Hints that name a disc take the next pair.
    reinit(
        sid.clone(),
        json!({"point": [discs::DISC_A[0], discs::DISC_A[1]]}),
    )
    .await;
    let (status, r) = upload_scene(&http, base, &sid, [0.0, 0.0]).await;
    assert_eq!(status, 200, "{r}");
    assert_on_disc(&r, 0, "initialised", discs::DISC_A, [0.0, 0.0]);

    // A lasso round disc B names it, though A is larger; so does a point
    // on A that says "not this".
    let lasso = discs::lasso(discs::DISC_B, 4.0, 10);
    reinit(sid.clone(), json!({"outline": lasso})).await;
    let (status, r) = upload_scene(&http, base, &sid, [0.0, 0.0]).await;
    assert_eq!(status, 200, "{r}");
    assert_on_disc(&r, 1, "initialised", discs::DISC_B, [0.0, 0.0]);
    let s = get_json(&format!("{base}/v1/sessions/{sid}")).await;
    assert_eq!(s["init"]["outline"].as_array().map(Vec::len), Some(10), "{s}");
    reinit(
        sid.clone(),
        json!({"exclude": [[discs::DISC_A[0], discs::DISC_A[1]]]}),
    )
    .await;
    let (status, r) = upload_scene(&http, base, &sid, [0.0, 0.0]).await;
    assert_eq!(status, 200, "{r}");
    assert_on_disc(&r, 2, "initialised", discs::DISC_B, [0.0, 0.0]);
    let s = get_json(&format!("{base}/v1/sessions/{sid}")).await;
    assert_eq!(
        s["init"]["outline"],
        Value::Null,
        "a new hint replaces the set: {s}"
    );

    // Two objects, a box around disc A and a point on it: one region.
    let sid = session(json!({"objects": [
        {"name": "boxed", "roi": discs::ROI_A},
        {"name": "pointed", "point": [discs::DISC_A[0], discs::DISC_A[1]]}
    ]}))
    .await;
    let (status, r) = upload_scene(&http, base, &sid, [0.0, 0.0]).await;
    assert_eq!(status, 422, "{r}");
    let m = message(&r, "objects_share_a_region");
    for needle in ["\"pointed\"", "\"boxed\""] {
        assert!(m.contains(needle), "message should name {needle}: {m}");
    }
    let (_, s) = json_of(
        http.get(format!("{base}/v1/sessions/{sid}"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(s["frames"].as_u64(), Some(0), "{s}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hints_name_the_object_and_reinit_switches_to_the_other() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("db.sqlite3"))).await;
    let http = reqwest::Client::new();
    let base = &server.base;

    // A session told to follow the smaller disc B.
    let (status, s) = json_of(
        http.post(format!("{base}/v1/sessions"))
            .json(&json!({"name": "two discs", "init": {"roi": discs::ROI_B, "polarity": "brighter", "contour_spacing_px": 3.0}}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 201, "{s}");
    assert_eq!(
        (s["init"]["roi"].clone(), s["init"]["polarity"].clone()),
        (json!(discs::ROI_B), json!("brighter"))
    );
    let sid = s["id"].as_str().unwrap().to_string();
    let motions = [[0.0, 0.0], [1.5, -1.0], [3.0, -2.0], [4.5, -3.0]];
    let (status, r) = upload_scene(&http, base, &sid, motions[0]).await;
    assert_eq!(status, 200, "{r}");
    assert_on_disc(&r, 0, "initialised", discs::DISC_B, motions[0]);
    let (_, r) = upload_scene(&http, base, &sid, motions[1]).await;
    assert_on_disc(&r, 1, "tracked", discs::DISC_B, motions[1]);
    let (_, before) = json_of(
        http.get(format!("{base}/v1/sessions/{sid}/results"))
            .send()
            .await
            .unwrap(),
    )
    .await;

    // New hints name disc A. The hints are replaced as a set (polarity
    // back to `any`), a tuning parameter given overrides the session's and
    // one left out keeps it.
    let (status, s) = json_of(
        http.post(format!("{base}/v1/sessions/{sid}/reinit"))
            .json(&json!({"init": {"roi": discs::ROI_A, "working_max_side": 320}}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 200, "{s}");
    assert_eq!(
        (s["state"].as_str(), s["frames"].as_u64()),
        (Some("awaiting_first_pair"), Some(2)),
        "{s}"
    );
    assert_eq!(s["init"]["roi"], json!(discs::ROI_A));
    assert_eq!(s["init"]["polarity"], "any");
    assert_eq!(s["init"]["point"], Value::Null);
    assert_eq!(s["init"]["working_max_side"], 320);
    assert_eq!(s["init"]["contour_spacing_px"], 3.0);
    assert_eq!(s["tracker"]["init"], s["init"]);
    let (_, got) = json_of(
        http.get(format!("{base}/v1/sessions/{sid}"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(got, s, "GET answers what reinit answered");

    // The next pair initialises on A; the frame counter goes on.
    let (status, r) = upload_scene(&http, base, &sid, motions[2]).await;
    assert_eq!(status, 200, "{r}");
    assert_on_disc(&r, 2, "initialised", discs::DISC_A, motions[2]);
    let (_, r) = upload_scene(&http, base, &sid, motions[3]).await;
    assert_on_disc(&r, 3, "tracked", discs::DISC_A, motions[3]);

    // The earlier results are untouched.
    let (_, after) = json_of(
        http.get(format!("{base}/v1/sessions/{sid}/results"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    let after = after["results"].as_array().unwrap();
    assert_eq!(after.len(), 4);
    assert_eq!(
        after[..2],
        before["results"].as_array().unwrap()[..],
        "results before the reinit changed"
    );

    // A reinit with a point only clears the roi; an empty one clears all hints.
    let (status, s) = json_of(
        http.post(format!("{base}/v1/sessions/{sid}/reinit"))
            .json(&json!({"init": {"point": [95.5, 127.0], "min_area_px": 500.0}}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 200, "{s}");
    assert_eq!(
        (s["init"]["roi"].clone(), s["init"]["point"].clone()),
        (Value::Null, json!([95.5, 127.0]))
    );
    assert_eq!(
        (
            s["init"]["min_area_px"].as_f64(),
            s["init"]["working_max_side"].as_u64()
        ),
        (Some(500.0), Some(320))
    );
    let (status, s) = json_of(
        http.post(format!("{base}/v1/sessions/{sid}/reinit"))
            .json(&json!({}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 200, "{s}");
    assert_eq!(
        (s["init"]["point"].clone(), s["init"]["min_area_px"].clone()),
        (Value::Null, Value::Null)
    );
    assert_eq!(s["frames"], 4);
    server.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_shot_depth_takes_hints_as_query_parameters() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("db.sqlite3"))).await;
    let http = reqwest::Client::new();
    let (left, right) = discs::scene_pair([0.0, 0.0]);
    let depth = |query: &'static str| {
        let request = http
            .post(format!("{}/v1/depth?{query}", server.base))
            .multipart(frames_form(&left, &right));
        async move { json_of(request.send().await.unwrap()).await }
    };
    for (query, disc) in [
        ("roi=200,75,70,70&polarity=brighter", discs::DISC_B),
        ("roi=40,80,100,100&polarity=any", discs::DISC_A),
        // A box past the top and right borders, and a point on B.
        ("roi=190,-30,200,230&point=235,110", discs::DISC_B),
    ] {
        let (status, r) = depth(query).await;
        assert_eq!(status, 200, "{query}: {r}");
        assert_eq!(r["session_id"], Value::Null);
        assert_on_disc(&r, 0, "initialised", disc, [0.0, 0.0]);
    }
    // Spaces around the numbers pass; other white space is refused as the
    // documented pattern says, a number that is not finite as a hint.
    for (query, status, code) in [
        ("roi=%20200%20,75,%2070,70&polarity=brighter", 200, ""),
        ("roi=200,75,70,70%09", 400, "invalid_query"),
        ("point=%09235,110", 400, "invalid_query"),
        ("point=inf,110", 422, "invalid_hint"),
        ("point=235,1e999", 422, "invalid_hint"),
    ] {
        let (got, r) = depth(query).await;
        assert_eq!(got, status, "{query}: {r}");
        if status != 200 {
            assert_eq!(r["error"]["code"], code, "{query}: {r}");
        }
    }
    server.stop().await.unwrap();
}

/// Issue #20: a calibration that takes the pixel size and the vergence from
/// the images (`from_images`, `from_stage_tilt`), used by a session fed
/// FEI TIFFs over REST and over the WebSocket: z equals the typed geometric
/// calibration's to 1e-9 um, and each result echoes the metadata. PNG
/// pairs (no metadata) get no z and a warning saying why.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn calibration_from_image_metadata_gives_the_typed_z() {
    use futures_util::SinkExt;
    use server::{next_reply, png, sdp1};
    use tokio_tungstenite::tungstenite::Message;

    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("db.sqlite3"))).await;
    let http = reqwest::Client::new();
    let base = &server.base;
    let create = |body: Value| {
        let http = http.clone();
        async move {
            json_of(
                http.post(format!("{base}/v1/calibrations"))
                    .json(&body)
                    .send()
                    .await
                    .unwrap(),
            )
            .await
        }
    };
    let (status, cal) =
        create(json!({"model": "geometric", "pixel_size": "from_images", "vergence": "from_stage_tilt"}))
            .await;
    assert_eq!(status, 201, "{cal}");
    assert_eq!(cal["pixel_size"], "from_images");
    assert_eq!(cal["vergence"], "from_stage_tilt");
    assert_eq!(cal["coefficients"], json!([]), "{cal}");
    // Both ways at once is refused, naming the fields.
    let (status, err) = create(
        json!({"model": "geometric", "pixel_size": "from_images", "pixel_size_um": 0.1,
        "vergence_deg": 5}),
    )
    .await;
    assert!(status == 400 || status == 422, "{status} {err}");
    assert!(
        err["error"]["message"]
            .as_str()
            .unwrap()
            .contains("pixel_size_um"),
        "{err}"
    );

    let (pixel_m, tilt_l, vergence_deg) = (9.76562e-8, 0.3, 6.0_f64);
    let tilt_r = tilt_l + vergence_deg.to_radians();
    let typed = semdepth_core::calib::build(semdepth_core::calib::CalibrationSpec::Geometric(
        semdepth_core::calib::GeometricSpec::new(pixel_m * 1e6, (tilt_r - tilt_l).to_degrees()),
    ))
    .unwrap();
    let (_, session) = json_of(
        http.post(format!("{base}/v1/sessions"))
            .json(&json!({"calibration_id": cal["id"]}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    let sid = session["id"].as_str().unwrap().to_string();
    let pairs = synth_pairs(Preset::Clean, Shape::Blob, 11, 6);
    let check = |r: &Value, what: &str| {
        let z = r["z_um"].as_f64().unwrap_or_else(|| panic!("{what}: no z: {r}"));
        let expected = typed.z_um([
            r["disparity_px"][0].as_f64().unwrap(),
            r["disparity_px"][1].as_f64().unwrap(),
        ]);
        assert!((z - expected).abs() <= 1e-9, "{what}: z {z} against {expected}");
        // With its standard error through the same slope (issue #17).
        let (d_std, z_std) = (
            r["disparity_std_px"].as_f64().unwrap(),
            r["z_std_um"].as_f64().unwrap(),
        );
        assert!(
            d_std > 0.0 && (z_std - d_std * typed.coefficients()[1]).abs() < 1e-9,
            "{what}: {r}"
        );
        let meta = &r["metadata"];
        assert!(
            (meta["right"]["pixel_width_m"].as_f64().unwrap() - pixel_m).abs() < 1e-9 * pixel_m,
            "{meta}"
        );
        assert!(
            (meta["stage_tilt_difference_rad"].as_f64().unwrap() - (tilt_r - tilt_l)).abs() < 1e-12,
            "{meta}"
        );
    };
    for pair in &pairs[..3] {
        let form = reqwest::multipart::Form::new()
            .part(
                "left",
                reqwest::multipart::Part::bytes(common::fei_tiff(&pair.left.to_gray8(), pixel_m, tilt_l))
                    .file_name("l.tif"),
            )
            .part(
                "right",
                reqwest::multipart::Part::bytes(common::fei_tiff(&pair.right.to_gray8(), pixel_m, tilt_r))
                    .file_name("r.tif"),
            );
        let (status, r) = json_of(
            http.post(format!("{base}/v1/sessions/{sid}/frames"))
                .multipart(form)
                .send()
                .await
                .unwrap(),
        )
        .await;
        assert_eq!(status, 200, "{r}");
        check(&r, "REST");
    }
    let (mut ws, _) = tokio_tungstenite::connect_async(server.stream_url(&sid, "all"))
        .await
        .unwrap();
    for (seq, pair) in pairs[3..5].iter().enumerate() {
        let (l, r) = (
            common::fei_tiff(&pair.left.to_gray8(), pixel_m, tilt_l),
            common::fei_tiff(&pair.right.to_gray8(), pixel_m, tilt_r),
        );
        let header = json!({"seq": seq, "encoding": "tiff", "left_len": l.len(), "right_len": r.len()});
        ws.send(Message::Binary(sdp1(&header, &l, &r).into()))
            .await
            .unwrap();
        check(&next_reply(&mut ws).await, "WebSocket");
    }
    // PNG files carry no metadata: tracked, but no z, and the reason.
    let (l, r) = (png(&pairs[5].left), png(&pairs[5].right));
    let header = json!({"seq": 9, "encoding": "png", "left_len": l.len(), "right_len": r.len()});
    ws.send(Message::Binary(sdp1(&header, &l, &r).into()))
        .await
        .unwrap();
    let reply = next_reply(&mut ws).await;
    assert_eq!(reply["status"], "tracked", "{reply}");
    assert!(reply["z_um"].is_null(), "{reply}");
    assert!(reply["warnings"].to_string().contains("no metadata"), "{reply}");
    server.stop().await.unwrap();
}

/// Issue #22: sessions idle for `--session-expiry-h` are deleted, with their
/// results, unless created with `keep`; a session that changes is not
/// idle. Bulk deletes take sessions by name prefix or idle time and leave
/// kept ones unless told otherwise.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn idle_sessions_expire_and_kept_ones_stay() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("expiry.sqlite3");
    let config = ServiceConfig {
        session_expiry: Some(std::time::Duration::from_secs(3)),
        ..test_config(&db)
    };
    let server = TestServer::start(config).await;
    let base = server.base.clone();
    let http = reqwest::Client::new();
    let create = |body: Value| {
        let (http, base) = (http.clone(), base.clone());
        async move {
            let (code, v) = json_of(
                http.post(format!("{base}/v1/sessions"))
                    .json(&body)
                    .send()
                    .await
                    .unwrap(),
            )
            .await;
            assert_eq!(code, 201, "{v}");
            v
        }
    };
    let scratch = create(json!({"name": "scratch"})).await;
    let kept = create(json!({"name": "overnight", "keep": true})).await;
    assert_eq!(scratch["keep"], json!(false));
    assert_eq!(kept["keep"], json!(true));
    let ids = |v: &Value| -> Vec<String> {
        v["sessions"]
            .as_array()
            .unwrap()
            .iter()
            .map(|s| s["id"].as_str().unwrap().to_string())
            .collect()
    };
    // A second session kept active by a change every second outlives the
    // expiry.
    let active = create(json!({"name": "active"})).await;
    let active_id = active["id"].as_str().unwrap().to_string();
    for k in 0..6 {
        tokio::time::sleep(std::time::Duration::from_secs(1)).await;
        let r = http
            .patch(format!("{base}/v1/sessions/{active_id}"))
            .json(&json!({"name": format!("active {k}")}))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 200);
    }
    let list = get_json(&format!("{base}/v1/sessions")).await;
    let mut left = ids(&list);
    left.sort();
    let mut expected = vec![kept["id"].as_str().unwrap().to_string(), active_id.clone()];
    expected.sort();
    assert_eq!(left, expected, "after 6 s with a 3-s expiry: {list}");
    let r = http
        .get(format!("{base}/v1/sessions/{}", scratch["id"].as_str().unwrap()))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 404, "the expired session is gone");
    server.stop().await.unwrap();

    // Bulk deletes, on a server without expiry over the same database.
    let server = TestServer::start(test_config(&db)).await;
    let base = server.base.clone();
    for name in ["demo 1", "demo 2", "experiment"] {
        let (code, v) = json_of(
            http.post(format!("{base}/v1/sessions"))
                .json(&json!({"name": name}))
                .send()
                .await
                .unwrap(),
        )
        .await;
        assert_eq!(code, 201, "{v}");
    }
    let (code, v) = json_of(http.delete(format!("{base}/v1/sessions")).send().await.unwrap()).await;
    assert_eq!(code, 400, "a bulk delete needs a filter: {v}");
    assert!(
        v["error"]["message"].as_str().unwrap().contains("name_prefix"),
        "{v}"
    );
    let (code, v) = json_of(
        http.delete(format!("{base}/v1/sessions?name_prefix=demo"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(code, 200, "{v}");
    assert_eq!(v["deleted"].as_array().unwrap().len(), 2, "{v}");
    // Idle for an hour: none. Idle for 0 s: all but the kept one.
    let (_, v) = json_of(
        http.delete(format!("{base}/v1/sessions?idle_for_s=3600"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(v["deleted"], json!([]), "{v}");
    // Filters that do not narrow (issue #66): an empty prefix, an idle time
    // under a minute without a prefix. Refused, and nothing deleted.
    for query in [
        "name_prefix=",
        "idle_for_s=0",
        "idle_for_s=59",
        "name_prefix=&idle_for_s=0",
    ] {
        let (code, v) = json_of(
            http.delete(format!("{base}/v1/sessions?{query}"))
                .send()
                .await
                .unwrap(),
        )
        .await;
        assert_eq!(code, 400, "{query}: {v}");
        assert_eq!(v["error"]["code"], "invalid_query", "{query}: {v}");
        let message = v["error"]["message"].as_str().unwrap();
        let names = if query.contains("name_prefix") {
            "name_prefix"
        } else {
            "idle_for_s"
        };
        assert!(message.contains(names), "{query}: {message}");
        let list = get_json(&format!("{base}/v1/sessions")).await;
        assert_eq!(ids(&list).len(), 3, "{query} deleted nothing: {list}");
    }
    // With a prefix, any idle time: all but the kept one.
    let mut deleted = 0;
    for prefix in ["a", "e"] {
        let (code, v) = json_of(
            http.delete(format!("{base}/v1/sessions?name_prefix={prefix}&idle_for_s=0"))
                .send()
                .await
                .unwrap(),
        )
        .await;
        assert_eq!(code, 200, "{v}");
        deleted += v["deleted"].as_array().unwrap().len();
    }
    assert_eq!(deleted, 2, "active and experiment");
    let list = get_json(&format!("{base}/v1/sessions")).await;
    assert_eq!(
        ids(&list),
        vec![kept["id"].as_str().unwrap().to_string()],
        "{list}"
    );
    let (_, v) = json_of(
        http.delete(format!("{base}/v1/sessions?name_prefix=over&include_kept=true"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(v["deleted"].as_array().unwrap().len(), 1, "{v}");
    server.stop().await.unwrap();
}

/// Issue #22: `contours=false` leaves the contours out of the upload's
/// reply and of a results page (their arrays empty, every number the same),
/// which makes a page of 4 results several times smaller.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn results_without_contours_are_light() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("light.sqlite3"))).await;
    let base = server.base.clone();
    let http = reqwest::Client::new();
    let sid = server::new_session(&base).await;
    for (k, pair) in synth_pairs(Preset::Clean, Shape::Blob, 3, 4).iter().enumerate() {
        let query = if k % 2 == 0 { "" } else { "?contours=false" };
        let (code, v) = json_of(
            http.post(format!("{base}/v1/sessions/{sid}/frames{query}"))
                .multipart(pair_form(pair))
                .send()
                .await
                .unwrap(),
        )
        .await;
        assert_eq!(code, 200, "{v}");
        let contour = v["left"]["contour"].as_array().unwrap();
        assert_eq!(
            contour.is_empty(),
            k % 2 == 1,
            "pair {k}: {} contour vertices",
            contour.len()
        );
    }
    let full = http
        .get(format!("{base}/v1/sessions/{sid}/results"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    let light = http
        .get(format!("{base}/v1/sessions/{sid}/results?contours=false"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    eprintln!(
        "4 results: {} bytes with contours, {} without",
        full.len(),
        light.len()
    );
    assert!(
        light.len() * 3 < full.len(),
        "{} bytes without contours, {} with",
        light.len(),
        full.len()
    );
    let (full, light): (Value, Value) = (
        serde_json::from_str(&full).unwrap(),
        serde_json::from_str(&light).unwrap(),
    );
    for (a, b) in full["results"]
        .as_array()
        .unwrap()
        .iter()
        .zip(light["results"].as_array().unwrap())
    {
        assert!(!a["left"]["contour"].as_array().unwrap().is_empty());
        assert_eq!(b["left"]["contour"], json!([]));
        assert_eq!(b["right"]["contour"], json!([]));
        assert_eq!(a["disparity_axis_px"], b["disparity_axis_px"]);
        assert_eq!(a["left"]["centroid"], b["left"]["centroid"]);
    }
    let (code, v) = json_of(
        http.get(format!("{base}/v1/sessions/{sid}/results?contours=maybe"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(code, 400, "{v}");
    server.stop().await.unwrap();
}

/// Issue #22: a calibration sample takes the latest pair's disparity only
/// when that pair was tracked (after a lost pair: 409, the calibration
/// unchanged), and records the session and frame it came from; every
/// sample's residual is shown, and correcting or removing an outlier
/// refits and restores R^2. Every change makes a new version; results keep the version they
/// used, and every version stays readable, across a restart.
/// A point on the image corner with the object said to be brighter there
/// gives no valid contour position: its energy has no finite value. The
/// pair is lost with `energy: null`, and the
/// stored result reads back (a non-finite energy used to be stored as null
/// and then refused as unreadable by every later read of the results).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lost_pair_whose_energy_is_not_finite_reads_back() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("energy.sqlite3"))).await;
    let base = server.base.clone();
    let http = reqwest::Client::new();
    let s = post_json(
        &format!("{base}/v1/sessions"),
        json!({"init": {"point": [0, 0], "polarity": "brighter"}}),
    )
    .await;
    let sid = s["id"].as_str().unwrap();
    let config = semdepth_core::synth::SynthConfig {
        frames: 3,
        ..semdepth_core::synth::SynthConfig::preset(Preset::Clean, Shape::Blob, 0)
    }
    .with_size(96, 80);
    let pair = semdepth_core::synth::frames(&config).unwrap().next().unwrap();
    let (code, v) = json_of(
        http.post(format!("{base}/v1/sessions/{sid}/frames"))
            .multipart(pair_form(&pair))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(code, 200, "{v}");
    assert_eq!(v["status"], "lost", "{v}");
    assert!(
        v["left"]["energy"].is_null(),
        "left energy {}",
        v["left"]["energy"]
    );
    for format in ["", "?format=csv"] {
        let r = http
            .get(format!("{base}/v1/sessions/{sid}/results{format}"))
            .send()
            .await
            .unwrap();
        let code = r.status().as_u16();
        let text = r.text().await.unwrap();
        assert_eq!(code, 200, "results{format}: {text}");
        assert!(text.contains("lost"), "results{format}: {text}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn calibration_samples_are_traced_and_outliers_removable() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("samples.sqlite3"))).await;
    let base = server.base.clone();
    let http = reqwest::Client::new();
    let cal = post_json(
        &format!("{base}/v1/calibrations"),
        json!({"model": "fit", "degree": 1, "samples": [
            {"disparity_px": 0.0, "z_um": 0.0}, {"disparity_px": 1.0, "z_um": 10.0}, {"disparity_px": 2.0, "z_um": 20.0}]}),
    )
    .await;
    let cal_id = cal["id"].as_str().unwrap().to_string();
    let sid = post_json(&format!("{base}/v1/sessions"), json!({"calibration_id": cal_id})).await["id"]
        .as_str()
        .unwrap()
        .to_string();
    let pairs = synth_pairs(Preset::Clean, Shape::Blob, 2, 1);
    let (code, first) = json_of(
        http.post(format!("{base}/v1/sessions/{sid}/frames"))
            .multipart(pair_form(&pairs[0]))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(
        (code, first["status"].as_str()),
        (200, Some("initialised")),
        "{first}"
    );
    let sample = |z: f64| {
        let (http, url) = (
            http.clone(),
            format!("{base}/v1/sessions/{sid}/calibration-samples"),
        );
        let body = json!({"calibration_id": cal_id, "z_um": z});
        async move { json_of(http.post(url).json(&body).send().await.unwrap()).await }
    };
    // The disparity there is about 3 px; on the line z = 10 d.
    let d0 = first["disparity_axis_px"].as_f64().unwrap();
    let (code, refit) = sample(10.0 * d0).await;
    assert_eq!(code, 200, "{refit}");
    let last = &refit["samples"][3];
    assert_eq!(last["session_id"], json!(sid), "{refit}");
    assert_eq!(last["frame"], json!(0), "{refit}");
    assert_eq!(refit["residuals_um"].as_array().unwrap().len(), 4, "{refit}");

    // A pair without the object: lost. A sample now is refused.
    let (w, h) = (pairs[0].left.width, pairs[0].left.height);
    let blank = semdepth_core::imageio::GrayFrame::new(w, h, 8, vec![120; (w * h) as usize]).unwrap();
    let (code, lost) = json_of(
        http.post(format!("{base}/v1/sessions/{sid}/frames"))
            .multipart(frames_form(&blank, &blank))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!((code, lost["status"].as_str()), (200, Some("lost")), "{lost}");
    let (code, refused) = sample(250.0).await;
    assert_eq!(code, 409, "{refused}");
    assert_eq!(refused["error"]["code"], json!("latest_pair_lost"), "{refused}");
    let unchanged = get_json(&format!("{base}/v1/calibrations/{cal_id}")).await;
    assert_eq!(unchanged["samples"].as_array().unwrap().len(), 4, "{unchanged}");

    // A mistyped height: R^2 falls and its residual stands out.
    let r2_before = unchanged["r_squared"].as_f64().unwrap();
    let bad = post_json(
        &format!("{base}/v1/calibrations/{cal_id}/samples"),
        json!({"disparity_px": 1.5, "z_um": 60.0}),
    )
    .await;
    let r2_bad = bad["r_squared"].as_f64().unwrap();
    assert!(r2_bad < r2_before - 0.1, "R^2 {r2_before:.4} -> {r2_bad:.4}");
    let residuals: Vec<f64> = bad["residuals_um"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap().abs())
        .collect();
    let worst = (0..residuals.len())
        .max_by(|&a, &b| residuals[a].total_cmp(&residuals[b]))
        .unwrap();
    assert_eq!(worst, 4, "the outlier's residual is the largest: {residuals:?}");
    // Its height corrected (z = 10 d on the line), the fit is good again.
    let (code, edited) = json_of(
        http.patch(format!("{base}/v1/calibrations/{cal_id}/samples/{worst}"))
            .json(&json!({"z_um": 15.0}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(code, 200, "{edited}");
    assert_eq!(edited["samples"][4]["z_um"], json!(15.0), "{edited}");
    assert_eq!(edited["samples"][4]["disparity_px"], json!(1.5), "{edited}");
    assert!(
        edited["r_squared"].as_f64().unwrap() > r2_before - 1e-3,
        "{edited}"
    );
    assert!(
        edited["residuals_um"][4].as_f64().unwrap().abs() < 1.0,
        "{edited}"
    );
    let (code, fixed) = json_of(
        http.delete(format!("{base}/v1/calibrations/{cal_id}/samples/{worst}"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(code, 200, "{fixed}");
    assert_eq!(fixed["samples"].as_array().unwrap().len(), 4);
    assert!(
        (fixed["r_squared"].as_f64().unwrap() - r2_before).abs() < 1e-12,
        "{fixed}"
    );
    let (code, missing) = json_of(
        http.delete(format!("{base}/v1/calibrations/{cal_id}/samples/9"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(code, 404, "{missing}");
    assert_eq!(missing["error"]["code"], json!("sample_not_found"), "{missing}");

    // Versions: created 1, the session's sample 2, the outlier 3, its
    // correction 4, its removal 5. The first result was made with version 1 and still says
    // so, with the same z; version 1 is still there to read.
    assert_eq!(first["calibration_version"], json!(1), "{first}");
    assert_eq!(fixed["version"], json!(5), "{fixed}");
    let page = get_json(&format!("{base}/v1/sessions/{sid}/results")).await;
    assert_eq!(page["results"][0]["calibration_version"], json!(1), "{page}");
    assert_eq!(page["results"][0]["z_um"], first["z_um"], "{page}");
    let v1 = get_json(&format!("{base}/v1/calibrations/{cal_id}/versions/1")).await;
    assert_eq!(v1["version"], json!(1), "{v1}");
    assert_eq!(v1["samples"].as_array().unwrap().len(), 3, "{v1}");
    assert_eq!(v1["coefficients"], cal["coefficients"], "{v1}");
    let v3 = get_json(&format!("{base}/v1/calibrations/{cal_id}/versions/3")).await;
    assert_eq!(v3["r_squared"], bad["r_squared"], "{v3}");
    let (code, none) = json_of(
        http.get(format!("{base}/v1/calibrations/{cal_id}/versions/6"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(code, 404, "{none}");
    assert_eq!(
        none["error"]["code"],
        json!("calibration_version_not_found"),
        "{none}"
    );
    // A pair now reports the current version; a restart keeps versions.
    let (_, later) = json_of(
        http.post(format!("{base}/v1/sessions/{sid}/frames"))
            .multipart(pair_form(&pairs[0]))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(later["calibration_version"], json!(5), "{later}");
    server.stop().await.unwrap();
    let server = TestServer::start(test_config(&dir.path().join("samples.sqlite3"))).await;
    let v1 = get_json(&format!("{}/v1/calibrations/{cal_id}/versions/1", server.base)).await;
    assert_eq!(v1["samples"].as_array().unwrap().len(), 3, "{v1}");
    let now = get_json(&format!("{}/v1/calibrations/{cal_id}", server.base)).await;
    assert_eq!(now["version"], json!(5), "{now}");
    server.stop().await.unwrap();
}

/// Issue #22: every result says when the pair arrived and was processed
/// (RFC 3339 UTC), what the client called it (`label`, `timestamp` form
/// fields; the file names), and the CSV's `name` column is the pair's own
/// name, not the session's id. A timestamp that is not RFC 3339 is a 400.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn results_carry_their_provenance() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("trace.sqlite3"))).await;
    let base = server.base.clone();
    let http = reqwest::Client::new();
    let sid = server::new_session(&base).await;
    let pairs = synth_pairs(Preset::Clean, Shape::Blob, 4, 2);
    let before = time::OffsetDateTime::now_utc();
    let labelled = pair_form(&pairs[0])
        .text("label", "z=120um step 3")
        .text("timestamp", "2026-11-25T09:30:00Z");
    let (code, first) = json_of(
        http.post(format!("{base}/v1/sessions/{sid}/frames"))
            .multipart(labelled)
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(code, 200, "{first}");
    assert_eq!(first["label"], json!("z=120um step 3"));
    assert_eq!(first["timestamp"], json!("2026-11-25T09:30:00Z"));
    assert_eq!(first["left_file"], json!("left.png"));
    assert_eq!(first["right_file"], json!("right.png"));
    let rfc3339 = &time::format_description::well_known::Rfc3339;
    let received = time::OffsetDateTime::parse(first["received_at"].as_str().unwrap(), rfc3339).unwrap();
    let processed = time::OffsetDateTime::parse(first["processed_at"].as_str().unwrap(), rfc3339).unwrap();
    let after = time::OffsetDateTime::now_utc();
    assert!(
        before <= received && received <= processed && processed <= after,
        "{first}"
    );
    // Without a label, the CSV row is named after the left file.
    let (code, _) = json_of(
        http.post(format!("{base}/v1/sessions/{sid}/frames"))
            .multipart(pair_form(&pairs[1]))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(code, 200);
    let csv = http
        .get(format!("{base}/v1/sessions/{sid}/results?format=csv"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    let names: Vec<&str> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(1).unwrap())
        .collect();
    assert_eq!(names, ["z=120um step 3", "left.png"], "{csv}");
    // Stored results keep it all.
    let page = get_json(&format!("{base}/v1/sessions/{sid}/results")).await;
    assert_eq!(page["results"][0]["label"], json!("z=120um step 3"));
    assert_eq!(page["results"][0]["received_at"], first["received_at"]);
    // A timestamp that is not RFC 3339.
    let bad = pair_form(&pairs[1]).text("timestamp", "yesterday");
    let (code, v) = json_of(
        http.post(format!("{base}/v1/sessions/{sid}/frames"))
            .multipart(bad)
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(code, 400, "{v}");
    assert_eq!(v["error"]["code"], json!("invalid_timestamp"), "{v}");
    server.stop().await.unwrap();
}

/// Issue #66: a CSV of results never hands a spreadsheet a formula. Labels
/// that begin with `=`, `+`, `-`, `@`, a tab or a carriage return come back
/// with a single quote in front (quoted as RFC 4180 wants where needed),
/// and the numbers, negative ones included, stay numbers.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn csv_cells_that_a_spreadsheet_would_run_are_neutralised() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("csv.sqlite3"))).await;
    let base = server.base.clone();
    let http = reqwest::Client::new();
    let sid = server::new_session(&base).await;
    let pairs = synth_pairs(Preset::Clean, Shape::Blob, 4, 6);
    let labels = ["=cmd|' /C calc'!A0", "+1+1", "-2+3", "@SUM(A1:A9)", "\tx", "\rx"];
    for (pair, label) in pairs.iter().zip(labels) {
        let (code, r) = json_of(
            http.post(format!("{base}/v1/sessions/{sid}/frames"))
                .multipart(pair_form(pair).text("label", label))
                .send()
                .await
                .unwrap(),
        )
        .await;
        assert_eq!(code, 200, "{r}");
        assert_eq!(r["label"], json!(label), "the JSON keeps the label as given");
    }
    let response = http
        .get(format!("{base}/v1/sessions/{sid}/results?format=csv"))
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), 200);
    let csv = response.text().await.unwrap();
    let expected = [
        "'=cmd|' /C calc'!A0",
        "'+1+1",
        "'-2+3",
        "'@SUM(A1:A9)",
        "'\tx",
        "\"'\rx\"",
    ];
    // Rows start with the frame number; the carriage-return label is quoted
    // and so keeps its row whole.
    let rows: Vec<&str> = csv.split('\n').skip(1).filter(|l| !l.is_empty()).collect();
    assert_eq!(rows.len(), labels.len(), "{csv:?}");
    for (k, (row, cell)) in rows.iter().zip(expected).enumerate() {
        let prefix = format!("{k},{cell},");
        assert!(
            row.starts_with(&prefix),
            "row {k} should start {prefix:?}: {row:?}"
        );
    }
    // A tracked pair's numbers are numbers: the disparity cell parses.
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let column = header.iter().position(|h| *h == "disparity_axis_px").unwrap();
    let last = rows[3].split(',').nth(column).unwrap();
    assert!(
        last.parse::<f64>().is_ok(),
        "disparity cell {last:?} in {:?}",
        rows[3]
    );
    server.stop().await.unwrap();
}

//! The session layer's rules under concurrency and change (issue #18): the
//! session limit holds against concurrent creations, a calibration being
//! deleted is never left attached, PATCH merges parameters, and a session
//! measures its disparity across its calibration's tilt axis. A real
//! server on 127.0.0.1 port 0 with a SQLite file, a real HTTP client.

use crate::discs;

use crate::server::{frames_form, json_of, test_config, TestServer};
use semdepth::service::state::ServiceConfig;
use serde_json::{json, Value};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn concurrent_creations_never_pass_the_session_limit() {
    let dir = tempfile::tempdir().unwrap();
    const LIMIT: usize = 5;
    let server = TestServer::start(ServiceConfig {
        max_sessions: LIMIT,
        ..test_config(&dir.path().join("db.sqlite3"))
    })
    .await;
    let http = reqwest::Client::new();
    // Forty open connections first, so that the creations arrive together.
    let warm: Vec<_> = (0..40)
        .map(|_| tokio::spawn(http.get(format!("{}/healthz", server.base)).send()))
        .collect();
    for w in warm {
        assert_eq!(w.await.unwrap().unwrap().status(), 200);
    }
    let start = std::sync::Arc::new(tokio::sync::Barrier::new(40));
    let creations = (0..40).map(|i| {
        let start = start.clone();
        let (http, url) = (http.clone(), format!("{}/v1/sessions", server.base));
        tokio::spawn(async move {
            start.wait().await;
            json_of(
                http.post(url)
                    .json(&json!({"name": format!("s{i}")}))
                    .send()
                    .await
                    .unwrap(),
            )
            .await
        })
    });
    let creations: Vec<_> = creations.collect();
    let mut created = 0;
    for c in creations {
        let (status, body) = c.await.unwrap();
        match status {
            201 => created += 1,
            409 => assert_eq!(body["error"]["code"], "session_limit_reached", "{body}"),
            other => panic!("unexpected {other}: {body}"),
        }
    }
    assert_eq!(
        created, LIMIT,
        "40 concurrent creations against a limit of {LIMIT}"
    );
    let (_, list) = json_of(
        http.get(format!("{}/v1/sessions", server.base))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(list["sessions"].as_array().unwrap().len(), LIMIT);
    server.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_deleted_calibration_is_never_left_attached() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("db.sqlite3"))).await;
    let (http, base) = (reqwest::Client::new(), server.base.clone());
    let (status, session) = json_of(
        http.post(format!("{base}/v1/sessions"))
            .json(&json!({}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 201);
    let sid = session["id"].as_str().unwrap().to_string();
    let (mut attached, mut deleted) = (0, 0);
    for round in 0..30 {
        let (status, cal) = json_of(
            http.post(format!("{base}/v1/calibrations"))
                .json(&json!({"model": "geometric", "pixel_size_um": 0.5, "vergence_deg": 6.0}))
                .send()
                .await
                .unwrap(),
        )
        .await;
        assert_eq!(status, 201, "{cal}");
        let cid = cal["id"].as_str().unwrap().to_string();
        let patch = http
            .patch(format!("{base}/v1/sessions/{sid}"))
            .json(&json!({"calibration_id": cid}))
            .send();
        let delete = http.delete(format!("{base}/v1/calibrations/{cid}")).send();
        // Alternate which request leaves first.
        let (p, d) = if round % 2 == 0 {
            tokio::join!(patch, delete)
        } else {
            let (d, p) = tokio::join!(delete, patch);
            (p, d)
        };
        let (p, d) = (p.unwrap().status().as_u16(), d.unwrap().status().as_u16());
        let (_, now) = json_of(
            http.get(format!("{base}/v1/sessions/{sid}"))
                .send()
                .await
                .unwrap(),
        )
        .await;
        let cal_status = http
            .get(format!("{base}/v1/calibrations/{cid}"))
            .send()
            .await
            .unwrap()
            .status()
            .as_u16();
        match (p, d) {
            // Attached first: the deletion was refused.
            (200, 409) => {
                attached += 1;
                assert_eq!(now["calibration_id"], json!(cid));
                assert_eq!(cal_status, 200);
                let r = http
                    .patch(format!("{base}/v1/sessions/{sid}"))
                    .json(&json!({"calibration_id": null}))
                    .send()
                    .await
                    .unwrap();
                assert_eq!(r.status(), 200);
            }
            // Deleted first: attaching it was refused.
            (404, 204) => {
                deleted += 1;
                assert_ne!(
                    now["calibration_id"],
                    json!(cid),
                    "session points at a deleted calibration"
                );
                assert_eq!(cal_status, 404);
            }
            other => panic!("round {round}: PATCH and DELETE answered {other:?}"),
        }
    }
    assert_eq!(attached + deleted, 30);
    server.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn patch_changes_only_the_parameters_it_names() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("db.sqlite3"))).await;
    let (http, base) = (reqwest::Client::new(), server.base.clone());
    let (status, session) = json_of(
        http.post(format!("{base}/v1/sessions"))
            .json(&json!({
                "init": {"roi": [40, 80, 100, 100], "polarity": "brighter"},
                "tracker": {"max_disparity_px": 48.0, "rigid": {"search_radius_px": 30.0}}
            }))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 201, "{session}");
    let sid = session["id"].as_str().unwrap();
    let patch = |body: Value| {
        let (http, url) = (http.clone(), format!("{base}/v1/sessions/{sid}"));
        async move { json_of(http.patch(url).json(&body).send().await.unwrap()).await }
    };
    let (status, patched) = patch(json!({"tracker": {"rigid": {"max_evaluations": 800}}})).await;
    assert_eq!(status, 200, "{patched}");
    let t = &patched["tracker"];
    assert_eq!(t["rigid"]["max_evaluations"], 800, "{t}");
    assert_eq!(
        t["rigid"]["search_radius_px"], 30.0,
        "a field the patch left out was reset: {t}"
    );
    assert_eq!(t["max_disparity_px"], 48.0, "{t}");
    assert_eq!(t["init"]["roi"], json!([40, 80, 100, 100]), "{t}");
    assert_eq!(t["init"]["polarity"], "brighter", "{t}");

    // `init` merges too; null sets a field back to its default.
    let (status, patched) = patch(json!({"init": {"roi": null, "point": [90, 130]}})).await;
    assert_eq!(status, 200, "{patched}");
    let init = &patched["tracker"]["init"];
    assert_eq!(
        (init["roi"].clone(), init["point"].clone()),
        (Value::Null, json!([90.0, 130.0])),
        "{init}"
    );
    assert_eq!(init["polarity"], "brighter", "{init}");
    assert_eq!(patched["tracker"]["rigid"]["max_evaluations"], 800);

    // The merged parameters are what is stored: a restart keeps them.
    let (_, before) = json_of(
        http.get(format!("{base}/v1/sessions/{sid}"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    let db = server.db.clone();
    server.stop().await.unwrap();
    let server = TestServer::start(test_config(&db)).await;
    let (_, after) = json_of(
        http.get(format!("{}/v1/sessions/{sid}", server.base))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(after["tracker"], before["tracker"]);

    // Unknown or invalid fields in a patch are named, and change nothing.
    let base = server.base.clone();
    for (body, field) in [
        (
            json!({"tracker": {"rigid": {"serch_radius_px": 3}}}),
            "serch_radius_px",
        ),
        (json!({"tracker": {"max_disparity_px": -1.0}}), "max_disparity_px"),
        (json!({"init": {"polarity": "sideways"}}), "sideways"),
        (json!({"tracker": 5}), "tracker"),
    ] {
        let (status, err) = json_of(
            http.patch(format!("{base}/v1/sessions/{sid}"))
                .json(&body)
                .send()
                .await
                .unwrap(),
        )
        .await;
        assert!(matches!(status, 400 | 422), "{body}: {status} {err}");
        let message = err["error"]["message"].as_str().unwrap();
        assert!(message.contains(field), "{body}: {message}");
    }
    let (_, unchanged) = json_of(
        http.get(format!("{base}/v1/sessions/{sid}"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(unchanged["tracker"], after["tracker"]);
    server.stop().await.unwrap();
}

/// Creates the calibration z = 1 + 2 d (um, d in px) across the tilt axis
/// `axis_deg`; returns its id.
async fn fit_calibration(http: &reqwest::Client, base: &str, axis_deg: f64) -> String {
    let (status, cal) = json_of(
        http.post(format!("{base}/v1/calibrations"))
            .json(&json!({"model": "fit", "degree": 1, "tilt_axis_deg": axis_deg,
                "samples": [{"disparity_px": 0.0, "z_um": 1.0}, {"disparity_px": 10.0, "z_um": 21.0}]}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 201, "{cal}");
    cal["id"].as_str().unwrap().to_string()
}

/// A session measures `disparity_axis_px` across its calibration's tilt
/// axis, the axis `z_um` is computed on: with the axis at 270 degrees
/// (pointing up the image), `d_axis = -dx`. The scene moves by
/// +6 px in x between the views.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_session_measures_across_its_calibrations_axis() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("db.sqlite3"))).await;
    let (http, base) = (reqwest::Client::new(), server.base.clone());
    let cal = fit_calibration(&http, &base, 270.0).await;
    let (status, session) = json_of(
        http.post(format!("{base}/v1/sessions"))
            .json(&json!({"calibration_id": cal, "init": {"roi": discs::ROI_A}}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 201, "{session}");
    let sid = session["id"].as_str().unwrap();
    for (frame, motion) in [[0.0, 0.0], [2.0, 1.0]].into_iter().enumerate() {
        let (left, right) = discs::scene_pair(motion);
        let (status, r) = json_of(
            http.post(format!("{base}/v1/sessions/{sid}/frames"))
                .multipart(frames_form(&left, &right))
                .send()
                .await
                .unwrap(),
        )
        .await;
        assert_eq!(status, 200, "{r}");
        let d = r["disparity_axis_px"].as_f64().unwrap();
        let z = r["z_um"].as_f64().unwrap();
        assert!(
            (d + discs::DISPARITY_PX).abs() < 0.3,
            "frame {frame}: disparity_axis_px {d:.3}, expected -{} across the calibration's axis",
            discs::DISPARITY_PX
        );
        assert!(
            (z - (1.0 + 2.0 * d)).abs() < 1e-6,
            "frame {frame}: z {z} for d_axis {d}"
        );
        if frame > 0 {
            let rel = r["relative_disparity_axis_px"].as_f64().unwrap();
            assert!(rel.abs() < 0.3, "frame {frame}: relative disparity {rel}");
        }
    }
    server.stop().await.unwrap();
}

/// A tilt axis given with a calibration of another axis is refused with 400
/// `tilt_axis_conflict` naming both values, never dropped: at session
/// creation, in a PATCH (against the session's calibration, or the one the
/// same PATCH attaches) and in `/v1/depth`. The same axis written another
/// way (-270 for 90) is accepted, and a refused PATCH changes nothing.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_tilt_axis_that_is_not_the_calibrations_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("db.sqlite3"))).await;
    let (http, base) = (reqwest::Client::new(), server.base.clone());
    let (c90, c0) = (
        fit_calibration(&http, &base, 90.0).await,
        fit_calibration(&http, &base, 0.0).await,
    );
    let conflict = |status: u16, err: &serde_json::Value, a: &str, b: &str| {
        assert_eq!(status, 400, "{err}");
        assert_eq!(err["error"]["code"], "tilt_axis_conflict", "{err}");
        let message = err["error"]["message"].as_str().unwrap();
        assert!(
            message.contains(a) && message.contains(b),
            "names {a} and {b}: {message}"
        );
    };

    // Creation.
    let (status, err) = json_of(
        http.post(format!("{base}/v1/sessions"))
            .json(&json!({"calibration_id": c90, "tracker": {"tilt_axis_deg": 0.0}}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    conflict(status, &err, "tilt_axis_deg 0", "axis 90 deg");
    let (status, session) = json_of(
        http.post(format!("{base}/v1/sessions"))
            .json(&json!({"calibration_id": c90, "tracker": {"tilt_axis_deg": -270.0}}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 201, "-270 is the axis 90: {session}");
    let sid = session["id"].as_str().unwrap();

    // PATCH: against the session's calibration, then with another attached.
    let patch = |body: serde_json::Value| {
        let (http, url) = (http.clone(), format!("{base}/v1/sessions/{sid}"));
        async move { json_of(http.patch(url).json(&body).send().await.unwrap()).await }
    };
    let (status, err) = patch(json!({"tracker": {"tilt_axis_deg": 45.0}})).await;
    conflict(status, &err, "tilt_axis_deg 45", "axis 90 deg");
    let (status, err) = patch(json!({"calibration_id": c0, "tracker": {"tilt_axis_deg": 90.0}})).await;
    conflict(status, &err, "tilt_axis_deg 90", "axis 0 deg");
    let (_, unchanged) = json_of(
        http.get(format!("{base}/v1/sessions/{sid}"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(
        unchanged["calibration_id"],
        c90.as_str(),
        "a refused PATCH changes nothing: {unchanged}"
    );
    let (status, changed) = patch(json!({"calibration_id": c0, "tracker": {"tilt_axis_deg": 360.0}})).await;
    assert_eq!(status, 200, "360 is the axis 0: {changed}");
    let (status, detached) = patch(json!({"calibration_id": null, "tracker": {"tilt_axis_deg": 30.0}})).await;
    assert_eq!(status, 200, "without a calibration any axis goes: {detached}");
    assert_eq!(detached["tracker"]["tilt_axis_deg"], 30.0, "{detached}");

    // One-shot depth: refused before the upload is read.
    let (left, right) = discs::scene_pair([0.0, 0.0]);
    let (status, err) = json_of(
        http.post(format!("{base}/v1/depth?calibration_id={c0}&tilt_axis_deg=90"))
            .multipart(frames_form(&left, &right))
            .send()
            .await
            .unwrap(),
    )
    .await;
    conflict(status, &err, "tilt_axis_deg 90", "axis 0 deg");
    let (status, r) = json_of(
        http.post(format!(
            "{base}/v1/depth?calibration_id={c90}&tilt_axis_deg=90&roi={}",
            discs::ROI_A.map(|v| v.to_string()).join(",")
        ))
        .multipart(frames_form(&left, &right))
        .send()
        .await
        .unwrap(),
    )
    .await;
    assert_eq!(status, 200, "the calibration's own axis: {r}");
    server.stop().await.unwrap();
}

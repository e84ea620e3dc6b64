//! Several objects per session over HTTP (issue #18): created with the
//! session, added, removed and named anew; every pair measures each object
//! and the height of each relative to each other; the objects survive a
//! restart. A real server on 127.0.0.1 port 0 with a SQLite file; a scene
//! of three discs at different heights (A: 6 px of disparity, B: 2.5 px,
//! C: 4 px).

use crate::discs;

use crate::server::{frames_form, json_of, test_config, TestServer};
use semdepth_core::imageio::GrayFrame;
use serde_json::{json, Value};

/// A third, smaller disc below B, and a box around it.
const DISC_C: [f64; 3] = [232.0, 196.0, 16.0];
const ROI_C: [i64; 4] = [206, 172, 52, 50];

/// Pair `k`: the discs moved by 1.5 px in x per pair.
fn pair(k: usize) -> (GrayFrame, GrayFrame) {
    let m = 1.5 * k as f64;
    let at = |d: [f64; 3], shift: f64| [d[0] + m + shift, d[1], d[2]];
    let (w, h) = (discs::WIDTH, discs::HEIGHT);
    (
        discs::discs_frame(
            w,
            h,
            &[at(discs::DISC_A, 0.0), at(discs::DISC_B, 0.0), at(DISC_C, 0.0)],
        ),
        discs::discs_frame(
            w,
            h,
            &[at(discs::DISC_A, 6.0), at(discs::DISC_B, 2.5), at(DISC_C, 4.0)],
        ),
    )
}

/// Pair `k` posted to the session: the status and the body.
async fn post_pair(http: &reqwest::Client, base: &str, sid: &str, k: usize) -> (u16, Value) {
    let (left, right) = pair(k);
    json_of(
        http.post(format!("{base}/v1/sessions/{sid}/frames"))
            .multipart(frames_form(&left, &right))
            .send()
            .await
            .unwrap(),
    )
    .await
}

async fn upload(http: &reqwest::Client, base: &str, sid: &str, k: usize) -> Value {
    let (status, r) = post_pair(http, base, sid, k).await;
    assert_eq!(status, 200, "{r}");
    r
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

/// The object `name` of a result, with its status and disparity checked.
fn object<'a>(r: &'a Value, name: &str, status: &str, disparity: f64) -> &'a Value {
    let o = r["objects"]
        .as_array()
        .unwrap()
        .iter()
        .find(|o| o["name"] == name)
        .unwrap_or_else(|| panic!("no object {name}: {r}"));
    assert_eq!(o["status"], status, "{name}: {o}");
    assert!(
        (f(&o["disparity_axis_px"]) - disparity).abs() < 0.3,
        "{name}: {o}"
    );
    o
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sessions_measure_several_objects_and_the_heights_between_them() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("db.sqlite3");
    let server = TestServer::start(test_config(&db)).await;
    let (http, base) = (reqwest::Client::new(), server.base.clone());
    let (_, cal) = json_of(
        http.post(format!("{base}/v1/calibrations"))
            .json(&json!({"model": "geometric", "pixel_size_um": 0.5, "vergence_deg": 6.0}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    let um_per_px = 0.5 / (2.0 * 3f64.to_radians().sin());
    let (status, s) = json_of(
        http.post(format!("{base}/v1/sessions"))
            .json(&json!({"calibration_id": cal["id"], "objects": [
                {"name": "high", "roi": discs::ROI_A},
                {"name": "low", "point": [235, 110], "polarity": "brighter"}
            ]}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 201, "{s}");
    let sid = s["id"].as_str().unwrap().to_string();
    let names: Vec<&str> = s["objects"]
        .as_array()
        .unwrap()
        .iter()
        .map(|o| o["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["high", "low"]);
    assert_eq!(s["objects"][1]["point"], json!([235.0, 110.0]));

    for k in 0..3 {
        let r = upload(&http, &base, &sid, k).await;
        let status = if k == 0 { "initialised" } else { "tracked" };
        let high = object(&r, "high", status, 6.0);
        let low = object(&r, "low", status, 2.5);
        let m = 1.5 * k as f64;
        assert!(discs::distance(&high["left"]["centroid"], discs::DISC_A[0] + m, discs::DISC_A[1]) < 1.0);
        assert!(discs::distance(&low["left"]["centroid"], discs::DISC_B[0] + m, discs::DISC_B[1]) < 1.0);
        // The first object's fields stay at the top level.
        assert_eq!(r["disparity_axis_px"], high["disparity_axis_px"]);
        let rel = &r["relative"][0];
        assert_eq!(
            (rel["from"].as_str(), rel["to"].as_str()),
            (Some("high"), Some("low")),
            "{r}"
        );
        let d = f(&rel["disparity_axis_px"]);
        assert!((d - 3.5).abs() < 0.3, "pair {k}: relative disparity {d}");
        assert!((f(&rel["dz_um"]) - d * um_per_px).abs() < 1e-6);
        let std = f(&rel["disparity_std_px"]);
        let expected = f(&high["disparity_std_px"]).hypot(f(&low["disparity_std_px"]));
        assert!((std - expected).abs() < 1e-9, "{std} against {expected}");
        assert!((f(&rel["dz_std_um"]) - std * um_per_px).abs() < 1e-6);
        assert_eq!(f(&r["relative"][1]["disparity_axis_px"]), -d);
    }

    // Object routes: the errors name what is wrong.
    let objects_url = format!("{base}/v1/sessions/{sid}/objects");
    for (body, status, code) in [
        (
            json!({"name": "high", "roi": discs::ROI_B}),
            409,
            "duplicate_object",
        ),
        (
            json!({"name": "no way", "roi": discs::ROI_B}),
            400,
            "invalid_object_name",
        ),
        (json!({"name": "tiny", "roi": [0, 0, 4, 4]}), 422, "invalid_hint"),
        (json!({"name": "x", "size": 3}), 400, "invalid_json"),
    ] {
        let (got, err) = json_of(http.post(&objects_url).json(&body).send().await.unwrap()).await;
        assert_eq!(
            (got, err["error"]["code"].as_str()),
            (status, Some(code)),
            "{body}: {err}"
        );
    }
    let (got, err) = json_of(http.delete(format!("{objects_url}/nope")).send().await.unwrap()).await;
    assert_eq!(
        (got, err["error"]["code"].as_str()),
        (404, Some("object_not_found")),
        "{err}"
    );
    // Hints name one object: not the session's.
    let (got, err) = json_of(
        http.post(format!("{base}/v1/sessions/{sid}/reinit"))
            .json(&json!({"init": {"roi": discs::ROI_B}}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(
        (got, err["error"]["code"].as_str()),
        (409, Some("several_objects")),
        "{err}"
    );
    let (got, _) = json_of(
        http.patch(format!("{base}/v1/sessions/{sid}"))
            .json(&json!({"init": {"roi": discs::ROI_B}}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(got, 409);

    // A third object whose box names the disc "low" follows is refused on
    // the pair it would initialise on (issue #65), naming both; the pair is
    // not counted and the others keep their state.
    let (got, s) = json_of(
        http.post(&objects_url)
            .json(&json!({"name": "twin", "roi": discs::ROI_B}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(got, 201, "{s}");
    let (got, err) = post_pair(&http, &base, &sid, 3).await;
    assert_eq!(got, 422, "{err}");
    assert_eq!(err["error"]["code"], "objects_share_a_region", "{err}");
    let m = err["error"]["message"].as_str().unwrap();
    assert!(m.contains("\"twin\"") && m.contains("\"low\""), "{m}");
    let (got, s) = json_of(http.delete(format!("{objects_url}/twin")).send().await.unwrap()).await;
    assert_eq!((got, s["frames"].as_u64()), (200, Some(3)), "{s}");

    // A third object, added mid-session: initialised on the next pair while
    // the others go on; six relative entries.
    let (got, s) = json_of(
        http.post(&objects_url)
            .json(&json!({"name": "again", "roi": ROI_C}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(got, 201, "{s}");
    assert_eq!(s["objects"][2]["state"], "awaiting_first_pair");
    let r = upload(&http, &base, &sid, 3).await;
    object(&r, "high", "tracked", 6.0);
    object(&r, "again", "initialised", 4.0);
    assert_eq!(r["relative"].as_array().unwrap().len(), 6);
    let (got, s) = json_of(http.delete(format!("{objects_url}/again")).send().await.unwrap()).await;
    assert_eq!((got, s["objects"].as_array().unwrap().len()), (200, 2), "{s}");

    // Name "low" anew (on disc C): it initialises there, "high" goes on.
    let (got, s) = json_of(
        http.post(format!("{objects_url}/low/reinit"))
            .json(&json!({"init": {"roi": ROI_C}}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(got, 200, "{s}");
    assert_eq!(s["objects"][1]["roi"], json!(ROI_C));
    assert_eq!(s["objects"][1]["point"], Value::Null);
    let r = upload(&http, &base, &sid, 4).await;
    object(&r, "high", "tracked", 6.0);
    object(&r, "low", "initialised", 4.0);
    let r = upload(&http, &base, &sid, 5).await;
    object(&r, "low", "tracked", 4.0);

    // CSV: a row per object and per ordered pair of objects.
    let text = http
        .get(format!("{base}/v1/sessions/{sid}/results?format=csv"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert!(
        lines[0].starts_with("frame,name,object,relative_to,status"),
        "{}",
        lines[0]
    );
    // Pairs 0-2, 4, 5: 2 objects + 2 relative rows; pair 3: 3 + 6.
    assert_eq!(lines.len(), 1 + 5 * 4 + 9, "{text}");

    // The objects and their trackers survive a restart.
    server.stop().await.unwrap();
    let server = TestServer::start(test_config(&db)).await;
    let base = server.base.clone();
    let r = upload(&http, &base, &sid, 6).await;
    object(&r, "high", "tracked", 6.0);
    object(&r, "low", "tracked", 4.0);
    assert_eq!(r["frame"], 6);
    // The last object cannot go.
    let (got, _) = json_of(
        http.delete(format!("{base}/v1/sessions/{sid}/objects/low"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(got, 200);
    let (got, err) = json_of(
        http.delete(format!("{base}/v1/sessions/{sid}/objects/high"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(
        (got, err["error"]["code"].as_str()),
        (409, Some("object_count")),
        "{err}"
    );
    server.stop().await.unwrap();
}

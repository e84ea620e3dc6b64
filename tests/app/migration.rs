//! A database written by the release before objects opens with today's
//! code (issue #18): its calibration is intact, its sessions continue as
//! one-object sessions with their parameters and results, and the next pair
//! is tracked from where the stored tracker stood. The fixture and how it
//! was made: `tests/fixtures/v1_database/README.md`.

use std::path::PathBuf;

use crate::server::{test_config, TestServer};
use serde_json::{json, Value};

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/v1_database")
        .join(name)
}

async fn get(http: &reqwest::Client, url: String) -> Value {
    let r = http.get(&url).send().await.unwrap();
    assert_eq!(r.status(), 200, "{url}");
    r.json().await.unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_database_of_the_previous_release_continues() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("v1.sqlite3");
    std::fs::copy(fixture("v1.sqlite3"), &db).unwrap();
    let ids = std::fs::read_to_string(fixture("ids.txt")).unwrap();
    let [cal, tracked, waiting]: [&str; 3] = ids.split_whitespace().collect::<Vec<_>>().try_into().unwrap();
    let before: Value =
        serde_json::from_str(&std::fs::read_to_string(fixture("results_v1.json")).unwrap()).unwrap();
    let truth: Value =
        serde_json::from_str(&std::fs::read_to_string(fixture("truth.json")).unwrap()).unwrap();

    let server = TestServer::start(test_config(&db)).await;
    let (http, base) = (reqwest::Client::new(), server.base.clone());

    // The calibration as it was.
    let c = get(&http, format!("{base}/v1/calibrations/{cal}")).await;
    assert_eq!(
        (c["name"].clone(), c["version"].clone()),
        (json!("lin"), json!(1)),
        "{c}"
    );
    assert_eq!(c["samples"].as_array().unwrap().len(), 3);
    let coefficients: Vec<f64> = c["coefficients"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert!(
        (coefficients[0] - 7.0 / 6.0).abs() < 1e-9 && (coefficients[1] - 2.0).abs() < 1e-9,
        "{c}"
    );

    // The sessions, as one-object sessions with their parameters.
    let s = get(&http, format!("{base}/v1/sessions/{tracked}")).await;
    assert_eq!(s["name"], "tracked");
    assert_eq!(s["state"], "tracking");
    assert_eq!(s["frames"], 3);
    assert_eq!(s["keep"], true);
    assert_eq!(s["calibration_id"], cal);
    assert_eq!(s["tracker"]["max_disparity_px"], 48.0);
    assert_eq!(s["init"]["polarity"], "brighter");
    let objects = s["objects"].as_array().unwrap();
    assert_eq!(objects.len(), 1, "{s}");
    assert_eq!(
        (objects[0]["name"].as_str(), objects[0]["state"].as_str()),
        (Some("object"), Some("tracking"))
    );
    let w = get(&http, format!("{base}/v1/sessions/{waiting}")).await;
    assert_eq!(w["state"], "awaiting_first_pair");
    assert_eq!(w["objects"][0]["roi"], json!([10, 10, 200, 200]));
    assert_eq!(w["objects"][0]["state"], "awaiting_first_pair");

    // Its results as they were stored.
    let after = get(
        &http,
        format!("{base}/v1/sessions/{tracked}/results?contours=false"),
    )
    .await;
    let (b, a) = (
        before["results"].as_array().unwrap(),
        after["results"].as_array().unwrap(),
    );
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(b) {
        for key in ["frame", "status", "disparity_axis_px", "z_um", "disparity_std_px"] {
            assert_eq!(x[key], y[key], "{key}");
        }
    }

    // The next pair continues from the stored tracker: tracked, frame 3,
    // on the truth (the earlier pairs were within 0.07 px of it).
    let form = reqwest::multipart::Form::new()
        .part(
            "left",
            reqwest::multipart::Part::bytes(std::fs::read(fixture("0003_left.png")).unwrap())
                .file_name("l.png"),
        )
        .part(
            "right",
            reqwest::multipart::Part::bytes(std::fs::read(fixture("0003_right.png")).unwrap())
                .file_name("r.png"),
        );
    let r = http
        .post(format!("{base}/v1/sessions/{tracked}/frames"))
        .multipart(form)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    let r: Value = r.json().await.unwrap();
    assert_eq!(
        (r["frame"].clone(), r["status"].clone()),
        (json!(3), json!("tracked")),
        "{r}"
    );
    let d = r["disparity_axis_px"].as_f64().unwrap();
    let expected = truth["frames"][3]["disparity_px"][0].as_f64().unwrap();
    assert!(
        (d - expected).abs() < 0.2,
        "disparity {d:.3} px, truth {expected:.3}"
    );
    let z = r["z_um"].as_f64().unwrap();
    assert!(
        (z - (coefficients[0] + coefficients[1] * d)).abs() < 1e-6,
        "z {z}"
    );
    // A session of one unnamed object answers as before objects.
    assert!(r.get("objects").is_none() && r.get("relative").is_none(), "{r}");

    // Stored in today's form, it opens again.
    server.stop().await.unwrap();
    let server = TestServer::start(test_config(&db)).await;
    let s = get(&http, format!("{}/v1/sessions/{tracked}", server.base)).await;
    assert_eq!(
        (s["frames"].clone(), s["state"].clone()),
        (json!(4), json!("tracking"))
    );
    server.stop().await.unwrap();
}

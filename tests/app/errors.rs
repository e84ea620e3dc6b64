//! Every bad input gets a 4xx with a JSON body naming the problem (issue #4,
//! "Security and limits"), and the server keeps working afterwards.

use crate::discs;

use crate::server::{
    frames_form, get_json, new_session, pair_form, png, synth_pairs, test_config, upload, TestServer,
};
use reqwest::multipart::{Form, Part};
use semdepth_core::synth::{Preset, Shape};
use serde_json::{json, Value};

/// Checks status and error code, and that the message is not empty.
async fn expect_error(r: reqwest::Response, status: u16, code: &str) -> String {
    let got = r.status().as_u16();
    let text = r.text().await.unwrap();
    let body: Value =
        serde_json::from_str(&text).unwrap_or_else(|e| panic!("error body is not JSON ({e}): {text:?}"));
    assert_eq!(
        (got, body["error"]["code"].as_str()),
        (status, Some(code)),
        "{body}"
    );
    let message = body["error"]["message"].as_str().unwrap().to_string();
    assert!(!message.is_empty());
    message
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_inputs_get_clear_4xx_errors() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = test_config(&dir.path().join("db.sqlite3"));
    config.max_sessions = 3;
    config.max_body_bytes = 8 * 1024 * 1024;
    let server = TestServer::start(config).await;
    // A pooled client, as lab scripts use: a request refused before its body
    // is read ends its connection, and the server says so (below), so the
    // pool does not reuse it.
    let http = reqwest::Client::new();
    let base = &server.base;
    let sid = new_session(base).await;
    let frames = format!("{base}/v1/sessions/{sid}/frames");
    let pairs = synth_pairs(Preset::Clean, Shape::Blob, 1, 1);
    let left = png(&pairs[0].left);

    // An upload refused before its body is read closes its connection, and
    // the answer says so.
    let r = http
        .post(format!("{base}/v1/sessions/s_missing/frames"))
        .multipart(pair_form(&pairs[0]))
        .send()
        .await
        .unwrap();
    assert_eq!(
        r.headers().get("connection").map(|v| v.to_str().unwrap()),
        Some("close")
    );
    expect_error(r, 404, "session_not_found").await;

    // Unknown ids and routes.
    expect_error(
        http.get(format!("{base}/v1/sessions/s_missing"))
            .send()
            .await
            .unwrap(),
        404,
        "session_not_found",
    )
    .await;
    expect_error(
        http.post(format!("{base}/v1/sessions/s_missing/frames"))
            .multipart(pair_form(&pairs[0]))
            .send()
            .await
            .unwrap(),
        404,
        "session_not_found",
    )
    .await;
    expect_error(
        http.get(format!("{base}/v1/calibrations/c_missing"))
            .send()
            .await
            .unwrap(),
        404,
        "calibration_not_found",
    )
    .await;
    expect_error(
        http.get(format!("{base}/v2/nothing")).send().await.unwrap(),
        404,
        "route_not_found",
    )
    .await;
    expect_error(
        http.put(format!("{base}/v1/sessions")).send().await.unwrap(),
        405,
        "method_not_allowed",
    )
    .await;

    // JSON: malformed, unknown field (named), wrong content type, bad values.
    expect_error(
        http.post(format!("{base}/v1/sessions"))
            .header("content-type", "application/json")
            .body("{\"name\": ")
            .send()
            .await
            .unwrap(),
        400,
        "invalid_json",
    )
    .await;
    let m = expect_error(
        http.post(format!("{base}/v1/sessions"))
            .json(&json!({"nmae": "typo"}))
            .send()
            .await
            .unwrap(),
        400,
        "invalid_json",
    )
    .await;
    assert!(m.contains("nmae"), "{m}");
    let m = expect_error(
        http.post(format!("{base}/v1/sessions"))
            .json(&json!({"tracker": {"max_disparity": 3}}))
            .send()
            .await
            .unwrap(),
        400,
        "invalid_json",
    )
    .await;
    assert!(m.contains("max_disparity"), "{m}");
    expect_error(
        http.post(format!("{base}/v1/sessions"))
            .body("{}")
            .send()
            .await
            .unwrap(),
        415,
        "unsupported_media_type",
    )
    .await;
    let m = expect_error(
        http.post(format!("{base}/v1/sessions"))
            .json(&json!({"tracker": {"max_disparity_px": -5.0}}))
            .send()
            .await
            .unwrap(),
        400,
        "invalid_parameter",
    )
    .await;
    assert!(m.contains("max_disparity_px"), "{m}");
    expect_error(
        http.post(format!("{base}/v1/sessions"))
            .json(&json!({"calibration_id": "c_missing"}))
            .send()
            .await
            .unwrap(),
        404,
        "calibration_not_found",
    )
    .await;
    expect_error(
        http.post(format!("{base}/v1/calibrations"))
            .json(&json!({"model": "magic"}))
            .send()
            .await
            .unwrap(),
        400,
        "invalid_json",
    )
    .await;
    expect_error(
        http.post(format!("{base}/v1/calibrations"))
            .json(&json!({"model": "geometric", "pixel_size_um": -1.0, "vergence_deg": 6.0}))
            .send()
            .await
            .unwrap(),
        422,
        "invalid_calibration",
    )
    .await;

    // A fit with too few distinct samples is created pending: no
    // coefficients, and it says why (its sessions get z null with a
    // warning until samples at another height are added).
    let r = http
        .post(format!("{base}/v1/calibrations"))
        .json(&json!({"model": "fit", "degree": 1, "samples": [{"disparity_px": 1.0, "z_um": 0.0}, {"disparity_px": 1.0, "z_um": 5.0}]}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 201);
    let body: Value = r.json().await.unwrap();
    assert!(body["pending"].as_str().unwrap().contains("distinct"), "{body}");
    assert_eq!(body["coefficients"], json!([]), "{body}");
    assert!(body.get("residuals_um").is_none(), "no fit, no residuals: {body}");
    let past = http
        .get(format!(
            "{base}/v1/calibrations/{}/versions/9223372036854775808",
            body["id"].as_str().unwrap()
        ))
        .send()
        .await
        .unwrap();
    assert_eq!(past.status(), 404, "a version past the last is not found");
    // A sample's frame beyond what storage holds is refused.
    let r = http
        .post(format!("{base}/v1/calibrations"))
        .json(&json!({"model": "fit", "samples": [{"disparity_px": 0.0, "z_um": 0.0, "frame": 9223372036854775808u64}]}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 422);
    let filled: Value = http
        .post(format!(
            "{base}/v1/calibrations/{}/samples",
            body["id"].as_str().unwrap()
        ))
        .json(&json!({"disparity_px": 2.0, "z_um": 10.0}))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert!(filled.get("pending").is_none(), "{filled}");
    assert_eq!(filled["coefficients"].as_array().unwrap().len(), 2, "{filled}");

    // Multipart: wrong content type, missing part, extra part, undecodable
    // image, mismatched sizes.
    expect_error(
        http.post(&frames).json(&json!({})).send().await.unwrap(),
        415,
        "unsupported_media_type",
    )
    .await;
    let m = expect_error(
        http.post(&frames)
            .multipart(Form::new().part("left", Part::bytes(left.clone())))
            .send()
            .await
            .unwrap(),
        400,
        "missing_part",
    )
    .await;
    assert!(m.contains("right"), "{m}");
    expect_error(
        http.post(&frames)
            .multipart(pair_form(&pairs[0]).part("middle", Part::bytes(vec![1, 2, 3])))
            .send()
            .await
            .unwrap(),
        400,
        "unexpected_part",
    )
    .await;
    let m = expect_error(
        http.post(&frames)
            .multipart(
                Form::new()
                    .part("left", Part::bytes(left.clone()))
                    .part("right", Part::bytes(b"not an image".to_vec())),
            )
            .send()
            .await
            .unwrap(),
        400,
        "unknown_image_format",
    )
    .await;
    assert!(m.starts_with("right image"), "{m}");
    let small = png(&semdepth_core::imageio::GrayFrame::filled(64, 48, 8, 100));
    expect_error(
        http.post(&frames)
            .multipart(
                Form::new()
                    .part("left", Part::bytes(left.clone()))
                    .part("right", Part::bytes(small)),
            )
            .send()
            .await
            .unwrap(),
        400,
        "pair_size_mismatch",
    )
    .await;
    // None of that counted as a pair.
    let s: Value = http
        .get(format!("{base}/v1/sessions/{sid}"))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert_eq!(s["frames"], 0);

    // A body over the limit (8 MiB here) is refused with 413, whether its
    // length is declared or it arrives chunked.
    let path = format!("/v1/sessions/{sid}/frames");
    let reply = raw_upload(server.addr, &path, Some(9 << 20), &[]).await;
    assert!(
        reply.starts_with("HTTP/1.1 413") && reply.contains("body_too_large"),
        "{reply}"
    );
    let reply = raw_upload(server.addr, &path, None, &vec![0u8; 9 << 20]).await;
    assert!(
        reply.starts_with("HTTP/1.1 413") && reply.contains("body_too_large"),
        "{reply}"
    );

    // Samples from a session without a disparity yet.
    let cal: Value = http
        .post(format!("{base}/v1/calibrations"))
        .json(&json!({"model": "fit", "samples": [{"disparity_px": 0.0, "z_um": 0.0}, {"disparity_px": 1.0, "z_um": 1.0}]}))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    expect_error(
        http.post(format!("{base}/v1/sessions/{sid}/calibration-samples"))
            .json(&json!({"calibration_id": cal["id"], "z_um": 3.0}))
            .send()
            .await
            .unwrap(),
        409,
        "no_disparity_yet",
    )
    .await;

    // Bad queries.
    for query in ["format=xml", "since=-1", "limit=0"] {
        let r = http
            .get(format!("{base}/v1/sessions/{sid}/results?{query}"))
            .send()
            .await
            .unwrap();
        expect_error(r, 400, "invalid_query").await;
    }

    // The session limit (3 here).
    for _ in 0..2 {
        assert_eq!(
            http.post(format!("{base}/v1/sessions"))
                .json(&json!({}))
                .send()
                .await
                .unwrap()
                .status(),
            201
        );
    }
    expect_error(
        http.post(format!("{base}/v1/sessions"))
            .json(&json!({}))
            .send()
            .await
            .unwrap(),
        409,
        "session_limit_reached",
    )
    .await;

    // After all that the session still works.
    let r = upload(&http, base, &sid, &pairs[0]).await;
    assert_eq!(r["status"], "initialised", "{r}");
    server.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_gigabyte_body_is_refused_without_reading_it() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("db.sqlite3"))).await;
    let sid = new_session(&server.base).await;
    // Declare 1 GiB: the server must answer 413 from the declared length
    // without waiting for (or buffering) the body.
    let path = format!("/v1/sessions/{sid}/frames");
    let reply = raw_upload(server.addr, &path, Some(1 << 30), &[0u8; 4096]).await;
    assert!(reply.starts_with("HTTP/1.1 413"), "{reply}");
    assert!(reply.contains("body_too_large"), "{reply}");
    server.stop().await.unwrap();
}

/// Sends a multipart upload by hand: with `declared` a Content-Length
/// header (and only `body` of it), else chunked transfer of `body`. Write
/// errors are ignored (the server may answer and close early); returns what
/// the server answered.
async fn raw_upload(addr: std::net::SocketAddr, path: &str, declared: Option<u64>, body: &[u8]) -> String {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let mut stream = tokio::net::TcpStream::connect(addr).await.unwrap();
    let length = match declared {
        Some(n) => format!("Content-Length: {n}"),
        None => "Transfer-Encoding: chunked".to_string(),
    };
    let head = format!("POST {path} HTTP/1.1\r\nHost: x\r\nContent-Type: multipart/form-data; boundary=XX\r\n{length}\r\n\r\n");
    let _ = stream.write_all(head.as_bytes()).await;
    let prefix = b"--XX\r\nContent-Disposition: form-data; name=\"left\"\r\n\r\n";
    match declared {
        Some(_) => {
            let _ = stream.write_all(prefix).await;
            let _ = stream.write_all(body).await;
        }
        None => {
            let mut chunks = vec![prefix.to_vec()];
            chunks.extend(body.chunks(1 << 16).map(|c| c.to_vec()));
            for c in chunks {
                let framed = [format!("{:x}\r\n", c.len()).into_bytes(), c, b"\r\n".to_vec()].concat();
                if stream.write_all(&framed).await.is_err() {
                    break;
                }
            }
        }
    }
    let mut reply = Vec::new();
    let mut buf = vec![0u8; 8192];
    loop {
        match tokio::time::timeout(std::time::Duration::from_secs(20), stream.read(&mut buf)).await {
            Ok(Ok(0)) | Ok(Err(_)) => break,
            Ok(Ok(n)) => {
                reply.extend_from_slice(&buf[..n]);
                if String::from_utf8_lossy(&reply).contains("}}") {
                    break;
                }
            }
            Err(_) => panic!(
                "no answer within 20 s; got so far: {}",
                String::from_utf8_lossy(&reply)
            ),
        }
    }
    String::from_utf8_lossy(&reply).into_owned()
}

/// Asserts an error and that its message mentions each of `needles`.
async fn expect_error_naming(r: reqwest::Response, status: u16, code: &str, needles: &[&str]) {
    let m = expect_error(r, status, code).await;
    for needle in needles {
        assert!(m.contains(needle), "message should mention {needle:?}: {m}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_hints_get_4xx_naming_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("db.sqlite3"))).await;
    let http = reqwest::Client::new();
    let base = &server.base;
    let create = |init: Value| {
        http.post(format!("{base}/v1/sessions"))
            .json(&json!({"init": init}))
            .send()
    };

    // Hints out of range, at creation: 422 invalid_hint naming the field.
    let r = create(json!({"roi": [200, 75, 8, 70]})).await.unwrap();
    expect_error_naming(r, 422, "invalid_hint", &["init.roi", "8x70", ">= 16"]).await;
    let r = create(json!({"point": [1e300, 5.0]})).await.unwrap();
    expect_error_naming(r, 422, "invalid_hint", &["init.point", "finite"]).await;
    let bow_tie = json!([[0, 0], [40, 40], [40, 0], [0, 40]]);
    let r = create(json!({"outline": bow_tie})).await.unwrap();
    expect_error_naming(r, 422, "invalid_hint", &["init.outline", "crosses itself"]).await;
    let r = create(json!({"outline": [[0, 0], [10, 0]]})).await.unwrap();
    expect_error_naming(
        r,
        422,
        "invalid_hint",
        &["init.outline", "2 vertices", "3..=4096"],
    )
    .await;
    let r = create(json!({"exclude": vec![[1.0, 1.0]; 65]})).await.unwrap();
    expect_error_naming(r, 422, "invalid_hint", &["init.exclude", "65 points"]).await;
    let r = create(json!({"outline": [[0, 0], [10, 0], [5]]})).await.unwrap();
    expect_error_naming(r, 400, "invalid_json", &["init.outline"]).await;
    let r = http
        .post(format!("{base}/v1/sessions"))
        .json(&json!({"tracker": {"init": {"roi": [0, 0, 4, 4]}}}))
        .send()
        .await
        .unwrap();
    expect_error_naming(r, 422, "invalid_hint", &["init.roi"]).await;
    // Hints that are not JSON of the right shape: 400 invalid_json naming
    // the field (and for the polarity the allowed values).
    let r = create(json!({"polarity": "up"})).await.unwrap();
    expect_error_naming(
        r,
        400,
        "invalid_json",
        &["init.polarity", "`up`", "brighter", "darker", "any"],
    )
    .await;
    let r = create(json!({"point": [5.0, null]})).await.unwrap();
    expect_error_naming(r, 400, "invalid_json", &["init.point"]).await;
    let r = create(json!({"point": [5.0]})).await.unwrap();
    expect_error_naming(r, 400, "invalid_json", &["init.point"]).await;
    let r = create(json!({"roi": [1, 2, 30]})).await.unwrap();
    expect_error_naming(r, 400, "invalid_json", &["init.roi"]).await;
    // None of that made a session.
    let list: Value = http
        .get(format!("{base}/v1/sessions"))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert_eq!(list["sessions"], json!([]));

    // PATCH and reinit refuse the same, and change nothing.
    let sid = new_session(base).await;
    let r = http
        .patch(format!("{base}/v1/sessions/{sid}"))
        .json(&json!({"init": {"roi": [0, 0, 15, 100]}}))
        .send()
        .await
        .unwrap();
    expect_error_naming(r, 422, "invalid_hint", &["init.roi", "15x100"]).await;
    let reinit = |body: Value| {
        http.post(format!("{base}/v1/sessions/{sid}/reinit"))
            .json(&body)
            .send()
    };
    let r = reinit(json!({"init": {"roi": [10, 10, 100, 0]}})).await.unwrap();
    expect_error_naming(r, 422, "invalid_hint", &["init.roi", "100x0"]).await;
    let r = reinit(json!({"init": {"polarity": "sideways"}})).await.unwrap();
    expect_error_naming(r, 400, "invalid_json", &["init.polarity", "brighter"]).await;
    let r = reinit(json!({"init": {"point": ["a", 3]}})).await.unwrap();
    expect_error_naming(r, 400, "invalid_json", &["init.point"]).await;
    let r = reinit(json!({"roi": [10, 10, 100, 100]})).await.unwrap();
    expect_error_naming(r, 400, "invalid_json", &["unknown field", "roi"]).await;
    let r = reinit(json!({"init": {"working_max_side": 10}})).await.unwrap();
    expect_error_naming(r, 400, "invalid_parameter", &["working_max_side"]).await;
    let r = http
        .post(format!("{base}/v1/sessions/s_missing/reinit"))
        .json(&json!({}))
        .send()
        .await
        .unwrap();
    expect_error(r, 404, "session_not_found").await;
    let s: Value = http
        .get(format!("{base}/v1/sessions/{sid}"))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert_eq!(
        (
            s["init"]["roi"].clone(),
            s["init"]["working_max_side"].clone(),
            s["updated_at"].clone()
        ),
        (Value::Null, json!(640), s["created_at"].clone()),
        "{s}"
    );

    // Hints that do not fit the uploaded images: 422 at upload, the pair
    // not counted and nothing stored.
    let (left, right) = discs::scene_pair([0.0, 0.0]);
    let upload_scene = |sid: String| {
        http.post(format!("{base}/v1/sessions/{sid}/frames"))
            .multipart(frames_form(&left, &right))
            .send()
    };
    for (hints, needles) in [
        (
            json!({"roi": [1000, 1000, 50, 50]}),
            ["init.roi", "outside the 320x240 image"],
        ),
        (
            json!({"roi": [-100, 20, 90, 90]}),
            ["init.roi", "outside the 320x240 image"],
        ),
        (
            json!({"point": [10.0, 250.0]}),
            ["init.point", "outside the 320x240 image"],
        ),
        (
            json!({"roi": discs::ROI_A, "point": [235.0, 110.0]}),
            ["init.point", "outside the roi"],
        ),
    ] {
        let r = create(hints.clone()).await.unwrap();
        assert_eq!(
            r.status(),
            201,
            "{hints}: the hints are checked against the images at upload"
        );
        let bad: Value = r.json().await.unwrap();
        let bad_sid = bad["id"].as_str().unwrap().to_string();
        for _ in 0..2 {
            let r = upload_scene(bad_sid.clone()).await.unwrap();
            expect_error_naming(r, 422, "invalid_hint", &needles).await;
        }
        let s: Value = http
            .get(format!("{base}/v1/sessions/{bad_sid}"))
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        assert_eq!(
            (s["frames"].as_u64(), s["state"].as_str()),
            (Some(0), Some("awaiting_first_pair")),
            "{hints}: {s}"
        );
        let page: Value = http
            .get(format!("{base}/v1/sessions/{bad_sid}/results"))
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        assert_eq!(page["results"], json!([]), "{hints}");
        // New hints that fit: the next pair is frame 0.
        let r = http
            .post(format!("{base}/v1/sessions/{bad_sid}/reinit"))
            .json(&json!({"init": {"roi": discs::ROI_B}}))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 200);
        let r: Value = upload_scene(bad_sid.clone()).await.unwrap().json().await.unwrap();
        assert_eq!(
            (r["frame"].as_u64(), r["status"].as_str()),
            (Some(0), Some("initialised")),
            "{r}"
        );
        let d = discs::distance(&r["left"]["centroid"], discs::DISC_B[0], discs::DISC_B[1]);
        assert!(
            d < 1.0,
            "{hints}: after the reinit, left centroid {d:.2} px off B"
        );
        http.delete(format!("{base}/v1/sessions/{bad_sid}"))
            .send()
            .await
            .unwrap();
    }

    // The one-shot's query hints: 400 when they do not parse, 422 when out
    // of range or outside the image.
    let depth = |query: &str| {
        http.post(format!("{base}/v1/depth?{query}"))
            .multipart(frames_form(&left, &right))
            .send()
    };
    for (query, status, code, needles) in [
        ("roi=1,2,30", 400, "invalid_query", &["roi", "four integers"][..]),
        ("roi=a,b,c,d", 400, "invalid_query", &["roi"][..]),
        ("point=5", 400, "invalid_query", &["point", "two numbers"][..]),
        (
            "polarity=up",
            400,
            "invalid_query",
            &["polarity", "\"up\"", "brighter, darker or any"][..],
        ),
        ("roi=0,0,8,8", 422, "invalid_hint", &["init.roi", ">= 16"][..]),
        ("point=nan,5", 422, "invalid_hint", &["init.point", "finite"][..]),
        (
            "roi=1000,1000,50,50",
            422,
            "invalid_hint",
            &["init.roi", "outside the 320x240 image"][..],
        ),
        (
            "point=10,250",
            422,
            "invalid_hint",
            &["init.point", "outside the 320x240 image"][..],
        ),
    ] {
        let r = depth(query).await.unwrap();
        expect_error_naming(r, status, code, needles).await;
    }
    server.stop().await.unwrap();
}

/// Issue #21: an image too thin to find an object in (its working copy,
/// 640 px on the longer side, would be under 8 px on the shorter) is a 400
/// `image_too_small` naming both sizes, not a `lost` pair with an internal
/// reason; the pair is not counted, and a pair of a usable size then works.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn images_too_thin_to_track_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("db.sqlite3"))).await;
    let http = reqwest::Client::new();
    let base = &server.base;
    let sid = new_session(base).await;
    let frames = format!("{base}/v1/sessions/{sid}/frames");
    for (w, h, reduced) in [(8000u32, 8u32, "615x0"), (8, 8000, "0x615"), (2000, 32, "500x8")] {
        let thin = semdepth_core::imageio::GrayFrame::new(w, h, 8, vec![90; (w * h) as usize]).unwrap();
        let r = http
            .post(&frames)
            .multipart(frames_form(&thin, &thin))
            .send()
            .await
            .unwrap();
        if reduced == "500x8" {
            // 8 px after the reduction is enough: the pair is processed.
            assert_eq!(r.status(), 200, "{w}x{h}: {}", r.text().await.unwrap());
            continue;
        }
        expect_error_naming(
            r,
            400,
            "image_too_small",
            &[&format!("{w}x{h}"), reduced, "too thin"],
        )
        .await;
    }
    let s = get_json(&format!("{base}/v1/sessions/{sid}")).await;
    assert_eq!(s["frames"].as_u64(), Some(1), "only the usable pair counted: {s}");
}

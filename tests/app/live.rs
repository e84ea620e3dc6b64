//! Issue #19, server side, over real sockets: the page and its files at `/`,
//! each session's latest pair as PNG (shrunk, with the contour drawn), the
//! server-sent result events, and the memory budget of the live frames.
//! The page itself is tested in a real browser by tests/browser/.

use crate::server;

use std::time::Duration;

use crate::server::{new_session, synth_pairs, test_config, upload, TestServer};
use semdepth_core::synth::{Preset, Shape};
use serde_json::Value;

async fn get(http: &reqwest::Client, url: &str) -> reqwest::Response {
    http.get(url).send().await.unwrap()
}

async fn error_code(r: reqwest::Response) -> (u16, String, String) {
    let status = r.status().as_u16();
    let body: Value = r.json().await.unwrap();
    (
        status,
        body["error"]["code"].as_str().unwrap().to_string(),
        body["error"]["message"].as_str().unwrap().to_string(),
    )
}

fn decode_png(bytes: &[u8]) -> image::DynamicImage {
    image::load_from_memory_with_format(bytes, image::ImageFormat::Png).expect("a PNG")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_latest_pair_is_served_as_png_with_its_contour() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("db.sqlite3"))).await;
    let (http, base) = (reqwest::Client::new(), server.base.clone());
    let sid = new_session(&base).await;
    let latest = |side: &str, query: &str| format!("{base}/v1/sessions/{sid}/frames/latest/{side}{query}");

    // Unknown session, and no pair yet: 404 with a JSON error naming why.
    let (status, code, _) =
        error_code(get(&http, &format!("{base}/v1/sessions/s_nope/frames/latest/left")).await).await;
    assert_eq!((status, code.as_str()), (404, "session_not_found"));
    let (status, code, message) = error_code(get(&http, &latest("left", "")).await).await;
    assert_eq!((status, code.as_str()), (404, "no_frame"));
    assert!(message.contains("none was processed"), "{message}");

    let pairs = synth_pairs(Preset::Clean, Shape::Sphere, 3, 2);
    let mut last = Value::Null;
    for pair in &pairs {
        last = upload(&http, &base, &sid, pair).await;
    }
    assert_eq!(last["status"], "tracked");

    // Full size, grey, the pair's own size; headers say which frame.
    let r = get(&http, &latest("left", "")).await;
    assert_eq!(r.status(), 200);
    assert_eq!(r.headers()["content-type"], "image/png");
    assert_eq!(r.headers()["x-frame"], "1");
    assert_eq!(r.headers()["x-frame-scale"], "1");
    let plain = decode_png(&r.bytes().await.unwrap());
    let (w, h) = (pairs[1].left.width, pairs[1].left.height);
    assert_eq!((plain.width(), plain.height()), (w, h));
    assert_eq!(plain.color(), image::ColorType::L8);
    // As acquired: 8-bit frames are not stretched.
    let left8 = pairs[1].left.to_gray8();
    assert_eq!(plain.to_luma8().as_raw(), left8.as_raw());

    // Shrunk, with the contour drawn in the tracked colour.
    let r = get(&http, &latest("left", "?max_side=320&overlay=true")).await;
    assert_eq!(r.status(), 200);
    let scale: f64 = r.headers()["x-frame-scale"].to_str().unwrap().parse().unwrap();
    let shown = decode_png(&r.bytes().await.unwrap()).to_rgb8();
    assert!(shown.width().max(shown.height()) <= 320);
    assert_eq!(scale, f64::from(w.max(h).div_ceil(320)));
    let colour = semdepth_core::display::PALETTE[0];
    let contour = last["left"]["contour"].as_array().unwrap();
    let on_contour = contour
        .iter()
        .filter(|p| {
            // Within a pixel of where the vertex lands in the shrunk image.
            let x = (p[0].as_f64().unwrap() - (scale - 1.0) / 2.0) / scale;
            let y = (p[1].as_f64().unwrap() - (scale - 1.0) / 2.0) / scale;
            (-1..=1).any(|dx| {
                (-1..=1).any(|dy| {
                    let (px, py) = ((x.round() as i64 + dx) as u32, (y.round() as i64 + dy) as u32);
                    px < shown.width() && py < shown.height() && shown.get_pixel(px, py).0 == colour
                })
            })
        })
        .count();
    assert!(
        on_contour * 10 >= contour.len() * 9,
        "only {on_contour} of {} contour vertices are drawn",
        contour.len()
    );
    // A line about 2 px wide along the contour, and nothing else.
    let coloured = shown.pixels().filter(|p| p.0 == colour).count() as f64;
    let at = |i: usize| {
        [
            contour[i % contour.len()][0].as_f64().unwrap(),
            contour[i % contour.len()][1].as_f64().unwrap(),
        ]
    };
    let perimeter: f64 = (0..contour.len())
        .map(|i| (at(i + 1)[0] - at(i)[0]).hypot(at(i + 1)[1] - at(i)[1]))
        .sum::<f64>()
        / scale;
    assert!(
        (1.5 * perimeter..4.0 * perimeter).contains(&coloured),
        "{coloured} coloured pixels along a contour {perimeter:.0} px long"
    );

    // The right image shows the right contour.
    let r = get(&http, &latest("right", "?overlay=true")).await;
    assert_eq!(r.status(), 200);
    let right = decode_png(&r.bytes().await.unwrap()).to_rgb8();
    let c = &last["right"]["centroid"];
    let first = &last["right"]["contour"][0];
    let (fx, fy) = (
        first[0].as_f64().unwrap().round() as i64,
        first[1].as_f64().unwrap().round() as i64,
    );
    let near =
        (-1..=1).any(|dx| (-1..=1).any(|dy| right.get_pixel((fx + dx) as u32, (fy + dy) as u32).0 == colour));
    assert!(near, "the right contour is drawn at its first vertex");
    let centre = right
        .get_pixel(c[0].as_f64().unwrap() as u32, c[1].as_f64().unwrap() as u32)
        .0;
    assert_eq!(centre[0], centre[1], "inside the contour is the image");

    // Bad queries and paths name the problem.
    let (status, code, message) = error_code(get(&http, &latest("left", "?max_side=4")).await).await;
    assert_eq!((status, code.as_str()), (400, "invalid_query"));
    assert!(message.contains("max_side 4 (expected 16..=16384)"), "{message}");
    let r = get(&http, &latest("middle", "")).await;
    assert_eq!(r.status(), 400);
    let (status, _, message) = error_code(get(&http, &latest("left", "?colour=red")).await).await;
    assert_eq!(status, 400);
    assert!(message.contains("colour"), "{message}");
    server.stop().await.unwrap();
}

/// Reads the event stream until `count` `result` events have come; returns
/// their data, parsed.
async fn read_events(response: &mut reqwest::Response, count: usize) -> Vec<Value> {
    let mut text = String::new();
    let mut events = Vec::new();
    while events.len() < count {
        let chunk = tokio::time::timeout(Duration::from_secs(30), response.chunk())
            .await
            .expect("an event within 30 s")
            .unwrap()
            .expect("the stream goes on");
        text.push_str(std::str::from_utf8(&chunk).unwrap());
        while let Some(end) = text.find("\n\n") {
            let block: String = text.drain(..end + 2).collect();
            if block.lines().any(|l| l == "event: result") {
                let data: String = block.lines().filter_map(|l| l.strip_prefix("data: ")).collect();
                events.push(serde_json::from_str(&data).unwrap());
            }
        }
    }
    events
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn result_events_follow_the_session_and_end_with_it() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("db.sqlite3"))).await;
    let (http, base) = (reqwest::Client::new(), server.base.clone());
    let sid = new_session(&base).await;
    let pairs = synth_pairs(Preset::Clean, Shape::Blob, 4, 6);
    let first = upload(&http, &base, &sid, &pairs[0]).await;

    let mut events = get(&http, &format!("{base}/v1/sessions/{sid}/events")).await;
    assert_eq!(events.status(), 200);
    assert_eq!(events.headers()["content-type"], "text/event-stream");
    // The latest result at once, contours included.
    let now = read_events(&mut events, 1).await;
    assert_eq!(now[0]["frame"], 0);
    assert_eq!(now[0]["left"]["contour"], first["left"]["contour"]);

    // Each newer result, in order; the last one always arrives.
    let mut answers = Vec::new();
    for pair in &pairs[1..] {
        answers.push(upload(&http, &base, &sid, pair).await);
    }
    let mut seen = Vec::new();
    while seen.last().map(|e: &Value| e["frame"].as_u64().unwrap()) != Some(5) {
        seen.extend(read_events(&mut events, 1).await);
    }
    let frames: Vec<u64> = seen.iter().map(|e| e["frame"].as_u64().unwrap()).collect();
    assert!(frames.windows(2).all(|w| w[0] < w[1]), "in order: {frames:?}");
    assert_eq!(
        seen.last().unwrap()["disparity_px"],
        answers.last().unwrap()["disparity_px"]
    );

    // Unknown session: 404; deleting the session ends its stream.
    let r = get(&http, &format!("{base}/v1/sessions/s_nope/events")).await;
    assert_eq!(r.status(), 404);
    let r = http
        .delete(format!("{base}/v1/sessions/{sid}"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 204);
    let end = tokio::time::timeout(Duration::from_secs(10), async {
        loop {
            match events.chunk().await {
                Ok(Some(_)) => continue,
                other => return other.map(|_| ()),
            }
        }
    })
    .await;
    assert!(end.is_ok(), "the event stream ends with its session");

    // A viewer still connected does not hold up a graceful stop.
    let sid = new_session(&base).await;
    upload(&http, &base, &sid, &pairs[0]).await;
    let mut watching = get(&http, &format!("{base}/v1/sessions/{sid}/events")).await;
    read_events(&mut watching, 1).await;
    tokio::time::timeout(Duration::from_secs(20), server.stop())
        .await
        .expect("the server stops with a viewer connected")
        .unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn live_frames_stay_within_their_budget() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = test_config(&dir.path().join("db.sqlite3"));
    let pairs = synth_pairs(Preset::Clean, Shape::Blob, 5, 1);
    // One pair's images (16-bit samples in memory) and a little more.
    let pair_bytes = 2 * 2 * (pairs[0].left.width * pairs[0].left.height) as usize;
    config.live_view_bytes = pair_bytes + pair_bytes / 2;
    let server = TestServer::start(config).await;
    let (http, base) = (reqwest::Client::new(), server.base.clone());
    let (a, b) = (new_session(&base).await, new_session(&base).await);
    upload(&http, &base, &a, &pairs[0]).await;
    let image = |sid: &str| format!("{base}/v1/sessions/{sid}/frames/latest/left");
    assert_eq!(get(&http, &image(&a)).await.status(), 200);
    upload(&http, &base, &b, &pairs[0]).await;
    // The newest stays; the older session's images are let go, its result stays.
    assert_eq!(get(&http, &image(&b)).await.status(), 200);
    let (status, code, message) = error_code(get(&http, &image(&a)).await).await;
    assert_eq!((status, code.as_str()), (404, "no_frame"));
    assert!(message.contains("--live-view-mib"), "{message}");
    let results = server::get_json(&format!("{base}/v1/sessions/{a}/results")).await;
    assert_eq!(results["results"].as_array().unwrap().len(), 1);
    // Its next pair brings its images back (and lets b's go).
    upload(&http, &base, &a, &pairs[0]).await;
    assert_eq!(get(&http, &image(&a)).await.status(), 200);
    assert_eq!(get(&http, &image(&b)).await.status(), 404);
    server.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_is_served_without_the_token_and_the_data_is_not() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = test_config(&dir.path().join("db.sqlite3"));
    config.token = Some("live-view-test-token".into());
    let server = TestServer::start(config).await;
    let (http, base) = (reqwest::Client::new(), server.base.clone());

    let r = get(&http, &format!("{base}/")).await;
    assert_eq!(r.status(), 200);
    assert_eq!(r.headers()["content-type"], "text/html; charset=utf-8");
    let csp = r.headers()["content-security-policy"]
        .to_str()
        .unwrap()
        .to_string();
    assert!(csp.contains("default-src 'self'"), "{csp}");
    let html = r.text().await.unwrap();
    assert!(
        html.contains(r#"<script type="module" src="/ui/app.js">"#),
        "{html}"
    );
    for (file, kind) in [
        ("app.js", "text/javascript"),
        ("style.css", "text/css"),
        ("icon.svg", "image/svg+xml"),
    ] {
        let r = get(&http, &format!("{base}/ui/{file}")).await;
        assert_eq!(r.status(), 200, "{file}");
        assert!(
            r.headers()["content-type"].to_str().unwrap().starts_with(kind),
            "{file}"
        );
        assert!(!r.text().await.unwrap().is_empty(), "{file}");
    }
    let (status, code, _) = error_code(get(&http, &format!("{base}/ui/secrets.txt")).await).await;
    assert_eq!((status, code.as_str()), (404, "route_not_found"));
    // The data the page shows needs the token.
    for path in [
        "/v1/sessions",
        "/v1/sessions/s_x/events",
        "/v1/sessions/s_x/frames/latest/left",
    ] {
        let (status, code, _) = error_code(get(&http, &format!("{base}{path}")).await).await;
        assert_eq!((status, code.as_str()), (401, "unauthorized"), "{path}");
    }
    server.stop().await.unwrap();
}

//! WebSocket streaming (issue #4): raw and PNG pairs over a real socket,
//! replies carrying `seq`, the `latest` policy skipping under overload, the
//! `all` policy answering every pair in order, malformed messages answered
//! without closing, ping answered while pairs are processed.

use crate::discs;
use crate::server;

use std::time::{Duration, Instant};

use crate::server::{
    new_session, next_reply, offset_free_rms, png, post_json, sdp1, sdp1_raw, sdp1_raw_frames, synth_pairs,
    test_config, TestServer,
};
use futures_util::{SinkExt, StreamExt};
use semdepth_core::synth::{Preset, Shape};
use serde_json::{json, Value};
use tokio_tungstenite::tungstenite::Message;

/// Disparity RMS limit (px, offset removed); see tests/app/api.rs.
const MAX_DISPARITY_RMS_PX: f64 = 0.15;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn all_policy_answers_every_pair_in_order_with_true_disparities() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("db.sqlite3"))).await;
    let sid = new_session(&server.base).await;
    let (ws, _) = tokio_tungstenite::connect_async(server.stream_url(&sid, "all"))
        .await
        .unwrap();
    let pairs = synth_pairs(Preset::Noisy, Shape::Sphere, 21, 10);
    // Send everything at once: the server must slow us down, not drop.
    let sender = {
        let messages: Vec<Vec<u8>> = pairs
            .iter()
            .enumerate()
            .map(|(i, p)| sdp1_raw(100 + i as u64, p))
            .collect();
        let (mut sink, stream) = ws.split();
        let task = tokio::spawn(async move {
            for m in messages {
                sink.send(Message::Binary(m.into())).await.unwrap();
            }
            sink
        });
        (task, stream)
    };
    let (task, mut stream) = sender;
    let mut errors = Vec::new();
    for (i, pair) in pairs.iter().enumerate() {
        let r = next_reply(&mut stream).await;
        assert_eq!(r["seq"], 100 + i as u64, "{r}");
        assert_eq!(r["frame"], i as u64, "{r}");
        assert_ne!(r["status"], "lost", "{r}");
        errors.push(r["disparity_px"][0].as_f64().unwrap() - pair.truth.disparity_px[0]);
    }
    let rms = offset_free_rms(&errors);
    eprintln!("WebSocket noisy sphere disparity RMS {rms:.4} px");
    assert!(rms <= MAX_DISPARITY_RMS_PX, "disparity RMS {rms} px");
    let sink = task.await.unwrap();
    let mut ws = sink.reunite(stream).unwrap();
    ws.close(None).await.unwrap();
    server.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn latest_policy_skips_under_overload_and_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = test_config(&dir.path().join("db.sqlite3"));
    config.workers = 1;
    let server = TestServer::start(config).await;
    let sid = new_session(&server.base).await;
    let (mut ws, _) = tokio_tungstenite::connect_async(server.stream_url(&sid, "latest"))
        .await
        .unwrap();
    // PNG pairs take a few ms each to decode and track; 40 sent back to back
    // arrive far faster than that.
    let pairs = synth_pairs(Preset::Clean, Shape::Blob, 5, 4);
    let encoded: Vec<(Vec<u8>, Vec<u8>)> = pairs.iter().map(|p| (png(&p.left), png(&p.right))).collect();
    let total = 40u64;
    for seq in 0..total {
        let (l, r) = &encoded[seq as usize % encoded.len()];
        let m = sdp1(
            &json!({"seq": seq, "encoding": "png", "left_len": l.len(), "right_len": r.len()}),
            l,
            r,
        );
        ws.send(Message::Binary(m.into())).await.unwrap();
    }
    let mut answered = std::collections::BTreeMap::new();
    while answered.len() < total as usize {
        let r = next_reply(&mut ws).await;
        let seq = r["seq"].as_u64().unwrap();
        let kind = if r["status"] == "skipped" {
            "skipped"
        } else {
            "result"
        };
        assert!(answered.insert(seq, kind).is_none(), "seq {seq} answered twice");
        if kind == "result" {
            assert!(r["frame"].is_u64(), "{r}");
        }
    }
    let skipped = answered.values().filter(|k| **k == "skipped").count();
    let processed = total as usize - skipped;
    eprintln!("latest policy: {processed} processed, {skipped} skipped of {total}");
    assert!(skipped > 0, "nothing skipped under overload");
    // The newest pair is never skipped: it is the one a lab script waits for.
    assert_eq!(answered[&(total - 1)], "result");
    let metrics = reqwest::get(format!("{}/metrics", server.base))
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert!(
        metrics.contains(&format!("semdepth_pairs_skipped_total {skipped}")),
        "{metrics}"
    );
    ws.close(None).await.unwrap();
    server.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn malformed_messages_get_errors_and_the_socket_stays_open() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("db.sqlite3"))).await;
    let sid = new_session(&server.base).await;
    let (mut ws, _) = tokio_tungstenite::connect_async(server.stream_url(&sid, "all"))
        .await
        .unwrap();
    let pair = &synth_pairs(Preset::Clean, Shape::Tip, 3, 1)[0];
    let truncated = png(&pair.left)[..200].to_vec();
    let cases: Vec<(Message, Option<u64>, &str)> = vec![
        (Message::Binary(b"hello".to_vec().into()), None, "bad_magic"),
        (Message::Text("{\"seq\": 1}".into()), None, "expected_binary"),
        (
            Message::Binary(sdp1(&json!({"seq": 2, "encoding": "raw", "left_len": 4, "right_len": 4}), &[0; 4], &[0; 4]).into()),
            Some(2),
            "invalid_header",
        ),
        (
            Message::Binary(sdp1(&json!({"seq": 3, "encoding": "png", "left_len": 9, "right_len": 4}), &[0; 4], &[0; 4]).into()),
            Some(3),
            "length_mismatch",
        ),
        (
            Message::Binary(sdp1(&json!({"seq": 4, "encoding": "png", "left_len": 200, "right_len": 200}), &truncated, &truncated).into()),
            Some(4),
            "corrupt_image",
        ),
        (
            Message::Binary(sdp1(&json!({"seq": 7, "encoding": "png", "left_len": 4, "right_len": 4}), b"abcd", b"abcd").into()),
            Some(7),
            "unknown_image_format",
        ),
        (
            Message::Binary(
                sdp1(
                    &json!({"seq": 5, "encoding": "raw", "width": 64, "height": 64, "bit_depth": 8, "left_len": 4096, "right_len": 1024}),
                    &[0; 4096],
                    &[0; 1024],
                )
                .into(),
            ),
            Some(5),
            "raw_length_mismatch",
        ),
    ];
    for (message, seq, code) in cases {
        ws.send(message).await.unwrap();
        let r = next_reply(&mut ws).await;
        assert_eq!(r["seq"].as_u64(), seq, "{r}");
        assert_eq!(r["error"]["code"], code, "{r}");
        assert!(!r["error"]["message"].as_str().unwrap().is_empty());
    }
    // Still open and working: a good pair after all that.
    ws.send(Message::Binary(sdp1_raw(6, pair).into())).await.unwrap();
    let r = next_reply(&mut ws).await;
    assert_eq!(
        (r["seq"].as_u64(), r["status"].as_str()),
        (Some(6), Some("initialised")),
        "{r}"
    );
    ws.close(None).await.unwrap();
    server.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ping_is_answered_while_pairs_are_processed() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = test_config(&dir.path().join("db.sqlite3"));
    config.workers = 1;
    let server = TestServer::start(config).await;
    let sid = new_session(&server.base).await;
    let (mut ws, _) = tokio_tungstenite::connect_async(server.stream_url(&sid, "latest"))
        .await
        .unwrap();
    let pairs = synth_pairs(Preset::Noisy, Shape::Rod, 9, 3);
    for (i, p) in pairs.iter().enumerate() {
        ws.send(Message::Binary(sdp1_raw(i as u64, p).into()))
            .await
            .unwrap();
    }
    let sent = Instant::now();
    ws.send(Message::Ping(b"are you there".to_vec().into()))
        .await
        .unwrap();
    let mut pong_after = None;
    let mut replies_before_pong = 0;
    let mut last_seq_answered = false;
    while !last_seq_answered {
        match tokio::time::timeout(Duration::from_secs(30), ws.next())
            .await
            .unwrap()
            .unwrap()
            .unwrap()
        {
            Message::Pong(p) => {
                assert_eq!(&p[..], b"are you there");
                pong_after = Some(sent.elapsed());
            }
            Message::Text(t) => {
                let r: Value = serde_json::from_str(&t).unwrap();
                // A `skipped` reply is the reader's own (pair 2 replaced
                // pair 1 in the queue) and may precede the pong; results
                // are the processor's.
                if pong_after.is_none() && r["status"] != "skipped" {
                    replies_before_pong += 1;
                }
                last_seq_answered = r["seq"] == 2 && r["status"] != "skipped";
            }
            _ => {}
        }
    }
    let pong_after = pong_after.expect("no pong before the last pair's result");
    eprintln!("pong after {pong_after:?}; {replies_before_pong} replies came before it");
    // The reader never waits on processing: the pong overtakes the queued
    // pairs (the first one alone, an initialisation, takes tens of ms).
    assert!(
        replies_before_pong <= 1,
        "{replies_before_pong} results before the pong"
    );
    ws.close(None).await.unwrap();
    server.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stream_of_unknown_session_is_404_and_plain_get_is_400() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("db.sqlite3"))).await;
    let err = tokio_tungstenite::connect_async(server.stream_url("s_nope", "all"))
        .await
        .unwrap_err();
    match err {
        tokio_tungstenite::tungstenite::Error::Http(r) => assert_eq!(r.status(), 404),
        other => panic!("expected an HTTP 404, got {other:?}"),
    }
    let sid = new_session(&server.base).await;
    let r = reqwest::get(format!("{}/v1/sessions/{sid}/stream", server.base))
        .await
        .unwrap();
    let status = r.status().as_u16();
    let body: Value = r.json().await.unwrap();
    assert!((400..500).contains(&status), "{status} {body}");
    assert_eq!(body["error"]["code"], "websocket_upgrade_required");
    let r = reqwest::get(format!(
        "{}/v1/sessions/{sid}/stream?policy=sometimes",
        server.base
    ))
    .await
    .unwrap();
    assert_eq!(r.status(), 400);
    server.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_4096x3072_16_bit_pair_fits_over_rest_and_websocket() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("db.sqlite3"))).await;
    let config = semdepth_core::synth::SynthConfig {
        frames: 1,
        bit_depth: 16,
        ..semdepth_core::synth::SynthConfig::preset(Preset::Clean, Shape::Blob, 41).with_size(4096, 3072)
    };
    let pair = semdepth_core::synth::frames(&config).unwrap().next().unwrap();
    assert_eq!(
        (pair.left.width, pair.left.height, pair.left.bit_depth),
        (4096, 3072, 16)
    );

    // REST: 16-bit PNGs in a multipart body on the default limits.
    let sid = new_session(&server.base).await;
    let form = reqwest::multipart::Form::new()
        .part("left", reqwest::multipart::Part::bytes(png(&pair.left)))
        .part("right", reqwest::multipart::Part::bytes(png(&pair.right)));
    let r: Value = reqwest::Client::new()
        .post(format!("{}/v1/sessions/{sid}/frames", server.base))
        .multipart(form)
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert_eq!(r["status"], "initialised", "{r}");
    let d = r["disparity_px"][0].as_f64().unwrap();
    assert!(
        (d - pair.truth.disparity_px[0]).abs() < 1.0,
        "disparity {d} vs truth {}",
        pair.truth.disparity_px[0]
    );

    // WebSocket: raw 16-bit little-endian, 2 x 25 MB in one message.
    let raw16 = |f: &semdepth_core::imageio::GrayFrame| {
        f.data.iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>()
    };
    let (l, r16) = (raw16(&pair.left), raw16(&pair.right));
    let message = sdp1(
        &json!({"seq": 1, "encoding": "raw", "width": 4096, "height": 3072, "bit_depth": 16,
            "left_len": l.len(), "right_len": r16.len()}),
        &l,
        &r16,
    );
    assert!(message.len() > 50_000_000);
    let sid = new_session(&server.base).await;
    let (mut ws, _) = tokio_tungstenite::connect_async(server.stream_url(&sid, "all"))
        .await
        .unwrap();
    ws.send(Message::Binary(message.into())).await.unwrap();
    let reply = next_reply(&mut ws).await;
    assert_eq!(
        (reply["seq"].as_u64(), reply["status"].as_str()),
        (Some(1), Some("initialised")),
        "{reply}"
    );
    let d = reply["disparity_px"][0].as_f64().unwrap();
    assert!((d - pair.truth.disparity_px[0]).abs() < 1.0);
    ws.close(None).await.unwrap();
    server.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_pair_the_hints_do_not_fit_gets_an_error_and_the_socket_stays_open() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("db.sqlite3"))).await;
    let base = &server.base;
    let session = post_json(
        &format!("{base}/v1/sessions"),
        json!({"init": {"roi": [1000, 1000, 50, 50]}}),
    )
    .await;
    let sid = session["id"].as_str().unwrap().to_string();
    let (mut ws, _) = tokio_tungstenite::connect_async(server.stream_url(&sid, "all"))
        .await
        .unwrap();
    let (left, right) = discs::scene_pair([0.0, 0.0]);
    for seq in [0, 1] {
        ws.send(Message::Binary(sdp1_raw_frames(seq, &left, &right).into()))
            .await
            .unwrap();
        let r = next_reply(&mut ws).await;
        assert_eq!(
            (r["seq"].as_u64(), r["error"]["code"].as_str()),
            (Some(seq), Some("invalid_hint")),
            "{r}"
        );
        let m = r["error"]["message"].as_str().unwrap();
        assert!(
            m.contains("init.roi") && m.contains("outside the 320x240 image"),
            "{m}"
        );
    }
    let s = server::get_json(&format!("{base}/v1/sessions/{sid}")).await;
    assert_eq!(
        (s["frames"].as_u64(), s["state"].as_str()),
        (Some(0), Some("awaiting_first_pair")),
        "{s}"
    );

    // New hints over REST while the socket stays open: the next pair on it
    // initialises on the named disc, as frame 0.
    let s = post_json(
        &format!("{base}/v1/sessions/{sid}/reinit"),
        json!({"init": {"roi": discs::ROI_B}}),
    )
    .await;
    assert_eq!(s["init"]["roi"], json!(discs::ROI_B));
    ws.send(Message::Binary(sdp1_raw_frames(2, &left, &right).into()))
        .await
        .unwrap();
    let r = next_reply(&mut ws).await;
    assert_eq!(
        (r["seq"].as_u64(), r["frame"].as_u64(), r["status"].as_str()),
        (Some(2), Some(0), Some("initialised")),
        "{r}"
    );
    let d = discs::distance(&r["left"]["centroid"], discs::DISC_B[0], discs::DISC_B[1]);
    assert!(
        d < 1.0,
        "left centroid {} is {d:.2} px off B",
        r["left"]["centroid"]
    );
    ws.close(None).await.unwrap();
    server.stop().await.unwrap();
}

/// Issue #64 item 5: hints over the socket itself. A text message
/// `{"reinit": {"init": {...}}}` names the object anew (answered with the
/// session and its hints): a lasso round disc B, then a point on the larger
/// disc A that is not the object, each take the next pair on B. A bad
/// control message gets an error naming the field, and the socket stays
/// open.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hints_sent_over_the_socket_name_the_next_pairs_object() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("db.sqlite3"))).await;
    let sid = new_session(&server.base).await;
    let (mut ws, _) = tokio_tungstenite::connect_async(server.stream_url(&sid, "all"))
        .await
        .unwrap();
    let (left, right) = discs::scene_pair([0.0, 0.0]);
    let [bx, by, _] = discs::DISC_B;
    let lasso = discs::lasso(discs::DISC_B, 5.0, 8);
    let not_a = json!([[discs::DISC_A[0], discs::DISC_A[1]]]);
    for (seq, init) in [(0, json!({"outline": lasso})), (1, json!({"exclude": not_a}))] {
        ws.send(Message::Text(
            json!({"reinit": {"init": init}}).to_string().into(),
        ))
        .await
        .unwrap();
        let r = next_reply(&mut ws).await;
        assert_eq!(
            (r["seq"].clone(), r["reinit"]["state"].as_str()),
            (Value::Null, Some("awaiting_first_pair")),
            "{r}"
        );
        assert_eq!(
            r["reinit"]["init"]["outline"].is_null(),
            seq == 1,
            "the hints go as a set: {r}"
        );
        ws.send(Message::Binary(sdp1_raw_frames(seq, &left, &right).into()))
            .await
            .unwrap();
        let r = next_reply(&mut ws).await;
        assert_eq!(
            (r["seq"].as_u64(), r["status"].as_str()),
            (Some(seq), Some("initialised")),
            "{r}"
        );
        let d = discs::distance(&r["left"]["centroid"], bx, by);
        assert!(
            d < 1.0,
            "{init}: left centroid {} is {d:.2} px off B",
            r["left"]["centroid"]
        );
    }
    let bad = [
        (
            json!({"reinit": {"init": {"outline": [[0, 0], [9, 9]]}}}),
            "invalid_hint",
            "init.outline",
        ),
        (
            json!({"reinit": {"init": {"roi": "x"}}}),
            "invalid_json",
            "reinit.init",
        ),
        (
            json!({"reinit": {"hints": {}}}),
            "invalid_json",
            "unknown field `hints`",
        ),
        (
            json!({"reinit": {"object": "nope", "init": {}}}),
            "object_not_found",
            "nope",
        ),
        (
            json!({"reinit": {"init": {"outline": [[[0]]]}}}),
            "invalid_json",
            "reinit.init.outline[0][0]",
        ),
        (json!({"hello": 1}), "expected_binary", "reinit"),
    ];
    for (message, code, needle) in bad {
        ws.send(Message::Text(message.to_string().into())).await.unwrap();
        let r = next_reply(&mut ws).await;
        assert_eq!(
            (r["seq"].clone(), r["error"]["code"].as_str()),
            (Value::Null, Some(code)),
            "{message}: {r}"
        );
        let m = r["error"]["message"].as_str().unwrap();
        assert!(m.contains(needle), "{message}: {m} lacks {needle:?}");
    }
    ws.send(Message::Binary(sdp1_raw_frames(2, &left, &right).into()))
        .await
        .unwrap();
    let r = next_reply(&mut ws).await;
    assert_eq!(
        (r["seq"].as_u64(), r["status"].as_str()),
        (Some(2), Some("tracked")),
        "{r}"
    );
    ws.close(None).await.unwrap();
    server.stop().await.unwrap();
}

/// Issue #22: a stream's pair header may carry `label` and `timestamp`; the
/// reply and the stored result echo them with the times of receipt and
/// processing. A timestamp that is not RFC 3339 is answered with an error
/// for that pair, and the stream goes on.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stream_headers_label_their_results() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(test_config(&dir.path().join("db.sqlite3"))).await;
    let sid = new_session(&server.base).await;
    let (mut ws, _) = tokio_tungstenite::connect_async(server.stream_url(&sid, "all"))
        .await
        .unwrap();
    let pairs = synth_pairs(Preset::Clean, Shape::Blob, 5, 2);
    let message = |seq: u64, pair: &semdepth_core::synth::SynthPair, label: &str, timestamp: &str| {
        server::sdp1_raw_with(
            seq,
            &pair.left,
            &pair.right,
            json!({"label": label, "timestamp": timestamp}),
        )
    };
    ws.send(Message::Binary(
        message(1, &pairs[0], "stage 0", "2026-11-25T08:00:00.5Z").into(),
    ))
    .await
    .unwrap();
    let reply = next_reply(&mut ws).await;
    assert_eq!(reply["label"], json!("stage 0"), "{reply}");
    assert_eq!(reply["timestamp"], json!("2026-11-25T08:00:00.5Z"), "{reply}");
    assert!(
        reply["received_at"].as_str().is_some_and(|t| t.ends_with('Z')),
        "{reply}"
    );
    assert!(reply["processed_at"].as_str().is_some(), "{reply}");
    ws.send(Message::Binary(message(2, &pairs[1], "stage 1", "soon").into()))
        .await
        .unwrap();
    let reply = next_reply(&mut ws).await;
    assert_eq!(reply["seq"], json!(2), "{reply}");
    assert_eq!(reply["error"]["code"], json!("invalid_timestamp"), "{reply}");
    let page = server::get_json(&format!("{}/v1/sessions/{sid}/results", server.base)).await;
    assert_eq!(page["results"].as_array().unwrap().len(), 1, "{page}");
    assert_eq!(page["results"][0]["label"], json!("stage 0"), "{page}");
    ws.close(None).await.unwrap();
    server.stop().await.unwrap();
}

/// A WebSocket to the session's stream over a plain TCP socket, after a
/// real handshake, for frames no client library would send.
async fn raw_stream(server: &TestServer, sid: &str) -> tokio::net::TcpStream {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let mut tcp = tokio::net::TcpStream::connect(server.addr).await.unwrap();
    let request = format!(
        "GET /v1/sessions/{sid}/stream?policy=all HTTP/1.1\r\nHost: {}\r\nUpgrade: websocket\r\n\
         Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n",
        server.addr
    );
    tcp.write_all(request.as_bytes()).await.unwrap();
    let mut head = Vec::new();
    while !head.ends_with(b"\r\n\r\n") {
        let mut byte = [0u8; 1];
        tcp.read_exact(&mut byte).await.unwrap();
        head.push(byte[0]);
    }
    assert!(
        head.starts_with(b"HTTP/1.1 101"),
        "{}",
        String::from_utf8_lossy(&head)
    );
    tcp
}

/// The code and reason of the close frame a raw socket (or its read half)
/// receives next; a connection that ends without one fails the test.
async fn raw_close_of(tcp: &mut (impl tokio::io::AsyncRead + Unpin)) -> (u16, String) {
    use tokio::io::AsyncReadExt;
    let mut head = [0u8; 4];
    tokio::time::timeout(Duration::from_secs(20), tcp.read_exact(&mut head))
        .await
        .expect("a close frame within 20 s")
        .expect("a close frame before the connection ended");
    assert_eq!(head[0], 0x88, "a close frame: {head:?}");
    let len = usize::from(head[1] & 0x7f);
    let mut reason = vec![0u8; len - 2];
    tcp.read_exact(&mut reason).await.unwrap();
    (
        u16::from_be_bytes([head[2], head[3]]),
        String::from_utf8_lossy(&reason).into_owned(),
    )
}

/// Issue #21, item 5: a message over the limit closes the stream with 1009
/// and a protocol violation with 1002, each with a short reason, not 1000;
/// the server keeps serving the session.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn broken_streams_close_with_the_reason() {
    use tokio::io::AsyncWriteExt;
    let dir = tempfile::tempdir().unwrap();
    let mut config = test_config(&dir.path().join("db.sqlite3"));
    config.max_ws_message_bytes = 1 << 20;
    let server = TestServer::start(config).await;
    let sid = new_session(&server.base).await;

    // Too big: a frame that announces 1.5 MiB against a 1 MiB limit (a
    // 640x480 raw pair fits). Only its header is sent: the server refuses
    // on the length, and a client still writing the payload when the
    // server closes gets a reset that can swallow the close frame.
    let mut tcp = raw_stream(&server, &sid).await;
    let mask = [1u8, 2, 3, 4];
    let mut header = vec![0x80 | 0x02, 0x80 | 127];
    header.extend((3u64 << 19).to_be_bytes());
    header.extend(mask);
    tcp.write_all(&header).await.unwrap();
    let (code, reason) = raw_close_of(&mut tcp).await;
    assert_eq!(code, 1009, "{reason}");
    assert!(
        reason.contains("too big") && reason.contains("1048576"),
        "{reason}"
    );

    // A protocol violation: a frame with the reserved bit RSV1 set (no
    // extension was negotiated), sent by hand after a real handshake.
    let mut tcp = raw_stream(&server, &sid).await;
    let mut frame = vec![0x80 | 0x40 | 0x02, 0x80 | 5];
    frame.extend(mask);
    frame.extend(b"hello".iter().enumerate().map(|(i, b)| b ^ mask[i % 4]));
    tcp.write_all(&frame).await.unwrap();
    let (code, reason) = raw_close_of(&mut tcp).await;
    assert_eq!(code, 1002, "{reason}");
    assert!(reason.contains("protocol error"), "{reason}");

    // The session still streams.
    let (mut ws, _) = tokio_tungstenite::connect_async(server.stream_url(&sid, "all"))
        .await
        .unwrap();
    let pairs = synth_pairs(Preset::Clean, Shape::Blob, 1, 1);
    ws.send(Message::Binary(sdp1_raw(0, &pairs[0]).into()))
        .await
        .unwrap();
    let reply = next_reply(&mut ws).await;
    assert_eq!(reply["status"], "initialised", "{reply}");
    ws.close(None).await.unwrap();
}

/// Issue #21, item 1: a stream on which no whole message arrives within
/// the idle timeout (here 1 s) is closed with 1008 and the reason: a
/// half-sent frame (its header only) and a silent client alike. The
/// session still streams afterwards.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn idle_and_half_sent_streams_are_closed_at_the_idle_timeout() {
    use tokio::io::AsyncWriteExt;
    let dir = tempfile::tempdir().unwrap();
    let mut config = test_config(&dir.path().join("db.sqlite3"));
    config.ws_idle_timeout = Duration::from_secs(1);
    let server = TestServer::start(config).await;
    let sid = new_session(&server.base).await;

    // A frame header announcing 100 bytes, then nothing.
    let mut half = raw_stream(&server, &sid).await;
    let started = Instant::now();
    half.write_all(&[0x80 | 0x02, 0x80 | 100, 1, 2, 3, 4])
        .await
        .unwrap();
    let (code, reason) = raw_close_of(&mut half).await;
    assert_eq!(code, 1008, "{reason}");
    assert!(reason.contains("idle"), "{reason}");
    let after = started.elapsed();
    assert!(
        after >= Duration::from_millis(900) && after < Duration::from_secs(10),
        "closed after {after:?} (timeout 1 s)"
    );

    // A client that says nothing at all.
    let mut silent = raw_stream(&server, &sid).await;
    let (code, reason) = raw_close_of(&mut silent).await;
    assert_eq!(code, 1008, "{reason}");

    // A client that sends a pair every 0.6 s is not cut off between its
    // pairs. It sends without waiting for replies, so that the gaps the
    // server sees do not grow with the time a pair takes on a busy machine.
    let (mut ws, _) = tokio_tungstenite::connect_async(server.stream_url(&sid, "all"))
        .await
        .unwrap();
    let pairs = synth_pairs(Preset::Clean, Shape::Blob, 1, 3);
    for (i, pair) in pairs.iter().enumerate() {
        tokio::time::sleep(Duration::from_millis(600)).await;
        ws.send(Message::Binary(sdp1_raw(i as u64, pair).into()))
            .await
            .unwrap();
    }
    for _ in &pairs {
        let reply = next_reply(&mut ws).await;
        assert!(
            reply["status"] == "initialised" || reply["status"] == "tracked",
            "{reply}"
        );
    }
    ws.close(None).await.unwrap();
}

/// Issue #66: a client that sends the whole of an oversize message (3 MiB
/// against a 2 MiB limit) while it reads gets the 1009 close frame every
/// time, twenty times in a row with both cores kept busy: the server holds
/// the socket open after its close frame instead of resetting the
/// connection under the close while the message still arrives.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_oversize_message_gets_its_close_code_every_time() {
    use tokio::io::AsyncWriteExt;
    let dir = tempfile::tempdir().unwrap();
    let mut config = test_config(&dir.path().join("db.sqlite3"));
    config.max_ws_message_bytes = 2 << 20;
    let server = TestServer::start(config).await;
    let sid = new_session(&server.base).await;
    // CPU load: two threads spinning for the length of the test.
    let spinning = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(true));
    let load: Vec<_> = (0..2)
        .map(|_| {
            let spinning = spinning.clone();
            std::thread::spawn(move || {
                let mut x = 0u64;
                while spinning.load(std::sync::atomic::Ordering::Relaxed) {
                    x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
                }
            })
        })
        .collect();
    let size = 3usize << 20;
    let mut codes = Vec::new();
    for _ in 0..20 {
        let tcp = raw_stream(&server, &sid).await;
        let (mut read, mut write) = tcp.into_split();
        // The whole message, masked as a client must, written while the
        // close frame is read.
        let mut frame = vec![0x80 | 0x02, 0x80 | 127];
        frame.extend((size as u64).to_be_bytes());
        frame.extend([9u8, 8, 7, 6]);
        frame.resize(frame.len() + size, 0x5a);
        let writer = tokio::spawn(async move { write.write_all(&frame).await.map(|_| write) });
        // A client slow to read (a loaded machine): the close frame waits
        // in its socket meanwhile. A client whose write fails first (the
        // server reset the connection) drops it with the close unread, as
        // asyncio's transports do: that counts as no close code (0).
        tokio::time::sleep(Duration::from_millis(200)).await;
        let writer = if writer.is_finished() {
            if matches!(writer.await, Ok(Err(_))) {
                codes.push(0);
                continue;
            }
            None
        } else {
            Some(writer)
        };
        let (code, reason) = raw_close_of(&mut read).await;
        codes.push(code);
        assert!(reason.contains("too big"), "{reason}");
        if let Some(writer) = writer {
            writer.abort();
        }
    }
    spinning.store(false, std::sync::atomic::Ordering::Relaxed);
    for thread in load {
        thread.join().unwrap();
    }
    assert!(codes.iter().all(|&c| c == 1009), "close codes: {codes:?}");
    server.stop().await.unwrap();
}

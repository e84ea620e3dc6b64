//! Issue #21, item 2: one client cannot exhaust the server's memory. A burst
//! of concurrent large uploads against `semdepth serve` (the binary, as a
//! child process, so that its memory is its own) with a small budget for
//! work in flight: the peak resident memory stays near the budget, and the
//! uploads beyond it are answered 503 `busy` with `Retry-After` before their
//! bodies are read. Streams under the same budget wait instead, and every
//! pair is answered. (With a budget too large to matter, the same burst
//! was all served and peaked at 334 MiB above the idle server's 14 MiB,
//! against 121 MiB with the budget.)

use crate::server;

use std::time::Duration;

use crate::child_server::ChildServer;

use futures_util::{SinkExt, StreamExt};
use serde_json::Value;
use tokio_tungstenite::tungstenite::Message;

/// Budget for work in flight given to the server, MiB.
const BUDGET_MIB: u64 = 120;
/// Concurrent uploads in the burst.
const BURST: usize = 12;
/// Peak resident memory allowed above the idle server's, beyond the budget:
/// the tracker's own buffers of one pair and the allocator's slack.
const SLACK_MIB: u64 = 110;

/// A 16-bit PNG of noise (incompressible: the body is as large as the
/// pixels).
fn noise_png(width: u32, height: u32, seed: u32) -> Vec<u8> {
    let mut state = seed.wrapping_mul(2_654_435_761).max(1);
    let data: Vec<u16> = (0..width * height)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            (state >> 8) as u16
        })
        .collect();
    let mut png = Vec::new();
    let encoder = image::codecs::png::PngEncoder::new_with_quality(
        &mut png,
        image::codecs::png::CompressionType::Fast,
        image::codecs::png::FilterType::NoFilter,
    );
    let bytes: Vec<u8> = data.iter().flat_map(|v| v.to_be_bytes()).collect();
    image::ImageEncoder::write_image(encoder, &bytes, width, height, image::ExtendedColorType::L16).unwrap();
    png
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_burst_of_large_uploads_stays_within_the_memory_budget() {
    let budget = BUDGET_MIB.to_string();
    let server = ChildServer::start(&[
        "--max-body-mib",
        "25",
        "--max-message-mib",
        "25",
        "--max-inflight-mib",
        &budget,
        "--workers",
        "1",
    ]);
    let base = format!("http://{}", server.addr);
    let http = reqwest::Client::new();
    for _ in 0..100 {
        if http.get(format!("{base}/readyz")).send().await.is_ok() {
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    // 3000x2000 16-bit noise: about 12 MB per image, 24 MB per body (near
    // the 25 MiB body limit), and 48 MB decoded: one upload takes 72 of the
    // 120 MiB.
    let (left, right) = (noise_png(3000, 2000, 1), noise_png(3000, 2000, 2));
    let idle_kib = server.rss_kib();

    let mut uploads = Vec::new();
    for _ in 0..BURST {
        let (http, url) = (http.clone(), format!("{base}/v1/depth"));
        let form = reqwest::multipart::Form::new()
            .part(
                "left",
                reqwest::multipart::Part::bytes(left.clone()).file_name("l.png"),
            )
            .part(
                "right",
                reqwest::multipart::Part::bytes(right.clone()).file_name("r.png"),
            );
        uploads.push(tokio::spawn(async move {
            let r = http.post(url).multipart(form).send().await;
            match r {
                Ok(r) => {
                    let status = r.status().as_u16();
                    let retry = r
                        .headers()
                        .get("retry-after")
                        .map(|v| v.to_str().unwrap().to_string());
                    let body: Value = r.json().await.unwrap_or(Value::Null);
                    (status, retry, body)
                }
                // The server may close a refused upload's connection while
                // the client still sends its body.
                Err(e) => (0, None, Value::String(e.to_string())),
            }
        }));
    }
    let mut answers = Vec::new();
    for u in uploads {
        answers.push(u.await.unwrap());
    }
    let peak_kib = server.peak_rss_kib();
    let above_idle_mib = peak_kib.saturating_sub(idle_kib) / 1024;
    let served = answers.iter().filter(|a| a.0 == 200).count();
    let busy: Vec<_> = answers.iter().filter(|a| a.0 == 503).collect();
    eprintln!(
        "{BURST} uploads of {:.1} MB: {served} served, {} busy, {} cut off; peak RSS {} MiB above idle ({} MiB)",
        (left.len() + right.len()) as f64 / 1e6,
        busy.len(),
        answers.iter().filter(|a| a.0 == 0).count(),
        above_idle_mib,
        idle_kib / 1024
    );
    assert!(served >= 1, "no upload was served: {answers:?}");
    assert!(!busy.is_empty(), "no upload was refused: {answers:?}");
    for (_, retry, body) in &busy {
        assert_eq!(retry.as_deref(), Some("1"), "503 without Retry-After: {body}");
        assert_eq!(body["error"]["code"], "busy", "{body}");
        assert!(
            body["error"]["message"]
                .as_str()
                .unwrap()
                .contains("--max-inflight-mib"),
            "{body}"
        );
    }
    assert!(
        answers.iter().all(|a| matches!(a.0, 0 | 200 | 503)),
        "unexpected answers: {answers:?}"
    );
    assert!(
        above_idle_mib <= BUDGET_MIB + SLACK_MIB,
        "peak RSS {above_idle_mib} MiB above idle (budget {BUDGET_MIB} MiB + {SLACK_MIB} MiB slack)"
    );

    // Streams under the same budget wait rather than fail: two sockets
    // sending 3 pairs each, every pair answered with a result.
    let mut streams = Vec::new();
    for _ in 0..2 {
        let session = server::new_session(&base).await;
        let url = format!("ws://{}/v1/sessions/{session}/stream?policy=all", server.addr);
        let (left, right) = (left.clone(), right.clone());
        streams.push(tokio::spawn(async move {
            let (mut ws, _) = tokio_tungstenite::connect_async(url).await.unwrap();
            for seq in 0..3u64 {
                let header = serde_json::json!({
                    "seq": seq, "encoding": "png", "left_len": left.len(), "right_len": right.len()
                });
                let message = server::sdp1(&header, &left, &right);
                ws.send(Message::Binary(message.into())).await.unwrap();
            }
            let mut seqs = Vec::new();
            while seqs.len() < 3 {
                let m = tokio::time::timeout(Duration::from_secs(120), ws.next())
                    .await
                    .expect("a reply within 120 s")
                    .expect("the socket stays open")
                    .unwrap();
                if let Message::Text(t) = m {
                    let reply: Value = serde_json::from_str(&t).unwrap();
                    assert!(reply.get("error").is_none(), "{reply}");
                    seqs.push(reply["seq"].as_u64().unwrap());
                }
            }
            seqs
        }));
    }
    for s in streams {
        assert_eq!(s.await.unwrap(), vec![0, 1, 2]);
    }
    let peak_kib = server.peak_rss_kib();
    let above_idle_mib = peak_kib.saturating_sub(idle_kib) / 1024;
    eprintln!("after two streams: peak RSS {above_idle_mib} MiB above idle");
    // Each socket may hold one message of 24 MB that it has read and not
    // yet reserved, beyond the budget.
    assert!(
        above_idle_mib <= BUDGET_MIB + SLACK_MIB + 2 * 25,
        "peak RSS {above_idle_mib} MiB above idle with two streams"
    );
}

//! A real server for integration tests: `semdepth::service::serve` on
//! 127.0.0.1 port 0 with a SQLite file in a temporary folder, plus helpers
//! to build uploads from the synthetic generator.
#![allow(dead_code)]

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use semdepth::service::state::ServiceConfig;
use semdepth_core::imageio::GrayFrame;
use semdepth_core::synth::{frames, Preset, Shape, SynthConfig, SynthPair};
use tokio::sync::oneshot;
use tokio::task::JoinHandle;

/// A server running in this process.
pub struct TestServer {
    /// `http://127.0.0.1:PORT`.
    pub base: String,
    /// The bound address.
    pub addr: SocketAddr,
    /// The database file.
    pub db: PathBuf,
    stop: Option<oneshot::Sender<()>>,
    task: Option<JoinHandle<Result<(), semdepth::service::ServeError>>>,
}

/// A configuration for tests: the given database, two workers.
pub fn test_config(db: &Path) -> ServiceConfig {
    ServiceConfig {
        db_path: db.display().to_string(),
        workers: 2,
        ..ServiceConfig::default()
    }
}

impl TestServer {
    /// Starts a server with `config` on 127.0.0.1 port 0 and waits until it
    /// is ready.
    pub async fn start(config: ServiceConfig) -> Self {
        let server = Self::start_unready(config).await;
        server.wait_ready().await;
        server
    }

    /// Starts a server with `config` on 127.0.0.1 port 0; the listener is
    /// bound when it returns, readiness is not awaited.
    pub async fn start_unready(config: ServiceConfig) -> Self {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let (stop, stopped) = oneshot::channel::<()>();
        let db = PathBuf::from(&config.db_path);
        let task = tokio::spawn(semdepth::service::serve(listener, config, async move {
            let _ = stopped.await;
        }));
        Self {
            base: format!("http://{addr}"),
            addr,
            db,
            stop: Some(stop),
            task: Some(task),
        }
    }

    /// Polls `/readyz` until it answers 200 (at most 30 s).
    pub async fn wait_ready(&self) {
        let client = reqwest::Client::new();
        for _ in 0..300 {
            if let Ok(r) = client.get(format!("{}/readyz", self.base)).send().await {
                if r.status() == 200 {
                    return;
                }
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        panic!("server at {} never became ready", self.base);
    }

    /// Graceful stop; returns what `serve` returned.
    pub async fn stop(mut self) -> Result<(), semdepth::service::ServeError> {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        self.task.take().unwrap().await.unwrap()
    }

    /// `ws://127.0.0.1:PORT/v1/sessions/{id}/stream?policy=...`.
    pub fn stream_url(&self, session: &str, policy: &str) -> String {
        format!("ws://{}/v1/sessions/{session}/stream?policy={policy}", self.addr)
    }
}

impl Drop for TestServer {
    fn drop(&mut self) {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
    }
}

/// `count` pairs of a synthetic sequence.
pub fn synth_pairs(preset: Preset, shape: Shape, seed: u64, count: usize) -> Vec<SynthPair> {
    let config = SynthConfig {
        frames: count,
        ..SynthConfig::preset(preset, shape, seed)
    };
    frames(&config).unwrap().collect()
}

/// A frame as PNG (8- or 16-bit as the frame is).
pub fn png(frame: &GrayFrame) -> Vec<u8> {
    let mut out = std::io::Cursor::new(Vec::new());
    if frame.bit_depth <= 8 {
        frame
            .to_gray8()
            .write_to(&mut out, image::ImageFormat::Png)
            .unwrap();
    } else {
        let img: image::ImageBuffer<image::Luma<u16>, Vec<u16>> =
            image::ImageBuffer::from_raw(frame.width, frame.height, frame.data.clone()).unwrap();
        img.write_to(&mut out, image::ImageFormat::Png).unwrap();
    }
    out.into_inner()
}

/// Raw 8-bit bytes of a frame (samples scaled to 0..=255).
pub fn raw8(frame: &GrayFrame) -> Vec<u8> {
    frame.to_gray8().into_raw()
}

/// A multipart form with `left` and `right` PNG parts.
pub fn pair_form(pair: &SynthPair) -> reqwest::multipart::Form {
    frames_form(&pair.left, &pair.right)
}

/// A multipart form with two frames as `left` and `right` PNG parts.
pub fn frames_form(left: &GrayFrame, right: &GrayFrame) -> reqwest::multipart::Form {
    reqwest::multipart::Form::new()
        .part(
            "left",
            reqwest::multipart::Part::bytes(png(left)).file_name("left.png"),
        )
        .part(
            "right",
            reqwest::multipart::Part::bytes(png(right)).file_name("right.png"),
        )
}

/// A binary stream message: `SDP1`, header length, JSON header, left, right.
pub fn sdp1(header: &serde_json::Value, left: &[u8], right: &[u8]) -> Vec<u8> {
    semdepth::service::wire::encode_pair_message(header, left, right)
}

/// A raw 8-bit stream message for a synthetic pair.
pub fn sdp1_raw(seq: u64, pair: &SynthPair) -> Vec<u8> {
    sdp1_raw_frames(seq, &pair.left, &pair.right)
}

/// A raw 8-bit stream message for two frames of equal size.
pub fn sdp1_raw_frames(seq: u64, left: &GrayFrame, right: &GrayFrame) -> Vec<u8> {
    sdp1_raw_with(seq, left, right, serde_json::json!({}))
}

/// [`sdp1_raw_frames`] with the header fields of `extra` (an object) added.
pub fn sdp1_raw_with(seq: u64, left: &GrayFrame, right: &GrayFrame, extra: serde_json::Value) -> Vec<u8> {
    let (l, r) = (raw8(left), raw8(right));
    let mut header = serde_json::json!({"seq": seq, "encoding": "raw", "width": left.width,
        "height": left.height, "bit_depth": 8, "left_len": l.len(), "right_len": r.len()});
    if let (Some(h), Some(e)) = (header.as_object_mut(), extra.as_object()) {
        h.extend(e.clone());
    }
    sdp1(&header, &l, &r)
}

/// RMS of `measured - truth` after removing the mean (the constant offset a
/// calibration's reference absorbs).
pub fn offset_free_rms(errors: &[f64]) -> f64 {
    let mean = errors.iter().sum::<f64>() / errors.len() as f64;
    (errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / errors.len() as f64).sqrt()
}

/// POSTs JSON and returns the JSON answer; panics on a non-2xx status.
pub async fn post_json(url: &str, body: serde_json::Value) -> serde_json::Value {
    let r = reqwest::Client::new().post(url).json(&body).send().await.unwrap();
    assert!(r.status().is_success(), "{url}: {}", r.status());
    r.json().await.unwrap()
}

/// GETs JSON; panics on a non-2xx status.
pub async fn get_json(url: &str) -> serde_json::Value {
    let r = reqwest::get(url).await.unwrap();
    assert!(r.status().is_success(), "{url}: {}", r.status());
    r.json().await.unwrap()
}

/// GETs a text body (e.g. `/metrics`); panics on a non-2xx status.
pub async fn get_text(url: &str) -> String {
    let r = reqwest::get(url).await.unwrap();
    assert!(r.status().is_success(), "{url}: {}", r.status());
    r.text().await.unwrap()
}

/// Creates a session on default parameters and returns its id.
pub async fn new_session(base: &str) -> String {
    let s = post_json(&format!("{base}/v1/sessions"), serde_json::json!({})).await;
    s["id"].as_str().unwrap().to_string()
}

/// Uploads a synthetic pair as PNG parts and returns the parsed answer.
pub async fn upload(
    http: &reqwest::Client,
    base: &str,
    session: &str,
    pair: &SynthPair,
) -> serde_json::Value {
    http.post(format!("{base}/v1/sessions/{session}/frames"))
        .multipart(pair_form(pair))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap()
}

/// The next text reply on a WebSocket (or its read half), parsed; control
/// frames are skipped. Panics on close, error or 60 s without a reply.
pub async fn next_reply<S>(ws: &mut S) -> serde_json::Value
where
    S: futures_util::Stream<
            Item = Result<tokio_tungstenite::tungstenite::Message, tokio_tungstenite::tungstenite::Error>,
        > + Unpin,
{
    use futures_util::StreamExt;
    use tokio_tungstenite::tungstenite::Message;
    loop {
        let m = tokio::time::timeout(Duration::from_secs(60), ws.next())
            .await
            .expect("no reply within 60 s")
            .expect("socket closed")
            .unwrap();
        match m {
            Message::Text(t) => return serde_json::from_str(&t).unwrap(),
            Message::Close(c) => panic!("socket closed: {c:?}"),
            _ => continue,
        }
    }
}

/// A reply's status and JSON body (null for an empty body); panics on a
/// body that is not JSON.
pub async fn json_of(r: reqwest::Response) -> (u16, serde_json::Value) {
    let status = r.status().as_u16();
    let text = r.text().await.unwrap();
    let value = if text.is_empty() {
        serde_json::Value::Null
    } else {
        serde_json::from_str(&text).unwrap_or_else(|e| panic!("not JSON ({e}): {text}"))
    };
    (status, value)
}

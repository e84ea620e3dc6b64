//! Load benchmark of the HTTP/WebSocket service: throughput and latency of
//! raw 8-bit 1024x768 pairs over WebSockets (one client as fast as possible,
//! one client paced at 100 pairs/s, eight concurrent clients), of REST
//! uploads of PNG pairs (one and four clients), and the server's memory per
//! idle session.
//!
//! The server is the release binary (`CARGO_BIN_EXE_semdepth`) started as a
//! child process (`semdepth serve --listen 127.0.0.1:0 --db <temp>`); the
//! clients run in this process on the same machine. Every scenario uses
//! fresh sessions. Messages and PNG files are prepared before timing.
//! The pairs are frames 0..30 of the clean blob sequence (seed 1), played
//! forwards and backwards so that the object moves continuously; (in this
//! sequence a tracking step costs about 2.5 times as much from frame 31 on,
//! so the pool stops before it, like `benches/track.rs` measures frame 1).
//! Latency is client-side: from the start of sending a pair to the arrival of
//! its reply. The server's `timing_ms` (queue, decode, track, total) is
//! reported as medians, and the CPU time of server and client per pair is
//! read from `/proc`.
//!
//! References measured in the same run: one pass summing every byte of both
//! images, the in-process `StereoTracker::process` step on the same pairs,
//! the round trip of `GET /healthz`, and the WebSocket round trip of a
//! message of the same size that the server rejects at once (bad magic).
//!
//! Targets (service issue): >= 300 pairs/s over one WebSocket, p99 latency
//! under 20 ms at 100 pairs/s, under 5 MB of server memory per idle session.
//!
//! `cargo bench --bench service_load [-- --quick] [-- SCENARIO...]`
//! (scenario names: ws_one, ws_objects_2, ws_objects_4, ws_objects_2_one_worker,
//! ws_objects_4_one_worker, ws_viewed, ws_paced,
//! ws_eight, rest_one, rest_four,
//! idle_memory; a name filters by substring; unknown flags are ignored).
//!
//! `cargo bench --bench service_load -- soak` runs only the soak test
//! (issue #21): 4 WebSocket streams, each sending a pair as soon as the
//! previous one is answered, for `SOAK_MINUTES` (default 20) minutes; the
//! server's RSS and the latency percentiles are sampled every 10 s, printed,
//! and written to `target/soak.json` with the slope of the RSS over the
//! second half.
//! Prints a table and writes the figures as JSON to
//! `target/service_load.json`.

use std::path::PathBuf;
use std::process::Command;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use semdepth_core::imageio::GrayFrame;
use semdepth_core::synth::{Preset, Shape, SynthConfig};
use semdepth_core::tracker::{StereoTracker, TrackerParams};
use serde_json::{json, Value};
use tokio::sync::Barrier;
use tokio_tungstenite::tungstenite::{Bytes, Message};

const WIDTH: u32 = 1024;
const HEIGHT: u32 = 768;
/// Pacing of the `ws_paced` scenario.
const PACED_RATE: f64 = 100.0;
const TARGET_WS_PAIRS_PER_S: f64 = 300.0;
const TARGET_PACED_P99_MS: f64 = 20.0;
const TARGET_IDLE_SESSION_MB: f64 = 5.0;

/// How much work each part does.
#[derive(Clone, Copy, Debug)]
struct Sizes {
    /// Distinct rendered pairs (played forwards and backwards).
    pool: usize,
    ws_warmup: usize,
    ws_pairs: usize,
    paced_pairs: usize,
    multi_clients: usize,
    multi_warmup: usize,
    multi_pairs_each: usize,
    rest_warmup: usize,
    rest_pairs: usize,
    rest_clients: usize,
    rest_pairs_each: usize,
    idle_sessions: usize,
    reference_reps: usize,
}

impl Sizes {
    fn new(quick: bool) -> Self {
        if quick {
            Self {
                pool: 30,
                ws_warmup: 10,
                ws_pairs: 150,
                paced_pairs: 100,
                multi_clients: 8,
                multi_warmup: 5,
                multi_pairs_each: 30,
                rest_warmup: 3,
                rest_pairs: 30,
                rest_clients: 4,
                rest_pairs_each: 10,
                idle_sessions: 50,
                reference_reps: 50,
            }
        } else {
            Self {
                pool: 30,
                ws_warmup: 20,
                ws_pairs: 500,
                paced_pairs: 300,
                multi_clients: 8,
                multi_warmup: 10,
                multi_pairs_each: 100,
                rest_warmup: 5,
                rest_pairs: 100,
                rest_clients: 4,
                rest_pairs_each: 40,
                idle_sessions: 200,
                reference_reps: 200,
            }
        }
    }
}

// ---------------------------------------------------------------- statistics

/// Nearest-rank percentile (`p` in 0..=1) of unsorted values.
fn percentile(values: &[f64], p: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let rank = ((p * v.len() as f64).ceil() as usize).clamp(1, v.len());
    v[rank - 1]
}

fn median(values: &[f64]) -> f64 {
    percentile(values, 0.5)
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// Rounds for the JSON output (3 significant decimals are plenty).
fn r3(x: f64) -> f64 {
    (x * 1e3).round() / 1e3
}

// -------------------------------------------------------------------- /proc

/// Clock ticks per second of /proc/<pid>/stat times.
fn clock_ticks() -> f64 {
    Command::new("getconf")
        .arg("CLK_TCK")
        .output()
        .ok()
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .and_then(|s| s.trim().parse().ok())
        .unwrap_or(100.0)
}

/// User + system CPU seconds of a process (all threads).
fn cpu_seconds(pid: u32, ticks: f64) -> f64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).expect("read /proc/<pid>/stat");
    // Fields after the parenthesised command name; utime and stime are 14 and 15.
    let after = &stat[stat.rfind(')').expect("stat format") + 2..];
    let fields: Vec<&str> = after.split_whitespace().collect();
    let utime: f64 = fields[11].parse().expect("utime");
    let stime: f64 = fields[12].parse().expect("stime");
    (utime + stime) / ticks
}

/// Minor page faults of a process so far (/proc/<pid>/stat field 10).
fn minor_faults(pid: u32) -> u64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).expect("read /proc/<pid>/stat");
    let after = &stat[stat.rfind(')').expect("stat format") + 2..];
    after
        .split_whitespace()
        .nth(7)
        .and_then(|f| f.parse().ok())
        .expect("minflt")
}

/// Nanoseconds this thread has spent on a CPU (/proc/thread-self/schedstat).
fn thread_run_ns() -> Option<u64> {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// Busy and total ticks of the whole machine (first line of /proc/stat).
fn machine_ticks() -> (u64, u64) {
    let stat = std::fs::read_to_string("/proc/stat").unwrap_or_default();
    let fields: Vec<u64> = stat
        .lines()
        .next()
        .unwrap_or_default()
        .split_whitespace()
        .skip(1)
        .filter_map(|f| f.parse().ok())
        .collect();
    let total: u64 = fields.iter().take(8).sum();
    let idle = fields.get(3).copied().unwrap_or(0) + fields.get(4).copied().unwrap_or(0);
    (total - idle, total)
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_default()
}

// ------------------------------------------------------------------- server

#[path = "../tests/common/child_server.rs"]
mod child_server;

/// The server under test, a child process on a temporary database.
type Server = child_server::ChildServer;

// --------------------------------------------------------------------- data

/// The pool of distinct rendered pairs, as frames and as raw 8-bit bytes.
struct Data {
    frames: Vec<(GrayFrame, GrayFrame)>,
    raw: Vec<(Vec<u8>, Vec<u8>)>,
    png: Vec<(Vec<u8>, Vec<u8>)>,
}

/// Pool index of the `k`-th pair sent: the pool played forwards, then
/// backwards, and so on, so that the object moves continuously.
fn pool_index(k: usize, pool: usize) -> usize {
    if pool < 2 {
        return 0;
    }
    let period = 2 * (pool - 1);
    let m = k % period;
    if m < pool {
        m
    } else {
        period - m
    }
}

fn png(frame: &GrayFrame) -> Vec<u8> {
    let mut out = std::io::Cursor::new(Vec::new());
    frame
        .to_gray8()
        .write_to(&mut out, image::ImageFormat::Png)
        .expect("PNG encoding");
    out.into_inner()
}

fn render(pool: usize) -> Data {
    let config = SynthConfig {
        frames: pool,
        ..SynthConfig::preset(Preset::Clean, Shape::Blob, 1).with_size(WIDTH, HEIGHT)
    };
    let frames: Vec<(GrayFrame, GrayFrame)> = semdepth_core::synth::frames(&config)
        .expect("valid synthetic configuration")
        .map(|p| (p.left, p.right))
        .collect();
    let raw = frames
        .iter()
        .map(|(l, r)| (l.to_gray8().into_raw(), r.to_gray8().into_raw()))
        .collect();
    let png = frames.iter().map(|(l, r)| (png(l), png(r))).collect();
    Data { frames, raw, png }
}

/// One `SDP1` message: magic, header length, JSON header, left, right.
fn sdp1(seq: usize, left: &[u8], right: &[u8]) -> Bytes {
    let header = json!({
        "seq": seq, "encoding": "raw", "width": WIDTH, "height": HEIGHT, "bit_depth": 8,
        "left_len": left.len(), "right_len": right.len(),
    });
    Bytes::from(semdepth::service::wire::encode_pair_message(&header, left, right))
}

/// Messages with seq 0..n over the pool.
fn messages(data: &Data, n: usize) -> Arc<Vec<Bytes>> {
    Arc::new(
        (0..n)
            .map(|k| {
                let (l, r) = &data.raw[pool_index(k, data.raw.len())];
                sdp1(k, l, r)
            })
            .collect(),
    )
}

// ------------------------------------------------------------------ clients

/// What the client saw of one pair.
#[derive(Clone, Debug)]
struct Reply {
    latency_ms: f64,
    queue_ms: f64,
    decode_ms: f64,
    track_ms: f64,
    total_ms: f64,
    status: String,
}

impl Reply {
    fn from_json(v: &Value, latency_ms: f64) -> Reply {
        if let Some(e) = v.get("error") {
            panic!("the server answered an error: {e}");
        }
        let t = |k: &str| v["timing_ms"][k].as_f64().unwrap_or(f64::NAN);
        Reply {
            latency_ms,
            queue_ms: t("queue"),
            decode_ms: t("decode"),
            track_ms: t("track"),
            total_ms: t("total"),
            status: v["status"].as_str().unwrap_or("?").to_string(),
        }
    }
}

/// The timed part of one client.
struct Run {
    replies: Vec<Reply>,
    first_send: Instant,
    last_reply: Instant,
}

async fn create_session(http: &reqwest::Client, server: &Server) -> String {
    create_session_with(http, server, json!({})).await
}

/// A session with `objects` objects, every one named after the sequence's
/// one blob (each its own tracker: the cost of several objects per pair).
async fn create_objects_session(http: &reqwest::Client, server: &Server, objects: usize) -> String {
    let objects: Vec<Value> = (0..objects).map(|k| json!({"name": format!("o{k}")})).collect();
    create_session_with(http, server, json!({"objects": objects})).await
}

async fn create_session_with(http: &reqwest::Client, server: &Server, body: Value) -> String {
    let response = http
        .post(server.url("/v1/sessions"))
        .json(&body)
        .send()
        .await
        .expect("POST /v1/sessions");
    assert_eq!(response.status().as_u16(), 201, "creating a session");
    let body: Value = response.json().await.expect("session JSON");
    body["id"].as_str().expect("session id").to_string()
}

type Ws = tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

async fn connect(server: &Server, session: &str) -> Ws {
    let url = format!("ws://{}/v1/sessions/{session}/stream?policy=all", server.addr);
    tokio_tungstenite::connect_async(url)
        .await
        .expect("WebSocket connect")
        .0
}

/// The next text message as JSON (pings and pongs skipped).
async fn next_json<S>(stream: &mut S) -> Value
where
    S: futures_util::Stream<Item = Result<Message, tokio_tungstenite::tungstenite::Error>> + Unpin,
{
    loop {
        match stream.next().await {
            Some(Ok(Message::Text(text))) => return serde_json::from_str(&text).expect("reply JSON"),
            Some(Ok(Message::Ping(_) | Message::Pong(_))) => continue,
            other => panic!("expected a text reply, got {other:?}"),
        }
    }
}

/// Sends `messages[..warmup]` one at a time (each waits for its reply), waits
/// at the barrier, then sends `messages[warmup..]` pipelined (or paced every
/// `pace`) while the replies are read.
async fn ws_client(
    ws: Ws,
    messages: Arc<Vec<Bytes>>,
    warmup: usize,
    pace: Option<Duration>,
    barrier: Arc<Barrier>,
) -> Run {
    let (mut sink, mut stream) = ws.split();
    for m in &messages[..warmup] {
        sink.send(Message::Binary(m.clone())).await.expect("send");
        Reply::from_json(&next_json(&mut stream).await, 0.0);
    }
    let n = messages.len() - warmup;
    barrier.wait().await;
    let t0 = Instant::now();
    let sent: Arc<Vec<AtomicU64>> = Arc::new((0..n).map(|_| AtomicU64::new(u64::MAX)).collect());
    let sender = {
        let (sent, messages) = (sent.clone(), messages.clone());
        tokio::spawn(async move {
            for k in 0..n {
                if let Some(pace) = pace {
                    tokio::time::sleep_until(tokio::time::Instant::from_std(t0 + pace * k as u32)).await;
                }
                sent[k].store(t0.elapsed().as_nanos() as u64, Ordering::Release);
                sink.send(Message::Binary(messages[warmup + k].clone()))
                    .await
                    .expect("send");
            }
            sink
        })
    };
    let mut replies = Vec::with_capacity(n);
    let mut last_reply = t0;
    for k in 0..n {
        let v = next_json(&mut stream).await;
        last_reply = Instant::now();
        let seq = v["seq"].as_u64().expect("reply seq") as usize;
        assert_eq!(seq, warmup + k, "replies arrive in order under policy=all");
        let sent_ns = sent[k].load(Ordering::Acquire);
        assert_ne!(sent_ns, u64::MAX, "reply before its pair was sent");
        let latency = ms(last_reply - t0) - sent_ns as f64 / 1e6;
        replies.push(Reply::from_json(&v, latency));
    }
    let mut sink = sender.await.expect("sender task");
    let _ = sink.send(Message::Close(None)).await;
    Run {
        replies,
        first_send: t0,
        last_reply,
    }
}

fn multipart(pair: &(Vec<u8>, Vec<u8>)) -> reqwest::multipart::Form {
    let part = |bytes: &Vec<u8>, name: &str| {
        reqwest::multipart::Part::bytes(bytes.clone())
            .file_name(format!("{name}.png"))
            .mime_str("image/png")
            .expect("mime")
    };
    reqwest::multipart::Form::new()
        .part("left", part(&pair.0, "left"))
        .part("right", part(&pair.1, "right"))
}

async fn upload(http: &reqwest::Client, url: &str, form: reqwest::multipart::Form) -> Value {
    let response = http.post(url).multipart(form).send().await.expect("upload");
    let status = response.status();
    let body: Value = response.json().await.expect("upload reply JSON");
    assert!(status.is_success(), "upload failed: {status} {body}");
    body
}

/// Uploads `warmup` pairs, waits at the barrier, then `n` more, one at a time.
async fn rest_client(
    http: reqwest::Client,
    url: String,
    pngs: Arc<Vec<(Vec<u8>, Vec<u8>)>>,
    warmup: usize,
    n: usize,
    barrier: Arc<Barrier>,
) -> Run {
    let pair = |k: usize| &pngs[pool_index(k, pngs.len())];
    for k in 0..warmup {
        Reply::from_json(&upload(&http, &url, multipart(pair(k))).await, 0.0);
    }
    barrier.wait().await;
    let first_send = Instant::now();
    let mut replies = Vec::with_capacity(n);
    let mut last_reply = first_send;
    for k in warmup..warmup + n {
        let form = multipart(pair(k));
        let t = Instant::now();
        let v = upload(&http, &url, form).await;
        last_reply = Instant::now();
        replies.push(Reply::from_json(&v, ms(last_reply - t)));
    }
    Run {
        replies,
        first_send,
        last_reply,
    }
}

// ---------------------------------------------------------------- summaries

/// Figures of one scenario.
#[derive(Debug)]
struct Summary {
    name: &'static str,
    what: String,
    clients: usize,
    pairs: usize,
    pairs_per_s: f64,
    latency_median_ms: f64,
    latency_p99_ms: f64,
    queue_ms: f64,
    decode_ms: f64,
    track_ms: f64,
    total_ms: f64,
    processing_ms: f64,
    server_cpu_ms_per_pair: f64,
    client_cpu_ms_per_pair: f64,
    server_faults_per_pair: f64,
    not_tracked: usize,
}

impl Summary {
    fn new(name: &'static str, what: String, runs: &[Run], cpu: Usage) -> Summary {
        let replies: Vec<&Reply> = runs.iter().flat_map(|r| &r.replies).collect();
        let first = runs.iter().map(|r| r.first_send).min().expect("runs");
        let last = runs.iter().map(|r| r.last_reply).max().expect("runs");
        let pairs = replies.len();
        let col = |f: fn(&Reply) -> f64| median(&replies.iter().map(|r| f(r)).collect::<Vec<_>>());
        let latencies: Vec<f64> = replies.iter().map(|r| r.latency_ms).collect();
        Summary {
            name,
            what,
            clients: runs.len(),
            pairs,
            pairs_per_s: pairs as f64 / (last - first).as_secs_f64(),
            latency_median_ms: median(&latencies),
            latency_p99_ms: percentile(&latencies, 0.99),
            queue_ms: col(|r| r.queue_ms),
            decode_ms: col(|r| r.decode_ms),
            track_ms: col(|r| r.track_ms),
            total_ms: col(|r| r.total_ms),
            processing_ms: col(|r| r.total_ms - r.queue_ms),
            server_cpu_ms_per_pair: cpu.server_cpu_s * 1e3 / pairs as f64,
            client_cpu_ms_per_pair: cpu.client_cpu_s * 1e3 / pairs as f64,
            server_faults_per_pair: cpu.server_minor_faults as f64 / pairs as f64,
            not_tracked: replies.iter().filter(|r| r.status != "tracked").count(),
        }
    }

    fn json(&self) -> Value {
        json!({
            "what": self.what,
            "clients": self.clients,
            "pairs": self.pairs,
            "pairs_per_s": r3(self.pairs_per_s),
            "latency_median_ms": r3(self.latency_median_ms),
            "latency_p99_ms": r3(self.latency_p99_ms),
            "server_timing_median_ms": {
                "queue": r3(self.queue_ms), "decode": r3(self.decode_ms),
                "track": r3(self.track_ms), "total": r3(self.total_ms),
            },
            "server_processing_median_ms": r3(self.processing_ms),
            "server_cpu_ms_per_pair": r3(self.server_cpu_ms_per_pair),
            "client_cpu_ms_per_pair": r3(self.client_cpu_ms_per_pair),
            "server_minor_page_faults_per_pair": r3(self.server_faults_per_pair),
            "not_tracked": self.not_tracked,
        })
    }
}

/// CPU seconds of the server and of this process spent while `f` runs.
struct CpuMeter {
    server_pid: u32,
    ticks: f64,
    start: Usage,
}

/// CPU seconds of the server and of this process, and the server's minor
/// page faults.
#[derive(Clone, Copy, Debug)]
struct Usage {
    server_cpu_s: f64,
    client_cpu_s: f64,
    server_minor_faults: u64,
}

impl CpuMeter {
    fn start(server: &Server, ticks: f64) -> CpuMeter {
        let pid = server.pid();
        CpuMeter {
            server_pid: pid,
            ticks,
            start: Self::now(pid, ticks),
        }
    }

    fn now(pid: u32, ticks: f64) -> Usage {
        Usage {
            server_cpu_s: cpu_seconds(pid, ticks),
            client_cpu_s: cpu_seconds(std::process::id(), ticks),
            server_minor_faults: minor_faults(pid),
        }
    }

    fn stop(&self) -> Usage {
        let end = Self::now(self.server_pid, self.ticks);
        Usage {
            server_cpu_s: end.server_cpu_s - self.start.server_cpu_s,
            client_cpu_s: end.client_cpu_s - self.start.client_cpu_s,
            server_minor_faults: end.server_minor_faults - self.start.server_minor_faults,
        }
    }
}

// --------------------------------------------------------------- scenarios

/// What a live-view page does while a stream runs: follows the session's
/// result events and, after each batch of them, fetches both latest images
/// at the page's size (900 px). Counts events and images.
async fn viewer(http: reqwest::Client, url: String, counts: Arc<[AtomicU64; 2]>) {
    let Ok(mut events) = http.get(format!("{url}/events")).send().await else {
        return;
    };
    let mut text = String::new();
    while let Ok(Some(chunk)) = events.chunk().await {
        text.push_str(&String::from_utf8_lossy(&chunk));
        let mut fresh = 0;
        while let Some(end) = text.find("\n\n") {
            let block: String = text.drain(..end + 2).collect();
            fresh += u64::from(block.contains("event: result"));
        }
        if fresh == 0 {
            continue;
        }
        counts[0].fetch_add(fresh, Ordering::Relaxed);
        for side in ["left", "right"] {
            let image = http
                .get(format!("{url}/frames/latest/{side}?max_side=900"))
                .send()
                .await;
            if let Ok(r) = image {
                if r.status().is_success() && r.bytes().await.is_ok() {
                    counts[1].fetch_add(1, Ordering::Relaxed);
                }
            }
        }
    }
}

/// `clients` WebSockets (one session each), each optionally watched by a
/// [`viewer`]; returns the runs and the CPU used, and the viewers' event and
/// image counts.
#[allow(clippy::too_many_arguments)]
async fn ws_scenario(
    server: &Server,
    http: &reqwest::Client,
    ticks: f64,
    messages: &Arc<Vec<Bytes>>,
    clients: usize,
    warmup: usize,
    pace: Option<Duration>,
    viewed: bool,
    objects: usize,
) -> (Vec<Run>, Usage, [u64; 2]) {
    let barrier = Arc::new(Barrier::new(clients + 1));
    let mut tasks = Vec::new();
    let counts = Arc::new([AtomicU64::new(0), AtomicU64::new(0)]);
    let mut viewers = Vec::new();
    for _ in 0..clients {
        let session = match objects {
            1 => create_session(http, server).await,
            n => create_objects_session(http, server, n).await,
        };
        if viewed {
            let url = format!("http://{}/v1/sessions/{session}", server.addr);
            viewers.push(tokio::spawn(viewer(http.clone(), url, counts.clone())));
        }
        let ws = connect(server, &session).await;
        tasks.push(tokio::spawn(ws_client(
            ws,
            messages.clone(),
            warmup,
            pace,
            barrier.clone(),
        )));
    }
    let (runs, usage) = measure(server, ticks, &barrier, tasks).await;
    for v in viewers {
        v.abort();
    }
    let seen = [
        counts[0].load(Ordering::Relaxed),
        counts[1].load(Ordering::Relaxed),
    ];
    (runs, usage, seen)
}

#[allow(clippy::too_many_arguments)]
async fn rest_scenario(
    server: &Server,
    http: &reqwest::Client,
    ticks: f64,
    pngs: &Arc<Vec<(Vec<u8>, Vec<u8>)>>,
    clients: usize,
    warmup: usize,
    n: usize,
) -> (Vec<Run>, Usage) {
    let barrier = Arc::new(Barrier::new(clients + 1));
    let mut tasks = Vec::new();
    for _ in 0..clients {
        let session = create_session(http, server).await;
        let url = server.url(&format!("/v1/sessions/{session}/frames"));
        tasks.push(tokio::spawn(rest_client(
            http.clone(),
            url,
            pngs.clone(),
            warmup,
            n,
            barrier.clone(),
        )));
    }
    measure(server, ticks, &barrier, tasks).await
}

/// Waits until every client has finished its warm-up (the barrier), then
/// measures CPU use until all of them are done.
async fn measure(
    server: &Server,
    ticks: f64,
    barrier: &Barrier,
    tasks: Vec<tokio::task::JoinHandle<Run>>,
) -> (Vec<Run>, Usage) {
    barrier.wait().await;
    let cpu = CpuMeter::start(server, ticks);
    let mut runs = Vec::new();
    for t in tasks {
        runs.push(t.await.expect("client task"));
    }
    (runs, cpu.stop())
}

/// Server memory per idle session, on a fresh server: RSS after a warm-up
/// session, then after `count` more sessions that each processed one pair.
async fn idle_memory(http: &reqwest::Client, pngs: &Arc<Vec<(Vec<u8>, Vec<u8>)>>, count: usize) -> Value {
    let server = Server::start(&["--max-sessions", "1024"]);
    let started_kib = server.rss_kib();
    // Warm-up: the allocator's working set for decoding and tracking.
    let warm = create_session(http, &server).await;
    let url = server.url(&format!("/v1/sessions/{warm}/frames"));
    for k in 0..3 {
        upload(http, &url, multipart(&pngs[pool_index(k, pngs.len())])).await;
    }
    tokio::time::sleep(Duration::from_millis(500)).await;
    let before_kib = server.rss_kib();
    let t = Instant::now();
    let init_latencies = Arc::new(Mutex::new(Vec::new()));
    // Two clients at a time: the first pair of a session is an initialisation.
    let next = Arc::new(AtomicU64::new(0));
    let mut tasks = Vec::new();
    for _ in 0..2 {
        let (http, pngs, next, lat) = (http.clone(), pngs.clone(), next.clone(), init_latencies.clone());
        let base = server.url("");
        let server_sessions = base.clone();
        tasks.push(tokio::spawn(async move {
            loop {
                let k = next.fetch_add(1, Ordering::Relaxed) as usize;
                if k >= count {
                    break;
                }
                let response = http
                    .post(format!("{server_sessions}/v1/sessions"))
                    .json(&json!({}))
                    .send()
                    .await
                    .expect("POST /v1/sessions");
                let body: Value = response.json().await.expect("session JSON");
                let id = body["id"].as_str().expect("session id").to_string();
                let form = multipart(&pngs[pool_index(k, pngs.len())]);
                let t = Instant::now();
                let v = upload(&http, &format!("{base}/v1/sessions/{id}/frames"), form).await;
                let status = v["status"].as_str().unwrap_or("?").to_string();
                lat.lock().expect("lock").push((ms(t.elapsed()), status));
            }
        }));
    }
    for t in tasks {
        t.await.expect("client task");
    }
    let fill_s = t.elapsed().as_secs_f64();
    tokio::time::sleep(Duration::from_secs(1)).await;
    let after_kib = server.rss_kib();
    let peak_kib = server.peak_rss_kib();
    let lat = init_latencies.lock().expect("lock").clone();
    let init_ms: Vec<f64> = lat.iter().map(|(l, _)| *l).collect();
    let initialised = lat.iter().filter(|(_, s)| s == "initialised").count();
    let warnings = server.warnings();
    server.stop();
    let per_session_mb = (after_kib as f64 - before_kib as f64) * 1024.0 / count as f64 / 1e6;
    json!({
        "sessions": count,
        "rss_at_start_mb": r3(started_kib as f64 * 1024.0 / 1e6),
        "rss_before_mb": r3(before_kib as f64 * 1024.0 / 1e6),
        "rss_after_mb": r3(after_kib as f64 * 1024.0 / 1e6),
        "peak_rss_mb": r3(peak_kib as f64 * 1024.0 / 1e6),
        "per_session_mb": r3(per_session_mb),
        "first_pair_rest_png_median_ms": r3(median(&init_ms)),
        "first_pairs_initialised": initialised,
        "fill_s": r3(fill_s),
        "server_warnings": warnings,
    })
}

// --------------------------------------------------------------- references

fn reference_sum_ms(data: &Data, reps: usize) -> f64 {
    let (l, r) = &data.raw[0];
    let sum = |b: &[u8]| b.iter().map(|&v| v as u64).sum::<u64>();
    let mut times = Vec::with_capacity(reps);
    for _ in 0..reps.max(20) {
        let t = Instant::now();
        std::hint::black_box(sum(std::hint::black_box(l)) + sum(std::hint::black_box(r)));
        times.push(ms(t.elapsed()));
    }
    median(&times)
}

/// In-process tracking step (no service) on the pool pairs, played like the
/// WebSocket scenarios play them: median wall time, and the share of the
/// wall time the thread spent on a CPU (the rest it waited for a core).
fn reference_track_ms(data: &Data, reps: usize) -> (f64, f64) {
    let pool = data.frames.len();
    let mut tracker = StereoTracker::new(TrackerParams::default());
    let (l, r) = &data.frames[0];
    tracker.process(l, r).expect("first pair");
    let mut times = Vec::with_capacity(reps);
    // The run time is accounted in scheduler ticks here: only the total is
    // meaningful.
    let (cpu0, wall0) = (thread_run_ns(), Instant::now());
    for k in 1..=reps.clamp(20, 200) {
        let (l, r) = &data.frames[pool_index(k, pool)];
        let t = Instant::now();
        std::hint::black_box(tracker.process(l, r).expect("pair"));
        times.push(ms(t.elapsed()));
    }
    let on_cpu = match (cpu0, thread_run_ns()) {
        (Some(a), Some(b)) => (b - a) as f64 / 1e9 / wall0.elapsed().as_secs_f64(),
        _ => f64::NAN,
    };
    (median(&times), on_cpu)
}

async fn reference_healthz(http: &reqwest::Client, server: &Server, reps: usize) -> (f64, f64) {
    let url = server.url("/healthz");
    let mut times = Vec::with_capacity(reps);
    for k in 0..reps + 20 {
        let t = Instant::now();
        let response = http.get(&url).send().await.expect("GET /healthz");
        assert!(response.status().is_success());
        response.bytes().await.expect("healthz body");
        if k >= 20 {
            times.push(ms(t.elapsed()));
        }
    }
    (median(&times), percentile(&times, 0.99))
}

/// Round trip of a pair-sized message the server rejects at once (bad
/// magic): transport, framing and unmasking without decoding or tracking.
async fn reference_ws_transport(
    http: &reqwest::Client,
    server: &Server,
    size: usize,
    reps: usize,
) -> (f64, f64) {
    let session = create_session(http, server).await;
    let (mut sink, mut stream) = connect(server, &session).await.split();
    let mut bytes = vec![0u8; size];
    bytes[..8].copy_from_slice(b"SDP0\0\0\0\0");
    let message = Bytes::from(bytes);
    let mut times = Vec::new();
    for k in 0..reps.min(100) + 5 {
        let t = Instant::now();
        sink.send(Message::Binary(message.clone())).await.expect("send");
        let v = next_json(&mut stream).await;
        assert_eq!(v["error"]["code"], "bad_magic", "{v}");
        if k >= 5 {
            times.push(ms(t.elapsed()));
        }
    }
    let _ = sink.send(Message::Close(None)).await;
    (median(&times), percentile(&times, 0.99))
}

// --------------------------------------------------------------------- main

fn main() {
    let mut quick = false;
    let mut filters = Vec::new();
    for arg in std::env::args().skip(1) {
        match arg.as_str() {
            "--quick" => quick = true,
            a if a.starts_with('-') => {} // --bench and other harness flags
            a => filters.push(a.to_string()),
        }
    }
    let wanted = |name: &str| filters.is_empty() || filters.iter().any(|f| name.contains(f.as_str()));
    let sizes = Sizes::new(quick);
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .expect("tokio runtime");
    if filters.iter().any(|f| f == "soak") {
        let minutes = std::env::var("SOAK_MINUTES")
            .ok()
            .and_then(|m| m.parse::<f64>().ok())
            .unwrap_or(20.0);
        runtime.block_on(soak(sizes.pool, minutes));
        return;
    }
    runtime.block_on(run(sizes, quick, &wanted));
}

/// Streams of the soak test.
const SOAK_STREAMS: usize = 4;
/// Sampling period of the soak test.
const SOAK_SAMPLE: Duration = Duration::from_secs(10);

/// The soak test: [`SOAK_STREAMS`] streams for `minutes`, sampled every
/// [`SOAK_SAMPLE`].
async fn soak(pool: usize, minutes: f64) {
    let data = render(pool);
    let server = Server::start(&["--max-sessions", "1024"]);
    let http = reqwest::Client::new();
    let messages = messages(&data, 2 * pool);
    let deadline = Instant::now() + Duration::from_secs_f64(minutes * 60.0);
    let latencies = Arc::new(Mutex::new(Vec::<f64>::new()));
    let errors = Arc::new(AtomicU64::new(0));
    let mut clients = Vec::new();
    for _ in 0..SOAK_STREAMS {
        // Each stream keeps its last `SOAK_RETENTION` (default 1,000)
        // results: 20 minutes at ~250 pairs/s per stream with the server's
        // default retention filled a 9.5 GB disk at minute 19.
        let retention: u64 = std::env::var("SOAK_RETENTION")
            .ok()
            .and_then(|r| r.parse().ok())
            .unwrap_or(1000);
        let created: Value = http
            .post(server.url("/v1/sessions"))
            .json(&json!({"retention": retention}))
            .send()
            .await
            .expect("create a session")
            .json()
            .await
            .expect("session JSON");
        let session = created["id"].as_str().expect("session id").to_string();
        let ws = connect(&server, &session).await;
        let (messages, latencies, errors) = (messages.clone(), latencies.clone(), errors.clone());
        clients.push(tokio::spawn(async move {
            let (mut sink, mut stream) = ws.split();
            let mut k = 0usize;
            while Instant::now() < deadline {
                let t = Instant::now();
                sink.send(Message::Binary(messages[k % messages.len()].clone()))
                    .await
                    .expect("send");
                let v = next_json(&mut stream).await;
                if v.get("error").is_some() {
                    errors.fetch_add(1, Ordering::Relaxed);
                    eprintln!("soak: error reply {v}");
                }
                latencies.lock().unwrap().push(ms(t.elapsed()));
                k += 1;
            }
            let _ = sink.send(Message::Close(None)).await;
            k
        }));
    }
    let start = Instant::now();
    let mut samples = Vec::new();
    println!("soak: {SOAK_STREAMS} streams of {WIDTH}x{HEIGHT} raw pairs for {minutes} min");
    println!(
        "{:>7} {:>9} {:>7} {:>8} {:>8}",
        "t s", "RSS MiB", "pairs", "p50 ms", "p99 ms"
    );
    while Instant::now() < deadline {
        tokio::time::sleep(SOAK_SAMPLE.min(deadline.saturating_duration_since(Instant::now()))).await;
        let window: Vec<f64> = std::mem::take(&mut *latencies.lock().unwrap());
        let rss = server.rss_kib() as f64 / 1024.0;
        let t = start.elapsed().as_secs_f64();
        let (p50, p99) = (median(&window), percentile(&window, 0.99));
        println!("{t:>7.0} {rss:>9.1} {:>7} {p50:>8.2} {p99:>8.2}", window.len());
        samples.push(json!({"t_s": r3(t), "rss_mib": r3(rss), "pairs": window.len(), "p50_ms": r3(p50), "p99_ms": r3(p99)}));
    }
    let mut pairs = 0;
    for c in clients {
        pairs += c.await.expect("soak client");
    }
    // Least-squares slope of the RSS over the second half, MiB per minute.
    let half: Vec<(f64, f64)> = samples[samples.len() / 2..]
        .iter()
        .map(|s| (s["t_s"].as_f64().unwrap() / 60.0, s["rss_mib"].as_f64().unwrap()))
        .collect();
    let n = half.len() as f64;
    let (mt, mr) = (
        half.iter().map(|h| h.0).sum::<f64>() / n,
        half.iter().map(|h| h.1).sum::<f64>() / n,
    );
    let slope = half.iter().map(|h| (h.0 - mt) * (h.1 - mr)).sum::<f64>()
        / half.iter().map(|h| (h.0 - mt).powi(2)).sum::<f64>().max(1e-12);
    let rss: Vec<f64> = samples.iter().map(|s| s["rss_mib"].as_f64().unwrap()).collect();
    let summary = json!({
        "streams": SOAK_STREAMS,
        "minutes": minutes,
        "pairs": pairs,
        "error_replies": errors.load(Ordering::Relaxed),
        "rss_first_mib": rss.first(),
        "rss_last_mib": rss.last(),
        "rss_max_mib": rss.iter().cloned().fold(0.0, f64::max),
        "rss_slope_second_half_mib_per_min": r3(slope),
        "samples": samples,
    });
    println!(
        "soak: {pairs} pairs; RSS {:.1} MiB after {:.0} s, {:.1} MiB at the end, max {:.1}; second half {slope:+.3} MiB/min",
        rss.first().unwrap_or(&0.0),
        SOAK_SAMPLE.as_secs_f64(),
        rss.last().unwrap_or(&0.0),
        rss.iter().cloned().fold(0.0, f64::max)
    );
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/soak.json");
    std::fs::write(&path, serde_json::to_string_pretty(&summary).unwrap()).expect("write soak.json");
    println!("written to {}", path.display());
}

async fn run(sizes: Sizes, quick: bool, wanted: &dyn Fn(&str) -> bool) {
    let wall = Instant::now();
    let load_start = load_average();
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    let ticks = clock_ticks();
    eprintln!(
        "service_load: {} mode, {cores} cores, load average {load_start}; rendering {} pairs of {WIDTH}x{HEIGHT}",
        if quick { "quick" } else { "full" },
        sizes.pool
    );
    let data = render(sizes.pool);
    let pair_bytes = data.raw[0].0.len() + data.raw[0].1.len();
    let png_bytes = median(
        &data
            .png
            .iter()
            .map(|(l, r)| (l.len() + r.len()) as f64)
            .collect::<Vec<_>>(),
    );
    let http = reqwest::Client::new();

    eprintln!("service_load: references");
    let sum_ms = reference_sum_ms(&data, sizes.reference_reps * 5);
    let (track_ms, track_on_cpu) = reference_track_ms(&data, sizes.reference_reps);
    let server = Server::start(&["--max-sessions", "1024"]);
    let rss_start_kib = server.rss_kib();
    // CPU of the whole machine, of the server and of this process from here
    // until the server stops: what is left is what other processes took.
    let machine_start = (machine_ticks(), Instant::now());
    let ours_start = cpu_seconds(server.pid(), ticks) + cpu_seconds(std::process::id(), ticks);
    let (healthz_ms, healthz_p99_ms) = reference_healthz(&http, &server, sizes.reference_reps).await;
    let (transport_ms, transport_p99_ms) =
        reference_ws_transport(&http, &server, pair_bytes + 150, sizes.reference_reps).await;

    let mut summaries = Vec::new();
    let largest = sizes.ws_warmup + sizes.ws_pairs.max(sizes.paced_pairs);
    let ws_messages = if wanted("ws_one") || wanted("ws_viewed") || wanted("ws_paced") || wanted("ws_objects")
    {
        messages(&data, largest)
    } else {
        Arc::new(Vec::new())
    };
    if wanted("ws_one") {
        eprintln!("service_load: ws_one");
        let msgs = Arc::new(ws_messages[..sizes.ws_warmup + sizes.ws_pairs].to_vec());
        let (runs, cpu, _) =
            ws_scenario(&server, &http, ticks, &msgs, 1, sizes.ws_warmup, None, false, 1).await;
        summaries.push(Summary::new(
            "ws_one",
            "1 WebSocket, raw 8-bit, pipelined, policy=all".into(),
            &runs,
            cpu,
        ));
    }
    // With one worker slot a session's objects are tracked one after the
    // other: the reference for tracking them side by side.
    let one_worker =
        wanted("ws_objects").then(|| Server::start(&["--max-sessions", "1024", "--workers", "1"]));
    for (objects, name, server) in [
        (2usize, "ws_objects_2", &server),
        (4, "ws_objects_4", &server),
        (
            2,
            "ws_objects_2_one_worker",
            one_worker.as_ref().unwrap_or(&server),
        ),
        (
            4,
            "ws_objects_4_one_worker",
            one_worker.as_ref().unwrap_or(&server),
        ),
    ] {
        if !wanted(name) || (name.ends_with("one_worker") && one_worker.is_none()) {
            continue;
        }
        eprintln!("service_load: {name}");
        let msgs = Arc::new(ws_messages[..sizes.ws_warmup + sizes.ws_pairs].to_vec());
        let (runs, cpu, _) = ws_scenario(
            server,
            &http,
            ticks,
            &msgs,
            1,
            sizes.ws_warmup,
            None,
            false,
            objects,
        )
        .await;
        summaries.push(Summary::new(
            name,
            format!(
                "as ws_one, the session tracking {objects} objects (each its own tracker on the one blob){}",
                if name.ends_with("one_worker") {
                    ", one worker slot (objects one after the other)"
                } else {
                    ""
                }
            ),
            &runs,
            cpu,
        ));
    }
    if wanted("ws_viewed") {
        eprintln!("service_load: ws_viewed");
        let msgs = Arc::new(ws_messages[..sizes.ws_warmup + sizes.ws_pairs].to_vec());
        let (runs, cpu, [events, images]) =
            ws_scenario(&server, &http, ticks, &msgs, 1, sizes.ws_warmup, None, true, 1).await;
        summaries.push(Summary::new(
            "ws_viewed",
            format!("as ws_one, watched by a live view ({events} events, {images} images of 900 px)"),
            &runs,
            cpu,
        ));
    }
    if wanted("ws_paced") {
        eprintln!("service_load: ws_paced");
        let msgs = Arc::new(ws_messages[..sizes.ws_warmup + sizes.paced_pairs].to_vec());
        let pace = Duration::from_secs_f64(1.0 / PACED_RATE);
        let (runs, cpu, _) = ws_scenario(
            &server,
            &http,
            ticks,
            &msgs,
            1,
            sizes.ws_warmup,
            Some(pace),
            false,
            1,
        )
        .await;
        summaries.push(Summary::new(
            "ws_paced",
            format!("1 WebSocket, raw 8-bit, paced at {PACED_RATE} pairs/s"),
            &runs,
            cpu,
        ));
    }
    drop(ws_messages);
    if wanted("ws_eight") {
        eprintln!("service_load: ws_eight");
        let msgs = messages(&data, sizes.multi_warmup + sizes.multi_pairs_each);
        let (runs, cpu, _) = ws_scenario(
            &server,
            &http,
            ticks,
            &msgs,
            sizes.multi_clients,
            sizes.multi_warmup,
            None,
            false,
            1,
        )
        .await;
        summaries.push(Summary::new(
            "ws_eight",
            format!(
                "{} WebSockets (one session each), raw 8-bit, pipelined",
                sizes.multi_clients
            ),
            &runs,
            cpu,
        ));
    }
    let pngs = Arc::new(data.png.clone());
    if wanted("rest_one") {
        eprintln!("service_load: rest_one");
        let (runs, cpu) = rest_scenario(
            &server,
            &http,
            ticks,
            &pngs,
            1,
            sizes.rest_warmup,
            sizes.rest_pairs,
        )
        .await;
        summaries.push(Summary::new(
            "rest_one",
            "REST multipart PNG, 1 client, sequential".into(),
            &runs,
            cpu,
        ));
    }
    if wanted("rest_four") {
        eprintln!("service_load: rest_four");
        let (runs, cpu) = rest_scenario(
            &server,
            &http,
            ticks,
            &pngs,
            sizes.rest_clients,
            sizes.rest_warmup,
            sizes.rest_pairs_each,
        )
        .await;
        summaries.push(Summary::new(
            "rest_four",
            format!(
                "REST multipart PNG, {} clients (one session each)",
                sizes.rest_clients
            ),
            &runs,
            cpu,
        ));
    }
    let rss_end_kib = server.rss_kib();
    let peak_kib = server.peak_rss_kib();
    let warnings = server.warnings();
    let ours_s = cpu_seconds(server.pid(), ticks) + cpu_seconds(std::process::id(), ticks) - ours_start;
    let machine_busy_s = (machine_ticks().0 - machine_start.0 .0) as f64 / ticks;
    let machine_s = machine_start.1.elapsed().as_secs_f64();
    let others_cores = ((machine_busy_s - ours_s) / machine_s).max(0.0);
    let ours_cores = ours_s / machine_s;
    server.stop();
    let memory = if wanted("idle_memory") {
        eprintln!("service_load: idle_memory ({} sessions)", sizes.idle_sessions);
        Some(idle_memory(&http, &pngs, sizes.idle_sessions).await)
    } else {
        None
    };
    let wall_s = wall.elapsed().as_secs_f64();
    let load_end = load_average();

    // ------------------------------------------------------------ report
    let mb = |kib: u64| kib as f64 * 1024.0 / 1e6;
    println!();
    println!(
        "service_load ({} mode): {WIDTH}x{HEIGHT} 8-bit pairs ({:.2} MB raw, {:.2} MB PNG), {cores} cores, load average {load_start} -> {load_end}",
        if quick { "quick" } else { "full" },
        pair_bytes as f64 / 1e6,
        png_bytes / 1e6
    );
    println!(
        "CPU during the scenarios: this benchmark (server and clients) {ours_cores:.2} cores, other processes {others_cores:.2} cores"
    );
    println!(
        "references: sum of both images {sum_ms:.3} ms; in-process track step {track_ms:.3} ms \
         (on a CPU {:.0}% of the time); \
         GET /healthz round trip {healthz_ms:.3} ms (p99 {healthz_p99_ms:.3}); \
         WebSocket round trip of a rejected pair-sized message {transport_ms:.3} ms (p99 {transport_p99_ms:.3})",
        track_on_cpu * 100.0
    );
    println!();
    println!(
        "{:<10} {:>3} {:>5} {:>8} {:>8} {:>8} | {:>6} {:>6} {:>6} {:>6} | {:>7} {:>7} | {:>7} | {:>5}",
        "scenario",
        "cl",
        "pairs",
        "pairs/s",
        "lat med",
        "lat p99",
        "queue",
        "decode",
        "track",
        "total",
        "srv cpu",
        "cli cpu",
        "faults",
        "!trk"
    );
    println!(
        "{:<10} {:>3} {:>5} {:>8} {:>8} {:>8} | {:>27} | {:>15} | {:>7} |",
        "", "", "", "", "ms", "ms", "server timing_ms medians", "ms per pair", "srv/pr"
    );
    for s in &summaries {
        println!(
            "{:<10} {:>3} {:>5} {:>8.1} {:>8.2} {:>8.2} | {:>6.2} {:>6.2} {:>6.2} {:>6.2} | {:>7.2} {:>7.2} | {:>7.0} | {:>5}",
            s.name,
            s.clients,
            s.pairs,
            s.pairs_per_s,
            s.latency_median_ms,
            s.latency_p99_ms,
            s.queue_ms,
            s.decode_ms,
            s.track_ms,
            s.total_ms,
            s.server_cpu_ms_per_pair,
            s.client_cpu_ms_per_pair,
            s.server_faults_per_pair,
            s.not_tracked
        );
    }
    println!();
    let find = |name: &str| summaries.iter().find(|s| s.name == name);
    let mut ratios = serde_json::Map::new();
    for s in &summaries {
        let interval = 1e3 / s.pairs_per_s;
        println!(
            "{:<10} {interval:6.2} ms per pair = {:5.1} x sum, {:4.2} x in-process track \
             (in server {:5.2}: decode+track {:5.2}); latency median = {:6.1} x /healthz, {:6.2} x WebSocket transport",
            s.name,
            interval / sum_ms,
            interval / track_ms,
            s.processing_ms,
            s.decode_ms + s.track_ms,
            s.latency_median_ms / healthz_ms,
            s.latency_median_ms / transport_ms,
        );
        ratios.insert(
            s.name.to_string(),
            json!({
                "ms_per_pair": r3(interval),
                "ms_per_pair_over_sum": r3(interval / sum_ms),
                "ms_per_pair_over_track": r3(interval / track_ms),
                "latency_median_over_healthz": r3(s.latency_median_ms / healthz_ms),
                "latency_median_over_ws_transport": r3(s.latency_median_ms / transport_ms),
            }),
        );
    }
    println!(
        "server RSS: {:.1} MB at start, {:.1} MB after the scenarios, peak {:.1} MB",
        mb(rss_start_kib),
        mb(rss_end_kib),
        mb(peak_kib)
    );
    if let Some(m) = &memory {
        println!(
            "idle sessions (fresh server): {} sessions, RSS {} -> {} MB: {} MB per session; first pair (initialisation, REST PNG) median {} ms",
            m["sessions"], m["rss_before_mb"], m["rss_after_mb"], m["per_session_mb"], m["first_pair_rest_png_median_ms"]
        );
    }
    for w in &warnings {
        println!("server warning: {w}");
    }

    let mut targets = serde_json::Map::new();
    let mut verdict = |key: &str, label: String, value: f64, limit: f64, higher_is_better: bool| {
        let met = if higher_is_better {
            value >= limit
        } else {
            value < limit
        };
        println!(
            "target {label}: {} ({value:.2})",
            if met { "met" } else { "NOT met" }
        );
        targets.insert(
            key.to_string(),
            json!({"value": r3(value), "limit": limit, "met": met}),
        );
    };
    if let Some(s) = find("ws_one") {
        verdict(
            "ws_one_pairs_per_s",
            format!(">= {TARGET_WS_PAIRS_PER_S} pairs/s over one WebSocket"),
            s.pairs_per_s,
            TARGET_WS_PAIRS_PER_S,
            true,
        );
    }
    if let Some(s) = find("ws_paced") {
        verdict(
            "ws_paced_p99_ms",
            format!("p99 < {TARGET_PACED_P99_MS} ms at {PACED_RATE} pairs/s"),
            s.latency_p99_ms,
            TARGET_PACED_P99_MS,
            false,
        );
    }
    if let Some(m) = &memory {
        verdict(
            "idle_session_mb",
            format!("< {TARGET_IDLE_SESSION_MB} MB per idle session"),
            m["per_session_mb"].as_f64().unwrap_or(f64::NAN),
            TARGET_IDLE_SESSION_MB,
            false,
        );
    }
    println!("wall time {wall_s:.1} s");

    let report = json!({
        "mode": if quick { "quick" } else { "full" },
        "machine": {
            "cores": cores, "load_average_start": load_start, "load_average_end": load_end,
            "cores_used_by_benchmark": r3(ours_cores), "cores_used_by_others": r3(others_cores),
        },
        "pair": {"width": WIDTH, "height": HEIGHT, "raw_bytes": pair_bytes, "png_bytes_median": png_bytes},
        "sizes": format!("{sizes:?}"),
        "reference": {
            "sum_pair_ms": r3(sum_ms),
            "track_inprocess_ms": r3(track_ms),
            "track_inprocess_on_cpu_share": r3(track_on_cpu),
            "healthz_rtt_median_ms": r3(healthz_ms),
            "healthz_rtt_p99_ms": r3(healthz_p99_ms),
            "ws_transport_rtt_median_ms": r3(transport_ms),
            "ws_transport_rtt_p99_ms": r3(transport_p99_ms),
        },
        "scenarios": summaries.iter().map(|s| (s.name.to_string(), s.json())).collect::<serde_json::Map<_, _>>(),
        "ratios": ratios,
        "server_rss_mb": {"start": r3(mb(rss_start_kib)), "end": r3(mb(rss_end_kib)), "peak": r3(mb(peak_kib))},
        "idle_memory": memory,
        "targets": targets,
        "server_warnings": warnings,
        "wall_s": r3(wall_s),
    });
    let target_dir = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target"));
    let path = target_dir.join("service_load.json");
    match std::fs::create_dir_all(&target_dir)
        .and_then(|_| std::fs::write(&path, serde_json::to_string_pretty(&report).expect("JSON")))
    {
        Ok(()) => println!("figures written to {}", path.display()),
        Err(e) => eprintln!("cannot write {}: {e}", path.display()),
    }
}

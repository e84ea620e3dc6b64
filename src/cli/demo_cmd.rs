//! `semdepth demo`: the whole mission in one command. Generates a synthetic
//! stereo sequence with known heights, creates a calibration (from the
//! generator's stage geometry, as a lab would from stage steps) and a
//! session, streams the pairs over the WebSocket of a running server (or of
//! one started in-process on a free port with an in-memory database), and
//! prints frame, true z, measured z and error.

use std::time::{Duration, Instant};

use clap::Args;
use futures_util::{SinkExt, StreamExt};
use serde_json::{json, Value};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_tungstenite::tungstenite::Message;

use super::CliError;
use crate::service::state::ServiceConfig;
use crate::service::wire::encode_pair_message;
use semdepth_core::synth::{frames, Preset, Shape, SynthConfig};

/// Arguments of `semdepth demo`.
#[derive(Debug, Args)]
pub struct DemoArgs {
    /// A running server (`http://HOST:PORT`); default: start one in this
    /// process on a free loopback port with an in-memory database.
    #[arg(long, value_name = "URL")]
    pub server: Option<String>,
    /// Bearer token for `--server`.
    #[arg(long, env = "SEMDEPTH_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// Pairs to stream.
    #[arg(long, default_value_t = 12)]
    pub frames: usize,
    /// Synthetic condition.
    #[arg(long, value_parser = super::preset_value(), default_value = "noisy")]
    pub preset: Preset,
    /// Object shape.
    #[arg(long, value_parser = super::shape_value(), default_value = "blob")]
    pub shape: Shape,
    /// Scene seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Keep the demo's session and calibration on `--server` (default:
    /// deleted when the demo ends, so that runs do not pile up).
    #[arg(long)]
    pub keep: bool,
}

/// Runs the demo and prints the table.
pub fn run(args: DemoArgs) -> Result<(), CliError> {
    if !(1..=1000).contains(&args.frames) {
        return Err(CliError::input(format!(
            "invalid --frames {} (expected 1..=1000)",
            args.frames
        )));
    }
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|e| CliError::with_code(1, format!("error[runtime]: {e}")))?;
    runtime.block_on(demo(args))
}

async fn demo(args: DemoArgs) -> Result<(), CliError> {
    let started = Instant::now();
    let fail = |what: &str, e: String| CliError::with_code(1, format!("error[demo]: {what}: {e}"));
    // The server: given, or in-process.
    let (base, local) = match &args.server {
        Some(url) => (url.trim_end_matches('/').to_string(), None),
        None => {
            let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
                .await
                .map_err(|e| fail("listening on loopback", e.to_string()))?;
            let addr = listener
                .local_addr()
                .map_err(|e| fail("listener", e.to_string()))?;
            let config = ServiceConfig {
                db_path: ":memory:".into(),
                ..ServiceConfig::default()
            };
            let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
            let task = tokio::spawn(crate::service::serve(listener, config, async move {
                let _ = stopped.await;
            }));
            (format!("http://{addr}"), Some((stop, task)))
        }
    };
    let authority = base
        .strip_prefix("http://")
        .ok_or_else(|| CliError::input(format!("invalid --server {base:?} (expected http://HOST:PORT)")))?
        .to_string();
    let token = args.token.clone();
    wait_ready(&authority)
        .await
        .map_err(|e| fail("server not ready", e))?;

    let config = SynthConfig {
        frames: args.frames,
        ..SynthConfig::preset(args.preset, args.shape, args.seed)
    };
    println!(
        "semdepth demo: {} {} sequence, seed {}, {} pairs of {}x{}, server {base}",
        args.preset.name(),
        args.shape.name(),
        args.seed,
        args.frames,
        config.width,
        config.height
    );
    // Calibration from two stage heights of the generator's geometry (what a
    // lab does by moving the stage and recording the disparity).
    let d = config.disparity.clone();
    let (status, cal) = http_json(
        &authority,
        token.as_deref(),
        "POST",
        "/v1/calibrations",
        &json!({"name": "demo stage steps", "model": "fit", "degree": 1, "samples": [
            {"disparity_px": d.at(0.0), "z_um": 0.0},
            {"disparity_px": d.at(100.0), "z_um": 100.0}]}),
    )
    .await
    .map_err(|e| fail("creating the calibration", e))?;
    if status != 201 {
        return Err(fail("creating the calibration", cal.to_string()));
    }
    let (status, session) = http_json(
        &authority,
        token.as_deref(),
        "POST",
        "/v1/sessions",
        &json!({"name": "demo", "calibration_id": cal["id"]}),
    )
    .await
    .map_err(|e| fail("creating the session", e))?;
    if status != 201 {
        return Err(fail("creating the session", session.to_string()));
    }
    let sid = session["id"].as_str().unwrap_or_default().to_string();

    let mut request = tokio_tungstenite::tungstenite::client::IntoClientRequest::into_client_request(
        format!("ws://{authority}/v1/sessions/{sid}/stream?policy=all"),
    )
    .map_err(|e| fail("stream URL", e.to_string()))?;
    if let Some(t) = &token {
        let value = format!("Bearer {t}")
            .parse()
            .map_err(|_| CliError::input("invalid token (expected printable ASCII)"))?;
        request.headers_mut().insert("authorization", value);
    }
    let (mut ws, _) = tokio_tungstenite::connect_async(request)
        .await
        .map_err(|e| fail("opening the stream", e.to_string()))?;

    println!(
        "{:>5}  {:>10}  {:>10}  {:>8}  {:>11}  status",
        "frame", "true z um", "z um", "error", "track ms"
    );
    let mut errors = Vec::new();
    let sequence = frames(&config).map_err(|e| fail("generating", e.to_string()))?;
    for (seq, pair) in sequence.enumerate() {
        let (left, right) = (pair.left.to_gray8().into_raw(), pair.right.to_gray8().into_raw());
        let message = encode_pair_message(
            &json!({"seq": seq, "encoding": "raw", "width": pair.left.width,
                "height": pair.left.height, "bit_depth": 8, "left_len": left.len(), "right_len": right.len()}),
            &left,
            &right,
        );
        ws.send(Message::Binary(message.into()))
            .await
            .map_err(|e| fail("sending a pair", e.to_string()))?;
        let reply = loop {
            match tokio::time::timeout(Duration::from_secs(60), ws.next()).await {
                Ok(Some(Ok(Message::Text(t)))) => {
                    break serde_json::from_str::<Value>(&t).unwrap_or(Value::Null)
                }
                Ok(Some(Ok(_))) => continue,
                Ok(other) => return Err(fail("stream closed", format!("{other:?}"))),
                Err(_) => return Err(fail("stream", "no reply within 60 s".into())),
            }
        };
        if let Some(e) = reply.get("error") {
            return Err(fail("server refused a pair", e.to_string()));
        }
        let truth = pair.truth.z_um;
        let z = reply["z_um"].as_f64();
        let status = reply["status"].as_str().unwrap_or("?");
        let track = reply["timing_ms"]["track"].as_f64().unwrap_or(f64::NAN);
        match z {
            Some(z) => {
                errors.push(z - truth);
                println!(
                    "{seq:>5}  {truth:>10.2}  {z:>10.2}  {:>+8.2}  {track:>11.2}  {status}",
                    z - truth
                );
            }
            None => println!(
                "{seq:>5}  {truth:>10.2}  {:>10}  {:>8}  {track:>11.2}  {status} ({})",
                "-",
                "-",
                reply["reason"].as_str().unwrap_or("")
            ),
        }
    }
    let _ = ws.close(None).await;
    if !errors.is_empty() {
        let mean = errors.iter().sum::<f64>() / errors.len() as f64;
        let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
        let spread = (errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / errors.len() as f64).sqrt();
        println!(
            "z error over {} pairs: RMS {rms:.2} um (constant offset {mean:+.2} um, spread {spread:.2} um); 1 px of disparity is {:.1} um here",
            errors.len(),
            1.0 / d.px_per_um
        );
    }
    if local.is_none() && !args.keep {
        let cal_id = cal["id"].as_str().unwrap_or_default();
        for path in [
            format!("/v1/sessions/{sid}"),
            format!("/v1/calibrations/{cal_id}"),
        ] {
            match http_json(&authority, token.as_deref(), "DELETE", &path, &Value::Null).await {
                Ok((204, _)) => {}
                Ok((status, body)) => eprintln!("warning: DELETE {path}: {status} {body}"),
                Err(e) => eprintln!("warning: DELETE {path}: {e}"),
            }
        }
        println!(
            "session {sid} and its calibration deleted (--keep keeps them); done in {:.1} s",
            started.elapsed().as_secs_f64()
        );
    } else {
        println!("session {sid}; done in {:.1} s", started.elapsed().as_secs_f64());
    }
    if let Some((stop, task)) = local {
        let _ = stop.send(());
        let _ = task.await;
    }
    Ok(())
}

async fn wait_ready(authority: &str) -> Result<(), String> {
    let mut last = String::new();
    for _ in 0..100 {
        match http_json(authority, None, "GET", "/readyz", &Value::Null).await {
            Ok((200, _)) => return Ok(()),
            Ok((s, body)) => last = format!("{s} {body}"),
            Err(e) => last = e,
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    Err(last)
}

/// A minimal HTTP/1.1 JSON request (Connection: close); returns the status
/// and the parsed body. Enough for the demo's few calls without pulling an
/// HTTP client into the binary.
async fn http_json(
    authority: &str,
    token: Option<&str>,
    method: &str,
    path: &str,
    body: &Value,
) -> Result<(u16, Value), String> {
    let mut stream = tokio::net::TcpStream::connect(authority)
        .await
        .map_err(|e| format!("{authority}: {e}"))?;
    let payload = if body.is_null() {
        String::new()
    } else {
        body.to_string()
    };
    let auth = token
        .map(|t| format!("Authorization: Bearer {t}\r\n"))
        .unwrap_or_default();
    let request = format!(
        "{method} {path} HTTP/1.1\r\nHost: {authority}\r\nConnection: close\r\n{auth}Content-Type: application/json\r\nContent-Length: {}\r\n\r\n{payload}",
        payload.len()
    );
    stream
        .write_all(request.as_bytes())
        .await
        .map_err(|e| e.to_string())?;
    let mut response = Vec::new();
    stream
        .read_to_end(&mut response)
        .await
        .map_err(|e| e.to_string())?;
    let text = String::from_utf8_lossy(&response);
    let (head, body) = text.split_once("\r\n\r\n").ok_or("malformed HTTP response")?;
    let status = head
        .split_whitespace()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .ok_or("malformed status line")?;
    let value = serde_json::from_str(body).unwrap_or(Value::String(body.to_string()));
    Ok((status, value))
}

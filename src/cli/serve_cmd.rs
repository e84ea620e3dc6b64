//! `semdepth serve`: runs the HTTP/WebSocket service; `semdepth openapi`
//! prints its OpenAPI document; `semdepth healthcheck` asks a running
//! server's `/healthz` (for container health checks, no curl needed).

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
use std::time::Duration;

use clap::{Args, ValueEnum};

use super::CliError;
use crate::service::state::{
    ServiceConfig, DEFAULT_DB_PATH, DEFAULT_HEADER_TIMEOUT_S, DEFAULT_LISTEN, DEFAULT_LIVE_VIEW_MIB,
    DEFAULT_MAX_BODY_MIB, DEFAULT_MAX_CONNECTIONS, DEFAULT_MAX_EVENT_STREAMS, DEFAULT_MAX_INFLIGHT_MIB,
    DEFAULT_MAX_MESSAGE_MIB, DEFAULT_MAX_SESSIONS, DEFAULT_MIN_FREE_DISK_MIB, DEFAULT_REQUEST_TIMEOUT_S,
    DEFAULT_RETENTION, DEFAULT_SESSION_EXPIRY_H, DEFAULT_WS_IDLE_TIMEOUT_S, DEFAULT_WS_QUEUE,
};
use semdepth_core::imageio::DecodeLimits;

/// Log output format.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum LogFormat {
    /// Human-readable lines.
    Text,
    /// One JSON object per line.
    Json,
}

/// Arguments of `semdepth serve` (each also from an environment variable).
#[derive(Debug, Args)]
pub struct ServeArgs {
    /// Address to listen on.
    #[arg(long, env = "SEMDEPTH_LISTEN", default_value = DEFAULT_LISTEN)]
    pub listen: String,
    /// SQLite database file (created with its folder), or `:memory:`.
    #[arg(long, env = "SEMDEPTH_DB", default_value = DEFAULT_DB_PATH)]
    pub db: String,
    /// Bearer token required on every /v1 request.
    #[arg(long, env = "SEMDEPTH_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// Largest request body, MiB.
    #[arg(long, env = "SEMDEPTH_MAX_BODY_MIB", default_value_t = DEFAULT_MAX_BODY_MIB)]
    pub max_body_mib: usize,
    /// Largest WebSocket message (one pair), MiB.
    #[arg(long, env = "SEMDEPTH_MAX_MESSAGE_MIB", default_value_t = DEFAULT_MAX_MESSAGE_MIB)]
    pub max_message_mib: usize,
    /// Largest image width and height accepted, pixels.
    #[arg(long, env = "SEMDEPTH_MAX_IMAGE_SIDE", default_value_t = DecodeLimits::default().max_width)]
    pub max_image_side: u32,
    /// Most memory one image's decoder may allocate, MiB.
    #[arg(long, env = "SEMDEPTH_MAX_DECODE_MIB", default_value_t = DecodeLimits::default().max_alloc_bytes >> 20)]
    pub max_decode_mib: u64,
    /// Most sessions held at once.
    #[arg(long, env = "SEMDEPTH_MAX_SESSIONS", default_value_t = DEFAULT_MAX_SESSIONS)]
    pub max_sessions: usize,
    /// Pairs processed at once [default: the number of CPU cores].
    #[arg(long, env = "SEMDEPTH_WORKERS")]
    pub workers: Option<usize>,
    /// Results kept per session unless the session says otherwise.
    #[arg(long, env = "SEMDEPTH_RETENTION", default_value_t = DEFAULT_RETENTION)]
    pub retention: u64,
    /// Longest time one HTTP request may take, seconds.
    #[arg(long, env = "SEMDEPTH_REQUEST_TIMEOUT_S", default_value_t = DEFAULT_REQUEST_TIMEOUT_S)]
    pub request_timeout_s: f64,
    /// Pairs that may wait per WebSocket under policy=all.
    #[arg(long, env = "SEMDEPTH_WS_QUEUE", default_value_t = DEFAULT_WS_QUEUE)]
    pub ws_queue: usize,
    /// Delete sessions without a pair or a change for this many hours,
    /// except those created with `keep`; 0: never.
    #[arg(long, env = "SEMDEPTH_SESSION_EXPIRY_H", default_value_t = DEFAULT_SESSION_EXPIRY_H)]
    pub session_expiry_h: f64,
    /// Largest size of the database file, MiB; beyond it new results are
    /// refused (503 `storage_error`, "database or disk is full") before the
    /// disk fills. 0: no limit but the disk's.
    #[arg(long, env = "SEMDEPTH_MAX_DB_MIB", default_value_t = 0)]
    pub max_db_mib: u64,
    /// Longest time a client may take to send a request's headers,
    /// seconds; the connection is closed after it.
    #[arg(long, env = "SEMDEPTH_HEADER_TIMEOUT_S", default_value_t = DEFAULT_HEADER_TIMEOUT_S)]
    pub header_timeout_s: f64,
    /// Most connections open at once, WebSockets included (each is a file
    /// descriptor); beyond it new connections are closed at once.
    #[arg(long, env = "SEMDEPTH_MAX_CONNECTIONS", default_value_t = DEFAULT_MAX_CONNECTIONS)]
    pub max_connections: usize,
    /// Most live-view event streams (`GET /v1/sessions/{id}/events`) open at
    /// once; one more is answered 503 `busy`.
    #[arg(long, env = "SEMDEPTH_MAX_EVENT_STREAMS", default_value_t = DEFAULT_MAX_EVENT_STREAMS)]
    pub max_event_streams: usize,
    /// Close a WebSocket on which no whole message arrives for this many
    /// seconds (1008, saying so).
    #[arg(long, env = "SEMDEPTH_WS_IDLE_TIMEOUT_S", default_value_t = DEFAULT_WS_IDLE_TIMEOUT_S)]
    pub ws_idle_timeout_s: f64,
    /// Most MiB of decoded images kept for the live view (each session's
    /// latest pair); beyond it the sessions updated longest ago show no
    /// image until their next pair. 0 keeps none.
    #[arg(long, env = "SEMDEPTH_LIVE_VIEW_MIB", default_value_t = DEFAULT_LIVE_VIEW_MIB)]
    pub live_view_mib: usize,
    /// Most MiB of request bodies, stream messages and the images decoded
    /// from them held at once: a request beyond it is answered 503 `busy`
    /// with Retry-After, a stream waits (at least the larger of
    /// --max-body-mib and --max-message-mib).
    #[arg(long, env = "SEMDEPTH_MAX_INFLIGHT_MIB", default_value_t = DEFAULT_MAX_INFLIGHT_MIB)]
    pub max_inflight_mib: usize,
    /// MiB kept free on the database's disk: below it new results are
    /// refused (503 disk_nearly_full) before the disk fills, and /readyz
    /// says so. 0: none.
    #[arg(long, env = "SEMDEPTH_MIN_FREE_DISK_MIB", default_value_t = DEFAULT_MIN_FREE_DISK_MIB)]
    pub min_free_disk_mib: u64,
    /// Log format.
    #[arg(long, env = "SEMDEPTH_LOG_FORMAT", value_enum, default_value_t = LogFormat::Text)]
    pub log_format: LogFormat,
}

impl ServeArgs {
    /// The service configuration these arguments describe.
    pub fn config(&self) -> Result<ServiceConfig, CliError> {
        if !(self.request_timeout_s.is_finite() && (0.1..=86_400.0).contains(&self.request_timeout_s)) {
            return Err(CliError::input(format!(
                "invalid --request-timeout-s {} (expected 0.1..=86400)",
                self.request_timeout_s
            )));
        }
        if !(self.header_timeout_s.is_finite() && (0.1..=3_600.0).contains(&self.header_timeout_s)) {
            return Err(CliError::input(format!(
                "invalid --header-timeout-s {} (expected 0.1..=3600)",
                self.header_timeout_s
            )));
        }
        if !(self.ws_idle_timeout_s.is_finite() && (0.1..=86_400.0).contains(&self.ws_idle_timeout_s)) {
            return Err(CliError::input(format!(
                "invalid --ws-idle-timeout-s {} (expected 0.1..=86400)",
                self.ws_idle_timeout_s
            )));
        }
        if !(self.session_expiry_h.is_finite() && (0.0..=100_000.0).contains(&self.session_expiry_h)) {
            return Err(CliError::input(format!(
                "invalid --session-expiry-h {} (expected 0..=100000, 0: never)",
                self.session_expiry_h
            )));
        }
        let defaults = ServiceConfig::default();
        let config = ServiceConfig {
            db_path: self.db.clone(),
            token: self.token.clone(),
            max_body_bytes: self.max_body_mib.saturating_mul(1 << 20),
            max_ws_message_bytes: self.max_message_mib.saturating_mul(1 << 20),
            decode_limits: DecodeLimits {
                max_width: self.max_image_side,
                max_height: self.max_image_side,
                max_alloc_bytes: self.max_decode_mib.saturating_mul(1 << 20),
            },
            max_sessions: self.max_sessions,
            workers: self.workers.unwrap_or(defaults.workers),
            default_retention: self.retention,
            request_timeout: Duration::from_secs_f64(self.request_timeout_s),
            ws_queue: self.ws_queue,
            session_expiry: (self.session_expiry_h > 0.0)
                .then(|| Duration::from_secs_f64(self.session_expiry_h * 3600.0)),
            max_db_bytes: (self.max_db_mib > 0).then(|| self.max_db_mib.saturating_mul(1 << 20)),
            header_timeout: Duration::from_secs_f64(self.header_timeout_s),
            max_connections: self.max_connections,
            max_event_streams: self.max_event_streams,
            ws_idle_timeout: Duration::from_secs_f64(self.ws_idle_timeout_s),
            live_view_bytes: self.live_view_mib.saturating_mul(1 << 20),
            max_inflight_bytes: self.max_inflight_mib.saturating_mul(1 << 20),
            min_free_disk_bytes: self.min_free_disk_mib.saturating_mul(1 << 20),
        };
        config.validate().map_err(CliError::input)?;
        Ok(config)
    }
}

/// Runs the server until SIGINT or SIGTERM.
pub fn run(args: ServeArgs) -> Result<(), CliError> {
    init_logging(args.log_format);
    let config = args.config()?;
    let addr = resolve(&args.listen)?;
    if config.token.is_none() && !addr.ip().is_loopback() {
        tracing::warn!(
            address = %addr,
            "LISTENING ON A NON-LOOPBACK ADDRESS WITHOUT A TOKEN: anyone who can reach this port can use and delete sessions and calibrations; set --token or SEMDEPTH_TOKEN"
        );
    }
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|e| CliError::with_code(1, format!("error[runtime]: {e}")))?;
    runtime.block_on(async move {
        let listener = tokio::net::TcpListener::bind(addr)
            .await
            .map_err(|e| CliError::with_code(1, format!("error[listen]: cannot listen on {addr}: {e}")))?;
        crate::service::serve(listener, config, shutdown_signal())
            .await
            .map_err(|e| CliError::with_code(1, format!("error[serve]: {e}")))
    })
}

/// Resolves once SIGINT (Ctrl-C) or SIGTERM arrives.
async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        _ = ctrl_c => {},
        _ = term => {},
    }
    tracing::info!("shutdown signal received: finishing pairs in flight");
}

fn init_logging(format: LogFormat) {
    use tracing_subscriber::EnvFilter;
    let filter = EnvFilter::try_from_env("SEMDEPTH_LOG").unwrap_or_else(|_| EnvFilter::new("info"));
    use std::io::IsTerminal;
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(std::io::stderr().is_terminal())
        .with_writer(std::io::stderr);
    let _ = match format {
        LogFormat::Text => builder.try_init(),
        LogFormat::Json => builder.json().try_init(),
    };
}

fn resolve(listen: &str) -> Result<SocketAddr, CliError> {
    listen
        .to_socket_addrs()
        .ok()
        .and_then(|mut a| a.next())
        .ok_or_else(|| {
            CliError::input(format!(
                "invalid --listen {listen:?} (expected HOST:PORT, e.g. 127.0.0.1:8080)"
            ))
        })
}

/// Arguments of `semdepth openapi`.
#[derive(Debug, Args)]
pub struct OpenapiArgs {
    /// Output format.
    #[arg(long, value_enum, default_value_t = SpecFormat::Yaml)]
    pub format: SpecFormat,
}

/// Format of the printed OpenAPI document.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum SpecFormat {
    /// YAML (`openapi/openapi.yaml`).
    Yaml,
    /// JSON (`openapi/openapi.json`, also served at /openapi.json).
    Json,
}

/// Prints the OpenAPI document.
pub fn run_openapi(args: OpenapiArgs) -> Result<(), CliError> {
    let text = match args.format {
        SpecFormat::Yaml => crate::service::openapi_yaml_text(),
        SpecFormat::Json => crate::service::openapi_json_text().to_string(),
    };
    print!("{text}");
    Ok(())
}

/// Arguments of `semdepth healthcheck`.
#[derive(Debug, Args)]
pub struct HealthcheckArgs {
    /// Address of the server (the port of `--listen`; a 0.0.0.0 host is asked on 127.0.0.1).
    #[arg(long, env = "SEMDEPTH_LISTEN", default_value = DEFAULT_LISTEN)]
    pub listen: String,
    /// Seconds to wait for the answer.
    #[arg(long, default_value_t = 3.0)]
    pub timeout_s: f64,
}

/// Exits 0 when `/healthz` answers 200, 1 otherwise.
pub fn run_healthcheck(args: HealthcheckArgs) -> Result<(), CliError> {
    let mut addr = resolve(&args.listen)?;
    if addr.ip().is_unspecified() {
        addr.set_ip(std::net::Ipv4Addr::LOCALHOST.into());
    }
    let timeout = Duration::from_secs_f64(args.timeout_s.clamp(0.1, 60.0));
    let fail = |e: String| CliError::with_code(1, format!("unhealthy: {e}"));
    let mut stream = TcpStream::connect_timeout(&addr, timeout).map_err(|e| fail(format!("{addr}: {e}")))?;
    stream
        .set_read_timeout(Some(timeout))
        .map_err(|e| fail(e.to_string()))?;
    stream
        .set_write_timeout(Some(timeout))
        .map_err(|e| fail(e.to_string()))?;
    write!(
        stream,
        "GET /healthz HTTP/1.0\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
    )
    .map_err(|e| fail(e.to_string()))?;
    let mut response = String::new();
    stream
        .read_to_string(&mut response)
        .map_err(|e| fail(e.to_string()))?;
    let status_ok = response
        .lines()
        .next()
        .is_some_and(|l| l.split_whitespace().nth(1) == Some("200"));
    if status_ok {
        println!("healthy");
        Ok(())
    } else {
        Err(fail(response.lines().next().unwrap_or("no answer").to_string()))
    }
}

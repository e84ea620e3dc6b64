//! The accept loop: HTTP/1.1 connections served by hyper with a deadline for
//! the request headers and a cap on open connections, drained gracefully on
//! shutdown. `axum::serve` sets neither: a client sending one header byte
//! every 2 s held its connection for good, and 1,100 of them under a 1024
//! file-descriptor limit kept `/healthz` from answering. Beyond the cap,
//! [`OPS_RESERVED`] more connections are accepted for the probes alone
//! (`/healthz`, `/readyz`, `/metrics`), so that an orchestrator never
//! restarts a server that is only busy.

use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use hyper::body::Incoming;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use tokio::net::TcpListener;
use tokio::sync::{watch, OwnedSemaphorePermit, Semaphore};
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;
use tower::ServiceExt;

/// How the loop treats connections.
#[derive(Clone, Copy, Debug)]
pub struct Limits {
    /// Longest time a client may take to send a request's headers (each
    /// request's, on a kept-alive connection too).
    pub header_timeout: Duration,
    /// Most connections open at once, WebSockets included; one more is
    /// closed unread.
    pub max_connections: usize,
}

/// Connections accepted beyond `max_connections` for the probes alone.
pub const OPS_RESERVED: usize = 8;

/// The paths a connection in a reserved slot is answered on.
pub const OPS_PATHS: [&str; 3] = ["/healthz", "/readyz", "/metrics"];

/// A connection's place under the cap, in every request's extensions: an
/// upgraded WebSocket keeps a clone for as long as it is open, so that it
/// still counts once the HTTP connection has handed its socket over.
#[derive(Clone)]
pub struct ConnectionSlot {
    _permit: Arc<OwnedSemaphorePermit>,
    reserved: bool,
}

impl ConnectionSlot {
    /// Whether the connection holds one of the [`OPS_RESERVED`] slots (the
    /// cap was reached when it came): only [`OPS_PATHS`] are served on it.
    pub fn reserved(&self) -> bool {
        self.reserved
    }
}

/// Serves `app` on `listener` until `stop` is cancelled, then lets every
/// open connection finish its requests (upgraded WebSockets are the
/// application's to close) and returns.
pub async fn serve(listener: TcpListener, app: Router, limits: Limits, stop: CancellationToken) {
    let slots = Arc::new(Semaphore::new(limits.max_connections));
    let reserve = Arc::new(Semaphore::new(OPS_RESERVED));
    let (closing, _) = watch::channel(());
    let tasks = TaskTracker::new();
    let mut refused_logged = false;
    loop {
        let (stream, peer) = tokio::select! {
            _ = stop.cancelled() => break,
            accepted = listener.accept() => match accepted {
                Ok(accepted) => accepted,
                Err(e) => {
                    // Out of file descriptors, for one: wait a little
                    // instead of spinning.
                    tracing::warn!(error = %e, "accept failed");
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                }
            },
        };
        let slot = match slots.clone().try_acquire_owned() {
            Ok(permit) => Some((permit, false)),
            Err(_) => reserve
                .clone()
                .try_acquire_owned()
                .ok()
                .map(|permit| (permit, true)),
        };
        let Some((permit, reserved)) = slot else {
            if !refused_logged {
                tracing::warn!(
                    limit = limits.max_connections,
                    "connection limit reached; closing new connections"
                );
                refused_logged = true;
            }
            drop(stream);
            continue;
        };
        refused_logged &= reserved;
        let slot = ConnectionSlot {
            _permit: Arc::new(permit),
            reserved,
        };
        let held = slot.clone();
        let service = TowerToHyperService::new(app.clone().map_request(
            move |mut request: axum::http::Request<Incoming>| {
                request.extensions_mut().insert(held.clone());
                request.map(axum::body::Body::new)
            },
        ));
        let mut closing = closing.subscribe();
        tasks.spawn(async move {
            let connection = hyper::server::conn::http1::Builder::new()
                .timer(TokioTimer::new())
                .header_read_timeout(limits.header_timeout)
                .serve_connection(TokioIo::new(stream), service)
                .with_upgrades();
            tokio::pin!(connection);
            tokio::select! {
                result = connection.as_mut() => {
                    if let Err(e) = result {
                        tracing::debug!(%peer, error = %e, "connection ended");
                    }
                }
                _ = closing.changed() => {
                    connection.as_mut().graceful_shutdown();
                    if let Err(e) = connection.await {
                        tracing::debug!(%peer, error = %e, "connection ended");
                    }
                }
            }
            drop(slot);
        });
    }
    drop(listener);
    // Connections finish the requests they have; idle ones close now.
    closing.send_replace(());
    tasks.close();
    tasks.wait().await;
}

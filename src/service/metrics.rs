//! Prometheus metrics (`GET /metrics`, OpenMetrics text): pairs processed,
//! skipped and failed, processing latency, active sessions and sockets.

use prometheus_client::encoding::text::encode;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::{exponential_buckets, Histogram};
use prometheus_client::registry::Registry;

/// Label set: one `(name, value)` pair.
type Labels = Vec<(String, String)>;

/// The service's metrics; cheap to update from any thread.
pub struct Metrics {
    registry: Registry,
    /// Pairs that produced a result, by status (initialised, tracked, lost).
    pub pairs_processed: Family<Labels, Counter>,
    /// Pairs dropped by the WebSocket `latest` policy.
    pub pairs_skipped: Counter,
    /// Pairs that produced no result, by error code.
    pub pairs_failed: Family<Labels, Counter>,
    /// Seconds from receipt of a pair to its result.
    pub processing_seconds: Histogram,
    /// Sessions currently held.
    pub active_sessions: Gauge,
    /// Open WebSocket streams.
    pub active_websockets: Gauge,
    /// Pair records committed to storage.
    pub stored_pairs: Counter,
    /// Size of the database file in bytes (pages in use and free), as of
    /// the last committed batch of pairs.
    pub storage_bytes: Gauge,
    /// Bytes of the memory budget for work in flight in use, as of the
    /// scrape (`--max-inflight-mib`).
    pub inflight_bytes: Gauge,
    /// Requests answered 503 `busy` because the memory budget was in use.
    pub refused_busy: Counter,
}

impl Default for Metrics {
    fn default() -> Self {
        Self::new()
    }
}

impl Metrics {
    /// Registers every metric under the `semdepth_` prefix.
    pub fn new() -> Self {
        let mut registry = Registry::with_prefix("semdepth");
        let pairs_processed = Family::<Labels, Counter>::default();
        let pairs_skipped = Counter::default();
        let pairs_failed = Family::<Labels, Counter>::default();
        // 0.25 ms .. ~4 s in factor-2 steps.
        let processing_seconds = Histogram::new(exponential_buckets(0.000_25, 2.0, 15));
        let active_sessions = Gauge::default();
        let active_websockets = Gauge::default();
        let stored_pairs = Counter::default();
        let storage_bytes = Gauge::default();
        let inflight_bytes = Gauge::default();
        let refused_busy = Counter::default();
        registry.register(
            "inflight_bytes",
            "Bytes of the budget for request bodies, stream messages and decoded images in flight in use",
            inflight_bytes.clone(),
        );
        registry.register(
            "refused_busy",
            "Requests answered 503 busy because the memory budget was in use",
            refused_busy.clone(),
        );
        registry.register(
            "storage_bytes",
            "Size of the database file (without its write-ahead log), bytes",
            storage_bytes.clone(),
        );
        registry.register(
            "pairs_processed",
            "Stereo pairs that produced a result, by status",
            pairs_processed.clone(),
        );
        registry.register(
            "pairs_skipped",
            "Stereo pairs skipped by the WebSocket latest policy",
            pairs_skipped.clone(),
        );
        registry.register(
            "pairs_failed",
            "Stereo pairs that produced no result, by error code",
            pairs_failed.clone(),
        );
        registry.register(
            "processing_seconds",
            "Time from receipt of a pair to its result",
            processing_seconds.clone(),
        );
        registry.register("active_sessions", "Sessions held", active_sessions.clone());
        registry.register(
            "active_websockets",
            "Open WebSocket streams",
            active_websockets.clone(),
        );
        registry.register(
            "stored_pairs",
            "Pair results committed to storage",
            stored_pairs.clone(),
        );
        Self {
            registry,
            pairs_processed,
            pairs_skipped,
            pairs_failed,
            processing_seconds,
            active_sessions,
            active_websockets,
            stored_pairs,
            storage_bytes,
            inflight_bytes,
            refused_busy,
        }
    }

    /// Counts a pair with a result.
    pub fn processed(&self, status: &str, seconds: f64) {
        self.pairs_processed
            .get_or_create(&vec![("status".to_string(), status.to_string())])
            .inc();
        self.processing_seconds.observe(seconds);
    }

    /// Counts a pair that failed with an error code.
    pub fn failed(&self, code: &str) {
        self.pairs_failed
            .get_or_create(&vec![("reason".to_string(), code.to_string())])
            .inc();
    }

    /// The OpenMetrics text.
    pub fn render(&self) -> String {
        let mut text = String::new();
        // Writing into a String cannot fail.
        let _ = encode(&mut text, &self.registry);
        text
    }
}

//! Processing of one stereo pair for a session or for the one-shot
//! endpoint: decode and track on the blocking pool (bounded by the worker
//! semaphore), in session order, then queue the result and the tracker
//! snapshot for storage and acknowledge only once they are committed.

use std::future::Future;
use std::pin::Pin;
use std::sync::Arc;
use std::time::Instant;

use axum::body::Bytes;
use axum::extract::multipart::{Multipart, MultipartError};
use axum::extract::{FromRequest, Request};
use axum::http::StatusCode;
use tokio::sync::{OwnedMutexGuard, OwnedSemaphorePermit};

use semdepth_core::calib::Calibration;
use semdepth_core::imageio::{DecodeLimits, GrayFrame};
use semdepth_core::pair::DecodedPair;
use semdepth_core::session::{Measurement, Session as Objects};
use semdepth_core::tracker::TrackerParams;

use super::api::model::{FrameResult, Provenance, TimingMs};
use super::api::SessionState;
use super::budget::{Reservation, DECODED_BYTES_PER_PIXEL};
use super::db::{LiveFrame, Session, SessionCore};
use super::error::ApiError;
use super::stamp::now_rfc3339;
use super::state::AppState;
use super::storage::{PairRecord, StorageError};

/// The two images of a pair as received.
#[derive(Clone, Debug)]
pub enum PairInput {
    /// Encoded files (PNG, TIFF, JPEG, BMP; the format is detected).
    Encoded {
        /// Left image bytes.
        left: Bytes,
        /// Right image bytes.
        right: Bytes,
    },
    /// Raw little-endian row-major samples.
    Raw {
        /// Left image samples.
        left: Bytes,
        /// Right image samples.
        right: Bytes,
        /// Width in pixels.
        width: u32,
        /// Height in pixels.
        height: u32,
        /// 8 or 16.
        bit_depth: u8,
    },
}

impl PairInput {
    /// Bytes the two decoded images take while they are decoded and
    /// tracked ([`DECODED_BYTES_PER_PIXEL`] per pixel), from the left
    /// image's size as its header gives it; 0 when that cannot be read
    /// (decoding then fails on its own).
    pub fn decoded_bytes(&self) -> usize {
        let (width, height) = match self {
            Self::Raw { width, height, .. } => (*width, *height),
            Self::Encoded { left, .. } => image::ImageReader::new(std::io::Cursor::new(left))
                .with_guessed_format()
                .ok()
                .and_then(|r| r.into_dimensions().ok())
                .unwrap_or((0, 0)),
        };
        (width as usize)
            .saturating_mul(height as usize)
            .saturating_mul(DECODED_BYTES_PER_PIXEL)
    }

    /// Decodes both images and reads their microscope metadata (raw
    /// samples carry none). CPU-heavy: call on the blocking pool.
    pub fn decode(&self, limits: &DecodeLimits) -> Result<DecodedPair, ApiError> {
        match self {
            Self::Encoded { left, right } => DecodedPair::from_files(left, right, limits),
            Self::Raw {
                left,
                right,
                width,
                height,
                bit_depth,
            } => DecodedPair::from_raw([left, right], *width, *height, *bit_depth, limits),
        }
        .map_err(|e| ApiError::from(e.error).prefixed(&format!("{} image", e.side.name())))
    }
}

/// A pair tracked and queued for storage, not yet acknowledged.
pub struct TrackedPair {
    /// The result (with the caller's `seq`).
    pub result: FrameResult,
    /// Resolves once the result and the tracker snapshot are committed.
    pub commit: Pin<Box<dyn Future<Output = Result<(), StorageError>> + Send>>,
}

/// Processes one pair of a session: strictly after the session's earlier
/// pairs, with at most `workers` pairs in flight overall. Returns once the
/// result is committed to storage.
pub async fn process_session_pair(
    state: &AppState,
    session: &Arc<Session>,
    input: PairInput,
    provenance: Provenance,
    received: Instant,
    seq: Option<u64>,
) -> Result<FrameResult, ApiError> {
    let tracked = track_session_pair(state, session, input, provenance, received, seq).await?;
    acknowledge(state, session, tracked, received).await
}

/// Tracks one pair of a session (in order, bounded) and queues its result
/// for storage; returns as soon as the session is free for its next pair,
/// before the commit. [`acknowledge`] waits for the commit.
///
/// The work runs in its own task: a client that disconnects mid-request
/// does not cancel a pair halfway (which would advance the tracker without
/// storing the result).
async fn track_session_pair(
    state: &AppState,
    session: &Arc<Session>,
    input: PairInput,
    provenance: Provenance,
    received: Instant,
    seq: Option<u64>,
) -> Result<TrackedPair, ApiError> {
    let (task_state, task_session) = (state.clone(), session.clone());
    let outcome = tokio::spawn(async move {
        run_session_pair(&task_state, &task_session, input, provenance, received, seq).await
    })
    .await
    .unwrap_or_else(|e| Err(ApiError::internal(format!("pair task failed: {e}"))));
    if let Err(e) = &outcome {
        state.metrics.failed(e.code());
    }
    outcome
}

/// Waits until a tracked pair is committed; only then is it a result. When
/// the commit fails, the session is marked to be reloaded from storage
/// before its next pair ([`Session::lock_core`]).
pub async fn acknowledge(
    state: &AppState,
    session: &Session,
    tracked: TrackedPair,
    received: Instant,
) -> Result<FrameResult, ApiError> {
    match tracked.commit.await {
        Ok(()) => {
            state.metrics.stored_pairs.inc();
            state.metrics.processed(
                tracked.result.result.status.name(),
                received.elapsed().as_secs_f64(),
            );
            Ok(tracked.result)
        }
        Err(e) => {
            session.fell_behind();
            let e = ApiError::from(e);
            state.metrics.failed(e.code());
            Err(e)
        }
    }
}

async fn run_session_pair(
    state: &AppState,
    session: &Arc<Session>,
    input: PairInput,
    provenance: Provenance,
    received: Instant,
    seq: Option<u64>,
) -> Result<TrackedPair, ApiError> {
    let held = reserve_decoding(state, &input).await?;
    let (core, permit) = claim(state, session).await?;
    let (task_state, task_session) = (state.clone(), session.clone());
    let outcome = tokio::task::spawn_blocking(move || {
        let _held = held;
        let mut core = core;
        track_locked(
            &task_state,
            &task_session,
            &mut core,
            &input,
            provenance,
            received,
            seq,
        )
    })
    .await
    .map_err(|e| ApiError::internal(format!("tracking task failed: {e}")))?;
    drop(permit);
    outcome
}

/// A pair of a stream, as the stream's processor hands it over.
pub struct StreamPair {
    /// The images.
    pub input: PairInput,
    /// Where it came from and when.
    pub provenance: Provenance,
    /// When the reader received it.
    pub received: Instant,
    /// The client's sequence number.
    pub seq: u64,
    /// Its bytes and its decoded images' of the memory budget, held until
    /// it is tracked.
    pub held: Reservation,
}

/// A stream's queue of waiting pairs, as the blocking batch sees it.
pub trait PairQueue: Send + 'static {
    /// The next waiting pair, if there is one (never waits).
    fn try_next(&mut self) -> Option<StreamPair>;
}

/// Longest a stream keeps its session and worker slot for one batch of
/// queued pairs before it lets other sessions (and requests on its own
/// session) in.
pub const STREAM_BATCH_BUDGET: std::time::Duration = std::time::Duration::from_millis(25);

/// Tracks `first` and then, in the same blocking task and without letting go
/// of the session or the worker slot, every further pair `queue` has ready,
/// for up to [`STREAM_BATCH_BUDGET`]. Each outcome goes to `deliver` in
/// order; `deliver` returns false to stop the stream. Returns the queue and
/// whether the stream should go on.
///
/// Why batches: handing each pair from the async processor to the blocking
/// pool and back cost a stream about 1.1 ms per pair beyond decoding and
/// tracking (3.98 ms per pair against 2.84 ms of decode and track in the
/// server, `service_load` ws_one), on a 2-core machine where the reader and
/// the client compete for the cores at every hand-off.
pub async fn track_stream_batch<Q, D>(
    state: &AppState,
    session: &Arc<Session>,
    first: StreamPair,
    mut queue: Q,
    mut deliver: D,
) -> (Q, bool)
where
    Q: PairQueue,
    D: FnMut(u64, Instant, Result<TrackedPair, ApiError>) -> bool + Send + 'static,
{
    let (core, permit) = match claim(state, session).await {
        Ok(claimed) => claimed,
        Err(e) => {
            state.metrics.failed(e.code());
            let go_on = deliver(first.seq, first.received, Err(e));
            return (queue, go_on);
        }
    };
    let (task_state, task_session) = (state.clone(), session.clone());
    let joined = tokio::task::spawn_blocking(move || {
        let mut core = core;
        let started = Instant::now();
        let mut pair = first;
        let go_on = loop {
            // A panic is a bug; like a failed blocking task on the
            // one-pair path, it fails this pair, not the stream.
            let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                track_locked(
                    &task_state,
                    &task_session,
                    &mut core,
                    &pair.input,
                    std::mem::take(&mut pair.provenance),
                    pair.received,
                    Some(pair.seq),
                )
            }))
            .unwrap_or_else(|_| Err(ApiError::internal("tracking task panicked")));
            if let Err(e) = &outcome {
                task_state.metrics.failed(e.code());
            }
            if !deliver(pair.seq, pair.received, outcome) {
                break false;
            }
            if started.elapsed() >= STREAM_BATCH_BUDGET {
                break true;
            }
            match queue.try_next() {
                Some(p) => pair = p,
                None => break true,
            }
        };
        (queue, go_on)
    })
    .await;
    drop(permit);
    // Panics are caught per pair above, and the blocking pool does not
    // cancel running tasks: the task always returns.
    joined.unwrap_or_else(|e| std::panic::resume_unwind(e.into_panic()))
}

/// Decodes and tracks one pair of a session whose core the caller holds
/// (on the blocking pool), then queues the result and the tracker snapshot
/// for storage. Pairs queued this way commit in frame order; once committed,
/// the pair becomes the session's [`LiveFrame`].
fn track_locked(
    state: &AppState,
    session: &Session,
    core: &mut SessionCore,
    input: &PairInput,
    provenance: Provenance,
    received: Instant,
    seq: Option<u64>,
) -> Result<TrackedPair, ApiError> {
    let calibration_id = core.calibration_id.clone();
    let (calibration, calibration_version) = state.db.calibration_model(calibration_id.as_deref()).unzip();
    let session_id = session.id();
    let queue = ms(received.elapsed());
    // The session measures every object across its calibration's tilt
    // axis (see `semdepth_core::session`).
    // Objects that initialise or search are tracked side by side on the
    // worker slots that are idle now (each thread holds one), one after the
    // other otherwise.
    let extra: Vec<_> = (1..core.session.useful_threads())
        .map_while(|_| state.workers.clone().try_acquire_owned().ok())
        .collect();
    let (measured, decode_ms, track_ms, [left, right]) = decode_and_measure(
        input,
        &state.config.decode_limits,
        &mut core.session,
        calibration.as_ref(),
        1 + extra.len(),
    )?;
    drop(extra);
    let result = &measured.objects[0].result;
    let now = now_rfc3339();
    let any_lost = measured
        .objects
        .iter()
        .any(|o| o.result.status == semdepth_core::tracker::Status::Lost);
    core.state = if any_lost {
        tracing::info!(
            session = session_id,
            frame = result.frame,
            reason = result.reason.as_deref().unwrap_or("-"),
            "pair lost"
        );
        SessionState::Lost
    } else {
        if let Some(d) = result.disparity_px {
            core.latest_disparity_px = Some(d);
        }
        SessionState::Tracking
    };
    core.updated_at = now.clone();
    let frame = frame_result(
        Some(session_id.to_owned()),
        (calibration.as_ref().and(calibration_id), calibration_version),
        measured,
        [queue, decode_ms, track_ms],
        received,
        Provenance {
            processed_at: Some(now.clone()),
            ..provenance
        },
    );
    let result_json = serde_json::to_string(&frame)
        .map_err(|e| ApiError::internal(format!("serialising a result: {e}")))?;
    let commit = state.db.record_pair(PairRecord {
        session_id: session_id.to_owned(),
        frame: frame.result.frame,
        result_json,
        frames: core.session.frames(),
        state: core.state,
        objects: core.object_records(),
        updated_at: now,
    });
    let shown = LiveFrame {
        result: frame.clone(),
        images: Some(Arc::new([left, right])),
        at: Instant::now(),
    };
    let (live_state, live_session) = (state.clone(), session.id().to_owned());
    let commit = async move {
        commit.await?;
        live_state.db.publish(&live_session, shown);
        Ok(())
    };
    Ok(TrackedPair {
        result: FrameResult { seq, ..frame },
        commit: Box::pin(commit),
    })
}

/// The one-shot measurement: a fresh tracker on one pair, nothing stored.
pub async fn process_one_shot(
    state: &AppState,
    params: TrackerParams,
    calibration_id: Option<String>,
    input: PairInput,
    provenance: Provenance,
    received: Instant,
) -> Result<FrameResult, ApiError> {
    let (calibration, calibration_version) = match &calibration_id {
        Some(id) => {
            let record = state.db.calibration(id)?;
            (Some(record.calibration), Some(record.version))
        }
        None => (None, None),
    };
    let limits = state.config.decode_limits;
    let held = reserve_decoding(state, &input).await?;
    let permit = worker_permit(state).await?;
    let queue = ms(received.elapsed());
    let outcome = tokio::task::spawn_blocking(move || {
        let _held = held;
        let mut session = Objects::single(params);
        decode_and_measure(&input, &limits, &mut session, calibration.as_ref(), 1)
            .map(|(m, d, t, _)| (m, d, t))
    })
    .await
    .map_err(|e| ApiError::internal(format!("tracking task failed: {e}")))?;
    drop(permit);
    let outcome = outcome.map(|(measured, decode_ms, track_ms)| {
        frame_result(
            None,
            (calibration_id, calibration_version),
            measured,
            [queue, decode_ms, track_ms],
            received,
            Provenance {
                processed_at: Some(now_rfc3339()),
                ..provenance
            },
        )
    });
    match &outcome {
        Ok(r) => state
            .metrics
            .processed(r.result.status.name(), received.elapsed().as_secs_f64()),
        Err(e) => state.metrics.failed(e.code()),
    }
    outcome
}

/// The session's core (held for the whole processing, so its pairs go in
/// order) and then a worker slot; an error once the session is deleted.
async fn claim(
    state: &AppState,
    session: &Session,
) -> Result<(OwnedMutexGuard<SessionCore>, OwnedSemaphorePermit), ApiError> {
    let core = state.db.claim(session).await?;
    Ok((core, worker_permit(state).await?))
}

/// Longest an uploaded pair waits for its decoded images' bytes of the
/// memory budget before it is answered 503 `busy` (a wait without end could
/// hold every body's bytes while each waits for the others').
const DECODE_BUDGET_WAIT: std::time::Duration = std::time::Duration::from_secs(2);

/// The decoded images' bytes of the memory budget for an uploaded pair.
async fn reserve_decoding(state: &AppState, input: &PairInput) -> Result<Reservation, ApiError> {
    let bytes = input.decoded_bytes();
    match tokio::time::timeout(DECODE_BUDGET_WAIT, state.budget.reserve(bytes)).await {
        Ok(held) => held,
        Err(_) => {
            state.metrics.refused_busy.inc();
            state.budget.try_reserve(bytes, "decoding this pair")
        }
    }
}

/// One of the `workers` slots for a pair.
async fn worker_permit(state: &AppState) -> Result<OwnedSemaphorePermit, ApiError> {
    state
        .workers
        .clone()
        .acquire_owned()
        .await
        .map_err(|_| ApiError::shutting_down())
}

/// Decodes and measures every object of `session` on up to `threads`
/// threads; returns the measurement, the decode and measure times (ms) and
/// the decoded images.
fn decode_and_measure(
    input: &PairInput,
    limits: &DecodeLimits,
    session: &mut Objects,
    calibration: Option<&Calibration>,
    threads: usize,
) -> Result<(Measurement, f64, f64, [GrayFrame; 2]), ApiError> {
    let started = Instant::now();
    let pair = input.decode(limits)?;
    let decoded = Instant::now();
    let measured =
        session
            .measure_pair(&pair, calibration, threads)
            .map_err(|e| match session.objects().len() {
                1 => ApiError::from(e.error),
                _ => ApiError::from(e.error).prefixed(&format!("object {:?}", e.object)),
            })?;
    Ok((
        measured,
        ms(decoded - started),
        ms(decoded.elapsed()),
        [pair.left, pair.right],
    ))
}

/// A measured pair as the API returns it: the first object's fields at
/// the top level, `objects` and `relative` as [`named_only`] keeps them;
/// `[queue, decode, track]` milliseconds, the total up to now since
/// `received`.
fn frame_result(
    session_id: Option<String>,
    (calibration_id, calibration_version): (Option<String>, Option<u64>),
    measured: Measurement,
    [queue, decode, track]: [f64; 3],
    received: Instant,
    provenance: Provenance,
) -> FrameResult {
    FrameResult {
        session_id,
        calibration_id,
        calibration_version,
        result: measured.objects[0].result.clone().into(),
        objects: named_only(measured.objects).into_iter().map(Into::into).collect(),
        relative: measured.relative.into_iter().map(Into::into).collect(),
        timing_ms: TimingMs {
            queue,
            decode,
            track,
            total: ms(received.elapsed()),
        },
        provenance,
        seq: None,
    }
}

/// The objects for a result: none for a session whose one object the
/// client never named (its result is the top-level fields, as before
/// objects). Repeating its contours there cost 13-16% of one WebSocket's
/// pairs/s (service_load ws_one, 677-717 against 805-839 pairs/s,
/// alternating runs).
fn named_only(
    objects: Vec<semdepth_core::session::ObjectResult>,
) -> Vec<semdepth_core::session::ObjectResult> {
    match objects.as_slice() {
        [only] if only.name == semdepth_core::session::DEFAULT_OBJECT_NAME => Vec::new(),
        _ => objects,
    }
}

fn ms(d: std::time::Duration) -> f64 {
    (d.as_secs_f64() * 1e6).round() / 1e3
}

/// Reads the `left` and `right` parts of a `multipart/form-data` upload.
pub async fn read_pair_upload(request: Request) -> Result<(PairInput, Provenance), ApiError> {
    let mut multipart = Multipart::from_request(request, &()).await.map_err(|e| {
        ApiError::UnsupportedMediaType(
            "unsupported_media_type",
            format!(
                "{} (expected multipart/form-data with parts \"left\" and \"right\")",
                e.body_text()
            ),
        )
    })?;
    let (mut left, mut right) = (None, None);
    let (mut label, mut timestamp) = (None, None);
    let mut files: [Option<String>; 2] = [None, None];
    while let Some(field) = multipart.next_field().await.map_err(multipart_error)? {
        let name = field.name().unwrap_or_default().to_string();
        let text_slot = match name.as_str() {
            "label" => Some(&mut label),
            "timestamp" => Some(&mut timestamp),
            _ => None,
        };
        if let Some(slot) = text_slot {
            if slot.is_some() {
                return Err(duplicate_part(&name));
            }
            let bytes = field.bytes().await.map_err(multipart_error)?;
            let text = String::from_utf8(bytes.to_vec()).map_err(|_| {
                ApiError::bad_request(
                    "invalid_multipart",
                    format!("multipart part {name:?} is not UTF-8 text"),
                )
            })?;
            *slot = Some(text);
            continue;
        }
        let (slot, file) = match name.as_str() {
            "left" => (&mut left, &mut files[0]),
            "right" => (&mut right, &mut files[1]),
            other => {
                return Err(ApiError::bad_request(
                    "unexpected_part",
                    format!("unexpected multipart part {other:?} (expected \"left\" and \"right\" images, optionally \"label\" and \"timestamp\")"),
                ))
            }
        };
        if slot.is_some() {
            return Err(duplicate_part(&name));
        }
        *file = field.file_name().map(|f| f.chars().take(200).collect());
        *slot = Some(field.bytes().await.map_err(multipart_error)?);
    }
    let mut provenance = Provenance::received(label, timestamp)?;
    [provenance.left_file, provenance.right_file] = files;
    match (left, right) {
        (Some(left), Some(right)) => Ok((PairInput::Encoded { left, right }, provenance)),
        (l, r) => {
            let missing: Vec<&str> = [("left", l.is_none()), ("right", r.is_none())]
                .iter()
                .filter(|(_, m)| *m)
                .map(|(n, _)| *n)
                .collect();
            Err(ApiError::bad_request(
                "missing_part",
                format!(
                    "multipart upload lacks the part(s) {} (expected \"left\" and \"right\" images)",
                    missing.join(" and ")
                ),
            ))
        }
    }
}

fn duplicate_part(name: &str) -> ApiError {
    ApiError::bad_request(
        "duplicate_part",
        format!("multipart part {name:?} given twice (expected it once)"),
    )
}

fn multipart_error(e: MultipartError) -> ApiError {
    let status = e.status();
    let code = if status == StatusCode::PAYLOAD_TOO_LARGE {
        "body_too_large"
    } else {
        "invalid_multipart"
    };
    let status = if status.is_client_error() {
        status
    } else {
        StatusCode::BAD_REQUEST
    };
    ApiError::with_status(status, code, format!("multipart body: {}", e.body_text()))
}

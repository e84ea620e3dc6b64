//! `/v1/sessions` and `/v1/depth`: sessions (create, list, get, patch,
//! delete, reset, reinit with new hints), pair uploads, results (JSON or
//! CSV), calibration samples from the latest disparity, and the one-shot
//! measurement (hints as query parameters).

use std::time::Instant;

use axum::extract::{Request, State};
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use serde::Deserialize;
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::api;
use super::api::csv::{csv_record, objects_csv_records, CSV_HEADER, OBJECTS_CSV_HEADER};
use super::api::Polarity as ApiPolarity;
use super::api::SessionState;
use semdepth_core::calib::{axis_component, same_tilt_axis, Sample};
use semdepth_core::init::{InitError, InitParams, Polarity};
use semdepth_core::session::{Session as Objects, SessionObject};
use semdepth_core::tracker::TrackerParams;

use super::api::model::{
    CalibrationView, ContoursQuery, FrameResult, ObjectCreate, PairUpload, ResultsPage, SessionCreate,
    SessionList, SessionPatch, SessionReinit, SessionSampleCreate, SessionView, SessionsDeleted, HINT_FIELDS,
};
use super::calibrations::{add_sample, check_name};
use super::db::SessionCore;
use super::error::{ApiError, ApiJson, ApiJsonFields, ApiPath, ApiQuery, ErrorBody};
use super::merge_patch;
use super::pipeline::{process_one_shot, process_session_pair, read_pair_upload};
use super::stamp::now_rfc3339;
use super::state::AppState;

/// Most results returned by one `GET .../results` request.
pub const MAX_RESULTS_PAGE: usize = 10_000;

/// The session and one-shot routes (the stream route lives in `ws`).
pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(create_session, list_sessions, delete_sessions))
        .routes(routes!(get_session, patch_session, delete_session))
        .routes(routes!(upload_pair))
        .routes(routes!(reset_session))
        .routes(routes!(reinit_session))
        .routes(routes!(add_object))
        .routes(routes!(delete_object))
        .routes(routes!(reinit_object))
        .routes(routes!(session_results))
        .routes(routes!(add_session_calibration_sample))
        .routes(routes!(one_shot_depth))
}

/// Create a session.
#[utoipa::path(
    post,
    path = "/v1/sessions",
    operation_id = "create_session",
    tag = "sessions",
    request_body = SessionCreate,
    responses(
        (status = 201, description = "Created; awaiting its first pair", body = SessionView),
        (status = 400, description = "Malformed JSON, unknown field or invalid parameter, or `tilt_axis_conflict`: tracker.tilt_axis_deg is not the calibration's axis", body = ErrorBody),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
        (status = 404, description = "Unknown calibration", body = ErrorBody),
        (status = 408, description = "The request took too long (slow upload)", body = ErrorBody),
        (status = 409, description = "Session limit reached (`session_limit_reached`), or two objects of one name (`duplicate_object`), or more than 16 (`object_count`)", body = ErrorBody),
        (status = 413, description = "Body beyond --max-body-mib", body = ErrorBody),
        (status = 415, description = "Not JSON", body = ErrorBody),
        (status = 422, description = "Invalid hint (`invalid_hint`): init.roi under 16 px a side, init.point not finite", body = ErrorBody),
        (status = 503, description = "Storage failed or the server is shutting down", body = ErrorBody),
    )
)]
pub async fn create_session(
    State(state): State<AppState>,
    ApiJson(body): ApiJson<SessionCreate>,
) -> Result<(StatusCode, ApiJson<SessionView>), ApiError> {
    check_name(body.name.as_deref())?;
    check_retention(body.retention)?;
    let axis = body.tracker.as_ref().and_then(|t| t.tilt_axis_deg);
    check_axis(&state, axis, body.calibration_id.as_deref())?;
    let params = merge_params(
        TrackerParams::default(),
        body.init.map(Into::into),
        body.tracker.map(Into::into),
    )?;
    let objects = match &body.objects {
        None => Objects::single(params),
        Some(list) => {
            let objects = list
                .iter()
                .map(|o| Ok(SessionObject::new(o.name.clone(), checked(o.params(&params))?)))
                .collect::<Result<Vec<_>, ApiError>>()?;
            Objects::new(objects, 0)?
        }
    };
    let core = SessionCore::new(
        body.name,
        body.calibration_id,
        body.retention,
        body.keep,
        objects,
        now_rfc3339(),
    );
    let view = state.db.create_session(core).await?;
    Ok((StatusCode::CREATED, ApiJson(view)))
}

/// List sessions, oldest first.
#[utoipa::path(
    get,
    path = "/v1/sessions",
    operation_id = "list_sessions",
    tag = "sessions",
    responses(
        (status = 200, description = "All sessions", body = SessionList),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
    )
)]
pub async fn list_sessions(State(state): State<AppState>) -> Result<ApiJson<SessionList>, ApiError> {
    Ok(ApiJson(SessionList {
        sessions: state.db.session_views().await?,
    }))
}

/// Get one session.
#[utoipa::path(
    get,
    path = "/v1/sessions/{id}",
    operation_id = "get_session",
    tag = "sessions",
    params(("id" = String, Path, description = "Session id")),
    responses(
        (status = 200, description = "The session", body = SessionView),
        (status = 400, description = "Invalid path: the id is not UTF-8", body = ErrorBody),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
        (status = 404, description = "No such session", body = ErrorBody),
    )
)]
pub async fn get_session(
    State(state): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<ApiJson<SessionView>, ApiError> {
    let core = state.db.session_core(&id).await?;
    Ok(ApiJson(core.view(&id, state.config.default_retention)))
}

/// Change a session: label, calibration, parameters, retention.
#[utoipa::path(
    patch,
    path = "/v1/sessions/{id}",
    operation_id = "patch_session",
    tag = "sessions",
    params(("id" = String, Path, description = "Session id")),
    request_body = SessionPatch,
    responses(
        (status = 200, description = "The changed session", body = SessionView),
        (status = 400, description = "Malformed JSON, unknown field, invalid parameter, an id that is not UTF-8, or `tilt_axis_conflict`: tracker.tilt_axis_deg is not the axis of the session's (new) calibration", body = ErrorBody),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
        (status = 404, description = "No such session or calibration", body = ErrorBody),
        (status = 408, description = "The request took too long (slow upload)", body = ErrorBody),
        (status = 409, description = "Hints for a session of several objects (`several_objects`): they are each object's own", body = ErrorBody),
        (status = 413, description = "Body beyond --max-body-mib", body = ErrorBody),
        (status = 415, description = "Not JSON", body = ErrorBody),
        (status = 422, description = "Invalid hint (`invalid_hint`): init.roi under 16 px a side, init.point not finite", body = ErrorBody),
        (status = 503, description = "Storage failed or the server is shutting down", body = ErrorBody),
    )
)]
pub async fn patch_session(
    State(state): State<AppState>,
    ApiPath(id): ApiPath<String>,
    ApiJson(body): ApiJson<SessionPatch>,
) -> Result<ApiJson<SessionView>, ApiError> {
    state.db.session(&id)?; // 404 before the body's own errors
    if let Some(Some(name)) = &body.name {
        check_name(Some(name))?;
    }
    check_retention(body.retention)?;
    let names_hints = |v: &Option<serde_json::Value>| {
        v.as_ref()
            .and_then(|v| v.as_object())
            .is_some_and(|m| HINT_FIELDS.iter().any(|h| m.contains_key(*h)))
    };
    let tracker_init = body.tracker.as_ref().and_then(|t| t.get("init")).cloned();
    let hints = names_hints(&body.init) || names_hints(&tracker_init);
    let attach = body.calibration_id.clone().flatten();
    // A tilt axis the patch sets (a number; null gives the axis back to the
    // calibration).
    let axis = body
        .tracker
        .as_ref()
        .and_then(|t| t.get("tilt_axis_deg"))
        .and_then(|v| v.as_f64());
    let view = state
        .db
        .update_session(&id, attach.as_deref(), |core| {
            let calibration = match &body.calibration_id {
                Some(change) => change.as_deref(),
                None => core.calibration_id.as_deref(),
            };
            check_axis(&state, axis, calibration)?;
            if core.session.objects().len() > 1 && hints {
                return Err(ApiError::conflict(
                    "several_objects",
                    "the session tracks several objects; their hints are their own (expected POST /v1/sessions/{id}/objects/{name}/reinit)",
                ));
            }
            if body.init.is_some() || body.tracker.is_some() {
                for object in core.session.objects_mut() {
                    let params =
                        patched_params(object.tracker.params(), body.init.clone(), body.tracker.clone())?;
                    object.tracker.set_params(params);
                }
            }
            if let Some(name) = body.name {
                core.name = name;
            }
            if let Some(cal) = body.calibration_id {
                core.calibration_id = cal;
            }
            if let Some(r) = body.retention {
                core.retention = Some(r);
            }
            if let Some(keep) = body.keep {
                core.keep = keep;
            }
            Ok(())
        })
        .await?;
    Ok(ApiJson(view))
}

/// Delete a session and its results.
#[utoipa::path(
    delete,
    path = "/v1/sessions/{id}",
    operation_id = "delete_session",
    tag = "sessions",
    params(("id" = String, Path, description = "Session id")),
    responses(
        (status = 204, description = "Deleted"),
        (status = 400, description = "Invalid path: the id is not UTF-8", body = ErrorBody),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
        (status = 404, description = "No such session", body = ErrorBody),
        (status = 503, description = "Storage failed or the server is shutting down", body = ErrorBody),
    )
)]
pub async fn delete_session(
    State(state): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<StatusCode, ApiError> {
    state.db.delete_session(&id).await?;
    Ok(StatusCode::NO_CONTENT)
}

/// Least `idle_for_s` of a bulk delete without a `name_prefix`, seconds:
/// less would take nearly every session not busy at that instant.
pub const MIN_IDLE_FOR_S: f64 = 60.0;

/// Query of `DELETE /v1/sessions`: which sessions to delete (at least one
/// of `name_prefix` and `idle_for_s`).
#[derive(Clone, Debug, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct BulkDeleteQuery {
    /// Sessions whose name starts with this (at least one character).
    #[param(min_length = 1)]
    pub name_prefix: Option<String>,
    /// Sessions without a pair or a change for at least this many seconds;
    /// at least 60 unless a `name_prefix` narrows the delete too.
    #[param(minimum = 0)]
    pub idle_for_s: Option<f64>,
    /// Include sessions marked `keep`. Default false.
    #[serde(default)]
    pub include_kept: bool,
}

/// Delete the sessions that match: by name prefix, by idle time, or both
/// (sessions busy with a pair and, unless included, those marked `keep`
/// are left).
#[utoipa::path(
    delete,
    path = "/v1/sessions",
    operation_id = "delete_sessions",
    tag = "sessions",
    params(BulkDeleteQuery),
    responses(
        (status = 200, description = "The sessions deleted", body = SessionsDeleted),
        (status = 400, description = "Neither name_prefix nor idle_for_s given, an empty name_prefix, idle_for_s under 60 without a name_prefix, or an invalid value", body = ErrorBody),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
        (status = 503, description = "Storage failed or the server is shutting down", body = ErrorBody),
    )
)]
pub async fn delete_sessions(
    State(state): State<AppState>,
    ApiQuery(query): ApiQuery<BulkDeleteQuery>,
) -> Result<ApiJson<SessionsDeleted>, ApiError> {
    if query.name_prefix.is_none() && query.idle_for_s.is_none() {
        return Err(ApiError::bad_request(
            "invalid_query",
            "give name_prefix, idle_for_s or both (a bulk delete of every session is not offered)",
        ));
    }
    // A filter must narrow: an empty prefix matches every name, and an idle
    // time of a few seconds every session not busy this instant.
    if query.name_prefix.as_deref() == Some("") {
        return Err(ApiError::bad_request(
            "invalid_query",
            "empty name_prefix (expected at least one character: an empty prefix matches every session)",
        ));
    }
    let least_idle = if query.name_prefix.is_some() {
        0.0
    } else {
        MIN_IDLE_FOR_S
    };
    let idle_for = match query.idle_for_s {
        Some(s) if s.is_finite() && (least_idle..=1e9).contains(&s) => {
            Some(std::time::Duration::from_secs_f64(s))
        }
        Some(s) => {
            let why = if query.name_prefix.is_some() {
                String::new()
            } else {
                format!("; below {MIN_IDLE_FOR_S} s only with a name_prefix")
            };
            return Err(ApiError::bad_request(
                "invalid_query",
                format!("invalid idle_for_s {s} (expected {least_idle}..=1e9{why})"),
            ));
        }
        None => None,
    };
    let ids = state
        .db
        .sessions_matching(idle_for, query.name_prefix.as_deref(), query.include_kept)?;
    let mut deleted = Vec::with_capacity(ids.len());
    for id in ids {
        match state.db.delete_session(&id).await {
            Ok(()) => deleted.push(id),
            // Deleted meanwhile by another request.
            Err(e) if e.status() == StatusCode::NOT_FOUND => {}
            Err(e) => return Err(e),
        }
    }
    Ok(ApiJson(SessionsDeleted { deleted }))
}

/// Upload one stereo pair; the first pair initialises the tracker.
#[utoipa::path(
    post,
    path = "/v1/sessions/{id}/frames",
    operation_id = "upload_pair",
    tag = "sessions",
    params(("id" = String, Path, description = "Session id"), ContoursQuery),
    request_body(content = PairUpload, content_type = "multipart/form-data", description = "Parts `left` and `right`: PNG, TIFF (8/16-bit), JPEG or BMP of equal size"),
    responses(
        (status = 200, description = "The pair's result (status initialised, tracked or lost)", body = FrameResult),
        (status = 400, description = "Bad multipart, missing part, undecodable image, mismatched sizes, a size other than the session's, or an id that is not UTF-8", body = ErrorBody),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
        (status = 404, description = "No such session", body = ErrorBody),
        (status = 408, description = "The upload took too long", body = ErrorBody),
        (status = 413, description = "Body or image beyond the limits", body = ErrorBody),
        (status = 415, description = "Not multipart/form-data", body = ErrorBody),
        (status = 422, description = "The session's hints do not fit the pair's images (`invalid_hint`: init.roi outside the image, init.point outside the image or the roi), a first pair's point or polarity matches no region (`hint_matches_nothing`, naming what was found instead), or two objects' hints resolve to one region (`objects_share_a_region`, naming both); the pair is not counted", body = ErrorBody),
        (status = 503, description = "Storage failed, the server is shutting down, or `busy`: the memory for work in flight (--max-inflight-mib) is in use; retry after the `Retry-After` seconds (the pair is not counted)", body = ErrorBody),
    )
)]
pub async fn upload_pair(
    State(state): State<AppState>,
    ApiPath(id): ApiPath<String>,
    ApiQuery(query): ApiQuery<ContoursQuery>,
    request: Request,
) -> Result<ApiJson<FrameResult>, ApiError> {
    let received = Instant::now();
    let session = state.db.session(&id)?;
    let (input, provenance) = read_pair_upload(request).await?;
    let result = process_session_pair(&state, &session, input, provenance, received, None).await?;
    Ok(ApiJson(if query.contours {
        result
    } else {
        result.without_contours()
    }))
}

/// Forget the object: the next pair initialises again.
#[utoipa::path(
    post,
    path = "/v1/sessions/{id}/reset",
    operation_id = "reset_session",
    tag = "sessions",
    params(("id" = String, Path, description = "Session id")),
    responses(
        (status = 200, description = "The session, awaiting its next first pair", body = SessionView),
        (status = 400, description = "Invalid path: the id is not UTF-8", body = ErrorBody),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
        (status = 404, description = "No such session", body = ErrorBody),
        (status = 503, description = "Storage failed or the server is shutting down", body = ErrorBody),
    )
)]
pub async fn reset_session(
    State(state): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<ApiJson<SessionView>, ApiError> {
    let view = state
        .db
        .update_session(&id, None, |core| {
            core.restart(None);
            Ok(())
        })
        .await?;
    Ok(ApiJson(view))
}

/// Name the object anew: the next pair initialises with these hints.
///
/// The hints (`roi`, `point`, `outline`, `exclude`, `polarity`,
/// `min_area_px`, `max_area_px`) replace the session's as a set; other `init` parameters given override
/// the session's. Earlier results stay and frames keep counting.
#[utoipa::path(
    post,
    path = "/v1/sessions/{id}/reinit",
    operation_id = "reinit_session",
    tag = "sessions",
    params(("id" = String, Path, description = "Session id")),
    request_body = SessionReinit,
    responses(
        (status = 200, description = "The session with its new hints, awaiting its next first pair", body = SessionView),
        (status = 400, description = "Malformed JSON, unknown field, invalid parameter (e.g. an unknown init.polarity, an init.point that is not two numbers), or an id that is not UTF-8", body = ErrorBody),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
        (status = 404, description = "No such session", body = ErrorBody),
        (status = 408, description = "The request took too long (slow upload)", body = ErrorBody),
        (status = 409, description = "The session tracks several objects (`several_objects`): name one with POST .../objects/{name}/reinit", body = ErrorBody),
        (status = 413, description = "Body beyond --max-body-mib", body = ErrorBody),
        (status = 415, description = "Not JSON", body = ErrorBody),
        (status = 422, description = "Invalid hint (`invalid_hint`): init.roi under 16 px a side, init.point not finite, init.outline crossing itself or of fewer than 3 vertices, more than 64 init.exclude points", body = ErrorBody),
        (status = 503, description = "Storage failed or the server is shutting down", body = ErrorBody),
    )
)]
pub async fn reinit_session(
    State(state): State<AppState>,
    ApiPath(id): ApiPath<String>,
    ApiJsonFields(body, fields): ApiJsonFields<SessionReinit>,
) -> Result<ApiJson<SessionView>, ApiError> {
    Ok(ApiJson(reinit(&state, &id, None, &body, &fields).await?))
}

/// Names the session's object (or its object `name`) anew with a reinit
/// body and its JSON `fields`: the next pair tracked initialises with the
/// new hints. The REST reinit routes and the stream's `reinit` message
/// share it.
pub(crate) async fn reinit(
    state: &AppState,
    id: &str,
    name: Option<&str>,
    body: &SessionReinit,
    fields: &serde_json::Map<String, serde_json::Value>,
) -> Result<SessionView, ApiError> {
    state
        .db
        .update_session(id, None, |core| match name {
            Some(name) => {
                let object = core.session.object_mut(name)?;
                let params = reinited(object.tracker.params(), body, fields)?;
                object.tracker.set_params(params);
                object.tracker.reset();
                Ok(())
            }
            None if core.session.objects().len() > 1 => Err(ApiError::conflict(
                "several_objects",
                format!(
                    "session {id:?} tracks {} objects (expected POST /v1/sessions/{{id}}/objects/{{name}}/reinit to name one)",
                    core.session.objects().len()
                ),
            )),
            None => {
                let params = reinited(core.primary().params(), body, fields)?;
                core.restart(Some(params));
                Ok(())
            }
        })
        .await
}

/// Output format of the results.
#[derive(Clone, Copy, Debug, Default, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum ResultsFormat {
    /// A JSON page of FrameResults.
    #[default]
    Json,
    /// CSV with a header line (contours left out).
    Csv,
}

/// Query of `GET /v1/sessions/{id}/results`.
#[derive(Clone, Debug, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct ResultsQuery {
    /// First frame to return. Default 0.
    #[serde(default)]
    pub since: u64,
    /// `json` (default) or `csv`.
    #[serde(default)]
    #[param(inline)]
    pub format: ResultsFormat,
    /// Most results returned (default and maximum 10000).
    #[param(minimum = 1, maximum = 10000)]
    pub limit: Option<usize>,
    /// Include the contours (default true; false empties their arrays).
    #[serde(default = "super::api::model::yes")]
    pub contours: bool,
}

/// The session's results, oldest first.
#[utoipa::path(
    get,
    path = "/v1/sessions/{id}/results",
    operation_id = "session_results",
    tag = "sessions",
    params(("id" = String, Path, description = "Session id"), ResultsQuery),
    responses(
        (status = 200, description = "Results with frame >= since", content(
            (ResultsPage = "application/json"),
            (String = "text/csv", example = "frame,name,status,...")
        )),
        (status = 400, description = "Invalid query, or an id that is not UTF-8", body = ErrorBody),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
        (status = 404, description = "No such session", body = ErrorBody),
        (status = 503, description = "Storage failed or the server is shutting down", body = ErrorBody),
    )
)]
pub async fn session_results(
    State(state): State<AppState>,
    ApiPath(id): ApiPath<String>,
    ApiQuery(query): ApiQuery<ResultsQuery>,
) -> Result<Response, ApiError> {
    state.db.session(&id)?;
    if query.since > MAX_INDEX {
        return Err(ApiError::bad_request(
            "invalid_query",
            format!("invalid since {} (expected 0..={MAX_INDEX})", query.since),
        ));
    }
    let limit = query.limit.unwrap_or(MAX_RESULTS_PAGE);
    if !(1..=MAX_RESULTS_PAGE).contains(&limit) {
        return Err(ApiError::bad_request(
            "invalid_query",
            format!("invalid limit {limit} (expected 1..={MAX_RESULTS_PAGE})"),
        ));
    }
    let rows = state.db.results(&id, query.since, limit + 1).await?;
    let more = rows.len() > limit;
    let mut results = Vec::with_capacity(rows.len().min(limit));
    for (frame, json) in rows.into_iter().take(limit) {
        let r: FrameResult = serde_json::from_str(&json).map_err(|e| {
            ApiError::internal(format!(
                "stored result {frame} of session {id} is unreadable: {e}"
            ))
        })?;
        results.push(if query.contours { r } else { r.without_contours() });
    }
    let next_since = if more {
        results.last().map(|r| r.result.frame + 1)
    } else {
        None
    };
    match query.format {
        ResultsFormat::Json => Ok(ApiJson(ResultsPage {
            session_id: id,
            results,
            next_since,
        })
        .into_response()),
        ResultsFormat::Csv => {
            // With several objects: a row per object and per ordered pair
            // of objects (see `report::objects_csv_records`).
            let named = results.iter().any(|r| r.objects.len() > 1);
            let mut text = if named {
                OBJECTS_CSV_HEADER.clone()
            } else {
                String::from(CSV_HEADER)
            };
            text.push('\n');
            for r in &results {
                let rows = match named {
                    false => vec![csv_record(&r.result, r.provenance.name())],
                    true => {
                        objects_csv_records(r.result.frame, &r.objects(), &r.relative, r.provenance.name())
                    }
                };
                for row in rows {
                    text.push_str(&row);
                    text.push('\n');
                }
            }
            Ok(([(header::CONTENT_TYPE, "text/csv; charset=utf-8")], text).into_response())
        }
    }
}

/// Pair the session's latest disparity with a known height and add it to a
/// fitted calibration.
#[utoipa::path(
    post,
    path = "/v1/sessions/{id}/calibration-samples",
    operation_id = "add_session_calibration_sample",
    tag = "sessions",
    params(("id" = String, Path, description = "Session id")),
    request_body = SessionSampleCreate,
    responses(
        (status = 200, description = "The refitted calibration", body = CalibrationView),
        (status = 400, description = "Malformed JSON, unknown field, or an id that is not UTF-8", body = ErrorBody),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
        (status = 404, description = "No such session or calibration", body = ErrorBody),
        (status = 408, description = "The request took too long (slow upload)", body = ErrorBody),
        (status = 409, description = "No tracked pair yet (`no_disparity_yet`), the latest pair was lost (`latest_pair_lost`), or not a fitted calibration", body = ErrorBody),
        (status = 413, description = "Body beyond --max-body-mib", body = ErrorBody),
        (status = 415, description = "Not JSON", body = ErrorBody),
        (status = 422, description = "Invalid height, or the refit is degenerate", body = ErrorBody),
        (status = 503, description = "Storage failed or the server is shutting down", body = ErrorBody),
    )
)]
pub async fn add_session_calibration_sample(
    State(state): State<AppState>,
    ApiPath(id): ApiPath<String>,
    ApiJson(body): ApiJson<SessionSampleCreate>,
) -> Result<ApiJson<CalibrationView>, ApiError> {
    state.db.session(&id)?; // 404 for the session before the calibration
    let calibration = state.db.calibration(&body.calibration_id)?;
    let (disparity, frame) = {
        let core = state.db.session_core(&id).await?;
        // Only the latest pair's own disparity: after a lost pair (or a
        // reset) the height would be paired with an older pair's.
        let frames = core.session.frames();
        match (core.state, core.latest_disparity_px, frames.checked_sub(1)) {
            (SessionState::Tracking, Some(d), Some(last)) => (d, last),
            (SessionState::Lost, _, _) => {
                return Err(ApiError::conflict(
                    "latest_pair_lost",
                    format!(
                        "session {id:?} cannot give a sample: its latest pair (frame {}) was lost, and an older pair's disparity would be paired with this height (upload a pair that is tracked first)",
                        frames.saturating_sub(1)
                    ),
                ))
            }
            _ => {
                return Err(ApiError::conflict(
                    "no_disparity_yet",
                    format!("session {id:?} has no tracked pair since its start or reset (upload a pair that is tracked first)"),
                ))
            }
        }
    };
    let d_axis = axis_component(calibration.calibration.tilt_axis_deg(), disparity);
    let sample = Sample::new(d_axis, body.z_um).from_pair(&id, frame);
    let view = add_sample(&state, &body.calibration_id, sample).await?;
    Ok(ApiJson(view))
}

/// Query of `POST /v1/depth`.
#[derive(Clone, Debug, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct DepthQuery {
    /// Calibration for z_um (omitted: z_um is null).
    pub calibration_id: Option<String>,
    /// Direction of the tilt axis, degrees from +x towards +y (default: the
    /// calibration's, else 90); with a calibration, it must be the
    /// calibration's axis (else 400 `tilt_axis_conflict`).
    #[param(minimum = -360.0, maximum = 360.0)]
    pub tilt_axis_deg: Option<f64>,
    /// Hint: the box `x,y,width,height` (pixels) the object lies in, clipped
    /// to the image; width and height >= 16 (a session's `init.roi`).
    #[param(
        example = "120,80,200,160",
        pattern = r"^ *[+-]?[0-9]+ *(, *[+-]?[0-9]+ *){3}$"
    )]
    pub roi: Option<String>,
    /// Hint: a point `x,y` (pixels) on the object (a session's `init.point`).
    #[param(
        example = "210.5,160",
        pattern = r"^ *[+-]?([0-9]+(\.[0-9]*)?|\.[0-9]+)([eE][+-]?[0-9]+)? *, *[+-]?([0-9]+(\.[0-9]*)?|\.[0-9]+)([eE][+-]?[0-9]+)? *$"
    )]
    pub point: Option<String>,
    /// Hint: the object's outline as drawn round it, `x,y,x,y,x,y,...`
    /// (pixels, at least three vertices; a session's `init.outline`).
    #[param(
        example = "100,80,300,80,300,240,100,240",
        pattern = r"^ *[+-]?([0-9]+(\.[0-9]*)?|\.[0-9]+)([eE][+-]?[0-9]+)? *(, *[+-]?([0-9]+(\.[0-9]*)?|\.[0-9]+)([eE][+-]?[0-9]+)? *){5,}$"
    )]
    pub outline: Option<String>,
    /// Hint: points on what is not the object, `x,y,x,y,...` (pixels, at
    /// most 64 points; a session's `init.exclude`).
    #[param(
        example = "40,300",
        pattern = r"^ *[+-]?([0-9]+(\.[0-9]*)?|\.[0-9]+)([eE][+-]?[0-9]+)? *(, *[+-]?([0-9]+(\.[0-9]*)?|\.[0-9]+)([eE][+-]?[0-9]+)? *)+$"
    )]
    pub exclude: Option<String>,
    /// Hint: `brighter`, `darker` or `any` (default; a session's `init.polarity`).
    #[param(value_type = Option<ApiPolarity>)]
    pub polarity: Option<String>,
}

impl DepthQuery {
    /// The hints of the query applied to `init`; 400 `invalid_query` for a
    /// value that does not parse, naming the parameter.
    fn apply_hints(&self, init: &mut InitParams) -> Result<(), ApiError> {
        if let Some(text) = &self.roi {
            init.roi = Some(numbers(text).ok_or_else(|| {
                ApiError::bad_request(
                    "invalid_query",
                    format!("invalid roi {text:?} (expected four integers x,y,width,height in pixels, e.g. roi=120,80,200,160)"),
                )
            })?);
        }
        if let Some(text) = &self.point {
            // "inf" and "NaN" parse, and are refused with the other hints' checks.
            init.point = Some(numbers(text).ok_or_else(|| {
                ApiError::bad_request(
                    "invalid_query",
                    format!(
                        "invalid point {text:?} (expected two numbers x,y in pixels, e.g. point=210.5,160)"
                    ),
                )
            })?);
        }
        if let Some(text) = &self.outline {
            init.outline = Some(xy_pairs(text, 3).ok_or_else(|| {
                ApiError::bad_request(
                    "invalid_query",
                    format!("invalid outline {text:?} (expected at least three x,y vertices in pixels, e.g. outline=100,80,300,80,300,240)"),
                )
            })?);
        }
        if let Some(text) = &self.exclude {
            init.exclude = xy_pairs(text, 1).ok_or_else(|| {
                ApiError::bad_request(
                    "invalid_query",
                    format!("invalid exclude {text:?} (expected x,y points in pixels, e.g. exclude=40,300)"),
                )
            })?;
        }
        if let Some(text) = &self.polarity {
            let all = [Polarity::Brighter, Polarity::Darker, Polarity::Any];
            init.polarity = all.into_iter().find(|p| p.name() == text).ok_or_else(|| {
                ApiError::bad_request(
                    "invalid_query",
                    format!("invalid polarity {text:?} (expected brighter, darker or any)"),
                )
            })?;
        }
        Ok(())
    }
}

/// Exactly `N` comma-separated numbers, each with optional spaces around it
/// (the pattern the query parameters document).
fn numbers<T: std::str::FromStr, const N: usize>(text: &str) -> Option<[T; N]> {
    listed(text)?.try_into().ok()
}

/// At least `least` comma-separated `x,y` pairs of numbers (the pattern
/// the query parameters document).
fn xy_pairs(text: &str, least: usize) -> Option<Vec<[f64; 2]>> {
    super::api::params::xy_pairs(&listed(text)?, least)
}

/// Comma-separated values, each with optional spaces around it.
fn listed<T: std::str::FromStr>(text: &str) -> Option<Vec<T>> {
    text.split(',')
        .map(|v| v.trim_matches(' ').parse().ok())
        .collect()
}

/// Initialise and measure one pair without a session.
#[utoipa::path(
    post,
    path = "/v1/depth",
    operation_id = "one_shot_depth",
    tag = "depth",
    params(DepthQuery),
    request_body(content = PairUpload, content_type = "multipart/form-data", description = "Parts `left` and `right`"),
    responses(
        (status = 200, description = "The pair's result (status initialised or lost)", body = FrameResult),
        (status = 400, description = "Bad multipart, missing part, undecodable image, mismatched sizes, invalid query (e.g. a roi that is not four integers, an unknown polarity), or `tilt_axis_conflict`: tilt_axis_deg is not the calibration's axis", body = ErrorBody),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
        (status = 404, description = "Unknown calibration", body = ErrorBody),
        (status = 408, description = "The upload took too long", body = ErrorBody),
        (status = 413, description = "Body or image beyond the limits", body = ErrorBody),
        (status = 415, description = "Not multipart/form-data", body = ErrorBody),
        (status = 422, description = "Invalid hint (`invalid_hint`): roi under 16 px a side or outside the image, point not finite or outside the image or the roi, an outline that crosses itself or encloses too little of the image, a point that is not the object inside the outline; or hints that match no region (`hint_matches_nothing`)", body = ErrorBody),
        (status = 503, description = "The server is shutting down, or `busy`: the memory for work in flight (--max-inflight-mib) is in use; retry after the `Retry-After` seconds", body = ErrorBody),
    )
)]
pub async fn one_shot_depth(
    State(state): State<AppState>,
    ApiQuery(query): ApiQuery<DepthQuery>,
    request: Request,
) -> Result<ApiJson<FrameResult>, ApiError> {
    let received = Instant::now();
    let mut params = TrackerParams::default();
    if let Some(id) = &query.calibration_id {
        let own = state.db.calibration(id)?.calibration.tilt_axis_deg();
        if let Some(axis) = query.tilt_axis_deg {
            same_axis(axis, own)?;
        }
        params.tilt_axis_deg = own;
    }
    if let Some(axis) = query.tilt_axis_deg {
        params.tilt_axis_deg = axis;
    }
    query.apply_hints(&mut params.init)?;
    let params = checked(params)?;
    let (input, provenance) = read_pair_upload(request).await?;
    let result = process_one_shot(&state, params, query.calibration_id, input, provenance, received).await?;
    Ok(ApiJson(result))
}

/// 400 `tilt_axis_conflict` when a tilt axis given explicitly is not the
/// axis of the calibration in use (404 for an unknown calibration): the
/// calibration's z is a function of the disparity across its own axis.
fn check_axis(state: &AppState, explicit: Option<f64>, calibration: Option<&str>) -> Result<(), ApiError> {
    let (Some(axis), Some(id)) = (explicit, calibration) else {
        return Ok(());
    };
    same_axis(axis, state.db.calibration(id)?.calibration.tilt_axis_deg())
}

/// [`same_tilt_axis`] as a 400 `tilt_axis_conflict`.
fn same_axis(explicit: f64, calibration: f64) -> Result<(), ApiError> {
    same_tilt_axis(explicit, calibration).map_err(|e| ApiError::bad_request("tilt_axis_conflict", e))
}

/// Parameters from a base, a top-level `init` and a `tracker` object.
/// Add an object to a session; it initialises on the next pair.
#[utoipa::path(
    post,
    path = "/v1/sessions/{id}/objects",
    operation_id = "add_object",
    tag = "sessions",
    params(("id" = String, Path, description = "Session id")),
    request_body = ObjectCreate,
    responses(
        (status = 201, description = "The session with the new object", body = SessionView),
        (status = 400, description = "Malformed JSON, unknown field, invalid object name or parameter", body = ErrorBody),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
        (status = 404, description = "No such session", body = ErrorBody),
        (status = 408, description = "The request took too long (slow upload)", body = ErrorBody),
        (status = 409, description = "An object of that name exists (`duplicate_object`), or the session has 16 (`object_count`)", body = ErrorBody),
        (status = 413, description = "Body beyond --max-body-mib", body = ErrorBody),
        (status = 415, description = "Not JSON", body = ErrorBody),
        (status = 422, description = "Invalid hint (`invalid_hint`)", body = ErrorBody),
        (status = 503, description = "Storage failed or the server is shutting down", body = ErrorBody),
    )
)]
pub async fn add_object(
    State(state): State<AppState>,
    ApiPath(id): ApiPath<String>,
    ApiJson(body): ApiJson<ObjectCreate>,
) -> Result<(StatusCode, ApiJson<SessionView>), ApiError> {
    let view = state
        .db
        .update_session(&id, None, |core| {
            let params = checked(body.params(core.primary().params()))?;
            Ok(core.session.add(SessionObject::new(body.name, params))?)
        })
        .await?;
    Ok((StatusCode::CREATED, ApiJson(view)))
}

/// Remove an object from a session (a session keeps at least one); the
/// results already stored keep it.
#[utoipa::path(
    delete,
    path = "/v1/sessions/{id}/objects/{name}",
    operation_id = "delete_object",
    tag = "sessions",
    params(
        ("id" = String, Path, description = "Session id"),
        ("name" = String, Path, description = "Object name"),
    ),
    responses(
        (status = 200, description = "The session without the object", body = SessionView),
        (status = 400, description = "Invalid path", body = ErrorBody),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
        (status = 404, description = "No such session or object", body = ErrorBody),
        (status = 409, description = "It is the session's last object (`object_count`)", body = ErrorBody),
        (status = 503, description = "Storage failed or the server is shutting down", body = ErrorBody),
    )
)]
pub async fn delete_object(
    State(state): State<AppState>,
    ApiPath((id, name)): ApiPath<(String, String)>,
) -> Result<ApiJson<SessionView>, ApiError> {
    let view = state
        .db
        .update_session(&id, None, |core| Ok(core.session.remove(&name).map(drop)?))
        .await?;
    Ok(ApiJson(view))
}

/// Name one object anew: its next pair initialises with these hints (the
/// hints replace its own as a set; other `init` parameters given override
/// its own). The other objects go on.
#[utoipa::path(
    post,
    path = "/v1/sessions/{id}/objects/{name}/reinit",
    operation_id = "reinit_object",
    tag = "sessions",
    params(
        ("id" = String, Path, description = "Session id"),
        ("name" = String, Path, description = "Object name"),
    ),
    request_body = SessionReinit,
    responses(
        (status = 200, description = "The session, the object awaiting its next first pair", body = SessionView),
        (status = 400, description = "Malformed JSON, unknown field, invalid parameter", body = ErrorBody),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
        (status = 404, description = "No such session or object", body = ErrorBody),
        (status = 408, description = "The request took too long (slow upload)", body = ErrorBody),
        (status = 413, description = "Body beyond --max-body-mib", body = ErrorBody),
        (status = 415, description = "Not JSON", body = ErrorBody),
        (status = 422, description = "Invalid hint (`invalid_hint`)", body = ErrorBody),
        (status = 503, description = "Storage failed or the server is shutting down", body = ErrorBody),
    )
)]
pub async fn reinit_object(
    State(state): State<AppState>,
    ApiPath((id, name)): ApiPath<(String, String)>,
    ApiJsonFields(body, fields): ApiJsonFields<SessionReinit>,
) -> Result<ApiJson<SessionView>, ApiError> {
    Ok(ApiJson(reinit(&state, &id, Some(&name), &body, &fields).await?))
}

/// `current` with a reinit body's `init` applied (see
/// [`SessionReinit::apply`]), validated.
fn reinited(
    current: &TrackerParams,
    body: &SessionReinit,
    fields: &serde_json::Map<String, serde_json::Value>,
) -> Result<TrackerParams, ApiError> {
    let mut params = current.clone();
    params.init = body
        .apply(&current.init, fields)
        .map_err(|e| ApiError::internal(format!("merging initialisation parameters: {e}")))?;
    checked(params)
}

fn merge_params(
    base: TrackerParams,
    init: Option<semdepth_core::init::InitParams>,
    tracker: Option<TrackerParams>,
) -> Result<TrackerParams, ApiError> {
    let mut params = match tracker {
        Some(t) => {
            if init.is_some() && t.init != base.init && t.init != semdepth_core::init::InitParams::default() {
                return Err(ApiError::bad_request(
                    "conflicting_parameters",
                    "both \"init\" and \"tracker.init\" are given (expected the initialisation parameters once, as \"init\")",
                ));
            }
            t
        }
        None => base,
    };
    if let Some(init) = init {
        params.init = init;
    }
    checked(params)
}

/// `current` with the merge patches (RFC 7396) `tracker` (on the whole
/// parameters) and `init` (on `init`) applied, then validated. Fields the
/// patches leave out keep their values; unknown fields are refused, as in
/// a full body.
fn patched_params(
    current: &TrackerParams,
    init: Option<serde_json::Value>,
    tracker: Option<serde_json::Value>,
) -> Result<TrackerParams, ApiError> {
    let invalid = |field: &str, e: serde_json::Error| {
        ApiError::bad_request("invalid_parameter", format!("{field}: {e}"))
    };
    let mut params = serde_json::to_value(api::TrackerParams::from(current.clone()))
        .map_err(|e| ApiError::internal(format!("serialising parameters: {e}")))?;
    if let Some(patch) = tracker {
        if init.is_some() && patch.get("init").is_some() {
            return Err(ApiError::bad_request(
                "conflicting_parameters",
                "both \"init\" and \"tracker.init\" are given (expected the initialisation parameters once, as \"init\")",
            ));
        }
        if !patch.is_object() {
            return Err(ApiError::bad_request(
                "invalid_parameter",
                format!("tracker: expected an object of the fields to change, got {patch}"),
            ));
        }
        merge_patch::apply(&mut params, patch);
    }
    if let Some(patch) = init {
        if !patch.is_object() {
            return Err(ApiError::bad_request(
                "invalid_parameter",
                format!("init: expected an object of the fields to change, got {patch}"),
            ));
        }
        merge_patch::apply(&mut params["init"], patch);
    }
    let params: api::TrackerParams = serde_json::from_value(params).map_err(|e| invalid("tracker", e))?;
    checked(params.into())
}

/// Validated parameters: 422 `invalid_hint` for a hint out of range (the
/// message names the field, e.g. `init.roi`), else 400 `invalid_parameter`.
fn checked(params: TrackerParams) -> Result<TrackerParams, ApiError> {
    if let Err(e @ InitError::InvalidHint { .. }) = params.init.validate() {
        return Err(ApiError::hint(e));
    }
    params
        .validate()
        .map_err(|e| ApiError::bad_request("invalid_parameter", e))?;
    Ok(params)
}

/// Largest count or frame index the API takes: SQLite integers are i64.
const MAX_INDEX: u64 = i64::MAX as u64;

fn check_retention(retention: Option<u64>) -> Result<(), ApiError> {
    match retention {
        Some(r) if !(1..=MAX_INDEX).contains(&r) => Err(ApiError::bad_request(
            "invalid_parameter",
            format!("invalid retention {r} (expected 1..={MAX_INDEX} results kept)"),
        )),
        _ => Ok(()),
    }
}

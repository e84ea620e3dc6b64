//! `/v1/calibrations`: create (geometric or fitted), list, get, delete,
//! append a sample and refit. Calibrations are committed with
//! `synchronous=FULL` before the response.

use axum::extract::State;
use axum::http::StatusCode;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use semdepth_core::calib::{build, Sample};

use super::api::model::{
    check_label, CalibrationCreate, CalibrationList, CalibrationView, Label, SampleCreate, SamplePatch,
};
use super::error::{ApiError, ApiJson, ApiPath, ErrorBody};
use super::state::AppState;

/// The calibration routes.
pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(create_calibration, list_calibrations))
        .routes(routes!(get_calibration, delete_calibration))
        .routes(routes!(add_calibration_sample))
        .routes(routes!(remove_calibration_sample, edit_calibration_sample))
        .routes(routes!(get_calibration_version))
}

/// One version of a calibration, as it was: what a result made with it
/// meant.
#[utoipa::path(
    get,
    path = "/v1/calibrations/{id}/versions/{version}",
    operation_id = "get_calibration_version",
    tag = "calibrations",
    params(
        ("id" = String, Path, description = "Calibration id"),
        ("version" = u64, Path, description = "Version, from 1"),
    ),
    responses(
        (status = 200, description = "The calibration at that version", body = CalibrationView),
        (status = 400, description = "Invalid path: the id is not UTF-8 or the version not a number", body = ErrorBody),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
        (status = 404, description = "No such calibration or version", body = ErrorBody),
        (status = 503, description = "Storage failed or the server is shutting down", body = ErrorBody),
    )
)]
pub async fn get_calibration_version(
    State(state): State<AppState>,
    ApiPath((id, version)): ApiPath<(String, u64)>,
) -> Result<ApiJson<CalibrationView>, ApiError> {
    Ok(ApiJson(CalibrationView::from(
        &state.db.calibration_version(&id, version).await?,
    )))
}

/// Create a calibration.
#[utoipa::path(
    post,
    path = "/v1/calibrations",
    operation_id = "create_calibration",
    tag = "calibrations",
    request_body = CalibrationCreate,
    responses(
        (status = 201, description = "Created", body = CalibrationView),
        (status = 400, description = "Malformed JSON or unknown field", body = ErrorBody),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
        (status = 408, description = "The request took too long (slow upload)", body = ErrorBody),
        (status = 413, description = "Body beyond --max-body-mib", body = ErrorBody),
        (status = 415, description = "Not JSON", body = ErrorBody),
        (status = 422, description = "Invalid parameters, too few distinct samples or a degenerate fit", body = ErrorBody),
        (status = 503, description = "Storage failed or the server is shutting down", body = ErrorBody),
    )
)]
pub async fn create_calibration(
    State(state): State<AppState>,
    ApiJson(body): ApiJson<CalibrationCreate>,
) -> Result<(StatusCode, ApiJson<CalibrationView>), ApiError> {
    let (name, spec) = body.into_parts();
    check_name(name.as_deref())?;
    let record = state.db.create_calibration(name, build(spec)?).await?;
    Ok((StatusCode::CREATED, ApiJson(CalibrationView::from(&record))))
}

/// List calibrations, oldest first.
#[utoipa::path(
    get,
    path = "/v1/calibrations",
    operation_id = "list_calibrations",
    tag = "calibrations",
    responses(
        (status = 200, description = "All calibrations", body = CalibrationList),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
    )
)]
pub async fn list_calibrations(State(state): State<AppState>) -> Result<ApiJson<CalibrationList>, ApiError> {
    let calibrations = state
        .db
        .calibrations()?
        .iter()
        .map(CalibrationView::from)
        .collect();
    Ok(ApiJson(CalibrationList { calibrations }))
}

/// Get one calibration.
#[utoipa::path(
    get,
    path = "/v1/calibrations/{id}",
    operation_id = "get_calibration",
    tag = "calibrations",
    params(("id" = String, Path, description = "Calibration id")),
    responses(
        (status = 200, description = "The calibration", body = CalibrationView),
        (status = 400, description = "Invalid path: the id is not UTF-8", body = ErrorBody),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
        (status = 404, description = "No such calibration", body = ErrorBody),
    )
)]
pub async fn get_calibration(
    State(state): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<ApiJson<CalibrationView>, ApiError> {
    Ok(ApiJson(CalibrationView::from(&state.db.calibration(&id)?)))
}

/// Delete a calibration. Refused (409) while a session uses it.
#[utoipa::path(
    delete,
    path = "/v1/calibrations/{id}",
    operation_id = "delete_calibration",
    tag = "calibrations",
    params(("id" = String, Path, description = "Calibration id")),
    responses(
        (status = 204, description = "Deleted"),
        (status = 400, description = "Invalid path: the id is not UTF-8", body = ErrorBody),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
        (status = 404, description = "No such calibration", body = ErrorBody),
        (status = 409, description = "A session uses it; detach it first", body = ErrorBody),
        (status = 503, description = "Storage failed or the server is shutting down", body = ErrorBody),
    )
)]
pub async fn delete_calibration(
    State(state): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<StatusCode, ApiError> {
    state.db.delete_calibration(&id).await?;
    Ok(StatusCode::NO_CONTENT)
}

/// Append a sample to a fitted calibration and refit it.
#[utoipa::path(
    post,
    path = "/v1/calibrations/{id}/samples",
    operation_id = "add_calibration_sample",
    tag = "calibrations",
    params(("id" = String, Path, description = "Calibration id")),
    request_body = SampleCreate,
    responses(
        (status = 200, description = "The refitted calibration", body = CalibrationView),
        (status = 400, description = "Malformed JSON, unknown field, or an id that is not UTF-8", body = ErrorBody),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
        (status = 404, description = "No such calibration", body = ErrorBody),
        (status = 408, description = "The request took too long (slow upload)", body = ErrorBody),
        (status = 409, description = "Not a fitted calibration", body = ErrorBody),
        (status = 413, description = "Body beyond --max-body-mib", body = ErrorBody),
        (status = 415, description = "Not JSON", body = ErrorBody),
        (status = 422, description = "Invalid sample, or the refit is degenerate", body = ErrorBody),
        (status = 503, description = "Storage failed or the server is shutting down", body = ErrorBody),
    )
)]
pub async fn add_calibration_sample(
    State(state): State<AppState>,
    ApiPath(id): ApiPath<String>,
    ApiJson(body): ApiJson<SampleCreate>,
) -> Result<ApiJson<CalibrationView>, ApiError> {
    let view = add_sample(&state, &id, Sample::new(body.disparity_px, body.z_um)).await?;
    Ok(ApiJson(view))
}

/// Remove a sample from a fitted calibration (an outlier, a mistyped
/// height) and refit.
#[utoipa::path(
    delete,
    path = "/v1/calibrations/{id}/samples/{index}",
    operation_id = "remove_calibration_sample",
    tag = "calibrations",
    params(
        ("id" = String, Path, description = "Calibration id"),
        ("index" = usize, Path, description = "The sample's position in `samples`, from 0"),
    ),
    responses(
        (status = 200, description = "The refitted calibration", body = CalibrationView),
        (status = 400, description = "Invalid path: the id is not UTF-8 or the index not a number", body = ErrorBody),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
        (status = 404, description = "No such calibration, or no such sample (`sample_not_found`)", body = ErrorBody),
        (status = 409, description = "Not a fitted calibration", body = ErrorBody),
        (status = 422, description = "The refit is degenerate (too few distinct samples left make the calibration pending)", body = ErrorBody),
        (status = 503, description = "Storage failed or the server is shutting down", body = ErrorBody),
    )
)]
pub async fn remove_calibration_sample(
    State(state): State<AppState>,
    ApiPath((id, index)): ApiPath<(String, usize)>,
) -> Result<ApiJson<CalibrationView>, ApiError> {
    let view = refit(&state, &id, |c| c.remove_sample(index).map(drop)).await?;
    Ok(ApiJson(view))
}

/// Change a sample of a fitted calibration (a height typed wrong) and
/// refit. Where the sample came from (session, frame) is kept.
#[utoipa::path(
    patch,
    path = "/v1/calibrations/{id}/samples/{index}",
    operation_id = "edit_calibration_sample",
    tag = "calibrations",
    params(
        ("id" = String, Path, description = "Calibration id"),
        ("index" = usize, Path, description = "The sample's position in `samples`, from 0"),
    ),
    request_body = SamplePatch,
    responses(
        (status = 200, description = "The refitted calibration", body = CalibrationView),
        (status = 400, description = "Malformed JSON, unknown field, or an invalid path", body = ErrorBody),
        (status = 401, description = "Missing or wrong bearer token", body = ErrorBody),
        (status = 404, description = "No such calibration, or no such sample (`sample_not_found`)", body = ErrorBody),
        (status = 409, description = "Not a fitted calibration", body = ErrorBody),
        (status = 415, description = "Not JSON", body = ErrorBody),
        (status = 422, description = "Invalid value, or the refit is degenerate", body = ErrorBody),
        (status = 503, description = "Storage failed or the server is shutting down", body = ErrorBody),
    )
)]
pub async fn edit_calibration_sample(
    State(state): State<AppState>,
    ApiPath((id, index)): ApiPath<(String, usize)>,
    ApiJson(body): ApiJson<SamplePatch>,
) -> Result<ApiJson<CalibrationView>, ApiError> {
    let view = refit(&state, &id, |c| {
        c.update_sample(index, |old| Sample {
            disparity_px: body.disparity_px.unwrap_or(old.disparity_px),
            z_um: body.z_um.unwrap_or(old.z_um),
            ..old.clone()
        })
        .map(drop)
    })
    .await?;
    Ok(ApiJson(view))
}

/// Adds a sample to the fitted calibration `id`, refits and stores it.
pub async fn add_sample(state: &AppState, id: &str, sample: Sample) -> Result<CalibrationView, ApiError> {
    refit(state, id, |c| c.add_sample(sample)).await
}

/// Changes the samples of the fitted calibration `id` by `change` (which
/// refits), and stores it; on any error it stays as it was.
async fn refit(
    state: &AppState,
    id: &str,
    change: impl FnOnce(&mut semdepth_core::calib::Calibration) -> Result<(), semdepth_core::calib::CalibError>,
) -> Result<CalibrationView, ApiError> {
    Ok(CalibrationView::from(
        &state.db.refit_calibration(id, change).await?,
    ))
}

/// Names are free text but bounded (see [`check_label`]).
pub fn check_name(name: Option<&str>) -> Result<(), ApiError> {
    check_label(Label::Name, name)
}

//! The JSON shapes of the API (contract: `../shared/docs/api.md`): requests
//! (all refusing unknown fields) and responses, with their OpenAPI schemas.

use serde::{Deserialize, Deserializer, Serialize};
use utoipa::ToSchema;

use semdepth_core::calib::{
    CalibrationSpec, FitSpec, GeometricSpec, DEFAULT_FIT_DEGREE, DEFAULT_TILT_AXIS_DEG,
};
use semdepth_core::{init, session, tracker};

use super::calibration::{PixelSizeSource, Sample, VergenceSource};
use super::params::{InitParams, Polarity, TrackerParams};
use super::results::{ObjectResult, PairResult, Relative, SessionState};
use crate::service::error::ApiError;
use crate::service::storage::{CalibrationRecord, ObjectRecord, SessionRecord};

/// Body of `POST /v1/calibrations`: a geometric model or a least-squares
/// fit through (disparity, z) samples.
#[derive(Clone, Debug, Deserialize, ToSchema)]
#[serde(tag = "model", rename_all = "snake_case", deny_unknown_fields)]
pub enum CalibrationCreate {
    /// Eucentric tilt geometry: z = (d - reference) * pixel_size / (2 sin(vergence / 2)).
    /// The pixel size is `pixel_size_um` or, with `"pixel_size": "from_images"`,
    /// each pair's image metadata; the vergence is `vergence_deg` or, with
    /// `"vergence": "from_stage_tilt"`, the right image's stage tilt minus the
    /// left's.
    #[schema(example = json!({"name": "5 kx, 6 deg", "model": "geometric", "pixel_size_um": 0.5, "vergence_deg": 6.0, "reference_disparity_px": 0.0, "tilt_axis_deg": 90.0}))]
    Geometric {
        /// Free-text label.
        #[serde(default)]
        name: Option<String>,
        /// Length of one pixel at the specimen, micrometres (> 0). Give this
        /// or `pixel_size`.
        #[serde(default)]
        #[schema(exclusive_minimum = 0.0)]
        pixel_size_um: Option<f64>,
        /// `from_images`: the pixel size each pair's images carry.
        #[serde(default)]
        pixel_size: Option<PixelSizeSource>,
        /// Total vergence angle between the two views, degrees (0 < v <= 90).
        /// Give this or `vergence`.
        #[serde(default)]
        #[schema(exclusive_minimum = 0.0, maximum = 90.0)]
        vergence_deg: Option<f64>,
        /// `from_stage_tilt`: the difference of each pair's stage tilts.
        #[serde(default)]
        vergence: Option<VergenceSource>,
        /// Disparity across the tilt axis at z = 0, pixels. Default 0.
        #[serde(default)]
        #[schema(minimum = -1e6, maximum = 1e6)]
        reference_disparity_px: f64,
        /// Direction of the tilt axis in the image, degrees from +x towards +y. Default 90.
        #[serde(default = "default_tilt_axis_deg")]
        #[schema(minimum = -360.0, maximum = 360.0)]
        tilt_axis_deg: f64,
    },
    /// Least-squares polynomial z(d) of degree 1 or 2 through samples.
    #[schema(example = json!({"name": "stage steps", "model": "fit", "degree": 1, "samples": [{"disparity_px": 1.2, "z_um": 0.0}, {"disparity_px": 3.4, "z_um": 10.0}]}))]
    Fit {
        /// Free-text label.
        #[serde(default)]
        name: Option<String>,
        /// Polynomial degree, 1 or 2. Default 1.
        #[serde(default = "default_fit_degree")]
        #[schema(minimum = 1, maximum = 2)]
        degree: u8,
        /// The measurements: disparity across the tilt axis (px) at a known
        /// height (um). With fewer than degree + 1 distinct disparities (none,
        /// say) the calibration is created `pending` and gives no z yet.
        #[schema(min_items = 0, max_items = 10000)]
        samples: Vec<Sample>,
        /// Direction of the tilt axis in the image, degrees from +x towards +y. Default 90.
        #[serde(default = "default_tilt_axis_deg")]
        #[schema(minimum = -360.0, maximum = 360.0)]
        tilt_axis_deg: f64,
    },
}

fn default_tilt_axis_deg() -> f64 {
    DEFAULT_TILT_AXIS_DEG
}

fn default_fit_degree() -> u8 {
    DEFAULT_FIT_DEGREE
}

impl CalibrationCreate {
    /// The label and the model's parameters.
    pub fn into_parts(self) -> (Option<String>, CalibrationSpec) {
        match self {
            Self::Geometric {
                name,
                pixel_size_um,
                pixel_size,
                vergence_deg,
                vergence,
                reference_disparity_px,
                tilt_axis_deg,
            } => (
                name,
                CalibrationSpec::Geometric(GeometricSpec {
                    pixel_size_um,
                    pixel_size: pixel_size.map(Into::into),
                    vergence_deg,
                    vergence: vergence.map(Into::into),
                    reference_disparity_px,
                    tilt_axis_deg,
                }),
            ),
            Self::Fit {
                name,
                degree,
                samples,
                tilt_axis_deg,
            } => (
                name,
                CalibrationSpec::Fit(FitSpec {
                    degree,
                    samples: samples.into_iter().map(Into::into).collect(),
                    tilt_axis_deg,
                }),
            ),
        }
    }
}

/// A stored calibration as the API returns it. Named `Calibration` in the
/// OpenAPI document: the resource a `calibration_id` names (tools that
/// infer links from field names, as schemathesis does, match the two).
#[derive(Clone, Debug, Serialize, Deserialize, ToSchema)]
#[schema(as = Calibration)]
#[schema(example = json!({"id": "c_3f2a", "name": "stage steps", "model": "fit", "tilt_axis_deg": 90.0, "coefficients": [-5.45, 4.54], "degree": 1, "samples": [{"disparity_px": 1.2, "z_um": 0.0}, {"disparity_px": 3.4, "z_um": 10.0}], "residual_rms_um": 0.0, "r_squared": 1.0, "created_at": "2026-11-21T10:00:00Z", "updated_at": "2026-11-21T10:00:00Z"}))]
pub struct CalibrationView {
    /// Opaque id.
    pub id: String,
    /// Free-text label.
    pub name: Option<String>,
    /// 1 when created, one more with every change of its samples; results
    /// record the version they used.
    pub version: u64,
    /// `geometric` or `fit`.
    pub model: String,
    /// A fit without enough distinct samples yet: why it gives no z (every
    /// result's z_um is null, with this as a warning, until samples at
    /// other heights are added).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pending: Option<String>,
    /// Direction of the tilt axis, degrees from +x towards +y.
    pub tilt_axis_deg: f64,
    /// z_um = c0 + c1 d (+ c2 d^2), d the disparity across the tilt axis in
    /// pixels; empty when the scale comes from each pair's images.
    pub coefficients: Vec<f64>,
    /// Geometric: micrometres per pixel.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pixel_size_um: Option<f64>,
    /// Geometric: `from_images` when the pixel size comes from each pair.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pixel_size: Option<PixelSizeSource>,
    /// Geometric: vergence angle, degrees.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vergence_deg: Option<f64>,
    /// Geometric: `from_stage_tilt` when the vergence comes from each pair.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vergence: Option<VergenceSource>,
    /// Geometric: disparity at z = 0, pixels.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reference_disparity_px: Option<f64>,
    /// Fit: polynomial degree.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub degree: Option<u8>,
    /// Fit: the samples, in the order they were given.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub samples: Option<Vec<Sample>>,
    /// Fit: per sample, its height minus the fit's at its disparity,
    /// micrometres (in the samples' order): an outlier stands out.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub residuals_um: Option<Vec<f64>>,
    /// Fit: RMS of the residuals, micrometres.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub residual_rms_um: Option<f64>,
    /// Fit: coefficient of determination, 0..=1.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub r_squared: Option<f64>,
    /// RFC 3339 UTC.
    pub created_at: String,
    /// RFC 3339 UTC.
    pub updated_at: String,
}

impl From<&CalibrationRecord> for CalibrationView {
    fn from(r: &CalibrationRecord) -> Self {
        let c = &r.calibration;
        let mut view = Self {
            id: r.id.clone(),
            name: r.name.clone(),
            version: r.version,
            model: c.model_name().to_string(),
            pending: c.pending(),
            tilt_axis_deg: c.tilt_axis_deg(),
            coefficients: c.coefficients().to_vec(),
            pixel_size_um: None,
            pixel_size: None,
            vergence_deg: None,
            vergence: None,
            reference_disparity_px: None,
            degree: None,
            samples: None,
            residuals_um: None,
            residual_rms_um: c.residual_rms_um(),
            r_squared: c.r_squared(),
            created_at: r.created_at.clone(),
            updated_at: r.updated_at.clone(),
        };
        match c.spec() {
            CalibrationSpec::Geometric(g) => {
                view.pixel_size_um = g.pixel_size_um;
                view.pixel_size = g.pixel_size.map(Into::into);
                view.vergence_deg = g.vergence_deg;
                view.vergence = g.vergence.map(Into::into);
                view.reference_disparity_px = Some(g.reference_disparity_px);
            }
            CalibrationSpec::Fit(f) => {
                view.degree = Some(f.degree);
                view.samples = Some(f.samples.iter().cloned().map(Into::into).collect());
                // None while pending: there is no fit to differ from.
                view.residuals_um = c.pending().is_none().then(|| c.residuals_um());
            }
        }
        view
    }
}

/// Body of `POST /v1/sessions`; every field is optional.
#[derive(Clone, Debug, Default, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"name": "gripper tip", "calibration_id": null, "tracker": {"tilt_axis_deg": 90.0, "max_disparity_px": 64.0}}))]
pub struct SessionCreate {
    /// Free-text label.
    #[serde(default)]
    pub name: Option<String>,
    /// Calibration turning disparity into z_um (null: z_um stays null).
    #[serde(default)]
    pub calibration_id: Option<String>,
    /// Initialisation parameters (defaults documented in the schema).
    #[serde(default)]
    pub init: Option<InitParams>,
    /// Tracker parameters (defaults documented in the schema). Its own
    /// `init` member, if given, must not contradict the top-level `init`.
    #[serde(default)]
    pub tracker: Option<TrackerParams>,
    /// Most per-pair results kept for this session (oldest dropped first);
    /// null: the server's default.
    #[serde(default)]
    #[schema(minimum = 1)]
    pub retention: Option<u64>,
    /// Exempt from the idle-session expiry (`--session-expiry-h`) and from
    /// bulk deletes unless they include kept sessions. Default false.
    #[serde(default)]
    pub keep: bool,
    /// The objects to track (1 to 16), each named with its own hints;
    /// every pair then measures each of them and the height of each
    /// relative to each other. Without it, one object named `object` with
    /// the hints of `init`.
    #[serde(default)]
    pub objects: Option<Vec<ObjectCreate>>,
}

/// An object of a session, named, with its hints (`POST /v1/sessions`
/// `objects`, `POST /v1/sessions/{id}/objects`). Its other parameters are
/// the session's `init` and `tracker`.
#[derive(Clone, Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"name": "needle", "roi": [0, 120, 300, 90], "polarity": "brighter"}))]
pub struct ObjectCreate {
    /// 1 to 64 of A-Z a-z 0-9 _ - . (unique in the session).
    #[schema(pattern = "^[A-Za-z0-9_.-]{1,64}$")]
    pub name: String,
    /// The box `[x, y, width, height]` the object lies in.
    #[serde(default)]
    #[schema(schema_with = super::params::roi_schema)]
    pub roi: Option<[i64; 4]>,
    /// A point `[x, y]` on the object.
    #[serde(default)]
    #[schema(value_type = Option<Vec<f64>>, min_items = 2, max_items = 2)]
    pub point: Option<[f64; 2]>,
    /// The object's outline as a person drew it (see `init.outline`).
    #[serde(default)]
    #[schema(value_type = Option<Vec<Vec<f64>>>, max_items = 4096, min_items = 3)]
    pub outline: Option<Vec<[f64; 2]>>,
    /// Points on what is not the object (see `init.exclude`).
    #[serde(default)]
    #[schema(value_type = Vec<Vec<f64>>, max_items = 64)]
    pub exclude: Vec<[f64; 2]>,
    /// The object against its surroundings; default `any`.
    #[serde(default)]
    pub polarity: Option<Polarity>,
    /// Smallest expected area, pixels (>= 0).
    #[serde(default)]
    #[schema(minimum = 0.0)]
    pub min_area_px: Option<f64>,
    /// Largest expected area, pixels (>= 0, >= `min_area_px`).
    #[serde(default)]
    #[schema(minimum = 0.0)]
    pub max_area_px: Option<f64>,
}

impl ObjectCreate {
    /// `base` with this object's hints in place of its own (as a set).
    pub fn params(&self, base: &tracker::TrackerParams) -> tracker::TrackerParams {
        let mut params = base.clone();
        params.init.roi = self.roi;
        params.init.point = self.point;
        params.init.outline = self.outline.clone();
        params.init.exclude = self.exclude.clone();
        params.init.polarity = self.polarity.unwrap_or_default().into();
        params.init.min_area_px = self.min_area_px;
        params.init.max_area_px = self.max_area_px;
        params
    }
}

/// An object of a session as the API shows it.
#[derive(Clone, Debug, Serialize, Deserialize, ToSchema)]
pub struct ObjectView {
    /// Its name.
    pub name: String,
    /// Where it stands (`awaiting_first_pair`: its next pair initialises it).
    pub state: SessionState,
    /// Its hints.
    pub roi: Option<[i64; 4]>,
    /// See `roi`.
    pub point: Option<[f64; 2]>,
    /// See `roi`.
    #[serde(default)]
    #[schema(value_type = Option<Vec<Vec<f64>>>)]
    pub outline: Option<Vec<[f64; 2]>>,
    /// See `roi`.
    #[serde(default)]
    #[schema(value_type = Vec<Vec<f64>>)]
    pub exclude: Vec<[f64; 2]>,
    /// See `roi`.
    pub polarity: Polarity,
    /// See `roi`.
    pub min_area_px: Option<f64>,
    /// See `roi`.
    pub max_area_px: Option<f64>,
}

impl ObjectView {
    fn of(o: &ObjectRecord) -> Self {
        let init = &o.params.init;
        let state = match &o.tracker_state {
            None => SessionState::AwaitingFirstPair,
            Some(s) if s.is_lost() => SessionState::Lost,
            Some(_) => SessionState::Tracking,
        };
        Self {
            name: o.name.clone(),
            state,
            roi: init.roi,
            point: init.point,
            outline: init.outline.clone(),
            exclude: init.exclude.clone(),
            polarity: init.polarity.into(),
            min_area_px: init.min_area_px,
            max_area_px: init.max_area_px,
        }
    }
}

/// Body of `PATCH /v1/sessions/{id}`: the fields to change.
#[derive(Clone, Debug, Default, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"calibration_id": "c_3f2a"}))]
pub struct SessionPatch {
    /// New label (null clears it).
    #[serde(default, deserialize_with = "present")]
    #[schema(value_type = Option<String>)]
    pub name: Option<Option<String>>,
    /// Calibration to use from the next pair on (null detaches it).
    #[serde(default, deserialize_with = "present")]
    #[schema(value_type = Option<String>)]
    pub calibration_id: Option<Option<String>>,
    /// Initialisation parameters to change, used at the next
    /// initialisation: a JSON merge patch (RFC 7396) of the session's, so
    /// fields left out keep their values and `null` sets a field back to
    /// its default (`"roi": null` clears the box).
    #[serde(default)]
    #[schema(value_type = Option<InitParams>)]
    pub init: Option<serde_json::Value>,
    /// Tracker parameters to change, used from the next pair on: a JSON
    /// merge patch of the session's, like `init`.
    #[serde(default)]
    #[schema(value_type = Option<TrackerParams>)]
    pub tracker: Option<serde_json::Value>,
    /// New result retention.
    #[serde(default)]
    #[schema(minimum = 1)]
    pub retention: Option<u64>,
    /// Exempt from the idle-session expiry, or not.
    #[serde(default)]
    pub keep: Option<bool>,
}

/// The `init` fields that name the object: `POST /v1/sessions/{id}/reinit`
/// replaces them as a set.
pub const HINT_FIELDS: [&str; 7] = [
    "roi",
    "point",
    "outline",
    "exclude",
    "polarity",
    "min_area_px",
    "max_area_px",
];

/// Body of `POST /v1/sessions/{id}/reinit`: new hints for the next
/// initialisation.
#[derive(Clone, Debug, Default, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"init": {"roi": [120, 80, 200, 160], "polarity": "brighter"}}))]
pub struct SessionReinit {
    /// The hints `roi`, `point`, `outline`, `exclude`, `polarity`,
    /// `min_area_px` and `max_area_px` replace the session's as a set (a new hint names a new object, so
    /// those left out are cleared); other initialisation parameters given
    /// here replace the session's, those left out keep it.
    #[serde(default)]
    pub init: InitParams,
}

impl SessionReinit {
    /// The session's `current` initialisation parameters with this body's
    /// applied; `fields` is the body as JSON, which tells the parameters
    /// given from those left out.
    pub fn apply(
        &self,
        current: &init::InitParams,
        fields: &serde_json::Map<String, serde_json::Value>,
    ) -> Result<init::InitParams, serde_json::Error> {
        let given = fields.get("init").and_then(serde_json::Value::as_object);
        let object = |p: &InitParams| match serde_json::to_value(p) {
            Ok(serde_json::Value::Object(map)) => Ok(map),
            Ok(other) => Err(serde::ser::Error::custom(format!(
                "initialisation parameters serialise to {other}, not an object"
            ))),
            Err(e) => Err(e),
        };
        let mut merged = object(&InitParams::from(current.clone()))?;
        // The hints go as a set: those left out are cleared.
        merged.retain(|key, _| !HINT_FIELDS.contains(&key.as_str()));
        for (key, value) in object(&self.init)? {
            if HINT_FIELDS.contains(&key.as_str()) || given.is_some_and(|g| g.contains_key(&key)) {
                merged.insert(key, value);
            }
        }
        serde_json::from_value::<InitParams>(serde_json::Value::Object(merged)).map(Into::into)
    }
}

/// Distinguishes an absent field (None) from an explicit null (Some(None)).
fn present<'de, D, T>(d: D) -> Result<Option<Option<T>>, D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    Option::<T>::deserialize(d).map(Some)
}

/// A session as the API returns it.
#[derive(Clone, Debug, Serialize, Deserialize, ToSchema)]
pub struct SessionView {
    /// Opaque id.
    pub id: String,
    /// Free-text label.
    pub name: Option<String>,
    /// Where it stands.
    pub state: SessionState,
    /// Calibration in use (null: z_um is null).
    pub calibration_id: Option<String>,
    /// Pairs processed so far (the next pair's frame index).
    pub frames: u64,
    /// Most results kept.
    pub retention: u64,
    /// Exempt from the idle-session expiry.
    pub keep: bool,
    /// Initialisation parameters (of the first object when there are several).
    pub init: InitParams,
    /// Tracker parameters (its `init` equals the top-level one); of the
    /// first object when there are several.
    pub tracker: TrackerParams,
    /// The objects, in the order of the results' `objects`.
    pub objects: Vec<ObjectView>,
    /// Disparity of the latest pair that was not lost, pixels.
    #[schema(value_type = Option<Vec<f64>>, min_items = 2, max_items = 2)]
    pub latest_disparity_px: Option<[f64; 2]>,
    /// RFC 3339 UTC.
    pub created_at: String,
    /// RFC 3339 UTC.
    pub updated_at: String,
}

impl SessionView {
    /// The view of a stored session.
    pub fn new(r: &SessionRecord, latest_disparity_px: Option<[f64; 2]>, default_retention: u64) -> Self {
        Self {
            id: r.id.clone(),
            name: r.name.clone(),
            state: r.state,
            calibration_id: r.calibration_id.clone(),
            frames: r.frames,
            retention: r.retention.unwrap_or(default_retention),
            keep: r.keep,
            init: r.objects[0].params.init.clone().into(),
            tracker: r.objects[0].params.clone().into(),
            objects: r.objects.iter().map(ObjectView::of).collect(),
            latest_disparity_px,
            created_at: r.created_at.clone(),
            updated_at: r.updated_at.clone(),
        }
    }
}

/// Body of `POST /v1/calibrations/{id}/samples`.
#[derive(Clone, Copy, Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"disparity_px": 5.1, "z_um": 20.0}))]
pub struct SampleCreate {
    /// Disparity across the tilt axis, pixels.
    #[schema(minimum = -1e6, maximum = 1e6)]
    pub disparity_px: f64,
    /// Known height, micrometres.
    #[schema(minimum = -1e6, maximum = 1e6)]
    pub z_um: f64,
}

/// Body of `PATCH /v1/calibrations/{id}/samples/{index}`: the values to
/// change (a height typed wrong, say).
#[derive(Clone, Copy, Debug, Default, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"z_um": 20.0}))]
pub struct SamplePatch {
    /// New disparity across the tilt axis, pixels.
    #[serde(default)]
    #[schema(minimum = -1e6, maximum = 1e6)]
    pub disparity_px: Option<f64>,
    /// New known height, micrometres.
    #[serde(default)]
    #[schema(minimum = -1e6, maximum = 1e6)]
    pub z_um: Option<f64>,
}

/// Body of `POST /v1/sessions/{id}/calibration-samples`.
#[derive(Clone, Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"calibration_id": "c_3f2a", "z_um": 20.0}))]
pub struct SessionSampleCreate {
    /// The fitted calibration to extend.
    pub calibration_id: String,
    /// The height the stage was just moved to, micrometres.
    #[schema(minimum = -1e6, maximum = 1e6)]
    pub z_um: f64,
}

/// Time spent on one pair, milliseconds.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize, ToSchema)]
pub struct TimingMs {
    /// Waiting for the session's earlier pairs and a free worker.
    pub queue: f64,
    /// Decoding both images.
    pub decode: f64,
    /// Tracking (both images, prefix sums included).
    pub track: f64,
    /// From receipt of the pair to its result.
    pub total: f64,
}

/// Which free-text field [`check_label`] checks.
#[derive(Clone, Copy, Debug)]
pub enum Label {
    /// A session's or calibration's `name`.
    Name,
    /// A pair's `label`.
    Label,
}

/// Free-text labels (names, a pair's label) are bounded: at most 200
/// characters, else 400 `invalid_{field}` naming the field.
pub fn check_label(field: Label, value: Option<&str>) -> Result<(), ApiError> {
    let (field, code) = match field {
        Label::Name => ("name", "invalid_name"),
        Label::Label => ("label", "invalid_label"),
    };
    match value {
        Some(v) if v.chars().count() > 200 => Err(ApiError::bad_request(
            code,
            format!(
                "{field} of {} characters (expected at most 200)",
                v.chars().count()
            ),
        )),
        _ => Ok(()),
    }
}

/// Where a pair came from and when: what makes a stored result traceable.
/// Every field is optional (results stored before it have none).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct Provenance {
    /// When the server received the pair, RFC 3339 UTC.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub received_at: Option<String>,
    /// When its result was made, RFC 3339 UTC.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub processed_at: Option<String>,
    /// The client's name for the pair (form field or SDP1 header `label`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub label: Option<String>,
    /// The client's time of acquisition (form field or SDP1 header
    /// `timestamp`), RFC 3339.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub timestamp: Option<String>,
    /// File name of the uploaded left image (multipart), if given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub left_file: Option<String>,
    /// File name of the uploaded right image, if given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub right_file: Option<String>,
}

impl Provenance {
    /// Received now, with the client's `label` and `timestamp` checked: a
    /// label of at most 200 characters, a timestamp in RFC 3339.
    pub fn received(label: Option<String>, timestamp: Option<String>) -> Result<Self, ApiError> {
        check_label(Label::Label, label.as_deref())?;
        if let Some(t) = &timestamp {
            if time::OffsetDateTime::parse(t, &time::format_description::well_known::Rfc3339).is_err() {
                return Err(ApiError::bad_request(
                    "invalid_timestamp",
                    format!("invalid timestamp {t:?} (expected RFC 3339, e.g. 2026-11-25T10:00:00Z)"),
                ));
            }
        }
        Ok(Self {
            received_at: Some(crate::service::stamp::now_rfc3339()),
            label,
            timestamp,
            ..Self::default()
        })
    }

    /// The pair's name for a CSV row: its label, else its left file name,
    /// else empty.
    pub fn name(&self) -> &str {
        self.label.as_deref().or(self.left_file.as_deref()).unwrap_or("")
    }
}

/// The result of one pair (contract, "FrameResult").
#[derive(Clone, Debug, Serialize, Deserialize, ToSchema)]
pub struct FrameResult {
    /// The session (null for the one-shot `/v1/depth`).
    pub session_id: Option<String>,
    /// The measurement of the session's first object (a one-object
    /// session's only one), as before sessions had objects.
    #[serde(flatten)]
    pub result: PairResult,
    /// Every object's measurement, in the session's order; absent for a
    /// session of one object the client did not name (the top-level fields
    /// are its measurement).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub objects: Vec<ObjectResult>,
    /// The height of every object relative to every other; absent with one
    /// object. Null numbers where either is not measured.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub relative: Vec<Relative>,
    /// The calibration that gave `z_um` (null: none).
    pub calibration_id: Option<String>,
    /// Its version then: the result keeps meaning that version after the
    /// calibration changes (`GET /v1/calibrations/{id}/versions/{version}`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration_version: Option<u64>,
    /// Time spent, milliseconds.
    pub timing_ms: TimingMs,
    /// Where the pair came from and when.
    #[serde(flatten)]
    pub provenance: Provenance,
    /// WebSocket only: the `seq` of the pair's header.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seq: Option<u64>,
}

impl FrameResult {
    /// Every object's measurement (a result stored before objects existed:
    /// its one object, named `object`).
    pub fn objects(&self) -> Vec<ObjectResult> {
        if self.objects.is_empty() {
            vec![ObjectResult {
                name: session::DEFAULT_OBJECT_NAME.into(),
                result: self.result.clone(),
            }]
        } else {
            self.objects.clone()
        }
    }

    /// The result with empty contour arrays (`contours=false`: a light
    /// reply; a quartz result is 41.6 KB with its contours).
    pub fn without_contours(mut self) -> Self {
        let results = std::iter::once(&mut self.result).chain(self.objects.iter_mut().map(|o| &mut o.result));
        for result in results {
            for image in [&mut result.left, &mut result.right].into_iter().flatten() {
                image.contour = Vec::new();
            }
        }
        self
    }
}

/// `contours=false` leaves the contours out of a result (their arrays are
/// empty); default true.
#[derive(Clone, Copy, Debug, Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct ContoursQuery {
    /// Include the contours (default true).
    #[serde(default = "yes")]
    pub contours: bool,
}

/// `true`, for serde defaults.
pub fn yes() -> bool {
    true
}

/// A session's results (`GET /v1/sessions/{id}/results`, JSON).
#[derive(Clone, Debug, Serialize, Deserialize, ToSchema)]
pub struct ResultsPage {
    /// The session.
    pub session_id: String,
    /// Results with frame >= `since`, oldest first.
    pub results: Vec<FrameResult>,
    /// `since` for the next page (one past the last frame returned), or null
    /// when this page holds everything up to now.
    pub next_since: Option<u64>,
}

/// List of calibrations.
#[derive(Clone, Debug, Serialize, Deserialize, ToSchema)]
pub struct CalibrationList {
    /// Oldest first.
    pub calibrations: Vec<CalibrationView>,
}

/// Reply of `DELETE /v1/sessions` (a bulk delete).
#[derive(Clone, Debug, Serialize, Deserialize, ToSchema)]
pub struct SessionsDeleted {
    /// Ids of the sessions deleted, sorted.
    pub deleted: Vec<String>,
}

/// List of sessions.
#[derive(Clone, Debug, Serialize, Deserialize, ToSchema)]
pub struct SessionList {
    /// Oldest first.
    pub sessions: Vec<SessionView>,
}

/// `GET /healthz` and `GET /readyz`.
#[derive(Clone, Debug, Serialize, Deserialize, ToSchema)]
pub struct Health {
    /// `ok`, or `unavailable` (readyz when storage does not answer or its
    /// writes fail).
    pub status: String,
    /// Crate version.
    pub version: String,
    /// Why it is unavailable (readyz), e.g. "storage: writes are failing:
    /// ... database or disk is full".
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
}

/// Multipart body of a pair upload (schema only).
#[allow(dead_code)]
#[derive(ToSchema)]
pub struct PairUpload {
    /// Left image: PNG, TIFF (8/16-bit), JPEG or BMP.
    #[schema(value_type = String, format = Binary)]
    pub left: Vec<u8>,
    /// Right image, same size as the left one.
    #[schema(value_type = String, format = Binary)]
    pub right: Vec<u8>,
}

//! Calibrations: the mapping from stereo disparity (pixels) to height z (micrometres).
//!
//! This is the depth step of Dahmen, Wortmann, Tunnell and Fatikow, "Automatic
//! extraction of distance information from stereo images using tracking data in
//! the scanning electron microscope", ICINCO 2009, section 4 (restated in
//! `docs/method.md`, section 3).
//!
//! The disparity of a tracked object is the 2-D vector
//! `d = centroid_right - centroid_left` in pixels (x to the right, y down). Only
//! its component across the beam's tilt axis carries height, see
//! [`axis_component`]. Two models map that scalar `d_axis` to `z_um`:
//!
//! - **geometric** (eucentric tilt by a total vergence angle `alpha`, pixel size `s`
//!   in micrometres per pixel at the specimen, reference disparity `d0` of the
//!   height z = 0): `z = (d_axis - d0) * s / (2 sin(alpha / 2))`. At `alpha` = 10
//!   degrees one pixel of disparity is 5.737 `s` of height. `s` and `alpha`
//!   may each come from every pair's image metadata instead ([`PairMeta`],
//!   read by [`crate::meta`]): `s` is then the pixel length across the tilt
//!   axis, `alpha` the right image's stage tilt minus the left's (signed, so
//!   a pair whose right image is tilted less gives heights of the other sign,
//!   as with the views swapped), and [`Calibration::z_for_pair`] says why a
//!   pair without usable metadata has no height.
//! - **fit**: least squares through measured samples `(disparity_px, z_um)` (the
//!   stage was moved to known heights), `z = c0 + c1 d (+ c2 d^2)`, with the residual
//!   RMS and R^2 reported.
//!
//! Both carry `coefficients` `[c0, c1(, c2)]` so that `z_um = c0 + c1 d + c2 d^2`
//! (none for a geometric calibration scaled from the images).
//! A user submits a [`CalibrationSpec`]; [`build`] validates it, fits, and returns a
//! [`Calibration`]. Every failure is a [`CalibError`] whose message says what was
//! expected and whose [`CalibError::code`] is a stable snake_case string.
//!
//! The JSON form of a [`Calibration`] is the spec's fields plus the derived ones
//! (`coefficients`, and for fits `residual_rms_um`, `r_squared`). On reading, the
//! derived fields are optional and always recomputed from the parameters; when
//! present they must agree with the recomputation (so a hand-edited coefficient
//! is refused instead of silently ignored).

use serde::{Deserialize, Serialize};

/// Default tilt axis direction in degrees: the image y axis, so the height
/// information is in the x component of the disparity.
pub const DEFAULT_TILT_AXIS_DEG: f64 = 90.0;

/// Default polynomial degree of a fitted calibration.
pub const DEFAULT_FIT_DEGREE: u8 = 1;

/// Disparities (pixels) closer together than this count as one distinct value
/// when checking that a fit has enough distinct samples.
pub const DISTINCT_DISPARITY_TOLERANCE_PX: f64 = 1e-6;

/// Largest accepted magnitude of a disparity or reference disparity, pixels.
pub const MAX_ABS_DISPARITY_PX: f64 = 1e6;

/// Largest accepted magnitude of a sample height, micrometres (1 m).
pub const MAX_ABS_Z_UM: f64 = 1e6;

/// Most samples one fitted calibration may hold.
pub const MAX_SAMPLES: usize = 10_000;

/// Fits whose design matrix (after centring and scaling the disparities) has a
/// 1-norm condition number above this are refused as degenerate.
pub const MAX_CONDITION_NUMBER: f64 = 1e10;

/// Top-level JSON keys that the HTTP service adds around a calibration
/// (`id`, `name`, timestamps). [`from_json`] ignores them, so a calibration
/// saved from `GET /v1/calibrations/{id}` can be read by the CLI.
pub const SERVICE_METADATA_FIELDS: [&str; 4] = ["id", "name", "created_at", "updated_at"];

/// Why a calibration could not be built, read or extended.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum CalibError {
    /// A parameter or sample is out of range or not finite, or stored derived
    /// fields disagree with the parameters.
    #[error("{0}")]
    Invalid(String),
    /// More samples than [`MAX_SAMPLES`].
    #[error("{samples} samples exceed the limit of {max} per calibration")]
    TooManySamples {
        /// Number of samples that was attempted.
        samples: usize,
        /// The limit.
        max: usize,
    },
    /// The least-squares system is singular or ill-conditioned.
    #[error("degenerate fit: {0}")]
    DegenerateFit(String),
    /// Samples were added to a calibration that is not a fit.
    #[error("samples only apply to fitted calibrations (model \"fit\"), but this calibration is {model}")]
    NotAFit {
        /// The calibration's model name.
        model: &'static str,
    },
    /// The JSON text is malformed or has the wrong shape (unknown or missing fields).
    #[error("invalid calibration JSON: {0}")]
    Json(String),
    /// A sample index past the end of the samples.
    #[error("no sample {index} (expected 0..{count}: the calibration has {count} samples)")]
    NoSuchSample {
        /// The index asked for.
        index: usize,
        /// Samples present.
        count: usize,
    },
}

impl CalibError {
    /// A stable snake_case code for APIs and logs.
    pub fn code(&self) -> &'static str {
        match self {
            Self::Invalid(_) => "invalid_calibration",
            Self::TooManySamples { .. } => "too_many_samples",
            Self::DegenerateFit(_) => "degenerate_fit",
            Self::NotAFit { .. } => "not_a_fit",
            Self::Json(_) => "invalid_calibration_json",
            Self::NoSuchSample { .. } => "sample_not_found",
        }
    }
}

/// One calibration measurement: the disparity across the tilt axis observed
/// with the object at a known height.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Sample {
    /// Disparity component across the tilt axis, pixels (see [`axis_component`]).
    #[schema(minimum = -1e6, maximum = 1e6)]
    pub disparity_px: f64,
    /// Known height, micrometres.
    #[schema(minimum = -1e6, maximum = 1e6)]
    pub z_um: f64,
    /// The session whose tracked pair gave the disparity (absent: typed in).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub session_id: Option<String>,
    /// That pair's frame index in the session.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame: Option<u64>,
}

impl Sample {
    /// A sample from a disparity (pixels) and a height (micrometres).
    pub fn new(disparity_px: f64, z_um: f64) -> Self {
        Self {
            disparity_px,
            z_um,
            session_id: None,
            frame: None,
        }
    }

    /// The sample marked as measured on `frame` of session `session_id`.
    pub fn from_pair(self, session_id: &str, frame: u64) -> Self {
        Self {
            session_id: Some(session_id.to_owned()),
            frame: Some(frame),
            ..self
        }
    }
}

/// Parameters of a geometric calibration. The pixel size and the vergence
/// are each either given (`pixel_size_um`, `vergence_deg`) or taken from
/// every pair's images (`pixel_size: "from_images"`,
/// `vergence: "from_stage_tilt"`; see [`PairMeta`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GeometricSpec {
    /// Length of one pixel at the specimen, micrometres per pixel (> 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pixel_size_um: Option<f64>,
    /// The pixel size from each pair's images instead.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pixel_size: Option<PixelSizeSource>,
    /// Total vergence angle between the two views, degrees (0 < vergence_deg <= 90).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vergence_deg: Option<f64>,
    /// The vergence from each pair's images instead.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vergence: Option<VergenceSource>,
    /// Disparity across the tilt axis at the reference height z = 0, pixels.
    #[serde(default)]
    pub reference_disparity_px: f64,
    /// Direction of the tilt axis in the image, degrees from +x towards +y.
    #[serde(default = "default_tilt_axis_deg")]
    pub tilt_axis_deg: f64,
}

impl GeometricSpec {
    /// A typed pixel size and vergence, reference disparity 0, tilt axis
    /// along the image y axis.
    pub fn new(pixel_size_um: f64, vergence_deg: f64) -> Self {
        Self {
            pixel_size_um: Some(pixel_size_um),
            pixel_size: None,
            vergence_deg: Some(vergence_deg),
            vergence: None,
            reference_disparity_px: 0.0,
            tilt_axis_deg: DEFAULT_TILT_AXIS_DEG,
        }
    }

    /// True when the pixel size or the vergence comes from the images.
    pub fn from_images(&self) -> bool {
        self.pixel_size.is_some() || self.vergence.is_some()
    }
}

/// Where a geometric calibration takes the pixel size from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum PixelSizeSource {
    /// The pixel size in each pair's image metadata (both images must carry
    /// it and agree within 1%).
    FromImages,
}

/// Where a geometric calibration takes the vergence from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum VergenceSource {
    /// The right image's stage tilt minus the left's (a stage-tilt pair).
    FromStageTilt,
}

impl<'de> Deserialize<'de> for PixelSizeSource {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        one_word(
            d,
            "from_images",
            "\"from_images\" (a number goes in pixel_size_um)",
        )
        .map(|()| Self::FromImages)
    }
}

impl<'de> Deserialize<'de> for VergenceSource {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        one_word(
            d,
            "from_stage_tilt",
            "\"from_stage_tilt\" (a number goes in vergence_deg)",
        )
        .map(|()| Self::FromStageTilt)
    }
}

/// Accepts exactly the string `word`; any other value is refused with an
/// error that says what was `expected`.
fn one_word<'de, D: serde::Deserializer<'de>>(
    d: D,
    word: &'static str,
    expected: &'static str,
) -> Result<(), D::Error> {
    struct Word(&'static str, &'static str);
    impl serde::de::Visitor<'_> for Word {
        type Value = ();
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str(self.1)
        }
        fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<(), E> {
            if v == self.0 {
                Ok(())
            } else {
                Err(E::invalid_value(serde::de::Unexpected::Str(v), &self))
            }
        }
    }
    d.deserialize_any(Word(word, expected))
}

/// What a pair's two images say about how they were taken (see
/// [`crate::meta`]), as far as depth needs it.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct PairMeta {
    /// The left image's.
    pub left: ViewMeta,
    /// The right image's.
    pub right: ViewMeta,
    /// Right stage tilt minus left, radians (null unless both are known).
    pub stage_tilt_difference_rad: Option<f64>,
}

/// One image's pixel size and stage tilt.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ViewMeta {
    /// Width of one pixel at the specimen, metres.
    pub pixel_width_m: Option<f64>,
    /// Height of one pixel at the specimen, metres.
    pub pixel_height_m: Option<f64>,
    /// Stage tilt, radians.
    pub stage_tilt_rad: Option<f64>,
}

impl ViewMeta {
    /// The fields of `meta` that depth needs.
    pub fn of(meta: &crate::meta::ImageMeta) -> Self {
        Self {
            pixel_width_m: meta.pixel_width_m,
            pixel_height_m: meta.pixel_height_m,
            stage_tilt_rad: meta.stage_tilt_rad,
        }
    }

    fn is_empty(&self) -> bool {
        self.pixel_width_m.is_none() && self.pixel_height_m.is_none() && self.stage_tilt_rad.is_none()
    }

    /// Length of one pixel along the disparity direction across a tilt axis
    /// at `tilt_axis_deg` (see [`axis_component`]), metres; a missing
    /// height is taken as the width and vice versa (square pixels).
    fn pixel_across_axis_m(&self, tilt_axis_deg: f64) -> Option<f64> {
        let w = self.pixel_width_m.or(self.pixel_height_m)?;
        let h = self.pixel_height_m.unwrap_or(w);
        let (sin_t, cos_t) = sin_cos_deg(tilt_axis_deg);
        Some((w * sin_t).hypot(h * cos_t))
    }
}

impl PairMeta {
    /// The pair's metadata, `None` when neither image carries any.
    pub fn of(left: &crate::meta::ImageMeta, right: &crate::meta::ImageMeta) -> Option<Self> {
        let (left, right) = (ViewMeta::of(left), ViewMeta::of(right));
        (!(left.is_empty() && right.is_empty())).then(|| Self::new(left, right))
    }

    /// The two views' metadata and their stage tilt difference.
    pub fn new(left: ViewMeta, right: ViewMeta) -> Self {
        let stage_tilt_difference_rad = match (left.stage_tilt_rad, right.stage_tilt_rad) {
            (Some(l), Some(r)) => Some(r - l),
            _ => None,
        };
        Self {
            left,
            right,
            stage_tilt_difference_rad,
        }
    }

    /// The pixel size across the tilt axis both images agree on (within
    /// [`PIXEL_SIZE_TOLERANCE`]), micrometres; the left image's.
    pub fn pixel_size_um(&self, tilt_axis_deg: f64) -> Result<f64, String> {
        let left = self.left.pixel_across_axis_m(tilt_axis_deg);
        let right = self.right.pixel_across_axis_m(tilt_axis_deg);
        match (left, right) {
            (Some(l), Some(r)) if (l - r).abs() > PIXEL_SIZE_TOLERANCE * l => Err(format!(
                "the left and right images' pixel sizes differ ({:.6e} m and {:.6e} m): the magnification changed within the pair",
                l, r
            )),
            (Some(l), _) if l.is_finite() && l > 0.0 => Ok(l * 1e6),
            (Some(l), _) => Err(format!("the left image's pixel size {l:e} m is not a positive length")),
            (None, _) => Err("the left image carries no pixel size".into()),
        }
    }
}

/// Relative difference of two pixel sizes above which they count as
/// different magnifications.
pub const PIXEL_SIZE_TOLERANCE: f64 = 0.01;

/// Warns once per change when a pair's pixel size contradicts a typed
/// geometric calibration's (the magnification changed since it was made).
#[derive(Clone, Debug, Default)]
pub struct MetaWatch {
    /// The pixel size (micrometres) of the last pair that carried one.
    last_pixel_size_um: Option<f64>,
}

impl MetaWatch {
    /// The warning for this pair, if its pixel size changed since the last
    /// pair's (or is the first seen) and differs from the calibration's by
    /// more than [`PIXEL_SIZE_TOLERANCE`].
    pub fn check(&mut self, calibration: &Calibration, meta: Option<&PairMeta>) -> Option<String> {
        let CalibrationSpec::Geometric(g) = calibration.spec() else {
            return None;
        };
        let typed = g.pixel_size_um?;
        let seen = meta?.pixel_size_um(g.tilt_axis_deg).ok()?;
        let changed = self
            .last_pixel_size_um
            .is_none_or(|last| (seen - last).abs() > PIXEL_SIZE_TOLERANCE * last);
        if !changed {
            return None;
        }
        self.last_pixel_size_um = Some(seen);
        ((seen - typed).abs() > PIXEL_SIZE_TOLERANCE * typed).then(|| {
            format!(
                "the images' pixel size {seen:.6} um differs from the calibration's {typed} um by {:.1}%: the magnification changed; z uses the calibration's",
                100.0 * (seen - typed) / typed
            )
        })
    }
}

/// Parameters of a fitted calibration.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FitSpec {
    /// Polynomial degree, 1 (linear) or 2 (quadratic).
    #[serde(default = "default_fit_degree")]
    pub degree: u8,
    /// The measurements to fit.
    pub samples: Vec<Sample>,
    /// Direction of the tilt axis in the image, degrees from +x towards +y; used
    /// when the calibration is applied to 2-D disparities.
    #[serde(default = "default_tilt_axis_deg")]
    pub tilt_axis_deg: f64,
}

/// What a user submits to create a calibration; JSON
/// `{"model": "geometric", "pixel_size_um": .., "vergence_deg": .., ...}` or
/// `{"model": "fit", "degree": 1, "samples": [{"disparity_px": .., "z_um": ..}, ..]}`.
/// Unknown fields are refused.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "snake_case", deny_unknown_fields)]
pub enum CalibrationSpec {
    /// Eucentric tilt geometry.
    Geometric(GeometricSpec),
    /// Least-squares polynomial through samples.
    Fit(FitSpec),
}

impl CalibrationSpec {
    /// The model name as in JSON: `"geometric"` or `"fit"`.
    pub fn model_name(&self) -> &'static str {
        match self {
            Self::Geometric(_) => "geometric",
            Self::Fit(_) => "fit",
        }
    }

    /// The tilt axis direction, degrees.
    pub fn tilt_axis_deg(&self) -> f64 {
        match self {
            Self::Geometric(g) => g.tilt_axis_deg,
            Self::Fit(f) => f.tilt_axis_deg,
        }
    }
}

/// Goodness of a least-squares fit.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FitStats {
    /// Root mean square of the residuals `z_i - z(d_i)` (divided by n, not n - p), micrometres.
    pub residual_rms_um: f64,
    /// Coefficient of determination `1 - SS_res / SS_tot`, clamped to [0, 1]. When
    /// all heights are equal (SS_tot = 0) it is 0/0; we then report 1.0, because a
    /// model with an intercept reproduces such data exactly (the fitted slope is 0).
    pub r_squared: f64,
}

/// A validated calibration: its parameters, polynomial coefficients and, for
/// fits, the fit statistics. Build one with [`build`] (or [`from_json`]); the
/// fields are private so the coefficients always match the parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(into = "CalibrationWire", try_from = "CalibrationWire")]
pub struct Calibration {
    spec: CalibrationSpec,
    /// Monomial coefficients `[c0, c1(, c2)]` in disparity pixels, as reported.
    coefficients: Vec<f64>,
    stats: Option<FitStats>,
    /// Evaluation form: `z = sum_k b_k u^k` with `u = (d - center_px) / scale_px`.
    /// Numerically better than the monomial form when the disparities are far
    /// from 0 compared with their spread. `None` for a geometric calibration
    /// that takes its scale from each pair's images.
    poly: Option<CenteredPoly>,
}

#[derive(Clone, Debug, PartialEq)]
struct CenteredPoly {
    center_px: f64,
    scale_px: f64,
    coefficients: Vec<f64>,
}

impl CenteredPoly {
    fn eval(&self, d: f64) -> f64 {
        let u = (d - self.center_px) / self.scale_px;
        self.coefficients.iter().rev().fold(0.0, |acc, &b| acc * u + b)
    }

    /// The same polynomial in powers of `d` itself.
    fn monomial(&self) -> Vec<f64> {
        let m = self.center_px;
        let t = 1.0 / self.scale_px;
        let b = &self.coefficients;
        match b.len() {
            2 => vec![b[0] - b[1] * m * t, b[1] * t],
            3 => {
                let t2 = t * t;
                vec![
                    b[0] - b[1] * m * t + b[2] * m * m * t2,
                    b[1] * t - 2.0 * b[2] * m * t2,
                    b[2] * t2,
                ]
            }
            _ => unreachable!("degree is validated to 1 or 2"),
        }
    }
}

/// The component of a 2-D disparity `d = [dx, dy]` (pixels) across the tilt axis.
///
/// The tilt axis points along `(cos t, sin t)` with `t = tilt_axis_deg`, measured
/// from +x towards +y (y down, so clockwise on screen). The component is taken
/// along `n = (sin t, -cos t)`, the axis direction turned by -90 degrees:
/// `d_axis = dx sin t - dy cos t`. Hence t = 90 (the default, axis = image y)
/// gives `d_axis = dx`, t = 0 (axis = image x) gives `d_axis = -dy`, t = 180 gives
/// `dy` and t = 270 gives `-dx`: turning the axis by 180 degrees flips the sign of
/// the height. Multiples of 90 degrees are exact.
pub fn axis_component(tilt_axis_deg: f64, d: [f64; 2]) -> f64 {
    let (sin_t, cos_t) = sin_cos_deg(tilt_axis_deg);
    d[0] * sin_t - d[1] * cos_t
}

/// Sine and cosine of an angle in degrees, exact at multiples of 90.
fn sin_cos_deg(deg: f64) -> (f64, f64) {
    let r = deg.rem_euclid(360.0);
    if r == 0.0 {
        (0.0, 1.0)
    } else if r == 90.0 {
        (1.0, 0.0)
    } else if r == 180.0 {
        (0.0, -1.0)
    } else if r == 270.0 {
        (-1.0, 0.0)
    } else {
        r.to_radians().sin_cos()
    }
}

/// Validates a spec, fits it (for [`CalibrationSpec::Fit`]) and returns the calibration.
///
/// Refuses (see [`CalibError`]): non-finite or out-of-range parameters
/// (`pixel_size_um` > 0, 0 < `vergence_deg` <= 90, `degree` 1 or 2, finite
/// `tilt_axis_deg` with magnitude <= 360, |disparities| <= [`MAX_ABS_DISPARITY_PX`],
/// |z_um| <= [`MAX_ABS_Z_UM`]) and ill-conditioned fits (`degenerate_fit`).
/// A fit with fewer distinct disparities than coefficients (none at all,
/// say) is built [`Calibration::pending`]: it gives no height until samples
/// at other heights are added.
pub fn build(spec: CalibrationSpec) -> Result<Calibration, CalibError> {
    check_tilt_axis(spec.tilt_axis_deg())?;
    match spec {
        CalibrationSpec::Geometric(g) => build_geometric(g),
        CalibrationSpec::Fit(f) => build_fit(f),
    }
}

impl TryFrom<CalibrationSpec> for Calibration {
    type Error = CalibError;

    fn try_from(spec: CalibrationSpec) -> Result<Self, CalibError> {
        build(spec)
    }
}

/// Reads a calibration from JSON text: either a [`CalibrationSpec`] (what a user
/// submits) or a full serialised [`Calibration`] (the spec plus `coefficients`
/// and, for fits, `residual_rms_um` and `r_squared`). The keys in
/// [`SERVICE_METADATA_FIELDS`] are ignored at the top level. The calibration is
/// always rebuilt from its parameters; derived fields, when present, must agree.
pub fn from_json(text: &str) -> Result<Calibration, CalibError> {
    let mut value: serde_json::Value =
        serde_json::from_str(text).map_err(|e| CalibError::Json(e.to_string()))?;
    let Some(object) = value.as_object_mut() else {
        return Err(CalibError::Json(
            "expected a JSON object with \"model\": \"geometric\" or \"fit\"".into(),
        ));
    };
    for key in SERVICE_METADATA_FIELDS {
        object.remove(key);
    }
    let has_derived = ["coefficients", "residual_rms_um", "r_squared"]
        .iter()
        .any(|k| object.contains_key(*k));
    if !has_derived {
        // A plain spec: its own error messages name exactly the spec's fields.
        let spec: CalibrationSpec =
            serde_json::from_value(value).map_err(|e| CalibError::Json(e.to_string()))?;
        return build(spec);
    }
    let wire: CalibrationWire = serde_json::from_value(value).map_err(|e| CalibError::Json(e.to_string()))?;
    Calibration::try_from(wire)
}

impl Calibration {
    /// The validated parameters this calibration was built from.
    pub fn spec(&self) -> &CalibrationSpec {
        &self.spec
    }

    /// The model name as in JSON: `"geometric"` or `"fit"`.
    pub fn model_name(&self) -> &'static str {
        self.spec.model_name()
    }

    /// True for a fitted calibration.
    pub fn is_fit(&self) -> bool {
        matches!(self.spec, CalibrationSpec::Fit(_))
    }

    /// Direction of the tilt axis in the image, degrees (see [`axis_component`]).
    pub fn tilt_axis_deg(&self) -> f64 {
        self.spec.tilt_axis_deg()
    }

    /// Coefficients `[c0, c1(, c2)]` with `z_um = c0 + c1 d + c2 d^2`, `d` the
    /// disparity across the tilt axis in pixels; units um, um/px, um/px^2.
    pub fn coefficients(&self) -> &[f64] {
        &self.coefficients
    }

    /// Fit statistics (fits only).
    pub fn fit_stats(&self) -> Option<FitStats> {
        self.stats
    }

    /// RMS of the fit residuals in micrometres (fits only).
    pub fn residual_rms_um(&self) -> Option<f64> {
        self.stats.map(|s| s.residual_rms_um)
    }

    /// Coefficient of determination of the fit (fits only); see [`FitStats::r_squared`].
    pub fn r_squared(&self) -> Option<f64> {
        self.stats.map(|s| s.r_squared)
    }

    /// The samples of a fit (empty for a geometric calibration).
    pub fn samples(&self) -> &[Sample] {
        match &self.spec {
            CalibrationSpec::Fit(f) => &f.samples,
            CalibrationSpec::Geometric(_) => &[],
        }
    }

    /// Height in micrometres for a 2-D disparity `[dx, dy]` in pixels: the
    /// component across the tilt axis ([`axis_component`]) through
    /// [`Calibration::z_from_axis`]. Non-finite input gives a non-finite
    /// result, and so does a calibration that takes its scale from the
    /// images (see [`Calibration::z_for_pair`]).
    pub fn z_um(&self, disparity_px: [f64; 2]) -> f64 {
        self.z_from_axis(axis_component(self.tilt_axis_deg(), disparity_px))
    }

    /// Height in micrometres for a disparity component across the tilt axis, pixels.
    /// Evaluated in the centred form the fit was solved in, so it stays accurate
    /// when the monomial coefficients are large and cancel. NaN for a
    /// calibration that takes its scale from the images.
    pub fn z_from_axis(&self, d_axis_px: f64) -> f64 {
        self.poly.as_ref().map_or(f64::NAN, |p| p.eval(d_axis_px))
    }

    /// Why a fitted calibration gives no height yet (fewer distinct
    /// disparities than coefficients), or `None` when it gives heights.
    pub fn pending(&self) -> Option<String> {
        let CalibrationSpec::Fit(f) = &self.spec else {
            return None;
        };
        if self.poly.is_some() {
            return None;
        }
        let d: Vec<f64> = f.samples.iter().map(|s| s.disparity_px).collect();
        Some(format!(
            "the fitted calibration has {} distinct disparity_px values of the {} a degree-{} fit needs (add samples at other heights)",
            count_distinct(&d, DISTINCT_DISPARITY_TOLERANCE_PX),
            f.degree as usize + 1,
            f.degree
        ))
    }

    /// True when the pixel size or the vergence comes from each pair's images.
    pub fn needs_images(&self) -> bool {
        matches!(&self.spec, CalibrationSpec::Geometric(g) if g.from_images())
    }

    /// Height in micrometres for a pair's 2-D disparity, with the pair's
    /// image metadata where the calibration takes its pixel size or
    /// vergence from it: `z = (d_axis - d0) s / (2 sin(dt / 2))`, `s` the
    /// pixel length across the tilt axis, `dt` the right image's stage tilt
    /// minus the left's (signed: a pair whose right image is tilted less
    /// gives heights of the other sign, as with the views swapped). The
    /// error says why there is no height (metadata missing or unusable).
    pub fn z_for_pair(&self, disparity_px: [f64; 2], meta: Option<&PairMeta>) -> Result<f64, String> {
        if let Some(why) = self.pending() {
            return Err(why);
        }
        let CalibrationSpec::Geometric(g) = &self.spec else {
            return Ok(self.z_um(disparity_px));
        };
        if !g.from_images() {
            return Ok(self.z_um(disparity_px));
        }
        let none = || {
            "the images carry no metadata (raw frames, or files without the microscope's tags)".to_string()
        };
        let pixel_size_um = match g.pixel_size_um {
            Some(s) => s,
            None => meta.ok_or_else(none)?.pixel_size_um(g.tilt_axis_deg)?,
        };
        let vergence_rad = match g.vergence_deg {
            Some(v) => v.to_radians(),
            None => {
                let dt = meta
                    .ok_or_else(none)?
                    .stage_tilt_difference_rad
                    .ok_or("the images do not both carry a stage tilt")?;
                if !(dt.is_finite() && dt != 0.0 && dt.abs() <= std::f64::consts::FRAC_PI_2) {
                    return Err(format!(
                        "the stage tilt difference {dt} rad is no vergence (expected 0 < |right - left| <= pi/2)"
                    ));
                }
                dt
            }
        };
        let d_axis = axis_component(g.tilt_axis_deg, disparity_px);
        let z = (d_axis - g.reference_disparity_px) * geometric_scale(pixel_size_um, vergence_rad);
        if z.is_finite() {
            Ok(z)
        } else {
            Err(format!(
                "pixel size {pixel_size_um} um with vergence {vergence_rad} rad gives no finite height"
            ))
        }
    }

    /// Standard error of [`Calibration::z_for_pair`]'s height for a
    /// disparity whose component across the tilt axis has standard error
    /// `std_px`: the slope dz/dd times `std_px` and, for a fit, its
    /// prediction error at d, `s^2 (1 + h(d))` with `s^2 = SS_res / (n - p)`
    /// and `h` the leverage of d. `None` when there is no height, or a fit
    /// has no more samples than coefficients (its error is then unknown).
    pub fn z_std_for_pair(
        &self,
        disparity_px: [f64; 2],
        std_px: f64,
        meta: Option<&PairMeta>,
    ) -> Option<f64> {
        let slope = self.slope_for_pair(disparity_px, meta)?;
        let mut variance = (slope * std_px).powi(2);
        if let Some(fit) = self.fit_variance()? {
            // A new observation: the fit's scatter plus its coefficients'.
            let x0 = fit.row(axis_component(self.tilt_axis_deg(), disparity_px));
            variance += fit.s2 * (1.0 + fit.leverage(&x0)?);
        }
        let std = variance.sqrt();
        std.is_finite().then_some(std)
    }

    /// The height of the object at disparity `from` above the one at `to`
    /// in the same pair, micrometres, and its standard error from the two
    /// disparities' standard errors `std_px` (independent: disjoint parts
    /// of the images) and, for a fitted calibration, its coefficients'
    /// uncertainty at the two disparities together (`s^2 g' (X'X)^-1 g`,
    /// `g` the difference of the two design rows: the intercept and the
    /// fit's scatter are shared and cancel). The error says why there is no
    /// height (see [`Calibration::z_for_pair`]).
    pub fn dz_for_pair(
        &self,
        from: [f64; 2],
        to: [f64; 2],
        std_px: [f64; 2],
        meta: Option<&PairMeta>,
    ) -> Result<(f64, Option<f64>), String> {
        let dz = self.z_for_pair(from, meta)? - self.z_for_pair(to, meta)?;
        let std = (|| {
            let mut variance = 0.0;
            for (d, s) in [(from, std_px[0]), (to, std_px[1])] {
                variance += (self.slope_for_pair(d, meta)? * s).powi(2);
            }
            if let Some(fit) = self.fit_variance()? {
                let axis = self.tilt_axis_deg();
                let (a, b) = (
                    fit.row(axis_component(axis, from)),
                    fit.row(axis_component(axis, to)),
                );
                let g: Vec<f64> = a.iter().zip(&b).map(|(a, b)| a - b).collect();
                variance += fit.s2 * fit.leverage(&g)?;
            }
            let std = variance.sqrt();
            std.is_finite().then_some(std)
        })();
        Ok((dz, std))
    }

    /// dz/dd along the disparity direction at `disparity_px`, micrometres
    /// per pixel: one pixel both ways, a central difference that is exact
    /// for the polynomials used.
    fn slope_for_pair(&self, disparity_px: [f64; 2], meta: Option<&PairMeta>) -> Option<f64> {
        let (sin_t, cos_t) = sin_cos_deg(self.tilt_axis_deg());
        let moved = |k: f64| [disparity_px[0] + k * sin_t, disparity_px[1] - k * cos_t];
        Some((self.z_for_pair(moved(1.0), meta).ok()? - self.z_for_pair(moved(-1.0), meta).ok()?) / 2.0)
    }

    /// What the prediction error of a fitted calibration needs: its design
    /// (centred and scaled powers of the disparity), `X'X` and the residual
    /// variance `s^2`. `Some(None)` for a geometric calibration (or a fit without heights
    /// yet), `None` for a fit with no more samples than coefficients, whose
    /// error is unknown.
    fn fit_variance(&self) -> Option<Option<FitVariance>> {
        let (CalibrationSpec::Fit(f), Some(poly), Some(stats)) = (&self.spec, &self.poly, self.stats) else {
            return Some(None);
        };
        let (n, p) = (f.samples.len(), f.degree as usize + 1);
        if n <= p {
            return None;
        }
        let mut fit = FitVariance {
            s2: stats.residual_rms_um.powi(2) * n as f64 / (n - p) as f64,
            center_px: poly.center_px,
            scale_px: poly.scale_px,
            terms: p,
            xtx: vec![vec![0.0; p]; p],
        };
        for sample in &f.samples {
            let x = fit.row(sample.disparity_px);
            for i in 0..p {
                for j in 0..p {
                    fit.xtx[i][j] += x[i] * x[j];
                }
            }
        }
        Some(Some(fit))
    }

    /// Appends a sample to a fitted calibration and refits. On error (invalid
    /// sample, too many samples, degenerate refit, or a geometric calibration:
    /// [`CalibError::NotAFit`]) the calibration is unchanged.
    pub fn add_sample(&mut self, sample: Sample) -> Result<(), CalibError> {
        self.change_samples(|samples| {
            samples.push(sample);
            Ok(())
        })
    }

    /// Removes sample `index` (0-based, in the order given) from a fitted
    /// calibration and refits; returns the sample. On error (no such
    /// sample: [`CalibError::NoSuchSample`], degenerate refit, a geometric
    /// calibration) the calibration is unchanged; too few samples left make
    /// it [`Calibration::pending`].
    pub fn remove_sample(&mut self, index: usize) -> Result<Sample, CalibError> {
        self.change_samples(|samples| {
            sample_at(samples, index)?;
            Ok(samples.remove(index))
        })
    }

    /// Replaces sample `index` of a fitted calibration by what `change`
    /// makes of it, and refits; returns the sample it replaced. Errors as
    /// [`Calibration::remove_sample`]; the calibration is then unchanged.
    pub fn update_sample(
        &mut self,
        index: usize,
        change: impl FnOnce(&Sample) -> Sample,
    ) -> Result<Sample, CalibError> {
        self.change_samples(|samples| {
            let slot = sample_at(samples, index)?;
            let new = change(slot);
            Ok(std::mem::replace(slot, new))
        })
    }

    /// Applies `change` to a copy of a fitted calibration's samples and
    /// refits; the calibration changes only when both succeed.
    fn change_samples<T>(
        &mut self,
        change: impl FnOnce(&mut Vec<Sample>) -> Result<T, CalibError>,
    ) -> Result<T, CalibError> {
        let CalibrationSpec::Fit(fit) = &self.spec else {
            return Err(CalibError::NotAFit {
                model: self.model_name(),
            });
        };
        let mut fit = fit.clone();
        let out = change(&mut fit.samples)?;
        *self = build_fit(fit)?;
        Ok(out)
    }

    /// Per sample of a fitted calibration, its height minus the fit's at
    /// its disparity, micrometres (in the samples' order; empty for a
    /// geometric calibration): an outlier stands out.
    pub fn residuals_um(&self) -> Vec<f64> {
        self.samples()
            .iter()
            .map(|s| s.z_um - self.z_from_axis(s.disparity_px))
            .collect()
    }
}

/// Sample `index`, or [`CalibError::NoSuchSample`].
fn sample_at(samples: &mut [Sample], index: usize) -> Result<&mut Sample, CalibError> {
    let count = samples.len();
    samples
        .get_mut(index)
        .ok_or(CalibError::NoSuchSample { index, count })
}

fn default_tilt_axis_deg() -> f64 {
    DEFAULT_TILT_AXIS_DEG
}

fn default_fit_degree() -> u8 {
    DEFAULT_FIT_DEGREE
}

fn check_tilt_axis(tilt_axis_deg: f64) -> Result<(), CalibError> {
    if !(tilt_axis_deg.is_finite() && tilt_axis_deg.abs() <= 360.0) {
        return Err(CalibError::Invalid(format!(
            "invalid tilt_axis_deg {tilt_axis_deg} (expected a finite angle with -360 <= tilt_axis_deg <= 360)"
        )));
    }
    Ok(())
}

fn build_geometric(g: GeometricSpec) -> Result<Calibration, CalibError> {
    let bad = |m: String| Err(CalibError::Invalid(m));
    match (g.pixel_size_um, g.pixel_size) {
        (Some(_), Some(_)) => {
            return bad(
                "both pixel_size_um and pixel_size given (expected one: a number, or \"from_images\")".into(),
            )
        }
        (None, None) => {
            return bad(
                "missing pixel_size_um (expected a number > 0, or \"pixel_size\": \"from_images\")".into(),
            )
        }
        (Some(s), None) if !(s.is_finite() && s > 0.0) => {
            return bad(format!(
                "invalid pixel_size_um {s} (expected a finite pixel_size_um > 0)"
            ))
        }
        _ => {}
    }
    match (g.vergence_deg, g.vergence) {
        (Some(_), Some(_)) => {
            return bad(
                "both vergence_deg and vergence given (expected one: a number, or \"from_stage_tilt\")"
                    .into(),
            )
        }
        (None, None) => return bad(
            "missing vergence_deg (expected 0 < vergence_deg <= 90, or \"vergence\": \"from_stage_tilt\")"
                .into(),
        ),
        (Some(v), None) if !(v > 0.0 && v <= 90.0) => {
            return bad(format!(
                "invalid vergence_deg {v} (expected 0 < vergence_deg <= 90)"
            ))
        }
        _ => {}
    }
    if !(g.reference_disparity_px.is_finite() && g.reference_disparity_px.abs() <= MAX_ABS_DISPARITY_PX) {
        return bad(format!(
            "invalid reference_disparity_px {} (expected a finite value with magnitude <= {MAX_ABS_DISPARITY_PX:e})",
            g.reference_disparity_px
        ));
    }
    check_tilt_axis(g.tilt_axis_deg)?;
    let (Some(pixel_size_um), Some(vergence_deg)) = (g.pixel_size_um, g.vergence_deg) else {
        // Scaled per pair from the images' metadata: no fixed coefficients.
        return Ok(Calibration {
            spec: CalibrationSpec::Geometric(g),
            coefficients: Vec::new(),
            stats: None,
            poly: None,
        });
    };
    let um_per_px = geometric_scale(pixel_size_um, vergence_deg.to_radians());
    // A subnormal vergence (or a huge pixel size) passes the range checks
    // but overflows the scale; such a calibration could not be stored.
    if !(um_per_px.is_finite() && (g.reference_disparity_px * um_per_px).is_finite()) {
        return bad(format!(
            "pixel_size_um {pixel_size_um} with vergence_deg {vergence_deg} gives a non-finite scale (expected a vergence of at least a few microdegrees)"
        ));
    }
    let poly = CenteredPoly {
        center_px: g.reference_disparity_px,
        scale_px: 1.0,
        coefficients: vec![0.0, um_per_px],
    };
    Ok(Calibration {
        spec: CalibrationSpec::Geometric(g),
        coefficients: vec![-g.reference_disparity_px * um_per_px, um_per_px],
        stats: None,
        poly: Some(poly),
    })
}

/// Micrometres of height per pixel of disparity: `s / (2 sin(alpha / 2))`.
fn geometric_scale(pixel_size_um: f64, vergence_rad: f64) -> f64 {
    pixel_size_um / (2.0 * (vergence_rad / 2.0).sin())
}

fn build_fit(f: FitSpec) -> Result<Calibration, CalibError> {
    if !(1..=2).contains(&f.degree) {
        return Err(CalibError::Invalid(format!(
            "invalid degree {} (expected 1 or 2)",
            f.degree
        )));
    }
    check_tilt_axis(f.tilt_axis_deg)?;
    if f.samples.len() > MAX_SAMPLES {
        return Err(CalibError::TooManySamples {
            samples: f.samples.len(),
            max: MAX_SAMPLES,
        });
    }
    for (i, s) in f.samples.iter().enumerate() {
        if !(s.disparity_px.is_finite() && s.disparity_px.abs() <= MAX_ABS_DISPARITY_PX) {
            return Err(CalibError::Invalid(format!(
                "invalid samples[{i}].disparity_px {} (expected a finite value with magnitude <= {MAX_ABS_DISPARITY_PX:e})",
                s.disparity_px
            )));
        }
        if s.frame.is_some_and(|f| f > i64::MAX as u64) {
            return Err(CalibError::Invalid(format!(
                "invalid samples[{i}].frame {} (expected 0..={})",
                s.frame.unwrap_or_default(),
                i64::MAX
            )));
        }
        if s.session_id.as_ref().is_some_and(|id| id.chars().count() > 200) {
            return Err(CalibError::Invalid(format!(
                "invalid samples[{i}].session_id (expected at most 200 characters)"
            )));
        }
        if !(s.z_um.is_finite() && s.z_um.abs() <= MAX_ABS_Z_UM) {
            return Err(CalibError::Invalid(format!(
                "invalid samples[{i}].z_um {} (expected a finite value with magnitude <= {MAX_ABS_Z_UM:e})",
                s.z_um
            )));
        }
    }
    let needed = f.degree as usize + 1;
    let d: Vec<f64> = f.samples.iter().map(|s| s.disparity_px).collect();
    let z: Vec<f64> = f.samples.iter().map(|s| s.z_um).collect();
    let distinct = count_distinct(&d, DISTINCT_DISPARITY_TOLERANCE_PX);
    if distinct < needed {
        // Pending: gives no height until it has enough distinct samples
        // (a calibration started empty and filled from stage steps).
        return Ok(Calibration {
            spec: CalibrationSpec::Fit(f),
            coefficients: Vec::new(),
            stats: None,
            poly: None,
        });
    }
    let (poly, stats) = fit_polynomial(&d, &z, f.degree)?;
    let coefficients = poly.monomial();
    if coefficients.iter().any(|c| !c.is_finite()) {
        return Err(CalibError::DegenerateFit(
            "the coefficients overflow; spread the samples over a wider range of disparities".into(),
        ));
    }
    Ok(Calibration {
        spec: CalibrationSpec::Fit(f),
        coefficients,
        stats: Some(stats),
        poly: Some(poly),
    })
}

/// Solves the small symmetric system `a x = b` by Gaussian elimination with
/// partial pivoting; `None` when it is singular.
/// A fitted calibration's design and residual variance (see
/// [`Calibration::fit_variance`]).
struct FitVariance {
    s2: f64,
    center_px: f64,
    scale_px: f64,
    terms: usize,
    xtx: Vec<Vec<f64>>,
}

impl FitVariance {
    /// The design row at a disparity across the axis.
    fn row(&self, d: f64) -> Vec<f64> {
        let u = (d - self.center_px) / self.scale_px;
        (0..self.terms).map(|k| u.powi(k as i32)).collect()
    }

    /// `x' (X'X)^-1 x`.
    fn leverage(&self, x: &[f64]) -> Option<f64> {
        let solved = solve(self.xtx.clone(), x.to_vec())?;
        Some(solved.iter().zip(x).map(|(a, b)| a * b).sum())
    }
}

fn solve(mut a: Vec<Vec<f64>>, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    for k in 0..n {
        let pivot = (k..n).max_by(|&i, &j| a[i][k].abs().total_cmp(&a[j][k].abs()))?;
        if a[pivot][k].abs() < 1e-300 {
            return None;
        }
        a.swap(k, pivot);
        b.swap(k, pivot);
        let (top, rest) = a.split_at_mut(k + 1);
        let pivot_row = &top[k];
        for (i, row) in rest.iter_mut().enumerate() {
            let m = row[k] / pivot_row[k];
            for (x, p) in row[k..].iter_mut().zip(&pivot_row[k..]) {
                *x -= m * p;
            }
            b[k + 1 + i] -= m * b[k];
        }
    }
    let mut x = vec![0.0; n];
    for i in (0..n).rev() {
        let s: f64 = (i + 1..n).map(|j| a[i][j] * x[j]).sum();
        x[i] = (b[i] - s) / a[i][i];
    }
    Some(x)
}

/// Number of groups of values, where sorted neighbours closer than `tol` join a group.
fn count_distinct(values: &[f64], tol: f64) -> usize {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let mut count = 0;
    let mut last = f64::NEG_INFINITY;
    for x in v {
        if x - last > tol {
            count += 1;
        }
        last = x;
    }
    count
}

/// Least squares `z = sum_k b_k u^k`, `u = (d - mean d) / max |d - mean d|`, by
/// Householder QR of the design matrix (no normal equations).
fn fit_polynomial(d: &[f64], z: &[f64], degree: u8) -> Result<(CenteredPoly, FitStats), CalibError> {
    let n = d.len();
    let p = degree as usize + 1;
    let center_px = d.iter().sum::<f64>() / n as f64;
    let scale_px = d.iter().map(|x| (x - center_px).abs()).fold(0.0, f64::max);
    if scale_px.is_nan() || scale_px <= 0.0 {
        return Err(CalibError::DegenerateFit(
            "all disparity_px values are equal".into(),
        ));
    }
    let u: Vec<f64> = d.iter().map(|x| (x - center_px) / scale_px).collect();
    // Columns of the design matrix: 1, u, u^2.
    let mut cols: Vec<Vec<f64>> = (0..p)
        .map(|k| u.iter().map(|x| x.powi(k as i32)).collect())
        .collect();
    let mut y = z.to_vec();
    for k in 0..p {
        let norm = cols[k][k..].iter().map(|x| x * x).sum::<f64>().sqrt();
        if norm == 0.0 {
            return Err(singular());
        }
        let alpha = if cols[k][k] > 0.0 { -norm } else { norm };
        let mut v: Vec<f64> = cols[k][k..].to_vec();
        v[0] -= alpha;
        let vv: f64 = v.iter().map(|x| x * x).sum();
        if vv > 0.0 {
            let reflect = |c: &mut [f64]| {
                let s = 2.0 * v.iter().zip(c.iter()).map(|(a, b)| a * b).sum::<f64>() / vv;
                c.iter_mut().zip(&v).for_each(|(ci, vi)| *ci -= s * vi);
            };
            for col in cols.iter_mut().skip(k) {
                reflect(&mut col[k..]);
            }
            reflect(&mut y[k..]);
        }
    }
    // R is upper triangular: r[i][j] = cols[j][i] for i <= j.
    let r = |i: usize, j: usize| cols[j][i];
    let cond = condition_number_1(p, &r);
    if cond.is_nan() || cond > MAX_CONDITION_NUMBER {
        return Err(CalibError::DegenerateFit(format!(
            "the design matrix is ill-conditioned (condition number {cond:.3e} > {MAX_CONDITION_NUMBER:e}): the \
             disparity_px values are too close together for a degree-{degree} fit; spread the samples over a \
             wider range of heights"
        )));
    }
    let mut b = vec![0.0; p];
    for i in (0..p).rev() {
        let s: f64 = (i + 1..p).map(|j| r(i, j) * b[j]).sum();
        b[i] = (y[i] - s) / r(i, i);
    }
    let poly = CenteredPoly {
        center_px,
        scale_px,
        coefficients: b,
    };
    let ss_res: f64 = d
        .iter()
        .zip(z)
        .map(|(&di, &zi)| (zi - poly.eval(di)).powi(2))
        .sum();
    let z_mean = z.iter().sum::<f64>() / n as f64;
    let ss_tot: f64 = z.iter().map(|zi| (zi - z_mean).powi(2)).sum();
    let z_max = z.iter().map(|x| x.abs()).fold(0.0, f64::max);
    // Sums of squares at the level of rounding noise count as zero.
    let noise = n as f64 * (16.0 * f64::EPSILON * z_max).powi(2);
    let r_squared = if ss_tot <= noise {
        1.0
    } else {
        (1.0 - ss_res / ss_tot).clamp(0.0, 1.0)
    };
    let residual_rms_um = (ss_res / n as f64).sqrt();
    if !residual_rms_um.is_finite() {
        return Err(singular());
    }
    Ok((
        poly,
        FitStats {
            residual_rms_um,
            r_squared,
        },
    ))
}

fn singular() -> CalibError {
    CalibError::DegenerateFit(
        "the design matrix is singular; spread the samples over a wider range of heights".into(),
    )
}

/// 1-norm condition number of a p x p upper-triangular matrix given by `r(i, j)`;
/// infinite when a diagonal entry is zero.
fn condition_number_1(p: usize, r: &dyn Fn(usize, usize) -> f64) -> f64 {
    if (0..p).any(|i| r(i, i) == 0.0) {
        return f64::INFINITY;
    }
    let col_norm = |m: &dyn Fn(usize, usize) -> f64| {
        (0..p)
            .map(|j| (0..p).map(|i| m(i, j).abs()).sum::<f64>())
            .fold(0.0, f64::max)
    };
    // Inverse by back substitution, column by column.
    let mut inv = vec![vec![0.0; p]; p];
    for (j, inv_col) in inv.iter_mut().enumerate() {
        for i in (0..p).rev() {
            let e = if i == j { 1.0 } else { 0.0 };
            let s: f64 = (i + 1..p).map(|k| r(i, k) * inv_col[k]).sum();
            inv_col[i] = (e - s) / r(i, i);
        }
    }
    col_norm(r) * col_norm(&|i, j| inv[j][i])
}

/// The JSON form of a [`Calibration`]: the spec's fields plus the derived ones,
/// which are optional on input (recomputed, and checked when present).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "snake_case", deny_unknown_fields)]
enum CalibrationWire {
    Geometric {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        pixel_size_um: Option<f64>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        pixel_size: Option<PixelSizeSource>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        vergence_deg: Option<f64>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        vergence: Option<VergenceSource>,
        #[serde(default)]
        reference_disparity_px: f64,
        #[serde(default = "default_tilt_axis_deg")]
        tilt_axis_deg: f64,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        coefficients: Option<Vec<f64>>,
    },
    Fit {
        #[serde(default = "default_fit_degree")]
        degree: u8,
        samples: Vec<Sample>,
        #[serde(default = "default_tilt_axis_deg")]
        tilt_axis_deg: f64,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        coefficients: Option<Vec<f64>>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        residual_rms_um: Option<f64>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        r_squared: Option<f64>,
    },
}

impl From<Calibration> for CalibrationWire {
    fn from(c: Calibration) -> Self {
        match c.spec {
            CalibrationSpec::Geometric(g) => Self::Geometric {
                pixel_size_um: g.pixel_size_um,
                pixel_size: g.pixel_size,
                vergence_deg: g.vergence_deg,
                vergence: g.vergence,
                reference_disparity_px: g.reference_disparity_px,
                tilt_axis_deg: g.tilt_axis_deg,
                // Scaled per pair from the images: none to store.
                coefficients: (!g.from_images()).then_some(c.coefficients),
            },
            CalibrationSpec::Fit(f) => Self::Fit {
                degree: f.degree,
                samples: f.samples,
                tilt_axis_deg: f.tilt_axis_deg,
                coefficients: Some(c.coefficients),
                residual_rms_um: c.stats.map(|s| s.residual_rms_um),
                r_squared: c.stats.map(|s| s.r_squared),
            },
        }
    }
}

impl TryFrom<CalibrationWire> for Calibration {
    type Error = CalibError;

    fn try_from(w: CalibrationWire) -> Result<Self, CalibError> {
        let (spec, coefficients, rms, r2) = match w {
            CalibrationWire::Geometric {
                pixel_size_um,
                pixel_size,
                vergence_deg,
                vergence,
                reference_disparity_px,
                tilt_axis_deg,
                coefficients,
            } => (
                CalibrationSpec::Geometric(GeometricSpec {
                    pixel_size_um,
                    pixel_size,
                    vergence_deg,
                    vergence,
                    reference_disparity_px,
                    tilt_axis_deg,
                }),
                coefficients,
                None,
                None,
            ),
            CalibrationWire::Fit {
                degree,
                samples,
                tilt_axis_deg,
                coefficients,
                residual_rms_um,
                r_squared,
            } => (
                CalibrationSpec::Fit(FitSpec {
                    degree,
                    samples,
                    tilt_axis_deg,
                }),
                coefficients,
                residual_rms_um,
                r_squared,
            ),
        };
        let cal = build(spec)?;
        if let Some(stored) = coefficients {
            let scale = cal.coefficients.iter().fold(1.0_f64, |m, c| m.max(c.abs()));
            let agrees = stored.len() == cal.coefficients.len()
                && stored
                    .iter()
                    .zip(&cal.coefficients)
                    .all(|(a, b)| close(*a, *b, 1e-12 * scale));
            if !agrees {
                return Err(CalibError::Invalid(format!(
                    "coefficients {stored:?} do not match the parameters (recomputed {:?}); remove \
                     `coefficients` to have them recomputed",
                    cal.coefficients
                )));
            }
        }
        if let Some(stats) = cal.stats {
            let z_scale = 1.0 + cal.samples().iter().fold(0.0_f64, |m, s| m.max(s.z_um.abs()));
            if let Some(stored) = rms {
                if !close(stored, stats.residual_rms_um, 1e-9 * z_scale) {
                    return Err(CalibError::Invalid(format!(
                        "residual_rms_um {stored} does not match the samples (recomputed {})",
                        stats.residual_rms_um
                    )));
                }
            }
            if let Some(stored) = r2 {
                if !close(stored, stats.r_squared, 1e-9) {
                    return Err(CalibError::Invalid(format!(
                        "r_squared {stored} does not match the samples (recomputed {})",
                        stats.r_squared
                    )));
                }
            }
        }
        Ok(cal)
    }
}

/// `a` and `b` agree to a relative 1e-6 or within `abs_tol`.
fn close(a: f64, b: f64, abs_tol: f64) -> bool {
    let diff = (a - b).abs();
    diff <= abs_tol || diff <= 1e-6 * a.abs().max(b.abs())
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    fn geometric(pixel_size_um: f64, vergence_deg: f64, d0: f64, tilt: f64) -> Calibration {
        build(CalibrationSpec::Geometric(GeometricSpec {
            pixel_size_um: Some(pixel_size_um),
            pixel_size: None,
            vergence_deg: Some(vergence_deg),
            vergence: None,
            reference_disparity_px: d0,
            tilt_axis_deg: tilt,
        }))
        .unwrap()
    }

    fn fit_spec(degree: u8, samples: Vec<Sample>) -> CalibrationSpec {
        CalibrationSpec::Fit(FitSpec {
            degree,
            samples,
            tilt_axis_deg: DEFAULT_TILT_AXIS_DEG,
        })
    }

    fn samples_of(d: &[f64], f: impl Fn(f64) -> f64) -> Vec<Sample> {
        d.iter().map(|&x| Sample::new(x, f(x))).collect()
    }

    fn rel_close(a: f64, b: f64, rel: f64) -> bool {
        (a - b).abs() <= rel * a.abs().max(b.abs()).max(1e-300)
    }

    #[test]
    fn geometric_ten_degrees_one_pixel_is_5_737_um() {
        let cal = geometric(1.0, 10.0, 0.0, 90.0);
        let z = cal.z_from_axis(1.0);
        assert!((z - 5.737).abs() < 5e-4, "{z}");
        assert!(rel_close(z, 1.0 / (2.0 * 5f64.to_radians().sin()), 1e-15));
        assert_eq!(cal.coefficients(), &[0.0, z]);
        assert_eq!(cal.z_um([1.0, 123.0]), z, "tilt axis 90: only dx counts");
        assert!((cal.z_from_axis(0.05) - 0.29).abs() < 5e-3, "0.05 px is 0.29 s");
        assert_eq!(cal.model_name(), "geometric");
        assert!(cal.fit_stats().is_none() && cal.samples().is_empty());
    }

    #[test]
    fn geometric_reference_disparity_offsets_zero() {
        let cal = geometric(0.5, 6.0, 2.5, 90.0);
        let k = 0.5 / (2.0 * 3f64.to_radians().sin());
        assert_eq!(cal.z_from_axis(2.5), 0.0);
        assert!(rel_close(cal.z_from_axis(3.5), k, 1e-14));
        assert!(rel_close(cal.z_from_axis(1.5), -k, 1e-14));
        let c = cal.coefficients();
        assert!(rel_close(c[1], k, 1e-15) && rel_close(c[0], -2.5 * k, 1e-15));
        for d in [-10.0, 0.0, 7.25] {
            assert!((c[0] + c[1] * d - cal.z_from_axis(d)).abs() < 1e-12);
        }
    }

    #[test]
    fn axis_component_sign_convention() {
        let d = [3.0, -2.0];
        assert_eq!(axis_component(90.0, d), 3.0);
        assert_eq!(axis_component(0.0, d), 2.0, "axis along x: -dy");
        assert_eq!(axis_component(180.0, d), -2.0, "dy");
        assert_eq!(axis_component(270.0, d), -3.0, "-dx");
        assert_eq!(axis_component(-90.0, d), -3.0);
        assert_eq!(axis_component(-180.0, d), -2.0);
        assert_eq!(axis_component(450.0, d), 3.0);
        let s = 45f64.to_radians().sin();
        assert!((axis_component(45.0, d) - (3.0 * s + 2.0 * s)).abs() < 1e-12);
        // Tilt axis 0 deg: the calibration uses -dy.
        let cal = geometric(1.0, 10.0, 0.0, 0.0);
        assert_eq!(cal.z_um([100.0, -1.0]), cal.z_from_axis(1.0));
        assert_eq!(cal.z_um([100.0, 2.0]), cal.z_from_axis(-2.0));
    }

    #[test]
    fn linear_fit_recovers_exact_coefficients() {
        let d = [-2.0, -1.0, -0.5, 0.0, 1.0, 2.0, 3.5];
        let cal = build(fit_spec(1, samples_of(&d, |x| 3.0 + 40.0 * x))).unwrap();
        let c = cal.coefficients();
        assert_eq!(c.len(), 2);
        assert!((c[0] - 3.0).abs() < 1e-12 && (c[1] - 40.0).abs() < 1e-12, "{c:?}");
        let stats = cal.fit_stats().unwrap();
        assert!(stats.residual_rms_um < 1e-12);
        assert_eq!(stats.r_squared, 1.0);
        assert!((cal.z_um([0.25, 9.0]) - 13.0).abs() < 1e-12);
        assert_eq!(cal.model_name(), "fit");
    }

    #[test]
    fn quadratic_fit_recovers_c2() {
        let d: Vec<f64> = (0..9).map(|i| -4.0 + i as f64).collect();
        let cal = build(fit_spec(2, samples_of(&d, |x| -1.5 + 12.0 * x + 0.75 * x * x))).unwrap();
        let c = cal.coefficients();
        assert_eq!(c.len(), 3);
        assert!((c[0] + 1.5).abs() < 1e-12);
        assert!((c[1] - 12.0).abs() < 1e-12);
        assert!((c[2] - 0.75).abs() < 1e-12, "{c:?}");
        assert!(cal.residual_rms_um().unwrap() < 1e-12);
    }

    #[test]
    fn noisy_fit_has_plausible_rms_and_r_squared() {
        // Like the paper's 60x data: ~4 px over 400 um, with 2 um of height noise.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let noise = Normal::new(0.0, 2.0).unwrap();
        let samples: Vec<Sample> = (0..41)
            .map(|i| {
                let d = 10.0 + 0.1 * i as f64;
                Sample::new(d, -1000.0 + 100.0 * d + noise.sample(&mut rng))
            })
            .collect();
        let cal = build(fit_spec(1, samples)).unwrap();
        let stats = cal.fit_stats().unwrap();
        assert!(
            stats.residual_rms_um > 1.2 && stats.residual_rms_um < 2.8,
            "{stats:?}"
        );
        assert!(stats.r_squared > 0.999 && stats.r_squared < 1.0, "{stats:?}");
        assert!(
            (cal.coefficients()[1] - 100.0).abs() < 2.0,
            "{:?}",
            cal.coefficients()
        );
    }

    #[test]
    fn too_few_distinct_disparities_give_no_height_until_there_are_enough() {
        // One distinct disparity for a line: pending, no height, and why.
        let pending = build(fit_spec(1, samples_of(&[2.0; 10], |_| 5.0))).unwrap();
        let why = pending.pending().expect("pending");
        assert!(why.contains("1 distinct disparity_px values of the 2"), "{why}");
        assert!(pending.coefficients().is_empty());
        assert_eq!(pending.fit_stats(), None);
        assert_eq!(pending.z_for_pair([3.0, 0.0], None), Err(why));
        // Two distinct for a parabola; values closer than the tolerance are
        // one; no samples at all.
        let d: Vec<f64> = (0..12).map(|i| if i % 2 == 0 { 1.0 } else { 4.0 }).collect();
        let two = build(fit_spec(2, samples_of(&d, |x| x * 3.0 + (x * 7.0).sin()))).unwrap();
        assert!(two
            .pending()
            .unwrap()
            .contains("2 distinct disparity_px values of the 3"));
        assert!(build(fit_spec(1, samples_of(&[1.0, 1.0 + 1e-9], |x| x)))
            .unwrap()
            .pending()
            .is_some());
        let mut empty = build(fit_spec(1, vec![])).unwrap();
        assert!(empty.pending().is_some());
        // Filled from stage steps: the second distinct sample makes it a line.
        empty.add_sample(Sample::new(1.0, 10.0)).unwrap();
        assert!(empty.pending().is_some());
        empty.add_sample(Sample::new(2.0, 20.0)).unwrap();
        assert_eq!(empty.pending(), None);
        assert!((empty.z_for_pair([3.0, 0.0], None).unwrap() - 30.0).abs() < 1e-9);
        // A pending calibration survives its JSON form.
        let back = from_json(&serde_json::to_string(&pending).unwrap()).unwrap();
        assert_eq!(back, pending);
    }

    #[test]
    fn refuses_ill_conditioned_fit() {
        // Three distinct disparities, two of them 2e-6 px apart over a 2e6 px range.
        let d = [-1e6, -1e6 + 2e-6, 1e6];
        let err = build(fit_spec(2, samples_of(&d, |x| x * 1e-3))).unwrap_err();
        assert_eq!(err.code(), "degenerate_fit", "{err}");
        assert!(err.to_string().contains("ill-conditioned"), "{err}");
    }

    #[test]
    fn refuses_invalid_and_non_finite_inputs() {
        let geo = |s: f64, v: f64, d0: f64, t: f64| {
            build(CalibrationSpec::Geometric(GeometricSpec {
                pixel_size_um: Some(s),
                pixel_size: None,
                vergence_deg: Some(v),
                vergence: None,
                reference_disparity_px: d0,
                tilt_axis_deg: t,
            }))
            .unwrap_err()
        };
        let err = geo(1.0, 0.0, 0.0, 90.0);
        assert_eq!(err.code(), "invalid_calibration");
        assert_eq!(
            err.to_string(),
            "invalid vergence_deg 0 (expected 0 < vergence_deg <= 90)"
        );
        assert!(geo(1.0, 90.5, 0.0, 90.0).to_string().contains("vergence_deg"));
        assert!(geo(1.0, f64::NAN, 0.0, 90.0).to_string().contains("vergence_deg"));
        assert!(geo(0.0, 5.0, 0.0, 90.0).to_string().contains("pixel_size_um > 0"));
        assert!(geo(f64::INFINITY, 5.0, 0.0, 90.0)
            .to_string()
            .contains("pixel_size_um"));
        assert!(geo(-1.0, 5.0, 0.0, 90.0).to_string().contains("pixel_size_um"));
        assert!(geo(1.0, 5.0, f64::NAN, 90.0)
            .to_string()
            .contains("reference_disparity_px"));
        assert!(geo(1.0, 5.0, 0.0, f64::NAN).to_string().contains("tilt_axis_deg"));
        assert!(build(CalibrationSpec::Geometric(GeometricSpec {
            pixel_size_um: Some(1.0),
            pixel_size: None,
            vergence_deg: Some(90.0),
            vergence: None,
            reference_disparity_px: 0.0,
            tilt_axis_deg: 90.0,
        }))
        .is_ok());

        let good = samples_of(&[0.0, 1.0, 2.0, 3.0], |x| 2.0 * x);
        for (i, bad) in [
            Sample::new(f64::NAN, 1.0),
            Sample::new(f64::INFINITY, 1.0),
            Sample::new(1.5, f64::NAN),
            Sample::new(1.5, f64::NEG_INFINITY),
            Sample::new(1e7, 1.0),
        ]
        .into_iter()
        .enumerate()
        {
            let mut s = good.clone();
            s.push(bad);
            let err = build(fit_spec(1, s)).unwrap_err();
            assert_eq!(err.code(), "invalid_calibration", "case {i}: {err}");
            assert!(err.to_string().contains("samples[4]"), "case {i}: {err}");
        }
        for degree in [0, 3] {
            let err = build(fit_spec(degree, good.clone())).unwrap_err();
            assert_eq!(
                err.to_string(),
                format!("invalid degree {degree} (expected 1 or 2)")
            );
        }
        let too_many = samples_of(&vec![1.0; MAX_SAMPLES + 1], |x| x);
        assert_eq!(
            build(fit_spec(1, too_many)).unwrap_err().code(),
            "too_many_samples"
        );
    }

    #[test]
    fn all_equal_heights_fit_with_r_squared_one() {
        let cal = build(fit_spec(1, samples_of(&[0.1, 0.7, 1.3, 2.2], |_| 0.3))).unwrap();
        let stats = cal.fit_stats().unwrap();
        assert_eq!(stats.r_squared, 1.0);
        assert!(stats.residual_rms_um < 1e-15);
        assert!(cal.coefficients()[1].abs() < 1e-14);
        assert!((cal.z_from_axis(5.0) - 0.3).abs() < 1e-13);
    }

    #[test]
    fn add_sample_refits() {
        let mut cal = build(fit_spec(1, samples_of(&[0.0, 1.0], |x| 10.0 * x))).unwrap();
        assert!((cal.coefficients()[1] - 10.0).abs() < 1e-12);
        assert_eq!(cal.r_squared(), Some(1.0));
        cal.add_sample(Sample::new(2.0, 26.0)).unwrap();
        assert_eq!(cal.samples().len(), 3);
        // Least squares through (0,0), (1,10), (2,26): slope 13, intercept -1.
        let c = cal.coefficients();
        assert!((c[0] + 1.0).abs() < 1e-12 && (c[1] - 13.0).abs() < 1e-12, "{c:?}");
        assert!(cal.residual_rms_um().unwrap() > 0.5);
        assert!(cal.r_squared().unwrap() < 1.0);

        // A failed add leaves the calibration unchanged.
        let before = cal.clone();
        assert_eq!(
            cal.add_sample(Sample::new(f64::NAN, 1.0)).unwrap_err().code(),
            "invalid_calibration"
        );
        assert_eq!(cal, before);

        let mut geo = geometric(1.0, 5.0, 0.0, 90.0);
        let err = geo.add_sample(Sample::new(1.0, 1.0)).unwrap_err();
        assert_eq!(err.code(), "not_a_fit");
        assert!(
            err.to_string()
                .contains("samples only apply to fitted calibrations"),
            "{err}"
        );
    }

    #[test]
    fn json_round_trip_of_spec_and_calibration() {
        // Spec with defaults.
        let spec: CalibrationSpec =
            serde_json::from_str(r#"{"model": "geometric", "pixel_size_um": 0.5, "vergence_deg": 6.0}"#)
                .unwrap();
        assert_eq!(
            spec,
            CalibrationSpec::Geometric(GeometricSpec {
                pixel_size_um: Some(0.5),
                pixel_size: None,
                vergence_deg: Some(6.0),
                vergence: None,
                reference_disparity_px: 0.0,
                tilt_axis_deg: 90.0
            })
        );
        let text = serde_json::to_string(&spec).unwrap();
        assert_eq!(serde_json::from_str::<CalibrationSpec>(&text).unwrap(), spec);
        let fit: CalibrationSpec = serde_json::from_str(
            r#"{"model": "fit", "samples": [{"disparity_px": 1.2, "z_um": 0.0}, {"disparity_px": 2.2, "z_um": 50.0}]}"#,
        )
        .unwrap();
        let CalibrationSpec::Fit(f) = &fit else { panic!() };
        assert_eq!((f.degree, f.tilt_axis_deg, f.samples.len()), (1, 90.0, 2));

        // Full calibrations, both models.
        let noisy = samples_of(&[0.0, 0.5, 1.1, 1.4, 2.0, 3.3], |x| {
            1.0 + 7.0 * x + (x * 13.0).sin()
        });
        for spec in [
            CalibrationSpec::Geometric(GeometricSpec {
                pixel_size_um: Some(0.37),
                pixel_size: None,
                vergence_deg: Some(7.5),
                vergence: None,
                reference_disparity_px: -1.25,
                tilt_axis_deg: 30.0,
            }),
            fit_spec(2, noisy),
        ] {
            let cal = build(spec.clone()).unwrap();
            let text = serde_json::to_string(&cal).unwrap();
            let v: serde_json::Value = serde_json::from_str(&text).unwrap();
            assert_eq!(v["model"], spec.model_name());
            assert!(v["coefficients"].is_array() && v["tilt_axis_deg"].is_number());
            assert_eq!(v.get("r_squared").is_some(), cal.is_fit());
            assert_eq!(v.get("residual_rms_um").is_some(), cal.is_fit());
            assert_eq!(serde_json::from_str::<Calibration>(&text).unwrap(), cal);
            assert_eq!(from_json(&text).unwrap(), cal);
            // from_json also takes the bare spec, and the service's metadata.
            assert_eq!(from_json(&serde_json::to_string(&spec).unwrap()).unwrap(), cal);
            let mut with_meta = v.clone();
            with_meta["id"] = "cal_1".into();
            with_meta["name"] = "stage A".into();
            with_meta["created_at"] = "2024-01-01T00:00:00Z".into();
            assert_eq!(from_json(&with_meta.to_string()).unwrap(), cal);
        }
        let fit_json =
            serde_json::to_value(build(fit_spec(1, samples_of(&[0.0, 1.0, 2.0], |x| x))).unwrap()).unwrap();
        assert_eq!(fit_json["samples"][1]["disparity_px"], 1.0);
        assert_eq!(fit_json["samples"][1]["z_um"], 1.0);
        assert_eq!(fit_json["degree"], 1);
    }

    #[test]
    fn json_refuses_typos_and_tampering() {
        let err = from_json(r#"{"model": "geometric", "pixel_size": 0.5, "vergence_deg": 6.0}"#).unwrap_err();
        assert_eq!(err.code(), "invalid_calibration_json");
        assert!(err.to_string().contains("pixel_size"), "{err}");
        assert!(serde_json::from_str::<CalibrationSpec>(
            r#"{"model": "fit", "samples": [{"disparity_px": 1, "z": 0}]}"#
        )
        .is_err());
        assert!(serde_json::from_str::<CalibrationSpec>(r#"{"model": "spline", "samples": []}"#).is_err());
        assert_eq!(
            from_json("[1, 2]").unwrap_err().code(),
            "invalid_calibration_json"
        );
        assert_eq!(from_json("{").unwrap_err().code(), "invalid_calibration_json");
        // Validation errors keep their own codes through from_json.
        let err =
            from_json(r#"{"model": "geometric", "pixel_size_um": 0.5, "vergence_deg": 0}"#).unwrap_err();
        assert_eq!(
            err.to_string(),
            "invalid vergence_deg 0 (expected 0 < vergence_deg <= 90)"
        );
        let one = from_json(r#"{"model": "fit", "degree": 2, "samples": [{"disparity_px": 1, "z_um": 0}]}"#)
            .unwrap();
        assert!(one.pending().is_some());

        // Edited coefficients or statistics are refused, not silently replaced.
        let cal = geometric(1.0, 10.0, 0.0, 90.0);
        let mut v = serde_json::to_value(&cal).unwrap();
        v["coefficients"][1] = 6.0.into();
        let err = from_json(&v.to_string()).unwrap_err();
        assert_eq!(err.code(), "invalid_calibration");
        assert!(err.to_string().contains("coefficients"), "{err}");
        assert!(serde_json::from_value::<Calibration>(v).is_err());
        let fit = build(fit_spec(1, samples_of(&[0.0, 1.0, 2.0], |x| x * x))).unwrap();
        let mut v = serde_json::to_value(&fit).unwrap();
        v["r_squared"] = 0.5.into();
        assert!(from_json(&v.to_string())
            .unwrap_err()
            .to_string()
            .contains("r_squared"));
        // A geometric calibration has no fit statistics.
        let mut v = serde_json::to_value(&cal).unwrap();
        v["r_squared"] = 1.0.into();
        assert_eq!(
            from_json(&v.to_string()).unwrap_err().code(),
            "invalid_calibration_json"
        );
    }

    #[test]
    fn ill_conditioned_disparities_still_fit_degree_two() {
        // Disparities 1000 +- 0.5 px: naive normal equations in d lose all digits here.
        let truth = |d: f64| {
            let e = d - 1000.0;
            5.0 + 40.0 * e + 30.0 * e * e
        };
        let d: Vec<f64> = (-10..=10).map(|k| 1000.0 + 0.05 * k as f64).collect();
        let cal = build(fit_spec(2, samples_of(&d, truth))).unwrap();
        let z_max = d.iter().map(|&x| truth(x).abs()).fold(0.0, f64::max);
        for &x in &d {
            let err = (cal.z_from_axis(x) - truth(x)).abs();
            assert!(err <= 1e-6 * z_max, "d={x}: err {err}");
        }
        // The monomial coefficients too: c2 = 30, c1 = 40 - 60000, c0 = 5 - 40000 + 3e7.
        let c = cal.coefficients();
        assert!(rel_close(c[2], 30.0, 1e-6), "{c:?}");
        assert!(rel_close(c[1], 40.0 - 60_000.0, 1e-6), "{c:?}");
        assert!(rel_close(c[0], 5.0 - 40_000.0 + 30_000_000.0, 1e-6), "{c:?}");
        let stats = cal.fit_stats().unwrap();
        assert!(stats.residual_rms_um <= 1e-6 * z_max, "{stats:?}");
        assert!(stats.r_squared > 1.0 - 1e-9);
        // Reading it back gives the same calibration.
        let text = serde_json::to_string(&cal).unwrap();
        assert_eq!(from_json(&text).unwrap(), cal);
    }

    #[test]
    fn geometric_scale_overflow_is_refused() {
        let spec = CalibrationSpec::Geometric(GeometricSpec {
            pixel_size_um: Some(0.5),
            pixel_size: None,
            vergence_deg: Some(5e-324),
            vergence: None,
            reference_disparity_px: 0.0,
            tilt_axis_deg: 90.0,
        });
        let e = build(spec).unwrap_err();
        assert_eq!(e.code(), "invalid_calibration");
        assert!(e.to_string().contains("non-finite"), "{e}");
    }

    fn view(pixel_m: f64, tilt_rad: f64) -> ViewMeta {
        ViewMeta {
            pixel_width_m: Some(pixel_m),
            pixel_height_m: Some(pixel_m),
            stage_tilt_rad: Some(tilt_rad),
        }
    }

    #[test]
    fn pixel_size_and_vergence_from_the_images_match_the_typed_calibration() {
        let from_images = from_json(
            r#"{"model": "geometric", "pixel_size": "from_images", "vergence": "from_stage_tilt",
                "reference_disparity_px": 1.5, "tilt_axis_deg": 90}"#,
        )
        .unwrap();
        assert!(from_images.needs_images());
        assert!(from_images.coefficients().is_empty());
        // Stored without coefficients, read back the same.
        let text = serde_json::to_string(&from_images).unwrap();
        assert!(!text.contains("coefficients"), "{text}");
        assert_eq!(from_json(&text).unwrap(), from_images);
        let (tilt_l, tilt_r) = (0.558473_f64, 0.558473_f64 + 7.0_f64.to_radians());
        let meta = PairMeta::new(view(9.76562e-8, tilt_l), view(9.76562e-8, tilt_r));
        let typed = build(CalibrationSpec::Geometric(GeometricSpec {
            reference_disparity_px: 1.5,
            ..GeometricSpec::new(0.0976562, (tilt_r - tilt_l).to_degrees())
        }))
        .unwrap();
        for d in [[-30.0, 2.0], [0.0, 0.0], [1.5, -4.0], [55.11, 4.26]] {
            let z = from_images.z_for_pair(d, Some(&meta)).unwrap();
            let expected = typed.z_um(d);
            assert!((z - expected).abs() <= 1e-9, "d {d:?}: {z} against {expected}");
        }
        // Either one from the images, the other typed.
        let half = build(CalibrationSpec::Geometric(GeometricSpec {
            pixel_size_um: None,
            pixel_size: Some(PixelSizeSource::FromImages),
            ..GeometricSpec::new(0.0, 7.0)
        }))
        .unwrap();
        let z = half.z_for_pair([10.0, 0.0], Some(&meta)).unwrap();
        let typed_half = build(CalibrationSpec::Geometric(GeometricSpec::new(0.0976562, 7.0))).unwrap();
        assert!((z - typed_half.z_um([10.0, 0.0])).abs() <= 1e-9);
        // A right image tilted less: heights of the other sign.
        let swapped = PairMeta::new(view(9.76562e-8, tilt_r), view(9.76562e-8, tilt_l));
        let z = from_images.z_for_pair([10.0, 0.0], Some(&swapped)).unwrap();
        assert!((z + typed.z_um([10.0, 0.0])).abs() <= 1e-9, "{z}");
    }

    #[test]
    fn missing_or_contradicting_metadata_gives_no_height_and_says_why() {
        let cal = from_json(
            r#"{"model": "geometric", "pixel_size": "from_images", "vergence": "from_stage_tilt"}"#,
        )
        .unwrap();
        let no_height = |meta: Option<&PairMeta>| cal.z_for_pair([3.0, 0.0], meta).unwrap_err();
        assert!(no_height(None).contains("no metadata"));
        let no_tilt = PairMeta::new(
            ViewMeta {
                stage_tilt_rad: None,
                ..view(1e-7, 0.0)
            },
            view(1e-7, 0.1),
        );
        assert!(no_height(Some(&no_tilt)).contains("stage tilt"));
        let same_tilt = PairMeta::new(view(1e-7, 0.1), view(1e-7, 0.1));
        assert!(no_height(Some(&same_tilt)).contains("no vergence"));
        let zoomed = PairMeta::new(view(1e-7, 0.0), view(1.05e-7, 0.1));
        assert!(no_height(Some(&zoomed)).contains("magnification"));
        let no_pixel = PairMeta::new(
            ViewMeta {
                pixel_width_m: None,
                pixel_height_m: None,
                ..view(1e-7, 0.0)
            },
            view(1e-7, 0.1),
        );
        assert!(no_height(Some(&no_pixel)).contains("no pixel size"));
        // Non-square pixels: the length across the tilt axis (axis along y:
        // the width; along x: the height).
        let wide = PairMeta::new(
            ViewMeta {
                pixel_width_m: Some(2e-7),
                pixel_height_m: Some(1e-7),
                stage_tilt_rad: Some(0.0),
            },
            ViewMeta {
                pixel_width_m: Some(2e-7),
                pixel_height_m: Some(1e-7),
                stage_tilt_rad: Some(0.1),
            },
        );
        assert!((wide.pixel_size_um(90.0).unwrap() - 0.2).abs() < 1e-12);
        assert!((wide.pixel_size_um(0.0).unwrap() - 0.1).abs() < 1e-12);
    }

    #[test]
    fn a_geometric_calibration_needs_one_pixel_size_and_one_vergence() {
        for (text, expected) in [
            (
                r#"{"model": "geometric", "pixel_size_um": 0.5, "pixel_size": "from_images", "vergence_deg": 5}"#,
                "both pixel_size_um and pixel_size",
            ),
            (
                r#"{"model": "geometric", "vergence_deg": 5}"#,
                "missing pixel_size_um",
            ),
            (
                r#"{"model": "geometric", "pixel_size_um": 0.5}"#,
                "missing vergence_deg",
            ),
            (
                r#"{"model": "geometric", "pixel_size_um": 0.5, "vergence_deg": 5, "vergence": "from_stage_tilt"}"#,
                "both vergence_deg and vergence",
            ),
            (
                r#"{"model": "geometric", "pixel_size": "from_file", "vergence_deg": 5}"#,
                "from_images",
            ),
        ] {
            let e = from_json(text).unwrap_err();
            assert!(e.to_string().contains(expected), "{text}: {e}");
        }
    }

    #[test]
    fn a_magnification_change_is_warned_once_per_change() {
        let cal = build(CalibrationSpec::Geometric(GeometricSpec::new(0.1, 6.0))).unwrap();
        let at = |pixel_m: f64| PairMeta::new(view(pixel_m, 0.0), view(pixel_m, 0.1));
        let mut watch = MetaWatch::default();
        let warned: Vec<bool> = [1e-7, 1e-7, 2e-7, 2e-7, 2.001e-7, 1e-7, 1.004e-7, 3e-7]
            .iter()
            .map(|&p| watch.check(&cal, Some(&at(p))).is_some())
            .collect();
        assert_eq!(warned, [false, false, true, false, false, false, false, true]);
        let text = MetaWatch::default().check(&cal, Some(&at(2e-7)));
        assert!(
            text.as_ref()
                .is_some_and(|t| t.contains("0.200000 um") && t.contains("100.0%")),
            "{text:?}"
        );
        // Without metadata, or with a fit, nothing to compare.
        assert_eq!(MetaWatch::default().check(&cal, None), None);
    }

    #[test]
    fn height_errors_carry_the_slope_and_a_fit_s_own_error() {
        // Geometric: the disparity error through the slope, nothing else.
        let geometric = build(CalibrationSpec::Geometric(GeometricSpec::new(0.5, 10.0))).unwrap();
        let slope = geometric.coefficients()[1];
        let std = geometric.z_std_for_pair([3.0, 1.0], 0.1, None).unwrap();
        assert!((std - 0.1 * slope).abs() < 1e-12, "{std} against {}", 0.1 * slope);
        // A linear fit through scattered samples: the prediction error
        // s^2 (1 + 1/n + (d - mean)^2 / Sxx) adds to the slope's term.
        let d = [0.0, 1.0, 2.0, 3.0, 4.0];
        let z = [0.1, 2.0, 3.9, 6.2, 7.8];
        let fit = build(CalibrationSpec::Fit(FitSpec {
            degree: 1,
            samples: d.iter().zip(z).map(|(&d, z)| Sample::new(d, z)).collect(),
            tilt_axis_deg: 90.0,
        }))
        .unwrap();
        let (n, mean) = (5.0, 2.0);
        let sxx: f64 = d.iter().map(|x| (x - mean).powi(2)).sum();
        let s2 = fit.residual_rms_um().unwrap().powi(2) * n / (n - 2.0);
        let c1 = fit.coefficients()[1];
        for x in [-1.0, 2.0, 6.0] {
            let expected = ((c1 * 0.05).powi(2) + s2 * (1.0 + 1.0 / n + (x - mean).powi(2) / sxx)).sqrt();
            let got = fit.z_std_for_pair([x, 0.0], 0.05, None).unwrap();
            assert!((got - expected).abs() < 1e-9, "d {x}: {got} against {expected}");
        }
        // As many samples as coefficients: the fit's error is unknown.
        let exact = build(CalibrationSpec::Fit(FitSpec {
            degree: 1,
            samples: vec![Sample::new(0.0, 0.0), Sample::new(1.0, 2.0)],
            tilt_axis_deg: 90.0,
        }))
        .unwrap();
        assert_eq!(exact.z_std_for_pair([0.5, 0.0], 0.05, None), None);
        // A height difference in one pair: the intercept and the fit's
        // scatter cancel, the slope's uncertainty stays, s^2 (a - b)^2 / Sxx.
        for (a, b) in [(1.0, 3.0), (-1.0, 6.0), (2.0, 2.0)] {
            let (dz, std) = fit.dz_for_pair([a, 0.0], [b, 0.0], [0.05, 0.08], None).unwrap();
            assert!((dz - c1 * (a - b)).abs() < 1e-9, "{dz}");
            let expected =
                (c1.powi(2) * (0.05f64.powi(2) + 0.08f64.powi(2)) + s2 * (a - b).powi(2) / sxx).sqrt();
            assert!(
                (std.unwrap() - expected).abs() < 1e-9,
                "{a} - {b}: {std:?} against {expected}"
            );
        }
        let (_, std) = geometric
            .dz_for_pair([3.0, 1.0], [1.0, 1.0], [0.1, 0.1], None)
            .unwrap();
        assert!((std.unwrap() - 0.1 * slope * 2f64.sqrt()).abs() < 1e-12);
    }
}

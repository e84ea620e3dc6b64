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
//! A calibration read back from storage or a file is rebuilt from its
//! parameters, and the derived fields it carries must agree
//! ([`Calibration::check_derived`]).

mod meta;
mod poly;
#[cfg(test)]
mod tests;

pub use meta::{MetaWatch, PairMeta, ViewMeta, PIXEL_SIZE_TOLERANCE};

use poly::{count_distinct, fit_polynomial, CenteredPoly, FitVariance};

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
            Self::NoSuchSample { .. } => "sample_not_found",
        }
    }
}

/// One calibration measurement: the disparity across the tilt axis observed
/// with the object at a known height.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Sample {
    /// Disparity component across the tilt axis, pixels (see [`axis_component`]).
    pub disparity_px: f64,
    /// Known height, micrometres.
    pub z_um: f64,
    /// The session whose tracked pair gave the disparity (absent: typed in).
    pub session_id: Option<String>,
    /// That pair's frame index in the session.
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
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct GeometricSpec {
    /// Length of one pixel at the specimen, micrometres per pixel (> 0).
    pub pixel_size_um: Option<f64>,
    /// The pixel size from each pair's images instead.
    pub pixel_size: Option<PixelSizeSource>,
    /// Total vergence angle between the two views, degrees (0 < vergence_deg <= 90).
    pub vergence_deg: Option<f64>,
    /// The vergence from each pair's images instead.
    pub vergence: Option<VergenceSource>,
    /// Disparity across the tilt axis at the reference height z = 0, pixels.
    pub reference_disparity_px: f64,
    /// Direction of the tilt axis in the image, degrees from +x towards +y.
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
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "snake_case"))]
pub enum PixelSizeSource {
    /// The pixel size in each pair's image metadata (both images must carry
    /// it and agree within 1%).
    FromImages,
}

/// Where a geometric calibration takes the vergence from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "snake_case"))]
pub enum VergenceSource {
    /// The right image's stage tilt minus the left's (a stage-tilt pair).
    FromStageTilt,
}

/// Parameters of a fitted calibration.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct FitSpec {
    /// Polynomial degree, 1 (linear) or 2 (quadratic).
    pub degree: u8,
    /// The measurements to fit.
    pub samples: Vec<Sample>,
    /// Direction of the tilt axis in the image, degrees from +x towards +y; used
    /// when the calibration is applied to 2-D disparities.
    pub tilt_axis_deg: f64,
}

/// What a user submits to create a calibration; JSON
/// `{"model": "geometric", "pixel_size_um": .., "vergence_deg": .., ...}` or
/// `{"model": "fit", "degree": 1, "samples": [{"disparity_px": .., "z_um": ..}, ..]}`.
/// Unknown fields are refused.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(tag = "model", rename_all = "snake_case"))]
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
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
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
#[derive(Clone, Debug, PartialEq)]
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

/// Checks a tilt axis given explicitly (a parameter, a flag) against the
/// calibration's: z is a function of the disparity across the calibration's
/// axis, so a different one would give numbers that look valid and are not.
/// Angles that differ by a multiple of 360 degrees are one axis. The error
/// names both values.
pub fn same_tilt_axis(explicit_deg: f64, calibration_deg: f64) -> Result<(), String> {
    if (explicit_deg - calibration_deg).rem_euclid(360.0) == 0.0 {
        return Ok(());
    }
    Err(format!(
        "tilt_axis_deg {explicit_deg} disagrees with the calibration's tilt axis {calibration_deg} deg \
         (expected the same axis, or tilt_axis_deg left out to use the calibration's)"
    ))
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

    /// Checks fields derived from this calibration's parameters that a
    /// stored or typed copy carries (each optional): `coefficients`, and a
    /// fit's `residual_rms_um` and `r_squared` must agree with the ones
    /// recomputed, so that a hand-edited coefficient is refused instead of
    /// silently ignored.
    pub fn check_derived(
        &self,
        coefficients: Option<&[f64]>,
        residual_rms_um: Option<f64>,
        r_squared: Option<f64>,
    ) -> Result<(), CalibError> {
        if let Some(stored) = coefficients {
            let scale = self.coefficients.iter().fold(1.0_f64, |m, c| m.max(c.abs()));
            let agrees = stored.len() == self.coefficients.len()
                && stored
                    .iter()
                    .zip(&self.coefficients)
                    .all(|(a, b)| close(*a, *b, 1e-12 * scale));
            if !agrees {
                return Err(CalibError::Invalid(format!(
                    "coefficients {stored:?} do not match the parameters (recomputed {:?}); remove \
                     `coefficients` to have them recomputed",
                    self.coefficients
                )));
            }
        }
        if let Some(stats) = self.stats {
            let z_scale = 1.0 + self.samples().iter().fold(0.0_f64, |m, s| m.max(s.z_um.abs()));
            if let Some(stored) = residual_rms_um {
                if !close(stored, stats.residual_rms_um, 1e-9 * z_scale) {
                    return Err(CalibError::Invalid(format!(
                        "residual_rms_um {stored} does not match the samples (recomputed {})",
                        stats.residual_rms_um
                    )));
                }
            }
            if let Some(stored) = r_squared {
                if !close(stored, stats.r_squared, 1e-9) {
                    return Err(CalibError::Invalid(format!(
                        "r_squared {stored} does not match the samples (recomputed {})",
                        stats.r_squared
                    )));
                }
            }
        }
        Ok(())
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
                let meta = meta.ok_or_else(none)?;
                if let Some(why) = meta.mixed_beams() {
                    return Err(why);
                }
                let dt = meta
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
    /// and `h` the leverage of d. A fit with no more samples than
    /// coefficients has no known error of its own: the slope's term alone
    /// (see [`Calibration::fit_error_unknown`]). `None` when there is no
    /// height.
    pub fn z_std_for_pair(
        &self,
        disparity_px: [f64; 2],
        std_px: f64,
        meta: Option<&PairMeta>,
    ) -> Option<f64> {
        let slope = self.slope_for_pair(disparity_px, meta)?;
        let mut variance = (slope * std_px).powi(2);
        if let Some(Some(fit)) = self.fit_variance() {
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
            if let Some(Some(fit)) = self.fit_variance() {
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

    /// Whether this is a fit with no more samples than coefficients (two
    /// for a straight line): its own prediction error is then unknown, and
    /// the standard errors of its heights count the disparity's alone.
    pub fn fit_error_unknown(&self) -> bool {
        self.fit_variance().is_none()
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

/// `a` and `b` agree to a relative 1e-6 or within `abs_tol`.
fn close(a: f64, b: f64, abs_tol: f64) -> bool {
    let diff = (a - b).abs();
    diff <= abs_tol || diff <= 1e-6 * a.abs().max(b.abs())
}

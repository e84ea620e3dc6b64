//! Calibrations on the wire, in storage and in the file the command line
//! reads: the service's own types, made from and into the algorithms'
//! [`semdepth_core::calib::Calibration`].

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use semdepth_core::calib::{self, build, CalibError, Calibration, CalibrationSpec, FitSpec, GeometricSpec};

/// Top-level keys the service adds around a calibration (`id`, `name`,
/// timestamps): [`read_calibration`] leaves them out, so that a calibration
/// saved from `GET /v1/calibrations/{id}` reads as a file.
pub const SERVICE_METADATA_FIELDS: [&str; 4] = ["id", "name", "created_at", "updated_at"];

/// One calibration measurement: the disparity across the tilt axis observed
/// with the object at a known height.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Sample {
    /// Disparity across the tilt axis, pixels; -1e6..=1e6.
    #[schema(minimum = -1e6, maximum = 1e6)]
    pub disparity_px: f64,
    /// Known height, micrometres; -1e6..=1e6.
    #[schema(minimum = -1e6, maximum = 1e6)]
    pub z_um: f64,
    /// The session whose tracked pair gave the disparity (absent: typed in).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub session_id: Option<String>,
    /// That pair's frame index in the session.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame: Option<u64>,
}

/// Where a geometric calibration takes the pixel size from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum PixelSizeSource {
    /// The pixel size in each pair's image metadata (both images must carry
    /// it and agree within 1%).
    FromImages,
}

/// Where a geometric calibration takes the vergence from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, ToSchema)]
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

fn default_tilt_axis_deg() -> f64 {
    calib::DEFAULT_TILT_AXIS_DEG
}

fn default_fit_degree() -> u8 {
    calib::DEFAULT_FIT_DEGREE
}

/// A calibration's parameters, and the fields derived from them: the body
/// storage keeps, and the file `semdepth process --calibration` reads. The
/// derived fields are optional on input: a calibration is always rebuilt
/// from its parameters, and derived fields that are given must agree (a
/// hand-edited coefficient is refused, not ignored).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "snake_case", deny_unknown_fields)]
pub enum CalibrationBody {
    /// Eucentric tilt geometry.
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
    /// Least-squares polynomial through samples.
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

/// Why a calibration file or stored body could not be read.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationReadError {
    /// The JSON text is malformed or has the wrong shape (unknown or missing fields).
    #[error("invalid calibration JSON: {0}")]
    Json(String),
    /// The parameters do not make a calibration, or derived fields disagree.
    #[error(transparent)]
    Calibration(#[from] CalibError),
}

impl CalibrationReadError {
    /// A stable snake_case code for APIs and logs.
    pub fn code(&self) -> &'static str {
        match self {
            Self::Json(_) => "invalid_calibration_json",
            Self::Calibration(e) => e.code(),
        }
    }
}

/// Reads a calibration from JSON text: the parameters alone (what a user
/// submits) or a [`CalibrationBody`] with its derived fields; the keys in
/// [`SERVICE_METADATA_FIELDS`] are left out at the top level.
pub fn read_calibration(text: &str) -> Result<Calibration, CalibrationReadError> {
    let json = |e: serde_json::Error| CalibrationReadError::Json(e.to_string());
    let mut value: serde_json::Value = serde_json::from_str(text).map_err(json)?;
    let Some(object) = value.as_object_mut() else {
        return Err(CalibrationReadError::Json(
            "expected a JSON object with \"model\": \"geometric\" or \"fit\"".into(),
        ));
    };
    for key in SERVICE_METADATA_FIELDS {
        object.remove(key);
    }
    let body: CalibrationBody = serde_json::from_value(value).map_err(json)?;
    Ok(Calibration::try_from(body)?)
}

impl From<Sample> for calib::Sample {
    fn from(s: Sample) -> Self {
        Self {
            disparity_px: s.disparity_px,
            z_um: s.z_um,
            session_id: s.session_id,
            frame: s.frame,
        }
    }
}

impl From<calib::Sample> for Sample {
    fn from(s: calib::Sample) -> Self {
        Self {
            disparity_px: s.disparity_px,
            z_um: s.z_um,
            session_id: s.session_id,
            frame: s.frame,
        }
    }
}

impl From<PixelSizeSource> for calib::PixelSizeSource {
    fn from(_: PixelSizeSource) -> Self {
        Self::FromImages
    }
}

impl From<calib::PixelSizeSource> for PixelSizeSource {
    fn from(_: calib::PixelSizeSource) -> Self {
        Self::FromImages
    }
}

impl From<VergenceSource> for calib::VergenceSource {
    fn from(_: VergenceSource) -> Self {
        Self::FromStageTilt
    }
}

impl From<calib::VergenceSource> for VergenceSource {
    fn from(_: calib::VergenceSource) -> Self {
        Self::FromStageTilt
    }
}

impl From<&Calibration> for CalibrationBody {
    fn from(c: &Calibration) -> Self {
        match c.spec() {
            CalibrationSpec::Geometric(g) => Self::Geometric {
                pixel_size_um: g.pixel_size_um,
                pixel_size: g.pixel_size.map(Into::into),
                vergence_deg: g.vergence_deg,
                vergence: g.vergence.map(Into::into),
                reference_disparity_px: g.reference_disparity_px,
                tilt_axis_deg: g.tilt_axis_deg,
                // Scaled per pair from the images: none to store.
                coefficients: (!g.from_images()).then(|| c.coefficients().to_vec()),
            },
            CalibrationSpec::Fit(f) => Self::Fit {
                degree: f.degree,
                samples: f.samples.iter().cloned().map(Into::into).collect(),
                tilt_axis_deg: f.tilt_axis_deg,
                coefficients: Some(c.coefficients().to_vec()),
                residual_rms_um: c.residual_rms_um(),
                r_squared: c.r_squared(),
            },
        }
    }
}

impl Serialize for CalibrationStored<'_> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        CalibrationBody::from(self.0).serialize(s)
    }
}

/// A calibration written as its [`CalibrationBody`].
pub struct CalibrationStored<'a>(pub &'a Calibration);

impl TryFrom<CalibrationBody> for Calibration {
    type Error = CalibError;

    fn try_from(body: CalibrationBody) -> Result<Self, CalibError> {
        let (spec, coefficients, rms, r2) = match body {
            CalibrationBody::Geometric {
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
                    pixel_size: pixel_size.map(Into::into),
                    vergence_deg,
                    vergence: vergence.map(Into::into),
                    reference_disparity_px,
                    tilt_axis_deg,
                }),
                coefficients,
                None,
                None,
            ),
            CalibrationBody::Fit {
                degree,
                samples,
                tilt_axis_deg,
                coefficients,
                residual_rms_um,
                r_squared,
            } => (
                CalibrationSpec::Fit(FitSpec {
                    degree,
                    samples: samples.into_iter().map(Into::into).collect(),
                    tilt_axis_deg,
                }),
                coefficients,
                residual_rms_um,
                r_squared,
            ),
        };
        let cal = build(spec)?;
        cal.check_derived(coefficients.as_deref(), rms, r2)?;
        Ok(cal)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn geometric(pixel_size_um: f64, vergence_deg: f64, d0: f64, tilt: f64) -> Calibration {
        build(CalibrationSpec::Geometric(GeometricSpec {
            reference_disparity_px: d0,
            tilt_axis_deg: tilt,
            ..GeometricSpec::new(pixel_size_um, vergence_deg)
        }))
        .unwrap()
    }

    fn fit_spec(degree: u8, samples: Vec<calib::Sample>) -> CalibrationSpec {
        CalibrationSpec::Fit(FitSpec {
            degree,
            samples,
            tilt_axis_deg: 90.0,
        })
    }

    fn samples_of(d: &[f64], f: impl Fn(f64) -> f64) -> Vec<calib::Sample> {
        d.iter().map(|&x| calib::Sample::new(x, f(x))).collect()
    }

    #[test]
    fn json_round_trip_of_spec_and_calibration() {
        // Parameters alone, with defaults.
        let cal =
            read_calibration(r#"{"model": "geometric", "pixel_size_um": 0.5, "vergence_deg": 6.0}"#).unwrap();
        assert_eq!(
            cal.spec(),
            &CalibrationSpec::Geometric(GeometricSpec {
                pixel_size_um: Some(0.5),
                pixel_size: None,
                vergence_deg: Some(6.0),
                vergence: None,
                reference_disparity_px: 0.0,
                tilt_axis_deg: 90.0
            })
        );
        let fit = read_calibration(
            r#"{"model": "fit", "samples": [{"disparity_px": 1.2, "z_um": 0.0}, {"disparity_px": 2.2, "z_um": 50.0}]}"#,
        )
        .unwrap();
        let CalibrationSpec::Fit(f) = fit.spec() else {
            panic!()
        };
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
            let text = serde_json::to_string(&CalibrationBody::from(&cal)).unwrap();
            let v: serde_json::Value = serde_json::from_str(&text).unwrap();
            assert_eq!(v["model"], spec.model_name());
            assert!(v["coefficients"].is_array() && v["tilt_axis_deg"].is_number());
            assert_eq!(v.get("r_squared").is_some(), cal.is_fit());
            assert_eq!(v.get("residual_rms_um").is_some(), cal.is_fit());
            assert_eq!(read_calibration(&text).unwrap(), cal);
            // The parameters alone read too, and the service's metadata is left out.
            let mut bare = v.clone();
            for derived in ["coefficients", "residual_rms_um", "r_squared"] {
                bare.as_object_mut().unwrap().remove(derived);
            }
            assert_eq!(read_calibration(&bare.to_string()).unwrap(), cal);
            let mut with_meta = v.clone();
            with_meta["id"] = "cal_1".into();
            with_meta["name"] = "stage A".into();
            with_meta["created_at"] = "2024-01-01T00:00:00Z".into();
            assert_eq!(read_calibration(&with_meta.to_string()).unwrap(), cal);
        }
        let fit_json = serde_json::to_value(CalibrationBody::from(
            &build(fit_spec(1, samples_of(&[0.0, 1.0, 2.0], |x| x))).unwrap(),
        ))
        .unwrap();
        assert_eq!(fit_json["samples"][1]["disparity_px"], 1.0);
        assert_eq!(fit_json["samples"][1]["z_um"], 1.0);
        assert_eq!(fit_json["degree"], 1);
    }

    #[test]
    fn json_refuses_typos_and_tampering() {
        let err = read_calibration(r#"{"model": "geometric", "pixel_size": 0.5, "vergence_deg": 6.0}"#)
            .unwrap_err();
        assert_eq!(err.code(), "invalid_calibration_json");
        assert!(err.to_string().contains("pixel_size"), "{err}");
        assert!(serde_json::from_str::<CalibrationBody>(
            r#"{"model": "fit", "samples": [{"disparity_px": 1, "z": 0}]}"#
        )
        .is_err());
        assert!(serde_json::from_str::<CalibrationBody>(r#"{"model": "spline", "samples": []}"#).is_err());
        assert_eq!(
            read_calibration("[1, 2]").unwrap_err().code(),
            "invalid_calibration_json"
        );
        assert_eq!(
            read_calibration("{").unwrap_err().code(),
            "invalid_calibration_json"
        );
        // Validation errors keep their own codes through from_json.
        let err = read_calibration(r#"{"model": "geometric", "pixel_size_um": 0.5, "vergence_deg": 0}"#)
            .unwrap_err();
        assert_eq!(
            err.to_string(),
            "invalid vergence_deg 0 (expected 0 < vergence_deg <= 90)"
        );
        let one =
            read_calibration(r#"{"model": "fit", "degree": 2, "samples": [{"disparity_px": 1, "z_um": 0}]}"#)
                .unwrap();
        assert!(one.pending().is_some());

        // Edited coefficients or statistics are refused, not silently replaced.
        let cal = geometric(1.0, 10.0, 0.0, 90.0);
        let mut v = serde_json::to_value(CalibrationBody::from(&cal)).unwrap();
        v["coefficients"][1] = 6.0.into();
        let err = read_calibration(&v.to_string()).unwrap_err();
        assert_eq!(err.code(), "invalid_calibration");
        assert!(err.to_string().contains("coefficients"), "{err}");
        let fit = build(fit_spec(1, samples_of(&[0.0, 1.0, 2.0], |x| x * x))).unwrap();
        let mut v = serde_json::to_value(CalibrationBody::from(&fit)).unwrap();
        v["r_squared"] = 0.5.into();
        assert!(read_calibration(&v.to_string())
            .unwrap_err()
            .to_string()
            .contains("r_squared"));
        // A geometric calibration has no fit statistics.
        let mut v = serde_json::to_value(CalibrationBody::from(&cal)).unwrap();
        v["r_squared"] = 1.0.into();
        assert_eq!(
            read_calibration(&v.to_string()).unwrap_err().code(),
            "invalid_calibration_json"
        );
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
            let e = read_calibration(text).unwrap_err();
            assert!(e.to_string().contains(expected), "{text}: {e}");
        }
    }

    #[test]
    fn a_calibration_from_the_images_is_stored_without_coefficients() {
        let from_images = read_calibration(
            r#"{"model": "geometric", "pixel_size": "from_images", "vergence": "from_stage_tilt",
                "reference_disparity_px": 1.5, "tilt_axis_deg": 90}"#,
        )
        .unwrap();
        assert!(from_images.needs_images());
        let text = serde_json::to_string(&CalibrationBody::from(&from_images)).unwrap();
        assert!(!text.contains("coefficients"), "{text}");
        assert_eq!(read_calibration(&text).unwrap(), from_images);
    }
}

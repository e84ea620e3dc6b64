//! What a pair's images say about how they were taken, as far as depth
//! needs it: each view's pixel size and stage tilt, and a watch that warns
//! once per change of magnification.

use super::{sin_cos_deg, Calibration, CalibrationSpec};
use crate::meta::Beam;

/// What a pair's two images say about how they were taken (see
/// [`crate::meta`]), as far as depth needs it.
#[derive(Clone, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct PairMeta {
    /// The left image's.
    pub left: ViewMeta,
    /// The right image's.
    pub right: ViewMeta,
    /// Right stage tilt minus left, radians (null unless both are known).
    pub stage_tilt_difference_rad: Option<f64>,
}

/// One image's pixel size, stage tilt and beam.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct ViewMeta {
    /// Width of one pixel at the specimen, metres.
    pub pixel_width_m: Option<f64>,
    /// Height of one pixel at the specimen, metres.
    pub pixel_height_m: Option<f64>,
    /// Stage tilt, radians.
    pub stage_tilt_rad: Option<f64>,
    /// The beam that took the image, where known.
    pub beam: Option<Beam>,
}

impl ViewMeta {
    /// The fields of `meta` that depth needs.
    pub fn of(meta: &crate::meta::ImageMeta) -> Self {
        Self {
            pixel_width_m: meta.pixel_width_m,
            pixel_height_m: meta.pixel_height_m,
            stage_tilt_rad: meta.stage_tilt_rad,
            beam: meta.beam,
        }
    }

    pub(super) fn is_empty(&self) -> bool {
        self.pixel_width_m.is_none()
            && self.pixel_height_m.is_none()
            && self.stage_tilt_rad.is_none()
            && self.beam.is_none()
    }

    /// Length of one pixel along the disparity direction across a tilt axis
    /// at `tilt_axis_deg` (see [`axis_component`]), metres; a missing
    /// height is taken as the width and vice versa (square pixels).
    pub(super) fn pixel_across_axis_m(&self, tilt_axis_deg: f64) -> Option<f64> {
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

    /// Why the stage tilt difference is not the angle between the views:
    /// one image is the electron beam's and the other the ion beam's (the
    /// two columns stand at an angle of their own). `None` when both
    /// beams are the same or one is unknown.
    pub fn mixed_beams(&self) -> Option<String> {
        match (self.left.beam, self.right.beam) {
            (Some(l), Some(r)) if l != r => Some(format!(
                "the left image is the {} beam's and the right the {} beam's: their stage tilt difference is not the angle between the views",
                l.name(),
                r.name()
            )),
            _ => None,
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

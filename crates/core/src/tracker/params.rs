//! The tracker's parameters, their defaults and their validation.

use crate::energy::EnergyParams;
use crate::fit::{FreeFitParams, RigidParams};
use crate::init::InitParams;
use crate::occlusion::OcclusionParams;
use crate::prefilter;

/// How many times its first pair's excess over
/// [`TrackerParams::max_disparity_std_px`] an object's disparity standard
/// error may exceed that limit before the pair is `uncertain`: an object
/// whose own outline gives no better (a real grain whose outline changes
/// with the tilt) keeps its numbers, while one that lost most of what fixed
/// its position says so. An object first measured within the limit is held
/// to the limit.
pub const STD_GROWTH: f64 = 4.0;

/// All tracking parameters, with documented defaults.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
pub struct TrackerParams {
    /// Automatic initialisation on the first pair.
    pub init: InitParams,
    /// The energy (lambda, k, window margin).
    pub energy: EnergyParams,
    /// The free fit on the first left image.
    pub free: FreeFitParams,
    /// The rigid fits.
    pub rigid: RigidParams,
    /// Detection of partial occlusion and the fit that ignores it.
    pub occlusion: OcclusionParams,
    /// Direction of the beam's tilt axis in the image, degrees from +x
    /// towards +y. Default 90 (the image y axis): disparity is then along x.
    /// A service session with a calibration measures across the
    /// calibration's axis instead, the one its `z_um` uses.
    pub tilt_axis_deg: f64,
    /// On the first pair, how far (pixels, along the disparity axis) the
    /// right view is searched from the left position; a fit that ends more
    /// than 8 px past it (or across the line) is no finding. Default 64.
    pub max_disparity_px: f64,
    /// Vertex spacing of the rigid template, pixels; default null: the free
    /// fit's own outline (vertices `free.spacing_px` apart) is the template.
    /// Resampling more densely only adds vertices on its edges, which makes
    /// every step dearer for no accuracy; more coarsely cuts its corners.
    pub template_spacing_px: Option<f64>,
    /// The pair is lost when the contrast in either image falls below this
    /// fraction of the contrast at initialisation. Default 0.3.
    pub min_contrast_ratio: f64,
    /// Let the right contour rotate independently of the left one (the paper
    /// does; `angle_diff_rad` is then measured). Default false: a tilt about
    /// an in-plane axis does not rotate the object in the image, and the
    /// extra freedom absorbs the outline's change of shape with tilt (on the
    /// real quartz pairs it moved the disparity 1.4 px away from the
    /// silhouettes' shift). When false the right contour keeps the left one's rotation and
    /// `angle_diff_rad` is 0.
    pub right_rotation: bool,
    /// After the first pair, let the right contour move only across the
    /// tilt axis from its prediction (the left pose plus the last
    /// disparity): a tilt shifts the object along its epipolar line, so the
    /// along-axis offset found on the first pair (a few pixels on the real
    /// quartz pairs) is kept. Default true: the freedom it removes only lets
    /// weak edges and slender objects slide. Set false when the stage
    /// drifts along the tilt axis between the two images of a pair.
    pub epipolar: bool,
    /// Gaussian smoothing (sigma, pixels) of both images before the fits,
    /// which restores their precision on blurred edges under white noise.
    /// Default null: chosen at initialisation from the object's fitted
    /// edge width (a defocus blur of 1.5 px or more) or its bright edge
    /// rim (a dark object), and only where the noise around it is white;
    /// otherwise none. 0: never smooth.
    pub prefilter_sigma_px: Option<f64>,
    /// A pair whose fits' own disparity standard error (`disparity_std_px`
    /// before a run's scatter scales it) exceeds this many pixels is
    /// reported `lost` with reason `uncertain`, without numbers; tracking
    /// goes on from its poses. Default 0.4: a `tracked`
    /// disparity is then within 1 px of the truth at 2.5 standard errors.
    /// Such pairs are the ones where too little of an occluded outline is
    /// left to fix the position. An object whose first pair (after a loss,
    /// the lower of the first initialisation's and the fresh one's) already
    /// exceeded the limit may exceed it by [`STD_GROWTH`] times as much.
    pub max_disparity_std_px: f64,
}

impl Default for TrackerParams {
    fn default() -> Self {
        Self {
            init: InitParams::default(),
            energy: EnergyParams::default(),
            free: FreeFitParams::default(),
            rigid: RigidParams::default(),
            occlusion: OcclusionParams::default(),
            tilt_axis_deg: 90.0,
            max_disparity_px: 64.0,
            template_spacing_px: None,
            min_contrast_ratio: 0.3,
            right_rotation: false,
            epipolar: true,
            prefilter_sigma_px: None,
            max_disparity_std_px: 0.4,
        }
    }
}

impl TrackerParams {
    /// The standard error above which a pair is `uncertain`, for an object
    /// whose first pair's was `first` px (see
    /// [`Self::max_disparity_std_px`]): the limit, raised for an object
    /// above it to its excess over the limit grown [`STD_GROWTH`] times
    /// (quartz 01-02, first 1.31 px: 4.0 px).
    pub fn std_limit(&self, first: f64) -> f64 {
        let limit = self.max_disparity_std_px;
        limit.max(limit + STD_GROWTH * (first - limit))
    }

    /// Checks every part; the message names the field and what was expected.
    pub fn validate(&self) -> Result<(), String> {
        self.init.validate().map_err(|e| format!("init: {e}"))?;
        self.energy
            .validate()
            .map_err(|e| format!("tracker.energy: {e}"))?;
        self.free.validate().map_err(|e| format!("tracker.free: {e}"))?;
        self.rigid.validate().map_err(|e| format!("tracker.rigid: {e}"))?;
        self.occlusion
            .validate()
            .map_err(|e| format!("tracker.occlusion: {e}"))?;
        if !(self.tilt_axis_deg.is_finite() && (-360.0..=360.0).contains(&self.tilt_axis_deg)) {
            return Err(format!(
                "invalid tilt_axis_deg {} (expected -360..=360)",
                self.tilt_axis_deg
            ));
        }
        if !(self.max_disparity_px.is_finite() && (0.0..=4096.0).contains(&self.max_disparity_px)) {
            return Err(format!(
                "invalid max_disparity_px {} (expected 0..=4096)",
                self.max_disparity_px
            ));
        }
        if let Some(spacing) = self.template_spacing_px {
            if !(spacing.is_finite() && (0.5..=20.0).contains(&spacing)) {
                return Err(format!(
                    "invalid template_spacing_px {spacing} (expected 0.5..=20, or null for the free fit's outline)"
                ));
            }
        }
        if !(self.max_disparity_std_px.is_finite() && (0.01..=1000.0).contains(&self.max_disparity_std_px)) {
            return Err(format!(
                "invalid max_disparity_std_px {} (expected 0.01..=1000)",
                self.max_disparity_std_px
            ));
        }
        if !(self.min_contrast_ratio.is_finite() && (0.0..=1.0).contains(&self.min_contrast_ratio)) {
            return Err(format!(
                "invalid min_contrast_ratio {} (expected 0..=1)",
                self.min_contrast_ratio
            ));
        }
        if let Some(sigma) = self.prefilter_sigma_px {
            if !(sigma.is_finite() && (0.0..=prefilter::MAX_SIGMA_PX).contains(&sigma)) {
                return Err(format!(
                    "invalid prefilter_sigma_px {sigma} (expected 0..=4, or null to follow the edge's width)"
                ));
            }
        }
        Ok(())
    }
}

//! What a pair yields: the contours, the disparity, its standard error and
//! the status, or the reason it is lost.

use crate::calib::{axis_component, Calibration, MetaWatch, PairMeta};
use crate::fit::{place, RigidTemplate};
use crate::geometry::{Point, Polygon};
use crate::imageio::ImageInputError;
use crate::meta::ImageMeta;
use crate::region::PixelRect;

use super::state::TrackerState;
use super::view_fit::ImageFit;
use super::StereoTracker;

/// Added in quadrature to the two views' standard errors: what the noise
/// model leaves out (the rigid template's mismatch with the outline,
/// sub-pixel discretisation), pixels.
pub const DISPARITY_STD_FLOOR_PX: f64 = 0.02;

/// Reason of a tracked pair whose object was found again by its template
/// after a loss.
pub const REACQUIRED: &str = "reacquired";

/// Reason of an initialised pair whose object, lost and not found by its
/// template after a change of the frame's tone curve, was initialised
/// afresh where it was last seen.
pub const FOUND_AFRESH: &str = "found afresh where it was last seen, after a change of tone";

/// Reason of a pair whose disparity is too uncertain to report (see
/// [`TrackerParams::max_disparity_std_px`]); the reason goes on after a colon.
pub const UNCERTAIN: &str = "uncertain";

/// How the reason of an `uncertain` pair ends: the tracker goes on from
/// its poses (unless a run of such pairs moved too far, see
/// [`MAX_UNVERIFIED_MOVE_PX`]).
pub(super) const GOES_ON: &str = "; tracking goes on";

/// Outcome of one pair.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "snake_case"))]
pub enum Status {
    /// The object was (re)found and fitted on this pair.
    Initialised,
    /// Both contours followed the object.
    Tracked,
    /// No trustworthy measurement; `reason` says why.
    Lost,
}

impl Status {
    /// The snake_case name used in JSON and CSV.
    pub fn name(self) -> &'static str {
        match self {
            Status::Initialised => "initialised",
            Status::Tracked => "tracked",
            Status::Lost => "lost",
        }
    }
}

/// The contour in one image of a pair.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct ImageResult {
    /// Contour vertices, pixels.
    pub contour: Vec<Point>,
    /// Area centroid of the contour, pixels.
    pub centroid: Point,
    /// Orientation of the contour's principal axis, radians in (-pi/2, pi/2].
    pub angle_rad: f64,
    /// Energy of the contour (lower is better).
    pub energy: f64,
    /// Michelson contrast of inside against the background window, -1..=1
    /// (over the visible sectors' bands when part of the outline is occluded).
    pub contrast: f64,
    /// Fraction of the outline found occluded (0 when fully visible).
    pub occluded_fraction: f64,
}

/// The measurement of one stereo pair.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct PairResult {
    /// Index of the pair in the sequence, from 0.
    pub frame: u64,
    /// What happened.
    pub status: Status,
    /// Why the pair is lost, or `reacquired` on a tracked pair whose object
    /// was found again by its template after a loss, or [`FOUND_AFRESH`] on
    /// an initialised pair whose object was initialised afresh where it was
    /// last seen after a change of tone; null otherwise.
    pub reason: Option<String>,
    /// The left contour (null when nothing was found).
    pub left: Option<ImageResult>,
    /// The right contour.
    pub right: Option<ImageResult>,
    /// Right minus left centroid, pixels.
    pub disparity_px: Option<Point>,
    /// Component of the disparity across the tilt axis, pixels.
    pub disparity_axis_px: Option<f64>,
    /// `disparity_axis_px` minus its value on the first pair of the session.
    pub relative_disparity_axis_px: Option<f64>,
    /// Rotation of the right contour minus that of the left, radians.
    pub angle_diff_rad: Option<f64>,
    /// Height from the calibration, micrometres; null without one.
    pub z_um: Option<f64>,
    /// Standard error of `disparity_axis_px`, pixels: the fits' own (see
    /// [`crate::uncertainty`]), scaled up once a run of pairs shows their
    /// disparities scatter more than that (see [`crate::scatter`]); null
    /// when the pair is not tracked.
    #[cfg_attr(feature = "serde", serde(default))]
    pub disparity_std_px: Option<f64>,
    /// Standard error of `z_um`, micrometres: `disparity_std_px` through the
    /// calibration's slope, and a fitted calibration's own prediction
    /// error (unknown for a fit with as many samples as coefficients:
    /// [`FIT_ERROR_UNKNOWN`] then warns); null without `z_um`.
    #[cfg_attr(feature = "serde", serde(default))]
    pub z_std_um: Option<f64>,
    /// What the two images' own metadata say (pixel size, stage tilt and
    /// their difference); absent when neither carries any.
    #[cfg_attr(feature = "serde", serde(default, skip_serializing_if = "Option::is_none"))]
    pub metadata: Option<PairMeta>,
    /// What in the images' metadata could not be read, contradicts the
    /// calibration, or leaves a tracked pair without z; absent when none.
    #[cfg_attr(feature = "serde", serde(default, skip_serializing_if = "Vec::is_empty"))]
    pub warnings: Vec<String>,
}

impl PairResult {
    /// Marks the pair lost for `reason`: no disparity, z or uncertainty is
    /// left for a script to use; the contours stay, for display.
    pub fn mark_lost(&mut self, reason: String) {
        self.status = Status::Lost;
        self.reason = Some(reason);
        self.disparity_px = None;
        self.disparity_axis_px = None;
        self.relative_disparity_axis_px = None;
        self.angle_diff_rad = None;
        self.disparity_std_px = None;
        self.z_um = None;
        self.z_std_um = None;
    }

    /// Records the two images' metadata (see [`crate::meta`]) and what
    /// could not be read of it.
    pub fn apply_metadata(&mut self, left: &ImageMeta, right: &ImageMeta) {
        self.metadata = PairMeta::of(left, right);
        for (side, meta) in [("left", left), ("right", right)] {
            self.warnings
                .extend(meta.warnings.iter().map(|w| format!("{side} image: {w}")));
        }
    }

    /// Fills `z_um` from a calibration and the pair's metadata (leaves it
    /// null for lost pairs, and for tracked ones whose metadata the
    /// calibration needs but cannot use: a warning then says why). `watch`
    /// carries the session's last pixel size, to warn once per
    /// magnification change that contradicts a typed calibration.
    pub fn apply_calibration(&mut self, calibration: Option<&Calibration>, watch: &mut MetaWatch) {
        self.z_um = None;
        self.z_std_um = None;
        let Some(c) = calibration else {
            return;
        };
        if let Some(w) = watch.check(c, self.metadata.as_ref()) {
            self.warnings.push(w);
        }
        let (Some(d), Status::Initialised | Status::Tracked) = (self.disparity_px, self.status) else {
            return;
        };
        match c.z_for_pair(d, self.metadata.as_ref()) {
            Ok(z) => {
                self.z_um = Some(z);
                self.z_std_um = self
                    .disparity_std_px
                    .and_then(|std| c.z_std_for_pair(d, std, self.metadata.as_ref()));
                if self.z_std_um.is_some() && c.fit_error_unknown() {
                    self.warnings.push(FIT_ERROR_UNKNOWN.into());
                }
            }
            Err(why) => self.warnings.push(format!("no z: {why}")),
        }
    }
}

/// The warning on a height from a fit with as many samples as
/// coefficients: its standard error counts the disparity's alone.
pub const FIT_ERROR_UNKNOWN: &str = "z_std_um counts the disparity's standard error only: the calibration has no more samples than coefficients, so its own error is unknown (add samples)";

/// Why a pair could not be processed at all (as opposed to a lost object).
#[derive(Debug, thiserror::Error)]
pub enum TrackError {
    /// The two images differ in size (or another input problem).
    #[error(transparent)]
    Input(#[from] ImageInputError),
    /// A hint of the initialisation (`init.roi`, `init.point`) does not fit
    /// the pair's images; the pair is not counted.
    #[error("{0}")]
    Hint(crate::init::InitError),
    /// The pair's size differs from the session's earlier pairs.
    #[error("pair is {width}x{height} but the session's pairs are {expected_width}x{expected_height} (expected the same size throughout; reset the session to change it)")]
    SizeChanged {
        width: u32,
        height: u32,
        expected_width: u32,
        expected_height: u32,
    },
}

impl PairResult {
    /// Pair `frame`, lost for `reason`: no contour, disparity, z or
    /// uncertainty.
    pub fn lost(frame: u64, reason: String) -> Self {
        PairResult {
            frame,
            status: Status::Lost,
            reason: Some(reason),
            left: None,
            right: None,
            disparity_px: None,
            disparity_axis_px: None,
            relative_disparity_axis_px: None,
            angle_diff_rad: None,
            z_um: None,
            disparity_std_px: None,
            z_std_um: None,
            metadata: None,
            warnings: Vec::new(),
        }
    }
}

impl StereoTracker {
    pub(super) fn pair_result(
        &self,
        frame: u64,
        status: Status,
        state: &TrackerState,
        template: &RigidTemplate,
        left: &ImageFit,
        right: &ImageFit,
    ) -> PairResult {
        let extent = PixelRect::full_size(state.width, state.height).extent();
        let outline = if state.outline.is_empty() {
            &template.points
        } else {
            &state.outline
        };
        let image = |fit: &ImageFit| {
            let contour = Polygon::new(place(outline, fit.pose));
            let angle = contour.orientation();
            // The part of a template cut by the border that is in the image.
            let contour = if template.cuts.is_empty() {
                contour
            } else {
                contour.clipped_to_box(extent)
            };
            // A dark object's outline need not share its core's centroid.
            let centroid = if state.outline.is_empty() {
                fit.pose.center()
            } else {
                place(&[Polygon::new(state.outline.clone()).centroid()], fit.pose)[0]
            };
            ImageResult {
                contour: contour.points,
                centroid,
                angle_rad: angle,
                energy: fit.terms.energy,
                contrast: fit.contrast,
                occluded_fraction: fit.occluded_fraction(),
            }
        };
        let disparity = state.disparity();
        let axis = axis_component(self.params.tilt_axis_deg, disparity);
        let std = [
            left.axis_std_px * left.pair_scale,
            right.axis_std_px * right.pair_scale,
            right.lag_px,
            left.risen_shift_px,
            right.risen_shift_px,
            DISPARITY_STD_FLOOR_PX,
        ]
        .iter()
        .map(|s| s * s)
        .sum::<f64>()
        .sqrt();
        PairResult {
            frame,
            status,
            reason: None,
            disparity_std_px: std.is_finite().then_some(std),
            z_std_um: None,
            left: Some(image(left)),
            right: Some(image(right)),
            disparity_px: Some(disparity),
            disparity_axis_px: Some(axis),
            relative_disparity_axis_px: Some(axis - state.first_disparity_axis_px),
            angle_diff_rad: Some(state.right.theta - state.left.theta),
            z_um: None,
            metadata: None,
            warnings: Vec::new(),
        }
    }
}

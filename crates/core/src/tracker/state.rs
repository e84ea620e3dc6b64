//! The tracker's durable state: template, poses, the reference appearance
//! of the first pair, and where the run stands.

use crate::fit::{Pose, RigidTemplate};
use crate::geometry::{HalfPlane, Point, Polygon};
use crate::occlusion::{SectorReference, SectorTemplate, GREY_QUANTILES};
use crate::scatter::DisparityRun;

use super::params::TrackerParams;

/// After a loss, pairs on which the object is sought by its own template
/// (over the hint box, then the whole image) before the tracker initialises
/// afresh: a lost object is not replaced by whatever is largest.
pub const REACQUIRE_PAIRS: u32 = 10;

/// The tracker's durable state: enough to continue a session after a restart.
#[derive(Clone, Debug, PartialEq)]
pub struct TrackerState {
    /// Rigid template: contour vertices relative to their area centroid.
    pub template: Vec<Point>,
    /// Current pose in the left image.
    pub left: Pose,
    /// Current pose in the right image.
    pub right: Pose,
    /// Left contrast at initialisation (the reference for "lost").
    pub reference_contrast: f64,
    /// Disparity-axis component on the session's first pair.
    pub first_disparity_axis_px: f64,
    /// The whole disparity on the session's first pair, so that the
    /// reference follows a change of tilt axis (absent in states stored
    /// before it was kept).
    pub first_disparity_px: Option<Point>,
    /// Frame size the state belongs to.
    pub width: u32,
    /// See `width`.
    pub height: u32,
    /// Where the tracker stands with its object: following it, seeking it
    /// after a loss, or about to initialise afresh.
    pub phase: Phase,
    /// Left pose change over the last pair (x, y, rotation): the next pair
    /// is predicted to continue it.
    pub left_velocity: [f64; 3],
    /// Per-sector contrasts of the left view on the first pair (reference
    /// appearance for occlusion detection).
    pub left_sector_contrasts: Vec<f64>,
    /// The same for the right view.
    pub right_sector_contrasts: Vec<f64>,
    /// Per-sector inner band means of the left view on the first pair (0:
    /// not seen; empty in states stored before they were kept): a sector
    /// whose contrast changed while its inner band kept the object's grey
    /// has a new backdrop, and is not hidden.
    pub left_sector_inner: Vec<f64>,
    /// The same for the right view.
    pub right_sector_inner: Vec<f64>,
    /// The grey levels' deciles ([`crate::occlusion::grey_quantiles`]) of
    /// the left and right frames the first pair's look was taken on (None
    /// in states stored before they were kept): a search after a loss reads
    /// from them how the microscope's brightness and contrast changed
    /// since.
    pub grey_quantiles: Option<[[f64; GREY_QUANTILES]; 2]>,
    /// Where the image border cut the object when the template was made
    /// (template coordinates; empty for an object inside the image).
    pub template_cuts: Vec<HalfPlane>,
    /// The object's outline in template coordinates, reported in place of
    /// the template: a dark object's template is the region inside its
    /// bright edge rim, the outline runs along the rim's outer edge (see
    /// [`crate::init::InitResult::core`]); any other template lies where
    /// the region energy is lowest, up to 1 px outside a blurred edge, the
    /// outline on the edge (see [`crate::init::fitted_to_edge`]). Empty: the
    /// template is the outline.
    pub outline: Vec<Point>,
    /// Width (Gaussian sigma, pixels) of the smoothing applied to both
    /// images before every fit of this object (see [`crate::prefilter`]);
    /// 0: none.
    pub prefilter_sigma_px: f64,
    /// Fresh objects refused as unlike the lost one since the object was
    /// initialised (see [`REFUSED_INITS`]).
    pub refused_inits: u32,
    /// The run of `uncertain` pairs the object is in, if any: how far the
    /// left contour moved from its predictions over it, pixels (see
    /// [`MAX_UNVERIFIED_MOVE_PX`]). It starts at an `uncertain` pair and
    /// ends at a pair with numbers, or when its moves lose the object (see
    /// [`RETURN_STD_SHARE`]).
    pub uncertain_run: Option<f64>,
    /// The disparity's standard error on the pair that initialised the
    /// object, pixels (0: not known, as in states stored before it was
    /// kept); see [`TrackerParams::max_disparity_std_px`].
    pub first_disparity_std_px: f64,
    /// The share of the outline as named that follows an edge (see
    /// [`crate::init::InitResult::edge_support`]; `None` for a drawn
    /// outline and in states stored before it was kept): below
    /// [`MIN_EDGE_SUPPORT`] every pair is `uncertain`.
    pub edge_support: Option<f64>,
    /// The run's last pairs with numbers, whose scatter scales each pair's
    /// standard error (see [`crate::scatter`]); empty in states stored
    /// before it was kept, and after an initialisation.
    pub disparity_run: DisparityRun,
}

/// Where a tracker stands with its object (before its first pair it has
/// no [`TrackerState`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// Following the object: each pair fits both views from their
    /// predicted poses.
    Tracking {
        /// Whether a tracking step has measured the left view's velocity
        /// since the object was found (by an initialisation or a search).
        /// Until then the prediction is the last pose, so an `uncertain`
        /// pair's move from it is the object's own motion as much as a
        /// slide, and does not count towards [`MAX_UNVERIFIED_MOVE_PX`]
        /// (a move the step did not follow on a pair whose object a search
        /// found still does).
        velocity_measured: bool,
    },
    /// Lost: each pair seeks the object by its own template (over the hint
    /// box, then the whole image), keeping the last good poses.
    Searching {
        /// Pairs searched in vain so far, fewer than [`REACQUIRE_PAIRS`].
        missed: u32,
    },
    /// Lost, and not found by its template in [`REACQUIRE_PAIRS`] pairs:
    /// the next pair initialises afresh, and a fresh object unlike the
    /// lost one is refused (see [`REFUSED_INITS`]).
    Reinitialising,
}

impl TrackerState {
    /// Whether the object is lost (sought by its template, or about to be
    /// initialised afresh).
    pub fn is_lost(&self) -> bool {
        !matches!(self.phase, Phase::Tracking { .. })
    }

    /// A pair's search for the lost template found nothing: one more
    /// missed search, or, after [`REACQUIRE_PAIRS`] of them, the next pair
    /// initialises afresh. Returns the searches missed.
    pub(super) fn miss(&mut self) -> u32 {
        let missed = match self.phase {
            Phase::Tracking { .. } => 1,
            Phase::Searching { missed } => missed + 1,
            Phase::Reinitialising => REACQUIRE_PAIRS,
        };
        self.phase = if missed < REACQUIRE_PAIRS {
            Phase::Searching { missed }
        } else {
            Phase::Reinitialising
        };
        missed
    }

    /// The last pair's disparity, right pose minus left pose, pixels.
    pub(super) fn disparity(&self) -> Point {
        [self.right.x - self.left.x, self.right.y - self.left.y]
    }

    /// The poses the next pair is predicted at: each view's last pose
    /// moved on by the left view's velocity (the right view keeps the last
    /// disparity).
    pub(super) fn predicted(&self) -> [Pose; 2] {
        let v = self.left_velocity;
        [self.left, self.right].map(|p| Pose {
            x: p.x + v[0],
            y: p.y + v[1],
            theta: p.theta + v[2],
        })
    }
}

impl TrackerState {
    /// The left view's reference look of the sectors.
    pub(super) fn left_look(&self) -> SectorReference<'_> {
        SectorReference {
            contrasts: &self.left_sector_contrasts,
            inner: &self.left_sector_inner,
        }
    }

    /// The right view's reference look of the sectors.
    pub(super) fn right_look(&self) -> SectorReference<'_> {
        SectorReference {
            contrasts: &self.right_sector_contrasts,
            inner: &self.right_sector_inner,
        }
    }
}

/// The rigid template and its sectors from saved template vertices (which
/// are relative to their centroid already).
pub(super) fn templates(state: &TrackerState, params: &TrackerParams) -> (RigidTemplate, SectorTemplate) {
    let mut rigid = RigidTemplate::new(
        &Polygon::new(state.template.clone()),
        params.rigid.coarse_vertices,
        &params.energy,
    )
    .0;
    rigid.cuts.clone_from(&state.template_cuts);
    let sectors = SectorTemplate::new(&rigid, params.occlusion.sectors);
    (rigid, sectors)
}

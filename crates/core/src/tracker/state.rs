//! The tracker's durable state: template, poses, the reference appearance
//! of the first pair, and where the run stands.

use crate::fit::{Pose, RigidTemplate};
use crate::geometry::{HalfPlane, Point, Polygon};
use crate::occlusion::{SectorReference, SectorTemplate};
use crate::scatter::DisparityRun;
use serde::{Deserialize, Serialize};

use super::params::TrackerParams;

/// The tracker's durable state: enough to continue a session after a restart.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
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
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub first_disparity_px: Option<Point>,
    /// Frame size the state belongs to.
    pub width: u32,
    /// See `width`.
    pub height: u32,
    /// True after a lost pair: the next pair searches for the template
    /// (or, after [`REACQUIRE_PAIRS`] searches in vain, initialises again).
    pub lost: bool,
    /// Left pose change over the last pair (x, y, rotation): the next pair
    /// is predicted to continue it.
    #[serde(default)]
    pub left_velocity: [f64; 3],
    /// Per-sector contrasts of the left view on the first pair (reference
    /// appearance for occlusion detection).
    #[serde(default)]
    pub left_sector_contrasts: Vec<f64>,
    /// The same for the right view.
    #[serde(default)]
    pub right_sector_contrasts: Vec<f64>,
    /// Per-sector inner band means of the left view on the first pair (0:
    /// not seen; empty in states stored before they were kept): a sector
    /// whose contrast changed while its inner band kept the object's grey
    /// has a new backdrop, and is not hidden.
    #[serde(default)]
    pub left_sector_inner: Vec<f64>,
    /// The same for the right view.
    #[serde(default)]
    pub right_sector_inner: Vec<f64>,
    /// Where the image border cut the object when the template was made
    /// (template coordinates; empty for an object inside the image).
    #[serde(default)]
    pub template_cuts: Vec<HalfPlane>,
    /// The object's outline in template coordinates, reported in place of
    /// the template: a dark object's template is the region inside its
    /// bright edge rim, the outline runs along the rim's outer edge (see
    /// [`crate::init::InitResult::core`]); any other template lies where
    /// the region energy is lowest, up to 1 px outside a blurred edge, the
    /// outline on the edge (see [`crate::init::fitted_to_edge`]). Empty: the
    /// template is the outline.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub outline: Vec<Point>,
    /// Width (Gaussian sigma, pixels) of the smoothing applied to both
    /// images before every fit of this object (see [`crate::prefilter`]);
    /// 0: none.
    #[serde(default)]
    pub prefilter_sigma_px: f64,
    /// Pairs since the object was lost whose search for its template found
    /// nothing (see [`REACQUIRE_PAIRS`]).
    #[serde(default)]
    pub missed_searches: u32,
    /// Fresh initialisations refused since the object was lost, as unlike
    /// it (see [`REFUSED_INITS`]).
    #[serde(default)]
    pub refused_inits: u32,
    /// How far the left contour moved from its predictions over the
    /// current run of `uncertain` pairs, pixels (see
    /// [`MAX_UNVERIFIED_MOVE_PX`]); 0 after a pair with numbers.
    #[serde(default)]
    pub unverified_move_px: f64,
    /// True from an `uncertain` pair until a pair with numbers, or until
    /// the run's unverified moves lose the object (see
    /// [`RETURN_STD_SHARE`]).
    #[serde(default)]
    pub uncertain_run: bool,
    /// The disparity's standard error on the pair that initialised the
    /// object, pixels (0: not known, as in states stored before it was
    /// kept); see [`TrackerParams::max_disparity_std_px`].
    #[serde(default)]
    pub first_disparity_std_px: f64,
    /// True from an initialisation or a search that found the object until
    /// a tracking step measures the left view's velocity: the prediction
    /// is the last pose, so an `uncertain` pair's move from it is the
    /// object's own motion as much as a slide, and does not count towards
    /// [`MAX_UNVERIFIED_MOVE_PX`]; a move the step did not follow on a
    /// pair whose object a search found still does.
    #[serde(default)]
    pub unmeasured_velocity: bool,
    /// The run's last pairs with numbers, whose scatter scales each pair's
    /// standard error (see [`crate::scatter`]); empty in states stored
    /// before it was kept, and after an initialisation.
    #[serde(default, skip_serializing_if = "DisparityRun::is_empty")]
    pub disparity_run: DisparityRun,
}

impl TrackerState {
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

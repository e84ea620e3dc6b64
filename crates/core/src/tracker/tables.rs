//! The prefix-sum tables a fit reads, built over what the template can
//! reach from a pose.

use crate::energy::{window_of, INTENSITY_OFFSET};
use crate::fit::{place, Pose, RigidTemplate};
use crate::imageio::GrayFrame;
use crate::occlusion::SectorTemplate;
use crate::region::{PixelRect, PrefixSums};

use super::StereoTracker;

impl StereoTracker {
    /// Reach of the tables built first around a prediction (see
    /// [`StereoTracker::fit_view`]), pixels: a fit from a prediction the
    /// sectors confirm moves less than this (over seeds 100-104, 1800
    /// fits, none reached it). Also the reach of the reference area that
    /// scales the energy, so that the energy of a pose does not depend on
    /// how far the tables reach.
    pub(super) const NEAR_REACH_PX: f64 = 6.0;

    /// Prefix sums over what the template can reach from `pose` within
    /// `reach` (at least [`StereoTracker::NEAR_REACH_PX`]), with the area it
    /// reaches within `NEAR_REACH_PX` as the reference area. Within
    /// `NEAR_REACH_PX` they are split tables ([`PrefixSums::split`]).
    pub(super) fn sums_around<'f>(
        &self,
        frame: &'f GrayFrame,
        template: &RigidTemplate,
        pose: Pose,
        reach: f64,
    ) -> PrefixSums<'f> {
        let cover = |reach: f64| {
            let [x0, y0, x1, y1] = template.reach(pose, reach);
            PixelRect::covering(x0, y0, x1, y1, frame.width, frame.height).unwrap_or(PixelRect::full(frame))
        };
        let near = cover(Self::NEAR_REACH_PX);
        // A template cut by the border sums its windows as polygons (clipped
        // at the cuts), from G over the whole reach.
        if reach > Self::NEAR_REACH_PX || !template.cuts.is_empty() {
            return PrefixSums::new(frame, cover(reach), INTENSITY_OFFSET).with_reference(near);
        }
        // G only where the contour and its sector bands can be; the window
        // sums from table rows where the window's top and bottom edges can
        // be: where they are at `pose`, plus the reach and what a rotation
        // of NEAR_ROTATION_RAD moves the outermost vertex. A pose past
        // either is refused (`outside_area`), and the fit widens to full
        // tables. Split tables that would not be smaller are not built.
        let guard = SectorTemplate::outer_band_width(template);
        let r = template.radius + guard + Self::NEAR_REACH_PX + 2.0;
        let polygons = PixelRect::around([pose.x, pose.y, pose.x, pose.y], r, frame.width, frame.height);
        let Some(polygons) = polygons.filter(|p| p.width * p.height < near.width * near.height) else {
            return PrefixSums::new(frame, near, INTENSITY_OFFSET);
        };
        let [_, top, _, bottom] = window_of(&place(&template.points, pose), template.margin);
        let slack = Self::NEAR_REACH_PX + 1.0 + template.radius * Self::NEAR_ROTATION_RAD;
        let edges = [[top - slack, top + slack], [bottom - slack, bottom + slack]];
        PrefixSums::split(frame, polygons, guard, near, &edges, INTENSITY_OFFSET)
    }

    /// Rotation within a fit on the near tables that their window rows
    /// allow for (about 3 degrees): the rigid fits from a confirmed
    /// prediction turn far less.
    pub(super) const NEAR_ROTATION_RAD: f64 = 0.05;
}

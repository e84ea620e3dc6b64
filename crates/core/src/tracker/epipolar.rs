//! The right view searched along its epipolar line: on the first pair from
//! the left pose, later when its disparity jumped.

use crate::energy::INTENSITY_OFFSET;
use crate::fit::{fit_rigid, Pose, RigidSearch, RigidTemplate};
use crate::geometry::Point;
use crate::imageio::GrayFrame;
use crate::occlusion::SectorTemplate;
use crate::region::{PixelRect, PrefixSums};
use crate::uncertainty;

use super::view_fit::{ImageFit, ViewSearch};
use super::StereoTracker;

/// How far across the epipolar line (and past either end of it) the
/// right view's search looks, pixels: the tables it fits on reach so far
/// around the template, and a fit that ends further out is no finding of
/// the search (a lamella whose energy falls towards a needle beside it slid
/// 88 px along the line, past the 64 px searched, on the static scans).
const SEARCH_BAND_PX: f64 = 8.0;

impl StereoTracker {
    /// The right view searched along the whole epipolar line from the left
    /// pose ([`StereoTracker::search_right`]) and fitted in full on the line
    /// from what the search found (a masked fit walks back along the weak
    /// edge that misled the first), when its energy is lower than
    /// `current`'s.
    pub(super) fn searched_right(
        &self,
        right: &GrayFrame,
        (template, sectors): &(RigidTemplate, SectorTemplate),
        (left, last_disparity): (Pose, Point),
        current: &ImageFit,
        search: ViewSearch,
        bands: uncertainty::NoiseBands,
    ) -> Option<ImageFit> {
        let pose = self
            .search_right(right, template, left, Some(last_disparity))
            .filter(|&pose| self.lower_energy(right, template, pose, current.pose))?;
        let sums = self.sums_around(right, template, pose, Self::NEAR_REACH_PX);
        let out = fit_rigid(
            &sums,
            template,
            pose,
            &self.params.energy,
            &self.params.rigid,
            RigidSearch {
                coarse_step_px: 1.0,
                rotate: search.rotate,
                line: search.line,
                within_px: self.params.rigid.search_radius_px,
            },
        );
        let mut fit = ImageFit::full(out.pose, out.terms);
        if !self.lower_energy(right, template, fit.pose, current.pose) {
            return None;
        }
        self.measure_std(right, &sums, (template, sectors), &mut fit, bands);
        Some(fit)
    }

    /// Searches the right image along the disparity axis for the template
    /// placed at the left pose: a scan in 2-px steps over
    /// +-`max_disparity_px` with the decimated contour, then rigid fits from
    /// the three best local minima; returns the lowest-energy pose.
    /// `last_disparity`: on a later pair with [`TrackerParams::epipolar`],
    /// the last pair's disparity, whose offset along the tilt axis the
    /// search keeps: it scans the line through the left pose plus that
    /// offset, and the fits move only along it. On the first pair (None)
    /// the fits are free, to find that offset (a free fit during tracking
    /// went 22 px off the line onto a bright bar beside a rod, crossing
    /// seed 118, and was reported `tracked`).
    pub(super) fn search_right(
        &self,
        right: &GrayFrame,
        template: &RigidTemplate,
        left: Pose,
        last_disparity: Option<Point>,
    ) -> Option<Pose> {
        let energy = &self.params.energy;
        let max_d = self.params.max_disparity_px;
        let dir = self.disparity_axis();
        // A displacement's component along the axis, and the rest of it.
        let split = |[dx, dy]: Point| {
            let along = dx * dir[0] + dy * dir[1];
            (along, [dx - along * dir[0], dy - along * dir[1]])
        };
        let kept = last_disparity
            .filter(|_| self.params.epipolar)
            .map(|d| split(d).1);
        let left = match kept {
            Some([ox, oy]) => Pose {
                x: left.x + ox,
                y: left.y + oy,
                ..left
            },
            None => left,
        };
        let [x0, y0, x1, y1] = template.reach(left, SEARCH_BAND_PX);
        let (ex, ey) = (dir[0].abs() * max_d, dir[1].abs() * max_d);
        let rect = PixelRect::covering(x0 - ex, y0 - ey, x1 + ex, y1 + ey, right.width, right.height)?;
        let sums = PrefixSums::new(right, rect, INTENSITY_OFFSET);
        let mut starts = template.lowest_along_line(&sums, energy, left, dir, max_d, 3);
        // The left pose itself (zero disparity) is always a candidate.
        if !starts.contains(&0.0) {
            starts.push(0.0);
        }
        let search = RigidSearch {
            coarse_step_px: 2.0,
            rotate: self.params.rigid.rotate && self.params.right_rotation,
            line: kept.map(|_| dir),
            within_px: f64::INFINITY,
        };
        starts
            .iter()
            .map(|&d| {
                let start = left.moved_along(dir, d);
                let out = fit_rigid(&sums, template, start, energy, &self.params.rigid, search);
                (out.pose, out.terms)
            })
            .filter(|(pose, terms)| {
                // Where the search looked: a fit that slid out of the band
                // found nothing the search can vouch for.
                let (along, [ax, ay]) = split([pose.x - left.x, pose.y - left.y]);
                terms.energy.is_finite()
                    && along.abs() <= max_d + SEARCH_BAND_PX
                    && ax.hypot(ay) <= SEARCH_BAND_PX
            })
            .min_by(|a, b| a.1.energy.total_cmp(&b.1.energy))
            .map(|(pose, _)| pose)
    }
}

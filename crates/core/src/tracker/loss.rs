//! Why a pair's measurement cannot be trusted: the contour left the image,
//! too much of it is hidden, its energy has no minimum along the disparity
//! axis, or its contrast collapsed.

use crate::fit::{place, RigidTemplate};
use crate::geometry::Polygon;
use crate::region::PixelRect;

use super::state::TrackerState;
use super::view_fit::{fraction, ImageFit, MAX_MASKED_FRACTION};
use super::StereoTracker;

impl StereoTracker {
    /// Least part of a template cut by the image border that must stay in
    /// both images.
    pub(super) const MIN_VISIBLE_FRACTION: f64 = 0.25;

    /// Why the measurement cannot be trusted, if it cannot.
    pub(super) fn loss_reason(
        &self,
        state: &TrackerState,
        template: &RigidTemplate,
        left: &ImageFit,
        right: &ImageFit,
    ) -> Option<String> {
        for (name, fit) in [("left", left), ("right", right)] {
            let pts = place(&template.points, fit.pose);
            if template.cuts.is_empty() {
                let inside = pts.iter().all(|p| {
                    p[0] >= 0.0
                        && p[1] >= 0.0
                        && p[0] <= (state.width - 1) as f64
                        && p[1] <= (state.height - 1) as f64
                });
                if !inside {
                    return Some(format!("the contour left the {name} image"));
                }
            } else {
                // An object cut by the border may move further out, until
                // too little of it is left to measure.
                let image = PixelRect::full_size(state.width, state.height).extent();
                let visible = Polygon::new(pts).clipped_to_box(image).area() / template.area;
                if visible < Self::MIN_VISIBLE_FRACTION {
                    return Some(format!(
                        "{:.0}% of the object is left in the {name} image (limit {:.0}%)",
                        100.0 * visible,
                        100.0 * Self::MIN_VISIBLE_FRACTION
                    ));
                }
            }
            if !fit.terms.energy.is_finite() {
                return Some(format!("no valid contour position in the {name} image"));
            }
            if fraction(&fit.occluded) > MAX_MASKED_FRACTION {
                return Some(format!(
                    "occluded: {:.0}% of the outline lost its contrast in the {name} image (limit {:.0}%)",
                    100.0 * fraction(&fit.occluded),
                    100.0 * MAX_MASKED_FRACTION
                ));
            }
            if fit.occluded_fraction() > self.params.occlusion.max_occluded_fraction {
                return Some(format!(
                    "{:.0}% of the outline is occluded in the {name} image (limit {:.0}%)",
                    100.0 * fit.occluded_fraction(),
                    100.0 * self.params.occlusion.max_occluded_fraction
                ));
            }
            // No standard error: the energy of what is visible has no
            // minimum along the disparity axis (a tip whose long side a bar
            // covered, sliding along its axis with the bar, 20 px off).
            if !fit.axis_std_px.is_finite() {
                return Some(format!(
                    "occluded: what is visible of the outline fixes no position along the disparity axis in the {name} image"
                ));
            }
            let reference = state.reference_contrast;
            if fit.contrast * reference.signum() < self.params.min_contrast_ratio * reference.abs() {
                return Some(format!(
                    "contrast collapsed in the {name} image ({:.3}, was {reference:.3} at initialisation; limit {:.2} of it)",
                    fit.contrast, self.params.min_contrast_ratio
                ));
            }
        }
        None
    }
}

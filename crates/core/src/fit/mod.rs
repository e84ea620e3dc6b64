//! Minimising the region energy ([`crate::energy`]): a free fit in which
//! vertices move individually (first pair, left image) and a rigid fit in
//! which the contour only translates and rotates (Dahmen et al., ICINCO 2009,
//! section 3; method note section 2, "Minimisation").

mod free;
mod rigid;
mod search;
mod template;
#[cfg(test)]
mod tests;

pub use free::{
    fit_free, fit_free_avoiding, fit_free_within, free_fit_tables, FreeFitOutcome, FreeFitParams,
    FREE_FIT_SLACK_PX, MIN_FREE_VERTICES,
};
pub use rigid::{fit_rigid, RigidOutcome, RigidParams, RigidSearch};
pub use search::{line_polish, newton_polish, CompassSearch};
pub use template::{FixedDomain, RigidTemplate};

use crate::geometry::Point;

/// Position and rotation of a rigid contour: the template (vertices relative
/// to its area centroid) rotated by `theta` and moved to `(x, y)`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Pose {
    /// Centroid x, pixels.
    pub x: f64,
    /// Centroid y, pixels.
    pub y: f64,
    /// Rotation from the template, radians (clockwise on screen, y down).
    pub theta: f64,
}

impl Pose {
    /// The centroid as a point.
    pub fn center(&self) -> Point {
        [self.x, self.y]
    }

    /// The pose moved `d` pixels along the unit direction `u`, its rotation
    /// kept.
    pub fn moved_along(self, u: Point, d: f64) -> Pose {
        Pose {
            x: self.x + d * u[0],
            y: self.y + d * u[1],
            ..self
        }
    }
}

/// The template's vertices placed at `pose`.
pub fn place(template: &[Point], pose: Pose) -> Vec<Point> {
    let mut placed = Vec::with_capacity(template.len());
    place_into(template, pose, &mut placed);
    placed
}

/// [`place`] into a reused buffer.
pub fn place_into(template: &[Point], pose: Pose, placed: &mut Vec<Point>) {
    let (s, c) = pose.theta.sin_cos();
    placed.clear();
    placed.extend(
        template
            .iter()
            .map(|p| [pose.x + c * p[0] - s * p[1], pose.y + s * p[0] + c * p[1]]),
    );
}

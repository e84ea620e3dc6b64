//! Objects cut by the image border: the part of a template both views
//! show, and a tool's free end.

use crate::fit::{Pose, RigidTemplate};
use crate::geometry::{HalfPlane, Point, Polygon};
use crate::region::PixelRect;

/// The limits ([`RigidTemplate::limits`]) of the left and right views of a
/// template cut by the border, at `left` with `disparity` (right minus left):
/// the image sides that cut it, each moved to where the other view's side
/// lies (a point p of the left view is at p + disparity in the right one),
/// so that each view leaves out what the other cannot see.
pub(super) fn shared_view_limits(
    template: &RigidTemplate,
    left: Pose,
    disparity: Point,
    [w, h]: [u32; 2],
) -> [Vec<HalfPlane>; 2] {
    let sides = HalfPlane::sides_of_box(PixelRect::full_size(w, h).extent());
    let cut_sides = template.cuts.iter().map(|c| {
        let placed = c.moved(left.theta, [left.x, left.y]);
        let facing = |s: &HalfPlane| s.normal[0] * placed.normal[0] + s.normal[1] * placed.normal[1];
        *sides
            .iter()
            .max_by(|a, b| facing(a).total_cmp(&facing(b)))
            .expect("four sides")
    });
    let moved = |side: HalfPlane, by: f64| {
        let shift = side.normal[0] * disparity[0] + side.normal[1] * disparity[1];
        HalfPlane::new(side.normal, side.offset + by * shift)
    };
    [
        cut_sides.clone().map(|side| moved(side, -1.0)).collect(),
        cut_sides.map(|side| moved(side, 1.0)).collect(),
    ]
}

/// Area of an elongated template's part within `length` of its free end
/// (the end of its long `axis`, a unit vector, away from the image
/// border's cuts); None without cuts, or when they lie along its length.
pub(super) fn free_end_area(
    polygon: &Polygon,
    [c, s]: Point,
    cuts: &[HalfPlane],
    length: f64,
) -> Option<f64> {
    // The cuts' normals point into the image, away from where the tool
    // goes on unseen: its free end lies that way along its axis.
    let inward = cuts
        .iter()
        .fold([0.0, 0.0], |a, h| [a[0] + h.normal[0], a[1] + h.normal[1]]);
    let towards = c * inward[0] + s * inward[1];
    let norm = inward[0].hypot(inward[1]);
    if norm == 0.0 || towards.abs() < 0.5 * norm {
        return None;
    }
    let sign = towards.signum();
    Some(polygon.end_area([sign * c, sign * s], length))
}

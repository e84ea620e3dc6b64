//! The rigid template: a fitted outline as vertices about its centroid,
//! with its decimated copy, its window margin, and the cuts of the image
//! border it carries.

use crate::energy::{
    evaluate_cut, evaluate_fixed, evaluate_with_length, window_of, EnergyParams, EnergyTerms,
};
use crate::geometry::{dist, solve3, HalfPlane, Point, Polygon};
use crate::region::PrefixSums;

use super::{place, Pose};

/// A rigid template with what the fit needs precomputed.
#[derive(Clone, Debug)]
pub struct RigidTemplate {
    /// Vertices relative to the area centroid, at rotation 0.
    pub points: Vec<Point>,
    /// A decimated copy for the coarse stage.
    pub coarse: Vec<Point>,
    /// Perimeter of `points` (unchanged by rigid motion).
    pub length: f64,
    /// Perimeter of `coarse`.
    pub coarse_length: f64,
    /// Largest vertex distance from the centroid (turns pixel steps into angles).
    pub radius: f64,
    /// Window margin (fixed for the template's area).
    pub margin: f64,
    /// False for outlines that look the same when rotated (a disc): their
    /// rotation cannot be measured, and letting it wander would only turn
    /// the template against the image's fixed shading.
    pub rotation_observable: bool,
    /// Area of `points`.
    pub area: f64,
    /// Where the image border cut the object when the template was made
    /// (template coordinates; empty for an object inside the image): the
    /// object goes on unseen beyond these half-planes, wherever they are
    /// placed, so the outline along them is no edge and its energy leaves
    /// out what lies beyond them ([`crate::energy::evaluate_cut`]; within a
    /// tracking step, [`RigidTemplate::fixed_at`]).
    pub cuts: Vec<HalfPlane>,
    /// Half-planes fixed in the image (image coordinates) outside which a
    /// fit of this template does not look; empty unless set for one view
    /// ([`RigidTemplate::limited_to`]).
    pub limits: Vec<HalfPlane>,
    /// Unit vector along the principal axis of `points`.
    pub axis: Point,
    /// For a template cut by the border, the domain one fit looks in, fixed
    /// in the image ([`RigidTemplate::fixed_at`]); `None` outside a tracking
    /// step's fits.
    pub fixed: Option<FixedDomain>,
}

/// Where the fits of one tracking step see a template cut by the border:
/// its cuts and window placed where the step started, fixed in the image
/// ([`crate::energy::evaluate_fixed`]).
#[derive(Clone, Debug, PartialEq)]
pub struct FixedDomain {
    /// The template's cuts at the start (image coordinates).
    pub cuts: Vec<HalfPlane>,
    /// The window box `[x0, y0, x1, y1]` (image coordinates).
    pub window: [f64; 4],
    /// How far the outline is continued beyond its cuts, pixels: as far as
    /// a fit may move it, plus the window margin.
    pub continued_px: f64,
}

impl FixedDomain {
    /// This domain moved by `by` (the other view of a stereo pair, `by` the
    /// disparity).
    pub fn moved(&self, by: Point) -> Self {
        let [x0, y0, x1, y1] = self.window;
        Self {
            cuts: self.cuts.iter().map(|c| c.moved(0.0, by)).collect(),
            window: [x0 + by[0], y0 + by[1], x1 + by[0], y1 + by[1]],
            continued_px: self.continued_px,
        }
    }
}

impl RigidTemplate {
    /// The direction the rigid fits translate along
    /// ([`CompassSearch::along`]): the principal axis for a template cut by
    /// the border (a tool entering the image), x and y otherwise.
    pub fn search_axis(&self) -> Option<Point> {
        (!self.cuts.is_empty()).then_some(self.axis)
    }
}

impl RigidTemplate {
    /// A template from an outline in image coordinates; returns it with the
    /// pose that reproduces the outline (centroid, rotation 0).
    pub fn new(outline: &Polygon, coarse_vertices: usize, energy: &EnergyParams) -> (Self, Pose) {
        let c = outline.centroid();
        let points: Vec<Point> = outline
            .points
            .iter()
            .map(|p| [p[0] - c[0], p[1] - c[1]])
            .collect();
        let radius = points
            .iter()
            .map(|p| p[0].hypot(p[1]))
            .fold(0.0, f64::max)
            .max(1.0);
        let coarse = Polygon::new(points.clone())
            .resampled(coarse_vertices.min(points.len()).max(8))
            .points;
        let rotation_observable = rotation_is_observable(&points);
        let angle = Polygon::new(points.clone()).orientation();
        let template = Self {
            length: Polygon::new(points.clone()).length(),
            coarse_length: Polygon::new(coarse.clone()).length(),
            points,
            coarse,
            radius,
            margin: energy.margin_for_area(outline.area()),
            rotation_observable,
            area: outline.area(),
            cuts: Vec::new(),
            limits: Vec::new(),
            axis: [angle.cos(), angle.sin()],
            fixed: None,
        };
        (
            template,
            Pose {
                x: c[0],
                y: c[1],
                theta: 0.0,
            },
        )
    }

    /// This template with the sides of the image box `image` (`[x0, y0, x1,
    /// y1]`, image coordinates) along which its outline at `pose` runs for
    /// [`RigidTemplate::MIN_CUT_PX`] or more as its cuts, each
    /// [`RigidTemplate::CUT_INSET_PX`] inside its side.
    pub fn cut_by(mut self, image: [f64; 4], pose: Pose) -> Self {
        let outline = place(&self.points, pose);
        let n = outline.len();
        self.cuts = HalfPlane::sides_of_box(image)
            .into_iter()
            .filter(|side| {
                let on = |p: Point| side.depth(p) < Self::ON_BORDER_PX;
                let along: f64 = (0..n)
                    .map(|i| (outline[i], outline[(i + 1) % n]))
                    .filter(|&(a, b)| on(a) && on(b))
                    .map(|(a, b)| dist(a, b))
                    .sum();
                along >= Self::MIN_CUT_PX
            })
            // n . (R q + t) >= o  <=>  (R^T n) . q >= o - n . t
            .map(|side| {
                let turned = side.moved(-pose.theta, [0.0, 0.0]);
                HalfPlane::new(turned.normal, -side.depth([pose.x, pose.y]) + Self::CUT_INSET_PX)
            })
            .collect();
        // The outline along a cut is no edge: a disc cut by the border
        // shows an arc, which looks the same turned about its centre.
        if !self.cuts.is_empty() && self.rotation_observable {
            let edge: Vec<Point> = self
                .points
                .iter()
                .copied()
                .filter(|&p| self.cuts.iter().all(|c| c.depth(p) >= 0.0))
                .collect();
            self.rotation_observable = circle_rms_residual(&edge).is_none_or(|r| r > ARC_RESIDUAL_PX);
        }
        self
    }

    /// This template with its cuts and window fixed in the image where they
    /// lie at `pose` ([`RigidTemplate::domain_at`]; nothing changes for a
    /// template without cuts), for fits that move it up to `reach` pixels.
    pub fn fixed_at(&self, image: [f64; 4], pose: Pose, reach: f64) -> Self {
        self.with_fixed(self.domain_at(image, pose, reach))
    }

    /// The domain fixed in the image where this template's cuts and window
    /// lie at `pose` (within its limits), for fits that move it up to
    /// `reach` pixels; `None` for a template without cuts.
    pub fn domain_at(&self, image: [f64; 4], pose: Pose, reach: f64) -> Option<FixedDomain> {
        if self.cuts.is_empty() {
            return None;
        }
        let cuts: Vec<HalfPlane> = self
            .cuts
            .iter()
            .map(|c| c.moved(pose.theta, [pose.x, pose.y]))
            .collect();
        let visible = HalfPlane::sides_of_box(image)
            .iter()
            .chain(&cuts)
            .chain(&self.limits)
            .fold(place(&self.points, pose), |p, side| side.clip(&p));
        let window = if visible.len() >= 3 {
            window_of(&visible, self.margin)
        } else {
            window_of(&place(&self.points, pose), self.margin)
        };
        Some(FixedDomain {
            cuts,
            window,
            continued_px: reach + self.margin,
        })
    }

    /// This template with `fixed` as its fixed domain.
    pub fn with_fixed(&self, fixed: Option<FixedDomain>) -> Self {
        Self {
            fixed,
            ..self.clone()
        }
    }

    /// The outline placed at `pose` (in `placed`) continued beyond the cuts:
    /// each vertex outside a cut moves `by` pixels away from the object,
    /// along the axis for a slender object entering along it, else along
    /// the cut's normal.
    pub(super) fn continued(&self, placed: &mut [Point], pose: Pose, by: f64) {
        let (s, c) = pose.theta.sin_cos();
        let axis = [
            c * self.axis[0] - s * self.axis[1],
            s * self.axis[0] + c * self.axis[1],
        ];
        for cut in self
            .cuts
            .iter()
            .map(|cut| cut.moved(pose.theta, [pose.x, pose.y]))
        {
            let along = cut.normal[0] * axis[0] + cut.normal[1] * axis[1];
            let inward = if along.abs() >= 0.5 {
                [axis[0] * along.signum(), axis[1] * along.signum()]
            } else {
                cut.normal
            };
            for p in placed.iter_mut().filter(|p| cut.depth(**p) < 0.0) {
                *p = [p[0] - by * inward[0], p[1] - by * inward[1]];
            }
        }
    }

    /// A vertex this close to an image side (pixels) lies on it.
    pub const ON_BORDER_PX: f64 = 0.75;

    /// How far inside the image side a cut lies, pixels. The image side
    /// itself is fixed in each view while the cut moves with the template:
    /// with the cut on the side, a fit that slid towards the border was
    /// clipped by the side in one view and by the cut in the other, took
    /// in more of the object there, and kept sliding (the real needle,
    /// entering from the border with its tip against the lamella, read
    /// 1.85 px of disparity for 3; 2.54 with the cut 4 px in, 3.001 with 6,
    /// 3.002 with 8). With it 6 px in, both views see the object up to the
    /// cut until a fit slides that far. Border-tool suites, seeds 0-4,
    /// 300-304 and 800-804 (16 pairs): disparity RMS 0.064, 0.063, 0.095 ->
    /// 0.057, 0.055, 0.071 px.
    pub const CUT_INSET_PX: f64 = 6.0;

    /// Outline along an image side that makes it a cut, pixels: an object
    /// that merely touches the border is not cut by it.
    pub const MIN_CUT_PX: f64 = 4.0;

    /// The cuts placed at `pose`, and the limits.
    pub fn cuts_at(&self, pose: Pose) -> Vec<HalfPlane> {
        self.cuts
            .iter()
            .map(|c| c.moved(pose.theta, [pose.x, pose.y]))
            .chain(self.limits.iter().copied())
            .collect()
    }

    /// This template limited to `limits` (image coordinates): a view of an
    /// object cut by the border looks only at what the other view sees too,
    /// so that both fit the same part of the object.
    pub fn limited_to(&self, limits: Vec<HalfPlane>) -> Self {
        Self {
            limits,
            ..self.clone()
        }
    }

    /// Energy of `placed`, this template's vertices (or its coarse copy's,
    /// of perimeter `length`) placed at `pose`.
    pub fn energy_of(
        &self,
        sums: &PrefixSums,
        placed: &[Point],
        pose: Pose,
        length: f64,
        energy: &EnergyParams,
    ) -> EnergyTerms {
        if self.cuts.is_empty() {
            evaluate_with_length(sums, placed, energy, self.margin, length)
        } else if let Some(fixed) = &self.fixed {
            let mut continued = placed.to_vec();
            self.continued(&mut continued, pose, fixed.continued_px);
            let sides: Vec<HalfPlane> = fixed.cuts.iter().chain(&self.limits).copied().collect();
            evaluate_fixed(
                sums,
                &continued,
                &sides,
                fixed.window,
                energy,
                [length, self.area],
            )
        } else {
            evaluate_cut(
                sums,
                placed,
                &self.cuts_at(pose),
                energy,
                self.margin,
                [length, self.area],
            )
        }
    }

    /// Energy of the template at `pose`.
    pub fn energy_at(&self, sums: &PrefixSums, pose: Pose, energy: &EnergyParams) -> EnergyTerms {
        self.energy_of(sums, &place(&self.points, pose), pose, self.length, energy)
    }

    /// The box the template can reach from `pose` within `reach` pixels,
    /// window margin included: `[x0, y0, x1, y1]`.
    pub fn reach(&self, pose: Pose, reach: f64) -> [f64; 4] {
        let r = self.radius + self.margin + reach + 2.0;
        [pose.x - r, pose.y - r, pose.x + r, pose.y + r]
    }
}

/// Whether rotating an outline (vertices relative to its centroid) by
/// 2 px of arc at its outermost vertex changes it visibly: the symmetric
/// difference must exceed 0.12 px per pixel of perimeter. The outline is
/// smoothed first (Gaussian along the contour, sigma about 3.5 px), because a
/// free fit on a noisy image leaves a jagged outline whose 2-px teeth would
/// make a disc look observable. Measured (smoothed, 5 seeds): discs
/// ("sphere") 0.01-0.06 clean and noisy, blobs 0.20-0.31, tips and rods
/// 0.65-0.89. (Unsmoothed with a 0.25 limit, blob seeds 1 and 2 were
/// "unobservable": their templates never turned while the object did,
/// and the left centroid drifted by 2.7 px over 45 frames.)
pub(super) fn rotation_is_observable(points: &[Point]) -> bool {
    let radius = points.iter().map(|p| p[0].hypot(p[1])).fold(0.0, f64::max);
    if radius < 2.0 || points.len() < 3 {
        return false;
    }
    let polygon = smoothed(&Polygon::new(points.to_vec()));
    let rotated = polygon.rotated_about([0.0, 0.0], 2.0 / radius);
    // Rasterise both on a 4x finer grid around the origin.
    let scale = 4.0;
    let side = (2.0 * radius * scale).ceil() as u32 + 4;
    let shift = side as f64 / 2.0;
    let raster = |p: &Polygon| p.scaled(scale, [shift, shift]).rasterize(side, side);
    let (a, b) = (raster(&polygon), raster(&rotated));
    let differing = a.iter().zip(&b).filter(|(x, y)| x != y).count() as f64 / (scale * scale);
    differing > 0.12 * polygon.length()
}

/// Largest RMS distance (pixels) of a cut template's edge from its
/// best-fitting circle for its rotation to count as unobservable.
pub(super) const ARC_RESIDUAL_PX: f64 = 0.6;

/// RMS distance of `points` from the circle fitted to them (algebraic
/// least squares, Kasa 1976); `None` for fewer than 8 points or a
/// degenerate fit.
pub(super) fn circle_rms_residual(points: &[Point]) -> Option<f64> {
    if points.len() < 8 {
        return None;
    }
    // Minimise sum (x^2 + y^2 + d x + e y + f)^2 over (d, e, f).
    let (mut m, mut v) = ([[0.0f64; 3]; 3], [0.0f64; 3]);
    for &[x, y] in points {
        let row = [x, y, 1.0];
        let z = -(x * x + y * y);
        for i in 0..3 {
            for j in 0..3 {
                m[i][j] += row[i] * row[j];
            }
            v[i] += row[i] * z;
        }
    }
    let [d, e, f] = solve3(&m, &v, 1e-9)?;
    let centre = [-d / 2.0, -e / 2.0];
    let r2 = centre[0] * centre[0] + centre[1] * centre[1] - f;
    if !(r2.is_finite() && r2 > 0.0) {
        return None;
    }
    let r = r2.sqrt();
    let sum: f64 = points.iter().map(|&p| (dist(p, centre) - r).powi(2)).sum();
    Some((sum / points.len() as f64).sqrt())
}

/// The outline resampled at about 1 px and low-passed along its length:
/// three passes of a 7-vertex moving average (sigma about 3.5 px).
pub(super) fn smoothed(outline: &Polygon) -> Polygon {
    let n = (outline.length().round() as usize).max(16);
    (0..3).fold(outline.resampled(n), |p, _| p.moving_average(3))
}

//! Minimising the region energy ([`crate::energy`]): a free fit in which
//! vertices move individually (first pair, left image) and a rigid fit in
//! which the contour only translates and rotates (Dahmen et al., ICINCO 2009,
//! section 3; method note section 2, "Minimisation").

use serde::{Deserialize, Serialize};

use crate::energy::{
    combine, evaluate, evaluate_cut, evaluate_fixed, evaluate_with_length, window_of, EnergyParams,
    EnergyTerms, INTENSITY_OFFSET,
};
use crate::geometry::{dist, segment_distance, segments_distance, solve3, HalfPlane, Point, Polygon};
use crate::imageio::GrayFrame;
use crate::region::{PixelRect, PrefixSums};

/// Parameters of the free (vertex-wise) fit.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(default, deny_unknown_fields)]
pub struct FreeFitParams {
    /// Target spacing of the vertices in pixels (at least 40 vertices are
    /// kept); the fitted outline becomes the rigid template as it is, so
    /// this also sets the cost of every later tracking step. Default 6;
    /// range 1..=20. Denser outlines fit the first image's
    /// pixel grid too closely: measured on synthetic sequences, spacing 3
    /// gave 0.049 px disparity RMS on clean data, spacing 6 0.033 px.
    pub spacing_px: f64,
    /// First trial move along the normal, pixels. Default 1.
    pub initial_step_px: f64,
    /// Smallest trial move; when no vertex can improve the energy by a move
    /// of this size the fit has converged. Default 0.125.
    pub min_step_px: f64,
    /// Cap on the number of sweeps over all vertices. Default 300.
    pub max_sweeps: usize,
    /// Resample to even spacing every this many sweeps. Default 4.
    pub resample_every: usize,
}

impl Default for FreeFitParams {
    fn default() -> Self {
        Self {
            spacing_px: 6.0,
            initial_step_px: 1.0,
            min_step_px: 0.125,
            max_sweeps: 300,
            resample_every: 4,
        }
    }
}

impl FreeFitParams {
    /// Checks ranges; the message says what was expected.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.spacing_px.is_finite() && (1.0..=20.0).contains(&self.spacing_px)) {
            return Err(format!(
                "invalid spacing_px {} (expected 1..=20)",
                self.spacing_px
            ));
        }
        if !(self.min_step_px > 0.0
            && self.min_step_px <= self.initial_step_px
            && self.initial_step_px <= 10.0)
        {
            return Err(format!(
                "invalid steps {}..{} (expected 0 < min_step_px <= initial_step_px <= 10)",
                self.min_step_px, self.initial_step_px
            ));
        }
        if !(1..=10_000).contains(&self.max_sweeps) || self.resample_every == 0 {
            return Err("invalid max_sweeps or resample_every (expected 1..=10000 and >= 1)".into());
        }
        Ok(())
    }
}

/// Fewest vertices of a freely fitted outline, whatever the spacing.
pub const MIN_FREE_VERTICES: usize = 40;

/// Result of a free fit.
#[derive(Clone, Debug)]
pub struct FreeFitOutcome {
    /// The fitted contour.
    pub polygon: Polygon,
    /// Its energy.
    pub terms: EnergyTerms,
    /// Sweeps made.
    pub sweeps: usize,
    /// True when it stopped because no move of `min_step_px` helped (false:
    /// stopped at `max_sweeps`).
    pub converged: bool,
}

/// Slack around a contour's window for the tables of a free fit, pixels:
/// room for the outline to move out.
pub const FREE_FIT_SLACK_PX: f64 = 16.0;

/// Tables for a free fit from `contour` in `frame`: its bounding box grown
/// by the energy's window margin and [`FREE_FIT_SLACK_PX`], clipped to the
/// image; `None` when the contour lies outside it.
pub fn free_fit_tables<'f>(
    frame: &'f GrayFrame,
    contour: &Polygon,
    energy: &EnergyParams,
) -> Option<PrefixSums<'f>> {
    let slack = energy.margin_for_area(contour.area()) + FREE_FIT_SLACK_PX;
    let rect = PixelRect::around(contour.bounds(), slack, frame.width, frame.height)?;
    Some(PrefixSums::new(frame, rect, INTENSITY_OFFSET))
}

/// Free minimisation: each vertex in turn tries a move of `step` along its
/// outward normal, then the opposite move, and keeps the first that lowers
/// the energy. Only the vertex's two edges change, so each trial costs O(1)
/// (two edge integrals). When a sweep moves fewer than 2% of the vertices,
/// the step halves; when that happens at `min_step_px`, the fit has
/// converged. The window is held fixed within a
/// sweep (so trials compare like with like) and updated between sweeps; the
/// outline is resampled to even spacing every `resample_every` sweeps.
pub fn fit_free(
    sums: &PrefixSums,
    initial: &Polygon,
    energy: &EnergyParams,
    params: &FreeFitParams,
) -> FreeFitOutcome {
    fit_free_within(sums, initial, energy, params, None)
}

/// [`fit_free`] with every vertex held inside `bounds` `[x0, y0, x1, y1]`
/// (the box a `roi` hint says the object lies in): a move that leaves it is
/// not tried, and an initial outline that runs past it is clipped to it
/// first. Without a limit the outline may grow along whatever the
/// two-region model takes for the object: on the real lift-out image a
/// box around the lamella gave the lamella (IoU 0.88 with its traced
/// outline) and the free fit then grew 90 px along the needle welded to
/// it, out of the box.
pub fn fit_free_within(
    sums: &PrefixSums,
    initial: &Polygon,
    energy: &EnergyParams,
    params: &FreeFitParams,
    bounds: Option<[f64; 4]>,
) -> FreeFitOutcome {
    fit_free_avoiding(sums, initial, energy, params, bounds, &|_| false)
}

/// [`fit_free_within`] with no vertex moved to a point where `forbidden`
/// holds (strips of substrate cut out of an earlier fit, see
/// [`crate::strips`]).
pub fn fit_free_avoiding(
    sums: &PrefixSums,
    initial: &Polygon,
    energy: &EnergyParams,
    params: &FreeFitParams,
    bounds: Option<[f64; 4]>,
    forbidden: &dyn Fn(Point) -> bool,
) -> FreeFitOutcome {
    let clipped;
    let initial = match bounds {
        Some(b) => {
            clipped = initial.clipped_to_box(b);
            &clipped
        }
        None => initial,
    };
    let inside =
        |q: Point| bounds.is_none_or(|[x0, y0, x1, y1]| q[0] >= x0 && q[0] <= x1 && q[1] >= y0 && q[1] <= y1);
    let margin = energy.margin_for_area(initial.area());
    let m_ref = sums.reference_mean();
    let vertices = |p: &Polygon| ((p.length() / params.spacing_px).round() as usize).max(MIN_FREE_VERTICES);
    let mut pts = initial.resampled(vertices(initial)).points;
    let mut last_simple = pts.clone();
    let mut step = params.initial_step_px;
    let mut converged = false;
    let mut sweeps = 0;
    while sweeps < params.max_sweeps {
        sweeps += 1;
        let [wx0, wy0, wx1, wy1] = window_of(&pts, margin);
        let window = if energy.whole_image_background {
            sums.total()
        } else {
            sums.rect_sum(wx0, wy0, wx1, wy1)
        };
        let n = pts.len();
        let (mut twice_area, mut length, mut integral) = (0.0, 0.0, 0.0);
        for i in 0..n {
            let (a, b) = (pts[i], pts[(i + 1) % n]);
            twice_area += cross(a, b);
            length += dist(a, b);
            integral += sums.edge_integral(a, b);
        }
        let sign = if twice_area < 0.0 { -1.0 } else { 1.0 };
        let terms_of = |twice_area: f64, length: f64, integral: f64| {
            let inside = crate::region::RegionSum {
                count: 0.5 * twice_area * sign,
                sum: integral * sign,
            };
            combine(energy, inside, window, length, m_ref)
        };
        let mut current = terms_of(twice_area, length, integral).energy;
        if !current.is_finite() {
            break;
        }
        let mut moved = 0usize;
        for i in 0..n {
            let (prev, p, next) = (pts[(i + n - 1) % n], pts[i], pts[(i + 1) % n]);
            let tangent = [next[0] - prev[0], next[1] - prev[1]];
            let tl = tangent[0].hypot(tangent[1]);
            if tl == 0.0 {
                continue;
            }
            let normal = [sign * tangent[1] / tl, -sign * tangent[0] / tl];
            let old_cross = cross(prev, p) + cross(p, next);
            let old_len = dist(prev, p) + dist(p, next);
            let old_int = sums.edge_integral(prev, p) + sums.edge_integral(p, next);
            for dir in [1.0, -1.0] {
                let q = [p[0] + dir * step * normal[0], p[1] + dir * step * normal[1]];
                if !sums.contains(&[q]) || !inside(q) || forbidden(q) {
                    continue;
                }
                let new_cross = cross(prev, q) + cross(q, next);
                let new_len = dist(prev, q) + dist(q, next);
                let new_int = sums.edge_integral(prev, q) + sums.edge_integral(q, next);
                let ta = twice_area - old_cross + new_cross;
                if ta * sign <= 0.0 {
                    continue; // would turn the contour inside out
                }
                let e = terms_of(ta, length - old_len + new_len, integral - old_int + new_int).energy;
                if e < current - 1e-12 * current.abs() {
                    pts[i] = q;
                    twice_area = ta;
                    length += new_len - old_len;
                    integral += new_int - old_int;
                    current = e;
                    moved += 1;
                    break;
                }
            }
        }
        // Noise lets a few vertices find an improving move on almost every
        // sweep; once fewer than 2% of them (at least one) still move, the
        // outline as a whole has settled at this step size.
        if moved <= n / 50 {
            if step <= params.min_step_px {
                converged = true;
                break;
            }
            step = (step * 0.5).max(params.min_step_px);
        }
        // Trial moves are checked locally (O(1)); a move can still make the
        // outline cross itself, and overlapping loops would be counted twice
        // by the region sums (seen on a large textured particle: the "area"
        // grew to 1.14M px). Such a sweep is undone and counts as no progress.
        if moved > 0 && !Polygon::new(pts.clone()).is_simple() {
            pts = last_simple.clone();
            if step <= params.min_step_px {
                converged = true;
                break;
            }
            step = (step * 0.5).max(params.min_step_px);
            continue;
        }
        last_simple.clone_from(&pts);
        if sweeps % params.resample_every == 0 {
            let polygon = Polygon::new(std::mem::take(&mut pts));
            pts = polygon.resampled(vertices(&polygon)).points;
        }
    }
    let pts = match cut_spurs(&pts, SPUR_NECK * params.spacing_px, SPUR_PATH * params.spacing_px) {
        Some(cut) => {
            let polygon = Polygon::new(cut);
            polygon.resampled(vertices(&polygon)).points
        }
        None => pts,
    };
    let terms = evaluate(sums, &pts, energy, margin);
    FreeFitOutcome {
        polygon: Polygon::new(pts),
        terms,
        sweeps,
        converged,
    }
}

/// Widest neck of a spur [`cut_spurs`] removes, in vertex spacings.
const SPUR_NECK: f64 = 0.75;

/// Longest outline around a spur [`cut_spurs`] removes, in vertex spacings.
const SPUR_PATH: f64 = 8.0;

/// The outline without its spurs and notches: runs of vertices that leave
/// the outline through a neck narrower than `neck` px (the distance between
/// the edges leaving and re-entering) and come back within `max_path` px of
/// outline, reaching more than `neck` from the cut, while the outline on
/// either side runs on in about the same direction (within 60 degrees; at
/// a tool's point or a rod's end it turns back, and is kept). The free fit
/// grows such spikes into noise or a rim; they carry little area but make
/// a disc's rotation look observable. `None` when there is nothing to cut.
fn cut_spurs(pts: &[Point], neck: f64, max_path: f64) -> Option<Vec<Point>> {
    let n = pts.len();
    if n < 8 {
        return None;
    }
    let p = |i: usize| pts[i % n];
    let unit = |a: Point, b: Point| {
        let l = dist(a, b).max(1e-12);
        [(b[0] - a[0]) / l, (b[1] - a[1]) / l]
    };
    let mut cut = vec![false; n];
    for i in 0..n {
        if cut[i] {
            continue;
        }
        // The farthest vertex j along the outline that closes a neck at i.
        let (mut path, mut best) = (0.0, None);
        for k in 3..n / 2 {
            path += dist(p(i + k - 1), p(i + k));
            if path > max_path {
                break;
            }
            let (j, d_in, d_out) = (i + k, unit(p(i + n - 1), p(i)), unit(p(i + k), p(i + k + 1)));
            let width = segments_distance(p(i), p(i + 1), p(j - 1), p(j));
            let reach = (i + 1..j)
                .map(|m| segment_distance(p(m), p(i), p(j)))
                .fold(0.0, f64::max);
            if width < neck && reach > neck && d_in[0] * d_out[0] + d_in[1] * d_out[1] > 0.5 {
                best = Some(k);
            }
        }
        if let Some(k) = best {
            for m in 1..k {
                cut[(i + m) % n] = true;
            }
        }
    }
    let kept: Vec<Point> = pts
        .iter()
        .zip(&cut)
        .filter(|(_, c)| !**c)
        .map(|(p, _)| *p)
        .collect();
    (kept.len() < n && kept.len() >= 3).then_some(kept)
}

/// Position and rotation of a rigid contour: the template (vertices relative
/// to its area centroid) rotated by `theta` and moved to `(x, y)`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
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

/// Parameters of the rigid fit.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(default, deny_unknown_fields)]
pub struct RigidParams {
    /// Largest motion between two pairs that the search is built to catch,
    /// pixels; the prefix sums cover the contour's reach plus this (the
    /// tracker first covers 6 px around a prediction and widens to this
    /// when the sectors do not confirm the prediction or the fit needs
    /// more). Default 24; range 1..=500.
    pub search_radius_px: f64,
    /// First step of the coarse stage, pixels. Default 8. With occlusion
    /// handling on, the tracker skips the coarse stage when the sectors
    /// confirm the predicted pose (each keeps >= 70% of its contrast there).
    pub coarse_step_px: f64,
    /// Vertices of the decimated contour used in the coarse stage. Default 48.
    pub coarse_vertices: usize,
    /// Smallest step of the compass search, pixels (rotation: arc length at
    /// the contour's outermost vertex); Newton steps on a local quadratic
    /// model refine the pose below it. Default 1/8: the same accuracy as 1/64
    /// on the synthetic suites (disparity RMS within 0.005 px, better on
    /// clean sequences: 0.025 against 0.030 px) with about 30 fewer energy
    /// evaluations per view.
    pub min_step_px: f64,
    /// Also search the rotation (the paper does). Default true.
    pub rotate: bool,
    /// Cap on energy evaluations per fit. Default 3000.
    pub max_evaluations: usize,
}

impl Default for RigidParams {
    fn default() -> Self {
        Self {
            search_radius_px: 24.0,
            coarse_step_px: 8.0,
            coarse_vertices: 48,
            min_step_px: 0.125,
            rotate: true,
            max_evaluations: 3000,
        }
    }
}

impl RigidParams {
    /// Checks ranges; the message says what was expected.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.search_radius_px.is_finite() && (1.0..=500.0).contains(&self.search_radius_px)) {
            return Err(format!(
                "invalid search_radius_px {} (expected 1..=500)",
                self.search_radius_px
            ));
        }
        if !(self.min_step_px > 0.0 && self.min_step_px <= 1.0) {
            return Err(format!(
                "invalid min_step_px {} (expected 0 < min_step_px <= 1)",
                self.min_step_px
            ));
        }
        if !(self.coarse_step_px.is_finite() && (1.0..=100.0).contains(&self.coarse_step_px)) {
            return Err(format!(
                "invalid coarse_step_px {} (expected 1..=100)",
                self.coarse_step_px
            ));
        }
        if !(8..=4096).contains(&self.coarse_vertices) {
            return Err(format!(
                "invalid coarse_vertices {} (expected 8..=4096)",
                self.coarse_vertices
            ));
        }
        if !(10..=1_000_000).contains(&self.max_evaluations) {
            return Err(format!(
                "invalid max_evaluations {} (expected 10..=1000000)",
                self.max_evaluations
            ));
        }
        Ok(())
    }
}

/// Result of a rigid fit.
#[derive(Clone, Copy, Debug)]
pub struct RigidOutcome {
    /// Best pose found.
    pub pose: Pose,
    /// Energy there.
    pub terms: EnergyTerms,
    /// Energy evaluations used.
    pub evaluations: usize,
    /// Some evaluated pose had no finite energy: its contour left the area
    /// the prefix sums cover (or a region was empty). The search could not
    /// go there, so a caller that built the sums over a short reach
    /// rebuilds them over a longer one and fits again.
    pub outside_area: bool,
}

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
    fn continued(&self, placed: &mut [Point], pose: Pose, by: f64) {
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

/// Rigid minimisation by compass search, in the paper's order: translation
/// in x, translation in y, rotation about the centroid; a move that helps is
/// repeated while it keeps helping. Each step size gets one such round and
/// then halves; at `min_step_px` rounds repeat until nothing improves. The
/// coarse stage runs on a decimated contour with steps from `coarse_step_px`
/// down to 1 px (translation only), so motion of tens of pixels costs
/// little; the fine stage uses every vertex, with steps from 0.5 px down to
/// `min_step_px`, then [`newton_polish`].
pub fn fit_rigid(
    sums: &PrefixSums,
    template: &RigidTemplate,
    start: Pose,
    energy: &EnergyParams,
    params: &RigidParams,
) -> RigidOutcome {
    fit_rigid_on_line(sums, template, start, energy, params, None, f64::INFINITY)
}

/// [`fit_rigid`] that, given a `line` (a unit vector in image coordinates),
/// translates only along it, with [`line_polish`] in place of
/// [`newton_polish`]: the right view of a stereo pair moves across the tilt
/// axis, along its epipolar line. Poses further than `within_px` from
/// `start` are invalid: a tracking step's object moves no further between
/// pairs, and beyond lie other things (a bar 41 px away captured a partly
/// occluded blob's contour, which the tables' corners still reached).
pub fn fit_rigid_on_line(
    sums: &PrefixSums,
    template: &RigidTemplate,
    start: Pose,
    energy: &EnergyParams,
    params: &RigidParams,
    line: Option<Point>,
    within_px: f64,
) -> RigidOutcome {
    // One vertex buffer for every evaluation (no allocation per pose).
    let placed = std::cell::RefCell::new(Vec::with_capacity(template.points.len()));
    // The lowest-energy pose of the fine stage with its terms: the fit ends
    // there, so its terms need no evaluation of their own (one of about 30
    // per view).
    let lowest = std::cell::Cell::new(None::<(Pose, EnergyTerms)>);
    let outside_area = std::cell::Cell::new(false);
    let eval_terms = |pts: &[Point], length: f64, pose: Pose| {
        if (pose.x - start.x).hypot(pose.y - start.y) > within_px {
            return EnergyTerms::INVALID;
        }
        let mut placed = placed.borrow_mut();
        place_into(pts, pose, &mut placed);
        let terms = template.energy_of(sums, &placed, pose, length, energy);
        if !terms.energy.is_finite() {
            outside_area.set(true);
        }
        terms
    };
    let eval = |pts: &[Point], length: f64, pose: Pose| eval_terms(pts, length, pose).energy;
    let mut pose = start;
    let mut evaluations = 0;
    // Coarse stage: translation only, decimated contour.
    if params.coarse_step_px > 1.0 {
        let coarse = CompassSearch {
            first_step: params.coarse_step_px,
            min_step: 1.0,
            radius: template.radius,
            rotate: false,
            max_evaluations: params.max_evaluations,
            settle_every_step: false,
            along: template.search_axis(),
            only: line,
        };
        let (p, _, used) = coarse.run(pose, |p| eval(&template.coarse, template.coarse_length, p));
        pose = p;
        evaluations += used;
    }
    // Fine stage: every vertex, with rotation.
    let fine = CompassSearch {
        // Half a pixel, after a coarse stage (translation to 1 px) or from
        // the right view's prediction: a round at 1 px rarely moved, and a
        // move that helps is repeated anyway (measured: 4 fewer evaluations
        // per 1024x768 step, synthetic suites unchanged to 1e-4 px).
        first_step: 0.5f64.max(params.min_step_px),
        min_step: params.min_step_px,
        radius: template.radius,
        rotate: params.rotate && template.rotation_observable,
        max_evaluations: params.max_evaluations.saturating_sub(evaluations).max(1),
        settle_every_step: false,
        along: template.search_axis(),
        only: line,
    };
    // The window moves with the contour, so the energy is a function of the
    // pose alone: two fits of the same image from different starts share
    // their minimum (a window held where each fit's coarse stage ended gave
    // identical images a disparity of up to 1.8 px on the quartz images).
    let energy_at = |p: Pose| {
        let terms = eval_terms(&template.points, template.length, p);
        if lowest.get().is_none_or(|(_, t)| terms.energy < t.energy) {
            lowest.set(Some((p, terms)));
        }
        terms.energy
    };
    let (pose, best, used) = fine.run(pose, energy_at);
    let (pose, _, polished) = match line {
        Some(u) => line_polish(pose, best, u, energy_at),
        None => newton_polish(pose, best, template.radius, fine.rotate, energy_at),
    };
    let terms = match lowest.get() {
        Some((at, terms)) if at == pose => terms,
        _ => template.energy_at(sums, pose, energy),
    };
    RigidOutcome {
        pose,
        terms,
        evaluations: evaluations + used + polished,
        outside_area: outside_area.get(),
    }
}

/// Refines a compass-search result with Newton steps on a local quadratic
/// model. Compass search stops when no single axis improves by a full step,
/// which in a valley where x, y and rotation are coupled can be a tenth of a
/// pixel from the minimum (measured on synthetic blobs: right-view errors of
/// +-0.13 px with the true minimum within 0.05 px). Gradient and Hessian come
/// from differences at h = 0.25 px (central on the axes, one corner for
/// each mixed term: 1 + 2d + d(d-1)/2 evaluations for d = 2 or 3
/// parameters); a step is kept only if it lowers the energy, and one
/// longer than 1 px is shortened to 1 px first. Two iterations at most; the second only when
/// the first moved by 0.05 px or more (it rarely does: stopping there saved
/// 9% of a 1024x768 step and left the synthetic suites' disparity RMS within
/// 0.001 px).
pub fn newton_polish(
    start: Pose,
    start_energy: f64,
    radius: f64,
    rotate: bool,
    energy_at: impl Fn(Pose) -> f64,
) -> (Pose, f64, usize) {
    const H: f64 = 0.25;
    // A step shorter than this (in the scaled units) ends the polish.
    const CONVERGED: f64 = 0.05;
    let d = if rotate { 3 } else { 2 };
    // Parameter scales: pixels for x and y, arc length at `radius` for rotation.
    let scale = [1.0, 1.0, 1.0 / radius];
    let shifted = |p: Pose, delta: [f64; 3]| Pose {
        x: p.x + delta[0] * scale[0],
        y: p.y + delta[1] * scale[1],
        theta: p.theta + delta[2] * scale[2],
    };
    let (mut pose, mut best, mut evaluations) = (start, start_energy, 0usize);
    for _ in 0..2 {
        if !best.is_finite() {
            break;
        }
        let mut g = [0.0; 3];
        let mut hess = [[0.0; 3]; 3];
        let mut plus = [0.0; 3];
        for i in 0..d {
            let mut e = [0.0; 3];
            e[i] = H;
            plus[i] = energy_at(shifted(pose, e));
            let minus = energy_at(shifted(pose, e.map(|v| -v)));
            evaluations += 2;
            g[i] = (plus[i] - minus) / (2.0 * H);
            hess[i][i] = (plus[i] - 2.0 * best + minus) / (H * H);
        }
        // Mixed terms from one corner each (forward differences, O(h)
        // accurate): 3 evaluations instead of 12 for d = 3, with the same
        // accuracy on the synthetic suites.
        for i in 0..d {
            for j in i + 1..d {
                let mut e = [0.0; 3];
                e[i] = H;
                e[j] = H;
                evaluations += 1;
                let v = (energy_at(shifted(pose, e)) - plus[i] - plus[j] + best) / (H * H);
                hess[i][j] = v;
                hess[j][i] = v;
            }
        }
        let Some(step) = solve_newton(&hess, &g, d) else {
            break;
        };
        let step_length = step.iter().map(|v| v * v).sum::<f64>().sqrt();
        // A longer step is shortened to 1 px (a trust region): in a flat
        // valley (a slender object whose ends are hidden) the full Newton
        // step overshoots, and refusing it left the fit where the compass
        // search stalled.
        let step = if step_length > 1.0 {
            step.map(|v| v / step_length)
        } else {
            step
        };
        let candidate = shifted(pose, step);
        let e = energy_at(candidate);
        evaluations += 1;
        if e < best {
            pose = candidate;
            best = e;
        } else {
            break;
        }
        if step_length < CONVERGED {
            break;
        }
    }
    (pose, best, evaluations)
}

/// [`newton_polish`] along one direction `u` only (unit vector, image
/// coordinates): a parabola through the energies at -h, 0 and +h
/// (h = 0.25 px), stepped to its vertex when that lowers the energy and
/// moves less than 1 px; twice at most.
pub fn line_polish(
    start: Pose,
    start_energy: f64,
    u: Point,
    energy_at: impl Fn(Pose) -> f64,
) -> (Pose, f64, usize) {
    const H: f64 = 0.25;
    let at = |p: Pose, s: f64| Pose {
        x: p.x + s * u[0],
        y: p.y + s * u[1],
        ..p
    };
    let (mut pose, mut best, mut evaluations) = (start, start_energy, 0);
    for _ in 0..2 {
        let (plus, minus) = (energy_at(at(pose, H)), energy_at(at(pose, -H)));
        evaluations += 2;
        let curvature = (plus + minus - 2.0 * best) / (H * H);
        if !(curvature > 0.0 && curvature.is_finite()) {
            break;
        }
        let step = -(plus - minus) / (2.0 * H) / curvature;
        if step.abs() >= 1.0 {
            break;
        }
        let candidate = at(pose, step);
        let e = energy_at(candidate);
        evaluations += 1;
        if e >= best {
            break;
        }
        (pose, best) = (candidate, e);
        if step.abs() < 0.05 {
            break;
        }
    }
    (pose, best, evaluations)
}

/// Solves H x = -g for the leading `d` x `d` block when H is positive
/// definite (a minimum); `None` otherwise.
fn solve_newton(h: &[[f64; 3]; 3], g: &[f64; 3], d: usize) -> Option<[f64; 3]> {
    // Cholesky factorisation of the d x d block, then two triangular solves.
    let mut l = [[0.0; 3]; 3];
    for i in 0..d {
        for j in 0..=i {
            let sum = h[i][j] - l[i][..j].iter().zip(&l[j][..j]).map(|(a, b)| a * b).sum::<f64>();
            if i == j {
                if sum <= 0.0 || !sum.is_finite() {
                    return None;
                }
                l[i][i] = sum.sqrt();
            } else {
                l[i][j] = sum / l[j][j];
            }
        }
    }
    let mut y = [0.0; 3];
    for i in 0..d {
        y[i] = (-g[i] - l[i][..i].iter().zip(&y[..i]).map(|(a, b)| a * b).sum::<f64>()) / l[i][i];
    }
    let mut x = [0.0; 3];
    for i in (0..d).rev() {
        x[i] = (y[i] - (i + 1..d).map(|k| l[k][i] * x[k]).sum::<f64>()) / l[i][i];
    }
    Some(x)
}

/// Compass search over poses: the schedule of step sizes and what to vary.
#[derive(Clone, Copy, Debug)]
pub struct CompassSearch {
    /// First step, pixels.
    pub first_step: f64,
    /// The search stops after a round without improvement at this step.
    pub min_step: f64,
    /// Turns a pixel step into a rotation step (arc length at this radius).
    pub radius: f64,
    /// Vary the rotation too.
    pub rotate: bool,
    /// Cap on energy evaluations.
    pub max_evaluations: usize,
    /// Repeat rounds at every step size until one brings no improvement
    /// (classic compass search). When false, every step above `min_step`
    /// gets a single round and then halves; only `min_step` is settled.
    /// The rigid fit's stages do this: the round that confirmed each
    /// larger step was 4-6 evaluations that almost never changed the result
    /// (measured: 114 -> 94 polygon evaluations per 1024x768 step, and the
    /// reference sequences' outputs within 6e-8 px).
    pub settle_every_step: bool,
    /// Translate along this unit vector and its perpendicular instead of x
    /// and y, turned with the pose (template coordinates): a slender tool's
    /// energy valley runs along its axis, and steps in x and y stall in a
    /// diagonal valley (a tip cut by the border stopped 2.3 px short).
    pub along: Option<Point>,
    /// Translate only along this unit vector (image coordinates).
    pub only: Option<Point>,
}

impl CompassSearch {
    /// Minimises `energy_at` from `start`; returns the best pose, its
    /// energy and the evaluations used.
    pub fn run(&self, start: Pose, mut energy_at: impl FnMut(Pose) -> f64) -> (Pose, f64, usize) {
        let mut evaluations = 1;
        let mut pose = start;
        let mut best = energy_at(pose);
        let mut step = self.first_step.max(self.min_step);
        loop {
            let (p, e, improved) = compass_round(pose, best, step, self, |p| {
                evaluations += 1;
                energy_at(p)
            });
            pose = p;
            best = e;
            if evaluations >= self.max_evaluations {
                break;
            }
            if !improved || (!self.settle_every_step && step > self.min_step) {
                if step <= self.min_step {
                    break;
                }
                step = (step * 0.5).max(self.min_step);
            }
        }
        (pose, best, evaluations)
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
fn rotation_is_observable(points: &[Point]) -> bool {
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
const ARC_RESIDUAL_PX: f64 = 0.6;

/// RMS distance of `points` from the circle fitted to them (algebraic
/// least squares, Kasa 1976); `None` for fewer than 8 points or a
/// degenerate fit.
fn circle_rms_residual(points: &[Point]) -> Option<f64> {
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
fn smoothed(outline: &Polygon) -> Polygon {
    let n = (outline.length().round() as usize).max(16);
    (0..3).fold(outline.resampled(n), |p, _| p.moving_average(3))
}

/// One round of compass search over x, y (and rotation); returns the new
/// pose, its energy, and whether anything improved.
fn compass_round(
    mut pose: Pose,
    mut best: f64,
    step: f64,
    search: &CompassSearch,
    mut energy_at: impl FnMut(Pose) -> f64,
) -> (Pose, f64, bool) {
    let mut improved = false;
    let axes: &[usize] = match (search.rotate, search.only.is_some()) {
        (true, false) => &[0, 1, 2],
        (false, false) => &[0, 1],
        (true, true) => &[0, 2],
        (false, true) => &[0],
    };
    for &axis in axes {
        let delta = if axis == 2 { step / search.radius } else { step };
        for dir in [1.0, -1.0] {
            let mut moved = false;
            // Keep going while the move helps (bounded: 64 steps).
            for _ in 0..64 {
                let mut candidate = pose;
                match (axis, search.along) {
                    (0 | 1, _) if search.only.is_some() => {
                        let u = search.only.unwrap_or([1.0, 0.0]);
                        candidate.x += dir * delta * u[0];
                        candidate.y += dir * delta * u[1];
                    }
                    (0, None) => candidate.x += dir * delta,
                    (1, None) => candidate.y += dir * delta,
                    (0 | 1, Some(u)) => {
                        let (sin, cos) = pose.theta.sin_cos();
                        let u = [cos * u[0] - sin * u[1], sin * u[0] + cos * u[1]];
                        let u = if axis == 0 { u } else { [-u[1], u[0]] };
                        candidate.x += dir * delta * u[0];
                        candidate.y += dir * delta * u[1];
                    }
                    _ => candidate.theta += dir * delta,
                }
                let e = energy_at(candidate);
                if e < best {
                    pose = candidate;
                    best = e;
                    moved = true;
                } else {
                    break;
                }
            }
            if moved {
                improved = true;
                break;
            }
        }
    }
    (pose, best, improved)
}

#[inline]
fn cross(a: Point, b: Point) -> f64 {
    a[0] * b[1] - b[0] * a[1]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::mask_iou;
    use crate::imageio::GrayFrame;
    use crate::region::PixelRect;
    use crate::synth::{Preset, Scene, Shape, SynthConfig};

    /// A spike and a notch 3 px wide on a circle are cut; a tool's point
    /// and a thin rod's ends, where the outline turns back, are kept.
    #[test]
    fn spurs_are_cut_and_points_kept() {
        let at = |angle: f64, r: f64| [r * angle.cos(), r * angle.sin()];
        let circle = Polygon::circle([0.0, 0.0], 60.0, 64).points;
        let mut points = Vec::new();
        for (k, p) in circle.iter().enumerate() {
            points.push(*p);
            let a = k as f64 * std::f64::consts::TAU / 64.0 + 0.04;
            if k == 10 || k == 40 {
                // 16 px out, or in, through a 3-px neck.
                let r = if k == 10 { 76.0 } else { 44.0 };
                points.extend([at(a, 60.0), at(a + 0.025, r), at(a + 0.05, 60.0)]);
            }
        }
        let spiky = Polygon::new(points);
        let spiky = spiky.resampled((spiky.length() / 6.0).round() as usize).points;
        let cut = cut_spurs(&spiky, 4.5, 48.0).expect("a spike and a notch");
        let radius = |p: &Point| p[0].hypot(p[1]);
        assert!(
            cut.iter().all(|p| (radius(p) - 60.0).abs() < 1.0),
            "a vertex left {:.1} px off the circle",
            cut.iter().map(|p| (radius(p) - 60.0).abs()).fold(0.0, f64::max)
        );
        assert!(
            cut_spurs(&circle, 4.5, 48.0).is_none(),
            "nothing to cut on a circle"
        );
        // A tool tip: a 10-degree point 120 px long, a vertex every 6 px.
        let tip = Polygon::new(vec![[0.0, 0.0], [120.0, -10.5], [120.0, 10.5]]);
        let tip = tip.resampled((tip.length() / 6.0).round() as usize).points;
        assert!(cut_spurs(&tip, 4.5, 48.0).is_none(), "the point is kept");
        // A rod 4 px wide (both sides within the neck) and 200 px long.
        let rod = Polygon::new(vec![[0.0, 0.0], [200.0, 0.0], [200.0, 4.0], [0.0, 4.0]]);
        let rod = rod.resampled((rod.length() / 6.0).round() as usize).points;
        assert!(cut_spurs(&rod, 4.5, 48.0).is_none(), "the ends are kept");
    }

    #[test]
    fn free_fit_pulls_a_rough_outline_onto_the_object() {
        for shape in Shape::ALL {
            let config = SynthConfig {
                frames: 1,
                ..SynthConfig::preset(Preset::Noisy, shape, 5)
            };
            let pair = Scene::new(&config).unwrap().render(0);
            let truth = &pair.truth.left.polygon;
            // Start 3 px too large (as a dilated initialisation would be).
            let c = truth.centroid();
            let r = truth.area().sqrt();
            let grow = 1.0 + 3.0 / r;
            let start = truth.scaled(grow, [c[0] * (1.0 - grow), c[1] * (1.0 - grow)]);
            let sums = PrefixSums::new(&pair.left, PixelRect::full(&pair.left), 1);
            let out = fit_free(&sums, &start, &EnergyParams::default(), &FreeFitParams::default());
            let (w, h) = (config.width, config.height);
            let truth_mask = truth.rasterize(w, h);
            let before = mask_iou(&start.rasterize(w, h), &truth_mask);
            let after = mask_iou(&out.polygon.rasterize(w, h), &truth_mask);
            assert!(
                after > 0.95 && after > before,
                "{shape:?}: IoU {before:.3} -> {after:.3}"
            );
            assert!(
                out.converged,
                "{shape:?} did not converge in {} sweeps",
                out.sweeps
            );
        }
    }

    #[test]
    fn rigid_fit_recovers_shift_and_rotation() {
        let config = SynthConfig {
            frames: 1,
            ..SynthConfig::preset(Preset::Clean, Shape::Tip, 2)
        };
        let pair = Scene::new(&config).unwrap().render(0);
        let truth = &pair.truth.left.polygon;
        let energy = EnergyParams::default();
        let (template, true_pose) = RigidTemplate::new(&truth.resampled(240), 48, &energy);
        let sums = PrefixSums::new(&pair.left, PixelRect::full(&pair.left), 1);
        for (dx, dy, dt) in [
            (0.3, -0.2, 0.0),
            (-12.0, 9.0, 0.03),
            (20.0, 0.0, -0.02),
            (0.0, -19.5, 0.0),
        ] {
            let start = Pose {
                x: true_pose.x + dx,
                y: true_pose.y + dy,
                theta: dt,
            };
            let out = fit_rigid(&sums, &template, start, &energy, &RigidParams::default());
            let err = (out.pose.x - true_pose.x).hypot(out.pose.y - true_pose.y);
            assert!(
                err < 0.05,
                "start offset ({dx}, {dy}, {dt}): error {err:.3} px, pose {:?}",
                out.pose
            );
            assert!(out.pose.theta.abs() < 0.002, "rotation {}", out.pose.theta);
        }
    }
    #[test]
    fn a_fit_that_needs_more_than_the_covered_area_says_so() {
        let config = SynthConfig {
            frames: 1,
            ..SynthConfig::preset(Preset::Clean, Shape::Blob, 3)
        };
        let pair = Scene::new(&config).unwrap().render(0);
        let energy = EnergyParams::default();
        let (template, true_pose) = RigidTemplate::new(&pair.truth.left.polygon.resampled(120), 48, &energy);
        // Start 10 px off; fine stage only, as from a confirmed prediction.
        let start = Pose {
            x: true_pose.x + 10.0,
            y: true_pose.y - 1.0,
            theta: 0.0,
        };
        let params = RigidParams {
            coarse_step_px: 1.0,
            ..RigidParams::default()
        };
        // Tables covering the start's window grown by `reach` on each side.
        let cover = |reach: f64| {
            let [x0, y0, x1, y1] = window_of(&place(&template.points, start), template.margin + reach);
            PixelRect::covering(x0, y0, x1, y1, pair.left.width, pair.left.height).unwrap()
        };
        // Reaching 1 px: the way to the object is cut off, and the outcome
        // says so.
        let short = PrefixSums::new(&pair.left, cover(1.0), 1);
        let cut = fit_rigid(&short, &template, start, &energy, &params);
        assert!(
            cut.outside_area,
            "pose {:?} from a 1-px reach, truth {true_pose:?}",
            cut.pose
        );
        // Reaching 16 px: found, and no evaluation left the area.
        let long = PrefixSums::new(&pair.left, cover(16.0), 1);
        let out = fit_rigid(&long, &template, start, &energy, &params);
        let err = (out.pose.x - true_pose.x).hypot(out.pose.y - true_pose.y);
        assert!(
            !out.outside_area && err < 0.05,
            "error {err:.3} px, outside {}",
            out.outside_area
        );
    }

    #[test]
    fn cuts_follow_the_template_and_leave_out_what_lies_beyond_them() {
        // A bar 40 px wide entering from the left border of a 200x100 image.
        let image = [-0.5, -0.5, 199.5, 99.5];
        let outline = Polygon::new(vec![[-0.5, 30.0], [120.0, 30.0], [120.0, 70.0], [-0.5, 70.0]]);
        let energy = EnergyParams::default();
        let (template, pose) = RigidTemplate::new(&outline, 32, &energy);
        let template = template.cut_by(image, pose);
        assert_eq!(
            template.cuts.len(),
            1,
            "only the left side runs along the outline"
        );
        // At the template's own pose the cut runs along the image's left
        // side, CUT_INSET_PX inside it.
        let inset = RigidTemplate::CUT_INSET_PX;
        let cut = template.cuts_at(pose)[0];
        assert!((cut.normal[0] - 1.0).abs() < 1e-12 && (cut.offset - (inset - 0.5)).abs() < 1e-9);
        // Moved and turned, it still runs along the outline's border side,
        // as far inside it.
        let moved = Pose {
            x: pose.x + 5.0,
            y: pose.y - 3.0,
            theta: 0.1,
        };
        let cut = template.cuts_at(moved)[0];
        let placed = place(&template.points, moved);
        let on_line = placed
            .iter()
            .filter(|p| (cut.depth(**p) + inset).abs() < 1e-9)
            .count();
        assert!(on_line >= 2, "{on_line} vertices on the moved border side");
        assert!(placed.iter().all(|p| cut.depth(*p) > -inset - 1e-9));
        // The bar shows its rotation; a disc cut by the border shows an arc,
        // which does not.
        assert!(template.rotation_observable);
        let disc = Polygon::circle([10.0, 50.0], 30.0, 120).clipped_to_box(image);
        let (d, p) = RigidTemplate::new(&disc, 32, &energy);
        assert!(d.rotation_observable, "uncut, the half disc's turn shows");
        assert!(!d.cut_by(image, p).rotation_observable);
        // An outline that only touches a side (less than MIN_CUT_PX) is not cut.
        let touching = Polygon::new(vec![[-0.5, 30.0], [60.0, 10.0], [60.0, 50.0], [-0.5, 32.0]]);
        let (t, p) = RigidTemplate::new(&touching, 32, &energy);
        assert!(t.cut_by(image, p).cuts.is_empty());

        // The energy of the cut template in an image of the bar is lowest
        // at the bar, also once the bar has moved 10 px further in (its base
        // still outside the frame); and what lies beyond the cut, where the
        // template does not know the object, does not change it.
        let frame_with_bar = |start: f64, end: f64| {
            let data = (0..200 * 100)
                .map(|i| {
                    let (x, y) = ((i % 200) as f64, (i / 200) as f64);
                    if (start..=end).contains(&x) && (30.0..70.0).contains(&y) {
                        180
                    } else {
                        60
                    }
                })
                .collect();
            GrayFrame::new(200, 100, 8, data).unwrap()
        };
        for shift in [0.0, 10.0] {
            let energy_at = |frame: &GrayFrame, dx: f64| {
                // The energy's scale, the mean of the reference area, from
                // where the frames agree.
                let reference = PixelRect {
                    x: 20,
                    y: 0,
                    width: 180,
                    height: 100,
                };
                let sums = PrefixSums::new(frame, PixelRect::full(frame), 1).with_reference(reference);
                let p = Pose {
                    x: pose.x + shift + dx,
                    ..pose
                };
                template.energy_at(&sums, p, &energy).energy
            };
            let frame = frame_with_bar(-1.0, 119.5 + shift);
            let best = energy_at(&frame, 0.0);
            assert!(best.is_finite());
            for dx in [-3.0, -1.0, 1.0, 3.0] {
                assert!(
                    energy_at(&frame, dx) > best,
                    "shift {shift}: energy at {dx} px not above the bar's"
                );
            }
            // The bar's unseen base gone: the same energy.
            let without_base = frame_with_bar(shift - 0.5, 119.5 + shift);
            let e = energy_at(&without_base, 0.0);
            assert!(
                (e - best).abs() < 1e-9 * best.abs(),
                "shift {shift}: {e} against {best}"
            );
        }
    }
    #[test]
    fn a_fixed_domain_holds_a_shaded_bar_at_its_tip() {
        // A bar 30 px wide with a round tip entering a 400x300 image from
        // its right side at 0.5 rad, brighter towards its base (150 at the
        // tip, 190 at its unseen end), moved 15 px further in since its
        // template was made.
        let (w, h) = (400usize, 300usize);
        let image = [-0.5, -0.5, w as f64 - 0.5, h as f64 - 0.5];
        let u = [-0.5f64.cos(), -0.5f64.sin()];
        let n = [-u[1], u[0]];
        let (base, half, length, shift) = ([420.0, 200.0], 15.0, 200.0, 15.0);
        let frame = {
            let length = length + shift;
            let data = (0..w * h)
                .map(|i| {
                    let d = [(i % w) as f64 - base[0], (i / w) as f64 - base[1]];
                    let (t, across) = (d[0] * u[0] + d[1] * u[1], (d[0] * n[0] + d[1] * n[1]).abs());
                    let bar = (0.0..=length).contains(&t) && across <= half;
                    if bar || (t - length).hypot(across) <= half {
                        (150.0 + 40.0 * (1.0 - t / length)).round() as u16
                    } else {
                        60
                    }
                })
                .collect();
            GrayFrame::new(w as u32, h as u32, 8, data).unwrap()
        };
        let tip = [base[0] + length * u[0], base[1] + length * u[1]];
        let mut outline: Vec<Point> = (0..=20)
            .map(|k| {
                let (s, c) = (std::f64::consts::PI * (k as f64 / 20.0 - 0.5)).sin_cos();
                [
                    tip[0] + half * (c * u[0] + s * n[0]),
                    tip[1] + half * (c * u[1] + s * n[1]),
                ]
            })
            .collect();
        outline.push([base[0] + half * n[0], base[1] + half * n[1]]);
        outline.push([base[0] - half * n[0], base[1] - half * n[1]]);
        let energy = EnergyParams::default();
        let (template, pose) = RigidTemplate::new(&Polygon::new(outline).clipped_to_box(image), 32, &energy);
        let template = template.cut_by(image, pose);
        assert_eq!(template.cuts.len(), 1);
        let sums = PrefixSums::new(&frame, PixelRect::full(&frame), 1);
        // Where along the axis (positive towards the tip) the energy is
        // lowest, within 20 px of the truth.
        let lowest = |template: &RigidTemplate| {
            (-80..=80)
                .map(|i| 0.25 * i as f64)
                .map(|s| {
                    let at = Pose {
                        x: pose.x + (shift + s) * u[0],
                        y: pose.y + (shift + s) * u[1],
                        ..pose
                    };
                    (s, template.energy_at(&sums, at, &energy).energy)
                })
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap()
                .0
        };
        // Cuts and window moving with the template: it slides back towards
        // the brighter base.
        let moving = lowest(&template);
        assert!(moving < -3.0, "moving cut: {moving:+.2} px");
        // In a domain fixed where the template was, only the tip moves
        // pixels between the regions.
        let fixed = lowest(&template.fixed_at(image, pose, 24.0));
        assert!(fixed.abs() <= 0.5, "fixed domain: {fixed:+.2} px");
    }
}

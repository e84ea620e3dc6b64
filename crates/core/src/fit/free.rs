//! The free fit of the first pair's left image: vertices move one by one
//! along their normals while the energy drops (method note, section 2).

use crate::energy::{combine, evaluate, window_of, EnergyParams, EnergyTerms, INTENSITY_OFFSET};
use crate::geometry::{dist, segment_distance, segments_distance, Point, Polygon};
use crate::imageio::GrayFrame;
use crate::region::{PixelRect, PrefixSums};

/// Parameters of the free (vertex-wise) fit.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
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
pub(super) const SPUR_NECK: f64 = 0.75;

/// Longest outline around a spur [`cut_spurs`] removes, in vertex spacings.
pub(super) const SPUR_PATH: f64 = 8.0;

/// The outline without its spurs and notches: runs of vertices that leave
/// the outline through a neck narrower than `neck` px (the distance between
/// the edges leaving and re-entering) and come back within `max_path` px of
/// outline, reaching more than `neck` from the cut, while the outline on
/// either side runs on in about the same direction (within 60 degrees; at
/// a tool's point or a rod's end it turns back, and is kept). The free fit
/// grows such spikes into noise or a rim; they carry little area but make
/// a disc's rotation look observable. `None` when there is nothing to cut.
pub(super) fn cut_spurs(pts: &[Point], neck: f64, max_path: f64) -> Option<Vec<Point>> {
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

#[inline]
pub(super) fn cross(a: Point, b: Point) -> f64 {
    a[0] * b[1] - b[0] * a[1]
}

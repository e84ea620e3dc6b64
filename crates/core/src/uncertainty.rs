//! Standard error of a rigid fit's position along the disparity axis, from
//! the fit itself.
//!
//! The rigid fit maximises the data term of the region energy (Dahmen et
//! al., ICINCO 2009, section 3; [`crate::energy`]),
//! `D = N_a f(m_a) + N_b f(m_b) - N_w f(m_w)` with `f(z) = z ln z`, or with
//! occluded sectors the same over the visible sectors' bands
//! ([`crate::occlusion`]). Moving the outline by `t` along a unit direction
//! `u` moves a strip of pixels of width `t (n . u)` across it, `n` the
//! outward normal; one pixel of value `I` passing from b to a changes `D`
//! by `I ln(m_a / m_b) - (m_a - m_b)`. With independent pixel noise of
//! standard deviation `sigma`, the slope `D'(t)` at the optimum therefore
//! has variance `sigma^2 ln(m_a / m_b)^2 S`, `S` the integral of
//! `(n . u)^2` over the (visible) outline in pixels, and the estimate `t*`
//! has the sandwich variance `Var D' / D''^2`:
//!
//! ```text
//! std(t*) = sigma |ln(m_a / m_b)| sqrt(S) / D''
//! ```
//!
//! The curvature `D''` is measured on the image (a central difference of
//! the energy at +-[`STEP_PX`], times `m_ref`), so blur, anti-aliasing and the
//! actual contrast are in it. `sigma` is the robust spread of the grey levels
//! in bands just inside and just outside the outline ([`band_sigma`]), so
//! texture where the fit looks counts as noise too; outside, with its
//! integrated autocorrelation along the outline, since texture that varies
//! slowly along it moves the fit as a whole. A template cut by the image
//! border adds the strip its cut carries ([`cut_length`]) where the cut
//! moves with it; in a tracking step the cut stays put
//! ([`crate::fit::RigidTemplate::fixed_at`]) and adds nothing.
//!
//! `D''` is the curvature along `u` with the position across `u` held,
//! while the fit moves the outline in both directions: a slender outline
//! at an angle to the axis trades a shift along `u` for one along its own
//! length. For a fit without hidden sectors the tracker multiplies the
//! result by [`marginal_factor`], the ratio of the marginal to the
//! conditional standard error for the outline's geometric information
//! matrix (1 for a compact outline); a fit with hidden sectors keeps the
//! conditional figure, as its bias term below already over-reports.
//!
//! A view's bands count as noise the texture and edges near the outline;
//! what the disparity feels is what differs between the two views there.
//! [`pair_sigma`] measures that; the tracker uses it, with the
//! surroundings' lag behind the object added, where the sum is below the
//! views' own figure (`StereoTracker::use_pair_noise`,
//! docs/uncertainty.md).
//!
//! What this leaves out (the template not matching the outline exactly,
//! sub-pixel discretisation) is the tracker's floor
//! ([`crate::tracker::DISPARITY_STD_FLOOR_PX`]) and, once a run of pairs
//! shows it, the factor by which their disparities scatter more than the
//! fits say ([`crate::scatter`]). A fit with sectors left out
//! (hidden, or before a new backdrop) also carries the bias of the partly
//! covered sectors next to them, which the noise does not show: the
//! tracker adds, in quadrature, how far the pose moves along the axis when
//! each left-out run grows by one sector, less the part of that shift the
//! noise alone explains ([`difference_variance`]). The calibration against the
//! synthetic suites is in docs/uncertainty.md.

use crate::geometry::{symmetric_eigenvalues, Point};
use crate::imageio::GrayFrame;

/// Step of the central difference that measures the curvature, pixels:
/// long enough to span the sub-pixel structure of an anti-aliased edge.
pub const STEP_PX: f64 = 0.5;

/// Where the bands of [`band_sigma`] lie, pixels from the outline (inner
/// band negative).
const BAND_PX: [f64; 2] = [1.5, 2.5];

/// How much farther out than the outer band the correlation of the
/// substrate's texture is measured, pixels: beyond an edge's blur and
/// rim, whose shape varies slowly along the outline too.
const FAR_PX: f64 = 4.0;

/// Unit normals of the open polyline `arc`, pointing to the side given by
/// `outward` (+1 or -1: the sign of the closed outline's signed area).
fn normals(arc: &[Point], outward: f64) -> Vec<Point> {
    let n = arc.len();
    (0..n)
        .map(|i| {
            let (a, b) = (arc[i.saturating_sub(1)], arc[(i + 1).min(n - 1)]);
            let t = [b[0] - a[0], b[1] - a[1]];
            let l = t[0].hypot(t[1]).max(1e-12);
            [outward * t[1] / l, -outward * t[0] / l]
        })
        .collect()
}

/// Where [`band_sigma`] measures the noise, and what was done to the frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct NoiseBands {
    /// The outer band is moved out by this much more, pixels (a dark
    /// object's rim).
    pub outer_offset_px: f64,
    /// Sigma of the Gaussian the frame was smoothed with, pixels; 0: none
    /// (see [`crate::prefilter`]).
    pub smoothing_px: f64,
    /// This function's result on the frame before smoothing, grey levels.
    pub raw_noise: Option<f64>,
}

/// The noise `sigma` of the module docs from two bands along the `arcs`
/// (open polylines in image coordinates, oriented like an outline whose
/// signed area has the sign of `outward`): 1.5-2.5 px inside and 1.5-2.5
/// px outside, the outer band moved out by `bands.outer_offset_px` more (a
/// dark object's rim), sampled at the nearest pixels. Each band's spread is
/// 1.4826 times the median absolute deviation from its median, so an
/// occluder or a rim in part of a band does not count. The outer band's
/// variance is multiplied by the correlation factor of one more band
/// `FAR_PX` (4 px) farther out. `None` with fewer than 8 samples of a band in
/// the image.
///
/// On a frame smoothed by a Gaussian of width `s`, the same measure on the
/// frame before (`bands.raw_noise`, `w`) gives it instead: for white noise
/// the outline integral of the smoothed noise has the variance
/// `w^2 / (2 sqrt(pi) s)` per pixel of length (the integral across the
/// outline of the squared 1-D Gaussian), so `sigma = w / sqrt(2 sqrt(pi) s)`.
/// The smoothed frame's own bands would weigh the little noise left against
/// texture, which smoothing keeps (the tracker smooths only where the noise
/// is mostly white, see [`crate::prefilter::MIN_WHITENESS`]).
pub fn band_sigma(frame: &GrayFrame, arcs: &[Vec<Point>], outward: f64, bands: NoiseBands) -> Option<f64> {
    if let (true, Some(raw)) = (bands.smoothing_px > 0.0, bands.raw_noise) {
        return Some(
            raw / (2.0 * std::f64::consts::PI.sqrt() * bands.smoothing_px)
                .max(1.0)
                .sqrt(),
        );
    }
    let runs =
        band_runs(frame, arcs, outward, bands.outer_offset_px).map(|run| run.into_iter().flatten().collect());
    spread_of_runs(runs, mean_spacing(arcs))
}

/// The grey levels of [`band_sigma`]'s five runs along the `arcs` (inner
/// band at 2.5 and 1.5 px, outer band at 1.5 and 2.5 px, the far run), in
/// order along the outline: `None` where a sample falls outside the frame.
fn band_runs(
    frame: &GrayFrame,
    arcs: &[Vec<Point>],
    outward: f64,
    outer_offset_px: f64,
) -> [Vec<Option<f64>>; 5] {
    let offsets = [
        -BAND_PX[1],
        -BAND_PX[0],
        BAND_PX[0] + outer_offset_px,
        BAND_PX[1] + outer_offset_px,
        0.5 * (BAND_PX[0] + BAND_PX[1]) + FAR_PX + outer_offset_px,
    ];
    let mut runs: [Vec<Option<f64>>; 5] = Default::default();
    for arc in arcs {
        for (p, n) in arc.iter().zip(normals(arc, outward)) {
            for (run, d) in runs.iter_mut().zip(offsets) {
                let (x, y) = ((p[0] + d * n[0]).round(), (p[1] + d * n[1]).round());
                let inside =
                    x >= 0.0 && y >= 0.0 && x < f64::from(frame.width) && y < f64::from(frame.height);
                run.push(inside.then(|| f64::from(frame.get(x as u32, y as u32))));
            }
        }
    }
    runs
}

/// The noise of [`band_sigma`] (or of [`pair_sigma`]) from its five runs,
/// `spacing` pixels apart along the outline.
fn spread_of_runs(runs: [Vec<f64>; 5], spacing: f64) -> Option<f64> {
    let [i0, i1, o0, o1, far] = runs;
    let inside = [i0, i1].concat();
    (inside.len() >= 8 && o0.len() + o1.len() >= 8).then(|| {
        // Texture inside moves with the object and does not move the fit;
        // the substrate's texture outside does, as a whole where it varies
        // slowly along the outline.
        let inner = median_and_spread(&inside).expect("8 samples or more").1;
        let outer = median_and_spread(&[o0, o1].concat())
            .expect("8 samples or more")
            .1;
        let factor = correlation_factor(&far, spacing);
        (0.5 * (inner * inner + outer * outer * factor)).sqrt()
    })
}

/// The noise `sigma` of one view from what differs between the two views
/// of a pair at their fitted poses: [`band_sigma`]'s bands sampled along
/// the same outline placed in each view (`arcs`, vertex for vertex), the
/// right view's samples less an affine map of the left's (a change of
/// brightness and contrast between the views), that residual's spread taken as [`band_sigma`] takes the grey levels',
/// divided by `sqrt(2)` (the difference of two views' independent noise).
/// What both views share (texture that moved with the object, a whole
/// frame shifted) is no noise of the disparity; what differs (independent
/// noise, texture at another disparity, a change of the object's look) is.
/// `None` with fewer than 8 samples of a band in both views.
///
/// The map is fitted over all bands by orthogonal least squares (the
/// principal axis of the sample pairs), as both views carry noise of the
/// same size: regressing the right view on the left would shrink the gain
/// by the noise's share of the left's variance and leave that share of
/// the scene's own grey levels in the residual, where it varies slowly
/// along the outline and the far run's correlation counts it many times
/// over (the real contact_1 needle with 20 grey levels of independent
/// noise in each view: a gain of 0.67-0.84 for 1, and twice the noise).
pub fn pair_sigma(
    frames: [&GrayFrame; 2],
    arcs: [&[Vec<Point>]; 2],
    outward: f64,
    outer_offset_px: f64,
) -> Option<f64> {
    let [left, right] = [0, 1].map(|k| band_runs(frames[k], arcs[k], outward, outer_offset_px));
    let pairs: Vec<(f64, f64)> = left
        .iter()
        .zip(&right)
        .flat_map(|(l, r)| l.iter().zip(r).filter_map(|(a, b)| Some(((*a)?, (*b)?))))
        .collect();
    if pairs.len() < 16 {
        return None;
    }
    // The affine map right = a left + b: the principal axis.
    let n = pairs.len() as f64;
    let (mx, my) = pairs
        .iter()
        .fold((0.0, 0.0), |(x, y), (a, b)| (x + a / n, y + b / n));
    let (sxy, sxx, syy) = pairs.iter().fold((0.0, 0.0, 0.0), |(xy, xx, yy), (a, b)| {
        (
            xy + (a - mx) * (b - my),
            xx + (a - mx) * (a - mx),
            yy + (b - my) * (b - my),
        )
    });
    let gain = if sxy != 0.0 {
        (syy - sxx + ((syy - sxx).powi(2) + 4.0 * sxy * sxy).sqrt()) / (2.0 * sxy)
    } else {
        1.0
    };
    let residuals = left.iter().zip(&right).map(|(l, r)| {
        l.iter()
            .zip(r)
            .filter_map(|(a, b)| Some((*b)? - (my + gain * ((*a)? - mx))))
            .collect::<Vec<f64>>()
    });
    let runs: [Vec<f64>; 5] = residuals.collect::<Vec<_>>().try_into().ok()?;
    let spacing = mean_spacing(arcs[0]);
    spread_of_runs(runs, spacing).map(|s| s / std::f64::consts::SQRT_2)
}

/// Mean distance between consecutive points of the `arcs`, pixels (1 when
/// they have no length).
fn mean_spacing(arcs: &[Vec<Point>]) -> f64 {
    let (length, steps) = arcs
        .iter()
        .flat_map(|arc| arc.windows(2))
        .fold((0.0, 0usize), |(l, n), w| {
            (l + (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]), n + 1)
        });
    if steps > 0 && length > 0.0 {
        length / steps as f64
    } else {
        1.0
    }
}

/// Largest factor [`correlation_factor`] gives: texture correlated over
/// more than this many pixels of outline is a shape, not noise.
const MAX_CORRELATION_PX: f64 = 40.0;

/// By how much the correlation of the samples of `run` (in order along the
/// outline, `spacing` pixels apart) multiplies the variance of an integral
/// along the outline, per pixel of length: `spacing * tau - (spacing - 1)`
/// for spacings of a pixel or more, `tau = 1 + 2 sum rho_k` the integrated
/// autocorrelation of the samples, summed over lags up to the first
/// `k >= 5 tau` (Sokal's window) if neighbours are correlated beyond the
/// noise of the estimate (`2 / sqrt(n)`; otherwise `tau = 1`), within
/// 1..=[`MAX_CORRELATION_PX`]. Deviations beyond 3 spreads (an occluder, a
/// rim) are clipped.
fn correlation_factor(run: &[f64], spacing: f64) -> f64 {
    let Some((median, mad)) = median_and_spread(run) else {
        return 1.0;
    };
    let clipped: Vec<f64> = run
        .iter()
        .map(|x| (x - median).clamp(-3.0 * mad, 3.0 * mad))
        .collect();
    let var: f64 = clipped.iter().map(|x| x * x).sum();
    let n = clipped.len();
    if var <= 0.0 || n < 8 {
        return 1.0;
    }
    let significant = 2.0 / (n as f64).sqrt();
    let step = spacing.max(1.0);
    // Lags beyond the largest factor's length add nothing the clamp below
    // keeps.
    let max_lag = ((MAX_CORRELATION_PX / step).ceil() as usize).min(n / 2);
    let mut tau = 1.0;
    for k in 1..max_lag {
        let lag: f64 = clipped.iter().zip(&clipped[k..]).map(|(a, b)| a * b).sum();
        let rho = lag / var * n as f64 / (n - k) as f64;
        if k == 1 && rho < significant {
            break;
        }
        tau += 2.0 * rho;
        if k as f64 >= 5.0 * tau {
            break;
        }
    }
    (step * tau - (step - 1.0)).clamp(1.0, MAX_CORRELATION_PX)
}

/// The median of `v` (the upper one of an even count) and 1.4826 times the
/// median absolute deviation from it: a centre and a standard deviation
/// that a minority of outliers does not move. `None` for an empty `v`.
pub fn median_and_spread(v: &[f64]) -> Option<(f64, f64)> {
    if v.is_empty() {
        return None;
    }
    let mid = v.len() / 2;
    let mut sorted = v.to_vec();
    let median = *sorted.select_nth_unstable_by(mid, f64::total_cmp).1;
    let mut dev: Vec<f64> = v.iter().map(|x| (x - median).abs()).collect();
    Some((
        median,
        1.4826 * *dev.select_nth_unstable_by(mid, f64::total_cmp).1,
    ))
}

/// `S`: the length of the `arcs` weighted by `(n . u)^2`, pixels; for an
/// edge `e` of length `l`, `(n . u)^2 l = (e x u)^2 / l`.
pub fn weighted_length(arcs: &[Vec<Point>], u: Point) -> f64 {
    arcs.iter()
        .flat_map(|arc| arc.windows(2))
        .map(|w| {
            let e = [w[1][0] - w[0][0], w[1][1] - w[0][1]];
            let l = e[0].hypot(e[1]);
            let cross = e[0] * u[1] - e[1] * u[0];
            if l > 0.0 {
                cross * cross / l
            } else {
                0.0
            }
        })
        .sum()
}

/// How much less well the `arcs` fix a position in their weakest
/// direction than along `u`: `sqrt(J_uu / lambda_min(J))` for the
/// geometric information matrix `J`, the integral of `n n^T` over the
/// arcs (its quadratic form in `u` is `S`, [`weighted_length`]). With the
/// same noise everywhere, the standard error of the position in its
/// weakest direction is the one along `u` times this factor; infinite
/// when the arcs fix no position along some direction (one straight edge,
/// as a slender object shows when a bar hides its other side and both
/// ends). 1 for a circle.
pub fn weakest_direction_factor(arcs: &[Vec<Point>], u: Point) -> f64 {
    let [xx, xy, yy] = information_matrix(arcs);
    let [lambda_min, _] = symmetric_eigenvalues([xx, xy, yy]);
    let j_uu = quadratic_form([xx, xy, yy], u);
    // Below a millionth of the total, the smallest eigenvalue is rounding.
    if lambda_min <= 1e-6 * (xx + yy) {
        f64::INFINITY
    } else {
        (j_uu / lambda_min).sqrt()
    }
}

/// How well the `arcs` fix a position in their weakest direction: the
/// smallest eigenvalue of their geometric information matrix (see
/// [`weakest_direction_factor`]), pixels of outline; 0 for one straight
/// edge or none. Its ratio for two sets of arcs is the inverse ratio of
/// the weakest direction's variances under the same noise.
pub fn weakest_information(arcs: &[Vec<Point>]) -> f64 {
    let [lambda_min, _] = symmetric_eigenvalues(information_matrix(arcs));
    lambda_min.max(0.0)
}

/// The direction in which the `arcs` fix a position least well: the unit
/// eigenvector of the smallest eigenvalue of their geometric information
/// matrix (see [`weakest_direction_factor`]).
pub fn weakest_direction(arcs: &[Vec<Point>]) -> Point {
    let [xx, xy, yy] = information_matrix(arcs);
    // The principal axis of the larger eigenvalue is at angle
    // 0.5 atan2(2 xy, xx - yy); the weakest direction is across it.
    let a = 0.5 * (2.0 * xy).atan2(xx - yy) + std::f64::consts::FRAC_PI_2;
    [a.cos(), a.sin()]
}

/// The smallest eigenvalue of the `arcs`' information matrix over the
/// largest (see [`weakest_direction_factor`]): 1 for a circle, 0 for one
/// straight edge or none.
pub fn isotropy(arcs: &[Vec<Point>]) -> f64 {
    let [small, large] = symmetric_eigenvalues(information_matrix(arcs));
    if large <= 0.0 {
        0.0
    } else {
        (small / large).max(0.0)
    }
}

/// By how much the fit's standard error along `u` exceeds the one
/// [`axis_std`] measures: `sqrt(J_uu (J^-1)_uu)` for the geometric
/// information matrix `J` of a translation (see
/// [`weakest_direction_factor`]). [`axis_std`] takes the energy's
/// curvature along `u` with the position across `u` held, a conditional
/// variance proportional to `1 / J_uu`; the fit moves the outline both
/// ways, so its estimate along `u` has the marginal variance, proportional
/// to `(J^-1)_uu`. For an outline whose information along and across its
/// long axis is `a` and `b`, at an angle `alpha` to `u`, the square of the
/// factor is `cos^4 + sin^4 + cos^2 sin^2 (a / b + b / a)`: 1 for a circle
/// and for a slender outline along or across `u`, 1.55 for a 60 x 8 px
/// rectangle at 45 degrees. At least 1 and at most
/// [`weakest_direction_factor`]; infinite when the arcs fix no position
/// along some direction.
pub fn marginal_factor(arcs: &[Vec<Point>], u: Point) -> f64 {
    let j = information_matrix(arcs);
    match inverse_form(j, u) {
        inverse if inverse.is_finite() => (quadratic_form(j, u) * inverse).sqrt().max(1.0),
        _ => f64::INFINITY,
    }
}

/// The variance of the difference between the positions along `u` fitted
/// on `arcs` and on `fewer` of them (a subset), in units of the
/// conditional variance along `u` from `arcs` (the energy's curvature):
/// `J_uu(arcs) ((J_fewer^-1)_uu - (J_arcs^-1)_uu)`, the translation's
/// marginal variances under the same noise per unit of outline. The
/// difference of an efficient estimate and a less efficient one has the
/// difference of their variances (Hausman, 1978). Infinite when `fewer`
/// fixes no position along some direction.
pub fn difference_variance(arcs: &[Vec<Point>], fewer: &[Vec<Point>], u: Point) -> f64 {
    let all = information_matrix(arcs);
    (quadratic_form(all, u) * (inverse_form(information_matrix(fewer), u) - inverse_form(all, u))).max(0.0)
}

/// [`difference_variance`] for positions fitted along `u` alone, the rest
/// of the pose held (as the right view's fit moves along its epipolar
/// line): `J_uu(arcs) / J_uu(fewer) - 1`, the conditional variances'
/// difference in the same units. Infinite when `fewer` fixes no position
/// along `u`.
pub fn line_difference_variance(arcs: &[Vec<Point>], fewer: &[Vec<Point>], u: Point) -> f64 {
    let (all, few) = (
        quadratic_form(information_matrix(arcs), u),
        quadratic_form(information_matrix(fewer), u),
    );
    if few > 0.0 {
        (all / few - 1.0).max(0.0)
    } else {
        f64::INFINITY
    }
}

/// How poorly the `arcs` fix a rigid pose's rotation about `centre`: the
/// rotation's entry of the inverse of the information matrix of (x, y,
/// theta), the integral of `J J^T` with `J = (n_x, n_y, (p - centre) x n)`
/// over the arcs (a normal shift of the outline at `p`). Its ratio for two
/// sets of arcs is the ratio of the rotation's variances under the same
/// noise; infinite when nothing fixes the rotation (an arc of a circle,
/// which turns about its centre unseen).
pub fn rotation_variance(arcs: &[Vec<Point>], centre: Point) -> f64 {
    match crate::geometry::solve3(&pose_information(arcs, centre), &[0.0, 0.0, 1.0], 0.0) {
        Some(x) if x[2].is_finite() && x[2] > 0.0 => x[2],
        _ => f64::INFINITY,
    }
}

/// The geometric information matrix of the `arcs` for a rigid pose (x, y,
/// theta about `centre`): the integral over them of `J J^T`, `J = (n_x,
/// n_y, (p - centre) x n)` for the unit normal `n` at `p`.
fn pose_information(arcs: &[Vec<Point>], centre: Point) -> [[f64; 3]; 3] {
    let mut m = [[0.0f64; 3]; 3];
    for w in arcs.iter().flat_map(|arc| arc.windows(2)) {
        let e = [w[1][0] - w[0][0], w[1][1] - w[0][1]];
        let l = e[0].hypot(e[1]);
        if l <= 0.0 {
            continue;
        }
        let n = [e[1] / l, -e[0] / l];
        let p = [
            0.5 * (w[0][0] + w[1][0]) - centre[0],
            0.5 * (w[0][1] + w[1][1]) - centre[1],
        ];
        let j = [n[0], n[1], p[0] * n[1] - p[1] * n[0]];
        for r in 0..3 {
            for c in 0..3 {
                m[r][c] += j[r] * j[c] * l;
            }
        }
    }
    m
}

/// `u^T M u` for the symmetric 2x2 matrix `M = [xx, xy, yy]`.
fn quadratic_form([xx, xy, yy]: [f64; 3], u: Point) -> f64 {
    xx * u[0] * u[0] + 2.0 * xy * u[0] * u[1] + yy * u[1] * u[1]
}

/// `u^T M^-1 u` for the symmetric 2x2 matrix `M = [xx, xy, yy]` (the
/// adjugate's form over the determinant); infinite where `M` is singular
/// to rounding (as in `weakest_direction_factor`: a determinant below a
/// millionth of the squared trace).
fn inverse_form([xx, xy, yy]: [f64; 3], u: Point) -> f64 {
    let det = xx * yy - xy * xy;
    if det <= 1e-6 * (xx + yy) * (xx + yy) {
        f64::INFINITY
    } else {
        quadratic_form([yy, -xy, xx], u) / det
    }
}

/// The geometric information matrix of the `arcs` for a translation, the
/// integral of `n n^T` over them: `[xx, xy, yy]` (the translation block of
/// [`pose_information`]).
fn information_matrix(arcs: &[Vec<Point>]) -> [f64; 3] {
    let m = pose_information(arcs, [0.0, 0.0]);
    [m[0][0], m[0][1], m[1][1]]
}

/// A cut's share of `S`: a template cut by the image border (a tool whose
/// base lies outside, [`crate::energy::evaluate_cut`]) bounds both the
/// object's region a and the window by its cut, which moves with it. A
/// pixel of value `I` it carries out of both changes `D` by
/// `I ln(m_w / m_a)` plus terms without `I`, where `m_w` is the window's
/// mean (`inside_share` of it is region a). So a cut of length `l`
/// weighs `l (n . u)^2 = s_cut` times `(ln(m_w / m_a) / ln(m_a / m_b))^2`
/// in `S`, for the region means `[m_a, m_b]`.
pub fn cut_length(s_cut: f64, [m_a, m_b]: [f64; 2], inside_share: f64) -> f64 {
    let share = inside_share.clamp(0.0, 1.0);
    let m_w = share * m_a + (1.0 - share) * m_b;
    let ratio = (m_w / m_a).ln() / (m_a / m_b).ln();
    if ratio.is_finite() {
        s_cut * ratio * ratio
    } else {
        0.0
    }
}

/// The standard error (pixels) of a position whose energy (as the fit
/// minimised it, `E = const - D / m_ref`) is `energy(t)` at a shift `t` along
/// the direction of `weighted_length`'s `s`, for region means `means`
/// (inside, outside) and pixel noise `sigma`. NaN when the energy has no
/// minimum there (curvature <= 0) or cannot be evaluated.
pub fn axis_std(energy: impl Fn(f64) -> f64, m_ref: f64, means: [f64; 2], s: f64, sigma: f64) -> f64 {
    let (minus, centre, plus) = (energy(-STEP_PX), energy(0.0), energy(STEP_PX));
    let curvature = m_ref * (plus + minus - 2.0 * centre) / (STEP_PX * STEP_PX);
    let std = sigma * (means[0] / means[1]).ln().abs() * s.sqrt() / curvature;
    if curvature > 0.0 && std.is_finite() {
        std
    } else {
        f64::NAN
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_slender_outline_without_its_ends_fixes_no_position_along_it() {
        // A needle's outline: two long sides and a tip cone at x = 60..70.
        let upper = vec![[0.0, -5.0], [60.0, -5.0]];
        let cone = vec![[60.0, -5.0], [70.0, 0.0], [60.0, 5.0]];
        let lower = vec![[60.0, 5.0], [0.0, 5.0]];
        let whole = weakest_information(&[upper.clone(), cone, lower.clone()]);
        // The cone's sides, 11.2 px each, with n_x^2 = 0.2 of their length.
        assert!((whole - 2.0 * 125f64.sqrt() * 0.2).abs() < 1e-9, "{whole}");
        assert_eq!(weakest_information(&[upper, lower]), 0.0);
        // A circle of radius r: pi r in every direction.
        let circle: Vec<Point> = (0..=256)
            .map(|k| {
                let a = std::f64::consts::TAU * k as f64 / 256.0;
                [10.0 * a.cos(), 10.0 * a.sin()]
            })
            .collect();
        let pi_r = 10.0 * std::f64::consts::PI;
        assert!((weakest_information(&[circle]) - pi_r).abs() < 0.01 * pi_r);
    }

    /// Half a circle has half its information in every direction: a fit on
    /// it has twice the variance, and its difference from the whole
    /// circle's fit the variance of one (Hausman). The same arcs differ by
    /// nothing; arcs that fix nothing along the axis, without bound.
    #[test]
    fn the_difference_of_two_fits_has_the_difference_of_their_variances() {
        let arc = |from: f64, to: f64| -> Vec<Point> {
            (0..=256)
                .map(|k| {
                    let a = from + (to - from) * k as f64 / 256.0;
                    [10.0 * a.cos(), 10.0 * a.sin()]
                })
                .collect()
        };
        let pi = std::f64::consts::PI;
        let whole = [arc(0.0, 2.0 * pi)];
        let half = [arc(-pi / 2.0, pi / 2.0)];
        for u in [[1.0, 0.0], [0.6, -0.8]] {
            let d = difference_variance(&whole, &half, u);
            assert!((d - 1.0).abs() < 1e-3, "{u:?}: {d}");
            assert!(difference_variance(&whole, &whole, u).abs() < 1e-9);
            // Along `u` alone: a half circle has half the information
            // along any direction, as in the free fit.
            let line = line_difference_variance(&whole, &half, u);
            assert!((line - 1.0).abs() < 1e-3, "{u:?}: along the line {line}");
            assert!(line_difference_variance(&whole, &whole, u).abs() < 1e-9);
        }
        // A quarter circle places a fit held to x better than a free one,
        // which trades x against y.
        let quarter = [arc(0.0, pi / 2.0)];
        let (free, line) = (
            difference_variance(&whole, &quarter, [1.0, 0.0]),
            line_difference_variance(&whole, &quarter, [1.0, 0.0]),
        );
        assert!(line.is_finite() && line < free, "free {free}, along x {line}");
        // Two straight sides along x fix nothing along x.
        let sides = [vec![[-10.0, -3.0], [10.0, -3.0]], vec![[10.0, 3.0], [-10.0, 3.0]]];
        assert!(difference_variance(&whole, &sides, [1.0, 0.0]).is_infinite());
        assert!(line_difference_variance(&whole, &sides, [1.0, 0.0]).is_infinite());
    }

    #[test]
    fn a_slender_outline_at_an_angle_to_the_axis_is_fixed_less_well_along_it() {
        // A closed rectangle of `length` x `width` px at `angle` (rad).
        let rectangle = |length: f64, width: f64, angle: f64| -> Vec<Point> {
            let (s, c) = angle.sin_cos();
            [
                [0.0, 0.0],
                [length, 0.0],
                [length, width],
                [0.0, width],
                [0.0, 0.0],
            ]
            .iter()
            .map(|p| [c * p[0] - s * p[1], s * p[0] + c * p[1]])
            .collect()
        };
        let u = [1.0, 0.0];
        // Along its length: a = 2 * 8 (the ends), b = 2 * 60 (the sides).
        let (a, b) = (16.0f64, 120.0f64);
        let diagonal = marginal_factor(&[rectangle(60.0, 8.0, std::f64::consts::FRAC_PI_4)], u);
        let expected = (0.5 + 0.25 * (a / b + b / a)).sqrt();
        assert!(
            (diagonal - expected).abs() < 1e-9,
            "{diagonal} against {expected}"
        );
        assert!((diagonal - 1.552).abs() < 1e-3, "{diagonal}");
        // Along and across the axis, and a circle: the curvature along `u`
        // alone is the whole story.
        for angle in [0.0, std::f64::consts::FRAC_PI_2] {
            let f = marginal_factor(&[rectangle(60.0, 8.0, angle)], u);
            assert!((f - 1.0).abs() < 1e-9, "{angle}: {f}");
        }
        let circle: Vec<Point> = (0..=256)
            .map(|k| {
                let a = std::f64::consts::TAU * k as f64 / 256.0;
                [10.0 * a.cos(), 10.0 * a.sin()]
            })
            .collect();
        assert!((marginal_factor(&[circle], u) - 1.0).abs() < 1e-6);
        // Never above the weakest direction's factor; a lone straight edge
        // at an angle fixes nothing along it.
        let tilted = [rectangle(60.0, 8.0, 0.3)];
        assert!(marginal_factor(&tilted, u) <= weakest_direction_factor(&tilted, u) + 1e-12);
        assert!(marginal_factor(&[vec![[0.0, 0.0], [40.0, 30.0]]], u).is_infinite());
    }

    #[test]
    fn an_arc_of_a_circle_fixes_no_rotation_and_a_straight_edge_does() {
        let arc = |from: f64, to: f64, centre: Point, r: f64| -> Vec<Point> {
            (0..=32)
                .map(|k| {
                    let a = from + (to - from) * k as f64 / 32.0;
                    [centre[0] + r * a.cos(), centre[1] + r * a.sin()]
                })
                .collect()
        };
        let pi = std::f64::consts::PI;
        // A tool: a round head of radius 10 about (-30, 0), two straight
        // sides from it to a tip at (30, 0); the pose's centre is the origin.
        let head = arc(0.5 * pi, 1.5 * pi, [-30.0, 0.0], 10.0);
        let upper = vec![[-30.0, -10.0], [30.0, 0.0]];
        let lower = vec![[30.0, 0.0], [-30.0, 10.0]];
        let whole = rotation_variance(&[head.clone(), upper.clone(), lower.clone()], [0.0, 0.0]);
        assert!(whole.is_finite() && whole > 0.0, "{whole}");
        // The head alone turns about its own centre unseen.
        let head_only = rotation_variance(std::slice::from_ref(&head), [0.0, 0.0]);
        assert!(head_only > 1e6 * whole, "{head_only} against {whole}");
        // With one side it is fixed, if less well.
        let with_side = rotation_variance(&[head, upper], [0.0, 0.0]);
        assert!(
            with_side.is_finite() && with_side < 10.0 * whole,
            "{with_side} against {whole}"
        );
        assert_eq!(rotation_variance(&[], [0.0, 0.0]), f64::INFINITY);
    }

    #[test]
    fn the_weakest_direction_of_an_outline() {
        let circle: Vec<Point> = (0..=64)
            .map(|k| {
                let a = k as f64 * std::f64::consts::TAU / 64.0;
                [10.0 * a.cos(), 10.0 * a.sin()]
            })
            .collect();
        let f = weakest_direction_factor(std::slice::from_ref(&circle), [1.0, 0.0]);
        assert!((f - 1.0).abs() < 1e-9, "circle: {f}");
        // One straight edge fixes nothing along itself.
        let edge = vec![[0.0, 0.0], [30.0, 10.0], [60.0, 20.0]];
        assert!(weakest_direction_factor(std::slice::from_ref(&edge), [1.0, 0.0]).is_infinite());
        // A rod's two long sides and one end along x: the end fixes x
        // weakly (its length 2r against the sides' 2L), while along y,
        // which the sides fix, the factor stays near 1.
        let (l, r) = (40.0, 5.0);
        let mut rod = vec![[-l, -r], [l, -r]];
        rod.extend((1..16).map(|k| {
            let a = -std::f64::consts::FRAC_PI_2 + k as f64 * std::f64::consts::PI / 16.0;
            [l + r * a.cos(), r * a.sin()]
        }));
        rod.extend([[l, r], [-l, r]]);
        let along = weakest_direction_factor(std::slice::from_ref(&rod), [1.0, 0.0]);
        let across = weakest_direction_factor(std::slice::from_ref(&rod), [0.0, 1.0]);
        assert!((0.99..1.01).contains(&along), "along the rod: {along}");
        assert!((4.0..8.0).contains(&across), "across the rod: {across}");
        // A circle fixes every direction alike, one straight edge none.
        assert!((isotropy(std::slice::from_ref(&circle)) - 1.0).abs() < 1e-9);
        assert!(isotropy(std::slice::from_ref(&edge)) < 1e-12);
        assert!((0.01..0.2).contains(&isotropy(std::slice::from_ref(&rod))));
        // Its weakest direction is along it, a straight edge's along itself.
        let w = weakest_direction(std::slice::from_ref(&rod));
        assert!(w[0].abs() > 0.999, "rod: {w:?}");
        let w = weakest_direction(std::slice::from_ref(&edge));
        let cross = (w[0] * 1.0 - w[1] * 3.0).abs() / 10f64.sqrt();
        assert!(cross < 1e-9, "edge: {w:?}");
    }
    use crate::energy::{EnergyParams, INTENSITY_OFFSET};
    use crate::fit::{Pose, RigidTemplate};
    use crate::geometry::Polygon;
    use crate::region::{PixelRect, PrefixSums};
    use rand::{Rng, SeedableRng};
    use rand_distr::{Distribution, Normal};

    /// A 200 x 200 8-bit frame of `grey` at each pixel (x, y), rounded and
    /// clipped.
    fn frame_of(mut grey: impl FnMut(f64, f64) -> f64) -> GrayFrame {
        let (w, h) = (200u32, 200u32);
        let data = (0..w * h)
            .map(|i| grey((i % w) as f64, (i / w) as f64).round().clamp(0.0, 255.0) as u16)
            .collect();
        GrayFrame::new(w, h, 8, data).unwrap()
    }

    /// A disc of radius 30 at (`cx`, 100), grey 160 on 80, anti-aliased,
    /// plus white Gaussian noise of standard deviation `sigma`.
    fn noisy_disc(cx: f64, sigma: f64, seed: u64) -> GrayFrame {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let noise = Normal::new(0.0, sigma).unwrap();
        frame_of(|x, y| {
            let v = crate::imageio::pixel_mean(x, y, |px, py| {
                if (px - cx).hypot(py - 100.0) < 30.0 {
                    160.0
                } else {
                    80.0
                }
            });
            v + noise.sample(&mut rng) + rng.gen_range(-0.5..0.5)
        })
    }

    /// White noise along the outline has no correlation to speak of; noise
    /// smoothed along it over about 10 samples multiplies the variance of
    /// an integral by about its correlation length.
    #[test]
    fn correlated_texture_counts_more_than_white_noise() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let normal = Normal::new(0.0, 10.0).unwrap();
        let white: Vec<f64> = (0..400).map(|_| normal.sample(&mut rng)).collect();
        let factor = correlation_factor(&white, 1.0);
        assert!((1.0..1.3).contains(&factor), "white noise: factor {factor:.2}");
        // A moving average over 11 samples: the variance of a long sum
        // grows 11-fold.
        let smooth: Vec<f64> = white.windows(11).map(|w| w.iter().sum::<f64>() / 11.0).collect();
        let factor = correlation_factor(&smooth, 1.0);
        assert!(
            (5.0..=22.0).contains(&factor),
            "smoothed noise: factor {factor:.2}"
        );
    }

    /// Over 40 noisy discs, the noise estimate is right on average and the
    /// spread of the best x position on a 0.02-px grid agrees with the mean
    /// reported standard error within a factor of 1.5.
    #[test]
    fn the_reported_error_matches_the_scatter_of_the_fit() {
        let energy = EnergyParams::default();
        let (template, _) = RigidTemplate::new(&Polygon::circle([0.0, 0.0], 30.0, 64), 32, &energy);
        let (mut reported, mut found, mut sigmas) = (Vec::new(), Vec::new(), Vec::new());
        for seed in 0..40 {
            let cx = 100.0 + 0.37 * (seed % 5) as f64;
            let frame = noisy_disc(cx, 20.0, seed);
            let sums = PrefixSums::new(&frame, PixelRect::full(&frame), INTENSITY_OFFSET);
            let at = |x: f64| {
                template
                    .energy_at(
                        &sums,
                        Pose {
                            x,
                            y: 100.0,
                            theta: 0.0,
                        },
                        &energy,
                    )
                    .energy
            };
            let best = (-50..=50)
                .map(|k| cx + 0.02 * k as f64)
                .min_by(|a, b| at(*a).total_cmp(&at(*b)))
                .unwrap();
            found.push(best - cx);
            let placed = crate::fit::place(
                &template.points,
                Pose {
                    x: best,
                    y: 100.0,
                    theta: 0.0,
                },
            );
            let mut arc = placed.clone();
            arc.push(arc[0]);
            let arcs = vec![arc];
            let outward = Polygon::new(placed).signed_area().signum();
            let sigma = band_sigma(&frame, &arcs, outward, NoiseBands::default()).unwrap();
            sigmas.push(sigma);
            let terms = template.energy_at(
                &sums,
                Pose {
                    x: best,
                    y: 100.0,
                    theta: 0.0,
                },
                &energy,
            );
            let s = weighted_length(&arcs, [1.0, 0.0]);
            assert!((s - std::f64::consts::PI * 30.0).abs() < 3.0, "S {s:.1} for pi r");
            reported.push(axis_std(
                |t| at(best + t),
                sums.reference_mean(),
                [terms.mean_inside, terms.mean_outside],
                s,
                sigma,
            ));
        }
        // 130 integer samples per band: each estimate scatters by about 15%.
        let mean_sigma = sigmas.iter().sum::<f64>() / sigmas.len() as f64;
        assert!(
            (mean_sigma - 20.0).abs() < 2.0,
            "mean noise estimate {mean_sigma:.1} for 20"
        );
        let mean_reported = reported.iter().sum::<f64>() / reported.len() as f64;
        let mean = found.iter().sum::<f64>() / found.len() as f64;
        let observed = (found.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / found.len() as f64).sqrt();
        let ratio = mean_reported / observed;
        assert!(
            (1.0 / 1.5..=1.5).contains(&ratio),
            "reported {mean_reported:.4} px against observed {observed:.4} px (ratio {ratio:.2})"
        );
    }

    /// A textured disc of radius 30 at (`disc_x`, 100) on a textured
    /// substrate whose pattern is placed at `substrate_x`, its grey levels
    /// mapped by `gain` and `offset`, plus white Gaussian noise of
    /// standard deviation 5.
    fn textured(disc_x: f64, substrate_x: f64, [gain, offset]: [f64; 2], seed: u64) -> GrayFrame {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let noise = Normal::new(0.0, 5.0).unwrap();
        frame_of(|x, y| {
            let v = if (x - disc_x).hypot(y - 100.0) < 30.0 {
                160.0 + 25.0 * (0.7 * (x - disc_x)).sin() * (0.5 * y).cos()
            } else {
                80.0 + 25.0 * (0.9 * (x - substrate_x) + 0.3 * y).sin()
            };
            gain * v + offset + noise.sample(&mut rng)
        })
    }

    /// The closed outline of a disc of radius 30 centred at (`x`, 100), as
    /// one arc.
    fn disc_outline(x: f64) -> Vec<Vec<Point>> {
        let mut arc = Polygon::circle([x, 100.0], 30.0, 96).points;
        arc.push(arc[0]);
        vec![arc]
    }

    /// The sign of [`disc_outline`]'s signed area.
    fn disc_outward() -> f64 {
        Polygon::circle([0.0, 0.0], 30.0, 96).signed_area().signum()
    }

    /// Both views carry noise: the map between their grey levels is fitted
    /// across, not along, so heavy noise does not shrink its gain and
    /// leave the scene's own grey levels, which vary slowly along the
    /// outline, in the residual (a disc on a substrate darkening around
    /// it, 30 grey levels of noise in each view, 3 px apart).
    #[test]
    fn heavy_noise_in_both_views_reads_as_itself() {
        let (outline, outward) = (disc_outline, disc_outward());
        let scene = |cx: f64, seed: u64| {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            let noise = Normal::new(0.0, 30.0).unwrap();
            frame_of(|x, y| {
                let v = if (x - cx).hypot(y - 100.0) < 30.0 {
                    170.0
                } else {
                    90.0 + 50.0 * (y - 100.0).atan2(x - cx).sin()
                };
                v + noise.sample(&mut rng)
            })
        };
        let sigma = pair_sigma(
            [&scene(90.0, 1), &scene(93.0, 2)],
            [&outline(90.0), &outline(93.0)],
            outward,
            0.0,
        )
        .unwrap();
        assert!((25.0..36.0).contains(&sigma), "{sigma:.1} grey levels");
    }

    /// The pair's noise is what differs between its views: a textured
    /// disc and substrate moved 3 px together, the right view darker and
    /// flatter (0.8 v + 30), show the white noise (5 grey levels) where
    /// one view's bands show the texture; the substrate lagging the disc
    /// by 2 px shows as noise.
    #[test]
    fn the_pairs_noise_is_what_differs_between_its_views() {
        let (outline, outward) = (disc_outline, disc_outward());
        let left = textured(90.0, 90.0, [1.0, 0.0], 1);
        let (l, r) = (outline(90.0), outline(93.0));
        let view = band_sigma(&left, &l, outward, NoiseBands::default()).unwrap();
        assert!(view > 12.0, "one view's bands: {view:.1} grey levels");
        let together = textured(93.0, 93.0, [0.8, 30.0], 2);
        let sigma = pair_sigma([&left, &together], [&l, &r], outward, 0.0).unwrap();
        assert!(
            (4.0..6.5).contains(&sigma),
            "moved together: {sigma:.1} grey levels"
        );
        let lagging = textured(93.0, 91.0, [0.8, 30.0], 2);
        let lag = pair_sigma([&left, &lagging], [&l, &r], outward, 0.0).unwrap();
        assert!(
            lag > 2.0 * sigma,
            "substrate lagging: {lag:.1} against {sigma:.1} grey levels"
        );
    }
}

//! Whether the surroundings of an object moved with it between the two
//! views: their lag behind it along the disparity axis, registered over
//! the energy's window outside the object.
//!
//! Texture near an outline moves a region fit; where it moved with the
//! object (a frame shifted as a whole, a scene scanned twice, texture at
//! the object's own height) it moves both views' fits alike and the
//! disparity not at all. Where the substrate lies at another height it
//! lags, and pulls the disparity towards its own, by no more than the lag:
//! a real needle composited over its own image with the substrate lagging
//! 2-4 px behind it (`tools/substrate_lag.py`) was pulled 0.2-0.9 px. The
//! tracker adds the lag to the disparity's standard error where it
//! measures the noise on the pair (see
//! [`StereoTracker::use_pair_noise`](super::StereoTracker::use_pair_noise)).

use crate::energy::window_of;
use crate::fit::{place, Pose};
use crate::geometry::{solve3, Point, Polygon};
use crate::imageio::GrayFrame;
use crate::region::PixelRect;

use super::profile::{bilinear, correlation};

/// How far outside the outline the surroundings are registered from,
/// pixels: an edge's blur (and a dark object's rim, added to it) goes
/// with the object.
const REGISTERED_FROM_PX: f64 = 3.0;

/// Most pixels the lag is registered on: the window outside the object is
/// sampled on a grid coarse enough to keep under it.
const MAX_SAMPLES: usize = 600;

/// Farthest lag sought, whole pixels each way, before Newton steps refine
/// it (the texture's own scale bounds where they converge from); a lag
/// beyond it is reported at the edge of the range, which is as far from
/// no lag.
const MAX_LAG_PX: i32 = 4;

/// Most Newton steps of the registration.
const STEPS: usize = 6;

/// The step below which the registration has converged, pixels: as small
/// as the floor the disparity's standard error keeps for what the model
/// leaves out (`DISPARITY_STD_FLOOR_PX`).
const CONVERGED_PX: f64 = 0.02;

/// The cubic B-spline's four weights at fraction `f` of a pixel.
fn spline_weights(f: f64) -> [f64; 4] {
    let g = 1.0 - f;
    [
        g * g * g / 6.0,
        (3.0 * f * f * f - 6.0 * f * f + 4.0) / 6.0,
        (3.0 * g * g * g - 6.0 * g * g + 4.0) / 6.0,
        f * f * f / 6.0,
    ]
}

/// A frame sampled through the cubic B-spline (smoothed, not interpolated:
/// no prefilter). The pixel noise such a sample carries hardly depends on
/// where between pixels it falls (0.46-0.50 of a pixel's variance along
/// each axis), where bilinear interpolation halves it midway: registered
/// on bilinear samples, two views with noise of their own prefer
/// half-pixel lags.
struct Smoothed<'a> {
    frame: &'a GrayFrame,
}

impl Smoothed<'_> {
    /// The frame at `q`; NaN where the 4x4 pixels leave it.
    fn at(&self, q: Point) -> f64 {
        self.around(q, [0, 0])
            .map_or(f64::NAN, |([wx, wy], start)| self.sum(start, [&wx, &wy]))
    }

    /// The frame at `q - u`, `q` and `q + u`, for a unit vector `u`. Along
    /// an image axis (the usual tilt axis) the three share one check and
    /// one set of weights.
    fn along(&self, q: Point, u: Point) -> [f64; 3] {
        let axis = [0, 1]
            .into_iter()
            .find(|&a| u[a].abs() == 1.0 && u[1 - a].abs() < 1e-9);
        let Some(a) = axis else {
            return [-1.0, 0.0, 1.0].map(|t| self.at([q[0] + t * u[0], q[1] + t * u[1]]));
        };
        let mut reach = [0, 0];
        reach[a] = 1;
        let Some(([wx, wy], start)) = self.around(q, reach) else {
            return [f64::NAN; 3];
        };
        // Across the axis first, at the six positions along it the three
        // samples cover, then along it.
        let w = self.frame.width as usize;
        let (along, across) = if a == 0 { (1, w) } else { (w, 1) };
        let (w_along, w_across) = if a == 0 { (wx, wy) } else { (wy, wx) };
        let base = start - along;
        let data = &self.frame.data;
        let mut column = [0.0; 6];
        for (j, weight) in w_across.iter().enumerate() {
            let line = &data[base + j * across..=base + j * across + 5 * along];
            for (k, c) in column.iter_mut().enumerate() {
                *c += weight * f64::from(line[k * along]);
            }
        }
        let sample = |t: usize| -> f64 { (0..4).map(|i| w_along[i] * column[i + t]).sum() };
        let (minus, plus) = if u[a] > 0.0 { (0, 2) } else { (2, 0) };
        [sample(minus), sample(1), sample(plus)]
    }

    /// The weights at `q` along x and y and the index of the 4x4 block's
    /// first pixel; None where the block, grown by `reach` pixels each way
    /// along x and y, leaves the frame.
    fn around(&self, q: Point, reach: [usize; 2]) -> Option<([[f64; 4]; 2], usize)> {
        let (w, h) = (self.frame.width as usize, self.frame.height as usize);
        // Truncation is the floor where it matters (from 1 on).
        if !(q[0] >= 1.0 + reach[0] as f64 && q[1] >= 1.0 + reach[1] as f64) {
            return None;
        }
        let (x0, y0) = (q[0] as usize, q[1] as usize);
        if x0 + 2 + reach[0] >= w || y0 + 2 + reach[1] >= h {
            return None;
        }
        let weights = [spline_weights(q[0] - x0 as f64), spline_weights(q[1] - y0 as f64)];
        Some((weights, (y0 - 1) * w + x0 - 1))
    }

    /// The 4x4 block from pixel index `start`, weighted by `wx` along x and
    /// `wy` along y.
    fn sum(&self, start: usize, [wx, wy]: [&[f64; 4]; 2]) -> f64 {
        let w = self.frame.width as usize;
        let block = &self.frame.data[start..start + 3 * w + 4];
        let mut sum = 0.0;
        for (j, wy) in wy.iter().enumerate() {
            let line = &block[j * w..j * w + 4];
            let across = f64::from(line[0]) * wx[0]
                + f64::from(line[1]) * wx[1]
                + f64::from(line[2]) * wx[2]
                + f64::from(line[3]) * wx[3];
            sum += wy * across;
        }
        sum
    }
}

/// The surroundings' lag behind the object ([`lag`]).
#[derive(Clone, Copy, Debug)]
pub(super) struct Lag {
    /// Pixels along the axis.
    pub(super) px: f64,
    /// Its standard error from the registration's residual, pixels.
    pub(super) std_px: f64,
}

/// The pixels of `rect` on a grid of `step` pixels whose centres lie
/// outside `outline` grown by `grow` pixels, in image coordinates (the
/// outline rasterised on the grid itself).
fn outside(rect: PixelRect, outline: &Polygon, grow: f64, step: usize) -> Vec<Point> {
    let s = step as f64;
    let (x0, y0) = (f64::from(rect.x), f64::from(rect.y));
    let (w, h) = (
        rect.width.div_ceil(step as u32),
        rect.height.div_ceil(step as u32),
    );
    let grown = outline
        .offset_along_normals(grow)
        .scaled(1.0 / s, [-x0 / s, -y0 / s])
        .rasterize(w, h);
    (0..h as usize)
        .flat_map(|y| (0..w as usize).map(move |x| (x, y)))
        .filter(|&(x, y)| !grown[y * w as usize + x])
        .map(|(x, y)| [x0 + x as f64 * s, y0 + y as f64 * s])
        .collect()
}

/// How far the surroundings in the right view lie along `u` from where
/// the object's motion between the views puts them, pixels: the pixels of
/// the left view's energy window (`margin` around the template `points` at
/// `poses[0]`) farther than [`REGISTERED_FROM_PX`] + `rim_px` outside the
/// object, carried into the right view by the rigid motion from
/// `poses[0]` to `poses[1]`, and registered there along `u` with an affine
/// change of grey levels: the whole-pixel lag within [`MAX_LAG_PX`] whose
/// samples correlate best, refined by Newton steps on [`Smoothed`]
/// samples.
/// None with fewer than 64 pixels or no texture to register.
pub(super) fn lag(
    [left, right]: [&GrayFrame; 2],
    points: &[Point],
    poses: [Pose; 2],
    (margin, rim_px): (f64, f64),
    u: Point,
) -> Option<Lag> {
    let outline = Polygon::new(place(points, poses[0]));
    let [x0, y0, x1, y1] = window_of(&outline.points, margin);
    let (w, h) = (f64::from(left.width), f64::from(left.height));
    let rect = PixelRect::covering(
        x0.max(1.0),
        y0.max(1.0),
        x1.min(w - 2.0),
        y1.min(h - 2.0),
        left.width,
        left.height,
    )?;
    let area = rect.width as usize * rect.height as usize;
    let step = ((area as f64 / MAX_SAMPLES as f64).sqrt().ceil() as usize).max(1);
    let pixels = outside(rect, &outline, REGISTERED_FROM_PX + rim_px, step);
    // Each pixel in the template's frame, then placed at the right pose.
    let (s, c) = (-poses[0].theta).sin_cos();
    let local: Vec<Point> = pixels
        .iter()
        .map(|p| {
            let (dx, dy) = (p[0] - poses[0].x, p[1] - poses[0].y);
            [c * dx - s * dy, s * dx + c * dy]
        })
        .collect();
    let mapped = place(&local, poses[1]);
    // The whole-pixel search, on every other pixel: the left view's own
    // pixels against the right view's, interpolated bilinearly at points
    // whole pixels apart, so that every lag's samples carry alike noise.
    let sparse: Vec<(f64, Point)> = pixels
        .iter()
        .zip(&mapped)
        .step_by(2)
        .map(|(p, &q)| (bilinear(left, *p), q))
        .collect();
    let mut lag = (-MAX_LAG_PX..=MAX_LAG_PX)
        .map(f64::from)
        .map(|l| {
            let (a, b): (Vec<f64>, Vec<f64>) = sparse
                .iter()
                .map(|&(a, q)| (a, bilinear(right, [q[0] + l * u[0], q[1] + l * u[1]])))
                .filter(|(a, b)| a.is_finite() && b.is_finite())
                .unzip();
            let c = correlation(&a, &b, &vec![1.0; a.len()]);
            (l, if a.len() >= 64 { c } else { f64::NAN })
        })
        .filter(|(_, c)| c.is_finite())
        .max_by(|a, b| a.1.total_cmp(&b.1))?
        .0;
    // right = gain left + offset: one step from `lag` (the gain and offset
    // solved afresh) and the step's variance from the residual. Both views
    // are sampled half the lag either way, so that the sampling smooths
    // both alike (sampled in one view only, bilinearly, it biased a
    // sub-pixel lag by up to 0.2 px). The difference's slope in the lag is
    // taken afresh at each step, by central differences a pixel either
    // way: their noise is then uncorrelated with the residual's at any lag
    // (taken once, where the search started, the noise they shared pulled
    // the lag towards that start).
    let (left_s, right_s) = (Smoothed { frame: left }, Smoothed { frame: right });
    let step_from = |lag: f64| -> Option<(f64, f64)> {
        let h = 0.5 * lag;
        let samples: Vec<[f64; 3]> = pixels
            .iter()
            .zip(&mapped)
            .map(|(p, q)| {
                // Each view at half the lag less a pixel, at it, and at a
                // pixel more: the left one at p - h u, the right at q + h u.
                let l = left_s.along([p[0] - h * u[0], p[1] - h * u[1]], [-u[0], -u[1]]);
                let r = right_s.along([q[0] + h * u[0], q[1] + h * u[1]], u);
                [l[1], r[1], 0.25 * (r[2] - r[0] - l[2] + l[0])]
            })
            .filter(|v| v.iter().all(|x| x.is_finite()))
            .collect();
        if samples.len() < 64 {
            return None;
        }
        let mut normal = [[0.0f64; 3]; 3];
        let mut rhs = [0.0f64; 3];
        for &[v, r, slope] in &samples {
            let j = [slope, -v, -1.0];
            for a in 0..3 {
                rhs[a] -= j[a] * r;
                for b in 0..3 {
                    normal[a][b] += j[a] * j[b];
                }
            }
        }
        // Singular below a determinant of 1e-12 times the largest element cubed.
        let scale = normal.iter().flatten().map(|v| v.abs()).fold(0.0, f64::max);
        let singular = 1e-12 * scale.powi(3);
        let x = solve3(&normal, &rhs, singular)?;
        let squares: f64 = samples
            .iter()
            .map(|&[v, r, slope]| (r + slope * x[0] - v * x[1] - x[2]).powi(2))
            .sum();
        let noise = squares / (samples.len() - 3) as f64;
        // The slopes' own noise adds to their squares what no texture
        // supplies: each is a quarter of the sum of four samples, two from
        // each view, whose noise the residual carries once from each view,
        // so its variance is an eighth of the residual's. The lag's
        // variance is the residual's over what remains (the step's fixed
        // point does not depend on it); None where the slopes are noise
        // alone.
        let mut texture = normal;
        texture[0][0] -= samples.len() as f64 * noise / 8.0;
        if texture[0][0] <= 0.0 {
            return None;
        }
        // The lag's element of the inverse of the normal matrix; the step
        // is Newton's on that curvature too (the slopes' noise slowed
        // Gauss-Newton's to half a step or less).
        let unit = solve3(&texture, &[1.0, 0.0, 0.0], singular)?[0];
        let step = solve3(&texture, &rhs, singular)?[0];
        Some((step, noise * unit))
    };
    let mut variance = f64::NAN;
    for _ in 0..STEPS {
        let (step, v) = step_from(lag)?;
        variance = v;
        lag += step.clamp(-1.0, 1.0);
        if step.abs() < CONVERGED_PX {
            break;
        }
    }
    (lag.is_finite() && variance.is_finite()).then(|| Lag {
        px: lag,
        std_px: variance.max(0.0).sqrt(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tracker::tests::noisy;

    /// A bright disc of radius 25 at (`disc_x`, 80) on a substrate whose
    /// texture is placed at `substrate_x`, its grey levels mapped by
    /// `gain`.
    fn scene(disc_x: f64, substrate_x: f64, gain: f64) -> GrayFrame {
        let (w, h) = (200u32, 160u32);
        let data = (0..w * h)
            .map(|i| {
                let (x, y) = (f64::from(i % w), f64::from(i / w));
                let v = if (x - disc_x).hypot(y - 80.0) < 25.0 {
                    180.0
                } else {
                    70.0 + 30.0 * (0.45 * (x - substrate_x)).sin() * (0.3 * y).cos()
                };
                (gain * v).round() as u16
            })
            .collect();
        GrayFrame::new(w, h, 8, data).unwrap()
    }

    /// The disc moves 3 px; the substrate with it, 1 px less, or 2.5 px
    /// more; the right view 20% brighter. A flat substrate has no lag to
    /// register.
    #[test]
    fn the_surroundings_lag_behind_the_object_is_measured() {
        let points = Polygon::circle([0.0, 0.0], 25.0, 64).points;
        let left = scene(90.0, 90.0, 1.0);
        let pose = |x: f64| Pose {
            x,
            y: 80.0,
            theta: 0.0,
        };
        let poses = [pose(90.0), pose(93.0)];
        for (substrate, expected) in [(93.0, 0.0), (92.0, -1.0), (95.5, 2.5)] {
            let right = scene(93.0, substrate, 1.2);
            let lag = lag([&left, &right], &points, poses, (20.0, 0.0), [1.0, 0.0]).unwrap();
            assert!(
                (lag.px - expected).abs() < 0.1 && lag.std_px < 0.05,
                "substrate at {substrate}: lag {:.3} +- {:.3} (expected {expected})",
                lag.px,
                lag.std_px
            );
        }
        let flat = GrayFrame::new(200, 160, 8, vec![70; 200 * 160]).unwrap();
        assert!(lag([&flat, &flat], &points, poses, (20.0, 0.0), [1.0, 0.0]).is_none());
    }

    /// Along an image axis, either way, the three samples of
    /// [`Smoothed::along`] are the ones [`Smoothed::at`] takes one by one;
    /// a constant frame smooths to itself.
    #[test]
    fn samples_along_an_axis_are_the_samples_one_by_one() {
        let frame = noisy(&scene(90.0, 90.0, 1.0), 20.0, 3);
        let smoothed = Smoothed { frame: &frame };
        for u in [[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0], [1.0, -6e-17]] {
            for q in [[40.3, 50.8], [100.0, 31.25], [2.5, 2.5]] {
                let three = smoothed.along(q, u);
                let one_by_one = [-1.0, 0.0, 1.0].map(|t| smoothed.at([q[0] + t * u[0], q[1] + t * u[1]]));
                for (a, b) in three.iter().zip(one_by_one) {
                    assert!(
                        (a - b).abs() < 1e-9,
                        "u {u:?} at {q:?}: {three:?} against {one_by_one:?}"
                    );
                }
            }
        }
        let flat = GrayFrame::new(20, 20, 8, vec![70; 400]).unwrap();
        let value = Smoothed { frame: &flat }.at([7.3, 9.9]);
        assert!((value - 70.0).abs() < 1e-9, "{value}");
    }

    /// Two views with noise of their own, about as heavy as the texture's
    /// contrast, the disc moved by 2.5 px and the substrate by as much or
    /// half a pixel more: the lag is found in every draw of the noise
    /// within three of its standard errors. Sampled bilinearly, a sample
    /// between pixels carries half the noise of one on a pixel, and the
    /// registration preferred half-pixel lags (0.66 px where there was
    /// none); with the slopes taken once where the whole-pixel search
    /// started, their noise pulled the lag towards that start.
    #[test]
    fn independent_noise_pulls_the_lag_neither_to_half_pixels_nor_to_its_start() {
        let points = Polygon::circle([0.0, 0.0], 25.0, 64).points;
        let pose = |x: f64| Pose {
            x,
            y: 80.0,
            theta: 0.0,
        };
        let left = scene(90.0, 90.0, 1.0);
        for expected in [0.0, 0.5] {
            let right = scene(92.5, 92.5 + expected, 1.0);
            for seed in 0..8 {
                let views = [noisy(&left, 20.0, 2 * seed), noisy(&right, 20.0, 2 * seed + 1)];
                let lag = lag(
                    [&views[0], &views[1]],
                    &points,
                    [pose(90.0), pose(92.5)],
                    (30.0, 0.0),
                    [1.0, 0.0],
                )
                .unwrap();
                assert!(
                    (lag.px - expected).abs() < 3.0 * lag.std_px,
                    "substrate {expected} px on, draw {seed}: lag {:.3} +- {:.3}",
                    lag.px,
                    lag.std_px
                );
            }
        }
    }
}

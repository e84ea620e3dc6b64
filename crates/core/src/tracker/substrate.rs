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

/// Farthest lag sought, whole pixels each way, before Gauss-Newton
/// refines it (the texture's own scale bounds where Gauss-Newton
/// converges from); a lag beyond it is reported at the edge of the
/// range, which is as far from no lag.
const MAX_LAG_PX: i32 = 4;

/// Most Gauss-Newton steps of the registration.
const STEPS: usize = 6;

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
/// samples correlate best, refined by Gauss-Newton on bilinear samples.
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
    // Both views sampled half the lag either way, so that bilinear
    // interpolation smooths both alike (sampled in one view only, it
    // biases a sub-pixel lag by up to 0.2 px).
    let left_at = |p: &Point, d: f64| bilinear(left, [p[0] - d * u[0], p[1] - d * u[1]]);
    let right_at = |q: &Point, d: f64| bilinear(right, [q[0] + d * u[0], q[1] + d * u[1]]);
    let mut lag = (-MAX_LAG_PX..=MAX_LAG_PX)
        .map(f64::from)
        .map(|l| {
            // Every other pixel: the search only picks a whole pixel.
            let (a, b): (Vec<f64>, Vec<f64>) = pixels
                .iter()
                .zip(&mapped)
                .step_by(2)
                .map(|(p, q)| (left_at(p, 0.5 * l), right_at(q, 0.5 * l)))
                .filter(|(a, b)| a.is_finite() && b.is_finite())
                .unzip();
            let c = correlation(&a, &b, &vec![1.0; a.len()]);
            (l, if a.len() >= 64 { c } else { f64::NAN })
        })
        .filter(|(_, c)| c.is_finite())
        .max_by(|a, b| a.1.total_cmp(&b.1))?
        .0;
    // The difference's slope in the lag, taken once where the search
    // started it (Gauss-Newton with a fixed Jacobian).
    let slopes: Vec<f64> = pixels
        .iter()
        .zip(&mapped)
        .map(|(p, q)| {
            let h = 0.5 * lag;
            0.25 * (right_at(q, h + 1.0) - right_at(q, h - 1.0) - left_at(p, h + 1.0) + left_at(p, h - 1.0))
        })
        .collect();
    // right = gain left + offset: one Gauss-Newton step from `lag` (the
    // gain and offset solved afresh) and the step's variance from the
    // residual.
    let step_from = |lag: f64| -> Option<(f64, f64)> {
        let h = 0.5 * lag;
        let samples: Vec<[f64; 3]> = pixels
            .iter()
            .zip(&mapped)
            .zip(&slopes)
            .map(|((p, q), &slope)| [left_at(p, h), right_at(q, h), slope])
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
        // The lag's element of the inverse of the normal matrix.
        let unit = solve3(&normal, &[1.0, 0.0, 0.0], singular)?[0];
        Some((x[0], noise * unit))
    };
    let mut variance = f64::NAN;
    for _ in 0..STEPS {
        let (step, v) = step_from(lag)?;
        variance = v;
        lag += step.clamp(-1.0, 1.0);
        if step.abs() < 1e-3 {
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
}

//! The grey profile across an object's outline: samples along each
//! vertex's normal, compared between pairs, and between the two views of
//! a first pair, by a correlation weighted by what each vertex fixes along
//! a direction. Affine changes of the grey levels leave the correlation
//! unchanged.

use crate::fit::{Pose, RigidTemplate};
use crate::geometry::{Point, Polygon};
use crate::imageio::GrayFrame;
use crate::occlusion::SectorTemplate;

/// Where the profile is sampled along each vertex's outward normal,
/// pixels: across the edge and the grey on either side of it, as far as
/// an edge blurred over a few pixels reaches.
const OFFSETS_PX: [f64; 8] = [-6.0, -4.0, -2.0, -1.0, 1.0, 2.0, 4.0, 6.0];

/// Vertices this close to the image border, pixels, are not sampled: an
/// outline along the border (an object cut by it) is no edge of the
/// object.
const BORDER_PX: f64 = 4.0;

/// The template's outline at `pose` with its unit outward normals.
fn placed(sectors: &SectorTemplate, pose: Pose) -> (Vec<Point>, Vec<Point>) {
    let mut contour = sectors.visible_arcs(pose, &[]).swap_remove(0);
    // The closed contour repeats its first vertex at the end.
    contour.pop();
    let normals = Polygon::new(contour.clone()).outward_normals();
    (contour, normals)
}

/// The grey profile of `frame` across the outline of `sectors` placed at
/// `pose`: per vertex, the samples at [`OFFSETS_PX`] along its outward
/// normal (bilinear); NaN outside the image and near its border.
pub(super) fn profile(frame: &GrayFrame, sectors: &SectorTemplate, pose: Pose) -> Vec<f64> {
    let (contour, normals) = placed(sectors, pose);
    let (w, h) = (frame.width as f64, frame.height as f64);
    let mut samples = Vec::with_capacity(contour.len() * OFFSETS_PX.len());
    for (p, n) in contour.iter().zip(&normals) {
        let near_border =
            p[0] < BORDER_PX || p[1] < BORDER_PX || p[0] > w - 1.0 - BORDER_PX || p[1] > h - 1.0 - BORDER_PX;
        samples.extend(OFFSETS_PX.iter().map(|o| {
            if near_border {
                f64::NAN
            } else {
                bilinear(frame, [p[0] + o * n[0], p[1] + o * n[1]])
            }
        }));
    }
    samples
}

/// The profile a later slide of the template is compared with
/// ([`StereoTracker::unconfirmed_slide`](super::StereoTracker::unconfirmed_slide)):
/// [`profile`] at `pose` for a template cut by the image border, None for
/// any other (only a border-cut object's slide is judged).
pub(super) fn slide_reference(
    frame: &GrayFrame,
    (template, sectors): (&RigidTemplate, &SectorTemplate),
    pose: Pose,
) -> Option<Vec<f64>> {
    (!template.cuts.is_empty()).then(|| profile(frame, sectors, pose))
}

/// The weight of each sample of [`profile`] for a comparison along the
/// unit direction `u`: the information its vertex gives on a move along
/// `u`, `(n . u)^2` times the vertex's share of the outline's length.
pub(super) fn weights_along(sectors: &SectorTemplate, pose: Pose, u: Point) -> Vec<f64> {
    let (contour, normals) = placed(sectors, pose);
    let count = contour.len();
    let mut weights = Vec::with_capacity(count * OFFSETS_PX.len());
    for i in 0..count {
        let (a, b) = (contour[(i + count - 1) % count], contour[(i + 1) % count]);
        let length = 0.5 * (b[0] - a[0]).hypot(b[1] - a[1]);
        let along = normals[i][0] * u[0] + normals[i][1] * u[1];
        weights.extend([along * along * length; OFFSETS_PX.len()]);
    }
    weights
}

/// Pearson correlation of two profiles of one outline, each sample
/// weighted by `weights`, over the samples both have; NaN when fewer than
/// two or either is flat. In -1..=1.
pub(super) fn correlation(a: &[f64], b: &[f64], weights: &[f64]) -> f64 {
    let both = || {
        a.iter()
            .zip(b)
            .zip(weights)
            .filter(|((x, y), w)| x.is_finite() && y.is_finite() && **w > 0.0)
            .map(|((x, y), w)| (*x, *y, *w))
    };
    let (mut total, mut mean_a, mut mean_b, mut count) = (0.0, 0.0, 0.0, 0);
    for (x, y, w) in both() {
        total += w;
        mean_a += w * x;
        mean_b += w * y;
        count += 1;
    }
    if count < 2 || total <= 0.0 {
        return f64::NAN;
    }
    (mean_a, mean_b) = (mean_a / total, mean_b / total);
    let (mut ab, mut aa, mut bb) = (0.0, 0.0, 0.0);
    for (x, y, w) in both() {
        ab += w * (x - mean_a) * (y - mean_b);
        aa += w * (x - mean_a) * (x - mean_a);
        bb += w * (y - mean_b) * (y - mean_b);
    }
    ab / (aa * bb).sqrt()
}

/// Where along the unit direction `u` the outline of `sectors` in `right`
/// looks most like the `reference` profile (another view's [`profile`],
/// with its [`weights_along`] `u`): their [`correlation`] for `right_pose`
/// moved by whole pixels `d` in `-reach..=reach` along `u`, its peak
/// refined by a parabola. Returns the peak's offset from `right_pose`
/// along `u`, its correlation and the correlation at `right_pose` itself;
/// None when no shift has a finite correlation.
pub(super) fn best_shift_along(
    (reference, weights): (&[f64], &[f64]),
    right: &GrayFrame,
    sectors: &SectorTemplate,
    right_pose: Pose,
    u: Point,
    reach: i64,
) -> Option<[f64; 3]> {
    let at = |d: i64| {
        correlation(
            reference,
            &profile(right, sectors, right_pose.moved_along(u, d as f64)),
            weights,
        )
    };
    let scan: Vec<(i64, f64)> = (-reach..=reach).map(|d| (d, at(d))).collect();
    let (k, &(d, peak)) = scan
        .iter()
        .enumerate()
        .filter(|(_, (_, c))| c.is_finite())
        .max_by(|a, b| a.1 .1.total_cmp(&b.1 .1))?;
    let side = |j: Option<usize>| j.and_then(|j| scan.get(j)).map(|s| s.1).filter(|c| c.is_finite());
    let offset = match (side(k.checked_sub(1)), side(Some(k + 1))) {
        (Some(a), Some(b)) if a + b - 2.0 * peak < 0.0 => 0.5 * (a - b) / (a + b - 2.0 * peak),
        _ => 0.0,
    };
    // Shift 0 is the scan's middle.
    Some([d as f64 + offset, peak, scan[reach as usize].1])
}

/// How alike a [`profile`] (`samples`, with its [`weights_along`] a
/// direction) is to itself under its own noise: the weighted
/// [`correlation`] of each even vertex's samples with the next vertex's,
/// which see nearly the same edge with their own noise, raised to the
/// whole profile's by the Spearman-Brown formula `2 r / (1 + r)`. The
/// correlation two views that differ only by noise reach at their true
/// offset; NaN where the correlation is.
pub(super) fn reliability(samples: &[f64], weights: &[f64]) -> f64 {
    let n = OFFSETS_PX.len();
    let vertices = samples.len() / n;
    let pick = |v: &[f64], first: usize| -> Vec<f64> {
        (first..vertices.saturating_sub(1 - first))
            .step_by(2)
            .flat_map(|k| v[k * n..(k + 1) * n].iter().copied())
            .collect()
    };
    let (even, odd) = (pick(samples, 0), pick(samples, 1));
    let count = even.len().min(odd.len());
    let half = correlation(&even[..count], &odd[..count], &pick(weights, 0)[..count]);
    2.0 * half / (1.0 + half)
}

/// `frame` at the point `q`, interpolated bilinearly; NaN outside.
pub(super) fn bilinear(frame: &GrayFrame, q: Point) -> f64 {
    let (w, h) = (frame.width as i64, frame.height as i64);
    let (x0, y0) = (q[0].floor() as i64, q[1].floor() as i64);
    if x0 < 0 || y0 < 0 || x0 + 1 >= w || y0 + 1 >= h {
        return f64::NAN;
    }
    let (fx, fy) = (q[0] - x0 as f64, q[1] - y0 as f64);
    let at = |x: i64, y: i64| f64::from(frame.data[(y * w + x) as usize]);
    (1.0 - fy) * ((1.0 - fx) * at(x0, y0) + fx * at(x0 + 1, y0))
        + fy * ((1.0 - fx) * at(x0, y0 + 1) + fx * at(x0 + 1, y0 + 1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::energy::EnergyParams;
    use crate::synth::{frames, Preset, Shape, SynthConfig};

    /// The right view's outline is found where the views' profiles agree,
    /// to a fraction of a pixel, whatever the right view's grey levels; a
    /// clean view's profile is more alike to itself than a noisy one's.
    #[test]
    fn the_best_shift_finds_the_disparity_and_the_reliability_sees_the_noise() {
        let first = |preset: Preset| {
            let config = SynthConfig {
                frames: 1,
                ..SynthConfig::preset(preset, Shape::Sphere, 3)
            };
            frames(&config).unwrap().next().unwrap()
        };
        let pair = first(Preset::Clean);
        let truth = &pair.truth;
        let (template, left_pose) =
            RigidTemplate::new(&truth.left.polygon.resampled(120), 48, &EnergyParams::default());
        let sectors = SectorTemplate::new(&template, 24);
        let u = [1.0, 0.0];
        let disparity = truth.right.centroid[0] - truth.left.centroid[0];
        // The right pose 6 px short of the truth along the axis.
        let right_pose = Pose {
            x: left_pose.x + disparity - 6.0,
            y: left_pose.y + truth.right.centroid[1] - truth.left.centroid[1],
            ..left_pose
        };
        let regraded = pair.right.regraded(0.5, 40.0);
        let left = |frame: &GrayFrame| {
            (
                profile(frame, &sectors, left_pose),
                weights_along(&sectors, left_pose, u),
            )
        };
        let (reference, weights) = left(&pair.left);
        for right in [&pair.right, &regraded] {
            let [offset, best, here] =
                best_shift_along((&reference, &weights), right, &sectors, right_pose, u, 12).unwrap();
            assert!((offset - 6.0).abs() < 0.3, "offset {offset:.2}");
            assert!(
                best > 0.9 && here < best,
                "{best:.2} against {here:.2} at the pose"
            );
        }
        let clean = reliability(&reference, &weights);
        let (noisy_samples, noisy_weights) = left(&first(Preset::Noisy).left);
        let noisy = reliability(&noisy_samples, &noisy_weights);
        assert!(
            clean > 0.95 && noisy < clean,
            "clean {clean:.3}, noisy {noisy:.3}"
        );
    }

    #[test]
    fn the_correlation_ignores_an_affine_grey_change_and_sees_a_different_profile() {
        let a = [10.0, 20.0, 30.0, 25.0, 5.0];
        let gained: Vec<f64> = a.iter().map(|v| 3.0 * v + 40.0).collect();
        let weights = [1.0; 5];
        assert!((correlation(&a, &gained, &weights) - 1.0).abs() < 1e-12);
        let other = [30.0, 5.0, 10.0, 20.0, 25.0];
        assert!(correlation(&a, &other, &weights) < 0.0);
        // Samples without weight or value do not count.
        let masked = [10.0, 20.0, f64::NAN, 0.0, 5.0];
        assert!((correlation(&a, &masked, &[1.0, 1.0, 1.0, 0.0, 1.0]) - 1.0).abs() < 1e-12);
        assert!(correlation(&a, &[1.0; 5], &weights).is_nan());
    }
}

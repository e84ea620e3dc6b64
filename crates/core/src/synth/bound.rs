//! Cramér-Rao bounds on how well one rendered view places the object's edge.
//!
//! Across its edge, a rendered object's mean grey level at signed distance
//! `t` from the outline (negative inside) is
//! `b + c Phi(-(t - e) / sigma) + A R(t - e)`: the background `b`, the
//! object's contrast `c`, the edge rim `A exp((t - e) / lambda)` inside the
//! edge (`rim_strength`, `rim_width_px`), all blurred by the Gaussian of
//! width `sigma` (`blur_sigma_px`); `e` is the edge's shift from the
//! outline, the quantity an initialisation must find. A pixel's grey level
//! has the variance `mu / dose + read_noise^2` (see [`super::Noise`]).
//! Pooled over the outline's length `P`, the Fisher information of
//! `(e, sigma, lambda, A, c, b)` is `F_ij = P * integral of
//! d_i mu d_j mu / var dt`, `t` from the object's inradius inside to 12 px
//! outside; no unbiased estimator places the whole outline with a standard
//! error below `sqrt((F^-1)_ee)`, the parameters not given being unknown.
//!
//! The figure leaves out the texture, the scan lines' jitter and gain, the
//! shading and the 1-px anti-aliasing ramp, and counts a strip of constant
//! length at every depth (more pixels than a convex object has inside):
//! each of these only adds error, so the figure is a lower bound. Under a
//! 2-px blur and a rim of half the object's contrast a rim and a shift look
//! alike: with both unknown the bound on a 15-25 px wide rod is 0.3-1.2 px
//! at 15-30 electrons, with the blur's width given 0.1-0.35 px.

use super::SynthConfig;
use crate::geometry::{segment_distance, Polygon};

/// Lower bounds on the standard error (pixels) of the whole outline's shift
/// onto the edge, from one view ([`edge_shift_bound`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EdgeBound {
    /// The blur's width, the rim's strength and decay and both levels
    /// unknown.
    pub unknown: f64,
    /// The blur's width given.
    pub blur_known: f64,
    /// The blur's width and the rim given: the levels only unknown.
    pub blur_and_rim_known: f64,
}

/// The bound for the object outlined by `polygon` in a view rendered with
/// `cfg`; `None` without shot noise (no bound: the image is exact).
pub fn edge_shift_bound(cfg: &SynthConfig, polygon: &Polygon) -> Option<EdgeBound> {
    let dose = cfg.noise.dose?;
    let p = [
        0.0,
        cfg.blur_sigma_px.max(0.05),
        cfg.rim_width_px,
        cfg.rim_strength,
        cfg.object_contrast,
        cfg.background_level,
    ];
    let strip = Strip {
        dose,
        read: cfg.noise.read_noise,
        length: polygon.length(),
        inside: inradius(polygon, cfg.width, cfg.height),
    };
    Some(EdgeBound {
        unknown: strip.bound(&p, &[0, 1, 2, 3, 4, 5]),
        blur_known: strip.bound(&p, &[0, 2, 3, 4, 5]),
        blur_and_rim_known: strip.bound(&p, &[0, 4, 5]),
    })
}

/// The chance, for a whole outline shifted by a normal error of standard
/// deviation `std` (pixels) from `polygon`, that its IoU with `polygon` is
/// at least `iou` (in (0, 1)), to first order in the shift: an outward
/// shift `d` gives `area / (area + P d)`, an inward one `(area - P d) /
/// area`.
pub fn iou_chance(polygon: &Polygon, std: f64, iou: f64) -> f64 {
    let (area, length) = (polygon.area(), polygon.length());
    let outward = area * (1.0 / iou - 1.0) / length;
    let inward = (1.0 - iou) * area / length;
    phi(outward / std) - phi(-inward / std)
}

/// The standard normal distribution function.
fn phi(x: f64) -> f64 {
    0.5 * libm::erfc(-x / std::f64::consts::SQRT_2)
}

/// The pooled strip across the outline that [`edge_shift_bound`] integrates
/// over.
struct Strip {
    dose: f64,
    read: f64,
    length: f64,
    inside: f64,
}

impl Strip {
    /// Reach of the strip outside the outline, pixels.
    const OUTSIDE_PX: f64 = 12.0;
    /// Integration step, pixels.
    const STEP_PX: f64 = 0.01;

    /// `sqrt((F^-1)_ee)` with the parameters at the indices in `free`
    /// unknown (the first must be the shift's, 0).
    fn bound(&self, p: &[f64; 6], free: &[usize]) -> f64 {
        let n = free.len();
        let mut f = vec![vec![0.0; n]; n];
        let steps = ((self.inside + Self::OUTSIDE_PX) / Self::STEP_PX) as usize;
        for k in 0..steps {
            let t = -self.inside + (k as f64 + 0.5) * Self::STEP_PX;
            let var = profile(t, p) / self.dose + self.read * self.read;
            let grad: Vec<f64> = free
                .iter()
                .map(|&i| {
                    let (mut hi, mut lo) = (*p, *p);
                    hi[i] += 1e-5;
                    lo[i] -= 1e-5;
                    (profile(t, &hi) - profile(t, &lo)) / 2e-5
                })
                .collect();
            for i in 0..n {
                for j in 0..n {
                    f[i][j] += self.length * grad[i] * grad[j] / var * Self::STEP_PX;
                }
            }
        }
        first_of_inverse(f).sqrt()
    }
}

/// The mean profile across the edge at signed distance `t`, parameters
/// `[e, sigma, lambda, A, c, b]` (see the module docs).
fn profile(t: f64, p: &[f64; 6]) -> f64 {
    let [e, sigma, lambda, a, c, b] = *p;
    let u = t - e;
    let arg = -(u / sigma + sigma / lambda);
    let rim = if arg < -30.0 || a == 0.0 {
        0.0
    } else {
        (u / lambda + sigma * sigma / (2.0 * lambda * lambda)).exp() * phi(arg)
    };
    b + c * phi(-u / sigma) + a * rim
}

/// `(F^-1)_00` of a symmetric positive definite `f` (Gauss-Jordan with
/// partial pivoting); infinite when `f` is singular.
fn first_of_inverse(mut f: Vec<Vec<f64>>) -> f64 {
    let n = f.len();
    let mut inv: Vec<Vec<f64>> = (0..n)
        .map(|i| (0..n).map(|j| if i == j { 1.0 } else { 0.0 }).collect())
        .collect();
    let scale = f.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    for col in 0..n {
        let pivot = (col..n)
            .max_by(|&a, &b| f[a][col].abs().total_cmp(&f[b][col].abs()))
            .unwrap_or(col);
        f.swap(col, pivot);
        inv.swap(col, pivot);
        let d = f[col][col];
        if d.abs() <= 1e-12 * scale {
            return f64::INFINITY;
        }
        for j in 0..n {
            f[col][j] /= d;
            inv[col][j] /= d;
        }
        for row in (0..n).filter(|&r| r != col) {
            let k = f[row][col];
            for j in 0..n {
                f[row][j] -= k * f[col][j];
                inv[row][j] -= k * inv[col][j];
            }
        }
    }
    inv[0][0]
}

/// Largest distance from a pixel centre inside `polygon` to its outline.
fn inradius(polygon: &Polygon, width: u32, height: u32) -> f64 {
    let mask = polygon.rasterize(width, height);
    let edges: Vec<_> = polygon.edges().collect();
    let w = width as usize;
    mask.iter()
        .enumerate()
        .filter(|(_, &m)| m)
        .map(|(k, _)| {
            let q = [(k % w) as f64, (k / w) as f64];
            edges
                .iter()
                .map(|&(a, b)| segment_distance(q, a, b))
                .fold(f64::INFINITY, f64::min)
        })
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::{Preset, Scene, Shape};

    fn blurred_rod(seed: u64) -> (SynthConfig, Polygon) {
        let cfg = SynthConfig {
            frames: 1,
            ..SynthConfig::preset(Preset::Blurred, Shape::Rod, seed)
        };
        let polygon = Scene::new(&cfg).unwrap().render(0).truth.left.polygon;
        (cfg, polygon)
    }

    /// Without read noise the information grows with the dose, so the bound
    /// falls as `1 / sqrt(dose)`; each parameter given lowers it.
    #[test]
    fn the_bound_falls_with_the_dose_and_with_what_is_known() {
        let (mut cfg, polygon) = blurred_rod(500);
        cfg.noise.read_noise = 0.0;
        let dose = cfg.noise.dose.unwrap();
        let low = edge_shift_bound(&cfg, &polygon).unwrap();
        cfg.noise.dose = Some(4.0 * dose);
        let high = edge_shift_bound(&cfg, &polygon).unwrap();
        for (l, h) in [
            (low.unknown, high.unknown),
            (low.blur_known, high.blur_known),
            (low.blur_and_rim_known, high.blur_and_rim_known),
        ] {
            assert!((l / h - 2.0).abs() < 1e-6, "{l} / {h}");
        }
        assert!(low.unknown > 1.5 * low.blur_known, "{low:?}");
        assert!(low.blur_known > 1.5 * low.blur_and_rim_known, "{low:?}");
        cfg.noise.dose = None;
        assert_eq!(edge_shift_bound(&cfg, &polygon), None);
    }

    /// Without a rim, with the blur given and under constant noise, the
    /// bound has a closed form: the shift's information `P c^2 / var`
    /// times `integral of g^2 = 1 / (2 sqrt(pi) sigma)` (`g` the blur's
    /// density), less what the two levels take of it (their block from
    /// `integral of Phi = L`, `integral of Phi^2 = L - sigma / sqrt(pi)`,
    /// `L` the depth inside, and the strip's width; the shift's products
    /// with them `1 / 2` and `1`). Within 3%.
    #[test]
    fn a_rimless_step_is_placed_as_a_blurred_step_allows() {
        let (mut cfg, polygon) = blurred_rod(501);
        cfg.rim_strength = 0.0;
        cfg.noise.read_noise = 0.02;
        cfg.noise.dose = Some(1e12);
        let got = edge_shift_bound(&cfg, &polygon).unwrap().blur_and_rim_known;
        let (sigma, c) = (cfg.blur_sigma_px, cfg.object_contrast);
        let inside = inradius(&polygon, cfg.width, cfg.height);
        let sqrt_pi = std::f64::consts::PI.sqrt();
        // Per unit of P c^2 / var, the shift's row [e, c, b] scaled by c.
        let f_ee = 1.0 / (2.0 * sqrt_pi * sigma);
        let (f_ec, f_eb) = (0.5 / c, 1.0 / c);
        let (f_cc, f_cb, f_bb) = (
            (inside - sigma / sqrt_pi) / (c * c),
            inside / (c * c),
            (inside + Strip::OUTSIDE_PX) / (c * c),
        );
        let det = f_cc * f_bb - f_cb * f_cb;
        let taken = (f_ec * f_ec * f_bb - 2.0 * f_ec * f_eb * f_cb + f_eb * f_eb * f_cc) / det;
        let info = polygon.length() * c * c / (0.02 * 0.02) * (f_ee - taken);
        let expected = info.recip().sqrt();
        assert!((got / expected - 1.0).abs() < 0.03, "{got} against {expected}");
    }

    #[test]
    fn the_iou_chance_is_a_probability_that_falls_with_the_error() {
        let (_, polygon) = blurred_rod(502);
        let small = iou_chance(&polygon, 0.05, 0.95);
        let large = iou_chance(&polygon, 1.0, 0.95);
        assert!(small > 0.999, "{small}");
        assert!(large > 0.0 && large < 0.5, "{large}");
    }
}

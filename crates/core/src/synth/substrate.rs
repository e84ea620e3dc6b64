//! Substrate features and optics of the harder scene classes: long
//! scratches and fibres (some under the object), a multi-scale relief
//! texture with SEM-style topographic and edge contrast, and Gaussian
//! defocus blur. Everything is a pure function of the seed and the scene
//! coordinates, so both cameras see the same static substrate.

use std::f64::consts::TAU;

use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::config::{Fibres, Relief};
use super::raster::{coverage, mix64, ValueNoise};
use crate::geometry::{segment_distance, Point, Polygon};

/// Arc-length step between the vertices of a substrate line, pixels.
const LINE_STEP: f64 = 1.5;

/// A long thin line on the substrate in left-image coordinates: a straight
/// scratch or a curved fibre.
#[derive(Clone, Debug, PartialEq)]
pub struct SubstrateLine {
    /// Vertices of the centre line (open polyline, about 1.5 px apart).
    pub points: Vec<Point>,
    /// Width of the line, pixels.
    pub width_px: f64,
    /// Grey-level change at the line's centre (negative: darker than the
    /// substrate), fraction of full scale.
    pub contrast: f64,
    /// True for a curved fibre, false for a straight scratch.
    pub curved: bool,
    /// True when the line was placed to run under the object at frame 0.
    pub under_object: bool,
}

impl SubstrateLine {
    /// Smallest distance from `p` to the centre line.
    pub fn distance_to(&self, p: Point) -> f64 {
        self.points
            .windows(2)
            .map(|s| segment_distance(p, s[0], s[1]))
            .fold(f64::INFINITY, f64::min)
    }
}

/// Places `cfg.under_object` lines through random points inside `object`
/// (long enough to leave it on both sides) and `cfg.count` lines anywhere
/// in the `width x height` frame.
pub fn place_lines(
    cfg: &Fibres,
    width: f64,
    height: f64,
    object: &Polygon,
    rng: &mut ChaCha8Rng,
) -> Vec<SubstrateLine> {
    let diag = width.hypot(height);
    let b = object.bounds();
    let mut out = Vec::with_capacity(cfg.count + cfg.under_object);
    for i in 0..cfg.count + cfg.under_object {
        let under = i < cfg.under_object;
        let width_px = rng.gen_range(cfg.width_px[0]..=cfg.width_px[1]);
        let magnitude = rng.gen_range(cfg.contrast[0]..=cfg.contrast[1]);
        let contrast = if rng.gen_bool(cfg.dark_fraction) {
            -magnitude
        } else {
            magnitude
        };
        let curved = rng.gen_bool(cfg.curved_fraction);
        let heading = rng.gen_range(0.0..TAU);
        let (anchor, back, forward) = if under {
            let mut anchor = object.centroid();
            for _ in 0..1000 {
                let p = [rng.gen_range(b[0]..=b[2]), rng.gen_range(b[1]..=b[3])];
                if object.contains(p) {
                    anchor = p;
                    break;
                }
            }
            // The farthest outline point: a line whose heading deviates by
            // at most ~0.8 rad from its mean covers a chord of at least
            // 0.69 of its length, so 2.2 times that distance leaves the object.
            let reach = object
                .points
                .iter()
                .map(|p| (p[0] - anchor[0]).hypot(p[1] - anchor[1]))
                .fold(0.0, f64::max);
            let base = 2.2 * reach + 10.0;
            (
                anchor,
                base + rng.gen_range(0.0..0.3) * diag,
                base + rng.gen_range(0.0..0.3) * diag,
            )
        } else {
            let half = 0.5 * rng.gen_range(0.3..0.9) * diag;
            (
                [rng.gen_range(0.0..width), rng.gen_range(0.0..height)],
                half,
                half,
            )
        };
        let bend = if curved {
            rng.gen_range(-0.5..0.5) / (back + forward)
        } else {
            0.0
        };
        let (wiggle, wiggle_len, phase) = if curved {
            (
                rng.gen_range(0.1..0.3),
                rng.gen_range(25.0..80.0),
                rng.gen_range(0.0..TAU),
            )
        } else {
            (0.0, 1.0, 0.0)
        };
        let direction = |s: f64| heading + bend * s + wiggle * (s / wiggle_len + phase).sin();
        let walk = |len: f64, sign: f64| -> Vec<Point> {
            let n = (len / LINE_STEP).ceil() as usize;
            let mut p = anchor;
            let mut pts = Vec::with_capacity(n);
            for k in 0..n {
                let s = sign * (k as f64 + 0.5) * LINE_STEP;
                let h = direction(s);
                p = [
                    p[0] + sign * LINE_STEP * h.cos(),
                    p[1] + sign * LINE_STEP * h.sin(),
                ];
                pts.push(p);
            }
            pts
        };
        let mut points: Vec<Point> = walk(back, -1.0).into_iter().rev().collect();
        points.push(anchor);
        points.extend(walk(forward, 1.0));
        out.push(SubstrateLine {
            points,
            width_px,
            contrast,
            curved,
            under_object: under,
        });
    }
    out
}

/// Blends a substrate line, shifted by `offset`, into the row-major buffer
/// `img` of width `w`: the centre brightens or darkens by the line's
/// contrast over its anti-aliased width; a dark line (a groove) also gets a
/// thin bright edge just outside (SEM edge effect).
pub fn blend_line(img: &mut [f32], w: usize, line: &SubstrateLine, offset: Point) {
    let h = img.len() / w;
    let r = line.width_px / 2.0;
    let pad = r + 3.0;
    let pts: Vec<Point> = line
        .points
        .iter()
        .map(|p| [p[0] + offset[0], p[1] + offset[1]])
        .collect();
    let (mut minx, mut miny, mut maxx, mut maxy) =
        (f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
    for p in &pts {
        minx = minx.min(p[0]);
        miny = miny.min(p[1]);
        maxx = maxx.max(p[0]);
        maxy = maxy.max(p[1]);
    }
    let x0 = (minx - pad).floor().max(0.0);
    let y0 = (miny - pad).floor().max(0.0);
    let x1 = (maxx + pad).ceil().min(w as f64 - 1.0);
    let y1 = (maxy + pad).ceil().min(h as f64 - 1.0);
    if x1 < x0 || y1 < y0 {
        return;
    }
    let (x0, y0) = (x0 as usize, y0 as usize);
    let (bw, bh) = (x1 as usize - x0 + 1, y1 as usize - y0 + 1);
    let far = (pad * pad) as f32;
    let mut d2 = vec![far; bw * bh];
    for s in pts.windows(2) {
        let (a, b) = (s[0], s[1]);
        let xlo = ((a[0].min(b[0]) - pad).floor().max(x0 as f64)) as usize;
        let ylo = ((a[1].min(b[1]) - pad).floor().max(y0 as f64)) as usize;
        let xhi = (a[0].max(b[0]) + pad).ceil().min(x1);
        let yhi = (a[1].max(b[1]) + pad).ceil().min(y1);
        if xhi < xlo as f64 || yhi < ylo as f64 {
            continue;
        }
        for y in ylo..=yhi as usize {
            for x in xlo..=xhi as usize {
                let d = segment_distance([x as f64, y as f64], a, b);
                let cell = &mut d2[(y - y0) * bw + x - x0];
                let dd = (d * d) as f32;
                if dd < *cell {
                    *cell = dd;
                }
            }
        }
    }
    let delta = line.contrast as f32;
    let rim = if delta < 0.0 { -0.4 * delta } else { 0.0 };
    for (r_i, row) in d2.chunks_exact(bw).enumerate() {
        let dst = &mut img[(y0 + r_i) * w + x0..(y0 + r_i) * w + x0 + bw];
        for (v, &dd) in dst.iter_mut().zip(row) {
            if dd >= far {
                continue;
            }
            let outside = dd.sqrt() - r as f32;
            let mut add = delta * coverage(outside);
            if rim > 0.0 {
                let e = (outside - 0.75) / 0.9;
                add += rim * (-e * e).exp();
            }
            *v += add;
        }
    }
}

/// A lattice value in [0, 1) for integer coordinates.
#[inline]
fn hash01(seed: u64, ix: i64, iy: i64) -> f64 {
    let h = mix64(
        seed ^ (ix as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (iy as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F),
    );
    (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// Smooth value noise in [-1, 1] at (x, y) (lattice spacing 1).
fn value_noise(seed: u64, x: f64, y: f64) -> f64 {
    let (fx, fy) = (x.floor(), y.floor());
    let (ix, iy) = (fx as i64, fy as i64);
    let s = |t: f64| t * t * (3.0 - 2.0 * t);
    let (tx, ty) = (s(x - fx), s(y - fy));
    let v = |dx: i64, dy: i64| 2.0 * hash01(seed, ix + dx, iy + dy) - 1.0;
    let top = v(0, 0) + tx * (v(1, 0) - v(0, 0));
    let bottom = v(0, 1) + tx * (v(1, 1) - v(0, 1));
    top + ty * (bottom - top)
}

/// Distances to the nearest and second-nearest feature point of a
/// cellular (Worley) pattern with one jittered point per cell of size 1,
/// and a random number in [0, 1) of the nearest point's cell.
fn worley(seed: u64, x: f64, y: f64) -> (f64, f64, f64) {
    let (cx, cy) = (x.floor() as i64, y.floor() as i64);
    let (mut f1, mut f2, mut id) = (f64::INFINITY, f64::INFINITY, 0.0);
    for dy in -1..=1 {
        for dx in -1..=1 {
            let (gx, gy) = (cx + dx, cy + dy);
            let px = gx as f64 + 0.1 + 0.8 * hash01(seed, gx, gy);
            let py = gy as f64 + 0.1 + 0.8 * hash01(seed ^ 0x5555, gx, gy);
            let d = (px - x).hypot(py - y);
            if d < f1 {
                f2 = f1;
                f1 = d;
                id = hash01(seed ^ 0x3C3C, gx, gy);
            } else if d < f2 {
                f2 = d;
            }
        }
    }
    (f1, f2, id)
}

/// The relief texture of one scene, evaluated at scene coordinates.
#[derive(Clone, Debug)]
pub struct ReliefField {
    cfg: Relief,
    seed: u64,
    undulation: ValueNoise,
    speckle: ValueNoise,
    /// Direction towards the detector (topographic shadowing).
    light: Point,
}

impl ReliefField {
    /// A relief for `cfg`, its details drawn from `rng`.
    pub fn new(cfg: &Relief, rng: &mut ChaCha8Rng) -> Self {
        let light_angle = rng.gen_range(0.0..TAU);
        Self {
            cfg: cfg.clone(),
            seed: rng.gen(),
            undulation: ValueNoise::new(rng.gen(), cfg.undulation_scale_px, 3, cfg.undulation),
            speckle: ValueNoise::new(rng.gen(), 2.0, 2, cfg.speckle),
            light: [light_angle.cos(), light_angle.sin()],
        }
    }

    /// Height (pixels) of the grains and ridges at scene point (x, y), and
    /// the grain-boundary closeness exp(-(F2 - F1) / width) in [0, 1].
    fn height(&self, x: f64, y: f64) -> (f64, f64) {
        let g = self.cfg.grain_px;
        // Grains of two sizes; each grain a paraboloid dome of its own
        // height (flanks steepen towards the boundaries).
        let (f1, f2, id) = worley(self.seed, x / g, y / g);
        let big = 2.7 * g;
        let (b1, b2, bid) = worley(self.seed ^ 0x7777, x / big, y / big);
        let dome = -f1 * f1 * g * (0.2 + 1.3 * id * id) - b1 * b1 * big * 0.5 * bid;
        // Boundaries light up where a slow noise says so: some grain
        // boundaries are bright, others hardly visible.
        let patchy =
            (0.55 + 0.8 * value_noise(self.seed ^ 0x1234, x / (4.0 * g), y / (4.0 * g))).clamp(0.0, 1.0);
        let boundary = patchy * (-(f2 - f1) * g / 2.0).exp() + 0.7 * (-(b2 - b1) * big / 2.5).exp() * bid;
        let (s, c) = self.cfg.ridge_angle_rad.sin_cos();
        let along = (c * x + s * y) / (8.0 * g);
        let across = (-s * x + c * y) / (0.6 * g);
        let ridge = 1.0 - value_noise(self.seed ^ 0xA5A5, across, along).abs();
        (dome + 0.3 * g * ridge * ridge, boundary.min(1.2))
    }

    /// Adds the relief to a layer of width `lw` whose column i, row y
    /// shows the scene point (x0 + i, y).
    pub fn add_to_layer(&self, layer: &mut [f32], lw: usize, x0: f64) {
        let h = layer.len() / lw;
        // Heights on a grid one pixel larger on every side (for gradients).
        let (gw, gh) = (lw + 2, h + 2);
        let mut height = vec![0.0f64; gw * gh];
        let mut edge = vec![0.0f64; gw * gh];
        for gy in 0..gh {
            for gx in 0..gw {
                let (hv, e) = self.height(x0 + gx as f64 - 1.0, gy as f64 - 1.0);
                height[gy * gw + gx] = hv;
                edge[gy * gw + gx] = e;
            }
        }
        let (s, c) = self.cfg.ridge_angle_rad.sin_cos();
        let gc = self.cfg.grain_contrast;
        for (y, row) in layer.chunks_exact_mut(lw).enumerate() {
            for (i, v) in row.iter_mut().enumerate() {
                let at = |dx: isize, dy: isize| {
                    height[(y as isize + 1 + dy) as usize * gw + (i as isize + 1 + dx) as usize]
                };
                let hx = 0.5 * (at(1, 0) - at(-1, 0));
                let hy = 0.5 * (at(0, 1) - at(0, -1));
                let slope2 = hx * hx + hy * hy;
                // Secondary-electron yield ~ 1 / cos(tilt), detector shadowing
                // along the light direction, bright grain boundaries.
                let tilt = ((1.0 + slope2).sqrt() - 1.0).min(1.5);
                let shadow = (self.light[0] * hx + self.light[1] * hy) / (1.0 + slope2).sqrt();
                let e = edge[(y + 1) * gw + i + 1];
                let x = x0 + i as f64;
                let along = (c * x + s * y as f64) / (8.0 * self.cfg.grain_px);
                let across = (-s * x + c * y as f64) / (0.6 * self.cfg.grain_px);
                let ridge = 1.0 - value_noise(self.seed ^ 0xA5A5, across, along).abs();
                let value = gc * (0.8 * tilt + 0.6 * shadow + 0.8 * e - 0.3)
                    + self.cfg.ridges * (2.0 * ridge.powi(3) - 0.5);
                *v += value as f32;
            }
            self.undulation.add_row(x0, y as f64, row);
            self.speckle.add_row(x0, y as f64, row);
        }
    }
}

/// Gaussian blur of standard deviation `sigma` (pixels) of a row-major
/// image of width `w`, separable, with edge pixels repeated beyond the border.
pub fn gaussian_blur(img: &mut [f32], w: usize, sigma: f64) {
    if sigma <= 0.0 || w == 0 {
        return;
    }
    let h = img.len() / w;
    let radius = (3.0 * sigma).ceil() as isize;
    let mut kernel: Vec<f32> = (-radius..=radius)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp() as f32)
        .collect();
    let sum: f32 = kernel.iter().sum();
    kernel.iter_mut().for_each(|k| *k /= sum);
    let mut tmp = vec![0.0f32; img.len()];
    let clamp = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
    for y in 0..h {
        let row = &img[y * w..(y + 1) * w];
        for x in 0..w {
            let mut acc = 0.0f32;
            for (k, &g) in kernel.iter().enumerate() {
                acc += g * row[clamp(x as isize + k as isize - radius, w)];
            }
            tmp[y * w + x] = acc;
        }
    }
    for y in 0..h {
        for x in 0..w {
            let mut acc = 0.0f32;
            for (k, &g) in kernel.iter().enumerate() {
                acc += g * tmp[clamp(y as isize + k as isize - radius, h) * w + x];
            }
            img[y * w + x] = acc;
        }
    }
}

//! SEM stereo pairs rendered another way than `semdepth_core::synth`, so that
//! accuracy is also measured on scenes our generator did not make.
//!
//! The scene is three-dimensional: a substrate whose height is a sum of
//! sinusoids (wavelengths 3-220 px) with grooves and debris, and solid
//! bodies above it (a floating lens-shaped grain, a needle whose base lies
//! outside the frame, a flat plate with vertical walls). Each view is an
//! orthographic projection after a rotation about the vertical image axis
//! through the image centre, by `-tilt/2` (left) and `+tilt/2` (right), so a
//! point at height z appears at `u = x0 + (x - x0) cos(phi) + z sin(phi)`:
//! its disparity is `2 z sin(tilt/2)`, parts of one object at different
//! heights shift differently, and walls appear on opposite sides in the two
//! views. Each row is rendered as a profile (polyline) cut through the
//! surfaces, drawn into 0.25-px bins with a depth test. The brightness is
//! the secondary-electron yield of the surface facing the beam (a material
//! factor times `sec(alpha)`, capped, times an off-axis detector's tilt
//! term), so shading differs between the views; then a Gaussian probe,
//! Poisson shot noise at a dose and a per-line offset. Nothing here uses
//! the generator's code.
#![allow(dead_code)]

use semdepth_core::imageio::GrayFrame;

/// Width of a projection bin, pixels.
const BIN: f64 = 0.25;
/// Bins per pixel along x.
const BINS_PER_PX: usize = 4;
/// Sub-rows per pixel along y.
const SUBROWS: usize = 2;
/// Largest secant of the angle to the beam (grazing faces saturate).
const MAX_SECANT: f64 = 4.0;
/// Margin sampled beyond the frame, pixels.
const PAD: f64 = 12.0;

/// splitmix64: the random numbers of this renderer.
#[derive(Clone)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed ^ 0x5DEE_CE66_D1CE_4E5B)
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }
    /// Standard normal (Box-Muller).
    pub fn normal(&mut self) -> f64 {
        let u = self.unit().max(1e-300);
        let v = self.unit();
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
    /// Poisson: Knuth's product below 30, a rounded normal above.
    pub fn poisson(&mut self, lambda: f64) -> f64 {
        if lambda <= 0.0 {
            return 0.0;
        }
        if lambda > 30.0 {
            return (lambda + lambda.sqrt() * self.normal()).round().max(0.0);
        }
        let limit = (-lambda).exp();
        let (mut k, mut p) = (0.0, 1.0);
        loop {
            p *= self.unit();
            if p <= limit {
                return k;
            }
            k += 1.0;
        }
    }
}

/// The shape of a body in its own frame (x along its axis), in pixels.
#[derive(Clone, Debug)]
pub enum Shape {
    /// A lens: a star-shaped outline of mean radius `radius`
    /// (`1 + sum c_j cos(j phi + p_j)` for j = 2, 3, 4) whose top rises as
    /// a half-ellipsoid of height `thickness` above its rim.
    Lens {
        radius: f64,
        harmonics: [(f64, f64); 3],
        thickness: f64,
    },
    /// A needle along -x from its tip at the origin: radius `tip` at the
    /// tip growing by `taper` per pixel up to `shank`; a round cross-section
    /// whose widest line (the silhouette) lies at the body's height.
    Needle { tip: f64, taper: f64, shank: f64 },
    /// A rectangle `2 half[0]` x `2 half[1]` with a flat top `thickness`
    /// above its vertical walls' feet.
    Plate { half: [f64; 2], thickness: f64 },
}

impl Shape {
    /// Height above the body's base at local `(a, b)`, or `None` outside.
    fn top(&self, a: f64, b: f64) -> Option<f64> {
        match *self {
            Shape::Lens {
                radius,
                harmonics,
                thickness,
            } => {
                let phi = b.atan2(a);
                let mut r = 1.0;
                for (j, (c, p)) in harmonics.iter().enumerate() {
                    r += c * ((j as f64 + 2.0) * phi + p).cos();
                }
                let rho2 = (a * a + b * b) / (radius * r).powi(2);
                (rho2 < 1.0).then(|| thickness * (1.0 - rho2).sqrt())
            }
            Shape::Needle { tip, taper, shank } => {
                let r2 = if a > 0.0 {
                    tip * tip - a * a - b * b
                } else {
                    (tip + taper * -a).min(shank).powi(2) - b * b
                };
                (r2 > 0.0).then(|| r2.sqrt())
            }
            Shape::Plate { half, thickness } => (a.abs() < half[0] && b.abs() < half[1]).then_some(thickness),
        }
    }

    /// Height of the wall's foot above the base where the outline is
    /// crossed (walls only for the plate).
    fn has_walls(&self) -> bool {
        matches!(self, Shape::Plate { .. })
    }

    /// Radius of a disc around the local origin holding the shape.
    fn reach(&self) -> f64 {
        match *self {
            Shape::Lens {
                radius, harmonics, ..
            } => radius * (1.0 + harmonics.iter().map(|h| h.0.abs()).sum::<f64>()),
            Shape::Needle { .. } => 4000.0,
            Shape::Plate { half, .. } => half[0].hypot(half[1]),
        }
    }
}

/// Where a body is in one frame: centre (or needle tip) in the scene's
/// x-y plane, rotation, and the height of its base (lens rim, needle axis,
/// plate wall feet), all in pixels.
#[derive(Clone, Copy, Debug)]
pub struct Pose {
    pub centre: [f64; 2],
    pub angle: f64,
    pub z: f64,
}

/// A body: shape, material (yield relative to the substrate's mean) and
/// its pose in every frame.
#[derive(Clone, Debug)]
pub struct Body {
    pub shape: Shape,
    pub material: f64,
    pub poses: Vec<Pose>,
}

impl Body {
    fn top(&self, k: usize, x: f64, y: f64) -> Option<f64> {
        let p = self.poses[k];
        let (s, c) = p.angle.sin_cos();
        let (dx, dy) = (x - p.centre[0], y - p.centre[1]);
        self.shape.top(c * dx + s * dy, -s * dx + c * dy).map(|t| p.z + t)
    }

    /// Height at which the silhouette lies: its disparity is the body's.
    pub fn silhouette_z(&self, k: usize) -> f64 {
        let p = self.poses[k];
        match self.shape {
            Shape::Plate { thickness, .. } => p.z + thickness / 2.0,
            _ => p.z,
        }
    }
}

/// A line groove in the substrate: from `a` to `b`, depth and width (px).
#[derive(Clone, Debug)]
struct Groove {
    a: [f64; 2],
    b: [f64; 2],
    depth: f64,
    width: f64,
}

/// The substrate: sinusoids `(amplitude, fx, fy, phase)`, grooves, debris
/// `(x, y, radius)` and a slowly varying material `(amplitude, fx, fy,
/// phase)`.
#[derive(Clone, Debug)]
pub struct Substrate {
    waves: Vec<(f64, f64, f64, f64)>,
    grooves: Vec<Groove>,
    debris: Vec<(f64, f64, f64)>,
    material: Vec<(f64, f64, f64, f64)>,
}

impl Substrate {
    /// `roughness` scales every slope (0 gives a flat, uniform substrate).
    pub fn random(
        rng: &mut Rng,
        width: f64,
        height: f64,
        roughness: f64,
        grooves: usize,
        debris: usize,
    ) -> Self {
        let waves = (0..48)
            .map(|_| {
                let wavelength = (3f64.ln() + rng.unit() * (220f64 / 3.0).ln()).exp();
                let dir = rng.range(0.0, std::f64::consts::TAU);
                let slope = roughness * rng.range(0.02, 0.07);
                (
                    slope * wavelength / std::f64::consts::TAU,
                    dir.cos() / wavelength,
                    dir.sin() / wavelength,
                    rng.range(0.0, std::f64::consts::TAU),
                )
            })
            .collect();
        let grooves = (0..grooves)
            .map(|_| {
                let c = [rng.range(0.0, width), rng.range(0.0, height)];
                let dir = rng.range(0.0, std::f64::consts::PI);
                let half = rng.range(0.3, 0.8) * width;
                Groove {
                    a: [c[0] - half * dir.cos(), c[1] - half * dir.sin()],
                    b: [c[0] + half * dir.cos(), c[1] + half * dir.sin()],
                    depth: rng.range(0.8, 2.5),
                    width: rng.range(0.6, 1.8),
                }
            })
            .collect();
        let debris = (0..debris)
            .map(|_| (rng.range(0.0, width), rng.range(0.0, height), rng.range(1.5, 5.0)))
            .collect();
        let material = (0..6)
            .map(|_| {
                let wavelength = rng.range(120.0, 500.0);
                let dir = rng.range(0.0, std::f64::consts::TAU);
                (
                    rng.range(0.01, 0.04),
                    dir.cos() / wavelength,
                    dir.sin() / wavelength,
                    rng.range(0.0, std::f64::consts::TAU),
                )
            })
            .collect();
        Substrate {
            waves,
            grooves,
            debris,
            material,
        }
    }

    /// A substrate without relief, grooves or debris: only its material's
    /// slow variation (wavelengths 120-500 px) shades it.
    pub fn flat(rng: &mut Rng, width: f64, height: f64) -> Self {
        Self::random(rng, width, height, 0.0, 0, 0)
    }

    /// Height, its gradient and the material factor along the sub-row `y`
    /// at `x = x0 + i BIN`, `n` samples.
    fn profile(&self, y: f64, x0: f64, n: usize) -> Vec<[f64; 4]> {
        let mut out = vec![[0.0, 0.0, 0.0, 1.0]; n];
        for &(amp, fx, fy, phase) in &self.waves {
            let tau = std::f64::consts::TAU;
            let (mut s, mut c) = (tau * (fx * x0 + fy * y) + phase).sin_cos();
            let (ds, dc) = (tau * fx * BIN).sin_cos();
            for o in out.iter_mut() {
                o[0] += amp * c;
                o[1] -= amp * tau * fx * s;
                o[2] -= amp * tau * fy * s;
                (s, c) = (s * dc + c * ds, c * dc - s * ds);
            }
        }
        for (i, o) in out.iter_mut().enumerate() {
            let x = x0 + i as f64 * BIN;
            for &(amp, fx, fy, phase) in &self.material {
                o[3] += amp * (std::f64::consts::TAU * (fx * x + fy * y) + phase).cos();
            }
            for g in &self.grooves {
                let (ux, uy) = (g.b[0] - g.a[0], g.b[1] - g.a[1]);
                let len2 = ux * ux + uy * uy;
                let t = (((x - g.a[0]) * ux + (y - g.a[1]) * uy) / len2).clamp(0.0, 1.0);
                let (dx, dy) = (x - g.a[0] - t * ux, y - g.a[1] - t * uy);
                let d2 = dx * dx + dy * dy;
                if d2 > 16.0 * g.width * g.width {
                    continue;
                }
                let e = (-d2 / (2.0 * g.width * g.width)).exp();
                o[0] -= g.depth * e;
                o[1] += g.depth * e * dx / (g.width * g.width);
                o[2] += g.depth * e * dy / (g.width * g.width);
            }
            for &(cx, cy, r) in &self.debris {
                let (dx, dy) = (x - cx, y - cy);
                let rho2 = (dx * dx + dy * dy) / (r * r);
                if rho2 >= 1.0 {
                    continue;
                }
                let root = (1.0 - rho2).sqrt().max(0.05);
                o[0] += r * root;
                o[1] -= dx / (r * root);
                o[2] -= dy / (r * root);
            }
        }
        out
    }
}

/// Imaging conditions.
#[derive(Clone, Debug)]
pub struct Imaging {
    /// Total tilt between the views, radians.
    pub tilt: f64,
    /// Electrons per pixel at the substrate's mean yield.
    pub dose: f64,
    /// Probe width (Gaussian sigma), pixels.
    pub probe_sigma: f64,
    /// Grey level of the substrate's mean yield (8-bit).
    pub grey: f64,
    /// Sigma of the per-line offset, grey levels.
    pub line_noise: f64,
}

/// A scene: size, substrate, bodies (the first is the one measured),
/// imaging and a seed for the noise.
#[derive(Clone, Debug)]
pub struct TiltedScene {
    pub width: usize,
    pub height: usize,
    pub substrate: Substrate,
    pub bodies: Vec<Body>,
    pub imaging: Imaging,
    pub seed: u64,
    /// The substrate's bins in each view (it does not move): computed on
    /// the first render.
    pub ground: std::sync::OnceLock<[Vec<f32>; 2]>,
}

/// One rendered pair with the truth about body 0.
pub struct TiltedPair {
    pub left: GrayFrame,
    pub right: GrayFrame,
    /// Body 0's visible pixels (at least half covered) in each view.
    pub left_mask: Vec<bool>,
    pub right_mask: Vec<bool>,
    /// Body 0's disparity along x, pixels: `2 z sin(tilt/2)` at its
    /// silhouette's height.
    pub disparity_px: f64,
    /// Body 0's reference point (centre, needle tip) in the left view.
    pub left_point: [f64; 2],
}

impl TiltedPair {
    /// The first and last columns and rows of body 0's left mask.
    pub fn left_bounds(&self) -> [usize; 4] {
        let w = self.left.width as usize;
        let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
        for (i, _) in self.left_mask.iter().enumerate().filter(|(_, &m)| m) {
            let (x, y) = (i % w, i / w);
            (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
        }
        [x0, y0, x1, y1]
    }

    /// A `roi` hint `[x, y, width, height]` 10% larger per side than body
    /// 0's left mask, as a person draws it.
    pub fn roi_hint(&self) -> [i64; 4] {
        let [x0, y0, x1, y1] = self.left_bounds();
        let (gx, gy) = (0.1 * (x1 - x0) as f64, 0.1 * (y1 - y0) as f64);
        [
            (x0 as f64 - gx).floor() as i64,
            (y0 as f64 - gy).floor() as i64,
            ((x1 - x0) as f64 + 2.0 * gx).ceil() as i64 + 1,
            ((y1 - y0) as f64 + 2.0 * gy).ceil() as i64 + 1,
        ]
    }

    /// A `point` hint: the centre of body 0's left mask's pixel nearest
    /// its centroid, where a person clicks.
    pub fn point_hint(&self) -> [f64; 2] {
        let w = self.left.width as usize;
        let pts: Vec<[f64; 2]> = (0..self.left_mask.len())
            .filter(|&i| self.left_mask[i])
            .map(|i| [(i % w) as f64 + 0.5, (i / w) as f64 + 0.5])
            .collect();
        let n = pts.len() as f64;
        let c = [
            pts.iter().map(|p| p[0]).sum::<f64>() / n,
            pts.iter().map(|p| p[1]).sum::<f64>() / n,
        ];
        let d = |p: &[f64; 2]| (p[0] - c[0]).hypot(p[1] - c[1]);
        *pts.iter()
            .min_by(|a, b| d(a).total_cmp(&d(b)))
            .expect("body 0 is in view")
    }
}

/// Label of the substrate in the bins.
const SUBSTRATE: u8 = u8::MAX;

/// One view's bins of one sub-row: depth, yield and what is seen.
struct Bins {
    depth: Vec<f64>,
    value: Vec<f64>,
    label: Vec<u8>,
}

impl TiltedScene {
    /// The direction towards the viewer of a view tilted by `phi`.
    fn view(phi: f64) -> [f64; 3] {
        [-phi.sin(), 0.0, phi.cos()]
    }

    /// Draws the profile `pts` (x, z, dz/dy) with material `m` and label
    /// into the bins of the view tilted by `phi`.
    fn draw(&self, bins: &mut Bins, phi: f64, pts: &[[f64; 3]], m: f64, label: u8) {
        let x0 = self.width as f64 / 2.0;
        let (s, c) = phi.sin_cos();
        let e = Self::view(phi);
        // An Everhart-Thornley detector off to the upper left.
        let det = [-0.55, -0.45, 0.70];
        let n_bins = bins.depth.len();
        for seg in pts.windows(2) {
            let ([xa, za, ga], [xb, zb, gb]) = (seg[0], seg[1]);
            let (dx, dz) = (xb - xa, zb - za);
            let gy = 0.5 * (ga + gb);
            let n = [-dz, -gy * dx, dx];
            let norm = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            if norm == 0.0 {
                continue;
            }
            let cos_a = (n[0] * e[0] + n[1] * e[1] + n[2] * e[2]) / norm;
            if cos_a <= 0.0 {
                continue;
            }
            let tilt_term = 1.0 + 0.3 * (n[0] * det[0] + n[1] * det[1] + n[2] * det[2]) / norm;
            let value = m * (1.0 / cos_a).min(MAX_SECANT) * tilt_term;
            let (ua, ub) = (x0 + (xa - x0) * c + za * s, x0 + (xb - x0) * c + zb * s);
            let (wa, wb) = (-(xa - x0) * s + za * c, -(xb - x0) * s + zb * c);
            let (lo, hi) = if ua < ub { (ua, ub) } else { (ub, ua) };
            let first = ((lo + PAD) / BIN - 0.5).ceil().max(0.0) as usize;
            let mut i = first;
            while i < n_bins {
                let u = (i as f64 + 0.5) * BIN - PAD;
                if u >= hi {
                    break;
                }
                let t = if ub == ua { 0.5 } else { (u - ua) / (ub - ua) };
                let w = wa + t * (wb - wa);
                if w > bins.depth[i] {
                    bins.depth[i] = w;
                    bins.value[i] = value;
                    bins.label[i] = label;
                }
                i += 1;
            }
        }
    }

    /// Profile of body `b` along the sub-row `y` in frame `k`: its runs of
    /// samples, each closed by the outline's crossings found by bisection.
    fn body_profiles(&self, b: usize, k: usize, y: f64) -> Vec<Vec<[f64; 3]>> {
        let body = &self.bodies[b];
        let p = body.poses[k];
        let reach = body.shape.reach();
        if (y - p.centre[1]).abs() > reach {
            return Vec::new();
        }
        let half = (reach * reach - (y - p.centre[1]).powi(2)).max(0.0).sqrt();
        let xa = (p.centre[0] - half).max(-PAD);
        let xb = (p.centre[0] + half).min(self.width as f64 + PAD);
        if xb <= xa {
            return Vec::new();
        }
        let top = |x: f64, y: f64| body.top(k, x, y);
        let slope_y = |x: f64, z: f64| {
            let h = 0.05;
            match (top(x, y + h), top(x, y - h)) {
                (Some(a), Some(b)) => (a - b) / (2.0 * h),
                (Some(a), None) => (a - z) / h,
                (None, Some(b)) => (z - b) / h,
                _ => 0.0,
            }
        };
        let edge = |inside: f64, outside: f64| {
            let (mut i, mut o) = (inside, outside);
            for _ in 0..12 {
                let m = 0.5 * (i + o);
                if top(m, y).is_some() {
                    i = m;
                } else {
                    o = m;
                }
            }
            i
        };
        let foot = p.z;
        let walls = body.shape.has_walls();
        let n = ((xb - xa) / BIN).ceil() as usize + 1;
        let mut runs = Vec::new();
        let mut run: Vec<[f64; 3]> = Vec::new();
        let mut prev_x = xa - BIN;
        for i in 0..n {
            let x = xa + i as f64 * BIN;
            match top(x, y) {
                Some(z) => {
                    if run.is_empty() {
                        let xe = if i == 0 { x } else { edge(x, prev_x) };
                        let ze = top(xe, y).unwrap_or(z);
                        if walls || i > 0 {
                            run.push([xe, if walls { foot } else { ze.min(foot) }, 0.0]);
                        }
                        if walls {
                            run.push([xe, ze, slope_y(xe, ze)]);
                        }
                    }
                    run.push([x, z, slope_y(x, z)]);
                }
                None => {
                    if !run.is_empty() {
                        let xe = edge(prev_x, x);
                        let ze = top(xe, y).unwrap_or(foot);
                        if walls {
                            run.push([xe, ze, slope_y(xe, ze)]);
                        }
                        run.push([xe, if walls { foot } else { ze.min(foot) }, 0.0]);
                        runs.push(std::mem::take(&mut run));
                    }
                }
            }
            prev_x = x;
        }
        if !run.is_empty() {
            runs.push(run);
        }
        runs
    }

    /// The substrate drawn into the bins of every sub-row of both views.
    fn ground_bins(&self, n_bins: usize, n_sub: usize) -> [Vec<f32>; 2] {
        let phis = [-self.imaging.tilt / 2.0, self.imaging.tilt / 2.0];
        let rows = self.height * SUBROWS;
        let mut out = [
            Vec::with_capacity(rows * n_bins),
            Vec::with_capacity(rows * n_bins),
        ];
        for r in 0..rows {
            let y = (r as f64 + 0.5) / SUBROWS as f64;
            let ground = self.substrate.profile(y, -PAD, n_sub);
            for (v, &phi) in phis.iter().enumerate() {
                let mut bins = Bins {
                    depth: vec![f64::NEG_INFINITY; n_bins],
                    value: vec![0.0; n_bins],
                    label: vec![SUBSTRATE; n_bins],
                };
                for (i, pair) in ground.windows(2).enumerate() {
                    let (a, b) = (pair[0], pair[1]);
                    let x = -PAD + i as f64 * BIN;
                    let gy = 0.5 * (a[2] + b[2]);
                    let pts = [[x, a[0], gy], [x + BIN, b[0], gy]];
                    self.draw(&mut bins, phi, &pts, 0.5 * (a[3] + b[3]), SUBSTRATE);
                }
                out[v].extend(bins.value.iter().map(|&g| g as f32));
            }
        }
        out
    }

    /// Renders frame `k`.
    pub fn render(&self, k: usize) -> TiltedPair {
        let (w, h) = (self.width, self.height);
        let n_bins = ((w as f64 + 2.0 * PAD) / BIN) as usize;
        let n_sub = ((w as f64 + 2.0 * PAD) / BIN) as usize + 1;
        let phis = [-self.imaging.tilt / 2.0, self.imaging.tilt / 2.0];
        let mut yields = [vec![0.0f64; w * h], vec![0.0f64; w * h]];
        let mut covered = [vec![0u8; w * h], vec![0u8; w * h]];
        let ground = self.ground.get_or_init(|| self.ground_bins(n_bins, n_sub));
        for row in 0..h {
            for sub in 0..SUBROWS {
                let y = row as f64 + (sub as f64 + 0.5) / SUBROWS as f64;
                let at = (row * SUBROWS + sub) * n_bins;
                for (v, &phi) in phis.iter().enumerate() {
                    let mut bins = Bins {
                        depth: vec![f64::NEG_INFINITY; n_bins],
                        value: ground[v][at..at + n_bins].iter().map(|&g| g as f64).collect(),
                        label: vec![SUBSTRATE; n_bins],
                    };
                    for b in 0..self.bodies.len() {
                        for run in self.body_profiles(b, k, y) {
                            self.draw(&mut bins, phi, &run, self.bodies[b].material, b as u8);
                        }
                    }
                    let off = (PAD / BIN) as usize;
                    for x in 0..w {
                        let mut sum = 0.0;
                        let mut mine = 0u8;
                        for j in 0..BINS_PER_PX {
                            let i = off + x * BINS_PER_PX + j;
                            sum += bins.value[i];
                            mine += (bins.label[i] == 0) as u8;
                        }
                        yields[v][row * w + x] += sum / (BINS_PER_PX * SUBROWS) as f64;
                        covered[v][row * w + x] += mine;
                    }
                }
            }
        }
        let half_cover = (BINS_PER_PX * SUBROWS / 2) as u8;
        let mut frames = Vec::with_capacity(2);
        for (v, y) in yields.iter().enumerate() {
            let blurred = blur(y, w, h, self.imaging.probe_sigma);
            let mut rng = Rng::new(self.seed.wrapping_mul(1_000_003) ^ (2 * k as u64 + v as u64));
            let scale = self.imaging.grey / self.imaging.dose;
            let mut data = Vec::with_capacity(w * h);
            for r in 0..h {
                let line = self.imaging.line_noise * rng.normal();
                for x in 0..w {
                    let counts = rng.poisson(self.imaging.dose * blurred[r * w + x]);
                    data.push((counts * scale + line).round().clamp(0.0, 255.0) as u16);
                }
            }
            frames.push(GrayFrame {
                width: w as u32,
                height: h as u32,
                bit_depth: 8,
                data,
            });
        }
        let body = &self.bodies[0];
        let z = body.silhouette_z(k);
        let p = body.poses[k].centre;
        let x0 = w as f64 / 2.0;
        let (s, c) = (self.imaging.tilt / 2.0).sin_cos();
        let right = frames.pop().unwrap();
        let left = frames.pop().unwrap();
        TiltedPair {
            left,
            right,
            left_mask: covered[0].iter().map(|&n| n >= half_cover).collect(),
            right_mask: covered[1].iter().map(|&n| n >= half_cover).collect(),
            disparity_px: 2.0 * z * s,
            left_point: [x0 + (p[0] - x0) * c - z * s, p[1]],
        }
    }
}

/// Separable Gaussian blur (edges clamped).
pub fn blur(src: &[f64], w: usize, h: usize, sigma: f64) -> Vec<f64> {
    if sigma <= 0.0 {
        return src.to_vec();
    }
    let r = (3.0 * sigma).ceil() as i64;
    let kernel: Vec<f64> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let total: f64 = kernel.iter().sum();
    let kernel: Vec<f64> = kernel.iter().map(|k| k / total).collect();
    // One pass along x (step 1, `w` per row) or y (step `w`, 1 per
    // column), edges clamped.
    let pass = |src: &[f64], step: usize, len: usize| -> Vec<f64> {
        (0..w * h)
            .map(|i| {
                let at = (i / step) % len;
                kernel
                    .iter()
                    .enumerate()
                    .map(|(j, k)| {
                        let t = (at as i64 + j as i64 - r).clamp(0, len as i64 - 1) as usize;
                        k * src[i - at * step + t * step]
                    })
                    .sum()
            })
            .collect()
    };
    pass(&pass(src, 1, w), w, h)
}

/// The scene classes measured on this renderer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Class {
    /// A bright grain floating above a rough substrate, drifting.
    Grain,
    /// A grain darker than the substrate (its steep rim is still bright).
    DarkGrain,
    /// A needle entering from a border, moving along its axis.
    Needle,
    /// A flat plate with walls, brighter than the substrate.
    Plate,
    /// A bright grain (the object) with a needle above it that sweeps in
    /// over part of it and back out, with its own height and disparity.
    Crossed,
    /// The same scene with the needle as the object: a tool passing over a
    /// particle as bright as itself.
    CrossedTool,
}

impl Class {
    pub const ALL: [Class; 6] = [
        Class::Grain,
        Class::DarkGrain,
        Class::Needle,
        Class::Plate,
        Class::Crossed,
        Class::CrossedTool,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Class::Grain => "grain",
            Class::DarkGrain => "dark_grain",
            Class::Needle => "needle",
            Class::Plate => "plate",
            Class::Crossed => "crossed",
            Class::CrossedTool => "crossed_tool",
        }
    }
}

/// A scene of `class` with `frames` frames, 640 x 480, drawn from `seed`:
/// the body drifts 0.5-3 px per pair, turns up to 0.004 rad per pair and
/// its height swings by up to 25 px (2.6 px of disparity at the 6 degree
/// tilt); the substrate has grooves (some under the body) and debris.
pub fn scene(class: Class, seed: u64, frames: usize) -> TiltedScene {
    let (width, height) = (640usize, 480usize);
    let (wf, hf) = (width as f64, height as f64);
    let mut rng = Rng::new(seed.wrapping_mul(0x2545_F491_4F6C_DD1D) ^ class as u64);
    let roughness = rng.range(0.6, 1.4);
    let substrate = Substrate::random(&mut rng, wf, hf, roughness, 4, 30);
    let z0 = rng.range(50.0, 110.0);
    let swing = rng.range(5.0, 25.0);
    let period = rng.range(12.0, 30.0);
    let speed = rng.range(0.5, 3.0);
    let heading = rng.range(0.0, std::f64::consts::TAU);
    let spin = rng.range(-0.004, 0.004);
    let (shape, material, start, angle, velocity) = match class {
        Class::Grain | Class::DarkGrain | Class::Crossed | Class::CrossedTool => {
            let radius = rng.range(28.0, 55.0);
            let harmonics = [
                (rng.range(0.0, 0.12), rng.range(0.0, 6.3)),
                (rng.range(0.0, 0.08), rng.range(0.0, 6.3)),
                (rng.range(0.0, 0.05), rng.range(0.0, 6.3)),
            ];
            let material = if class != Class::DarkGrain {
                rng.range(1.3, 1.8)
            } else {
                rng.range(0.45, 0.7)
            };
            let shape = Shape::Lens {
                radius,
                harmonics,
                thickness: radius * rng.range(0.5, 1.0),
            };
            let start = [rng.range(0.35, 0.65) * wf, rng.range(0.35, 0.65) * hf];
            let v = [speed * heading.cos(), speed * heading.sin()];
            (shape, material, start, rng.range(0.0, 6.3), v)
        }
        Class::Needle => {
            // From one of the four borders, pointing inwards within 35
            // degrees of the normal, tip 90-220 px in.
            let side = (rng.next_u64() % 4) as usize;
            let normal: f64 = [0.0, 0.5, 1.0, 1.5][side] * std::f64::consts::PI;
            let angle = normal + rng.range(-0.6, 0.6);
            let depth = rng.range(90.0, 220.0);
            let along = rng.range(0.3, 0.7);
            let start = match side {
                0 => [depth, along * hf],
                1 => [along * wf, depth],
                2 => [wf - depth, along * hf],
                _ => [along * wf, hf - depth],
            };
            let shape = Shape::Needle {
                tip: rng.range(2.0, 5.0),
                taper: rng.range(0.12, 0.3),
                shank: rng.range(10.0, 18.0),
            };
            // In and out along its axis, and a little sideways.
            let v = [speed * angle.cos(), speed * angle.sin()];
            (shape, rng.range(1.4, 2.0), start, angle, v)
        }
        Class::Plate => {
            let shape = Shape::Plate {
                half: [rng.range(30.0, 60.0), rng.range(12.0, 25.0)],
                thickness: rng.range(4.0, 12.0),
            };
            let start = [rng.range(0.35, 0.65) * wf, rng.range(0.35, 0.65) * hf];
            let v = [speed * heading.cos(), speed * heading.sin()];
            (shape, rng.range(1.3, 1.7), start, rng.range(0.0, 6.3), v)
        }
    };
    let needle = class == Class::Needle;
    let poses = (0..frames)
        .map(|k| {
            let t = k as f64;
            // The needle goes in and out along its axis (a triangle wave
            // of 8 pairs each way); the others drift on.
            let travel = if needle {
                let phase = (t / 8.0).rem_euclid(2.0);
                if phase < 1.0 {
                    8.0 * phase
                } else {
                    8.0 * (2.0 - phase)
                }
            } else {
                t
            };
            Pose {
                centre: [start[0] + velocity[0] * travel, start[1] + velocity[1] * travel],
                angle: angle + if needle { 0.0 } else { spin * t },
                z: z0 + swing * (std::f64::consts::TAU * t / period).sin(),
            }
        })
        .collect();
    let mut bodies = vec![Body {
        shape,
        material,
        poses,
    }];
    if matches!(class, Class::Crossed | Class::CrossedTool) {
        bodies.push(crossing_needle(&bodies[0], seed, frames));
    }
    if class == Class::CrossedTool {
        bodies.swap(0, 1);
    }
    TiltedScene {
        width,
        height,
        substrate,
        bodies,
        imaging: Imaging {
            tilt: 6f64.to_radians(),
            dose: rng.range(12.0, 40.0),
            probe_sigma: rng.range(0.5, 1.0),
            grey: 90.0,
            line_noise: 1.5,
        },
        seed,
        ground: Default::default(),
    }
}

/// A needle above `grain` that comes in from 50 px beyond its rim along a
/// random direction, passes a random side of its centre and reaches up to
/// half its radius past the centre line in 10 pairs, then goes back; it
/// follows the grain's drift and stays 15-35 px above the grain's top,
/// with a height swing of its own.
fn crossing_needle(grain: &Body, seed: u64, frames: usize) -> Body {
    let mut rng = Rng::new(seed ^ 0x00C0_55ED_0000_0001);
    let Shape::Lens {
        radius, thickness, ..
    } = grain.shape
    else {
        unreachable!("the crossed grain is a lens")
    };
    let dir = rng.range(0.0, std::f64::consts::TAU);
    let (c, s) = (dir.cos(), dir.sin());
    let side = rng.range(-0.5, 0.5) * radius;
    let run = radius + 50.0 + rng.range(0.0, 0.5) * radius;
    let above = thickness + rng.range(15.0, 35.0);
    let (swing, period) = (rng.range(0.0, 8.0), rng.range(10.0, 25.0));
    let shape = Shape::Needle {
        tip: rng.range(2.0, 4.0),
        taper: rng.range(0.15, 0.3),
        shank: rng.range(9.0, 14.0),
    };
    let poses = (0..frames)
        .map(|k| {
            let g = grain.poses[k];
            let phase = (k as f64 / 10.0).rem_euclid(2.0);
            let travel = run * if phase < 1.0 { phase } else { 2.0 - phase };
            let back = radius + 50.0 - travel;
            Pose {
                centre: [
                    g.centre[0] - back * c - side * s,
                    g.centre[1] - back * s + side * c,
                ],
                angle: dir,
                z: g.z + above + swing * (std::f64::consts::TAU * k as f64 / period).sin(),
            }
        })
        .collect();
    Body {
        shape,
        material: rng.range(1.5, 2.0),
        poses,
    }
}

/// Where the tracked contour puts body 0's reference point, as an error
/// against the truth, pair by pair: a needle's tip is carried by the
/// contour from the first tracked pair (its centroid is that of the part
/// inside the frame); the others' centres are the truth's reference
/// point. A fresh initialisation makes a new template, and the carried
/// point starts again from it.
pub struct ReferencePoint {
    carried_by_contour: bool,
    anchor: Option<semdepth_core::geometry::CarriedPoint>,
}

impl ReferencePoint {
    pub fn new(class: Class) -> Self {
        Self {
            carried_by_contour: matches!(class, Class::Needle | Class::CrossedTool),
            anchor: None,
        }
    }

    /// The reference point's error (tracked minus truth), pixels, for a
    /// tracked or initialised `result` of `pair`.
    pub fn error(&mut self, pair: &TiltedPair, result: &semdepth_core::tracker::PairResult) -> [f64; 2] {
        let left = result.left.as_ref().expect("a tracked pair has a left contour");
        if result.status == semdepth_core::tracker::Status::Initialised {
            self.anchor = None;
        }
        let by_contour = self.carried_by_contour;
        let carried = self.anchor.get_or_insert_with(|| {
            let at = if by_contour {
                left.centroid
            } else {
                pair.left_point
            };
            semdepth_core::geometry::CarriedPoint::new(pair.left_point, at, left.angle_rad)
        });
        let c = carried.at(left.centroid, left.angle_rad);
        [c[0] - pair.left_point[0], c[1] - pair.left_point[1]]
    }
}

/// IoU of `result`'s left contour with `pair`'s left mask (0 without one).
pub fn left_iou(pair: &TiltedPair, result: &semdepth_core::tracker::PairResult) -> f64 {
    let (w, h) = (pair.left.width, pair.left.height);
    result.left.as_ref().map_or(0.0, |l| {
        semdepth_core::geometry::mask_iou(
            &semdepth_core::geometry::Polygon::new(l.contour.clone()).rasterize(w, h),
            &pair.left_mask,
        )
    })
}

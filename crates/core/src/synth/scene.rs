//! A prepared synthetic scene: the object's outline, its trajectory (pose
//! and height per frame), the static background layers of both cameras with
//! their clutter, and the optional occluder. Any frame can be rendered on
//! its own (random access), so sequences stream without holding images.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::config::{BorderEntry, BorderSide, Shape, SynthConfig, ZPattern, BORDER_MARGIN};
use super::noise;
use super::raster::{band_field, blend_capsule, coverage, mix64, ValueNoise};
use super::shapes::{
    self, area_of, clip_half_plane, max_radius, object_outline, overlap_with_convex, particle_outline,
};
use super::substrate::{self, ReliefField, SubstrateLine};
use super::truth::{FrameTruth, ObjectTruth, OccluderTruth, SynthPair};
use super::SynthError;
use crate::geometry::{segment_distance, Point, Polygon};
use crate::imageio::GrayFrame;

/// Independent random streams derived from the seed.
mod stream {
    pub const SHAPE: u64 = 1;
    pub const MOTION: u64 = 2;
    pub const CLUTTER: u64 = 3;
    pub const LOOK: u64 = 4;
    pub const OCCLUDER: u64 = 5;
    pub const IMAGE: u64 = 6;
    pub const BORDER: u64 = 7;
    pub const FIBRES: u64 = 8;
    pub const RELIEF: u64 = 9;
}

/// A random generator for one purpose (and index) of a seed.
fn rng_for(seed: u64, stream: u64, index: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(mix64(
        seed ^ mix64(stream.wrapping_mul(0x1000_0000_0001) ^ mix64(index)),
    ))
}

/// Which camera of the stereo pair.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Side {
    Left,
    Right,
}

/// Rigid pose and height of the object in one frame (left image).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Pose {
    center: Point,
    angle: f64,
    z: f64,
}

impl Pose {
    /// Maps object coordinates to image coordinates, shifted by `dx`.
    fn apply(&self, q: Point, dx: f64) -> Point {
        let (s, c) = self.angle.sin_cos();
        [
            self.center[0] + dx + c * q[0] - s * q[1],
            self.center[1] + s * q[0] + c * q[1],
        ]
    }

    fn polygon(&self, outline: &Polygon, dx: f64) -> Polygon {
        Polygon::new(outline.points.iter().map(|&q| self.apply(q, dx)).collect())
    }
}

/// The occluder in object coordinates: a convex bar covering the part of
/// the object beyond a cut line, and how far along the cut direction `n` it
/// withdraws from there at the start of a sweep (0 when it does not sweep).
#[derive(Clone, Debug)]
struct Occluder {
    bar: Polygon,
    n: Point,
    withdrawal_px: f64,
    sweep_frames: usize,
    enter_frame: usize,
    z_offset_um: f64,
    brightness: f32,
}

/// How grey levels are painted (shared by the object, particles, occluder).
#[derive(Clone, Copy, Debug)]
struct Rim {
    strength: f32,
    width: f32,
    /// Distance beyond which the rim is exactly zero.
    band: f32,
    floor: f32,
}

impl Rim {
    fn new(strength: f64, width: f64) -> Self {
        let band = if strength == 0.0 {
            1.5
        } else {
            (4.0 * width + 1.5) as f32
        };
        let width = width as f32;
        Self {
            strength: strength as f32,
            width,
            band,
            floor: (-band / width).exp(),
        }
    }

    /// Rim brightness at signed distance `sd` (negative inside): full at the
    /// edge, decaying inwards, zero at the band's end.
    #[inline]
    fn at(&self, sd: f32) -> f32 {
        if self.strength == 0.0 || sd <= -self.band {
            return 0.0;
        }
        let d = (-sd).max(0.0);
        self.strength * ((-d / self.width).exp() - self.floor).max(0.0) / (1.0 - self.floor)
    }

    fn scaled(&self, factor: f32) -> Self {
        Self {
            strength: self.strength * factor,
            ..*self
        }
    }
}

/// A texture tabulated on a 1-px grid over a square centred on the origin
/// (object coordinates), sampled bilinearly; zero outside.
#[derive(Clone, Debug)]
struct TextureGrid {
    half: f64,
    n: usize,
    values: Vec<f32>,
}

impl TextureGrid {
    fn new(noise: &ValueNoise, half: f64) -> Self {
        let half = half.ceil();
        let n = 2 * half as usize + 1;
        let mut values = vec![0.0f32; n * n];
        for (y, row) in values.chunks_exact_mut(n).enumerate() {
            noise.add_row(-half, y as f64 - half, row);
        }
        Self { half, n, values }
    }

    #[inline]
    fn sample(&self, u: f64, v: f64) -> f32 {
        let (fx, fy) = (u + self.half, v + self.half);
        let limit = (self.n - 1) as f64;
        if !(fx >= 0.0 && fy >= 0.0 && fx < limit && fy < limit) {
            return 0.0;
        }
        // Non-negative: truncation is floor.
        let (ix, iy) = (fx as usize, fy as usize);
        let (tx, ty) = ((fx - ix as f64) as f32, (fy - iy as f64) as f32);
        let i = iy * self.n + ix;
        let v = &self.values;
        let top = v[i] + tx * (v[i + 1] - v[i]);
        let bottom = v[i + self.n] + tx * (v[i + self.n + 1] - v[i + self.n]);
        top + ty * (bottom - top)
    }
}

/// Everything needed to render any frame of a configured sequence.
#[derive(Clone, Debug)]
pub struct Scene {
    cfg: SynthConfig,
    size: f64,
    outline: Polygon,
    area: f64,
    poses: Vec<Pose>,
    background_disparity: f64,
    pad: usize,
    layers: [Vec<f32>; 2],
    particles: Vec<Polygon>,
    lines: Vec<SubstrateLine>,
    light: Point,
    texture: TextureGrid,
    rim: Rim,
    occluder: Option<Occluder>,
}

impl Scene {
    /// Validates `config` and prepares the scene (outline, trajectory,
    /// background layers with clutter, occluder placement).
    pub fn new(config: &SynthConfig) -> Result<Self, SynthError> {
        config.validate()?;
        let cfg = config.clone();
        let size = cfg.object_size();
        let mut outline = object_outline(cfg.shape, size, &mut rng_for(cfg.seed, stream::SHAPE, 0));
        if let Some(b) = cfg.border_entry.as_ref().filter(|b| b.width_scale != 1.0) {
            // Slender tool: squeeze across the axis (the centroid stays at
            // the origin, the outline stays dense).
            outline = Polygon::new(
                outline
                    .points
                    .iter()
                    .map(|p| [p[0], p[1] * b.width_scale])
                    .collect(),
            );
        }
        let area = outline.area();
        let poses = trajectory(&cfg, &outline)?;
        let mut look = rng_for(cfg.seed, stream::LOOK, 0);
        let light_angle = look.gen_range(0.0..std::f64::consts::TAU);
        let rim = Rim::new(cfg.rim_strength, cfg.rim_width_px);
        let noise = ValueNoise::new(look.gen(), 0.15 * size, 4, cfg.object_texture);
        let texture = TextureGrid::new(&noise, max_radius(&outline) + rim.band as f64 + 8.0);
        let background_disparity = cfg.disparity.at(cfg.disparity.background_z_um);
        let pad = (4.0 * cfg.noise.line_jitter_px).ceil() as usize + 2;
        let mut scene = Self {
            occluder: cfg.occlusion.as_ref().map(|o| place_occluder(&cfg, &outline, o)),
            rim,
            cfg,
            size,
            outline,
            area,
            poses,
            background_disparity,
            pad,
            layers: [Vec::new(), Vec::new()],
            particles: Vec::new(),
            lines: Vec::new(),
            light: [light_angle.cos(), light_angle.sin()],
            texture,
        };
        scene.build_background(&mut look);
        Ok(scene)
    }

    /// The configuration the scene was built from.
    pub fn config(&self) -> &SynthConfig {
        &self.cfg
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// True when there are no frames (never, for a valid config).
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// The object's outline in object coordinates (centroid at the origin).
    pub fn outline(&self) -> &Polygon {
        &self.outline
    }

    /// The clutter particles as drawn in the left image.
    pub fn particles(&self) -> &[Polygon] {
        &self.particles
    }

    /// The long scratches and fibres of the substrate (left-image
    /// coordinates; the right image shows them shifted by the background's
    /// disparity). Empty unless `fibres` is configured.
    pub fn lines(&self) -> &[SubstrateLine] {
        &self.lines
    }

    /// Ground truth of frame `k` (panics if `k >= len()`).
    pub fn truth(&self, k: usize) -> FrameTruth {
        let pose = self.poses[k];
        let d = self.cfg.disparity.at(pose.z);
        let rotation = pose.angle;
        let (w, h) = (self.cfg.width, self.cfg.height);
        let left = ObjectTruth::in_frame(pose.polygon(&self.outline, 0.0), rotation, w, h);
        let right = ObjectTruth::in_frame(pose.polygon(&self.outline, d), rotation, w, h);
        // Exact by construction: the right outline is the left one moved by d.
        let disparity_px = [d, 0.0];
        let visible_disparity_px = [
            right.visible_centroid[0] - left.visible_centroid[0],
            right.visible_centroid[1] - left.visible_centroid[1],
        ];
        let occluder = self.occluder_truth(k, &left.polygon, &right.polygon);
        let (occluded_fraction, occluded_fraction_right) = occluder
            .as_ref()
            .map_or((0.0, 0.0), |o| (o.fraction_left, o.fraction_right));
        FrameTruth {
            frame: k,
            z_um: pose.z,
            disparity_px,
            visible_disparity_px,
            background_disparity_px: self.background_disparity,
            left,
            right,
            occluded_fraction,
            occluded_fraction_right,
            occluder,
        }
    }

    fn occluder_truth(&self, k: usize, left: &Polygon, right: &Polygon) -> Option<OccluderTruth> {
        let occ = self.occluder.as_ref().filter(|o| k >= o.enter_frame)?;
        let pose = self.poses[k];
        let d_occ = self.cfg.disparity.at(pose.z + occ.z_offset_um);
        let bar = occ.bar_at(k);
        let bar_left = pose.polygon(&bar, 0.0);
        let bar_right = pose.polygon(&bar, d_occ);
        Some(OccluderTruth {
            fraction_left: overlap_with_convex(&left.points, &bar_left.points) / left.area(),
            fraction_right: overlap_with_convex(&right.points, &bar_right.points) / right.area(),
            disparity_px: [d_occ, 0.0],
            left: bar_left,
            right: bar_right,
        })
    }

    /// Renders frame `k` (both images) with its ground truth.
    pub fn render(&self, k: usize) -> SynthPair {
        let truth = self.truth(k);
        let left = self.render_image(k, Side::Left, &truth);
        let right = self.render_image(k, Side::Right, &truth);
        SynthPair { left, right, truth }
    }

    fn render_image(&self, k: usize, side: Side, truth: &FrameTruth) -> GrayFrame {
        let (w, h) = (self.cfg.width as usize, self.cfg.height as usize);
        let mut chacha = rng_for(
            self.cfg.seed,
            stream::IMAGE,
            2 * k as u64 + (side == Side::Right) as u64,
        );
        let mut rng = noise::FastRng::from_chacha(&mut chacha);
        let jitter = noise::row_jitter(h, self.cfg.noise.line_jitter_px, self.pad as f64 - 1.5, &mut rng);
        let mut img = self.background(side, &jitter);
        let (object, dx) = match side {
            Side::Left => (&truth.left, 0.0),
            Side::Right => (&truth.right, truth.disparity_px[0]),
        };
        self.paint_object(&mut img, &object.polygon.points, &jitter, k, dx);
        if let Some(occ) = &truth.occluder {
            let bar = match side {
                Side::Left => &occ.left,
                Side::Right => &occ.right,
            };
            let brightness = self.occluder.as_ref().map_or(0.8, |o| o.brightness);
            let pts = shapes::subdivided(bar, 2.0);
            paint_polygon(&mut img, [w, h], &pts, &jitter, self.rim.scaled(0.5), |_, _| {
                brightness
            });
        }
        if self.cfg.blur_sigma_px > 0.0 {
            // Defocus acts on the scene before the detector adds noise.
            substrate::gaussian_blur(&mut img, w, self.cfg.blur_sigma_px);
        }
        let (gain, offset) = noise::flicker_gain_offset(self.cfg.flicker, &mut rng);
        let data = noise::finish(
            &img,
            w,
            &self.cfg.noise,
            gain,
            offset,
            self.cfg.bit_depth,
            &mut rng,
        );
        GrayFrame {
            width: self.cfg.width,
            height: self.cfg.height,
            bit_depth: self.cfg.bit_depth,
            data,
        }
    }

    /// The static background of one camera, each row shifted by its jitter
    /// (linear interpolation in the padded layer).
    fn background(&self, side: Side, jitter: &[f32]) -> Vec<f32> {
        let (w, h) = (self.cfg.width as usize, self.cfg.height as usize);
        let lw = w + 2 * self.pad;
        let layer = &self.layers[side as usize];
        let mut img = vec![0.0f32; w * h];
        for (y, row) in img.chunks_exact_mut(w).enumerate() {
            let j = jitter[y];
            let i0 = j.floor();
            let f = j - i0;
            let start = y * lw + (self.pad as i64 + i0 as i64) as usize;
            let src = &layer[start..start + w + 1];
            if f == 0.0 {
                row.copy_from_slice(&src[..w]);
            } else {
                for (x, v) in row.iter_mut().enumerate() {
                    *v = src[x] + f * (src[x + 1] - src[x]);
                }
            }
        }
        img
    }

    /// Paints the object (outline `pts` in image coordinates, shifted by
    /// `dx` from the left pose) with rim, texture and shading.
    fn paint_object(&self, img: &mut [f32], pts: &[Point], jitter: &[f32], k: usize, dx: f64) {
        let pose = self.poses[k];
        let center = [pose.center[0] + dx, pose.center[1]];
        let (s, c) = pose.angle.sin_cos();
        let base = (self.cfg.background_level + self.cfg.object_contrast) as f32;
        let radius = self.size / 2.0;
        let shading = self.cfg.shading as f32;
        let sphere = self.cfg.shape == Shape::Sphere;
        let textured = self.cfg.object_texture > 0.0;
        let light = self.light;
        let value = |qx: f64, qy: f64| -> f32 {
            let (rx, ry) = (qx - center[0], qy - center[1]);
            let mut v = base;
            if textured {
                // Object coordinates: the texture moves with the object.
                v += self.texture.sample(c * rx + s * ry, -s * rx + c * ry);
            }
            if shading != 0.0 {
                let along = ((light[0] * rx + light[1] * ry) / radius) as f32;
                if sphere {
                    let nz = (1.0 - (rx * rx + ry * ry) / (radius * radius)).max(0.0).sqrt() as f32;
                    v += shading * (0.6 * along + 0.4 * (nz - 2.0 / 3.0));
                } else {
                    v += shading * 0.5 * along;
                }
            }
            v
        };
        let (w, h) = (self.cfg.width as usize, self.cfg.height as usize);
        paint_polygon(img, [w, h], pts, jitter, self.rim, value);
    }

    /// Builds both background layers: level, gradient, texture, particles
    /// and scratches (the right layer shifted by the background disparity).
    fn build_background(&mut self, look: &mut ChaCha8Rng) {
        let cfg = &self.cfg;
        let texture = ValueNoise::new(look.gen(), 40.0, 4, cfg.clutter.texture_amplitude);
        let grad_angle = look.gen_range(0.0..std::f64::consts::TAU);
        let grad = [
            grad_angle.cos() * cfg.background_gradient,
            grad_angle.sin() * cfg.background_gradient,
        ];
        let mut clutter_rng = rng_for(cfg.seed, stream::CLUTTER, 0);
        let (particles, looks) = self.place_particles(&mut clutter_rng);
        let scratches = self.place_scratches(&mut clutter_rng);
        // The scene classes draw from their own streams: the basic presets'
        // backgrounds stay exactly as they were.
        let lines = cfg.fibres.as_ref().map_or_else(Vec::new, |f| {
            let object = self.poses[0].polygon(&self.outline, 0.0);
            let mut rng = rng_for(cfg.seed, stream::FIBRES, 0);
            substrate::place_lines(f, cfg.width as f64, cfg.height as f64, &object, &mut rng)
        });
        let relief = cfg
            .relief
            .as_ref()
            .map(|r| ReliefField::new(r, &mut rng_for(cfg.seed, stream::RELIEF, 0)));
        let (w, h) = (cfg.width as usize, cfg.height as usize);
        let lw = w + 2 * self.pad;
        let mut layers = [Vec::new(), Vec::new()];
        for (side, layer) in layers.iter_mut().enumerate() {
            let shift = if side == 0 { 0.0 } else { self.background_disparity };
            // Layer column i shows scene x = i - pad (right camera: minus shift).
            let x0 = -(self.pad as f64) - shift;
            *layer = vec![0.0f32; lw * h];
            for (y, row) in layer.chunks_exact_mut(lw).enumerate() {
                let gy = grad[1] * (y as f64 / h as f64 - 0.5);
                for (i, v) in row.iter_mut().enumerate() {
                    let gx = grad[0] * ((x0 + i as f64) / w as f64 - 0.5);
                    *v = (cfg.background_level + gx + gy) as f32;
                }
                texture.add_row(x0, y as f64, row);
            }
            if let Some(relief) = &relief {
                relief.add_to_layer(layer, lw, x0);
            }
            let offset = [self.pad as f64 + shift, 0.0];
            let zeros = vec![0.0f32; h];
            for (p, &value) in particles.iter().zip(&looks) {
                let pts: Vec<Point> = p.translated(offset).points;
                paint_polygon(layer, [lw, h], &pts, &zeros, self.rim.scaled(0.7), |_, _| value);
            }
            for &(a, b, width, delta) in &scratches {
                let a = [a[0] + offset[0], a[1]];
                let b = [b[0] + offset[0], b[1]];
                blend_capsule(layer, lw, a, b, width, delta);
            }
            for line in &lines {
                substrate::blend_line(layer, lw, line, offset);
            }
        }
        self.layers = layers;
        self.lines = lines;
        self.particles = particles;
    }

    /// Distance that clutter keeps from the object's centroid at frame 0.
    fn clutter_clearance(&self) -> f64 {
        let d0 = self.cfg.disparity.at(self.poses[0].z);
        max_radius(&self.outline) + 0.15 * self.size + (d0 - self.background_disparity).abs()
    }

    /// Random particles (left-image coordinates) and their grey levels; each
    /// at most 4% of the object's area, none touching the object at frame 0.
    fn place_particles(&self, rng: &mut ChaCha8Rng) -> (Vec<Polygon>, Vec<f32>) {
        let cfg = &self.cfg;
        let (w, h) = (cfg.width as f64, cfg.height as f64);
        let max_area = 0.04 * self.area;
        let r_max = (max_area / std::f64::consts::PI).sqrt() / 1.25;
        let clearance = self.clutter_clearance();
        let c0 = self.poses[0].center;
        let mut out = Vec::new();
        let mut looks = Vec::new();
        for _ in 0..cfg.clutter.particles {
            let r = rng.gen_range(0.3..1.0) * r_max.max(2.0);
            let mut p = particle_outline(r, rng);
            let a = p.area();
            if a > max_area {
                p = p.scaled((max_area / a).sqrt(), [0.0, 0.0]);
            }
            let pr = max_radius(&p);
            let value = (cfg.background_level + cfg.object_contrast * rng.gen_range(0.4..0.9)) as f32;
            for _ in 0..200 {
                let c = [
                    rng.gen_range(pr + 2.0..w - pr - 3.0),
                    rng.gen_range(pr + 2.0..h - pr - 3.0),
                ];
                if (c[0] - c0[0]).hypot(c[1] - c0[1]) >= clearance + pr {
                    out.push(p.rotated_about([0.0, 0.0], rng.gen_range(0.0..6.3)).translated(c));
                    looks.push(value);
                    break;
                }
            }
        }
        (out, looks)
    }

    /// Random scratches (a, b, width, grey-level change), none touching the
    /// object at frame 0.
    fn place_scratches(&self, rng: &mut ChaCha8Rng) -> Vec<(Point, Point, f64, f32)> {
        let cfg = &self.cfg;
        let (w, h) = (cfg.width as f64, cfg.height as f64);
        let clearance = self.clutter_clearance();
        let c0 = self.poses[0].center;
        let mut out = Vec::new();
        for _ in 0..cfg.clutter.scratches {
            let len = rng.gen_range(0.3..0.8) * self.size;
            let width = rng.gen_range(1.2..3.0);
            let sign = if rng.gen_bool(0.5) { 1.0 } else { -1.0 };
            let delta = (sign * rng.gen_range(0.08..0.18)) as f32;
            for _ in 0..200 {
                let t = rng.gen_range(0.0..std::f64::consts::PI);
                let m = [rng.gen_range(0.0..w), rng.gen_range(0.0..h)];
                let half = [0.5 * len * t.cos(), 0.5 * len * t.sin()];
                let a = [m[0] - half[0], m[1] - half[1]];
                let b = [m[0] + half[0], m[1] + half[1]];
                if segment_distance(c0, a, b) >= clearance + width {
                    out.push((a, b, width, delta));
                    break;
                }
            }
        }
        out
    }
}

/// Composites a polygon over `img` (size [w, h]): each pixel moves towards
/// `value(sample x, sample y) + rim` by the polygon's coverage.
fn paint_polygon(
    img: &mut [f32],
    size: [usize; 2],
    pts: &[Point],
    jitter: &[f32],
    rim: Rim,
    value: impl Fn(f64, f64) -> f32,
) {
    let [w, h] = size;
    let Some(field) = band_field(pts, jitter, rim.band as f64, w, h) else {
        return;
    };
    for r in 0..field.h {
        let y = field.y0 + r;
        let j = jitter[y] as f64;
        let src = &field.sd[r * field.w..(r + 1) * field.w];
        let dst = &mut img[y * w + field.x0..y * w + field.x0 + field.w];
        for (i, (&sd, out)) in src.iter().zip(dst.iter_mut()).enumerate() {
            let cov = coverage(sd);
            if cov > 0.0 {
                let v = value((field.x0 + i) as f64 + j, y as f64) + rim.at(sd);
                *out += cov * (v - *out);
            }
        }
    }
}

/// Folds `x` into [lo, hi] by reflection at both ends.
fn fold(x: f64, lo: f64, hi: f64) -> f64 {
    let span = hi - lo;
    if span <= 0.0 {
        return lo;
    }
    let t = (x - lo).rem_euclid(2.0 * span);
    lo + if t <= span { t } else { 2.0 * span - t }
}

/// Heights of all frames.
fn heights(cfg: &SynthConfig, rng: &mut ChaCha8Rng) -> Vec<f64> {
    let m = &cfg.motion;
    let [lo, hi] = m.z_range_um;
    let mut walk = m.z_start_um;
    (0..cfg.frames)
        .map(|k| {
            let raw = match m.z_pattern {
                ZPattern::Constant => m.z_start_um,
                ZPattern::Steps => m.z_start_um + (k / m.z_hold_frames) as f64 * m.z_step_um,
                ZPattern::Ramp => m.z_start_um + k as f64 * m.z_step_um,
                ZPattern::RandomWalk => {
                    if k > 0 && m.z_step_um > 0.0 {
                        walk += rng.gen_range(-m.z_step_um..=m.z_step_um);
                    }
                    walk
                }
            };
            let z = fold(raw, lo, hi);
            if m.z_pattern == ZPattern::RandomWalk {
                walk = z;
            }
            z
        })
        .collect()
}

/// Bounding box [min x, min y, max x, max y] of the outline relative to its
/// centroid over all rotations in `angle0 + [0, span]` (a circle when the
/// span covers a full turn).
fn rotation_extents(outline: &Polygon, angle0: f64, span: f64) -> [f64; 4] {
    if span.abs() >= std::f64::consts::TAU {
        let r = max_radius(outline);
        return [-r, -r, r, r];
    }
    let steps = (span.abs() / 0.005).ceil() as usize;
    let mut b = [f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY];
    for i in 0..=steps {
        let a = angle0 + span * i as f64 / steps.max(1) as f64;
        let (s, c) = a.sin_cos();
        for q in &outline.points {
            let (x, y) = (c * q[0] - s * q[1], s * q[0] + c * q[1]);
            b = [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)];
        }
    }
    // Slack for the outline between sampled angles.
    let slack = 0.05 + max_radius(outline) * 0.005 * 0.005;
    [b[0] - slack, b[1] - slack, b[2] + slack, b[3] + slack]
}

/// Poses of all frames: heights, rotation and a drift reflected inside the
/// region where the object (both images) keeps the border margin.
fn trajectory(cfg: &SynthConfig, outline: &Polygon) -> Result<Vec<Pose>, SynthError> {
    if let Some(entry) = &cfg.border_entry {
        return border_trajectory(cfg, entry, outline);
    }
    let m = &cfg.motion;
    let mut rng = rng_for(cfg.seed, stream::MOTION, 0);
    let angle0 = m
        .start_angle_rad
        .unwrap_or_else(|| rng.gen_range(0.0..std::f64::consts::TAU));
    let zs = heights(cfg, &mut rng);
    let span = m.rotation_rad_per_frame * (cfg.frames - 1) as f64;
    let ext = rotation_extents(outline, angle0, span);
    let (dmin, dmax) = zs
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &z| {
            let d = cfg.disparity.at(z);
            (lo.min(d), hi.max(d))
        });
    let margin = BORDER_MARGIN * cfg.object_size();
    let (w, h) = (cfg.width as f64, cfg.height as f64);
    let lo = [-0.5 + margin - ext[0] - dmin.min(0.0), -0.5 + margin - ext[1]];
    let hi = [
        w - 0.5 - margin - ext[2] - dmax.max(0.0),
        h - 0.5 - margin - ext[3],
    ];
    if lo[0] > hi[0] || lo[1] > hi[1] {
        return Err(SynthError::DoesNotFit(format!(
            "an object of {:.0}x{:.0} px (after rotation) with disparities {dmin:.1}..{dmax:.1} px and a margin of {margin:.1} px needs at least {:.0}x{:.0} pixels, the image is {}x{} (expected a smaller object_size_px, rotation or disparity range)",
            ext[2] - ext[0],
            ext[3] - ext[1],
            ext[2] - ext[0] + (dmax.max(0.0) - dmin.min(0.0)) + 2.0 * margin,
            ext[3] - ext[1] + 2.0 * margin,
            cfg.width,
            cfg.height
        )));
    }
    let start = match m.start_px {
        Some(p) => {
            if p[0] < lo[0] || p[0] > hi[0] || p[1] < lo[1] || p[1] > hi[1] {
                return Err(SynthError::InvalidConfig {
                    field: "motion.start_px",
                    message: format!(
                        "[{:.1}, {:.1}] (expected x in {:.1}..={:.1} and y in {:.1}..={:.1} so the object keeps the border margin)",
                        p[0], p[1], lo[0], hi[0], lo[1], hi[1]
                    ),
                });
            }
            p
        }
        None => [rng.gen_range(lo[0]..=hi[0]), rng.gen_range(lo[1]..=hi[1])],
    };
    Ok(zs
        .iter()
        .enumerate()
        .map(|(k, &z)| {
            let t = k as f64;
            Pose {
                center: [
                    fold(start[0] + t * m.drift_px_per_frame[0], lo[0], hi[0]),
                    fold(start[1] + t * m.drift_px_per_frame[1], lo[1], hi[1]),
                ],
                angle: angle0 + t * m.rotation_rad_per_frame,
                z,
            }
        })
        .collect())
}

/// The frame in the coordinates of one border: the corner `origin` and the
/// unit vectors `n` (inward normal) and `t` (along the border) such that
/// the frame is {origin + s n + u t : 0 <= s <= depth, 0 <= u <= length}.
struct BorderFrame {
    origin: Point,
    n: Point,
    t: Point,
    depth: f64,
    length: f64,
}

impl BorderFrame {
    fn new(side: BorderSide, width: f64, height: f64) -> Self {
        let n = side.inward_normal();
        let t = [-n[1], n[0]];
        let (x1, y1) = (width - 0.5, height - 0.5);
        let (origin, depth, length) = match side {
            BorderSide::Left => ([-0.5, -0.5], width, height),
            BorderSide::Top => ([x1, -0.5], height, width),
            BorderSide::Right => ([x1, y1], width, height),
            BorderSide::Bottom => ([-0.5, y1], height, width),
        };
        Self {
            origin,
            n,
            t,
            depth,
            length,
        }
    }

    /// Range [min, max] of the projections onto `dir` (a unit axis vector)
    /// of a bounding box [min x, min y, max x, max y].
    fn project(bbox: [f64; 4], dir: Point) -> [f64; 2] {
        let (a, b) = if dir[0] != 0.0 {
            (bbox[0] * dir[0], bbox[2] * dir[0])
        } else {
            (bbox[1] * dir[1], bbox[3] * dir[1])
        };
        [a.min(b), a.max(b)]
    }
}

/// Fraction of `outline` (turned by `angle`, centroid at depth `s` from the
/// border along `n`) on the inner side of the border line.
fn inside_fraction(outline: &Polygon, angle: f64, n: Point, s: f64) -> f64 {
    let (sn, cs) = angle.sin_cos();
    let pts: Vec<Point> = outline
        .points
        .iter()
        .map(|q| [cs * q[0] - sn * q[1], sn * q[0] + cs * q[1]])
        .collect();
    area_of(&clip_half_plane(&pts, n, -s)) / area_of(&pts).max(1e-12)
}

/// Poses of a border-crossing object. Its axis points into the frame along
/// the border's normal turned by the entry angle, and the centroid moves on
/// the line `origin + u0 t + q dir`; the insertion q runs in steps of
/// `insertion_px_per_frame`, reflected at the ends of the range where, in
/// every frame and both images, the outline reaches past the border by
/// `min_outside_px`, its far end (the tip) keeps the border margin from the
/// opposite side, its sides keep the margin from the two lateral borders
/// and at least `min_visible_fraction` of its area is inside.
fn border_trajectory(
    cfg: &SynthConfig,
    entry: &BorderEntry,
    outline: &Polygon,
) -> Result<Vec<Pose>, SynthError> {
    let m = &cfg.motion;
    let zs = heights(cfg, &mut rng_for(cfg.seed, stream::MOTION, 0));
    let mut rng = rng_for(cfg.seed, stream::BORDER, 0);
    let side = entry.side.unwrap_or_else(|| BorderSide::ALL[rng.gen_range(0..4)]);
    let alpha = entry.angle_rad.unwrap_or_else(|| rng.gen_range(-0.52..0.52));
    let f = BorderFrame::new(side, cfg.width as f64, cfg.height as f64);
    let (sa, ca) = alpha.sin_cos();
    let dir = [ca * f.n[0] + sa * f.t[0], ca * f.n[1] + sa * f.t[1]];
    let angle0 = dir[1].atan2(dir[0]);
    let span = m.rotation_rad_per_frame * (cfg.frames - 1) as f64;
    let ext = rotation_extents(outline, angle0, span);
    let a_ext = BorderFrame::project(ext, f.n);
    let b_ext = BorderFrame::project(ext, f.t);
    let (dmin, dmax) = zs
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &z| {
            let d = cfg.disparity.at(z);
            (lo.min(d), hi.max(d))
        });
    // Depth of the centroid at which the inside fraction is just reached,
    // worst case over the rotations of the sequence (sampled).
    let samples = if span == 0.0 {
        1
    } else {
        ((span.abs() / 0.01).ceil() as usize).clamp(2, 64)
    };
    let mut s_fraction = f64::NEG_INFINITY;
    for i in 0..samples {
        let angle = angle0 + span * i as f64 / (samples - 1).max(1) as f64;
        let (mut lo, mut hi) = (-a_ext[1], -a_ext[0]);
        for _ in 0..50 {
            let mid = 0.5 * (lo + hi);
            if inside_fraction(outline, angle, f.n, mid) >= entry.min_visible_fraction {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        // Slack for the outline between the sampled angles.
        s_fraction = s_fraction.max(hi + span.abs() / (samples - 1).max(1) as f64 * max_radius(outline));
    }
    let margin = BORDER_MARGIN * cfg.object_size();
    // Insertion range [q_lo, q_hi] over both images (the right one is
    // shifted by the disparity along x).
    let (mut q_lo, mut q_hi) = (f64::NEG_INFINITY, f64::INFINITY);
    let (mut b_lo, mut b_hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for e in [0.0, dmin, dmax] {
        let ds = e * f.n[0];
        let du = e * f.t[0];
        q_hi = q_hi
            .min((-entry.min_outside_px - a_ext[0] - ds) / ca)
            .min((f.depth - margin - a_ext[1] - ds) / ca);
        q_lo = q_lo.max((s_fraction - ds) / ca);
        b_lo = b_lo.min(b_ext[0] + du);
        b_hi = b_hi.max(b_ext[1] + du);
    }
    let does_not_fit = |why: String| {
        SynthError::DoesNotFit(format!(
            "an object of {:.0}x{:.0} px entering from the {} border at {alpha:.2} rad {why} (expected a smaller object_size_px, min_visible_fraction or min_outside_px, or a larger image)",
            ext[2] - ext[0],
            ext[3] - ext[1],
            side.name(),
        ))
    };
    if q_lo > q_hi {
        return Err(does_not_fit(format!(
            "cannot keep {:.0}% of its area inside, reach {:.1} px past the border and keep a margin of {margin:.1} px from the opposite border",
            100.0 * entry.min_visible_fraction,
            entry.min_outside_px
        )));
    }
    // Lateral room: the centroid's position along the border moves by
    // q sin(alpha); shrink the insertion range about its middle if needed.
    let room = f.length - 2.0 * margin - (b_hi - b_lo);
    if room < 0.0 {
        return Err(does_not_fit(format!(
            "is wider than the {:.0} px border minus margins of {margin:.1} px",
            f.length
        )));
    }
    if sa.abs() * (q_hi - q_lo) > room {
        let mid = 0.5 * (q_lo + q_hi);
        let half = 0.5 * room / sa.abs();
        (q_lo, q_hi) = (mid - half, mid + half);
    }
    let u_lo = margin - b_lo - (q_lo * sa).min(q_hi * sa);
    let u_hi = f.length - margin - b_hi - (q_lo * sa).max(q_hi * sa);
    let u0 = rng.gen_range(u_lo..=u_hi.max(u_lo));
    let q0 = rng.gen_range(q_lo..=q_hi);
    Ok(zs
        .iter()
        .enumerate()
        .map(|(k, &z)| {
            let t = k as f64;
            let q = fold(q0 + t * entry.insertion_px_per_frame, q_lo, q_hi);
            let (s, u) = (q * ca, u0 + q * sa);
            Pose {
                center: [
                    f.origin[0] + s * f.n[0] + u * f.t[0],
                    f.origin[1] + s * f.n[1] + u * f.t[1],
                ],
                angle: angle0 + t * m.rotation_rad_per_frame,
                z,
            }
        })
        .collect())
}

impl Occluder {
    /// The bar in frame `k >= enter_frame` (object coordinates): in place,
    /// or on its sweep, withdrawn along `n` by a triangle wave that starts
    /// at the full withdrawal (touching the object) and reaches 0 (covering
    /// `fraction` of it) after `sweep_frames` frames.
    fn bar_at(&self, k: usize) -> Polygon {
        if self.sweep_frames == 0 {
            return self.bar.clone();
        }
        let period = 2 * self.sweep_frames;
        let phase = (k - self.enter_frame) % period;
        let covering = phase.min(period - phase) as f64 / self.sweep_frames as f64;
        let back = (1.0 - covering) * self.withdrawal_px;
        let [nx, ny] = self.n;
        Polygon::new(
            self.bar
                .points
                .iter()
                .map(|p| [p[0] + back * nx, p[1] + back * ny])
                .collect(),
        )
    }
}

/// Places the occluder bar (object coordinates) so that it covers the
/// requested fraction of the outline's area (bisection on the cut line).
fn place_occluder(cfg: &SynthConfig, outline: &Polygon, occ: &super::config::Occlusion) -> Occluder {
    let mut rng = rng_for(cfg.seed, stream::OCCLUDER, 0);
    let psi = occ
        .cut_angle_rad
        .unwrap_or_else(|| rng.gen_range(0.0..std::f64::consts::TAU));
    let n = [psi.cos(), psi.sin()];
    let t = [-n[1], n[0]];
    let along = |q: &Point| n[0] * q[0] + n[1] * q[1];
    let across = |q: &Point| (t[0] * q[0] + t[1] * q[1]).abs();
    let s_min = outline.points.iter().map(along).fold(f64::INFINITY, f64::min);
    let s_max = outline.points.iter().map(along).fold(f64::NEG_INFINITY, f64::max);
    let target = occ.fraction * outline.area();
    let (mut lo, mut hi) = (s_min, s_max);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if area_of(&clip_half_plane(&outline.points, n, mid)) > target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let s = 0.5 * (lo + hi);
    let size = cfg.object_size();
    let far = s_max + 0.15 * size;
    let half = outline.points.iter().map(across).fold(0.0, f64::max) + 0.1 * size;
    let corner = |a: f64, b: f64| [a * n[0] + b * t[0], a * n[1] + b * t[1]];
    Occluder {
        bar: Polygon::new(vec![
            corner(s, -half),
            corner(s, half),
            corner(far, half),
            corner(far, -half),
        ]),
        n,
        withdrawal_px: s_max - s,
        sweep_frames: occ.sweep_frames,
        enter_frame: occ.enter_frame,
        z_offset_um: occ.z_offset_um,
        brightness: occ.brightness as f32,
    }
}

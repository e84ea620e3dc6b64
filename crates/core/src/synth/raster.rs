//! Rasterisation primitives: hashed value noise, narrow-band signed distance
//! fields of polygons (with per-row scan jitter) and anti-aliased capsules.
//!
//! Anti-aliasing: a pixel whose centre lies at signed distance `sd` from an
//! outline (negative inside) is covered by a smoothstep of `sd` across
//! 1.5 px, point-symmetric about the edge, so the intensity-weighted
//! centroid agrees with the polygon's centroid to a few 1e-3 px at most.

use crate::geometry::Point;

/// SplitMix64 finaliser: a good 64-bit mixing function.
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A lattice value in [-1, 1] for integer coordinates.
#[inline]
fn lattice(seed: u64, ix: i64, iy: i64) -> f32 {
    let h = mix64(
        seed ^ (ix as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (iy as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F),
    );
    (h >> 40) as f32 * (2.0 / (1u64 << 24) as f32) - 1.0
}

#[inline]
fn smooth(t: f32) -> f32 {
    t * t * (3.0 - 2.0 * t)
}

/// Smooth random texture: a sum of value-noise octaves, defined on the
/// whole plane without storage (lattice values are hashed).
#[derive(Clone, Debug)]
pub struct ValueNoise {
    seed: u64,
    /// (lattice spacing in pixels, amplitude) per octave.
    octaves: Vec<(f64, f32)>,
}

impl ValueNoise {
    /// Octaves with spacings `base`, `base/2`, ... (`count` of them) and
    /// amplitudes halving each time, scaled so that values stay roughly
    /// within +-`amplitude`.
    pub fn new(seed: u64, base: f64, count: usize, amplitude: f64) -> Self {
        let norm: f64 = (0..count).map(|i| 0.5f64.powi(i as i32)).sum();
        let octaves = (0..count)
            .map(|i| {
                let spacing = (base / 2f64.powi(i as i32)).max(2.0);
                let amp = amplitude * 0.5f64.powi(i as i32) / norm;
                (spacing, amp as f32)
            })
            .collect();
        Self {
            seed: mix64(seed),
            octaves,
        }
    }

    /// Adds the texture at (x0 + i, y) to `out[i]` for every i: a whole row,
    /// interpolating each octave's lattice row once.
    pub fn add_row(&self, x0: f64, y: f64, out: &mut [f32]) {
        let mut column: Vec<f32> = Vec::new();
        for (i, &(spacing, amp)) in self.octaves.iter().enumerate() {
            let seed = self.seed.wrapping_add(i as u64);
            let fy = y / spacing;
            let iy = fy.floor();
            let ty = smooth((fy - iy) as f32);
            let iy = iy as i64;
            let first = (x0 / spacing).floor() as i64;
            let last = ((x0 + out.len() as f64) / spacing).floor() as i64 + 1;
            column.clear();
            column.extend(
                (first..=last).map(|ix| amp * lerp(lattice(seed, ix, iy), lattice(seed, ix, iy + 1), ty)),
            );
            let inv = 1.0 / spacing;
            for (k, o) in out.iter_mut().enumerate() {
                let fx = (x0 + k as f64) * inv;
                let ix = fx.floor();
                let j = (ix as i64 - first) as usize;
                *o += lerp(column[j], column[j + 1], smooth((fx - ix) as f32));
            }
        }
    }
}

#[inline]
fn lerp(a: f32, b: f32, t: f32) -> f32 {
    a + (b - a) * t
}

/// A signed distance field (negative inside) over a window of the image,
/// clamped to +-`band`: only the pixels of the window are evaluated.
#[derive(Clone, Debug)]
pub struct BandField {
    /// Column of the window's first pixel.
    pub x0: usize,
    /// Row of the window's first pixel.
    pub y0: usize,
    /// Window width.
    pub w: usize,
    /// Window height.
    pub h: usize,
    /// Row-major signed distances of the window, clamped to +-band.
    pub sd: Vec<f32>,
}

/// Signed distances from the pixels of a `width x height` image to the
/// closed polygon `pts`, where pixel (x, y) samples the scene at
/// (x + jitter[y], y). `None` when the polygon misses the image.
/// Edges should be short (see `shapes::subdivided`): each edge visits the
/// pixels of its bounding box grown by `band`.
pub fn band_field(
    pts: &[Point],
    jitter: &[f32],
    band: f64,
    width: usize,
    height: usize,
) -> Option<BandField> {
    let (mut minx, mut miny, mut maxx, mut maxy) =
        (f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
    for p in pts {
        minx = minx.min(p[0]);
        miny = miny.min(p[1]);
        maxx = maxx.max(p[0]);
        maxy = maxy.max(p[1]);
    }
    let jmax = jitter.iter().fold(0.0f32, |m, j| m.max(j.abs())) as f64;
    let x0 = (minx - band - jmax).floor().max(0.0) as usize;
    let y0 = (miny - band).floor().max(0.0) as usize;
    let x1 = ((maxx + band + jmax).ceil() as i64).min(width as i64 - 1);
    let y1 = ((maxy + band).ceil() as i64).min(height as i64 - 1);
    if x1 < x0 as i64 || y1 < y0 as i64 {
        return None;
    }
    let (w, h) = (x1 as usize - x0 + 1, y1 as usize - y0 + 1);
    let band2 = (band * band) as f32;
    let mut d2 = vec![band2; w * h];
    for i in 0..pts.len() {
        edge_distances(
            pts[i],
            pts[(i + 1) % pts.len()],
            jitter,
            band,
            [x0, y0, w, h],
            &mut d2,
        );
    }
    let mut sd: Vec<f32> = d2.iter().map(|d| d.sqrt()).collect();
    flip_inside(pts, jitter, [x0, y0, w, h], &mut sd);
    Some(BandField { x0, y0, w, h, sd })
}

/// Lowers `d2` (squared distances over window `win` = [x0, y0, w, h]) to
/// the squared distance from each pixel's sample point to segment a-b.
fn edge_distances(a: Point, b: Point, jitter: &[f32], band: f64, win: [usize; 4], d2: &mut [f32]) {
    let [x0, y0, w, h] = win;
    let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
    let inv_len2 = 1.0 / (ex * ex + ey * ey).max(1e-18);
    let (ymin, ymax) = (a[1].min(b[1]), a[1].max(b[1]));
    let ylo = ((ymin - band).ceil() as i64).max(y0 as i64);
    let yhi = ((ymax + band).floor() as i64).min((y0 + h) as i64 - 1);
    for y in ylo..=yhi {
        let yf = y as f64;
        // Rows away from the segment's y-range see a narrower band.
        let dy = (ymin - yf).max(yf - ymax).max(0.0);
        let reach = (band * band - dy * dy).max(0.0).sqrt();
        let j = jitter[y as usize] as f64;
        let xlo = ((a[0].min(b[0]) - reach - j).ceil() as i64).max(x0 as i64);
        let xhi = ((a[0].max(b[0]) + reach - j).floor() as i64).min((x0 + w) as i64 - 1);
        if xhi < xlo {
            continue;
        }
        let py = yf - a[1];
        let row = (y as usize - y0) * w;
        for x in xlo..=xhi {
            let px = x as f64 + j - a[0];
            let t = ((px * ex + py * ey) * inv_len2).clamp(0.0, 1.0);
            let (dx, dy) = (px - t * ex, py - t * ey);
            let d = (dx * dx + dy * dy) as f32;
            let cell = &mut d2[row + x as usize - x0];
            if d < *cell {
                *cell = d;
            }
        }
    }
}

/// Negates the distances of pixels whose sample point lies inside the
/// polygon (even-odd rule, same convention as `Polygon::rasterize`).
fn flip_inside(pts: &[Point], jitter: &[f32], win: [usize; 4], sd: &mut [f32]) {
    let [x0, y0, w, h] = win;
    let mut crossings: Vec<f64> = Vec::new();
    let n = pts.len();
    for r in 0..h {
        let y = (y0 + r) as f64;
        crossings.clear();
        for i in 0..n {
            let (a, b) = (pts[i], pts[(i + 1) % n]);
            if (a[1] > y) != (b[1] > y) {
                crossings.push(a[0] + (y - a[1]) / (b[1] - a[1]) * (b[0] - a[0]));
            }
        }
        crossings.sort_by(|p, q| p.total_cmp(q));
        let j = jitter[y0 + r] as f64;
        for pair in crossings.chunks_exact(2) {
            let start = ((pair[0] - j).ceil() as i64 - x0 as i64).clamp(0, w as i64) as usize;
            let end = ((pair[1] - j).ceil() as i64 - x0 as i64).clamp(0, w as i64) as usize;
            for v in &mut sd[r * w + start..r * w + end.max(start)] {
                *v = -*v;
            }
        }
    }
}

/// Half-width of the anti-aliasing edge profile in pixels.
pub const EDGE_HALF_WIDTH: f32 = 0.75;

/// Coverage of a pixel at signed distance `sd` from an edge: a smoothstep
/// across 1.5 px, point-symmetric about the edge (so it keeps the edge's
/// position and the shape's centroid), smooth enough that pixel sampling
/// adds almost no aliasing to area and centroid.
#[inline]
pub fn coverage(sd: f32) -> f32 {
    let t = ((EDGE_HALF_WIDTH - sd) * (0.5 / EDGE_HALF_WIDTH)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Blends a straight line of width `width` from `a` to `b` (round caps) into
/// an image row-major buffer `img` of width `w`: each pixel moves towards
/// `value(pixel)` by the line's coverage. No jitter (static layers only).
pub fn blend_capsule(img: &mut [f32], w: usize, a: Point, b: Point, width: f64, delta: f32) {
    let h = img.len() / w;
    let r = width / 2.0;
    let pad = r + 1.5;
    let xlo = (a[0].min(b[0]) - pad).floor().max(0.0) as usize;
    let ylo = (a[1].min(b[1]) - pad).floor().max(0.0) as usize;
    let xhi = ((a[0].max(b[0]) + pad).ceil() as i64).min(w as i64 - 1);
    let yhi = ((a[1].max(b[1]) + pad).ceil() as i64).min(h as i64 - 1);
    let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
    let len2 = (ex * ex + ey * ey).max(1e-18);
    for y in ylo as i64..=yhi {
        for x in xlo as i64..=xhi {
            let (px, py) = (x as f64 - a[0], y as f64 - a[1]);
            let t = ((px * ex + py * ey) / len2).clamp(0.0, 1.0);
            let d = ((px - t * ex).powi(2) + (py - t * ey).powi(2)).sqrt() - r;
            let c = coverage(d as f32);
            if c > 0.0 {
                img[y as usize * w + x as usize] += delta * c;
            }
        }
    }
}

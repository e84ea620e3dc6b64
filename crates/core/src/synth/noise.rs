//! Detector and scan noise applied to a rendered image: per-row jitter
//! offsets, frame gain/offset (flicker), per-row gain, Poisson shot noise,
//! Gaussian read noise, clamping and quantisation.

use std::sync::OnceLock;

use rand::{Rng, RngCore};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use super::config::Noise;

/// Means below this are sampled from tables (see [`poisson`]);
/// above it, by the rounded normal approximation round(lambda + sqrt(lambda) z)
/// (skewness 1/sqrt(lambda) < 0.18 is the only difference).
pub const POISSON_EXACT_BELOW: f64 = 32.0;
/// Grid step of the tabulated means.
const GRID: f64 = 1.0 / 32.0;

/// xoshiro256++: a small, fast generator for per-pixel noise, seeded from a
/// ChaCha8 stream (so every image is still determined by the seed).
#[derive(Clone, Debug)]
pub struct FastRng {
    s: [u64; 4],
}

impl FastRng {
    /// Seeds the state from a ChaCha8 generator.
    pub fn from_chacha(rng: &mut ChaCha8Rng) -> Self {
        let mut s = [0u64; 4];
        for v in &mut s {
            *v = rng.next_u64();
        }
        if s == [0; 4] {
            s[0] = 1;
        }
        Self { s }
    }
}

impl RngCore for FastRng {
    #[inline]
    fn next_u32(&mut self) -> u32 {
        (self.next_u64() >> 32) as u32
    }

    #[inline]
    fn next_u64(&mut self) -> u64 {
        let s = &mut self.s;
        let result = (s[0].wrapping_add(s[3])).rotate_left(23).wrapping_add(s[0]);
        let t = s[1] << 17;
        s[2] ^= s[0];
        s[3] ^= s[1];
        s[1] ^= s[2];
        s[0] ^= s[3];
        s[2] ^= t;
        s[3] = s[3].rotate_left(45);
        result
    }

    fn fill_bytes(&mut self, dest: &mut [u8]) {
        for chunk in dest.chunks_mut(8) {
            let v = self.next_u64().to_le_bytes();
            chunk.copy_from_slice(&v[..chunk.len()]);
        }
    }

    fn try_fill_bytes(&mut self, dest: &mut [u8]) -> Result<(), rand::Error> {
        self.fill_bytes(dest);
        Ok(())
    }
}

/// Walker alias tables of Poisson(m * GRID) for the grid means below
/// [`POISSON_EXACT_BELOW`], flattened: O(1) sampling without searching.
struct PoissonTables {
    /// Start of each mean's table in `threshold` / `alias`.
    offsets: Vec<usize>,
    /// Keep outcome j when a uniform u32 is below threshold[j].
    threshold: Vec<u32>,
    /// Otherwise take alias[j].
    alias: Vec<u16>,
}

/// Poisson probabilities of `lambda` up to a tail below 1e-13, renormalised.
fn poisson_pmf(lambda: f64) -> Vec<f64> {
    let mut p = (-lambda).exp();
    let mut pmf = vec![p];
    let mut k = 0.0;
    while (k < lambda || p > 1e-13) && k < 400.0 {
        k += 1.0;
        p *= lambda / k;
        pmf.push(p);
    }
    let total: f64 = pmf.iter().sum();
    pmf.iter_mut().for_each(|q| *q /= total);
    pmf
}

/// Appends the alias table of `pmf` (Vose's method).
fn push_alias(pmf: &[f64], threshold: &mut Vec<u32>, alias: &mut Vec<u16>) {
    let n = pmf.len();
    let mut scaled: Vec<f64> = pmf.iter().map(|p| p * n as f64).collect();
    let mut prob = vec![1.0; n];
    let mut other: Vec<u16> = (0..n as u16).collect();
    let (mut small, mut large): (Vec<usize>, Vec<usize>) = (0..n).partition(|&i| scaled[i] < 1.0);
    while let (Some(s), Some(&l)) = (small.pop(), large.last()) {
        prob[s] = scaled[s];
        other[s] = l as u16;
        scaled[l] -= 1.0 - scaled[s];
        if scaled[l] < 1.0 {
            large.pop();
            small.push(l);
        }
    }
    threshold.extend(
        prob.iter()
            .map(|&p| (p * 4_294_967_296.0).min(4_294_967_295.0) as u32),
    );
    alias.extend(other);
}

fn tables() -> &'static PoissonTables {
    static TABLES: OnceLock<PoissonTables> = OnceLock::new();
    TABLES.get_or_init(|| {
        let n = (POISSON_EXACT_BELOW / GRID) as usize + 2;
        let mut t = PoissonTables {
            offsets: Vec::with_capacity(n + 1),
            threshold: Vec::new(),
            alias: Vec::new(),
        };
        for i in 0..n {
            t.offsets.push(t.threshold.len());
            push_alias(&poisson_pmf(i as f64 * GRID), &mut t.threshold, &mut t.alias);
        }
        t.offsets.push(t.threshold.len());
        t
    })
}

/// A Poisson sample with mean `lambda`. Below [`POISSON_EXACT_BELOW`]: the
/// mixture of the tabulated Poisson laws of the two neighbouring grid means
/// (1/32 apart) whose mean is exactly `lambda` (variance excess at most
/// 1/4096), drawn in O(1) from alias tables. Above: the rounded normal
/// approximation.
#[inline]
pub fn poisson(lambda: f64, rng: &mut FastRng) -> f64 {
    if lambda <= 0.0 {
        return 0.0;
    }
    if lambda >= POISSON_EXACT_BELOW {
        let z: f64 = StandardNormal.sample(rng);
        let x = lambda + lambda.sqrt() * z + 0.5;
        return if x <= 0.0 { 0.0 } else { (x as u64) as f64 };
    }
    let t = tables();
    let g = lambda * (1.0 / GRID);
    let i = g as usize;
    let frac = ((g - i as f64) * 4_294_967_296.0) as u64;
    let r = rng.next_u64();
    let m = i + ((r & 0xFFFF_FFFF) < frac) as usize;
    let (start, end) = (t.offsets[m], t.offsets[m + 1]);
    let j = start + (((r >> 32) * (end - start) as u64) >> 32) as usize;
    let k = if (rng.next_u64() as u32) < t.threshold[j] {
        j - start
    } else {
        t.alias[j] as usize
    };
    k as f64
}

/// Per-row horizontal shifts (pixels) of one scan: N(0, sigma^2), clamped
/// to +-`limit`. All zero when sigma is 0 (no random numbers drawn).
pub fn row_jitter(height: usize, sigma: f64, limit: f64, rng: &mut FastRng) -> Vec<f32> {
    if sigma <= 0.0 {
        return vec![0.0; height];
    }
    (0..height)
        .map(|_| {
            let z: f64 = StandardNormal.sample(rng);
            (z * sigma).clamp(-limit, limit) as f32
        })
        .collect()
}

/// Gain and offset of one image under flicker amplitude `flicker`:
/// gain in 1 +- flicker, offset in +-0.1 flicker (fraction of full scale).
pub fn flicker_gain_offset(flicker: f64, rng: &mut FastRng) -> (f32, f32) {
    if flicker <= 0.0 {
        return (1.0, 0.0);
    }
    let gain = 1.0 + flicker * rng.gen_range(-1.0..=1.0);
    let offset = 0.1 * flicker * rng.gen_range(-1.0..=1.0);
    (gain as f32, offset as f32)
}

/// Applies flicker (`gain`, `offset`), per-row gain, shot noise and read
/// noise to `img` (intensities as fractions of full scale, row width `w`)
/// and quantises to `bit_depth`.
pub fn finish(
    img: &[f32],
    w: usize,
    noise: &Noise,
    gain: f32,
    offset: f32,
    bit_depth: u8,
    rng: &mut FastRng,
) -> Vec<u16> {
    let max = if bit_depth == 8 { 255.0 } else { 65535.0 };
    let mut out = Vec::with_capacity(img.len());
    let read = noise.read_noise;
    for row in img.chunks_exact(w) {
        let line = if noise.line_gain > 0.0 {
            let z: f64 = StandardNormal.sample(rng);
            (1.0 + noise.line_gain * z).max(0.0) as f32
        } else {
            1.0
        };
        let (g, o) = (gain * line, offset * line);
        for &v in row {
            let mut v = (v * g + o) as f64;
            if let Some(dose) = noise.dose {
                v = poisson(dose * v, rng) / dose;
            }
            if read > 0.0 {
                let z: f64 = StandardNormal.sample(rng);
                v += read * z;
            }
            // +0.5 and truncation: rounding without a libm call.
            out.push((v.clamp(0.0, 1.0) * max + 0.5) as u16);
        }
    }
    out
}

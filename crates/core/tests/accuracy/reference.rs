//! References independent of semdepth for the accuracy tests: paths to the
//! real images, a reference segmentation by global thresholding (no code
//! from `semdepth_core::init`), an outline traced by hand, and scenes built
//! here rather than by the generator.
#![allow(dead_code)]

use semdepth_core::display::{render_png, Overlay};
use semdepth_core::geometry::Point;
use semdepth_core::imageio::GrayFrame;
use std::path::PathBuf;

/// `../shared` beside the repository.
pub fn shared_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared")
}

/// The real quartz images `Quarz_01.png` .. `Quarz_03.png`.
pub fn quartz_path(index: u32) -> PathBuf {
    shared_dir().join(format!("data/real/quartz/Quarz_{index:02}.png"))
}

/// A reference object mask by global thresholding, independent of the
/// initialisation pipeline: box blur (radius 3), Otsu's threshold, the largest
/// 4-connected bright component, holes filled. Returns a row-major mask.
pub fn otsu_reference_mask(data: &[u16], width: usize, height: usize, max_value: u16) -> Vec<bool> {
    let scale = 255.0 / max_value as f64;
    let grey: Vec<f64> = data.iter().map(|&v| v as f64 * scale).collect();
    let blurred = box_blur(&grey, width, height, 3);
    let mut hist = [0usize; 256];
    for &v in &blurred {
        hist[v.round().clamp(0.0, 255.0) as usize] += 1;
    }
    let threshold = otsu(&hist);
    let bright: Vec<bool> = blurred.iter().map(|&v| v > threshold as f64).collect();
    let largest = largest_component(&bright, width, height);
    fill_holes(&largest, width, height)
}

/// Otsu's threshold of a 256-bin histogram.
pub fn otsu(hist: &[usize; 256]) -> usize {
    let total: usize = hist.iter().sum();
    let sum_all: f64 = hist.iter().enumerate().map(|(i, &c)| i as f64 * c as f64).sum();
    let (mut w0, mut sum0, mut best, mut best_t) = (0.0, 0.0, -1.0, 0);
    for (t, &c) in hist.iter().enumerate() {
        w0 += c as f64;
        sum0 += t as f64 * c as f64;
        let w1 = total as f64 - w0;
        if w0 == 0.0 || w1 == 0.0 {
            continue;
        }
        let between = w0 * w1 * (sum0 / w0 - (sum_all - sum0) / w1).powi(2);
        if between > best {
            best = between;
            best_t = t;
        }
    }
    best_t
}

fn box_blur(src: &[f64], w: usize, h: usize, r: usize) -> Vec<f64> {
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let (x0, x1) = (x.saturating_sub(r), (x + r).min(w - 1));
            let (y0, y1) = (y.saturating_sub(r), (y + r).min(h - 1));
            let mut s = 0.0;
            for yy in y0..=y1 {
                s += src[yy * w + x0..=yy * w + x1].iter().sum::<f64>();
            }
            out[y * w + x] = s / ((x1 - x0 + 1) * (y1 - y0 + 1)) as f64;
        }
    }
    out
}

fn largest_component(mask: &[bool], w: usize, h: usize) -> Vec<bool> {
    let mut label = vec![0u32; w * h];
    let mut best = (0u32, 0usize);
    let mut next = 0u32;
    let mut stack = Vec::new();
    for start in 0..w * h {
        if !mask[start] || label[start] != 0 {
            continue;
        }
        next += 1;
        let mut size = 0;
        label[start] = next;
        stack.push(start);
        while let Some(i) = stack.pop() {
            size += 1;
            let (x, y) = (i % w, i / w);
            let mut visit = |j: usize| {
                if mask[j] && label[j] == 0 {
                    label[j] = next;
                    stack.push(j);
                }
            };
            if x > 0 {
                visit(i - 1);
            }
            if x + 1 < w {
                visit(i + 1);
            }
            if y > 0 {
                visit(i - w);
            }
            if y + 1 < h {
                visit(i + w);
            }
        }
        if size > best.1 {
            best = (next, size);
        }
    }
    label.iter().map(|&l| l == best.0 && l != 0).collect()
}

fn fill_holes(mask: &[bool], w: usize, h: usize) -> Vec<bool> {
    // Background reachable from the frame edge stays background.
    let mut outside = vec![false; w * h];
    let mut stack: Vec<usize> = (0..w * h)
        .filter(|&i| {
            let (x, y) = (i % w, i / w);
            (x == 0 || y == 0 || x == w - 1 || y == h - 1) && !mask[i]
        })
        .collect();
    for &i in &stack {
        outside[i] = true;
    }
    while let Some(i) = stack.pop() {
        let (x, y) = (i % w, i / w);
        let neighbours = [
            (x > 0).then(|| i - 1),
            (x + 1 < w).then(|| i + 1),
            (y > 0).then(|| i - w),
            (y + 1 < h).then(|| i + w),
        ];
        for j in neighbours.into_iter().flatten() {
            if !mask[j] && !outside[j] {
                outside[j] = true;
                stack.push(j);
            }
        }
    }
    outside.iter().map(|&o| !o).collect()
}

/// Centroid of a mask's true pixels.
pub fn mask_centroid(mask: &[bool], w: usize) -> [f64; 2] {
    let (mut sx, mut sy, mut n) = (0.0, 0.0, 0.0);
    for (i, &m) in mask.iter().enumerate() {
        if m {
            sx += (i % w) as f64;
            sy += (i / w) as f64;
            n += 1.0;
        }
    }
    [sx / n, sy / n]
}

/// The lift-out image `needle_lamella_fei.tif` (a needle entering from the
/// left border holding a lamella).
pub fn fibsem_path() -> PathBuf {
    shared_dir().join("data/real/fibsem/needle_lamella_fei.tif")
}

/// [`otsu_reference_mask`] of the box `[x, y, w, h]` of an image, placed in
/// a full-size row-major mask (false outside the box).
pub fn otsu_reference_mask_in_box(
    data: &[u16],
    width: usize,
    max_value: u16,
    [x, y, w, h]: [usize; 4],
) -> Vec<bool> {
    let crop: Vec<u16> = (y..y + h)
        .flat_map(|row| data[row * width + x..row * width + x + w].iter().copied())
        .collect();
    let local = otsu_reference_mask(&crop, w, h, max_value);
    let mut mask = vec![false; data.len()];
    for (i, &m) in local.iter().enumerate() {
        mask[(y + i / w) * width + x + i % w] = m;
    }
    mask
}

/// The lamella in the real lift-out image, traced by hand on the image
/// (corners of its top face, its right side and the wavy lower edge of its
/// bright front face), full-resolution pixels. `tests/init_real.rs` checks
/// it against the image's gradients, not against semdepth.
pub const LAMELLA_OUTLINE: [[f64; 2]; 8] = [
    [274.0, 449.0],
    [457.0, 458.0],
    [459.0, 622.0],
    [420.0, 624.0],
    [330.0, 618.0],
    [265.0, 612.0],
    [264.0, 545.0],
    [268.0, 470.0],
];

/// A session object named `name` whose hint is the box `roi`
/// (`[x, y, width, height]`), tracked with the default parameters.
pub fn boxed_object(name: &str, roi: [i64; 4]) -> semdepth_core::session::SessionObject {
    semdepth_core::session::SessionObject::new(
        name,
        semdepth_core::tracker::TrackerParams {
            init: semdepth_core::init::InitParams {
                roi: Some(roi),
                ..Default::default()
            },
            ..Default::default()
        },
    )
}

/// `over` painted onto `under` where `mask` is set (same size).
pub fn composite(
    under: &semdepth_core::imageio::GrayFrame,
    over: &semdepth_core::imageio::GrayFrame,
    mask: &[bool],
) -> semdepth_core::imageio::GrayFrame {
    let data = under
        .data
        .iter()
        .zip(&over.data)
        .zip(mask)
        .map(|((u, o), m)| if *m { *o } else { *u })
        .collect();
    semdepth_core::imageio::GrayFrame::new(under.width, under.height, under.bit_depth, data).unwrap()
}

/// The scenes of a tool passing in front of a particle (`frames` pairs):
/// a tip 80 um above a sphere, starting above it at (320, 100) and
/// sweeping down 8 px per pair without turning, the sphere drifting
/// slowly at (340, 250). Each pair is the particle's scene with the tool's
/// painted over it inside the tool's true outline ([`composite`]), so the
/// tool hides the particle with its own disparity.
pub fn tool_over_particle(
    preset: semdepth_core::synth::Preset,
    seed: u64,
    frames: usize,
) -> (semdepth_core::synth::Scene, semdepth_core::synth::Scene) {
    use semdepth_core::synth::{Scene, Shape, SynthConfig, ZPattern};
    let mut tool = SynthConfig {
        frames,
        ..SynthConfig::preset(preset, Shape::Tip, seed)
    };
    tool.motion.z_pattern = ZPattern::Constant;
    tool.motion.z_start_um = 60.0;
    tool.motion.start_px = Some([320.0, 100.0]);
    tool.motion.start_angle_rad = Some(0.0);
    tool.motion.drift_px_per_frame = [0.0, 8.0];
    tool.motion.rotation_rad_per_frame = 0.0;
    let mut particle = SynthConfig {
        frames,
        ..SynthConfig::preset(preset, Shape::Sphere, seed + 1000)
    };
    particle.motion.z_pattern = ZPattern::Constant;
    particle.motion.z_start_um = -20.0;
    particle.motion.start_px = Some([340.0, 250.0]);
    particle.motion.drift_px_per_frame = [0.3, 0.1];
    (Scene::new(&tool).unwrap(), Scene::new(&particle).unwrap())
}

/// The translation `d` that best maps `a` onto `b` over `pixels`:
/// `b(p + d) = a(p)`, by Gauss-Newton on bilinear samples (Lucas-Kanade)
/// from `start`, within 2 px of it. `pixels` must stay 3 px inside the
/// image at every `d` tried.
pub fn register(a: &[f64], b: &[f64], w: usize, pixels: &[(usize, usize)], start: Point) -> Point {
    let sample = |img: &[f64], x: f64, y: f64| -> f64 {
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (i, j) = (x0 as usize, y0 as usize);
        let p = |ii: usize, jj: usize| img[jj * w + ii];
        (1.0 - fy) * ((1.0 - fx) * p(i, j) + fx * p(i + 1, j))
            + fy * ((1.0 - fx) * p(i, j + 1) + fx * p(i + 1, j + 1))
    };
    let mut d = start;
    for _ in 0..50 {
        let (mut hxx, mut hxy, mut hyy, mut bx, mut by) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for &(x, y) in pixels {
            let (xb, yb) = (x as f64 + d[0], y as f64 + d[1]);
            let gx = sample(b, xb + 0.5, yb) - sample(b, xb - 0.5, yb);
            let gy = sample(b, xb, yb + 0.5) - sample(b, xb, yb - 0.5);
            let e = sample(b, xb, yb) - a[y * w + x];
            hxx += gx * gx;
            hxy += gx * gy;
            hyy += gy * gy;
            bx += gx * e;
            by += gy * e;
        }
        let det = hxx * hyy - hxy * hxy;
        let step = [(hyy * bx - hxy * by) / det, (hxx * by - hxy * bx) / det];
        d = [
            (d[0] - step[0]).clamp(start[0] - 2.0, start[0] + 2.0),
            (d[1] - step[1]).clamp(start[1] - 2.0, start[1] + 2.0),
        ];
        if step[0].hypot(step[1]) < 1e-5 {
            break;
        }
    }
    d
}

/// `mask` grown by `r` pixels (square neighbourhood).
pub fn grow(mask: &[bool], w: usize, h: usize, r: usize) -> Vec<bool> {
    let mut out = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            if mask[y * w + x] {
                for yy in y.saturating_sub(r)..=(y + r).min(h - 1) {
                    for xx in x.saturating_sub(r)..=(x + r).min(w - 1) {
                        out[yy * w + xx] = true;
                    }
                }
            }
        }
    }
    out
}

/// `data` smoothed by a Gaussian of `sigma` pixels ([`crate::tilted::blur`]).
pub fn gaussian(data: &[u16], w: usize, h: usize, sigma: f64) -> Vec<f64> {
    crate::tilted::blur(
        &data.iter().map(|&v| f64::from(v)).collect::<Vec<_>>(),
        w,
        h,
        sigma,
    )
}

/// The whole-pixel translation `d` within `range` (x, y: from `-range`
/// to `range`) that maximises the normalised cross-correlation of `a` at
/// `pixels` with `b` at `pixels + d`, and that correlation; offsets that
/// take a pixel outside `b` are not tried.
pub fn ncc_offset(
    a: &[f64],
    b: &[f64],
    [w, h]: [usize; 2],
    pixels: &[(usize, usize)],
    range: [i64; 2],
) -> ([i64; 2], f64) {
    let n = pixels.len() as f64;
    let mean_a = pixels.iter().map(|&(x, y)| a[y * w + x]).sum::<f64>() / n;
    let var_a = pixels
        .iter()
        .map(|&(x, y)| (a[y * w + x] - mean_a).powi(2))
        .sum::<f64>();
    // The offsets that keep every pixel inside `b`: those that keep the
    // pixels' bounding box inside.
    let (x0, x1) = pixels
        .iter()
        .fold((usize::MAX, 0), |(lo, hi), &(x, _)| (lo.min(x), hi.max(x)));
    let (y0, y1) = pixels
        .iter()
        .fold((usize::MAX, 0), |(lo, hi), &(_, y)| (lo.min(y), hi.max(y)));
    let fits = |lo: usize, hi: usize, d: i64, len: usize| lo as i64 + d >= 0 && hi as i64 + d < len as i64;
    let mut best = ([0, 0], f64::NEG_INFINITY);
    for dy in -range[1]..=range[1] {
        for dx in -range[0]..=range[0] {
            if !(fits(x0, x1, dx, w) && fits(y0, y1, dy, h)) {
                continue;
            }
            let at = |&(x, y): &(usize, usize)| b[(y as i64 + dy) as usize * w + (x as i64 + dx) as usize];
            let mean_b = pixels.iter().map(at).sum::<f64>() / n;
            let (mut cross, mut var_b) = (0.0, 0.0);
            for p in pixels {
                let (da, db) = (a[p.1 * w + p.0] - mean_a, at(p) - mean_b);
                cross += da * db;
                var_b += db * db;
            }
            let c = cross / (var_a * var_b).sqrt();
            if c > best.1 {
                best = ([dx, dy], c);
            }
        }
    }
    best
}

/// Writes two frames side by side (8 px apart, each drawn at most 768 px
/// wide) with their overlays, as `dir/file`.
pub fn write_side_by_side(dir: &str, file: &str, views: [(&GrayFrame, &[Overlay]); 2]) {
    let images: Vec<image::RgbImage> = views
        .iter()
        .map(|(frame, overlays)| {
            let png = render_png(frame, Some(768), overlays).expect("render");
            image::load_from_memory(&png).expect("png").to_rgb8()
        })
        .collect();
    let (w, h) = (images[0].width(), images[0].height());
    let mut both = image::RgbImage::new(2 * w + 8, h);
    image::imageops::replace(&mut both, &images[0], 0, 0);
    image::imageops::replace(&mut both, &images[1], i64::from(w) + 8, 0);
    std::fs::create_dir_all(dir).expect("overlay folder");
    both.save(PathBuf::from(dir).join(file)).expect("write overlay");
}

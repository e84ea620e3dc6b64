//! Matched pre-filter: a Gaussian smoothing that restores the region energy's
//! precision on blurred edges.
//!
//! The region energy (Dahmen et al., section 3) moves a boundary by the
//! brightness of the pixels on it only: its derivative with respect to a
//! normal shift is the outline integral of (value - threshold). Across a
//! step blurred by a Gaussian of width `sigma`, that reads the profile where
//! its slope is `C / (sqrt(2 pi) sigma)`, and the shift's variance per unit
//! of outline grows as `2 pi sigma^2 noise^2 / C^2`. The matched filter (the
//! profile weighted by its own derivative, a Gaussian of width `sigma`)
//! reaches `2 sqrt(pi) sigma noise^2 / C^2`, sqrt(pi) sigma times less. Smoothing
//! the image with a Gaussian of the edge's own width before the fit makes
//! the boundary's reading exactly that weighted profile, and leaves the
//! edge of a straight step where it was. On a sharp edge (width under a
//! pixel) smoothing only costs precision, so the tracker smooths only
//! objects whose fitted edge width (`init::edge_width`) is at least
//! [`MIN_EDGE_WIDTH_PX`].

use crate::geometry::Polygon;
use crate::imageio::GrayFrame;
use crate::region::PixelRect;

/// Edges at least this wide (fitted Gaussian sigma, pixels) are smoothed
/// before the rigid fits; the generator's sharp scenes measure 0.3-1.4,
/// its defocus-blurred ones (a 1.5-2.5 px blur) 1.9-2.5.
pub const MIN_EDGE_WIDTH_PX: f64 = 1.5;

/// Objects are smoothed only where at least this share of the substrate's
/// variance is white (see [`substrate_whiteness`]): smoothing averages
/// white noise away, not texture a few pixels wide, whose edges it only
/// blurs. The generator's noisy scenes measure 0.6-1.0, its relief
/// substrates 0.42-0.53.
pub const MIN_WHITENESS: f64 = 0.75;

/// Least and most smoothing of a dark object with a bright edge rim, pixels.
pub const MIN_RIM_SIGMA_PX: f64 = 1.0;
/// See [`MIN_RIM_SIGMA_PX`].
pub const MAX_RIM_SIGMA_PX: f64 = 2.0;

/// Largest smoothing applied, pixels (a wider fitted edge is a shallow
/// gradient, not a blur to match).
pub const MAX_SIGMA_PX: f64 = 4.0;

/// `frame` smoothed by a Gaussian of standard deviation `sigma` pixels
/// (see [`Smoother::smooth_into`]).
pub fn smoothed(frame: &GrayFrame, sigma: f64) -> GrayFrame {
    let mut out = frame.clone();
    Smoother::default().smooth_into(frame, sigma, PixelRect::full(frame), &mut out);
    out
}

/// Scratch rows for [`Smoother::smooth_into`], kept between frames: a
/// 1024x768 frame's first touch of fresh buffers cost more than the
/// smoothing itself (2.3 ms against 0.9 ms for the vertical pass).
#[derive(Clone, Debug, Default)]
pub struct Smoother {
    vertical: Vec<f32>,
    padded: Vec<f32>,
    row: Vec<f32>,
}

impl Smoother {
    /// Writes `frame` into `out` with the pixels in `window` (clipped to
    /// the frame) smoothed by a Gaussian of standard deviation `sigma`
    /// pixels (edge pixels repeated beyond the frame's border) and rounded
    /// to the frame's sample range; the pixels outside `window` are copied.
    /// `sigma` is clamped to `0..=MAX_SIGMA_PX`; 0 copies.
    ///
    /// Separable, each pass a sum of shifted rows that the compiler
    /// vectorises: 2.3 ms for a whole 1024x768 frame at sigma 2 with the
    /// buffers reused, where `imageproc::filter::gaussian_blur_f32` took
    /// 10.1 ms (medians of 15 on the same machine).
    pub fn smooth_into(&mut self, frame: &GrayFrame, sigma: f64, window: PixelRect, out: &mut GrayFrame) {
        let sigma = sigma.clamp(0.0, MAX_SIGMA_PX);
        let (fw, fh) = (frame.width as usize, frame.height as usize);
        out.width = frame.width;
        out.height = frame.height;
        out.bit_depth = frame.bit_depth;
        out.data.clear();
        out.data.extend_from_slice(&frame.data);
        if sigma <= 0.0 || fw == 0 || fh == 0 {
            return;
        }
        let window = window.clipped_to(frame);
        let kernel = kernel(sigma);
        let r = kernel.len() / 2;
        let (x0, y0) = (window.x as usize, window.y as usize);
        let (w, h) = (window.width as usize, window.height as usize);
        // Columns the horizontal pass reads: the window and r beyond it.
        let (c0, c1) = (x0.saturating_sub(r), (x0 + w + r).min(fw));
        let cw = c1 - c0;
        // Vertical pass over those columns: each output row a weighted sum
        // of input rows.
        self.vertical.clear();
        self.vertical.resize(cw * h, 0.0);
        for (y, acc) in self.vertical.chunks_exact_mut(cw).enumerate() {
            for (k, &g) in kernel.iter().enumerate() {
                let src = (y0 + y + k).saturating_sub(r).min(fh - 1);
                let line = &frame.data[src * fw + c0..src * fw + c1];
                for (a, &v) in acc.iter_mut().zip(line) {
                    *a += g * f32::from(v);
                }
            }
        }
        // Horizontal pass over the window, each row padded with the
        // frame's end pixels where the kernel leaves the frame.
        let max = ((1u32 << frame.bit_depth) - 1) as f32;
        self.padded.resize(w + 2 * r, 0.0);
        self.row.resize(w, 0.0);
        for (y, line) in self.vertical.chunks_exact(cw).enumerate() {
            for (j, p) in self.padded.iter_mut().enumerate() {
                let column = (x0 + j).saturating_sub(r).min(fw - 1);
                *p = line[column - c0];
            }
            self.row.fill(0.0);
            for (k, &g) in kernel.iter().enumerate() {
                for (a, &v) in self.row.iter_mut().zip(&self.padded[k..k + w]) {
                    *a += g * v;
                }
            }
            // Rounded half up (the values are not negative).
            let start = (y0 + y) * fw + x0;
            for (o, &v) in out.data[start..start + w].iter_mut().zip(&self.row) {
                *o = (v.clamp(0.0, max) + 0.5) as u16;
            }
        }
    }
}

/// Share of the substrate's variance that changes from pixel to pixel
/// (1 for white noise, near 0 for texture that is smooth over a few pixels):
/// half the variance of horizontal neighbour differences over the variance,
/// in the ring `RING_PX` wide that starts `GAP_PX` outside `contour`.
/// `None` with fewer than 64 pixel pairs in the ring.
pub fn substrate_whiteness(frame: &GrayFrame, contour: &Polygon) -> Option<f64> {
    const GAP_PX: f64 = 4.0;
    const RING_PX: f64 = 8.0;
    let near = contour.offset_along_normals(GAP_PX);
    let reach = GAP_PX + RING_PX;
    let rect = PixelRect::around(contour.bounds(), reach, frame.width, frame.height)?;
    let (w, h) = (rect.width as usize, rect.height as usize);
    let local = |p: &Polygon| {
        p.translated([-(rect.x as f64), -(rect.y as f64)])
            .rasterize(rect.width, rect.height)
    };
    let inner = local(&near);
    let outer = local(&contour.offset_along_normals(reach));
    let ring = |k: usize| outer[k] && !inner[k];
    let [mut n, mut s, mut q, mut dq] = [0.0f64; 4];
    for y in 0..h {
        for x in 0..w - 1 {
            let k = y * w + x;
            if ring(k) && ring(k + 1) {
                let at = |dx: usize| {
                    f64::from(
                        frame.data[(rect.y as usize + y) * frame.width as usize + rect.x as usize + x + dx],
                    )
                };
                let (a, b) = (at(0), at(1));
                n += 1.0;
                s += a;
                q += a * a;
                dq += (b - a) * (b - a);
            }
        }
    }
    if n < 64.0 {
        return None;
    }
    let var = q / n - (s / n) * (s / n);
    (var > 0.0).then(|| 0.5 * dq / n / var)
}

/// The normalised Gaussian of `sigma` pixels, cut at 3 sigma.
fn kernel(sigma: f64) -> Vec<f32> {
    let r = (3.0 * sigma).ceil() as i64;
    let raw: Vec<f64> = (-r..=r)
        .map(|i| (-((i * i) as f64) / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum: f64 = raw.iter().sum();
    raw.iter().map(|&g| (g / sum) as f32).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(width: u32, height: u32, f: impl Fn(u32, u32) -> u16) -> GrayFrame {
        GrayFrame {
            width,
            height,
            bit_depth: 8,
            data: (0..height)
                .flat_map(|y| (0..width).map(move |x| (x, y)))
                .map(|(x, y)| f(x, y))
                .collect(),
        }
    }

    #[test]
    fn a_step_keeps_its_midpoint_and_levels() {
        // A vertical step between columns 19 and 20 of 40.
        let step = frame(40, 12, |x, _| if x < 20 { 50 } else { 200 });
        let s = smoothed(&step, 2.0);
        let row = &s.data[6 * 40..7 * 40];
        // Far from the edge the levels stay; across it the profile is odd
        // about the midpoint between the two columns.
        assert_eq!(row[0], 50);
        assert_eq!(row[39], 200);
        for d in 0..8 {
            let (a, b) = (f64::from(row[19 - d]), f64::from(row[20 + d]));
            assert!((a + b - 250.0).abs() <= 1.0, "column pair {d}: {a} + {b}");
        }
        // It is smoothed: the columns beside the edge moved towards the middle.
        assert!(row[19] > 80 && row[20] < 170, "{:?}", &row[16..24]);
    }

    #[test]
    fn matches_a_direct_two_dimensional_convolution() {
        let noise = frame(37, 29, |x, y| ((x * 37 + y * 91 + x * y) % 256) as u16);
        let sigma = 1.7;
        let ours = smoothed(&noise, sigma);
        // Every output pixel from the 2-D Gaussian (cut at 3 sigma), with
        // coordinates clamped to the frame.
        let r = (3.0 * sigma).ceil() as i64;
        let g = |d: i64| (-((d * d) as f64) / (2.0 * sigma * sigma)).exp();
        let norm: f64 = (-r..=r).map(g).sum::<f64>().powi(2);
        for y in 0..29i64 {
            for x in 0..37i64 {
                let mut acc = 0.0;
                for dy in -r..=r {
                    for dx in -r..=r {
                        let (sx, sy) = ((x + dx).clamp(0, 36), (y + dy).clamp(0, 28));
                        acc += g(dx) * g(dy) * f64::from(noise.data[(sy * 37 + sx) as usize]);
                    }
                }
                let got = f64::from(ours.data[(y * 37 + x) as usize]);
                assert!(
                    (got - acc / norm).abs() <= 0.51,
                    "({x}, {y}): {got} vs {}",
                    acc / norm
                );
            }
        }
    }

    #[test]
    fn a_window_is_smoothed_as_in_the_whole_frame_and_the_rest_copied() {
        let noise = frame(40, 30, |x, y| ((x * 53 + y * 29 + x * y * 7) % 256) as u16);
        let whole = smoothed(&noise, 1.3);
        let window = PixelRect {
            x: 3,
            y: 20,
            width: 30,
            height: 10,
        };
        let mut out = noise.clone();
        Smoother::default().smooth_into(&noise, 1.3, window, &mut out);
        for y in 0..30 {
            for x in 0..40 {
                let k = y * 40 + x;
                let inside = (3..33).contains(&x) && (20..30).contains(&y);
                let expected = if inside { whole.data[k] } else { noise.data[k] };
                assert_eq!(out.data[k], expected, "({x}, {y})");
            }
        }
    }

    #[test]
    fn zero_sigma_is_a_copy_and_range_is_kept() {
        let noise = frame(16, 16, |x, y| ((x * 37 + y * 91) % 256) as u16);
        assert_eq!(smoothed(&noise, 0.0), noise);
        let s = smoothed(&noise, 1.0);
        assert!(s.data.iter().all(|&v| v <= 255));
        assert_eq!((s.width, s.height, s.bit_depth), (16, 16, 8));
    }
}

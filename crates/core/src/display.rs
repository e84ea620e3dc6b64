//! Display images for the live view: a frame rendered to 8 bits, shrunk by
//! area averaging to a longest side, with contours drawn over it, as PNG.
//!
//! 8-bit frames are shown as acquired; 16-bit frames are stretched between
//! their 0.1 and 99.9 percentiles (SEM detectors rarely fill 16 bits, and a
//! plain shift would show most 12-bit frames near black).

use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::{ImageEncoder, Rgb, RgbImage};
use imageproc::drawing::draw_line_segment_mut;

use crate::geometry::Point;
use crate::imageio::GrayFrame;

/// Colours given to objects in turn (also the viewer's, in `ui/app.js`).
pub const PALETTE: [[u8; 3]; 6] = [
    [0, 220, 255],
    [255, 170, 0],
    [120, 255, 80],
    [255, 80, 200],
    [255, 255, 90],
    [160, 130, 255],
];

/// Colour of a contour whose pair was not tracked.
pub const LOST_COLOUR: [u8; 3] = [255, 60, 40];

/// A contour to draw over a frame, in the frame's pixel coordinates.
pub struct Overlay<'a> {
    /// Closed polygon (the last vertex joins the first).
    pub contour: &'a [Point],
    /// RGB.
    pub colour: [u8; 3],
}

/// The integer factor that shrinks a `width` x `height` frame until its
/// longest side is at most `max_side` (1 without a limit); shrunk pixel i
/// averages frame pixels i f ..= i f + f - 1.
pub fn shrink_factor(width: u32, height: u32, max_side: Option<u32>) -> u32 {
    let longest = width.max(height).max(1);
    max_side.map_or(1, |m| longest.div_ceil(m.max(1))).max(1)
}

/// Renders `frame` as PNG: shrunk by an integer factor so that its longest
/// side is at most `max_side` (when given), with `overlays` drawn 2 px wide.
/// Grey PNG without overlays, RGB with them.
pub fn render_png(frame: &GrayFrame, max_side: Option<u32>, overlays: &[Overlay]) -> Result<Vec<u8>, String> {
    let factor = shrink_factor(frame.width, frame.height, max_side);
    let (w, h, samples) = shrink(frame, factor);
    let grey = to_8bit(&samples, frame.bit_depth);
    let mut png = Vec::new();
    let encoder = PngEncoder::new_with_quality(&mut png, CompressionType::Fast, FilterType::Sub);
    if overlays.is_empty() {
        encoder
            .write_image(&grey, w, h, image::ExtendedColorType::L8)
            .map_err(|e| format!("encoding PNG: {e}"))?;
        return Ok(png);
    }
    let mut rgb = RgbImage::from_fn(w, h, |x, y| {
        let v = grey[(y * w + x) as usize];
        Rgb([v, v, v])
    });
    // A source pixel x maps to (x - (f - 1) / 2) / f in the shrunk image,
    // whose pixel i averages source pixels i f ..= i f + f - 1.
    let f = factor as f32;
    let to_shown = |p: &Point| {
        (
            (p[0] as f32 - (f - 1.0) / 2.0) / f,
            (p[1] as f32 - (f - 1.0) / 2.0) / f,
        )
    };
    for overlay in overlays {
        let n = overlay.contour.len();
        for i in 0..n {
            let (a, b) = (
                to_shown(&overlay.contour[i]),
                to_shown(&overlay.contour[(i + 1) % n]),
            );
            for (dx, dy) in [(0.0, 0.0), (0.5, 0.0), (0.0, 0.5)] {
                draw_line_segment_mut(
                    &mut rgb,
                    (a.0 + dx, a.1 + dy),
                    (b.0 + dx, b.1 + dy),
                    Rgb(overlay.colour),
                );
            }
        }
    }
    encoder
        .write_image(rgb.as_raw(), w, h, image::ExtendedColorType::Rgb8)
        .map_err(|e| format!("encoding PNG: {e}"))?;
    Ok(png)
}

/// Averages `factor` x `factor` blocks (partial blocks at the right and
/// bottom edges average what they hold).
fn shrink(frame: &GrayFrame, factor: u32) -> (u32, u32, Vec<u16>) {
    if factor == 1 {
        return (frame.width, frame.height, frame.data.clone());
    }
    let (w, h) = (frame.width.div_ceil(factor), frame.height.div_ceil(factor));
    let fw = frame.width as usize;
    let mut sums = vec![0u64; (w * h) as usize];
    let mut counts = vec![0u32; (w * h) as usize];
    for (y, row) in frame.data.chunks_exact(fw).enumerate() {
        let out_row = (y as u32 / factor * w) as usize;
        for (x, &v) in row.iter().enumerate() {
            let i = out_row + x / factor as usize;
            sums[i] += u64::from(v);
            counts[i] += 1;
        }
    }
    let samples = sums
        .iter()
        .zip(&counts)
        .map(|(&s, &c)| ((s + u64::from(c) / 2) / u64::from(c.max(1))) as u16)
        .collect();
    (w, h, samples)
}

/// 8-bit samples: as they are for 8-bit frames, stretched between the 0.1
/// and 99.9 percentiles for 16-bit ones.
fn to_8bit(samples: &[u16], bit_depth: u8) -> Vec<u8> {
    if bit_depth <= 8 {
        return samples.iter().map(|&v| v.min(255) as u8).collect();
    }
    let mut histogram = vec![0u32; 1 << 16];
    for &v in samples {
        histogram[v as usize] += 1;
    }
    let n = samples.len() as u64;
    let quantile = |q: f64| {
        let target = (q * n as f64) as u64;
        let mut seen = 0u64;
        for (v, &c) in histogram.iter().enumerate() {
            seen += u64::from(c);
            if seen > target {
                return v as f64;
            }
        }
        65535.0
    };
    let (lo, hi) = (quantile(0.001), quantile(0.999));
    let scale = 255.0 / (hi - lo).max(1.0);
    samples
        .iter()
        .map(|&v| ((f64::from(v) - lo) * scale).round().clamp(0.0, 255.0) as u8)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(width: u32, height: u32, bit_depth: u8, f: impl Fn(u32, u32) -> u16) -> GrayFrame {
        let data = (0..height)
            .flat_map(|y| (0..width).map(move |x| (x, y)))
            .map(|(x, y)| f(x, y))
            .collect();
        GrayFrame {
            width,
            height,
            bit_depth,
            data,
        }
    }

    fn decode(png: &[u8]) -> image::DynamicImage {
        image::load_from_memory_with_format(png, image::ImageFormat::Png).expect("valid PNG")
    }

    #[test]
    fn shrinks_to_the_longest_side_by_area_averages() {
        let f = frame(10, 6, 8, |x, _| if x < 5 { 0 } else { 200 });
        let img = decode(&render_png(&f, Some(5), &[]).unwrap()).to_luma8();
        assert_eq!(img.dimensions(), (5, 3));
        // Block x = 2 holds source columns 4 (0) and 5 (200).
        assert_eq!(img.get_pixel(2, 0)[0], 100);
        assert_eq!(img.get_pixel(0, 0)[0], 0);
        assert_eq!(img.get_pixel(4, 2)[0], 200);
    }

    #[test]
    fn sixteen_bit_frames_are_stretched() {
        let f = frame(100, 10, 16, |x, _| 1000 + 10 * x as u16);
        let img = decode(&render_png(&f, None, &[]).unwrap()).to_luma8();
        assert_eq!(img.get_pixel(0, 0)[0], 0);
        assert_eq!(img.get_pixel(99, 0)[0], 255);
        assert!((100..156).contains(&img.get_pixel(50, 0)[0]));
    }

    #[test]
    fn contours_are_drawn_in_their_colour_where_they_run() {
        let f = frame(40, 40, 8, |_, _| 50);
        let square = [[10.0, 10.0], [30.0, 10.0], [30.0, 30.0], [10.0, 30.0]];
        let overlay = Overlay {
            contour: &square,
            colour: PALETTE[0],
        };
        let img = decode(&render_png(&f, Some(20), &[overlay]).unwrap()).to_rgb8();
        assert_eq!(img.dimensions(), (20, 20));
        // (10, 20) in the frame is (4.75, 9.75) shrunk: on the left edge.
        let on = img.get_pixel(5, 10).0;
        assert_eq!(on, PALETTE[0], "the edge is drawn");
        assert_eq!(img.get_pixel(10, 10).0, [50, 50, 50], "inside is the frame");
    }
}

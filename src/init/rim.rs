//! The bright edge rim of a dark object: grows a dark region's outline over it.
//!
//! SEM images brighten the edges of an object (more secondary electrons
//! escape near an edge), so a dark particle on a brighter substrate shows a
//! bright rim just inside its outline. The darker-than-its-surroundings
//! region the candidates find stops at the inner side of that rim, a few
//! pixels inside the object. [`grow_over_rim`] measures the brightness
//! profile outwards in half-pixel rings (region sums, O(contour length) per
//! ring) and moves the outline to the rim's outer edge.

use crate::geometry::Polygon;
use crate::imageio::GrayFrame;
use crate::region::{PixelRect, PrefixSums, RegionSum};

/// Width of one ring, pixels.
const RING_PX: f64 = 0.5;

/// The substrate is the band this far outside the largest growth, pixels.
const SUBSTRATE_BAND_PX: [f64; 2] = [3.0, 9.0];

/// `contour` (a dark object's outline, away from the image border) grown
/// outwards over a bright rim within `max_px`: the mean of every half-pixel
/// ring out to `max_px` is measured; when the brightest exceeds the
/// substrate's mean (the band 3..9 px beyond `max_px`) by at least
/// `min_excess` of the substrate-to-object contrast, the outline moves to
/// where the rim falls half way back to the substrate beyond its peak.
/// Returns the contour unchanged when there is no such rim, when the bands
/// leave the image, or when the outline is too small to offset.
pub(super) fn grow_over_rim(frame: &GrayFrame, contour: &Polygon, max_px: f64, min_excess: f64) -> Polygon {
    let reach = max_px + SUBSTRATE_BAND_PX[1] + 2.0;
    let [x0, y0, x1, y1] = contour.bounds();
    let Some(rect) = PixelRect::covering(
        x0 - reach,
        y0 - reach,
        x1 + reach,
        y1 + reach,
        frame.width,
        frame.height,
    ) else {
        return contour.clone();
    };
    // Only differences of means are compared: no intensity offset needed.
    let sums = PrefixSums::new(frame, rect, 0);
    // Normals from a smoothed copy (about 9 vertices): the outline's pixel
    // noise would turn offsets of 10-20 px along the vertex normals into
    // loops.
    let normals = contour.moving_average(4).outward_normals();
    let grown = |d: f64| contour.offset_along(&normals, d);
    let outer = grown(max_px + SUBSTRATE_BAND_PX[1]);
    if contour.len() < 8 || !sums.contains(&outer.points) {
        return contour.clone();
    }
    let sum = |d: f64| sums.polygon(&grown(d).points);
    // Mean of the band between two outlines' region sums.
    let band = |inner: RegionSum, outer: RegionSum| {
        let count = outer.count - inner.count;
        (count > 0.0).then(|| (outer.sum - inner.sum) / count)
    };
    let object = sums.polygon(&contour.points).mean();
    let substrate_band = band(
        sum(max_px + SUBSTRATE_BAND_PX[0]),
        sum(max_px + SUBSTRATE_BAND_PX[1]),
    );
    let Some(substrate) = substrate_band else {
        return contour.clone();
    };
    let contrast = substrate - object;
    if contrast <= 0.0 {
        return contour.clone();
    }
    let rings = (max_px / RING_PX).floor() as usize;
    // Each ring's outline is summed once and serves both rings it bounds.
    let outlines: Vec<RegionSum> = (0..=rings).map(|k| sum(k as f64 * RING_PX)).collect();
    let profile: Option<Vec<f64>> = outlines.windows(2).map(|w| band(w[0], w[1])).collect();
    let Some(profile) = profile else {
        return contour.clone();
    };
    let Some((peak_at, &peak)) = profile.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1)) else {
        return contour.clone();
    };
    if peak - substrate < min_excess * contrast {
        return contour.clone();
    }
    // The outline is where the rim falls half way back to the substrate
    // (an anti-aliased edge's midpoint), between two ring centres.
    let half = substrate + 0.5 * (peak - substrate);
    let Some(k) = (peak_at + 1..profile.len()).find(|&k| profile[k] <= half) else {
        return contour.clone();
    };
    let t = (profile[k - 1] - half) / (profile[k - 1] - profile[k]);
    let grown_px = (k as f64 - 0.5 + t) * RING_PX;
    grown(grown_px)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A disc of radius `radius` at (100, 100): `core` inside, a 2-px ring
    /// of `rim` just inside the outline, `substrate` outside (anti-aliased
    /// by 4x4 supersampling).
    fn disc(radius: f64, core: f64, rim: f64, substrate: f64) -> GrayFrame {
        let (w, h) = (200u32, 200u32);
        let data = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                let mut v = 0.0;
                for sy in 0..4 {
                    for sx in 0..4 {
                        let (px, py) = (x - 0.375 + sx as f64 * 0.25, y - 0.375 + sy as f64 * 0.25);
                        let r = (px - 100.0).hypot(py - 100.0);
                        v += if r > radius {
                            substrate
                        } else if r > radius - 2.0 {
                            rim
                        } else {
                            core
                        };
                    }
                }
                (v / 16.0).round() as u16
            })
            .collect();
        GrayFrame::new(w, h, 8, data).unwrap()
    }

    fn mean_radius(p: &Polygon) -> f64 {
        let c = p.centroid();
        p.points
            .iter()
            .map(|q| (q[0] - c[0]).hypot(q[1] - c[1]))
            .sum::<f64>()
            / p.len() as f64
    }

    #[test]
    fn a_dark_core_grows_to_the_outer_edge_of_its_rim() {
        let frame = disc(40.0, 60.0, 200.0, 140.0);
        for start in [36.5, 37.5, 38.0] {
            let grown = grow_over_rim(&frame, &Polygon::circle([100.0, 100.0], start, 96), 6.0, 0.15);
            let r = mean_radius(&grown);
            assert!(
                (r - 40.0).abs() < 0.5,
                "from radius {start}: grown to {r:.2}, expected 40 +- 0.5"
            );
        }
    }

    #[test]
    fn outlines_without_a_bright_rim_stay() {
        // No rim: the ring outside the dark core is the substrate.
        let plain = disc(40.0, 60.0, 60.0, 140.0);
        // A bright object: its surroundings are darker.
        let bright = disc(40.0, 200.0, 230.0, 60.0);
        for frame in [&plain, &bright] {
            let start = Polygon::circle([100.0, 100.0], 40.0, 96);
            let grown = grow_over_rim(frame, &start, 6.0, 0.15);
            assert_eq!(grown, start);
        }
        // Too close to the image border for the substrate band: unchanged.
        let near = Polygon::circle([12.0, 100.0], 8.0, 32);
        assert_eq!(grow_over_rim(&plain, &near, 6.0, 0.15), near);
    }
}

//! The bright edge rim of a dark object: grows a dark region's outline over it.
//!
//! SEM images brighten the edges of an object (more secondary electrons
//! escape near an edge), so a dark particle on a brighter substrate shows a
//! bright rim just inside its outline. The darker-than-its-surroundings
//! region the candidates find stops at the inner side of that rim, a few
//! pixels inside the object. [`grow_over_rim`] measures the brightness
//! profile outwards in half-pixel rings, sector by sector along the outline
//! (region sums of thin strips, O(strip length) each), and moves each part
//! of the outline to the outer edge of the rim there. Sector by sector,
//! because the rim is rarely even: a shaded sphere's lit side is bright out
//! to its edge, where an outline already sits, while its shadowed side
//! shows a thin rim.

use crate::geometry::{Point, Polygon};
use crate::imageio::GrayFrame;
use crate::region::{PixelRect, PrefixSums};

/// How many times the reach a sector whose rim still rises there is
/// measured out to.
const FAR_REACH: f64 = 2.0;

/// Width of one ring, pixels.
const RING_PX: f64 = 0.5;

/// The substrate is the band this far outside the largest growth, pixels.
const SUBSTRATE_BAND_PX: [f64; 2] = [3.0, 9.0];

/// How far inside the outline the profile starts, as a share of the
/// outward reach.
const INWARD_SHARE: f64 = 0.6;

/// Length of a sector along the outline, pixels (at least 8 sectors): a
/// ring's strip then covers about 8 pixels, short enough to follow a rod's
/// rounded end.
const SECTOR_PX: f64 = 16.0;

/// A dark object's outline grown over its bright rim.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct Grown {
    /// The outline on the rim's outer edge.
    pub outline: Polygon,
    /// Mean distance the outline moved, pixels.
    pub mean_px: f64,
}

/// `contour` (a dark object's outline, away from the image border) grown
/// outwards over a bright rim within `max_px`. In each sector the mean of
/// every half-pixel ring out to `max_px` is measured (with a quarter weight
/// from each neighbouring sector against noise); where the brightest
/// exceeds the substrate's mean there (the band 3..9 px beyond `max_px`) by
/// at least `min_excess` of the substrate-to-object contrast, that part of
/// the outline moves to where the rim falls half way back to the substrate
/// beyond its peak, elsewhere it stays. A sector whose bands leave the
/// image takes the growth of the nearest measured sector on either side.
/// A sector whose rim still rises at `max_px`, or does not fall back
/// within it, is measured again out to [`FAR_REACH`] times as far (a large
/// grain's steep side can show a rim 15 px wide, and the substrate band
/// then lay on it); one whose rim still rises there takes the growth of
/// its measured neighbours. A lone sector left without a rim between two
/// grown by more than half of `max_px` takes their mean. `None` when no sector has
/// such a rim, when every sector's bands leave the image, or when the
/// outline is too small to offset.
pub(super) fn grow_over_rim(
    frame: &GrayFrame,
    contour: &Polygon,
    max_px: f64,
    min_excess: f64,
) -> Option<Grown> {
    let n = contour.len();
    if n < 16 {
        return None;
    }
    // Normals from a smoothed copy (about 9 vertices): the outline's pixel
    // noise would turn offsets of 10-20 px along the vertex normals into
    // loops.
    let normals = contour.moving_average(4).outward_normals();
    let at = |i: usize, d: f64| -> Point {
        let (p, q) = (contour.points[i % n], normals[i % n]);
        [p[0] + d * q[0], p[1] + d * q[1]]
    };
    // Sector k spans vertices starts[k]..=starts[k + 1] (cyclically).
    let count = ((contour.length() / SECTOR_PX).round() as usize).clamp(8, n / 2);
    let starts: Vec<usize> = (0..=count).map(|k| k * n / count).collect();
    let near = sector_growth(frame, contour, &at, &starts, max_px, min_excess)?;
    // Where the rim still rises at the reach (a wide rim on a large grain's
    // steep side), the profile is measured again out to twice as far; its
    // growth counts when it lies beyond half the first reach. Where it
    // still rises there, the profile says nothing of the edge, and the
    // sector takes its measured neighbours' growth like one whose bands
    // leave the image (a dark grain's lit side, its rim brighter and wider
    // than elsewhere, kept three sectors on the core between sectors grown
    // by 15-18 px).
    let growth = if near.contains(&Sector::Unfinished) {
        let far = sector_growth(frame, contour, &at, &starts, FAR_REACH * max_px, min_excess);
        near.iter()
            .enumerate()
            .map(|(k, &g)| match (g, far.as_ref().map(|f| f[k])) {
                (Sector::Unfinished, Some(Sector::Grown(f))) if f > 0.5 * max_px => Sector::Grown(f),
                (Sector::Unfinished | Sector::Grown(0.0), Some(Sector::Unfinished)) => Sector::Unmeasured,
                (Sector::Unfinished, _) => Sector::Grown(0.0),
                (g, _) => g,
            })
            .collect()
    } else {
        near
    };
    // A sector not measured takes the mean of the nearest measured sector
    // on either side (no sector is left unfinished here: the second pass
    // settled them all).
    let value = |g: Sector| match g {
        Sector::Grown(v) => Some(v),
        Sector::Unfinished => Some(0.0),
        Sector::Unmeasured => None,
    };
    let nearest = |k: usize, step: usize| {
        (1..count)
            .map(|j| (k + j * step) % count)
            .find_map(|j| value(growth[j]))
            .unwrap_or(0.0)
    };
    let growth: Vec<f64> = (0..count)
        .map(|k| value(growth[k]).unwrap_or_else(|| 0.5 * (nearest(k, 1) + nearest(k, count - 1))))
        .collect();
    // A lone sector left without a rim between two grown by more than half
    // the reach takes their mean: a rim does not stop for 16 px of outline,
    // while a profile can mislead (the substrate band on the rim, or the
    // rim still rising at twice the reach, a dark grain's rim 16-19 px wide
    // left a notch in its outline).
    let growth: Vec<f64> = (0..count)
        .map(|k| {
            let (before, after) = (growth[(k + count - 1) % count], growth[(k + 1) % count]);
            if growth[k] == 0.0 && before.min(after) > 0.5 * max_px {
                0.5 * (before + after)
            } else {
                growth[k]
            }
        })
        .collect();
    if growth.iter().all(|&g| g == 0.0) {
        return None;
    }
    let offsets = super::edge_fit::per_vertex(&starts, &growth, n);
    let outline = Polygon::new((0..n).map(|i| at(i, offsets[i])).collect());
    let mean_px = offsets.iter().sum::<f64>() / n as f64;
    Some(Grown { outline, mean_px })
}

/// What one sector's profile says.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Sector {
    /// Its bands leave the image.
    Unmeasured,
    /// The outline moves this far out (0: no rim).
    Grown(f64),
    /// The rim does not fall back to the substrate within reach.
    Unfinished,
}

/// Each sector's growth over the rim within `max_px` (see
/// [`grow_over_rim`]); `None` when the profiles leave the image everywhere
/// or the substrate is not brighter than the object.
fn sector_growth(
    frame: &GrayFrame,
    contour: &Polygon,
    at: &dyn Fn(usize, f64) -> Point,
    starts: &[usize],
    max_px: f64,
    min_excess: f64,
) -> Option<Vec<Sector>> {
    let count = starts.len() - 1;
    let reach = max_px + SUBSTRATE_BAND_PX[1] + 2.0;
    let rect = PixelRect::around(contour.bounds(), reach, frame.width, frame.height)?;
    // Only differences of means are compared: no intensity offset needed.
    let sums = PrefixSums::new(frame, rect, 0);
    // Sum and area of the strip between offsets d0 < d1 along sector k.
    let strip = |k: usize, d0: f64, d1: f64| -> [f64; 2] {
        let (a, b) = (starts[k], starts[k + 1]);
        let mut points: Vec<Point> = (a..=b).map(|i| at(i, d0)).collect();
        points.extend((a..=b).rev().map(|i| at(i, d1)));
        let s = sums.polygon(&points);
        [s.sum, s.count]
    };
    if !sums.contains(&contour.points) {
        return None;
    }
    let object = sums.polygon(&contour.points).mean();
    // Rings from `inward` inside the outline, which may already lie on
    // the rim or beyond it in places, out to `max_px`.
    let inward = (INWARD_SHARE * max_px / RING_PX).floor() as usize;
    let rings = inward + (max_px / RING_PX).floor() as usize;
    let ring = |r: usize| (r as f64 - inward as f64) * RING_PX;
    let substrate_band = [max_px + SUBSTRATE_BAND_PX[0], max_px + SUBSTRATE_BAND_PX[1]];
    // A sector whose profile runs out of the image (an object near the
    // border) is not measured; it takes its measured neighbours' growth.
    let measured: Vec<bool> = (0..count)
        .map(|k| {
            let (a, b) = (starts[k], starts[k + 1]);
            let ends: Vec<Point> = (a..=b)
                .flat_map(|i| [at(i, ring(0)), at(i, substrate_band[1])])
                .collect();
            sums.contains(&ends)
        })
        .collect();
    if !measured.contains(&true) {
        return None;
    }
    // Per measured sector: the substrate band, then every ring, as [sum,
    // area]; zeros elsewhere.
    let raw: Vec<Vec<[f64; 2]>> = (0..count)
        .map(|k| {
            if !measured[k] {
                return vec![[0.0, 0.0]; rings + 1];
            }
            std::iter::once(strip(k, substrate_band[0], substrate_band[1]))
                .chain((0..rings).map(|r| strip(k, ring(r), ring(r) + RING_PX)))
                .collect()
        })
        .collect();
    let total = |r: usize| {
        raw.iter()
            .fold([0.0, 0.0], |t, s| [t[0] + s[r][0], t[1] + s[r][1]])
    };
    let [sum, area] = total(0);
    if area <= 0.0 {
        return None;
    }
    let contrast = sum / area - object;
    if contrast <= 0.0 {
        return None;
    }
    // Each sector's means, a quarter weight from each neighbour.
    let growth = (0..count)
        .map(|k| {
            if !measured[k] {
                return Sector::Unmeasured;
            }
            let grown = || -> Option<Sector> {
                let means: Option<Vec<f64>> = (0..=rings)
                    .map(|r| {
                        let [s, a] = [(count + k - 1) % count, k, (k + 1) % count]
                            .iter()
                            .zip([0.25, 0.5, 0.25])
                            .fold([0.0, 0.0], |t, (&j, w)| {
                                [t[0] + w * raw[j][r][0], t[1] + w * raw[j][r][1]]
                            });
                        (a > 0.0).then(|| s / a)
                    })
                    .collect();
                let means = means?;
                let (substrate, profile) = (means[0], &means[1..]);
                let (peak_at, &peak) = profile.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1))?;
                // Still rising at the reach: the substrate band may lie on
                // the rim itself.
                if peak_at + 2 >= profile.len() {
                    return Some(Sector::Unfinished);
                }
                if peak - substrate < min_excess * contrast {
                    return Some(Sector::Grown(0.0));
                }
                // The outline is where the rim falls back to the substrate
                // most steeply (an anti-aliased edge's midpoint), found between
                // the peak and the first ring at half its excess: the
                // half-way level itself sits 0.45 px out on average, as the
                // outline's own scatter lowers the narrow peak.
                let half = substrate + 0.5 * (peak - substrate);
                let Some(end) = (peak_at + 1..profile.len()).find(|&r| profile[r] <= half) else {
                    return Some(Sector::Unfinished);
                };
                let end = (end + 2).min(profile.len() - 1);
                // Fall between rings r - 1 and r, at their common boundary.
                let fall = |r: usize| profile[r - 1] - profile[r];
                let r = (peak_at + 1..=end).max_by(|&a, &b| fall(a).total_cmp(&fall(b)))?;
                // Parabola through the falls around the steepest.
                let shift = if r > peak_at + 1 && r < end {
                    let (a, b, c) = (fall(r - 1), fall(r), fall(r + 1));
                    let d = a - 2.0 * b + c;
                    if d < 0.0 {
                        (0.5 * (a - c) / d).clamp(-0.5, 0.5)
                    } else {
                        0.0
                    }
                } else {
                    0.0
                };
                Some(Sector::Grown(ring(r) + shift * RING_PX))
            };
            grown().unwrap_or(Sector::Grown(0.0))
        })
        .collect();
    Some(growth)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A disc of radius `radius` at (100, 100): `core` inside, a 2-px ring
    /// of `rim` just inside the outline, `substrate` outside (anti-aliased
    /// by 4x4 supersampling).
    fn disc(radius: f64, core: f64, rim: f64, substrate: f64) -> GrayFrame {
        disc_in(200, radius, core, rim, substrate)
    }

    /// [`disc`] in an image `w` pixels wide.
    fn disc_in(w: u32, radius: f64, core: f64, rim: f64, substrate: f64) -> GrayFrame {
        let h = 200u32;
        let data = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                let v = crate::imageio::pixel_mean(x, y, |px, py| {
                    let r = (px - 100.0).hypot(py - 100.0);
                    if r > radius {
                        substrate
                    } else if r > radius - 2.0 {
                        rim
                    } else {
                        core
                    }
                });
                v.round() as u16
            })
            .collect();
        GrayFrame::new(w, h, 8, data).unwrap()
    }

    /// A 200 x 200 frame whose brightness at distance `r` from (100, 100),
    /// at `degrees` (image coordinates, y down), is `value(r, degrees)`,
    /// anti-aliased by 4x4 supersampling.
    fn radial(value: impl Fn(f64, f64) -> f64) -> GrayFrame {
        let data = (0..200u32 * 200)
            .map(|i| {
                let (x, y) = ((i % 200) as f64, (i / 200) as f64);
                crate::imageio::pixel_mean(x, y, |px, py| {
                    let (dx, dy) = (px - 100.0, py - 100.0);
                    value(dx.hypot(dy), dy.atan2(dx).to_degrees())
                })
                .round() as u16
            })
            .collect();
        GrayFrame::new(200, 200, 8, data).unwrap()
    }

    /// A dark grain's steep side: the core (60) brightens linearly from
    /// radius 30 to a rim of 200 at `edge`, on a substrate of 140.
    fn ramp(r: f64, edge: f64) -> f64 {
        if r > edge {
            140.0
        } else {
            60.0 + 140.0 * ((r - 30.0) / (edge - 30.0)).clamp(0.0, 1.0)
        }
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
            let Grown { outline, mean_px: by } =
                grow_over_rim(&frame, &Polygon::circle([100.0, 100.0], start, 96), 6.0, 0.15).unwrap();
            let r = mean_radius(&outline);
            assert!((by - (r - start)).abs() < 0.05, "grown by {by:.2} to {r:.2}");
            assert!(
                (r - 40.0).abs() < 0.5,
                "from radius {start}: grown to {r:.2}, expected 40 +- 0.5"
            );
        }
    }

    #[test]
    fn a_rim_wider_than_the_reach_is_followed_to_its_outer_edge() {
        // Radius 40: the core (60) brightens linearly from radius 30 to a
        // rim of 200 at the edge, on a substrate of 140 (a dark grain's
        // steep side). From radius 31 the edge is 9 px out, past a reach
        // of 8 px where the rim is still rising.
        let frame = radial(|r, _| ramp(r, 40.0));
        let start = Polygon::circle([100.0, 100.0], 31.0, 96);
        let Grown { outline, .. } = grow_over_rim(&frame, &start, 8.0, 0.15).unwrap();
        let r = mean_radius(&outline);
        assert!((r - 40.0).abs() < 0.5, "grown to {r:.2}, expected 40 +- 0.5");
    }

    #[test]
    fn a_lone_sector_without_a_rim_between_grown_ones_takes_their_growth() {
        // Radius 44: the core (60) brightens linearly from radius 30 to a
        // rim of 200 at the edge, on a substrate of 140. Between 3 and 27
        // degrees a bright speck at radius 35-37 makes the first sector's
        // profile peak inside the 8-px reach from radius 31, below its
        // substrate band (42-48 px, half on the rim): no rim there, while
        // both neighbours still rise at the reach and are measured again
        // out to twice as far. Left alone, its outline stayed at radius 31,
        // a notch 13 px deep.
        let frame = radial(|r, degrees| {
            if (35.0..37.0).contains(&r) && (3.0..27.0).contains(&degrees) {
                215.0
            } else {
                ramp(r, 44.0)
            }
        });
        let start = Polygon::circle([100.0, 100.0], 31.0, 96);
        let Grown { outline, .. } = grow_over_rim(&frame, &start, 8.0, 0.3).unwrap();
        for (i, p) in outline.points.iter().enumerate().take(8).skip(1) {
            let r = (p[0] - 100.0).hypot(p[1] - 100.0);
            assert!(
                (r - 44.0).abs() < 1.5,
                "vertex {i}: radius {r:.2}, expected 44 +- 1.5"
            );
        }
    }

    #[test]
    fn sectors_whose_rim_rises_past_twice_the_reach_take_their_neighbours_growth() {
        // As above, but between 0 and 120 degrees the edge swells to a
        // radius of 60 (at 60 degrees), the rim rising all the way: past
        // twice the 8-px reach from radius 31 the profile never falls back,
        // and those sectors take the growth of the sectors beside them
        // instead of none.
        let frame = radial(|r, degrees| {
            let swell = (std::f64::consts::PI * degrees / 120.0).sin().powi(2);
            let edge = if (0.0..120.0).contains(&degrees) {
                44.0 + 16.0 * swell
            } else {
                44.0
            };
            ramp(r, edge)
        });
        let start = Polygon::circle([100.0, 100.0], 31.0, 96);
        let Grown { outline, .. } = grow_over_rim(&frame, &start, 8.0, 0.15).unwrap();
        // Without: radius 31 from 45 to 75 degrees (vertices 12-20).
        for (i, p) in outline.points.iter().enumerate().take(32) {
            let r = (p[0] - 100.0).hypot(p[1] - 100.0);
            assert!(
                (42.0..50.0).contains(&r),
                "vertex {i}: radius {r:.2}, expected 42-50"
            );
        }
    }

    #[test]
    fn a_core_near_the_border_grows_where_its_bands_leave_the_image() {
        // The disc's right side ends 6 px from the border: its substrate
        // band (3..9 px beyond the 6-px reach) leaves the image there.
        let frame = disc_in(146, 40.0, 60.0, 200.0, 140.0);
        let start = Polygon::circle([100.0, 100.0], 37.5, 96);
        let Grown { outline, .. } = grow_over_rim(&frame, &start, 6.0, 0.15).unwrap();
        let radii: Vec<f64> = outline
            .points
            .iter()
            .map(|q| (q[0] - 100.0).hypot(q[1] - 100.0))
            .collect();
        for (i, r) in radii.iter().enumerate() {
            assert!(
                (r - 40.0).abs() < 0.6,
                "vertex {i}: grown to radius {r:.2}, expected 40 +- 0.6"
            );
        }
        let c = outline.centroid();
        assert!(
            (c[0] - 100.0).hypot(c[1] - 100.0) < 0.2,
            "centroid {c:?}, expected (100, 100) within 0.2 px"
        );
    }

    #[test]
    fn outlines_without_a_bright_rim_stay() {
        // No rim: the ring outside the dark core is the substrate.
        let plain = disc(40.0, 60.0, 60.0, 140.0);
        // A bright object: its surroundings are darker.
        let bright = disc(40.0, 200.0, 230.0, 60.0);
        for frame in [&plain, &bright] {
            let start = Polygon::circle([100.0, 100.0], 40.0, 96);
            assert_eq!(grow_over_rim(frame, &start, 6.0, 0.15), None);
        }
        // Near the image border, with no rim where its bands are measured.
        let near = Polygon::circle([12.0, 100.0], 8.0, 32);
        assert_eq!(grow_over_rim(&plain, &near, 6.0, 0.15), None);
    }
}

//! Strips of substrate that a free fit keeps inside an outline: cut out,
//! and the outline fitted again around them.
//!
//! The free fit ([`crate::fit::fit_free`]) weighs each pixel against the
//! two regions' means over the whole window (Dahmen et al., section 3). On
//! a substrate whose brightness varies (grains, relief) the substrate next
//! to a bright grain boundary can be brighter than the window's mean
//! background by more than half the object's contrast, and a wedge of it
//! between a boundary and the object then lowers the energy: the outline
//! runs out along the boundary and back (relief rods: spikes of 3-9 px).
//!
//! [`cut_strips`] judges each pixel inside the outline against its
//! surroundings instead. After a 3x3 mean it belongs to the object when it
//! lies nearer the object's local level (the mean of the pixels at least
//! [`CORE_DEPTH_PX`] inside, within [`OBJECT_REACH_PX`]; measured again
//! without the pixels a first pass gave the substrate, so that a wide strip
//! does not lower it) than the substrate's (the mean of the pixels outside
//! the outline within [`SUBSTRATE_REACH_PX`]). The object's pixels are
//! opened with a disk of radius [`OPENING_RADIUS_PX`], which cuts the bright
//! lines that hold a wedge, and the largest opened region's holes are then
//! filled (filled first, a sliver that a line holds against the object
//! would be a hole, and kept). A part the opening removes is a strip when
//! - it is at least 3 px wide somewhere (it survives a one-pixel erosion);
//! - at least [`MIN_LINE_SHARE`] of it is the line that held it (pixels as
//!   bright as the object): the band inside a blurred edge, where the
//!   outline lies outside the edge, has none;
//! - its other pixels' mean lies at least [`MIN_STRIP_CONTRAST`] of the
//!   object's contrast and [`MIN_STRIP_SCORE`] standard errors away from
//!   the object's local level: a tool's thin point, cut by the opening, is
//!   as bright as the object, and where the object itself fades into the
//!   substrate's grey (a sphere's shaded side) its pixels are nearer the
//!   fade outside than the object's level but still close to the latter;
//!   when they were mostly a hole in the object's pixels, at least
//!   [`MIN_HOLE_STRIP_CONTRAST`] of the contrast: such pixels were picked
//!   for lying nearer the substrate, which noise alone achieves by up to
//!   half the contrast where the object fades at its edge.
//!
//! [`refit_without_strips`] fits freely again from the opened region's
//! outline, with no vertex allowed into a strip.

use image::{GrayImage, Luma};
use imageproc::region_labelling::{connected_components, Connectivity};

use crate::energy::EnergyParams;
use crate::fit::{fit_free_avoiding, FreeFitOutcome, FreeFitParams};
use crate::geometry::{Point, Polygon};
use crate::imageio::GrayFrame;
use crate::init::{dilate_disk, erode_disk, fill_region, mask_image, outer_regions, Region};
use crate::region::PrefixSums;

/// Radius of the opening that cuts lines and strips loose, pixels: lines up
/// to twice as wide go.
pub const OPENING_RADIUS_PX: u8 = 2;

/// Half-side of the square over which the substrate's local level is
/// averaged, pixels.
pub const SUBSTRATE_REACH_PX: u32 = 6;

/// Half-side of the square over which the object's local level is
/// averaged, pixels.
pub const OBJECT_REACH_PX: u32 = 10;

/// Depth inside the outline from which a pixel gives the object's level,
/// pixels: the blurred edge lies outside it.
pub const CORE_DEPTH_PX: u8 = 3;

/// Smallest difference between a strip's mean and the object's local
/// level, as a share of the object's contrast with its surroundings.
pub const MIN_STRIP_CONTRAST: f64 = 0.25;

/// Smallest difference between a strip's mean and the object's local
/// level, in standard errors of that mean under the pixel noise: a few
/// pixels darker by chance are no strip.
pub const MIN_STRIP_SCORE: f64 = 4.0;

/// The share of the object's contrast by which a strip that was mostly a
/// hole in the object's pixels lies off its level: noise picked for lying
/// nearer the substrate reaches about half the contrast where the object
/// fades at its edge (a shaded sphere under strong noise: 0.40), a sliver
/// of substrate nearly all of it (relief rods: 0.73-0.79).
pub const MIN_HOLE_STRIP_CONTRAST: f64 = 0.6;

/// Smallest share of a cut part that is the line holding it (pixels as
/// bright as the object that the opening cut off): a band along a blurred
/// edge, where the outline lies outside the edge, has none.
pub const MIN_LINE_SHARE: f64 = 0.25;

/// Largest share of the region the strips may take: more is not a strip
/// but part of the object unlike the rest (a sphere's shaded side).
pub const MAX_CUT_SHARE: f64 = 0.15;

/// `fitted` (a free fit's outline in `frame`, on `sums`) fitted again
/// without the strips of substrate it holds (see the module docs); `None`
/// when it holds none.
pub fn refit_without_strips(
    frame: &GrayFrame,
    sums: &PrefixSums,
    fitted: &Polygon,
    energy: &EnergyParams,
    params: &FreeFitParams,
    within: Option<[f64; 4]>,
) -> Option<FreeFitOutcome> {
    let cut = cut_strips(frame, fitted)?;
    let forbidden = |q: Point| cut.is_strip(q);
    Some(fit_free_avoiding(
        sums, &cut.start, energy, params, within, &forbidden,
    ))
}

/// An outline with its strips cut out: the opened region's outline, and
/// the removed strips as a mask over a box of the frame.
pub struct Cut {
    /// Outline of the object's pixels after the opening, through the
    /// centres of its border pixels (smoothed).
    pub start: Polygon,
    /// Top-left pixel of the mask's box.
    origin: [u32; 2],
    /// The removed strips (non-zero), over the box.
    strips: GrayImage,
}

impl Cut {
    /// Whether `q` lies in a removed strip (its nearest pixel does).
    pub fn is_strip(&self, q: Point) -> bool {
        let (x, y) = (
            q[0].round() - self.origin[0] as f64,
            q[1].round() - self.origin[1] as f64,
        );
        x >= 0.0
            && y >= 0.0
            && (x as u32) < self.strips.width()
            && (y as u32) < self.strips.height()
            && self.strips.get_pixel(x as u32, y as u32)[0] != 0
    }

    /// Pixels in the removed strips.
    pub fn strip_px(&self) -> usize {
        self.strips.pixels().filter(|p| p[0] != 0).count()
    }
}

/// The strips of substrate inside `outline` in `frame`, cut out (see the
/// module docs); `None` when there is none at least 3 px wide, or when the
/// strips would take more than [`MAX_CUT_SHARE`] of the region.
pub fn cut_strips(frame: &GrayFrame, outline: &Polygon) -> Option<Cut> {
    let reach = SUBSTRATE_REACH_PX as f64 + 2.0;
    let [bx0, by0, bx1, by1] = outline.bounds();
    if !(bx0.is_finite() && by0.is_finite() && bx1.is_finite() && by1.is_finite()) {
        return None;
    }
    let x0 = (bx0 - reach).floor().max(0.0) as u32;
    let y0 = (by0 - reach).floor().max(0.0) as u32;
    let x1 = ((bx1 + reach).ceil().max(0.0) as u32).min(frame.width.checked_sub(1)?);
    let y1 = ((by1 + reach).ceil().max(0.0) as u32).min(frame.height.checked_sub(1)?);
    if x1 < x0 + 8 || y1 < y0 + 8 {
        return None;
    }
    let (w, h) = (x1 - x0 + 1, y1 - y0 + 1);
    let inside = mask_image(
        w,
        h,
        &outline.translated([-(x0 as f64), -(y0 as f64)]).rasterize(w, h),
    );
    let area = inside.pixels().filter(|p| p[0] != 0).count();
    let core = erode_disk(&inside, CORE_DEPTH_PX);
    let at = |x: u32, y: u32| frame.data[((y0 + y) * frame.width + x0 + x) as usize] as f64;
    let smoothed = box_mean(w, h, 1, |x, y| Some(at(x, y)));
    let substrate = box_mean(w, h, SUBSTRATE_REACH_PX, |x, y| {
        (inside.get_pixel(x, y)[0] == 0).then(|| at(x, y))
    });
    // The object's local level, over the pixels of `mask`, and over all.
    let levels = |mask: &GrayImage| {
        let local = box_mean(w, h, OBJECT_REACH_PX, |x, y| {
            (mask.get_pixel(x, y)[0] != 0).then(|| at(x, y))
        });
        (local, mean_where(mask, true, at))
    };
    let classified = |(object, whole): &(Vec<Option<f64>>, Option<f64>)| {
        GrayImage::from_fn(w, h, |x, y| {
            let i = (y * w + x) as usize;
            let keep = inside.get_pixel(x, y)[0] != 0
                && match (substrate[i], object[i].or(*whole)) {
                    (Some(s), Some(o)) => {
                        let v = smoothed[i].unwrap_or(s);
                        (v - o).abs() <= (v - s).abs()
                    }
                    _ => true,
                };
            Luma([if keep { 255 } else { 0 }])
        })
    };
    // Twice: a strip wide enough to have a core of its own lowers the
    // object's level around it in the first pass.
    let first = classified(&levels(&core));
    let core = both(&core, &first);
    let levels = levels(&core);
    let like_object = classified(&levels);
    let (object, whole_object) = levels;
    // Opened before its holes are filled: a sliver of substrate that a
    // line holds against the object is a hole until the opening cuts the
    // line.
    let opened = dilate_disk(&erode_disk(&like_object, OPENING_RADIUS_PX), OPENING_RADIUS_PX);
    let region = outer_regions(&opened).into_iter().next()?;
    let kept = filled(&region, w, h);
    // What the cut removes, where it is at least 3 px wide (an opening by
    // one pixel): not the opening's rounding or the blurred edge's band.
    let removed = GrayImage::from_fn(w, h, |x, y| {
        let gone = inside.get_pixel(x, y)[0] != 0 && kept.get_pixel(x, y)[0] == 0;
        Luma([if gone { 255 } else { 0 }])
    });
    let wide = erode_disk(&removed, 1);
    let candidates = both(&dilate_disk(&wide, 1), &removed);
    // A strip counts when it differs from the object's local level by at
    // least MIN_STRIP_CONTRAST of the object's contrast with the substrate
    // around it: where the object itself fades (a sphere's shaded side),
    // the substrate's local level is the fade's, and the pixels nearer it
    // are still nearly the object's.
    let ring = mean_where(&inside, false, at);
    let contrast = (whole_object? - ring?).abs();
    // The pixel noise about the object's local level (median absolute
    // deviation, scaled to a standard deviation).
    let sigma = {
        let mut dev: Vec<f64> = core
            .enumerate_pixels()
            .filter(|(_, _, p)| p[0] != 0)
            .filter_map(|(x, y, _)| object[(y * w + x) as usize].map(|o| (at(x, y) - o).abs()))
            .collect();
        let mid = dev.len() / 2;
        1.4826 * *dev.select_nth_unstable_by(mid, f64::total_cmp).1
    };
    // The object's holes: pixels nearer the substrate that the object's
    // pixels enclose.
    let enclosing = filled(&outer_regions(&like_object).into_iter().next()?, w, h);
    let hole = |x: u32, y: u32| enclosing.get_pixel(x, y)[0] != 0 && like_object.get_pixel(x, y)[0] == 0;
    let mut strips = GrayImage::new(w, h);
    for part in components(&candidates) {
        // Its pixels nearer the substrate; the rest is the line that held
        // it (object-like pixels the opening cut off).
        let substrate_like: Vec<(u32, u32)> = part
            .iter()
            .copied()
            .filter(|&(x, y)| like_object.get_pixel(x, y)[0] == 0)
            .collect();
        let line = part.len() - substrate_like.len();
        let (mut off, mut n) = (0.0, 0.0f64);
        for &(x, y) in &substrate_like {
            if let Some(o) = object[(y * w + x) as usize].or(whole_object) {
                off += at(x, y) - o;
                n += 1.0;
            }
        }
        let off = (off / n.max(1.0)).abs();
        let held = line as f64 >= MIN_LINE_SHARE * part.len() as f64;
        // Mostly a hole's pixels: chosen for lying nearer the substrate,
        // noise on a fading edge reaches up to half the contrast.
        let from_hole =
            2 * substrate_like.iter().filter(|&&(x, y)| hole(x, y)).count() > substrate_like.len();
        let min_contrast = if from_hole {
            MIN_HOLE_STRIP_CONTRAST
        } else {
            MIN_STRIP_CONTRAST
        };
        if held && n > 0.0 && off >= min_contrast * contrast && off >= MIN_STRIP_SCORE * sigma / n.sqrt() {
            for &(x, y) in &part {
                strips.put_pixel(x, y, Luma([255]));
            }
        }
    }
    let strip_px = strips.pixels().filter(|p| p[0] != 0).count();
    if strip_px == 0 || strip_px as f64 > MAX_CUT_SHARE * area as f64 {
        return None;
    }
    let start = Polygon::new(
        region
            .border
            .iter()
            .map(|p| [(p[0] + x0 as i32) as f64, (p[1] + y0 as i32) as f64])
            .collect(),
    )
    .moving_average(2);
    (start.len() >= 8).then_some(Cut {
        start,
        origin: [x0, y0],
        strips,
    })
}

/// Mean of `value(x, y)` over the pixels of `mask` that are non-zero (or,
/// with `set` false, zero); `None` when there is none.
fn mean_where(mask: &GrayImage, set: bool, value: impl Fn(u32, u32) -> f64) -> Option<f64> {
    let (sum, n) = mask
        .enumerate_pixels()
        .filter(|(_, _, p)| (p[0] != 0) == set)
        .fold((0.0, 0usize), |(sum, n), (x, y, _)| (sum + value(x, y), n + 1));
    (n > 0).then(|| sum / n as f64)
}

/// The pixels non-zero in both `a` and `b` (of one size), 255/0.
fn both(a: &GrayImage, b: &GrayImage) -> GrayImage {
    GrayImage::from_fn(a.width(), a.height(), |x, y| {
        Luma([if a.get_pixel(x, y)[0] != 0 && b.get_pixel(x, y)[0] != 0 {
            255
        } else {
            0
        }])
    })
}

/// Mean of `value(x, y)` over the pixels where it is `Some`, in the square
/// of half-side `r` around each pixel of a `w x h` box (summed-area
/// tables); `None` where there is no such pixel.
fn box_mean(w: u32, h: u32, r: u32, value: impl Fn(u32, u32) -> Option<f64>) -> Vec<Option<f64>> {
    let (w, h) = (w as usize, h as usize);
    let stride = w + 1;
    let mut sum = vec![0.0; stride * (h + 1)];
    let mut count = vec![0.0; stride * (h + 1)];
    for y in 0..h {
        for x in 0..w {
            let (s, c) = value(x as u32, y as u32).map_or((0.0, 0.0), |v| (v, 1.0));
            let i = (y + 1) * stride + x + 1;
            sum[i] = s + sum[i - 1] + sum[i - stride] - sum[i - stride - 1];
            count[i] = c + count[i - 1] + count[i - stride] - count[i - stride - 1];
        }
    }
    let r = r as usize;
    let rect = |t: &[f64], xa: usize, ya: usize, xb: usize, yb: usize| {
        t[yb * stride + xb] - t[ya * stride + xb] - t[yb * stride + xa] + t[ya * stride + xa]
    };
    (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let (xa, ya, xb, yb) = (
                x.saturating_sub(r),
                y.saturating_sub(r),
                (x + r + 1).min(w),
                (y + r + 1).min(h),
            );
            let c = rect(&count, xa, ya, xb, yb);
            (c > 0.5).then(|| rect(&sum, xa, ya, xb, yb) / c)
        })
        .collect()
}

/// `region` filled (holes included), as a `w x h` mask.
fn filled(region: &Region, w: u32, h: u32) -> GrayImage {
    let (part, px, py) = fill_region(&region.border);
    let mut out = GrayImage::new(w, h);
    image::imageops::replace(&mut out, &part, px as i64, py as i64);
    out
}

/// The 8-connected parts of `mask` (non-zero pixels), as pixel lists.
fn components(mask: &GrayImage) -> Vec<Vec<(u32, u32)>> {
    let labels = connected_components(mask, Connectivity::Eight, Luma([0u8]));
    let mut parts: Vec<Vec<(u32, u32)>> = Vec::new();
    for (x, y, label) in labels.enumerate_pixels() {
        if let Some(k) = (label[0] as usize).checked_sub(1) {
            if parts.len() <= k {
                parts.resize_with(k + 1, Vec::new);
            }
            parts[k].push((x, y));
        }
    }
    parts
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::free_fit_tables;
    use crate::geometry::polygon_iou;

    /// The rod's outline: a 120 x 20 px bar.
    fn rod() -> Polygon {
        Polygon::new(vec![[40.0, 50.0], [160.0, 50.0], [160.0, 70.0], [40.0, 70.0]])
    }

    /// The outline a free fit held on a grain boundary gives: the rod and a
    /// wedge on its upper edge between x = 100 and 130, 14 px high.
    fn rod_with_wedge() -> Polygon {
        Polygon::new(vec![
            [40.0, 50.0],
            [100.0, 50.0],
            [125.0, 36.0],
            [130.0, 50.0],
            [160.0, 50.0],
            [160.0, 70.0],
            [40.0, 70.0],
        ])
    }

    /// A 200 x 120 frame: substrate at 60, the rod at 150, a bright line
    /// (150) along the wedge's outer edges, and a grain of brighter
    /// substrate at `grain` above the rod between x = 90 and 140 (the
    /// wedge is part of it), with deterministic noise of +-`noise`.
    fn scene(grain: f64, noise: f64) -> GrayFrame {
        let (w, h) = (200u32, 120u32);
        let rod = rod().rasterize(w, h);
        let outer = rod_with_wedge().rasterize(w, h);
        let line = |x: f64, y: f64| {
            let d1 = crate::geometry::segment_distance([x, y], [100.0, 50.0], [125.0, 36.0]);
            let d2 = crate::geometry::segment_distance([x, y], [125.0, 36.0], [130.0, 50.0]);
            d1.min(d2) <= 1.2
        };
        let data = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                let base = if rod[i as usize] || line(x, y) {
                    150.0
                } else if outer[i as usize] || ((90.0..140.0).contains(&x) && (30.0..50.0).contains(&y)) {
                    grain
                } else {
                    60.0
                };
                // A hash of the position in -1..1.
                let hash =
                    ((i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 40) as f64 / (1u64 << 24) as f64;
                (base + noise * (2.0 * hash - 1.0)).round() as u16
            })
            .collect();
        GrayFrame {
            width: w,
            height: h,
            bit_depth: 8,
            data,
        }
    }

    #[test]
    fn a_wedge_of_bright_substrate_is_cut_out() {
        let frame = scene(95.0, 20.0);
        let cut = cut_strips(&frame, &rod_with_wedge()).expect("the wedge is a strip");
        // Inside the wedge, not in the rod or on its edge.
        assert!(cut.is_strip([122.0, 44.0]));
        for q in [[100.0, 60.0], [115.0, 51.0], [150.0, 51.0], [41.0, 60.0]] {
            assert!(!cut.is_strip(q), "{q:?} is not in the wedge");
        }
        assert!((20..200).contains(&cut.strip_px()), "{} px", cut.strip_px());
    }

    #[test]
    fn the_refit_leaves_the_wedge_out() {
        let frame = scene(95.0, 20.0);
        let energy = EnergyParams::default();
        let held = rod_with_wedge();
        let sums = free_fit_tables(&frame, &held, &energy).unwrap();
        let refit = refit_without_strips(&frame, &sums, &held, &energy, &FreeFitParams::default(), None)
            .expect("a strip to cut");
        let before = polygon_iou(&held, &rod());
        let after = polygon_iou(&refit.polygon, &rod());
        // The wedge is 5% of the rod's area; the refit's outline lies on
        // the rod's edges to a fraction of a pixel.
        assert!(before < 0.96, "{before}");
        assert!(after > 0.97, "{after}");
    }

    #[test]
    fn an_outline_without_a_wedge_is_left_alone() {
        assert!(cut_strips(&scene(95.0, 20.0), &rod()).is_none());
    }

    #[test]
    fn a_part_as_bright_as_the_object_is_no_strip() {
        // The "wedge" is part of the object: the opening cuts nothing wide.
        assert!(cut_strips(&scene(150.0, 20.0), &rod_with_wedge()).is_none());
        // Fainter, but nearer the object's level than the substrate's.
        assert!(cut_strips(&scene(130.0, 20.0), &rod_with_wedge()).is_none());
    }

    /// Deterministic noise in about -1..1 (a sum of three hashed uniforms,
    /// roughly Gaussian with standard deviation 0.5).
    fn hashed_noise(i: u64) -> f64 {
        (1..=3u64)
            .map(|k| {
                let h = (i.wrapping_add(k << 32)).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 40;
                h as f64 / (1u64 << 24) as f64 - 0.5
            })
            .sum::<f64>()
    }

    #[test]
    fn a_sliver_of_substrate_a_line_holds_against_the_object_is_cut() {
        // The rod at 150 on 60, and above its upper edge between x = 100
        // and 130 a bright line 2 px wide that closes a 5-px sliver of
        // substrate against it; the outline takes in the line and the
        // sliver. The sliver is a hole in the object's pixels until the
        // opening cuts the line.
        let outline = Polygon::new(vec![
            [40.0, 50.0],
            [100.0, 50.0],
            [100.0, 43.0],
            [130.0, 43.0],
            [130.0, 50.0],
            [160.0, 50.0],
            [160.0, 70.0],
            [40.0, 70.0],
        ]);
        let (w, h) = (200u32, 120u32);
        let rod = rod().rasterize(w, h);
        let data = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let line =
                    (100..=130).contains(&x) && (43..=49).contains(&y) && (y <= 44 || x <= 101 || x >= 129);
                let base = if rod[i as usize] || line { 150.0 } else { 60.0 };
                (base + 20.0 * hashed_noise(i as u64)).round() as u16
            })
            .collect();
        let frame = GrayFrame::new(w, h, 8, data).unwrap();
        let cut = cut_strips(&frame, &outline).expect("the sliver is a strip");
        assert!(cut.is_strip([115.0, 47.0]));
        for q in [[100.0, 60.0], [115.0, 52.0], [150.0, 51.0]] {
            assert!(!cut.is_strip(q), "{q:?} is not in the sliver");
        }
    }
}

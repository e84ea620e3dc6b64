//! Candidate objects for the initialisation, and the score that ranks them.
//!
//! Two sources of candidates on the working image:
//! - the paper's edge pipeline (Canny, dilation, filled outer contours,
//!   erosion; see [`super::initialise`]), and
//! - threshold components: for grey levels spread between the working
//!   image's extremes, the 4-connected components above the level (for
//!   brighter objects) and below it (darker), with holes filled and thin
//!   appendages cut off by an opening scaled to the component. For a fixed
//!   window the two-region Poisson model's best labelling of the pixels is a
//!   threshold (its per-pixel log-likelihood ratio is monotonic in the grey
//!   value), so these are the model's own partitions, regularised. They need
//!   no closed outline, so an object cut by the image border is found too.
//!
//! Every candidate is scored with the method's region energy (method note,
//! section 2) on the working image, in full-resolution pixels:
//!
//! ```text
//! E = L^2 / A - D / m_w,   D = N_a f(m_a) + N_b f(m_b) - N_w f(m_w),   f(z) = z ln z
//! score = -E / L
//! ```
//!
//! over the window w (the bounding box grown by 0.3 sqrt(A), at least 8 px),
//! where L leaves out the outline's run along the image border (not an edge
//! of the object). The score is the energy the outline gains per pixel of its
//! length: about a quarter of the object's thickness times its squared
//! relative contrast, so it prefers thick, contrasted regions to slivers,
//! ragged outlines and faint patches of background, and size counts only
//! through thickness.

use image::{GrayImage, Luma};

use super::morphology::{dilate_disk, erode_disk, fill_region, outer_regions};
use super::{FloatImage, Polarity};

/// Width of the bands inside and outside a candidate's outline whose grey
/// difference tells an edge from a level line of a smooth gradient,
/// working pixels.
const EDGE_BAND: u8 = 2;

/// How far from a candidate's outline its edge is sought, working pixels
/// inwards and outwards: a threshold component of the smoothed image
/// reaches 2-3 px past the edge of a bright grain with an edge rim (tilted
/// grain 200: its bands on either side of the outline both lay on the
/// substrate, a share of 0.02, and a region running out along a scratch
/// was taken instead).
const EDGE_REACH: [i32; 2] = [3, 2];

/// A part that the edges cut off a region under the point replaces the
/// region only when it holds at most this share of it (see
/// [`WorkArea::part_under_point`]): less is the edge pixels along its own
/// outline, not another object.
const PART_SHARE: f64 = 0.9;

/// Least share of the outline of a part under the point that must lie on
/// its region's outline: a grain's core inside the edges along its
/// rim showed 0.00-0.05 of it there (tilted renderer, grain seed 7 and the
/// crossed needle's grain), the real parts beside another object 0.35-0.95.
const PART_OUTER_SHARE: f64 = 0.2;

/// Grey levels tried per polarity.
const LEVELS: usize = 16;

/// How a candidate was found.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "snake_case", tag = "kind"))]
pub enum Source {
    /// A filled outline of the edge pipeline (dilation radius in working px).
    Edges { dilation_radius: u8 },
    /// A component above (`brighter`) or below (`darker`) a grey level
    /// (0..=1 of full scale).
    Threshold { polarity: Polarity, level: f32 },
    /// The region a person outlined (the `outline` hint).
    Outline,
}

/// The energy terms behind a candidate's score, in full-resolution pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Score {
    /// -E / L: the energy gain per pixel of outline (higher is better).
    pub score: f64,
    /// Michelson contrast of the region against the rest of its window,
    /// -1..=1 (negative: darker than its surroundings).
    pub contrast: f64,
    /// D / m_w, the two-region log-likelihood ratio (>= 0).
    pub data: f64,
    /// Outline length L, leaving out the run along the image border.
    pub outline_px: f64,
    /// Area A.
    pub area_px: f64,
}

/// Where the object may lie, and how the working image maps to the frame.
pub(super) struct WorkArea<'a> {
    /// The working copy (0..=1), unblurred: the scores' statistics.
    pub work: &'a FloatImage,
    /// The blurred working copy: the threshold components.
    pub blurred: &'a FloatImage,
    /// Integer downsampling factor.
    pub scale: u32,
    /// Which sides of the working image (left, top, right, bottom) lie on
    /// the image border.
    pub image_sides: [bool; 4],
    /// The working pixels `[x0, y0, x1, y1)` a candidate may cover (the
    /// roi with a little slack, or everything).
    pub domain: [u32; 4],
    /// The roi itself in working pixels (the domain without its slack).
    pub roi_box: [u32; 4],
    /// A working pixel the object must cover (the point hint).
    pub point: Option<[u32; 2]>,
    /// Working pixels the object must not cover (the `exclude` hint; those
    /// outside the working image left out).
    pub exclude: Vec<[u32; 2]>,
    /// Object polarity allowed.
    pub polarity: Polarity,
    /// Area range in working pixels.
    pub min_area: f64,
    pub max_area: f64,
    /// The grey-value offset of the energy (one grey level) on the 0..=1 scale.
    pub offset: f64,
    /// Summed-area table of `work`.
    pub table: SummedArea,
}

/// A summed-area table of a working image: window sums in O(1).
pub(super) struct SummedArea {
    stride: usize,
    sums: Vec<f64>,
}

impl SummedArea {
    pub fn new(image: &FloatImage) -> Self {
        let (w, h) = (image.width() as usize, image.height() as usize);
        let stride = w + 1;
        let mut sums = vec![0.0; stride * (h + 1)];
        for (y, row) in image.as_raw().chunks_exact(w).enumerate() {
            let mut acc = 0.0;
            for (x, &v) in row.iter().enumerate() {
                acc += v as f64;
                sums[(y + 1) * stride + x + 1] = sums[y * stride + x + 1] + acc;
            }
        }
        Self { stride, sums }
    }

    /// Pixel count and sum over `[x0, y0, x1, y1)`.
    pub fn sum(&self, [x0, y0, x1, y1]: [usize; 4]) -> (f64, f64) {
        let at = |x: usize, y: usize| self.sums[y * self.stride + x];
        let n = ((x1 - x0) * (y1 - y0)) as f64;
        (n, at(x1, y1) - at(x0, y1) - at(x1, y0) + at(x0, y0))
    }
}

/// A candidate region on the working image.
#[derive(Clone, Debug)]
pub(super) struct Candidate {
    /// Working coordinates of the mask's first pixel.
    pub origin: [u32; 2],
    pub width: u32,
    pub height: u32,
    /// Row-major, `width * height`.
    pub mask: Vec<bool>,
    pub source: Source,
    pub score: Score,
    /// The sides (left, top, right, bottom) where the region was cut at the
    /// roi's box because it went on past it (see `WorkArea::clipped_to_box`).
    pub cut_at_box: [bool; 4],
}

impl Candidate {
    /// The mask as an 8-bit image (255 inside).
    pub fn image(&self) -> GrayImage {
        GrayImage::from_raw(
            self.width,
            self.height,
            self.mask.iter().map(|&m| if m { 255 } else { 0 }).collect(),
        )
        .expect("length matches size")
    }

    /// The bounding box `[x0, y0, x1, y1)` in working pixels.
    pub fn bbox(&self) -> [u32; 4] {
        [
            self.origin[0],
            self.origin[1],
            self.origin[0] + self.width,
            self.origin[1] + self.height,
        ]
    }

    /// Pixels inside.
    pub fn area(&self) -> usize {
        self.mask.iter().filter(|&&m| m).count()
    }

    /// Which sides (left, top, right, bottom) of the box `[x0, y0, x1, y1)`
    /// the region reaches: its bounding box lies on that side and a pixel
    /// of it there is inside.
    pub fn reaches(&self, [x0, y0, x1, y1]: [u32; 4]) -> [bool; 4] {
        let (cw, ch) = (self.width, self.height);
        let any_in_column = |x: u32| (0..ch).any(|y| self.mask[(y * cw + x) as usize]);
        let any_in_row = |y: u32| (0..cw).any(|x| self.mask[(y * cw + x) as usize]);
        let [bx1, by1] = [self.origin[0] + cw, self.origin[1] + ch];
        [
            self.origin[0] == x0 && any_in_column(0),
            self.origin[1] == y0 && any_in_row(0),
            bx1 == x1 && any_in_column(cw - 1),
            by1 == y1 && any_in_row(ch - 1),
        ]
    }

    /// Whether the working pixel `[x, y]` is inside.
    pub fn covers(&self, [x, y]: [u32; 2]) -> bool {
        let ([x0, y0], w) = (self.origin, self.width);
        x >= x0
            && y >= y0
            && x - x0 < w
            && y - y0 < self.height
            && self.mask[((y - y0) * w + (x - x0)) as usize]
    }
}

/// Why candidates were turned down, for the error when none is left.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Rejections {
    /// Largest area (working px) of a region outside the size range.
    pub largest_out_of_range: f64,
    /// Regions turned down for their size.
    pub size: usize,
    /// Regions that span the frame or fill the box (structure or background).
    pub spanning: usize,
    /// Regions of the wrong polarity or with no contrast.
    pub polarity: usize,
    /// Regions that do not cover the point.
    pub point: usize,
    /// Regions that cover a point that is not the object.
    pub excluded: usize,
}

impl WorkArea<'_> {
    fn width(&self) -> u32 {
        self.work.width()
    }

    fn height(&self) -> u32 {
        self.work.height()
    }

    /// Threshold components of both (or the allowed) polarities at
    /// [`LEVELS`] grey levels: every component in the size range is scored
    /// from running sums (holes and all), and the best few of each distinct
    /// region (see [`finalists`]) come back as masks with their holes
    /// filled, scored again (before pruning, see [`WorkArea::finish`]).
    /// Turned-down regions are counted in `rejected`.
    pub fn threshold_candidates(&self, rejected: &mut Rejections) -> Vec<Candidate> {
        let Some((lo, hi)) = self.level_range() else {
            return Vec::new();
        };
        let polarities: &[Polarity] = match self.polarity {
            Polarity::Any => &[Polarity::Brighter, Polarity::Darker],
            Polarity::Brighter => &[Polarity::Brighter],
            Polarity::Darker => &[Polarity::Darker],
        };
        let levels = Levels::new(self, lo, hi);
        let (w, min_count, max_count) = (
            self.width() as usize,
            (0.5 * self.min_area).max(1.0) as u32,
            1.5 * self.max_area,
        );
        // Every component's provisional score; the masks of those that can
        // still matter (a fifth of the best score so far, or more).
        let mut scored: Vec<(Candidate, Score)> = Vec::new();
        let mut best = 0.0f64;
        for &polarity in polarities {
            let mut emitted: std::collections::HashMap<u32, u32> = std::collections::HashMap::new();
            levels.grow(self, polarity, min_count, |k, forest| {
                for root in forest.large_roots() {
                    let stats = forest.stats(root);
                    // A component that barely grew since it was last scored
                    // is the same region.
                    if emitted.get(&root).is_some_and(|&n| stats.count < n + n / 50 + 1) {
                        continue;
                    }
                    emitted.insert(root, stats.count);
                    if stats.count as f64 > max_count {
                        continue;
                    }
                    let bbox = stats.bbox.map(u32::from);
                    if self.spans(bbox) {
                        rejected.spanning += 1;
                        continue;
                    }
                    if let Some([px, py]) = self.point {
                        let p = py as usize * w + px as usize;
                        if !forest.contains(p) || forest.find(p) != root {
                            rejected.point += 1;
                            continue;
                        }
                    }
                    let Some(score) =
                        self.score_from(stats.count as f64, stats.sum as f64, bbox, stats.edges as f64)
                    else {
                        continue;
                    };
                    if !self.polarity.admits(score.contrast) {
                        rejected.polarity += 1;
                        continue;
                    }
                    if score.score < 0.2 * best {
                        continue;
                    }
                    best = best.max(score.score);
                    let [x0, y0, x1, y1] = bbox;
                    let (cw, ch) = (x1 - x0, y1 - y0);
                    let mut mask = vec![false; (cw * ch) as usize];
                    for y in y0..y1 {
                        for x in x0..x1 {
                            let i = y as usize * w + x as usize;
                            mask[((y - y0) * cw + x - x0) as usize] =
                                forest.contains(i) && forest.find(i) == root;
                        }
                    }
                    let source = Source::Threshold {
                        polarity,
                        level: levels.value(k),
                    };
                    let candidate = Candidate {
                        origin: [x0, y0],
                        width: cw,
                        height: ch,
                        mask,
                        source,
                        score,
                        cut_at_box: [false; 4],
                    };
                    scored.push((candidate, score));
                }
            });
        }
        finalists(scored, |(c, score)| (c.bbox(), score.score))
            .into_iter()
            .filter_map(|(c, _)| {
                let mask = c.mask.clone();
                self.provisional(c.origin, c.width, c.height, mask, c.source, rejected)
            })
            .collect()
    }

    /// The grey levels' range: the 0.5th and 99.5th percentiles of the
    /// blurred domain; `None` for a featureless one.
    fn level_range(&self) -> Option<(f32, f32)> {
        let [x0, y0, x1, y1] = self.domain;
        let w = self.width() as usize;
        let values = self.blurred.as_raw();
        let step = (((x1 - x0) as usize * (y1 - y0) as usize) / 50_000).max(1);
        let mut sample: Vec<f32> = (y0 as usize..y1 as usize)
            .flat_map(|y| (x0 as usize..x1 as usize).map(move |x| y * w + x))
            .step_by(step)
            .map(|i| values[i])
            .collect();
        if sample.len() < 16 {
            return None;
        }
        let n = sample.len();
        let lo = *sample.select_nth_unstable_by(n / 200, |a, b| a.total_cmp(b)).1;
        let hi = *sample
            .select_nth_unstable_by(n - 1 - n / 200, |a, b| a.total_cmp(b))
            .1;
        (hi - lo > 1e-4).then_some((lo, hi))
    }

    /// A region from the edge pipeline (a traced border in working
    /// coordinates), clipped to the domain and scored.
    pub fn edge_candidate(
        &self,
        border: &[[i32; 2]],
        radius: u8,
        rejected: &mut Rejections,
    ) -> Option<Candidate> {
        let (filled, bx, by) = fill_region(border);
        let [dx0, dy0, dx1, dy1] = self.domain.map(|v| v as i32);
        let (x0, y0) = (bx.max(dx0), by.max(dy0));
        let x1 = (bx + filled.width() as i32).min(dx1);
        let y1 = (by + filled.height() as i32).min(dy1);
        if x1 <= x0 || y1 <= y0 {
            return None;
        }
        let (cw, ch) = ((x1 - x0) as u32, (y1 - y0) as u32);
        let mut mask = vec![false; (cw * ch) as usize];
        for y in y0..y1 {
            for x in x0..x1 {
                mask[((y - y0) as u32 * cw + (x - x0) as u32) as usize] =
                    filled.get_pixel((x - bx) as u32, (y - by) as u32)[0] != 0;
            }
        }
        if let Some([px, py]) = self.point {
            let (lx, ly) = (px as i32 - x0, py as i32 - y0);
            if lx < 0
                || ly < 0
                || lx >= cw as i32
                || ly >= ch as i32
                || !mask[(ly as u32 * cw + lx as u32) as usize]
            {
                rejected.point += 1;
                return None;
            }
        }
        let source = Source::Edges {
            dilation_radius: radius,
        };
        self.provisional([x0 as u32, y0 as u32], cw, ch, mask, source, rejected)
    }

    /// A region with its holes filled, checked and scored as it is: cheap,
    /// for ranking the many regions before the few best are pruned.
    fn provisional(
        &self,
        origin: [u32; 2],
        width: u32,
        height: u32,
        mask: Vec<bool>,
        source: Source,
        rejected: &mut Rejections,
    ) -> Option<Candidate> {
        let candidate = Candidate {
            origin,
            width,
            height,
            mask: fill_holes(&mask, width, height),
            source,
            score: Score {
                score: f64::NEG_INFINITY,
                contrast: 0.0,
                data: 0.0,
                outline_px: 0.0,
                area_px: 0.0,
            },
            cut_at_box: [false; 4],
        };
        self.checked(candidate, rejected)
    }

    /// The region with thin appendages cut off (an opening scaled to its
    /// thickness, see [`WorkArea::prune`]), the part that covers the point
    /// (or the largest) kept, checked and scored again.
    pub fn finish(&self, c: &Candidate, rejected: &mut Rejections) -> Option<Candidate> {
        let clipped = self.clipped_to_box(c);
        let c = clipped.as_ref().unwrap_or(c);
        let (width, height) = (c.width, c.height);
        let count = c.area();
        let perimeter = boundary_edges(&c.mask, width, height) as f64 * std::f64::consts::FRAC_PI_4;
        let thickness = 2.0 * count as f64 / perimeter.max(1.0);
        let radius = (0.15 * thickness).round().clamp(1.0, 6.0) as u8;
        let pruned = self.prune(c.origin, width, height, &c.mask, radius);
        let local_point = self
            .point
            .map(|[px, py]| [px as i64 - c.origin[0] as i64, py as i64 - c.origin[1] as i64]);
        let part = keep_one_component(&pruned, width, height, local_point)?;
        self.checked(
            Candidate {
                mask: part,
                ..c.clone()
            },
            rejected,
        )
    }

    /// A candidate that runs to the outer edge of the roi's slack on a
    /// side inside the image goes on past the box there: the box frames
    /// only what lies inside it, so that side is cut at the box instead
    /// (None when no side is cut).
    fn clipped_to_box(&self, c: &Candidate) -> Option<Candidate> {
        let (d, b) = (self.domain, self.roi_box);
        let [x0, y0] = c.origin;
        let (ww, wh) = (self.width(), self.height());
        // Per side (left, top, right, bottom): whether the slack's edge
        // lies on the image border, and whether the candidate reaches it.
        let on_image = [
            d[0] == 0 && self.image_sides[0],
            d[1] == 0 && self.image_sides[1],
            d[2] == ww && self.image_sides[2],
            d[3] == wh && self.image_sides[3],
        ];
        let reaches = c.reaches(d);
        let cut = [0, 1, 2, 3].map(|k| reaches[k] && !on_image[k] && b[k] != d[k]);
        if !cut.contains(&true) {
            return None;
        }
        let keep = |x: u32, y: u32| {
            !(cut[0] && x < b[0] || cut[1] && y < b[1] || cut[2] && x >= b[2] || cut[3] && y >= b[3])
        };
        let mask = (0..c.height)
            .flat_map(|j| (0..c.width).map(move |i| (i, j)))
            .map(|(i, j)| c.mask[(j * c.width + i) as usize] && keep(x0 + i, y0 + j))
            .collect();
        Some(Candidate {
            mask,
            cut_at_box: [0, 1, 2, 3].map(|k| cut[k] || c.cut_at_box[k]),
            ..c.clone()
        })
    }

    /// The part of `c` under the point that `edges` (the working image's
    /// Canny edges, dilated by `edge_radius` to close their gaps) part
    /// from the rest of it: the 4-connected component of its pixels off
    /// the edges that holds the point, given back the pixels beside it,
    /// finished as any candidate. `None` without a point, when the edges
    /// part off at most [`1 - PART_SHARE`](PART_SHARE) of it, when less
    /// than [`PART_OUTER_SHARE`] of the part's outline lies on the region's
    /// (within the edges' band), or when the part is refused.
    pub fn part_under_point(
        &self,
        c: &Candidate,
        (edges, edge_radius): (&GrayImage, u8),
        rejected: &mut Rejections,
    ) -> Option<Candidate> {
        let [px, py] = self.point?;
        let [x0, y0] = c.origin;
        let (w, h) = (c.width, c.height);
        let pixels = || (0..h).flat_map(move |j| (0..w).map(move |i| (i, j)));
        let off: Vec<bool> = pixels()
            .map(|(i, j)| c.mask[(j * w + i) as usize] && edges.get_pixel(x0 + i, y0 + j)[0] == 0)
            .collect();
        let local = [i64::from(px) - i64::from(x0), i64::from(py) - i64::from(y0)];
        let part = keep_one_component(&off, w, h, Some(local))?;
        let inside = |i: i64, j: i64| i >= 0 && j >= 0 && i < w as i64 && j < h as i64;
        let at = |i: i64, j: i64| inside(i, j) && part[(j * w as i64 + i) as usize];
        let grown: Vec<bool> = pixels()
            .map(|(i, j)| {
                let (i, j) = (i64::from(i), i64::from(j));
                c.mask[(j * w as i64 + i) as usize]
                    && [(0, 0), (-1, 0), (1, 0), (0, -1), (0, 1)]
                        .iter()
                        .any(|(di, dj)| at(i + di, j + dj))
            })
            .collect();
        let mask = fill_holes(&grown, w, h);
        let kept = mask.iter().filter(|&&m| m).count();
        if kept as f64 > PART_SHARE * c.area() as f64 {
            return None;
        }
        // A part the rest surrounds is a core inside its rim (the SEM's
        // edge effect: Canny finds both sides of a bright rim), not an
        // object beside another.
        let reach = i64::from(edge_radius) + 1;
        let at_mask = |m: &[bool], i: i64, j: i64| inside(i, j) && m[(j * w as i64 + i) as usize];
        let (mut boundary, mut outer) = (0usize, 0usize);
        for (i, j) in pixels().map(|(i, j)| (i64::from(i), i64::from(j))) {
            let on_boundary = at_mask(&mask, i, j)
                && [(-1, 0), (1, 0), (0, -1), (0, 1)]
                    .iter()
                    .any(|(a, b)| !at_mask(&mask, i + a, j + b));
            if on_boundary {
                boundary += 1;
                let near_outside =
                    (-reach..=reach).any(|a| (-reach..=reach).any(|b| !at_mask(&c.mask, i + a, j + b)));
                outer += usize::from(near_outside);
            }
        }
        if (outer as f64) < PART_OUTER_SHARE * boundary as f64 {
            return None;
        }
        self.finish(&Candidate { mask, ..c.clone() }, rejected)
    }

    /// The candidate trimmed to its pixels, checked (size, spanning,
    /// polarity) and scored.
    fn checked(&self, candidate: Candidate, rejected: &mut Rejections) -> Option<Candidate> {
        let mut candidate = trim(candidate)?;
        let area = candidate.area() as f64;
        if area < self.min_area || area > self.max_area {
            rejected.size += 1;
            rejected.largest_out_of_range = rejected.largest_out_of_range.max(area);
            return None;
        }
        if self.spans(candidate.bbox()) {
            rejected.spanning += 1;
            return None;
        }
        if self.exclude.iter().any(|&p| candidate.covers(p)) {
            rejected.excluded += 1;
            return None;
        }
        let score = self.score(&candidate)?;
        if !self.polarity.admits(score.contrast) || score.contrast.abs() < 0.005 {
            rejected.polarity += 1;
            return None;
        }
        candidate.score = score;
        Some(candidate)
    }

    /// Cuts thin appendages: an opening by a disk of `radius`, after which
    /// the parts it removed that stay within `3 radius` of what is left come
    /// back (corners and a tool's point are not appendages; a scratch or
    /// fibre running off the object reaches further). Pixels past the image
    /// border count as continuing the mask's border pixels, so an object cut
    /// by the border is not eaten away there.
    fn prune(&self, origin: [u32; 2], width: u32, height: u32, mask: &[bool], radius: u8) -> Vec<bool> {
        let pad = radius as u32 + 1;
        let (pw, ph) = (width + 2 * pad, height + 2 * pad);
        let [left, top, right, bottom] = self.image_sides;
        let at_left = left && origin[0] == 0;
        let at_top = top && origin[1] == 0;
        let at_right = right && origin[0] + width == self.width();
        let at_bottom = bottom && origin[1] + height == self.height();
        let padded = GrayImage::from_fn(pw, ph, |x, y| {
            let (mut lx, mut ly) = (x as i64 - pad as i64, y as i64 - pad as i64);
            if lx < 0 && at_left {
                lx = 0;
            }
            if ly < 0 && at_top {
                ly = 0;
            }
            if lx >= width as i64 && at_right {
                lx = width as i64 - 1;
            }
            if ly >= height as i64 && at_bottom {
                ly = height as i64 - 1;
            }
            let inside = lx >= 0 && ly >= 0 && lx < width as i64 && ly < height as i64;
            Luma([if inside && mask[(ly as u32 * width + lx as u32) as usize] {
                255
            } else {
                0
            }])
        });
        let opened = dilate_disk(&erode_disk(&padded, radius), radius);
        let reach = dilate_disk(&opened, radius.saturating_mul(3));
        let at =
            |img: &GrayImage, i: usize| img.get_pixel(i as u32 % width + pad, i as u32 / width + pad)[0] != 0;
        let mut kept: Vec<bool> = (0..mask.len()).map(|i| at(&opened, i)).collect();
        let removed: Vec<bool> = (0..mask.len()).map(|i| mask[i] && !kept[i]).collect();
        let (wu, hu) = (width as usize, height as usize);
        let mut labels = vec![0u32; wu * hu];
        let parts = components(
            &|i| removed[i],
            wu,
            hu,
            [0, 0, width, height],
            &mut labels,
            &mut Vec::new(),
        );
        let mut near = vec![true; parts.len() + 1];
        for (i, &l) in labels.iter().enumerate() {
            if l != 0 && !at(&reach, i) {
                near[l as usize] = false;
            }
        }
        for (k, &l) in labels.iter().enumerate() {
            if l != 0 && near[l as usize] {
                kept[k] = true;
            }
        }
        kept
    }

    /// A structure rather than an object: a region with bounding box
    /// `[x0, y0, x1, y1)` that touches opposite image borders, every side of
    /// the searched box, or three sides of a box inside the image.
    fn spans(&self, [cx0, cy0, cx1, cy1]: [u32; 4]) -> bool {
        let [x0, y0, x1, y1] = self.domain;
        let touches = [cx0 <= x0, cy0 <= y0, cx1 >= x1, cy1 >= y1];
        let at_image_side = [
            touches[0] && self.image_sides[0] && x0 == 0,
            touches[1] && self.image_sides[1] && y0 == 0,
            touches[2] && self.image_sides[2] && x1 == self.width(),
            touches[3] && self.image_sides[3] && y1 == self.height(),
        ];
        let opposite = (at_image_side[0] && at_image_side[2]) || (at_image_side[1] && at_image_side[3]);
        let inner_sides = touches
            .iter()
            .zip(&at_image_side)
            .filter(|(t, i)| **t && !**i)
            .count();
        opposite || touches.iter().all(|&t| t) || inner_sides >= 3
    }

    /// The region energy's terms and score (see the module docs).
    pub fn score(&self, c: &Candidate) -> Option<Score> {
        let (n_a, s_a) = self.region_sum(c);
        self.score_from(n_a, s_a, c.bbox(), self.outline_edges(c) as f64)
    }

    /// Pixel count and grey-value sum of the candidate's region.
    fn region_sum(&self, c: &Candidate) -> (f64, f64) {
        let w = self.width() as usize;
        let values = self.work.as_raw();
        let (mut n_a, mut s_a) = (0.0f64, 0.0f64);
        for y in 0..c.height {
            let row = &values[(c.origin[1] + y) as usize * w + c.origin[0] as usize..][..c.width as usize];
            let m = &c.mask[(y * c.width) as usize..][..c.width as usize];
            for (&v, &inside) in row.iter().zip(m) {
                if inside {
                    n_a += 1.0;
                    s_a += v as f64;
                }
            }
        }
        (n_a, s_a)
    }

    /// The window a region of `n_a` working pixels within `bbox` is scored
    /// against: the box grown by 0.3 sqrt(A) full-resolution pixels (at
    /// least 8), clipped to the image, `[x0, y0, x1, y1)`.
    fn score_window(&self, n_a: f64, bbox: [u32; 4]) -> [usize; 4] {
        let s = self.scale as f64;
        let (w, h) = (self.width() as i64, self.height() as i64);
        let margin = ((0.3 * (n_a * s * s).sqrt()).max(8.0) / s).ceil() as i64;
        [
            (bbox[0] as i64 - margin).max(0) as usize,
            (bbox[1] as i64 - margin).max(0) as usize,
            (bbox[2] as i64 + margin).min(w) as usize,
            (bbox[3] as i64 + margin).min(h) as usize,
        ]
    }

    /// How much of the region's contrast its outline shows as a step: the
    /// mean grey of a band [`EDGE_BAND`] working pixels wide inside the
    /// outline minus that of the band as wide outside it, over the region's
    /// mean minus the rest of its window's (as in the score), in absolute
    /// value; the largest such share with both bands moved together up to
    /// [`EDGE_REACH`] px inwards or outwards, as the outline need not lie
    /// on the edge. About 0.6-1 on an object's edge, more with an edge rim;
    /// a level line of a smooth gradient (a patch of shaded substrate)
    /// shows 0.1-0.3 wherever the bands lie. `None` without pixels in a
    /// band; pixels past the image border belong to no band.
    pub fn edge_share(&self, c: &Candidate) -> Option<f64> {
        let band = i32::from(EDGE_BAND);
        let [reach_in, reach_out] = EDGE_REACH;
        // Rings one pixel wide by distance from the outline: ring k holds
        // the pixels -k px inside it for k < 0 and k + 1 px outside it for
        // k >= 0, k in -inner..outer (stored at k + inner).
        let (inner, outer) = (reach_in + band, reach_out + band);
        let pad = outer as u32 + 1;
        let (pw, ph) = (c.width + 2 * pad, c.height + 2 * pad);
        let (iw, ih) = (self.width() as i64, self.height() as i64);
        let global = |x: u32, y: u32| {
            (
                c.origin[0] as i64 + x as i64 - pad as i64,
                c.origin[1] as i64 + y as i64 - pad as i64,
            )
        };
        // Past the image border the mask continues its border pixels.
        let padded = GrayImage::from_fn(pw, ph, |x, y| {
            let (gx, gy) = global(x, y);
            let (cx, cy) = (gx.clamp(0, iw - 1), gy.clamp(0, ih - 1));
            let (lx, ly) = (cx - c.origin[0] as i64, cy - c.origin[1] as i64);
            let inside = lx >= 0 && ly >= 0 && lx < c.width as i64 && ly < c.height as i64;
            Luma([if inside && c.mask[(ly as u32 * c.width + lx as u32) as usize] {
                255
            } else {
                0
            }])
        });
        let shrunk: Vec<GrayImage> = (1..=inner as u8).map(|r| erode_disk(&padded, r)).collect();
        let grown: Vec<GrayImage> = (1..=outer as u8).map(|r| dilate_disk(&padded, r)).collect();
        let values = self.work.as_raw();
        let mut rings = vec![[0.0f64; 2]; (inner + outer) as usize];
        for y in 0..ph {
            for x in 0..pw {
                let (gx, gy) = global(x, y);
                if gx < 0 || gy < 0 || gx >= iw || gy >= ih {
                    continue;
                }
                let on = |image: &GrayImage| image.get_pixel(x, y)[0] != 0;
                let ring = if on(&padded) {
                    shrunk.iter().position(|s| !on(s)).map(|r| inner - 1 - r as i32)
                } else {
                    grown.iter().position(on).map(|r| inner + r as i32)
                };
                if let Some(k) = ring {
                    let v = values[(gy * iw + gx) as usize] as f64;
                    rings[k as usize][0] += 1.0;
                    rings[k as usize][1] += v;
                }
            }
        }
        // The mean grey of the rings k0..k0 + band (k0 relative to the
        // outline, as above).
        let band_mean = |k0: i32| {
            let [n, s] = (k0..k0 + band)
                .map(|k| rings[(k + inner) as usize])
                .fold([0.0, 0.0], |a, r| [a[0] + r[0], a[1] + r[1]]);
            (n > 0.0).then(|| s / n)
        };
        // The region against its window, as in the score.
        let (n_a, s_a) = self.region_sum(c);
        let (n_w, s_w) = self.table.sum(self.score_window(n_a, c.bbox()));
        let rest = (s_w - s_a) / (n_w - n_a).max(1.0);
        let contrast = s_a / n_a - rest;
        if contrast == 0.0 {
            return None;
        }
        (-reach_in..=reach_out)
            .filter_map(|shift| Some(band_mean(shift - band)? - band_mean(shift)?))
            .map(|step| (step / contrast).abs())
            .max_by(f64::total_cmp)
    }

    /// The score of a region of `n_a` working pixels with grey-value sum
    /// `s_a` (0..=1 scale), bounding box `bbox` and `edges` pixel edges of
    /// outline; `None` when it is empty or has too little background
    /// around it to say what it stands out from.
    fn score_from(&self, n_a: f64, s_a: f64, bbox: [u32; 4], edges: f64) -> Option<Score> {
        if n_a == 0.0 {
            return None;
        }
        let s = self.scale as f64;
        let (n_w, s_w) = self.table.sum(self.score_window(n_a, bbox));
        let o = self.offset;
        let (s_a, s_w) = (s_a + o * n_a, s_w + o * n_w);
        let (n_b, s_b) = (n_w - n_a, s_w - s_a);
        if n_b < 0.1 * n_a || s_b <= 0.0 {
            return None;
        }
        let f = crate::energy::f;
        let (m_a, m_b, m_w) = (s_a / n_a, s_b / n_b, s_w / n_w);
        let d = n_a * f(m_a) + n_b * f(m_b) - n_w * f(m_w);
        let data = d / m_w * s * s;
        let outline = edges * std::f64::consts::FRAC_PI_4 * s;
        let area = n_a * s * s;
        let score = if outline > 0.0 {
            (data - outline * outline / area) / outline
        } else {
            f64::NEG_INFINITY
        };
        Some(Score {
            score,
            contrast: crate::energy::michelson(m_a, m_b),
            data,
            outline_px: outline,
            area_px: area,
        })
    }

    /// Pixel edges between the region and the rest of the image, leaving
    /// out those on the image border.
    fn outline_edges(&self, c: &Candidate) -> usize {
        let (cw, ch) = (c.width as i64, c.height as i64);
        let at = |x: i64, y: i64| x >= 0 && y >= 0 && x < cw && y < ch && c.mask[(y * cw + x) as usize];
        let (iw, ih) = (self.width() as i64, self.height() as i64);
        let [ox, oy] = [c.origin[0] as i64, c.origin[1] as i64];
        // A neighbour past the image border on a side that is the image's
        // own border is not background.
        let beyond_image = |x: i64, y: i64| {
            let (gx, gy) = (ox + x, oy + y);
            (gx < 0 && self.image_sides[0])
                || (gy < 0 && self.image_sides[1])
                || (gx >= iw && self.image_sides[2])
                || (gy >= ih && self.image_sides[3])
        };
        let mut edges = 0;
        for y in 0..ch {
            for x in 0..cw {
                if !c.mask[(y * cw + x) as usize] {
                    continue;
                }
                for (dx, dy) in [(-1, 0), (1, 0), (0, -1), (0, 1)] {
                    let (nx, ny) = (x + dx, y + dy);
                    if !at(nx, ny) && !beyond_image(nx, ny) {
                        edges += 1;
                    }
                }
            }
        }
        edges
    }

    /// Which image borders (left, top, right, bottom) the region touches.
    pub fn border_sides(&self, c: &Candidate) -> [bool; 4] {
        let reached = c.reaches([0, 0, self.width(), self.height()]);
        [0, 1, 2, 3].map(|k| self.image_sides[k] && reached[k])
    }
}

/// The grey levels of the threshold components, and the domain's pixels by
/// bucket: how many levels lie below their (blurred) value.
struct Levels {
    lo: f32,
    hi: f32,
    /// Domain pixel indices by bucket.
    by_bucket: Vec<Vec<u32>>,
}

impl Levels {
    fn new(area: &WorkArea, lo: f32, hi: f32) -> Self {
        let w = area.width() as usize;
        let [dx0, dy0, dx1, dy1] = area.domain.map(|v| v as usize);
        let mut by_bucket: Vec<Vec<u32>> = vec![Vec::new(); LEVELS + 1];
        let values = area.blurred.as_raw();
        for y in dy0..dy1 {
            for x in dx0..dx1 {
                let i = y * w + x;
                let b = ((values[i] - lo) / (hi - lo) * LEVELS as f32 + 0.5)
                    .floor()
                    .clamp(0.0, LEVELS as f32) as u8;
                by_bucket[b as usize].push(i as u32);
            }
        }
        Self { lo, hi, by_bucket }
    }

    /// Grey level `k` (0..LEVELS) on the 0..=1 scale.
    fn value(&self, k: usize) -> f32 {
        self.lo + (self.hi - self.lo) * (k as f32 + 0.5) / LEVELS as f32
    }

    /// Grows the level sets of one polarity, brightest (darkest) pixels
    /// first, and calls `at_level(k, forest)` once the set holds every
    /// pixel above (below) level k.
    fn grow<'a>(
        &self,
        area: &WorkArea<'a>,
        polarity: Polarity,
        min_count: u32,
        mut at_level: impl FnMut(usize, &mut Forest<'a>),
    ) {
        let bright = polarity == Polarity::Brighter;
        let mut forest = Forest::new(area);
        // Brighter: after adding bucket b the set is {bucket >= b}, the
        // pixels above level b - 1. Darker: {bucket <= b}, below level b.
        let order: Vec<u8> = if bright {
            (1..=LEVELS as u8).rev().collect()
        } else {
            (0..LEVELS as u8).collect()
        };
        for now in order {
            for &i in &self.by_bucket[now as usize] {
                forest.add(i as usize, min_count);
            }
            let k = if bright { now as usize - 1 } else { now as usize };
            at_level(k, &mut forest);
        }
    }
}

/// The regions worth a closer look: by score, the best two of each of the
/// best four distinct regions (regions whose bounding boxes overlap by more
/// than half are one region at different levels).
pub(super) fn finalists<T>(mut items: Vec<T>, key: impl Fn(&T) -> ([u32; 4], f64)) -> Vec<T> {
    const REGIONS: usize = 4;
    const PER_REGION: usize = 2;
    items.sort_by(|a, b| key(b).1.total_cmp(&key(a).1));
    let overlap = |a: [u32; 4], b: [u32; 4]| {
        let iw = a[2].min(b[2]).saturating_sub(a[0].max(b[0])) as f64;
        let ih = a[3].min(b[3]).saturating_sub(a[1].max(b[1])) as f64;
        let area = |r: [u32; 4]| (r[2] - r[0]) as f64 * (r[3] - r[1]) as f64;
        let inter = iw * ih;
        inter / (area(a) + area(b) - inter)
    };
    let mut leaders: Vec<([u32; 4], usize)> = Vec::new();
    let mut out = Vec::new();
    for item in items {
        let b = key(&item).0;
        match leaders.iter().position(|(l, _)| overlap(*l, b) > 0.5) {
            Some(k) if leaders[k].1 < PER_REGION => {
                leaders[k].1 += 1;
                out.push(item);
            }
            Some(_) => {}
            None if leaders.len() < REGIONS => {
                leaders.push((b, 1));
                out.push(item);
            }
            None => {}
        }
    }
    out
}

/// Union-find over the pixels of a growing level set (4-connected), with
/// each root's pixel count, grey-value sum, outline edges and bounding box:
/// every level's components in one pass over the pixels in order of value.
struct Forest<'a> {
    width: usize,
    height: usize,
    values: &'a [f32],
    /// Which sides of the working image (left, top, right, bottom) lie on
    /// the image border: edges there are not outline.
    image_sides: [bool; 4],
    parent: Vec<u32>,
    /// Per root.
    stats: Vec<ComponentStats>,
    /// Roots that reached the smallest count of interest (some may have
    /// been merged since).
    large: Vec<u32>,
}

/// What a root knows of its component.
#[derive(Clone, Copy, Debug, Default)]
struct ComponentStats {
    count: u32,
    /// Sum of the unblurred working values (f32 keeps the table small; its
    /// 1e-7 relative error is far below what a score can resolve).
    sum: f32,
    /// Pixel edges to pixels outside the component, not counting edges on
    /// the image border.
    edges: u32,
    /// `[x0, y0, x1, y1)` (working images are at most 8192 px a side).
    bbox: [u16; 4],
}

impl<'a> Forest<'a> {
    const NONE: u32 = u32::MAX;

    fn new(area: &WorkArea<'a>) -> Self {
        let (width, height) = (area.width() as usize, area.height() as usize);
        Self {
            width,
            height,
            values: area.work.as_raw(),
            image_sides: area.image_sides,
            parent: vec![Self::NONE; width * height],
            stats: vec![ComponentStats::default(); width * height],
            large: Vec::new(),
        }
    }

    fn find(&mut self, i: usize) -> u32 {
        let mut root = i as u32;
        while self.parent[root as usize] != root {
            root = self.parent[root as usize];
        }
        let mut j = i as u32;
        while self.parent[j as usize] != root {
            let next = self.parent[j as usize];
            self.parent[j as usize] = root;
            j = next;
        }
        root
    }

    /// True when pixel `i` is in the set (the set only grows).
    fn contains(&self, i: usize) -> bool {
        self.parent[i] != Self::NONE
    }

    /// Adds pixel `i` and merges it with its neighbours already in the set;
    /// roots reaching `min_count` pixels are remembered.
    fn add(&mut self, i: usize, min_count: u32) {
        let (x, y) = (i % self.width, i / self.width);
        let at_side = [x == 0, y == 0, x + 1 == self.width, y + 1 == self.height];
        let border_edges = at_side
            .iter()
            .zip(&self.image_sides)
            .filter(|(a, b)| **a && **b)
            .count() as u32;
        self.parent[i] = i as u32;
        let neighbours = [
            (x > 0).then(|| i - 1),
            (x + 1 < self.width).then(|| i + 1),
            (y > 0).then(|| i - self.width),
            (y + 1 < self.height).then(|| i + self.width),
        ];
        let mut joined = 0u32;
        let mut stats = ComponentStats {
            count: 1,
            sum: self.values[i],
            edges: 0,
            bbox: [x as u16, y as u16, x as u16 + 1, y as u16 + 1],
        };
        let mut root = i as u32;
        for j in neighbours.into_iter().flatten() {
            if self.parent[j] == Self::NONE {
                continue;
            }
            joined += 1;
            let other = self.find(j);
            if other == root {
                continue;
            }
            let o = self.stats[other as usize];
            stats.count += o.count;
            stats.sum += o.sum;
            stats.edges += o.edges;
            stats.bbox = [
                stats.bbox[0].min(o.bbox[0]),
                stats.bbox[1].min(o.bbox[1]),
                stats.bbox[2].max(o.bbox[2]),
                stats.bbox[3].max(o.bbox[3]),
            ];
            // Union by size: the larger root stays.
            let (big, small) = if o.count >= self.stats[root as usize].count.max(1) {
                (other, root)
            } else {
                (root, other)
            };
            self.parent[small as usize] = big;
            root = big;
        }
        // Each joined neighbour turns one of its edges and one of the new
        // pixel's into inner edges.
        stats.edges = stats.edges + 4 - border_edges - 2 * joined;
        let was = self.stats[root as usize].count;
        let before = if root == i as u32 { 0 } else { was };
        self.stats[root as usize] = stats;
        if before < min_count && stats.count >= min_count {
            self.large.push(root);
        }
    }

    /// The current roots among the remembered large ones.
    fn large_roots(&mut self) -> Vec<u32> {
        let mut roots: Vec<u32> = self
            .large
            .iter()
            .copied()
            .filter(|&r| self.parent[r as usize] == r)
            .collect();
        roots.sort_unstable();
        roots.dedup();
        self.large.clone_from(&roots);
        roots
    }

    /// A root's component.
    fn stats(&self, root: u32) -> ComponentStats {
        self.stats[root as usize]
    }
}

/// A 4-connected component of a threshold mask.
struct Component {
    label: u32,
    count: usize,
}

/// The 4-connected components of the pixels where `inside` holds, within
/// `domain`; `labels` (reused, `w * h`) gets each pixel's component label
/// (0: none).
fn components(
    inside: &dyn Fn(usize) -> bool,
    w: usize,
    h: usize,
    domain: [u32; 4],
    labels: &mut [u32],
    stack: &mut Vec<usize>,
) -> Vec<Component> {
    let [x0, y0, x1, y1] = domain.map(|v| v as usize);
    debug_assert!(x1 <= w && y1 <= h);
    labels.fill(0);
    let mut out = Vec::new();
    let mut next = 0u32;
    for y in y0..y1 {
        for x in x0..x1 {
            let start = y * w + x;
            if labels[start] != 0 || !inside(start) {
                continue;
            }
            next += 1;
            labels[start] = next;
            stack.push(start);
            let mut count = 0usize;
            while let Some(i) = stack.pop() {
                count += 1;
                let (px, py) = (i % w, i / w);
                let mut visit = |j: usize| {
                    if labels[j] == 0 && inside(j) {
                        labels[j] = next;
                        stack.push(j);
                    }
                };
                if px > x0 {
                    visit(i - 1);
                }
                if px + 1 < x1 {
                    visit(i + 1);
                }
                if py > y0 {
                    visit(i - w);
                }
                if py + 1 < y1 {
                    visit(i + w);
                }
            }
            out.push(Component { label: next, count });
        }
    }
    out
}

/// The mask with its holes filled: every pixel that the outside of the
/// mask's box cannot reach (4-connected) through background.
pub(super) fn fill_holes(mask: &[bool], w: u32, h: u32) -> Vec<bool> {
    let (w, h) = (w as usize, h as usize);
    let mut outside = vec![false; w * h];
    let mut stack: Vec<usize> = Vec::new();
    let seed = |i: usize, outside: &mut Vec<bool>, stack: &mut Vec<usize>| {
        if !mask[i] && !outside[i] {
            outside[i] = true;
            stack.push(i);
        }
    };
    for x in 0..w {
        seed(x, &mut outside, &mut stack);
        seed((h - 1) * w + x, &mut outside, &mut stack);
    }
    for y in 0..h {
        seed(y * w, &mut outside, &mut stack);
        seed(y * w + w - 1, &mut outside, &mut stack);
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
            seed(j, &mut outside, &mut stack);
        }
    }
    outside.iter().map(|&o| !o).collect()
}

/// Pixel edges between mask and non-mask pixels (the box's outside counts
/// as non-mask).
fn boundary_edges(mask: &[bool], w: u32, h: u32) -> usize {
    let (w, h) = (w as usize, h as usize);
    let at = |x: usize, y: usize| mask[y * w + x];
    let mut edges = 0;
    for y in 0..h {
        for x in 0..w {
            if !at(x, y) {
                continue;
            }
            edges += usize::from(x == 0 || !at(x - 1, y))
                + usize::from(x + 1 == w || !at(x + 1, y))
                + usize::from(y == 0 || !at(x, y - 1))
                + usize::from(y + 1 == h || !at(x, y + 1));
        }
    }
    edges
}

/// The 4-connected part of `mask` that covers `point` (local pixel), or
/// without a point the largest; `None` when nothing is left or the point is
/// not covered.
fn keep_one_component(mask: &[bool], w: u32, h: u32, point: Option<[i64; 2]>) -> Option<Vec<bool>> {
    let (wu, hu) = (w as usize, h as usize);
    let mut labels = vec![0u32; wu * hu];
    let mut stack = Vec::new();
    let parts = components(&|i| mask[i], wu, hu, [0, 0, w, h], &mut labels, &mut stack);
    let label = match point {
        Some([x, y]) => {
            if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 {
                return None;
            }
            let l = labels[y as usize * wu + x as usize];
            (l != 0).then_some(l)?
        }
        None => parts.iter().max_by_key(|c| c.count)?.label,
    };
    Some(labels.iter().map(|&l| l == label).collect())
}

/// The candidate with its mask cropped to the bounding box of its pixels;
/// `None` when empty.
fn trim(c: Candidate) -> Option<Candidate> {
    let (w, h) = (c.width, c.height);
    let (mut x0, mut y0, mut x1, mut y1) = (w, h, 0, 0);
    for y in 0..h {
        for x in 0..w {
            if c.mask[(y * w + x) as usize] {
                x0 = x0.min(x);
                y0 = y0.min(y);
                x1 = x1.max(x + 1);
                y1 = y1.max(y + 1);
            }
        }
    }
    if x1 <= x0 {
        return None;
    }
    let (nw, nh) = (x1 - x0, y1 - y0);
    let mask = (y0..y1)
        .flat_map(|y| (x0..x1).map(move |x| (x, y)))
        .map(|(x, y)| c.mask[(y * w + x) as usize])
        .collect();
    Some(Candidate {
        origin: [c.origin[0] + x0, c.origin[1] + y0],
        width: nw,
        height: nh,
        mask,
        ..c
    })
}

/// The outer border of a candidate's mask, traced (working coordinates).
pub(super) fn traced_border(c: &Candidate) -> Option<Vec<[i32; 2]>> {
    let region = outer_regions(&c.image()).into_iter().next()?;
    Some(
        region
            .border
            .iter()
            .map(|p| [p[0] + c.origin[0] as i32, p[1] + c.origin[1] as i32])
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A work area over `work` at scale 1, every side on the image border,
    /// with the domain and roi box `[domain, roi_box]` and no other hint.
    fn work_area(work: &FloatImage, [domain, roi_box]: [[u32; 4]; 2]) -> WorkArea<'_> {
        WorkArea {
            work,
            blurred: work,
            scale: 1,
            image_sides: [true; 4],
            domain,
            roi_box,
            point: None,
            exclude: Vec::new(),
            polarity: Polarity::Any,
            min_area: 0.0,
            max_area: f64::INFINITY,
            offset: 1.0 / 255.0,
            table: SummedArea::new(work),
        }
    }

    /// An unscored candidate with `mask` (`width` x `height`) at `origin`.
    fn candidate(origin: [u32; 2], width: u32, height: u32, mask: Vec<bool>) -> Candidate {
        Candidate {
            origin,
            width,
            height,
            mask,
            source: Source::Edges { dilation_radius: 1 },
            score: Score {
                score: 0.0,
                contrast: 0.0,
                data: 0.0,
                outline_px: 0.0,
                area_px: 0.0,
            },
            cut_at_box: [false; 4],
        }
    }

    /// The share of its contrast a disc of radius 20 at (60, 60) shows as
    /// a step at its outline, on the 120 x 120 image `grey(r)`.
    fn disc_edge_share(grey: impl Fn(f64) -> f32) -> f64 {
        let n = 120u32;
        let work = FloatImage::from_fn(n, n, |x, y| {
            Luma([grey((x as f64 - 60.0).hypot(y as f64 - 60.0))])
        });
        let area = work_area(&work, [[0, 0, n, n]; 2]);
        let mask: Vec<bool> = (0..41 * 41)
            .map(|i| ((i % 41) as f64 - 20.0).hypot((i / 41) as f64 - 20.0) < 20.0)
            .collect();
        area.edge_share(&candidate([40, 40], 41, 41, mask)).unwrap()
    }

    #[test]
    fn a_region_that_runs_on_past_a_box_is_cut_at_the_box() {
        // A 100 x 60 working image; the box [20, 10, 70, 50) with 5 px of
        // slack, the slack's left side on the image border.
        let (w, h) = (100u32, 60u32);
        let work = FloatImage::new(w, h);
        let area = work_area(&work, [[0, 5, 75, 55], [20, 10, 70, 50]]);
        let band = |[x0, y0, x1, y1]: [u32; 4]| {
            candidate(
                [x0, y0],
                x1 - x0,
                y1 - y0,
                vec![true; ((x1 - x0) * (y1 - y0)) as usize],
            )
        };
        // A band from the image's left border to the slack's right edge:
        // cut at the box's right side, not at its left (the image border).
        let cut = area.clipped_to_box(&band([0, 20, 75, 30])).expect("cut");
        let kept = |x: u32| cut.covers([x, 25]);
        assert!(kept(0) && kept(69) && !kept(70) && !kept(74));
        // Within the slack on every side: as it was.
        assert!(area.clipped_to_box(&band([18, 8, 72, 52])).is_none());
        // Up to the slack's top edge: cut at the box's top.
        let top = area.clipped_to_box(&band([30, 5, 40, 30])).expect("cut");
        assert!(!top.covers([35, 9]) && top.covers([35, 10]));
    }

    #[test]
    fn an_object_shows_its_contrast_at_its_outline_and_a_shaded_patch_does_not() {
        // A disc of 0.6 on 0.4: the bands on either side of its outline
        // differ by its whole contrast.
        let object = disc_edge_share(|r| if r < 20.0 { 0.6 } else { 0.4 });
        assert!(object > 0.8, "object: {object:.2}");
        // The level line r = 20 of a smooth cone (substrate shaded from
        // 0.7 at its top to 0.3 at 60 px): 0.15-0.25 of the contrast.
        let patch = disc_edge_share(|r| (0.7 - 0.4 * r / 60.0).max(0.3) as f32);
        assert!(patch < super::super::prompted::NO_EDGE_SHARE, "patch: {patch:.2}");
    }

    #[test]
    fn an_outline_a_few_pixels_off_the_edge_still_shows_it() {
        // The disc of radius 20 around an object of radius 17.5 (the
        // outline 2.5 px outside its edge, as a threshold of the smoothed
        // image puts it) and of radius 22 (2 px inside): both see the step.
        for edge in [17.5, 22.0] {
            let share = disc_edge_share(|r| if r < edge { 0.6 } else { 0.4 });
            assert!(share > 0.8, "edge at r = {edge}: {share:.2}");
        }
        // Nothing nearer than 5 px: the bands find no step.
        let far = disc_edge_share(|r| if r < 14.0 { 0.6 } else { 0.4 });
        assert!(
            far < super::super::prompted::NO_EDGE_SHARE,
            "edge at r = 14: {far:.2}"
        );
    }

    #[test]
    fn holes_are_filled_and_the_outside_kept() {
        // A ring 7x7 with a hole at its centre, in a 9x9 box.
        let mut mask = vec![false; 81];
        for y in 1..8 {
            for x in 1..8 {
                mask[y * 9 + x] = !(x == 4 && y == 4);
            }
        }
        let filled = fill_holes(&mask, 9, 9);
        assert!(filled[4 * 9 + 4], "hole filled");
        assert!(!filled[0], "outside kept");
        assert_eq!(filled.iter().filter(|&&m| m).count(), 49);
    }

    #[test]
    fn components_are_four_connected_and_bounded_by_the_domain() {
        // Two pixels touching only diagonally, and a bar cut by the domain.
        let (w, h) = (8usize, 6usize);
        let mut on = vec![false; w * h];
        on[w + 1] = true;
        on[2 * w + 2] = true;
        for x in 4..8 {
            on[4 * w + x] = true;
        }
        let mut labels = vec![0; w * h];
        let parts = components(&|i| on[i], w, h, [0, 0, 6, 6], &mut labels, &mut Vec::new());
        let mut counts: Vec<usize> = parts.iter().map(|c| c.count).collect();
        counts.sort();
        assert_eq!(
            counts,
            vec![1, 1, 2],
            "diagonal neighbours apart; bar clipped at x = 6"
        );
        let bar = parts.iter().find(|c| c.count == 2).unwrap();
        assert_eq!(labels[4 * w + 4], bar.label);
        assert_eq!(labels[4 * w + 6], 0, "outside the domain");
    }
}

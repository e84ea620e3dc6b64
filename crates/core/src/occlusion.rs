//! Partial occlusion: which parts of a rigid contour are hidden, and an
//! energy that ignores them.
//!
//! The rigid contour is split into sectors (runs of consecutive vertices).
//! For each sector, a thin band just inside the contour and one just outside
//! it give a local contrast. On the first pair these contrasts are the
//! object's reference appearance. On a later pair, something covering part of
//! the object (a gripper, a second particle, debris) changes the contrast of
//! the sectors it covers far more than noise, drift or charging do (global
//! gain changes are normalised out by the median ratio). Those sectors are
//! dropped, and the pose is fitted with a band energy over the remaining
//! sectors: the same two-region likelihood ratio as [`crate::energy`], with
//! region a the union of the inner bands and b the union of the outer bands.
//! A changed sector whose inner band keeps the object's grey is not hidden:
//! the object is in front of a new backdrop (a tool passing over a
//! particle). It is left out of the fit like a hidden one, but it counts
//! neither towards the hidden share that loses the object nor towards the
//! typical contrast ([`judge_look`]).
//! The rigid shape then keeps the centroid right from the visible part of the
//! outline (the paper's claim, method note section 2, "Robustness").
//! A look compared with the first pair's across a change of the microscope's
//! brightness and contrast is first mapped back through that change, an
//! affine map of grey levels read off the two frames' deciles
//! ([`GreyMap`]): the contrasts' ratios hold under a gain, not an offset.

use crate::energy::{data_term, michelson, INTENSITY_OFFSET};
use crate::fit::{place, Pose, RigidTemplate};
use crate::geometry::{HalfPlane, Point, Polygon};
use crate::imageio::GrayFrame;
use crate::region::{PrefixSums, RegionSum};
use crate::uncertainty::median_and_spread;

/// Parameters of the occlusion handling.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
pub struct OcclusionParams {
    /// Look for occlusion at all. Default true.
    pub enabled: bool,
    /// Number of sectors along the contour. Default 24; range 8..=256.
    pub sectors: usize,
    /// A sector counts as occluded when its contrast, relative to its
    /// reference and to the median over all sectors, falls below this
    /// fraction of it. Default 0.35: something in front of the outline
    /// wipes out or inverts its contrast, while a change of viewpoint or
    /// shading only weakens it (the real quartz tilt series weakens sectors
    /// to 0.4..0.7 of their contrast).
    pub min_contrast_ratio: f64,
    /// ... or rises above this multiple of it (an occluder covering only
    /// the outer band). Default 2.
    pub max_contrast_ratio: f64,
    /// Beyond this fraction of occluded sectors the pair is lost: too little
    /// of the outline is visible to place the contour. Default 0.6.
    pub max_occluded_fraction: f64,
}

impl Default for OcclusionParams {
    fn default() -> Self {
        Self {
            enabled: true,
            sectors: 24,
            min_contrast_ratio: 0.35,
            max_contrast_ratio: 2.0,
            max_occluded_fraction: 0.6,
        }
    }
}

impl OcclusionParams {
    /// Checks ranges; the message says what was expected.
    pub fn validate(&self) -> Result<(), String> {
        if !(8..=256).contains(&self.sectors) {
            return Err(format!("invalid sectors {} (expected 8..=256)", self.sectors));
        }
        if !(self.min_contrast_ratio.is_finite()
            && self.max_contrast_ratio.is_finite()
            && 0.0 <= self.min_contrast_ratio
            && self.min_contrast_ratio < 1.0
            && 1.0 < self.max_contrast_ratio
            && self.max_contrast_ratio <= 100.0)
        {
            return Err(format!(
                "invalid min_contrast_ratio {} / max_contrast_ratio {} (expected 0 <= min < 1 < max <= 100)",
                self.min_contrast_ratio, self.max_contrast_ratio
            ));
        }
        if !(self.max_occluded_fraction.is_finite() && (0.0..=0.9).contains(&self.max_occluded_fraction)) {
            return Err(format!(
                "invalid max_occluded_fraction {} (expected 0..=0.9)",
                self.max_occluded_fraction
            ));
        }
        Ok(())
    }
}

/// The sector layout of a rigid template, with its inner and outer band
/// outlines (in template coordinates, like the template's vertices).
#[derive(Clone, Debug)]
pub struct SectorTemplate {
    /// The template's outline resampled to vertices at most
    /// [`SectorTemplate::MAX_SPACING_PX`] apart (template coordinates).
    contour: Vec<Point>,
    /// First vertex of each sector; sector k runs from `starts[k]` to
    /// `starts[k + 1]` inclusive (wrapping), so neighbours share a vertex.
    starts: Vec<usize>,
    /// Vertices moved inwards by the inner band width.
    inner: Vec<Point>,
    /// Vertices moved outwards by the outer band width.
    outer: Vec<Point>,
    /// The template's cuts ([`RigidTemplate::cuts`]).
    cuts: Vec<HalfPlane>,
    /// The template's limits ([`RigidTemplate::limits`]).
    limits: Vec<HalfPlane>,
}

impl SectorTemplate {
    /// These sectors limited like [`RigidTemplate::limited_to`].
    pub fn limited_to(&self, limits: Vec<HalfPlane>) -> Self {
        Self {
            limits,
            ..self.clone()
        }
    }

    /// Largest vertex spacing of the sector outline, pixels. The template
    /// itself is coarser (the free fit's vertices, 6 px apart by default),
    /// and sector boundaries fall on vertices; this keeps the sector layout
    /// the 2-px template had. Measured on the occluded suite, both layouts
    /// fail on the same few rods (an occluder along the rod's length), where
    /// tracking is chaotic: with 6-px sectors seeds 100-104 lost a pair,
    /// with these they give 0.120 px (0.087 with the old 2-px template);
    /// over seeds 100-119 (20 pairs) 0.30 and 0.49 px against 0.21 before,
    /// nearly all of it two rods; over 200-219 0.173 and 0.165 against 0.167.
    pub const MAX_SPACING_PX: f64 = 2.0;

    /// Sectors of about equal vertex count. The inner band is at most a
    /// third of the object's mean thickness (2A/L) wide, so it stays inside
    /// thin objects; the outer band is as wide as the template's margin, up
    /// to 12 px.
    pub fn new(template: &RigidTemplate, sectors: usize) -> Self {
        let outline = Polygon::new(template.points.clone());
        let dense = ((outline.length() / Self::MAX_SPACING_PX).round() as usize).max(outline.len());
        let polygon = outline.resampled(dense);
        let n = polygon.len();
        let sectors = sectors.clamp(1, n.max(1));
        let starts = (0..sectors).map(|k| k * n / sectors).collect();
        let thickness = 2.0 * polygon.area() / polygon.length().max(1e-9);
        let inner_width = (thickness / 3.0).clamp(1.5, 8.0);
        let outer_width = Self::outer_band_width(template);
        Self {
            starts,
            inner: polygon.offset_along_normals(-inner_width).points,
            outer: polygon.offset_along_normals(outer_width).points,
            contour: polygon.points,
            cuts: template.cuts.clone(),
            limits: template.limits.clone(),
        }
    }

    /// Width of the outer bands for `template`, pixels: its window margin
    /// within 3..=12.
    pub fn outer_band_width(template: &RigidTemplate) -> f64 {
        template.margin.clamp(3.0, 12.0)
    }

    /// Number of sectors.
    pub fn len(&self) -> usize {
        self.starts.len()
    }

    /// True when there are no sectors.
    pub fn is_empty(&self) -> bool {
        self.starts.is_empty()
    }

    /// Inner- and outer-band sums of every sector at `pose`. Each band is
    /// the sector's arc of the contour, closed by the matching arc of the
    /// inner (outer) outline; the contour arc is walked once for both.
    /// `None` for a sector that is not seen: for a template cut by the
    /// image border, one whose bands reach within a pixel of the image
    /// border or of a cut (the outline along a cut is no edge of the
    /// object, and it is left out like an occluded sector), or past the
    /// covered area.
    pub fn band_sums(&self, sums: &PrefixSums, pose: Pose) -> Vec<Option<(RegionSum, RegionSum)>> {
        let contour = place(&self.contour, pose);
        let inner = place(&self.inner, pose);
        let outer = place(&self.outer, pose);
        let n = contour.len();
        let domain: Vec<HalfPlane> = if self.cuts.is_empty() {
            Vec::new()
        } else {
            let cuts = self.cuts.iter().map(|c| c.moved(pose.theta, [pose.x, pose.y]));
            HalfPlane::sides_of_box(sums.image_extent())
                .into_iter()
                .chain(cuts)
                .chain(self.limits.iter().copied())
                .collect()
        };
        let seen = |p: Point| domain.iter().all(|h| h.depth(p) >= 1.0) && sums.covers(&[p]);
        let mut arc = Vec::with_capacity(n / self.starts.len().max(1) + 4);
        (0..self.starts.len())
            .map(|k| {
                let (start, end) = (self.starts[k], self.starts.get(k + 1).copied().unwrap_or(n));
                if !domain.is_empty() && !(start..=end).all(|i| seen(inner[i % n]) && seen(outer[i % n])) {
                    return None;
                }
                arc.clear();
                arc.extend((start..=end).map(|i| contour[i % n]));
                let along = sums.path(&arc);
                let (first, last) = (contour[start % n], contour[end % n]);
                let mut band = |other: &[Point]| {
                    arc.clear();
                    arc.push(last);
                    arc.extend((start..=end).rev().map(|i| other[i % n]));
                    arc.push(first);
                    (along + sums.path(&arc)).region()
                };
                Some((band(&inner), band(&outer)))
            })
            .collect()
    }

    /// The contour arcs of the sectors not marked occluded, placed at
    /// `pose`, in the template's orientation (consecutive visible sectors
    /// joined into one arc); the whole contour, its first vertex repeated at
    /// the end, when none is marked.
    pub fn visible_arcs(&self, pose: Pose, occluded: &[bool]) -> Vec<Vec<Point>> {
        let contour = place(&self.contour, pose);
        let n = contour.len();
        if !occluded.contains(&true) {
            let mut closed = contour;
            closed.push(closed[0]);
            return vec![closed];
        }
        let mut arcs: Vec<Vec<Point>> = Vec::new();
        let mut open = false;
        for k in 0..self.starts.len() {
            if occluded.get(k).copied().unwrap_or(false) {
                open = false;
                continue;
            }
            let (start, end) = (self.starts[k], self.starts.get(k + 1).copied().unwrap_or(n));
            if !open {
                arcs.push(vec![contour[start % n]]);
                open = true;
            }
            let arc = arcs.last_mut().expect("an arc is open");
            arc.extend((start + 1..=end).map(|i| contour[i % n]));
        }
        arcs
    }

    /// Michelson contrast of every sector's inner band against its outer
    /// band; NaN for a sector that is not seen.
    pub fn contrasts(&self, sums: &PrefixSums, pose: Pose) -> Vec<f64> {
        self.look(sums, pose).contrasts
    }

    /// Every sector's contrast ([`SectorTemplate::contrasts`]) and inner
    /// band mean; NaN for a sector that is not seen.
    pub fn look(&self, sums: &PrefixSums, pose: Pose) -> SectorLook {
        let (contrasts, inner) = self
            .band_sums(sums, pose)
            .into_iter()
            .map(|bands| {
                bands.map_or((f64::NAN, f64::NAN), |(a, b)| {
                    (michelson(a.mean(), b.mean()), a.mean())
                })
            })
            .unzip();
        SectorLook { contrasts, inner }
    }

    /// The inner and outer bands of the seen sectors not marked occluded,
    /// each summed into one region.
    pub fn visible_bands(&self, sums: &PrefixSums, pose: Pose, occluded: &[bool]) -> (RegionSum, RegionSum) {
        let (mut a, mut b) = (RegionSum::default(), RegionSum::default());
        for (k, bands) in self.band_sums(sums, pose).into_iter().enumerate() {
            let Some((inside, outside)) = bands else {
                continue;
            };
            if occluded.get(k).copied().unwrap_or(false) {
                continue;
            }
            a.count += inside.count;
            a.sum += inside.sum;
            b.count += outside.count;
            b.sum += outside.sum;
        }
        (a, b)
    }

    /// Band energy over the seen sectors not marked occluded: minus the
    /// two-region likelihood ratio of the union of their inner bands against
    /// the union of their outer bands, divided by `m_ref`. `+inf` when the
    /// outer band leaves the covered area (a template without cuts) or
    /// nothing is left.
    pub fn masked_energy(&self, sums: &PrefixSums, pose: Pose, occluded: &[bool], m_ref: f64) -> f64 {
        // The outer band's edge, not the contour: on tables split with a
        // guard (`PrefixSums::split`) the contour must stay a guard inside
        // their area, its band need not (a rod's band at its ends reached
        // into the guard, and every masked energy there was infinite).
        if self.cuts.is_empty() && !sums.covers(&place(&self.outer, pose)) {
            return f64::INFINITY;
        }
        let (a, b) = self.visible_bands(sums, pose, occluded);
        let both = RegionSum {
            count: a.count + b.count,
            sum: a.sum + b.sum,
        };
        match data_term(a, both) {
            Some(d) => -d / m_ref,
            None => f64::INFINITY,
        }
    }
}

/// How the sectors of a contour look in one view: per sector the Michelson
/// contrast of the inner band against the outer one, and the inner band's
/// mean grey level (NaN, or 0 in a stored reference, where not seen).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SectorLook {
    /// Contrast per sector.
    pub contrasts: Vec<f64>,
    /// Inner band mean per sector (empty: not known, as in states stored
    /// before it was kept).
    pub inner: Vec<f64>,
}

/// A view's reference look of the sectors as stored (borrowed): per sector
/// the contrast and the inner band mean (0 where not seen; `inner` empty
/// in states stored before it was kept).
#[derive(Clone, Copy, Debug)]
pub struct SectorReference<'a> {
    /// Contrast per sector.
    pub contrasts: &'a [f64],
    /// Inner band mean per sector.
    pub inner: &'a [f64],
}

/// `marks` with each marked run grown by one sector on each side (the
/// sectors wrap round).
pub fn grown(marks: &[bool]) -> Vec<bool> {
    let n = marks.len();
    (0..n)
        .map(|k| marks[k] || marks[(k + 1) % n] || marks[(k + n - 1) % n])
        .collect()
}

/// A sector whose contrast rose above this multiple of its reference
/// (relative to the median sector), in a run of at least
/// [`MIN_RISEN_RUN`] such sectors, lies before something darker along that
/// stretch: a new backdrop, or an occluder over the object's edge, which
/// the contrast alone does not tell apart ([`SectorJudgement::risen`]).
pub const RISEN_RATIO: f64 = 1.4;

/// The shortest run of risen sectors ([`RISEN_RATIO`]): a relief substrate
/// raises single sectors up to 2 times as the object moves over it.
pub const MIN_RISEN_RUN: usize = 3;

/// The runs of sectors whose contrast rose above [`RISEN_RATIO`] times
/// their own reference (Michelson contrasts: a change of gain leaves them),
/// at least [`MIN_RISEN_RUN`] long and grown by a sector on each side.
/// Unlike [`SectorJudgement::risen`], not against the median sector, which
/// falls when most of the outline loses its contrast (a tool over a
/// particle), and including sectors risen beyond `max_ratio`. Sectors
/// whose reference contrast is weak (below [`WEAK_SECTOR_SHARE`] of the
/// median) or not seen are never marked.
pub fn risen_on_their_own(reference: &[f64], current: &SectorLook) -> Vec<bool> {
    let typical = median_magnitude(reference);
    let marks: Vec<bool> = reference
        .iter()
        .zip(&current.contrasts)
        .map(|(r, c)| {
            r.is_finite() && *r != 0.0 && r.abs() >= WEAK_SECTOR_SHARE * typical && c / r > RISEN_RATIO
        })
        .collect();
    grown(&runs_at_least(&marks, MIN_RISEN_RUN))
}

/// A sector whose reference contrast is below this share of the median
/// sector's carries too little signal to judge (the looks leave it out).
pub const WEAK_SECTOR_SHARE: f64 = 0.25;

/// Per sector of a reference look, whether it was seen (a finite, non-zero
/// contrast) but shows no edge of the object: its contrast below
/// [`WEAK_SECTOR_SHARE`] of the median sector's, or of the other sign than
/// the object's (the median sector's).
/// Such a sector faces something as bright as the object or brighter (a
/// lamella's end welded to a needle's tip, a plate's end against a post of
/// its own grey): in a region energy it pulls the outline towards that
/// neighbour instead of holding it to the object's edge.
pub fn edgeless(reference: &[f64]) -> Vec<bool> {
    let typical = median_magnitude(reference);
    let mut signed: Vec<f64> = reference
        .iter()
        .copied()
        .filter(|&r| r.is_finite() && r != 0.0)
        .collect();
    signed.sort_by(|a, b| a.total_cmp(b));
    let sign = signed.get(signed.len() / 2).copied().unwrap_or(0.0).signum();
    reference
        .iter()
        .map(|&r| r.is_finite() && r != 0.0 && (r * sign <= 0.0 || r.abs() < WEAK_SECTOR_SHARE * typical))
        .collect()
}

/// The median magnitude of the seen reference contrasts (0 when none is
/// seen): a sector far below it carries too little signal to judge.
fn median_magnitude(reference: &[f64]) -> f64 {
    let mut magnitudes: Vec<f64> = reference
        .iter()
        .filter(|r| r.is_finite())
        .map(|r| r.abs())
        .collect();
    magnitudes.sort_by(|a, b| a.total_cmp(b));
    magnitudes.get(magnitudes.len() / 2).copied().unwrap_or(0.0)
}

/// The marks that belong to a run of at least `min` consecutive marks
/// (the sectors wrap round; all marked is one run).
pub fn runs_at_least(marks: &[bool], min: usize) -> Vec<bool> {
    let n = marks.len();
    if marks.iter().all(|&m| m) {
        return marks.to_vec();
    }
    let mut out = vec![false; n];
    // Start just after an unmarked sector so that no run wraps past the start.
    let start = (0..n).find(|&k| !marks[k]).map_or(0, |k| k + 1);
    let mut run = Vec::new();
    for i in 0..=n {
        let k = (start + i) % n;
        if i < n && marks[k] {
            run.push(k);
        } else {
            if run.len() >= min {
                for &j in &run {
                    out[j] = true;
                }
            }
            run.clear();
        }
    }
    out
}

/// What [`judge_sectors`] found.
#[derive(Clone, Debug, PartialEq)]
pub struct SectorJudgement {
    /// Per sector: left out of the fit, its contrast changed (grown by one
    /// sector on each side of a run).
    pub occluded: Vec<bool>,
    /// Per sector: hidden, the changed sectors whose inner band changed too
    /// (grown likewise). A changed sector whose inner band still shows the
    /// object's own grey is the object in front of a new backdrop (a tool
    /// passing over a particle): its edge is left out of the fit, but the
    /// object is not hidden there. Equal to `occluded` when the reference
    /// has no inner band means.
    pub hidden: Vec<bool>,
    /// Per sector: not marked, but in a run of sectors whose contrast rose
    /// above [`RISEN_RATIO`] (grown like the marks). The edge shows there,
    /// stronger; it may still lie inside the object's where a darker
    /// occluder covers its rim.
    pub risen: Vec<bool>,
    /// Median contrast ratio (current / reference) of the strong sectors:
    /// near 1 when the pose is right and the view unobstructed, low when the
    /// contour is misplaced. 1 when no sector is strong.
    pub median_ratio: f64,
    /// Lowest contrast ratio of the strong sectors: it falls as soon as any
    /// part of the outline leaves its edge, whichever the shape and the
    /// direction (a rod moved along its axis keeps its median). 1 when no
    /// sector is strong.
    pub lowest_ratio: f64,
}

impl SectorJudgement {
    /// Lowest ratio of a confirmed pose (see [`SectorJudgement::confirms_pose`]).
    pub const CONFIRMED_LOWEST_RATIO: f64 = 0.7;

    /// True when every strong sector keeps at least 70% of its reference
    /// contrast and the median ratio lies within 0.8..=1.25: every part of
    /// the outline is within a few pixels of its edge. Measured on noisy
    /// synthetic images, a pose 4 px off gives a lowest ratio of 0.39-0.65
    /// (any shape, 8 directions); at the tracker's predicted poses on the
    /// synthetic suites (seeds 100-104, 1440 predictions) it was 0.75 or
    /// more in 95% of cases.
    pub fn confirms_pose(&self) -> bool {
        self.lowest_ratio >= Self::CONFIRMED_LOWEST_RATIO && (0.8..=1.25).contains(&self.median_ratio)
    }
}

/// Which sectors are occluded, comparing current contrasts with the
/// reference ones. Each sector's ratio current/reference is divided by the
/// median ratio (so a global change of gain or offset, e.g. charging, does
/// not count); a sector is occluded when that normalised ratio lies outside
/// `min_ratio..=max_ratio`. Sectors whose reference contrast is weak (below a
/// quarter of the median) carry too little signal to judge and are never
/// marked. A sector not seen (its contrast not finite, e.g. cut off by the
/// image border) is neither judged nor marked.
pub fn judge_sectors(reference: &[f64], current: &[f64], min_ratio: f64, max_ratio: f64) -> SectorJudgement {
    judge_look(
        SectorReference {
            contrasts: reference,
            inner: &[],
        },
        &SectorLook {
            contrasts: current.to_vec(),
            inner: Vec::new(),
        },
        min_ratio,
        max_ratio,
    )
}

/// A sector's outer band mean from its inner band mean `inner` and its
/// Michelson contrast `contrast` (what a [`SectorLook`] keeps).
fn outer_mean(inner: f64, contrast: f64) -> f64 {
    inner * (1.0 - contrast) / (1.0 + contrast)
}

/// The change of the object's grey relative to its surroundings' since
/// `reference`: the median over the sectors seen in both of the inner
/// band's ratio (current / reference), divided by the median of the outer
/// band's. Near 1 when the same object is in view under any gain (e.g.
/// charging); the grey of something else in the object's place (a brighter
/// bar) moves it. `None` when fewer than 3 sectors are seen in both.
pub fn grey_change(reference: SectorReference, current: &SectorLook) -> Option<f64> {
    let (mut inner, mut outside) = (Vec::new(), Vec::new());
    for k in 0..reference.contrasts.len().min(current.contrasts.len()) {
        let (Some(&ri), Some(&ci)) = (reference.inner.get(k), current.inner.get(k)) else {
            continue;
        };
        let (rc, cc) = (reference.contrasts[k], current.contrasts[k]);
        let (ro, co) = (outer_mean(ri, rc), outer_mean(ci, cc));
        if [ri, ci, ro, co].iter().all(|v| v.is_finite() && *v > 0.0) {
            inner.push(ci / ri);
            outside.push(co / ro);
        }
    }
    if inner.len() < 3 {
        return None;
    }
    // Both medians are of positive ratios.
    let (gi, _) = median_and_spread(&inner)?;
    let (go, _) = median_and_spread(&outside)?;
    Some(gi / go)
}

/// How many quantiles of a frame's grey levels [`grey_quantiles`] gives:
/// its deciles.
pub const GREY_QUANTILES: usize = 9;

/// A frame's grey levels at the shares 0.1, 0.2, ..., 0.9 of its pixels
/// (its deciles; each level spread evenly over its unit bin, so that an
/// 8-bit frame's deciles move continuously), with [`INTENSITY_OFFSET`]
/// added as the looks' band means have it. An affine change of grey levels
/// maps each of them; an object that enters or leaves the frame moves a
/// few ([`GreyMap::between`] reads the change robustly).
pub fn grey_quantiles(frame: &GrayFrame) -> [f64; GREY_QUANTILES] {
    let mut counts = vec![0u32; usize::from(frame.max_value()) + 1];
    for &v in &frame.data {
        if let Some(c) = counts.get_mut(usize::from(v)) {
            *c += 1;
        }
    }
    let n = frame.data.len() as f64;
    let mut quantiles = [0.0; GREY_QUANTILES];
    let (mut level, mut below) = (0usize, 0.0);
    for (k, q) in quantiles.iter_mut().enumerate() {
        let rank = n * (k + 1) as f64 / (GREY_QUANTILES + 1) as f64;
        while level + 1 < counts.len() && below + f64::from(counts[level]) < rank {
            below += f64::from(counts[level]);
            level += 1;
        }
        let within = (rank - below) / f64::from(counts[level].max(1));
        *q = level as f64 - 0.5 + within.clamp(0.0, 1.0) + f64::from(INTENSITY_OFFSET);
    }
    quantiles
}

/// An affine change of grey levels between a reference frame and the
/// current one, `current = gain * reference + offset`: a microscope's
/// automatic brightness and contrast between them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GreyMap {
    pub gain: f64,
    pub offset: f64,
}

impl GreyMap {
    /// The change from a frame with [`grey_quantiles`] `reference` to one
    /// with `current`, fitted by Theil and Sen's estimator: the gain the
    /// median of the slopes between every two quantiles, the offset the
    /// median of what is left. Robust to the few quantiles that an object
    /// entering or leaving the frame moves. None when the reference's
    /// quantiles are all one level.
    pub fn between(reference: &[f64; GREY_QUANTILES], current: &[f64; GREY_QUANTILES]) -> Option<Self> {
        let mut slopes = Vec::with_capacity(GREY_QUANTILES * (GREY_QUANTILES - 1) / 2);
        for i in 0..GREY_QUANTILES {
            for j in i + 1..GREY_QUANTILES {
                let run = reference[j] - reference[i];
                if run > 1e-9 {
                    slopes.push((current[j] - current[i]) / run);
                }
            }
        }
        let (gain, _) = median_and_spread(&slopes)?;
        if !(gain.is_finite() && gain > 0.0) {
            return None;
        }
        let rest: Vec<f64> = reference.iter().zip(current).map(|(r, c)| c - gain * r).collect();
        let (offset, _) = median_and_spread(&rest)?;
        Some(Self { gain, offset })
    }

    /// How much of the change from `reference` to `current` (each a
    /// frame's [`grey_quantiles`]) this map leaves unexplained: the median
    /// of the quantiles' absolute residuals, over the current frame's
    /// spread from its first quantile to its last. Near 0 for a change of
    /// brightness and contrast (0.000-0.011 between the real sequences'
    /// frames, up to 0.012 after a regrade of 8-bit levels, which rounds
    /// them; a regrade that clips the brightest levels moves only the top
    /// quantiles, which the median leaves out); a change of the tone curve
    /// leaves more (the real contact sequence after its tone change:
    /// 0.079-0.104). In 0..; NaN when the current quantiles are all one
    /// level.
    pub fn unexplained(&self, reference: &[f64; GREY_QUANTILES], current: &[f64; GREY_QUANTILES]) -> f64 {
        let residuals: Vec<f64> = reference
            .iter()
            .zip(current)
            .map(|(r, c)| (c - (self.gain * r + self.offset)).abs())
            .collect();
        let spread = current[GREY_QUANTILES - 1] - current[0];
        match median_and_spread(&residuals) {
            Some((median, _)) if spread > 0.0 => median / spread,
            _ => f64::NAN,
        }
    }

    /// `look` as the reference frame's grey levels would show it: each
    /// sector's inner and outer band means mapped back, its contrast
    /// taken again from them. A sector whose mapped means are not both
    /// positive keeps no contrast (NaN).
    pub fn look_back(&self, look: &SectorLook) -> SectorLook {
        if look.inner.len() != look.contrasts.len() {
            return look.clone();
        }
        let back = |v: f64| (v - self.offset) / self.gain;
        let (contrasts, inner) = look
            .contrasts
            .iter()
            .zip(&look.inner)
            .map(|(&m, &a)| {
                let b = outer_mean(a, m);
                let (a, b) = (back(a), back(b));
                if a > 0.0 && b > 0.0 {
                    ((a - b) / (a + b), a)
                } else {
                    (f64::NAN, f64::NAN)
                }
            })
            .unzip();
        SectorLook { contrasts, inner }
    }
}

/// A sector's inner band holds the object's grey when its mean, relative
/// to the reference and to the median such ratio, stays within this
/// fraction of 1, or within three robust standard deviations of the
/// sectors' ratios (up to [`MAX_INNER_HOLDS_TOLERANCE`]).
pub const INNER_HOLDS_TOLERANCE: f64 = 0.08;

/// The largest tolerance of [`INNER_HOLDS_TOLERANCE`] in noisy frames.
pub const MAX_INNER_HOLDS_TOLERANCE: f64 = 0.2;

/// [`judge_sectors`] that also tells a hidden sector from a new backdrop by
/// the inner band means (when both looks have them): a changed sector
/// whose inner band holds the object's grey (see [`INNER_HOLDS_TOLERANCE`])
/// is backdrop. Such sectors do not set the median and lowest ratios (the
/// typical sector of a tool over a particle lost its contrast, yet the tool
/// is in view).
pub fn judge_look(
    reference: SectorReference,
    current: &SectorLook,
    min_ratio: f64,
    max_ratio: f64,
) -> SectorJudgement {
    let (reference_inner, reference) = (reference.inner, reference.contrasts);
    let current_inner = &current.inner;
    let current = &current.contrasts[..];
    let typical = median_magnitude(reference);
    let strong: Vec<bool> = reference
        .iter()
        .zip(current)
        .map(|(r, c)| r.is_finite() && c.is_finite() && r.abs() >= WEAK_SECTOR_SHARE * typical && *r != 0.0)
        .collect();
    let ratios: Vec<f64> = reference
        .iter()
        .zip(current)
        .zip(&strong)
        .map(|((r, c), s)| if *s { c / r } else { 1.0 })
        .collect();
    // Whose inner band holds the object's grey (after the median change
    // of all strong sectors' inner bands, e.g. charging).
    let holds: Vec<bool> = if reference_inner.len() == reference.len()
        && current_inner.len() == reference.len()
    {
        let inner_ratio = |k: usize| {
            let (r, c) = (reference_inner[k], current_inner[k]);
            (strong[k] && r > 0.0 && c.is_finite()).then(|| c / r)
        };
        let inner_ratios: Vec<f64> = (0..reference.len()).filter_map(inner_ratio).collect();
        match median_and_spread(&inner_ratios) {
            Some((g, spread)) if g > 0.0 => {
                // The tolerance grows with the sectors' own scatter
                // (three robust standard deviations) in noisy frames.
                let tolerance = (3.0 * spread / g).clamp(INNER_HOLDS_TOLERANCE, MAX_INNER_HOLDS_TOLERANCE);
                (0..reference.len())
                    .map(|k| inner_ratio(k).is_some_and(|r| (r / g - 1.0).abs() <= tolerance))
                    .collect()
            }
            _ => vec![false; reference.len()],
        }
    } else {
        vec![false; reference.len()]
    };
    // Backdrop candidates (inner band held, contrast halved or doubled
    // before normalising) do not set the median. Partly changed sectors
    // count as candidates too, so that most of a tool's outline over a
    // particle does not pull the median down (with the thresholds 0.35 and
    // 2 instead of 0.5 and 2, a tool over a particle was lost in 3.3% of
    // the clean pairs against none; the relief suite had 3 confident
    // wrong pairs and 6 lost against 1 and 0; 0.7 and 1/0.7 lost 21
    // occluded pairs against 10, one confident wrong).
    let candidate = |k: usize| holds[k] && !(0.5..=2.0).contains(&ratios[k]);
    let sorted = |keep: &dyn Fn(usize) -> bool| {
        let mut v: Vec<f64> = (0..reference.len())
            .filter(|&k| strong[k] && keep(k))
            .map(|k| ratios[k])
            .collect();
        v.sort_by(|a, b| a.total_cmp(b));
        v
    };
    let mut strong_ratios = sorted(&|k| !candidate(k));
    if strong_ratios.len() < 3 {
        strong_ratios = sorted(&|_| true);
    }
    if strong_ratios.is_empty() {
        return SectorJudgement {
            occluded: vec![false; reference.len()],
            hidden: vec![false; reference.len()],
            risen: vec![false; reference.len()],
            median_ratio: 1.0,
            lowest_ratio: 1.0,
        };
    }
    let median = strong_ratios[strong_ratios.len() / 2];
    let marks: Vec<bool> = ratios
        .iter()
        .zip(&strong)
        .map(|(r, s)| *s && median > 0.0 && !(min_ratio..=max_ratio).contains(&(r / median)))
        .collect();
    let hidden: Vec<bool> = marks.iter().zip(&holds).map(|(m, h)| *m && !h).collect();
    let risen: Vec<bool> = (0..ratios.len())
        .map(|k| strong[k] && !marks[k] && median > 0.0 && ratios[k] / median > RISEN_RATIO)
        .collect();
    let seen_ratios = sorted(&|k| !(marks[k] && holds[k]));
    let lowest = seen_ratios.first().copied().unwrap_or(strong_ratios[0]);
    // An occluder covers a contiguous stretch of the outline, and the
    // sectors at its ends are only partly covered (their contrast changes
    // less than the threshold): each marked run grows by one sector per side.
    let occluded = grown(&marks);
    let risen = grown(&runs_at_least(&risen, MIN_RISEN_RUN))
        .into_iter()
        .zip(&occluded)
        .map(|(r, o)| r && !o)
        .collect();
    SectorJudgement {
        occluded,
        hidden: grown(&hidden),
        risen,
        median_ratio: median,
        lowest_ratio: lowest,
    }
}

/// Per sector of `hidden`: both of its bands now show the grey that the
/// sector's outer band showed in `reference` (scaled by the median change
/// of the outer bands of the sectors not in `left_out`, e.g. charging),
/// within `tolerance` of it. The contour runs over bare substrate there: it
/// left the object's edge, as a rod's end does when the rod slid along its
/// axis. An occluder shows its own grey in the inner band instead. The
/// scale comes from sectors that kept their contrast only: before a new
/// backdrop (a tool over a particle as bright as itself) the outer bands
/// changed, and their median would make the tool's own grey look like the
/// substrate's. Needs the inner band means of both looks (all false
/// without them).
pub fn overhanging(
    reference: SectorReference,
    current: &SectorLook,
    (left_out, hidden): (&[bool], &[bool]),
    tolerance: f64,
) -> Vec<bool> {
    let n = hidden.len();
    if reference.inner.len() != n
        || current.inner.len() != n
        || reference.contrasts.len() != n
        || left_out.len() != n
    {
        return vec![false; n];
    }
    // Per sector: the reference's outer grey, the current inner and outer.
    let greys = |k: usize| {
        let (ri, ci) = (reference.inner[k], current.inner[k]);
        let g = [
            outer_mean(ri, reference.contrasts[k]),
            ci,
            outer_mean(ci, current.contrasts[k]),
        ];
        g.iter().all(|v| v.is_finite() && *v > 0.0).then_some(g)
    };
    let gains: Vec<f64> = (0..n)
        .filter(|&k| !left_out[k])
        .filter_map(|k| greys(k).map(|[ro, _, co]| co / ro))
        .collect();
    let Some((gain, _)) = median_and_spread(&gains) else {
        return vec![false; n];
    };
    (0..n)
        .map(|k| {
            hidden[k]
                && greys(k).is_some_and(|[ro, ci, co]| {
                    let substrate = gain * ro;
                    (ci / substrate - 1.0).abs() <= tolerance && (co / substrate - 1.0).abs() <= tolerance
                })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_changed_sector_is_marked_and_a_global_gain_is_not() {
        let reference = vec![0.4; 24];
        let mut current: Vec<f64> = reference.iter().map(|r| r * 0.8).collect(); // charging
        let judged = judge_sectors(&reference, &current, 0.35, 2.0);
        assert!(judged.occluded.iter().all(|m| !m) && (judged.median_ratio - 0.8).abs() < 1e-12);
        assert!((judged.lowest_ratio - 0.8).abs() < 1e-12);
        for c in current.iter_mut().take(6) {
            *c = 0.02; // covered by something as bright as the object
        }
        current[10] = -0.3; // covered by something dark
        current[20] = 0.25; // weakened by a change of view: not occlusion
        let marks = judge_sectors(&reference, &current, 0.35, 2.0).occluded;
        let marked: Vec<usize> = (0..24).filter(|&k| marks[k]).collect();
        // Runs 0..=5 and 10, each grown by one sector (wrapping round to 23).
        assert_eq!(marked, vec![0, 1, 2, 3, 4, 5, 6, 9, 10, 11, 23]);
    }

    #[test]
    fn sectors_risen_on_their_own_are_found_whatever_the_median() {
        let reference = vec![0.4; 24];
        let look = |contrasts: Vec<f64>| SectorLook {
            contrasts,
            inner: Vec::new(),
        };
        // Half the outline against a dark bar (1.6 times its contrast,
        // beyond the judgement's max_ratio against the median), the other
        // half without contrast.
        let mut half: Vec<f64> = (0..24).map(|k| if k < 12 { 0.64 } else { 0.0 }).collect();
        half[11] = 0.36;
        let marked: Vec<usize> = (0..24)
            .filter(|&k| risen_on_their_own(&reference, &look(half.clone()))[k])
            .collect();
        assert_eq!(marked, (0..12).chain([23]).collect::<Vec<_>>());
        // A tool over a particle: most of its outline without contrast,
        // its base as it was. Against the median the base has risen; on
        // its own it has not.
        let tool: Vec<f64> = (0..24).map(|k| if k < 6 { 0.4 } else { 0.02 }).collect();
        assert!(!risen_on_their_own(&reference, &look(tool)).contains(&true));
        // A single risen sector is no run; a weak reference is not judged.
        let mut single = vec![0.4; 24];
        single[5] = 0.8;
        assert!(!risen_on_their_own(&reference, &look(single)).contains(&true));
        let mut weak = reference.clone();
        weak[..4].fill(0.05);
        let mut current = vec![0.4; 24];
        current[..4].fill(0.2);
        assert!(!risen_on_their_own(&weak, &look(current)).contains(&true));
    }

    #[test]
    fn a_run_of_risen_contrasts_is_found_and_a_single_one_is_not() {
        let reference = vec![0.4; 24];
        let mut current = reference.clone();
        // Something darker along sectors 22, 23, 0 and 1 (the run wraps
        // round); sector 10 alone rises as much, as relief texture does.
        for k in [22, 23, 0, 1, 10] {
            current[k] = 0.4 * 1.7;
        }
        let judged = judge_sectors(&reference, &current, 0.35, 2.0);
        assert!(!judged.occluded.contains(&true), "a rise is not occlusion");
        let risen: Vec<usize> = (0..24).filter(|&k| judged.risen[k]).collect();
        assert_eq!(risen, vec![0, 1, 2, 21, 22, 23]);
        // Below the ratio, nothing.
        let mut current = reference.clone();
        for c in current.iter_mut().take(6) {
            *c *= RISEN_RATIO - 0.05;
        }
        assert!(!judge_sectors(&reference, &current, 0.35, 2.0)
            .risen
            .contains(&true));
        assert_eq!(runs_at_least(&[true; 5], 7), vec![true; 5]);
        assert_eq!(
            runs_at_least(&[true, false, false, true, true], 3),
            vec![true, false, false, true, true]
        );
        assert!(!runs_at_least(&[true, false, true, true, false], 3).contains(&true));
    }

    #[test]
    fn a_new_backdrop_is_left_out_but_not_hidden() {
        let look = |contrasts: Vec<f64>, inner: Vec<f64>| SectorLook { contrasts, inner };
        let reference = look(vec![0.4; 24], vec![150.0; 24]);
        // Sectors 0..=13 now lie before a particle as bright as the object
        // (contrast gone, inner band unchanged); sectors 18..=20 are covered
        // by a dark occluder (contrast inverted, inner band darkened).
        let mut current = look(vec![0.4; 24], vec![151.0; 24]);
        for k in 0..14 {
            current.contrasts[k] = 0.02;
        }
        for k in 18..21 {
            current.contrasts[k] = -0.3;
            current.inner[k] = 40.0;
        }
        let judged = judge_look(
            SectorReference {
                contrasts: &reference.contrasts,
                inner: &reference.inner,
            },
            &current,
            0.35,
            2.0,
        );
        let marked = |m: &[bool]| (0..24).filter(|&k| m[k]).collect::<Vec<usize>>();
        // Every changed sector is left out of the fit (runs grown by one)...
        let mut out: Vec<usize> = (0..15).chain(17..22).collect();
        out.push(23);
        assert_eq!(marked(&judged.occluded), out);
        // ...but only the covered ones are hidden, and the typical sector
        // keeps its contrast.
        assert_eq!(marked(&judged.hidden), vec![17, 18, 19, 20, 21]);
        assert!((judged.median_ratio - 1.0).abs() < 1e-12, "{judged:?}");
        // Without inner band means the typical sector has lost its
        // contrast, and the sectors that kept it look hidden instead.
        let blind = judge_sectors(&reference.contrasts, &current.contrasts, 0.35, 2.0);
        assert!(blind.median_ratio < 0.35, "{blind:?}");
        assert!(
            blind.hidden[16] && blind.hidden[22] && !blind.hidden[5],
            "{blind:?}"
        );
    }

    #[test]
    fn the_grey_change_ignores_gain_and_sees_another_grey() {
        // An object at 150 on a background of 60 (Michelson 0.43).
        let m = |a: f64, b: f64| (a - b) / (a + b);
        let look = |a: f64, b: f64| SectorLook {
            contrasts: vec![m(a, b); 24],
            inner: vec![a; 24],
        };
        let first = look(150.0, 60.0);
        let reference = SectorReference {
            contrasts: &first.contrasts,
            inner: &first.inner,
        };
        // Charging: everything 30% brighter.
        let g = grey_change(reference, &look(195.0, 78.0)).unwrap();
        assert!((g - 1.0).abs() < 1e-9, "{g}");
        // A bar at 100 against the same background, its edge contrast
        // near the object's.
        let g = grey_change(reference, &look(100.0, 60.0)).unwrap();
        assert!((g - 100.0 / 150.0).abs() < 1e-9, "{g}");
        // Too few sectors seen.
        let mut unseen = look(150.0, 60.0);
        unseen.inner[2..].fill(f64::NAN);
        assert_eq!(grey_change(reference, &unseen), None);
    }

    #[test]
    fn sectors_facing_something_as_bright_or_brighter_show_no_edge() {
        // A lamella (brighter than the void round it) welded to a needle's
        // tip at sectors 1-3: one reversed, two weak; sectors 5-6 not seen.
        let mut reference = vec![0.45; 12];
        reference[1] = -0.06;
        reference[2] = 0.03;
        reference[3] = 0.1;
        reference[4] = 0.2;
        reference[5] = 0.0;
        reference[6] = f64::NAN;
        let marks = edgeless(&reference);
        let expected: Vec<bool> = (0..12).map(|k| (1..=3).contains(&k)).collect();
        assert_eq!(marks, expected);
        // A darker object the same way round: its sign is the median's.
        let darker: Vec<f64> = reference.iter().map(|r| -r).collect();
        assert_eq!(edgeless(&darker), expected);
        assert!(!edgeless(&[0.3; 12]).contains(&true));
    }

    #[test]
    fn weak_reference_sectors_are_never_marked() {
        let mut reference = vec![0.4; 16];
        reference[3] = 0.01;
        let mut current = reference.clone();
        current[3] = 0.2;
        let marks = judge_sectors(&reference, &current, 0.35, 2.0).occluded;
        assert!(!marks[3]);
    }

    #[test]
    fn bare_substrate_in_both_bands_is_an_overhang_and_an_occluder_is_not() {
        // Object 150 on substrate 75 (Michelson contrast 1/3); everything
        // 10% darker now (charging).
        let reference = SectorLook {
            contrasts: vec![1.0 / 3.0; 24],
            inner: vec![150.0; 24],
        };
        let reference = SectorReference {
            contrasts: &reference.contrasts,
            inner: &reference.inner,
        };
        let mut current = SectorLook {
            contrasts: vec![1.0 / 3.0; 24],
            inner: vec![135.0; 24],
        };
        // Sectors 0..=2: the contour's end over bare substrate (both bands
        // 67.5, the substrate's grey after the same change); 3..=5: under a
        // bright bar (both bands 200); 6: a sector not seen.
        for k in 0..3 {
            (current.contrasts[k], current.inner[k]) = (0.0, 68.0);
        }
        for k in 3..6 {
            (current.contrasts[k], current.inner[k]) = (0.0, 200.0);
        }
        (current.contrasts[6], current.inner[6]) = (f64::NAN, f64::NAN);
        let hidden: Vec<bool> = (0..24).map(|k| k < 7).collect();
        let over = overhanging(reference, &current, (&hidden, &hidden), INNER_HOLDS_TOLERANCE);
        assert_eq!((0..24).filter(|&k| over[k]).collect::<Vec<_>>(), vec![0, 1, 2]);
        // Only hidden sectors are judged; without inner means, none.
        let none = [false; 24];
        assert!(!overhanging(reference, &current, (&none, &none), INNER_HOLDS_TOLERANCE).contains(&true));
        let bare = SectorReference {
            contrasts: reference.contrasts,
            inner: &[],
        };
        assert!(!overhanging(bare, &current, (&hidden, &hidden), INNER_HOLDS_TOLERANCE).contains(&true));
        // A darker substrate under the end (a dark occluder, 20% below the
        // substrate's grey) is no overhang at this tolerance.
        for k in 0..3 {
            current.inner[k] = 54.0;
        }
        assert!(!overhanging(reference, &current, (&hidden, &hidden), INNER_HOLDS_TOLERANCE).contains(&true));
        // A tool as bright as the particle it now lies over: most of its
        // outline (sectors 8..=23) before the particle (outer bands 135,
        // left out but not hidden), sectors 0..=2 hidden with the tool's
        // grey inside and the particle's outside. The scale of the
        // substrate's grey comes from sectors 3..=7 (unchanged), so the
        // tool's grey is no substrate.
        let mut tool = SectorLook {
            contrasts: vec![1.0 / 3.0; 24],
            inner: vec![150.0; 24],
        };
        for k in 0..24 {
            if !(3..8).contains(&k) {
                (tool.contrasts[k], tool.inner[k]) = (0.0, 150.0);
            }
        }
        let left_out: Vec<bool> = (0..24).map(|k| !(3..8).contains(&k)).collect();
        let hidden: Vec<bool> = (0..24).map(|k| k < 3).collect();
        assert!(!overhanging(reference, &tool, (&left_out, &hidden), INNER_HOLDS_TOLERANCE).contains(&true));
        // Scaled by the median of all but the hidden sectors, the
        // particle's grey passed for the substrate's.
        assert!(overhanging(reference, &tool, (&hidden, &hidden), INNER_HOLDS_TOLERANCE).contains(&true));
    }
}

#[cfg(test)]
mod prediction_tests {
    use super::*;
    use crate::energy::EnergyParams;
    use crate::region::PixelRect;
    use crate::synth::{frames, Preset, Shape, SynthConfig};

    /// Reference contrasts from the true outline of frame 0, and the
    /// judgement at `pose(frame truth)` in `frame`.
    fn judged_at(shape: Shape, seed: u64, frame: usize, offset: [f64; 2]) -> SectorJudgement {
        let config = SynthConfig {
            frames: frame + 1,
            ..SynthConfig::preset(Preset::Noisy, shape, seed)
        };
        let pairs: Vec<_> = frames(&config).unwrap().collect();
        let truth0 = &pairs[0].truth.left;
        let (template, pose0) =
            RigidTemplate::new(&truth0.polygon.resampled(120), 48, &EnergyParams::default());
        let sectors = SectorTemplate::new(&template, 24);
        let sums0 = PrefixSums::new(&pairs[0].left, PixelRect::full(&pairs[0].left), 1);
        let reference = sectors.contrasts(&sums0, pose0);
        let (image, truth) = (&pairs[frame].left, &pairs[frame].truth.left);
        let sums = PrefixSums::new(image, PixelRect::full(image), 1);
        // The template's centroid is the outline's; the truth moves rigidly.
        let moved = Pose {
            x: pose0.x + truth.centroid[0] - truth0.centroid[0] + offset[0],
            y: pose0.y + truth.centroid[1] - truth0.centroid[1] + offset[1],
            theta: truth.rotation_rad - truth0.rotation_rad,
        };
        judge_sectors(&reference, &sectors.contrasts(&sums, moved), 0.35, 2.0)
    }

    /// A frame's grey levels changed affinely (as a microscope's automatic
    /// brightness and contrast do): the sectors' look there, mapped back
    /// through the change read off the two frames' deciles, is the
    /// look in the frame as it was; unmapped, its contrasts are not.
    #[test]
    fn a_look_through_a_change_of_grey_levels_is_mapped_back() {
        let config = SynthConfig {
            frames: 1,
            ..SynthConfig::preset(Preset::Clean, Shape::Blob, 3)
        };
        let pair = frames(&config).unwrap().next().unwrap();
        let brightest = pair.left.data.iter().max().copied().unwrap_or(0);
        let darkest = pair.left.data.iter().min().copied().unwrap_or(0);
        let truth = &pair.truth.left;
        let (template, pose) =
            RigidTemplate::new(&truth.polygon.resampled(120), 48, &EnergyParams::default());
        let sectors = SectorTemplate::new(&template, 24);
        let look_in =
            |frame: &GrayFrame| sectors.look(&PrefixSums::new(frame, PixelRect::full(frame), 1), pose);
        let before = look_in(&pair.left);
        for (gain, offset) in [(1.3, -20.0), (0.7, 15.0), (1.0, -30.0)] {
            // No grey level clipped: the change stays affine.
            let range = [darkest, brightest].map(|v| gain * f64::from(v) + offset);
            assert!(range[0] >= 0.0 && range[1] <= 255.0, "{range:?}");
            let changed = pair.left.regraded(gain, offset);
            let after = look_in(&changed);
            let map = GreyMap::between(&grey_quantiles(&pair.left), &grey_quantiles(&changed)).unwrap();
            assert!(
                (map.gain / gain - 1.0).abs() < 0.05,
                "{map:?} for gain {gain}, offset {offset}"
            );
            let back = map.look_back(&after);
            let off = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
            // Deciles of 8-bit levels a gain has respaced carry a few
            // per cent of error into the gain (measured: 1.336 for 1.3).
            let relative = |a: &[f64], b: &[f64]| {
                a.iter()
                    .zip(b)
                    .map(|(x, y)| (x / y - 1.0).abs())
                    .fold(0.0, f64::max)
            };
            assert!(
                off(&back.contrasts, &before.contrasts) < 0.01,
                "{back:?} against {before:?}"
            );
            assert!(
                relative(&back.inner, &before.inner) < 0.03,
                "{back:?} against {before:?}"
            );
            assert!(
                off(&after.contrasts, &before.contrasts) > 0.03,
                "gain {gain}, offset {offset}: {after:?}"
            );
            // A brightness and contrast change leaves next to nothing
            // unexplained (measured: up to 0.012, the rounding of 8-bit
            // levels).
            let left = grey_quantiles(&pair.left);
            let unexplained = map.unexplained(&left, &grey_quantiles(&changed));
            assert!(unexplained < 0.02, "gain {gain}, offset {offset}: {unexplained}");
        }
    }

    #[test]
    fn a_tone_curve_leaves_what_no_gain_and_offset_explain() {
        // The deciles of the real contact sequence's first frame, and of
        // its fifth, after the microscope's tone change (rounded).
        let reference: [f64; GREY_QUANTILES] = [32.0, 40.0, 54.0, 67.0, 79.0, 94.0, 112.0, 144.0, 229.0];
        let retoned: [f64; GREY_QUANTILES] = [32.0, 49.0, 82.0, 116.0, 142.0, 160.0, 181.0, 200.0, 220.0];
        let fitted = |current: &[f64; GREY_QUANTILES]| {
            let map = GreyMap::between(&reference, current).unwrap();
            map.unexplained(&reference, current)
        };
        assert!(fitted(&retoned) > 0.07, "{}", fitted(&retoned));
        let affine = reference.map(|r| 1.4 * r - 20.0);
        assert!(fitted(&affine) < 1e-9, "{}", fitted(&affine));
        // An object entering the frame moves one decile: the median
        // leaves it out.
        let mut entered = affine;
        entered[6] += 25.0;
        assert!(fitted(&entered) < 0.01, "{}", fitted(&entered));
        // All one level: nothing to measure.
        let flat = [50.0; GREY_QUANTILES];
        assert!(GreyMap {
            gain: 1.0,
            offset: 0.0
        }
        .unexplained(&reference, &flat)
        .is_nan());
    }

    #[test]
    fn the_true_pose_in_a_later_noisy_frame_is_confirmed() {
        for shape in Shape::ALL {
            for seed in [3, 4] {
                let judged = judged_at(shape, seed, 5, [0.0, 0.0]);
                assert!(judged.confirms_pose(), "{shape:?} seed {seed}: {judged:?}");
            }
        }
    }

    #[test]
    fn a_pose_five_pixels_off_in_any_direction_is_not_confirmed() {
        // Measured on seed 3 (lowest ratio at 4 px: 0.39-0.65, at 6 px:
        // 0.14-0.40, over 8 directions and all shapes), so 5 px leaves
        // margin below 0.7. Rods and tips moved along their axis keep their
        // median ratio near 1: only the lowest ratio sees it.
        for shape in Shape::ALL {
            for seed in [3, 4] {
                for k in 0..8 {
                    let a = k as f64 * std::f64::consts::FRAC_PI_4;
                    let judged = judged_at(shape, seed, 0, [5.0 * a.cos(), 5.0 * a.sin()]);
                    assert!(
                        !judged.confirms_pose(),
                        "{shape:?} seed {seed}, direction {k}: {judged:?}"
                    );
                }
            }
        }
    }
}

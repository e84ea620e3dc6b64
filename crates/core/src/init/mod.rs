//! Automatic initialisation: find the object in the first (left) image without
//! a person drawing it (Dahmen et al., ICINCO 2009, section 2; method note
//! section 1).
//!
//! Pipeline, on a working copy of the image box-downsampled so that its longer
//! side is at most [`InitParams::working_max_side`] (pixel parameters then suit
//! any frame size, and noise is averaged away):
//! 1. Gaussian low-pass (sigma adapts to the estimated noise level);
//! 2. Canny: Sobel gradients, non-maximum suppression, hysteresis with
//!    thresholds derived from the image's own gradient statistics;
//! 3. dilation with a disk of radius r to close gaps in the outline;
//! 4. outer contours (Suzuki-Abe) that no other contour encloses;
//! 5. filling, 6. size thresholding, keeping the largest plausible region;
//! 7. erosion of the filled region by r, undoing the dilation's growth, so the
//!    returned contour hugs the object.
//!
//! The region so found is the incumbent; scored candidates ([`prompted`])
//! replace it where the paper's rule fails: clutter joined to the outline,
//! an object cut by the image border, a hint it misses (see [`initialise`]).
//! A dark object's outline is then settled by the region-based free fit
//! and grown over the object's bright edge rim ([`rim`]). Last, the
//! outline is moved onto the object's edge to a fraction of a pixel, where
//! the thresholds left it 0.2-0.5 px outside ([`edge_fit`]).
//!
//! The output contour is in full-resolution pixel coordinates (centre of the
//! top-left pixel at (0, 0)).

use std::cell::OnceCell;

use image::{GrayImage, ImageBuffer, Luma};

use crate::energy::EnergyParams;
use crate::fit::{fit_free, free_fit_tables, FreeFitParams};
use crate::geometry::{Point, Polygon};
use crate::imageio::GrayFrame;

mod candidates;
mod edge_fit;
mod edges;
mod morphology;
mod outlined;
mod prompted;
mod rim;

pub use candidates::{Score, Source};
pub use edge_fit::{edge_width, fitted_to_edge};
pub use edges::{
    auto_thresholds, estimate_noise, hysteresis, non_maximum_suppression, sobel_noise_gain, Gradient,
};
pub use morphology::{dilate_disk, erode_disk, fill_region, mask_image, outer_regions, Region};
use morphology::{largest_component_border, shifted, without_tails};
use prompted::Outcome;

/// A single-channel f32 image (values in 0..=1 after normalisation).
pub type FloatImage = ImageBuffer<Luma<f32>, Vec<f32>>;

/// Which way the object differs from its surroundings.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "snake_case"))]
pub enum Polarity {
    /// Brighter than its surroundings (most particles and tools in SE images).
    Brighter,
    /// Darker than its surroundings.
    Darker,
    /// Either (the default).
    #[default]
    Any,
}

impl Polarity {
    /// The snake_case name used in JSON and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Polarity::Brighter => "brighter",
            Polarity::Darker => "darker",
            Polarity::Any => "any",
        }
    }

    /// Whether an object of Michelson `contrast` against its surroundings
    /// (positive: brighter) fits this polarity.
    pub fn admits(self, contrast: f64) -> bool {
        match self {
            Polarity::Brighter => contrast > 0.0,
            Polarity::Darker => contrast < 0.0,
            Polarity::Any => contrast != 0.0,
        }
    }
}

/// How far outside a dark region its bright edge rim is looked for, in
/// working pixels (see [`rim`]).
const RIM_REACH_WORKING_PX: f64 = 10.0;

/// How much brighter than the substrate a dark object's rim must be, as a
/// fraction of the substrate-to-object contrast (see [`rim`]).
const RIM_MIN_EXCESS: f64 = 0.15;

/// Vertex spacing of the free fit whose region the rim is grown from,
/// pixels: at the tracker's 6 px its length term cut 3-4 px off the ends of
/// thin rods and tips. The tracker's template (the core) keeps its own.
const RIM_CORE_SPACING_PX: f64 = 3.0;

/// Largest magnitude of a hint coordinate or size, pixels (2^31).
pub const MAX_HINT_COORDINATE: i64 = 1 << 31;

/// Smallest width and height of a `roi` hint, pixels.
pub const MIN_ROI_SIDE: i64 = 16;

/// Most vertices of an `outline` hint (a lasso sampled at every pointer
/// move of a few seconds' drawing stays well below).
pub const MAX_OUTLINE_VERTICES: usize = 4096;

/// Smallest area of an `outline` hint inside the image, pixels (that of
/// the smallest `roi`).
pub const MIN_OUTLINE_AREA_PX: f64 = (MIN_ROI_SIDE * MIN_ROI_SIDE) as f64;

/// Most `exclude` points.
pub const MAX_EXCLUDE_POINTS: usize = 64;

/// Parameters of the initialisation. Every field has a default that works
/// without tuning on 640x480 to 4096x4096 SEM frames; `None` means "derive
/// from the image".
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
pub struct InitParams {
    /// Longest side of the working copy in pixels (the image is box-averaged
    /// by an integer factor to fit). Default 640; range 64..=8192.
    pub working_max_side: u32,
    /// Gaussian standard deviation in working pixels; `None`: 1.0 for clean
    /// images, rising with the estimated noise level up to 3.0.
    pub sigma: Option<f32>,
    /// Canny thresholds on the gradient magnitude (grey levels per pixel, on
    /// the 0..=1 scale of the working image). `None`: from the image's
    /// gradient statistics (see [`auto_thresholds`]).
    pub low_threshold: Option<f32>,
    /// See `low_threshold`; must be >= it.
    pub high_threshold: Option<f32>,
    /// Radius of the disk used to dilate edges, in working pixels. `None`:
    /// about 1/150 of the working image's shorter side (2..=6), doubled once
    /// if nothing plausible is found.
    pub dilation_radius: Option<u8>,
    /// Smallest accepted object area in full-resolution pixels. `None`:
    /// 0.2% of the searched area.
    pub min_area_px: Option<f64>,
    /// Largest accepted object area in full-resolution pixels. `None`: 90%
    /// of the searched area.
    pub max_area_px: Option<f64>,
    /// Hint: the box `[x, y, width, height]` (pixels) the object lies in.
    /// Clipped to the image, so a box around a tool that enters from the
    /// image border may run past it; width and height >= 16, and the box
    /// must overlap the image.
    pub roi: Option<[i64; 4]>,
    /// Hint: a point `[x, y]` (pixels) on the object, as a person clicks it.
    /// Must lie inside the image (and inside `roi` when both are given).
    pub point: Option<[f64; 2]>,
    /// Hint: is the object brighter or darker than its surroundings?
    /// Default `any`.
    pub polarity: Polarity,
    /// Hint: the object's outline as a person drew it (a lasso), vertices
    /// `[x, y]` in pixels, 3 to [`MAX_OUTLINE_VERTICES`], not crossing
    /// itself. The most direct hint: the object is the region it encloses,
    /// moved onto the object's edges (see [`outlined`]); a part drawn past
    /// the image border says the object crosses it there. Its `point`, if
    /// given, must lie inside it.
    pub outline: Option<Vec<[f64; 2]>>,
    /// Hint: points `[x, y]` (pixels) on regions that are not the object
    /// ("not this"), at most [`MAX_EXCLUDE_POINTS`]: no region that covers
    /// one is taken. Each must lie inside the image, and outside the
    /// `outline`.
    pub exclude: Vec<[f64; 2]>,
    /// Vertex spacing of the returned contour in full-resolution pixels
    /// (default 2.0; range 0.5..=50).
    pub contour_spacing_px: f64,
}

impl Default for InitParams {
    fn default() -> Self {
        Self {
            working_max_side: 640,
            sigma: None,
            low_threshold: None,
            high_threshold: None,
            dilation_radius: None,
            min_area_px: None,
            max_area_px: None,
            roi: None,
            point: None,
            polarity: Polarity::Any,
            outline: None,
            exclude: Vec::new(),
            contour_spacing_px: 2.0,
        }
    }
}

/// The found object.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct InitResult {
    /// Outline of the object, full-resolution pixel coordinates.
    pub contour: Polygon,
    /// Centroid of the contour's area.
    pub centroid: Point,
    /// Area enclosed by the contour, in pixels.
    pub area_px: f64,
    /// Bounding box of the contour as `[min_x, min_y, max_x, max_y]`.
    pub bbox: [f64; 4],
    /// Mean width of the bright edge rim of a dark object that the outline
    /// was grown over, pixels (0 without one; see [`rim`]).
    #[cfg_attr(feature = "serde", serde(default))]
    pub rim_px: f64,
    /// The region inside the rim (`None` without one): darker than the
    /// substrate throughout, it is what a two-region energy fits, and what
    /// the tracker's template follows.
    #[cfg_attr(feature = "serde", serde(default, skip_serializing_if = "Option::is_none"))]
    pub core: Option<Polygon>,
    /// Share of the outline, leaving out its runs along the image border,
    /// that lies near an edge the Canny stage found (0..=1): how much of it
    /// follows a strong edge. Near: within the Canny blur's sigma plus one
    /// working pixel, as Canny places the edge of a structure narrower than
    /// its blur (an edge rim) up to that far inside it.
    /// A region most of whose outline follows none (a shadow's soft level
    /// line taken with the object) may hold more or less than the object;
    /// the tracker reports it `uncertain`. `None` for a drawn outline.
    #[cfg_attr(feature = "serde", serde(default, skip_serializing_if = "Option::is_none"))]
    pub edge_support: Option<f64>,
    /// Its score (the region energy's gain per pixel of outline, higher is
    /// better) and contrast (see [`candidates`]); `None` only when the
    /// paper's region stood without any candidate to compare it with.
    pub score: Option<Score>,
    /// Where the region came from.
    pub source: Source,
    /// The image borders the object crosses (`left`, `top`, `right`,
    /// `bottom`): its outline runs along them there, which is no edge of
    /// the object.
    pub border: Vec<String>,
    /// The sides of the `roi` (`left`, `top`, `right`, `bottom`) where the
    /// region was cut at the box because it went on past it: the outline
    /// runs along the box there, which is no edge of the object, and a fit
    /// keeps to the box on that side (see [`InitParams::fit_domain`]).
    #[cfg_attr(feature = "serde", serde(default, skip_serializing_if = "Vec::is_empty"))]
    pub cut_at_box: Vec<String>,
    /// What the pipeline used and saw, for diagnosis.
    pub diagnostics: InitDiagnostics,
}

/// Values the pipeline chose or measured on the way.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct InitDiagnostics {
    /// Integer downsampling factor of the working copy.
    pub scale: u32,
    /// Estimated noise standard deviation (0..=1 scale, full resolution).
    pub noise_sigma: f32,
    /// Gaussian sigma used (working pixels).
    pub sigma: f32,
    /// Canny thresholds used.
    pub low_threshold: f32,
    pub high_threshold: f32,
    /// Dilation radius used (working pixels).
    pub dilation_radius: u8,
    /// Number of edge pixels after hysteresis.
    pub edge_pixels: usize,
    /// Number of candidate regions (outer contours for the largest-region
    /// rule, scored candidates when they were ranked).
    pub candidates: usize,
    /// The next best candidates, best first (at most four).
    pub runners_up: Vec<RunnerUp>,
}

/// A candidate that lost, for diagnosis.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct RunnerUp {
    /// Its score.
    pub score: Score,
    /// Where it came from.
    pub source: Source,
    /// Its bounding box `[x0, y0, x1, y1]`, pixels.
    pub bbox: [f64; 4],
}

/// Why no object was found, or why the request was refused.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(tag = "reason", rename_all = "snake_case"))]
pub enum InitError {
    /// A parameter is out of range.
    #[error("invalid parameter: {0}")]
    InvalidParams(String),
    /// A hint (`roi`, `point`) is malformed or does not fit the image.
    #[error("invalid {field}: {message}")]
    InvalidHint {
        /// The hint's field name (`roi` or `point`).
        field: String,
        /// The value and what was expected.
        message: String,
    },
    /// The image has no edges above the thresholds (e.g. a blank frame).
    #[error("no edges found (high threshold {high_threshold:.4}): the image looks featureless")]
    NoEdges { high_threshold: f32 },
    /// Edges exist but no closed region within the size range.
    #[error("no region in the expected size range {min_area_px:.0}..={max_area_px:.0} px (largest closed region: {largest_area_px:.0} px)")]
    NothingInSizeRange {
        min_area_px: f64,
        max_area_px: f64,
        largest_area_px: f64,
    },
    /// The only plausible object touches the image (or region-of-interest)
    /// border, so its outline is incomplete.
    #[error("the object touches the {edge} border of the searched area; move it into view or widen the region of interest")]
    TouchesBorder { edge: String },
    /// Regions exist, but none is a plausible object with these hints.
    #[error("no plausible object: {message} (point at the object or draw a box around it)")]
    NoPlausibleRegion { message: String },
    /// A `point` or `polarity` hint that no region satisfies: the object
    /// it names is not there, and another is not taken in its place.
    #[error("no region fits the hints {hint}; found instead: {found}")]
    HintMatchesNothing {
        /// The hint, as given (`point (520, 300)`, `polarity darker`).
        hint: String,
        /// What the image holds instead.
        found: String,
    },
    /// Two objects of one session whose hints resolve to one region (their
    /// first outlines overlap by more than [`SAME_REGION_IOU`]): a height
    /// of an object above itself is no measurement.
    #[error("its hints resolve to the region of object {other:?} (IoU {iou:.2} of their first outlines); give each object hints that only it fits")]
    SameRegion {
        /// The other object's name.
        other: String,
        /// The IoU of the two first outlines.
        iou: f64,
    },
}

/// The IoU of two objects' first outlines above which they are one region
/// (see [`InitError::SameRegion`]).
pub const SAME_REGION_IOU: f64 = 0.5;

impl InitError {
    /// A stable snake_case code for APIs and logs.
    pub fn code(&self) -> &'static str {
        match self {
            Self::InvalidParams(_) => "invalid_init_params",
            Self::InvalidHint { .. } => "invalid_hint",
            Self::NoEdges { .. } => "no_edges",
            Self::NothingInSizeRange { .. } => "nothing_in_size_range",
            Self::TouchesBorder { .. } => "object_touches_border",
            Self::NoPlausibleRegion { .. } => "no_plausible_region",
            Self::HintMatchesNothing { .. } => "hint_matches_nothing",
            Self::SameRegion { .. } => "objects_share_a_region",
        }
    }
}

impl InitParams {
    /// The size of a `width` x `height` frame's working copy (see the module
    /// docs): reduced by the smallest integer factor that brings its longer
    /// side to at most `working_max_side`.
    pub fn working_size(&self, width: u32, height: u32) -> (u32, u32) {
        let scale = self.working_scale(width, height);
        (width / scale, height / scale)
    }

    /// The factor of [`Self::working_size`].
    fn working_scale(&self, width: u32, height: u32) -> u32 {
        width.max(height).div_ceil(self.working_max_side.max(1)).max(1)
    }

    /// Checks ranges; the message says what was expected.
    pub fn validate(&self) -> Result<(), InitError> {
        let bad = |m: String| Err(InitError::InvalidParams(m));
        let hint = |field: &str, message: String| {
            Err(InitError::InvalidHint {
                field: field.into(),
                message,
            })
        };
        if !(64..=8192).contains(&self.working_max_side) {
            return bad(format!(
                "working_max_side {} (expected 64..=8192)",
                self.working_max_side
            ));
        }
        if let Some(s) = self.sigma {
            if !(s.is_finite() && (0.3..=20.0).contains(&s)) {
                return bad(format!("sigma {s} (expected 0.3..=20)"));
            }
        }
        for (name, t) in [
            ("low_threshold", self.low_threshold),
            ("high_threshold", self.high_threshold),
        ] {
            if let Some(t) = t {
                if !(t.is_finite() && t > 0.0 && t <= 1.0) {
                    return bad(format!("{name} {t} (expected 0 < t <= 1)"));
                }
            }
        }
        if let (Some(l), Some(h)) = (self.low_threshold, self.high_threshold) {
            if l > h {
                return bad(format!(
                    "low_threshold {l} > high_threshold {h} (expected low <= high)"
                ));
            }
        }
        if let Some(r) = self.dilation_radius {
            if !(1..=32).contains(&r) {
                return bad(format!("dilation_radius {r} (expected 1..=32)"));
            }
        }
        for (name, a) in [
            ("min_area_px", self.min_area_px),
            ("max_area_px", self.max_area_px),
        ] {
            if let Some(a) = a {
                if !(a.is_finite() && a >= 0.0) {
                    return bad(format!("{name} {a} (expected a finite number >= 0)"));
                }
            }
        }
        if let (Some(lo), Some(hi)) = (self.min_area_px, self.max_area_px) {
            if lo > hi {
                return bad(format!(
                    "min_area_px {lo} > max_area_px {hi} (expected min <= max)"
                ));
            }
        }
        if let Some([x, y, w, h]) = self.roi {
            let limit = MAX_HINT_COORDINATE;
            if [x, y].iter().any(|v| v.abs() > limit) || w > limit || h > limit {
                return hint(
                    "roi",
                    format!("[{x}, {y}, {w}, {h}] (expected coordinates within +-{limit})"),
                );
            }
            if w < MIN_ROI_SIDE || h < MIN_ROI_SIDE {
                return hint(
                    "roi",
                    format!("[{x}, {y}, {w}, {h}]: a box of {w}x{h} px (expected width and height >= {MIN_ROI_SIDE})"),
                );
            }
        }
        if let Some([x, y]) = self.point {
            if !(x.is_finite()
                && y.is_finite()
                && x.abs() <= MAX_HINT_COORDINATE as f64
                && y.abs() <= MAX_HINT_COORDINATE as f64)
            {
                return hint(
                    "point",
                    format!("[{x}, {y}] (expected two finite pixel coordinates)"),
                );
            }
        }
        let finite = |[x, y]: [f64; 2]| {
            x.is_finite()
                && y.is_finite()
                && x.abs() <= MAX_HINT_COORDINATE as f64
                && y.abs() <= MAX_HINT_COORDINATE as f64
        };
        if let Some(outline) = &self.outline {
            if !(3..=MAX_OUTLINE_VERTICES).contains(&outline.len()) {
                return hint(
                    "outline",
                    format!("{} vertices (expected 3..={MAX_OUTLINE_VERTICES})", outline.len()),
                );
            }
            if let Some(k) = outline.iter().position(|&p| !finite(p)) {
                let [x, y] = outline[k];
                return hint(
                    "outline",
                    format!("vertex {k} [{x}, {y}] (expected two finite pixel coordinates)"),
                );
            }
            if !Polygon::new(outline.clone()).is_simple() {
                return hint(
                    "outline",
                    "crosses itself (expected an outline drawn once round the object)".into(),
                );
            }
        }
        if self.exclude.len() > MAX_EXCLUDE_POINTS {
            return hint(
                "exclude",
                format!(
                    "{} points (expected at most {MAX_EXCLUDE_POINTS})",
                    self.exclude.len()
                ),
            );
        }
        if let Some(k) = self.exclude.iter().position(|&p| !finite(p)) {
            let [x, y] = self.exclude[k];
            return hint(
                "exclude",
                format!("point {k} [{x}, {y}] (expected two finite pixel coordinates)"),
            );
        }
        if !(self.contour_spacing_px.is_finite() && (0.5..=50.0).contains(&self.contour_spacing_px)) {
            return bad(format!(
                "contour_spacing_px {} (expected 0.5..=50)",
                self.contour_spacing_px
            ));
        }
        Ok(())
    }
}

/// The hints of [`InitParams`] checked against an image's size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hints {
    /// The `roi` clipped to the image, `[x, y, width, height]`; the whole
    /// image without one.
    pub roi: [u32; 4],
    /// True when a `roi` was given.
    pub has_roi: bool,
    /// The `point`, inside `roi`.
    pub point: Option<[f64; 2]>,
    /// The polarity.
    pub polarity: Polarity,
    /// True when `exclude` points were given.
    pub has_exclude: bool,
}

impl Hints {
    /// True when any hint narrows the search (a `roi`, a `point`, a
    /// polarity other than `any`, or points that are not the object).
    pub fn given(&self) -> bool {
        self.has_roi || self.point.is_some() || self.polarity != Polarity::Any || self.has_exclude
    }
}

impl InitParams {
    /// The hints checked against a `width` x `height` image: the `roi`
    /// clipped to it (an error only when nothing of at least
    /// [`MIN_ROI_SIDE`] px a side is left), the `point` inside both.
    pub fn hints_for(&self, width: u32, height: u32) -> Result<Hints, InitError> {
        let hint = |field: &str, message: String| InitError::InvalidHint {
            field: field.into(),
            message,
        };
        let (wi, hi) = (i64::from(width), i64::from(height));
        let roi = match self.roi {
            None => [0, 0, width, height],
            Some([x, y, w, h]) => {
                let (x0, y0) = (x.max(0), y.max(0));
                let (x1, y1) = ((x + w).min(wi), (y + h).min(hi));
                if x1 <= x0 || y1 <= y0 {
                    return Err(hint(
                        "roi",
                        format!("[{x}, {y}, {w}, {h}] lies outside the {width}x{height} image (expected a box that overlaps it)"),
                    ));
                }
                let (cw, ch) = (x1 - x0, y1 - y0);
                if cw < MIN_ROI_SIDE.min(wi) || ch < MIN_ROI_SIDE.min(hi) {
                    return Err(hint(
                        "roi",
                        format!(
                            "[{x}, {y}, {w}, {h}] overlaps the {width}x{height} image by only {cw}x{ch} px (expected at least {MIN_ROI_SIDE}x{MIN_ROI_SIDE})"
                        ),
                    ));
                }
                [x0 as u32, y0 as u32, cw as u32, ch as u32]
            }
        };
        if let Some([px, py]) = self.point {
            let (lx, ly) = (width as f64 - 0.5, height as f64 - 0.5);
            if !(px >= -0.5 && px <= lx && py >= -0.5 && py <= ly) {
                return Err(hint(
                    "point",
                    format!("[{px}, {py}] lies outside the {width}x{height} image (expected -0.5 <= x <= {lx} and -0.5 <= y <= {ly})"),
                ));
            }
            let [rx, ry, rw, rh] = roi.map(f64::from);
            if self.roi.is_some()
                && !(px >= rx - 0.5 && px <= rx + rw - 0.5 && py >= ry - 0.5 && py <= ry + rh - 0.5)
            {
                return Err(hint(
                    "point",
                    format!("[{px}, {py}] lies outside the roi (expected a point on the object, inside the box it lies in)"),
                ));
            }
        }
        let (lx, ly) = (width as f64 - 0.5, height as f64 - 0.5);
        let in_image = |[px, py]: [f64; 2]| px >= -0.5 && px <= lx && py >= -0.5 && py <= ly;
        if let Some(k) = self.exclude.iter().position(|&p| !in_image(p)) {
            let [px, py] = self.exclude[k];
            return Err(hint(
                "exclude",
                format!("point {k} [{px}, {py}] lies outside the {width}x{height} image (expected -0.5 <= x <= {lx} and -0.5 <= y <= {ly})"),
            ));
        }
        if let Some(outline) = &self.outline {
            let drawn = Polygon::new(outline.clone());
            let inside = drawn.clipped_to_box([-0.5, -0.5, lx, ly]).area();
            if inside < MIN_OUTLINE_AREA_PX {
                return Err(hint(
                    "outline",
                    format!("encloses {inside:.0} px of the {width}x{height} image (expected at least {MIN_OUTLINE_AREA_PX:.0})"),
                ));
            }
            if let Some([px, py]) = self.point.filter(|&p| !drawn.contains(p)) {
                return Err(hint(
                    "point",
                    format!(
                        "[{px}, {py}] lies outside the outline (expected a point on the object it encloses)"
                    ),
                ));
            }
            if let Some(k) = self.exclude.iter().position(|&p| drawn.contains(p)) {
                let [px, py] = self.exclude[k];
                return Err(hint(
                    "exclude",
                    format!("point {k} [{px}, {py}] lies inside the outline (expected points on what is not the object)"),
                ));
            }
        }
        Ok(Hints {
            roi,
            has_roi: self.roi.is_some(),
            point: self.point,
            polarity: self.polarity,
            has_exclude: !self.exclude.is_empty(),
        })
    }
}

impl InitParams {
    /// Where the hints say the object lies in a `width` x `height` image,
    /// as `[x0, y0, x1, y1]` ([`roi_domain`] of the `roi`, else of the
    /// `outline`'s bounding box); `None` without either.
    pub fn hinted_domain(&self, width: u32, height: u32) -> Option<[f64; 4]> {
        let roi = self.roi.or_else(|| {
            let [x0, y0, x1, y1] = Polygon::new(self.outline.clone()?).bounds();
            let (x, y) = (x0.floor() as i64, y0.floor() as i64);
            Some([x, y, x1.ceil() as i64 + 1 - x, y1.ceil() as i64 + 1 - y])
        })?;
        roi_domain(roi, width, height)
    }

    /// Where a fit may move the outline of an object found with these
    /// hints in a `width` x `height` image: the [`Self::hinted_domain`],
    /// narrowed to the `roi`'s own box on the sides `cut_at_box` names
    /// (the region went on past the box there, so what lies beyond it is
    /// not the object the box frames).
    pub fn fit_domain(&self, width: u32, height: u32, cut_at_box: &[String]) -> Option<[f64; 4]> {
        let mut domain = self.hinted_domain(width, height)?;
        if let Some([x, y, w, h]) = self.roi {
            let edges = [x, y, x + w, y + h].map(|e| e as f64 - 0.5);
            for (k, side) in SIDES.iter().enumerate() {
                if cut_at_box.iter().any(|c| c == side) {
                    domain[k] = if k < 2 {
                        domain[k].max(edges[k])
                    } else {
                        domain[k].min(edges[k])
                    };
                }
            }
        }
        Some(domain)
    }

    /// `outline` (found in a `width` x `height` image) kept to the `roi`'s
    /// box on the sides `cut_at_box` names; as it is without any.
    pub fn held_at_cut(&self, outline: Polygon, width: u32, height: u32, cut_at_box: &[String]) -> Polygon {
        if cut_at_box.is_empty() {
            return outline;
        }
        match self.fit_domain(width, height, cut_at_box) {
            Some(b) => outline.clipped_to_box(b),
            None => outline,
        }
    }

    /// True when a hint names one region: a `roi`, a `point` or an
    /// `outline`.
    pub fn names_region(&self) -> bool {
        self.roi.is_some() || self.point.is_some() || self.outline.is_some()
    }
}

/// The names of a box's or the image's sides, in the order of the
/// `[bool; 4]` side sets and `[x0, y0, x1, y1]` boxes.
const SIDES: [&str; 4] = ["left", "top", "right", "bottom"];

/// The names of the sides (left, top, right, bottom) set in `sides`.
fn side_names(sides: [bool; 4]) -> Vec<String> {
    SIDES
        .iter()
        .zip(sides)
        .filter(|(_, on)| *on)
        .map(|(name, _)| name.to_string())
        .collect()
}

/// Where an object named by a `roi` `[x, y, w, h]` may lie in a
/// `width` x `height` image: the box grown by the slack the initialisation
/// gives a tight box, clipped to the image, as `[x0, y0, x1, y1]` in pixel
/// coordinates (pixel centres are integers). `None` without an overlap.
pub fn roi_domain([x, y, w, h]: [i64; 4], width: u32, height: u32) -> Option<[f64; 4]> {
    let slack = prompted::roi_slack(w as f64, h as f64);
    let x0 = (x as f64 - 0.5 - slack).max(-0.5);
    let y0 = (y as f64 - 0.5 - slack).max(-0.5);
    let x1 = ((x + w) as f64 - 0.5 + slack).min(width as f64 - 0.5);
    let y1 = ((y + h) as f64 - 0.5 + slack).min(height as f64 - 0.5);
    (x1 > x0 && y1 > y0).then_some([x0, y0, x1, y1])
}

/// Finds the object in `frame`. The paper's rule (steps 1-7 of the module
/// docs: the largest closed region in the size range) proposes it; the
/// scored candidates ([`prompted`]) replace it when one scores at least
/// twice as high (scratches or fibres joined to the outline, texture taken
/// for the object), when it misses a hint (outside the `roi`, not on the
/// `point`, the wrong `polarity`), or when the rule finds nothing (e.g. a
/// tool entering from the image border).
pub fn initialise(frame: &GrayFrame, params: &InitParams) -> Result<InitResult, InitError> {
    params.validate()?;
    // A drawn outline says where the object's edge is: it is not grown
    // over a rim beyond it, and it comes moved onto the edge already.
    if let Some(outline) = &params.outline {
        let hints = params.hints_for(frame.width, frame.height)?;
        return outlined::outlined(frame, params, &hints, outline);
    }
    let (found, stage) = find_object(frame, params)?;
    let found = grown_over_rim(frame, found);
    // The outline on the object's edge to a fraction of a pixel, where the
    // pipeline's thresholds left it 0.2-0.5 px outside (see [`edge_fit`]).
    let found = match fitted_to_edge(frame, &found.contour) {
        // No part of it moved past the box where it was cut.
        Some((contour, _)) => {
            let held = params.held_at_cut(contour, frame.width, frame.height, &found.cut_at_box);
            found.with_contour(held)
        }
        None => found,
    };
    let edge_support = stage.edge_support(&found.contour, [frame.width, frame.height]);
    Ok(InitResult {
        edge_support,
        ..found
    })
}

impl InitResult {
    /// The result with `contour` as its outline, and its area, box and
    /// centroid.
    pub fn with_contour(self, contour: Polygon) -> Self {
        InitResult {
            area_px: contour.area(),
            bbox: contour.bounds(),
            centroid: contour.centroid(),
            contour,
            ..self
        }
    }
}

/// A dark object's outline grown over its bright edge rim (see [`rim`]);
/// any other found object as it is.
fn grown_over_rim(frame: &GrayFrame, found: InitResult) -> InitResult {
    let dark = found.score.is_some_and(|s| s.contrast < 0.0);
    if !dark || !found.border.is_empty() {
        return found;
    }
    let reach = RIM_REACH_WORKING_PX * found.diagnostics.scale as f64;
    let spacings = [FreeFitParams::default().spacing_px, RIM_CORE_SPACING_PX];
    let Some([core, fine]) = fitted_cores(frame, &found.contour, spacings) else {
        return found;
    };
    let Some(grown) = rim::grow_over_rim(frame, &fine, reach, RIM_MIN_EXCESS) else {
        return found;
    };
    InitResult {
        rim_px: grown.mean_px,
        core: Some(core),
        ..found
    }
    .with_contour(grown.outline)
}

/// `contour` after the region-based active contour's free fit with the
/// default energy (Dahmen et al., section 3): the edge pipeline's outline
/// of a dark object carries spurs of substrate and runs out over its rim in
/// places, and the rim is measured from the region inside it, which is
/// what the fit settles on. One fit per vertex spacing in `spacings_px`,
/// on one table. `None` when the contour lies outside the image.
fn fitted_cores<const N: usize>(
    frame: &GrayFrame,
    contour: &Polygon,
    spacings_px: [f64; N],
) -> Option<[Polygon; N]> {
    let energy = EnergyParams::default();
    let sums = free_fit_tables(frame, contour, &energy)?;
    Some(spacings_px.map(|spacing_px| {
        let params = FreeFitParams {
            spacing_px,
            ..FreeFitParams::default()
        };
        fit_free(&sums, contour, &energy, &params).polygon
    }))
}

/// [`initialise`] up to the rim, with the edge stage it ran.
fn find_object(frame: &GrayFrame, params: &InitParams) -> Result<(InitResult, EdgeStage), InitError> {
    let hints = params.hints_for(frame.width, frame.height)?;
    let stage = edge_stage(frame, params, &hints)?;
    let found = chosen_region(frame, params, &hints, &stage)?;
    Ok((found, stage))
}

/// The region the paper's rule or a candidate makes the object.
fn chosen_region(
    frame: &GrayFrame,
    params: &InitParams,
    hints: &Hints,
    stage: &EdgeStage,
) -> Result<InitResult, InitError> {
    let found = |incumbent| prompted::find(frame, params, hints, stage, incumbent);
    let paper = match largest_region(params, stage) {
        Ok((mut paper, border, radius))
            if paper_fits_box(&paper, hints)
                && !params.exclude.iter().any(|&p| paper.contour.contains(p)) =>
        {
            return Ok(match found(Some((&border, radius))) {
                Ok(Outcome::Found(better)) => *better,
                Ok(Outcome::Stands { score, runners_up }) => {
                    paper.score = Some(score);
                    paper.diagnostics.runners_up = runners_up;
                    paper
                }
                // No candidate to challenge it: the paper's region stands,
                // unless it misses the point or the polarity too.
                Err(e) if !prompted::admits(frame, params, hints, stage, (&border, radius)) => {
                    return Err(hint_matches_nothing(hints, &paper, &e));
                }
                Err(_) => paper,
            });
        }
        other => other,
    };
    // The paper's rule found nothing, or nothing that fits the hints.
    let fallback = hints.given()
        || matches!(
            paper,
            Err(InitError::TouchesBorder { .. } | InitError::NothingInSizeRange { .. })
        );
    if !fallback {
        return paper.map(|(found, _, _)| found);
    }
    match (found(None), paper) {
        (Ok(Outcome::Found(candidate)), _) => Ok(*candidate),
        (Err(e), _) if hints.given() => Err(e),
        (_, Err(e)) => Err(e),
        (_, Ok(_)) => Err(InitError::NoPlausibleRegion {
            message: "the largest region lies outside the roi and no candidate fits the hints".into(),
        }),
    }
}

/// The error for a `point` or `polarity` hint that neither a candidate nor
/// the paper's region (`paper`) satisfies: it names the hints and what was
/// found instead (the paper's region, and why each candidate was turned
/// down, from `candidates`).
fn hint_matches_nothing(hints: &Hints, paper: &InitResult, candidates: &InitError) -> InitError {
    let mut hint = Vec::new();
    if let Some([x, y]) = hints.point {
        hint.push(format!("point ({x:.0}, {y:.0})"));
    }
    if hints.polarity != Polarity::Any {
        hint.push(format!("polarity {}", hints.polarity.name()));
    }
    if hints.has_exclude {
        hint.push("points that are not the object".into());
    }
    let [x0, y0, x1, y1] = paper.bbox;
    let [cx, cy] = paper.centroid;
    InitError::HintMatchesNothing {
        hint: hint.join(" and "),
        found: format!(
            "the largest region, centred at ({cx:.0}, {cy:.0}), {:.0} x {:.0} px, which the hints exclude; {candidates}",
            x1 - x0,
            y1 - y0
        ),
    }
}

/// Whether the paper's region lies in the `roi` (with the slack of a box
/// drawn tight around the object: 4% of its longer side, at least 2 px);
/// always without a roi. The paper's rule searches the roi's surroundings
/// too, for the background statistics.
fn paper_fits_box(found: &InitResult, hints: &Hints) -> bool {
    if !hints.has_roi {
        return true;
    }
    let [x, y, w, h] = hints.roi.map(f64::from);
    let slack = (0.04 * w.max(h)).max(2.0);
    let [x0, y0, x1, y1] = found.bbox;
    x0 >= x - 0.5 - slack && y0 >= y - 0.5 - slack && x1 <= x + w - 0.5 + slack && y1 <= y + h - 0.5 + slack
}

/// The paper's rule: the largest closed outline of the dilated edges whose
/// filled area lies in the size range, away from the image border; with its
/// border in working pixels and the dilation radius that closed it.
fn largest_region(
    params: &InitParams,
    stage: &EdgeStage,
) -> Result<(InitResult, Vec<[i32; 2]>, u8), InitError> {
    let EdgeStage {
        area: roi,
        scale,
        noise_work,
        sigma,
        low,
        high,
        ref edges,
        edge_pixels,
        ref radii,
        ..
    } = *stage;
    let (w, h) = edges.dimensions();
    let noise_full = noise_work * scale as f32;
    if edge_pixels == 0 {
        return Err(InitError::NoEdges { high_threshold: high });
    }

    let searched_area = roi[2] as f64 * roi[3] as f64;
    let min_area = params.min_area_px.unwrap_or(0.002 * searched_area);
    let max_area = params.max_area_px.unwrap_or(0.9 * searched_area);
    let px_per_work = (scale * scale) as f64;

    let mut last_error = None;
    for (k, &radius) in radii.iter().enumerate() {
        let regions = stage.regions(k);
        let candidates = regions.len();
        match select_object(
            regions,
            w,
            h,
            radius,
            min_area / px_per_work,
            max_area / px_per_work,
        ) {
            Ok(object) => {
                let contour = to_full_resolution(&object, scale, roi, params.contour_spacing_px);
                let centroid = contour.centroid();
                let result = InitResult {
                    area_px: contour.area(),
                    bbox: contour.bounds(),
                    centroid,
                    contour,
                    rim_px: 0.0,
                    edge_support: None,
                    core: None,
                    score: None,
                    source: Source::Edges {
                        dilation_radius: radius,
                    },
                    border: Vec::new(),
                    cut_at_box: Vec::new(),
                    diagnostics: InitDiagnostics {
                        scale,
                        noise_sigma: noise_full,
                        sigma,
                        low_threshold: low,
                        high_threshold: high,
                        dilation_radius: radius,
                        edge_pixels,
                        candidates,
                        runners_up: Vec::new(),
                    },
                };
                return Ok((result, object, radius));
            }
            Err(SelectError::Border(edge)) => last_error = Some(InitError::TouchesBorder { edge }),
            Err(SelectError::Size(largest)) => {
                // A touching-border verdict from a smaller radius is more
                // telling than "nothing in range" from a larger one.
                if !matches!(last_error, Some(InitError::TouchesBorder { .. })) {
                    last_error = Some(InitError::NothingInSizeRange {
                        min_area_px: min_area,
                        max_area_px: max_area,
                        largest_area_px: largest * px_per_work,
                    })
                }
            }
        }
    }
    Err(last_error.expect("at least one radius tried"))
}

/// The first half of [`initialise`]: the working copy and its edge map,
/// with the values chosen on the way.
pub(super) struct EdgeStage {
    /// Searched area `[x, y, w, h]` of the frame: the roi with some of its
    /// surroundings (for the background statistics), or the whole frame.
    pub(super) area: [u32; 4],
    /// Integer downsampling factor of the working copy.
    pub(super) scale: u32,
    /// The working copy (0..=1).
    pub(super) work: FloatImage,
    /// Estimated noise of the working copy.
    pub(super) noise_work: f32,
    /// Gaussian sigma used.
    pub(super) sigma: f32,
    /// The blurred working copy.
    pub(super) blurred: FloatImage,
    /// Canny thresholds used.
    pub(super) low: f32,
    pub(super) high: f32,
    /// Edge pixels (255) after hysteresis.
    pub(super) edges: GrayImage,
    /// How many edge pixels there are.
    pub(super) edge_pixels: usize,
    /// The dilation radii to try, in order (working pixels).
    pub(super) radii: Vec<u8>,
    /// The outer regions of the edges dilated by each radius, traced on
    /// first use: the paper's rule and the candidates share them.
    regions: Vec<OnceCell<Vec<Region>>>,
}

impl EdgeStage {
    /// The outer regions of the edges dilated by `radii[k]`, largest first.
    pub(super) fn regions(&self, k: usize) -> &[Region] {
        self.regions[k].get_or_init(|| outer_regions(&dilate_disk(&self.edges, self.radii[k])))
    }

    /// [`InitResult::edge_support`] of `contour` (full-resolution pixels)
    /// in a frame `[width, height]`: sampled once per working pixel of its
    /// length; `None` when it runs along the image border only.
    fn edge_support(&self, contour: &Polygon, [width, height]: [u32; 2]) -> Option<f64> {
        let reach = self.sigma.ceil() as u8 + 1;
        let near = dilate_disk(&self.edges, reach);
        let (w, h) = near.dimensions();
        let s = f64::from(self.scale);
        let [x0, y0, ..] = self.area.map(f64::from);
        let on_border = |[x, y]: [f64; 2]| {
            x < 0.5 || y < 0.5 || x > f64::from(width) - 1.5 || y > f64::from(height) - 1.5
        };
        let (mut samples, mut on_edge) = (0usize, 0usize);
        for &p in contour
            .resampled_every(s, 8)
            .points
            .iter()
            .filter(|&&p| !on_border(p))
        {
            samples += 1;
            let [wx, wy] = [((p[0] + 0.5 - x0) / s).floor(), ((p[1] + 0.5 - y0) / s).floor()];
            let inside = wx >= 0.0 && wy >= 0.0 && wx < f64::from(w) && wy < f64::from(h);
            if inside && near.get_pixel(wx as u32, wy as u32)[0] != 0 {
                on_edge += 1;
            }
        }
        (samples > 0).then(|| on_edge as f64 / samples as f64)
    }
}

/// A region of the dilated edges, filled and eroded back by the dilation
/// radius (working pixels).
pub(super) struct ErodedRegion {
    /// The eroded fill, its first pixel at `origin`.
    pub(super) eroded: GrayImage,
    pub(super) origin: [i32; 2],
    /// Outer border of its largest component, in working coordinates.
    pub(super) border: Vec<[i32; 2]>,
    /// Area of that component, working pixels.
    pub(super) area: f64,
    /// Whether it is a filled shape rather than an open outline: a closed
    /// outline fills to a region much thicker than the dilated edge line
    /// (about one pixel after erosion); an open one (a gap wider than the
    /// dilation closes, or an object cut by the frame edge) stays a line.
    pub(super) closed: bool,
}

/// The regions (largest first) filled and eroded by `radius`: at most eight,
/// none far below `min_area` (working pixels), which could not grow into
/// range; a few attempts bound the cost when many large regions are
/// rejected.
pub(super) fn eroded_regions(
    regions: &[Region],
    radius: u8,
    min_area: f64,
) -> impl Iterator<Item = ErodedRegion> + '_ {
    let min_thickness = radius as f64 + 1.0;
    regions
        .iter()
        .filter(move |r| r.approx_area >= min_area * 0.5)
        .take(8)
        .filter_map(move |region| {
            let (filled, x0, y0) = fill_region(&region.border);
            let eroded = erode_disk(&filled, radius);
            let (border, area) = largest_component_border(&eroded)?;
            let border = shifted(&border, [x0, y0]);
            // Mean thickness 2A/P (exact for long strips, r for a disc of radius r).
            let thickness = 2.0 * area / border.len().max(1) as f64;
            Some(ErodedRegion {
                eroded,
                origin: [x0, y0],
                border,
                area,
                closed: thickness >= min_thickness,
            })
        })
}

/// The area searched for an object with these hints: the roi grown by 30%
/// of its longer side (at least 16 px), clipped to the frame; the frame
/// without a roi.
fn searched_area(frame: &GrayFrame, hints: &Hints) -> [u32; 4] {
    if !hints.has_roi {
        return [0, 0, frame.width, frame.height];
    }
    let [x, y, w, h] = hints.roi;
    let grow = ((0.3 * w.max(h) as f64).ceil() as u32).max(16);
    let (x0, y0) = (x.saturating_sub(grow), y.saturating_sub(grow));
    let x1 = (x + w).saturating_add(grow).min(frame.width);
    let y1 = (y + h).saturating_add(grow).min(frame.height);
    [x0, y0, x1 - x0, y1 - y0]
}

/// Downsamples, blurs and runs Canny as [`initialise`] does.
fn edge_stage(frame: &GrayFrame, params: &InitParams, hints: &Hints) -> Result<EdgeStage, InitError> {
    let area = searched_area(frame, hints);
    let scale = params.working_scale(area[2], area[3]);
    let work = downsample(frame, area, scale);
    let (w, h) = work.dimensions();
    if w < 8 || h < 8 {
        return Err(InitError::InvalidParams(format!(
            "working image {w}x{h} is too small (expected at least 8x8: enlarge the roi or working_max_side)"
        )));
    }
    // Noise of the working copy (box averaging by `scale` divides white
    // noise by `scale`; reported at full resolution for comparability).
    let noise_work = estimate_noise(&work);
    let sigma = params
        .sigma
        .unwrap_or_else(|| (1.0 + 60.0 * noise_work).clamp(1.0, 3.0));
    let blurred = imageproc::filter::gaussian_blur_f32(&work, sigma);
    let gradient = Gradient::sobel(&blurred);
    let (auto_low, auto_high) = auto_thresholds(&gradient.magnitude, noise_work * sobel_noise_gain(sigma));
    let high = params.high_threshold.unwrap_or(auto_high);
    let low = params.low_threshold.unwrap_or(auto_low.min(high));
    let edges = hysteresis(&non_maximum_suppression(&gradient, low), w, h, low, high);
    let edge_pixels = edges.iter().filter(|&&p| p > 0).count();
    let auto_radius = auto_dilation_radius(w, h);
    let radii = match params.dilation_radius {
        Some(r) => vec![r],
        None => vec![auto_radius, auto_radius * 2],
    };
    Ok(EdgeStage {
        area,
        scale,
        work,
        noise_work,
        sigma,
        blurred,
        low,
        high,
        edges,
        edge_pixels,
        regions: radii.iter().map(|_| OnceCell::new()).collect(),
        radii,
    })
}

/// First dilation radius (working pixels) when none is given: about 1/150
/// of the working image's shorter side.
fn auto_dilation_radius(width: u32, height: u32) -> u8 {
    ((width.min(height) as f32 / 150.0).round() as u8).clamp(2, 6)
}

/// The intermediate images of [`initialise`] (working copy, blurred copy,
/// edges, edges dilated by the first radius tried) for diagnosis; empty when
/// the parameters are invalid.
pub fn debug_stages(frame: &GrayFrame, params: &InitParams) -> Vec<(&'static str, GrayImage)> {
    let Ok(stage) = params
        .hints_for(frame.width, frame.height)
        .and_then(|hints| edge_stage(frame, params, &hints))
    else {
        return Vec::new();
    };
    let (w, h) = stage.work.dimensions();
    let radius = params
        .dilation_radius
        .unwrap_or_else(|| auto_dilation_radius(w, h));
    let dilated = dilate_disk(&stage.edges, radius);
    let to8 = |img: &FloatImage| {
        GrayImage::from_fn(w, h, |x, y| {
            Luma([(img.get_pixel(x, y)[0] * 255.0).clamp(0.0, 255.0) as u8])
        })
    };
    vec![
        ("work", to8(&stage.work)),
        ("blurred", to8(&stage.blurred)),
        ("edges", stage.edges),
        ("dilated", dilated),
    ]
}

enum SelectError {
    /// Largest candidate's area (working pixels) when none is in range.
    Size(f64),
    /// The best candidate touches this border.
    Border(String),
}

/// Picks the largest region whose eroded area lies in `min..=max` (working
/// pixels), that is a filled shape rather than an open outline, and that does
/// not touch the image border; returns its eroded outer border.
fn select_object(
    regions: &[Region],
    width: u32,
    height: u32,
    radius: u8,
    min_area: f64,
    max_area: f64,
) -> Result<Vec<[i32; 2]>, SelectError> {
    let mut largest_seen = 0.0f64;
    let mut border_hit = None;
    for region in eroded_regions(regions, radius, min_area) {
        let touched = touched_border(&region.border, width, height);
        if !region.closed {
            if let Some(edge) = touched {
                border_hit.get_or_insert(edge);
            }
            continue;
        }
        largest_seen = largest_seen.max(region.area);
        if region.area < min_area || region.area > max_area {
            continue;
        }
        if let Some(edge) = touched {
            border_hit.get_or_insert(edge);
            continue;
        }
        return Ok(without_tails(&region.eroded, region.border, region.origin));
    }
    Err(match border_hit {
        Some(edge) => SelectError::Border(edge),
        None => SelectError::Size(largest_seen),
    })
}

/// Which border of the working image a region touches, if any: comes within
/// two pixels of it. Sobel gradients vanish on the outermost pixel ring, so an
/// object cut by the frame edge leaves its outline open about there.
fn touched_border(border: &[[i32; 2]], width: u32, height: u32) -> Option<String> {
    const MARGIN: i32 = 2;
    let (w, h) = (width as i32, height as i32);
    for p in border {
        if p[0] <= MARGIN {
            return Some("left".into());
        }
        if p[1] <= MARGIN {
            return Some("top".into());
        }
        if p[0] >= w - 1 - MARGIN {
            return Some("right".into());
        }
        if p[1] >= h - 1 - MARGIN {
            return Some("bottom".into());
        }
    }
    None
}

/// Maps a working-resolution border to a smooth full-resolution contour.
fn to_full_resolution(border: &[[i32; 2]], scale: u32, roi: [u32; 4], spacing: f64) -> Polygon {
    // Working pixel i covers full-resolution pixels i*s .. i*s+s-1, whose
    // centre is at i*s + (s-1)/2.
    let s = scale as f64;
    let offset = [roi[0] as f64 + (s - 1.0) / 2.0, roi[1] as f64 + (s - 1.0) / 2.0];
    let raw = Polygon::new(border.iter().map(|p| [p[0] as f64, p[1] as f64]).collect());
    // A traced border is a pixel staircase; a short moving average turns it
    // into a sub-pixel outline before resampling.
    let smooth = raw.moving_average(2);
    let full = smooth.scaled(s, offset);
    full.resampled_every(spacing, 8)
}

/// Box-averages the `roi` of a frame by an integer `factor`, normalised to
/// 0..=1. Partial blocks at the right and bottom edges are dropped.
pub fn downsample(frame: &GrayFrame, roi: [u32; 4], factor: u32) -> FloatImage {
    let f = factor.max(1) as usize;
    let (w, h) = (roi[2] as usize / f, roi[3] as usize / f);
    let norm = 1.0 / (frame.max_value() as f32 * (f * f) as f32);
    let mut out = vec![0.0f32; w * h];
    let mut acc = vec![0u32; w];
    for oy in 0..h {
        acc.fill(0);
        for dy in 0..f {
            let row = frame.row(roi[1] + (oy * f + dy) as u32);
            let row = &row[roi[0] as usize..roi[0] as usize + w * f];
            for (ox, block) in row.chunks_exact(f).enumerate() {
                acc[ox] += block.iter().map(|&v| v as u32).sum::<u32>();
            }
        }
        for (o, &a) in out[oy * w..(oy + 1) * w].iter_mut().zip(&acc) {
            *o = a as f32 * norm;
        }
    }
    FloatImage::from_raw(w as u32, h as u32, out).expect("length matches size")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::mask_iou;

    /// A frame with a bright disc (value `fg`) on a background `bg`.
    fn disc_frame(w: u32, h: u32, c: Point, r: f64, bg: u16, fg: u16) -> GrayFrame {
        let mut f = GrayFrame::filled(w, h, 8, bg);
        for y in 0..h {
            for x in 0..w {
                if ((x as f64 - c[0]).powi(2) + (y as f64 - c[1]).powi(2)).sqrt() < r {
                    f.data[(y * w + x) as usize] = fg;
                }
            }
        }
        f
    }

    #[test]
    fn size_thresholding_picks_largest_in_range() {
        // Two discs: radius 60 (area ~11300) and radius 25 (area ~1960).
        let mut f = disc_frame(400, 300, [120.0, 150.0], 60.0, 60, 180);
        let small = disc_frame(400, 300, [310.0, 150.0], 25.0, 60, 180);
        for (d, s) in f.data.iter_mut().zip(&small.data) {
            *d = (*d).max(*s);
        }
        let big = initialise(&f, &InitParams::default()).unwrap();
        assert!((big.centroid[0] - 120.0).abs() < 1.0, "{:?}", big.centroid);
        let only_small = InitParams {
            max_area_px: Some(5000.0),
            ..InitParams::default()
        };
        let r = initialise(&f, &only_small).unwrap();
        assert!((r.centroid[0] - 310.0).abs() < 1.0, "{:?}", r.centroid);
        let none = InitParams {
            min_area_px: Some(20000.0),
            ..InitParams::default()
        };
        assert!(matches!(
            initialise(&f, &none),
            Err(InitError::NothingInSizeRange { .. })
        ));
    }

    #[test]
    fn disc_is_found_and_hugged() {
        let f = disc_frame(320, 240, [150.3, 110.7], 50.0, 50, 170);
        let r = initialise(&f, &InitParams::default()).unwrap();
        assert!(
            (r.centroid[0] - 150.3).abs() < 0.5 && (r.centroid[1] - 110.7).abs() < 0.5,
            "{:?}",
            r.centroid
        );
        let truth = Polygon::circle([150.3, 110.7], 50.0, 720).rasterize(320, 240);
        let found = r.contour.rasterize(320, 240);
        let iou = mask_iou(&truth, &found);
        assert!(iou > 0.97, "IoU {iou}");
        assert!((r.area_px - std::f64::consts::PI * 2500.0).abs() < 0.04 * std::f64::consts::PI * 2500.0);
    }

    /// Two bright discs: radius 60 at (120, 150) and 25 at (310, 150).
    fn two_discs() -> GrayFrame {
        let mut f = disc_frame(400, 300, [120.0, 150.0], 60.0, 60, 180);
        let small = disc_frame(400, 300, [310.0, 150.0], 25.0, 60, 180);
        for (d, s) in f.data.iter_mut().zip(&small.data) {
            *d = (*d).max(*s);
        }
        f
    }

    #[test]
    fn an_outline_names_the_region_it_encloses_moved_onto_its_edge() {
        let f = two_discs();
        // Drawn loosely, 2 px outside the small disc's edge, with 12 clicks.
        let drawn = Polygon::circle([310.0, 150.0], 27.0, 12).points;
        let params = InitParams {
            outline: Some(drawn),
            ..InitParams::default()
        };
        let r = initialise(&f, &params).unwrap();
        assert_eq!(r.source, Source::Outline);
        assert!(r.border.is_empty(), "{:?}", r.border);
        assert!(r.score.is_some_and(|s| s.contrast > 0.2), "{:?}", r.score);
        let truth = Polygon::circle([310.0, 150.0], 25.0, 720).rasterize(400, 300);
        let iou = mask_iou(&truth, &r.contour.rasterize(400, 300));
        assert!(iou > 0.93, "IoU {iou}");
        // Of the opposite polarity it names nothing.
        let darker = InitParams {
            polarity: Polarity::Darker,
            ..params
        };
        let e = initialise(&f, &darker).unwrap_err();
        assert!(
            matches!(&e, InitError::HintMatchesNothing { found, .. } if found.contains("brighter")),
            "{e}"
        );
    }

    #[test]
    fn a_loose_lasso_shrinks_onto_the_object_it_encloses() {
        // A disc of radius 35 with a soft edge, and a square drawn round it
        // 5 px outside its sides and 21 px at its corners: beyond the edge
        // fit's reach, the region-based fit moves it onto the disc.
        let (w, h) = (200, 160);
        let data = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| {
                let r = (x as f64 - 90.0).hypot(y as f64 - 80.0);
                (60.0 + 120.0 / (1.0 + (r - 35.0).min(50.0).exp())) as u16
            })
            .collect();
        let f = GrayFrame::new(w, h, 8, data).unwrap();
        let params = InitParams {
            outline: Some(vec![[50.0, 40.0], [130.0, 40.0], [130.0, 120.0], [50.0, 120.0]]),
            ..InitParams::default()
        };
        let r = initialise(&f, &params).unwrap();
        let truth = Polygon::circle([90.0, 80.0], 35.0, 720).rasterize(w, h);
        let iou = mask_iou(&truth, &r.contour.rasterize(w, h));
        // The square as drawn: 0.60. Its corners, over flat background,
        // round off only under the length term (0.89 measured).
        assert!(iou > 0.85, "IoU {iou}, area {}", r.area_px);
    }

    #[test]
    fn an_outline_drawn_past_the_border_names_an_object_cut_by_it() {
        let f = disc_frame(200, 200, [10.0, 100.0], 50.0, 40, 200);
        let drawn = vec![[-30.0, 40.0], [70.0, 45.0], [70.0, 155.0], [-30.0, 160.0]];
        let params = InitParams {
            outline: Some(drawn),
            ..InitParams::default()
        };
        let r = initialise(&f, &params).unwrap();
        assert_eq!(r.border, vec!["left".to_string()]);
        assert!(
            r.contour.points.iter().all(|p| p[0] >= -0.5),
            "clipped to the image"
        );
    }

    #[test]
    fn a_point_names_the_part_of_a_region_an_edge_parts_off() {
        // A bright needle (grey 180) from the left border, its tip welded
        // to a mid-grey lamella (110, x 100..160) on a dark ground (40):
        // one threshold takes both, an edge runs between them.
        let (w, h) = (240u32, 160u32);
        let needle = |x: f64, y: f64| x < 100.0 && (y - 80.0).abs() < 8.0 + 0.2 * (100.0 - x);
        let lamella = |x: f64, y: f64| (100.0..160.0).contains(&x) && (62.0..98.0).contains(&y);
        let grey = |x: f64, y: f64| match (needle(x, y), lamella(x, y)) {
            (true, _) => 180,
            (_, true) => 110,
            _ => 40,
        };
        let data = (0..h)
            .flat_map(|y| (0..w).map(move |x| grey(x as f64, y as f64)))
            .collect();
        let f = GrayFrame::new(w, h, 8, data).unwrap();
        let truth = |inside: &dyn Fn(f64, f64) -> bool| -> Vec<bool> {
            (0..w * h)
                .map(|i| inside((i % w) as f64, (i / w) as f64))
                .collect()
        };
        for (point, object, name) in [
            ([50.0, 80.0], truth(&needle), "needle"),
            ([130.0, 80.0], truth(&lamella), "lamella"),
        ] {
            let params = InitParams {
                point: Some(point),
                ..InitParams::default()
            };
            let r = initialise(&f, &params).unwrap();
            let iou = mask_iou(&object, &r.contour.rasterize(w, h));
            assert!(iou > 0.9, "{name}: IoU {iou:.3}, box {:?}", r.bbox);
        }
    }

    #[test]
    fn a_point_that_is_not_the_object_turns_its_region_down() {
        let f = two_discs();
        let not_big = InitParams {
            exclude: vec![[120.0, 150.0]],
            ..InitParams::default()
        };
        let r = initialise(&f, &not_big).unwrap();
        assert!((r.centroid[0] - 310.0).abs() < 1.0, "{:?}", r.centroid);
        let neither = InitParams {
            exclude: vec![[120.0, 150.0], [310.0, 150.0]],
            ..InitParams::default()
        };
        let e = initialise(&f, &neither).unwrap_err();
        assert!(
            e.to_string().contains("cover a point that is not the object"),
            "{e}"
        );
    }

    #[test]
    fn the_share_of_an_outline_near_an_edge_is_measured() {
        let f = disc_frame(320, 240, [150.0, 110.0], 50.0, 50, 170);
        let params = InitParams::default();
        let hints = params.hints_for(320, 240).unwrap();
        let stage = edge_stage(&f, &params, &hints).unwrap();
        let support = |outline: Vec<Point>| stage.edge_support(&Polygon::new(outline), [320, 240]).unwrap();
        let on = support(Polygon::circle([150.0, 110.0], 50.0, 360).points);
        assert!(on >= 0.95, "the disc's own outline: {on:.2}");
        // A circle over the flat substrate beside it, 30 px from its edge.
        let off = support(Polygon::circle([260.0, 110.0], 30.0, 360).points);
        assert!(off <= 0.05, "over bare substrate: {off:.2}");
        // The disc's left half closed by its diameter: the arc (157 px) on
        // the edge, the diameter (100 px) across the flat inside.
        let half: Vec<Point> = (0..=180)
            .map(|k| {
                let a = std::f64::consts::FRAC_PI_2 + (k as f64).to_radians();
                [150.0 + 50.0 * a.cos(), 110.0 - 50.0 * a.sin()]
            })
            .collect();
        let share = support(half);
        assert!((0.5..=0.72).contains(&share), "half on the edge: {share:.2}");
        // Found by a point, the disc's outline follows its edge; a drawn
        // outline is its own evidence.
        let pointed = InitParams {
            point: Some([150.0, 110.0]),
            ..InitParams::default()
        };
        let found = initialise(&f, &pointed).unwrap().edge_support.unwrap();
        assert!(found >= 0.95, "found by a point: {found:.2}");
        let drawn = InitParams {
            outline: Some(Polygon::circle([150.0, 110.0], 53.0, 16).points),
            ..InitParams::default()
        };
        assert_eq!(initialise(&f, &drawn).unwrap().edge_support, None);
    }

    #[test]
    fn bad_outlines_and_exclusions_are_named() {
        let f = two_discs();
        let square = vec![[290.0, 130.0], [330.0, 130.0], [330.0, 170.0], [290.0, 170.0]];
        let cases: Vec<(InitParams, &str, &str)> = vec![
            (
                InitParams {
                    outline: Some(vec![[0.0, 0.0], [10.0, 0.0]]),
                    ..InitParams::default()
                },
                "outline",
                "2 vertices (expected 3..=4096)",
            ),
            (
                InitParams {
                    outline: Some(vec![[0.0, 0.0], [40.0, 40.0], [40.0, 0.0], [0.0, 40.0]]),
                    ..InitParams::default()
                },
                "outline",
                "crosses itself",
            ),
            (
                InitParams {
                    outline: Some(vec![[0.0, f64::NAN], [40.0, 0.0], [0.0, 40.0]]),
                    ..InitParams::default()
                },
                "outline",
                "vertex 0",
            ),
            (
                InitParams {
                    outline: Some(vec![[500.0, 0.0], [600.0, 0.0], [600.0, 100.0]]),
                    ..InitParams::default()
                },
                "outline",
                "encloses 0 px of the 400x300 image",
            ),
            (
                InitParams {
                    outline: Some(square.clone()),
                    point: Some([100.0, 100.0]),
                    ..InitParams::default()
                },
                "point",
                "outside the outline",
            ),
            (
                InitParams {
                    outline: Some(square),
                    exclude: vec![[310.0, 150.0]],
                    ..InitParams::default()
                },
                "exclude",
                "inside the outline",
            ),
            (
                InitParams {
                    exclude: vec![[-10.0, 5.0]],
                    ..InitParams::default()
                },
                "exclude",
                "outside the 400x300 image",
            ),
            (
                InitParams {
                    exclude: vec![[1.0, 1.0]; 65],
                    ..InitParams::default()
                },
                "exclude",
                "65 points (expected at most 64)",
            ),
        ];
        for (params, field, needle) in cases {
            match initialise(&f, &params) {
                Err(InitError::InvalidHint { field: f, message }) => {
                    assert_eq!(f, field, "{message}");
                    assert!(message.contains(needle), "{message} lacks {needle:?}");
                }
                other => panic!("{field} {needle:?}: {other:?}"),
            }
        }
    }

    #[test]
    fn blank_image_has_no_edges() {
        let f = GrayFrame::filled(100, 80, 8, 90);
        assert!(matches!(
            initialise(&f, &InitParams::default()),
            Err(InitError::NoEdges { .. })
        ));
    }

    #[test]
    fn an_object_cut_by_the_border_is_found_with_its_outline_on_the_border() {
        // The largest-region rule refuses it; the candidates find it.
        let f = disc_frame(200, 200, [10.0, 100.0], 50.0, 40, 200);
        let r = initialise(&f, &InitParams::default()).unwrap();
        assert_eq!(r.border, vec!["left".to_string()]);
        assert!(r.score.is_some(), "ranked by score: {:?}", r.source);
        let on_edge = r.contour.points.iter().filter(|p| p[0] == -0.5).count();
        assert!(on_edge >= 2, "{on_edge} vertices on the image edge");
        let truth = Polygon::circle([10.0, 100.0], 50.0, 720).rasterize(200, 200);
        let iou = mask_iou(&truth, &r.contour.rasterize(200, 200));
        assert!(iou > 0.95, "IoU {iou}");
    }

    #[test]
    fn roi_restricts_the_search() {
        let mut f = disc_frame(400, 300, [100.0, 150.0], 60.0, 60, 180);
        let other = disc_frame(400, 300, [300.0, 150.0], 40.0, 60, 180);
        for (d, s) in f.data.iter_mut().zip(&other.data) {
            *d = (*d).max(*s);
        }
        let params = InitParams {
            roi: Some([220, 50, 170, 200]),
            ..InitParams::default()
        };
        let r = initialise(&f, &params).unwrap();
        assert!(
            (r.centroid[0] - 300.0).abs() < 1.0 && (r.centroid[1] - 150.0).abs() < 1.0,
            "{:?}",
            r.centroid
        );
        let bad = InitParams {
            roi: Some([390, 0, 20, 20]),
            ..InitParams::default()
        };
        let e = initialise(&f, &bad).unwrap_err();
        assert!(
            matches!(&e, InitError::InvalidHint { field, message } if field == "roi" && message.contains("10x20")),
            "{e}"
        );
    }

    #[test]
    fn invalid_params_are_named() {
        let p = InitParams {
            sigma: Some(-1.0),
            ..InitParams::default()
        };
        let e = p.validate().unwrap_err().to_string();
        assert!(e.contains("sigma") && e.contains("expected"), "{e}");
    }

    #[test]
    fn downsample_averages_blocks() {
        // 4x2 is below GrayFrame::new's minimum size: build the frame directly.
        let f = GrayFrame {
            width: 4,
            height: 2,
            bit_depth: 8,
            data: vec![0, 255, 0, 0, 255, 255, 0, 255],
        };
        let d = downsample(&f, [0, 0, 4, 2], 2);
        assert_eq!(d.dimensions(), (2, 1));
        assert!((d.get_pixel(0, 0)[0] - 0.75).abs() < 1e-6);
        assert!((d.get_pixel(1, 0)[0] - 0.25).abs() < 1e-6);
    }
}

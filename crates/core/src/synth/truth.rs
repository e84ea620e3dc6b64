//! Ground truth of synthetic frames: the object's outline, centroid,
//! orientation and area in both images (also the part inside the frame, for
//! objects that cross an image border), height, disparity and occlusion.

use serde::{Deserialize, Serialize};

use super::config::BorderSide;
use crate::geometry::{Point, Polygon};
use crate::imageio::GrayFrame;

/// The object as it appears in one image.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ObjectTruth {
    /// Area centroid of `polygon` (pixels).
    pub centroid: Point,
    /// Principal-axis orientation of `polygon` (`Polygon::orientation`), in
    /// (-pi/2, pi/2]; ill-defined for the sphere.
    pub angle_rad: f64,
    /// Rigid rotation of the shape (unwrapped, clockwise on screen) since
    /// its reference pose; differences between frames are the true rotation
    /// also for the sphere.
    pub rotation_rad: f64,
    /// Dense outline of the full (unoccluded) object in pixel coordinates.
    pub polygon: Polygon,
    /// Area of `polygon` in square pixels.
    pub area_px: f64,
    /// `polygon` clipped to the image rectangle [-0.5, -0.5, w - 0.5,
    /// h - 0.5]: the part a tracker can see (equal to `polygon` when the
    /// object lies inside the frame). May have zero-width edges along the
    /// border where the outline leaves and re-enters the frame.
    pub visible_polygon: Polygon,
    /// Area centroid of `visible_polygon` (pixels): where a tracker of the
    /// visible part should put its centroid.
    pub visible_centroid: Point,
    /// Area of `visible_polygon` in square pixels.
    pub visible_area_px: f64,
    /// The image borders the full outline crosses (empty when the object is
    /// inside the frame), in the order left, top, right, bottom.
    pub border: Vec<BorderSide>,
}

impl ObjectTruth {
    /// Truth for an outline, taking it to lie inside the frame (the
    /// visible part is the whole polygon, no border is crossed).
    pub fn from_polygon(polygon: Polygon, rotation_rad: f64) -> Self {
        let centroid = polygon.centroid();
        let area_px = polygon.area();
        Self {
            centroid,
            angle_rad: polygon.orientation(),
            rotation_rad,
            area_px,
            visible_polygon: polygon.clone(),
            visible_centroid: centroid,
            visible_area_px: area_px,
            border: Vec::new(),
            polygon,
        }
    }

    /// Truth for an outline in a `width x height` image: centroid,
    /// orientation and area of the polygon and of its part inside the frame,
    /// and the borders it crosses.
    pub fn in_frame(polygon: Polygon, rotation_rad: f64, width: u32, height: u32) -> Self {
        let visible_polygon = clip_to_frame(&polygon, width, height);
        let visible_area_px = visible_polygon.area();
        let b = polygon.bounds();
        let (xmax, ymax) = (width as f64 - 0.5, height as f64 - 0.5);
        let border = [
            (b[0] < -0.5, BorderSide::Left),
            (b[1] < -0.5, BorderSide::Top),
            (b[2] > xmax, BorderSide::Right),
            (b[3] > ymax, BorderSide::Bottom),
        ]
        .into_iter()
        .filter_map(|(crossed, side)| crossed.then_some(side))
        .collect();
        let centroid = polygon.centroid();
        Self {
            centroid,
            angle_rad: polygon.orientation(),
            rotation_rad,
            area_px: polygon.area(),
            // An object entirely outside has no visible centroid: keep a
            // finite value (JSON has no NaN).
            visible_centroid: if visible_area_px > 1e-9 {
                visible_polygon.centroid()
            } else {
                centroid
            },
            visible_area_px,
            visible_polygon,
            border,
            polygon,
        }
    }

    /// Row-major mask of the pixels whose centres lie inside the object
    /// (only pixels of the `width x height` frame exist, so this is also
    /// the mask of `visible_polygon`).
    pub fn mask(&self, width: u32, height: u32) -> Vec<bool> {
        self.polygon.rasterize(width, height)
    }

    /// A `roi` hint `[x, y, width, height]` around the visible object: its
    /// bounding box grown by `grow` (e.g. 0.1) of its width and height on
    /// every side, as a person would draw it.
    pub fn roi_hint(&self, grow: f64) -> [i64; 4] {
        let [x0, y0, x1, y1] = self.visible_polygon.bounds();
        let (gx, gy) = (grow * (x1 - x0), grow * (y1 - y0));
        [
            (x0 - gx).floor() as i64,
            (y0 - gy).floor() as i64,
            (x1 - x0 + 2.0 * gx).ceil() as i64 + 1,
            (y1 - y0 + 2.0 * gy).ceil() as i64 + 1,
        ]
    }

    /// A `point` hint on the object in a `width` x `height` frame: the
    /// centre of its pixel nearest the visible centroid, as a person clicks
    /// it; `None` when no pixel centre lies inside it.
    pub fn point_hint(&self, width: u32, height: u32) -> Option<Point> {
        let mask = self.mask(width, height);
        let c = self.visible_centroid;
        let w = width as usize;
        (0..mask.len())
            .filter(|&i| mask[i])
            .map(|i| [(i % w) as f64, (i / w) as f64])
            .min_by(|a, b| {
                (a[0] - c[0])
                    .hypot(a[1] - c[1])
                    .total_cmp(&(b[0] - c[0]).hypot(b[1] - c[1]))
            })
    }

    /// Fraction of the object's area inside the frame (1 when it does not
    /// cross a border).
    pub fn visible_fraction(&self) -> f64 {
        if self.area_px > 0.0 {
            self.visible_area_px / self.area_px
        } else {
            0.0
        }
    }
}

/// `polygon` clipped to the image rectangle [-0.5, -0.5, w - 0.5, h - 0.5]
/// (Sutherland-Hodgman against its four sides: exact area for any simple
/// outline, since the rectangle is convex). Unchanged when inside.
pub fn clip_to_frame(polygon: &Polygon, width: u32, height: u32) -> Polygon {
    let (xmax, ymax) = (width as f64 - 0.5, height as f64 - 0.5);
    let b = polygon.bounds();
    if b[0] >= -0.5 && b[1] >= -0.5 && b[2] <= xmax && b[3] <= ymax {
        return polygon.clone();
    }
    polygon.clipped_to_box([-0.5, -0.5, xmax, ymax])
}

/// One tracked pair's errors against the truth less its sequence's median
/// errors: what is left once the constant offsets (the template's own
/// reference point, the disparity offset a calibration absorbs) are gone.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Deviation {
    /// Disparity error along x minus the sequence's median, pixels.
    pub disparity_px: f64,
    /// Left-centroid error minus the sequence's medians (x and y), pixels.
    pub centroid_px: Point,
}

impl Deviation {
    /// "Confident wrong" (issue #17): a pair reported tracked while its
    /// disparity is off by more than 1 px or its left centroid by more
    /// than 3 px, after the medians are removed.
    pub fn confident_wrong(&self) -> bool {
        self.disparity_px.abs() > 1.0 || self.centroid_px[0].hypot(self.centroid_px[1]) > 3.0
    }
}

/// The deviations of a sequence's tracked pairs: `disparity_errors[i]` and
/// `centroid_errors[i]` are pair i's errors against the truth (measured
/// minus true); each is taken less its median over the sequence (the
/// upper median of an even count).
pub fn deviations_from_medians(disparity_errors: &[f64], centroid_errors: &[Point]) -> Vec<Deviation> {
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(0.0)
    };
    let md = median(disparity_errors.to_vec());
    let mx = median(centroid_errors.iter().map(|c| c[0]).collect());
    let my = median(centroid_errors.iter().map(|c| c[1]).collect());
    disparity_errors
        .iter()
        .zip(centroid_errors)
        .map(|(e, c)| Deviation {
            disparity_px: e - md,
            centroid_px: [c[0] - mx, c[1] - my],
        })
        .collect()
}

/// The occluder of one frame (present from `Occlusion::enter_frame` on).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct OccluderTruth {
    /// Outline in the left image.
    pub left: Polygon,
    /// Outline in the right image.
    pub right: Polygon,
    /// Disparity of the occluder (right minus left), pixels.
    pub disparity_px: Point,
    /// Fraction of the object's area it hides in the left image.
    pub fraction_left: f64,
    /// Fraction of the object's area it hides in the right image.
    pub fraction_right: f64,
}

/// Ground truth of one stereo pair.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct FrameTruth {
    /// Frame index, from 0.
    pub frame: usize,
    /// Height of the object in micrometres.
    pub z_um: f64,
    /// Right centroid minus left centroid of the full object, pixels
    /// (y is always 0: the tilt axis is the image y axis).
    pub disparity_px: Point,
    /// Right minus left `visible_centroid`: what a tracker of the visible
    /// part measures; differs from `disparity_px` when the object crosses a
    /// border (the two images clip it differently).
    pub visible_disparity_px: Point,
    /// Disparity of the background (substrate), pixels.
    pub background_disparity_px: f64,
    /// The object in the left image.
    pub left: ObjectTruth,
    /// The object in the right image.
    pub right: ObjectTruth,
    /// Fraction of the object's area hidden by the occluder (left image; 0
    /// without occluder).
    pub occluded_fraction: f64,
    /// The same for the right image.
    pub occluded_fraction_right: f64,
    /// The occluder, when present in this frame.
    pub occluder: Option<OccluderTruth>,
}

/// One rendered stereo pair with its truth.
#[derive(Clone, Debug)]
pub struct SynthPair {
    /// Left (reference) image.
    pub left: GrayFrame,
    /// Right image.
    pub right: GrayFrame,
    /// What the images show.
    pub truth: FrameTruth,
}

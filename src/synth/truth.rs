//! Ground truth of synthetic frames: the object's outline, centroid,
//! orientation and area in both images, height, disparity and occlusion.

use serde::{Deserialize, Serialize};

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
}

impl ObjectTruth {
    /// Truth for an outline: centroid, orientation and area of the polygon.
    pub fn from_polygon(polygon: Polygon, rotation_rad: f64) -> Self {
        Self {
            centroid: polygon.centroid(),
            angle_rad: polygon.orientation(),
            rotation_rad,
            area_px: polygon.area(),
            polygon,
        }
    }

    /// Row-major mask of the pixels whose centres lie inside the object.
    pub fn mask(&self, width: u32, height: u32) -> Vec<bool> {
        self.polygon.rasterize(width, height)
    }
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

//! What a pair's measurement looks like on the wire and in storage: the
//! service's own types, made from the tracker's results.

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use semdepth_core::geometry::Point;
use semdepth_core::{calib, session, tracker};

/// Outcome of one pair.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    /// The object was found (or found afresh) and fitted on this pair.
    Initialised,
    /// Both contours followed the object.
    Tracked,
    /// No trustworthy measurement; `reason` says why.
    Lost,
}

impl Status {
    /// The snake_case name used in JSON and CSV.
    pub fn name(self) -> &'static str {
        match self {
            Status::Initialised => "initialised",
            Status::Tracked => "tracked",
            Status::Lost => "lost",
        }
    }
}

/// Where a session (or one of its objects) stands.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum SessionState {
    /// Its next pair initialises it (new, reset or re-initialised).
    #[default]
    AwaitingFirstPair,
    /// Its last pair was measured.
    Tracking,
    /// Its last pair was lost (of a session: any of its objects').
    Lost,
}

impl SessionState {
    /// The snake_case name used in JSON and in storage.
    pub fn name(self) -> &'static str {
        match self {
            Self::AwaitingFirstPair => "awaiting_first_pair",
            Self::Tracking => "tracking",
            Self::Lost => "lost",
        }
    }

    /// The state of this name, if any.
    pub fn from_name(name: &str) -> Option<Self> {
        [Self::AwaitingFirstPair, Self::Tracking, Self::Lost]
            .into_iter()
            .find(|s| s.name() == name)
    }
}

/// The contour in one image of a pair.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct ImageResult {
    /// Contour vertices `[x, y]`, pixels, to a thousandth of a pixel.
    #[schema(schema_with = contour_schema)]
    #[serde(serialize_with = "thousandths")]
    pub contour: Vec<Point>,
    /// Area centroid of the contour, pixels.
    #[schema(value_type = Vec<f64>, min_items = 2, max_items = 2)]
    pub centroid: Point,
    /// Orientation of the contour's principal axis, radians in (-pi/2, pi/2].
    pub angle_rad: f64,
    /// Energy of the contour (lower is better); null when it has no finite
    /// value (a contour that encloses no area, on a lost pair).
    pub energy: Option<f64>,
    /// Michelson contrast of inside against the background window, -1..=1
    /// (over the visible sectors when part of the outline is occluded).
    pub contrast: f64,
    /// Fraction of the outline found occluded, 0..=1.
    pub occluded_fraction: f64,
}

/// Writes vertices to a thousandth of a pixel: far below the tracking's
/// accuracy, and half the size of a record at full precision.
fn thousandths<S: serde::Serializer>(points: &[Point], s: S) -> Result<S::Ok, S::Error> {
    let round = |v: f64| (v * 1000.0).round() / 1000.0;
    s.collect_seq(points.iter().map(|p| [round(p[0]), round(p[1])]))
}

/// OpenAPI schema of [`ImageResult::contour`]: `[x, y]` pairs.
fn contour_schema() -> utoipa::openapi::schema::Array {
    use utoipa::openapi::schema::{ArrayBuilder, KnownFormat, ObjectBuilder, SchemaFormat, Type};
    let number = ObjectBuilder::new()
        .schema_type(Type::Number)
        .format(Some(SchemaFormat::KnownFormat(KnownFormat::Double)));
    ArrayBuilder::new()
        .items(
            ArrayBuilder::new()
                .items(number)
                .min_items(Some(2))
                .max_items(Some(2)),
        )
        .description(Some("Contour vertices `[x, y]`, pixels."))
        .build()
}

/// The measurement of one stereo pair.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct PairResult {
    /// Index of the pair in the sequence, from 0.
    pub frame: u64,
    /// What happened.
    pub status: Status,
    /// Why the pair is lost, or `reacquired` on a tracked pair whose object
    /// was found again by its template after a loss, or `found afresh where
    /// it was last seen, after a change of tone` on an initialised pair
    /// whose object was lost and then initialised afresh after the
    /// microscope changed its tone curve; null otherwise.
    pub reason: Option<String>,
    /// The left contour (null when nothing was found).
    pub left: Option<ImageResult>,
    /// The right contour.
    pub right: Option<ImageResult>,
    /// Right minus left centroid, pixels.
    #[schema(value_type = Option<Vec<f64>>, min_items = 2, max_items = 2)]
    pub disparity_px: Option<Point>,
    /// Component of the disparity across the tilt axis, pixels.
    pub disparity_axis_px: Option<f64>,
    /// `disparity_axis_px` minus its value on the session's first pair, pixels.
    pub relative_disparity_axis_px: Option<f64>,
    /// Rotation of the right contour minus that of the left, radians.
    pub angle_diff_rad: Option<f64>,
    /// Height from the calibration, micrometres; null without one.
    pub z_um: Option<f64>,
    /// Standard error of `disparity_axis_px`, pixels: the fits' own, scaled
    /// up once a run of pairs shows their disparities scatter more; null
    /// when the pair is not tracked.
    #[serde(default)]
    pub disparity_std_px: Option<f64>,
    /// Standard error of `z_um`, micrometres: `disparity_std_px` through the
    /// calibration's slope, and a fitted calibration's prediction error
    /// (unknown for a fit with as many samples as coefficients, which a
    /// warning then says); null without `z_um`.
    #[serde(default)]
    pub z_std_um: Option<f64>,
    /// What the two images' metadata say (pixel size, stage tilt and their
    /// difference); absent when neither carries any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub metadata: Option<PairMeta>,
    /// What in the images' metadata could not be read, contradicts the
    /// calibration, or leaves a tracked pair without z; absent when none.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
}

/// What a pair's two images say about how they were taken.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct PairMeta {
    /// The left image's.
    pub left: ViewMeta,
    /// The right image's.
    pub right: ViewMeta,
    /// Right stage tilt minus left, radians (null unless both are known).
    pub stage_tilt_difference_rad: Option<f64>,
}

/// One image's pixel size, stage tilt and beam.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct ViewMeta {
    /// Width of one pixel at the specimen, metres.
    pub pixel_width_m: Option<f64>,
    /// Height of one pixel at the specimen, metres.
    pub pixel_height_m: Option<f64>,
    /// Stage tilt, radians.
    pub stage_tilt_rad: Option<f64>,
    /// The beam that took the image (from FEI's `[Beam] Beam` or
    /// OpenFIBSEM's `beam_type`); null when the file does not say.
    #[serde(default)]
    pub beam: Option<Beam>,
}

/// The beam that took an image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Beam {
    /// The electron beam (SEM).
    Electron,
    /// The focused ion beam (FIB).
    Ion,
}

impl Beam {
    /// The wire name (`electron`, `ion`).
    pub fn name(self) -> &'static str {
        match self {
            Beam::Electron => "electron",
            Beam::Ion => "ion",
        }
    }
}

impl From<semdepth_core::meta::Beam> for Beam {
    fn from(b: semdepth_core::meta::Beam) -> Self {
        match b {
            semdepth_core::meta::Beam::Electron => Beam::Electron,
            semdepth_core::meta::Beam::Ion => Beam::Ion,
        }
    }
}

/// One object's measurement of a pair.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct ObjectResult {
    /// The object's name.
    pub name: String,
    /// Its measurement (status, contours, disparity, z and their errors).
    #[serde(flatten)]
    pub result: PairResult,
}

/// The height of one object relative to another on the same pair; null
/// numbers when either is not measured, and `dz_um` without a calibration.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct Relative {
    /// The object measured.
    pub from: String,
    /// The object it is measured against.
    pub to: String,
    /// `from`'s disparity across the tilt axis minus `to`'s, pixels.
    pub disparity_axis_px: Option<f64>,
    /// Standard error of `disparity_axis_px`, pixels.
    pub disparity_std_px: Option<f64>,
    /// `from`'s height minus `to`'s, micrometres.
    pub dz_um: Option<f64>,
    /// Standard error of `dz_um`, micrometres.
    pub dz_std_um: Option<f64>,
}

impl From<tracker::Status> for Status {
    fn from(s: tracker::Status) -> Self {
        match s {
            tracker::Status::Initialised => Self::Initialised,
            tracker::Status::Tracked => Self::Tracked,
            tracker::Status::Lost => Self::Lost,
        }
    }
}

impl From<tracker::ImageResult> for ImageResult {
    fn from(r: tracker::ImageResult) -> Self {
        Self {
            contour: r.contour,
            centroid: r.centroid,
            angle_rad: r.angle_rad,
            energy: r.energy.is_finite().then_some(r.energy),
            contrast: r.contrast,
            occluded_fraction: r.occluded_fraction,
        }
    }
}

impl From<tracker::PairResult> for PairResult {
    fn from(r: tracker::PairResult) -> Self {
        Self {
            frame: r.frame,
            status: r.status.into(),
            reason: r.reason,
            left: r.left.map(Into::into),
            right: r.right.map(Into::into),
            disparity_px: r.disparity_px,
            disparity_axis_px: r.disparity_axis_px,
            relative_disparity_axis_px: r.relative_disparity_axis_px,
            angle_diff_rad: r.angle_diff_rad,
            z_um: r.z_um,
            disparity_std_px: r.disparity_std_px,
            z_std_um: r.z_std_um,
            metadata: r.metadata.map(Into::into),
            warnings: r.warnings,
        }
    }
}

impl From<calib::PairMeta> for PairMeta {
    fn from(m: calib::PairMeta) -> Self {
        Self {
            left: m.left.into(),
            right: m.right.into(),
            stage_tilt_difference_rad: m.stage_tilt_difference_rad,
        }
    }
}

impl From<calib::ViewMeta> for ViewMeta {
    fn from(m: calib::ViewMeta) -> Self {
        Self {
            pixel_width_m: m.pixel_width_m,
            pixel_height_m: m.pixel_height_m,
            stage_tilt_rad: m.stage_tilt_rad,
            beam: m.beam.map(Beam::from),
        }
    }
}

impl From<session::ObjectResult> for ObjectResult {
    fn from(o: session::ObjectResult) -> Self {
        Self {
            name: o.name,
            result: o.result.into(),
        }
    }
}

impl From<session::Relative> for Relative {
    fn from(r: session::Relative) -> Self {
        Self {
            from: r.from,
            to: r.to,
            disparity_axis_px: r.disparity_axis_px,
            disparity_std_px: r.disparity_std_px,
            dz_um: r.dz_um,
            dz_std_um: r.dz_std_um,
        }
    }
}

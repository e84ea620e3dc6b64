//! The tracker's parameters as requests carry them and storage keeps them:
//! the service's own types, each field with its meaning, unit, default and
//! range. Defaults come from the algorithms' own types; ranges are checked
//! by them ([`semdepth_core::tracker::TrackerParams::validate`]).

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use semdepth_core::{energy, fit, init, occlusion, tracker};

/// Largest magnitude of a hint coordinate or size, pixels.
const MAX_HINT: i64 = init::MAX_HINT_COORDINATE;

/// The tracker's parameters; every field has a default.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(default, deny_unknown_fields)]
pub struct TrackerParams {
    /// Automatic initialisation on the first pair, and the hints that name
    /// the object.
    pub init: InitParams,
    /// The region energy.
    pub energy: EnergyParams,
    /// The free fit on the first left image.
    pub free: FreeFitParams,
    /// The rigid fits of every later pair.
    pub rigid: RigidParams,
    /// Detection of partial occlusion and the fit that leaves it out.
    pub occlusion: OcclusionParams,
    /// Direction of the beam's tilt axis in the image, degrees from +x
    /// towards +y; disparity is measured across it. -360..=360. Null or
    /// left out: the calibration's axis when there is one, else 90 (the
    /// image y axis: disparity along x). Given with a calibration, it must
    /// be the calibration's axis (else 400 `tilt_axis_conflict`).
    #[schema(minimum = -360.0, maximum = 360.0)]
    #[serde(default)]
    pub tilt_axis_deg: Option<f64>,
    /// How far the right view is searched from the left position on the
    /// first pair, pixels along the disparity axis. Default 64; 0..=4096.
    #[schema(minimum = 0.0, maximum = 4096.0)]
    pub max_disparity_px: f64,
    /// Vertex spacing of the rigid template, pixels; null (the default):
    /// the free fit's own outline is the template. 0.5..=20.
    #[schema(minimum = 0.5, maximum = 20.0)]
    pub template_spacing_px: Option<f64>,
    /// A pair is lost when the contrast in either image falls below this
    /// fraction of the contrast at initialisation. Default 0.3; 0..=1.
    #[schema(minimum = 0.0, maximum = 1.0)]
    pub min_contrast_ratio: f64,
    /// Let the right contour rotate apart from the left one (the paper
    /// does; `angle_diff_rad` is then measured). Default false: a tilt
    /// about an in-plane axis does not rotate the object in the image.
    pub right_rotation: bool,
    /// After the first pair, move the right contour only across the tilt
    /// axis from its prediction (along its epipolar line). Default true;
    /// set false when the stage drifts along the tilt axis between the two
    /// images of a pair.
    pub epipolar: bool,
    /// Gaussian smoothing (sigma, pixels) of both images before the fits;
    /// null (the default): chosen at initialisation from the object's edge
    /// width or bright rim, where the noise around it is white; 0: never.
    /// 0..=4.
    #[schema(minimum = 0.0, maximum = 4.0)]
    pub prefilter_sigma_px: Option<f64>,
    /// A pair whose fits' own disparity standard error exceeds this is
    /// `lost` with reason `uncertain`, without numbers, and tracking goes
    /// on; an object whose first pair already exceeded it is held to a
    /// limit grown from that pair's. Pixels; default 0.4; 0.01..=1000.
    #[schema(minimum = 0.01, maximum = 1000.0)]
    pub max_disparity_std_px: f64,
}

impl Default for TrackerParams {
    /// The algorithms' defaults, the tilt axis left to the calibration.
    fn default() -> Self {
        Self {
            tilt_axis_deg: None,
            ..tracker::TrackerParams::default().into()
        }
    }
}

/// Which way the object differs from its surroundings.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize, ToSchema, clap::ValueEnum,
)]
#[serde(rename_all = "snake_case")]
pub enum Polarity {
    /// Brighter than its surroundings (most particles and tools in SE images).
    Brighter,
    /// Darker than its surroundings.
    Darker,
    /// Either (the default).
    #[default]
    Any,
}

/// The automatic initialisation and the hints that name the object; null
/// numbers are derived from the image.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(default, deny_unknown_fields)]
pub struct InitParams {
    /// Longest side of the working copy, pixels (the image is box-averaged
    /// by an integer factor to fit). Default 640; 64..=8192.
    #[schema(minimum = 64, maximum = 8192)]
    pub working_max_side: u32,
    /// Gaussian standard deviation, working pixels; null (the default):
    /// from the estimated noise, 1 to 3. 0.3..=20.
    #[schema(minimum = 0.3, maximum = 20.0)]
    pub sigma: Option<f32>,
    /// Canny's lower threshold on the gradient magnitude (grey levels per
    /// pixel on the working image's 0..=1 scale); null (the default): from
    /// the image's gradient statistics. Above 0, at most 1.
    #[schema(exclusive_minimum = 0.0, maximum = 1.0)]
    pub low_threshold: Option<f32>,
    /// Canny's upper threshold, at least `low_threshold`; null (the
    /// default): from the image. Above 0, at most 1.
    #[schema(exclusive_minimum = 0.0, maximum = 1.0)]
    pub high_threshold: Option<f32>,
    /// Radius of the disk that closes gaps in the edges, working pixels;
    /// null (the default): about 1/150 of the working image's shorter side.
    /// 1..=32.
    #[schema(minimum = 1, maximum = 32)]
    pub dilation_radius: Option<u8>,
    /// Smallest accepted object area, pixels; null (the default): 0.2% of
    /// the searched area. At least 0.
    #[schema(minimum = 0.0)]
    pub min_area_px: Option<f64>,
    /// Largest accepted object area, pixels; null (the default): 90% of the
    /// searched area. At least `min_area_px`.
    #[schema(minimum = 0.0)]
    pub max_area_px: Option<f64>,
    /// Hint: the box `[x, y, width, height]` (pixels) the object lies in.
    #[schema(schema_with = roi_schema)]
    pub roi: Option<[i64; 4]>,
    /// Hint: a point `[x, y]` (pixels) on the object, as a person clicks
    /// it; inside the image (and inside `roi` when both are given).
    #[schema(value_type = Option<Vec<f64>>, min_items = 2, max_items = 2)]
    pub point: Option<[f64; 2]>,
    /// Hint: is the object brighter or darker than its surroundings?
    /// Default `any`.
    pub polarity: Polarity,
    /// Hint: the object's outline as a person drew it (a lasso): vertices
    /// `[x, y]` in pixels, 3 to 4096, not crossing itself, at least 256 px
    /// of it inside the image. The object is the region it encloses, moved
    /// onto the object's edges; a part drawn past the image border says the
    /// object crosses it there. A `point` must lie inside it.
    #[schema(value_type = Option<Vec<Vec<f64>>>, max_items = 4096, min_items = 3)]
    pub outline: Option<Vec<[f64; 2]>>,
    /// Hint: points `[x, y]` (pixels) on what is not the object ("not
    /// this"), at most 64, inside the image and outside the `outline`: no
    /// region that covers one is taken.
    #[schema(value_type = Vec<Vec<f64>>, max_items = 64)]
    pub exclude: Vec<[f64; 2]>,
    /// Vertex spacing of the initial outline, pixels. Default 2; 0.5..=50.
    #[schema(minimum = 0.5, maximum = 50.0)]
    pub contour_spacing_px: f64,
}

/// `values` as `[x, y]` pairs (an `outline`'s vertices, `exclude` points):
/// `None` unless an even count of at least `2 * least` numbers.
pub fn xy_pairs(values: &[f64], least: usize) -> Option<Vec<[f64; 2]>> {
    (values.len().is_multiple_of(2) && values.len() >= 2 * least)
        .then(|| values.chunks_exact(2).map(|c| [c[0], c[1]]).collect())
}

impl Default for InitParams {
    fn default() -> Self {
        init::InitParams::default().into()
    }
}

/// OpenAPI schema of [`InitParams::roi`]: null or four 64-bit integers.
pub(crate) fn roi_schema() -> utoipa::openapi::schema::Array {
    use utoipa::openapi::schema::{ArrayBuilder, KnownFormat, ObjectBuilder, SchemaFormat, SchemaType, Type};
    ArrayBuilder::new()
        .schema_type(SchemaType::from_iter([Type::Array, Type::Null]))
        .items(
            ObjectBuilder::new()
                .schema_type(Type::Integer)
                .format(Some(SchemaFormat::KnownFormat(KnownFormat::Int64)))
                .minimum(Some(-MAX_HINT))
                .maximum(Some(MAX_HINT)),
        )
        .min_items(Some(4))
        .max_items(Some(4))
        .description(Some(
            "Hint: the box `[x, y, width, height]` (pixels) the object lies in, clipped to the image \
             (it may run past the image border); width and height >= 16; it must overlap the image.",
        ))
        .build()
}

/// The region energy E = lambda L^k / A - D (method note, section 2).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(default, deny_unknown_fields)]
pub struct EnergyParams {
    /// Weight lambda of the internal (compactness) energy. Default 1; 0..=1000.
    #[schema(minimum = 0.0, maximum = 1000.0)]
    pub lambda: f64,
    /// Exponent k of the contour length in L^k / A. Default 2 (scale-free); 1..=3.
    #[schema(minimum = 1.0, maximum = 3.0)]
    pub k: f64,
    /// Margin by which the background window extends beyond the contour's
    /// bounding box, pixels; null (the default): 0.3 sqrt(area), at least
    /// 8. 1..=500.
    #[schema(minimum = 1.0, maximum = 500.0)]
    pub margin_px: Option<f64>,
    /// Take the whole image as the background region instead of a window
    /// (a full-frame sum per image; for diagnosis). Default false.
    pub whole_image_background: bool,
}

impl Default for EnergyParams {
    fn default() -> Self {
        energy::EnergyParams::default().into()
    }
}

/// The free fit: vertices move one by one along their normals while the
/// energy drops.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(default, deny_unknown_fields)]
pub struct FreeFitParams {
    /// Target spacing of the vertices, pixels (at least 40 vertices are
    /// kept); the fitted outline is the rigid template, so it also sets the
    /// cost of every later pair. Default 6; 1..=20.
    #[schema(minimum = 1.0, maximum = 20.0)]
    pub spacing_px: f64,
    /// First trial move along the normal, pixels. Default 1; at most 10.
    #[schema(exclusive_minimum = 0.0, maximum = 10.0)]
    pub initial_step_px: f64,
    /// Smallest trial move, pixels: when no vertex improves by it the fit
    /// has converged. Default 0.125; above 0, at most `initial_step_px`.
    #[schema(exclusive_minimum = 0.0, maximum = 10.0)]
    pub min_step_px: f64,
    /// Most sweeps over all vertices. Default 300; 1..=10000.
    #[schema(minimum = 1, maximum = 10000)]
    pub max_sweeps: usize,
    /// Resample to even spacing every this many sweeps. Default 4; at least 1.
    #[schema(minimum = 1)]
    pub resample_every: usize,
}

impl Default for FreeFitParams {
    fn default() -> Self {
        fit::FreeFitParams::default().into()
    }
}

/// The rigid fits (translation and rotation) of every later pair.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(default, deny_unknown_fields)]
pub struct RigidParams {
    /// Largest motion between two pairs the search is built to catch,
    /// pixels. Default 24; 1..=500.
    #[schema(minimum = 1.0, maximum = 500.0)]
    pub search_radius_px: f64,
    /// First step of the coarse stage, pixels (skipped when the occlusion
    /// sectors confirm the predicted pose). Default 8; 1..=100.
    #[schema(minimum = 1.0, maximum = 100.0)]
    pub coarse_step_px: f64,
    /// Vertices of the decimated contour of the coarse stage. Default 48; 8..=4096.
    #[schema(minimum = 8, maximum = 4096)]
    pub coarse_vertices: usize,
    /// Smallest step of the compass search, pixels (rotation: arc length
    /// at the outermost vertex); Newton steps refine below it. Default
    /// 0.125; above 0, at most 1.
    #[schema(exclusive_minimum = 0.0, maximum = 1.0)]
    pub min_step_px: f64,
    /// Search the rotation too (the paper does). Default true.
    pub rotate: bool,
    /// Most energy evaluations per fit. Default 3000; 10..=1000000.
    #[schema(minimum = 10, maximum = 1000000)]
    pub max_evaluations: usize,
}

impl Default for RigidParams {
    fn default() -> Self {
        fit::RigidParams::default().into()
    }
}

/// Detection of partial occlusion, per sector of the outline, and the fit
/// that leaves occluded sectors out.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(default, deny_unknown_fields)]
pub struct OcclusionParams {
    /// Look for occlusion at all. Default true.
    pub enabled: bool,
    /// Sectors along the contour. Default 24; 8..=256.
    #[schema(minimum = 8, maximum = 256)]
    pub sectors: usize,
    /// A sector counts as occluded when its contrast, against its first
    /// pair's and the median sector's, falls below this fraction. Default
    /// 0.35; 0 to below 1.
    #[schema(minimum = 0.0, exclusive_maximum = 1.0)]
    pub min_contrast_ratio: f64,
    /// ... or rises above this multiple (an occluder over the outer band
    /// only). Default 2; above 1, at most 100.
    #[schema(exclusive_minimum = 1.0, maximum = 100.0)]
    pub max_contrast_ratio: f64,
    /// Beyond this fraction of occluded sectors the pair is lost. Default
    /// 0.6; 0..=0.9.
    #[schema(minimum = 0.0, maximum = 0.9)]
    pub max_occluded_fraction: f64,
}

impl Default for OcclusionParams {
    fn default() -> Self {
        occlusion::OcclusionParams::default().into()
    }
}

impl From<tracker::TrackerParams> for TrackerParams {
    fn from(p: tracker::TrackerParams) -> Self {
        Self {
            init: p.init.into(),
            energy: p.energy.into(),
            free: p.free.into(),
            rigid: p.rigid.into(),
            occlusion: p.occlusion.into(),
            tilt_axis_deg: Some(p.tilt_axis_deg),
            max_disparity_px: p.max_disparity_px,
            template_spacing_px: p.template_spacing_px,
            min_contrast_ratio: p.min_contrast_ratio,
            right_rotation: p.right_rotation,
            epipolar: p.epipolar,
            prefilter_sigma_px: p.prefilter_sigma_px,
            max_disparity_std_px: p.max_disparity_std_px,
        }
    }
}

impl From<TrackerParams> for tracker::TrackerParams {
    fn from(p: TrackerParams) -> Self {
        Self {
            init: p.init.into(),
            energy: p.energy.into(),
            free: p.free.into(),
            rigid: p.rigid.into(),
            occlusion: p.occlusion.into(),
            tilt_axis_deg: p
                .tilt_axis_deg
                .unwrap_or(tracker::TrackerParams::default().tilt_axis_deg),
            max_disparity_px: p.max_disparity_px,
            template_spacing_px: p.template_spacing_px,
            min_contrast_ratio: p.min_contrast_ratio,
            right_rotation: p.right_rotation,
            epipolar: p.epipolar,
            prefilter_sigma_px: p.prefilter_sigma_px,
            max_disparity_std_px: p.max_disparity_std_px,
        }
    }
}

impl From<init::Polarity> for Polarity {
    fn from(p: init::Polarity) -> Self {
        match p {
            init::Polarity::Brighter => Self::Brighter,
            init::Polarity::Darker => Self::Darker,
            init::Polarity::Any => Self::Any,
        }
    }
}

impl From<Polarity> for init::Polarity {
    fn from(p: Polarity) -> Self {
        match p {
            Polarity::Brighter => Self::Brighter,
            Polarity::Darker => Self::Darker,
            Polarity::Any => Self::Any,
        }
    }
}

impl From<init::InitParams> for InitParams {
    fn from(p: init::InitParams) -> Self {
        Self {
            working_max_side: p.working_max_side,
            sigma: p.sigma,
            low_threshold: p.low_threshold,
            high_threshold: p.high_threshold,
            dilation_radius: p.dilation_radius,
            min_area_px: p.min_area_px,
            max_area_px: p.max_area_px,
            roi: p.roi,
            point: p.point,
            polarity: p.polarity.into(),
            outline: p.outline,
            exclude: p.exclude,
            contour_spacing_px: p.contour_spacing_px,
        }
    }
}

impl From<InitParams> for init::InitParams {
    fn from(p: InitParams) -> Self {
        Self {
            working_max_side: p.working_max_side,
            sigma: p.sigma,
            low_threshold: p.low_threshold,
            high_threshold: p.high_threshold,
            dilation_radius: p.dilation_radius,
            min_area_px: p.min_area_px,
            max_area_px: p.max_area_px,
            roi: p.roi,
            point: p.point,
            polarity: p.polarity.into(),
            outline: p.outline,
            exclude: p.exclude,
            contour_spacing_px: p.contour_spacing_px,
        }
    }
}

impl From<energy::EnergyParams> for EnergyParams {
    fn from(p: energy::EnergyParams) -> Self {
        Self {
            lambda: p.lambda,
            k: p.k,
            margin_px: p.margin_px,
            whole_image_background: p.whole_image_background,
        }
    }
}

impl From<EnergyParams> for energy::EnergyParams {
    fn from(p: EnergyParams) -> Self {
        Self {
            lambda: p.lambda,
            k: p.k,
            margin_px: p.margin_px,
            whole_image_background: p.whole_image_background,
        }
    }
}

impl From<fit::FreeFitParams> for FreeFitParams {
    fn from(p: fit::FreeFitParams) -> Self {
        Self {
            spacing_px: p.spacing_px,
            initial_step_px: p.initial_step_px,
            min_step_px: p.min_step_px,
            max_sweeps: p.max_sweeps,
            resample_every: p.resample_every,
        }
    }
}

impl From<FreeFitParams> for fit::FreeFitParams {
    fn from(p: FreeFitParams) -> Self {
        Self {
            spacing_px: p.spacing_px,
            initial_step_px: p.initial_step_px,
            min_step_px: p.min_step_px,
            max_sweeps: p.max_sweeps,
            resample_every: p.resample_every,
        }
    }
}

impl From<fit::RigidParams> for RigidParams {
    fn from(p: fit::RigidParams) -> Self {
        Self {
            search_radius_px: p.search_radius_px,
            coarse_step_px: p.coarse_step_px,
            coarse_vertices: p.coarse_vertices,
            min_step_px: p.min_step_px,
            rotate: p.rotate,
            max_evaluations: p.max_evaluations,
        }
    }
}

impl From<RigidParams> for fit::RigidParams {
    fn from(p: RigidParams) -> Self {
        Self {
            search_radius_px: p.search_radius_px,
            coarse_step_px: p.coarse_step_px,
            coarse_vertices: p.coarse_vertices,
            min_step_px: p.min_step_px,
            rotate: p.rotate,
            max_evaluations: p.max_evaluations,
        }
    }
}

impl From<occlusion::OcclusionParams> for OcclusionParams {
    fn from(p: occlusion::OcclusionParams) -> Self {
        Self {
            enabled: p.enabled,
            sectors: p.sectors,
            min_contrast_ratio: p.min_contrast_ratio,
            max_contrast_ratio: p.max_contrast_ratio,
            max_occluded_fraction: p.max_occluded_fraction,
        }
    }
}

impl From<OcclusionParams> for occlusion::OcclusionParams {
    fn from(p: OcclusionParams) -> Self {
        Self {
            enabled: p.enabled,
            sectors: p.sectors,
            min_contrast_ratio: p.min_contrast_ratio,
            max_contrast_ratio: p.max_contrast_ratio,
            max_occluded_fraction: p.max_occluded_fraction,
        }
    }
}

//! Configuration of the synthetic SEM stereo generator: shapes, motion,
//! stereo geometry, noise, clutter, occlusion, presets and validation.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::SynthError;

/// Smallest accepted image side in pixels.
pub const MIN_SIDE: u32 = 64;
/// Largest accepted image side in pixels (matches the decoder's default limit).
pub const MAX_SIDE: u32 = 8192;
/// Smallest accepted object size in pixels.
pub const MIN_OBJECT_PX: f64 = 12.0;
/// Margin kept between the object and every image border, as a fraction of
/// the object size.
pub const BORDER_MARGIN: f64 = 0.1;

/// The kind of object that is tracked.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Shape {
    /// Irregular rounded particle (radius modulated by low-order harmonics), like a quartz grain.
    #[default]
    Blob,
    /// Disc with spherical shading.
    Sphere,
    /// Tapered tool tip: a teardrop narrowing to a rounded point.
    Tip,
    /// Thin rod (capsule), width 0.12-0.2 of its length.
    Rod,
}

impl Shape {
    /// Every shape, in declaration order.
    pub const ALL: [Shape; 4] = [Shape::Blob, Shape::Sphere, Shape::Tip, Shape::Rod];

    /// The shape of this name ([`Self::name`]; `-` may stand for `_`).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|v| v.name() == name.replace('-', "_"))
    }

    /// The snake_case name used in JSON and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Shape::Blob => "blob",
            Shape::Sphere => "sphere",
            Shape::Tip => "tip",
            Shape::Rod => "rod",
        }
    }
}

/// An image border (the side an object enters from or crosses).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BorderSide {
    /// x = -0.5.
    Left,
    /// y = -0.5.
    Top,
    /// x = width - 0.5.
    Right,
    /// y = height - 0.5.
    Bottom,
}

impl BorderSide {
    /// Every side, in declaration order.
    pub const ALL: [BorderSide; 4] = [
        BorderSide::Left,
        BorderSide::Top,
        BorderSide::Right,
        BorderSide::Bottom,
    ];

    /// The snake_case name used in JSON.
    pub fn name(self) -> &'static str {
        match self {
            BorderSide::Left => "left",
            BorderSide::Top => "top",
            BorderSide::Right => "right",
            BorderSide::Bottom => "bottom",
        }
    }

    /// Unit normal of this border pointing into the image.
    pub fn inward_normal(self) -> [f64; 2] {
        match self {
            BorderSide::Left => [1.0, 0.0],
            BorderSide::Top => [0.0, 1.0],
            BorderSide::Right => [-1.0, 0.0],
            BorderSide::Bottom => [0.0, -1.0],
        }
    }
}

/// Named scene recipes; the seed varies motion, stereo and noise within each.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Preset {
    /// No noise, mild texture, no clutter, no occlusion, no flicker.
    #[default]
    Clean,
    /// Strong shot noise, read noise, scan-line jitter and line gain.
    Noisy,
    /// Background texture, 20+ small particles and a few scratches, moderate noise.
    Cluttered,
    /// 25% of the object hidden from frame 1 on by a second object in front, moderate noise.
    Occluded,
    /// +-20% grey-level gain/offset changes between images (charging), moderate noise.
    Flicker,
    /// A long tool entering from an image border (its base outside the
    /// frame), moving in and out along its axis, moderate noise.
    BorderTool,
    /// Long scratches and fibres on the substrate, several running under
    /// the object, moderate noise.
    Scratched,
    /// A dark object with a bright edge rim on a brighter substrate, moderate noise.
    Dark,
    /// Defocus blur (Gaussian sigma 1.5-2.5 px) at low dose.
    Blurred,
    /// A substrate with multi-scale relief texture (undulations, grains
    /// with bright boundaries, ridges, speckle), moderate noise.
    Relief,
    /// A bright or dark bar at its own height that slides in over up to a
    /// third of the object's area and out again, on its own (see
    /// [`Occlusion::sweep_frames`]), moderate noise.
    Crossing,
    /// The object moves 15-20 px between pairs, reflected at the frame's
    /// margins (a reversal is a 30-40 px miss of a constant-velocity
    /// prediction), moderate noise.
    Fast,
    /// `noisy`'s strong noise, `occluded`'s occluder and `flicker`'s
    /// grey-level changes together.
    Combined,
}

impl Preset {
    /// Every preset, in declaration order.
    pub const ALL: [Preset; 13] = [
        Preset::Clean,
        Preset::Noisy,
        Preset::Cluttered,
        Preset::Occluded,
        Preset::Flicker,
        Preset::BorderTool,
        Preset::Scratched,
        Preset::Dark,
        Preset::Blurred,
        Preset::Relief,
        Preset::Crossing,
        Preset::Fast,
        Preset::Combined,
    ];

    /// The original five presets: a bright object fully inside the frame
    /// (with margin) on a smooth substrate, the scenes initialisation and
    /// tracker were developed on.
    pub const BASIC: [Preset; 5] = [
        Preset::Clean,
        Preset::Noisy,
        Preset::Cluttered,
        Preset::Occluded,
        Preset::Flicker,
    ];

    /// The scene classes unlike the basic ones (border-crossing tool,
    /// scratches and fibres under the object, dark object, defocus blur,
    /// relief substrate), each a test of robustness.
    pub const HARD: [Preset; 5] = [
        Preset::BorderTool,
        Preset::Scratched,
        Preset::Dark,
        Preset::Blurred,
        Preset::Relief,
    ];

    /// The tracker's hard conditions (an occluder moving on its own, 15-20
    /// px between pairs, strong noise with occlusion and flicker): the
    /// object is visible in every pair.
    pub const TRACKING: [Preset; 3] = [Preset::Crossing, Preset::Fast, Preset::Combined];

    /// The preset of this name ([`Self::name`]; `-` may stand for `_`).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|v| v.name() == name.replace('-', "_"))
    }

    /// The snake_case name used in JSON and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Preset::Clean => "clean",
            Preset::Noisy => "noisy",
            Preset::Cluttered => "cluttered",
            Preset::Occluded => "occluded",
            Preset::Flicker => "flicker",
            Preset::BorderTool => "border_tool",
            Preset::Scratched => "scratched",
            Preset::Dark => "dark",
            Preset::Blurred => "blurred",
            Preset::Relief => "relief",
            Preset::Crossing => "crossing",
            Preset::Fast => "fast",
            Preset::Combined => "combined",
        }
    }
}

/// How the object's height z evolves over the frames. Every pattern is folded
/// (reflected) back into [`Motion::z_range_um`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ZPattern {
    /// z stays at `z_start_um`.
    Constant,
    /// Staircase: z jumps by `z_step_um` every `z_hold_frames` frames.
    #[default]
    Steps,
    /// z changes by `z_step_um` every frame.
    Ramp,
    /// Random walk: every frame z changes by a uniform amount in [-z_step_um, z_step_um].
    RandomWalk,
}

/// Rigid motion of the object over the sequence (left image coordinates).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Motion {
    /// Drift of the centroid per frame in pixels; reflected at the borders of
    /// the region where the object stays inside the frame with margin.
    pub drift_px_per_frame: [f64; 2],
    /// Rotation per frame in radians (clockwise on screen).
    pub rotation_rad_per_frame: f64,
    /// How z evolves.
    pub z_pattern: ZPattern,
    /// Size of one z change in micrometres.
    pub z_step_um: f64,
    /// Frames per stair of [`ZPattern::Steps`] (>= 1).
    pub z_hold_frames: usize,
    /// Height at frame 0 in micrometres.
    pub z_start_um: f64,
    /// Range [min, max] that z stays in, micrometres.
    pub z_range_um: [f64; 2],
    /// Left-image centroid at frame 0; `None` picks one from the seed.
    pub start_px: Option<[f64; 2]>,
    /// Rotation of the shape at frame 0; `None` picks one from the seed.
    pub start_angle_rad: Option<f64>,
}

impl Default for Motion {
    fn default() -> Self {
        Self {
            drift_px_per_frame: [1.0, 0.5],
            rotation_rad_per_frame: 0.002,
            z_pattern: ZPattern::Steps,
            z_step_um: 40.0,
            z_hold_frames: 2,
            z_start_um: 0.0,
            z_range_um: [-150.0, 150.0],
            start_px: None,
            start_angle_rad: None,
        }
    }
}

/// Stereo geometry: the right image shows a point at height z shifted along
/// x by `offset_px + px_per_um * z` (the tilt axis is the image y axis).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Disparity {
    /// Disparity gain in pixels per micrometre of height.
    pub px_per_um: f64,
    /// Disparity at z = 0 (the unknown constant), pixels.
    pub offset_px: f64,
    /// Height of the substrate (background), micrometres.
    pub background_z_um: f64,
}

impl Default for Disparity {
    fn default() -> Self {
        Self {
            px_per_um: 0.01,
            offset_px: 3.0,
            background_z_um: -250.0,
        }
    }
}

impl Disparity {
    /// Disparity in pixels of a point at height `z_um`.
    pub fn at(&self, z_um: f64) -> f64 {
        self.offset_px + self.px_per_um * z_um
    }
}

/// Detector and scan noise. Intensities are fractions of full scale.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Noise {
    /// Electrons per pixel at full-scale intensity 1.0: a pixel of intensity
    /// I becomes Poisson(dose * I) / dose. `None`: no shot noise.
    pub dose: Option<f64>,
    /// Standard deviation of additive Gaussian read noise (fraction of full scale).
    pub read_noise: f64,
    /// Standard deviation of the per-scan-line horizontal shift in pixels.
    pub line_jitter_px: f64,
    /// Standard deviation of the per-scan-line relative gain.
    pub line_gain: f64,
}

/// Things in the background that are not the object.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Clutter {
    /// Number of small particles (each at most 4% of the object's area).
    pub particles: usize,
    /// Number of thin straight scratches.
    pub scratches: usize,
    /// Amplitude of the smooth background texture (fraction of full scale).
    pub texture_amplitude: f64,
}

impl Default for Clutter {
    fn default() -> Self {
        Self {
            particles: 0,
            scratches: 0,
            texture_amplitude: 0.02,
        }
    }
}

/// A second object in front of the tracked one (think of a gripper jaw): it
/// sits `z_offset_um` higher (so its disparity differs) and is absent before
/// `enter_frame`. With `sweep_frames` 0 it moves rigidly with the object in
/// the left image and hides `fraction` of the object's area there from
/// `enter_frame` on; otherwise it also slides in and out on its own.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Occlusion {
    /// Fraction of the object's area hidden in the left image (0 < f < 0.9).
    pub fraction: f64,
    /// First frame in which the occluder is present (>= 1).
    pub enter_frame: usize,
    /// Height of the occluder above the object, micrometres.
    pub z_offset_um: f64,
    /// Grey level of the occluder (fraction of full scale).
    pub brightness: f64,
    /// Direction (object coordinates) from which the occluder covers the
    /// object; `None` picks one from the seed.
    pub cut_angle_rad: Option<f64>,
    /// 0: the occluder keeps its place on the object. N > 0: it moves on its
    /// own along the cut direction, from just touching the object at
    /// `enter_frame` to hiding `fraction` of its area N frames later and back
    /// out again (a triangle wave of period 2N frames).
    pub sweep_frames: usize,
}

impl Default for Occlusion {
    fn default() -> Self {
        Self {
            fraction: 0.25,
            enter_frame: 1,
            z_offset_um: 150.0,
            brightness: 0.85,
            cut_angle_rad: None,
            sweep_frames: 0,
        }
    }
}

/// The object enters the frame from an image border, like a manipulator
/// tool whose base is outside the field of view. The object is oriented
/// with its +x end (the tip of [`Shape::Tip`]) pointing into the image along
/// the border's inward normal turned by `angle_rad`, and moves along that
/// axis; `motion.drift_px_per_frame`, `motion.start_px` and
/// `motion.start_angle_rad` are not used (rotation per frame and heights are).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BorderEntry {
    /// The border the object crosses; `None` picks one from the seed.
    pub side: Option<BorderSide>,
    /// Angle between the object's axis and the border's inward normal,
    /// radians (|angle| <= 1.0); `None` picks one in +-0.52 (30 degrees).
    pub angle_rad: Option<f64>,
    /// Movement along the axis per frame, pixels (positive: further in
    /// first), reflected at the ends of the range where every constraint
    /// below holds.
    pub insertion_px_per_frame: f64,
    /// Smallest fraction of the object's area inside the frame, in every
    /// frame and both images (0.05..=0.95).
    pub min_visible_fraction: f64,
    /// Smallest distance by which the outline reaches past the border, in
    /// every frame and both images, pixels (0.5..=1000): the object always
    /// crosses the border.
    pub min_outside_px: f64,
    /// Scale of the outline across its axis (0.1..=1): below 1 the tool is
    /// more slender than the shape's usual proportions (a needle).
    pub width_scale: f64,
}

impl Default for BorderEntry {
    fn default() -> Self {
        Self {
            side: None,
            angle_rad: None,
            insertion_px_per_frame: 10.0,
            min_visible_fraction: 0.45,
            min_outside_px: 4.0,
            width_scale: 1.0,
        }
    }
}

/// Long thin lines on the substrate: straight scratches and curved fibres,
/// brighter or darker than the substrate. They are static (they move with
/// the background's disparity) and the object is painted over them.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Fibres {
    /// Lines placed anywhere on the substrate.
    pub count: usize,
    /// Further lines that cross the object's outline at frame 0 (each runs
    /// through a point inside the object and leaves it on both sides).
    pub under_object: usize,
    /// Range [min, max] of the line widths, pixels (0.5..=20).
    pub width_px: [f64; 2],
    /// Range [min, max] of the grey-level change of a line (magnitude,
    /// fraction of full scale, 0..=1).
    pub contrast: [f64; 2],
    /// Probability that a line is darker than the substrate (0..=1).
    pub dark_fraction: f64,
    /// Probability that a line is a curved fibre rather than a straight
    /// scratch (0..=1).
    pub curved_fraction: f64,
}

impl Default for Fibres {
    fn default() -> Self {
        Self {
            count: 5,
            under_object: 3,
            width_px: [1.0, 4.0],
            contrast: [0.06, 0.2],
            dark_fraction: 0.5,
            curved_fraction: 0.4,
        }
    }
}

/// Multi-scale relief of the substrate, as on a milled or sputtered
/// surface in a FIB-SEM: large brightness undulations, grains whose tilted
/// flanks and boundaries light up (SEM topographic and edge contrast),
/// streaky ridges and fine speckle. Added to the smooth texture of
/// [`Clutter`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Relief {
    /// Amplitude of the large-scale brightness undulations (fraction of
    /// full scale, 0..=1).
    pub undulation: f64,
    /// Lattice spacing of the undulations, pixels (4..=100000).
    pub undulation_scale_px: f64,
    /// Mean grain diameter, pixels (3..=10000).
    pub grain_px: f64,
    /// Brightness of the grains' topographic contrast: flanks, shadowing
    /// and bright boundaries (fraction of full scale, 0..=1).
    pub grain_contrast: f64,
    /// Amplitude of the ridges (streaks along `ridge_angle_rad`, fraction
    /// of full scale, 0..=1).
    pub ridges: f64,
    /// Direction of the ridges, radians (-10..=10; pi/2: vertical, like
    /// FIB curtaining).
    pub ridge_angle_rad: f64,
    /// Amplitude of the fine speckle (fraction of full scale, 0..=1).
    pub speckle: f64,
}

impl Default for Relief {
    fn default() -> Self {
        Self {
            undulation: 0.06,
            undulation_scale_px: 160.0,
            grain_px: 16.0,
            grain_contrast: 0.15,
            ridges: 0.05,
            ridge_angle_rad: std::f64::consts::FRAC_PI_2,
            speckle: 0.03,
        }
    }
}

/// Everything that defines a synthetic sequence. Together with the seed it
/// determines every pixel: the same config renders the same bytes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SynthConfig {
    /// Image width in pixels (>= 64).
    pub width: u32,
    /// Image height in pixels (>= 64).
    pub height: u32,
    /// Number of stereo pairs (>= 1).
    pub frames: usize,
    /// Seed of every random choice (shape, placement, textures, noise).
    pub seed: u64,
    /// The tracked object's shape.
    pub shape: Shape,
    /// Characteristic diameter / length of the object in pixels;
    /// `None`: 0.3 * min(width, height).
    pub object_size_px: Option<f64>,
    /// 8 (PNG output) or 16 (TIFF output).
    pub bit_depth: u8,
    /// Rigid motion and height changes.
    pub motion: Motion,
    /// Stereo geometry.
    pub disparity: Disparity,
    /// Detector and scan noise.
    pub noise: Noise,
    /// Relative amplitude of per-image gain changes (charging); the offset
    /// changes by up to `0.1 * flicker` of full scale. 0.2 means +-20% gain.
    pub flicker: f64,
    /// Background particles, scratches and texture.
    pub clutter: Clutter,
    /// Optional occluder entering after frame 0.
    pub occlusion: Option<Occlusion>,
    /// Mean grey level of the background (fraction of full scale).
    pub background_level: f64,
    /// Total grey-level change of the background gradient across the frame.
    pub background_gradient: f64,
    /// Object grey level minus background level.
    pub object_contrast: f64,
    /// Extra brightness of the SEM edge effect just inside the outline.
    pub rim_strength: f64,
    /// Decay length of the rim in pixels (intensity ~ exp(-dist / width)).
    pub rim_width_px: f64,
    /// Amplitude of the smooth texture inside the object (moves with it).
    pub object_texture: f64,
    /// Amplitude of the detector-side shading across the object (the
    /// sphere also gets a centre-bright spherical term).
    pub shading: f64,
    /// The object crosses an image border (a tool entering the frame);
    /// `None`: it stays inside with margin.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub border_entry: Option<BorderEntry>,
    /// Long scratches and fibres on the substrate, some under the object.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fibres: Option<Fibres>,
    /// Standard deviation of the Gaussian defocus blur applied to the
    /// rendered scene before noise, pixels (0: sharp, up to 20).
    #[serde(skip_serializing_if = "is_zero")]
    pub blur_sigma_px: f64,
    /// Multi-scale relief texture of the substrate.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub relief: Option<Relief>,
}

/// For `skip_serializing_if`: fields at their default 0 are left out, so
/// configs of the basic presets serialise as before.
fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

impl Default for SynthConfig {
    fn default() -> Self {
        Self {
            width: 640,
            height: 480,
            frames: 10,
            seed: 0,
            shape: Shape::Blob,
            object_size_px: None,
            bit_depth: 8,
            motion: Motion::default(),
            disparity: Disparity::default(),
            noise: Noise::default(),
            flicker: 0.0,
            clutter: Clutter::default(),
            occlusion: None,
            background_level: 0.27,
            background_gradient: 0.05,
            object_contrast: 0.33,
            rim_strength: 0.15,
            rim_width_px: 2.0,
            object_texture: 0.03,
            shading: 0.08,
            border_entry: None,
            fibres: None,
            blur_sigma_px: 0.0,
            relief: None,
        }
    }
}

/// Rounds to 9 decimals so that the value survives a JSON round trip
/// exactly (serde_json parses such short decimals without rounding error).
fn q(x: f64) -> f64 {
    (x * 1e9).round() / 1e9
}

/// "Moderate" noise shared by the cluttered, occluded and flicker presets.
fn moderate_noise(rng: &mut ChaCha8Rng) -> Noise {
    Noise {
        dose: Some(q(rng.gen_range(60.0..120.0))),
        read_noise: 0.01,
        line_jitter_px: 0.1,
        line_gain: 0.01,
    }
}

/// "Strong" noise of the noisy and combined presets: 8-15 electrons at the
/// object's grey level, read noise, scan-line jitter and gain.
fn strong_noise(cfg: &SynthConfig, rng: &mut ChaCha8Rng) -> Noise {
    let object_level = cfg.background_level + cfg.object_contrast;
    Noise {
        dose: Some(q(rng.gen_range(8.0..15.0) / object_level)),
        read_noise: 0.02,
        line_jitter_px: q(rng.gen_range(0.2..0.4)),
        line_gain: 0.03,
    }
}

/// The occluder of the occluded and combined presets: dark in 30% of the
/// seeds, otherwise bright, 1-3 px of disparity above the object, hiding a
/// quarter of it.
fn quarter_occluder(cfg: &SynthConfig, rng: &mut ChaCha8Rng) -> Occlusion {
    let dark = rng.gen_bool(0.3);
    Occlusion {
        brightness: if dark { 0.1 } else { q(rng.gen_range(0.75..0.9)) },
        z_offset_um: q(rng.gen_range(1.0..3.0) / cfg.disparity.px_per_um),
        ..Occlusion::default()
    }
}

/// Seed-dependent motion and stereo geometry for a 640x480-like frame.
fn random_motion(rng: &mut ChaCha8Rng) -> (Motion, Disparity) {
    let dir = rng.gen_range(0.0..std::f64::consts::TAU);
    let speed = rng.gen_range(0.5..3.0);
    let px_per_um = q(rng.gen_range(0.005..0.03));
    // Disparity change per z step: 0.1 .. 2 px.
    let step_px = rng.gen_range(0.1..2.0);
    // Half-range of disparity over the sequence: 1.5 .. 6 px.
    let range_px: f64 = rng.gen_range(1.5f64..6.0).max(step_px * 1.5);
    let z_half = q(range_px / px_per_um);
    let z_pattern = match rng.gen_range(0..3) {
        0 => ZPattern::Steps,
        1 => ZPattern::Ramp,
        _ => ZPattern::RandomWalk,
    };
    let motion = Motion {
        drift_px_per_frame: [q(speed * dir.cos()), q(speed * dir.sin())],
        rotation_rad_per_frame: q(rng.gen_range(-0.01..0.01)),
        z_pattern,
        z_step_um: q(step_px / px_per_um),
        z_hold_frames: rng.gen_range(1..4),
        z_start_um: q(rng.gen_range(-0.5..0.5) * z_half),
        z_range_um: [-z_half, z_half],
        start_px: None,
        start_angle_rad: None,
    };
    let disparity = Disparity {
        px_per_um,
        offset_px: q(rng.gen_range(-8.0..8.0)),
        background_z_um: q(-z_half - rng.gen_range(50.0..150.0)),
    };
    (motion, disparity)
}

impl SynthConfig {
    /// A 640x480, 10-frame, 8-bit sequence of the given recipe. The seed
    /// varies object size, drift direction and speed, rotation, z pattern,
    /// disparity gain and offset, noise levels and the scene itself.
    pub fn preset(preset: Preset, shape: Shape, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5EED_0FF2_E5E7);
        let (motion, disparity) = random_motion(&mut rng);
        let size_factor = rng.gen_range(0.25..0.35);
        let base = Self::default();
        let mut cfg = Self {
            seed,
            shape,
            object_size_px: Some(q(size_factor * base.width.min(base.height) as f64)),
            motion,
            disparity,
            shading: if shape == Shape::Sphere { 0.25 } else { 0.08 },
            object_texture: 0.05,
            ..base
        };
        match preset {
            Preset::Clean => {
                cfg.object_texture = 0.02;
                cfg.clutter.texture_amplitude = 0.015;
            }
            Preset::Noisy => cfg.noise = strong_noise(&cfg, &mut rng),
            Preset::Cluttered => {
                cfg.noise = moderate_noise(&mut rng);
                cfg.clutter = Clutter {
                    particles: rng.gen_range(20..36),
                    scratches: rng.gen_range(3..7),
                    texture_amplitude: 0.05,
                };
            }
            Preset::Occluded => {
                cfg.noise = moderate_noise(&mut rng);
                cfg.occlusion = Some(quarter_occluder(&cfg, &mut rng));
            }
            Preset::Crossing => {
                cfg.noise = moderate_noise(&mut rng);
                let dark = rng.gen_bool(0.4);
                cfg.occlusion = Some(Occlusion {
                    fraction: q(rng.gen_range(0.2..0.33)),
                    brightness: if dark { 0.1 } else { q(rng.gen_range(0.75..0.9)) },
                    z_offset_um: q(rng.gen_range(1.0..3.0) / cfg.disparity.px_per_um),
                    sweep_frames: rng.gen_range(3..6),
                    ..Occlusion::default()
                });
            }
            Preset::Fast => {
                cfg.noise = moderate_noise(&mut rng);
                let [dx, dy] = cfg.motion.drift_px_per_frame;
                let k = rng.gen_range(15.0..20.0) / dx.hypot(dy);
                cfg.motion.drift_px_per_frame = [q(dx * k), q(dy * k)];
            }
            Preset::Flicker => {
                cfg.noise = moderate_noise(&mut rng);
                cfg.flicker = 0.2;
            }
            Preset::Combined => {
                cfg.noise = strong_noise(&cfg, &mut rng);
                cfg.occlusion = Some(quarter_occluder(&cfg, &mut rng));
                cfg.flicker = 0.2;
            }
            Preset::BorderTool => cfg.make_border_tool(&mut rng),
            Preset::Scratched => {
                cfg.noise = moderate_noise(&mut rng);
                cfg.clutter.texture_amplitude = 0.03;
                cfg.fibres = Some(Fibres {
                    count: rng.gen_range(4..9),
                    under_object: rng.gen_range(3..6),
                    width_px: [1.0, 4.0],
                    contrast: [0.06, q(rng.gen_range(0.15..0.25))],
                    dark_fraction: 0.5,
                    curved_fraction: q(rng.gen_range(0.3..0.6)),
                });
            }
            Preset::Dark => {
                cfg.noise = moderate_noise(&mut rng);
                cfg.background_level = q(rng.gen_range(0.5..0.62));
                cfg.object_contrast = -q(rng.gen_range(0.28..0.38));
                cfg.rim_width_px = q(rng.gen_range(1.8..2.6));
                // Where the object fully covers a pixel (0.75 px inside the
                // outline) the rim is 0.08-0.18 brighter than the substrate.
                let peak = -cfg.object_contrast + rng.gen_range(0.08..0.18);
                cfg.rim_strength = q((peak / (-0.75 / cfg.rim_width_px).exp()).min(1.0));
                cfg.object_texture = 0.03;
                cfg.clutter.texture_amplitude = 0.03;
                if shape != Shape::Sphere {
                    cfg.shading = 0.05;
                }
            }
            Preset::Blurred => {
                // 15-30 electrons at the object's grey level: milder than `noisy`.
                let object_level = cfg.background_level + cfg.object_contrast;
                cfg.noise = Noise {
                    dose: Some(q(rng.gen_range(15.0..30.0) / object_level)),
                    read_noise: 0.015,
                    line_jitter_px: q(rng.gen_range(0.1..0.25)),
                    line_gain: 0.02,
                };
                cfg.blur_sigma_px = q(rng.gen_range(1.5..2.5));
            }
            Preset::Relief => {
                cfg.noise = moderate_noise(&mut rng);
                cfg.clutter.texture_amplitude = 0.015;
                cfg.relief = Some(Relief {
                    undulation: q(rng.gen_range(0.04..0.09)),
                    undulation_scale_px: q(rng.gen_range(110.0..220.0)),
                    grain_px: q(rng.gen_range(10.0..24.0)),
                    grain_contrast: q(rng.gen_range(0.12..0.2)),
                    ridges: q(rng.gen_range(0.03..0.08)),
                    ridge_angle_rad: q(std::f64::consts::FRAC_PI_2 + rng.gen_range(-0.3..0.3)),
                    speckle: q(rng.gen_range(0.02..0.04)),
                });
            }
        }
        cfg
    }

    /// The border_tool recipe: a long tool (tip and rod 0.5-0.8 of the
    /// smaller image side, slender) or a large blob/sphere (0.3-0.45) cut
    /// by a seed-chosen border, entering within +-30 degrees of the
    /// border's normal and moving 5-20 px per frame along its axis.
    fn make_border_tool(&mut self, rng: &mut ChaCha8Rng) {
        let side_px = self.width.min(self.height) as f64;
        let tool = matches!(self.shape, Shape::Tip | Shape::Rod);
        let size = if tool {
            rng.gen_range(0.5..0.8)
        } else {
            rng.gen_range(0.3..0.45)
        };
        self.object_size_px = Some(q(size * side_px));
        self.noise = moderate_noise(rng);
        self.clutter.texture_amplitude = 0.03;
        self.motion.rotation_rad_per_frame = q(rng.gen_range(-0.004..0.004));
        let speed = rng.gen_range(5.0..20.0);
        let sign = if rng.gen_bool(0.5) { 1.0 } else { -1.0 };
        self.border_entry = Some(BorderEntry {
            side: Some(BorderSide::ALL[rng.gen_range(0..4)]),
            angle_rad: Some(q(rng.gen_range(-0.52..0.52))),
            insertion_px_per_frame: q(sign * speed),
            min_visible_fraction: 0.45,
            min_outside_px: 4.0,
            width_scale: if tool { q(rng.gen_range(0.45..0.75)) } else { 1.0 },
        });
    }

    /// The same scene at another image size; an explicit object size scales
    /// with the smaller side.
    pub fn with_size(mut self, width: u32, height: u32) -> Self {
        let old = self.width.min(self.height).max(1) as f64;
        let new = width.min(height) as f64;
        if let Some(s) = self.object_size_px.as_mut() {
            *s *= new / old;
        }
        self.width = width;
        self.height = height;
        self
    }

    /// The object size in pixels (resolving the default).
    pub fn object_size(&self) -> f64 {
        self.object_size_px
            .unwrap_or(0.3 * self.width.min(self.height) as f64)
    }

    /// Checks every field; the error names the field and what was expected.
    /// (Whether the object fits along its path is checked when the scene is
    /// built.)
    pub fn validate(&self) -> Result<(), SynthError> {
        let bad = |field: &'static str, message: String| Err(SynthError::InvalidConfig { field, message });
        for (field, v) in [("width", self.width), ("height", self.height)] {
            if !(MIN_SIDE..=MAX_SIDE).contains(&v) {
                return bad(field, format!("{v} (expected {MIN_SIDE}..={MAX_SIDE} pixels)"));
            }
        }
        if self.frames == 0 {
            return bad("frames", "0 (expected at least 1)".into());
        }
        if self.bit_depth != 8 && self.bit_depth != 16 {
            return bad("bit_depth", format!("{} (expected 8 or 16)", self.bit_depth));
        }
        let size = self.object_size();
        let max_size = 0.8 * self.width.min(self.height) as f64;
        if !size.is_finite() || size < MIN_OBJECT_PX || size > max_size {
            return bad(
                "object_size_px",
                format!(
                    "{size} (expected {MIN_OBJECT_PX}..={max_size:.1} px for a {}x{} image)",
                    self.width, self.height
                ),
            );
        }
        self.validate_numbers()?;
        self.validate_motion()?;
        self.validate_noise()?;
        self.validate_occlusion()?;
        self.validate_scene_classes()
    }

    /// Border entry, fibres, blur and relief.
    fn validate_scene_classes(&self) -> Result<(), SynthError> {
        check_range("blur_sigma_px", self.blur_sigma_px, 0.0, 20.0)?;
        if let Some(b) = &self.border_entry {
            if let Some(a) = b.angle_rad {
                check_range("border_entry.angle_rad", a, -1.0, 1.0)?;
            }
            check_range(
                "border_entry.insertion_px_per_frame",
                b.insertion_px_per_frame,
                -1000.0,
                1000.0,
            )?;
            check_range(
                "border_entry.min_visible_fraction",
                b.min_visible_fraction,
                0.05,
                0.95,
            )?;
            check_range("border_entry.min_outside_px", b.min_outside_px, 0.5, 1000.0)?;
            check_range("border_entry.width_scale", b.width_scale, 0.1, 1.0)?;
        }
        if let Some(f) = &self.fibres {
            if f.count > 10_000 || f.under_object > 10_000 {
                return Err(SynthError::InvalidConfig {
                    field: "fibres",
                    message: format!(
                        "count {} and under_object {} (expected at most 10000 each)",
                        f.count, f.under_object
                    ),
                });
            }
            check_range("fibres.width_px[0]", f.width_px[0], 0.5, 20.0)?;
            check_range("fibres.width_px[1]", f.width_px[1], f.width_px[0], 20.0)?;
            check_range("fibres.contrast[0]", f.contrast[0], 0.0, 1.0)?;
            check_range("fibres.contrast[1]", f.contrast[1], f.contrast[0], 1.0)?;
            check_range("fibres.dark_fraction", f.dark_fraction, 0.0, 1.0)?;
            check_range("fibres.curved_fraction", f.curved_fraction, 0.0, 1.0)?;
        }
        if let Some(r) = &self.relief {
            check_range("relief.undulation", r.undulation, 0.0, 1.0)?;
            check_range(
                "relief.undulation_scale_px",
                r.undulation_scale_px,
                4.0,
                100_000.0,
            )?;
            check_range("relief.grain_px", r.grain_px, 3.0, 10_000.0)?;
            check_range("relief.grain_contrast", r.grain_contrast, 0.0, 1.0)?;
            check_range("relief.ridges", r.ridges, 0.0, 1.0)?;
            check_range("relief.ridge_angle_rad", r.ridge_angle_rad, -10.0, 10.0)?;
            check_range("relief.speckle", r.speckle, 0.0, 1.0)?;
        }
        Ok(())
    }

    fn validate_numbers(&self) -> Result<(), SynthError> {
        let checks: [(&'static str, f64, f64, f64); 9] = [
            ("flicker", self.flicker, 0.0, 0.9),
            ("background_level", self.background_level, 0.0, 1.0),
            ("background_gradient", self.background_gradient, -1.0, 1.0),
            ("object_contrast", self.object_contrast, -1.0, 1.0),
            ("rim_strength", self.rim_strength, -1.0, 1.0),
            ("rim_width_px", self.rim_width_px, 0.1, 50.0),
            ("object_texture", self.object_texture, 0.0, 1.0),
            ("shading", self.shading, 0.0, 1.0),
            (
                "clutter.texture_amplitude",
                self.clutter.texture_amplitude,
                0.0,
                1.0,
            ),
        ];
        for (field, v, lo, hi) in checks {
            check_range(field, v, lo, hi)?;
        }
        if self.clutter.particles > 10_000 || self.clutter.scratches > 10_000 {
            return Err(SynthError::InvalidConfig {
                field: "clutter",
                message: "too many particles or scratches (expected at most 10000 each)".into(),
            });
        }
        let d = &self.disparity;
        check_range("disparity.px_per_um", d.px_per_um, -100.0, 100.0)?;
        check_range("disparity.offset_px", d.offset_px, -1000.0, 1000.0)?;
        check_range("disparity.background_z_um", d.background_z_um, -1e9, 1e9)
    }

    fn validate_motion(&self) -> Result<(), SynthError> {
        let m = &self.motion;
        check_range(
            "motion.drift_px_per_frame[0]",
            m.drift_px_per_frame[0],
            -1000.0,
            1000.0,
        )?;
        check_range(
            "motion.drift_px_per_frame[1]",
            m.drift_px_per_frame[1],
            -1000.0,
            1000.0,
        )?;
        check_range(
            "motion.rotation_rad_per_frame",
            m.rotation_rad_per_frame,
            -1.0,
            1.0,
        )?;
        check_range("motion.z_step_um", m.z_step_um, 0.0, 1e9)?;
        check_range("motion.z_range_um[0]", m.z_range_um[0], -1e9, 1e9)?;
        check_range("motion.z_range_um[1]", m.z_range_um[1], m.z_range_um[0], 1e9)?;
        check_range(
            "motion.z_start_um",
            m.z_start_um,
            m.z_range_um[0],
            m.z_range_um[1],
        )?;
        if m.z_hold_frames == 0 {
            return Err(SynthError::InvalidConfig {
                field: "motion.z_hold_frames",
                message: "0 (expected at least 1)".into(),
            });
        }
        if let Some(a) = m.start_angle_rad {
            check_range("motion.start_angle_rad", a, -1e6, 1e6)?;
        }
        if let Some(p) = m.start_px {
            check_range("motion.start_px[0]", p[0], -0.5, self.width as f64 - 0.5)?;
            check_range("motion.start_px[1]", p[1], -0.5, self.height as f64 - 0.5)?;
        }
        Ok(())
    }

    fn validate_noise(&self) -> Result<(), SynthError> {
        let n = &self.noise;
        if let Some(dose) = n.dose {
            check_range("noise.dose", dose, 1e-3, 1e9)?;
            if dose <= 0.0 {
                return Err(SynthError::InvalidConfig {
                    field: "noise.dose",
                    message: format!("{dose} (expected > 0 electrons per pixel, or null for no shot noise)"),
                });
            }
        }
        check_range("noise.read_noise", n.read_noise, 0.0, 1.0)?;
        check_range("noise.line_jitter_px", n.line_jitter_px, 0.0, 10.0)?;
        check_range("noise.line_gain", n.line_gain, 0.0, 0.5)
    }

    fn validate_occlusion(&self) -> Result<(), SynthError> {
        let Some(o) = &self.occlusion else {
            return Ok(());
        };
        check_range("occlusion.fraction", o.fraction, 0.01, 0.9)?;
        if o.enter_frame == 0 {
            return Err(SynthError::InvalidConfig {
                field: "occlusion.enter_frame",
                message: "0 (expected >= 1: the occluder is absent in frame 0)".into(),
            });
        }
        check_range("occlusion.z_offset_um", o.z_offset_um, -1e9, 1e9)?;
        check_range("occlusion.brightness", o.brightness, 0.0, 1.0)?;
        if let Some(a) = o.cut_angle_rad {
            check_range("occlusion.cut_angle_rad", a, -1e6, 1e6)?;
        }
        Ok(())
    }
}

/// Error unless `lo <= v <= hi` and `v` is finite.
fn check_range(field: &'static str, v: f64, lo: f64, hi: f64) -> Result<(), SynthError> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(())
    } else {
        Err(SynthError::InvalidConfig {
            field,
            message: format!("{v} (expected a number in {lo}..={hi})"),
        })
    }
}

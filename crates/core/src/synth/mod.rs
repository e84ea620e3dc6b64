//! Synthetic SEM stereo sequences with ground truth: the measure of every
//! accuracy claim of the project.
//!
//! A [`SynthConfig`] (usually from [`SynthConfig::preset`]) describes an
//! object ([`Shape`]) moving rigidly and in height over `frames` stereo
//! pairs. The right image shows the object shifted along x by
//! `offset_px + px_per_um * z` and the background by the background's
//! disparity. Rendering is anti-aliased (1-px ramp on the exact signed
//! distance to a dense outline), with an SEM edge rim, texture that moves
//! with the object, static background texture and clutter, and then, per
//! image: scan-line jitter, flicker, line gain, Poisson shot noise, read
//! noise and quantisation. The same config always gives the same bytes.
//!
//! ```no_run
//! use semdepth_core::synth::{frames, Preset, Shape, SynthConfig};
//! let cfg = SynthConfig::preset(Preset::Noisy, Shape::Blob, 7);
//! for pair in frames(&cfg).unwrap() {
//!     let _d = pair.truth.disparity_px[0];
//! }
//! ```

mod bound;
mod config;
mod noise;
mod output;
mod raster;
mod scene;
mod shapes;
mod substrate;
#[cfg(test)]
pub(crate) use substrate::gaussian_blur;
mod truth;

#[cfg(test)]
mod tests;

pub use bound::{edge_shift_bound, iou_chance, EdgeBound};
pub use config::{
    BorderEntry, BorderSide, Clutter, Disparity, Fibres, Motion, Noise, Occlusion, Preset, Relief, Shape,
    SynthConfig, ZPattern, BORDER_MARGIN, MAX_SIDE, MIN_OBJECT_PX, MIN_SIDE,
};
pub use output::{write_sequence, SequenceSummary};
pub use scene::Scene;
pub use shapes::MIN_VERTICES;
pub use substrate::SubstrateLine;
pub use truth::{
    clip_to_frame, deviations_from_medians, Deviation, FrameTruth, ObjectTruth, OccluderTruth, SynthPair,
};

/// Why a sequence could not be generated or written.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    /// A config field is out of range.
    #[error("invalid synth config field `{field}`: {message}")]
    InvalidConfig {
        /// Dotted path of the field.
        field: &'static str,
        /// The value and what was expected.
        message: String,
    },
    /// The object cannot stay inside the frame with margin.
    #[error("object does not fit: {0}")]
    DoesNotFit(String),
    /// Creating a directory or writing a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file or directory.
        path: String,
        /// The underlying error.
        source: std::io::Error,
    },
    /// Encoding an image failed.
    #[error("writing image: {0}")]
    Image(#[from] crate::imageio::ImageInputError),
    /// Serialising the truth failed.
    #[error("writing truth.json: {0}")]
    Json(#[from] serde_json::Error),
}

impl SynthError {
    /// A stable snake_case code for APIs and logs.
    pub fn code(&self) -> &'static str {
        match self {
            Self::InvalidConfig { .. } => "invalid_synth_config",
            Self::DoesNotFit(_) => "object_does_not_fit",
            Self::Io { .. } => "io_error",
            Self::Image(_) => "image_write_error",
            Self::Json(_) => "json_error",
        }
    }

    /// True when the config (user input) is at fault rather than the system.
    pub fn is_input_error(&self) -> bool {
        matches!(self, Self::InvalidConfig { .. } | Self::DoesNotFit(_))
    }
}

/// A whole sequence in memory.
#[derive(Clone, Debug)]
pub struct Sequence {
    /// The configuration that produced it.
    pub config: SynthConfig,
    /// The stereo pairs, frame 0 first.
    pub pairs: Vec<SynthPair>,
}

/// Streaming iterator over the pairs of a sequence (rendered on demand).
#[derive(Clone, Debug)]
pub struct Frames {
    scene: Scene,
    next: usize,
}

impl Frames {
    /// The prepared scene (config, outline, particles; random access to
    /// any frame via [`Scene::render`]).
    pub fn scene(&self) -> &Scene {
        &self.scene
    }
}

impl Iterator for Frames {
    type Item = SynthPair;

    fn next(&mut self) -> Option<SynthPair> {
        if self.next >= self.scene.len() {
            return None;
        }
        let pair = self.scene.render(self.next);
        self.next += 1;
        Some(pair)
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        let n = self.scene.len() - self.next;
        (n, Some(n))
    }
}

impl ExactSizeIterator for Frames {}

/// Validates `config` and returns an iterator that renders one pair at a time.
pub fn frames(config: &SynthConfig) -> Result<Frames, SynthError> {
    Ok(Frames {
        scene: Scene::new(config)?,
        next: 0,
    })
}

/// Renders a whole sequence into memory.
pub fn generate(config: &SynthConfig) -> Result<Sequence, SynthError> {
    Ok(Sequence {
        config: config.clone(),
        pairs: frames(config)?.collect(),
    })
}

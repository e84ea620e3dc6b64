//! Writing a sequence to disk: `NNNN_left.png` / `NNNN_right.png` (8-bit) or
//! `.tif` (16-bit) per pair and a streamed `truth.json` =
//! `{"config": {...}, "frames": [FrameTruth, ...]}`.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::{frames, Preset, Shape, SynthConfig, SynthError};

/// Name of the ground-truth file inside the output directory.
pub const TRUTH_FILE: &str = "truth.json";

/// What [`write_sequence`] wrote.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SequenceSummary {
    /// The output directory.
    pub out_dir: String,
    /// Number of stereo pairs.
    pub frames: usize,
    /// Image files written (names relative to `out_dir`), left then right per pair.
    pub files: Vec<String>,
    /// The ground-truth file (relative to `out_dir`).
    pub truth: String,
    /// The object's shape.
    pub shape: Shape,
    /// The preset the config came from, when known (set by the caller).
    pub preset: Option<Preset>,
    /// The seed.
    pub seed: u64,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// 8 or 16.
    pub bit_depth: u8,
    /// Wall time of rendering and writing, milliseconds.
    pub elapsed_ms: f64,
}

fn io_error(path: &Path) -> impl FnOnce(std::io::Error) -> SynthError + '_ {
    move |source| SynthError::Io {
        path: path.display().to_string(),
        source,
    }
}

/// Renders `config` one pair at a time into `out_dir` (created if needed)
/// and streams the truth to `truth.json`.
pub fn write_sequence(config: &SynthConfig, out_dir: &Path) -> Result<SequenceSummary, SynthError> {
    let started = Instant::now();
    let iter = frames(config)?;
    std::fs::create_dir_all(out_dir).map_err(io_error(out_dir))?;
    let digits = (config.frames.saturating_sub(1).max(1).ilog10() as usize + 1).max(4);
    let ext = if config.bit_depth == 16 { "tif" } else { "png" };
    let truth_path = out_dir.join(TRUTH_FILE);
    let file = File::create(&truth_path).map_err(io_error(&truth_path))?;
    let mut truth = BufWriter::new(file);
    truth.write_all(b"{\"config\":").map_err(io_error(&truth_path))?;
    serde_json::to_writer(&mut truth, config)?;
    truth.write_all(b",\"frames\":[").map_err(io_error(&truth_path))?;
    let mut files = Vec::with_capacity(2 * config.frames);
    for (k, pair) in iter.enumerate() {
        for (side, image) in [("left", &pair.left), ("right", &pair.right)] {
            let name = format!("{k:0digits$}_{side}.{ext}");
            image.save(&out_dir.join(&name))?;
            files.push(name);
        }
        if k > 0 {
            truth.write_all(b",").map_err(io_error(&truth_path))?;
        }
        serde_json::to_writer(&mut truth, &pair.truth)?;
    }
    truth.write_all(b"]}\n").map_err(io_error(&truth_path))?;
    truth.flush().map_err(io_error(&truth_path))?;
    Ok(SequenceSummary {
        out_dir: out_dir.display().to_string(),
        frames: config.frames,
        files,
        truth: TRUTH_FILE.to_string(),
        shape: config.shape,
        preset: None,
        seed: config.seed,
        width: config.width,
        height: config.height,
        bit_depth: config.bit_depth,
        elapsed_ms: started.elapsed().as_secs_f64() * 1e3,
    })
}

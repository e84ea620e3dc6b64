//! `semdepth synth OUT_DIR`: write a synthetic SEM stereo sequence with
//! ground truth and print a one-line JSON summary.

use std::path::PathBuf;

use clap::Args;

use super::CliError;
use semdepth_core::synth::{write_sequence, Preset, Shape, SynthConfig, SynthError};

/// Arguments of `semdepth synth`.
#[derive(Debug, Args)]
pub struct SynthArgs {
    /// Output directory (created if missing).
    pub out_dir: PathBuf,
    /// Scene recipe.
    #[arg(long, value_parser = super::preset_value(), default_value = "clean")]
    pub preset: Preset,
    /// Object shape.
    #[arg(long, value_parser = super::shape_value())]
    pub shape: Option<Shape>,
    /// Random seed [default: 0].
    #[arg(long)]
    pub seed: Option<u64>,
    /// Number of stereo pairs [default: 10].
    #[arg(long)]
    pub frames: Option<usize>,
    /// Image width in pixels [default: 640].
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height in pixels [default: 480].
    #[arg(long)]
    pub height: Option<u32>,
    /// Bit depth: 8 (PNG) or 16 (TIFF) [default: 8].
    #[arg(long)]
    pub bit_depth: Option<u8>,
    /// Electrons per pixel at full-scale intensity (enables shot noise).
    #[arg(long)]
    pub dose: Option<f64>,
    /// A full SynthConfig as JSON; replaces the preset (the other flags
    /// still override its fields).
    #[arg(long)]
    pub config: Option<PathBuf>,
}

impl SynthArgs {
    /// The configuration these arguments describe.
    pub fn to_config(&self) -> Result<SynthConfig, CliError> {
        let mut cfg = match &self.config {
            Some(path) => {
                let text = std::fs::read_to_string(path)
                    .map_err(|e| CliError::input(format!("{}: {e}", path.display())))?;
                serde_json::from_str::<SynthConfig>(&text).map_err(|e| {
                    CliError::input(format!("{}: not a valid synth config: {e}", path.display()))
                })?
            }
            None => SynthConfig::preset(
                self.preset,
                self.shape.unwrap_or_default(),
                self.seed.unwrap_or(0),
            ),
        };
        if let Some(shape) = self.shape {
            cfg.shape = shape;
        }
        if let Some(seed) = self.seed {
            cfg.seed = seed;
        }
        if let Some(frames) = self.frames {
            cfg.frames = frames;
        }
        if self.width.is_some() || self.height.is_some() {
            let (w, h) = (self.width.unwrap_or(cfg.width), self.height.unwrap_or(cfg.height));
            cfg = cfg.with_size(w, h);
        }
        if let Some(bits) = self.bit_depth {
            cfg.bit_depth = bits;
        }
        if let Some(dose) = self.dose {
            cfg.noise.dose = Some(dose);
        }
        Ok(cfg)
    }
}

/// Runs `semdepth synth`: exit code 2 for a bad config, 1 when writing fails.
pub fn run(args: SynthArgs) -> Result<(), CliError> {
    let cfg = args.to_config()?;
    let mut summary = write_sequence(&cfg, &args.out_dir).map_err(|e| match e {
        e @ (SynthError::InvalidConfig { .. } | SynthError::DoesNotFit(_)) => {
            CliError::input(format!("error[{}]: {e}", e.code()))
        }
        e => CliError::with_code(1, format!("error[{}]: {e}", e.code())),
    })?;
    summary.preset = args.config.is_none().then_some(args.preset);
    let line = serde_json::to_string(&summary).map_err(|e| CliError::with_code(1, e.to_string()))?;
    println!("{line}");
    Ok(())
}

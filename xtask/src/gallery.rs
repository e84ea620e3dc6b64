//! `cargo xtask gallery`: the left image of frame 0 of every hard scene
//! class (border_tool, scratched, dark, blurred, relief) and every shape as
//! `OUT/PRESET_SHAPE.png`, so a person can check that they look like SEM
//! scenes.

use std::path::PathBuf;

use semdepth_core::synth::{Preset, Scene, Shape, SynthConfig};

/// Where, and which seed.
#[derive(clap::Args)]
pub struct Args {
    /// Output folder (made when missing).
    out: PathBuf,
    /// Seed.
    #[arg(default_value_t = 0)]
    seed: u64,
}

pub fn run(args: Args) -> crate::Result {
    std::fs::create_dir_all(&args.out).map_err(|e| format!("{}: {e}", args.out.display()))?;
    for preset in Preset::HARD {
        for shape in Shape::ALL {
            let cfg = SynthConfig::preset(preset, shape, args.seed);
            let scene = Scene::new(&cfg).map_err(|e| format!("{} {}: {e}", preset.name(), shape.name()))?;
            let path = args.out.join(format!("{}_{}.png", preset.name(), shape.name()));
            scene
                .render(0)
                .left
                .save(&path)
                .map_err(|e| format!("{}: {e}", path.display()))?;
            println!("{}", path.display());
        }
    }
    Ok(())
}

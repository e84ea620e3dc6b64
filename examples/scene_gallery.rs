//! Writes the left image of frame 0 of every hard scene class (border_tool,
//! scratched, dark, blurred, relief) x every shape as PNG, so a person can
//! check that they look like SEM scenes.
//!
//! `cargo run --release --example scene_gallery -- OUT_DIR [SEED]` writes
//! `OUT_DIR/PRESET_SHAPE.png` (seed 0 unless given).

use std::path::PathBuf;
use std::process::ExitCode;

use semdepth::synth::{Preset, Scene, Shape, SynthConfig};

fn main() -> ExitCode {
    let mut args = std::env::args().skip(1);
    let Some(out) = args.next().map(PathBuf::from) else {
        eprintln!("usage: scene_gallery OUT_DIR [SEED]");
        return ExitCode::from(2);
    };
    let seed = match args.next().map(|s| s.parse::<u64>()) {
        None => 0,
        Some(Ok(s)) => s,
        Some(Err(e)) => {
            eprintln!("SEED: {e}");
            return ExitCode::from(2);
        }
    };
    if let Err(e) = std::fs::create_dir_all(&out) {
        eprintln!("{}: {e}", out.display());
        return ExitCode::from(1);
    }
    for preset in Preset::HARD {
        for shape in Shape::ALL {
            let cfg = SynthConfig::preset(preset, shape, seed);
            let scene = match Scene::new(&cfg) {
                Ok(s) => s,
                Err(e) => {
                    eprintln!("{} {}: {e}", preset.name(), shape.name());
                    return ExitCode::from(1);
                }
            };
            let path = out.join(format!("{}_{}.png", preset.name(), shape.name()));
            if let Err(e) = scene.render(0).left.save(&path) {
                eprintln!("{}: {e}", path.display());
                return ExitCode::from(1);
            }
            println!("{}", path.display());
        }
    }
    ExitCode::SUCCESS
}

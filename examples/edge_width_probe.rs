//! The two inputs of the tracker's pre-filter choice on every preset's first
//! left image: the object's fitted edge width (px) / the substrate's
//! whiteness, per shape and seed:
//! `cargo run --release --example edge_width_probe -- [SEEDS] [FIRST_SEED]`.
use semdepth::geometry::Polygon;
use semdepth::init::{edge_width, initialise, InitParams};
use semdepth::synth::{Preset, Scene, Shape, SynthConfig};

fn main() {
    let a: Vec<u64> = std::env::args().skip(1).map(|s| s.parse().unwrap()).collect();
    let (seeds, seed0) = (*a.first().unwrap_or(&5), *a.get(1).unwrap_or(&0));
    for preset in Preset::ALL {
        let mut line = format!("{:12}", preset.name());
        for shape in Shape::ALL {
            for seed in seed0..seed0 + seeds {
                let cfg = SynthConfig {
                    frames: 1,
                    ..SynthConfig::preset(preset, shape, seed)
                };
                let pair = Scene::new(&cfg).unwrap().render(0);
                let found = initialise(&pair.left, &InitParams::default()).unwrap();
                let c: &Polygon = found.core.as_ref().unwrap_or(&found.contour);
                line += &format!(
                    " {:.2}/{:.2}",
                    edge_width(&pair.left, c).unwrap_or(f64::NAN),
                    semdepth::prefilter::substrate_whiteness(&pair.left, &found.contour).unwrap_or(f64::NAN)
                );
            }
            line += " |";
        }
        println!("{line}");
    }
}

//! Prints the energy of the true outline grown/shrunk radially, and shifted,
//! on clean synthetic frames: `cargo run --release --example energy_profile`.
use semdepth::energy::{evaluate, EnergyParams};
use semdepth::region::{PixelRect, PrefixSums};
use semdepth::synth::{Preset, Scene, Shape, SynthConfig};

fn main() {
    for shape in Shape::ALL {
        let mut cfg = SynthConfig {
            frames: 1,
            ..SynthConfig::preset(Preset::Clean, shape, 11)
        };
        if std::env::var("PLAIN").is_ok() {
            cfg.rim_strength = 0.0;
            cfg.object_texture = 0.0;
            cfg.shading = 0.0;
            cfg.clutter.texture_amplitude = 0.0;
            cfg.background_gradient = 0.0;
        }
        let pair = Scene::new(&cfg).unwrap().render(0);
        let truth = pair.truth.left.polygon.resampled(400);
        let sums = PrefixSums::new(&pair.left, PixelRect::full(&pair.left), 1);
        let p = EnergyParams {
            lambda: 0.0,
            ..EnergyParams::default()
        };
        let margin = p.margin_for_area(truth.area());
        let mut line = format!("{:>6} grow:", shape.name());
        for g in [-1.0, -0.5, -0.25, 0.0, 0.25, 0.5, 1.0] {
            let pts = truth.offset_along_normals(g).points;
            line += &format!(" {g:+}:{:.2}", evaluate(&sums, &pts, &p, margin).energy);
        }
        println!("{line}");
    }
}

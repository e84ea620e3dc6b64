//! Energy of the tracker's template along x around the true pose, in both
//! images of one frame: `energy_scan PRESET SHAPE SEED FRAME`.
use clap::ValueEnum;
use semdepth::energy::{evaluate, EnergyParams};
use semdepth::fit::{place, Pose, RigidTemplate};
use semdepth::region::{PixelRect, PrefixSums};
use semdepth::synth::{Preset, Scene, Shape, SynthConfig};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let preset = Preset::from_str(&a[1], true).unwrap();
    let shape = Shape::from_str(&a[2], true).unwrap();
    let seed: u64 = a[3].parse().unwrap();
    let k: usize = a[4].parse().unwrap();
    let cfg = SynthConfig {
        frames: k + 1,
        ..SynthConfig::preset(preset, shape, seed)
    };
    let scene = Scene::new(&cfg).unwrap();
    let pair = scene.render(k);
    let energy = EnergyParams::default();
    // Template: the true outline (so only the energy's own bias shows).
    let grow: f64 = std::env::var("GROW").map(|v| v.parse().unwrap()).unwrap_or(0.0);
    let (template, _) = RigidTemplate::new(
        &pair.truth.left.polygon.resampled(200).offset_along_normals(grow),
        48,
        &energy,
    );
    for (name, img, truth) in [
        ("L", &pair.left, &pair.truth.left),
        ("R", &pair.right, &pair.truth.right),
    ] {
        let sums = PrefixSums::new(img, PixelRect::full(img), 1);
        let c = truth.centroid;
        let mut best = (0.0, f64::INFINITY);
        let mut line = String::new();
        for i in -40..=40 {
            let dx = i as f64 * 0.01;
            let e = evaluate(
                &sums,
                &place(
                    &template.points,
                    Pose {
                        x: c[0] + dx,
                        y: c[1],
                        theta: 0.0,
                    },
                ),
                &energy,
                template.margin,
            )
            .energy;
            if e < best.1 {
                best = (dx, e);
            }
            if i % 10 == 0 {
                line += &format!(" {dx:+.2}:{e:.3}");
            }
        }
        println!("{name}: argmin dx {:+.3}  {line}", best.0);
    }
}

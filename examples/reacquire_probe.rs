//! The template search after a loss, measured: each sequence is tracked
//! for pairs 0-4, lost on two blank pairs, and given pair 7; prints how many
//! were found again (`tracked` within 3 px of the truth, after pair 4's
//! offset), missed, or taken wrong (`tracked` farther off).
//! `cargo run --release --example reacquire_probe -- PRESET SEEDS [FIRST_SEED]`.
use clap::ValueEnum;
use semdepth::imageio::GrayFrame;
use semdepth::synth::{Preset, Scene, Shape, SynthConfig};
use semdepth::tracker::{Status, StereoTracker, TrackerParams};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let preset = Preset::from_str(&a[1], true).unwrap();
    let seeds: u64 = a[2].parse().unwrap();
    let seed0: u64 = a.get(3).map_or(100, |s| s.parse().unwrap());
    let (mut found, mut missed, mut wrong) = (0, 0, 0);
    for shape in Shape::ALL {
        for seed in seed0..seed0 + seeds {
            let config = SynthConfig {
                frames: 14,
                ..SynthConfig::preset(preset, shape, seed)
            };
            let scene = Scene::new(&config).unwrap();
            let mut t = StereoTracker::new(TrackerParams::default());
            let mut off = [0.0; 2];
            for k in 0..5 {
                let p = scene.render(k);
                let r = t.process(&p.left, &p.right).unwrap();
                if let Some(l) = &r.left {
                    off = [
                        l.centroid[0] - p.truth.left.centroid[0],
                        l.centroid[1] - p.truth.left.centroid[1],
                    ];
                }
            }
            let blank = GrayFrame::filled(config.width, config.height, 8, 60);
            for _ in 0..2 {
                t.process(&blank, &blank).unwrap();
            }
            let p = scene.render(7);
            let r = t.process(&p.left, &p.right).unwrap();
            if r.status == Status::Tracked {
                let l = r.left.unwrap();
                let e = (l.centroid[0] - p.truth.left.centroid[0] - off[0])
                    .hypot(l.centroid[1] - p.truth.left.centroid[1] - off[1]);
                if e > 3.0 {
                    wrong += 1;
                    println!("{}/{seed} wrong {e:.1}", shape.name());
                } else {
                    found += 1;
                }
            } else {
                missed += 1;
                println!("{}/{seed} missed: {:?}", shape.name(), r.reason);
            }
        }
    }
    println!("{} found {found} missed {missed} wrong {wrong}", preset.name());
}

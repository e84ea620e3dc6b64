//! An object that stands still for three pairs and then moves on at
//! `STRIDE` (default 2) times its drift per pair, so that the tracker's
//! prediction is off by that much at the first moving pair, where the
//! preset's occluder, if any, arrives too: pairs 0, 0, 0, then every
//! `STRIDE`th pair up to 8 more. Prints the pairs `tracked` off the truth
//! (disparity more than 1 px or left centroid more than 3 px off, after
//! the first pair's offset) and the counts.
//! `cargo run --release --example restart_probe -- PRESET SEEDS [FIRST_SEED]`
//! (env SHAPE=name for one shape, VERBOSE=1 for every pair).
use clap::ValueEnum;
use semdepth::synth::{Preset, Scene, Shape, SynthConfig};
use semdepth::tracker::{Status, StereoTracker, TrackerParams};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let preset = Preset::from_str(&a[1], true).unwrap();
    let seeds: u64 = a[2].parse().unwrap();
    let seed0: u64 = a.get(3).map_or(100, |s| s.parse().unwrap());
    let stride: usize = std::env::var("STRIDE")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(2);
    let only = std::env::var("SHAPE").ok();
    let verbose = std::env::var("VERBOSE").is_ok();
    let (mut pairs, mut untracked, mut wrong) = (0, 0, 0);
    for shape in Shape::ALL
        .into_iter()
        .filter(|s| only.as_deref().is_none_or(|o| o == s.name()))
    {
        for seed in seed0..seed0 + seeds {
            let config = SynthConfig {
                frames: 2 + 8 * stride,
                ..SynthConfig::preset(preset, shape, seed)
            };
            let scene = Scene::new(&config).unwrap();
            let mut t = StereoTracker::new(TrackerParams::default());
            let order = [0, 0, 0].into_iter().chain((1..=8).map(|i| i * stride));
            let mut off = None;
            for k in order {
                let p = scene.render(k);
                let r = t.process(&p.left, &p.right).unwrap();
                pairs += 1;
                let (Some(l), Some(d)) = (&r.left, r.disparity_px) else {
                    untracked += 1;
                    if verbose {
                        println!("  {}/{seed} frame {k}: {:?}", shape.name(), r.reason);
                    }
                    continue;
                };
                // Against the whole object's truth: not meaningful for a
                // tool cut by the border (border_tool).
                let e = [
                    l.centroid[0] - p.truth.left.centroid[0],
                    l.centroid[1] - p.truth.left.centroid[1],
                    d[0] - p.truth.disparity_px[0],
                ];
                let o = *off.get_or_insert(e);
                let (c, dd) = ((e[0] - o[0]).hypot(e[1] - o[1]), (e[2] - o[2]).abs());
                if verbose {
                    println!(
                        "  {}/{seed} frame {k}: {:?}, centroid {c:.2} px, disparity {dd:.2} px off, {:.0}% hidden (truth {:.0}%)",
                        shape.name(),
                        r.status,
                        100.0 * l.occluded_fraction,
                        100.0 * p.truth.occluded_fraction
                    );
                }
                if r.status == Status::Tracked && (c > 3.0 || dd > 1.0) {
                    wrong += 1;
                    println!(
                        "{}/{seed} frame {k}: centroid {c:.1} px, disparity {dd:.2} px off",
                        shape.name()
                    );
                }
            }
        }
    }
    println!(
        "{} stride {stride}: {pairs} pairs, untracked {untracked}, confident wrong {wrong}",
        preset.name()
    );
}

//! Repeats one tracking step (pair 1 of a clean blob sequence) for profiling:
//! `cargo run --release --example step_profile -- [WIDTH HEIGHT] [REPEATS]`.
use semdepth::synth::{Preset, Scene, Shape, SynthConfig};
use semdepth::tracker::{StereoTracker, TrackerParams};

fn main() {
    let a: Vec<u32> = std::env::args()
        .skip(1)
        .map(|s| s.parse().expect("number"))
        .collect();
    let (w, h) = if a.len() >= 2 { (a[0], a[1]) } else { (1024, 768) };
    let repeats = a.get(2).copied().unwrap_or(2000);
    let config = SynthConfig {
        frames: 2,
        ..SynthConfig::preset(Preset::Clean, Shape::Blob, 1).with_size(w, h)
    };
    let scene = Scene::new(&config).expect("valid config");
    let (first, second) = (scene.render(0), scene.render(1));
    let mut tracker = StereoTracker::new(TrackerParams::default());
    tracker.process(&first.left, &first.right).unwrap();
    let mut times = Vec::new();
    for _ in 0..repeats {
        let mut t = tracker.clone();
        let start = std::time::Instant::now();
        std::hint::black_box(t.process(&second.left, &second.right).unwrap());
        times.push(start.elapsed().as_secs_f64() * 1e3);
    }
    if times.is_empty() {
        return;
    }
    times.sort_by(f64::total_cmp);
    println!(
        "{w}x{h}: median {:.3} ms, min {:.3} ms over {repeats}",
        times[times.len() / 2],
        times[0]
    );
}

//! `cargo xtask step-profile`: repeats one tracking step (pair 1 of a clean
//! blob sequence) and prints its median and minimum time, for profiling
//! (`perf record cargo xtask step-profile`); the benchmark of record is
//! `cargo bench --bench track`.

use semdepth_core::synth::{Preset, Scene, Shape, SynthConfig};
use semdepth_core::tracker::{StereoTracker, TrackerParams};

/// Frame size and repeats.
#[derive(clap::Args)]
pub struct Args {
    /// Frame width, px.
    #[arg(long, default_value_t = 1024)]
    width: u32,
    /// Frame height, px.
    #[arg(long, default_value_t = 768)]
    height: u32,
    /// Steps timed.
    #[arg(long, default_value_t = 2000)]
    repeats: usize,
}

pub fn run(args: Args) -> crate::Result {
    let (w, h) = (args.width, args.height);
    let config = SynthConfig {
        frames: 2,
        ..SynthConfig::preset(Preset::Clean, Shape::Blob, 1).with_size(w, h)
    };
    let scene = Scene::new(&config)?;
    let (first, second) = (scene.render(0), scene.render(1));
    let mut tracker = StereoTracker::new(TrackerParams::default());
    tracker.process(&first.left, &first.right)?;
    let mut times = Vec::with_capacity(args.repeats);
    for _ in 0..args.repeats {
        let mut t = tracker.clone();
        let start = std::time::Instant::now();
        std::hint::black_box(t.process(&second.left, &second.right)?);
        times.push(start.elapsed().as_secs_f64() * 1e3);
    }
    if times.is_empty() {
        return Ok(());
    }
    times.sort_by(f64::total_cmp);
    println!(
        "{w}x{h}: median {:.3} ms, min {:.3} ms over {}",
        times[times.len() / 2],
        times[0],
        args.repeats
    );
    Ok(())
}

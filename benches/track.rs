//! Tracking speed at 640x480, 1024x768 and 2048x2048 (8-bit synthetic clean
//! blob frames): one tracking step of a stereo pair (`track_pair`: rigid fits
//! in both images, prefix sums included; the tracker is cloned outside the
//! timed part because `process` moves it on), the first-pair initialisation
//! (`initialise_pair`: find, free fit, search of the right view), and, as a
//! reference measured in the same run, one pass summing every pixel of both
//! images (`reference_sum`).
//! Target (tracker issue): a 1024x768 pair under 1 ms on one core (goal 0.5 ms).
//! `python3 tools/bench_report.py track` prints medians and ratios.

use criterion::{black_box, criterion_group, criterion_main, BatchSize, BenchmarkId, Criterion};
use semdepth::imageio::GrayFrame;
use semdepth::synth::{Preset, Scene, Shape, SynthConfig};
use semdepth::tracker::{Status, StereoTracker, TrackerParams};

const SIZES: [(u32, u32); 3] = [(640, 480), (1024, 768), (2048, 2048)];

/// Pairs 0 and 1 of a clean blob sequence at this size.
fn pairs(width: u32, height: u32) -> [(GrayFrame, GrayFrame); 2] {
    let config = SynthConfig {
        frames: 2,
        ..SynthConfig::preset(Preset::Clean, Shape::Blob, 1).with_size(width, height)
    };
    let scene = Scene::new(&config).expect("valid config");
    [0, 1].map(|k| {
        let pair = scene.render(k);
        (pair.left, pair.right)
    })
}

fn bench_track(c: &mut Criterion) {
    let mut group = c.benchmark_group("track");
    group.sample_size(50);
    let mut inputs = Vec::new();
    for (w, h) in SIZES {
        let id = format!("{w}x{h}");
        let [first, second] = pairs(w, h);
        let mut tracker = StereoTracker::new(TrackerParams::default());
        let init = tracker.process(&first.0, &first.1).expect("same-size pair");
        assert_eq!(init.status, Status::Initialised, "{id}: {:?}", init.reason);
        // Make sure the benchmark measures a successful step.
        let step = tracker
            .clone()
            .process(&second.0, &second.1)
            .expect("same-size pair");
        assert_eq!(step.status, Status::Tracked, "{id}: {:?}", step.reason);
        group.bench_with_input(BenchmarkId::new("track_pair", &id), &second, |b, (l, r)| {
            b.iter_batched(
                || tracker.clone(),
                |mut t| t.process(black_box(l), black_box(r)).unwrap(),
                BatchSize::SmallInput,
            )
        });
        group.bench_with_input(BenchmarkId::new("reference_sum", &id), &second, |b, (l, r)| {
            b.iter(|| {
                let sum = |f: &GrayFrame| f.data.iter().map(|&v| v as u64).sum::<u64>();
                sum(black_box(l)) + sum(black_box(r))
            })
        });
        inputs.push((id, first));
    }
    // The first pair costs far more (initialisation and free fit): fewer samples.
    group.sample_size(10);
    for (id, first) in &inputs {
        group.bench_with_input(BenchmarkId::new("initialise_pair", id), first, |b, (l, r)| {
            b.iter(|| {
                StereoTracker::new(TrackerParams::default())
                    .process(black_box(l), black_box(r))
                    .unwrap()
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench_track);
criterion_main!(benches);

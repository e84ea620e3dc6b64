//! Tracking speed at 640x480, 1024x768 and 2048x2048 (8-bit synthetic clean
//! blob frames): one tracking step of a stereo pair (`track_pair`: rigid fits
//! in both images, prefix sums included; the tracker is cloned outside the
//! timed part because `process` moves it on), the first-pair initialisation
//! (`initialise_pair`: find, free fit, search of the right view), and, as a
//! reference measured in the same run, one pass summing every pixel of both
//! images (`reference_sum`); at 1024x768 also the step on a defocus-blurred
//! low-dose blob (`track_pair_blurred`), where both images are smoothed to
//! the edge's width first (`semdepth_core::prefilter`); and the pair after a
//! loss (`reacquire_pair`: the lost template sought over the whole left
//! image, then along the right view's epipolar line, and the tracking step
//! from where it was found); and the factor a run's scatter gives a
//! tracked pair's standard error over a full window
//! (`scatter_factor_full_run`, `semdepth_core::scatter`), part of every step.
//! Target (tracker issue): a 1024x768 pair under 1 ms on one core (goal 0.5 ms).
//! `python3 tools/bench_report.py track` prints medians and ratios.

use criterion::{black_box, criterion_group, criterion_main, BatchSize, BenchmarkId, Criterion};
use semdepth_core::imageio::GrayFrame;
use semdepth_core::scatter::{DisparityRun, Measured};
use semdepth_core::synth::{Preset, Scene, Shape, SynthConfig};
use semdepth_core::tracker::{Status, StereoTracker, TrackerParams, REACQUIRED};

const SIZES: [(u32, u32); 3] = [(640, 480), (1024, 768), (2048, 2048)];

/// Pairs 0 and 1 of a blob sequence of `preset` at this size.
fn pairs(preset: Preset, width: u32, height: u32) -> [(GrayFrame, GrayFrame); 2] {
    let config = SynthConfig {
        frames: 2,
        ..SynthConfig::preset(preset, Shape::Blob, 1).with_size(width, height)
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
    let blurred = (Preset::Blurred, "track_pair_blurred", 1024, 768);
    for (preset, name, w, h) in SIZES
        .map(|(w, h)| (Preset::Clean, "track_pair", w, h))
        .into_iter()
        .chain([blurred])
    {
        let id = format!("{w}x{h}");
        let [first, second] = pairs(preset, w, h);
        let mut tracker = StereoTracker::new(TrackerParams::default());
        let init = tracker.process(&first.0, &first.1).expect("same-size pair");
        assert_eq!(init.status, Status::Initialised, "{id}: {:?}", init.reason);
        // Make sure the benchmark measures a successful step.
        let step = tracker
            .clone()
            .process(&second.0, &second.1)
            .expect("same-size pair");
        assert_eq!(step.status, Status::Tracked, "{id}: {:?}", step.reason);
        if preset == Preset::Blurred {
            let sigma = tracker.state().map_or(0.0, |s| s.prefilter_sigma_px);
            assert!(sigma > 0.0, "{id}: a blurred scene is smoothed");
        }
        group.bench_with_input(BenchmarkId::new(name, &id), &second, |b, (l, r)| {
            b.iter_batched(
                || tracker.clone(),
                |mut t| t.process(black_box(l), black_box(r)).unwrap(),
                BatchSize::SmallInput,
            )
        });
        if preset == Preset::Blurred {
            continue;
        }
        group.bench_with_input(BenchmarkId::new("reference_sum", &id), &second, |b, (l, r)| {
            b.iter(|| {
                let sum = |f: &GrayFrame| f.data.iter().map(|&v| v as u64).sum::<u64>();
                sum(black_box(l)) + sum(black_box(r))
            })
        });
        inputs.push((id, first, tracker, second));
    }
    // The first pair costs far more (initialisation and free fit): fewer samples.
    group.sample_size(10);
    for (id, first, tracker, second) in &inputs {
        group.bench_with_input(BenchmarkId::new("initialise_pair", id), first, |b, (l, r)| {
            b.iter(|| {
                StereoTracker::new(TrackerParams::default())
                    .process(black_box(l), black_box(r))
                    .unwrap()
            })
        });
        // Lost on a blank pair, then one search missed on another: the next
        // pair seeks the template.
        let mut lost = tracker.clone();
        let blank = GrayFrame {
            data: vec![90; first.0.data.len()],
            ..first.0.clone()
        };
        for _ in 0..2 {
            let r = lost.process(&blank, &blank).expect("same-size pair");
            assert_eq!(r.status, Status::Lost, "{id}: a blank pair");
        }
        let found = lost
            .clone()
            .process(&second.0, &second.1)
            .expect("same-size pair");
        assert_eq!(
            found.reason.as_deref(),
            Some(REACQUIRED),
            "{id}: {:?}",
            found.status
        );
        group.bench_with_input(BenchmarkId::new("reacquire_pair", id), second, |b, (l, r)| {
            b.iter_batched(
                || lost.clone(),
                |mut t| t.process(black_box(l), black_box(r)).unwrap(),
                BatchSize::SmallInput,
            )
        });
    }
    let mut run = DisparityRun::default();
    for k in 0..40u64 {
        // A ramp with a deterministic scatter of up to 0.05 px.
        let wobble = 0.05 * ((k * 7919 % 13) as f64 / 6.0 - 1.0);
        run.push(Measured {
            frame: k,
            disparity_px: 3.0 + 0.7 * k as f64 + wobble,
            std_px: 0.015,
        });
    }
    assert!(run.factor() > 1.0, "the run scales its standard error");
    group.bench_function("scatter_factor_full_run", |b| b.iter(|| black_box(&run).factor()));
    group.finish();
}

criterion_group!(benches, bench_track);
criterion_main!(benches);

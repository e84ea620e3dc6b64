//! Initialisation speed at 640x480, 1024x768 and 2048x2048 (8-bit synthetic
//! cluttered frames), next to two references measured in the same run: one
//! pass summing the image (the cost of reading it once) and imageproc's own
//! `canny` (fixed sigma 1.4, absolute thresholds) on the full frame; at
//! 1024x768 and 2048x2048 also with a `roi` box hint around the object (10%
//! larger than it: the prompted path, issue #16), and the edge fit alone
//! (`init::fitted_to_edge` on the found outline).
//! Target (issue #2): 1024x768 under 15 ms on one core.
//! `python3 tools/bench_report.py init` prints medians and ratios.

use criterion::{black_box, criterion_group, criterion_main, BenchmarkId, Criterion};
use semdepth_core::imageio::GrayFrame;
use semdepth_core::init::{fitted_to_edge, initialise, InitParams};
use semdepth_core::synth::{Preset, Scene, Shape, SynthConfig};

/// The left frame and a `roi` hint around its object.
fn frame(width: u32, height: u32) -> (GrayFrame, [i64; 4]) {
    let config = SynthConfig {
        frames: 1,
        ..SynthConfig::preset(Preset::Cluttered, Shape::Blob, 1).with_size(width, height)
    };
    let pair = Scene::new(&config).expect("valid config").render(0);
    (pair.left, pair.truth.left.roi_hint(0.1))
}

fn bench_init(c: &mut Criterion) {
    let mut group = c.benchmark_group("init");
    group.sample_size(20);
    for (w, h) in [(640, 480), (1024, 768), (2048, 2048)] {
        let (f, roi) = frame(w, h);
        let id = format!("{w}x{h}");
        // Make sure the benchmark measures a successful run.
        initialise(&f, &InitParams::default()).expect("object found");
        group.bench_with_input(BenchmarkId::new("initialise", &id), &f, |b, f| {
            b.iter(|| initialise(black_box(f), &InitParams::default()).unwrap())
        });
        if w >= 1024 {
            let hinted = InitParams {
                roi: Some(roi),
                ..InitParams::default()
            };
            initialise(&f, &hinted).expect("object found from the box");
            group.bench_with_input(BenchmarkId::new("initialise_roi", &id), &f, |b, f| {
                b.iter(|| initialise(black_box(f), &hinted).unwrap())
            });
        }
        // The edge fit alone, on the outline the initialisation found.
        let found = initialise(&f, &InitParams::default()).expect("object found");
        group.bench_with_input(BenchmarkId::new("fitted_to_edge", &id), &f, |b, f| {
            b.iter(|| fitted_to_edge(black_box(f), &found.contour).expect("an edge"))
        });
        group.bench_with_input(BenchmarkId::new("reference_sum", &id), &f, |b, f| {
            b.iter(|| black_box(f).data.iter().map(|&v| v as u64).sum::<u64>())
        });
        let gray = f.to_gray8();
        group.bench_with_input(BenchmarkId::new("imageproc_canny", &id), &gray, |b, g| {
            b.iter(|| imageproc::edges::canny(black_box(g), 10.0, 30.0))
        });
    }
    group.finish();
}

criterion_group!(benches, bench_init);
criterion_main!(benches);

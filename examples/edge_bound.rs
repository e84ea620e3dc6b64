//! How well one image can place a blurred object's edge: the Cramér-Rao
//! bound on the whole outline's shift ([`semdepth::synth::edge_shift_bound`])
//! next to the tracker's first left contour (`roi` hint) on the same scene,
//! and the chance that an unbiased estimator at the bound keeps IoU >= 0.95.
//! `cargo run --release --example edge_bound -- [SEEDS] [FIRST_SEED]`;
//! `ONLY=blurred` (the default) picks the presets, `SHAPE=rod` one shape.
use semdepth::geometry::{mask_iou, Polygon};
use semdepth::init::InitParams;
use semdepth::synth::{edge_shift_bound, iou_chance, Preset, Scene, Shape, SynthConfig};
use semdepth::tracker::{Status, StereoTracker, TrackerParams};

fn main() {
    let args: Vec<u64> = std::env::args().skip(1).map(|s| s.parse().unwrap()).collect();
    let seeds = *args.first().unwrap_or(&10);
    let seed0 = *args.get(1).unwrap_or(&500);
    let only = std::env::var("ONLY").unwrap_or_else(|_| "blurred".into());
    let shape_only = std::env::var("SHAPE").ok();
    println!(
        "scene            | first IoU (area ratio) | bound, px: unknown / blur known / blur and rim known | chance of IoU >= 0.95 at the bound: one view / two / blur known"
    );
    for preset in Preset::ALL
        .into_iter()
        .filter(|p| only.split(',').any(|o| o == p.name()))
    {
        let (mut chances, mut passed) = (Vec::new(), 0usize);
        for shape in Shape::ALL {
            if shape_only.as_deref().is_some_and(|s| s != shape.name()) {
                continue;
            }
            for seed in seed0..seed0 + seeds {
                let cfg = SynthConfig {
                    frames: 1,
                    ..SynthConfig::preset(preset, shape, seed)
                };
                let pair = Scene::new(&cfg).unwrap().render(0);
                let (w, h) = (cfg.width, cfg.height);
                let polygon = &pair.truth.left.polygon;
                let Some(bound) = edge_shift_bound(&cfg, polygon) else {
                    continue;
                };
                let mut tracker = StereoTracker::new(TrackerParams {
                    init: InitParams {
                        roi: Some(pair.truth.left.roi_hint(0.1)),
                        ..InitParams::default()
                    },
                    ..TrackerParams::default()
                });
                let first = tracker.process(&pair.left, &pair.right).unwrap();
                let truth = pair.truth.left.mask(w, h);
                let found = first
                    .left
                    .filter(|_| first.status == Status::Initialised)
                    .map(|l| Polygon::new(l.contour).rasterize(w, h));
                let count = |m: &[bool]| m.iter().filter(|&&x| x).count() as f64;
                let (iou, ratio) = found
                    .as_ref()
                    .map_or((0.0, 0.0), |m| (mask_iou(m, &truth), count(m) / count(&truth)));
                passed += usize::from(iou >= 0.95);
                let chance = [
                    iou_chance(polygon, bound.unknown, 0.95),
                    iou_chance(polygon, bound.unknown / std::f64::consts::SQRT_2, 0.95),
                    iou_chance(polygon, bound.blur_known, 0.95),
                ];
                chances.push(chance);
                println!(
                    "{:<16} | {iou:.3} ({ratio:.3})          | {:.2} / {:.2} / {:.3} | {:.2} / {:.2} / {:.2}",
                    format!("{}/{}/{seed}", preset.name(), shape.name()),
                    bound.unknown,
                    bound.blur_known,
                    bound.blur_and_rim_known,
                    chance[0],
                    chance[1],
                    chance[2]
                );
            }
        }
        let n = chances.len().max(1) as f64;
        let mean = |k: usize| chances.iter().map(|c| c[k]).sum::<f64>() / n;
        println!(
            "{}: {} scenes, IoU >= 0.95 measured {:.3}; expected at the bound: one view {:.3}, two views {:.3}, blur known {:.3}",
            preset.name(),
            chances.len(),
            passed as f64 / n,
            mean(0),
            mean(1),
            mean(2)
        );
    }
}

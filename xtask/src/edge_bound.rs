//! `cargo xtask edge-bound`: how well one image can place a blurred
//! object's edge: the Cramér-Rao bound on the whole outline's shift
//! (`semdepth_core::synth::edge_shift_bound`) next to the tracker's first
//! left contour (`roi` hint) on the same scene, and the chance that an
//! unbiased estimator at the bound keeps IoU >= 0.95.

use semdepth_core::geometry::{mask_iou, Polygon};
use semdepth_core::init::InitParams;
use semdepth_core::synth::{edge_shift_bound, iou_chance, Preset, Scene, Shape, SynthConfig};
use semdepth_core::tracker::{Status, StereoTracker, TrackerParams};

/// Which scenes.
#[derive(clap::Args)]
pub struct Args {
    /// Seeds per condition and shape.
    #[arg(default_value_t = 10)]
    seeds: u64,
    /// First seed.
    #[arg(default_value_t = 500)]
    seed0: u64,
    /// Conditions, comma-separated.
    #[arg(long, default_value = "blurred")]
    only: String,
    /// One shape only.
    #[arg(long)]
    shape: Option<String>,
}

pub fn run(args: Args) -> crate::Result {
    let (seeds, seed0) = (args.seeds, args.seed0);
    let only: Vec<Preset> = args
        .only
        .split(',')
        .map(crate::preset)
        .collect::<Result<_, _>>()?;
    let shape_only = args.shape.as_deref().map(crate::shape).transpose()?;
    println!(
        "scene            | first IoU (area ratio) | bound, px: unknown / blur known / blur and rim known | chance of IoU >= 0.95 at the bound: one view / two / blur known"
    );
    for preset in Preset::ALL.into_iter().filter(|p| only.contains(p)) {
        let (mut chances, mut passed) = (Vec::new(), 0usize);
        for shape in Shape::ALL {
            if shape_only.is_some_and(|s| s != shape) {
                continue;
            }
            for seed in seed0..seed0 + seeds {
                let cfg = SynthConfig {
                    frames: 1,
                    ..SynthConfig::preset(preset, shape, seed)
                };
                let pair = Scene::new(&cfg)?.render(0);
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
                let first = tracker.process(&pair.left, &pair.right)?;
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
    Ok(())
}

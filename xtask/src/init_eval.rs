//! `cargo xtask init-eval`: initialisation against the generator's
//! frame-clipped truth on every scene class: IoU of the found region,
//! without hints, with a `roi` (the visible object's bounding box grown by
//! 10% per side) and with a `point` (the visible mask pixel nearest its
//! centroid).

use semdepth_core::geometry::{mask_iou, Polygon};
use semdepth_core::init::{initialise, InitParams};
use semdepth_core::synth::{Preset, Scene, Shape, SynthConfig};
use semdepth_core::tracker::{Status, StereoTracker, TrackerParams};

/// Which scenes, and what to measure.
#[derive(clap::Args)]
pub struct Args {
    /// Seeds per condition and shape.
    #[arg(default_value_t = 5)]
    seeds: u64,
    /// First seed.
    #[arg(default_value_t = 300)]
    seed0: u64,
    /// Conditions, comma-separated (default: all).
    #[arg(long)]
    only: Option<String>,
    /// List the scenes under the bar.
    #[arg(long)]
    fails: bool,
    /// Measure the first pair's left contour after the tracker's free fit
    /// instead of the initialisation's outline.
    #[arg(long)]
    fit: bool,
    /// With `--fit`: the pre-filter's sigma, px (0: none).
    #[arg(long)]
    prefilter: Option<f64>,
}

pub fn run(args: Args) -> crate::Result {
    let only: Option<Vec<Preset>> = args
        .only
        .as_deref()
        .map(|list| list.split(',').map(crate::preset).collect::<Result<_, _>>())
        .transpose()?;
    let (seeds, seed0, list, fit) = (args.seeds, args.seed0, args.fails, args.fit);
    println!("preset       | none >=0.9 | roi >=0.95 | point >=0.95 | median IoU none/roi/point");
    for preset in Preset::ALL {
        if only.as_ref().is_some_and(|only| !only.contains(&preset)) {
            continue;
        }
        let mut ious: [Vec<f64>; 3] = Default::default();
        let mut fails = Vec::new();
        for shape in Shape::ALL {
            for seed in seed0..seed0 + seeds {
                let cfg = SynthConfig {
                    frames: 1,
                    ..SynthConfig::preset(preset, shape, seed)
                };
                let pair = Scene::new(&cfg)?.render(0);
                let (w, h) = (cfg.width, cfg.height);
                let truth = pair.truth.left.mask(w, h);
                let roi = pair.truth.left.roi_hint(0.1);
                let point = pair.truth.left.point_hint(w, h).unwrap();
                let runs = [
                    InitParams::default(),
                    InitParams {
                        roi: Some(roi),
                        ..InitParams::default()
                    },
                    InitParams {
                        point: Some(point),
                        ..InitParams::default()
                    },
                ];
                for (k, params) in runs.iter().enumerate() {
                    let contour = if fit {
                        let mut tracker = StereoTracker::new(TrackerParams {
                            init: params.clone(),
                            prefilter_sigma_px: args.prefilter,
                            ..TrackerParams::default()
                        });
                        let first = tracker.process(&pair.left, &pair.right)?;
                        first
                            .left
                            .filter(|_| first.status == Status::Initialised)
                            .map(|l| Polygon::new(l.contour))
                    } else {
                        initialise(&pair.left, params).ok().map(|found| found.contour)
                    };
                    let found = contour.map(|c| c.rasterize(w, h));
                    let iou = found.as_ref().map_or(0.0, |m| mask_iou(m, &truth));
                    // Found area over true area: above 1 when the outline lies outside the edge.
                    let area = |m: &[bool]| m.iter().filter(|&&b| b).count() as f64;
                    let ratio = found.as_ref().map_or(0.0, |m| area(m) / area(&truth));
                    let limit = if k == 0 { 0.9 } else { 0.95 };
                    if iou < limit {
                        fails.push(format!(
                            "{}/{}/{seed} {}: {iou:.3} (area {ratio:.3} of the truth's)",
                            preset.name(),
                            shape.name(),
                            ["none", "roi", "point"][k]
                        ));
                    }
                    ious[k].push(iou);
                }
            }
        }
        let share = |v: &[f64], limit: f64| v.iter().filter(|&&x| x >= limit).count() as f64 / v.len() as f64;
        let median = |v: &mut Vec<f64>| {
            v.sort_by(|a, b| a.total_cmp(b));
            v[v.len() / 2]
        };
        let (a, b, c) = (share(&ious[0], 0.9), share(&ious[1], 0.95), share(&ious[2], 0.95));
        println!(
            "{:<12} | {a:>10.2} | {b:>10.2} | {c:>12.2} | {:.3} / {:.3} / {:.3}",
            preset.name(),
            median(&mut ious[0]),
            median(&mut ious[1]),
            median(&mut ious[2])
        );
        if list {
            for f in fails {
                println!("    {f}");
            }
        }
    }
    Ok(())
}

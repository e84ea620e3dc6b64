//! Initialisation on synthetic SEM frames against the generator's ground
//! truth: every shape, every preset (frame 0, before any occlusion), 20 seeds.

use semdepth::geometry::mask_iou;
use semdepth::init::{initialise, InitParams};
use semdepth::synth::{Preset, Scene, Shape, SynthConfig};

/// IoU a case must reach to count as a success (issue #2).
const MIN_IOU: f64 = 0.9;
/// Share of cases that must succeed (issue #2).
const MIN_SUCCESS_RATE: f64 = 0.95;
const SEEDS: u64 = 20;

#[test]
fn synthetic_initial_regions_match_truth() {
    let mut total = 0usize;
    let mut failures = Vec::new();
    for preset in Preset::BASIC {
        for shape in Shape::ALL {
            let mut ious = Vec::new();
            for seed in 0..SEEDS {
                let config = SynthConfig {
                    frames: 1,
                    ..SynthConfig::preset(preset, shape, seed)
                };
                let pair = Scene::new(&config).unwrap().render(0);
                let truth = pair.truth.left.mask(config.width, config.height);
                total += 1;
                let iou = match initialise(&pair.left, &InitParams::default()) {
                    Ok(found) => mask_iou(&found.contour.rasterize(config.width, config.height), &truth),
                    Err(e) => {
                        failures.push(format!("{}/{}/seed {seed}: {e}", preset.name(), shape.name()));
                        ious.push(0.0);
                        continue;
                    }
                };
                if iou < MIN_IOU {
                    failures.push(format!(
                        "{}/{}/seed {seed}: IoU {iou:.3}",
                        preset.name(),
                        shape.name()
                    ));
                }
                ious.push(iou);
            }
            ious.sort_by(|a, b| a.total_cmp(b));
            eprintln!(
                "{:>9} {:>6}: IoU min {:.3} median {:.3} max {:.3}",
                preset.name(),
                shape.name(),
                ious[0],
                ious[ious.len() / 2],
                ious[ious.len() - 1]
            );
        }
    }
    let rate = 1.0 - failures.len() as f64 / total as f64;
    eprintln!(
        "{} of {total} cases below IoU {MIN_IOU} (success rate {:.3}):",
        failures.len(),
        rate
    );
    for f in &failures {
        eprintln!("  {f}");
    }
    assert!(
        rate >= MIN_SUCCESS_RATE,
        "success rate {rate:.3} < {MIN_SUCCESS_RATE}; failures: {failures:#?}"
    );
}

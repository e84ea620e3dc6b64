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

/// A dark object with a bright SEM edge rim (the generator's `dark` scene
/// class), found from a box around it: the region must include the rim
/// (`init::rim`). Without the rim step the found region stops inside it
/// (median IoU 0.87-0.91 on seeds 300-302). Thresholds: every case
/// IoU >= 0.9 and the median >= 0.95 (measured on these unseen seeds: min
/// 0.932, median 0.969). Issue #16 asks for >= 0.95 in 95% of cases with a
/// hint: not met yet (90% here; a tip and a rod fall short).
#[test]
fn dark_objects_with_a_bright_rim_are_found_with_their_rim() {
    let mut ious = Vec::new();
    for shape in Shape::ALL {
        for seed in 400..405 {
            let config = SynthConfig {
                frames: 1,
                ..SynthConfig::preset(Preset::Dark, shape, seed)
            };
            let pair = Scene::new(&config).unwrap().render(0);
            let (w, h) = (config.width, config.height);
            let truth = pair.truth.left.mask(w, h);
            let roi = pair.truth.left.roi_hint(0.1);
            let params = InitParams {
                roi: Some(roi),
                ..InitParams::default()
            };
            let found = initialise(&pair.left, &params)
                .unwrap_or_else(|e| panic!("dark/{}/seed {seed}: {e}", shape.name()));
            let iou = mask_iou(&found.contour.rasterize(w, h), &truth);
            eprintln!("dark/{}/seed {seed}: IoU {iou:.3}", shape.name());
            assert!(
                iou >= 0.9,
                "dark/{}/seed {seed}: IoU {iou:.3} < 0.9",
                shape.name()
            );
            ious.push(iou);
        }
    }
    ious.sort_by(|a, b| a.total_cmp(b));
    let median = ious[ious.len() / 2];
    assert!(median >= 0.95, "median IoU {median:.3} < 0.95");
}

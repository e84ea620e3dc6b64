//! How far the first left contour lies outside the truth, per preset, shape
//! and seed: `IoU(mean offset px|best IoU@its constant offset)`, where the
//! mean offset is the area difference over the truth's perimeter, with a
//! `roi` hint. `FIT=1` measures the tracker's first contour instead of the
//! initialisation's; `ONLY=` and `SHAPE=` restrict.
//! `cargo run --release --example offset_probe -- [SEEDS] [FIRST_SEED]`
use semdepth::geometry::mask_iou;
use semdepth::init::{initialise, InitParams};
use semdepth::synth::{Preset, Scene, Shape, SynthConfig};

fn main() {
    let args: Vec<u64> = std::env::args().skip(1).map(|s| s.parse().unwrap()).collect();
    let seeds = *args.first().unwrap_or(&5);
    let seed0 = *args.get(1).unwrap_or(&500);
    for preset in Preset::ALL {
        if let Ok(only) = std::env::var("ONLY") {
            if !only.split(',').any(|p| p == preset.name()) {
                continue;
            }
        }
        for shape in Shape::ALL {
            if let Ok(only) = std::env::var("SHAPE") {
                if !only.split(',').any(|p| p == shape.name()) {
                    continue;
                }
            }
            let mut line = format!("{:<12}{:<7}", preset.name(), shape.name());
            for seed in seed0..seed0 + seeds {
                let cfg = SynthConfig {
                    frames: 1,
                    ..SynthConfig::preset(preset, shape, seed)
                };
                let pair = Scene::new(&cfg).unwrap().render(0);
                let (w, h) = (cfg.width, cfg.height);
                let truth = pair.truth.left.mask(w, h);
                let tpoly = &pair.truth.left.visible_polygon;
                let roi = pair.truth.left.roi_hint(0.1);
                let Ok(found) = initialise(
                    &pair.left,
                    &InitParams {
                        roi: Some(roi),
                        ..InitParams::default()
                    },
                ) else {
                    line += " FAIL";
                    continue;
                };
                let c = if std::env::var("FIT").is_ok() {
                    let mut tracker =
                        semdepth::tracker::StereoTracker::new(semdepth::tracker::TrackerParams {
                            init: InitParams {
                                roi: Some(roi),
                                ..InitParams::default()
                            },
                            ..Default::default()
                        });
                    let first = tracker.process(&pair.left, &pair.right).unwrap();
                    semdepth::geometry::Polygon::new(first.left.unwrap().contour)
                } else {
                    found.contour.clone()
                };
                let c = &c;
                let off = (c.area() - tpoly.area()) / tpoly.length();
                let iou = mask_iou(&c.rasterize(w, h), &truth);
                let best = (-8..=8)
                    .map(|k| {
                        let d = k as f64 * 0.1;
                        (mask_iou(&c.offset_along_normals(d).rasterize(w, h), &truth), d)
                    })
                    .max_by(|a, b| a.0.total_cmp(&b.0))
                    .unwrap();
                line += &format!(" {iou:.3}({off:+.2}|{:.3}@{:+.1})", best.0, best.1);
            }
            println!("{line}");
        }
    }
}

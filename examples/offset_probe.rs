//! How far the first left contour lies outside the truth, per preset, shape
//! and seed: `IoU(mean offset px|best IoU@its constant offset)`, where the
//! mean offset is the area difference over the truth's perimeter, with a
//! `roi` hint. `FIT=1` measures the tracker's first contour instead of the
//! initialisation's; `ONLY=` and `SHAPE=` restrict; `NOISELESS=1` renders
//! without noise, `BLUR=2.0` with that blur (px); `PROFILE=6` prints the
//! signed distance (outside +) of every 6th vertex to the truth.
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
                let mut cfg = SynthConfig {
                    frames: 1,
                    ..SynthConfig::preset(preset, shape, seed)
                };
                if std::env::var("NOISELESS").is_ok() {
                    cfg.noise = semdepth::synth::Noise {
                        dose: None,
                        read_noise: 0.0,
                        line_jitter_px: 0.0,
                        line_gain: 0.0,
                    };
                }
                if let Ok(b) = std::env::var("BLUR") {
                    cfg.blur_sigma_px = b.parse().unwrap();
                }
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
                if std::env::var("PROFILE").is_ok() {
                    // Signed distance (outside +) of every 6th vertex to the truth.
                    let seg = |p: [f64; 2], a: [f64; 2], b: [f64; 2]| {
                        let d = [b[0] - a[0], b[1] - a[1]];
                        let t = (((p[0] - a[0]) * d[0] + (p[1] - a[1]) * d[1])
                            / (d[0] * d[0] + d[1] * d[1]).max(1e-12))
                        .clamp(0.0, 1.0);
                        semdepth::geometry::dist(p, [a[0] + t * d[0], a[1] + t * d[1]])
                    };
                    let prof: Vec<String> = c
                        .points
                        .iter()
                        .step_by(std::env::var("PROFILE").unwrap().parse().unwrap())
                        .map(|&p| {
                            let d = tpoly
                                .edges()
                                .map(|(a, b)| seg(p, a, b))
                                .fold(f64::INFINITY, f64::min);
                            let s = if tpoly.contains(p) { -d } else { d };
                            format!("{s:+.1}")
                        })
                        .collect();
                    eprintln!("profile {}", prof.join(" "));
                }
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

//! Runs the initialisation on one image (a synthetic preset or a file) with
//! optional hints and prints the result, the runners-up and the time:
//! `cargo run --release --example init_probe -- PRESET SHAPE SEED [W H]` or
//! `-- FILE [x y w h]`.
use std::time::Instant;

use semdepth::imageio::{read_file, DecodeLimits};
use semdepth::init::{initialise, InitParams};
use semdepth::synth::{Preset, Scene, Shape, SynthConfig};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut params = InitParams::default();
    let (frame, truth) = if std::path::Path::new(&args[0]).exists() {
        if args.len() >= 5 {
            let v: Vec<i64> = args[1..5].iter().map(|s| s.parse().unwrap()).collect();
            params.roi = Some([v[0], v[1], v[2], v[3]]);
        }
        (
            read_file(std::path::Path::new(&args[0]), &DecodeLimits::default()).unwrap(),
            None,
        )
    } else {
        let preset: Preset = clap::ValueEnum::from_str(&args[0], true).unwrap();
        let shape: Shape = clap::ValueEnum::from_str(&args[1], true).unwrap();
        let seed: u64 = args[2].parse().unwrap();
        let mut cfg = SynthConfig {
            frames: 1,
            ..SynthConfig::preset(preset, shape, seed)
        };
        if args.len() >= 5 {
            cfg = cfg.with_size(args[3].parse().unwrap(), args[4].parse().unwrap());
        }
        let pair = Scene::new(&cfg).unwrap().render(0);
        let mask = pair.truth.left.mask(cfg.width, cfg.height);
        (pair.left, Some(mask))
    };
    let t = Instant::now();
    let r = initialise(&frame, &params);
    let ms = t.elapsed().as_secs_f64() * 1e3;
    let n = 10;
    let t = Instant::now();
    for _ in 0..n {
        let _ = initialise(&frame, &params);
    }
    let per = t.elapsed().as_secs_f64() * 1e3 / n as f64;
    match r {
        Ok(r) => {
            let iou = truth
                .map(|m| semdepth::geometry::mask_iou(&r.contour.rasterize(frame.width, frame.height), &m));
            println!(
                "score {:?} contrast {:?} area {:.0} source {:?} border {:?} iou {:?} candidates {} first {ms:.1} ms, mean {per:.1} ms",
                r.score.map(|s| s.score), r.score.map(|s| s.contrast), r.area_px, r.source, r.border, iou, r.diagnostics.candidates
            );
            for c in &r.diagnostics.runners_up {
                println!(
                    "  runner-up score {:.2} contrast {:.3} area {:.0} {:?} bbox {:?}",
                    c.score.score,
                    c.score.contrast,
                    c.score.area_px,
                    c.source,
                    c.bbox.map(|v| v.round())
                );
            }
        }
        Err(e) => println!("error {e} ({ms:.1} ms)"),
    }
}

//! Prints per-frame left/right centroid errors for one synthetic sequence:
//! `cargo run --release --example track_one -- PRESET SHAPE SEED [FRAMES]`;
//! `HINT=roi|point` hints the first pair, `DUMP=dir` writes overlays.
use clap::ValueEnum;
use semdepth::display::{render_png, Overlay};
use semdepth::energy::{evaluate, EnergyParams};
use semdepth::fit::{place, RigidTemplate};
use semdepth::geometry::Polygon;
use semdepth::region::{PixelRect, PrefixSums};
use semdepth::synth::{frames, Preset, Shape, SynthConfig};
use semdepth::tracker::{StereoTracker, TrackerParams};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let preset = Preset::from_str(&a[1], true).unwrap();
    let shape = Shape::from_str(&a[2], true).unwrap();
    let seed: u64 = a[3].parse().unwrap();
    let n: usize = a.get(4).map_or(10, |s| s.parse().unwrap());
    let cfg = SynthConfig {
        frames: n,
        ..SynthConfig::preset(preset, shape, seed)
    };
    println!("motion {:?}", cfg.motion);
    let pairs: Vec<_> = frames(&cfg).unwrap().collect();
    let mut params = TrackerParams::default();
    // HINT=roi or HINT=point gives the first pair's object as a hint, as
    // track_eval does.
    let first = &pairs[0].truth.left;
    match std::env::var("HINT").as_deref() {
        Ok("roi") => params.init.roi = Some(first.roi_hint(0.1)),
        Ok("point") => params.init.point = first.point_hint(cfg.width, cfg.height),
        _ => {}
    }
    let mut t = StereoTracker::new(params);
    for pair in pairs {
        let r = t.process(&pair.left, &pair.right).unwrap();
        if std::env::var("SCAN").is_ok() {
            let st = t.state().unwrap();
            let (tpl, _) =
                RigidTemplate::new(&Polygon::new(st.template.clone()), 48, &EnergyParams::default());
            for (name, img, pose, truth) in [
                ("L", &pair.left, st.left, pair.truth.left.centroid),
                ("R", &pair.right, st.right, pair.truth.right.centroid),
            ] {
                let sums = PrefixSums::new(img, PixelRect::full(img), 1);
                let mut best = (0.0, f64::INFINITY);
                for i in -30..=30 {
                    let mut p = pose;
                    p.x = truth[0] + i as f64 * 0.01;
                    let e = evaluate(
                        &sums,
                        &place(&tpl.points, p),
                        &EnergyParams::default(),
                        tpl.margin,
                    )
                    .energy;
                    if e < best.1 {
                        best = (i as f64 * 0.01, e);
                    }
                }
                println!(
                    "  {name}: tracker x err {:+.3}, scan argmin (true-template-free) x err {:+.3}",
                    pose.x - truth[0],
                    best.0
                );
            }
        }
        // DUMP=dir writes each image with the tracked (red) and true (green)
        // outlines.
        if let Ok(dir) = std::env::var("DUMP") {
            for (side, img, view, truth) in [
                ("left", &pair.left, &r.left, &pair.truth.left.polygon.points),
                ("right", &pair.right, &r.right, &pair.truth.right.polygon.points),
            ] {
                let mut overlays = vec![Overlay {
                    contour: truth,
                    colour: [0, 255, 0],
                }];
                if let Some(v) = view {
                    overlays.push(Overlay {
                        contour: &v.contour,
                        colour: [255, 0, 0],
                    });
                }
                let png = render_png(img, None, &overlays).unwrap();
                std::fs::write(format!("{dir}/{side}_{:02}.png", r.frame), png).unwrap();
            }
        }
        let (Some(l), Some(rr), Some(d)) = (&r.left, &r.right, r.disparity_px) else {
            println!("{} {:?} {:?}", r.frame, r.status, r.reason);
            continue;
        };
        let tl = pair.truth.left.centroid;
        let tr = pair.truth.right.centroid;
        println!(
            "{} {:?} L err ({:+.3},{:+.3}) R err ({:+.3},{:+.3}) dx err {:+.3} truth d {:.3} z {:.1} angle L {:+.4} truth rot {:+.4} occl {:.2}/{:.2} std {:.3}",
            r.frame, r.status, l.centroid[0] - tl[0], l.centroid[1] - tl[1], rr.centroid[0] - tr[0], rr.centroid[1] - tr[1],
            d[0] - pair.truth.disparity_px[0], pair.truth.disparity_px[0], pair.truth.z_um,
            r.angle_diff_rad.unwrap_or(f64::NAN), pair.truth.left.rotation_rad, l.occluded_fraction, rr.occluded_fraction, r.disparity_std_px.unwrap_or(f64::NAN)
        );
    }
}

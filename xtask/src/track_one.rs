//! `cargo xtask track-one`: one synthetic sequence, pair by pair: each
//! view's centroid error against the truth, the disparity's error and
//! standard error; optionally every image with the tracked (red) and true
//! (green) outlines.

use semdepth_core::display::{render_png, Overlay};
use semdepth_core::synth::{frames, SynthConfig};
use semdepth_core::tracker::{StereoTracker, TrackerParams};

use crate::Hint;

/// Which sequence.
#[derive(clap::Args)]
pub struct Args {
    /// Condition (`clean`, `noisy`, `occluded`, ...).
    preset: String,
    /// Shape (`blob`, `sphere`, `tip`, `rod`).
    shape: String,
    /// Seed.
    seed: u64,
    /// Pairs.
    #[arg(default_value_t = 10)]
    frames: usize,
    /// Give the first pair's object as a hint.
    #[arg(long, value_enum)]
    hint: Option<Hint>,
    /// Write every image with the tracked and true outlines to this folder.
    #[arg(long)]
    dump: Option<String>,
}

pub fn run(args: Args) -> crate::Result {
    let cfg = SynthConfig {
        frames: args.frames,
        ..SynthConfig::preset(
            crate::preset(&args.preset)?,
            crate::shape(&args.shape)?,
            args.seed,
        )
    };
    println!("motion {:?}", cfg.motion);
    let pairs: Vec<_> = frames(&cfg)?.collect();
    let mut params = TrackerParams::default();
    let first = &pairs[0].truth.left;
    match args.hint {
        Some(Hint::Roi) => params.init.roi = Some(first.roi_hint(0.1)),
        Some(Hint::Point) => params.init.point = first.point_hint(cfg.width, cfg.height),
        None => {}
    }
    let mut tracker = StereoTracker::new(params);
    for pair in pairs {
        let r = tracker.process(&pair.left, &pair.right)?;
        if let Some(dir) = &args.dump {
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
                std::fs::write(
                    format!("{dir}/{side}_{:02}.png", r.frame),
                    render_png(img, None, &overlays)?,
                )?;
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
            r.frame,
            r.status,
            l.centroid[0] - tl[0],
            l.centroid[1] - tl[1],
            rr.centroid[0] - tr[0],
            rr.centroid[1] - tr[1],
            d[0] - pair.truth.disparity_px[0],
            pair.truth.disparity_px[0],
            pair.truth.z_um,
            r.angle_diff_rad.unwrap_or(f64::NAN),
            pair.truth.left.rotation_rad,
            l.occluded_fraction,
            rr.occluded_fraction,
            r.disparity_std_px.unwrap_or(f64::NAN)
        );
    }
    Ok(())
}

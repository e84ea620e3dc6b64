//! `cargo xtask tilted-eval`: initialises and tracks the scenes of
//! `crates/core/tests/accuracy/tilted.rs` (a renderer independent of
//! `semdepth_core::synth`: three-dimensional bodies above a rough substrate
//! seen from two beam tilts) and prints, per class, the first left
//! contour's IoU with the truth and the tracking figures. "Confident
//! wrong": a tracked pair off by more than 1 px in disparity or 3 px in the
//! left reference point (centre, or the needle's tip carried by the
//! contour), after removing the sequence's median offsets.

use semdepth_core::display::{render_png, Overlay};
use semdepth_core::geometry::mask_iou;
use semdepth_core::tracker::{Status, StereoTracker, TrackerParams};

#[path = "../../crates/core/tests/accuracy/tilted.rs"]
mod tilted;

use tilted::{Class, TiltedPair};

use crate::Hint;

/// What to track and how.
#[derive(clap::Args)]
pub struct Args {
    /// Seeds per class.
    #[arg(default_value_t = 5)]
    seeds: u64,
    /// Pairs per sequence.
    #[arg(default_value_t = 20)]
    frames: usize,
    /// Classes, comma-separated (default: all).
    #[arg(long)]
    only: Option<String>,
    /// First seed.
    #[arg(long, default_value_t = 0)]
    seed0: u64,
    /// Give the first pair's object as a hint.
    #[arg(long, value_enum)]
    hint: Option<Hint>,
    /// Print every pair.
    #[arg(long)]
    frames_out: bool,
    /// Write the first left image with the first contour (red) and every
    /// pair's two views of the first seed to this folder.
    #[arg(long)]
    dump: Option<String>,
    /// Write every sequence as `DIR/CLASS/CLASS_SEED/` with `NNNN_left.png`,
    /// `NNNN_right.png` and a `truth.json` that `tools/ncc_baseline.py
    /// --sequences DIR` reads (the truth's polygon is the left mask's
    /// bounding box, its centroid the reference point).
    #[arg(long)]
    save: Option<String>,
    /// Per-line offsets of the scan (0 removes them), to separate the shot
    /// noise's share of an error from the rest.
    #[arg(long)]
    line_noise: Option<f64>,
    /// Put the bodies over a flat substrate.
    #[arg(long)]
    flat: bool,
    /// Hold every body at its pose of this pair, so the pairs differ by their noise alone.
    #[arg(long = "static")]
    static_pose: Option<usize>,
    /// Multiply the dose.
    #[arg(long)]
    dose_scale: Option<f64>,
}

fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    if s.is_empty() {
        0.0
    } else {
        s[s.len() / 2]
    }
}

/// Writes a sequence for `tools/ncc_baseline.py --sequences`.
fn save(root: &str, class: Class, seed: u64, pairs: &[TiltedPair]) -> crate::Result {
    let dir = format!("{root}/{}/{}_{seed}", class.name(), class.name());
    std::fs::create_dir_all(&dir)?;
    let mut frames = Vec::new();
    for (k, p) in pairs.iter().enumerate() {
        for (side, frame) in [("left", &p.left), ("right", &p.right)] {
            std::fs::write(format!("{dir}/{k:04}_{side}.png"), render_png(frame, None, &[])?)?;
        }
        let [x0, y0, x1, y1] = p.left_bounds().map(|v| v as f64);
        frames.push(format!(
            "{{\"left\": {{\"polygon\": [[{x0}, {y0}], [{x1}, {y0}], [{x1}, {y1}], [{x0}, {y1}]], \"centroid\": [{}, {}]}}, \"disparity_px\": [{}, 0.0]}}",
            p.left_point[0], p.left_point[1], p.disparity_px
        ));
    }
    std::fs::write(
        format!("{dir}/truth.json"),
        format!("{{\"frames\": [{}]}}", frames.join(", ")),
    )?;
    Ok(())
}

pub fn run(args: Args) -> crate::Result {
    let (seeds, nframes, seed0) = (args.seeds, args.frames, args.seed0);
    let (hint, dump, frames_out) = (args.hint, args.dump.clone(), args.frames_out);
    if let Some(only) = &args.only {
        for name in only.split(',') {
            if !Class::ALL.iter().any(|c| c.name() == name) {
                let names: Vec<&str> = Class::ALL.iter().map(|c| c.name()).collect();
                return Err(format!("unknown class {name:?} (expected one of {})", names.join(", ")).into());
            }
        }
    }
    for class in Class::ALL {
        if args
            .only
            .as_ref()
            .is_some_and(|o| !o.split(',').any(|c| c == class.name()))
        {
            continue;
        }
        let (mut ious, mut misses) = (Vec::new(), Vec::new());
        let (mut sq, mut n, mut pairs, mut untracked, mut wrong) = (0.0, 0usize, 0usize, 0usize, 0usize);
        let (mut std_sum, mut std_n) = (0.0, 0usize);
        for seed in seed0..seed0 + seeds {
            let mut scene = tilted::scene(class, seed, nframes);
            if let Some(v) = args.line_noise {
                scene.imaging.line_noise = v;
            }
            if args.flat {
                let (w, h) = (scene.width as f64, scene.height as f64);
                scene.substrate = tilted::Substrate::flat(&mut tilted::Rng::new(seed), w, h);
            }
            if let Some(k) = args.static_pose {
                for body in &mut scene.bodies {
                    body.poses = vec![body.poses[k]; nframes];
                }
            }
            if let Some(v) = args.dose_scale {
                scene.imaging.dose *= v;
            }
            let rendered: Vec<TiltedPair> = (0..nframes).map(|k| scene.render(k)).collect();
            let (w, h) = (scene.width, scene.height);
            if let Some(root) = &args.save {
                save(root, class, seed, &rendered)?;
            }
            let mut params = TrackerParams::default();
            match hint {
                Some(Hint::Roi) => params.init.roi = Some(rendered[0].roi_hint()),
                Some(Hint::Point) => params.init.point = Some(rendered[0].point_hint()),
                None => {}
            }
            let params_copy = params.init.clone();
            let mut tracker = StereoTracker::new(params);
            let mut reference = tilted::ReferencePoint::new(class);
            let (mut ds, mut cs, mut stds, mut frames_ok, mut truths) =
                (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
            for (k, pair) in rendered.iter().enumerate() {
                let r = tracker.process(&pair.left, &pair.right)?;
                pairs += 1;
                if k == 0 {
                    let iou = tilted::left_iou(pair, &r);
                    ious.push(iou);
                    if frames_out {
                        let init = semdepth_core::init::initialise(&pair.left, &params_copy)
                            .map(|r| mask_iou(&r.contour.rasterize(w as u32, h as u32), &pair.left_mask));
                        eprintln!(
                            "  {} {seed}: initialisation's own IoU {init:.3?}, first contour {iou:.3}",
                            class.name()
                        );
                    }
                    if iou < 0.9 {
                        misses.push(format!("{seed}: {iou:.3}"));
                    }
                }
                if let Some(dir) = &dump {
                    if k == 0 {
                        for (side, frame) in [("left", &pair.left), ("right", &pair.right)] {
                            let png = render_png(frame, None, &[])?;
                            std::fs::write(format!("{dir}/{}_{seed}_{side}.png", class.name()), png)?;
                        }
                    }
                    if seed == seed0 || k == 0 {
                        let views = [("", &pair.left, &r.left), ("_right", &pair.right, &r.right)];
                        for (suffix, image, fit) in views {
                            let contour = fit.as_ref().map(|l| l.contour.clone());
                            let overlays: Vec<Overlay> = contour
                                .iter()
                                .map(|c| Overlay {
                                    contour: c,
                                    colour: [255, 0, 0],
                                })
                                .collect();
                            let png = render_png(image, None, &overlays)?;
                            let name = format!("{dir}/{}_{seed}_{k:02}{suffix}.png", class.name());
                            std::fs::write(name, png)?;
                        }
                    }
                }
                if !matches!(r.status, Status::Tracked | Status::Initialised) {
                    untracked += 1;
                    if frames_out {
                        eprintln!(
                            "  {} {seed} pair {k}: {:?} {:?}",
                            class.name(),
                            r.status,
                            r.reason
                        );
                    }
                    continue;
                }
                let left = r.left.as_ref().unwrap();
                let e = reference.error(pair, &r);
                let d = r.disparity_px.unwrap()[0] - pair.disparity_px;
                ds.push(d);
                cs.push(e);
                stds.push(r.disparity_std_px.unwrap_or(f64::NAN));
                frames_ok.push(k);
                truths.push(pair.disparity_px);
                if frames_out {
                    eprintln!(
                        "  {} {seed} pair {k}: occluded {:.2} / {:.2}, reason {:?}",
                        class.name(),
                        left.occluded_fraction,
                        r.right.as_ref().unwrap().occluded_fraction,
                        r.reason
                    );
                }
            }
            let md = median(&ds);
            let mc = [
                median(&cs.iter().map(|c| c[0]).collect::<Vec<_>>()),
                median(&cs.iter().map(|c| c[1]).collect::<Vec<_>>()),
            ];
            for i in 0..ds.len() {
                let e = ds[i] - md;
                let ce = (cs[i][0] - mc[0]).hypot(cs[i][1] - mc[1]);
                sq += e * e;
                n += 1;
                if stds[i].is_finite() {
                    std_sum += stds[i];
                    std_n += 1;
                }
                let bad = e.abs() > 1.0 || ce > 3.0;
                wrong += bad as usize;
                if frames_out || bad {
                    eprintln!(
                        "  {} {seed} pair {}: disparity error {e:+.3} (raw {:+.3}, std {:.3}) truth {:.3} centroid error {ce:.2} (raw {:+.1}, {:+.1}){}",
                        class.name(),
                        frames_ok[i],
                        ds[i],
                        stds[i],
                        truths[i],
                        cs[i][0],
                        cs[i][1],
                        if bad { "  CONFIDENT WRONG" } else { "" }
                    );
                }
            }
        }
        let rms = (sq / n.max(1) as f64).sqrt();
        let good = ious.iter().filter(|&&v| v >= 0.9).count();
        println!(
            "{:<11} IoU>=0.9 {good}/{} (median {:.3}) misses [{}] | disparity RMS {rms:.3} px, std ratio {:.2}, untracked {untracked}/{pairs}, confident wrong {wrong}",
            class.name(),
            ious.len(),
            median(&ious),
            misses.join(", "),
            (std_sum / std_n.max(1) as f64) / rms.max(1e-9),
        );
    }
    Ok(())
}

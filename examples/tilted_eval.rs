//! Initialises and tracks the scenes of `tests/common/tilted.rs` (a
//! renderer independent of `semdepth::synth`) and prints, per class, the
//! first left contour's IoU with the truth and the tracking figures:
//! `cargo run --release --example tilted_eval -- [SEEDS] [FRAMES]`.
//! Env: `ONLY=grain,needle` picks classes, `SEED0=100` the first seed,
//! `HINT=roi|point` gives the first pair's object as a hint, `FRAMES_OUT=1`
//! prints every pair, `DUMP=dir` writes the first left image with the
//! first contour (red) and every pair's two views of the first seed,
//! `SAVE=dir` writes every sequence as `dir/CLASS/CLASS_SEED/` with
//! `NNNN_left.png`, `NNNN_right.png` and a `truth.json` that
//! `tools/ncc_baseline.py --sequences dir` reads (the truth's polygon is
//! the left mask's bounding box, its centroid the reference point).
//! `LINE_NOISE=0` removes the per-line offsets and `DOSE_SCALE=16`
//! multiplies the dose, to separate the shot noise's share of an error
//! from the rest; `FLAT=1` puts the bodies over a flat substrate
//! (`Substrate::flat`); `STATIC=k` holds every body at its pose of pair
//! `k`, so the pairs differ by their noise alone.
//! "Confident wrong": a tracked pair off by more than 1 px in disparity or
//! 3 px in the left reference point (centre, or the needle's tip carried by
//! the contour), after removing the sequence's median offsets.
use semdepth::display::{render_png, Overlay};
use semdepth::geometry::mask_iou;
use semdepth::tracker::{Status, StereoTracker, TrackerParams};

#[path = "../tests/common/tilted.rs"]
mod tilted;

use tilted::{Class, TiltedPair};

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
fn save(root: &str, class: Class, seed: u64, pairs: &[TiltedPair]) {
    let dir = format!("{root}/{}/{}_{seed}", class.name(), class.name());
    std::fs::create_dir_all(&dir).unwrap();
    let mut frames = Vec::new();
    for (k, p) in pairs.iter().enumerate() {
        for (side, frame) in [("left", &p.left), ("right", &p.right)] {
            std::fs::write(
                format!("{dir}/{k:04}_{side}.png"),
                render_png(frame, None, &[]).unwrap(),
            )
            .unwrap();
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
    )
    .unwrap();
}

fn main() {
    let args: Vec<usize> = std::env::args().skip(1).map(|s| s.parse().unwrap()).collect();
    let seeds = *args.first().unwrap_or(&5) as u64;
    let nframes = *args.get(1).unwrap_or(&20);
    let seed0: u64 = std::env::var("SEED0").map_or(0, |v| v.parse().unwrap());
    let hint = std::env::var("HINT").ok();
    let dump = std::env::var("DUMP").ok();
    let frames_out = std::env::var("FRAMES_OUT").is_ok();
    for class in Class::ALL {
        if std::env::var("ONLY").is_ok_and(|o| !o.split(',').any(|c| c == class.name())) {
            continue;
        }
        let (mut ious, mut misses) = (Vec::new(), Vec::new());
        let (mut sq, mut n, mut pairs, mut untracked, mut wrong) = (0.0, 0usize, 0usize, 0usize, 0usize);
        let (mut std_sum, mut std_n) = (0.0, 0usize);
        for seed in seed0..seed0 + seeds {
            let mut scene = tilted::scene(class, seed, nframes);
            if let Ok(v) = std::env::var("LINE_NOISE") {
                scene.imaging.line_noise = v.parse().unwrap();
            }
            if std::env::var("FLAT").is_ok() {
                let (w, h) = (scene.width as f64, scene.height as f64);
                scene.substrate = tilted::Substrate::flat(&mut tilted::Rng::new(seed), w, h);
            }
            if let Ok(v) = std::env::var("STATIC") {
                let k: usize = v.parse().unwrap();
                for body in &mut scene.bodies {
                    body.poses = vec![body.poses[k]; nframes];
                }
            }
            if let Ok(v) = std::env::var("DOSE_SCALE") {
                scene.imaging.dose *= v.parse::<f64>().unwrap();
            }
            let rendered: Vec<TiltedPair> = (0..nframes).map(|k| scene.render(k)).collect();
            let (w, h) = (scene.width, scene.height);
            if let Ok(root) = std::env::var("SAVE") {
                save(&root, class, seed, &rendered);
            }
            let mut params = TrackerParams::default();
            match hint.as_deref() {
                Some("roi") => params.init.roi = Some(rendered[0].roi_hint()),
                Some("point") => params.init.point = Some(rendered[0].point_hint()),
                _ => {}
            }
            let params_copy = params.init.clone();
            let mut tracker = StereoTracker::new(params);
            let mut reference = tilted::ReferencePoint::new(class);
            let (mut ds, mut cs, mut stds, mut frames_ok, mut truths) =
                (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
            for (k, pair) in rendered.iter().enumerate() {
                if std::env::var("PROBE").is_ok_and(|v| v.split(',').any(|f| f == k.to_string())) {
                    let init = semdepth::init::initialise(&pair.left, &params_copy);
                    eprintln!("PROBE pair {k}: hint {:?}", params_copy.point);
                    match init {
                        Ok(r) => eprintln!(
                            "  area {:.0} bbox {:?} source {:?} border {:?} score {:?}\n  diag {:?}",
                            r.area_px, r.bbox, r.source, r.border, r.score, r.diagnostics
                        ),
                        Err(e) => eprintln!("  error {e}"),
                    }
                }
                let r = tracker.process(&pair.left, &pair.right).unwrap();
                pairs += 1;
                if k == 0 {
                    let iou = tilted::left_iou(pair, &r);
                    ious.push(iou);
                    if frames_out {
                        let init = semdepth::init::initialise(&pair.left, &params_copy)
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
                            let png = render_png(frame, None, &[]).unwrap();
                            std::fs::write(format!("{dir}/{}_{seed}_{side}.png", class.name()), png).unwrap();
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
                            let png = render_png(image, None, &overlays).unwrap();
                            let name = format!("{dir}/{}_{seed}_{k:02}{suffix}.png", class.name());
                            std::fs::write(name, png).unwrap();
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
}

//! `cargo xtask track-eval`: tracks the generator's sequences and prints the
//! disparity and centroid errors per condition. "Confident wrong": tracked
//! pairs off by more than 1 px in disparity or 3 px in the left centroid,
//! after removing the sequence's median offsets. For an object that crosses
//! the image border, the left centroid is the point the tracked contour
//! carries where the object's centroid was in the first pair.

use semdepth_core::geometry::CarriedPoint;
use semdepth_core::synth::Shape;
use semdepth_core::synth::{deviations_from_medians, frames, Preset, SynthConfig};
use semdepth_core::tracker::{Status, StereoTracker, TrackerParams};

use crate::Hint;

/// The share of the outline hidden up to which an occluded object is to be
/// held; beyond it, `lost` (reason `occluded`) is right.
const HEAVY_OCCLUSION: f64 = 0.4;

/// What to track and how.
#[derive(clap::Args)]
pub struct Args {
    /// Seeds per condition and shape.
    #[arg(default_value_t = 5)]
    seeds: u64,
    /// Pairs per sequence.
    #[arg(default_value_t = 10)]
    frames: usize,
    /// Conditions, comma-separated (default: the five basic ones).
    #[arg(long)]
    only: Option<String>,
    /// One shape only.
    #[arg(long)]
    shape: Option<String>,
    /// First seed.
    #[arg(long, default_value_t = 0)]
    seed0: u64,
    /// Give the first pair's object as a hint.
    #[arg(long, value_enum)]
    hint: Option<Hint>,
    /// Render with the clean preset's noise.
    #[arg(long)]
    no_noise: bool,
    /// Speed in px per pair, in the seed's drift direction.
    #[arg(long)]
    drift: Option<f64>,
    /// Rotation per pair, radians.
    #[arg(long)]
    rot: Option<f64>,
    /// The pre-filter's sigma, px (0: none).
    #[arg(long)]
    prefilter: Option<f64>,
    /// `max_disparity_std_px`.
    #[arg(long)]
    max_std: Option<f64>,
    /// The energy's lambda.
    #[arg(long)]
    lambda: Option<f64>,
    /// The free fit's vertex spacing, px.
    #[arg(long)]
    spacing: Option<f64>,
    /// The rigid fit's smallest step, px.
    #[arg(long)]
    min_step: Option<f64>,
    /// Occlusion sectors.
    #[arg(long)]
    sectors: Option<usize>,
    /// The rigid template's vertex spacing, px.
    #[arg(long)]
    template_spacing: Option<f64>,
    /// Print every pair (errors of both views against the truth's centroids).
    #[arg(long)]
    frames_out: bool,
    /// Print every sequence's RMS.
    #[arg(long)]
    verbose: bool,
}

/// Largest share of the object's outline (in either view) that the
/// occluder covers: the outline sampled every 0.25 px, points inside the
/// occluder's polygon counted.
fn hidden_outline(truth: &semdepth_core::synth::FrameTruth) -> f64 {
    let Some(occ) = &truth.occluder else {
        return 0.0;
    };
    let share = |object: &semdepth_core::geometry::Polygon, bar: &semdepth_core::geometry::Polygon| {
        let (mut inside, mut all) = (0usize, 0usize);
        for (a, b) in object.edges() {
            let steps = (semdepth_core::geometry::dist(a, b) / 0.25).ceil().max(1.0) as usize;
            for k in 0..steps {
                let t = k as f64 / steps as f64;
                all += 1;
                inside += bar.contains([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]) as usize;
            }
        }
        inside as f64 / all.max(1) as f64
    };
    share(&truth.left.polygon, &occ.left).max(share(&truth.right.polygon, &occ.right))
}

pub fn run(args: Args) -> crate::Result {
    let only: Option<Vec<Preset>> = args
        .only
        .as_deref()
        .map(|list| list.split(',').map(crate::preset).collect::<Result<_, _>>())
        .transpose()?;
    let shape_only = args.shape.as_deref().map(crate::shape).transpose()?;
    let (seeds, nframes) = (args.seeds, args.frames);
    for preset in Preset::ALL {
        // ONLY=occluded,noisy restricts the run to those conditions.
        match &only {
            Some(only) if !only.contains(&preset) => continue,
            None if !Preset::BASIC.contains(&preset) => continue,
            _ => {}
        }
        let (mut heavy_pairs, mut heavy_lost) = (0usize, 0usize);
        let (mut sq_d, mut sq_c, mut n, mut lost, mut worst, mut flagged) =
            (0.0, 0.0, 0usize, 0usize, 0.0f64, 0usize);
        let (mut sum_std, mut n_std) = (0.0f64, 0usize);
        // Tracked pairs, and confident wrong ones, by reported std:
        // <= 0.5, 0.5-1, > 1 px.
        let (mut std_bins, mut wrong_bins) = ([0usize; 3], [0usize; 3]);
        let mut wrong = 0usize;
        let t = std::time::Instant::now();
        for shape in Shape::ALL {
            if shape_only.is_some_and(|s| s != shape) {
                continue;
            }
            let seed0 = args.seed0;
            for seed in seed0..seed0 + seeds {
                let mut cfg = SynthConfig {
                    frames: nframes,
                    ..SynthConfig::preset(preset, shape, seed)
                };
                if args.no_noise {
                    cfg.noise = SynthConfig::preset(Preset::Clean, shape, seed).noise;
                }
                if let Some(v) = args.drift {
                    // Speed in px per pair, in the seed's drift direction.
                    let [dx, dy] = cfg.motion.drift_px_per_frame;
                    let k = v / dx.hypot(dy).max(1e-9);
                    cfg.motion.drift_px_per_frame = [dx * k, dy * k];
                }
                if let Some(v) = args.rot {
                    cfg.motion.rotation_rad_per_frame = v;
                }
                let mut params = TrackerParams {
                    prefilter_sigma_px: args.prefilter,
                    ..TrackerParams::default()
                };
                if let Some(v) = args.max_std {
                    params.max_disparity_std_px = v;
                }
                if let Some(v) = args.lambda {
                    params.energy.lambda = v;
                }
                if let Some(v) = args.spacing {
                    params.free.spacing_px = v;
                }
                if let Some(v) = args.min_step {
                    params.rigid.min_step_px = v;
                }
                if let Some(v) = args.sectors {
                    params.occlusion.sectors = v;
                }
                if let Some(v) = args.template_spacing {
                    params.template_spacing_px = Some(v);
                }
                let pairs: Vec<_> = frames(&cfg)?.collect();
                let first = &pairs[0].truth.left;
                match args.hint {
                    Some(Hint::Roi) => params.init.roi = Some(first.roi_hint(0.1)),
                    Some(Hint::Point) => params.init.point = first.point_hint(cfg.width, cfg.height),
                    None => {}
                }
                let mut tracker = StereoTracker::new(params);
                let mut errs = Vec::new();
                let mut cents: Vec<[f64; 2]> = Vec::new();
                let mut stds: Vec<f64> = Vec::new();
                let mut anchor: Option<CarriedPoint> = None;
                for pair in pairs {
                    let r = tracker.process(&pair.left, &pair.right)?;
                    let hidden = hidden_outline(&pair.truth);
                    let heavy = hidden > HEAVY_OCCLUSION;
                    heavy_pairs += heavy as usize;
                    if r.status == Status::Lost {
                        lost += 1;
                        heavy_lost += heavy as usize;
                        eprintln!(
                            "{}/{}/{seed} frame {}: lost ({:.2} of the outline hidden): {:?}",
                            preset.name(),
                            shape.name(),
                            r.frame,
                            hidden,
                            r.reason
                        );
                        continue;
                    }
                    if r.left.as_ref().unwrap().occluded_fraction > 0.0
                        || r.right.as_ref().unwrap().occluded_fraction > 0.0
                    {
                        flagged += 1;
                    }
                    let d = r.disparity_px.unwrap()[0] - pair.truth.disparity_px[0];
                    if args.frames_out {
                        let (l, rr) = (r.left.as_ref().unwrap(), r.right.as_ref().unwrap());
                        eprintln!(
                            "  frame {}: err {d:+.3} std {:.3} disparity {:.3} (truth {:.3}) left - truth ({:.2}, {:.2}) right - truth ({:.2}, {:.2}) occluded {:.2}/{:.2} (truth {:.2}) energy {:.1}/{:.1}",
                            r.frame,
                            r.disparity_std_px.unwrap_or(f64::NAN),
                            r.disparity_px.unwrap()[0],
                            pair.truth.disparity_px[0],
                            l.centroid[0] - pair.truth.left.visible_centroid[0],
                            l.centroid[1] - pair.truth.left.visible_centroid[1],
                            rr.centroid[0] - pair.truth.right.visible_centroid[0],
                            rr.centroid[1] - pair.truth.right.visible_centroid[1],
                            l.occluded_fraction,
                            rr.occluded_fraction,
                            hidden,
                            l.energy,
                            rr.energy
                        );
                    }
                    // For an object crossing the border, the left
                    // centroid is judged by where the tracked contour puts
                    // the point that was the object's centroid in the
                    // first tracked pair (moved with the contour's own
                    // translation and rotation), against that centroid's
                    // truth: the tracked part's centroid is not the
                    // object's, and a disc cut by the border may turn
                    // about its centre unseen.
                    let left = r.left.as_ref().unwrap();
                    let truth = &pair.truth.left;
                    let carried = anchor.get_or_insert_with(|| {
                        let centroid = if truth.border.is_empty() {
                            truth.centroid
                        } else {
                            left.centroid
                        };
                        CarriedPoint::new(truth.centroid, centroid, left.angle_rad)
                    });
                    let c = carried.at(left.centroid, left.angle_rad);
                    let tc = truth.centroid;
                    sq_c += (c[0] - tc[0]).powi(2) + (c[1] - tc[1]).powi(2);
                    cents.push([c[0] - tc[0], c[1] - tc[1]]);
                    if args.frames_out {
                        eprintln!(
                            "    left centroid error ({:.2}, {:.2})",
                            c[0] - tc[0],
                            c[1] - tc[1]
                        );
                    }
                    errs.push(d);
                    stds.push(r.disparity_std_px.unwrap_or(f64::NAN));
                    if let Some(std) = r.disparity_std_px {
                        (sum_std, n_std) = (sum_std + std, n_std + 1);
                    }
                }
                let mean = errs.iter().sum::<f64>() / errs.len().max(1) as f64;
                // Confident wrong (issue #17): tracked while the disparity
                // is off by more than 1 px or the left centroid by more than
                // 3 px, after removing the sequence's median offsets.
                let deviations = deviations_from_medians(&errs, &cents);
                let seq_wrong = deviations.iter().filter(|d| d.confident_wrong()).count();
                for (d, s) in deviations.iter().zip(&stds) {
                    let k = if *s > 1.0 {
                        2
                    } else if *s > 0.5 {
                        1
                    } else {
                        0
                    };
                    std_bins[k] += 1;
                    if d.confident_wrong() {
                        wrong_bins[k] += 1;
                    }
                }
                if seq_wrong > 0 {
                    eprintln!(
                        "{}/{}/{seed}: {seq_wrong} confident wrong",
                        preset.name(),
                        shape.name()
                    );
                }
                wrong += seq_wrong;
                if args.verbose {
                    let rms = (errs.iter().map(|e| (e - mean).powi(2)).sum::<f64>()
                        / errs.len().max(1) as f64)
                        .sqrt();
                    eprintln!("{}/{}/{seed}: rms {rms:.4}", preset.name(), shape.name());
                }
                let seq_sq: f64 = errs.iter().map(|e| (e - mean).powi(2)).sum();
                let seq_rms = (seq_sq / errs.len().max(1) as f64).sqrt();
                if seq_rms > 0.1 {
                    eprintln!(
                        "{}/{}/{seed}: seq rms {seq_rms:.3} errs {:?}",
                        preset.name(),
                        shape.name(),
                        errs.iter()
                            .map(|e| ((e - mean) * 1000.0).round() / 1000.0)
                            .collect::<Vec<_>>()
                    );
                }
                worst = worst.max(errs.iter().map(|e| (e - mean).abs()).fold(0.0, f64::max));
                sq_d += seq_sq;
                n += errs.len();
            }
        }
        println!(
            "{:>9}: disparity RMS {:.4} px, mean reported std {:.4} px (ratio {:.2}, {n_std} pairs), max {:.3}, confident wrong {wrong}, left centroid RMS {:.3} px, lost {lost}, occlusion flagged in {flagged}, {n} pairs, {:.1} ms/pair incl. rendering",
            preset.name(),
            (sq_d / n as f64).sqrt(),
            sum_std / n_std.max(1) as f64,
            sum_std / n_std.max(1) as f64 / (sq_d / n as f64).sqrt(),
            worst,
            (sq_c / n as f64).sqrt(),
            t.elapsed().as_secs_f64() * 1e3 / (n + lost) as f64
        );
        println!(
            "{:>9}  not tracked: {} of {} pairs with at most {:.0}% of the outline hidden ({:.1}%), {heavy_lost} of {heavy_pairs} with more",
            "",
            lost - heavy_lost,
            n + lost - heavy_pairs,
            100.0 * HEAVY_OCCLUSION,
            100.0 * (lost - heavy_lost) as f64 / (n + lost - heavy_pairs).max(1) as f64
        );
        println!(
            "{:>9}  tracked pairs by reported std <=0.5 / 0.5-1 / >1 px: {:?}, confident wrong among them: {:?}",
            "", std_bins, wrong_bins
        );
    }
    Ok(())
}

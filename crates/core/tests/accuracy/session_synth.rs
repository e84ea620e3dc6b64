//! Two objects in one session (issue #18) against the generator's truth: a
//! tool coming down in steps above a particle, both drifting. Each pair is
//! two generator scenes side by side (the tool's on the left half, the
//! particle's on the right half, each 640x480 with its own height
//! sequence), so each object's true disparity is its scene's and the
//! relative truth is their difference.

use crate::reference;

use semdepth_core::calib::{build, Calibration, CalibrationSpec, GeometricSpec};
use semdepth_core::imageio::GrayFrame;
use semdepth_core::session::Session;
use semdepth_core::synth::{Preset, Scene, Shape, SynthConfig, ZPattern};
use semdepth_core::tracker::Status;

/// Pairs per sequence.
const FRAMES: usize = 24;
/// Unseen seeds (the generator's tuning used 0-9 and 100-104).
const SEEDS: std::ops::Range<u64> = 800..805;
/// Relative disparity error std limit over all sequences (offset removed
/// per sequence), pixels: the 0.2 px-equivalent.
const MAX_RELATIVE_STD_PX: f64 = 0.2;
/// The reported std's mean over the observed error std, both ways.
const MAX_STD_RATIO: f64 = 1.5;
/// Share of pairs on which either object may be untracked.
const MAX_UNTRACKED: f64 = 0.05;
/// Share of pairs on which the tool passing in front of the particle may be
/// untracked ([`a_tool_passing_in_front_of_the_particle`]): on seed 802 it
/// is lost from pair 14 on, where its contour had turned onto the
/// particle's edge (before, it went on turning and was `tracked` 5-36 px
/// off to the end), and its template is not found again while it lies over
/// the particle: 10 of 120 pairs in the clean scenes.
const MAX_TOOL_UNTRACKED: f64 = 0.09;

/// `a` and `b` side by side (same height and bit depth).
fn side_by_side(a: &GrayFrame, b: &GrayFrame) -> GrayFrame {
    assert_eq!((a.height, a.bit_depth), (b.height, b.bit_depth));
    let mut data = Vec::with_capacity((a.width + b.width) as usize * a.height as usize);
    for y in 0..a.height {
        data.extend_from_slice(a.row(y));
        data.extend_from_slice(b.row(y));
    }
    GrayFrame::new(a.width + b.width, a.height, a.bit_depth, data).unwrap()
}

/// The tool's and the particle's scenes for `seed`.
fn scenes(preset: Preset, seed: u64) -> (Scene, Scene) {
    let mut tool = SynthConfig {
        frames: FRAMES,
        ..SynthConfig::preset(preset, Shape::Tip, seed)
    };
    tool.motion.z_pattern = ZPattern::Steps;
    // From the top of the range down in 20-um steps (the generator's
    // staircase climbs and is folded back at 150 um).
    tool.motion.z_range_um = [-150.0, 150.0];
    tool.motion.z_start_um = 150.0;
    tool.motion.z_step_um = 20.0;
    tool.motion.z_hold_frames = 3;
    tool.motion.drift_px_per_frame = [0.6, 0.3];
    let mut particle = SynthConfig {
        frames: FRAMES,
        ..SynthConfig::preset(preset, Shape::Sphere, seed + 1000)
    };
    particle.motion.z_pattern = ZPattern::Constant;
    particle.motion.z_start_um = 0.0;
    particle.motion.drift_px_per_frame = [0.6, 0.3];
    (Scene::new(&tool).unwrap(), Scene::new(&particle).unwrap())
}

/// Micrometres of height per pixel of disparity of the tests' calibration
/// (0.5 um pixels, 6 degrees of vergence: 4.78).
fn um_per_px() -> f64 {
    0.5 / (2.0 * (3.0f64).to_radians().sin())
}

fn std_of(v: &[f64]) -> f64 {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt()
}

fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s[s.len() / 2]
}

#[test]
fn relative_height_of_a_tool_above_a_particle() {
    // 0.5 um pixels, 6 degrees of vergence: 4.78 um per pixel of disparity.
    let calibration: Calibration = build(CalibrationSpec::Geometric(GeometricSpec::new(0.5, 6.0))).unwrap();
    let um_per_px = um_per_px();
    for preset in [Preset::Clean, Preset::Noisy] {
        let (mut errors, mut reported, mut dz_errors, mut dz_reported) = (vec![], vec![], vec![], vec![]);
        let (mut untracked, mut pairs, mut confident_wrong) = (0usize, 0usize, Vec::new());
        for seed in SEEDS {
            let (tool, particle) = scenes(preset, seed);
            let first = (tool.render(0), particle.render(0));
            let width = first.0.left.width as i64;
            let roi_tool = first.0.truth.left.roi_hint(0.1);
            let mut roi_particle = first.1.truth.left.roi_hint(0.1);
            roi_particle[0] += width;
            let object = reference::boxed_object;
            let mut session = Session::new(
                vec![object("tool", roi_tool), object("particle", roi_particle)],
                0,
            )
            .unwrap();
            let (mut seq_err, mut seq_dz_err, mut seq_true) = (vec![], vec![], vec![]);
            for k in 0..FRAMES {
                let (a, b) = (tool.render(k), particle.render(k));
                let left = side_by_side(&a.left, &b.left);
                let right = side_by_side(&a.right, &b.right);
                let m = session.measure(&left, &right, None, Some(&calibration)).unwrap();
                pairs += 1;
                assert_eq!(m.objects.len(), 2);
                assert_eq!(m.relative.len(), 2);
                let ok = m
                    .objects
                    .iter()
                    .all(|o| matches!(o.result.status, Status::Initialised | Status::Tracked));
                let rel = &m.relative[0];
                assert_eq!((rel.from.as_str(), rel.to.as_str()), ("tool", "particle"));
                let back = &m.relative[1];
                if !ok {
                    untracked += 1;
                    assert_eq!(
                        rel.disparity_axis_px, None,
                        "a relative number with an object lost"
                    );
                    continue;
                }
                let truth = a.truth.disparity_px[0] - b.truth.disparity_px[0];
                let d = rel.disparity_axis_px.unwrap();
                assert_eq!(back.disparity_axis_px, Some(-d));
                seq_err.push(d - truth);
                seq_true.push(truth);
                reported.push(rel.disparity_std_px.unwrap());
                seq_dz_err.push(rel.dz_um.unwrap() - truth * um_per_px);
                dz_reported.push(rel.dz_std_um.unwrap());
            }
            let offset = median(&seq_err);
            let dz_offset = median(&seq_dz_err);
            for (e, t) in seq_err.iter().zip(&seq_true) {
                if (e - offset).abs() > 1.0 {
                    confident_wrong.push(format!("seed {seed}: error {:.2} px at truth {t:.2}", e - offset));
                }
            }
            errors.extend(seq_err.iter().map(|e| e - offset));
            dz_errors.extend(seq_dz_err.iter().map(|e| e - dz_offset));
            // The tool came down: the relative truth spans the steps.
            let span = seq_true.iter().cloned().fold(f64::MIN, f64::max)
                - seq_true.iter().cloned().fold(f64::MAX, f64::min);
            assert!(
                span > 1.0,
                "seed {seed}: the tool's height hardly changed ({span:.2} px)"
            );
        }
        let std = std_of(&errors);
        let dz_std = std_of(&dz_errors);
        let ratio = reported.iter().sum::<f64>() / reported.len() as f64 / std;
        let dz_ratio = dz_reported.iter().sum::<f64>() / dz_reported.len() as f64 / dz_std;
        let share = untracked as f64 / pairs as f64;
        println!(
            "{}: relative disparity error std {std:.3} px, dz error std {dz_std:.3} um, std ratio {ratio:.2} (dz {dz_ratio:.2}), untracked {share:.3}",
            preset.name()
        );
        assert!(
            confident_wrong.is_empty(),
            "{}: {confident_wrong:#?}",
            preset.name()
        );
        assert!(
            share <= MAX_UNTRACKED,
            "{}: {untracked} of {pairs} pairs untracked",
            preset.name()
        );
        assert!(
            std <= MAX_RELATIVE_STD_PX,
            "{}: relative disparity error std {std:.3} px (limit {MAX_RELATIVE_STD_PX})",
            preset.name()
        );
        assert!(
            dz_std <= MAX_RELATIVE_STD_PX * um_per_px,
            "{}: dz error std {dz_std:.3} um (limit {:.3})",
            preset.name(),
            MAX_RELATIVE_STD_PX * um_per_px
        );
        for (what, r) in [("disparity", ratio), ("dz", dz_ratio)] {
            assert!(
                (1.0 / MAX_STD_RATIO..=MAX_STD_RATIO).contains(&r),
                "{}: reported {what} std / observed = {r:.2} (expected within a factor {MAX_STD_RATIO})",
                preset.name()
            );
        }
    }
}

/// Fraction of the particle's area the tool hides (left image) beyond which
/// the particle may be reported lost (`occluded`) rather than tracked.
const MAY_LOSE_HIDDEN: f64 = 0.25;

/// The tool passing in front of the particle on `preset`, over [`SEEDS`]
/// (see [`a_tool_passing_in_front_of_the_particle`]).
fn tool_passing_in_front(preset: Preset) -> Passing {
    let calibration: Calibration = build(CalibrationSpec::Geometric(GeometricSpec::new(0.5, 6.0))).unwrap();
    {
        let (mut errors, mut reported, mut dz_errors, mut dz_reported) = (vec![], vec![], vec![], vec![]);
        let mut particle_untracked = 0usize;
        let (mut failures, mut tool_untracked, mut pairs, mut max_hidden) = (vec![], 0usize, 0usize, 0.0f64);
        let mut wandered = vec![];
        for seed in SEEDS {
            let (tool, particle) = reference::tool_over_particle(preset, seed, FRAMES);
            let (a, b) = (tool.render(0), particle.render(0));
            let object = reference::boxed_object;
            let mut session = Session::new(
                vec![
                    object("tool", a.truth.left.roi_hint(0.1)),
                    object("particle", b.truth.left.roi_hint(0.1)),
                ],
                0,
            )
            .unwrap();
            let (mut seq_err, mut seq_reported, mut seq_dz_err) = (vec![], vec![], vec![]);
            let mut own_errors = [vec![], vec![]];
            let mut own_centroid_errors: [Vec<(usize, [f64; 2])>; 2] = [vec![], vec![]];
            for k in 0..FRAMES {
                let (a, b) = (tool.render(k), particle.render(k));
                let (w, h) = (a.left.width, a.left.height);
                let tool_left = a.truth.left.polygon.rasterize(w, h);
                let tool_right = a.truth.right.polygon.rasterize(w, h);
                let under = b.truth.left.polygon.rasterize(w, h);
                let hidden = under.iter().zip(&tool_left).filter(|(p, t)| **p && **t).count() as f64
                    / under.iter().filter(|p| **p).count() as f64;
                max_hidden = max_hidden.max(hidden);
                let left = reference::composite(&b.left, &a.left, &tool_left);
                let right = reference::composite(&b.right, &a.right, &tool_right);
                let m = session.measure(&left, &right, None, Some(&calibration)).unwrap();
                pairs += 1;
                let measured =
                    |i: usize| matches!(m.objects[i].result.status, Status::Initialised | Status::Tracked);
                if !measured(0) {
                    tool_untracked += 1;
                }
                if !measured(1) {
                    particle_untracked += 1;
                }
                if !measured(1) && hidden <= MAY_LOSE_HIDDEN {
                    failures.push(format!(
                        "seed {seed} pair {k}: particle {:?} ({:?}) with {:.0}% hidden",
                        m.objects[1].result.status,
                        m.objects[1].result.reason,
                        100.0 * hidden
                    ));
                }
                let truths = [a.truth.disparity_px[0], b.truth.disparity_px[0]];
                let centroids = [a.truth.left.centroid, b.truth.left.centroid];
                for i in 0..2 {
                    if measured(i) {
                        let d = m.objects[i].result.disparity_axis_px.unwrap();
                        own_errors[i].push((k, d - truths[i]));
                        let c = m.objects[i].result.left.as_ref().unwrap().centroid;
                        own_centroid_errors[i].push((k, [c[0] - centroids[i][0], c[1] - centroids[i][1]]));
                    }
                }
                if measured(0) && measured(1) {
                    let rel = &m.relative[0];
                    seq_err.push(rel.disparity_axis_px.unwrap() - (truths[0] - truths[1]));
                    seq_reported.push(rel.disparity_std_px.unwrap());
                    seq_dz_err.push(rel.dz_um.unwrap() - (truths[0] - truths[1]) * um_per_px());
                    dz_reported.push(rel.dz_std_um.unwrap());
                }
            }
            // Confident wrong: a measured disparity more than 1 px off
            // the truth, or (`wandered`) a left centroid more than 3 px
            // from it, after the sequence's median offsets (issue #17).
            for (i, name) in ["tool", "particle"].into_iter().enumerate() {
                let offsets: Vec<f64> = own_errors[i].iter().map(|e| e.1).collect();
                let offset = median(&offsets);
                for (k, e) in &own_errors[i] {
                    if (e - offset).abs() > 1.0 {
                        failures.push(format!(
                            "seed {seed} pair {k}: {name} disparity {:.2} px off, tracked",
                            e - offset
                        ));
                    }
                }
                let xs: Vec<f64> = own_centroid_errors[i].iter().map(|e| e.1[0]).collect();
                let ys: Vec<f64> = own_centroid_errors[i].iter().map(|e| e.1[1]).collect();
                let (ox, oy) = (median(&xs), median(&ys));
                for (k, e) in &own_centroid_errors[i] {
                    let off = (e[0] - ox).hypot(e[1] - oy);
                    if off > 3.0 {
                        wandered.push(format!(
                            "seed {seed} pair {k}: {name} left centroid {off:.1} px off, tracked"
                        ));
                    }
                }
            }
            let offset = median(&seq_err);
            errors.extend(seq_err.iter().map(|e| e - offset));
            reported.extend(seq_reported);
            let dz_offset = median(&seq_dz_err);
            dz_errors.extend(seq_dz_err.iter().map(|e| e - dz_offset));
        }
        let std = std_of(&errors);
        let ratio = reported.iter().sum::<f64>() / reported.len() as f64 / std;
        let dz_std = std_of(&dz_errors);
        let dz_ratio = dz_reported.iter().sum::<f64>() / dz_reported.len() as f64 / dz_std;
        let share = tool_untracked as f64 / pairs as f64;
        println!(
            "{}: relative disparity error std {std:.3} px over {} pairs, dz error std {dz_std:.3} um, std ratio {ratio:.2} (dz {dz_ratio:.2}), tool untracked {share:.3}, particle untracked {:.3}, particle hidden up to {:.0}%",
            preset.name(),
            errors.len(),
            particle_untracked as f64 / pairs as f64,
            100.0 * max_hidden
        );
        Passing {
            std,
            ratio,
            dz_std,
            dz_ratio,
            tool_untracked: share,
            particle_untracked: particle_untracked as f64 / pairs as f64,
            max_hidden,
            failures,
            wandered,
        }
    }
}

/// What [`tool_passing_in_front`] measured over the seeds.
struct Passing {
    /// Relative disparity error std (offset removed per sequence), pixels.
    std: f64,
    /// Mean reported relative std over `std`.
    ratio: f64,
    /// Relative height error std (offset removed per sequence), um.
    dz_std: f64,
    /// Mean reported `dz_std_um` over `dz_std`.
    dz_ratio: f64,
    /// Share of pairs with the tool in front not measured.
    tool_untracked: f64,
    /// Share of pairs with the particle not measured.
    particle_untracked: f64,
    /// Largest fraction of the particle hidden.
    max_hidden: f64,
    /// Confident wrong pairs by disparity, and the particle lost while
    /// mostly visible.
    failures: Vec<String>,
    /// Pairs tracked with a left centroid more than 3 px off.
    wandered: Vec<String>,
}

/// One object passing in front of the other: a tool 80 um above a particle
/// sweeps down across it, hiding a third of it, in one scene. Each pair is
/// the particle's generator scene with the tool's scene painted over it
/// inside the tool's true outline (its own rim, grey and noise), in both
/// views with each view's outline, so the tool hides the particle with its
/// own disparity. Both objects keep their disparity (no confident wrong
/// pair) and stay tracked (the tool in front is not taken for hidden when
/// its backdrop changes from substrate to particle; the particle is never
/// lost while at most a quarter of it is hidden), and the relative
/// disparity and height hold to the two-object limit (0.2 px, 0.96 um)
/// with a calibrated std.
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn a_tool_passing_in_front_of_the_particle() {
    for preset in [Preset::Clean, Preset::Noisy] {
        let p = tool_passing_in_front(preset);
        assert!(
            p.max_hidden > 0.3,
            "the tool hardly passed over the particle ({:.2})",
            p.max_hidden
        );
        assert!(p.failures.is_empty(), "{}: {:#?}", preset.name(), p.failures);
        for (what, share, limit) in [
            ("tool in front", p.tool_untracked, MAX_TOOL_UNTRACKED),
            ("particle", p.particle_untracked, MAX_UNTRACKED),
        ] {
            assert!(
                share <= limit,
                "{}: the {what} untracked in {:.1}% of pairs",
                preset.name(),
                100.0 * share
            );
        }
        assert!(
            p.std <= MAX_RELATIVE_STD_PX,
            "{}: relative disparity error std {:.3} px (limit {MAX_RELATIVE_STD_PX})",
            preset.name(),
            p.std
        );
        assert!(
            p.dz_std <= MAX_RELATIVE_STD_PX * um_per_px(),
            "{}: dz error std {:.3} um (limit {:.3})",
            preset.name(),
            p.dz_std,
            MAX_RELATIVE_STD_PX * um_per_px()
        );
        for (what, r) in [("disparity", p.ratio), ("dz", p.dz_ratio)] {
            assert!(
                (1.0 / MAX_STD_RATIO..=MAX_STD_RATIO).contains(&r),
                "{}: reported {what} std / observed = {r:.2} (expected within a factor {MAX_STD_RATIO})",
                preset.name()
            );
        }
        // Both contours stay on their objects (left centroid within 3 px
        // of the truth after the offsets). Before, the clean tool of seed
        // 802, once turned onto the particle's edge, went on turning and
        // was `tracked` 5-36 px off from pair 14 (it is lost there now);
        // under noise the tools of seeds 800, 801 and 804, their round
        // heads all that was visible, turned slowly and were `tracked` 3-9
        // px off over pairs 20-23 (they now keep their rotation).
        assert!(p.wandered.is_empty(), "{}: {:#?}", preset.name(), p.wandered);
    }
}

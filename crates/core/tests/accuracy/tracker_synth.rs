//! Tracking accuracy against the synthetic generator's ground truth (issue
//! #3): 4 shapes x 5 seeds per condition, 10 pairs each. The seeds (100..105)
//! differ from those used while tuning the defaults (0..5).
//!
//! Disparity error: measured minus true disparity along x (the default tilt
//! axis is the image y axis); the constant offset of each sequence is removed
//! (it is what a calibration's reference absorbs), then the RMS is taken over
//! all pairs of the condition. Left centroid error: Euclidean, no offset
//! removed. Lost pairs count as failures.

use semdepth_core::geometry::CarriedPoint;
use semdepth_core::synth::{deviations_from_medians, frames, Preset, Shape, SynthConfig, SynthPair};
use semdepth_core::tracker::{PairResult, Status, StereoTracker, TrackerParams};

const SEEDS: std::ops::Range<u64> = 100..105;
const FRAMES: usize = 10;
/// Left centroid RMS limit for every condition (issue #3).
const MAX_CENTROID_RMS_PX: f64 = 0.5;

struct Accuracy {
    disparity_rms: f64,
    /// Mean reported `disparity_std_px` over the tracked pairs divided by
    /// `disparity_rms` (issue #17: calibrated within a factor of 1.5).
    std_ratio: f64,
    centroid_rms: f64,
    /// Largest left centroid error of any pair.
    centroid_max: f64,
    lost: usize,
    pairs: usize,
    /// Tracked pairs off by more than 1 px in disparity or 3 px in the left
    /// centroid, after removing each sequence's median offsets (issue #17).
    confident_wrong: usize,
}

fn measure(preset: Preset, shapes: &[Shape], seeds: std::ops::Range<u64>, frame_count: usize) -> Accuracy {
    let (mut sq_disparity, mut sq_centroid, mut pairs, mut lost) = (0.0, 0.0, 0usize, 0usize);
    let mut sum_std = 0.0;
    let mut centroid_max = 0.0f64;
    let mut confident_wrong = 0usize;
    for &shape in shapes {
        for seed in seeds.clone() {
            let config = SynthConfig {
                frames: frame_count,
                ..SynthConfig::preset(preset, shape, seed)
            };
            let mut tracker = StereoTracker::new(TrackerParams::default());
            let mut errors = Vec::new();
            let mut centroid_errors = Vec::new();
            for pair in frames(&config).unwrap() {
                let result = tracker.process(&pair.left, &pair.right).unwrap();
                if result.status == Status::Lost {
                    eprintln!(
                        "{}/{}/{seed} pair {}: lost: {:?}",
                        preset.name(),
                        shape.name(),
                        result.frame,
                        result.reason
                    );
                    lost += 1;
                    continue;
                }
                errors.push(result.disparity_px.unwrap()[0] - pair.truth.disparity_px[0]);
                sum_std += result
                    .disparity_std_px
                    .expect("a tracked pair has a standard error");
                let (c, t) = (result.left.unwrap().centroid, pair.truth.left.centroid);
                let centroid_error = (c[0] - t[0]).hypot(c[1] - t[1]);
                centroid_errors.push([c[0] - t[0], c[1] - t[1]]);
                sq_centroid += centroid_error.powi(2);
                centroid_max = centroid_max.max(centroid_error);
            }
            for d in deviations_from_medians(&errors, &centroid_errors) {
                if d.confident_wrong() {
                    eprintln!(
                        "{}/{}/{seed}: confident wrong: disparity {:+.2} px, centroid ({:+.1}, {:+.1}) px from the medians",
                        preset.name(),
                        shape.name(),
                        d.disparity_px,
                        d.centroid_px[0],
                        d.centroid_px[1]
                    );
                    confident_wrong += 1;
                }
            }
            let offset = errors.iter().sum::<f64>() / errors.len().max(1) as f64;
            sq_disparity += errors.iter().map(|e| (e - offset).powi(2)).sum::<f64>();
            pairs += errors.len();
        }
    }
    let disparity_rms = (sq_disparity / pairs as f64).sqrt();
    let accuracy = Accuracy {
        disparity_rms,
        std_ratio: sum_std / pairs as f64 / disparity_rms,
        centroid_rms: (sq_centroid / pairs as f64).sqrt(),
        centroid_max,
        lost,
        pairs,
        confident_wrong,
    };
    eprintln!(
        "{:>9}: disparity RMS {:.4} px (reported std / RMS {:.2}), left centroid RMS {:.3} px (max {:.3}), {} pairs, {} lost, {} confident wrong",
        preset.name(),
        accuracy.disparity_rms,
        accuracy.std_ratio,
        accuracy.centroid_rms,
        accuracy.centroid_max,
        accuracy.pairs,
        accuracy.lost,
        accuracy.confident_wrong
    );
    accuracy
}

/// The reported standard error is calibrated (issue #17): its mean over
/// the tracked pairs is within a factor of 1.5 of the observed RMS.
fn assert_calibrated_std(preset: Preset, a: &Accuracy) {
    assert!(
        (1.0 / 1.5..=1.5).contains(&a.std_ratio),
        "{}: mean reported std / observed RMS = {:.2} (expected 0.67..=1.5)",
        preset.name(),
        a.std_ratio
    );
}

/// The condition on the seeds 100..105: no confident wrong pair, at most
/// `max_lost_share` of the pairs not tracked, the std calibrated, and the
/// disparity and left centroid RMS within their limits.
fn check(preset: Preset, max_disparity_rms: f64, max_lost_share: f64) {
    let a = measure(preset, &Shape::ALL, SEEDS, FRAMES);
    let total = Shape::ALL.len() * SEEDS.count() * FRAMES;
    assert_eq!(a.pairs + a.lost, total);
    assert!(
        a.lost as f64 <= max_lost_share * total as f64,
        "{}: {} of {total} pairs not tracked (limit {:.0}%)",
        preset.name(),
        a.lost,
        100.0 * max_lost_share
    );
    assert_eq!(a.confident_wrong, 0, "{}: confident wrong pairs", preset.name());
    assert_calibrated_std(preset, &a);
    assert!(
        a.disparity_rms <= max_disparity_rms,
        "{}: disparity RMS {:.4} px > {max_disparity_rms}",
        preset.name(),
        a.disparity_rms
    );
    assert!(
        a.centroid_rms <= MAX_CENTROID_RMS_PX,
        "{}: left centroid RMS {:.3} px > {MAX_CENTROID_RMS_PX}",
        preset.name(),
        a.centroid_rms
    );
}

#[test]
fn clean_sequences() {
    check(Preset::Clean, 0.05, 0.0);
}

#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn strong_poisson_and_scan_line_noise() {
    check(Preset::Noisy, 0.15, 0.0);
}

#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn quarter_occlusion_entering_after_the_first_pair() {
    // The object stays visible, so at most 5% of the pairs may be untracked
    // (issue #17): a pair whose disparity's standard error grew past
    // `max_disparity_std_px` under the occluder is `uncertain` (measured:
    // 1 of 200, rod 101, 0.64 px).
    check(Preset::Occluded, 0.15, 0.05);
}

#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn grey_level_flicker() {
    check(Preset::Flicker, 0.15, 0.0);
}

#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn cluttered_background() {
    // Not a condition of the issue; held to the noisy limit.
    check(Preset::Cluttered, 0.15, 0.0);
}

/// Issue #17, items 3 and 4: a bright or dark bar at its own height that
/// slides in over up to a third of the object's area and out again on its
/// own (10 pairs), and motion of 15-20 px between pairs with reversals at
/// the frame's margins, 30-40 px from a constant-velocity prediction (20
/// pairs). 4 shapes x seeds 100..105 (developed on 0..10 and 900..905):
/// disparity RMS <= 0.15 px, no confident wrong pair, at most 5% of the
/// pairs not tracked (the object is visible in all), the reported std
/// calibrated. Measured: crossing 0.053 px, fast 0.040 px, none lost.
/// Before the search was held to its disc and a fit that lost the object
/// searched the discs around the prediction and the last pose: fast lost
/// a pair and put one 1.3 px off here (seeds 0..10: 29 of 800 pairs lost,
/// every other pair of a rod), and on crossing seeds 0..10 (20 pairs) a
/// blob's contour was pulled 41 px onto the bar, 9 pairs confident wrong.
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn occluders_moving_on_their_own_and_fast_motion() {
    for (preset, frame_count) in [(Preset::Crossing, FRAMES), (Preset::Fast, 20)] {
        let a = measure(preset, &Shape::ALL, SEEDS, frame_count);
        let total = a.pairs + a.lost;
        assert!(
            a.lost as f64 <= 0.05 * total as f64,
            "{}: {} of {total} pairs not tracked (limit 5%)",
            preset.name(),
            a.lost
        );
        assert_eq!(a.confident_wrong, 0, "{}: confident wrong pairs", preset.name());
        assert!(
            a.disparity_rms <= 0.15,
            "{}: disparity RMS {:.4} px > 0.15",
            preset.name(),
            a.disparity_rms
        );
        assert_calibrated_std(preset, &a);
    }
}

/// Issue #17: strong noise, a quarter occluder and grey-level flicker
/// together, 4 shapes x seeds 100..105, 10 pairs: disparity RMS <= 0.25 px,
/// no confident wrong pair, at most 5% not tracked, the std calibrated.
/// Measured: 0.125 px, 6 of 200 pairs not tracked (`occluded` or
/// `uncertain`), std ratio 1.02 (0.120 px, 8 pairs and 1.14 before the
/// masked runs' shift was cleared of what the noise gives it).
/// Before, a rod half under a bright bar parallel to it was taken 24 px
/// onto the bar, its median sector at 0.06 of its first contrast, and
/// reported 0% occluded and `tracked` 1.5-3 px off: 0.293 px, 5 confident
/// wrong. On seeds 900..905 rod 902 was 1.1 px off at 2.7 standard errors
/// while its limit was four times its first pair's (see
/// `an_object_first_measured_within_the_limit_is_held_to_it`); tip 116
/// (seeds 100..119), 1.2 px off at 2.6 standard errors (0.46 px), is
/// `uncertain` since the default `max_disparity_std_px` is 0.4 px (rod
/// 118's slide over a run of `uncertain` pairs is caught: see
/// `a_run_of_uncertain_pairs_does_not_walk_the_contour_off_unnoticed`).
/// Seeds 300..305 no longer show rod 302 sliding along its axis (see
/// `a_move_the_visible_outline_does_not_fix_is_not_followed`).
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn noise_occlusion_and_flicker_together() {
    let a = measure(Preset::Combined, &Shape::ALL, SEEDS, FRAMES);
    let total = a.pairs + a.lost;
    assert!(
        a.lost as f64 <= 0.05 * total as f64,
        "{} of {total} pairs not tracked (limit 5%)",
        a.lost
    );
    assert_eq!(a.confident_wrong, 0, "confident wrong pairs");
    assert!(
        a.disparity_rms <= 0.25,
        "disparity RMS {:.4} px > 0.25",
        a.disparity_rms
    );
    assert_calibrated_std(Preset::Combined, &a);
}

#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn long_sequences_follow_the_rotating_object() {
    // 45 pairs while the object turns by up to 0.01 rad per pair: a template
    // that does not turn with it drifts (blob seed 1 reached 0.9 px here, and
    // 2.7 px at 1024x768, before blob outlines counted as rotation-observable).
    const LONG_FRAMES: usize = 45;
    let seeds = 0..3;
    let a = measure(Preset::Clean, &Shape::ALL, seeds.clone(), LONG_FRAMES);
    assert_eq!(a.pairs + a.lost, Shape::ALL.len() * seeds.count() * LONG_FRAMES);
    assert_clean_tracking(&a);
}

/// No pair lost, disparity RMS within the clean limit, and every pair's
/// left centroid within the centroid limit.
fn assert_clean_tracking(a: &Accuracy) {
    assert_eq!(a.lost, 0, "{} pairs lost", a.lost);
    assert!(
        a.disparity_rms <= 0.05,
        "disparity RMS {:.4} px > 0.05",
        a.disparity_rms
    );
    assert!(
        a.centroid_max <= MAX_CENTROID_RMS_PX,
        "largest left centroid error {:.3} px > {MAX_CENTROID_RMS_PX}",
        a.centroid_max
    );
}

#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn an_edge_chain_touching_the_outline_does_not_become_part_of_it() {
    // Clean tip, seed 201: a chain of background edges met the tip's outline
    // and the initial outline ran 300 px out along it and back. The tail
    // carried 19 of 24 occlusion sectors; occlusion was flagged from pair 2,
    // the pair was lost at 5 and the disparity error reached 2.2 px.
    let seeds = 201..202;
    let a = measure(Preset::Clean, &[Shape::Tip], seeds, 20);
    assert_clean_tracking(&a);
}

/// Tools entering from an image border (issue #16): the base lies outside
/// the frame and the tool moves 5-20 px per pair in and out along its axis.
/// Per shape over seeds 800..810 (not used while developing: 300-304,
/// 500-504, 600-604 and 700-704 were), 10 pairs each: no pair lost, the
/// left contour on the object in every pair (at least 95% of its area on
/// the frame-clipped truth; it covers only the part seen on the first pair,
/// so a tool that moved in is covered up to where the border was), and the
/// disparity RMS (offset per sequence removed) within the 0.15 px
/// for every shape (measured 0.054 / 0.059 / 0.057 / 0.076 px; a slender tip
/// entering along the disparity axis reached 0.28 px before the right view
/// was held to its epipolar line, where it slid along its own axis). The
/// reported standard error is calibrated within a factor of 1.5 over all
/// of them (measured 0.90; 0.83 before the cuts' share of the noise).
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn tools_entering_from_the_border_are_tracked() {
    use semdepth_core::geometry::Polygon;
    const SEEDS: std::ops::Range<u64> = 800..810;
    let (mut pooled, mut reported) = ((0.0, 0usize), 0.0);
    for (shape, limit) in [
        (Shape::Blob, 0.15),
        (Shape::Sphere, 0.15),
        (Shape::Rod, 0.15),
        (Shape::Tip, 0.15),
    ] {
        let (mut sq, mut pairs, mut worst_on) = (0.0, 0usize, 1.0f64);
        for seed in SEEDS {
            let config = border_tool_config(shape, seed);
            let mut errors = Vec::new();
            for (result, pair) in tracked_sequence(&config) {
                assert_ne!(
                    result.status,
                    Status::Lost,
                    "{}/{seed} pair {}: {:?}",
                    shape.name(),
                    result.frame,
                    result.reason
                );
                errors.push(result.disparity_px.unwrap()[0] - pair.truth.disparity_px[0]);
                reported += result.disparity_std_px.expect("a tracked pair has a std");
                let (w, h) = (config.width, config.height);
                let contour = Polygon::new(result.left.unwrap().contour);
                let (ours, truth) = (
                    contour.rasterize(w, h),
                    pair.truth.left.visible_polygon.rasterize(w, h),
                );
                let on = ours.iter().zip(&truth).filter(|(a, b)| **a && **b).count();
                let area = ours.iter().filter(|a| **a).count();
                worst_on = worst_on.min(on as f64 / area.max(1) as f64);
            }
            let offset = errors.iter().sum::<f64>() / errors.len() as f64;
            sq += errors.iter().map(|e| (e - offset).powi(2)).sum::<f64>();
            pairs += errors.len();
        }
        let rms = (sq / pairs as f64).sqrt();
        eprintln!(
            "border_tool/{}: disparity RMS {rms:.4} px, least share of the left contour on the object {worst_on:.3}, {pairs} pairs",
            shape.name()
        );
        assert!(
            rms <= limit,
            "{}: disparity RMS {rms:.4} px > {limit}",
            shape.name()
        );
        assert!(
            worst_on >= 0.95,
            "{}: only {worst_on:.3} of a left contour on the object (< 0.95)",
            shape.name()
        );
        pooled = (pooled.0 + sq, pooled.1 + pairs);
    }
    let rms = (pooled.0 / pooled.1 as f64).sqrt();
    let ratio = reported / pooled.1 as f64 / rms;
    eprintln!("border_tool: disparity RMS {rms:.4} px, mean reported std / RMS {ratio:.2}");
    assert!(
        (1.0 / 1.5..=1.5).contains(&ratio),
        "border tools: mean reported std / observed RMS = {ratio:.2} (expected 0.67..=1.5)"
    );
}

/// The other new scene classes of issue #16, 4 shapes x seeds 900..905 (not
/// used while developing), 10 pairs each: at most 5% of the pairs not
/// tracked (issue #17; measured: relief rod 903's pair 5 `uncertain` at
/// 0.42 px, the others none) and none confidently wrong, the reported
/// standard error calibrated within a factor of 1.5.
/// Scratches and fibres under the object, a dark object with a bright rim
/// and a relief substrate: within the 0.15 px (measured 0.042,
/// 0.097 and 0.113; the dark scene 0.119 with 3 confident wrong pairs
/// before the free fit's spurs were cut). Defocus
/// blur at low dose: within the 0.2 px (measured 0.154; 0.252
/// before both images were smoothed to the blurred edge's width).
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn scratched_dark_blurred_and_relief_scenes() {
    for (preset, limit) in [
        (Preset::Scratched, 0.15),
        (Preset::Dark, 0.15),
        (Preset::Blurred, 0.2),
        (Preset::Relief, 0.15),
    ] {
        let a = measure(preset, &Shape::ALL, 900..905, FRAMES);
        let total = a.pairs + a.lost;
        assert!(
            a.lost * 20 <= total,
            "{}: {} of {total} pairs not tracked",
            preset.name(),
            a.lost
        );
        assert_eq!(
            a.confident_wrong,
            0,
            "{}: {} confident wrong pairs",
            preset.name(),
            a.confident_wrong
        );
        assert_calibrated_std(preset, &a);
        assert!(
            a.disparity_rms <= limit,
            "{}: disparity RMS {:.4} px > {limit}",
            preset.name(),
            a.disparity_rms
        );
    }
}

/// No confident wrong pair on tools entering from the border, seeds
/// 900..910 (4 shapes, 10 pairs each): every tracked pair's disparity lies
/// within 1 px of the truth and its left contour within 3 px, after
/// removing the sequence's median offsets. The contour's position is that
/// of the point it carries where the object's centroid was in the first
/// pair (the visible part's centroid is not the object's). A rod (seed
/// 904, pair 6) had its left contour settle 7 px along its axis while the
/// right one stayed on the object: 6.8 px off, `tracked`, until the left
/// view was fitted again from the right view's result when both fits left
/// their predictions by more than 1.5 px. Before the fits' domain was fixed
/// in the image, 1 tool in 10 (seeds 100..120 and 200..210) slid along its
/// axis, up to 20 px, with the disparity right.
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn border_tools_have_no_confident_wrong_pairs() {
    let mut wrong = Vec::new();
    let mut worst = (0.0f64, 0.0f64);
    for shape in Shape::ALL {
        for seed in 900..910 {
            let (mut errors, mut centroids, mut frames_seen) = (Vec::new(), Vec::new(), Vec::new());
            let mut anchor = None;
            for (result, pair) in tracked_sequence(&border_tool_config(shape, seed)) {
                if !matches!(result.status, Status::Tracked | Status::Initialised) {
                    continue;
                }
                let d = result.disparity_px.expect("a tracked pair has a disparity");
                errors.push(d[0] - pair.truth.disparity_px[0]);
                let left = result.left.expect("a tracked pair has a left view");
                let truth = pair.truth.left.centroid;
                // The object's centroid relative to the contour in the first pair.
                let carried = anchor
                    .get_or_insert_with(|| CarriedPoint::new(truth, left.centroid, left.angle_rad))
                    .at(left.centroid, left.angle_rad);
                centroids.push([carried[0] - truth[0], carried[1] - truth[1]]);
                frames_seen.push(result.frame);
            }
            for (d, frame) in deviations_from_medians(&errors, &centroids)
                .iter()
                .zip(frames_seen)
            {
                worst = (
                    worst.0.max(d.disparity_px.abs()),
                    worst.1.max(d.centroid_px[0].hypot(d.centroid_px[1])),
                );
                if d.confident_wrong() {
                    wrong.push(format!(
                        "{}/{seed} pair {frame}: disparity {:+.2} px, centroid ({:+.1}, {:+.1}) px",
                        shape.name(),
                        d.disparity_px,
                        d.centroid_px[0],
                        d.centroid_px[1]
                    ));
                }
            }
        }
    }
    eprintln!(
        "border tools, seeds 900..910: largest deviation from the medians {:.3} px in disparity, {:.2} px in position",
        worst.0, worst.1
    );
    assert!(wrong.is_empty(), "confident wrong, reported tracked: {wrong:#?}");
}

/// A border-tool sequence of [`FRAMES`] pairs.
fn border_tool_config(shape: Shape, seed: u64) -> SynthConfig {
    SynthConfig {
        frames: FRAMES,
        ..SynthConfig::preset(Preset::BorderTool, shape, seed)
    }
}

/// Every pair of `config`'s sequence with its result from one tracker on
/// default parameters.
/// Confident wrong pairs among tracked ones, from their disparity errors
/// along x and left centroid errors (after the medians; see
/// [`deviations_from_medians`]).
fn confident_wrong(errors: &[f64], centroids: &[[f64; 2]]) -> usize {
    deviations_from_medians(errors, centroids)
        .iter()
        .filter(|d| d.confident_wrong())
        .count()
}

/// Tracks `config` (called `name`) and checks every pair with a number against the truth,
/// after the first such pair's offsets: its left centroid within
/// `max_moved_px` and its disparity within `max_disparity_px`. Returns how
/// many pairs had numbers and the reasons of the others.
fn assert_held(
    name: &str,
    config: &SynthConfig,
    max_moved_px: f64,
    max_disparity_px: f64,
) -> (usize, Vec<String>) {
    let (mut first, mut tracked, mut reasons) = (None, 0, Vec::new());
    for (result, pair) in tracked_sequence(config) {
        let Some(error) = truth_errors(&result, &pair) else {
            reasons.push(result.reason.unwrap_or_default());
            continue;
        };
        tracked += 1;
        let (e0, c0) = *first.get_or_insert(error);
        let moved = (error.1[0] - c0[0]).hypot(error.1[1] - c0[1]);
        assert!(
            moved <= max_moved_px && (error.0 - e0).abs() <= max_disparity_px,
            "{name} pair {}: left centroid {moved:.2} px, disparity {:+.2} px off the first pair's offsets",
            result.frame,
            error.0 - e0
        );
    }
    (tracked, reasons)
}

fn tracked_sequence(config: &SynthConfig) -> impl Iterator<Item = (PairResult, SynthPair)> {
    tracked_with(config, TrackerParams::default())
}

fn tracked_with(
    config: &SynthConfig,
    params: TrackerParams,
) -> impl Iterator<Item = (PairResult, SynthPair)> {
    let mut tracker = StereoTracker::new(params);
    frames(config).unwrap().map(move |pair| {
        let result = tracker.process(&pair.left, &pair.right).unwrap();
        (result, pair)
    })
}

/// A pair's errors against its truth (measured minus true): the disparity
/// along x and the left centroid; `None` for a pair without numbers.
fn truth_errors(result: &PairResult, pair: &SynthPair) -> Option<(f64, [f64; 2])> {
    let (d, left) = (result.disparity_px?, result.left.as_ref()?);
    let t = pair.truth.left.centroid;
    Some((
        d[0] - pair.truth.disparity_px[0],
        [left.centroid[0] - t[0], left.centroid[1] - t[1]],
    ))
}

/// Tracks pairs 0-4 of `scene`, each `initialised` or `tracked`, then
/// feeds two blank pairs of grey `blank` (the beam blanked), each `lost`
/// without a disparity; returns pair 4's disparity and left centroid errors
/// ([`truth_errors`]), the offsets of the template's reference point.
fn lost_after_five_pairs(
    scene: &semdepth_core::synth::Scene,
    tracker: &mut StereoTracker,
    blank: u16,
    name: &str,
) -> (f64, [f64; 2]) {
    let mut offsets = (0.0, [0.0; 2]);
    for k in 0..5 {
        let pair = scene.render(k);
        let r = tracker.process(&pair.left, &pair.right).unwrap();
        assert!(
            matches!(r.status, Status::Initialised | Status::Tracked),
            "{name} pair {k}: {:?}",
            r.reason
        );
        offsets = truth_errors(&r, &pair).expect("a tracked pair has numbers");
    }
    let config = scene.config();
    let blank = semdepth_core::imageio::GrayFrame::filled(config.width, config.height, 8, blank);
    for k in 0..2 {
        let r = tracker.process(&blank, &blank).unwrap();
        assert_eq!(r.status, Status::Lost, "{name} blank pair {k}: {:?}", r.reason);
        assert!(
            r.disparity_px.is_none(),
            "{name}: a lost pair carries no disparity"
        );
    }
    offsets
}

/// A sequence tracked from its first pair: the disparity and left
/// centroid errors of the pairs with numbers, and "pair N: reason" for the
/// others.
fn errors_and_reasons(config: &SynthConfig, params: TrackerParams) -> (Vec<f64>, Vec<[f64; 2]>, Vec<String>) {
    let (mut errors, mut centroids, mut reasons) = (Vec::new(), Vec::new(), Vec::new());
    for (result, pair) in tracked_with(config, params) {
        match truth_errors(&result, &pair) {
            Some((d, c)) => {
                errors.push(d);
                centroids.push(c);
            }
            None => reasons.push(format!(
                "pair {}: {}",
                result.frame,
                result.reason.unwrap_or_default()
            )),
        }
    }
    (errors, centroids, reasons)
}

/// Tracks `frames` pairs of `preset`, `shape` and `seed` with the default
/// parameters and requires no confident wrong pair; prints and returns
/// the tracked pairs' disparity errors and the other pairs' reasons.
fn without_confident_wrong(
    preset: Preset,
    shape: Shape,
    seed: u64,
    frames: usize,
) -> (Vec<f64>, Vec<String>) {
    let config = SynthConfig {
        frames,
        ..SynthConfig::preset(preset, shape, seed)
    };
    let (errors, centroids, reasons) = errors_and_reasons(&config, TrackerParams::default());
    eprintln!("errors {errors:+.2?}; not tracked: {reasons:#?}");
    assert_eq!(confident_wrong(&errors, &centroids), 0, "confident wrong pairs");
    (errors, reasons)
}

/// Issue #17, item 4: after a loss the object is sought by its own
/// template, not initialised afresh on whatever is largest. Fast sequences
/// (15-20 px per pair), 4 shapes x seeds 100..103: pairs 0-4 are tracked,
/// then two blank pairs (the beam blanked) lose the object and find
/// nothing, then pair 12 (the object 100-160 px away) is `tracked` with
/// reason `reacquired`: its disparity within 0.3 px and its left centroid
/// within 2 px of the truth, after the offsets of pair 4 (the template's
/// own reference point and disparity offset).
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn a_lost_object_is_found_again_by_its_template() {
    use semdepth_core::synth::Scene;
    use semdepth_core::tracker::{Phase, REACQUIRED, REACQUIRE_PAIRS};
    for shape in Shape::ALL {
        for seed in 100..103 {
            let name = format!("fast/{}/{seed}", shape.name());
            let config = SynthConfig {
                frames: 13,
                ..SynthConfig::preset(Preset::Fast, shape, seed)
            };
            let scene = Scene::new(&config).unwrap();
            let mut tracker = StereoTracker::new(TrackerParams::default());
            let (d0, c0) = lost_after_five_pairs(&scene, &mut tracker, 90, &name);
            assert_eq!(
                tracker.state().unwrap().phase,
                Phase::Searching { missed: 1 },
                "{name}: one search missed"
            );
            const { assert!(REACQUIRE_PAIRS > 1) };
            let pair = scene.render(12);
            let r = tracker.process(&pair.left, &pair.right).unwrap();
            assert_eq!(r.status, Status::Tracked, "{name}: {:?}", r.reason);
            assert_eq!(r.reason.as_deref(), Some(REACQUIRED), "{name}");
            let (d, c) = truth_errors(&r, &pair).expect("a tracked pair has numbers");
            let (d, off) = (d - d0, (c[0] - c0[0]).hypot(c[1] - c0[1]));
            eprintln!("{name}: reacquired, disparity {d:+.3} px, left centroid {off:.2} px from the truth");
            assert!(d.abs() <= 0.3, "{name}: disparity {d:+.3} px off");
            assert!(off <= 2.0, "{name}: left centroid {off:.2} px off");
            let next = tracker
                .process(&scene.render(12).left, &scene.render(12).right)
                .unwrap();
            assert_eq!(
                next.status,
                Status::Tracked,
                "{name}: the pair after: {:?}",
                next.reason
            );
            assert_eq!(next.reason, None, "{name}");
        }
    }
}

/// Issue #17, item 4: a rod lost under a bright bar is found again by its
/// template once the bar has left it, though the bar still lies beside it
/// (crossing, seed 118, 20 pairs: lost at pair 7, the bar off its outline
/// at pair 9). The bar gives many minima of the template's energy lower
/// than the rod's, and it changes the contrast of the rod's sectors that
/// face it (0.38-0.5 of them): with the five lowest minima fitted and a
/// quarter of the sectors changed allowed, the rod stayed lost to the end.
/// Required: a pair among 8-10 `tracked` with reason `reacquired`, its
/// disparity within 0.5 px and its left centroid within 2 px of the truth
/// (after the first pair's offsets).
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn a_rod_beside_a_bright_bar_is_found_again() {
    use semdepth_core::tracker::REACQUIRED;
    let config = SynthConfig {
        frames: 20,
        ..SynthConfig::preset(Preset::Crossing, Shape::Rod, 118)
    };
    let mut offsets = None;
    let mut reacquired = None;
    for (result, pair) in tracked_sequence(&config).take(11) {
        let Some(errors) = truth_errors(&result, &pair) else {
            continue;
        };
        let (d0, c0) = *offsets.get_or_insert(errors);
        if result.frame >= 8 && result.reason.as_deref() == Some(REACQUIRED) {
            assert_eq!(result.status, Status::Tracked);
            let off = (errors.1[0] - c0[0]).hypot(errors.1[1] - c0[1]);
            reacquired = Some((result.frame, errors.0 - d0, off));
            break;
        }
    }
    let (frame, d, off) = reacquired.expect("the rod is found again by pair 10");
    eprintln!("reacquired at pair {frame}: disparity {d:+.3} px, left centroid {off:.2} px from the truth");
    assert!(d.abs() <= 0.5, "pair {frame}: disparity {d:+.3} px off");
    assert!(off <= 2.0, "pair {frame}: left centroid {off:.2} px off");
}

/// Issue #17, item 3: the template search after a loss does not take a
/// bar for the object. Crossing rod 2005 (20 pairs): a bright bar lies
/// along the rod from pair 2, and the rod's template, placed inside the
/// bar along its edge, kept most sectors' contrast (the median at
/// 0.87-0.91 of the first pair's) while its inside showed 0.62-0.72 of the
/// rod's grey against the same background; taken at pair 9, it was
/// `reacquired` 36 px off. The rod is lost here by two blank pairs after
/// pair 4; of pairs 7-13, none may be `tracked` with its disparity more
/// than 1 px or its left centroid more than 3 px off the truth (after
/// pair 4's offsets).
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn a_bar_beside_a_lost_rod_is_not_taken_for_it() {
    use semdepth_core::synth::Scene;
    let config = SynthConfig {
        frames: 20,
        ..SynthConfig::preset(Preset::Crossing, Shape::Rod, 2005)
    };
    let scene = Scene::new(&config).unwrap();
    let mut tracker = StereoTracker::new(TrackerParams::default());
    let offsets = lost_after_five_pairs(&scene, &mut tracker, 60, "crossing/rod/2005");
    for k in 7..14 {
        let pair = scene.render(k);
        let r = tracker.process(&pair.left, &pair.right).unwrap();
        let Some((d, c)) = truth_errors(&r, &pair) else {
            eprintln!("pair {k}: {:?}", r.reason);
            continue;
        };
        let (d, off) = (d - offsets.0, (c[0] - offsets.1[0]).hypot(c[1] - offsets.1[1]));
        eprintln!(
            "pair {k}: {:?} {:?}, disparity {d:+.2} px, left centroid {off:.1} px off",
            r.status, r.reason
        );
        if r.status == Status::Tracked {
            assert!(
                d.abs() <= 1.0 && off <= 3.0,
                "pair {k}: tracked {d:+.2} px / {off:.1} px off"
            );
        }
    }
}

/// Issue #17: an object first measured within `max_disparity_std_px` is
/// held to it. Combined rod 902, 10 pairs (seeds 900..905's run): a dark
/// bar first covers its right end at pair 1, and its standard error grows
/// from 0.14 px to 0.40 px; against four times its first pair's (0.55
/// px) the pair was `tracked` 1.0 px off. Held to 0.4 px, pair 1 is
/// `uncertain`, and as the object's velocity was not yet measured, its
/// move from the first pose (the rod's own 3 px drift) does not end the
/// run of uncertain pairs and lose the rod. Required: no confident wrong
/// pair, pair 1 `uncertain`, at least 7 of the 10 pairs `tracked`
/// (measured: 7, pairs 5 and 6 `uncertain` too at 0.46 and 0.53 px).
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn an_object_first_measured_within_the_limit_is_held_to_it() {
    use semdepth_core::tracker::UNCERTAIN;
    let (errors, reasons) = without_confident_wrong(Preset::Combined, Shape::Rod, 902, 10);
    assert!(
        reasons
            .iter()
            .any(|r| r.starts_with(&format!("pair 1: {UNCERTAIN}"))),
        "pair 1 is not uncertain: {reasons:#?}"
    );
    assert!(
        errors.len() >= 7,
        "{} of 10 pairs tracked: {reasons:#?}",
        errors.len()
    );
}

/// Issue #17, item 3: a dark bar that sweeps along a rod's long side
/// without covering it (crossing rod 1017, 20 pairs; an unseen seed) raises
/// the contrast of half its sectors. Where that moved the left fit, the
/// pose's move without those sectors is a bias the standard error carries;
/// it was measured as none, on tables whose guard the rod's band at its
/// ends reached into, and pairs 3 and 13 were `tracked` 1.08 and 1.00 px
/// off at a reported 0.30 and 0.28 px. Required: no confident wrong pair,
/// and at least 3 of the 20 pairs `tracked` (measured: 3; the bar lies
/// beside the rod or over it in the others).
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn a_dark_bar_beside_a_rod_does_not_move_it_unreported() {
    let (errors, reasons) = without_confident_wrong(Preset::Crossing, Shape::Rod, 1017, 20);
    assert!(
        errors.len() >= 3,
        "{} of 20 pairs tracked: {reasons:#?}",
        errors.len()
    );
}

/// Issue #17, item 3: a bright bar as bright as a rod, and wider, over the
/// rod's upper half along its length (combined rod 2017, 20 pairs; an
/// unseen seed; 38% of the outline hidden). On pair 1 the full fit ran to
/// the edge of the search disc and the masked fit walked on: both contours
/// went 31 px onto the bar, `tracked` 1.29 px off at a reported 0.26 px.
/// Required: no confident wrong pair, and pair 1 `lost` as occluded, its
/// move past the search radius named.
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn a_bar_as_bright_as_a_rod_does_not_take_its_contour_unreported() {
    let (_, reasons) = without_confident_wrong(Preset::Combined, Shape::Rod, 2017, 20);
    assert!(
        reasons
            .iter()
            .any(|r| r.starts_with("pair 1: occluded") && r.contains("past the search radius")),
        "pair 1 is not lost past the search radius: {reasons:#?}"
    );
}

/// Issue #17, item 3: a bar 1.11-1.26 times a rod's grey along the rod
/// (occluded rod 2008, 20 pairs; an unseen seed), hiding 47% of its
/// outline from pair 1 on. At pair 3 the fit slid 3.2 px along the rod with
/// 58% of its sectors left out and was `tracked` with its left centroid
/// 4.0 px along the axis. Required: no confident wrong pair, and pair 3
/// `lost` as occluded, its move named.
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn a_rod_sliding_along_a_bar_is_not_tracked_off() {
    let (_, reasons) = without_confident_wrong(Preset::Occluded, Shape::Rod, 2008, 20);
    assert!(
        reasons
            .iter()
            .any(|r| r.starts_with("pair 3: occluded") && r.contains("from its prediction (more than")),
        "pair 3 is not lost for its move: {reasons:#?}"
    );
}

/// Issue #17, item 5: 200 pairs while the object turns by 0.005 rad per
/// pair and drifts 0.5-3 px per pair (reflected at the frame's margins),
/// 4 shapes, seed 100, noise of the clean preset: the left centroid's error,
/// after removing the first pair's offset, stays under 0.5 px to the end;
/// disparity RMS <= 0.15 px; no pair lost. Measured: largest centroid
/// error 0.2 px, disparity RMS 0.02 px.
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn two_hundred_turning_pairs_do_not_creep() {
    for shape in Shape::ALL {
        let name = format!("clean/{}/100, 200 pairs", shape.name());
        let mut config = SynthConfig {
            frames: 200,
            ..SynthConfig::preset(Preset::Clean, shape, 100)
        };
        config.motion.rotation_rad_per_frame = 0.005;
        let mut tracker = StereoTracker::new(TrackerParams::default());
        let (mut first, mut worst, mut errors) = (None, (0.0f64, 0u64), Vec::new());
        for pair in frames(&config).unwrap() {
            let r = tracker.process(&pair.left, &pair.right).unwrap();
            assert_ne!(r.status, Status::Lost, "{name} pair {}: {:?}", r.frame, r.reason);
            let (c, t) = (r.left.unwrap().centroid, pair.truth.left.centroid);
            let offset = *first.get_or_insert([c[0] - t[0], c[1] - t[1]]);
            let creep = (c[0] - t[0] - offset[0]).hypot(c[1] - t[1] - offset[1]);
            if creep > worst.0 {
                worst = (creep, r.frame);
            }
            errors.push(r.disparity_px.unwrap()[0] - pair.truth.disparity_px[0]);
        }
        let mean = errors.iter().sum::<f64>() / errors.len() as f64;
        let rms = (errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / errors.len() as f64).sqrt();
        eprintln!(
            "{name}: largest centroid creep {:.3} px (pair {}), disparity RMS {rms:.4} px",
            worst.0, worst.1
        );
        assert!(
            worst.0 < 0.5,
            "{name}: the left centroid crept {:.3} px by pair {}",
            worst.0,
            worst.1
        );
        assert!(rms <= 0.15, "{name}: disparity RMS {rms:.4} px > 0.15");
    }
}

/// Issue #17, item 3: when too little of the object is visible to trust,
/// the pair is lost with reason `occluded`, not tracked elsewhere. Strong
/// noise, an occluder and flicker together (rod, seed 9): on pair 1 the
/// occluder hides 58% of the left outline and the right view's search along
/// its line found a pose 32 px away; that pair was reported `tracked`.
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn a_disparity_that_jumps_under_heavy_occlusion_is_not_trusted() {
    // The sequence's length shapes its motion: pairs 0 and 1 of 20.
    let config = SynthConfig {
        frames: 20,
        ..SynthConfig::preset(Preset::Combined, Shape::Rod, 9)
    };
    let mut tracker = StereoTracker::new(TrackerParams::default());
    let results: Vec<(PairResult, SynthPair)> = frames(&config)
        .unwrap()
        .take(2)
        .map(|pair| (tracker.process(&pair.left, &pair.right).unwrap(), pair))
        .collect();
    let offset = results[0].0.disparity_px.unwrap()[0] - results[0].1.truth.disparity_px[0];
    let (r, pair) = &results[1];
    match r.status {
        Status::Lost => {
            let reason = r.reason.as_deref().unwrap_or_default();
            assert!(reason.starts_with("occluded"), "{reason}");
            assert!(r.disparity_px.is_none());
        }
        _ => {
            let e = r.disparity_px.unwrap()[0] - pair.truth.disparity_px[0] - offset;
            assert!(e.abs() < 1.0, "tracked {e:+.2} px off the truth: {:?}", r.reason);
        }
    }
}

/// Tracks `shape` on `preset` (seed `seed`, a 26-pair sequence) through
/// pairs 0, 0, 0 (standing still) and then every `stride`th pair up to
/// `last` (`examples/restart_probe`); asserts that every pair with numbers
/// lies within 1 px of disparity and 3 px of left centroid of the truth
/// after the first pair's offsets, and that at least one pair has them.
/// Returns the reasons of the pairs without numbers.
fn restarted_within_truth(
    preset: Preset,
    shape: Shape,
    seed: u64,
    stride: usize,
    last: usize,
) -> Vec<String> {
    let name = format!("{} {} {seed}", preset.name(), shape.name());
    let config = SynthConfig {
        frames: 26,
        ..SynthConfig::preset(preset, shape, seed)
    };
    let scene = semdepth_core::synth::Scene::new(&config).unwrap();
    let mut tracker = StereoTracker::new(TrackerParams::default());
    let mut offsets = None;
    let mut reasons = Vec::new();
    for k in [0, 0, 0].into_iter().chain((stride..=last).step_by(stride)) {
        let pair = scene.render(k);
        let r = tracker.process(&pair.left, &pair.right).unwrap();
        let Some((d, c)) = truth_errors(&r, &pair) else {
            reasons.push(r.reason.unwrap_or_default());
            continue;
        };
        let (d0, c0) = *offsets.get_or_insert((d, c));
        let (dd, dc) = ((d - d0).abs(), (c[0] - c0[0]).hypot(c[1] - c0[1]));
        assert!(
            dd <= 1.0 && dc <= 3.0,
            "{name} pair {k}: {:?} {dd:.2} px of disparity and {dc:.1} px of left centroid off ({:?})",
            r.status,
            r.reason
        );
    }
    assert!(offsets.is_some(), "{name}: never tracked");
    reasons
}

/// An object that stood still for three pairs starts to move at three
/// times its drift just as the preset's bright bar comes over a quarter of
/// it (pairs 0, 0, 0, then every third pair to 12 of a 26-pair sequence,
/// `examples/restart_probe` with STRIDE=3): the prediction is the old pose,
/// and a full fit from there was drawn onto the bar. Occluded blob 105 was
/// `tracked` 29 px off at pair 3 with 83% of its sectors left out, combined
/// blob 101 21-23 px off at pairs 3 and 6, combined blob 105 26 px off at
/// pairs 3-12. Every pair with numbers must be within 1 px of disparity
/// and 3 px of left centroid of the truth after the first pair's offsets;
/// a pair lost as occluded is the right answer.
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn an_occluder_arriving_as_the_object_starts_to_move_does_not_take_it() {
    for (preset, seed) in [
        (Preset::Occluded, 105),
        (Preset::Combined, 101),
        (Preset::Combined, 105),
    ] {
        let lost = restarted_within_truth(preset, Shape::Blob, seed, 3, 12).len();
        // At least three pairs have numbers (the still ones): the test
        // would pass vacuously if the object were never found.
        assert!(
            lost <= 4,
            "{} blob {seed}: {lost} of 7 pairs without numbers",
            preset.name()
        );
    }
}

/// A slender object whose prediction is off along its axis (it stood
/// still for three pairs, then moved on at three times its drift: pairs 0,
/// 0, 0, then every third pair to 24, `examples/restart_probe` with
/// STRIDE=3) can slide along the axis: its far end's sectors, past the
/// object's end, are left out as hidden, and what is left holds it
/// nowhere in particular. Those sectors show bare substrate in both bands,
/// which an occluder does not; a run of two is lost. Before: combined rod
/// 108 was `tracked` 19 px along its axis (a bright bar across its other
/// end), fast rods 101, 102, 106, 107 and 109 15-110 px. Every pair with
/// numbers must be within 1 px of disparity and 3 px of left centroid of
/// the truth after the first pair's offsets; at least one pair is lost for
/// this reason.
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn a_contour_whose_end_left_the_object_is_not_tracked() {
    let mut overhangs = 0;
    for (preset, seed) in [
        (Preset::Combined, 108),
        (Preset::Fast, 101),
        (Preset::Fast, 102),
        (Preset::Fast, 106),
        (Preset::Fast, 107),
        (Preset::Fast, 109),
    ] {
        overhangs += restarted_within_truth(preset, Shape::Rod, seed, 3, 24)
            .iter()
            .filter(|reason| reason.contains("left the object's edge"))
            .count();
    }
    assert!(overhangs > 0, "no pair was lost for leaving the object's edge");
}

/// A tracked pair always carries its standard error (issue #17). Where
/// what is visible of the outline has no energy minimum along the
/// disparity axis, the pair is lost as occluded instead: a tip whose long
/// side a dark bar covered (crossing, seed 203, 20 pairs) slid 14-20 px
/// along its axis with the bar at pairs 10 and 11, reported `tracked`
/// without a standard error. (That tip's runs of `uncertain` pairs now end
/// earlier, at [`semdepth_core::tracker::MAX_UNVERIFIED_MOVE_PX`]; a rod half
/// under a bar, crossing seed 114, pair 4, has such a pair.)
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn a_fit_without_a_minimum_along_the_axis_is_not_tracked() {
    let config = SynthConfig {
        frames: 20,
        ..SynthConfig::preset(Preset::Crossing, Shape::Rod, 114)
    };
    let mut without_minimum = 0;
    for (result, _) in tracked_sequence(&config) {
        match result.status {
            Status::Tracked | Status::Initialised => assert!(
                result.disparity_std_px.is_some_and(f64::is_finite),
                "pair {}: tracked without a standard error",
                result.frame
            ),
            _ => {
                let reason = result.reason.unwrap_or_default();
                without_minimum += usize::from(reason.contains("fixes no position along the disparity axis"));
                assert!(
                    result.disparity_px.is_none(),
                    "pair {}: a lost pair has no number",
                    result.frame
                );
            }
        }
    }
    assert!(
        without_minimum >= 1,
        "no pair was lost for want of a minimum along the axis"
    );
}

/// After the first pair the right view is searched along its epipolar
/// line only, keeping the last pair's offset along the tilt axis: a rod
/// beside a bright bar (crossing, seed 118, 20 pairs) was found 22 px off
/// that line on the bar at pairs 13-15, the disparity 15-18 px wrong and
/// `tracked`. Every tracked pair's disparity across the line (y) stays
/// within 1 px of the truth's, none is confidently wrong, and at least 7
/// pairs are tracked: pairs 0-2, 9-10 and 17-19. Pairs 7 and 13 end runs
/// of `uncertain` pairs over which the contour moved more than 3 px from
/// its predictions; the rod's template is found again beside the bar once
/// the bar leaves it (the search takes up to 40% of the sectors changed
/// by the bar behind them: with a quarter, the rod stayed lost from pair 8
/// to the end).
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn the_right_view_is_searched_on_its_epipolar_line() {
    let config = SynthConfig {
        frames: 20,
        ..SynthConfig::preset(Preset::Crossing, Shape::Rod, 118)
    };
    let (mut errors, mut centroids) = (Vec::new(), Vec::new());
    for (result, pair) in tracked_sequence(&config) {
        let Some(d) = result.disparity_px else {
            continue;
        };
        assert!(
            (d[1] - pair.truth.disparity_px[1]).abs() < 1.0,
            "pair {}: disparity across the line {:.2} px, truth {:.2}",
            result.frame,
            d[1],
            pair.truth.disparity_px[1]
        );
        let (e, c) = truth_errors(&result, &pair).expect("a pair with a disparity");
        errors.push(e);
        centroids.push(c);
    }
    let wrong = confident_wrong(&errors, &centroids);
    assert_eq!(wrong, 0, "confident wrong pairs of {} tracked", errors.len());
    // Pairs 3-7 and 11-13, under the bar, are `uncertain` (standard errors
    // of 0.46-2 px, or the position fixed in one direction only); the
    // template is sought in pairs 8 and 14-16.
    assert!(errors.len() >= 7, "only {} of 20 pairs tracked", errors.len());
}

/// A dark bar over half of a slender object's width, along it: the
/// visible edge is the bar's, and a masked fit that settles on it with the
/// other side's sectors "occluded" (the contour merely left that edge) is
/// doubted: without the sectors risen against the bar as well, what is
/// left must still place the contour. Before, the crossing rod of seed 114
/// (20 pairs) was `tracked` 2.6-3.2 px off in disparity with standard
/// errors of 0.11-0.49 px (4 pairs), and the crossing tip of seed 203 slid
/// 9-14 px along its axis (5 pairs). No pair is confident wrong, and the
/// rod's pairs under the bar are lost as occluded or uncertain: from pair
/// 1 on the bar hides 41-48% of its outline, and only its first pair need
/// be tracked (pair 1 was `tracked` 0.95 px off at 0.37 px while the bias
/// of its risen sectors went unmeasured on the near tables; it is
/// `uncertain` at 0.84 px now). The tip keeps at least 2 pairs (5).
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn a_bar_along_half_an_object_does_not_place_its_contour() {
    for (shape, seed) in [(Shape::Rod, 114), (Shape::Tip, 203)] {
        let config = SynthConfig {
            frames: 20,
            ..SynthConfig::preset(Preset::Crossing, shape, seed)
        };
        let (mut errors, mut centroids, mut occluded) = (Vec::new(), Vec::new(), 0);
        for (result, pair) in tracked_sequence(&config) {
            let Some((e, c)) = truth_errors(&result, &pair) else {
                let reason = result.reason.unwrap_or_default();
                occluded += usize::from(reason.starts_with("occluded") || reason.starts_with("uncertain"));
                continue;
            };
            errors.push(e);
            centroids.push(c);
        }
        let wrong = confident_wrong(&errors, &centroids);
        let name = format!("crossing/{}/{seed}", shape.name());
        assert_eq!(
            wrong,
            0,
            "{name}: confident wrong pairs of {} tracked",
            errors.len()
        );
        let least = if shape == Shape::Rod { 1 } else { 2 };
        assert!(
            errors.len() >= least,
            "{name}: only {} of 20 pairs tracked (expected {least} or more)",
            errors.len()
        );
        if shape == Shape::Rod {
            assert!(
                occluded >= 10,
                "{name}: {occluded} pairs lost as occluded or uncertain, expected 10 or more"
            );
        }
    }
}

/// A fit that moved along the one direction its visible outline does not
/// fix is not followed there: rod 302 (combined, 10 pairs), its lower end
/// going under a bright bar, slid 5 px along its axis on pair 1 (its
/// position fixed only to 2 px, `uncertain`), and from there, its upper
/// end's sectors inside the rod looking like a new backdrop, pairs 2-4 were
/// `tracked` 15-35 px off along the axis with the disparity right. Every
/// pair with a number has its left centroid within 3 px of the truth and
/// its disparity within 1 px, after the first pair's offsets, and at least
/// 8 of the 10 pairs are tracked.
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn a_move_the_visible_outline_does_not_fix_is_not_followed() {
    let config = SynthConfig {
        frames: 10,
        ..SynthConfig::preset(Preset::Combined, Shape::Rod, 302)
    };
    let (tracked, _) = assert_held("combined/rod/302", &config, 3.0, 1.0);
    assert!(tracked >= 8, "only {tracked} of 10 pairs tracked");
}

/// A full fit that cleared the sectors an occluder hid at the prediction
/// by moving the outline's end onto the occluder's edge is contradicted
/// by the masked fit from the prediction, which has the lower energy over
/// the sectors both see: crossing rod 111 (20 pairs), a dark bar over one
/// end, was `tracked` 4.2 px along its axis at pair 16, every sector
/// within its thresholds. Every pair with a number has its left centroid
/// within 2 px of the truth and its disparity within 0.5 px, after the
/// first pair's offsets, and every pair is tracked.
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn a_full_fit_onto_an_occluders_edge_gives_way_to_the_masked_fit() {
    let config = SynthConfig {
        frames: 20,
        ..SynthConfig::preset(Preset::Crossing, Shape::Rod, 111)
    };
    let (tracked, _) = assert_held("crossing/rod/111", &config, 2.0, 0.5);
    assert_eq!(tracked, 20, "pairs tracked");
}

/// After a loss, an object initialised afresh must look like the lost one
/// (principal spreads within `MIN_SPREAD_RATIO` of its template's) or the
/// lost template is sought on: rod 114 under a dark bar along its length
/// (occluded and combined, 20 pairs) was initialised afresh on what the
/// bar left visible (spreads 34.9 x 4.9 px against 34.6 x 6.6 px) or on the
/// rod merged with the bar (40.4 x 12.0 px), then `tracked` 0.85-1.5 px off
/// in disparity and 3-11 px off in position at every later pair. No pair
/// with a number is more than 1 px off in disparity or 3 px in the left
/// centroid after the first pair's offsets, and the fresh object is
/// refused at least once.
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn an_object_initialised_afresh_is_refused_unlike_the_lost_one() {
    use semdepth_core::tracker::MIN_SPREAD_RATIO;
    for preset in [Preset::Occluded, Preset::Combined] {
        let config = SynthConfig {
            frames: 20,
            ..SynthConfig::preset(preset, Shape::Rod, 114)
        };
        let name = format!("{}/rod/114", preset.name());
        let (_, reasons) = assert_held(&name, &config, 3.0, 1.0);
        let limit = format!("ratio limit {MIN_SPREAD_RATIO}");
        assert!(
            reasons.iter().any(|r| r.contains(&limit)),
            "{name}: no fresh object was refused"
        );
    }
}

/// Re-acquisition takes the object again only where its whole outline
/// shows, at most a quarter of it before a new backdrop: a faint rod lost
/// under a bright bar (combined, seed 118, 20 pairs) was taken again
/// inside the bar, half its outline along the bar's edge and the other
/// half "before a new backdrop" of the bar's grey, 13-47 px off and
/// `tracked` with reason `reacquired` at pairs 14-19. No re-acquired pair's
/// left centroid is more than 3 px from the truth.
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn a_reacquired_object_shows_its_whole_outline() {
    use semdepth_core::tracker::REACQUIRED;
    let config = SynthConfig {
        frames: 20,
        ..SynthConfig::preset(Preset::Combined, Shape::Rod, 118)
    };
    for (result, pair) in tracked_sequence(&config) {
        if result.disparity_px.is_none() || result.reason.as_deref() != Some(REACQUIRED) {
            continue;
        }
        let (c, t) = (result.left.unwrap().centroid, pair.truth.left.centroid);
        assert!(
            (c[0] - t[0]).hypot(c[1] - t[1]) < 3.0,
            "pair {} ({:?}): left centroid ({:.1}, {:.1}), truth ({:.1}, {:.1})",
            result.frame,
            result.reason,
            c[0],
            c[1],
            t[0],
            t[1]
        );
    }
}

/// A pair whose disparity's standard error exceeds `max_disparity_std_px`
/// (an occluded tip, seed 101, pair 6: 0.59 px), or whose left outline
/// fixes the object's position in one direction only to more than 1.5 px
/// (an occluded rod 42% hidden, seed 4000 over 20 pairs, pair 16; seed
/// 101's rod, pair 8, gave 2.4 px until the masked runs' shift was cleared
/// of its noise, and is now tracked 0.12 px off), is `lost` with reason
/// `uncertain` and no numbers, and tracking goes on from it: the next pair
/// is tracked, not searched for. With the limit raised, the tip's pair is
/// tracked with that standard error.
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn an_uncertain_pair_is_not_reported() {
    use semdepth_core::tracker::UNCERTAIN;
    let sequence = |shape: Shape, seed: u64, frames_n: usize, params: TrackerParams| -> Vec<PairResult> {
        let config = SynthConfig {
            frames: frames_n,
            ..SynthConfig::preset(Preset::Occluded, shape, seed)
        };
        let mut tracker = StereoTracker::new(params);
        frames(&config)
            .unwrap()
            .map(|pair| tracker.process(&pair.left, &pair.right).unwrap())
            .collect()
    };
    let first_uncertain = |results: &[PairResult], why: &str| -> u64 {
        let uncertain: Vec<&PairResult> = results
            .iter()
            .filter(|r| r.reason.as_deref().is_some_and(|s| s.starts_with(UNCERTAIN)))
            .collect();
        for r in &uncertain {
            assert_eq!(r.status, Status::Lost);
            assert!(r.disparity_px.is_none() && r.disparity_std_px.is_none() && r.z_um.is_none());
            if let Some(next) = results.iter().find(|n| n.frame == r.frame + 1) {
                assert!(
                    next.status == Status::Tracked && next.reason.is_none()
                        || next.reason.as_deref().is_some_and(|s| s.starts_with(UNCERTAIN)),
                    "pair {} after an uncertain one: {:?} {:?}",
                    next.frame,
                    next.status,
                    next.reason
                );
            }
        }
        uncertain
            .iter()
            .find(|r| r.reason.as_deref().is_some_and(|s| s.contains(why)))
            .unwrap_or_else(|| panic!("no pair uncertain for: {why}"))
            .frame
    };
    let tip = sequence(Shape::Tip, 101, 10, TrackerParams::default());
    let frame = first_uncertain(&tip, "standard error is");
    first_uncertain(
        &sequence(Shape::Rod, 4000, 20, TrackerParams::default()),
        "fixes the object's position only",
    );
    let relaxed = sequence(
        Shape::Tip,
        101,
        10,
        TrackerParams {
            max_disparity_std_px: 1000.0,
            ..TrackerParams::default()
        },
    );
    let same = &relaxed[frame as usize];
    assert_eq!(same.status, Status::Tracked, "{:?}", same.reason);
    assert!(same.disparity_std_px.unwrap() > TrackerParams::default().max_disparity_std_px);
}

/// The strips cut from the first free fit ([`semdepth_core::strips`]) are
/// substrate, not noise: on a sphere whose shaded side fades towards the
/// substrate's grey under strong noise (combined, seed 104, 20 pairs),
/// noise near that edge forms holes in the object's pixels, which the cut's
/// opening opens to the outline. When such a hole passed as a strip, the
/// first template lost 103 px of the sphere's edge, the object was lost in
/// pair 4 and 4 pairs were confident wrong. Required: no confident wrong
/// pair and at most one pair without numbers.
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn noise_at_a_shaded_edge_is_not_cut_from_the_first_outline() {
    let config = SynthConfig {
        frames: 20,
        ..SynthConfig::preset(Preset::Combined, Shape::Sphere, 104)
    };
    let (errors, centroids, untracked) = errors_and_reasons(&config, TrackerParams::default());
    let wrong = confident_wrong(&errors, &centroids);
    assert_eq!(wrong, 0, "confident wrong pairs (untracked: {untracked:?})");
    assert!(untracked.len() <= 1, "pairs without numbers: {untracked:#?}");
}

/// Issue #17: a run of `uncertain` pairs does not walk the contour off the
/// object unnoticed. A rod under a bright bar along it (combined, seed
/// 118, 20 pairs; the bar hides 42% of its outline) slid 4.3 px along its
/// axis over five `uncertain` pairs, and the next pair was `tracked` with
/// its left centroid that far off. Past
/// [`semdepth_core::tracker::MAX_UNVERIFIED_MOVE_PX`] of moves from the
/// predictions the object counts as lost and its template is sought.
/// Required: no confident wrong pair, and the reason of the pair that
/// ended the run says so.
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn a_run_of_uncertain_pairs_does_not_walk_the_contour_off_unnoticed() {
    let config = SynthConfig {
        frames: 20,
        ..SynthConfig::preset(Preset::Combined, Shape::Rod, 118)
    };
    assert_caught_and_said(&config, "from its predictions");
}

/// Tracks `config` without hints and asserts that no pair is confident
/// wrong and that some pair without numbers has a reason containing `says`.
fn assert_caught_and_said(config: &SynthConfig, says: &str) {
    let (errors, centroids, reasons) = errors_and_reasons(config, TrackerParams::default());
    assert_eq!(
        confident_wrong(&errors, &centroids),
        0,
        "confident wrong pairs (untracked: {reasons:#?})"
    );
    assert!(
        reasons.iter().any(|r| r.contains(says)),
        "no pair without numbers says {says:?}: {reasons:#?}"
    );
}

/// Issue #17: a position held only by the ends of what is left out is not
/// `tracked`. A rod with a bright bar along one side and over its lower
/// end (occluded, seed 2001, 30 pairs; 43% of its outline hidden, looked
/// at while the rule was made) kept its left side's sectors, whose last
/// few pixels round into the caps fix its position along its axis with
/// about 1% of what the whole outline gives. Its contour slid down the rod
/// by about 0.6 px per pair, `tracked` with a position error of 0.35-0.4
/// px reported in that direction, and 5 pairs were 3-14 px off. Required:
/// no confident wrong pair, and the pairs without numbers say why.
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn a_position_held_only_by_the_ends_of_what_is_left_out_is_not_tracked() {
    let config = SynthConfig {
        frames: 30,
        ..SynthConfig::preset(Preset::Occluded, Shape::Rod, 2001)
    };
    assert_caught_and_said(&config, "weakest direction");
}

/// Issue #17: an object found afresh after a loss sets no looser limit on
/// its standard error than the object's first initialisation did. With a
/// `roi` hint, combined rod 118 (a bright bar along it hides 42% of its
/// outline) was lost at pair 7, its template not found for ten pairs, and
/// initialised afresh at pair 18 on its visible half: a standard error of
/// 2.5 px, so a limit of 4 times that, and pair 19 was `tracked` at 3.2 px,
/// 4.5 px off. Required: no confident wrong pair, and a pair from the
/// fresh initialisation on (pairs 17-19; measured: 17 and 18, at 1.78 and
/// 2.57 px) `uncertain` against the first pair's 0.14 px. The box is drawn
/// with a fifth of the rod's size as margin: with a tenth, the rod had
/// moved out past the box's slack by then, the fresh region is cut at the
/// box, and it is refused as unlike the lost object (no numbers either).
#[test]
#[ignore = "accuracy suite: cargo test --test accuracy -- --ignored"]
fn an_object_found_afresh_keeps_the_first_standard_error_as_its_reference() {
    let config = SynthConfig {
        frames: 20,
        ..SynthConfig::preset(Preset::Combined, Shape::Rod, 118)
    };
    let first = frames(&config).unwrap().next().unwrap();
    let mut params = TrackerParams::default();
    params.init.roi = Some(first.truth.left.roi_hint(0.2));
    let (errors, centroids, reasons) = errors_and_reasons(&config, params);
    assert_eq!(
        confident_wrong(&errors, &centroids),
        0,
        "confident wrong pairs (untracked: {reasons:#?})"
    );
    assert!(
        reasons.iter().any(|r| ["pair 17", "pair 18", "pair 19"]
            .iter()
            .any(|p| r.starts_with(&format!("{p}: uncertain")))
            && r.contains("first pair's 0.1")),
        "{reasons:#?}"
    );
}

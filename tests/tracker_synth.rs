//! Tracking accuracy against the synthetic generator's ground truth (issue
//! #3): 4 shapes x 5 seeds per condition, 10 pairs each. The seeds (100..105)
//! differ from those used while tuning the defaults (0..5).
//!
//! Disparity error: measured minus true disparity along x (the default tilt
//! axis is the image y axis); the constant offset of each sequence is removed
//! (it is what a calibration's reference absorbs), then the RMS is taken over
//! all pairs of the condition. Left centroid error: Euclidean, no offset
//! removed. Lost pairs count as failures.

use semdepth::synth::{frames, Preset, Shape, SynthConfig};
use semdepth::tracker::{Status, StereoTracker, TrackerParams};

const SEEDS: std::ops::Range<u64> = 100..105;
const FRAMES: usize = 10;
/// Left centroid RMS limit for every condition (issue #3).
const MAX_CENTROID_RMS_PX: f64 = 0.5;

struct Accuracy {
    disparity_rms: f64,
    centroid_rms: f64,
    lost: usize,
    pairs: usize,
}

fn measure(preset: Preset) -> Accuracy {
    let (mut sq_disparity, mut sq_centroid, mut pairs, mut lost) = (0.0, 0.0, 0usize, 0usize);
    for shape in Shape::ALL {
        for seed in SEEDS {
            let config = SynthConfig {
                frames: FRAMES,
                ..SynthConfig::preset(preset, shape, seed)
            };
            let mut tracker = StereoTracker::new(TrackerParams::default());
            let mut errors = Vec::new();
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
                let (c, t) = (result.left.unwrap().centroid, pair.truth.left.centroid);
                sq_centroid += (c[0] - t[0]).powi(2) + (c[1] - t[1]).powi(2);
            }
            let offset = errors.iter().sum::<f64>() / errors.len().max(1) as f64;
            sq_disparity += errors.iter().map(|e| (e - offset).powi(2)).sum::<f64>();
            pairs += errors.len();
        }
    }
    let accuracy = Accuracy {
        disparity_rms: (sq_disparity / pairs as f64).sqrt(),
        centroid_rms: (sq_centroid / pairs as f64).sqrt(),
        lost,
        pairs,
    };
    eprintln!(
        "{:>9}: disparity RMS {:.4} px, left centroid RMS {:.3} px, {} pairs, {} lost",
        preset.name(),
        accuracy.disparity_rms,
        accuracy.centroid_rms,
        accuracy.pairs,
        accuracy.lost
    );
    accuracy
}

fn check(preset: Preset, max_disparity_rms: f64) {
    let a = measure(preset);
    assert_eq!(a.lost, 0, "{}: {} pairs lost", preset.name(), a.lost);
    assert_eq!(a.pairs, Shape::ALL.len() * SEEDS.count() * FRAMES);
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
    check(Preset::Clean, 0.05);
}

#[test]
fn strong_poisson_and_scan_line_noise() {
    check(Preset::Noisy, 0.15);
}

#[test]
fn quarter_occlusion_entering_after_the_first_pair() {
    check(Preset::Occluded, 0.15);
}

#[test]
fn grey_level_flicker() {
    check(Preset::Flicker, 0.15);
}

#[test]
fn cluttered_background() {
    // Not a condition of the issue; held to the noisy limit.
    check(Preset::Cluttered, 0.15);
}

//! The stereo tracker on the real quartz images (`../shared/data/real/quartz`):
//! the particle seen under three tilts. Images 01 and 02 (and 01 and 03) are
//! treated as stereo pairs, and the tracked shifts are compared with an
//! independent estimate: the shift between the centroids of Otsu threshold
//! masks (`reference.rs`, no code from the tracker or the initialisation).
//! Between 01 and 02 the particle moves about 27 px in x, between 01 and 03
//! about 54 px.

use crate::reference::{mask_centroid, otsu_reference_mask, quartz_path};
use semdepth_core::geometry::Point;
use semdepth_core::imageio::{read_file, DecodeLimits, GrayFrame};
use semdepth_core::tracker::{PairResult, Status, StereoTracker, TrackerParams};

fn load(index: u32) -> GrayFrame {
    let path = quartz_path(index);
    read_file(&path, &DecodeLimits::default()).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Centroid of the Otsu reference mask of one image.
fn reference_centroid(frame: &GrayFrame) -> Point {
    let (w, h) = (frame.width as usize, frame.height as usize);
    let mask = otsu_reference_mask(&frame.data, w, h, frame.max_value());
    mask_centroid(&mask, w)
}

fn sub(a: Point, b: Point) -> Point {
    [a[0] - b[0], a[1] - b[1]]
}

fn norm(a: Point) -> f64 {
    a[0].hypot(a[1])
}

fn fmt(p: Point) -> String {
    format!("({:+.2}, {:+.2})", p[0], p[1])
}

fn centroids(result: &PairResult) -> (Point, Point) {
    let left = result.left.as_ref().expect("left contour").centroid;
    let right = result.right.as_ref().expect("right contour").centroid;
    (left, right)
}

fn assert_not_lost(result: &PairResult, what: &str) {
    assert_ne!(
        result.status,
        Status::Lost,
        "{what}: lost ({})",
        result.reason.as_deref().unwrap_or("no reason")
    );
}

/// Tracks (01, `right`) as a stereo pair with a fresh tracker (two tilts of
/// the same scene are what a stereo pair is; a fresh tracker exercises the
/// first-pair search of the right view along x, up to `max_disparity_px` =
/// 64) and returns the tracked shift (right minus left centroid) and the
/// reference shift between Otsu mask centroids.
fn stereo_shift(frames: &[GrayFrame; 3], reference: &[Point], right: usize) -> (Point, Point) {
    let pair = format!("Quarz_01 -> Quarz_{:02}", right + 1);
    let mut tracker = StereoTracker::new(TrackerParams::default());
    let result = tracker
        .process(&frames[0], &frames[right])
        .expect("same-size pair");
    assert_not_lost(&result, &pair);
    let (l, r) = centroids(&result);
    let tracked = sub(r, l);
    let expected = sub(reference[right], reference[0]);
    eprintln!(
        "{pair}: tracked left {} right {} shift {} | reference (Otsu mask centroids) shift {} | \
         difference {:.3} px; disparity_axis_px {:.3}",
        fmt(l),
        fmt(r),
        fmt(tracked),
        fmt(expected),
        norm(sub(tracked, expected)),
        result.disparity_axis_px.unwrap_or(f64::NAN),
    );
    let disparity = result.disparity_px.expect("disparity");
    assert!(
        norm(sub(disparity, tracked)) < 1e-9,
        "{pair}: disparity_px {} is not right minus left centroid {}",
        fmt(disparity),
        fmt(tracked)
    );
    (tracked, expected)
}

fn load_all() -> ([GrayFrame; 3], Vec<Point>) {
    let frames = [load(1), load(2), load(3)];
    let reference = frames.iter().map(reference_centroid).collect();
    (frames, reference)
}

/// Issue #3: the tracked shift agrees with the independent estimate within
/// 1 px (measured: 0.74 px).
#[test]
fn stereo_shift_01_02_matches_the_reference() {
    assert_shift_matches_reference(1);
}

/// The 01->03 shift along the tilt axis (x) lies within 1.5 px of the
/// Otsu-centroid shift. Issue #16 retired the 2-D 1-px comparison of issue
/// #3: the grain's outline changes with tilt, so independent estimates of
/// its 01->03 shift disagree with each other by 2-4 px in y (see
/// `examples/energy_valley`), while x, the component depth is read from,
/// agrees.
#[test]
fn stereo_shift_01_03_along_the_axis_matches_the_reference() {
    let (frames, reference) = load_all();
    let (tracked, expected) = stereo_shift(&frames, &reference, 2);
    let err = (tracked[0] - expected[0]).abs();
    assert!(
        err < 1.5,
        "tracked x shift {:.2} differs from the reference {:.2} by {err:.3} px (limit 1.5 px)",
        tracked[0],
        expected[0]
    );
}

/// The stereo shift (01, `right`) lies within 1 px of the reference shift.
fn assert_shift_matches_reference(right: usize) {
    let (frames, reference) = load_all();
    let (tracked, expected) = stereo_shift(&frames, &reference, right);
    let err = norm(sub(tracked, expected));
    assert!(
        err < 1.0,
        "tracked shift {} differs from the reference {} by {err:.3} px (limit 1 px)",
        fmt(tracked),
        fmt(expected)
    );
}

/// Issue #3: the 01->03 shift is about twice the 01->02 shift (measured
/// 2.10), and the x shifts are near the method note's 27 and 54 px.
#[test]
fn stereo_shift_doubles_with_the_tilt() {
    let (frames, reference) = load_all();
    let (a, ra) = stereo_shift(&frames, &reference, 1);
    let (b, rb) = stereo_shift(&frames, &reference, 2);
    let ratio = b[0] / a[0];
    eprintln!(
        "x shift 01->03 / 01->02 = {ratio:.3} (reference {:.3})",
        rb[0] / ra[0]
    );
    assert!(
        (1.8..=2.2).contains(&ratio),
        "the 01->03 shift {} should be about twice the 01->02 shift {} (ratio {ratio:.3}, expected 1.8..2.2)",
        fmt(b),
        fmt(a)
    );
    assert!(
        (a[0] - 27.0).abs() < 2.0 && (b[0] - 54.0).abs() < 3.0,
        "x shifts {} and {}",
        a[0],
        b[0]
    );
}

/// A pair of identical images has zero disparity, also after tracking: the
/// two views' fits minimise the same energy from the same start.
#[test]
fn identical_views_give_zero_disparity() {
    let frame = load(2);
    let mut tracker = StereoTracker::new(TrackerParams::default());
    for k in 0..3 {
        let result = tracker.process(&frame, &frame).expect("same-size pair");
        assert_not_lost(&result, "identical pair");
        let d = result.disparity_px.expect("disparity");
        assert!(norm(d) < 0.01, "pair {k}: disparity {} should be zero", fmt(d));
    }
}

/// One session, pairs (01, 02) then (01, 03): the tilt doubles between the
/// pairs, and the second pair's x shift must still lie within 1.5 px of
/// the Otsu-centroid shift, as when the pair is tracked alone (issue #17: it
/// was reported `tracked` at 73.9 px, the right contour having walked
/// 47 px along the grain from its prediction; the reference is 54.1).
#[test]
fn a_session_whose_tilt_doubles_follows_the_disparity() {
    let (frames, reference) = load_all();
    let mut tracker = StereoTracker::new(TrackerParams::default());
    let first = tracker.process(&frames[0], &frames[1]).expect("same-size pair");
    assert_not_lost(&first, "Quarz_01 -> Quarz_02");
    let second = tracker.process(&frames[0], &frames[2]).expect("same-size pair");
    assert_not_lost(&second, "then Quarz_01 -> Quarz_03");
    let (l, r) = centroids(&second);
    let (tracked, expected) = (sub(r, l), sub(reference[2], reference[0]));
    let err = (tracked[0] - expected[0]).abs();
    eprintln!(
        "session 01-02 then 01-03: {:?} shift {} (reference {}), x off by {err:.3} px",
        second.status,
        fmt(tracked),
        fmt(expected)
    );
    assert!(
        err < 1.5,
        "second pair's x shift {:.2} differs from the reference {:.2} by {err:.3} px (limit 1.5 px)",
        tracked[0],
        expected[0]
    );
}

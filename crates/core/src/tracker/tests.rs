//! Unit tests of the tracker.
use super::*;
use crate::calib::MetaWatch;
use crate::fit::place;
use crate::geometry::{polygon_iou, Point, Polygon};
use crate::region::PrefixSums;
use crate::region::RegionSum;
use crate::synth::{frames, Preset, Scene, Shape, SynthConfig};

fn sequence(preset: Preset, shape: Shape, seed: u64, n: usize) -> Vec<crate::synth::SynthPair> {
    let config = SynthConfig {
        frames: n,
        ..SynthConfig::preset(preset, shape, seed)
    };
    frames(&config).unwrap().collect()
}

#[test]
fn first_pair_initialises_then_tracks() {
    let pairs = sequence(Preset::Clean, Shape::Blob, 3, 3);
    let mut tracker = StereoTracker::new(TrackerParams::default());
    let statuses: Vec<Status> = pairs
        .iter()
        .map(|p| tracker.process(&p.left, &p.right).unwrap().status)
        .collect();
    assert_eq!(
        statuses,
        vec![Status::Initialised, Status::Tracked, Status::Tracked]
    );
    assert_eq!(tracker.frames(), 3);
}

/// An object whose outline as named mostly follows no edge
/// ([`MIN_EDGE_SUPPORT`]) is followed, its pairs withheld as `uncertain`
/// with the share in the reason; with enough of it on an edge they carry
/// numbers.
#[test]
fn an_outline_mostly_on_no_edge_withholds_its_pairs_and_tracking_goes_on() {
    let pairs = sequence(Preset::Clean, Shape::Blob, 3, 4);
    let mut tracker = StereoTracker::new(TrackerParams::default());
    let first = tracker.process(&pairs[0].left, &pairs[0].right).unwrap();
    assert_eq!(first.status, Status::Initialised, "{first:?}");
    let support = tracker.state.as_ref().unwrap().edge_support.unwrap();
    assert!(
        support >= MIN_EDGE_SUPPORT,
        "the blob's outline: {support:.2} near an edge"
    );
    tracker.state.as_mut().unwrap().edge_support = Some(0.3);
    for pair in &pairs[1..3] {
        let r = tracker.process(&pair.left, &pair.right).unwrap();
        assert_eq!(r.status, Status::Lost, "{r:?}");
        let reason = r.reason.as_deref().unwrap();
        assert!(
            reason.starts_with(UNCERTAIN)
                && reason.contains("30% of the object's outline")
                && reason.ends_with(GOES_ON),
            "{reason}"
        );
        assert!(r.disparity_px.is_none() && r.left.is_some(), "{r:?}");
        let state = tracker.state.as_ref().unwrap();
        assert!(!state.is_lost() && state.uncertain_run.is_none(), "{state:?}");
    }
    tracker.state.as_mut().unwrap().edge_support = Some(MIN_EDGE_SUPPORT);
    let r = tracker.process(&pairs[3].left, &pairs[3].right).unwrap();
    assert_eq!(r.status, Status::Tracked, "{r:?}");
}

/// A fresh initialisation after a loss whose object is unlike the lost
/// template is refused [`REFUSED_INITS`] times, each followed by
/// [`REACQUIRE_PAIRS`] template searches; the next is taken as it is.
#[test]
fn unlike_fresh_objects_are_refused_a_bounded_number_of_times() {
    let pairs = sequence(Preset::Clean, Shape::Rod, 5, 2);
    let mut tracker = StereoTracker::new(TrackerParams::default());
    tracker.process(&pairs[0].left, &pairs[0].right).unwrap();
    let lose = |tracker: &mut StereoTracker, factor: f64| {
        let state = tracker.state.as_mut().unwrap();
        state.phase = Phase::Reinitialising;
        state
            .template
            .iter_mut()
            .for_each(|p| *p = [p[0] * factor, p[1] * factor]);
    };
    // The same object, its template 10% larger: alike, taken.
    lose(&mut tracker, 1.1);
    let r = tracker.process(&pairs[1].left, &pairs[1].right).unwrap();
    assert_eq!(r.status, Status::Initialised, "{r:?}");
    // Twice its size: refused, the template sought again.
    lose(&mut tracker, 2.0);
    for refusal in 1..=REFUSED_INITS {
        let r = tracker.process(&pairs[1].left, &pairs[1].right).unwrap();
        assert_eq!(r.status, Status::Lost, "{r:?}");
        assert!(
            r.reason.as_deref().unwrap().contains("unlike the lost one"),
            "{r:?}"
        );
        let state = tracker.state.as_mut().unwrap();
        assert_eq!(
            (state.refused_inits, state.phase),
            (refusal, Phase::Searching { missed: 0 })
        );
        state.phase = Phase::Reinitialising;
    }
    let r = tracker.process(&pairs[1].left, &pairs[1].right).unwrap();
    assert_eq!(r.status, Status::Initialised, "{r:?}");
    assert_eq!(tracker.state.as_ref().unwrap().refused_inits, 0);
}

/// A whole object lost under a bright bar that runs out of the frame
/// is not replaced by what a fresh initialisation finds there: the
/// visible part of the rod merged with the bar, cut by the border and
/// larger than the rod, whose centroid lies 35 px off (combined rod
/// 104, pair 19; it was `initialised` with a disparity 1.6 px off).
#[test]
fn a_fresh_object_cut_by_the_border_larger_than_the_lost_one_is_refused() {
    let pairs = sequence(Preset::Combined, Shape::Rod, 104, 20);
    let mut tracker = StereoTracker::new(TrackerParams::default());
    tracker.process(&pairs[0].left, &pairs[0].right).unwrap();
    let state = tracker.state.as_mut().unwrap();
    assert!(
        state.template_cuts.is_empty(),
        "the rod is whole on the first pair"
    );
    state.phase = Phase::Reinitialising;
    let last = &pairs[19];
    let r = tracker.process(&last.left, &last.right).unwrap();
    if r.status != Status::Lost {
        let off = dist(r.left.as_ref().unwrap().centroid, last.truth.left.centroid);
        panic!("taken {off:.1} px from the rod: {:?} {:?}", r.status, r.reason);
    }
    assert!(
        r.reason.as_deref().unwrap().contains("larger than the lost one"),
        "{r:?}"
    );
    assert_eq!(tracker.state.as_ref().unwrap().refused_inits, 1);
}

#[test]
fn blank_right_image_is_lost_not_a_confident_answer() {
    let pairs = sequence(Preset::Clean, Shape::Sphere, 4, 2);
    let mut tracker = StereoTracker::new(TrackerParams::default());
    tracker.process(&pairs[0].left, &pairs[0].right).unwrap();
    let blank = GrayFrame::filled(pairs[1].right.width, pairs[1].right.height, 8, 70);
    let r = tracker.process(&pairs[1].left, &blank).unwrap();
    assert_eq!(r.status, Status::Lost, "{r:?}");
    // Lost means no number (issue #17): nothing for a script to use,
    // even with a calibration; the contours stay for display.
    let mut r = r;
    let calibration = crate::calib::build(crate::calib::CalibrationSpec::Geometric(
        crate::calib::GeometricSpec::new(0.1, 6.0),
    ))
    .unwrap();
    r.apply_calibration(Some(&calibration), &mut MetaWatch::default());
    assert_eq!(
        (
            r.disparity_px,
            r.disparity_axis_px,
            r.relative_disparity_axis_px,
            r.angle_diff_rad
        ),
        (None, None, None, None),
        "{r:?}"
    );
    assert_eq!(
        (r.disparity_std_px, r.z_um, r.z_std_um),
        (None, None, None),
        "{r:?}"
    );
    assert!(r.left.is_some(), "the left contour is kept for display");
    let reason = r.reason.unwrap();
    assert!(reason.contains("right image"), "{reason}");
    // The next pair finds the object again by its template (issue #17)
    // and measures normally, with a standard error.
    let again = tracker.process(&pairs[1].left, &pairs[1].right).unwrap();
    assert_eq!(again.status, Status::Tracked, "{:?}", again.reason);
    assert_eq!(again.reason.as_deref(), Some(REACQUIRED));
    let std = again.disparity_std_px.expect("a standard error");
    assert!(std > 0.0 && std < 0.2, "clean sphere: {std}");
}

#[test]
fn a_tracker_from_a_saved_state_continues_the_session() {
    let pairs = sequence(Preset::Clean, Shape::Tip, 5, 4);
    let mut a = StereoTracker::new(TrackerParams::default());
    for p in &pairs[..2] {
        a.process(&p.left, &p.right).unwrap();
    }
    let state = a.state().cloned();
    let mut b = StereoTracker::from_state(TrackerParams::default(), state, a.frames());
    for p in &pairs[2..] {
        let (ra, rb) = (
            a.process(&p.left, &p.right).unwrap(),
            b.process(&p.left, &p.right).unwrap(),
        );
        assert_eq!(rb.status, Status::Tracked);
        assert_eq!(ra.frame, rb.frame);
        let (da, db) = (ra.disparity_px.unwrap(), rb.disparity_px.unwrap());
        assert!(
            (da[0] - db[0]).abs() < 1e-9 && (da[1] - db[1]).abs() < 1e-9,
            "{da:?} vs {db:?}"
        );
    }
}

/// The first pair of `config`'s scene with its object started at `start`.
fn started_at(config: &SynthConfig, start: Point) -> crate::synth::SynthPair {
    let mut config = config.clone();
    config.motion.start_px = Some(start);
    Scene::new(&config).unwrap().render(0)
}

#[test]
fn a_twenty_pixel_jump_between_pairs_is_caught() {
    let config = SynthConfig {
        frames: 1,
        ..SynthConfig::preset(Preset::Noisy, Shape::Blob, 6)
    };
    let first = Scene::new(&config).unwrap().render(0);
    // The same scene with the object started 20 px further right and 5 px down.
    let start = first.truth.left.centroid;
    let moved = started_at(&config, [start[0] + 20.0, start[1] + 5.0]);
    let mut tracker = StereoTracker::new(TrackerParams::default());
    tracker.process(&first.left, &first.right).unwrap();
    let r = tracker.process(&moved.left, &moved.right).unwrap();
    assert_eq!(r.status, Status::Tracked, "{:?}", r.reason);
    let c = r.left.unwrap().centroid;
    let t = moved.truth.left.centroid;
    assert!(
        (c[0] - t[0]).hypot(c[1] - t[1]) < 0.5,
        "left centroid {c:?} vs truth {t:?}"
    );
    let d = r.disparity_px.unwrap()[0] - moved.truth.disparity_px[0];
    let d0 = first.truth.disparity_px[0];
    assert!(d.abs() < 0.5, "disparity error {d} (first pair's disparity {d0})");
}

/// A stage move carries the object out of the box it was named in: the
/// tracking step loses it, and the next pair's search finds it outside the
/// box, over the whole image.
#[test]
fn an_object_moved_out_of_its_hint_box_is_found_again() {
    let config = SynthConfig {
        frames: 1,
        ..SynthConfig::preset(Preset::Clean, Shape::Blob, 6)
    };
    let first = Scene::new(&config).unwrap().render(0);
    let [cx, cy] = first.truth.left.centroid;
    let (w, h) = (first.left.width as f64, first.left.height as f64);
    // A box a person draws around the object.
    let roi = first.truth.left.roi_hint(0.2);
    // Moved to the other side of the frame, well outside the box.
    let other = |c: f64, side: f64| if c < side / 2.0 { 0.7 * side } else { 0.3 * side };
    let to = [other(cx, w), other(cy, h)];
    let moved = started_at(&config, to);
    let t = moved.truth.left.centroid;
    let outside = |p: Point| {
        let [x, y, bw, bh] = roi.map(|v| v as f64);
        p[0] < x || p[0] > x + bw || p[1] < y || p[1] > y + bh
    };
    assert!(outside(t), "moved to {t:?}, box {roi:?}");
    let mut params = TrackerParams::default();
    params.init.roi = Some(roi);
    let mut tracker = StereoTracker::new(params);
    let r = tracker.process(&first.left, &first.right).unwrap();
    assert_eq!(r.status, Status::Initialised, "{:?}", r.reason);
    let r = tracker.process(&moved.left, &moved.right).unwrap();
    assert_eq!(r.status, Status::Lost, "{r:?}");
    let r = tracker.process(&moved.left, &moved.right).unwrap();
    assert_eq!(r.status, Status::Tracked, "{:?}", r.reason);
    assert_eq!(r.reason.as_deref(), Some(REACQUIRED));
    let c = r.left.unwrap().centroid;
    assert!(
        (c[0] - t[0]).hypot(c[1] - t[1]) < 0.5,
        "left centroid {c:?} vs truth {t:?}"
    );
    let d = r.disparity_px.unwrap()[0] - moved.truth.disparity_px[0];
    assert!(d.abs() < 0.5, "disparity error {d}");
}

/// The near tables (G around the contour, window rows around its
/// window's edges) give the full-reach tables' energies, and refuse a
/// pose whose window edges leave their rows.
#[test]
fn near_tables_give_full_table_energies_and_refuse_what_they_do_not_cover() {
    let pairs = sequence(Preset::Noisy, Shape::Rod, 8, 2);
    let mut tracker = StereoTracker::new(TrackerParams::default());
    tracker.process(&pairs[0].left, &pairs[0].right).unwrap();
    let (template, _) = tracker.template.as_ref().unwrap();
    let pose = tracker.state.as_ref().unwrap().left;
    let frame = &pairs[1].left;
    let near = tracker.sums_around(frame, template, pose, StereoTracker::NEAR_REACH_PX);
    let full = tracker.sums_around(frame, template, pose, 24.0);
    let energy = |sums: &PrefixSums, (dx, dy, dt): (f64, f64, f64)| {
        let moved = Pose {
            x: pose.x + dx,
            y: pose.y + dy,
            theta: pose.theta + dt,
        };
        let points = place(&template.points, moved);
        let params = &tracker.params.energy;
        crate::energy::evaluate_with_length(sums, &points, params, template.margin, template.length).energy
    };
    for shift in [
        (0.0, 0.0, 0.0),
        (5.5, -5.5, 0.0),
        (-4.0, 3.0, 0.03),
        (2.0, 2.0, -0.04),
    ] {
        let (a, b) = (energy(&near, shift), energy(&full, shift));
        assert!(
            a.is_finite() && (a - b).abs() < 1e-9 * b.abs(),
            "{shift:?}: near {a} full {b}"
        );
    }
    for shift in [(0.0, 20.0, 0.0), (0.0, -20.0, 0.0)] {
        let (a, b) = (energy(&near, shift), energy(&full, shift));
        assert!(!a.is_finite() && b.is_finite(), "{shift:?}: near {a} full {b}");
    }
}

/// The near tables give the full-reach tables' band energy with
/// sectors left out (the risen or masked sectors' bias terms are such
/// fits). A rod's outer band at its ends reaches into the guard the
/// near tables keep around its contour: when the band had to stay a
/// guard inside them, every masked energy there was infinite, the
/// masked fit never moved, and the bias of a dark bar beside a rod
/// counted as none (crossing rod 1017: `tracked` 1.1 px off at a
/// reported 0.3 px).
#[test]
fn near_tables_give_full_table_masked_energies() {
    let pairs = sequence(Preset::Noisy, Shape::Rod, 8, 2);
    let mut tracker = StereoTracker::new(TrackerParams::default());
    tracker.process(&pairs[0].left, &pairs[0].right).unwrap();
    let (template, sectors) = tracker.template.as_ref().unwrap();
    let pose = tracker.state.as_ref().unwrap().left;
    let frame = &pairs[1].left;
    let near = tracker.sums_around(frame, template, pose, StereoTracker::NEAR_REACH_PX);
    let full = tracker.sums_around(frame, template, pose, 24.0);
    let n = tracker.params.occlusion.sectors;
    let mask: Vec<bool> = (0..n).map(|k| k >= n / 2).collect();
    for shift in [(0.0, 0.0), (1.5, -1.0), (-2.0, 2.0)] {
        let moved = Pose {
            x: pose.x + shift.0,
            y: pose.y + shift.1,
            ..pose
        };
        let (a, b) = (
            sectors.masked_energy(&near, moved, &mask, full.reference_mean()),
            sectors.masked_energy(&full, moved, &mask, full.reference_mean()),
        );
        assert!(
            a.is_finite() && (a - b).abs() < 1e-9 * b.abs(),
            "{shift:?}: near {a} full {b}"
        );
    }
}

/// The same for a template cut by the image border, whose sectors are
/// judged seen vertex by vertex: a band may reach into the guard of
/// split tables (it was judged unseen there, as a rod's was above).
#[test]
fn near_tables_see_the_sectors_full_tables_see() {
    let pairs = sequence(Preset::BorderTool, Shape::Tip, 8, 1);
    let mut tracker = StereoTracker::new(TrackerParams::default());
    tracker.process(&pairs[0].left, &pairs[0].right).unwrap();
    let (template, sectors) = tracker.template.as_ref().unwrap();
    assert!(!template.cuts.is_empty(), "the tool is cut by the border");
    let pose = tracker.state.as_ref().unwrap().left;
    let frame = &pairs[0].left;
    let guard = SectorTemplate::outer_band_width(template);
    // Tables just wide enough for the outer band: the band's outermost
    // vertices lie within the guard.
    let r = template.radius + guard + 1.0;
    let polygons = PixelRect::around([pose.x, pose.y, pose.x, pose.y], r, frame.width, frame.height).unwrap();
    let near = PrefixSums::split(frame, polygons, guard, polygons, &[], INTENSITY_OFFSET);
    let full = PrefixSums::new(frame, PixelRect::full(frame), INTENSITY_OFFSET);
    let (a, b) = (sectors.band_sums(&near, pose), sectors.band_sums(&full, pose));
    let seen = b.iter().filter(|s| s.is_some()).count();
    assert!(
        seen >= a.len() / 2,
        "full tables see {seen} of {} sectors",
        a.len()
    );
    for (k, (a, b)) in a.iter().zip(&b).enumerate() {
        let sum = |s: &Option<(RegionSum, RegionSum)>| s.map(|(i, o)| (i.count, i.sum, o.count, o.sum));
        let (a, b) = (sum(a), sum(b));
        let close = match (a, b) {
            (Some(a), Some(b)) => [a.0 - b.0, a.1 - b.1, a.2 - b.2, a.3 - b.3]
                .iter()
                .zip([b.0, b.1, b.2, b.3])
                .all(|(d, v)| d.abs() <= 1e-9 * v.abs().max(1.0)),
            (None, None) => true,
            _ => false,
        };
        assert!(close, "sector {k}: near {a:?} full {b:?}");
    }
}

#[test]
fn size_change_mid_session_is_an_error() {
    let pairs = sequence(Preset::Clean, Shape::Blob, 7, 1);
    let mut tracker = StereoTracker::new(TrackerParams::default());
    tracker.process(&pairs[0].left, &pairs[0].right).unwrap();
    let small = GrayFrame::filled(320, 240, 8, 50);
    let e = tracker.process(&small, &small).unwrap_err();
    assert!(matches!(e, TrackError::SizeChanged { width: 320, .. }), "{e}");
    let mismatched = tracker.process(&pairs[0].left, &small).unwrap_err();
    assert!(matches!(
        mismatched,
        TrackError::Input(ImageInputError::PairSizeMismatch { .. })
    ));
}

#[test]
fn tilt_axis_selects_the_disparity_component() {
    let pairs = sequence(Preset::Clean, Shape::Rod, 8, 1);
    let params = TrackerParams {
        tilt_axis_deg: 0.0,
        ..TrackerParams::default()
    };
    let mut tracker = StereoTracker::new(params);
    let r = tracker.process(&pairs[0].left, &pairs[0].right).unwrap();
    let d = r.disparity_px.unwrap();
    // Tilt axis along x: the useful component is across it, -dy.
    assert!((r.disparity_axis_px.unwrap() + d[1]).abs() < 1e-12);
    assert_eq!(r.relative_disparity_axis_px, Some(0.0));
}

#[test]
fn invalid_parameters_are_named() {
    let params = TrackerParams {
        min_contrast_ratio: 2.0,
        ..TrackerParams::default()
    };
    let e = params.validate().unwrap_err();
    assert!(e.contains("min_contrast_ratio") && e.contains("expected"), "{e}");
    let mut p = TrackerParams::default();
    p.occlusion.sectors = 2;
    assert!(p.validate().unwrap_err().contains("occlusion"));
    for bad in [0.0, -1.0, f64::NAN, 1e6] {
        let p = TrackerParams {
            max_disparity_std_px: bad,
            ..TrackerParams::default()
        };
        let e = p.validate().unwrap_err();
        assert!(
            e.contains("max_disparity_std_px") && e.contains("0.01..=1000"),
            "{e}"
        );
    }
}

/// A tool entering from the border moves along its axis by 5-20 px a
/// pair, unpredicted on the pair after its first: with no velocity
/// measured the prediction is only the last pose, so the move is the
/// tool's own motion, followed, and not judged as a slide (a tracker
/// restored from the same state, which has no last profile to compare
/// with, follows it alike).
#[test]
fn a_border_tools_move_on_the_pair_after_its_first_is_followed() {
    let pairs = sequence(Preset::BorderTool, Shape::Tip, 300, 2);
    let params = TrackerParams::default();
    let mut tracker = StereoTracker::new(params.clone());
    let first = tracker.process(&pairs[0].left, &pairs[0].right).unwrap();
    assert_eq!(first.status, Status::Initialised, "{first:?}");
    assert!(
        !tracker.template.as_ref().unwrap().0.cuts.is_empty(),
        "a border tool"
    );
    let mut restored = StereoTracker::from_state(params, tracker.state().cloned(), tracker.frames());
    let before = tracker.state().unwrap().left;
    // The template's pose moves as the whole tool does (its centroid,
    // outside the image included).
    let [t0, t1] = [0, 1].map(|k| pairs[k].truth.left.centroid);
    let moved = [t1[0] - t0[0], t1[1] - t0[1]];
    assert!(moved[0].hypot(moved[1]) > 4.0, "the tool moved {moved:?}");
    for (name, tracker) in [("live", &mut tracker), ("restored", &mut restored)] {
        let followed = tracker.process(&pairs[1].left, &pairs[1].right).unwrap();
        assert_eq!(followed.status, Status::Tracked, "{name}: {followed:?}");
        let after = tracker.state().unwrap().left;
        let off = (after.x - before.x - moved[0]).hypot(after.y - before.y - moved[1]);
        assert!(
            off < 1.0,
            "{name}: followed {off:.2} px off the tool's move {moved:?}"
        );
    }
}

/// A box whose side cuts through a region (a needle running on into the
/// lamella welded to its tip) frames the part inside it: the region is cut
/// at the box there, and the first pair's free fit keeps to the box on that
/// side instead of running on to the edge of the box's slack.
#[test]
fn the_first_fit_keeps_to_the_side_where_the_box_cut_the_region() {
    // A bright needle tapering from the left border to its tip at x = 90,
    // welded there to a bright block (x 90..180, y 48..72) on a dark ground.
    let (w, h) = (200u32, 120u32);
    let inside = |x: f64, y: f64| {
        let needle = x < 90.0 && (y - 60.0).abs() < 4.0 + 0.15 * (90.0 - x);
        let block = (90.0..180.0).contains(&x) && (48.0..72.0).contains(&y);
        needle || block
    };
    let data = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| if inside(x as f64, y as f64) { 180 } else { 60 })
        .collect();
    let frame = crate::imageio::GrayFrame::new(w, h, 8, data).unwrap();
    let params = TrackerParams {
        init: crate::init::InitParams {
            roi: Some([0, 30, 100, 60]),
            ..crate::init::InitParams::default()
        },
        ..TrackerParams::default()
    };
    let found = crate::init::initialise(&frame, &params.init).unwrap();
    assert_eq!(found.cut_at_box, vec!["right".to_string()], "{found:?}");
    assert_eq!(found.border, vec!["left".to_string()]);
    let outline = StereoTracker::first_outline(&params, &frame, found).unwrap();
    // The box's right edge lies at x = 99.5; its slack reaches 103.5.
    let right = outline.bounds()[2];
    assert!((98.5..=100.0).contains(&right), "right end at {right:.2}");
}

/// A low-contrast plate between a brighter needle and a post of its own
/// grey (a lamella in its gap, as on the static scans): along the
/// disparity axis its energy falls towards the needle and is flat towards
/// the post, so no fit places it. Its first pair carries no number rather
/// than one 20 px off; the plate apart from both, its ends edges of its
/// own, is measured.
#[test]
fn a_plate_whose_energy_fixes_no_position_along_the_axis_gets_no_number() {
    let scene = |shift: f64, own_edge: bool| {
        let (w, h) = (360u32, 140u32);
        let mut noise = 0x2545_f491_4f6c_dd1du64;
        let data = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64 - shift, (i / w) as f64);
                // With edges of its own, a gap of the background parts the
                // plate from the needle and from the post.
                let gap = if own_edge { 6.0 } else { 0.0 };
                let grey = if (50.0..90.0).contains(&y) && (60.0..180.0 - gap).contains(&x) {
                    200.0
                } else if (55.0..85.0).contains(&y) && (180.0..270.0).contains(&x) || x >= 270.0 + gap {
                    120.0
                } else {
                    40.0
                };
                noise ^= noise << 13;
                noise ^= noise >> 7;
                noise ^= noise << 17;
                (grey + (noise % 31) as f64 - 15.0) as u16
            })
            .collect();
        GrayFrame::new(w, h, 8, data).expect("a valid frame")
    };
    let outline = vec![[177.0, 52.0], [273.0, 52.0], [273.0, 88.0], [177.0, 88.0]];
    for own_edge in [false, true] {
        let mut params = TrackerParams::default();
        params.init.outline = Some(outline.clone());
        let mut tracker = StereoTracker::new(params);
        let r = tracker
            .process(&scene(0.0, own_edge), &scene(3.0, own_edge))
            .unwrap();
        match r.disparity_axis_px {
            Some(d) => {
                let std = r.disparity_std_px.unwrap();
                assert!(
                    own_edge && (d - 3.0).abs() <= 3.0 * std,
                    "{own_edge}: {d:.2} +- {std:.2}: {r:?}"
                );
            }
            None => {
                // Without either check: 38.9 px at a reported 0.50 px.
                let reason = r.reason.as_deref().unwrap_or_default();
                assert!(
                    !own_edge
                        && (reason.contains("looks most like the left view's")
                            || reason.contains("no minimum of the energy")),
                    "{own_edge}: {r:?}"
                );
            }
        }
    }
}

/// Lost on a pair whose right view is blank, the object is found again by
/// its template on the next pair, whose grey levels the microscope's
/// automatic brightness and contrast changed affinely: a gain, an offset,
/// or both (the search's look checks compare the first pair's look seen
/// through that change; with a gain alone they held before, and an offset
/// of -30 grey levels on a background of 69 refused every shape). Found
/// within half a pixel of the truth's disparity.
#[test]
fn a_lost_object_is_found_again_through_a_change_of_brightness_and_contrast() {
    for shape in [Shape::Sphere, Shape::Blob, Shape::Rod] {
        let pairs = sequence(Preset::Clean, shape, 4, 2);
        for (gain, offset) in [(1.0, -30.0), (1.4, -50.0), (0.6, 20.0), (1.0, 40.0), (2.0, -60.0)] {
            let mut tracker = StereoTracker::new(TrackerParams::default());
            tracker.process(&pairs[0].left, &pairs[0].right).unwrap();
            let blank = GrayFrame::filled(pairs[1].right.width, pairs[1].right.height, 8, 70);
            assert_eq!(
                tracker.process(&pairs[1].left, &blank).unwrap().status,
                Status::Lost
            );
            let again = tracker
                .process(
                    &pairs[1].left.regraded(gain, offset),
                    &pairs[1].right.regraded(gain, offset),
                )
                .unwrap();
            let case = format!("{shape:?}, gain {gain}, offset {offset}");
            assert_eq!(again.status, Status::Tracked, "{case}: {:?}", again.reason);
            assert_eq!(again.reason.as_deref(), Some(REACQUIRED), "{case}");
            let error = again.disparity_px.unwrap()[0] - pairs[1].truth.disparity_px[0];
            assert!(error.abs() < 0.5, "{case}: disparity off by {error:.2} px");
        }
    }
}

/// `frame` plus white Gaussian noise of `sigma` grey levels drawn from
/// `seed`, rounded (8-bit range).
pub(super) fn noisy(frame: &GrayFrame, sigma: f64, seed: u64) -> GrayFrame {
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let normal = Normal::new(0.0, sigma).unwrap();
    let data = frame
        .data
        .iter()
        .map(|&v| (f64::from(v) + normal.sample(&mut rng)).round().clamp(0.0, 255.0) as u16)
        .collect();
    GrayFrame { data, ..*frame }
}

/// A bright disc (radius 25, its edge a ramp 2.5 px wide) at (`disc_x`,
/// 80) on a substrate whose texture (+-40 grey levels) moves with it, plus
/// white Gaussian noise of `sigma` grey levels drawn from `seed`.
fn textured_disc(disc_x: f64, sigma: f64, seed: u64) -> GrayFrame {
    let (w, h) = (220u32, 160u32);
    let data = (0..w * h)
        .map(|i| {
            let (x, y) = (f64::from(i % w), f64::from(i / w));
            let inside = ((25.0 - (x - disc_x).hypot(y - 80.0)) / 2.5 + 0.5).clamp(0.0, 1.0);
            let substrate = 70.0 + 40.0 * (0.45 * (x - disc_x)).sin() * (0.3 * y).cos();
            (inside * 180.0 + (1.0 - inside) * substrate).round() as u16
        })
        .collect();
    noisy(&GrayFrame::new(w, h, 8, data).unwrap(), sigma, seed)
}

/// Issue #64 item 4 on a scene whose texture moves with the object (as on
/// a shifted real frame) and whose two views carry noise of their own (as
/// a tilt pair's scans): the reported standard error within a factor of
/// 1.5 of the errors (RMS of error over standard error, 6 draws of 6
/// pairs; 0.98). A view's own figure counts the texture as noise; the
/// pair's noise does not, and the surroundings' lag registered at the
/// fitted poses is the disparity's own error: counted whole, with the
/// pair's noise taken twice, the figure was 1.43 times the errors (0.70,
/// inside the factor here; the real sequences' floor on the ratio is what
/// catches it). With the edge a pixel wide the errors of one sub-pixel
/// disparity share a bias of up to 0.1 px, which no noise figure sees.
#[test]
fn texture_that_moves_with_the_object_and_noise_of_each_view_give_a_calibrated_standard_error() {
    let mut z = Vec::new();
    for draw in 0..6u64 {
        let mut tracker = StereoTracker::new(TrackerParams::default());
        for k in 0..6u64 {
            let (x, d) = (70.0 + 1.7 * k as f64, 2.3 + 0.13 * k as f64);
            let seed = 100 * draw + 2 * k;
            let left = textured_disc(x, 16.0, seed);
            let right = textured_disc(x + d, 16.0, seed + 1);
            let result = tracker.process(&left, &right).unwrap();
            assert!(
                matches!(result.status, Status::Initialised | Status::Tracked),
                "draw {draw}, pair {k}: {:?} {:?}",
                result.status,
                result.reason
            );
            let (disparity, std) = (result.disparity_px.unwrap()[0], result.disparity_std_px.unwrap());
            z.push((disparity - d) / std);
        }
    }
    let rms = (z.iter().map(|z| z * z).sum::<f64>() / z.len() as f64).sqrt();
    assert!(
        (1.0 / 1.5..=1.5).contains(&rms),
        "RMS error/std {rms:.2} over {} pairs (expected within a factor 1.5 of 1): {z:.2?}",
        z.len()
    );
}

/// A lost object that its template does not find after a change of tone
/// that no gain and offset explain is initialised afresh where it was
/// last seen ([`FOUND_AFRESH`]), on the object; through a change of
/// brightness and contrast the search finds it ([`REACQUIRED`]) and
/// nothing starts afresh. The tone curve (as contact_1's from frame 4)
/// stretches the upper half of the substrate's grey three times and flattens
/// the sphere's brightness above it, so the sphere's looks no longer match.
#[test]
fn a_lost_object_is_found_afresh_after_a_change_of_tone_only() {
    let pairs = sequence(Preset::Clean, Shape::Sphere, 4, 3);
    let deciles = crate::occlusion::grey_quantiles(&pairs[0].left);
    let (mid, top) = (deciles[4], deciles[8] + 5.0);
    let tone = move |v: f64| mid + 3.0 * (v.min(top) - mid).max(0.0) + (v - mid).min(0.0);
    let affine = |v: f64| 1.2 * v - 10.0;
    for (curve, status, reason) in [
        (&tone as &dyn Fn(f64) -> f64, Status::Initialised, FOUND_AFRESH),
        (&affine, Status::Tracked, REACQUIRED),
    ] {
        let mut tracker = StereoTracker::new(TrackerParams::default());
        let first = tracker.process(&pairs[0].left, &pairs[0].right).unwrap();
        assert_eq!(first.status, Status::Initialised, "{first:?}");
        let blank = GrayFrame::filled(pairs[1].right.width, pairs[1].right.height, 8, 70);
        let lost = tracker.process(&pairs[1].left, &blank).unwrap();
        assert_eq!(lost.status, Status::Lost, "{lost:?}");
        let (left, right) = (pairs[2].left.toned(curve), pairs[2].right.toned(curve));
        let again = tracker.process(&left, &right).unwrap();
        assert_eq!(
            (again.status, again.reason.as_deref()),
            (status, Some(reason)),
            "{again:?}"
        );
        let error = again.disparity_px.unwrap()[0] - pairs[2].truth.disparity_px[0];
        assert!(error.abs() < 0.1, "{reason}: disparity {error:+.3} px off");
        let contour = Polygon::new(again.left.as_ref().unwrap().contour.clone());
        let iou = polygon_iou(&contour, &pairs[2].truth.left.polygon);
        assert!(iou > 0.9, "{reason}: IoU {iou:.3}");
    }
}

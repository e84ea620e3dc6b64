//! Unit tests of the fits.
use super::free::cut_spurs;
use super::*;
use crate::energy::{window_of, EnergyParams};
use crate::geometry::mask_iou;
use crate::geometry::Polygon;
use crate::imageio::GrayFrame;
use crate::region::PixelRect;
use crate::region::PrefixSums;
use crate::synth::{Preset, Scene, Shape, SynthConfig};

/// A spike and a notch 3 px wide on a circle are cut; a tool's point
/// and a thin rod's ends, where the outline turns back, are kept.
#[test]
fn spurs_are_cut_and_points_kept() {
    let at = |angle: f64, r: f64| [r * angle.cos(), r * angle.sin()];
    let circle = Polygon::circle([0.0, 0.0], 60.0, 64).points;
    let mut points = Vec::new();
    for (k, p) in circle.iter().enumerate() {
        points.push(*p);
        let a = k as f64 * std::f64::consts::TAU / 64.0 + 0.04;
        if k == 10 || k == 40 {
            // 16 px out, or in, through a 3-px neck.
            let r = if k == 10 { 76.0 } else { 44.0 };
            points.extend([at(a, 60.0), at(a + 0.025, r), at(a + 0.05, 60.0)]);
        }
    }
    let spiky = Polygon::new(points);
    let spiky = spiky.resampled((spiky.length() / 6.0).round() as usize).points;
    let cut = cut_spurs(&spiky, 4.5, 48.0).expect("a spike and a notch");
    let radius = |p: &Point| p[0].hypot(p[1]);
    assert!(
        cut.iter().all(|p| (radius(p) - 60.0).abs() < 1.0),
        "a vertex left {:.1} px off the circle",
        cut.iter().map(|p| (radius(p) - 60.0).abs()).fold(0.0, f64::max)
    );
    assert!(
        cut_spurs(&circle, 4.5, 48.0).is_none(),
        "nothing to cut on a circle"
    );
    // A tool tip: a 10-degree point 120 px long, a vertex every 6 px.
    let tip = Polygon::new(vec![[0.0, 0.0], [120.0, -10.5], [120.0, 10.5]]);
    let tip = tip.resampled((tip.length() / 6.0).round() as usize).points;
    assert!(cut_spurs(&tip, 4.5, 48.0).is_none(), "the point is kept");
    // A rod 4 px wide (both sides within the neck) and 200 px long.
    let rod = Polygon::new(vec![[0.0, 0.0], [200.0, 0.0], [200.0, 4.0], [0.0, 4.0]]);
    let rod = rod.resampled((rod.length() / 6.0).round() as usize).points;
    assert!(cut_spurs(&rod, 4.5, 48.0).is_none(), "the ends are kept");
}

#[test]
fn free_fit_pulls_a_rough_outline_onto_the_object() {
    for shape in Shape::ALL {
        let config = SynthConfig {
            frames: 1,
            ..SynthConfig::preset(Preset::Noisy, shape, 5)
        };
        let pair = Scene::new(&config).unwrap().render(0);
        let truth = &pair.truth.left.polygon;
        // Start 3 px too large (as a dilated initialisation would be).
        let c = truth.centroid();
        let r = truth.area().sqrt();
        let grow = 1.0 + 3.0 / r;
        let start = truth.scaled(grow, [c[0] * (1.0 - grow), c[1] * (1.0 - grow)]);
        let sums = PrefixSums::new(&pair.left, PixelRect::full(&pair.left), 1);
        let out = fit_free(&sums, &start, &EnergyParams::default(), &FreeFitParams::default());
        let (w, h) = (config.width, config.height);
        let truth_mask = truth.rasterize(w, h);
        let before = mask_iou(&start.rasterize(w, h), &truth_mask);
        let after = mask_iou(&out.polygon.rasterize(w, h), &truth_mask);
        assert!(
            after > 0.95 && after > before,
            "{shape:?}: IoU {before:.3} -> {after:.3}"
        );
        assert!(
            out.converged,
            "{shape:?} did not converge in {} sweeps",
            out.sweeps
        );
    }
}

#[test]
fn rigid_fit_recovers_shift_and_rotation() {
    let config = SynthConfig {
        frames: 1,
        ..SynthConfig::preset(Preset::Clean, Shape::Tip, 2)
    };
    let pair = Scene::new(&config).unwrap().render(0);
    let truth = &pair.truth.left.polygon;
    let energy = EnergyParams::default();
    let (template, true_pose) = RigidTemplate::new(&truth.resampled(240), 48, &energy);
    let sums = PrefixSums::new(&pair.left, PixelRect::full(&pair.left), 1);
    for (dx, dy, dt) in [
        (0.3, -0.2, 0.0),
        (-12.0, 9.0, 0.03),
        (20.0, 0.0, -0.02),
        (0.0, -19.5, 0.0),
    ] {
        let start = Pose {
            x: true_pose.x + dx,
            y: true_pose.y + dy,
            theta: dt,
        };
        let params = RigidParams::default();
        let out = fit_rigid(
            &sums,
            &template,
            start,
            &energy,
            &params,
            RigidSearch::of(&params),
        );
        let err = (out.pose.x - true_pose.x).hypot(out.pose.y - true_pose.y);
        assert!(
            err < 0.05,
            "start offset ({dx}, {dy}, {dt}): error {err:.3} px, pose {:?}",
            out.pose
        );
        assert!(out.pose.theta.abs() < 0.002, "rotation {}", out.pose.theta);
    }
}
#[test]
fn a_fit_that_needs_more_than_the_covered_area_says_so() {
    let config = SynthConfig {
        frames: 1,
        ..SynthConfig::preset(Preset::Clean, Shape::Blob, 3)
    };
    let pair = Scene::new(&config).unwrap().render(0);
    let energy = EnergyParams::default();
    let (template, true_pose) = RigidTemplate::new(&pair.truth.left.polygon.resampled(120), 48, &energy);
    // Start 10 px off; fine stage only, as from a confirmed prediction.
    let start = Pose {
        x: true_pose.x + 10.0,
        y: true_pose.y - 1.0,
        theta: 0.0,
    };
    let params = RigidParams::default();
    let search = RigidSearch::of(&params).fine_only();
    // Tables covering the start's window grown by `reach` on each side.
    let cover = |reach: f64| {
        let [x0, y0, x1, y1] = window_of(&place(&template.points, start), template.margin + reach);
        PixelRect::covering(x0, y0, x1, y1, pair.left.width, pair.left.height).unwrap()
    };
    // Reaching 1 px: the way to the object is cut off, and the outcome
    // says so.
    let short = PrefixSums::new(&pair.left, cover(1.0), 1);
    let cut = fit_rigid(&short, &template, start, &energy, &params, search);
    assert!(
        cut.outside_area,
        "pose {:?} from a 1-px reach, truth {true_pose:?}",
        cut.pose
    );
    // Reaching 16 px: found, and no evaluation left the area.
    let long = PrefixSums::new(&pair.left, cover(16.0), 1);
    let out = fit_rigid(&long, &template, start, &energy, &params, search);
    let err = (out.pose.x - true_pose.x).hypot(out.pose.y - true_pose.y);
    assert!(
        !out.outside_area && err < 0.05,
        "error {err:.3} px, outside {}",
        out.outside_area
    );
}

#[test]
fn cuts_follow_the_template_and_leave_out_what_lies_beyond_them() {
    // A bar 40 px wide entering from the left border of a 200x100 image.
    let image = [-0.5, -0.5, 199.5, 99.5];
    let outline = Polygon::new(vec![[-0.5, 30.0], [120.0, 30.0], [120.0, 70.0], [-0.5, 70.0]]);
    let energy = EnergyParams::default();
    let (template, pose) = RigidTemplate::new(&outline, 32, &energy);
    let template = template.cut_by(image, pose);
    assert_eq!(
        template.cuts.len(),
        1,
        "only the left side runs along the outline"
    );
    // At the template's own pose the cut runs along the image's left
    // side, CUT_INSET_PX inside it.
    let inset = RigidTemplate::CUT_INSET_PX;
    let cut = template.cuts_at(pose)[0];
    assert!((cut.normal[0] - 1.0).abs() < 1e-12 && (cut.offset - (inset - 0.5)).abs() < 1e-9);
    // Moved and turned, it still runs along the outline's border side,
    // as far inside it.
    let moved = Pose {
        x: pose.x + 5.0,
        y: pose.y - 3.0,
        theta: 0.1,
    };
    let cut = template.cuts_at(moved)[0];
    let placed = place(&template.points, moved);
    let on_line = placed
        .iter()
        .filter(|p| (cut.depth(**p) + inset).abs() < 1e-9)
        .count();
    assert!(on_line >= 2, "{on_line} vertices on the moved border side");
    assert!(placed.iter().all(|p| cut.depth(*p) > -inset - 1e-9));
    // The bar shows its rotation; a disc cut by the border shows an arc,
    // which does not.
    assert!(template.rotation_observable);
    let disc = Polygon::circle([10.0, 50.0], 30.0, 120).clipped_to_box(image);
    let (d, p) = RigidTemplate::new(&disc, 32, &energy);
    assert!(d.rotation_observable, "uncut, the half disc's turn shows");
    assert!(!d.cut_by(image, p).rotation_observable);
    // An outline that only touches a side (less than MIN_CUT_PX) is not cut.
    let touching = Polygon::new(vec![[-0.5, 30.0], [60.0, 10.0], [60.0, 50.0], [-0.5, 32.0]]);
    let (t, p) = RigidTemplate::new(&touching, 32, &energy);
    assert!(t.cut_by(image, p).cuts.is_empty());

    // The energy of the cut template in an image of the bar is lowest
    // at the bar, also once the bar has moved 10 px further in (its base
    // still outside the frame); and what lies beyond the cut, where the
    // template does not know the object, does not change it.
    let frame_with_bar = |start: f64, end: f64| {
        let data = (0..200 * 100)
            .map(|i| {
                let (x, y) = ((i % 200) as f64, (i / 200) as f64);
                if (start..=end).contains(&x) && (30.0..70.0).contains(&y) {
                    180
                } else {
                    60
                }
            })
            .collect();
        GrayFrame::new(200, 100, 8, data).unwrap()
    };
    for shift in [0.0, 10.0] {
        let energy_at = |frame: &GrayFrame, dx: f64| {
            // The energy's scale, the mean of the reference area, from
            // where the frames agree.
            let reference = PixelRect {
                x: 20,
                y: 0,
                width: 180,
                height: 100,
            };
            let sums = PrefixSums::new(frame, PixelRect::full(frame), 1).with_reference(reference);
            let p = Pose {
                x: pose.x + shift + dx,
                ..pose
            };
            template.energy_at(&sums, p, &energy).energy
        };
        let frame = frame_with_bar(-1.0, 119.5 + shift);
        let best = energy_at(&frame, 0.0);
        assert!(best.is_finite());
        for dx in [-3.0, -1.0, 1.0, 3.0] {
            assert!(
                energy_at(&frame, dx) > best,
                "shift {shift}: energy at {dx} px not above the bar's"
            );
        }
        // The bar's unseen base gone: the same energy.
        let without_base = frame_with_bar(shift - 0.5, 119.5 + shift);
        let e = energy_at(&without_base, 0.0);
        assert!(
            (e - best).abs() < 1e-9 * best.abs(),
            "shift {shift}: {e} against {best}"
        );
    }
}
#[test]
fn a_fixed_domain_holds_a_shaded_bar_at_its_tip() {
    // A bar 30 px wide with a round tip entering a 400x300 image from
    // its right side at 0.5 rad, brighter towards its base (150 at the
    // tip, 190 at its unseen end), moved 15 px further in since its
    // template was made.
    let (w, h) = (400usize, 300usize);
    let image = [-0.5, -0.5, w as f64 - 0.5, h as f64 - 0.5];
    let u = [-0.5f64.cos(), -0.5f64.sin()];
    let n = [-u[1], u[0]];
    let (base, half, length, shift) = ([420.0, 200.0], 15.0, 200.0, 15.0);
    let frame = {
        let length = length + shift;
        let data = (0..w * h)
            .map(|i| {
                let d = [(i % w) as f64 - base[0], (i / w) as f64 - base[1]];
                let (t, across) = (d[0] * u[0] + d[1] * u[1], (d[0] * n[0] + d[1] * n[1]).abs());
                let bar = (0.0..=length).contains(&t) && across <= half;
                if bar || (t - length).hypot(across) <= half {
                    (150.0 + 40.0 * (1.0 - t / length)).round() as u16
                } else {
                    60
                }
            })
            .collect();
        GrayFrame::new(w as u32, h as u32, 8, data).unwrap()
    };
    let tip = [base[0] + length * u[0], base[1] + length * u[1]];
    let mut outline: Vec<Point> = (0..=20)
        .map(|k| {
            let (s, c) = (std::f64::consts::PI * (k as f64 / 20.0 - 0.5)).sin_cos();
            [
                tip[0] + half * (c * u[0] + s * n[0]),
                tip[1] + half * (c * u[1] + s * n[1]),
            ]
        })
        .collect();
    outline.push([base[0] + half * n[0], base[1] + half * n[1]]);
    outline.push([base[0] - half * n[0], base[1] - half * n[1]]);
    let energy = EnergyParams::default();
    let (template, pose) = RigidTemplate::new(&Polygon::new(outline).clipped_to_box(image), 32, &energy);
    let template = template.cut_by(image, pose);
    assert_eq!(template.cuts.len(), 1);
    let sums = PrefixSums::new(&frame, PixelRect::full(&frame), 1);
    // Where along the axis (positive towards the tip) the energy is
    // lowest, within 20 px of the truth.
    let lowest = |template: &RigidTemplate| {
        (-80..=80)
            .map(|i| 0.25 * i as f64)
            .map(|s| {
                let at = Pose {
                    x: pose.x + (shift + s) * u[0],
                    y: pose.y + (shift + s) * u[1],
                    ..pose
                };
                (s, template.energy_at(&sums, at, &energy).energy)
            })
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap()
            .0
    };
    // Cuts and window moving with the template: it slides back towards
    // the brighter base.
    let moving = lowest(&template);
    assert!(moving < -3.0, "moving cut: {moving:+.2} px");
    // In a domain fixed where the template was, only the tip moves
    // pixels between the regions.
    let fixed = lowest(&template.fixed_at(image, pose, 24.0));
    assert!(fixed.abs() <= 0.5, "fixed domain: {fixed:+.2} px");
}

use super::*;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

fn geometric(pixel_size_um: f64, vergence_deg: f64, d0: f64, tilt: f64) -> Calibration {
    build(CalibrationSpec::Geometric(GeometricSpec {
        pixel_size_um: Some(pixel_size_um),
        pixel_size: None,
        vergence_deg: Some(vergence_deg),
        vergence: None,
        reference_disparity_px: d0,
        tilt_axis_deg: tilt,
    }))
    .unwrap()
}

fn fit_spec(degree: u8, samples: Vec<Sample>) -> CalibrationSpec {
    CalibrationSpec::Fit(FitSpec {
        degree,
        samples,
        tilt_axis_deg: DEFAULT_TILT_AXIS_DEG,
    })
}

fn samples_of(d: &[f64], f: impl Fn(f64) -> f64) -> Vec<Sample> {
    d.iter().map(|&x| Sample::new(x, f(x))).collect()
}

fn rel_close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * a.abs().max(b.abs()).max(1e-300)
}

#[test]
fn geometric_ten_degrees_one_pixel_is_5_737_um() {
    let cal = geometric(1.0, 10.0, 0.0, 90.0);
    let z = cal.z_from_axis(1.0);
    assert!((z - 5.737).abs() < 5e-4, "{z}");
    assert!(rel_close(z, 1.0 / (2.0 * 5f64.to_radians().sin()), 1e-15));
    assert_eq!(cal.coefficients(), &[0.0, z]);
    assert_eq!(cal.z_um([1.0, 123.0]), z, "tilt axis 90: only dx counts");
    assert!((cal.z_from_axis(0.05) - 0.29).abs() < 5e-3, "0.05 px is 0.29 s");
    assert_eq!(cal.model_name(), "geometric");
    assert!(cal.fit_stats().is_none() && cal.samples().is_empty());
}

#[test]
fn geometric_reference_disparity_offsets_zero() {
    let cal = geometric(0.5, 6.0, 2.5, 90.0);
    let k = 0.5 / (2.0 * 3f64.to_radians().sin());
    assert_eq!(cal.z_from_axis(2.5), 0.0);
    assert!(rel_close(cal.z_from_axis(3.5), k, 1e-14));
    assert!(rel_close(cal.z_from_axis(1.5), -k, 1e-14));
    let c = cal.coefficients();
    assert!(rel_close(c[1], k, 1e-15) && rel_close(c[0], -2.5 * k, 1e-15));
    for d in [-10.0, 0.0, 7.25] {
        assert!((c[0] + c[1] * d - cal.z_from_axis(d)).abs() < 1e-12);
    }
}

#[test]
fn axis_component_sign_convention() {
    let d = [3.0, -2.0];
    assert_eq!(axis_component(90.0, d), 3.0);
    assert_eq!(axis_component(0.0, d), 2.0, "axis along x: -dy");
    assert_eq!(axis_component(180.0, d), -2.0, "dy");
    assert_eq!(axis_component(270.0, d), -3.0, "-dx");
    assert_eq!(axis_component(-90.0, d), -3.0);
    assert_eq!(axis_component(-180.0, d), -2.0);
    assert_eq!(axis_component(450.0, d), 3.0);
    let s = 45f64.to_radians().sin();
    assert!((axis_component(45.0, d) - (3.0 * s + 2.0 * s)).abs() < 1e-12);
    // Tilt axis 0 deg: the calibration uses -dy.
    let cal = geometric(1.0, 10.0, 0.0, 0.0);
    assert_eq!(cal.z_um([100.0, -1.0]), cal.z_from_axis(1.0));
    assert_eq!(cal.z_um([100.0, 2.0]), cal.z_from_axis(-2.0));
}

#[test]
fn linear_fit_recovers_exact_coefficients() {
    let d = [-2.0, -1.0, -0.5, 0.0, 1.0, 2.0, 3.5];
    let cal = build(fit_spec(1, samples_of(&d, |x| 3.0 + 40.0 * x))).unwrap();
    let c = cal.coefficients();
    assert_eq!(c.len(), 2);
    assert!((c[0] - 3.0).abs() < 1e-12 && (c[1] - 40.0).abs() < 1e-12, "{c:?}");
    let stats = cal.fit_stats().unwrap();
    assert!(stats.residual_rms_um < 1e-12);
    assert_eq!(stats.r_squared, 1.0);
    assert!((cal.z_um([0.25, 9.0]) - 13.0).abs() < 1e-12);
    assert_eq!(cal.model_name(), "fit");
}

#[test]
fn quadratic_fit_recovers_c2() {
    let d: Vec<f64> = (0..9).map(|i| -4.0 + i as f64).collect();
    let cal = build(fit_spec(2, samples_of(&d, |x| -1.5 + 12.0 * x + 0.75 * x * x))).unwrap();
    let c = cal.coefficients();
    assert_eq!(c.len(), 3);
    assert!((c[0] + 1.5).abs() < 1e-12);
    assert!((c[1] - 12.0).abs() < 1e-12);
    assert!((c[2] - 0.75).abs() < 1e-12, "{c:?}");
    assert!(cal.residual_rms_um().unwrap() < 1e-12);
}

#[test]
fn noisy_fit_has_plausible_rms_and_r_squared() {
    // Like the paper's 60x data: ~4 px over 400 um, with 2 um of height noise.
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let noise = Normal::new(0.0, 2.0).unwrap();
    let samples: Vec<Sample> = (0..41)
        .map(|i| {
            let d = 10.0 + 0.1 * i as f64;
            Sample::new(d, -1000.0 + 100.0 * d + noise.sample(&mut rng))
        })
        .collect();
    let cal = build(fit_spec(1, samples)).unwrap();
    let stats = cal.fit_stats().unwrap();
    assert!(
        stats.residual_rms_um > 1.2 && stats.residual_rms_um < 2.8,
        "{stats:?}"
    );
    assert!(stats.r_squared > 0.999 && stats.r_squared < 1.0, "{stats:?}");
    assert!(
        (cal.coefficients()[1] - 100.0).abs() < 2.0,
        "{:?}",
        cal.coefficients()
    );
}

#[test]
fn too_few_distinct_disparities_give_no_height_until_there_are_enough() {
    // One distinct disparity for a line: pending, no height, and why.
    let pending = build(fit_spec(1, samples_of(&[2.0; 10], |_| 5.0))).unwrap();
    let why = pending.pending().expect("pending");
    assert!(why.contains("1 distinct disparity_px values of the 2"), "{why}");
    assert!(pending.coefficients().is_empty());
    assert_eq!(pending.fit_stats(), None);
    assert_eq!(pending.z_for_pair([3.0, 0.0], None), Err(why));
    // Two distinct for a parabola; values closer than the tolerance are
    // one; no samples at all.
    let d: Vec<f64> = (0..12).map(|i| if i % 2 == 0 { 1.0 } else { 4.0 }).collect();
    let two = build(fit_spec(2, samples_of(&d, |x| x * 3.0 + (x * 7.0).sin()))).unwrap();
    assert!(two
        .pending()
        .unwrap()
        .contains("2 distinct disparity_px values of the 3"));
    assert!(build(fit_spec(1, samples_of(&[1.0, 1.0 + 1e-9], |x| x)))
        .unwrap()
        .pending()
        .is_some());
    let mut empty = build(fit_spec(1, vec![])).unwrap();
    assert!(empty.pending().is_some());
    // Filled from stage steps: the second distinct sample makes it a line.
    empty.add_sample(Sample::new(1.0, 10.0)).unwrap();
    assert!(empty.pending().is_some());
    empty.add_sample(Sample::new(2.0, 20.0)).unwrap();
    assert_eq!(empty.pending(), None);
    assert!((empty.z_for_pair([3.0, 0.0], None).unwrap() - 30.0).abs() < 1e-9);
    // A pending calibration is rebuilt the same from its parameters.
    assert_eq!(build(pending.spec().clone()).unwrap(), pending);
}

#[test]
fn refuses_ill_conditioned_fit() {
    // Three distinct disparities, two of them 2e-6 px apart over a 2e6 px range.
    let d = [-1e6, -1e6 + 2e-6, 1e6];
    let err = build(fit_spec(2, samples_of(&d, |x| x * 1e-3))).unwrap_err();
    assert_eq!(err.code(), "degenerate_fit", "{err}");
    assert!(err.to_string().contains("ill-conditioned"), "{err}");
}

#[test]
fn refuses_invalid_and_non_finite_inputs() {
    let geo = |s: f64, v: f64, d0: f64, t: f64| {
        build(CalibrationSpec::Geometric(GeometricSpec {
            pixel_size_um: Some(s),
            pixel_size: None,
            vergence_deg: Some(v),
            vergence: None,
            reference_disparity_px: d0,
            tilt_axis_deg: t,
        }))
        .unwrap_err()
    };
    let err = geo(1.0, 0.0, 0.0, 90.0);
    assert_eq!(err.code(), "invalid_calibration");
    assert_eq!(
        err.to_string(),
        "invalid vergence_deg 0 (expected 0 < vergence_deg <= 90)"
    );
    assert!(geo(1.0, 90.5, 0.0, 90.0).to_string().contains("vergence_deg"));
    assert!(geo(1.0, f64::NAN, 0.0, 90.0).to_string().contains("vergence_deg"));
    assert!(geo(0.0, 5.0, 0.0, 90.0).to_string().contains("pixel_size_um > 0"));
    assert!(geo(f64::INFINITY, 5.0, 0.0, 90.0)
        .to_string()
        .contains("pixel_size_um"));
    assert!(geo(-1.0, 5.0, 0.0, 90.0).to_string().contains("pixel_size_um"));
    assert!(geo(1.0, 5.0, f64::NAN, 90.0)
        .to_string()
        .contains("reference_disparity_px"));
    assert!(geo(1.0, 5.0, 0.0, f64::NAN).to_string().contains("tilt_axis_deg"));
    assert!(build(CalibrationSpec::Geometric(GeometricSpec {
        pixel_size_um: Some(1.0),
        pixel_size: None,
        vergence_deg: Some(90.0),
        vergence: None,
        reference_disparity_px: 0.0,
        tilt_axis_deg: 90.0,
    }))
    .is_ok());

    let good = samples_of(&[0.0, 1.0, 2.0, 3.0], |x| 2.0 * x);
    for (i, bad) in [
        Sample::new(f64::NAN, 1.0),
        Sample::new(f64::INFINITY, 1.0),
        Sample::new(1.5, f64::NAN),
        Sample::new(1.5, f64::NEG_INFINITY),
        Sample::new(1e7, 1.0),
    ]
    .into_iter()
    .enumerate()
    {
        let mut s = good.clone();
        s.push(bad);
        let err = build(fit_spec(1, s)).unwrap_err();
        assert_eq!(err.code(), "invalid_calibration", "case {i}: {err}");
        assert!(err.to_string().contains("samples[4]"), "case {i}: {err}");
    }
    for degree in [0, 3] {
        let err = build(fit_spec(degree, good.clone())).unwrap_err();
        assert_eq!(
            err.to_string(),
            format!("invalid degree {degree} (expected 1 or 2)")
        );
    }
    let too_many = samples_of(&vec![1.0; MAX_SAMPLES + 1], |x| x);
    assert_eq!(
        build(fit_spec(1, too_many)).unwrap_err().code(),
        "too_many_samples"
    );
}

#[test]
fn all_equal_heights_fit_with_r_squared_one() {
    let cal = build(fit_spec(1, samples_of(&[0.1, 0.7, 1.3, 2.2], |_| 0.3))).unwrap();
    let stats = cal.fit_stats().unwrap();
    assert_eq!(stats.r_squared, 1.0);
    assert!(stats.residual_rms_um < 1e-15);
    assert!(cal.coefficients()[1].abs() < 1e-14);
    assert!((cal.z_from_axis(5.0) - 0.3).abs() < 1e-13);
}

#[test]
fn add_sample_refits() {
    let mut cal = build(fit_spec(1, samples_of(&[0.0, 1.0], |x| 10.0 * x))).unwrap();
    assert!((cal.coefficients()[1] - 10.0).abs() < 1e-12);
    assert_eq!(cal.r_squared(), Some(1.0));
    cal.add_sample(Sample::new(2.0, 26.0)).unwrap();
    assert_eq!(cal.samples().len(), 3);
    // Least squares through (0,0), (1,10), (2,26): slope 13, intercept -1.
    let c = cal.coefficients();
    assert!((c[0] + 1.0).abs() < 1e-12 && (c[1] - 13.0).abs() < 1e-12, "{c:?}");
    assert!(cal.residual_rms_um().unwrap() > 0.5);
    assert!(cal.r_squared().unwrap() < 1.0);

    // A failed add leaves the calibration unchanged.
    let before = cal.clone();
    assert_eq!(
        cal.add_sample(Sample::new(f64::NAN, 1.0)).unwrap_err().code(),
        "invalid_calibration"
    );
    assert_eq!(cal, before);

    let mut geo = geometric(1.0, 5.0, 0.0, 90.0);
    let err = geo.add_sample(Sample::new(1.0, 1.0)).unwrap_err();
    assert_eq!(err.code(), "not_a_fit");
    assert!(
        err.to_string()
            .contains("samples only apply to fitted calibrations"),
        "{err}"
    );
}

#[test]
fn ill_conditioned_disparities_still_fit_degree_two() {
    // Disparities 1000 +- 0.5 px: naive normal equations in d lose all digits here.
    let truth = |d: f64| {
        let e = d - 1000.0;
        5.0 + 40.0 * e + 30.0 * e * e
    };
    let d: Vec<f64> = (-10..=10).map(|k| 1000.0 + 0.05 * k as f64).collect();
    let cal = build(fit_spec(2, samples_of(&d, truth))).unwrap();
    let z_max = d.iter().map(|&x| truth(x).abs()).fold(0.0, f64::max);
    for &x in &d {
        let err = (cal.z_from_axis(x) - truth(x)).abs();
        assert!(err <= 1e-6 * z_max, "d={x}: err {err}");
    }
    // The monomial coefficients too: c2 = 30, c1 = 40 - 60000, c0 = 5 - 40000 + 3e7.
    let c = cal.coefficients();
    assert!(rel_close(c[2], 30.0, 1e-6), "{c:?}");
    assert!(rel_close(c[1], 40.0 - 60_000.0, 1e-6), "{c:?}");
    assert!(rel_close(c[0], 5.0 - 40_000.0 + 30_000_000.0, 1e-6), "{c:?}");
    let stats = cal.fit_stats().unwrap();
    assert!(stats.residual_rms_um <= 1e-6 * z_max, "{stats:?}");
    assert!(stats.r_squared > 1.0 - 1e-9);
    // Reading it back gives the same calibration.
    // Rebuilt from its parameters it is the same, and its derived fields agree.
    assert_eq!(build(cal.spec().clone()).unwrap(), cal);
    cal.check_derived(Some(cal.coefficients()), cal.residual_rms_um(), cal.r_squared())
        .unwrap();
}

#[test]
fn geometric_scale_overflow_is_refused() {
    let spec = CalibrationSpec::Geometric(GeometricSpec {
        pixel_size_um: Some(0.5),
        pixel_size: None,
        vergence_deg: Some(5e-324),
        vergence: None,
        reference_disparity_px: 0.0,
        tilt_axis_deg: 90.0,
    });
    let e = build(spec).unwrap_err();
    assert_eq!(e.code(), "invalid_calibration");
    assert!(e.to_string().contains("non-finite"), "{e}");
}

/// A geometric calibration taking the pixel size and the vergence from
/// the images, with this reference disparity.
fn from_images_spec(reference_disparity_px: f64) -> CalibrationSpec {
    CalibrationSpec::Geometric(GeometricSpec {
        pixel_size_um: None,
        pixel_size: Some(PixelSizeSource::FromImages),
        vergence_deg: None,
        vergence: Some(VergenceSource::FromStageTilt),
        reference_disparity_px,
        tilt_axis_deg: 90.0,
    })
}

fn view(pixel_m: f64, tilt_rad: f64) -> ViewMeta {
    ViewMeta {
        pixel_width_m: Some(pixel_m),
        pixel_height_m: Some(pixel_m),
        stage_tilt_rad: Some(tilt_rad),
        beam: None,
    }
}

#[test]
fn pixel_size_and_vergence_from_the_images_match_the_typed_calibration() {
    let from_images = build(from_images_spec(1.5)).unwrap();
    assert!(from_images.needs_images());
    assert!(from_images.coefficients().is_empty());
    let (tilt_l, tilt_r) = (0.558473_f64, 0.558473_f64 + 7.0_f64.to_radians());
    let meta = PairMeta::new(view(9.76562e-8, tilt_l), view(9.76562e-8, tilt_r));
    let typed = build(CalibrationSpec::Geometric(GeometricSpec {
        reference_disparity_px: 1.5,
        ..GeometricSpec::new(0.0976562, (tilt_r - tilt_l).to_degrees())
    }))
    .unwrap();
    for d in [[-30.0, 2.0], [0.0, 0.0], [1.5, -4.0], [55.11, 4.26]] {
        let z = from_images.z_for_pair(d, Some(&meta)).unwrap();
        let expected = typed.z_um(d);
        assert!((z - expected).abs() <= 1e-9, "d {d:?}: {z} against {expected}");
    }
    // Either one from the images, the other typed.
    let half = build(CalibrationSpec::Geometric(GeometricSpec {
        pixel_size_um: None,
        pixel_size: Some(PixelSizeSource::FromImages),
        ..GeometricSpec::new(0.0, 7.0)
    }))
    .unwrap();
    let z = half.z_for_pair([10.0, 0.0], Some(&meta)).unwrap();
    let typed_half = build(CalibrationSpec::Geometric(GeometricSpec::new(0.0976562, 7.0))).unwrap();
    assert!((z - typed_half.z_um([10.0, 0.0])).abs() <= 1e-9);
    // A right image tilted less: heights of the other sign.
    let swapped = PairMeta::new(view(9.76562e-8, tilt_r), view(9.76562e-8, tilt_l));
    let z = from_images.z_for_pair([10.0, 0.0], Some(&swapped)).unwrap();
    assert!((z + typed.z_um([10.0, 0.0])).abs() <= 1e-9, "{z}");
}

#[test]
fn missing_or_contradicting_metadata_gives_no_height_and_says_why() {
    let cal = build(from_images_spec(0.0)).unwrap();
    let no_height = |meta: Option<&PairMeta>| cal.z_for_pair([3.0, 0.0], meta).unwrap_err();
    assert!(no_height(None).contains("no metadata"));
    let no_tilt = PairMeta::new(
        ViewMeta {
            stage_tilt_rad: None,
            ..view(1e-7, 0.0)
        },
        view(1e-7, 0.1),
    );
    assert!(no_height(Some(&no_tilt)).contains("stage tilt"));
    let same_tilt = PairMeta::new(view(1e-7, 0.1), view(1e-7, 0.1));
    assert!(no_height(Some(&same_tilt)).contains("no vergence"));
    let zoomed = PairMeta::new(view(1e-7, 0.0), view(1.05e-7, 0.1));
    assert!(no_height(Some(&zoomed)).contains("magnification"));
    let no_pixel = PairMeta::new(
        ViewMeta {
            pixel_width_m: None,
            pixel_height_m: None,
            ..view(1e-7, 0.0)
        },
        view(1e-7, 0.1),
    );
    assert!(no_height(Some(&no_pixel)).contains("no pixel size"));
    // An electron image beside an ion image: the columns' own angle is
    // between the views, not the stage tilt difference.
    use crate::meta::Beam;
    let by = |beam: Beam, tilt_rad: f64| ViewMeta {
        beam: Some(beam),
        ..view(1e-7, tilt_rad)
    };
    let mixed = PairMeta::new(by(Beam::Electron, 0.0), by(Beam::Ion, 0.1));
    assert!(no_height(Some(&mixed))
        .contains("the left image is the electron beam's and the right the ion beam's"));
    let both_ion = PairMeta::new(by(Beam::Ion, 0.0), by(Beam::Ion, 0.1));
    assert!(cal.z_for_pair([3.0, 0.0], Some(&both_ion)).is_ok());
    // Non-square pixels: the length across the tilt axis (axis along y:
    // the width; along x: the height).
    let wide = PairMeta::new(
        ViewMeta {
            pixel_width_m: Some(2e-7),
            pixel_height_m: Some(1e-7),
            stage_tilt_rad: Some(0.0),
            beam: None,
        },
        ViewMeta {
            pixel_width_m: Some(2e-7),
            pixel_height_m: Some(1e-7),
            stage_tilt_rad: Some(0.1),
            beam: None,
        },
    );
    assert!((wide.pixel_size_um(90.0).unwrap() - 0.2).abs() < 1e-12);
    assert!((wide.pixel_size_um(0.0).unwrap() - 0.1).abs() < 1e-12);
}

#[test]
fn a_magnification_change_is_warned_once_per_change() {
    let cal = build(CalibrationSpec::Geometric(GeometricSpec::new(0.1, 6.0))).unwrap();
    let at = |pixel_m: f64| PairMeta::new(view(pixel_m, 0.0), view(pixel_m, 0.1));
    let mut watch = MetaWatch::default();
    let warned: Vec<bool> = [1e-7, 1e-7, 2e-7, 2e-7, 2.001e-7, 1e-7, 1.004e-7, 3e-7]
        .iter()
        .map(|&p| watch.check(&cal, Some(&at(p))).is_some())
        .collect();
    assert_eq!(warned, [false, false, true, false, false, false, false, true]);
    let text = MetaWatch::default().check(&cal, Some(&at(2e-7)));
    assert!(
        text.as_ref()
            .is_some_and(|t| t.contains("0.200000 um") && t.contains("100.0%")),
        "{text:?}"
    );
    // Without metadata, or with a fit, nothing to compare.
    assert_eq!(MetaWatch::default().check(&cal, None), None);
}

#[test]
fn height_errors_carry_the_slope_and_a_fit_s_own_error() {
    // Geometric: the disparity error through the slope, nothing else.
    let geometric = build(CalibrationSpec::Geometric(GeometricSpec::new(0.5, 10.0))).unwrap();
    let slope = geometric.coefficients()[1];
    let std = geometric.z_std_for_pair([3.0, 1.0], 0.1, None).unwrap();
    assert!((std - 0.1 * slope).abs() < 1e-12, "{std} against {}", 0.1 * slope);
    // A linear fit through scattered samples: the prediction error
    // s^2 (1 + 1/n + (d - mean)^2 / Sxx) adds to the slope's term.
    let d = [0.0, 1.0, 2.0, 3.0, 4.0];
    let z = [0.1, 2.0, 3.9, 6.2, 7.8];
    let fit = build(CalibrationSpec::Fit(FitSpec {
        degree: 1,
        samples: d.iter().zip(z).map(|(&d, z)| Sample::new(d, z)).collect(),
        tilt_axis_deg: 90.0,
    }))
    .unwrap();
    let (n, mean) = (5.0, 2.0);
    let sxx: f64 = d.iter().map(|x| (x - mean).powi(2)).sum();
    let s2 = fit.residual_rms_um().unwrap().powi(2) * n / (n - 2.0);
    let c1 = fit.coefficients()[1];
    for x in [-1.0, 2.0, 6.0] {
        let expected = ((c1 * 0.05).powi(2) + s2 * (1.0 + 1.0 / n + (x - mean).powi(2) / sxx)).sqrt();
        let got = fit.z_std_for_pair([x, 0.0], 0.05, None).unwrap();
        assert!((got - expected).abs() < 1e-9, "d {x}: {got} against {expected}");
    }
    // As many samples as coefficients: the fit's error is unknown, and the
    // height's standard error is the disparity's through the slope (2 um/px).
    let exact = build(CalibrationSpec::Fit(FitSpec {
        degree: 1,
        samples: vec![Sample::new(0.0, 0.0), Sample::new(1.0, 2.0)],
        tilt_axis_deg: 90.0,
    }))
    .unwrap();
    assert!(exact.fit_error_unknown() && !fit.fit_error_unknown());
    let std = exact.z_std_for_pair([0.5, 0.0], 0.05, None).unwrap();
    assert!((std - 0.1).abs() < 1e-9, "{std}");
    // A height difference in one pair: the intercept and the fit's
    // scatter cancel, the slope's uncertainty stays, s^2 (a - b)^2 / Sxx.
    for (a, b) in [(1.0, 3.0), (-1.0, 6.0), (2.0, 2.0)] {
        let (dz, std) = fit.dz_for_pair([a, 0.0], [b, 0.0], [0.05, 0.08], None).unwrap();
        assert!((dz - c1 * (a - b)).abs() < 1e-9, "{dz}");
        let expected = (c1.powi(2) * (0.05f64.powi(2) + 0.08f64.powi(2)) + s2 * (a - b).powi(2) / sxx).sqrt();
        assert!(
            (std.unwrap() - expected).abs() < 1e-9,
            "{a} - {b}: {std:?} against {expected}"
        );
    }
    let (_, std) = geometric
        .dz_for_pair([3.0, 1.0], [1.0, 1.0], [0.1, 0.1], None)
        .unwrap();
    assert!((std.unwrap() - 0.1 * slope * 2f64.sqrt()).abs() < 1e-12);
}

#[test]
fn an_explicit_tilt_axis_must_be_the_calibrations() {
    assert!(same_tilt_axis(90.0, 90.0).is_ok());
    assert!(same_tilt_axis(-270.0, 90.0).is_ok(), "one axis, written two ways");
    let e = same_tilt_axis(0.0, 90.0).unwrap_err();
    assert!(e.contains("tilt_axis_deg 0") && e.contains("90 deg"), "{e}");
    assert!(
        same_tilt_axis(270.0, 90.0).is_err(),
        "the opposite direction flips z"
    );
}

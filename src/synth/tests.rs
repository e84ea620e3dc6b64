//! Tests of the synthetic sequence generator: determinism, truth vs
//! rendering, margins, clutter, occlusion, noise statistics, output files,
//! validation, plus an ignored timing report.

use super::shapes::overlap_with_convex;
use super::*;

/// A plain scene: uniform object on a uniform background, no noise.
fn uniform(shape: Shape, seed: u64) -> SynthConfig {
    let mut cfg = SynthConfig::preset(Preset::Clean, shape, seed);
    cfg.frames = 3;
    cfg.bit_depth = 16;
    cfg.rim_strength = 0.0;
    cfg.object_texture = 0.0;
    cfg.shading = 0.0;
    cfg.background_gradient = 0.0;
    cfg.clutter.texture_amplitude = 0.0;
    cfg
}

/// First moment of (I - bg) / (fg - bg) over the image.
fn intensity_centroid(img: &crate::imageio::GrayFrame, bg: f64, fg: f64) -> [f64; 2] {
    let (mut m0, mut mx, mut my) = (0.0, 0.0, 0.0);
    for y in 0..img.height {
        for x in 0..img.width {
            let v = (img.get(x, y) as f64 - bg) / (fg - bg);
            m0 += v;
            mx += v * x as f64;
            my += v * y as f64;
        }
    }
    [mx / m0, my / m0]
}

#[test]
fn same_seed_same_bytes_other_seed_differs() {
    let mut cfg = SynthConfig::preset(Preset::Noisy, Shape::Blob, 11);
    cfg.frames = 2;
    let a = generate(&cfg).unwrap();
    let b = generate(&cfg).unwrap();
    for (p, q) in a.pairs.iter().zip(&b.pairs) {
        assert_eq!(p.left, q.left);
        assert_eq!(p.right, q.right);
        assert_eq!(p.truth, q.truth);
    }
    cfg.seed = 12;
    let c = generate(&cfg).unwrap();
    assert_ne!(a.pairs[0].left.data, c.pairs[0].left.data);
    // Random access equals streaming.
    cfg.seed = 11;
    let scene = Scene::new(&cfg).unwrap();
    assert_eq!(scene.render(1).right, a.pairs[1].right);
}

#[test]
fn truth_centroid_matches_intensity_moment() {
    for shape in Shape::ALL {
        for seed in [1, 2] {
            let cfg = uniform(shape, seed);
            let max = 65535.0;
            let bg = (cfg.background_level * max).round();
            let fg = ((cfg.background_level + cfg.object_contrast) * max).round();
            for pair in frames(&cfg).unwrap() {
                let t = &pair.truth;
                let cl = intensity_centroid(&pair.left, bg, fg);
                let cr = intensity_centroid(&pair.right, bg, fg);
                let el = (cl[0] - t.left.centroid[0]).hypot(cl[1] - t.left.centroid[1]);
                let er = (cr[0] - t.right.centroid[0]).hypot(cr[1] - t.right.centroid[1]);
                assert!(
                    el < 0.005 && er < 0.005,
                    "{shape:?} seed {seed} frame {}: errors {el:.4} {er:.4}",
                    t.frame
                );
                let dx = t.right.centroid[0] - t.left.centroid[0];
                assert!((t.disparity_px[0] - dx).abs() < 1e-9 && t.disparity_px[1] == 0.0);
                assert!((t.right.centroid[1] - t.left.centroid[1]).abs() < 1e-9);
                let expected = cfg.disparity.offset_px + cfg.disparity.px_per_um * t.z_um;
                assert!((t.disparity_px[0] - expected).abs() < 1e-9);
                // Measured disparity agrees too.
                assert!(
                    ((cr[0] - cl[0]) - dx).abs() < 0.005,
                    "{shape:?}: measured disparity {}",
                    cr[0] - cl[0]
                );
                assert!(t.left.polygon.len() >= MIN_VERTICES);
            }
        }
    }
}

#[test]
fn every_shape_and_preset_renders_inside_the_frame() {
    for shape in Shape::ALL {
        for preset in Preset::ALL {
            for seed in 0..20 {
                let mut cfg = SynthConfig::preset(preset, shape, seed);
                cfg.frames = 40;
                let scene = Scene::new(&cfg).unwrap_or_else(|e| panic!("{shape:?} {preset:?} {seed}: {e}"));
                let margin = BORDER_MARGIN * cfg.object_size() - 1e-6;
                for k in 0..cfg.frames {
                    let t = scene.truth(k);
                    for obj in [&t.left, &t.right] {
                        let b = obj.polygon.bounds();
                        assert!(
                            b[0] >= -0.5 + margin
                                && b[1] >= -0.5 + margin
                                && b[2] <= cfg.width as f64 - 0.5 - margin
                                && b[3] <= cfg.height as f64 - 0.5 - margin,
                            "{shape:?} {preset:?} seed {seed} frame {k}: bounds {b:?}"
                        );
                    }
                }
                if seed == 0 {
                    let pair = scene.render(1);
                    assert_eq!(pair.left.data.len(), 640 * 480);
                    assert_eq!(pair.right.bit_depth, 8);
                }
            }
        }
    }
}

#[test]
fn seeds_vary_motion_and_disparity() {
    let cfgs: Vec<SynthConfig> = (0..20)
        .map(|s| SynthConfig::preset(Preset::Clean, Shape::Blob, s))
        .collect();
    let speeds: Vec<f64> = cfgs
        .iter()
        .map(|c| c.motion.drift_px_per_frame[0].hypot(c.motion.drift_px_per_frame[1]))
        .collect();
    assert!(speeds.iter().all(|&s| (0.5..=3.0).contains(&s)));
    assert!(speeds.iter().cloned().fold(0.0, f64::max) - speeds.iter().cloned().fold(9.0, f64::min) > 1.5);
    let patterns: std::collections::HashSet<String> =
        cfgs.iter().map(|c| format!("{:?}", c.motion.z_pattern)).collect();
    assert!(patterns.len() >= 3, "{patterns:?}");
    for c in &cfgs {
        assert!(c.motion.rotation_rad_per_frame.abs() <= 0.01);
        let step = c.motion.z_step_um * c.disparity.px_per_um;
        assert!((0.1..=2.0).contains(&step), "{step}");
    }
}

#[test]
fn clutter_is_smaller_than_the_object_and_off_it() {
    for seed in 0..10 {
        let cfg = SynthConfig::preset(Preset::Cluttered, Shape::Rod, seed);
        let scene = Scene::new(&cfg).unwrap();
        let t = scene.truth(0);
        assert!(scene.particles().len() >= 20, "{}", scene.particles().len());
        for p in scene.particles() {
            assert!(
                p.area() <= 0.05 * t.left.area_px,
                "particle {} vs object {}",
                p.area(),
                t.left.area_px
            );
            assert!(
                overlap_with_convex(&t.left.polygon.points, &p.points) == 0.0 || !p.contains(t.left.centroid)
            );
            let b = p.bounds();
            assert!(b[0] > -0.5 && b[1] > -0.5 && b[2] < 639.5 && b[3] < 479.5);
        }
        let mask = t.left.mask(cfg.width, cfg.height);
        for p in scene.particles() {
            let pm = p.rasterize(cfg.width, cfg.height);
            assert!(
                !mask.iter().zip(&pm).any(|(a, b)| *a && *b),
                "particle touches the object at frame 0"
            );
        }
    }
}

#[test]
fn occlusion_fraction_and_entry() {
    for shape in Shape::ALL {
        for seed in 0..5 {
            let mut cfg = SynthConfig::preset(Preset::Occluded, shape, seed);
            cfg.frames = 4;
            let scene = Scene::new(&cfg).unwrap();
            let t0 = scene.truth(0);
            assert_eq!(t0.occluded_fraction, 0.0);
            assert!(t0.occluder.is_none());
            for k in 1..cfg.frames {
                let t = scene.truth(k);
                assert!(
                    (t.occluded_fraction - 0.25).abs() <= 0.03,
                    "{shape:?} {seed}: {}",
                    t.occluded_fraction
                );
                assert!(t.occluded_fraction_right > 0.0 && t.occluder.is_some());
            }
            // The rendering agrees: count object pixels that show the occluder.
            cfg.noise = Noise::default();
            cfg.object_texture = 0.0;
            cfg.rim_strength = 0.0;
            cfg.shading = 0.0;
            let occ = cfg.occlusion.clone().unwrap();
            let pair = Scene::new(&cfg).unwrap().render(2);
            let mask = pair.truth.left.mask(cfg.width, cfg.height);
            let obj = (cfg.background_level + cfg.object_contrast) * 255.0;
            let threshold = 0.5 * (obj + occ.brightness * 255.0);
            let above = occ.brightness * 255.0 > obj;
            let (mut inside, mut hidden) = (0usize, 0usize);
            for (i, &m) in mask.iter().enumerate() {
                if m {
                    inside += 1;
                    let v = pair.left.data[i] as f64;
                    hidden += ((v > threshold) == above) as usize;
                }
            }
            let f = hidden as f64 / inside as f64;
            assert!((f - 0.25).abs() < 0.03, "{shape:?} {seed}: rendered fraction {f}");
        }
    }
}

#[test]
fn shot_noise_matches_dose() {
    let mut cfg = uniform(Shape::Sphere, 5);
    cfg.frames = 1;
    cfg.noise = Noise {
        dose: Some(20.0),
        ..Noise::default()
    };
    let noisy = generate(&cfg).unwrap().pairs.remove(0).left;
    cfg.noise.dose = None;
    let clean = generate(&cfg).unwrap().pairs.remove(0).left;
    let max = 65535.0;
    let mut ratio = 0.0;
    for (&n, &c) in noisy.data.iter().zip(&clean.data) {
        let (n, c) = (n as f64 / max, c as f64 / max);
        ratio += (n - c).powi(2) / (c / 20.0);
    }
    ratio /= noisy.data.len() as f64;
    assert!((ratio - 1.0).abs() < 0.05, "variance ratio {ratio}");
    // The Noisy preset is visibly noisy: local std dev of the background.
    let pair = Scene::new(&SynthConfig::preset(Preset::Noisy, Shape::Blob, 1))
        .unwrap()
        .render(0);
    let row: Vec<f64> = pair.left.row(5).iter().map(|&v| v as f64).collect();
    let mean = row.iter().sum::<f64>() / row.len() as f64;
    let std = (row.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / row.len() as f64).sqrt();
    assert!(std > 10.0, "std {std}");
}

#[test]
fn poisson_sampler_mean_and_variance() {
    use rand::SeedableRng;
    let mut rng = noise::FastRng::from_chacha(&mut rand_chacha::ChaCha8Rng::seed_from_u64(3));
    for lambda in [0.01, 0.3, 4.0, 12.03, 31.99, 32.0, 41.0, 300.0] {
        let n = 200_000;
        let xs: Vec<f64> = (0..n).map(|_| noise::poisson(lambda, &mut rng)).collect();
        let mean = xs.iter().sum::<f64>() / n as f64;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64;
        assert!(
            (mean - lambda).abs() < 0.02 * lambda + 0.01,
            "{lambda}: mean {mean}"
        );
        assert!((var - lambda).abs() < 0.03 * lambda + 0.01, "{lambda}: var {var}");
    }
}

#[test]
fn flicker_changes_grey_levels_between_frames() {
    let mut cfg = SynthConfig::preset(Preset::Flicker, Shape::Sphere, 2);
    cfg.frames = 6;
    let means: Vec<f64> = frames(&cfg)
        .unwrap()
        .map(|p| p.left.data.iter().map(|&v| v as f64).sum::<f64>() / p.left.data.len() as f64)
        .collect();
    let spread = means.iter().cloned().fold(0.0, f64::max) - means.iter().cloned().fold(1e9, f64::min);
    assert!(spread > 5.0, "means {means:?}");
}

#[test]
fn sixteen_bit_output() {
    let mut cfg = SynthConfig::preset(Preset::Noisy, Shape::Tip, 4);
    cfg.bit_depth = 16;
    cfg.frames = 1;
    let pair = generate(&cfg).unwrap().pairs.remove(0);
    assert_eq!(pair.left.bit_depth, 16);
    assert!(pair.left.data.iter().any(|&v| v > 255));
    let dir = tempfile::tempdir().unwrap();
    let summary = write_sequence(&cfg, dir.path()).unwrap();
    assert_eq!(summary.files, vec!["0000_left.tif", "0000_right.tif"]);
    let back = crate::imageio::read_file(&dir.path().join("0000_left.tif"), &Default::default()).unwrap();
    assert_eq!(back, pair.left);
}

#[test]
fn write_sequence_files_and_truth() {
    let mut cfg = SynthConfig::preset(Preset::Occluded, Shape::Blob, 9);
    cfg.frames = 3;
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("seq");
    let summary = write_sequence(&cfg, &out).unwrap();
    assert_eq!(summary.frames, 3);
    assert_eq!(summary.files.len(), 6);
    for f in &summary.files {
        assert!(out.join(f).is_file(), "{f}");
    }
    assert!(out.join("0002_right.png").is_file());
    let text = std::fs::read_to_string(out.join("truth.json")).unwrap();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let back: SynthConfig = serde_json::from_value(v["config"].clone()).unwrap();
    assert_eq!(back, cfg);
    let truths: Vec<FrameTruth> = serde_json::from_value(v["frames"].clone()).unwrap();
    assert_eq!(truths.len(), 3);
    // JSON parsing may differ from the written truth in the last ulp.
    let expected = Scene::new(&cfg).unwrap().truth(2);
    assert_eq!(truths[2].frame, 2);
    assert!((truths[2].z_um - expected.z_um).abs() < 1e-9);
    assert!((truths[2].left.centroid[0] - expected.left.centroid[0]).abs() < 1e-9);
    assert_eq!(truths[2].right.polygon.len(), expected.right.polygon.len());
    assert!((truths[2].occluded_fraction - expected.occluded_fraction).abs() < 1e-12);
    let img = crate::imageio::read_file(&out.join("0001_left.png"), &Default::default()).unwrap();
    assert_eq!(img, Scene::new(&back).unwrap().render(1).left);
}

#[test]
fn config_json_uses_snake_case_and_defaults() {
    let cfg: SynthConfig =
        serde_json::from_str(r#"{"shape": "rod", "width": 800, "occlusion": {"fraction": 0.3}}"#).unwrap();
    assert_eq!(cfg.shape, Shape::Rod);
    assert_eq!(cfg.height, 480);
    assert_eq!(cfg.object_size(), 0.3 * 480.0);
    assert_eq!(cfg.occlusion.as_ref().unwrap().enter_frame, 1);
    assert!(serde_json::from_str::<SynthConfig>(r#"{"widht": 800}"#).is_err());
    assert_eq!(
        serde_json::to_string(&Preset::Cluttered).unwrap(),
        "\"cluttered\""
    );
    Scene::new(&cfg).unwrap();
}

#[test]
fn bad_configs_are_rejected_with_the_field() {
    let base = SynthConfig::default;
    let cases: Vec<(SynthConfig, &str)> = vec![
        (SynthConfig { width: 10, ..base() }, "width"),
        (SynthConfig { frames: 0, ..base() }, "frames"),
        (
            SynthConfig {
                bit_depth: 12,
                ..base()
            },
            "bit_depth",
        ),
        (
            SynthConfig {
                object_size_px: Some(1000.0),
                ..base()
            },
            "object_size_px",
        ),
        (
            SynthConfig {
                flicker: f64::NAN,
                ..base()
            },
            "flicker",
        ),
        (
            SynthConfig {
                noise: Noise {
                    dose: Some(-1.0),
                    ..Noise::default()
                },
                ..base()
            },
            "noise.dose",
        ),
        (
            SynthConfig {
                occlusion: Some(Occlusion {
                    enter_frame: 0,
                    ..Occlusion::default()
                }),
                ..base()
            },
            "occlusion.enter_frame",
        ),
        (
            SynthConfig {
                motion: Motion {
                    start_px: Some([2.0, 2.0]),
                    ..Motion::default()
                },
                ..base()
            },
            "motion.start_px",
        ),
    ];
    for (cfg, field) in cases {
        match Scene::new(&cfg) {
            Err(SynthError::InvalidConfig { field: f, message }) => {
                assert_eq!(f, field, "{message}");
                assert!(message.contains("expected"), "{message}");
            }
            other => panic!("{field}: {other:?}"),
        }
    }
    let wide = SynthConfig {
        object_size_px: Some(300.0),
        disparity: Disparity {
            offset_px: 400.0,
            ..Disparity::default()
        },
        ..base()
    };
    let err = Scene::new(&wide).unwrap_err();
    assert!(
        matches!(err, SynthError::DoesNotFit(_)) && err.is_input_error(),
        "{err}"
    );
    assert!(write_sequence(&base(), std::path::Path::new("/proc/definitely/not/here")).is_err());
}

#[test]
fn overlap_of_squares() {
    let a = vec![[0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [0.0, 4.0]];
    let b = vec![[2.0, 1.0], [2.0, 3.0], [6.0, 3.0], [6.0, 1.0]];
    assert!((overlap_with_convex(&a, &b) - 4.0).abs() < 1e-12);
    let b_rev: Vec<_> = b.iter().rev().cloned().collect();
    assert!((overlap_with_convex(&a, &b_rev) - 4.0).abs() < 1e-12);
}

/// Timing report: `cargo test --release --lib synth::tests::timing -- --ignored --nocapture`.
#[test]
#[ignore]
fn timing_per_preset() {
    for preset in Preset::ALL {
        for shape in [Shape::Blob, Shape::Rod] {
            let mut cfg = SynthConfig::preset(preset, shape, 1);
            cfg.frames = 20;
            let start = std::time::Instant::now();
            let scene = Scene::new(&cfg).unwrap();
            let setup = start.elapsed().as_secs_f64() * 1e3;
            let start = std::time::Instant::now();
            for k in 0..cfg.frames {
                std::hint::black_box(scene.render(k));
            }
            let per_pair = start.elapsed().as_secs_f64() * 1e3 / cfg.frames as f64;
            println!(
                "{:>9} {:>5}: setup {setup:6.1} ms, {per_pair:6.2} ms per 640x480 pair ({:.2} ms per image)",
                preset.name(),
                shape.name(),
                per_pair / 2.0
            );
        }
    }
}

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
        for preset in Preset::BASIC {
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
    assert_invalid(cases);
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

/// FNV-1a 64 over the bytes of both images of frames 0 and 2 of every
/// original preset x shape for seeds 0 and 1.
fn basic_presets_digest() -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for preset in Preset::BASIC {
        for shape in Shape::ALL {
            for seed in [0, 1] {
                let mut cfg = SynthConfig::preset(preset, shape, seed);
                cfg.frames = 3;
                let scene = Scene::new(&cfg).unwrap();
                for k in [0, 2] {
                    let pair = scene.render(k);
                    for img in [&pair.left, &pair.right] {
                        for &v in &img.data {
                            h = (h ^ v as u64).wrapping_mul(0x0100_0000_01b3);
                        }
                    }
                    for p in &pair.truth.left.polygon.points {
                        h = (h ^ p[0].to_bits() ^ p[1].to_bits().rotate_left(7))
                            .wrapping_mul(0x0100_0000_01b3);
                    }
                }
            }
        }
    }
    h
}

#[test]
fn basic_presets_unchanged() {
    // Digest of the images and outlines before the hard scene classes were
    // added: the basic presets must render the same bytes.
    assert_eq!(basic_presets_digest(), 0xe20f_9a83_7346_25fd);
    // Their configs serialise without the new fields.
    let json = serde_json::to_string(&SynthConfig::preset(Preset::Cluttered, Shape::Tip, 3)).unwrap();
    for key in ["border_entry", "fibres", "blur_sigma_px", "relief"] {
        assert!(!json.contains(key), "{key} in {json}");
    }
}

/// Means of the left image of `pair` inside the truth mask and outside it
/// (outside: within `reach` px of the object's bounding box, inside the frame).
fn inside_outside_means(pair: &SynthPair, reach: f64) -> (f64, f64) {
    let (w, h) = (pair.left.width, pair.left.height);
    let mask = pair.truth.left.mask(w, h);
    let b = pair.truth.left.visible_polygon.bounds();
    let (mut si, mut ni, mut so, mut no) = (0.0, 0usize, 0.0, 0usize);
    for y in 0..h {
        for x in 0..w {
            let v = pair.left.get(x, y) as f64;
            let (xf, yf) = (x as f64, y as f64);
            if mask[(y * w + x) as usize] {
                si += v;
                ni += 1;
            } else if xf >= b[0] - reach && xf <= b[2] + reach && yf >= b[1] - reach && yf <= b[3] + reach {
                so += v;
                no += 1;
            }
        }
    }
    (si / ni.max(1) as f64, so / no.max(1) as f64)
}

#[test]
fn hard_presets_render_with_the_expected_contrast() {
    for preset in Preset::HARD {
        for shape in Shape::ALL {
            for seed in 0..3 {
                let cfg = SynthConfig::preset(preset, shape, seed);
                let scene = Scene::new(&cfg).unwrap_or_else(|e| panic!("{preset:?} {shape:?} {seed}: {e}"));
                assert_eq!(scene.len(), 10);
                for k in [0, 9] {
                    let pair = scene.render(k);
                    let t = &pair.truth;
                    // The mask is the frame-clipped outline: its pixel count
                    // matches the visible area up to the outline's length.
                    let count = t.left.mask(cfg.width, cfg.height).iter().filter(|&&m| m).count() as f64;
                    let slack = t.left.visible_polygon.length() + 4.0;
                    assert!(
                        (count - t.left.visible_area_px).abs() < slack,
                        "{preset:?} {shape:?} {seed} frame {k}: {count} px vs area {}",
                        t.left.visible_area_px
                    );
                    let (inside, outside) = inside_outside_means(&pair, 0.2 * cfg.object_size());
                    let brighter = preset != Preset::Dark;
                    assert!(
                        (inside > outside + 15.0) == brighter && (inside < outside - 15.0) != brighter,
                        "{preset:?} {shape:?} {seed} frame {k}: inside {inside:.1}, outside {outside:.1}"
                    );
                    let d = t.right.centroid[0] - t.left.centroid[0];
                    assert!((t.disparity_px[0] - d).abs() < 1e-9);
                    let vd = t.right.visible_centroid[0] - t.left.visible_centroid[0];
                    assert!((t.visible_disparity_px[0] - vd).abs() < 1e-9);
                }
            }
        }
    }
}

#[test]
fn hard_presets_are_deterministic() {
    for (i, preset) in Preset::HARD.into_iter().enumerate() {
        let shape = Shape::ALL[i % 4];
        let mut cfg = SynthConfig::preset(preset, shape, 21);
        cfg.frames = 2;
        let a = generate(&cfg).unwrap();
        let b = generate(&cfg).unwrap();
        for (p, q) in a.pairs.iter().zip(&b.pairs) {
            assert_eq!(p.left, q.left, "{preset:?}");
            assert_eq!(p.right, q.right, "{preset:?}");
            assert_eq!(p.truth, q.truth, "{preset:?}");
        }
        assert_eq!(
            SynthConfig::preset(preset, shape, 21),
            SynthConfig::preset(preset, shape, 21)
        );
        cfg.seed = 22;
        assert_ne!(
            generate(&cfg).unwrap().pairs[0].left.data,
            a.pairs[0].left.data,
            "{preset:?}"
        );
        // The config survives JSON and renders the same bytes.
        let back: SynthConfig = serde_json::from_str(&serde_json::to_string(&a.config).unwrap()).unwrap();
        assert_eq!(back, a.config);
        assert_eq!(Scene::new(&back).unwrap().render(1).right, a.pairs[1].right);
    }
}

#[test]
fn border_tool_crosses_its_border_in_every_frame() {
    let mut sides = std::collections::HashSet::new();
    for shape in Shape::ALL {
        for seed in 0..12 {
            let cfg = SynthConfig::preset(Preset::BorderTool, shape, seed);
            let entry = cfg.border_entry.clone().unwrap();
            let side = entry.side.unwrap();
            sides.insert(side);
            assert!(entry.angle_rad.unwrap().abs() <= 0.53);
            assert!((5.0..=20.0).contains(&entry.insertion_px_per_frame.abs()));
            let scene = Scene::new(&cfg).unwrap_or_else(|e| panic!("{shape:?} {seed}: {e}"));
            let n = side.inward_normal();
            let (w, h) = (cfg.width as f64, cfg.height as f64);
            // Depth of a point from the entry border, along the inward normal.
            let depth = |p: &[f64; 2]| match side {
                BorderSide::Left => p[0] + 0.5,
                BorderSide::Top => p[1] + 0.5,
                BorderSide::Right => w - 0.5 - p[0],
                BorderSide::Bottom => h - 0.5 - p[1],
            };
            let extent = if n[0] != 0.0 { w } else { h };
            let margin = BORDER_MARGIN * cfg.object_size() - 1e-6;
            let mut steps = Vec::new();
            let mut previous: Option<[f64; 2]> = None;
            for k in 0..cfg.frames {
                let t = scene.truth(k);
                for obj in [&t.left, &t.right] {
                    assert_eq!(obj.border, vec![side], "{shape:?} {seed} frame {k}");
                    let (lo, hi) = obj
                        .polygon
                        .points
                        .iter()
                        .map(depth)
                        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), d| {
                            (a.min(d), b.max(d))
                        });
                    assert!(
                        lo <= -entry.min_outside_px + 1e-6,
                        "{shape:?} {seed} frame {k}: base at {lo}"
                    );
                    assert!(
                        hi <= extent - margin,
                        "{shape:?} {seed} frame {k}: tip at {hi} of {extent}"
                    );
                    let f = obj.visible_fraction();
                    assert!(
                        (0.4..1.0).contains(&f),
                        "{shape:?} {seed} frame {k}: fraction {f}"
                    );
                    assert!(obj.visible_area_px < obj.area_px);
                    let b = obj.visible_polygon.bounds();
                    assert!(
                        b[0] >= -0.5 - 1e-9
                            && b[1] >= -0.5 - 1e-9
                            && b[2] <= w - 0.5 + 1e-9
                            && b[3] <= h - 0.5 + 1e-9
                    );
                }
                // The tip (the far end of the axis) points into the frame.
                if shape == Shape::Tip {
                    let dir = [t.left.rotation_rad.cos(), t.left.rotation_rad.sin()];
                    assert!(
                        dir[0] * n[0] + dir[1] * n[1] > 0.8,
                        "{seed} frame {k}: axis {dir:?}"
                    );
                }
                let c = t.left.centroid;
                if let Some(p) = previous {
                    steps.push((c[0] - p[0]).hypot(c[1] - p[1]));
                }
                previous = Some(c);
            }
            let max_step = steps.iter().cloned().fold(0.0, f64::max);
            assert!(
                (4.0..=21.0).contains(&max_step),
                "{shape:?} {seed}: steps {steps:?}"
            );
        }
    }
    assert_eq!(sides.len(), 4, "{sides:?}");
}

#[test]
fn scratched_lines_run_under_the_object() {
    for shape in Shape::ALL {
        for seed in 0..4 {
            let cfg = SynthConfig::preset(Preset::Scratched, shape, seed);
            let scene = Scene::new(&cfg).unwrap();
            let lines = scene.lines();
            assert!(
                lines.iter().any(|l| l.curved) || lines.len() < 8,
                "{shape:?} {seed}"
            );
            assert!(lines.iter().any(|l| l.contrast > 0.0) && lines.iter().any(|l| l.contrast < 0.0));
            for l in lines {
                assert!((1.0..=4.0).contains(&l.width_px));
            }
            for k in [0, cfg.frames - 1] {
                let object = &scene.truth(k).left.polygon;
                // A line touches the outline when it has points on both sides.
                let touching = lines
                    .iter()
                    .filter(|l| {
                        let inside = l
                            .points
                            .iter()
                            .step_by(2)
                            .filter(|p| object.contains(**p))
                            .count();
                        inside > 0 && inside < l.points.len().div_ceil(2)
                    })
                    .count();
                assert!(
                    touching >= 2,
                    "{shape:?} {seed} frame {k}: {touching} lines touch the object"
                );
            }
            // Lines are in the substrate: without noise and object, the
            // right image shows them shifted by the background disparity.
            let mut plain = cfg.clone();
            plain.noise = Noise::default();
            plain.clutter.texture_amplitude = 0.0;
            plain.background_gradient = 0.0;
            plain.object_contrast = 0.0;
            plain.rim_strength = 0.0;
            plain.object_texture = 0.0;
            plain.shading = 0.0;
            plain.frames = 1;
            let pair = Scene::new(&plain).unwrap().render(0);
            let bg = (plain.background_level * 255.0).round() as i32;
            let marked = |img: &crate::imageio::GrayFrame| {
                img.data.iter().filter(|&&v| (v as i32 - bg).abs() > 5).count()
            };
            assert!(marked(&pair.left) > 500, "{}", marked(&pair.left));
            let d = pair.truth.background_disparity_px;
            let (w, h) = (plain.width as i64, plain.height as i64);
            let (mut same, mut total) = (0usize, 0usize);
            for y in 0..h {
                for x in 20..w - 20 {
                    let l = pair.left.data[(y * w + x) as usize] as f64;
                    if (l - bg as f64).abs() > 20.0 && !pair.truth.left.polygon.contains([x as f64, y as f64])
                    {
                        // The right image at x + d, interpolated.
                        let xr = x as f64 + d;
                        let (i, f) = (xr.floor() as i64, xr - xr.floor());
                        if i < 0 || i + 1 >= w {
                            continue;
                        }
                        let r0 = pair.right.data[(y * w + i) as usize] as f64;
                        let r1 = pair.right.data[(y * w + i + 1) as usize] as f64;
                        total += 1;
                        same += ((r0 + f * (r1 - r0) - l).abs() <= 15.0) as usize;
                    }
                }
            }
            assert!(total > 100, "{total}");
            assert!(same as f64 > 0.8 * total as f64, "{same} of {total}");
        }
    }
}

#[test]
fn dark_object_has_a_bright_rim() {
    for shape in Shape::ALL {
        for seed in 0..3 {
            let cfg = SynthConfig::preset(Preset::Dark, shape, seed);
            assert!(cfg.object_contrast <= -0.25 && cfg.rim_strength > -cfg.object_contrast);
            let mut plain = cfg.clone();
            plain.noise = Noise::default();
            plain.frames = 1;
            let pair = Scene::new(&plain).unwrap().render(0);
            let (w, h) = (plain.width as i64, plain.height as i64);
            let mask = pair.truth.left.mask(plain.width, plain.height);
            let at = |x: i64, y: i64| x >= 0 && y >= 0 && x < w && y < h && mask[(y * w + x) as usize];
            // Inside pixels next to an outside one: the rim.
            let (mut rim, mut n_rim) = (0.0, 0usize);
            for y in 0..h {
                for x in 0..w {
                    if at(x, y) && !(at(x - 1, y) && at(x + 1, y) && at(x, y - 1) && at(x, y + 1)) {
                        rim += pair.left.data[(y * w + x) as usize] as f64;
                        n_rim += 1;
                    }
                }
            }
            let rim = rim / n_rim as f64;
            let (inside, outside) = inside_outside_means(&pair, 0.2 * plain.object_size());
            assert!(
                inside < outside - 20.0,
                "{shape:?} {seed}: object {inside:.1} vs substrate {outside:.1}"
            );
            assert!(
                rim > outside + 5.0,
                "{shape:?} {seed}: rim {rim:.1} vs substrate {outside:.1}"
            );
        }
    }
}

/// Mean squared difference of horizontally and vertically neighbouring
/// pixels: the image's high-frequency energy.
fn high_frequency_energy(img: &crate::imageio::GrayFrame) -> f64 {
    let (w, h) = (img.width as usize, img.height as usize);
    let mut e = 0.0;
    for y in 0..h - 1 {
        for x in 0..w - 1 {
            let v = img.data[y * w + x] as f64;
            e +=
                (img.data[y * w + x + 1] as f64 - v).powi(2) + (img.data[(y + 1) * w + x] as f64 - v).powi(2);
        }
    }
    e / ((w - 1) * (h - 1)) as f64
}

#[test]
fn blurred_images_are_smoother() {
    for shape in Shape::ALL {
        for seed in 0..3 {
            let cfg = SynthConfig::preset(Preset::Blurred, shape, seed);
            assert!((1.5..=2.5).contains(&cfg.blur_sigma_px));
            let electrons = cfg.noise.dose.unwrap() * (cfg.background_level + cfg.object_contrast);
            assert!((15.0..=30.0).contains(&electrons), "{electrons}");
            // Noise-free, textured: blur removes most of the high frequencies.
            let mut plain = cfg.clone();
            plain.noise = Noise::default();
            plain.frames = 1;
            plain.clutter.texture_amplitude = 0.05;
            plain.object_texture = 0.1;
            let blurred = Scene::new(&plain).unwrap().render(0);
            plain.blur_sigma_px = 0.0;
            let sharp = Scene::new(&plain).unwrap().render(0);
            let ratio = high_frequency_energy(&blurred.left) / high_frequency_energy(&sharp.left);
            assert!(ratio < 0.5, "{shape:?} {seed}: high-frequency ratio {ratio:.3}");
            // The truth does not change with blur.
            assert_eq!(blurred.truth, sharp.truth);
        }
    }
}

#[test]
fn relief_substrate_has_object_like_structure() {
    for shape in [Shape::Blob, Shape::Rod] {
        for seed in 0..3 {
            let cfg = SynthConfig::preset(Preset::Relief, shape, seed);
            let mut plain = cfg.clone();
            plain.noise = Noise::default();
            plain.frames = 1;
            let pair = Scene::new(&plain).unwrap().render(0);
            let mask = pair.truth.left.mask(plain.width, plain.height);
            let mut values: Vec<f64> = pair
                .left
                .data
                .iter()
                .zip(&mask)
                .filter(|(_, &m)| !m)
                .map(|(&v, _)| v as f64 / 255.0)
                .collect();
            values.sort_by(f64::total_cmp);
            let p = |q: f64| values[(q * (values.len() - 1) as f64) as usize];
            let spread = p(0.99) - p(0.01);
            assert!(
                spread > 0.6 * plain.object_contrast,
                "{shape:?} {seed}: substrate spread {spread:.3}"
            );
            // Much rougher than the smooth texture of the basic presets.
            let mut smooth = plain.clone();
            smooth.relief = None;
            let base = Scene::new(&smooth).unwrap().render(0);
            assert!(high_frequency_energy(&pair.left) > 5.0 * high_frequency_energy(&base.left));
        }
    }
}

#[test]
fn truth_of_objects_inside_the_frame() {
    let pair = Scene::new(&SynthConfig::preset(Preset::Clean, Shape::Blob, 4))
        .unwrap()
        .render(0);
    for obj in [&pair.truth.left, &pair.truth.right] {
        assert_eq!(obj.visible_polygon, obj.polygon);
        assert_eq!(obj.visible_centroid, obj.centroid);
        assert!(obj.border.is_empty());
        assert_eq!(obj.visible_fraction(), 1.0);
    }
    assert!((pair.truth.visible_disparity_px[0] - pair.truth.disparity_px[0]).abs() < 1e-9);
    // Clipping: a square half outside the left border.
    let sq = crate::geometry::Polygon::new(vec![[-10.5, 10.0], [9.5, 10.0], [9.5, 30.0], [-10.5, 30.0]]);
    let t = ObjectTruth::in_frame(sq, 0.0, 64, 64);
    assert_eq!(t.border, vec![BorderSide::Left]);
    assert!((t.visible_area_px - 200.0).abs() < 1e-9);
    assert!((t.visible_centroid[0] - 4.5).abs() < 1e-9 && (t.visible_centroid[1] - 20.0).abs() < 1e-9);
    let json = serde_json::to_string(&t).unwrap();
    assert!(json.contains(r#""border":["left"]"#), "{json}");
}

#[test]
fn scene_class_fields_default_and_validate() {
    let cfg: SynthConfig =
        serde_json::from_str(r#"{"shape": "tip", "border_entry": {"side": "top"}, "fibres": {}}"#).unwrap();
    assert_eq!(cfg.border_entry.as_ref().unwrap().side, Some(BorderSide::Top));
    assert_eq!(cfg.border_entry.as_ref().unwrap().min_visible_fraction, 0.45);
    assert_eq!(cfg.fibres.as_ref().unwrap().under_object, 3);
    assert_eq!(cfg.blur_sigma_px, 0.0);
    assert!(cfg.relief.is_none());
    let scene = Scene::new(&cfg).unwrap();
    assert_eq!(scene.truth(0).left.border, vec![BorderSide::Top]);
    assert!(serde_json::from_str::<SynthConfig>(r#"{"border_entry": {"sid": "top"}}"#).is_err());
    let base = SynthConfig::default;
    let cases: Vec<(SynthConfig, &str)> = vec![
        (
            SynthConfig {
                blur_sigma_px: -1.0,
                ..base()
            },
            "blur_sigma_px",
        ),
        (
            SynthConfig {
                border_entry: Some(BorderEntry {
                    angle_rad: Some(2.0),
                    ..BorderEntry::default()
                }),
                ..base()
            },
            "border_entry.angle_rad",
        ),
        (
            SynthConfig {
                border_entry: Some(BorderEntry {
                    min_visible_fraction: 1.0,
                    ..BorderEntry::default()
                }),
                ..base()
            },
            "border_entry.min_visible_fraction",
        ),
        (
            SynthConfig {
                fibres: Some(Fibres {
                    width_px: [5.0, 2.0],
                    ..Fibres::default()
                }),
                ..base()
            },
            "fibres.width_px[1]",
        ),
        (
            SynthConfig {
                relief: Some(Relief {
                    grain_px: f64::NAN,
                    ..Relief::default()
                }),
                ..base()
            },
            "relief.grain_px",
        ),
    ];
    assert_invalid(cases);
    // A tool too large for its border does not fit: an error, no panic.
    let big = SynthConfig {
        object_size_px: Some(380.0),
        border_entry: Some(BorderEntry {
            min_visible_fraction: 0.95,
            min_outside_px: 300.0,
            ..BorderEntry::default()
        }),
        ..base()
    };
    assert!(matches!(Scene::new(&big), Err(SynthError::DoesNotFit(_))));
}

/// Every config of `cases` is refused naming its field (and saying what was
/// expected).
fn assert_invalid(cases: Vec<(SynthConfig, &str)>) {
    for (cfg, field) in cases {
        match Scene::new(&cfg) {
            Err(SynthError::InvalidConfig { field: f, message }) => {
                assert_eq!(f, field, "{message}");
                assert!(message.contains("expected"), "{message}");
            }
            other => panic!("{field}: {other:?}"),
        }
    }
}

/// Issue #17's "confident wrong" rule: errors less the sequence's medians;
/// more than 1 px of disparity or 3 px of centroid flags a pair.
#[test]
fn confident_wrong_pairs_are_those_far_from_the_medians() {
    use super::deviations_from_medians;
    // Offsets 5 px (disparity) and (10, -4) px (centroid) are removed.
    let disparity = [5.0, 5.1, 4.9, 6.2, 5.0];
    let centroid = [
        [10.0, -4.0],
        [10.2, -4.1],
        [10.0, -0.8],
        [10.1, -4.0],
        [9.9, -3.9],
    ];
    let flags: Vec<bool> = deviations_from_medians(&disparity, &centroid)
        .iter()
        .map(|d| d.confident_wrong())
        .collect();
    assert_eq!(flags, [false, false, true, true, false]);
    let d = deviations_from_medians(&disparity, &centroid)[3];
    assert!((d.disparity_px - 1.2).abs() < 1e-12, "{d:?}");
}

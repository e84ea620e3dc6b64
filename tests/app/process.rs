//! `semdepth process DIR` end to end: a synthetic sequence from `semdepth
//! synth` (checked against its truth.json), JSONL and CSV output, a
//! calibration, bad input, and the real quartz images as a fixture folder.

use crate::common;
use crate::discs;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde_json::Value;

fn semdepth(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_semdepth"))
        .args(args)
        .output()
        .expect("run semdepth")
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn assert_success(out: &Output) {
    assert!(
        out.status.success(),
        "exit {:?}: {}",
        out.status.code(),
        stderr(out)
    );
}

/// Asserts exit code 2 and that stderr mentions each of `needles`.
fn assert_input_error(out: &Output, needles: &[&str]) {
    let err = stderr(out);
    assert_eq!(out.status.code(), Some(2), "stderr: {err}");
    for needle in needles {
        assert!(err.contains(needle), "stderr should mention {needle:?}: {err}");
    }
}

fn jsonl(out: &Output) -> Vec<Value> {
    String::from_utf8(out.stdout.clone())
        .expect("utf-8 stdout")
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("not JSON ({e}): {l}")))
        .collect()
}

fn path_str(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// A clean 10-pair blob sequence (seed 1) in `dir/seq`; returns its folder
/// and truth.json.
fn synth_clean(dir: &Path) -> (PathBuf, Value) {
    let seq = dir.join("seq");
    let out = semdepth(&[
        "synth",
        path_str(&seq),
        "--preset",
        "clean",
        "--shape",
        "blob",
        "--seed",
        "1",
        "--frames",
        "10",
    ]);
    assert_success(&out);
    let truth = serde_json::from_slice(&std::fs::read(seq.join("truth.json")).unwrap()).unwrap();
    (seq, truth)
}

/// `semdepth process SEQ --calibration CAL --no-contour`, the calibration
/// JSON `calibration` written into `dir`: its records (the run must succeed).
fn process_calibrated(dir: &Path, seq: &Path, calibration: &str) -> Vec<Value> {
    let path = dir.join("cal.json");
    std::fs::write(&path, calibration).unwrap();
    let out = semdepth(&[
        "process",
        path_str(seq),
        "--calibration",
        path_str(&path),
        "--no-contour",
    ]);
    assert_success(&out);
    jsonl(&out)
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("expected a number, got {v}"))
}

#[test]
fn process_tracks_a_synthetic_sequence_against_its_truth() {
    let dir = tempfile::tempdir().unwrap();
    let (seq, truth) = synth_clean(dir.path());
    let out = semdepth(&["process", path_str(&seq)]);
    assert_success(&out);
    let records = jsonl(&out);
    assert_eq!(records.len(), 10);
    let mut residuals = Vec::new();
    for (k, r) in records.iter().enumerate() {
        assert_eq!(r["frame"], k as u64);
        assert_eq!(r["name"], format!("{k:04}"));
        assert_eq!(r["status"], if k == 0 { "initialised" } else { "tracked" }, "{r}");
        assert!(r["reason"].is_null());
        for side in ["left", "right"] {
            let image = &r[side];
            for key in ["centroid", "angle_rad", "energy", "contrast"] {
                assert!(!image[key].is_null(), "{side}.{key} missing: {r}");
            }
            assert!(
                image["contour"].as_array().is_some_and(|c| c.len() >= 16),
                "{side}.contour"
            );
        }
        for key in [
            "disparity_px",
            "disparity_axis_px",
            "relative_disparity_axis_px",
            "angle_diff_rad",
        ] {
            assert!(!r[key].is_null(), "{key} missing: {r}");
        }
        assert!(r["z_um"].is_null(), "no calibration, no z: {r}");
        assert!(f(&r["timing_ms"]["decode"]) >= 0.0 && f(&r["timing_ms"]["track"]) >= 0.0);
        // Default tilt axis 90 deg: the axis component is the x disparity.
        assert_eq!(r["disparity_axis_px"], r["disparity_px"][0]);
        let truth_d = f(&truth["frames"][k]["disparity_px"][0]);
        residuals.push(f(&r["disparity_axis_px"]) - truth_d);
    }
    let mean = residuals.iter().sum::<f64>() / residuals.len() as f64;
    let centred: Vec<f64> = residuals.iter().map(|r| r - mean).collect();
    let spread =
        centred.iter().cloned().fold(f64::MIN, f64::max) - centred.iter().cloned().fold(f64::MAX, f64::min);
    eprintln!(
        "disparity residuals (tracked - truth): mean {mean:+.4} px, spread {spread:.4} px: {residuals:.3?}"
    );
    assert!(
        spread < 0.2,
        "disparity error spread {spread:.3} px (limit 0.2): {residuals:.3?}"
    );
}

#[test]
fn process_with_a_geometric_calibration_fills_z() {
    let dir = tempfile::tempdir().unwrap();
    let (seq, _) = synth_clean(dir.path());
    let records = process_calibrated(
        dir.path(),
        &seq,
        r#"{"model":"geometric","pixel_size_um":1.0,"vergence_deg":10.0}"#,
    );
    assert_eq!(records.len(), 10);
    let per_px = 1.0 / (2.0 * 5.0f64.to_radians().sin());
    for r in &records {
        let z = f(&r["z_um"]);
        let expected = (f(&r["disparity_axis_px"]) - 0.0) * per_px;
        assert!((z - expected).abs() < 1e-6, "z_um {z} != {expected}: {r}");
        // The standard error goes through the same slope (issue #17).
        let std = f(&r["disparity_std_px"]);
        assert!(std > 0.0 && std < 0.2, "clean blob: disparity_std_px {std}");
        assert!((f(&r["z_std_um"]) - std * per_px).abs() < 1e-6, "{r}");
        for side in ["left", "right"] {
            assert!(
                r[side].get("contour").is_none(),
                "--no-contour keeps {side}.contour"
            );
            assert!(!r[side]["centroid"].is_null());
        }
    }
}

/// Issue #65: a straight line through two samples has no error of its
/// own, yet every tracked pair carries `z_std_um`: the disparity's standard
/// error through the slope (2.5 um/px here), with a warning that says what
/// it leaves out.
#[test]
fn a_two_sample_fit_gives_z_std_from_the_disparity_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let (seq, _) = synth_clean(dir.path());
    let records = process_calibrated(
        dir.path(),
        &seq,
        r#"{"model":"fit","degree":1,"samples":[{"disparity_px":0.0,"z_um":0.0},{"disparity_px":4.0,"z_um":10.0}]}"#,
    );
    for r in records {
        let std = f(&r["disparity_std_px"]);
        assert!((f(&r["z_std_um"]) - 2.5 * std).abs() < 1e-9, "{r}");
        let warned = r["warnings"].as_array().is_some_and(|w| {
            w.iter()
                .any(|w| w.as_str().is_some_and(|w| w.contains("its own error is unknown")))
        });
        assert!(warned, "no warning: {r}");
    }
}

/// `png` rewritten as an FEI TIFF (see [`common::fei_tiff`]).
fn fei_tiff(png: &Path, tiff: &Path, pixel_m: f64, tilt_rad: f64) {
    let image = image::open(png).unwrap().to_luma8();
    std::fs::write(tiff, common::fei_tiff(&image, pixel_m, tilt_rad)).unwrap();
}

/// Issue #20: a stage-tilt pair whose TIFFs carry the microscope's pixel
/// size and stage tilts gives z with a calibration that takes both from the
/// images, equal to the typed geometric calibration's to 1e-9 um; each
/// record echoes the metadata; a pair whose two images disagree on the
/// pixel size gets no z and says why; a typed calibration whose pixel size
/// the images contradict is warned about once per change.
#[test]
fn process_takes_pixel_size_and_stage_tilt_from_the_images() {
    let dir = tempfile::tempdir().unwrap();
    let (seq, _) = synth_clean(dir.path());
    let tiffs = dir.path().join("tiffs");
    std::fs::create_dir(&tiffs).unwrap();
    let (pixel_m, tilt_l, vergence_deg) = (9.76562e-8, 0.558473, 7.0_f64);
    let tilt_r = tilt_l + vergence_deg.to_radians();
    for k in 0..10 {
        let name = |side: &str, ext: &str| format!("{k:04}_{side}.{ext}");
        // Pair 7's right image was taken at another magnification.
        let right_pixel = if k == 7 { 1.05 * pixel_m } else { pixel_m };
        fei_tiff(
            &seq.join(name("left", "png")),
            &tiffs.join(name("left", "tif")),
            pixel_m,
            tilt_l,
        );
        fei_tiff(
            &seq.join(name("right", "png")),
            &tiffs.join(name("right", "tif")),
            right_pixel,
            tilt_r,
        );
    }
    let run = |calibration: &str| process_calibrated(dir.path(), &tiffs, calibration);
    let from_images =
        run(r#"{"model": "geometric", "pixel_size": "from_images", "vergence": "from_stage_tilt"}"#);
    let typed = run(&format!(
        r#"{{"model": "geometric", "pixel_size_um": {}, "vergence_deg": {}}}"#,
        pixel_m * 1e6,
        (tilt_r - tilt_l).to_degrees()
    ));
    assert_eq!(from_images.len(), 10);
    for (k, (a, b)) in from_images.iter().zip(&typed).enumerate() {
        assert_eq!(a["status"], b["status"]);
        let meta = &a["metadata"];
        assert!(
            (f(&meta["left"]["pixel_width_m"]) - pixel_m).abs() < 1e-9 * pixel_m,
            "{meta}"
        );
        assert!(
            (f(&meta["left"]["stage_tilt_rad"]) - tilt_l).abs() < 1e-12,
            "{meta}"
        );
        assert!(
            (f(&meta["stage_tilt_difference_rad"]) - (tilt_r - tilt_l)).abs() < 1e-12,
            "{meta}"
        );
        if k == 7 {
            assert!(a["z_um"].is_null(), "pair 7: {a}");
            let warnings = a["warnings"].to_string();
            assert!(
                warnings.contains("no z") && warnings.contains("magnification"),
                "{warnings}"
            );
            continue;
        }
        let (za, zb) = (f(&a["z_um"]), f(&b["z_um"]));
        assert!(
            (za - zb).abs() <= 1e-9,
            "pair {k}: z {za} from the images, {zb} typed"
        );
        assert!(a.get("warnings").is_none(), "pair {k}: {a}");
    }
    // A typed pixel size the images contradict: warned on the first pair
    // and where the magnification changes (pair 7's right image differs
    // from its left: that pair's own pixel size is the left's, unchanged).
    let off = run(r#"{"model": "geometric", "pixel_size_um": 0.2, "vergence_deg": 7}"#);
    let warned: Vec<usize> = (0..10).filter(|&k| off[k].get("warnings").is_some()).collect();
    assert_eq!(warned, [0], "{off:?}");
    assert!(
        off[0]["warnings"].to_string().contains("magnification changed"),
        "{}",
        off[0]
    );
    assert!(
        !off[0]["z_um"].is_null(),
        "the calibration's z still comes: {}",
        off[0]
    );
}

/// Splits one CSV line into cells (quoted cells may hold commas and `""`).
fn csv_cells(line: &str) -> Vec<String> {
    let (mut cells, mut cell, mut quoted, mut chars) =
        (Vec::new(), String::new(), false, line.chars().peekable());
    while let Some(c) = chars.next() {
        match (c, quoted) {
            ('"', true) if chars.peek() == Some(&'"') => {
                cell.push('"');
                chars.next();
            }
            ('"', _) => quoted = !quoted,
            (',', false) => cells.push(std::mem::take(&mut cell)),
            (c, _) => cell.push(c),
        }
    }
    assert!(!quoted, "unterminated quote: {line}");
    cells.push(cell);
    cells
}

#[test]
fn process_csv_has_the_documented_columns() {
    let dir = tempfile::tempdir().unwrap();
    let (seq, _) = synth_clean(dir.path());
    let out = semdepth(&["process", path_str(&seq), "--format", "csv"]);
    assert_success(&out);
    let text = String::from_utf8(out.stdout.clone()).unwrap();
    let mut lines = text.lines();
    let header = csv_cells(lines.next().expect("header"));
    let expected = "frame,name,status,reason,left_x,left_y,left_angle_rad,left_contrast,right_x,right_y,\
right_angle_rad,right_contrast,disparity_x_px,disparity_y_px,disparity_axis_px,relative_disparity_axis_px,\
angle_diff_rad,z_um,disparity_std_px,z_std_um,left_pixel_width_m,left_pixel_height_m,left_stage_tilt_rad,left_beam,\
right_pixel_width_m,right_pixel_height_m,right_stage_tilt_rad,right_beam,stage_tilt_difference_rad,warnings";
    assert_eq!(header.join(","), expected);
    let rows: Vec<Vec<String>> = lines.map(csv_cells).collect();
    assert_eq!(rows.len(), 10);
    // The same numbers as the JSON output.
    let json = jsonl(&semdepth(&["process", path_str(&seq), "--no-contour"]));
    for (k, row) in rows.iter().enumerate() {
        assert_eq!(row.len(), header.len(), "row {k}: {row:?}");
        let cell = |name: &str| &row[header.iter().position(|h| h == name).unwrap()];
        assert_eq!(cell("frame"), &k.to_string());
        assert_eq!(cell("name"), &format!("{k:04}"));
        assert_eq!(cell("status"), json[k]["status"].as_str().unwrap());
        assert_eq!(cell("reason"), "");
        assert_eq!(cell("z_um"), "", "no calibration: empty z_um");
        let num = |name: &str| {
            cell(name)
                .parse::<f64>()
                .unwrap_or_else(|e| panic!("row {k} {name}: {e}"))
        };
        assert_eq!(num("left_x"), f(&json[k]["left"]["centroid"][0]));
        assert_eq!(num("right_y"), f(&json[k]["right"]["centroid"][1]));
        assert_eq!(num("disparity_x_px"), f(&json[k]["disparity_px"][0]));
        assert_eq!(num("disparity_axis_px"), f(&json[k]["disparity_axis_px"]));
        assert_eq!(num("angle_diff_rad"), f(&json[k]["angle_diff_rad"]));
    }
}

/// The real FIB tilt pair (OpenFIBSEM files) in CSV: z from the files'
/// pixel size and stage tilts, both views' beam named.
#[test]
fn process_csv_of_the_fib_tilt_pair_names_the_beam_and_fills_z() {
    let dir = tempfile::tempdir().unwrap();
    let cal = dir.path().join("tilt.json");
    std::fs::write(
        &cal,
        r#"{"model": "geometric", "pixel_size": "from_images", "vergence": "from_stage_tilt", "tilt_axis_deg": 0}"#,
    )
    .unwrap();
    let folder = crate::common::shared_dir().join("data/real/fibsem_tilt");
    let out = semdepth(&[
        "process",
        path_str(&folder),
        "--pairs",
        "undercut_stage30deg_ib.tif:undercut_stage25deg_ib.tif",
        "--calibration",
        path_str(&cal),
        "--roi",
        "640",
        "635",
        "260",
        "105",
        "--format",
        "csv",
    ]);
    assert_success(&out);
    let text = String::from_utf8(out.stdout.clone()).unwrap();
    let mut lines = text.lines();
    let header = csv_cells(lines.next().expect("header"));
    let row = csv_cells(lines.next().expect("one row"));
    let cell = |name: &str| row[header.iter().position(|h| h == name).unwrap()].clone();
    assert_eq!(
        (cell("left_beam"), cell("right_beam")),
        ("ion".to_string(), "ion".to_string())
    );
    assert_eq!(cell("status"), "initialised");
    let (d_y, z): (f64, f64) = (
        cell("disparity_y_px").parse().unwrap(),
        cell("z_um").parse().unwrap(),
    );
    // Across a tilt axis along x: the axis component is -d_y; 97.66 nm
    // pixels, tilts 30 and 25 degrees (the folder's README).
    let dt = 0.43632024519054546 - 0.5235865576931467_f64;
    let expected = -d_y * 0.09765625 / (2.0 * (dt / 2.0).sin());
    assert!(
        (z - expected).abs() <= 1e-6 * expected.abs(),
        "z {z} against {expected}"
    );
}

#[test]
fn process_rejects_bad_folders_and_images() {
    let dir = tempfile::tempdir().unwrap();
    let (seq, _) = synth_clean(dir.path());

    // A folder that does not exist.
    let missing = dir.path().join("no_such_dir");
    assert_input_error(&semdepth(&["process", path_str(&missing)]), &["no_such_dir"]);

    // An empty folder (and one with only unrelated files).
    let empty = dir.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    assert_input_error(&semdepth(&["process", path_str(&empty)]), &["no stereo pairs"]);
    std::fs::write(empty.join("notes_left.txt"), "not an image").unwrap();
    assert_input_error(&semdepth(&["process", path_str(&empty)]), &["no stereo pairs"]);

    // A left image without its right image.
    let unpaired = dir.path().join("unpaired");
    std::fs::create_dir(&unpaired).unwrap();
    for name in ["0000_left.png", "0000_right.png", "0001_left.png"] {
        std::fs::copy(seq.join(name), unpaired.join(name)).unwrap();
    }
    assert_input_error(
        &semdepth(&["process", path_str(&unpaired)]),
        &["0001_left.png", "no right image"],
    );

    // A corrupt image after a good pair: the good record is printed first.
    let corrupt = dir.path().join("corrupt");
    std::fs::create_dir(&corrupt).unwrap();
    for name in ["0000_left.png", "0000_right.png", "0001_left.png"] {
        std::fs::copy(seq.join(name), corrupt.join(name)).unwrap();
    }
    let bytes = std::fs::read(seq.join("0001_right.png")).unwrap();
    std::fs::write(corrupt.join("0001_right.png"), &bytes[..bytes.len() / 3]).unwrap();
    let out = semdepth(&["process", path_str(&corrupt)]);
    assert_input_error(&out, &["0001_right.png", "corrupt_image"]);
    let printed = jsonl(&out);
    assert_eq!(printed.len(), 1, "the pair before the corrupt one is printed");
    assert_eq!(printed[0]["name"], "0000");

    // Pairs of different sizes within a sequence.
    let sizes = dir.path().join("sizes");
    let out = semdepth(&[
        "synth",
        path_str(&sizes),
        "--frames",
        "1",
        "--width",
        "320",
        "--height",
        "240",
    ]);
    assert_success(&out);
    for name in ["0000_left.png", "0000_right.png"] {
        std::fs::copy(seq.join(name), sizes.join(name.replace("0000", "0001"))).unwrap();
    }
    let out = semdepth(&["process", path_str(&sizes)]);
    assert_input_error(&out, &["0001", "pair_size_changed"]);
    assert_eq!(jsonl(&out).len(), 1);
}

#[test]
fn process_rejects_bad_parameters() {
    let dir = tempfile::tempdir().unwrap();
    let (seq, _) = synth_clean(dir.path());
    let params = dir.path().join("params.json");

    // Unknown field.
    std::fs::write(&params, r#"{"max_disparity_px": 40, "speed": "fast"}"#).unwrap();
    let out = semdepth(&["process", path_str(&seq), "--params", path_str(&params)]);
    assert_input_error(&out, &["params.json", "unknown field", "speed"]);
    assert!(out.stdout.is_empty());

    // Not JSON at all.
    std::fs::write(&params, "max_disparity_px = 40").unwrap();
    assert_input_error(
        &semdepth(&["process", path_str(&seq), "--params", path_str(&params)]),
        &["params.json"],
    );

    // Out of range, from the file and from a flag.
    std::fs::write(&params, r#"{"rigid": {"search_radius_px": 0.0}}"#).unwrap();
    assert_input_error(
        &semdepth(&["process", path_str(&seq), "--params", path_str(&params)]),
        &["search_radius_px"],
    );
    assert_input_error(
        &semdepth(&["process", path_str(&seq), "--max-disparity=-5"]),
        &["max_disparity_px"],
    );

    // A valid file with a flag on top is accepted.
    std::fs::write(
        &params,
        r#"{"max_disparity_px": 40, "rigid": {"search_radius_px": 30}}"#,
    )
    .unwrap();
    let out = semdepth(&[
        "process",
        path_str(&seq),
        "--params",
        path_str(&params),
        "--search-radius",
        "20",
        "--no-contour",
    ]);
    assert_success(&out);
    assert_eq!(jsonl(&out).len(), 10);

    // A calibration file that is not one.
    let cal = dir.path().join("cal.json");
    std::fs::write(
        &cal,
        r#"{"model":"geometric","pixel_size_um":-1,"vergence_deg":10}"#,
    )
    .unwrap();
    assert_input_error(
        &semdepth(&["process", path_str(&seq), "--calibration", path_str(&cal)]),
        &["cal.json"],
    );
}

/// The real quartz images as a fixture folder: consecutive tilt steps as a
/// sequence, pair 0000 = (01, 02), pair 0001 = (02, 03). Each pair's
/// disparity is about 27 px; between the pairs the left view moves by about
/// 27 px (tracked rigidly) while the outline changes with the tilt.
#[test]
fn process_runs_on_the_real_quartz_images() {
    let dir = tempfile::tempdir().unwrap();
    let fixture = dir.path().join("quartz");
    std::fs::create_dir(&fixture).unwrap();
    for (name, index) in [
        ("0000_left.png", 1),
        ("0000_right.png", 2),
        ("0001_left.png", 2),
        ("0001_right.png", 3),
    ] {
        std::fs::copy(common::quartz_path(index), fixture.join(name)).unwrap();
    }
    let out = semdepth(&["process", path_str(&fixture), "--no-contour", "--progress"]);
    eprintln!("stderr: {}", stderr(&out));
    assert_success(&out);
    let records = jsonl(&out);
    for r in &records {
        eprintln!(
            "{}: status {} reason {} disparity {} axis {} left {} right {}",
            r["name"],
            r["status"],
            r["reason"],
            r["disparity_px"],
            r["disparity_axis_px"],
            r["left"]["centroid"],
            r["right"]["centroid"]
        );
    }
    assert_eq!(records.len(), 2);
    assert!(
        stderr(&out).contains("processed 2 pairs"),
        "summary line: {}",
        stderr(&out)
    );
    for (r, expected) in records.iter().zip([27.0, 27.0]) {
        assert_ne!(r["status"], "lost", "{}: {}", r["name"], r["reason"]);
        let d = f(&r["disparity_axis_px"]);
        assert!(
            (d - expected).abs() < 3.0,
            "{}: disparity_axis_px {d:.2}, expected about {expected} (within 3 px)",
            r["name"]
        );
    }
}

/// Three pairs of the two-disc scene (both discs moving by 1.5 px in x and
/// -1 px in y per pair) in `dir/discs`; returns the folder and each pair's
/// motion.
fn two_disc_folder(dir: &Path) -> (PathBuf, Vec<[f64; 2]>) {
    let folder = dir.join("discs");
    std::fs::create_dir(&folder).unwrap();
    let motions: Vec<[f64; 2]> = (0..3).map(|k| [1.5 * k as f64, -(k as f64)]).collect();
    for (k, &motion) in motions.iter().enumerate() {
        let (left, right) = discs::scene_pair(motion);
        left.to_gray8()
            .save(folder.join(format!("{k:04}_left.png")))
            .unwrap();
        right
            .to_gray8()
            .save(folder.join(format!("{k:04}_right.png")))
            .unwrap();
    }
    (folder, motions)
}

/// Asserts that `process` succeeded and tracked `disc` through every pair:
/// the first initialised, the others tracked, the left centroid on the disc
/// and the disparity the scene's.
fn assert_tracks_disc(out: &Output, disc: [f64; 3], motions: &[[f64; 2]], what: &str) {
    assert_success(out);
    let records = jsonl(out);
    assert_eq!(records.len(), motions.len(), "{what}");
    for (k, (r, m)) in records.iter().zip(motions).enumerate() {
        assert_eq!(
            r["status"],
            if k == 0 { "initialised" } else { "tracked" },
            "{what}: {r}"
        );
        let d = discs::distance(&r["left"]["centroid"], disc[0] + m[0], disc[1] + m[1]);
        assert!(
            d < 1.0,
            "{what}: pair {k} left centroid {} is {d:.2} px off the disc",
            r["left"]["centroid"]
        );
        let disparity = f(&r["disparity_axis_px"]);
        assert!(
            (disparity - discs::DISPARITY_PX).abs() < 0.3,
            "{what}: pair {k} disparity {disparity:.3} px, expected {}",
            discs::DISPARITY_PX
        );
    }
}

#[test]
fn process_hints_name_the_object() {
    let dir = tempfile::tempdir().unwrap();
    let (folder, motions) = two_disc_folder(dir.path());
    let folder = path_str(&folder);
    let args = |r: [i64; 4]| r.map(|v| v.to_string());

    // A box around either disc tracks that disc.
    for (roi, disc, what) in [
        (discs::ROI_A, discs::DISC_A, "--roi around A"),
        (discs::ROI_B, discs::DISC_B, "--roi around B"),
    ] {
        let r = args(roi);
        let out = semdepth(&[
            "process",
            folder,
            "--no-contour",
            "--roi",
            &r[0],
            &r[1],
            &r[2],
            &r[3],
        ]);
        assert_tracks_disc(&out, disc, &motions, what);
    }
    // A box running past the image's top and right borders, with a point
    // and the polarity.
    let out = semdepth(&[
        "process",
        folder,
        "--no-contour",
        "--roi",
        "190",
        "-30",
        "200",
        "230",
        "--point",
        "235",
        "110",
        "--polarity",
        "brighter",
    ]);
    assert_tracks_disc(&out, discs::DISC_B, &motions, "--roi past the border around B");

    // The params file's init.roi still works, and the flags override it.
    let params = dir.path().join("params.json");
    std::fs::write(
        &params,
        serde_json::json!({"init": {"roi": discs::ROI_A}}).to_string(),
    )
    .unwrap();
    let out = semdepth(&["process", folder, "--no-contour", "--params", path_str(&params)]);
    assert_tracks_disc(&out, discs::DISC_A, &motions, "init.roi around A in --params");
    let r = args(discs::ROI_B);
    let out = semdepth(&[
        "process",
        folder,
        "--no-contour",
        "--params",
        path_str(&params),
        "--roi",
        &r[0],
        &r[1],
        &r[2],
        &r[3],
    ]);
    assert_tracks_disc(&out, discs::DISC_B, &motions, "--roi around B over the file's A");
}

/// Issue #65: two objects whose hints resolve to one disc are refused,
/// naming both (exit 2), before any record is written; so is an object
/// whose polarity no region has.
#[test]
fn process_refuses_two_objects_on_one_region_and_hints_that_name_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let (folder, _) = two_disc_folder(dir.path());
    let folder = path_str(&folder);
    let [ax, ay, _] = discs::DISC_A;
    let [x, y, w, h] = discs::ROI_A;
    let boxed = format!("boxed:roi={x},{y},{w},{h}");
    let pointed = format!("pointed:point={ax},{ay}");
    let out = semdepth(&["process", folder, "--object", &boxed, "--object", &pointed]);
    assert_input_error(&out, &["objects_share_a_region", "\"boxed\"", "--object pointed"]);
    assert!(out.stdout.is_empty(), "no record before the refusal");
    let out = semdepth(&[
        "process",
        folder,
        "--object",
        &boxed,
        "--object",
        "dark:polarity=darker",
    ]);
    assert_input_error(
        &out,
        &["hint_matches_nothing", "polarity darker", "--object dark"],
    );
}

#[test]
fn process_refuses_bad_hints_naming_them() {
    let dir = tempfile::tempdir().unwrap();
    let (folder, _) = two_disc_folder(dir.path());
    let folder = path_str(&folder);
    let params = dir.path().join("params.json");
    let with_params = |json: serde_json::Value| {
        std::fs::write(&params, json.to_string()).unwrap();
        semdepth(&["process", folder, "--params", path_str(&params)])
    };

    // Out of the image: found at the first pair, before any record.
    let out = semdepth(&["process", folder, "--roi", "400", "10", "50", "50"]);
    assert_input_error(
        &out,
        &[
            "error[invalid_hint]",
            "--roi",
            "outside the 320x240 image",
            "0000",
        ],
    );
    assert!(out.stdout.is_empty(), "nothing printed before the error");
    let out = semdepth(&["process", folder, "--point", "10", "250", "--format", "csv"]);
    assert_input_error(
        &out,
        &["error[invalid_hint]", "--point", "outside the 320x240 image"],
    );
    assert!(out.stdout.is_empty(), "no CSV header before the error");
    let out = with_params(serde_json::json!({"init": {"roi": [-500, 0, 100, 100]}}));
    assert_input_error(
        &out,
        &["error[invalid_hint]", "init.roi in", "params.json", "outside"],
    );
    // Out of range whatever the images.
    let out = semdepth(&["process", folder, "--roi", "200", "75", "8", "70"]);
    assert_input_error(&out, &["error[invalid_hint]", "--roi", "8x70", ">= 16"]);
    let out = with_params(serde_json::json!({"init": {"roi": [200, 75, 70, 10]}}));
    assert_input_error(&out, &["error[invalid_hint]", "init.roi in", "70x10"]);
    // Unknown polarity, from the flag and from the file.
    let out = semdepth(&["process", folder, "--polarity", "up"]);
    assert_input_error(&out, &["--polarity", "'up'", "brighter", "darker", "any"]);
    let out = with_params(serde_json::json!({"init": {"polarity": "up"}}));
    assert_input_error(&out, &["invalid_params", "init.polarity", "`up`", "brighter"]);
    // A point that is not two numbers.
    let out = semdepth(&["process", folder, "--point", "10", "x"]);
    assert_input_error(&out, &["--point", "'x'"]);
    let out = with_params(serde_json::json!({"init": {"point": [10]}}));
    assert_input_error(&out, &["invalid_params", "init.point"]);
}

/// Three pairs of the two-disc scene in which disc A stands higher than
/// disc B: A's disparity is 6 px, B's 2.5 px; both move by 1.5 px in x per
/// pair. Returns the folder.
fn two_height_folder(dir: &Path) -> PathBuf {
    let folder = dir.join("heights");
    std::fs::create_dir(&folder).unwrap();
    for k in 0..3 {
        let m = 1.5 * k as f64;
        let at = |d: [f64; 3], shift: f64| [d[0] + m + shift, d[1], d[2]];
        let (w, h) = (discs::WIDTH, discs::HEIGHT);
        let left = discs::discs_frame(w, h, &[at(discs::DISC_A, 0.0), at(discs::DISC_B, 0.0)]);
        let right = discs::discs_frame(w, h, &[at(discs::DISC_A, 6.0), at(discs::DISC_B, 2.5)]);
        for (side, frame) in [("left", left), ("right", right)] {
            frame
                .to_gray8()
                .save(folder.join(format!("{k:04}_{side}.png")))
                .unwrap();
        }
    }
    folder
}

#[test]
fn process_measures_named_objects_and_their_relative_height() {
    let dir = tempfile::tempdir().unwrap();
    let folder = two_height_folder(dir.path());
    let cal = dir.path().join("cal.json");
    std::fs::write(
        &cal,
        r#"{"model": "geometric", "pixel_size_um": 0.5, "vergence_deg": 6.0}"#,
    )
    .unwrap();
    let um_per_px = 0.5 / (2.0 * 3f64.to_radians().sin());
    let args = [
        "process",
        path_str(&folder),
        "--calibration",
        path_str(&cal),
        "--object",
        "high:roi=40,80,100,100",
        "--object",
        "low:point=235,110:polarity=brighter",
    ];
    let out = semdepth(&args);
    assert_success(&out);
    let records = jsonl(&out);
    assert_eq!(records.len(), 3);
    for (k, r) in records.iter().enumerate() {
        let objects = r["objects"].as_array().unwrap();
        let names: Vec<&str> = objects.iter().map(|o| o["name"].as_str().unwrap()).collect();
        assert_eq!(names, ["high", "low"], "{r}");
        let m = 1.5 * k as f64;
        for (o, disc, disparity) in [
            (&objects[0], discs::DISC_A, 6.0),
            (&objects[1], discs::DISC_B, 2.5),
        ] {
            assert_eq!(o["status"], if k == 0 { "initialised" } else { "tracked" }, "{o}");
            let d = discs::distance(&o["left"]["centroid"], disc[0] + m, disc[1]);
            assert!(d < 1.0, "pair {k} {}: centroid {d:.2} px off", o["name"]);
            assert!((f(&o["disparity_axis_px"]) - disparity).abs() < 0.3, "{o}");
        }
        let relative = r["relative"].as_array().unwrap();
        assert_eq!(relative.len(), 2, "{r}");
        assert_eq!(
            (relative[0]["from"].as_str(), relative[0]["to"].as_str()),
            (Some("high"), Some("low"))
        );
        let rel = f(&relative[0]["disparity_axis_px"]);
        assert!((rel - 3.5).abs() < 0.3, "pair {k}: relative disparity {rel}");
        assert!((f(&relative[0]["dz_um"]) - rel * um_per_px).abs() < 1e-6);
        assert!(f(&relative[0]["dz_std_um"]) > 0.0);
        assert_eq!(f(&relative[1]["disparity_axis_px"]), -rel);
        // The first object's fields stay at the top level.
        assert_eq!(r["status"], objects[0]["status"]);
        assert_eq!(r["disparity_axis_px"], objects[0]["disparity_axis_px"]);
    }

    // CSV: one row per pair and object, then the relative rows.
    let mut csv_args = args.to_vec();
    csv_args.extend(["--format", "csv"]);
    let out = semdepth(&csv_args);
    assert_success(&out);
    let text = String::from_utf8(out.stdout).unwrap();
    let lines: Vec<Vec<String>> = text.lines().map(csv_cells).collect();
    let header = &lines[0];
    assert_eq!(&header[..5], ["frame", "name", "object", "relative_to", "status"]);
    assert_eq!(lines.len(), 1 + 3 * 4, "{text}");
    let col = |name: &str| header.iter().position(|h| h == name).unwrap();
    for row in &lines[1..] {
        assert_eq!(row.len(), header.len(), "{row:?}");
    }
    let rel_row = &lines[3];
    assert_eq!(
        (
            rel_row[col("object")].as_str(),
            rel_row[col("relative_to")].as_str()
        ),
        ("high", "low")
    );
    let rel: f64 = rel_row[col("disparity_axis_px")].parse().unwrap();
    assert!((rel - 3.5).abs() < 0.3, "{rel_row:?}");
    assert_eq!(lines[1][col("object")], "high");
    assert_eq!(lines[1][col("relative_to")], "");

    // Bad object specifications name what is wrong.
    for (spec, needles) in [
        ("bad name:roi=1,2,30,40", vec!["invalid object name"]),
        ("a:roi=1,2,30", vec!["roi", "4 comma-separated numbers"]),
        ("a:size=3", vec!["unknown key \"size\""]),
        ("a:polarity=sideways", vec!["polarity", "brighter, darker or any"]),
        ("a:roi=1,2,3,4", vec!["roi of --object a"]),
        ("a:roi=5000,5000,40,40", vec!["roi of --object a"]),
    ] {
        let out = semdepth(&["process", path_str(&folder), "--object", spec]);
        let mut needles = needles;
        needles.push("--object");
        assert_input_error(&out, &needles);
    }
    let out = semdepth(&["process", path_str(&folder), "--object", "a", "--object", "a"]);
    assert_input_error(&out, &["duplicate_object", "\"a\""]);
    let out = semdepth(&[
        "process",
        path_str(&folder),
        "--object",
        "a",
        "--roi",
        "1,2,30,40",
    ]);
    assert_input_error(&out, &["conflicting_hints"]);
}

/// A tilt axis given by flag or params file that is not the calibration's
/// is refused (exit 2, naming both values); the same axis written another
/// way, or none, runs.
#[test]
fn process_refuses_a_tilt_axis_that_is_not_the_calibrations() {
    let dir = tempfile::tempdir().unwrap();
    let (seq, _) = synth_clean(dir.path());
    let cal = dir.path().join("cal.json");
    std::fs::write(
        &cal,
        r#"{"model": "geometric", "pixel_size_um": 0.5, "vergence_deg": 6.0, "tilt_axis_deg": 90.0}"#,
    )
    .unwrap();
    let params = dir.path().join("params.json");
    std::fs::write(&params, r#"{"tilt_axis_deg": 0.0}"#).unwrap();
    let run = |extra: &[&str]| {
        let mut args = vec![
            "process",
            path_str(&seq),
            "--calibration",
            path_str(&cal),
            "--no-contour",
        ];
        args.extend_from_slice(extra);
        semdepth(&args)
    };
    assert_input_error(
        &run(&["--tilt-axis-deg", "45"]),
        &["tilt_axis_conflict", "tilt_axis_deg 45", "axis 90 deg"],
    );
    assert_input_error(
        &run(&["--params", path_str(&params)]),
        &["tilt_axis_conflict", "tilt_axis_deg 0", "axis 90 deg"],
    );
    assert_success(&run(&["--tilt-axis-deg", "-270"]));
    assert_success(&run(&[]));
}

/// Issue #65: the shipped quartz tilt series runs as shipped. Without
/// `--series` the folder has no NAME_left/NAME_right pairs and the message
/// says what to add; with it, (01, 02) then (01, 03) are tracked as one
/// sequence, each shift along the tilt axis within 1.5 px of the Otsu masks'
/// centroid shift (26.97 and 54.07 px; see the real-image accuracy tests).
#[test]
fn process_takes_the_quartz_tilt_series() {
    let quartz = concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data/real/quartz");
    assert_input_error(&semdepth(&["process", quartz]), &["no_pairs", "--series"]);
    let out = semdepth(&["process", quartz, "--series", "--no-contour"]);
    assert_success(&out);
    let records = jsonl(&out);
    let names: Vec<&str> = records.iter().map(|r| r["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["Quarz_01-Quarz_02", "Quarz_01-Quarz_03"]);
    for (record, (status, reference)) in records.iter().zip([("initialised", 26.97), ("tracked", 54.07)]) {
        assert_eq!(record["status"], status, "{record}");
        let d = record["disparity_axis_px"].as_f64().unwrap();
        assert!(
            (d - reference).abs() < 1.5,
            "{}: {d:.2} px against {reference}",
            record["name"]
        );
    }
    let lonely = tempfile::tempdir().unwrap();
    std::fs::copy(format!("{quartz}/Quarz_01.png"), lonely.path().join("a.png")).unwrap();
    assert_input_error(
        &semdepth(&["process", path_str(lonely.path()), "--series"]),
        &["no_pairs", "at least two"],
    );

    // The same pairs listed explicitly, in another order: the records follow
    // the list, and the pair listed alone measures as it does first.
    let listed = |list: &str| semdepth(&["process", quartz, "--pairs", list, "--no-contour"]);
    let out = listed("Quarz_01.png:Quarz_03.png, Quarz_01.png:Quarz_02.png");
    assert_success(&out);
    let names: Vec<String> = jsonl(&out)
        .iter()
        .map(|r| r["name"].as_str().unwrap().to_string())
        .collect();
    assert_eq!(names, ["Quarz_01-Quarz_03", "Quarz_01-Quarz_02"]);
    let alone = jsonl(&listed("Quarz_01.png:Quarz_02.png"));
    assert_eq!(alone[0]["disparity_axis_px"], records[0]["disparity_axis_px"]);
    // Entries that name no pair: exit 2 naming the entry.
    assert_input_error(
        &listed("Quarz_01.png"),
        &["invalid_pairs", "\"Quarz_01.png\"", "LEFT:RIGHT"],
    );
    assert_input_error(&listed("Quarz_01.png:nope.png"), &["invalid_pairs", "nope.png"]);
    assert_input_error(&listed(" , "), &["invalid_pairs", "no pair"]);
}

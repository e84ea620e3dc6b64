//! The `semdepth` binary end to end: `synth` writes a sequence with truth,
//! `init` finds the object in it; bad input gives a message and exit code.

mod common;

use std::process::{Command, Output};

fn semdepth(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_semdepth"))
        .args(args)
        .output()
        .expect("run semdepth")
}

fn stdout_json(out: &Output) -> serde_json::Value {
    assert!(
        out.status.success(),
        "exit {:?}: {}",
        out.status.code(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("stdout is one JSON document")
}

#[test]
fn synth_then_init_finds_the_true_centroid() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("seq");
    let summary = stdout_json(&semdepth(&[
        "synth",
        out_dir.to_str().unwrap(),
        "--preset",
        "cluttered",
        "--shape",
        "tip",
        "--seed",
        "3",
        "--frames",
        "2",
    ]));
    assert_eq!(summary["frames"], 2);
    for name in [
        "0000_left.png",
        "0000_right.png",
        "0001_left.png",
        "0001_right.png",
        "truth.json",
    ] {
        assert!(out_dir.join(name).is_file(), "{name} missing");
    }
    let truth: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out_dir.join("truth.json")).unwrap()).unwrap();
    let expected = &truth["frames"][0]["left"]["centroid"];

    let found = stdout_json(&semdepth(&[
        "init",
        out_dir.join("0000_left.png").to_str().unwrap(),
    ]));
    let dx = found["centroid"][0].as_f64().unwrap() - expected[0].as_f64().unwrap();
    let dy = found["centroid"][1].as_f64().unwrap() - expected[1].as_f64().unwrap();
    // Initialisation is coarse (the tracker refines it): within 1.5 px.
    assert!(dx.hypot(dy) < 1.5, "centroid off by ({dx:.2}, {dy:.2})");
    assert!(found["contour"].as_array().unwrap().len() > 20);
}

#[test]
fn init_on_real_quartz_image() {
    let path = common::quartz_path(1);
    let found = stdout_json(&semdepth(&["init", path.to_str().unwrap(), "--no-contour"]));
    assert!(found.get("contour").is_none());
    let area = found["area_px"].as_f64().unwrap();
    assert!((500_000.0..800_000.0).contains(&area), "area {area}");
}

#[test]
fn init_reports_bad_input_with_exit_codes() {
    let dir = tempfile::tempdir().unwrap();
    let missing = semdepth(&["init", dir.path().join("nope.png").to_str().unwrap()]);
    assert_eq!(missing.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&missing.stderr).contains("nope.png"));

    let empty = dir.path().join("empty.png");
    std::fs::write(&empty, b"").unwrap();
    let out = semdepth(&["init", empty.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("empty_image"));

    let blank = dir.path().join("blank.png");
    image::GrayImage::from_pixel(64, 64, image::Luma([100]))
        .save(&blank)
        .unwrap();
    let out = semdepth(&["init", blank.to_str().unwrap()]);
    assert_eq!(
        out.status.code(),
        Some(3),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stderr).contains("no_edges"));

    let out = semdepth(&["init", blank.to_str().unwrap(), "--sigma", "-2"]);
    assert_eq!(out.status.code(), Some(2));
}

#[test]
fn synth_rejects_bad_options() {
    let dir = tempfile::tempdir().unwrap();
    let out = semdepth(&["synth", dir.path().to_str().unwrap(), "--width", "10"]);
    assert_eq!(
        out.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(!String::from_utf8_lossy(&out.stderr).is_empty());
}

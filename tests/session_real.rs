//! Two objects in one session on the real lift-out image (issue #18): a box
//! around the needle and a box around the lamella initialise each on its
//! own object. The references are the ones `tests/init_real.rs` derives and
//! checks independently of semdepth (the needle: the Otsu mask of its box;
//! the lamella: an outline traced by hand). The right view is the image
//! moved 3 px in x (the border column repeated: the needle goes on past
//! the border), so both objects' disparity is 3 px.

mod common;

use semdepth::geometry::{mask_iou, Polygon};
use semdepth::imageio::{read_file, DecodeLimits, GrayFrame};
use semdepth::init::InitParams;
use semdepth::session::{Session, SessionObject};
use semdepth::tracker::{Status, TrackerParams};

/// The needle's box as a person draws it (running past the left border).
const NEEDLE_BOX: [i64; 4] = [-20, 520, 320, 520];
/// The lamella's box.
const LAMELLA_BOX: [i64; 4] = [250, 430, 230, 210];
/// The hand-traced lamella of `tests/init_real.rs`.
const LAMELLA_OUTLINE: [[f64; 2]; 8] = [
    [274.0, 449.0],
    [457.0, 458.0],
    [459.0, 622.0],
    [420.0, 624.0],
    [330.0, 618.0],
    [265.0, 612.0],
    [264.0, 545.0],
    [268.0, 470.0],
];
/// Shift of the right view, pixels.
const SHIFT: usize = 3;
/// Each object's first left contour against its reference, IoU (the
/// initialisation alone reaches 0.85 on both, `tests/init_real.rs`).
const MIN_IOU: f64 = 0.8;
/// Each object's disparity error, pixels.
const MAX_DISPARITY_ERROR_PX: f64 = 0.3;

fn shifted(frame: &GrayFrame, dx: usize) -> GrayFrame {
    let w = frame.width as usize;
    let mut data = Vec::with_capacity(frame.data.len());
    for y in 0..frame.height {
        let row = frame.row(y);
        data.extend(std::iter::repeat_n(row[0], dx));
        data.extend_from_slice(&row[..w - dx]);
    }
    GrayFrame::new(frame.width, frame.height, frame.bit_depth, data).unwrap()
}

/// Not met yet (issue #18's acceptance on the real image): the
/// initialisation finds both (`tests/init_real.rs`), but the tracker's free
/// fit then moves the lamella's outline off it (IoU 0.37, its box
/// 167..461 x 448..720 against the lamella's 264..459 x 449..624) and the
/// needle's disparity reads 2.45 px for 3 (measured 2026-11-26).
#[test]
#[ignore = "open gap of issue #18: the free fit leaves the real lamella; run with --ignored"]
fn needle_and_lamella_are_found_from_their_boxes() {
    let left = read_file(&common::fibsem_path(), &DecodeLimits::default()).unwrap();
    let right = shifted(&left, SHIFT);
    let (w, h) = (left.width as usize, left.height as usize);
    let needle_ref =
        common::otsu_reference_mask_in_box(&left.data, w, left.max_value(), [0, 520, 300, h - 520]);
    let lamella_ref = Polygon::new(LAMELLA_OUTLINE.to_vec()).rasterize(left.width, left.height);
    let object = |name: &str, roi: [i64; 4]| {
        SessionObject::new(
            name,
            TrackerParams {
                init: InitParams {
                    roi: Some(roi),
                    ..InitParams::default()
                },
                ..TrackerParams::default()
            },
        )
    };
    let mut session = Session::new(
        vec![object("needle", NEEDLE_BOX), object("lamella", LAMELLA_BOX)],
        0,
    )
    .unwrap();
    let m = session.measure(&left, &right, None, None).unwrap();
    let mut disparities = Vec::new();
    for (o, reference) in m.objects.iter().zip([&needle_ref, &lamella_ref]) {
        assert_eq!(
            o.result.status,
            Status::Initialised,
            "{}: {:?}",
            o.name,
            o.result.reason
        );
        let mask =
            Polygon::new(o.result.left.as_ref().unwrap().contour.clone()).rasterize(left.width, left.height);
        let iou = mask_iou(&mask, reference);
        let d = o.result.disparity_axis_px.unwrap();
        eprintln!("{}: IoU {iou:.3}, disparity {d:.3} px", o.name);
        disparities.push(d);
        assert!(
            iou >= MIN_IOU,
            "{}: IoU {iou:.3} with its reference (limit {MIN_IOU})",
            o.name
        );
        assert!(
            (d - SHIFT as f64).abs() < MAX_DISPARITY_ERROR_PX,
            "{}: disparity {d:.3} px for {SHIFT}",
            o.name
        );
    }
    // Neither took the other: the two outlines hardly overlap.
    let masks: Vec<Vec<bool>> = m
        .objects
        .iter()
        .map(|o| {
            Polygon::new(o.result.left.as_ref().unwrap().contour.clone()).rasterize(left.width, left.height)
        })
        .collect();
    let overlap = mask_iou(&masks[0], &masks[1]);
    assert!(
        overlap < 0.1,
        "needle and lamella outlines overlap: IoU {overlap:.3}"
    );
    let rel = m.relative[0].disparity_axis_px.unwrap();
    assert!(
        (rel - (disparities[0] - disparities[1])).abs() < 1e-9,
        "relative disparity {rel:.3}"
    );
}

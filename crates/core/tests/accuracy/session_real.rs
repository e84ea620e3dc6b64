//! Two objects in one session on the real lift-out image (issue #18): a box
//! around the needle and a box around the lamella initialise each on its
//! own object. The references are the ones `tests/init_real.rs` derives and
//! checks independently of semdepth (the needle: the Otsu mask of its box;
//! the lamella: an outline traced by hand). The two views are the image
//! cut 3 px apart, so both objects' disparity is 3 px.

use crate::reference;

use semdepth_core::geometry::{mask_iou, Polygon};
use semdepth_core::imageio::{read_file, DecodeLimits, GrayFrame};
use semdepth_core::session::Session;
use semdepth_core::tracker::Status;

/// The needle's box as a person draws it (running past the left border).
const NEEDLE_BOX: [i64; 4] = [-20, 520, 320, 520];
/// The lamella's box.
const LAMELLA_BOX: [i64; 4] = [250, 430, 230, 210];
/// Shift of the right view, pixels.
const SHIFT: usize = 3;
/// Each object's first left contour against its reference, IoU (the
/// initialisation alone reaches 0.85 on both, `tests/init_real.rs`).
const MIN_IOU: f64 = 0.8;
/// Each object's disparity error, pixels (both measure within 0.002 px).
const MAX_DISPARITY_ERROR_PX: f64 = 0.1;

/// Columns `x0..x0 + width` of `frame`.
fn columns(frame: &GrayFrame, x0: usize, width: usize) -> GrayFrame {
    let mut data = Vec::with_capacity(width * frame.height as usize);
    for y in 0..frame.height {
        data.extend_from_slice(&frame.row(y)[x0..x0 + width]);
    }
    GrayFrame::new(width as u32, frame.height, frame.bit_depth, data).unwrap()
}

/// The two objects of one session, measured on the first pair.
fn first_pair() -> (semdepth_core::session::Measurement, [Vec<bool>; 2], GrayFrame) {
    // The views are the image's columns SHIFT.. and ..width - SHIFT: what
    // the left view shows at x the right one shows at x + SHIFT, and both
    // show the needle going on past their left border.
    let image = read_file(&reference::fibsem_path(), &DecodeLimits::default()).unwrap();
    let narrower = image.width as usize - SHIFT;
    let (left, right) = (columns(&image, SHIFT, narrower), columns(&image, 0, narrower));
    let (w, h) = (left.width as usize, left.height as usize);
    let needle_ref =
        reference::otsu_reference_mask_in_box(&left.data, w, left.max_value(), [0, 520, 300, h - 520]);
    let lamella_ref = Polygon::new(reference::LAMELLA_OUTLINE.to_vec())
        .translated([-(SHIFT as f64), 0.0])
        .rasterize(left.width, left.height);
    let object = reference::boxed_object;
    let mut session = Session::new(
        vec![object("needle", NEEDLE_BOX), object("lamella", LAMELLA_BOX)],
        0,
    )
    .unwrap();
    let m = session.measure(&left, &right, None, None).unwrap();
    (m, [needle_ref, lamella_ref], left)
}

/// Issue #18: each box initialises its own object, the needle entering
/// from the border and the lamella it holds, and neither takes the other.
#[test]
fn needle_and_lamella_are_found_from_their_boxes() {
    let (m, references, left) = first_pair();
    let mut failures = Vec::new();
    for (o, reference) in m.objects.iter().zip(&references) {
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
        eprintln!("{}: IoU {iou:.3}", o.name);
        if iou < MIN_IOU {
            failures.push(format!(
                "{}: IoU {iou:.3} with its reference (limit {MIN_IOU})",
                o.name
            ));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
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
    let d: Vec<f64> = m
        .objects
        .iter()
        .map(|o| o.result.disparity_axis_px.unwrap())
        .collect();
    let rel = m.relative[0].disparity_axis_px.unwrap();
    assert!((rel - (d[0] - d[1])).abs() < 1e-9, "relative disparity {rel:.3}");
}

/// Issue #17 on a real image: both objects measure the 3 px between the
/// views, also the needle whose base lies past the border and whose tip
/// touches the lamella (before the cuts lay inside the image side it read
/// 1.85 px, 13 of its reported standard errors off).
#[test]
fn needle_and_lamella_have_the_true_disparity() {
    let (m, _, _) = first_pair();
    let mut failures = Vec::new();
    for o in &m.objects {
        let d = o.result.disparity_axis_px.unwrap();
        eprintln!(
            "{}: disparity {d:.3} px, std {:?}",
            o.name, o.result.disparity_std_px
        );
        if (d - SHIFT as f64).abs() >= MAX_DISPARITY_ERROR_PX {
            failures.push(format!("{}: disparity {d:.3} px for {SHIFT}", o.name));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

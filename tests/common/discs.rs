//! A scene with two objects for the hint tests, built here rather than by
//! the generator: two bright discs on a dark, faintly textured background,
//! the right view shifted by a known disparity along x. Without a hint the
//! initialisation may take either disc; a `roi` around one must pick it.
#![allow(dead_code)]

use semdepth_core::imageio::GrayFrame;

/// Image size of the scene, pixels.
pub const WIDTH: u32 = 320;
/// See [`WIDTH`].
pub const HEIGHT: u32 = 240;
/// The larger disc `[cx, cy, radius]` in the left image.
pub const DISC_A: [f64; 3] = [90.0, 130.0, 34.0];
/// The smaller disc, 145 px to the right of A (beyond the first pair's
/// disparity search of 64 px, so the right view cannot confuse them).
pub const DISC_B: [f64; 3] = [235.0, 110.0, 24.0];
/// A box `[x, y, w, h]` around A only (16 px margin).
pub const ROI_A: [i64; 4] = [40, 80, 100, 100];
/// A box around B only (11 px margin).
pub const ROI_B: [i64; 4] = [200, 75, 70, 70];
/// Disparity of both discs between the left and right views, pixels (x).
pub const DISPARITY_PX: f64 = 6.0;

/// A lasso round `disc`: `vertices` points on a circle `margin` px outside it.
pub fn lasso([cx, cy, r]: [f64; 3], margin: f64, vertices: usize) -> Vec<[f64; 2]> {
    (0..vertices)
        .map(|k| {
            let a = k as f64 * std::f64::consts::TAU / vertices as f64;
            [cx + (r + margin) * a.cos(), cy + (r + margin) * a.sin()]
        })
        .collect()
}

/// An 8-bit frame: each disc `[cx, cy, r]` at grey 180 with a soft edge
/// about 1 px wide, background 60, plus a deterministic texture of +-3
/// grey levels.
pub fn discs_frame(width: u32, height: u32, discs: &[[f64; 3]]) -> GrayFrame {
    let mut data = Vec::with_capacity(width as usize * height as usize);
    for y in 0..height {
        for x in 0..width {
            let mut v = 60.0;
            for &[cx, cy, r] in discs {
                let d = (x as f64 - cx).hypot(y as f64 - cy) - r;
                v += 120.0 / (1.0 + (2.0 * d).clamp(-50.0, 50.0).exp());
            }
            let hash = (x as u64)
                .wrapping_mul(0x9E37_79B9_7F4A_7C15)
                .wrapping_add((y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F));
            let texture = ((hash >> 40) % 7) as f64 - 3.0;
            data.push((v + texture).round().clamp(0.0, 255.0) as u16);
        }
    }
    GrayFrame::new(width, height, 8, data).expect("a valid 8-bit frame")
}

/// The scene's pair with both discs moved by `motion` `[dx, dy]` pixels
/// (between pairs): left, and right shifted by [`DISPARITY_PX`] in x.
pub fn scene_pair(motion: [f64; 2]) -> (GrayFrame, GrayFrame) {
    let moved = |d: [f64; 3], shift: f64| [d[0] + motion[0] + shift, d[1] + motion[1], d[2]];
    let left = discs_frame(WIDTH, HEIGHT, &[moved(DISC_A, 0.0), moved(DISC_B, 0.0)]);
    let right = discs_frame(
        WIDTH,
        HEIGHT,
        &[moved(DISC_A, DISPARITY_PX), moved(DISC_B, DISPARITY_PX)],
    );
    (left, right)
}

/// Distance of a `[x, y]` JSON centroid from `[cx, cy]`.
pub fn distance(centroid: &serde_json::Value, cx: f64, cy: f64) -> f64 {
    let x = centroid[0]
        .as_f64()
        .unwrap_or_else(|| panic!("centroid {centroid}"));
    let y = centroid[1]
        .as_f64()
        .unwrap_or_else(|| panic!("centroid {centroid}"));
    (x - cx).hypot(y - cy)
}

/// An 8-bit frame as PNG bytes.
pub fn png8(frame: &GrayFrame) -> Vec<u8> {
    let mut out = std::io::Cursor::new(Vec::new());
    frame
        .to_gray8()
        .write_to(&mut out, image::ImageFormat::Png)
        .unwrap();
    out.into_inner()
}

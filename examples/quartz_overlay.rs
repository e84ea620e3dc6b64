//! Tracks a real stereo pair and draws the left contour on the left image and
//! the right contour on the right image side by side:
//! `quartz_overlay LEFT RIGHT OUT.png`.
use imageproc::drawing::draw_line_segment_mut;
use semdepth::imageio::{read_file, DecodeLimits};
use semdepth::tracker::{StereoTracker, TrackerParams};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let l = read_file(a[1].as_ref(), &DecodeLimits::default()).unwrap();
    let r = read_file(a[2].as_ref(), &DecodeLimits::default()).unwrap();
    let mut params = TrackerParams::default();
    if std::env::var("NOROT").is_ok() {
        params.rigid.rotate = false;
    }
    let mut t = StereoTracker::new(params);
    let res = t.process(&l, &r).unwrap();
    println!(
        "{:?} {:?} disparity {:?}",
        res.status, res.reason, res.disparity_px
    );
    let w = l.width;
    let mut canvas = image::RgbImage::new(2 * w, l.height);
    for (k, (img, side)) in [(&l, res.left.as_ref()), (&r, res.right.as_ref())]
        .into_iter()
        .enumerate()
    {
        let g = image::DynamicImage::ImageLuma8(img.to_gray8()).to_rgb8();
        image::imageops::replace(&mut canvas, &g, (k as u32 * w) as i64, 0);
        if let Some(side) = side {
            let n = side.contour.len();
            for i in 0..n {
                let (p, q) = (side.contour[i], side.contour[(i + 1) % n]);
                let off = (k as u32 * w) as f32;
                draw_line_segment_mut(
                    &mut canvas,
                    (p[0] as f32 + off, p[1] as f32),
                    (q[0] as f32 + off, q[1] as f32),
                    image::Rgb([255, 60, 60]),
                );
            }
        }
    }
    image::imageops::resize(
        &canvas,
        canvas.width() / 2,
        canvas.height() / 2,
        image::imageops::FilterType::Triangle,
    )
    .save(&a[3])
    .unwrap();
}

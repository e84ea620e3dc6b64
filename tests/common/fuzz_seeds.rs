//! Valid inputs in every form the service accepts: the seeds of the
//! mutation corpus (`tests/fuzz_corpus.rs`) and of the `cargo fuzz` targets
//! (`examples/fuzz_seeds.rs` writes them to `fuzz/corpus/`).

use std::io::Cursor;

use semdepth::service::wire::encode_pair_message;

fn encoded(img: image::DynamicImage, format: image::ImageFormat) -> Vec<u8> {
    let mut out = Cursor::new(Vec::new());
    img.write_to(&mut out, format).unwrap();
    out.into_inner()
}

/// Valid images in every accepted format, named.
pub fn image_seeds() -> Vec<(&'static str, Vec<u8>)> {
    let grey8 = image::GrayImage::from_fn(48, 32, |x, y| image::Luma([((x * 5) ^ (y * 3)) as u8]));
    let grey16 = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(40, 24, |x, y| {
        image::Luma([(x * 1500 + y * 700) as u16])
    });
    let rgb = image::RgbImage::from_fn(32, 32, |x, y| image::Rgb([x as u8 * 7, y as u8 * 5, 90]));
    vec![
        ("png8", encoded(grey8.clone().into(), image::ImageFormat::Png)),
        ("png16", encoded(grey16.clone().into(), image::ImageFormat::Png)),
        ("tiff8", encoded(grey8.clone().into(), image::ImageFormat::Tiff)),
        ("tiff16", encoded(grey16.into(), image::ImageFormat::Tiff)),
        ("jpeg", encoded(rgb.clone().into(), image::ImageFormat::Jpeg)),
        ("bmp", encoded(rgb.into(), image::ImageFormat::Bmp)),
    ]
}

/// Valid SDP1 messages: raw 8-bit samples and PNG files.
pub fn message_seeds() -> Vec<(&'static str, Vec<u8>)> {
    let (w, h) = (24u32, 16u32);
    let raw: Vec<u8> = (0..w * h).map(|i| (i * 7) as u8).collect();
    let png = image_seeds().remove(0).1;
    vec![
        (
            "sdp1-raw",
            encode_pair_message(
                &serde_json::json!({"seq": 1, "encoding": "raw", "width": w, "height": h, "bit_depth": 8,
                    "left_len": raw.len(), "right_len": raw.len()}),
                &raw,
                &raw,
            ),
        ),
        (
            "sdp1-png",
            encode_pair_message(
                &serde_json::json!({"seq": 2, "encoding": "png", "left_len": png.len(), "right_len": png.len(),
                    "label": "corpus", "timestamp": "2026-11-26T00:00:00Z"}),
                &png,
                &png,
            ),
        ),
    ]
}

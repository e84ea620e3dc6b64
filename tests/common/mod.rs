//! Helpers shared by the application's tests: paths to the shared data and
//! images with microscope metadata.
#![allow(dead_code)]

use std::path::PathBuf;

/// `../shared` beside the repository.
pub fn shared_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared")
}

/// The real quartz images `Quarz_01.png` .. `Quarz_03.png`.
pub fn quartz_path(index: u32) -> PathBuf {
    shared_dir().join(format!("data/real/quartz/Quarz_{index:02}.png"))
}

/// `image` as an 8-bit TIFF carrying FEI metadata (tag 34682,
/// `FEI_HELIOS`, ini text as the microscope writes it) with this pixel size
/// (metres) and stage tilt (radians).
pub fn fei_tiff(image: &image::GrayImage, pixel_m: f64, tilt_rad: f64) -> Vec<u8> {
    use tiff::encoder::{colortype::Gray8, TiffEncoder};
    let text = format!(
        "[User]\r\nDate=11/25/2026\r\n[Beam]\r\nHV=5000\r\n[Scan]\r\nPixelWidth={pixel_m:e}\r\nPixelHeight={pixel_m:e}\r\n\
         [Stage]\r\nStageT={tilt_rad}\r\nWorkingDistance=0.0165\r\n"
    );
    let mut out = std::io::Cursor::new(Vec::new());
    let mut encoder = TiffEncoder::new(&mut out).unwrap();
    let mut page = encoder.new_image::<Gray8>(image.width(), image.height()).unwrap();
    page.encoder()
        .write_tag(tiff::tags::Tag::Unknown(34682), text.as_str())
        .unwrap();
    page.write_data(image.as_raw()).unwrap();
    out.into_inner()
}

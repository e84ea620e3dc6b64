//! Microscope metadata (`semdepth_core::meta` and `semdepth meta`): the real FEI
//! file in `../shared/data/real/fibsem/`, ZEISS / TESCAN / FEI fixtures
//! written here with the `tiff` encoder, and garbled or truncated tags.

use crate::common;

use std::io::Cursor;
use std::path::PathBuf;
use std::process::{Command, Output};

use semdepth_core::meta::{read_meta, Beam, ImageMeta, Vendor, TAG_CZ_SEM, TAG_FEI_HELIOS, TAG_TESCAN};
use tiff::encoder::{colortype, TiffEncoder};
use tiff::tags::Tag;

/// What the real file's README states (`[Scan] PixelWidth`, `[Stage]
/// StageT`, `[Stage] WorkingDistance`).
const FEI_PIXEL_M: f64 = 9.76562e-08;
const FEI_TILT_RAD: f64 = 0.558473;
const FEI_WD_M: f64 = 0.0165;

fn fei_path() -> PathBuf {
    common::shared_dir().join("data/real/fibsem/needle_lamella_fei.tif")
}

/// The real OpenFIBSEM tilt pair (`fibsem_tilt/`) and what its README
/// states: ion-beam images, 97.66 nm pixels, stage tilts 30 and 25 degrees.
fn tilt_pair() -> [(PathBuf, f64); 2] {
    let dir = common::shared_dir().join("data/real/fibsem_tilt");
    [
        (dir.join("undercut_stage30deg_ib.tif"), 0.5235865576931467),
        (dir.join("undercut_stage25deg_ib.tif"), 0.43632024519054546),
    ]
}
const TILT_PAIR_PIXEL_M: f64 = 9.765624999999999e-08;

fn semdepth(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_semdepth"))
        .args(args)
        .output()
        .expect("run semdepth")
}

/// A tag value as the fixture writes it: ASCII type (NUL-terminated, ASCII
/// only) or BYTE type (any bytes).
#[derive(Clone, Copy)]
enum Text<'a> {
    Ascii(&'a str),
    Bytes(&'a [u8]),
}

/// A 16x16 TIFF with one page per entry of `pages`, each an (optional)
/// vendor tag; `sixteen_bit` picks 16-bit grey instead of 8-bit.
fn tiff_pages(pages: &[Option<(u16, Text)>], sixteen_bit: bool) -> Vec<u8> {
    let mut cursor = Cursor::new(Vec::new());
    {
        let mut encoder = TiffEncoder::new(&mut cursor).unwrap();
        for page in pages {
            macro_rules! write_page {
                ($colour:ty, $data:expr) => {{
                    let mut image = encoder.new_image::<$colour>(16, 16).unwrap();
                    match page {
                        Some((tag, Text::Ascii(s))) => {
                            image.encoder().write_tag(Tag::Unknown(*tag), *s).unwrap()
                        }
                        Some((tag, Text::Bytes(b))) => {
                            image.encoder().write_tag(Tag::Unknown(*tag), *b).unwrap()
                        }
                        None => {}
                    }
                    image.write_data($data).unwrap();
                }};
            }
            if sixteen_bit {
                write_page!(colortype::Gray16, &[40_000u16; 256]);
            } else {
                write_page!(colortype::Gray8, &[100u8; 256]);
            }
        }
    }
    cursor.into_inner()
}

/// A one-page 8-bit TIFF carrying `text` in `tag`.
fn tiff8(tag: u16, text: Text) -> Vec<u8> {
    tiff_pages(&[Some((tag, text))], false)
}

fn close(actual: Option<f64>, expected: f64, what: &str) {
    let v = actual.unwrap_or_else(|| panic!("{what} missing"));
    assert!(
        (v - expected).abs() <= 1e-9 * expected.abs(),
        "{what}: {v:e}, expected {expected:e}"
    );
}

fn assert_warned(meta: &ImageMeta, needle: &str) {
    assert!(
        meta.warnings.iter().any(|w| w.contains(needle)),
        "no warning containing {needle:?} in {:?}",
        meta.warnings
    );
}

#[test]
fn real_fei_file_gives_pixel_size_tilt_and_working_distance() {
    let bytes = std::fs::read(fei_path()).unwrap();
    let meta = read_meta(&bytes);
    assert_eq!(meta.vendor, Some(Vendor::Fei));
    close(meta.pixel_width_m, FEI_PIXEL_M, "pixel width");
    close(meta.pixel_height_m, FEI_PIXEL_M, "pixel height");
    close(meta.stage_tilt_rad, FEI_TILT_RAD, "stage tilt");
    close(meta.working_distance_m, FEI_WD_M, "working distance");
    close(meta.high_voltage_v, 30_000.0, "high voltage");
    assert!(meta.warnings.is_empty(), "{:?}", meta.warnings);
}

#[test]
fn real_openfibsem_files_give_the_ion_beams_values() {
    for (path, tilt) in tilt_pair() {
        let meta = read_meta(&std::fs::read(&path).unwrap());
        assert_eq!(meta.vendor, Some(Vendor::OpenFibsem), "{}", path.display());
        assert_eq!(meta.beam, Some(Beam::Ion));
        close(meta.pixel_width_m, TILT_PAIR_PIXEL_M, "pixel width");
        close(meta.pixel_height_m, TILT_PAIR_PIXEL_M, "pixel height");
        close(meta.stage_tilt_rad, tilt, "stage tilt");
        close(meta.working_distance_m, 0.0165, "working distance");
        close(meta.high_voltage_v, 30_000.0, "high voltage");
        assert_eq!(meta.magnification, None);
        assert!(meta.warnings.is_empty(), "{:?}", meta.warnings);
    }
    // The FEI-tagged electron image beside them: the microscope's own tag.
    let fei = common::shared_dir().join("data/real/fibsem_tilt/openfibsem_start_eb_fei.tif");
    let meta = read_meta(&std::fs::read(fei).unwrap());
    assert_eq!(
        (meta.vendor, meta.beam),
        (Some(Vendor::Fei), Some(Beam::Electron))
    );
}

#[test]
fn cli_meta_prints_the_openfibsem_values() {
    let [(first, tilt), _] = tilt_pair();
    let out = semdepth(&["meta", first.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("stdout is JSON");
    let r = &json[0];
    assert_eq!(r["vendor"], "openfibsem");
    assert_eq!(r["beam"], "ion");
    close(r["pixel_width_m"].as_f64(), TILT_PAIR_PIXEL_M, "pixel_width_m");
    close(r["stage_tilt_rad"].as_f64(), tilt, "stage_tilt_rad");
    close(r["working_distance_m"].as_f64(), 0.0165, "working_distance_m");
    assert_eq!(r["warnings"], serde_json::json!([]));
}

#[test]
fn cli_meta_prints_the_real_fei_values() {
    let path = fei_path();
    let out = semdepth(&["meta", path.to_str().unwrap()]);
    assert!(
        out.status.success(),
        "exit {:?}: {}",
        out.status.code(),
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("stdout is JSON");
    let records = json.as_array().expect("a JSON array");
    assert_eq!(records.len(), 1);
    let r = &records[0];
    assert_eq!(r["image"], path.display().to_string());
    assert_eq!(r["vendor"], "fei");
    assert_eq!(r["beam"], "ion");
    close(r["pixel_width_m"].as_f64(), FEI_PIXEL_M, "pixel_width_m");
    close(r["pixel_height_m"].as_f64(), FEI_PIXEL_M, "pixel_height_m");
    close(r["stage_tilt_rad"].as_f64(), FEI_TILT_RAD, "stage_tilt_rad");
    close(r["working_distance_m"].as_f64(), FEI_WD_M, "working_distance_m");
    assert!(r["magnification"].is_null());
    assert_eq!(r["warnings"], serde_json::json!([]));
}

#[test]
fn cli_meta_on_a_missing_file_exits_2_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("no_such_image.tif");
    let out = semdepth(&["meta", fei_path().to_str().unwrap(), missing.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains(missing.to_str().unwrap()), "stderr: {stderr}");
    assert!(
        out.stdout.is_empty(),
        "stdout: {}",
        String::from_utf8_lossy(&out.stdout)
    );
}

#[test]
fn cli_meta_on_files_without_metadata_prints_nulls() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("plain.png");
    std::fs::write(&png, png_bytes()).unwrap();
    let tif = dir.path().join("plain.tif");
    std::fs::write(&tif, tiff_pages(&[None], false)).unwrap();
    let out = semdepth(&["meta", png.to_str().unwrap(), tif.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let records = json.as_array().unwrap();
    assert_eq!(records.len(), 2);
    for (r, path) in records.iter().zip([&png, &tif]) {
        assert_eq!(r["image"], path.display().to_string());
        for field in [
            "vendor",
            "pixel_width_m",
            "pixel_height_m",
            "stage_tilt_rad",
            "working_distance_m",
            "high_voltage_v",
            "magnification",
        ] {
            assert!(r[field].is_null(), "{field} in {r}");
        }
        assert_eq!(r["warnings"], serde_json::json!([]));
    }
}

/// The ZEISS layout: a parameter name line, then `Label = value unit`; the
/// file also has the display pixel `AP_PIXEL_SIZE`, which must not be used.
const ZEISS: &str = "\r\nSV_USER_NAME\r\nUser Name = lab\r\n\
AP_PIXEL_SIZE\r\nPixel Size = 186.0 nm\r\n\
AP_IMAGE_PIXEL_SIZE\r\nImage Pixel Size = 3.572 nm\r\n\
AP_STAGE_AT_T\r\nStage at T = 52.0 deg\r\n\
AP_WD\r\nWD = 5.1 mm\r\n\
AP_MAG\r\nMag = 2.00 K X\r\n\
AP_ACTUALKV\r\nEHT = 3.00 kV\r\n\
DP_DETECTOR_TYPE\r\nSignal A = InLens\r\n";

#[test]
fn zeiss_fixture_two_line_form() {
    let meta = read_meta(&tiff8(TAG_CZ_SEM, Text::Ascii(ZEISS)));
    assert_eq!(meta.vendor, Some(Vendor::Zeiss));
    close(meta.pixel_width_m, 3.572e-9, "pixel width");
    close(meta.pixel_height_m, 3.572e-9, "pixel height");
    close(meta.stage_tilt_rad, 52f64.to_radians(), "stage tilt");
    close(meta.working_distance_m, 5.1e-3, "working distance");
    close(meta.magnification, 2000.0, "magnification");
    close(meta.high_voltage_v, 3000.0, "high voltage");
    assert!(meta.warnings.is_empty(), "{:?}", meta.warnings);
}

#[test]
fn zeiss_fixture_one_line_form_with_utf8_micro_and_degree() {
    for micro in ["\u{b5}m", "\u{3bc}m", "um"] {
        let text = format!(
            "AP_IMAGE_PIXEL_SIZE = 0.25 {micro}\nAP_STAGE_AT_T = -5.5°\nAP_WD = 0.0081 m\nAP_MAG = 1.50 M X\n"
        );
        let meta = read_meta(&tiff8(TAG_CZ_SEM, Text::Bytes(text.as_bytes())));
        assert_eq!(meta.vendor, Some(Vendor::Zeiss), "{micro}");
        close(meta.pixel_width_m, 0.25e-6, "pixel width");
        close(meta.pixel_height_m, 0.25e-6, "pixel height");
        close(meta.stage_tilt_rad, (-5.5f64).to_radians(), "stage tilt");
        close(meta.working_distance_m, 0.0081, "working distance");
        close(meta.magnification, 1.5e6, "magnification");
        assert_eq!(meta.high_voltage_v, None);
        assert!(meta.warnings.is_empty(), "{micro}: {:?}", meta.warnings);
    }
}

#[test]
fn zeiss_latin1_bytes_missing_units_and_bad_numbers() {
    // 0xB5 is µ and 0xB0 is ° in Latin-1, as older SmartSEM versions write them.
    let text: &[u8] = b"AP_IMAGE_PIXEL_SIZE\r\nImage Pixel Size = 2.5 \xb5m\r\n\
AP_STAGE_AT_T\r\nStage at T = 10.0 \xb0\r\n\
AP_WD\r\nWD = 5\r\n\
AP_MAG\r\nMag = 1,5 K X\r\n\
AP_ACTUALKV\r\nEHT = 3.00 furlongs\r\n";
    let meta = read_meta(&tiff8(TAG_CZ_SEM, Text::Bytes(text)));
    assert_eq!(meta.vendor, Some(Vendor::Zeiss));
    close(meta.pixel_width_m, 2.5e-6, "pixel width");
    close(meta.stage_tilt_rad, 10f64.to_radians(), "stage tilt");
    assert_eq!(meta.working_distance_m, None);
    assert_eq!(meta.magnification, None);
    assert_eq!(meta.high_voltage_v, None);
    assert_warned(&meta, "ZEISS AP_WD: '5' has no unit");
    assert_warned(&meta, "ZEISS AP_MAG: '1,5 K X' is not a number");
    assert_warned(&meta, "ZEISS AP_ACTUALKV: unknown voltage unit 'furlongs'");
    assert_eq!(meta.warnings.len(), 3, "{:?}", meta.warnings);
}

#[test]
fn zeiss_display_pixel_alone_is_not_used() {
    let text = "AP_PIXEL_SIZE\r\nPixel Size = 186.0 nm\r\nAP_STAGE_AT_T\r\nStage at T = 0.0 deg\r\n";
    let meta = read_meta(&tiff8(TAG_CZ_SEM, Text::Ascii(text)));
    assert_eq!(meta.pixel_width_m, None);
    assert_eq!(meta.pixel_height_m, None);
    assert_eq!(meta.stage_tilt_rad, Some(0.0));
    assert_warned(&meta, "no pixel size");
    assert_warned(&meta, "AP_PIXEL_SIZE");
}

/// The TESCAN layout: `[MAIN]` and `[SEM]` ini sections, `[SEM]` first.
const TESCAN: &str =
    "[MAIN]\r\nDevice=MIRA3\r\nPixelSizeX=9.9e-009\r\nStageTilt=1.0\r\nMagnification=25000\r\n\
[SEM]\r\nHV=20000.0\r\nWD=0.00987\r\nPixelSizeX=4.5e-009\r\nPixelSizeY=5.0e-009\r\nStageTilt=15.0\r\n";

#[test]
fn tescan_fixture() {
    let meta = read_meta(&tiff8(TAG_TESCAN, Text::Ascii(TESCAN)));
    assert_eq!(meta.vendor, Some(Vendor::Tescan));
    close(meta.pixel_width_m, 4.5e-9, "pixel width");
    close(meta.pixel_height_m, 5.0e-9, "pixel height");
    close(meta.stage_tilt_rad, 15f64.to_radians(), "stage tilt");
    close(meta.working_distance_m, 0.00987, "working distance");
    close(meta.high_voltage_v, 20_000.0, "high voltage");
    close(meta.magnification, 25_000.0, "magnification");
    assert!(meta.warnings.is_empty(), "{:?}", meta.warnings);
}

#[test]
fn tescan_tag_cut_off_mid_line() {
    let cut = "[MAIN]\r\nPixelSizeX=2e-9\r\nPixelSizeY=1.5e-\0";
    let meta = read_meta(&tiff8(TAG_TESCAN, Text::Bytes(cut.as_bytes())));
    assert_eq!(meta.vendor, Some(Vendor::Tescan));
    close(meta.pixel_width_m, 2e-9, "pixel width");
    close(meta.pixel_height_m, 2e-9, "pixel height (square assumed)");
    assert_eq!(meta.stage_tilt_rad, None);
    assert_warned(&meta, "TESCAN [MAIN] PixelSizeY: '1.5e-' is not a number");
    assert_warned(&meta, "square pixels assumed");
    assert_warned(&meta, "no stage tilt");
}

/// FEI ini text with a non-square pixel, as in the real file's layout.
const FEI: &str = "[User]\r\nDate=12/14/2022\r\n\r\n[Beam]\r\nHV=2000\r\nBeam=EBeam\r\nScan=EScan\r\n\r\n\
[Scan]\r\nPixelWidth=1.25e-008\r\nPixelHeight=2.5e-008\r\nHorFieldsize=1.28e-005\r\n\r\n\
[Stage]\r\nStageT=-0.1\r\nWorkingDistance=0.0041\r\n\r\n[Image]\r\nResolutionX=1024\r\n";

#[test]
fn fei_text_in_a_16_bit_tiff() {
    let meta = read_meta(&tiff_pages(&[Some((TAG_FEI_HELIOS, Text::Ascii(FEI)))], true));
    assert_eq!(meta.vendor, Some(Vendor::Fei));
    close(meta.pixel_width_m, 1.25e-8, "pixel width");
    close(meta.pixel_height_m, 2.5e-8, "pixel height");
    close(meta.stage_tilt_rad, -0.1, "stage tilt");
    close(meta.working_distance_m, 0.0041, "working distance");
    close(meta.high_voltage_v, 2000.0, "high voltage");
    assert_eq!(meta.magnification, None);
    assert!(meta.warnings.is_empty(), "{:?}", meta.warnings);
}

#[test]
fn two_page_tiff_reads_the_first_page_tag() {
    let second = FEI.replace("1.25e-008", "7e-007");
    let bytes = tiff_pages(
        &[
            Some((TAG_FEI_HELIOS, Text::Ascii(FEI))),
            Some((TAG_FEI_HELIOS, Text::Ascii(&second))),
        ],
        false,
    );
    let meta = read_meta(&bytes);
    close(meta.pixel_width_m, 1.25e-8, "pixel width of page 1");
    assert!(meta.warnings.is_empty(), "{:?}", meta.warnings);

    // Only the first IFD is looked at: a tag on page 2 alone is not found.
    let only_second = tiff_pages(&[None, Some((TAG_FEI_HELIOS, Text::Ascii(FEI)))], false);
    assert_eq!(read_meta(&only_second), ImageMeta::default());
}

#[test]
fn fei_missing_equals_unparsable_numbers_and_fallbacks() {
    let text = "[Scan]\r\nPixelWidth 9.76562e-008\r\nPixelHeight=9.76562e-008\r\n\
[Stage]\r\nStageT=abc\r\nStageTb=0.25\r\nWorkingDistance=1,5\r\n[EBeam]\r\nWD=0.007\r\n\
[Beam]\r\nHV=30 kV\r\n";
    let meta = read_meta(&tiff8(TAG_FEI_HELIOS, Text::Ascii(text)));
    assert_eq!(meta.vendor, Some(Vendor::Fei));
    close(meta.pixel_width_m, 9.76562e-8, "pixel width (square assumed)");
    close(meta.pixel_height_m, 9.76562e-8, "pixel height");
    close(meta.stage_tilt_rad, 0.25, "stage tilt from StageTb");
    close(meta.working_distance_m, 0.007, "working distance from [EBeam] WD");
    assert_eq!(meta.high_voltage_v, None);
    assert_warned(&meta, "FEI [Scan] PixelWidth is missing: square pixels assumed");
    assert_warned(&meta, "FEI [Stage] StageT: 'abc' is not a number");
    assert_warned(&meta, "FEI [Stage] WorkingDistance: '1,5' is not a number");
    assert_warned(&meta, "FEI [Beam] HV: '30 kV' is not a number");
    assert_eq!(meta.warnings.len(), 4, "{:?}", meta.warnings);
}

#[test]
fn fei_pixel_size_derived_from_field_width() {
    let text = "[Scan]\nHorFieldsize=0.00015\n[Image]\nResolutionX=1536\n[Stage]\nStageT=0.2\n";
    let meta = read_meta(&tiff8(TAG_FEI_HELIOS, Text::Ascii(text)));
    close(meta.pixel_width_m, 0.00015 / 1536.0, "derived pixel width");
    close(meta.pixel_height_m, 0.00015 / 1536.0, "derived pixel height");
    assert_warned(&meta, "derived");
    assert_eq!(meta.warnings.len(), 1, "{:?}", meta.warnings);
}

#[test]
fn empty_vendor_tags_report_absent_values() {
    for (tag, vendor) in [
        (TAG_FEI_HELIOS, Vendor::Fei),
        (TAG_CZ_SEM, Vendor::Zeiss),
        (TAG_TESCAN, Vendor::Tescan),
    ] {
        for text in [Text::Ascii(""), Text::Bytes(b"\0\0\0\0\0\0\0\0\r\n")] {
            let meta = read_meta(&tiff8(tag, text));
            assert_eq!(meta.vendor, Some(vendor));
            assert_eq!(meta.pixel_width_m, None);
            assert_eq!(meta.stage_tilt_rad, None);
            assert_warned(&meta, "no pixel size");
            assert_warned(&meta, "no stage tilt");
            assert_eq!(meta.warnings.len(), 2, "{:?}", meta.warnings);
        }
    }
}

#[test]
fn huge_junk_tag_still_yields_the_values_after_it() {
    // 1 MB of pseudo-random bytes (with many '=', '[', newlines and NULs),
    // then a valid FEI block.
    const JUNK: &[u8] = b"=[]\r\n\0 abcXYZ0123456789.e-\xb5\xff";
    let mut state = 0x2545_F491_4F6C_DD1Du64;
    let mut text: Vec<u8> = (0..1 << 20)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            JUNK[(state % JUNK.len() as u64) as usize]
        })
        .collect();
    text.extend_from_slice(b"\r\n[Scan]\r\nPixelWidth=3e-9\r\nPixelHeight=3e-9\r\n[Stage]\r\nStageT=0.3\r\n");
    let meta = read_meta(&tiff8(TAG_FEI_HELIOS, Text::Bytes(&text)));
    assert_eq!(meta.vendor, Some(Vendor::Fei));
    close(meta.pixel_width_m, 3e-9, "pixel width");
    close(meta.stage_tilt_rad, 0.3, "stage tilt");
    assert!(meta.warnings.is_empty(), "{:?}", meta.warnings);

    // The same junk as ZEISS and TESCAN text: no panic, nothing invented.
    for tag in [TAG_CZ_SEM, TAG_TESCAN] {
        let meta = read_meta(&tiff8(tag, Text::Bytes(&text[..1 << 20])));
        assert_eq!(meta.pixel_width_m, None);
        assert_warned(&meta, "no pixel size");
    }
}

#[test]
fn truncated_fixture_files_never_panic() {
    let bytes = tiff8(TAG_CZ_SEM, Text::Ascii(ZEISS));
    for len in 0..bytes.len() {
        let meta = read_meta(&bytes[..len]);
        if len < 4 {
            assert_eq!(meta, ImageMeta::default(), "length {len}");
        }
    }
}

fn png_bytes() -> Vec<u8> {
    let mut out = Cursor::new(Vec::new());
    image::DynamicImage::new_luma8(16, 16)
        .write_to(&mut out, image::ImageFormat::Png)
        .unwrap();
    out.into_inner()
}

#[test]
fn png_and_jpeg_have_no_metadata_and_no_warnings() {
    let mut jpeg = Cursor::new(Vec::new());
    image::DynamicImage::new_luma8(16, 16)
        .write_to(&mut jpeg, image::ImageFormat::Jpeg)
        .unwrap();
    let mut bmp = Cursor::new(Vec::new());
    image::DynamicImage::new_luma8(16, 16)
        .write_to(&mut bmp, image::ImageFormat::Bmp)
        .unwrap();
    for bytes in [
        png_bytes(),
        jpeg.into_inner(),
        bmp.into_inner(),
        b"not an image".to_vec(),
    ] {
        assert_eq!(read_meta(&bytes), ImageMeta::default());
    }
}

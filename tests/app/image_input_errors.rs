//! Bad image input gets its specific error, never a panic or a huge
//! allocation (issue #2).

use std::io::Cursor;

use semdepth_core::imageio::{check_pair, decode, decode_raw, DecodeLimits, GrayFrame, ImageInputError};

fn png_bytes(width: u32, height: u32) -> Vec<u8> {
    let img = image::GrayImage::from_fn(width, height, |x, y| image::Luma([(x ^ y) as u8]));
    let mut out = Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).unwrap();
    out.into_inner()
}

/// A PNG whose header declares `width` x `height` (valid CRC) followed by a
/// tiny IDAT: a decompression-bomb-style header with no real data.
fn png_declaring(width: u32, height: u32) -> Vec<u8> {
    fn chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
        out.extend_from_slice(&(data.len() as u32).to_be_bytes());
        let mut crc_input = kind.to_vec();
        crc_input.extend_from_slice(data);
        out.extend_from_slice(&crc_input);
        out.extend_from_slice(&crc32(&crc_input).to_be_bytes());
    }
    let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = Vec::new();
    ihdr.extend_from_slice(&width.to_be_bytes());
    ihdr.extend_from_slice(&height.to_be_bytes());
    ihdr.extend_from_slice(&[8, 0, 0, 0, 0]); // 8-bit grey, deflate, no interlace
    chunk(&mut out, b"IHDR", &ihdr);
    chunk(
        &mut out,
        b"IDAT",
        &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01],
    );
    chunk(&mut out, b"IEND", &[]);
    out
}

fn crc32(data: &[u8]) -> u32 {
    let mut crc = 0xFFFF_FFFFu32;
    for &b in data {
        crc ^= b as u32;
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

#[test]
fn empty_file() {
    let e = decode(&[], &DecodeLimits::default()).unwrap_err();
    assert!(matches!(e, ImageInputError::Empty), "{e}");
    assert_eq!(e.code(), "empty_image");
}

#[test]
fn not_an_image() {
    let e = decode(b"hello, this is text", &DecodeLimits::default()).unwrap_err();
    assert!(matches!(e, ImageInputError::UnknownFormat), "{e}");
}

#[test]
fn truncated_png() {
    let bytes = png_bytes(64, 64);
    for cut in [bytes.len() / 2, 40, 20] {
        let e = decode(&bytes[..cut], &DecodeLimits::default()).unwrap_err();
        assert!(
            matches!(e, ImageInputError::Corrupt { format: "PNG", .. }),
            "cut at {cut}: {e}"
        );
        assert!(e.to_string().contains("PNG"), "{e}");
    }
}

#[test]
fn png_declaring_100000_squared_pixels() {
    let bytes = png_declaring(100_000, 100_000);
    assert!(bytes.len() < 100, "the header alone is tiny");
    let e = decode(&bytes, &DecodeLimits::default()).unwrap_err();
    match e {
        ImageInputError::TooLarge {
            width,
            height,
            max_width,
            ..
        } => {
            assert_eq!((width, height), (100_000, 100_000));
            assert_eq!(max_width, DecodeLimits::default().max_width);
        }
        other => panic!("expected TooLarge, got {other}"),
    }
}

#[test]
fn memory_limit_is_enforced_within_size_limits() {
    // 4000 x 4000 is within the size limits below, but 16 MB exceeds 1 MB.
    let limits = DecodeLimits {
        max_width: 8192,
        max_height: 8192,
        max_alloc_bytes: 1 << 20,
    };
    let e = decode(&png_declaring(4000, 4000), &limits).unwrap_err();
    assert!(matches!(e, ImageInputError::MemoryLimit { .. }), "{e}");
}

#[test]
fn one_by_one_image() {
    let e = decode(&png_bytes(1, 1), &DecodeLimits::default()).unwrap_err();
    assert!(
        matches!(
            e,
            ImageInputError::TooSmall {
                width: 1,
                height: 1,
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("expected at least"), "{e}");
    let e = decode_raw(&[0], 1, 1, 8, &DecodeLimits::default()).unwrap_err();
    assert!(matches!(e, ImageInputError::TooSmall { .. }), "{e}");
}

#[test]
fn mismatched_pair_sizes() {
    let left = decode(&png_bytes(64, 48), &DecodeLimits::default()).unwrap();
    let right = decode(&png_bytes(64, 50), &DecodeLimits::default()).unwrap();
    let e = check_pair(&left, &right).unwrap_err();
    assert!(matches!(e, ImageInputError::PairSizeMismatch { .. }), "{e}");
    assert_eq!(
        e.to_string(),
        "left image is 64x48 but right image is 64x50 (expected equal sizes)"
    );
    assert!(check_pair(&left, &left.clone()).is_ok());
}

#[test]
fn raw_buffer_of_wrong_length() {
    let e = decode_raw(&[0; 100], 16, 16, 16, &DecodeLimits::default()).unwrap_err();
    assert_eq!(
        e.to_string(),
        "raw buffer has 100 bytes, expected 512 for 16x16 at 16 bits"
    );
}

#[test]
fn sixteen_bit_png_round_trip_through_save() {
    let dir = tempfile::tempdir().unwrap();
    let frame = GrayFrame::new(16, 16, 16, (0..256u32).map(|v| (v * 250) as u16).collect()).unwrap();
    for name in ["f.png", "f.tif"] {
        let path = dir.path().join(name);
        frame.save(&path).unwrap();
        let back = semdepth_core::imageio::read_file(&path, &DecodeLimits::default()).unwrap();
        assert_eq!(back, frame, "{name}");
    }
}

//! Image input: decode PNG, TIFF, JPEG, BMP and raw little-endian buffers into
//! grey-level frames, with size limits, and write frames back out.
//!
//! Every frame is stored as `u16` samples together with its bit depth (8 or
//! 16), so 16-bit SEM detectors keep their precision while 8-bit images cost
//! nothing extra to interpret. Colour input is converted to luma (Rec. 709
//! weights, as the `image` crate does).

use std::io::Cursor;
use std::path::Path;

use image::{DynamicImage, ImageDecoder, ImageFormat, ImageReader};

/// A grey-level image: row-major samples, `width * height` of them.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GrayFrame {
    /// Columns (x runs 0..width, to the right).
    pub width: u32,
    /// Rows (y runs 0..height, downwards).
    pub height: u32,
    /// 8 or 16: the range of the samples is 0..=2^bit_depth - 1.
    pub bit_depth: u8,
    /// Row-major samples; index `y * width + x`.
    pub data: Vec<u16>,
}

/// Limits applied before and while decoding, so a hostile or broken file is
/// an error rather than a huge allocation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct DecodeLimits {
    /// Largest accepted width in pixels.
    pub max_width: u32,
    /// Largest accepted height in pixels.
    pub max_height: u32,
    /// Largest number of bytes the decoder may allocate for one image.
    pub max_alloc_bytes: u64,
}

impl Default for DecodeLimits {
    /// 8192 x 8192 pixels and 512 MiB: a 16-bit 8k frame still fits.
    fn default() -> Self {
        Self {
            max_width: 8192,
            max_height: 8192,
            max_alloc_bytes: 512 * 1024 * 1024,
        }
    }
}

/// Smallest side accepted: the initialisation and the tracker need room for
/// an object and some background around it.
pub const MIN_SIDE: u32 = 8;

/// Why an image could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ImageInputError {
    /// Zero bytes were given.
    #[error("empty image data (expected a PNG, TIFF, JPEG or BMP file)")]
    Empty,
    /// The bytes are not one of the supported formats.
    #[error("unrecognised image format (expected PNG, TIFF, JPEG or BMP)")]
    UnknownFormat,
    /// The header declares a size beyond the configured limits.
    #[error("image of {width}x{height} exceeds the limit of {max_width}x{max_height} pixels")]
    TooLarge {
        width: u32,
        height: u32,
        max_width: u32,
        max_height: u32,
    },
    /// Decoding would allocate more than the configured limit.
    #[error("decoding needs more than the limit of {max_alloc_bytes} bytes")]
    MemoryLimit { max_alloc_bytes: u64 },
    /// The image is too small to hold an object.
    #[error("image of {width}x{height} is too small (expected at least {min}x{min} pixels)")]
    TooSmall { width: u32, height: u32, min: u32 },
    /// The image is too thin to find an object in: its working copy
    /// (reduced so that its longer side is at most `working_max_side`) is
    /// under `min` pixels on a side.
    #[error("image of {width}x{height} is too thin: reduced to at most {working_max_side} px on its longer side it is {working_width}x{working_height} (expected at least {min}x{min} after the reduction: a shorter side of at least 1/{ratio} of the longer, or a larger init.working_max_side)", ratio = working_max_side / min)]
    TooThin {
        width: u32,
        height: u32,
        working_width: u32,
        working_height: u32,
        working_max_side: u32,
        min: u32,
    },
    /// The file is cut short or corrupt.
    #[error("corrupt or truncated {format} data: {detail}")]
    Corrupt { format: &'static str, detail: String },
    /// Only 8- and 16-bit samples are supported.
    #[error("unsupported bit depth {0} (expected 8 or 16)")]
    BitDepth(u32),
    /// A raw buffer's length does not match its declared size.
    #[error("raw buffer has {actual} bytes, expected {expected} for {width}x{height} at {bit_depth} bits")]
    RawLength {
        actual: usize,
        expected: usize,
        width: u32,
        height: u32,
        bit_depth: u8,
    },
    /// Left and right images of a pair differ in size.
    #[error("left image is {left_width}x{left_height} but right image is {right_width}x{right_height} (expected equal sizes)")]
    PairSizeMismatch {
        left_width: u32,
        left_height: u32,
        right_width: u32,
        right_height: u32,
    },
    /// Reading or writing a file failed.
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    /// Encoding an output file failed.
    #[error("could not encode image: {0}")]
    Encode(String),
}

impl ImageInputError {
    /// A stable snake_case code for APIs and logs.
    pub fn code(&self) -> &'static str {
        match self {
            Self::Empty => "empty_image",
            Self::UnknownFormat => "unknown_image_format",
            Self::TooLarge { .. } => "image_too_large",
            Self::MemoryLimit { .. } => "image_memory_limit",
            Self::TooSmall { .. } | Self::TooThin { .. } => "image_too_small",
            Self::Corrupt { .. } => "corrupt_image",
            Self::BitDepth(_) => "unsupported_bit_depth",
            Self::RawLength { .. } => "raw_length_mismatch",
            Self::PairSizeMismatch { .. } => "pair_size_mismatch",
            Self::Io { .. } => "io_error",
            Self::Encode(_) => "encode_error",
        }
    }
}

impl GrayFrame {
    /// A frame from samples; checks the length, the bit depth and the
    /// minimum size, and that no sample exceeds the bit depth's range.
    pub fn new(width: u32, height: u32, bit_depth: u8, data: Vec<u16>) -> Result<Self, ImageInputError> {
        if bit_depth != 8 && bit_depth != 16 {
            return Err(ImageInputError::BitDepth(bit_depth as u32));
        }
        let expected = width as usize * height as usize;
        if data.len() != expected {
            return Err(ImageInputError::RawLength {
                actual: data.len() * if bit_depth == 8 { 1 } else { 2 },
                expected: expected * if bit_depth == 8 { 1 } else { 2 },
                width,
                height,
                bit_depth,
            });
        }
        check_min_size(width, height)?;
        let frame = Self {
            width,
            height,
            bit_depth,
            data,
        };
        if bit_depth == 8 && frame.data.iter().any(|&v| v > 255) {
            return Err(ImageInputError::Corrupt {
                format: "raw",
                detail: "8-bit frame holds a sample above 255".into(),
            });
        }
        Ok(frame)
    }

    /// A frame of constant value (useful for tests and synthesis).
    pub fn filled(width: u32, height: u32, bit_depth: u8, value: u16) -> Self {
        Self {
            width,
            height,
            bit_depth,
            data: vec![value; width as usize * height as usize],
        }
    }

    /// This frame with its grey levels changed to `gain * v + offset`,
    /// rounded and clipped to the range: what a microscope's automatic
    /// brightness and contrast do between frames (useful for tests).
    pub fn regraded(&self, gain: f64, offset: f64) -> Self {
        self.toned(|v| gain * v + offset)
    }

    /// This frame with each grey level `v` changed to `curve(v)`, rounded
    /// and clipped to the range: a change of the tone curve (useful for
    /// tests).
    pub fn toned(&self, curve: impl Fn(f64) -> f64) -> Self {
        let max = f64::from(self.max_value());
        let data = self
            .data
            .iter()
            .map(|&v| curve(f64::from(v)).round().clamp(0.0, max) as u16)
            .collect();
        Self { data, ..*self }
    }

    /// Largest representable sample: 255 or 65535.
    pub fn max_value(&self) -> u16 {
        if self.bit_depth == 8 {
            255
        } else {
            u16::MAX
        }
    }

    /// The sample at column `x`, row `y` (panics out of range, like slices).
    #[inline]
    pub fn get(&self, x: u32, y: u32) -> u16 {
        self.data[y as usize * self.width as usize + x as usize]
    }

    /// One row of samples.
    #[inline]
    pub fn row(&self, y: u32) -> &[u16] {
        let w = self.width as usize;
        &self.data[y as usize * w..(y as usize + 1) * w]
    }

    /// An 8-bit copy (16-bit samples are scaled by 255/65535, rounded).
    pub fn to_gray8(&self) -> image::GrayImage {
        let data: Vec<u8> = if self.bit_depth == 8 {
            self.data.iter().map(|&v| v as u8).collect()
        } else {
            self.data
                .iter()
                .map(|&v| ((v as u32 * 255 + 32767) / 65535) as u8)
                .collect()
        };
        image::GrayImage::from_raw(self.width, self.height, data).expect("length matches size")
    }

    /// Samples scaled to 0.0..=1.0.
    pub fn to_unit_f32(&self) -> Vec<f32> {
        let scale = 1.0 / self.max_value() as f32;
        self.data.iter().map(|&v| v as f32 * scale).collect()
    }

    /// Writes an 8-bit PNG or 16-bit TIFF, chosen by the frame's bit depth
    /// unless the extension asks for something else (`.png`, `.tif`, `.tiff`,
    /// `.bmp`, `.jpg`). PNG and TIFF keep 16 bits; BMP and JPEG are 8-bit.
    pub fn save(&self, path: &Path) -> Result<(), ImageInputError> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase())
            .unwrap_or_default();
        let keep16 = self.bit_depth == 16 && matches!(ext.as_str(), "png" | "tif" | "tiff");
        let image = if keep16 {
            DynamicImage::ImageLuma16(
                image::ImageBuffer::from_raw(self.width, self.height, self.data.clone())
                    .expect("length matches size"),
            )
        } else {
            DynamicImage::ImageLuma8(self.to_gray8())
        };
        image.save(path).map_err(|e| match e {
            image::ImageError::IoError(source) => ImageInputError::Io {
                path: path.display().to_string(),
                source,
            },
            other => ImageInputError::Encode(other.to_string()),
        })
    }
}

/// Decodes an encoded image (PNG, TIFF, JPEG, BMP; format sniffed from the
/// bytes) into a grey-level frame, within `limits`.
pub fn decode(bytes: &[u8], limits: &DecodeLimits) -> Result<GrayFrame, ImageInputError> {
    if bytes.is_empty() {
        return Err(ImageInputError::Empty);
    }
    let format = image::guess_format(bytes).map_err(|_| ImageInputError::UnknownFormat)?;
    let format_name = match format {
        ImageFormat::Png => "PNG",
        ImageFormat::Tiff => "TIFF",
        ImageFormat::Jpeg => "JPEG",
        ImageFormat::Bmp => "BMP",
        _ => return Err(ImageInputError::UnknownFormat),
    };
    // Read the header first, so a declared size beyond the limits is
    // reported with its numbers before any decoder state is set up.
    let (width, height) = ImageReader::with_format(Cursor::new(bytes), format)
        .into_dimensions()
        .map_err(|e| map_decode_error(e, format_name, limits))?;
    if width > limits.max_width || height > limits.max_height {
        return Err(ImageInputError::TooLarge {
            width,
            height,
            max_width: limits.max_width,
            max_height: limits.max_height,
        });
    }
    check_min_size(width, height)?;
    let mut reader = ImageReader::with_format(Cursor::new(bytes), format);
    let mut image_limits = image::Limits::default();
    image_limits.max_image_width = Some(limits.max_width);
    image_limits.max_image_height = Some(limits.max_height);
    image_limits.max_alloc = Some(limits.max_alloc_bytes);
    reader.limits(image_limits);
    let decoder = reader
        .into_decoder()
        .map_err(|e| map_decode_error(e, format_name, limits))?;
    // Not every decoder checks `max_alloc` against the output buffer, so
    // check it here: colour images need their decoded size plus the grey copy.
    if decoder.total_bytes() > limits.max_alloc_bytes {
        return Err(ImageInputError::MemoryLimit {
            max_alloc_bytes: limits.max_alloc_bytes,
        });
    }
    let image = DynamicImage::from_decoder(decoder).map_err(|e| map_decode_error(e, format_name, limits))?;
    Ok(from_dynamic(image))
}

/// Mean of `value` over the pixel box centred on (`x`, `y`), sampled 4x4:
/// an anti-aliased rendering of a scene for tests.
#[cfg(test)]
pub(crate) fn pixel_mean(x: f64, y: f64, value: impl Fn(f64, f64) -> f64) -> f64 {
    let at = |k: u32| -0.375 + f64::from(k) * 0.25;
    (0..16).map(|k| value(x + at(k % 4), y + at(k / 4))).sum::<f64>() / 16.0
}

/// Reads and decodes an image file (see [`decode`]).
pub fn read_file(path: &Path, limits: &DecodeLimits) -> Result<GrayFrame, ImageInputError> {
    decode(&read_bytes(path)?, limits)
}

/// The bytes of a file, with an I/O error that names it.
pub fn read_bytes(path: &Path) -> Result<Vec<u8>, ImageInputError> {
    std::fs::read(path).map_err(|source| ImageInputError::Io {
        path: path.display().to_string(),
        source,
    })
}

/// Interprets a raw little-endian, row-major buffer of 8- or 16-bit samples.
pub fn decode_raw(
    bytes: &[u8],
    width: u32,
    height: u32,
    bit_depth: u8,
    limits: &DecodeLimits,
) -> Result<GrayFrame, ImageInputError> {
    if bit_depth != 8 && bit_depth != 16 {
        return Err(ImageInputError::BitDepth(bit_depth as u32));
    }
    if width > limits.max_width || height > limits.max_height {
        return Err(ImageInputError::TooLarge {
            width,
            height,
            max_width: limits.max_width,
            max_height: limits.max_height,
        });
    }
    check_min_size(width, height)?;
    let bytes_per_sample = (bit_depth / 8) as usize;
    let expected = width as usize * height as usize * bytes_per_sample;
    if bytes.len() != expected {
        return Err(ImageInputError::RawLength {
            actual: bytes.len(),
            expected,
            width,
            height,
            bit_depth,
        });
    }
    let data = if bit_depth == 8 {
        bytes.iter().map(|&b| b as u16).collect()
    } else {
        bytes
            .chunks_exact(2)
            .map(|c| u16::from_le_bytes([c[0], c[1]]))
            .collect()
    };
    Ok(GrayFrame {
        width,
        height,
        bit_depth,
        data,
    })
}

/// Checks that the two images of a stereo pair have the same size.
pub fn check_pair(left: &GrayFrame, right: &GrayFrame) -> Result<(), ImageInputError> {
    if left.width != right.width || left.height != right.height {
        return Err(ImageInputError::PairSizeMismatch {
            left_width: left.width,
            left_height: left.height,
            right_width: right.width,
            right_height: right.height,
        });
    }
    Ok(())
}

fn check_min_size(width: u32, height: u32) -> Result<(), ImageInputError> {
    if width < MIN_SIDE || height < MIN_SIDE {
        return Err(ImageInputError::TooSmall {
            width,
            height,
            min: MIN_SIDE,
        });
    }
    Ok(())
}

fn from_dynamic(image: DynamicImage) -> GrayFrame {
    let (width, height) = (image.width(), image.height());
    match image {
        DynamicImage::ImageLuma8(buf) => GrayFrame {
            width,
            height,
            bit_depth: 8,
            data: buf.into_raw().into_iter().map(u16::from).collect(),
        },
        DynamicImage::ImageLuma16(buf) => GrayFrame {
            width,
            height,
            bit_depth: 16,
            data: buf.into_raw(),
        },
        // 16-bit colour, and 32-bit float, keep 16 bits of luma.
        other @ (DynamicImage::ImageRgb16(_)
        | DynamicImage::ImageRgba16(_)
        | DynamicImage::ImageLumaA16(_)
        | DynamicImage::ImageRgb32F(_)
        | DynamicImage::ImageRgba32F(_)) => GrayFrame {
            width,
            height,
            bit_depth: 16,
            data: other.into_luma16().into_raw(),
        },
        other => GrayFrame {
            width,
            height,
            bit_depth: 8,
            data: other.into_luma8().into_raw().into_iter().map(u16::from).collect(),
        },
    }
}

fn map_decode_error(
    error: image::ImageError,
    format: &'static str,
    limits: &DecodeLimits,
) -> ImageInputError {
    use image::error::{ImageError as E, LimitErrorKind};
    match error {
        E::Limits(l) => match l.kind() {
            LimitErrorKind::InsufficientMemory => ImageInputError::MemoryLimit {
                max_alloc_bytes: limits.max_alloc_bytes,
            },
            LimitErrorKind::DimensionError => ImageInputError::Corrupt {
                format,
                detail: "image dimensions exceed the configured limits".into(),
            },
            _ => ImageInputError::MemoryLimit {
                max_alloc_bytes: limits.max_alloc_bytes,
            },
        },
        E::Unsupported(u) => ImageInputError::Corrupt {
            format,
            detail: format!("unsupported variant: {u}"),
        },
        E::IoError(e) => ImageInputError::Corrupt {
            format,
            detail: format!("unexpected end of data or read error: {e}"),
        },
        other => ImageInputError::Corrupt {
            format,
            detail: other.to_string(),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn encode(image: DynamicImage, format: ImageFormat) -> Vec<u8> {
        let mut out = Cursor::new(Vec::new());
        image.write_to(&mut out, format).unwrap();
        out.into_inner()
    }

    fn ramp8(w: u32, h: u32) -> image::GrayImage {
        image::GrayImage::from_fn(w, h, |x, y| image::Luma([((x * 7 + y * 3) % 256) as u8]))
    }

    #[test]
    fn png_8bit_roundtrip() {
        let img = ramp8(32, 20);
        let bytes = encode(DynamicImage::ImageLuma8(img.clone()), ImageFormat::Png);
        let frame = decode(&bytes, &DecodeLimits::default()).unwrap();
        assert_eq!((frame.width, frame.height, frame.bit_depth), (32, 20, 8));
        assert_eq!(frame.get(5, 3), img.get_pixel(5, 3)[0] as u16);
        assert_eq!(frame.to_gray8(), img);
    }

    #[test]
    fn tiff_16bit_keeps_precision() {
        let img = image::ImageBuffer::<image::Luma<u16>, _>::from_fn(16, 16, |x, y| {
            image::Luma([(x * 4000 + y * 3 + 1) as u16])
        });
        let bytes = encode(DynamicImage::ImageLuma16(img.clone()), ImageFormat::Tiff);
        let frame = decode(&bytes, &DecodeLimits::default()).unwrap();
        assert_eq!(frame.bit_depth, 16);
        assert_eq!(frame.get(3, 7), img.get_pixel(3, 7)[0]);
        assert_eq!(frame.get(15, 0), 60001);
    }

    #[test]
    fn colour_becomes_luma() {
        let img = image::RgbImage::from_fn(10, 10, |_, _| image::Rgb([255, 0, 0]));
        let bytes = encode(DynamicImage::ImageRgb8(img), ImageFormat::Bmp);
        let frame = decode(&bytes, &DecodeLimits::default()).unwrap();
        assert_eq!(frame.bit_depth, 8);
        // Rec. 709 luma of pure red is about 0.2126 * 255 = 54.
        assert!((frame.get(0, 0) as i32 - 54).abs() <= 1, "{}", frame.get(0, 0));
    }

    #[test]
    fn jpeg_decodes() {
        let bytes = encode(DynamicImage::ImageLuma8(ramp8(24, 24)), ImageFormat::Jpeg);
        let frame = decode(&bytes, &DecodeLimits::default()).unwrap();
        assert_eq!((frame.width, frame.height), (24, 24));
    }

    #[test]
    fn raw_8_and_16() {
        let limits = DecodeLimits::default();
        let f = decode_raw(&[1u8; 64], 8, 8, 8, &limits).unwrap();
        assert_eq!(f.get(7, 7), 1);
        let mut bytes = vec![0u8; 128];
        bytes[2] = 0x34;
        bytes[3] = 0x12;
        let f = decode_raw(&bytes, 8, 8, 16, &limits).unwrap();
        assert_eq!(f.get(1, 0), 0x1234);
        assert!(matches!(
            decode_raw(&bytes, 8, 8, 8, &limits),
            Err(ImageInputError::RawLength {
                actual: 128,
                expected: 64,
                ..
            })
        ));
        assert!(matches!(
            decode_raw(&bytes, 8, 8, 12, &limits),
            Err(ImageInputError::BitDepth(12))
        ));
    }

    #[test]
    fn limits_apply_to_raw() {
        let limits = DecodeLimits {
            max_width: 16,
            max_height: 16,
            max_alloc_bytes: 1 << 20,
        };
        assert!(matches!(
            decode_raw(&vec![0u8; 32 * 8], 32, 8, 8, &limits),
            Err(ImageInputError::TooLarge { width: 32, .. })
        ));
    }
}

//! One stereo pair from the bytes of its two images: both decoded and
//! their microscope metadata read. The command line (`process`) and the
//! service take this one path from bytes to a measurement
//! ([`crate::session::Session::measure_pair`]).

use crate::imageio::{decode, decode_raw, DecodeLimits, GrayFrame, ImageInputError};
use crate::meta::{read_meta, ImageMeta};

/// Which image of a pair.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    /// The first view.
    Left,
    /// The second view (tilted).
    Right,
}

impl Side {
    /// `left` or `right`.
    pub fn name(self) -> &'static str {
        match self {
            Side::Left => "left",
            Side::Right => "right",
        }
    }
}

/// An image of a pair that could not be decoded, and why.
#[derive(Debug)]
pub struct PairError {
    /// Which image.
    pub side: Side,
    /// Why.
    pub error: ImageInputError,
}

/// The error of an image of this side.
fn side(side: Side) -> impl Fn(ImageInputError) -> PairError {
    move |error| PairError { side, error }
}

/// A decoded stereo pair.
#[derive(Clone, Debug)]
pub struct DecodedPair {
    /// The left image.
    pub left: GrayFrame,
    /// The right image.
    pub right: GrayFrame,
    /// What the two files' metadata say (None for raw samples, which carry
    /// none).
    pub meta: Option<(ImageMeta, ImageMeta)>,
}

impl DecodedPair {
    /// Decodes two image files (PNG, TIFF, JPEG, BMP) and reads their
    /// metadata. CPU-heavy.
    pub fn from_files(left: &[u8], right: &[u8], limits: &DecodeLimits) -> Result<Self, PairError> {
        Ok(Self {
            left: decode(left, limits).map_err(side(Side::Left))?,
            right: decode(right, limits).map_err(side(Side::Right))?,
            meta: Some((read_meta(left), read_meta(right))),
        })
    }

    /// Interprets two raw little-endian, row-major buffers of `bit_depth`
    /// (8 or 16) samples of `width` x `height`.
    pub fn from_raw(
        [left, right]: [&[u8]; 2],
        width: u32,
        height: u32,
        bit_depth: u8,
        limits: &DecodeLimits,
    ) -> Result<Self, PairError> {
        Ok(Self {
            left: decode_raw(left, width, height, bit_depth, limits).map_err(side(Side::Left))?,
            right: decode_raw(right, width, height, bit_depth, limits).map_err(side(Side::Right))?,
            meta: None,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bad_image_is_named_by_its_side() {
        let limits = DecodeLimits::default();
        let good = [7u8; 16 * 16];
        let e = DecodedPair::from_raw([&good, &good[..10]], 16, 16, 8, &limits).unwrap_err();
        assert_eq!(e.side, Side::Right);
        let e = DecodedPair::from_files(b"not an image", b"", &limits).unwrap_err();
        assert_eq!(e.side, Side::Left);
        let pair = DecodedPair::from_raw([&good, &good], 16, 16, 8, &limits).unwrap();
        assert!(pair.meta.is_none() && pair.left.width == 16);
    }
}

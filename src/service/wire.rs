//! SDP1, the WebSocket message of one stereo pair, parsed and encoded in
//! one place for the server, the CLI's demo, the tests and the benches.
//!
//! A message is `b"SDP1"`, a u32 little-endian header length, a UTF-8 JSON
//! [`PairHeader`], the left image's bytes, the right image's bytes
//! (`left_len` and `right_len` of the header). Images are encoded files
//! (PNG, TIFF, ...) or raw little-endian row-major samples.

use axum::body::Bytes;
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use super::api::model::Provenance;
use super::error::ApiError;
use super::pipeline::PairInput;

/// Magic bytes opening every pair message.
pub const MAGIC: &[u8; 4] = b"SDP1";

/// Largest JSON header accepted, bytes.
pub const MAX_HEADER_BYTES: usize = 64 * 1024;

/// Encoding of the images in a pair message.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Encoding {
    /// Little-endian row-major samples; width, height and bit_depth required.
    Raw,
    /// PNG files.
    Png,
    /// TIFF files.
    Tiff,
    /// JPEG files (accepted like any encoded format).
    Jpeg,
    /// BMP files.
    Bmp,
}

/// The JSON header of a pair message.
#[derive(Clone, Debug, Deserialize, Serialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct PairHeader {
    /// The client's sequence number, echoed in the reply.
    pub seq: u64,
    /// How the images are encoded.
    pub encoding: Encoding,
    /// Raw only: width in pixels.
    #[serde(default)]
    pub width: Option<u32>,
    /// Raw only: height in pixels.
    #[serde(default)]
    pub height: Option<u32>,
    /// Raw only: 8 or 16.
    #[serde(default)]
    pub bit_depth: Option<u8>,
    /// Length of the left image in bytes.
    pub left_len: u64,
    /// Length of the right image in bytes.
    pub right_len: u64,
    /// The client's name for the pair (at most 200 characters), echoed in
    /// the result and its CSV row.
    #[serde(default)]
    pub label: Option<String>,
    /// The client's time of acquisition, RFC 3339, echoed in the result.
    #[serde(default)]
    pub timestamp: Option<String>,
}

/// Builds a pair message: [`MAGIC`], the header's length (u32 little
/// endian), the JSON header, then the left and right bytes. The header is a
/// JSON value, not a [`PairHeader`], so that callers (and tests) can send any
/// header, valid or not.
pub fn encode_pair_message(header: &serde_json::Value, left: &[u8], right: &[u8]) -> Vec<u8> {
    let header = header.to_string().into_bytes();
    let mut m = Vec::with_capacity(8 + header.len() + left.len() + right.len());
    m.extend_from_slice(MAGIC);
    m.extend_from_slice(&(header.len() as u32).to_le_bytes());
    m.extend_from_slice(&header);
    m.extend_from_slice(left);
    m.extend_from_slice(right);
    m
}

/// One parsed pair message.
#[derive(Debug)]
pub struct PairMessage {
    /// Client sequence number.
    pub seq: u64,
    /// The images.
    pub input: PairInput,
    /// The header's label and timestamp, and when the message arrived.
    pub provenance: Provenance,
}

/// Parses a pair message; on failure returns the seq if the header was
/// readable, and the error.
pub fn parse_pair_message(bytes: &Bytes) -> Result<PairMessage, (Option<u64>, ApiError)> {
    let bad = |seq, code: &'static str, message: String| (seq, ApiError::bad_request(code, message));
    if bytes.len() < 8 || &bytes[..4] != MAGIC {
        return Err(bad(
            None,
            "bad_magic",
            "message does not start with b\"SDP1\" and a header length (expected SDP1 + u32 LE length + JSON header + left + right)".into(),
        ));
    }
    let header_len = u32::from_le_bytes([bytes[4], bytes[5], bytes[6], bytes[7]]) as usize;
    if header_len > MAX_HEADER_BYTES || 8 + header_len > bytes.len() {
        return Err(bad(
            None,
            "bad_header_length",
            format!(
                "header length {header_len} does not fit the {}-byte message (expected at most {MAX_HEADER_BYTES} and within the message)",
                bytes.len()
            ),
        ));
    }
    let header: PairHeader = serde_json::from_slice(&bytes[8..8 + header_len]).map_err(|e| {
        // Recover the seq for the reply if the JSON has one.
        let seq = serde_json::from_slice::<serde_json::Value>(&bytes[8..8 + header_len])
            .ok()
            .and_then(|v| v.get("seq").and_then(|s| s.as_u64()));
        bad(seq, "invalid_header", format!("pair header: {e}"))
    })?;
    let seq = Some(header.seq);
    let body = bytes.slice(8 + header_len..);
    let declared = header.left_len.checked_add(header.right_len);
    if declared != Some(body.len() as u64) {
        return Err(bad(
            seq,
            "length_mismatch",
            format!(
                "header declares left_len {} + right_len {} bytes but {} follow the header (expected them equal)",
                header.left_len,
                header.right_len,
                body.len()
            ),
        ));
    }
    let provenance = Provenance::received(header.label, header.timestamp).map_err(|e| (seq, e))?;
    let split = header.left_len as usize;
    let (left, right) = (body.slice(..split), body.slice(split..));
    let input = match header.encoding {
        Encoding::Raw => {
            let (Some(width), Some(height), Some(bit_depth)) =
                (header.width, header.height, header.bit_depth)
            else {
                return Err(bad(
                    seq,
                    "invalid_header",
                    "raw encoding needs width, height and bit_depth in the header".into(),
                ));
            };
            PairInput::Raw {
                left,
                right,
                width,
                height,
                bit_depth,
            }
        }
        _ => PairInput::Encoded { left, right },
    };
    Ok(PairMessage {
        seq: header.seq,
        input,
        provenance,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn message(header: &serde_json::Value, left: &[u8], right: &[u8]) -> Bytes {
        Bytes::from(encode_pair_message(header, left, right))
    }

    #[test]
    fn parses_raw_pair_and_splits_images() {
        let m = message(
            &serde_json::json!({"seq": 7, "encoding": "raw", "width": 2, "height": 1, "bit_depth": 8, "left_len": 2, "right_len": 2}),
            &[1, 2],
            &[3, 4],
        );
        let p = parse_pair_message(&m).unwrap();
        assert_eq!(p.seq, 7);
        match p.input {
            PairInput::Raw {
                left,
                right,
                width,
                height,
                bit_depth,
            } => {
                assert_eq!((&left[..], &right[..]), (&[1u8, 2][..], &[3u8, 4][..]));
                assert_eq!((width, height, bit_depth), (2, 1, 8));
            }
            other => panic!("expected raw, got {other:?}"),
        }
    }

    #[test]
    fn malformed_messages_name_the_problem_and_keep_the_seq() {
        let e = parse_pair_message(&Bytes::from_static(b"nope")).unwrap_err();
        assert_eq!((e.0, e.1.code()), (None, "bad_magic"));

        let m = message(
            &serde_json::json!({"seq": 3, "encoding": "png", "left_len": 5, "right_len": 5}),
            &[0; 5],
            &[0; 4],
        );
        let e = parse_pair_message(&m).unwrap_err();
        assert_eq!((e.0, e.1.code()), (Some(3), "length_mismatch"));

        let m = message(
            &serde_json::json!({"seq": 4, "encoding": "raw", "left_len": 1, "right_len": 1}),
            &[0],
            &[0],
        );
        let e = parse_pair_message(&m).unwrap_err();
        assert_eq!((e.0, e.1.code()), (Some(4), "invalid_header"));

        let m = message(
            &serde_json::json!({"seq": 5, "encoding": "png", "left_len": 1, "right_len": 1, "colour": true}),
            &[0],
            &[0],
        );
        let e = parse_pair_message(&m).unwrap_err();
        assert_eq!((e.0, e.1.code()), (Some(5), "invalid_header"));
        assert!(e.1.parts().1.contains("colour"), "{}", e.1.parts().1);

        let mut bytes = MAGIC.to_vec();
        bytes.extend_from_slice(&u32::MAX.to_le_bytes());
        let e = parse_pair_message(&Bytes::from(bytes)).unwrap_err();
        assert_eq!(e.1.code(), "bad_header_length");
    }
}

//! Any bytes as one WebSocket pair message (`SDP1`, header length, JSON
//! header, left and right bytes): parsed, then both images decoded as the
//! service would; an error naming the problem, never a panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use semdepth_core::imageio::DecodeLimits;
use semdepth::service::ws::parse_pair_message;

fuzz_target!(|data: &[u8]| {
    let bytes = bytes::Bytes::copy_from_slice(data);
    if let Ok(message) = parse_pair_message(&bytes) {
        let limits = DecodeLimits {
            max_width: 2048,
            max_height: 2048,
            max_alloc_bytes: 64 << 20,
        };
        let _ = message.input.decode(&limits);
    }
});

//! Any bytes as an image file (PNG, TIFF, JPEG, BMP; format sniffed) under
//! the service's decode limits, and its microscope metadata: an error or a
//! frame within the limits, never a panic or an allocation beyond them.
#![no_main]

use libfuzzer_sys::fuzz_target;
use semdepth_core::imageio::{decode, DecodeLimits};

fuzz_target!(|data: &[u8]| {
    // Small limits keep each run fast; the checks are the same as the
    // defaults'.
    let limits = DecodeLimits {
        max_width: 2048,
        max_height: 2048,
        max_alloc_bytes: 64 << 20,
    };
    if let Ok(frame) = decode(data, &limits) {
        assert!(frame.width as usize * frame.height as usize == frame.data.len());
        assert!(frame.width <= limits.max_width && frame.height <= limits.max_height);
    }
    let _ = semdepth_core::meta::read_meta(data);
});

//! Issue #21: a corpus of mutated and crafted inputs kept as a test. Valid
//! seeds in every accepted form (PNG 8/16-bit, TIFF 8/16-bit, JPEG, BMP,
//! SDP1 stream messages with raw and PNG images) are mutated the ways
//! hostile or broken clients break files: bit flips, overwritten bytes,
//! patched integers (sizes, lengths, offsets), truncation, duplicated and
//! inserted runs. Every mutant is decoded (or parsed and decoded) as the
//! service would: the answer is a frame within the limits or an error,
//! never a panic. The same inputs seed the `cargo fuzz` targets in `fuzz/`;
//! an input a fuzzer finds is added to `fuzz/regressions/` and replayed here.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;

use axum::body::Bytes;
use semdepth::service::wire::parse_pair_message;
use semdepth_core::imageio::{decode, DecodeLimits};

use crate::fuzz_seeds::{image_seeds, message_seeds};

/// Mutants per seed.
const MUTANTS: usize = 300;

fn limits() -> DecodeLimits {
    DecodeLimits {
        max_width: 2048,
        max_height: 2048,
        max_alloc_bytes: 64 << 20,
    }
}

/// xorshift64*: deterministic mutations without a dependency.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// One mutant of `seed`: one to three of the mutations.
fn mutate(seed: &[u8], rng: &mut Rng) -> Vec<u8> {
    let mut m = seed.to_vec();
    for _ in 0..1 + rng.below(3) {
        if m.is_empty() {
            m.push(rng.next() as u8);
        }
        let at = rng.below(m.len());
        match rng.below(7) {
            0 => m[at] ^= 1 << rng.below(8),
            1 => m[at] = [0x00, 0xff, 0x7f, 0x80, 0x01][rng.below(5)],
            2 => {
                // A 4-byte integer, big or little endian, made huge, zero or
                // negative: image sizes, chunk and header lengths, offsets.
                let value: u32 = [0, 1, 0x7fff_ffff, 0xffff_ffff, 0x0001_0000, 65_535][rng.below(6)];
                let bytes = if rng.below(2) == 0 {
                    value.to_be_bytes()
                } else {
                    value.to_le_bytes()
                };
                for (k, b) in bytes.iter().enumerate() {
                    if let Some(slot) = m.get_mut(at + k) {
                        *slot = *b;
                    }
                }
            }
            3 => m.truncate(at),
            4 => {
                let len = rng.below(64).min(m.len() - at);
                let run = m[at..at + len].to_vec();
                m.splice(at..at, run);
            }
            5 => {
                let run: Vec<u8> = (0..1 + rng.below(16)).map(|_| rng.next() as u8).collect();
                m.splice(at..at, run);
            }
            _ => {
                let len = rng.below(32).min(m.len() - at);
                m.drain(at..at + len);
            }
        }
    }
    m
}

/// Decodes one image as the service would; panics become errors naming
/// the input.
fn check_image(name: &str, bytes: &[u8]) -> Result<bool, String> {
    let limits = limits();
    catch_unwind(AssertUnwindSafe(|| {
        let _ = semdepth_core::meta::read_meta(bytes);
        match decode(bytes, &limits) {
            Ok(frame) => {
                assert_eq!(frame.data.len(), frame.width as usize * frame.height as usize);
                assert!(frame.width <= limits.max_width && frame.height <= limits.max_height);
                true
            }
            Err(e) => {
                assert!(!e.to_string().is_empty());
                false
            }
        }
    }))
    .map_err(|_| format!("{name}: panicked"))
}

/// Parses one stream message and decodes its images as the service would.
fn check_message(name: &str, bytes: &[u8]) -> Result<bool, String> {
    let limits = limits();
    catch_unwind(AssertUnwindSafe(|| {
        match parse_pair_message(&Bytes::copy_from_slice(bytes)) {
            Ok(message) => message.input.decode(&limits).is_ok(),
            Err((_, e)) => {
                assert!(e.status().is_client_error(), "{e}");
                false
            }
        }
    }))
    .map_err(|_| format!("{name}: panicked"))
}

#[test]
fn mutated_images_and_messages_give_errors_not_panics() {
    // The decoders' own panics would print; the failures are listed below.
    let mut failures = Vec::new();
    let mut decoded = 0usize;
    let mut total = 0usize;
    let mut rng = Rng(0x5eed_d3b7_0000_0021);
    for (name, seed) in image_seeds() {
        assert_eq!(
            check_image(name, &seed),
            Ok(true),
            "{name}: the seed itself decodes"
        );
        for k in 0..MUTANTS {
            let mutant = mutate(&seed, &mut rng);
            total += 1;
            match check_image(&format!("{name} mutant {k}"), &mutant) {
                Ok(ok) => decoded += usize::from(ok),
                Err(e) => failures.push(e),
            }
        }
    }
    for (name, seed) in message_seeds() {
        assert_eq!(
            check_message(name, &seed),
            Ok(true),
            "{name}: the seed itself decodes"
        );
        for k in 0..MUTANTS {
            let mutant = mutate(&seed, &mut rng);
            total += 1;
            match check_message(&format!("{name} mutant {k}"), &mutant) {
                Ok(ok) => decoded += usize::from(ok),
                Err(e) => failures.push(e),
            }
        }
    }
    eprintln!("{total} mutants: {decoded} decoded, the rest refused with an error");
    assert!(failures.is_empty(), "{failures:#?}");
    // The mutations must reach the decoders, not only their first check.
    assert!(decoded > total / 20, "only {decoded} of {total} mutants decoded");
}

/// Inputs a fuzzer once found (`fuzz/regressions/{decode,sdp1}/`), replayed.
#[test]
fn fuzzer_findings_stay_fixed() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/regressions");
    for (target, check) in [
        ("decode", check_image as fn(&str, &[u8]) -> Result<bool, String>),
        ("sdp1", check_message),
    ] {
        let Ok(entries) = std::fs::read_dir(root.join(target)) else {
            continue;
        };
        for entry in entries {
            let path = entry.unwrap().path();
            let bytes = std::fs::read(&path).unwrap();
            check(&path.display().to_string(), &bytes).unwrap();
        }
    }
}

//! Writes the seed inputs of the fuzz targets: images to
//! `fuzz/corpus/decode/`, SDP1 messages to `fuzz/corpus/sdp1/` (or under
//! the directory given).
//!
//! `cargo run --example fuzz_seeds [DIR]`

#[path = "../tests/common/fuzz_seeds.rs"]
mod fuzz_seeds;

fn main() -> std::io::Result<()> {
    let root = std::path::PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "fuzz/corpus".into()));
    for (target, seeds) in [
        ("decode", fuzz_seeds::image_seeds()),
        ("sdp1", fuzz_seeds::message_seeds()),
    ] {
        let dir = root.join(target);
        std::fs::create_dir_all(&dir)?;
        for (name, bytes) in seeds {
            std::fs::write(dir.join(format!("seed-{name}")), bytes)?;
        }
        println!("{}", dir.display());
    }
    Ok(())
}

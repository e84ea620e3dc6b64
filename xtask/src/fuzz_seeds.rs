//! `cargo xtask fuzz-seeds`: writes the seed inputs of the fuzz targets
//! (`fuzz/`): images to `DIR/decode/`, SDP1 messages to `DIR/sdp1/`.

#[path = "../../tests/common/fuzz_seeds.rs"]
mod seeds;

/// Where.
#[derive(clap::Args)]
pub struct Args {
    /// Corpus root.
    #[arg(default_value = "fuzz/corpus")]
    dir: std::path::PathBuf,
}

pub fn run(args: Args) -> crate::Result {
    for (target, seeds) in [("decode", seeds::image_seeds()), ("sdp1", seeds::message_seeds())] {
        let dir = args.dir.join(target);
        std::fs::create_dir_all(&dir)?;
        for (name, bytes) in seeds {
            std::fs::write(dir.join(format!("seed-{name}")), bytes)?;
        }
        println!("{}", dir.display());
    }
    Ok(())
}

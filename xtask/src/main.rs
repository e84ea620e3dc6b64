//! semdepth's developer tools, one subcommand each: `cargo xtask --help`.
//!
//! The evaluations track scenes with a known truth and print the figures
//! that docs/ and BENCHMARKS.md quote; every number they print comes
//! from the library as a user would call it.
//! - `track-eval`: the generator's scene classes (`semdepth_core::synth`),
//!   disparity and centroid errors against its truth.
//! - `tilted-eval`: scenes of an independent renderer (three-dimensional
//!   bodies seen from two beam tilts, `crates/core/tests/accuracy/tilted.rs`).
//! - `init-eval`: the first outline's IoU with the truth, with and without
//!   hints.
//! - `edge-bound`: the Cramér-Rao bound on a blurred edge's placement
//!   beside the first outline.
//! - `track-one`: one synthetic sequence, pair by pair.
//! - `gallery`: the first left image of every hard scene class, as PNG.
//! - `step-profile`: one tracking step repeated, median and minimum time.
//! - `fuzz-seeds`: the seed inputs of the fuzz targets in `fuzz/`.

use clap::{Parser, Subcommand};

mod edge_bound;
mod fuzz_seeds;
mod gallery;
mod init_eval;
mod step_profile;
mod tilted_eval;
mod track_eval;
mod track_one;

#[derive(Parser)]
#[command(name = "cargo xtask", about = "semdepth's developer tools")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Track the generator's sequences and print disparity and centroid errors per condition.
    TrackEval(track_eval::Args),
    /// Track the independent renderer's scenes and print IoU and tracking figures per class.
    TiltedEval(tilted_eval::Args),
    /// Initialise on every scene class and print the first outline's IoU with the truth.
    InitEval(init_eval::Args),
    /// Print the Cramér-Rao bound on a blurred outline's shift beside the first contour.
    EdgeBound(edge_bound::Args),
    /// Track one synthetic sequence and print every pair's errors.
    TrackOne(track_one::Args),
    /// Write the first left image of every hard scene class as PNG.
    Gallery(gallery::Args),
    /// Repeat one tracking step and print its median and minimum time.
    StepProfile(step_profile::Args),
    /// Write the seed inputs of the fuzz targets.
    FuzzSeeds(fuzz_seeds::Args),
}

fn main() -> std::process::ExitCode {
    let result = match Cli::parse().command {
        Command::TrackEval(a) => track_eval::run(a),
        Command::TiltedEval(a) => tilted_eval::run(a),
        Command::InitEval(a) => init_eval::run(a),
        Command::EdgeBound(a) => edge_bound::run(a),
        Command::TrackOne(a) => track_one::run(a),
        Command::Gallery(a) => gallery::run(a),
        Command::StepProfile(a) => step_profile::run(a),
        Command::FuzzSeeds(a) => fuzz_seeds::run(a),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("xtask: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}

/// What a subcommand reports when it cannot run.
pub type Result<T = ()> = std::result::Result<T, Box<dyn std::error::Error>>;

/// Parses a generator's scene condition by name (`noisy`, `border_tool`, ...).
pub fn preset(name: &str) -> std::result::Result<semdepth_core::synth::Preset, String> {
    use semdepth_core::synth::Preset;
    Preset::ALL.into_iter().find(|p| p.name() == name).ok_or_else(|| {
        let names: Vec<&str> = Preset::ALL.iter().map(|p| p.name()).collect();
        format!(
            "unknown condition {name:?} (expected one of {})",
            names.join(", ")
        )
    })
}

/// Parses a generator's object shape by name (`sphere`, `rod`, ...).
pub fn shape(name: &str) -> std::result::Result<semdepth_core::synth::Shape, String> {
    use semdepth_core::synth::Shape;
    Shape::ALL.into_iter().find(|s| s.name() == name).ok_or_else(|| {
        let names: Vec<&str> = Shape::ALL.iter().map(|s| s.name()).collect();
        format!("unknown shape {name:?} (expected one of {})", names.join(", "))
    })
}

/// How the first pair names its object.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Hint {
    /// A box 10% larger than the visible object.
    Roi,
    /// The visible object's pixel nearest its centroid.
    Point,
}

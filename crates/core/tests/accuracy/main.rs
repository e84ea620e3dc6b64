//! Accuracy against independent truth: the generator's ground truth, the
//! scenes of an independent renderer ([`tilted`]) and the real images in
//! `../shared/data/real/`, with the thresholds stated in each test.
//!
//! `cargo test` runs one smoke case per family and every real-image test;
//! the full suites are ignored there and run with
//!
//! ```sh
//! cargo test --test accuracy -- --ignored
//! ```

mod reference;
mod tilted;

mod init_real;
mod init_synth;
mod liftout_real;
mod session_real;
mod session_synth;
mod tilt_pair_real;
mod tracker_real;
mod tracker_synth;
mod tracker_tilted;

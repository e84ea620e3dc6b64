//! Measures one stereo pair with the library and writes each view with its
//! contour drawn over it:
//!
//! ```sh
//! cargo run --release -p semdepth-core --example track_pair -- \
//!     ../shared/data/real/quartz/Quarz_01.png ../shared/data/real/quartz/Quarz_03.png overlay
//! ```
//!
//! prints the status, the disparity and its standard error, and writes
//! `overlay_left.png` and `overlay_right.png` (shrunk to at most 1024 px).

use std::process::ExitCode;

use semdepth_core::display::{render_png, Overlay};
use semdepth_core::imageio::{read_file, DecodeLimits};
use semdepth_core::tracker::{StereoTracker, TrackerParams};

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [left, right, out] = args.as_slice() else {
        eprintln!("usage: track_pair LEFT RIGHT OUT_PREFIX");
        return ExitCode::from(2);
    };
    match run(left, right, out) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("track_pair: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run(left: &str, right: &str, out: &str) -> Result<(), Box<dyn std::error::Error>> {
    let limits = DecodeLimits::default();
    let (l, r) = (
        read_file(left.as_ref(), &limits)?,
        read_file(right.as_ref(), &limits)?,
    );
    let mut tracker = StereoTracker::new(TrackerParams::default());
    let result = tracker.process(&l, &r)?;
    println!(
        "{} {} disparity {:?} px, across the tilt axis {:?} px, standard error {:?} px",
        result.status.name(),
        result.reason.as_deref().unwrap_or(""),
        result.disparity_px,
        result.disparity_axis_px,
        result.disparity_std_px
    );
    for (side, frame, view) in [("left", &l, &result.left), ("right", &r, &result.right)] {
        let overlays: Vec<Overlay> = view
            .iter()
            .map(|v| Overlay {
                contour: &v.contour,
                colour: [255, 60, 60],
            })
            .collect();
        let path = format!("{out}_{side}.png");
        std::fs::write(&path, render_png(frame, Some(1024), &overlays)?)?;
        println!("{path}");
    }
    Ok(())
}

//! semdepth: the height (z) of a tracked object from SEM stereo pairs.
//!
//! The method follows Dahmen, Wortmann, Tunnell and Fatikow, "Automatic
//! extraction of distance information from stereo images using tracking data
//! in the scanning electron microscope", ICINCO 2009.
//!
//! Module map (all pure: no async, no HTTP):
//! - [`imageio`]: decode PNG/TIFF/JPEG/BMP and raw buffers into [`imageio::GrayFrame`]s, with limits.
//! - [`geometry`]: closed polygons (length, area, centroid, orientation, resampling, rasterisation).
//! - [`synth`]: synthetic SEM stereo sequences with ground truth.
//! - [`init`]: automatic initialisation (Gaussian, Canny, dilation, outer contours, size filter).
//! - [`cli`]: the command-line front end used by `main.rs`.

pub mod cli;
pub mod geometry;
pub mod imageio;
pub mod init;
pub mod synth;

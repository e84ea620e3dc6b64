//! semdepth-core: the algorithms of semdepth, the height (z) of a tracked
//! object from SEM stereo pairs. Pure: no async, no I/O beyond decoding
//! the bytes it is given, no HTTP.
//!
//! The method follows Dahmen, Wortmann, Tunnell and Fatikow, "Automatic
//! extraction of distance information from stereo images using tracking data
//! in the scanning electron microscope", ICINCO 2009.
//!
//! Module map:
//! - [`imageio`]: decode PNG/TIFF/JPEG/BMP and raw buffers into [`imageio::GrayFrame`]s, with limits.
//! - [`pair`]: a stereo pair decoded from its files' bytes, with their metadata (the one path of the CLI and the service).
//! - [`meta`]: pixel size, stage tilt and working distance from the microscope's TIFF tags (FEI, ZEISS, TESCAN).
//! - [`geometry`]: closed polygons (length, area, centroid, orientation, resampling, rasterisation).
//! - [`prefilter`]: the Gaussian smoothing matched to a blurred edge, before the rigid fits.
//! - [`occlusion`]: per-sector detection of partial occlusion and a band energy over the visible sectors; the change of grey levels between two frames.
//! - [`region`]: region sums in O(contour length) (Green's theorem on row prefix sums), window sums.
//! - `synth` (feature `synth`): synthetic SEM stereo sequences with ground truth.
//! - [`energy`]: the region energy E = lambda L^k/A - D (two-region Poisson likelihood ratio).
//! - [`fit`]: free (vertex-wise) and rigid (x, y, rotation) minimisation of the energy.
//! - [`init`]: automatic initialisation (Gaussian, Canny, dilation, outer contours, size filter).
//! - [`strips`]: strips of substrate a free fit keeps inside an outline, cut out and fitted again.
//! - [`calib`]: calibrations from disparity (px) to height z (um): geometric or least-squares fit.
//! - [`uncertainty`]: standard error of a fitted position along the disparity axis (sandwich estimate from the energy's curvature and the pixel noise).
//! - [`scatter`]: how much more a run's disparities scatter from pair to pair than their fits say (a Birge ratio on second differences).
//! - [`tracker`]: the stereo tracker: initialise and fit on the first pair, rigid tracking after, disparity.
//! - [`session`]: a session's named objects measured on every pair, their heights through one calibration and the heights between them.
//! - [`display`]: 8-bit PNG renderings of frames with contours drawn over them (the live view's images).

pub mod calib;
pub mod display;
pub mod energy;
pub mod fit;
pub mod geometry;
pub mod imageio;
pub mod init;
pub mod meta;
pub mod occlusion;
pub mod pair;
pub mod prefilter;
pub mod region;
pub mod scatter;
pub mod session;
pub mod strips;
#[cfg(feature = "synth")]
pub mod synth;
pub mod tracker;
pub mod uncertainty;

//! The service's own wire and storage types: what requests carry, what
//! responses and the command line's output say, and what storage keeps.
//! Each is converted to and from the algorithms' types in
//! [`semdepth_core`], so that the algorithms can change their types without
//! changing the API or making a stored database unreadable.
//!
//! - [`params`]: the tracker's parameters (requests, storage, the command
//!   line's parameter file).
//! - [`results`]: a pair's measurement (responses, storage, the command
//!   line's records).
//! - [`calibration`]: calibrations (requests, responses, storage, the
//!   command line's calibration file).
//! - [`csv`]: results as CSV rows (`?format=csv`, `semdepth process --format csv`).
//! - [`model`]: the other requests and responses (sessions, objects,
//!   calibrations, results pages, health).

pub mod calibration;
pub mod csv;
pub mod model;
pub mod params;
pub mod results;

pub use calibration::{
    read_calibration, CalibrationBody, CalibrationReadError, PixelSizeSource, Sample, VergenceSource,
};
pub use params::{
    EnergyParams, FreeFitParams, InitParams, OcclusionParams, Polarity, RigidParams, TrackerParams,
};
pub use results::{
    ImageResult, ObjectResult, PairMeta, PairResult, Relative, SessionState, Status, ViewMeta,
};

//! `semdepth meta IMAGE...`: print what the microscope wrote into each image
//! file (pixel size, stage tilt, working distance, ...) as a JSON array.

use std::io::Read;
use std::path::{Path, PathBuf};

use clap::Args;
use serde::Serialize;

use super::CliError;
use semdepth_core::imageio::ImageInputError;
use semdepth_core::meta::{read_meta, ImageMeta};

/// Largest file read, in bytes (1 GiB): far above any SEM image, and a
/// bound on what a mistaken path (a disk image, a device) can cost.
pub const MAX_FILE_BYTES: u64 = 1 << 30;

/// Arguments of `semdepth meta`.
#[derive(Debug, Args)]
pub struct MetaArgs {
    /// The image files (TIFF from FEI / Thermo Fisher, ZEISS or TESCAN
    /// microscopes, or saved by OpenFIBSEM with its JSON description;
    /// other files give records with every field null).
    #[arg(required = true)]
    pub images: Vec<PathBuf>,
}

/// One printed record: the path, then what the image says, in SI units
/// (null where absent or unreadable), and what could not be read.
#[derive(Serialize)]
struct Record<'a> {
    image: String,
    /// `fei`, `zeiss`, `tescan` or `openfibsem`; null: no microscope
    /// metadata.
    vendor: Option<&'static str>,
    /// `electron` or `ion`: the beam that took the image, where known.
    beam: Option<&'static str>,
    pixel_width_m: Option<f64>,
    pixel_height_m: Option<f64>,
    stage_tilt_rad: Option<f64>,
    working_distance_m: Option<f64>,
    high_voltage_v: Option<f64>,
    magnification: Option<f64>,
    warnings: &'a [String],
}

impl<'a> Record<'a> {
    fn new(image: String, meta: &'a ImageMeta) -> Self {
        Self {
            image,
            vendor: meta.vendor.map(|v| v.name()),
            beam: meta.beam.map(|b| b.name()),
            pixel_width_m: meta.pixel_width_m,
            pixel_height_m: meta.pixel_height_m,
            stage_tilt_rad: meta.stage_tilt_rad,
            working_distance_m: meta.working_distance_m,
            high_voltage_v: meta.high_voltage_v,
            magnification: meta.magnification,
            warnings: &meta.warnings,
        }
    }
}

/// Runs `semdepth meta`; exit code 2 when a file cannot be read. A readable
/// file without metadata is not an error: its fields are null.
pub fn run(args: MetaArgs) -> Result<(), CliError> {
    let mut metas = Vec::with_capacity(args.images.len());
    for path in &args.images {
        metas.push(read_meta(&read_capped(path)?));
    }
    let records: Vec<Record> = args
        .images
        .iter()
        .zip(&metas)
        .map(|(path, meta)| Record::new(path.display().to_string(), meta))
        .collect();
    let json = serde_json::to_string(&records)
        .map_err(|e| CliError::with_code(1, format!("could not write JSON: {e}")))?;
    println!("{json}");
    Ok(())
}

/// The bytes of `path`, at most [`MAX_FILE_BYTES`] of them.
fn read_capped(path: &Path) -> Result<Vec<u8>, CliError> {
    let io_error = |source| {
        CliError::from(ImageInputError::Io {
            path: path.display().to_string(),
            source,
        })
    };
    let file = std::fs::File::open(path).map_err(io_error)?;
    let mut bytes = Vec::new();
    file.take(MAX_FILE_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(io_error)?;
    if bytes.len() as u64 > MAX_FILE_BYTES {
        return Err(CliError::input(format!(
            "error[file_too_large]: {} is larger than {MAX_FILE_BYTES} bytes",
            path.display()
        )));
    }
    Ok(bytes)
}

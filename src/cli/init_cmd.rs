//! `semdepth init IMAGE`: run the automatic initialisation on one image and
//! print the found object as JSON, with the outline tracking starts from.

use std::path::PathBuf;

use clap::Args;

use super::{exactly, pairs, CliError};
use crate::service::api::Polarity;
use semdepth_core::imageio::{read_file, DecodeLimits};
use semdepth_core::init::{initialise, InitDiagnostics, InitParams, Score, Source};
use semdepth_core::tracker::{StereoTracker, TrackerParams};

/// Arguments of `semdepth init`.
#[derive(Debug, Args)]
pub struct InitArgs {
    /// The image to search (PNG, TIFF, JPEG or BMP; 8 or 16 bit).
    pub image: PathBuf,
    /// Smallest expected object area in pixels.
    #[arg(long)]
    pub min_area: Option<f64>,
    /// Largest expected object area in pixels.
    #[arg(long)]
    pub max_area: Option<f64>,
    /// Hint: the box the object lies in, X Y WIDTH HEIGHT in pixels (spaces
    /// or commas between them; with commas a negative X needs `--roi=-20,..`;
    /// clipped
    /// to the image: it may run past the border, for a tool entering there).
    #[arg(long, num_args = 1..=4, value_delimiter = ',', value_names = ["X", "Y", "WIDTH", "HEIGHT"], allow_negative_numbers = true)]
    pub roi: Option<Vec<i64>>,
    /// Hint: a point on the object, X Y in pixels (spaces or commas).
    #[arg(long, num_args = 1..=2, value_delimiter = ',', value_names = ["X", "Y"], allow_negative_numbers = true)]
    pub point: Option<Vec<f64>>,
    /// Hint: the object's outline as drawn round it (a lasso), X,Y pairs in
    /// pixels, at least 3, commas between them (`--outline=-10,40,..` when
    /// X is negative: a part drawn past the border says the object crosses
    /// it there).
    #[arg(long, num_args = 1.., value_delimiter = ',', value_name = "X,Y,...", allow_negative_numbers = true)]
    pub outline: Option<Vec<f64>>,
    /// Hint: a point on something that is not the object, X,Y in pixels;
    /// repeat for more (at most 64).
    #[arg(long, num_args = 1..=2, value_delimiter = ',', value_names = ["X", "Y"], allow_negative_numbers = true, action = clap::ArgAction::Append)]
    pub exclude: Vec<f64>,
    /// Hint: the object is brighter or darker than its surroundings.
    #[arg(long, value_enum, default_value_t = Polarity::Any)]
    pub polarity: Polarity,
    /// Gaussian sigma in working pixels (default: adapts to the noise).
    #[arg(long)]
    pub sigma: Option<f32>,
    /// Canny low threshold (0..1 grey levels per pixel; default: adaptive).
    #[arg(long)]
    pub low_threshold: Option<f32>,
    /// Canny high threshold (default: adaptive).
    #[arg(long)]
    pub high_threshold: Option<f32>,
    /// Dilation radius in working pixels (default: adapts to the image size).
    #[arg(long)]
    pub dilation_radius: Option<u8>,
    /// Longest side of the working copy (the image is downsampled to fit).
    #[arg(long, default_value_t = InitParams::default().working_max_side)]
    pub working_max_side: u32,
    /// Vertex spacing of the printed contour in pixels.
    #[arg(long, default_value_t = InitParams::default().contour_spacing_px)]
    pub contour_spacing: f64,
    /// Leave out the contour points (print only centroid, area, bbox).
    #[arg(long)]
    pub no_contour: bool,
    /// Also write the image with the found contour drawn on it (PNG).
    #[arg(long, value_name = "PNG")]
    pub overlay: Option<PathBuf>,
    /// Print the initialisation's own outline (the edge pipeline's or the
    /// prompted segmentation's) instead of the one tracking starts from
    /// (fitted freely, strips of substrate cut out, moved onto the edge).
    #[arg(long)]
    pub unfitted: bool,
}

/// Runs `semdepth init`; exit code 3 when no object is found, 2 when a
/// `--point` or `--polarity` matches no region.
pub fn run(args: InitArgs) -> Result<(), CliError> {
    let frame = read_file(&args.image, &DecodeLimits::default())?;
    let params = InitParams {
        working_max_side: args.working_max_side,
        sigma: args.sigma,
        low_threshold: args.low_threshold,
        high_threshold: args.high_threshold,
        dilation_radius: args.dilation_radius,
        min_area_px: args.min_area,
        max_area_px: args.max_area,
        roi: args.roi.as_deref().map(|r| exactly("roi", r)).transpose()?,
        point: args.point.as_deref().map(|p| exactly("point", p)).transpose()?,
        polarity: args.polarity.into(),
        outline: args
            .outline
            .as_deref()
            .map(|o| pairs("outline", o, 3))
            .transpose()?,
        exclude: pairs("exclude", &args.exclude, 0)?,
        contour_spacing_px: args.contour_spacing,
    };
    let result = initialise(&frame, &params).map_err(|e| match e {
        semdepth_core::init::InitError::InvalidParams(_) => {
            CliError::input(format!("error[{}]: {e}", e.code()))
        }
        semdepth_core::init::InitError::InvalidHint { .. } => {
            super::hint_error(&e, |field| format!("--{field}"))
        }
        // A hint that names nothing is the request's fault, not the image's.
        semdepth_core::init::InitError::HintMatchesNothing { .. } => {
            CliError::input(format!("error[{}]: {}: {e}", e.code(), args.image.display()))
        }
        _ => CliError::with_code(
            3,
            format!(
                "error[{}]: no object found in {}: {e}",
                e.code(),
                args.image.display()
            ),
        ),
    })?;
    // The outline tracking starts from, as `semdepth process` reports it
    // for the first pair: what a person checks before tracking.
    let fitted = (!args.unfitted)
        .then(|| {
            let tracker = TrackerParams {
                init: params.clone(),
                ..TrackerParams::default()
            };
            StereoTracker::first_outline(&tracker, &frame, result.clone())
        })
        .flatten()
        .map(|outline| outline.resampled_every(params.contour_spacing_px, 8));
    let is_fitted = fitted.is_some();
    let result = match fitted {
        Some(outline) => result.with_contour(outline),
        None => result,
    };
    let mut json = serde_json::json!({
        "image": args.image.display().to_string(),
        "width": frame.width,
        "height": frame.height,
        "centroid": result.centroid,
        "area_px": result.area_px,
        "bbox": result.bbox,
        "rim_px": result.rim_px,
        "edge_support": result.edge_support,
        "score": result.score.map(score_json),
        "source": source_json(result.source),
        "border": result.border,
        "cut_at_box": result.cut_at_box,
        "diagnostics": diagnostics_json(&result.diagnostics),
        "fitted": is_fitted,
    });
    if !args.no_contour {
        let rounded: Vec<[f64; 2]> = result
            .contour
            .points
            .iter()
            .map(|p| [(p[0] * 1000.0).round() / 1000.0, (p[1] * 1000.0).round() / 1000.0])
            .collect();
        json["contour"] = serde_json::json!(rounded);
    }
    if let Some(path) = &args.overlay {
        write_overlay(&frame, &result.contour, path)?;
    }
    println!("{json}");
    Ok(())
}

/// Draws the contour (white, with a black halo) over an 8-bit copy of the image.
fn write_overlay(
    frame: &semdepth_core::imageio::GrayFrame,
    contour: &semdepth_core::geometry::Polygon,
    path: &std::path::Path,
) -> Result<(), CliError> {
    use imageproc::drawing::draw_line_segment_mut;
    let mut canvas = image::DynamicImage::ImageLuma8(frame.to_gray8()).to_rgb8();
    for (a, b) in contour.edges() {
        for (d, colour) in [(1.0, [0, 0, 0]), (0.0, [255, 64, 64])] {
            let (a, b) = (
                [a[0] as f32 + d, a[1] as f32 + d],
                [b[0] as f32 + d, b[1] as f32 + d],
            );
            draw_line_segment_mut(&mut canvas, (a[0], a[1]), (b[0], b[1]), image::Rgb(colour));
        }
    }
    canvas
        .save(path)
        .map_err(|e| CliError::with_code(1, format!("could not write overlay {}: {e}", path.display())))
}

/// A candidate's score as `semdepth init` prints it.
fn score_json(s: Score) -> serde_json::Value {
    serde_json::json!({
        "score": s.score,
        "contrast": s.contrast,
        "data": s.data,
        "outline_px": s.outline_px,
        "area_px": s.area_px,
    })
}

/// Where a candidate came from, as `semdepth init` prints it.
fn source_json(s: Source) -> serde_json::Value {
    match s {
        Source::Edges { dilation_radius } => {
            serde_json::json!({"kind": "edges", "dilation_radius": dilation_radius})
        }
        Source::Threshold { polarity, level } => serde_json::json!({
            "kind": "threshold",
            "polarity": Polarity::from(polarity),
            "level": level,
        }),
        Source::Outline => serde_json::json!({"kind": "outline"}),
    }
}

/// What the initialisation used and saw, as `semdepth init` prints it.
fn diagnostics_json(d: &InitDiagnostics) -> serde_json::Value {
    let runners_up: Vec<serde_json::Value> = d
        .runners_up
        .iter()
        .map(|r| {
            serde_json::json!({
                "score": score_json(r.score),
                "source": source_json(r.source),
                "bbox": r.bbox,
            })
        })
        .collect();
    serde_json::json!({
        "scale": d.scale,
        "noise_sigma": d.noise_sigma,
        "sigma": d.sigma,
        "low_threshold": d.low_threshold,
        "high_threshold": d.high_threshold,
        "dilation_radius": d.dilation_radius,
        "edge_pixels": d.edge_pixels,
        "candidates": d.candidates,
        "runners_up": runners_up,
    })
}

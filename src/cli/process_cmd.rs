//! `semdepth process DIR`: track a folder of stereo pairs (`*_left.EXT` /
//! `*_right.EXT`) as one sequence and print one record per pair (JSON lines or
//! CSV) as it goes.

use std::collections::BTreeMap;
use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use clap::{Args, ValueEnum};

use super::{exactly, hint_error, pairs, CliError};
use crate::service::api::csv::{csv_record, objects_csv_records, CSV_HEADER, OBJECTS_CSV_HEADER};
use crate::service::api::{self, read_calibration, ObjectResult, PairResult, Polarity, Relative, Status};
use semdepth_core::calib::{same_tilt_axis, Calibration};
use semdepth_core::imageio::{read_bytes, DecodeLimits};
use semdepth_core::init::InitError;
use semdepth_core::pair::{DecodedPair, Side};
use semdepth_core::session::{check_object_name, Session, SessionObject};
use semdepth_core::tracker::{TrackError, TrackerParams};

/// Image extensions recognised in the folder (compared case-insensitively).
pub const IMAGE_EXTENSIONS: [&str; 6] = ["png", "tif", "tiff", "jpg", "jpeg", "bmp"];

/// Output format of `semdepth process`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Format {
    /// One JSON object per line.
    Jsonl,
    /// A header line, then one row per pair.
    Csv,
}

/// Arguments of `semdepth process`.
#[derive(Debug, Args)]
pub struct ProcessArgs {
    /// Folder with the pairs NAME_left.EXT / NAME_right.EXT (EXT: png, tif,
    /// tiff, jpg, jpeg, bmp), processed in order of NAME; with --series, a
    /// tilt series of single images; with --pairs, the pairs it lists.
    pub dir: PathBuf,
    /// The folder is a tilt series: its images in order of name, each
    /// after the first paired with the first (first, 2nd), (first, 3rd), ...
    /// and tracked as one sequence.
    #[arg(long, conflicts_with = "pairs")]
    pub series: bool,
    /// The pairs to process, in order: LEFT:RIGHT file names in the folder,
    /// comma-separated (`Quarz_01.png:Quarz_02.png,Quarz_01.png:Quarz_03.png`),
    /// tracked as one sequence and named LEFT-RIGHT after their stems.
    #[arg(long, value_name = "LEFT:RIGHT,...")]
    pub pairs: Option<String>,
    /// Calibration JSON (geometric or fit); fills z_um.
    #[arg(long, value_name = "CAL.json")]
    pub calibration: Option<PathBuf>,
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Jsonl)]
    pub format: Format,
    /// Full tracker parameters as JSON (the flags below override its fields).
    #[arg(long, value_name = "PARAMS.json")]
    pub params: Option<PathBuf>,
    /// Direction of the tilt axis in the image, degrees from +x towards +y
    /// [default: 90, or the calibration's axis].
    #[arg(long, allow_negative_numbers = true)]
    pub tilt_axis_deg: Option<f64>,
    /// Largest disparity searched on the first pair, pixels [default: 64].
    #[arg(long)]
    pub max_disparity: Option<f64>,
    /// Largest motion between two pairs the rigid fit catches, pixels [default: 24].
    #[arg(long)]
    pub search_radius: Option<f64>,
    /// Smallest expected object area in pixels.
    #[arg(long)]
    pub min_area: Option<f64>,
    /// Largest expected object area in pixels.
    #[arg(long)]
    pub max_area: Option<f64>,
    /// Hint: the box the object lies in on the first pair, X Y WIDTH HEIGHT
    /// in pixels, spaces or commas between them (with commas a negative X
    /// needs `--roi=-20,..`; clipped to the image: it may run past the
    /// border, for a tool entering there) [default: the params file's
    /// init.roi].
    #[arg(long, num_args = 1..=4, value_delimiter = ',', value_names = ["X", "Y", "WIDTH", "HEIGHT"], allow_negative_numbers = true)]
    pub roi: Option<Vec<i64>>,
    /// Hint: a point on the object on the first pair, X Y in pixels
    /// [default: the params file's init.point].
    #[arg(long, num_args = 1..=2, value_delimiter = ',', value_names = ["X", "Y"], allow_negative_numbers = true)]
    pub point: Option<Vec<f64>>,
    /// Hint: the object's outline as drawn round it (a lasso), X,Y pairs in
    /// pixels, at least 3, commas between them (`--outline=-10,40,..` when
    /// X is negative: a part drawn past the border says the object crosses
    /// it there) [default: the params file's init.outline].
    #[arg(long, num_args = 1.., value_delimiter = ',', value_name = "X,Y,...", allow_negative_numbers = true)]
    pub outline: Option<Vec<f64>>,
    /// Hint: a point on something that is not the object, X,Y in pixels;
    /// repeat for more (at most 64)
    /// [default: the params file's init.exclude].
    #[arg(long, num_args = 1..=2, value_delimiter = ',', value_names = ["X", "Y"], allow_negative_numbers = true, action = clap::ArgAction::Append)]
    pub exclude: Vec<f64>,
    /// Hint: the object is brighter or darker than its surroundings
    /// [default: the params file's init.polarity, else any].
    #[arg(long, value_enum)]
    pub polarity: Option<Polarity>,
    /// An object to track, with its hints: NAME, then `:KEY=VALUE` for
    /// each hint, KEY one of roi (X,Y,W,H), point (X,Y), outline
    /// (X,Y,X,Y,X,Y,...), exclude (X,Y; repeatable), polarity (brighter,
    /// darker, any), min_area, max_area; e.g.
    /// `--object needle:roi=0,100,300,80 --object lamella:point=520,300:polarity=darker`.
    /// Repeat for up to 16 objects; each pair then gives every object's
    /// measurement and the height of each relative to each other. The
    /// other flags and the params file apply to all objects; --roi,
    /// --point, --outline, --exclude and --polarity do not go with --object.
    #[arg(long = "object", value_name = "NAME[:KEY=VALUE...]")]
    pub objects: Vec<String>,
    /// Leave out the contour points.
    #[arg(long)]
    pub no_contour: bool,
    /// Report progress on stderr (on by default when stderr is a terminal).
    #[arg(long)]
    pub progress: bool,
}

/// A file's name without its extension ("" for none): what a pair made of
/// two single images is named after.
fn stem(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// The pairs of a tilt series in `dir`: its images (by extension) in order
/// of file name, each after the first paired with the first, named
/// `FIRST-K` after their stems. Fewer than two images is an error (exit 2).
pub fn find_series(dir: &Path) -> Result<Vec<PairFiles>, CliError> {
    let mut images: Vec<PathBuf> = folder_files(dir)?.into_iter().filter(|p| is_image(p)).collect();
    images.sort();
    match images.as_slice() {
        [first, rest @ ..] if !rest.is_empty() => Ok(rest
            .iter()
            .map(|k| PairFiles {
                name: format!("{}-{}", stem(first), stem(k)),
                left: first.clone(),
                right: k.clone(),
            })
            .collect()),
        _ => Err(CliError::input(format!(
            "error[no_pairs]: {} image(s) in {} (expected at least two for a tilt series, EXT one of {})",
            images.len(),
            dir.display(),
            IMAGE_EXTENSIONS.join(", ")
        ))),
    }
}

/// The pairs `list` names in `dir` (see [`ProcessArgs::pairs`]): each
/// `LEFT:RIGHT` must name two image files in the folder (exit 2 naming the
/// entry otherwise).
pub fn listed_pairs(dir: &Path, list: &str) -> Result<Vec<PairFiles>, CliError> {
    let pairs: Vec<PairFiles> = list
        .split(',')
        .map(str::trim)
        .filter(|entry| !entry.is_empty())
        .map(|entry| {
            let bad = |why: String| {
                CliError::input(format!("error[invalid_pairs]: --pairs entry {entry:?}: {why}"))
            };
            let (left, right) = entry
                .split_once(':')
                .ok_or_else(|| bad("expected LEFT:RIGHT, two file names in the folder".into()))?;
            let file = |name: &str| {
                let path = dir.join(name.trim());
                if !(path.is_file() && is_image(&path)) {
                    return Err(bad(format!(
                        "{} is no image file (expected one of {} in {})",
                        path.display(),
                        IMAGE_EXTENSIONS.join(", "),
                        dir.display()
                    )));
                }
                Ok(path)
            };
            let (left, right) = (file(left)?, file(right)?);
            Ok(PairFiles {
                name: format!("{}-{}", stem(&left), stem(&right)),
                left,
                right,
            })
        })
        .collect::<Result<_, CliError>>()?;
    if pairs.is_empty() {
        return Err(CliError::input(
            "error[invalid_pairs]: --pairs names no pair (expected LEFT:RIGHT,...)",
        ));
    }
    Ok(pairs)
}

/// One stereo pair found in the folder.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PairFiles {
    /// The common prefix before `_left` / `_right`.
    pub name: String,
    /// The left image.
    pub left: PathBuf,
    /// The right image.
    pub right: PathBuf,
}

/// Finds the pairs in `dir`, sorted by name. Other files are ignored; a left
/// image without a right one (or the other way round), two images for the
/// same side and name, and a folder without pairs are errors (exit 2).
pub fn find_pairs(dir: &Path) -> Result<Vec<PairFiles>, CliError> {
    // name -> (left, right)
    let mut sides: BTreeMap<String, [Option<PathBuf>; 2]> = BTreeMap::new();
    for path in folder_files(dir)? {
        let Some((name, side)) = classify(&path) else {
            continue;
        };
        let slot = &mut sides.entry(name.clone()).or_default()[side];
        if let Some(other) = slot {
            return Err(CliError::input(format!(
                "error[duplicate_image]: two {} images for pair {name:?}: {} and {} (expected one)",
                ["left", "right"][side],
                other.display(),
                path.display()
            )));
        }
        *slot = Some(path);
    }
    if sides.is_empty() {
        return Err(CliError::input(format!(
            "error[no_pairs]: no stereo pairs in {} (expected files NAME_left.EXT and NAME_right.EXT, EXT one of {}; a tilt series of single images takes --series)",
            dir.display(),
            IMAGE_EXTENSIONS.join(", ")
        )));
    }
    sides
        .into_iter()
        .map(|(name, [left, right])| match (left, right) {
            (Some(left), Some(right)) => Ok(PairFiles { name, left, right }),
            (Some(left), None) => Err(CliError::input(format!(
                "error[unpaired_image]: {} has no right image (expected {name}_right.EXT beside it)",
                left.display()
            ))),
            (None, Some(right)) => Err(CliError::input(format!(
                "error[unpaired_image]: {} has no left image (expected {name}_left.EXT beside it)",
                right.display()
            ))),
            (None, None) => unreachable!("a pair is only recorded with one of its images"),
        })
        .collect()
}

/// The files (not folders) in `dir`, in no order.
fn folder_files(dir: &Path) -> Result<Vec<PathBuf>, CliError> {
    let unreadable = |e: std::io::Error| {
        CliError::input(format!(
            "error[io_error]: cannot read the folder {}: {e}",
            dir.display()
        ))
    };
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(unreadable)? {
        let path = entry.map_err(unreadable)?.path();
        if path.is_file() {
            files.push(path);
        }
    }
    Ok(files)
}

/// Whether the file's extension is one of [`IMAGE_EXTENSIONS`] (any case).
fn is_image(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| IMAGE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

/// `(name, 0 for left / 1 for right)` when the file is NAME_left.EXT or
/// NAME_right.EXT with a supported extension.
fn classify(path: &Path) -> Option<(String, usize)> {
    if !is_image(path) {
        return None;
    }
    let stem = path.file_stem()?.to_str()?;
    if let Some(name) = stem.strip_suffix("_left") {
        Some((name.to_string(), 0))
    } else {
        stem.strip_suffix("_right").map(|name| (name.to_string(), 1))
    }
}

impl ProcessArgs {
    /// The tracker parameters: the `--params` file (or the defaults), the
    /// flags on top, the calibration's tilt axis when none was given, validated.
    pub fn tracker_params(&self, calibration: Option<&Calibration>) -> Result<TrackerParams, CliError> {
        let (mut params, file_sets_axis) = match &self.params {
            Some(path) => {
                let text = std::fs::read_to_string(path)
                    .map_err(|e| CliError::input(format!("error[io_error]: {}: {e}", path.display())))?;
                // The path names the field of a bad value (e.g. `init.polarity`).
                let params: api::TrackerParams =
                    serde_path_to_error::deserialize(&mut serde_json::Deserializer::from_str(&text))
                        .map_err(|e| {
                            CliError::input(format!(
                                "error[invalid_params]: {}: not valid tracker parameters: {e}",
                                path.display()
                            ))
                        })?;
                let sets_axis = params.tilt_axis_deg.is_some();
                (TrackerParams::from(params), sets_axis)
            }
            None => (TrackerParams::default(), false),
        };
        if let Some(v) = self.tilt_axis_deg {
            params.tilt_axis_deg = v;
        }
        if let Some(v) = self.max_disparity {
            params.max_disparity_px = v;
        }
        if let Some(v) = self.search_radius {
            params.rigid.search_radius_px = v;
        }
        if let Some(v) = self.min_area {
            params.init.min_area_px = Some(v);
        }
        if let Some(v) = self.max_area {
            params.init.max_area_px = Some(v);
        }
        if let Some(r) = &self.roi {
            params.init.roi = Some(exactly("roi", r)?);
        }
        if let Some(p) = &self.point {
            params.init.point = Some(exactly("point", p)?);
        }
        if let Some(o) = &self.outline {
            params.init.outline = Some(pairs("outline", o, 3)?);
        }
        if !self.exclude.is_empty() {
            params.init.exclude = pairs("exclude", &self.exclude, 1)?;
        }
        if let Some(p) = self.polarity {
            params.init.polarity = p.into();
        }
        if let Err(e @ InitError::InvalidHint { .. }) = params.init.validate() {
            return Err(hint_error(&e, |field| self.hint_source(field)));
        }
        if let Some(cal) = calibration {
            let explicit = self.tilt_axis_deg.is_some() || file_sets_axis;
            let (a, b) = (params.tilt_axis_deg, cal.tilt_axis_deg());
            if !explicit {
                params.tilt_axis_deg = b;
            } else {
                same_tilt_axis(a, b)
                    .map_err(|e| CliError::input(format!("error[tilt_axis_conflict]: {e}")))?;
            }
        }
        params
            .validate()
            .map_err(|e| CliError::input(format!("error[invalid_params]: {e}")))?;
        Ok(params)
    }

    /// Where the hint `field` (`roi`, `point`) came from, for messages: its
    /// flag, or the params file's `init` field.
    fn hint_source(&self, field: &str) -> String {
        let flag = match field {
            "roi" => self.roi.is_some(),
            "point" => self.point.is_some(),
            "outline" => self.outline.is_some(),
            "exclude" => !self.exclude.is_empty(),
            _ => false,
        };
        match &self.params {
            Some(path) if !flag => format!("init.{field} in {}", path.display()),
            _ => format!("--{field}"),
        }
    }
}

/// `--object NAME[:KEY=VALUE...]`: the name and the hints replacing
/// `base`'s (exit 2 naming the object and the key otherwise).
pub fn parse_object(spec: &str, base: &TrackerParams) -> Result<SessionObject, CliError> {
    let bad = |what: String| CliError::input(format!("error[invalid_object]: --object {spec:?}: {what}"));
    let mut parts = spec.split(':');
    let name = parts.next().unwrap_or_default();
    check_object_name(name).map_err(|e| bad(e.to_string()))?;
    let mut params = base.clone();
    params.init.roi = None;
    params.init.point = None;
    params.init.outline = None;
    params.init.exclude = Vec::new();
    params.init.polarity = Polarity::Any.into();
    for part in parts {
        let (key, value) = part
            .split_once('=')
            .ok_or_else(|| bad(format!("{part:?} is not KEY=VALUE")))?;
        let parsed = || -> Option<Vec<f64>> {
            let v: Vec<f64> = value
                .split(',')
                .map(|x| x.trim().parse::<f64>())
                .collect::<Result<_, _>>()
                .ok()?;
            v.iter().all(|x| x.is_finite()).then_some(v)
        };
        let numbers = |n: usize| -> Result<Vec<f64>, CliError> {
            match parsed() {
                Some(v) if v.len() == n => Ok(v),
                _ => Err(bad(format!(
                    "{key}={value:?} (expected {n} comma-separated numbers)"
                ))),
            }
        };
        let xy_pairs = |least: usize| -> Result<Vec<[f64; 2]>, CliError> {
            match parsed().and_then(|v| crate::service::api::params::xy_pairs(&v, least)) {
                Some(pairs) => Ok(pairs),
                None => Err(bad(format!(
                    "{key}={value:?} (expected at least {least} comma-separated X,Y pairs)"
                ))),
            }
        };
        match key {
            "roi" => {
                let v = numbers(4)?;
                if v.iter().any(|x| x.fract() != 0.0) {
                    return Err(bad(format!("roi={value:?} (expected whole pixels X,Y,W,H)")));
                }
                params.init.roi = Some([v[0] as i64, v[1] as i64, v[2] as i64, v[3] as i64]);
            }
            "point" => {
                let v = numbers(2)?;
                params.init.point = Some([v[0], v[1]]);
            }
            "outline" => params.init.outline = Some(xy_pairs(3)?),
            // Repeatable: each adds its points.
            "exclude" => params.init.exclude.extend(xy_pairs(1)?),
            "polarity" => {
                params.init.polarity = <Polarity as clap::ValueEnum>::from_str(value, true)
                    .map_err(|_| bad(format!("polarity={value:?} (expected brighter, darker or any)")))?
                    .into();
            }
            "min_area" => params.init.min_area_px = Some(numbers(1)?[0]),
            "max_area" => params.init.max_area_px = Some(numbers(1)?[0]),
            other => {
                return Err(bad(format!(
                    "unknown key {other:?} (expected roi, point, outline, exclude, polarity, min_area or max_area)"
                )))
            }
        }
    }
    if let Err(e @ InitError::InvalidHint { .. }) = params.init.validate() {
        return Err(hint_error(&e, |field| format!("{field} of --object {name}")));
    }
    params
        .validate()
        .map_err(|e| bad(format!("invalid parameters: {e}")))?;
    Ok(SessionObject::new(name, params))
}

/// Runs `semdepth process`: exit code 2 for bad arguments or input (including
/// an image that cannot be read, after the records already printed).
pub fn run(args: ProcessArgs) -> Result<(), CliError> {
    let calibration = match &args.calibration {
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .map_err(|e| CliError::input(format!("error[io_error]: {}: {e}", path.display())))?;
            Some(
                read_calibration(&text)
                    .map_err(|e| CliError::input(format!("error[{}]: {}: {e}", e.code(), path.display())))?,
            )
        }
        None => None,
    };
    let params = args.tracker_params(calibration.as_ref())?;
    let named = !args.objects.is_empty();
    let mut session = if named {
        if args.roi.is_some()
            || args.point.is_some()
            || args.outline.is_some()
            || !args.exclude.is_empty()
            || args.polarity.is_some()
        {
            return Err(CliError::input(
                "error[conflicting_hints]: --roi, --point, --outline, --exclude and --polarity name one object; with --object, give the hints inside it (--object NAME:roi=X,Y,W,H)",
            ));
        }
        let objects = args
            .objects
            .iter()
            .map(|spec| parse_object(spec, &params))
            .collect::<Result<Vec<_>, _>>()?;
        Session::new(objects, 0)
            .map_err(|e| CliError::input(format!("error[{}]: --object: {e}", e.code())))?
    } else {
        Session::single(params)
    };
    let pairs = match (&args.pairs, args.series) {
        (Some(list), _) => listed_pairs(&args.dir, list)?,
        (None, true) => find_series(&args.dir)?,
        (None, false) => find_pairs(&args.dir)?,
    };
    let limits = DecodeLimits::default();
    let mut progress = Progress::new(pairs.len(), args.progress || std::io::stderr().is_terminal());
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    // The CSV header goes out with the first record, so that an error on
    // the first pair (e.g. hints that do not fit the images) prints nothing.
    let mut header_due = args.format == Format::Csv;
    // Objects that initialise or search are tracked side by side, up to
    // one thread per core.
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    for pair in &pairs {
        let threads = session.useful_threads().min(cores);
        let started = Instant::now();
        let decoded_pair = read_pair(pair, &limits)?;
        let decoded = Instant::now();
        let measured = session
            .measure_pair(&decoded_pair, calibration.as_ref(), threads)
            .map_err(|e| match &e.error {
                // The hints do not fit the images: name the flag or field.
                TrackError::Hint(hint) => {
                    let mut err = match named {
                        true => hint_error(hint, |field| format!("{field} of --object {}", e.object)),
                        false => hint_error(hint, |field| args.hint_source(field)),
                    };
                    if named && !matches!(hint, InitError::InvalidHint { .. }) {
                        err.message = format!("{} (--object {})", err.message, e.object);
                    }
                    err.message = format!("{} (pair {:?}, {})", err.message, pair.name, pair.left.display());
                    err
                }
                other => CliError::input(format!(
                    "error[{}]: pair {:?} ({}, {}): {other}",
                    track_error_code(other),
                    pair.name,
                    pair.left.display(),
                    pair.right.display()
                )),
            })?;
        let timing = Timing {
            decode: ms(decoded - started),
            track: ms(decoded.elapsed()),
        };
        let frame = measured.frame;
        let objects: Vec<ObjectResult> = measured.objects.into_iter().map(Into::into).collect();
        let relative: Vec<Relative> = measured.relative.into_iter().map(Into::into).collect();
        let lines = match (args.format, named) {
            (Format::Jsonl, false) => vec![json_record(
                &objects[0].result,
                &pair.name,
                timing,
                !args.no_contour,
            )?],
            (Format::Jsonl, true) => vec![json_measurement(
                (&objects, &relative),
                &pair.name,
                timing,
                !args.no_contour,
            )?],
            (Format::Csv, false) => vec![csv_record(&objects[0].result, &pair.name)],
            (Format::Csv, true) => objects_csv_records(frame, &objects, &relative, &pair.name),
        };
        let header = if named {
            OBJECTS_CSV_HEADER.as_str()
        } else {
            CSV_HEADER
        };
        if std::mem::take(&mut header_due) && !emit(&mut out, header)? {
            return Ok(());
        }
        for line in lines {
            if !emit(&mut out, &line)? {
                return Ok(()); // stdout closed (e.g. `| head`): stop quietly
            }
        }
        // A pair counts as tracked when every object is.
        let status = objects
            .iter()
            .map(|o| o.result.status)
            .max_by_key(|s| match s {
                Status::Tracked => 0,
                Status::Initialised => 1,
                Status::Lost => 2,
            })
            .unwrap_or(Status::Lost);
        progress.record(status);
    }
    progress.finish();
    Ok(())
}

/// The pair's two files decoded, with what their microscope metadata say
/// (see [`semdepth_core::pair`]); an error names the file.
fn read_pair(pair: &PairFiles, limits: &DecodeLimits) -> Result<DecodedPair, CliError> {
    // The I/O error names the path already.
    let read =
        |path: &Path| read_bytes(path).map_err(|e| CliError::input(format!("error[{}]: {e}", e.code())));
    let (left, right) = (read(&pair.left)?, read(&pair.right)?);
    DecodedPair::from_files(&left, &right, limits).map_err(|e| {
        let path = match e.side {
            Side::Left => &pair.left,
            Side::Right => &pair.right,
        };
        CliError::input(format!(
            "error[{}]: {}: {}",
            e.error.code(),
            path.display(),
            e.error
        ))
    })
}

fn track_error_code(e: &TrackError) -> &'static str {
    match e {
        TrackError::Input(e) => e.code(),
        TrackError::SizeChanged { .. } => "pair_size_changed",
        TrackError::Hint(e) => e.code(),
    }
}

fn ms(d: Duration) -> f64 {
    // Microsecond resolution is plenty and keeps the lines short.
    (d.as_secs_f64() * 1e6).round() / 1e3
}

/// Writes one line and flushes; false when stdout is closed.
fn emit(out: &mut impl Write, line: &str) -> Result<bool, CliError> {
    match writeln!(out, "{line}").and_then(|_| out.flush()) {
        Ok(()) => Ok(true),
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(false),
        Err(e) => Err(CliError::with_code(
            1,
            format!("error[io_error]: writing to stdout: {e}"),
        )),
    }
}

/// Decode and tracking time of one pair, milliseconds.
#[derive(Clone, Copy, Debug, serde::Serialize)]
struct Timing {
    decode: f64,
    track: f64,
}

/// Keys written first, in this order; any others follow alphabetically.
const JSON_KEY_ORDER: [&str; 14] = [
    "frame",
    "name",
    "status",
    "reason",
    "disparity_px",
    "disparity_axis_px",
    "relative_disparity_axis_px",
    "angle_diff_rad",
    "disparity_std_px",
    "z_um",
    "z_std_um",
    "left",
    "right",
    "timing_ms",
];

/// The pair's result as one JSON object: the [`PairResult`] fields as they
/// serialise, plus `name` and `timing_ms`.
fn json_record(result: &PairResult, name: &str, timing: Timing, contour: bool) -> Result<String, CliError> {
    ordered_json(&record_map(result, name, Some(timing), contour)?)
}

/// A pair's measurement with named objects as one JSON object: the first
/// object's fields at the top level as in [`json_record`] (as the service's
/// results have them), then `objects` (each object's fields, its `name`
/// first) and `relative`.
fn json_measurement(
    (objects, relative): (&[ObjectResult], &[Relative]),
    name: &str,
    timing: Timing,
    contour: bool,
) -> Result<String, CliError> {
    let mut line = json_record(&objects[0].result, name, timing, contour)?;
    line.pop(); // the closing brace
    line.push_str(",\"objects\":[");
    for (i, o) in objects.iter().enumerate() {
        let mut object = record_map(&o.result, &o.name, None, contour)?;
        object.remove("frame");
        if i > 0 {
            line.push(',');
        }
        line.push_str(&ordered_json(&object)?);
    }
    line.push_str("],\"relative\":");
    line.push_str(&serde_json::to_string(relative).map_err(internal_json)?);
    line.push('}');
    Ok(line)
}

/// The [`PairResult`] fields as they serialise, plus `name` and, when
/// given, `timing_ms`; without the contours unless `contour`.
fn record_map(
    result: &PairResult,
    name: &str,
    timing: Option<Timing>,
    contour: bool,
) -> Result<serde_json::Map<String, serde_json::Value>, CliError> {
    let serde_json::Value::Object(mut map) = serde_json::to_value(result).map_err(internal_json)? else {
        return Err(CliError::with_code(
            1,
            "error[internal]: a pair result is not a JSON object",
        ));
    };
    map.insert("name".into(), name.into());
    if let Some(timing) = timing {
        map.insert(
            "timing_ms".into(),
            serde_json::to_value(timing).map_err(internal_json)?,
        );
    }
    if !contour {
        for side in ["left", "right"] {
            if let Some(serde_json::Value::Object(image)) = map.get_mut(side) {
                image.remove("contour");
            }
        }
    }
    Ok(map)
}

/// `map` as a JSON object with the keys of [`JSON_KEY_ORDER`] first, in
/// that order, then the others.
fn ordered_json(map: &serde_json::Map<String, serde_json::Value>) -> Result<String, CliError> {
    let keys = JSON_KEY_ORDER
        .iter()
        .copied()
        .filter(|k| map.contains_key(*k))
        .chain(
            map.keys()
                .map(String::as_str)
                .filter(|k| !JSON_KEY_ORDER.contains(k)),
        );
    let mut line = String::from("{");
    for (i, key) in keys.enumerate() {
        if i > 0 {
            line.push(',');
        }
        line.push_str(&serde_json::to_string(key).map_err(internal_json)?);
        line.push(':');
        line.push_str(&serde_json::to_string(&map[key]).map_err(internal_json)?);
    }
    line.push('}');
    Ok(line)
}

fn internal_json(e: serde_json::Error) -> CliError {
    CliError::with_code(1, format!("error[internal]: {e}"))
}

/// Progress and summary lines on stderr.
struct Progress {
    enabled: bool,
    total: usize,
    done: usize,
    tracked: usize,
    initialised: usize,
    lost: usize,
    started: Instant,
}

impl Progress {
    fn new(total: usize, enabled: bool) -> Self {
        Self {
            enabled,
            total,
            done: 0,
            tracked: 0,
            initialised: 0,
            lost: 0,
            started: Instant::now(),
        }
    }

    fn record(&mut self, status: Status) {
        self.done += 1;
        match status {
            Status::Initialised => self.initialised += 1,
            Status::Tracked => self.tracked += 1,
            Status::Lost => self.lost += 1,
        }
        if self.enabled && self.done.is_multiple_of(10) && self.done < self.total {
            let rate = self.done as f64 / self.started.elapsed().as_secs_f64().max(1e-9);
            eprintln!("processed {}/{} pairs ({rate:.1} pairs/s)", self.done, self.total);
        }
    }

    fn finish(&self) {
        if self.enabled {
            let elapsed = self.started.elapsed().as_secs_f64();
            eprintln!(
                "processed {} pairs in {elapsed:.2} s ({:.1} pairs/s): {} initialised, {} tracked, {} lost",
                self.done,
                self.done as f64 / elapsed.max(1e-9),
                self.initialised,
                self.tracked,
                self.lost
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn classify_names() {
        assert_eq!(classify(Path::new("a/0001_left.PNG")), Some(("0001".into(), 0)));
        assert_eq!(classify(Path::new("x_y_right.tiff")), Some(("x_y".into(), 1)));
        assert_eq!(classify(Path::new("_left.jpg")), Some(("".into(), 0)));
        assert_eq!(classify(Path::new("0001_left.json")), None);
        assert_eq!(classify(Path::new("0001_middle.png")), None);
        assert_eq!(classify(Path::new("truth.json")), None);
    }
}

//! Microscope metadata from image files: pixel size, stage tilt, working
//! distance and beam settings as FEI / Thermo Fisher, ZEISS SmartSEM and
//! TESCAN write them into their TIFF files, converted to SI units.
//!
//! Where the values come from (first IFD of the TIFF only):
//! - FEI / Thermo Fisher: tag 34682 (`FEI_HELIOS`) or 34680 (`FEI_SFEG`),
//!   ini text. `[Scan] PixelWidth` / `PixelHeight` (metres; else `[EScan]`;
//!   else derived as `[Scan] HorFieldsize` or `[EBeam] HFW` over `[Image]
//!   ResolutionX`), `[Stage] StageT` (radians; else `StageTa`, `StageTb`),
//!   `[Stage] WorkingDistance` (metres; else the beam section's `WD`),
//!   `[Beam] HV` (volts).
//! - ZEISS SmartSEM: tag 34118 (`CZ_SEM`), a parameter name line
//!   (`AP_IMAGE_PIXEL_SIZE`) followed by `Label = value unit`, or both on
//!   one line. `AP_IMAGE_PIXEL_SIZE` (pm, nm, µm, mm or m; square pixels),
//!   `AP_STAGE_AT_T` (degrees), `AP_WD` (length with unit), `AP_MAG`
//!   (`2.00 K X` = 2000), `AP_ACTUALKV` / `AP_MANUALKV` (kV or V).
//!   `AP_PIXEL_SIZE` is the display pixel and never used.
//! - TESCAN: tag 50431, ini text with `[MAIN]` and `[SEM]` sections (`[SEM]`
//!   first): `PixelSizeX` / `PixelSizeY` (metres), `StageTilt` (degrees),
//!   `WD` (metres), `HV` (volts), `Magnification`.
//! - OpenFIBSEM (fibsemOS, the lift-out automation's own format), when none
//!   of the tags above is present: JSON in the ImageDescription (tag 270),
//!   see [`openfibsem`].
//!
//! Which beam took the image (electron or ion) comes from FEI's `[Beam]
//! Beam` (`EBeam`, `IBeam`) and OpenFIBSEM's `beam_type`.
//!
//! Reading never fails and never panics: whatever is missing or garbled is
//! `None`, with a one-sentence warning naming the key. Tag text that is not
//! valid UTF-8 is decoded byte by byte as Latin-1 (so a `µ` written as the
//! single byte 0xB5 still reads as `µ`).
//!
//! - [`read_meta`]: bytes of any image file -> [`ImageMeta`].
//! - [`parse_fei`], [`parse_zeiss`], [`parse_tescan`]: a vendor tag's text ->
//!   [`ImageMeta`]; [`parse_openfibsem`]: an ImageDescription's.

pub mod openfibsem;

pub use openfibsem::parse_openfibsem;

use std::collections::HashMap;
use std::io::Cursor;

use tiff::decoder::Decoder;
use tiff::tags::{Tag, Type};

/// TIFF tag of FEI / Thermo Fisher SFEG microscopes (ini text).
pub const TAG_FEI_SFEG: u16 = 34680;
/// TIFF tag of FEI / Thermo Fisher Helios and most later microscopes (ini text).
pub const TAG_FEI_HELIOS: u16 = 34682;
/// TIFF tag of ZEISS SmartSEM (`CZ_SEM`).
pub const TAG_CZ_SEM: u16 = 34118;
/// TIFF tag of TESCAN microscopes (ini text).
pub const TAG_TESCAN: u16 = 50431;
/// TIFF ImageDescription, where OpenFIBSEM writes its JSON.
pub const TAG_IMAGE_DESCRIPTION: u16 = 270;

/// The vendor tags looked for, in this order; the first one present is used
/// (the microscope's own before the automation's description).
const VENDOR_TAGS: [(u16, Vendor); 5] = [
    (TAG_FEI_HELIOS, Vendor::Fei),
    (TAG_FEI_SFEG, Vendor::Fei),
    (TAG_CZ_SEM, Vendor::Zeiss),
    (TAG_TESCAN, Vendor::Tescan),
    (TAG_IMAGE_DESCRIPTION, Vendor::OpenFibsem),
];

/// Longest vendor tag text read, in bytes: real tags are a few kB, so more
/// than this is junk and only its beginning is looked at.
const MAX_TAG_BYTES: usize = 16 << 20;

/// Longest piece of a bad value quoted in a warning, in characters.
const MAX_QUOTE_CHARS: usize = 40;

/// The microscope maker whose metadata was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "snake_case"))]
pub enum Vendor {
    /// FEI / Thermo Fisher (TIFF tag 34682 `FEI_HELIOS` or 34680 `FEI_SFEG`).
    Fei,
    /// ZEISS SmartSEM (TIFF tag 34118 `CZ_SEM`).
    Zeiss,
    /// TESCAN (TIFF tag 50431).
    Tescan,
    /// OpenFIBSEM / fibsemOS (JSON in the TIFF ImageDescription, tag 270).
    OpenFibsem,
}

/// The beam that took an image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "snake_case"))]
pub enum Beam {
    /// The electron beam (SEM).
    Electron,
    /// The focused ion beam (FIB).
    Ion,
}

impl Beam {
    /// The snake_case name (`electron`, `ion`).
    pub fn name(self) -> &'static str {
        match self {
            Beam::Electron => "electron",
            Beam::Ion => "ion",
        }
    }
}

impl Vendor {
    /// The snake_case name (`fei`, `zeiss`, `tescan`).
    pub fn name(self) -> &'static str {
        match self {
            Vendor::Fei => "fei",
            Vendor::Zeiss => "zeiss",
            Vendor::Tescan => "tescan",
            Vendor::OpenFibsem => "openfibsem",
        }
    }

    /// The name used in warnings.
    fn label(self) -> &'static str {
        match self {
            Vendor::Fei => "FEI",
            Vendor::Zeiss => "ZEISS",
            Vendor::Tescan => "TESCAN",
            Vendor::OpenFibsem => "OpenFIBSEM",
        }
    }
}

/// What an image file says about how it was taken, in SI units. Every field
/// is `None` when absent or unreadable; `warnings` say what could not be
/// read and why.
#[derive(Clone, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct ImageMeta {
    /// Whose metadata was found (`None`: none).
    pub vendor: Option<Vendor>,
    /// The beam that took the image, where the metadata says.
    pub beam: Option<Beam>,
    /// Width of one pixel at the specimen, metres.
    pub pixel_width_m: Option<f64>,
    /// Height of one pixel at the specimen, metres.
    pub pixel_height_m: Option<f64>,
    /// Stage tilt, radians.
    pub stage_tilt_rad: Option<f64>,
    /// Working distance, metres.
    pub working_distance_m: Option<f64>,
    /// Accelerating voltage, volts.
    pub high_voltage_v: Option<f64>,
    /// Magnification as the microscope reports it.
    pub magnification: Option<f64>,
    /// What could not be read, and why.
    pub warnings: Vec<String>,
}

impl ImageMeta {
    /// An empty record for `vendor`, to be filled by a parser.
    fn for_vendor(vendor: Vendor) -> Self {
        Self {
            vendor: Some(vendor),
            ..Self::default()
        }
    }
}

/// The metadata in `bytes` (any image file). Never fails: a file that is not
/// a TIFF, or a TIFF without vendor tags, gives an empty [`ImageMeta`]; a
/// TIFF whose tags cannot be read gives an empty one with a warning.
pub fn read_meta(bytes: &[u8]) -> ImageMeta {
    if !is_tiff(bytes) {
        return ImageMeta::default();
    }
    match vendor_tag(bytes) {
        Ok(None) => ImageMeta::default(),
        Ok(Some(found)) => {
            let text = decode_text(&found.raw);
            let mut meta = match found.vendor {
                Vendor::Fei => parse_fei(&text),
                Vendor::Zeiss => parse_zeiss(&text),
                Vendor::Tescan => parse_tescan(&text),
                // Any other description is no metadata, nor worth a warning.
                Vendor::OpenFibsem => match parse_openfibsem(&text) {
                    Some(meta) => meta,
                    None => return ImageMeta::default(),
                },
            };
            meta.warnings.splice(0..0, found.warnings);
            meta
        }
        Err(warning) => ImageMeta {
            warnings: vec![warning],
            ..ImageMeta::default()
        },
    }
}

/// Whether `bytes` start with a TIFF or BigTIFF signature (either byte order).
fn is_tiff(bytes: &[u8]) -> bool {
    matches!(
        bytes.get(..4),
        Some(b"II*\0") | Some(b"MM\0*") | Some(b"II+\0") | Some(b"MM\0+")
    )
}

/// A vendor tag's raw value, with anything worth telling about reading it.
struct FoundTag {
    vendor: Vendor,
    raw: Vec<u8>,
    warnings: Vec<String>,
}

/// The first vendor tag in the first IFD of the TIFF in `bytes`: `Ok(None)`
/// when there is none, `Err(warning)` when the TIFF's tags cannot be read.
fn vendor_tag(bytes: &[u8]) -> Result<Option<FoundTag>, String> {
    let mut decoder =
        Decoder::new(Cursor::new(bytes)).map_err(|e| format!("the TIFF's tags could not be read: {e}"))?;
    let mut ifd = decoder.image_ifd();
    for (number, vendor) in VENDOR_TAGS {
        let tag = Tag::from_u16_exhaustive(number);
        let Some(entry) = ifd.find_entry(tag) else {
            continue;
        };
        let mut found = FoundTag {
            vendor,
            raw: Vec::new(),
            warnings: Vec::new(),
        };
        let label = vendor.label();
        if !matches!(
            entry.field_type(),
            Type::ASCII | Type::BYTE | Type::UNDEFINED | Type::SBYTE
        ) {
            found.warnings.push(format!(
                "{label} tag {number} has type {:?}, not text: it was not read",
                entry.field_type()
            ));
            return Ok(Some(found));
        }
        // One byte per count; never more than the file itself holds.
        let declared = usize::try_from(entry.count()).unwrap_or(usize::MAX);
        let len = declared.min(MAX_TAG_BYTES).min(bytes.len());
        let mut raw = vec![0u8; len];
        match ifd.find_tag_bytes(tag, &mut raw, 0) {
            Ok(Some(n)) => {
                raw.truncate(n.min(len));
                if declared > len {
                    found.warnings.push(format!(
                        "{label} tag {number} declares {declared} bytes: only the first {len} were read"
                    ));
                }
                found.raw = raw;
            }
            Ok(None) => {}
            Err(e) => found
                .warnings
                .push(format!("{label} tag {number} could not be read: {e}")),
        }
        return Ok(Some(found));
    }
    Ok(None)
}

/// Tag bytes as text: valid UTF-8 as such, every other byte as Latin-1 (a
/// lone 0xB5 is `µ`, 0xB0 is `°`), so nothing is lost and nothing fails.
fn decode_text(raw: &[u8]) -> String {
    let mut text = String::with_capacity(raw.len());
    for chunk in raw.utf8_chunks() {
        text.push_str(chunk.valid());
        text.extend(chunk.invalid().iter().map(|&b| char::from(b)));
    }
    text
}

/// The lines of tag text: split at CR, LF and NUL (tags end in NULs, and
/// both line endings occur), trimmed, empty ones dropped.
fn lines(text: &str) -> impl Iterator<Item = &str> {
    text.split(['\n', '\r', '\0'])
        .map(str::trim)
        .filter(|l| !l.is_empty())
}

/// `raw` shortened and stripped of control characters, for a warning.
pub(crate) fn quote(raw: &str) -> String {
    let mut out: String = raw
        .chars()
        .take(MAX_QUOTE_CHARS)
        .map(|c| if c.is_control() { '\u{FFFD}' } else { c })
        .collect();
    if raw.chars().nth(MAX_QUOTE_CHARS).is_some() {
        out.push('…');
    }
    out
}

/// A plain decimal number (`9.76562e-008`, `-12`, `.5`); no thousands or
/// decimal commas, nothing infinite or NaN.
fn parse_number(s: &str) -> Option<f64> {
    let s = s.trim();
    if s.is_empty() || !s.bytes().all(|b| b.is_ascii_digit() || b"+-.eE".contains(&b)) {
        return None;
    }
    s.parse::<f64>().ok().filter(|v| v.is_finite())
}

/// What went wrong with one value.
enum ValueError {
    /// Key present with an empty value: treated as absent, no warning.
    Empty,
    /// A sentence for the warnings (without the key).
    Bad(String),
}

/// A number as a positive length (or voltage...), else why not.
fn positive(v: f64, raw: &str) -> Result<f64, ValueError> {
    if v > 0.0 {
        Ok(v)
    } else {
        Err(ValueError::Bad(format!("'{}' is not positive", quote(raw))))
    }
}

/// A plain number from an ini value.
fn number_value(raw: &str) -> Result<f64, ValueError> {
    if raw.trim().is_empty() {
        return Err(ValueError::Empty);
    }
    parse_number(raw).ok_or_else(|| ValueError::Bad(format!("'{}' is not a number", quote(raw))))
}

/// An ini text (FEI, TESCAN): `[Section]` lines and `Key=Value` lines. Names
/// are compared case-insensitively; the first occurrence of a key wins.
struct Ini {
    values: HashMap<(String, String), String>,
}

impl Ini {
    /// Parses `text`; lines that are neither a section nor `Key=Value` are skipped.
    fn parse(text: &str) -> Self {
        let mut values = HashMap::new();
        let mut section = String::new();
        for line in lines(text) {
            if let Some(rest) = line.strip_prefix('[') {
                if let Some(end) = rest.find(']') {
                    section = rest[..end].trim().to_ascii_lowercase();
                    continue;
                }
            }
            let Some((key, value)) = line.split_once('=') else {
                continue;
            };
            let key = key.trim();
            if key.is_empty() {
                continue;
            }
            values
                .entry((section.clone(), key.to_ascii_lowercase()))
                .or_insert_with(|| value.trim().to_string());
        }
        Self { values }
    }

    /// The value of `key` in `section` (`""`: before any section).
    fn get(&self, section: &str, key: &str) -> Option<&str> {
        self.values
            .get(&(section.to_ascii_lowercase(), key.to_ascii_lowercase()))
            .map(String::as_str)
    }

    /// The first of `candidates` (section, key) that is present, non-empty
    /// and accepted by `convert`; each rejected one adds a warning, so a
    /// garbled value falls through to the next candidate.
    fn first(
        &self,
        vendor: Vendor,
        candidates: &[(&str, &str)],
        convert: impl Fn(&str) -> Result<f64, ValueError>,
        warnings: &mut Vec<String>,
    ) -> Option<f64> {
        self.first_at(vendor, candidates, convert, warnings)
            .map(|(v, _)| v)
    }

    /// [`Ini::first`], also saying which candidate gave the value.
    fn first_at(
        &self,
        vendor: Vendor,
        candidates: &[(&str, &str)],
        convert: impl Fn(&str) -> Result<f64, ValueError>,
        warnings: &mut Vec<String>,
    ) -> Option<(f64, usize)> {
        for (i, &(section, key)) in candidates.iter().enumerate() {
            // A candidate named twice (the named beam section is `EBeam`)
            // is looked at, and warned about, once.
            let same =
                |&(s, k): &(&str, &str)| s.eq_ignore_ascii_case(section) && k.eq_ignore_ascii_case(key);
            if candidates[..i].iter().any(same) {
                continue;
            }
            let Some(raw) = self.get(section, key) else {
                continue;
            };
            match convert(raw) {
                Ok(v) => return Some((v, i)),
                Err(ValueError::Empty) => {}
                Err(ValueError::Bad(why)) => {
                    let place = if section.is_empty() {
                        key.to_string()
                    } else {
                        format!("[{section}] {key}")
                    };
                    warnings.push(format!("{} {place}: {why}", vendor.label()));
                }
            }
        }
        None
    }
}

/// A pixel size from an ini value: a positive number of metres.
fn ini_length(raw: &str) -> Result<f64, ValueError> {
    number_value(raw).and_then(|v| positive(v, raw))
}

/// Parses the text of the FEI / Thermo Fisher tag (34682 or 34680): ini
/// sections with metres, radians and volts.
pub fn parse_fei(text: &str) -> ImageMeta {
    let vendor = Vendor::Fei;
    let ini = Ini::parse(text);
    let mut meta = ImageMeta::for_vendor(vendor);
    let w = &mut meta.warnings;

    // The beam and scan sections of this image are named in [Beam]
    // (`Beam=EBeam`, `Scan=EScan`; `IBeam`/`IScan` for an ion image).
    let named = |key: &str, default: &'static str| -> String {
        ini.get("Beam", key)
            .filter(|s| !s.is_empty() && !s.contains(['[', ']']))
            .unwrap_or(default)
            .to_string()
    };
    let beam = named("Beam", "EBeam");
    let scan = named("Scan", "EScan");
    meta.beam = match ini.get("Beam", "Beam") {
        Some(b) if b.eq_ignore_ascii_case("EBeam") => Some(Beam::Electron),
        Some(b) if b.eq_ignore_ascii_case("IBeam") => Some(Beam::Ion),
        _ => None,
    };

    // Pixel size: [Scan], then the named scan section, then [EScan].
    let mut scan_sections = vec!["Scan".to_string()];
    for s in [scan.clone(), "EScan".to_string()] {
        if !scan_sections.iter().any(|t| t.eq_ignore_ascii_case(&s)) {
            scan_sections.push(s);
        }
    }
    for section in &scan_sections {
        let width = ini.first(vendor, &[(section.as_str(), "PixelWidth")], ini_length, w);
        let height = ini.first(vendor, &[(section.as_str(), "PixelHeight")], ini_length, w);
        if width.is_none() && height.is_none() {
            continue;
        }
        if width.is_none() || height.is_none() {
            let missing = if width.is_none() {
                "PixelWidth"
            } else {
                "PixelHeight"
            };
            w.push(format!(
                "FEI [{section}] {missing} is missing: square pixels assumed"
            ));
        }
        meta.pixel_width_m = width.or(height);
        meta.pixel_height_m = height.or(width);
        break;
    }
    if meta.pixel_width_m.is_none() {
        let field_sources = [("Scan", "HorFieldsize"), (beam.as_str(), "HFW"), ("EBeam", "HFW")];
        let field = ini
            .first_at(vendor, &field_sources, ini_length, w)
            .map(|(v, i)| (v, field_sources[i].0, field_sources[i].1));
        let columns = ini.first(vendor, &[("Image", "ResolutionX")], ini_length, w);
        match (field, columns) {
            (Some((field, section, key)), Some(columns)) => {
                let size = field / columns;
                meta.pixel_width_m = Some(size);
                meta.pixel_height_m = Some(size);
                w.push(format!(
                    "FEI pixel size derived from [{section}] {key} / [Image] ResolutionX \
                     (no [Scan] PixelWidth): square pixels assumed"
                ));
            }
            _ => w.push(
                "FEI: no pixel size ([Scan] PixelWidth, [EScan] PixelWidth and the field width \
                 with [Image] ResolutionX are missing or unreadable)"
                    .to_string(),
            ),
        }
    }

    meta.stage_tilt_rad = ini.first(
        vendor,
        &[("Stage", "StageT"), ("Stage", "StageTa"), ("Stage", "StageTb")],
        number_value,
        w,
    );
    if meta.stage_tilt_rad.is_none() {
        w.push(
            "FEI: no stage tilt ([Stage] StageT, StageTa and StageTb are missing or unreadable)".to_string(),
        );
    }

    meta.working_distance_m = ini.first(
        vendor,
        &[
            ("Stage", "WorkingDistance"),
            (beam.as_str(), "WD"),
            ("EBeam", "WD"),
            ("Beam", "WD"),
        ],
        ini_length,
        w,
    );
    meta.high_voltage_v = ini.first(
        vendor,
        &[("Beam", "HV"), (beam.as_str(), "HV"), ("EBeam", "HV")],
        number_value,
        w,
    );
    meta
}

/// Parses the text of the TESCAN tag (50431): ini with `[MAIN]` and `[SEM]`
/// sections; metres, degrees (tilt) and volts.
pub fn parse_tescan(text: &str) -> ImageMeta {
    let vendor = Vendor::Tescan;
    let ini = Ini::parse(text);
    let mut meta = ImageMeta::for_vendor(vendor);
    let w = &mut meta.warnings;
    let places = |key: &'static str| [("SEM", key), ("MAIN", key), ("", key)];

    let width = ini.first(vendor, &places("PixelSizeX"), ini_length, w);
    let height = ini.first(vendor, &places("PixelSizeY"), ini_length, w);
    match (width, height) {
        (None, None) => {
            w.push("TESCAN: no pixel size (PixelSizeX and PixelSizeY are missing or unreadable)".to_string())
        }
        (Some(_), None) | (None, Some(_)) => {
            let missing = if width.is_none() {
                "PixelSizeX"
            } else {
                "PixelSizeY"
            };
            w.push(format!("TESCAN {missing} is missing: square pixels assumed"));
        }
        _ => {}
    }
    meta.pixel_width_m = width.or(height);
    meta.pixel_height_m = height.or(width);

    meta.stage_tilt_rad = ini
        .first(vendor, &places("StageTilt"), number_value, w)
        .map(f64::to_radians);
    if meta.stage_tilt_rad.is_none() {
        w.push("TESCAN: no stage tilt (StageTilt is missing or unreadable)".to_string());
    }
    meta.working_distance_m = ini.first(vendor, &places("WD"), ini_length, w);
    meta.high_voltage_v = ini.first(vendor, &places("HV"), number_value, w);
    meta.magnification = ini.first(vendor, &places("Magnification"), ini_length, w);
    meta
}

/// Whether `s` looks like a SmartSEM parameter name (`AP_WD`, `DP_DETECTOR`):
/// upper-case ASCII letters, digits and underscores, with an underscore.
fn is_zeiss_name(s: &str) -> bool {
    s.len() >= 3
        && s.starts_with(|c: char| c.is_ascii_uppercase())
        && s.contains('_')
        && s.chars()
            .all(|c| c.is_ascii_uppercase() || c.is_ascii_digit() || c == '_')
}

/// The parameters of a ZEISS `CZ_SEM` text: name -> the value after `=`
/// (or `:`), from a name line followed by a `Label = value` line, or from a
/// single `NAME = value` line. The first occurrence wins.
fn zeiss_params(text: &str) -> HashMap<&str, &str> {
    let mut params = HashMap::new();
    let mut pending: Option<&str> = None;
    for line in lines(text) {
        if is_zeiss_name(line) {
            pending = Some(line);
            continue;
        }
        let Some(at) = line.find('=').or_else(|| line.find(':')) else {
            pending = None;
            continue;
        };
        let (label, value) = (line[..at].trim(), line[at + 1..].trim());
        let name = if is_zeiss_name(label) {
            Some(label)
        } else {
            pending
        };
        pending = None;
        if let Some(name) = name {
            params.entry(name).or_insert(value);
        }
    }
    params
}

/// Splits `3.572 nm`, `3.572nm`, `45.0°` or `2.00 K X` into the number and
/// the rest (the unit, trimmed; empty when there is none).
fn split_quantity(raw: &str) -> Option<(f64, &str)> {
    let raw = raw.trim();
    let first = raw.split_whitespace().next()?;
    if let Some(v) = parse_number(first) {
        return Some((v, raw[first.len()..].trim()));
    }
    // A unit glued to the number: the number ends where a letter or a
    // symbol such as ° or µ begins.
    let end = first.find(|c: char| !(c.is_ascii_digit() || "+-.eE".contains(c)))?;
    let mut cut = end;
    while cut > 0 {
        if let Some(v) = parse_number(&first[..cut]) {
            let unit_start = &raw[cut..];
            if unit_start.starts_with(|c: char| c.is_alphabetic() || "°º".contains(c)) {
                return Some((v, unit_start.trim()));
            }
            return None;
        }
        cut -= 1;
    }
    None
}

/// Metres per unit of length as SmartSEM writes them.
fn length_unit(unit: &str) -> Option<f64> {
    match unit {
        "pm" => Some(1e-12),
        "nm" => Some(1e-9),
        "µm" | "μm" | "um" => Some(1e-6),
        "mm" => Some(1e-3),
        "cm" => Some(1e-2),
        "m" => Some(1.0),
        _ => None,
    }
}

/// A positive length with its unit, in metres.
fn zeiss_length(raw: &str) -> Result<f64, ValueError> {
    let (v, unit) = zeiss_quantity(raw)?;
    if unit.is_empty() {
        return Err(ValueError::Bad(format!("'{}' has no unit", quote(raw))));
    }
    let scale =
        length_unit(unit).ok_or_else(|| ValueError::Bad(format!("unknown length unit '{}'", quote(unit))))?;
    positive(v * scale, raw)
}

/// An angle in degrees (bare, `°` or `deg`), or in `rad`, in radians.
fn zeiss_angle(raw: &str) -> Result<f64, ValueError> {
    let (v, unit) = zeiss_quantity(raw)?;
    match unit {
        "" | "°" | "º" | "deg" | "degree" | "degrees" => Ok(v.to_radians()),
        "rad" => Ok(v),
        other => Err(ValueError::Bad(format!("unknown angle unit '{}'", quote(other)))),
    }
}

/// A magnification: `500 X`, `2.00 K X` (thousands), `1.50 M X` (millions).
fn zeiss_magnification(raw: &str) -> Result<f64, ValueError> {
    let (v, unit) = zeiss_quantity(raw)?;
    let unit: String = unit.split_whitespace().collect::<String>().to_ascii_lowercase();
    let scale = match unit.as_str() {
        "" | "x" => 1.0,
        "kx" => 1e3,
        "mx" => 1e6,
        _ => {
            return Err(ValueError::Bad(format!(
                "unknown magnification unit '{}'",
                quote(&unit)
            )))
        }
    };
    positive(v * scale, raw)
}

/// A voltage in kV or V, in volts.
fn zeiss_voltage(raw: &str) -> Result<f64, ValueError> {
    let (v, unit) = zeiss_quantity(raw)?;
    match unit.to_ascii_lowercase().as_str() {
        "kv" => Ok(v * 1e3),
        "v" => Ok(v),
        "" => Err(ValueError::Bad(format!("'{}' has no unit", quote(raw)))),
        _ => Err(ValueError::Bad(format!("unknown voltage unit '{}'", quote(unit)))),
    }
}

/// Number and unit of a ZEISS value, or why not.
fn zeiss_quantity(raw: &str) -> Result<(f64, &str), ValueError> {
    if raw.trim().is_empty() {
        return Err(ValueError::Empty);
    }
    split_quantity(raw).ok_or_else(|| ValueError::Bad(format!("'{}' is not a number", quote(raw))))
}

/// Parses the text of the ZEISS SmartSEM tag (34118, `CZ_SEM`): each value
/// with the unit written next to it, converted to SI.
pub fn parse_zeiss(text: &str) -> ImageMeta {
    let params = zeiss_params(text);
    let mut meta = ImageMeta::for_vendor(Vendor::Zeiss);
    let w = &mut meta.warnings;
    let read = |name: &str, convert: fn(&str) -> Result<f64, ValueError>, w: &mut Vec<String>| {
        let raw = params.get(name)?;
        match convert(raw) {
            Ok(v) => Some(v),
            Err(ValueError::Empty) => None,
            Err(ValueError::Bad(why)) => {
                w.push(format!("ZEISS {name}: {why}"));
                None
            }
        }
    };

    let pixel = read("AP_IMAGE_PIXEL_SIZE", zeiss_length, w);
    meta.pixel_width_m = pixel;
    meta.pixel_height_m = pixel;
    if pixel.is_none() {
        if params.contains_key("AP_IMAGE_PIXEL_SIZE") {
            w.push("ZEISS: no pixel size (AP_IMAGE_PIXEL_SIZE is unreadable)".to_string());
        } else if params.contains_key("AP_PIXEL_SIZE") {
            w.push(
                "ZEISS: no pixel size: only AP_PIXEL_SIZE (the display pixel, wrong for most image \
                 sizes) is present, not AP_IMAGE_PIXEL_SIZE"
                    .to_string(),
            );
        } else {
            w.push("ZEISS: no pixel size (AP_IMAGE_PIXEL_SIZE is missing)".to_string());
        }
    }

    meta.stage_tilt_rad = read("AP_STAGE_AT_T", zeiss_angle, w);
    if meta.stage_tilt_rad.is_none() {
        w.push("ZEISS: no stage tilt (AP_STAGE_AT_T is missing or unreadable)".to_string());
    }
    meta.working_distance_m = read("AP_WD", zeiss_length, w);
    meta.magnification = read("AP_MAG", zeiss_magnification, w);
    meta.high_voltage_v =
        read("AP_ACTUALKV", zeiss_voltage, w).or_else(|| read("AP_MANUALKV", zeiss_voltage, w));
    meta
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A little-endian TIFF (8x8, 8-bit grey) with `extra` = (tag, type, bytes).
    fn tiff_with(extra: &[(u16, u16, &[u8])]) -> Vec<u8> {
        build_tiff(false, extra)
    }

    /// A minimal uncompressed 8x8 grey TIFF written by hand, either byte order.
    fn build_tiff(big_endian: bool, extra: &[(u16, u16, &[u8])]) -> Vec<u8> {
        let u16b = |v: u16| {
            if big_endian {
                v.to_be_bytes()
            } else {
                v.to_le_bytes()
            }
        };
        let u32b = |v: u32| {
            if big_endian {
                v.to_be_bytes()
            } else {
                v.to_le_bytes()
            }
        };
        let mut out = Vec::new();
        out.extend_from_slice(if big_endian { b"MM" } else { b"II" });
        out.extend_from_slice(&u16b(42));
        let pixels_at = 8u32;
        let n_entries = 8 + extra.len();
        let ifd_at = pixels_at + 64;
        out.extend_from_slice(&u32b(ifd_at));
        let data_at = ifd_at + 2 + 12 * n_entries as u32 + 4;
        let mut entries: Vec<(u16, u16, u32, [u8; 4])> = Vec::new();
        let short = |v: u16| {
            let mut b = [0u8; 4];
            b[..2].copy_from_slice(&u16b(v));
            b
        };
        entries.push((256, 3, 1, short(8)));
        entries.push((257, 3, 1, short(8)));
        entries.push((258, 3, 1, short(8)));
        entries.push((259, 3, 1, short(1)));
        entries.push((262, 3, 1, short(1)));
        entries.push((273, 4, 1, u32b(pixels_at)));
        entries.push((278, 3, 1, short(8)));
        entries.push((279, 4, 1, u32b(64)));
        let mut data = Vec::new();
        for &(tag, ty, bytes) in extra {
            if bytes.len() <= 4 {
                let mut b = [0u8; 4];
                b[..bytes.len()].copy_from_slice(bytes);
                entries.push((tag, ty, bytes.len() as u32, b));
            } else {
                entries.push((tag, ty, bytes.len() as u32, u32b(data_at + data.len() as u32)));
                data.extend_from_slice(bytes);
            }
        }
        entries.sort_by_key(|e| e.0);
        out.extend(std::iter::repeat_n(128u8, 64));
        out.extend_from_slice(&u16b(n_entries as u16));
        for (tag, ty, count, value) in entries {
            out.extend_from_slice(&u16b(tag));
            out.extend_from_slice(&u16b(ty));
            out.extend_from_slice(&u32b(count));
            out.extend_from_slice(&value);
        }
        out.extend_from_slice(&u32b(0));
        out.extend_from_slice(&data);
        out
    }

    const FEI: &str =
        "[User]\r\nDate=12/14/2022\r\n\r\n[Beam]\r\nHV=5000\r\nBeam=EBeam\r\nScan=EScan\r\n\r\n\
        [EBeam]\r\nWD=0.004\r\n\r\n[Scan]\r\nPixelWidth=9.76562e-008\r\nPixelHeight=9.76562e-008\r\n\r\n\
        [Stage]\r\nStageT=0.558473\r\nWorkingDistance=0.0165\r\n\0";

    #[test]
    fn fei_text_gives_si_values() {
        let m = parse_fei(FEI);
        assert_eq!(m.vendor, Some(Vendor::Fei));
        assert_eq!(m.pixel_width_m, Some(9.76562e-8));
        assert_eq!(m.pixel_height_m, Some(9.76562e-8));
        assert_eq!(m.stage_tilt_rad, Some(0.558473));
        assert_eq!(m.working_distance_m, Some(0.0165));
        assert_eq!(m.high_voltage_v, Some(5000.0));
        assert_eq!(m.magnification, None);
        assert!(m.warnings.is_empty(), "{:?}", m.warnings);
    }

    #[test]
    fn fei_falls_back_to_escan_tilt_a_and_beam_wd() {
        let text = "[Beam]\nBeam=EBeam\n[EScan]\nPixelWidth=2e-9\nPixelHeight=3e-9\n\
                    [Stage]\nStageTa=0.1\nStageTb=0.2\n[EBeam]\nWD=0.005\n";
        let m = parse_fei(text);
        assert_eq!(m.pixel_width_m, Some(2e-9));
        assert_eq!(m.pixel_height_m, Some(3e-9));
        assert_eq!(m.stage_tilt_rad, Some(0.1));
        assert_eq!(m.working_distance_m, Some(0.005));
        assert!(m.warnings.is_empty(), "{:?}", m.warnings);
    }

    #[test]
    fn fei_derives_pixel_size_from_field_width_with_a_warning() {
        let m = parse_fei("[Scan]\nHorFieldsize=0.0001024\n[Image]\nResolutionX=1024\n[Stage]\nStageT=0\n");
        let p = m.pixel_width_m.unwrap();
        assert!((p - 1e-7).abs() < 1e-18, "{p}");
        assert_eq!(m.pixel_height_m, Some(p));
        assert_eq!(m.warnings.len(), 1, "{:?}", m.warnings);
        assert!(m.warnings[0].contains("derived"), "{:?}", m.warnings);
    }

    #[test]
    fn fei_bad_numbers_are_named_in_warnings() {
        let m = parse_fei("[Scan]\nPixelWidth=abc\nPixelHeight=1,5\n[Stage]\nStageT=\n");
        assert_eq!(m.pixel_width_m, None);
        assert_eq!(m.stage_tilt_rad, None);
        let all = m.warnings.join("\n");
        assert!(
            all.contains("FEI [Scan] PixelWidth: 'abc' is not a number"),
            "{all}"
        );
        assert!(
            all.contains("FEI [Scan] PixelHeight: '1,5' is not a number"),
            "{all}"
        );
        assert!(all.contains("no pixel size"), "{all}");
        assert!(all.contains("no stage tilt"), "{all}");
    }

    #[test]
    fn zeiss_two_line_and_one_line_forms() {
        let text = "\0\0DP_NAME\r\nName = x\r\nAP_IMAGE_PIXEL_SIZE\r\nImage Pixel Size = 3.572 nm\r\n\
                    AP_PIXEL_SIZE\r\nPixel Size = 99 nm\r\nAP_STAGE_AT_T = 52.0 °\r\nAP_WD\r\nWD = 8.5 mm\r\n\
                    AP_MAG\r\nMag = 2.00 K X\r\nAP_ACTUALKV\r\nEHT = 5.00 kV\r\n";
        let m = parse_zeiss(text);
        assert_eq!(m.vendor, Some(Vendor::Zeiss));
        let p = m.pixel_width_m.unwrap();
        assert!((p - 3.572e-9).abs() < 1e-20, "{p}");
        assert_eq!(m.pixel_height_m, Some(p));
        assert!((m.stage_tilt_rad.unwrap() - 52f64.to_radians()).abs() < 1e-12);
        assert!((m.working_distance_m.unwrap() - 8.5e-3).abs() < 1e-15);
        assert_eq!(m.magnification, Some(2000.0));
        assert_eq!(m.high_voltage_v, Some(5000.0));
        assert!(m.warnings.is_empty(), "{:?}", m.warnings);
    }

    #[test]
    fn zeiss_quantities() {
        assert_eq!(split_quantity("3.572nm"), Some((3.572, "nm")));
        assert_eq!(split_quantity("45°"), Some((45.0, "°")));
        assert_eq!(split_quantity("1.5e-3 mm"), Some((1.5e-3, "mm")));
        assert_eq!(split_quantity("1,5 nm"), None);
        assert!(matches!(zeiss_magnification("1.50 M X"), Ok(v) if v == 1.5e6));
        assert!(matches!(zeiss_magnification("500 X"), Ok(v) if v == 500.0));
        for unit in ["µm", "μm", "um"] {
            assert!(matches!(zeiss_length(&format!("2 {unit}")), Ok(v) if (v - 2e-6).abs() < 1e-18));
        }
        assert!(matches!(zeiss_length("2 pm"), Ok(v) if (v - 2e-12).abs() < 1e-24));
        assert!(matches!(zeiss_length("2 m"), Ok(v) if v == 2.0));
        assert!(matches!(zeiss_length("2"), Err(ValueError::Bad(_))));
        assert!(matches!(zeiss_length("2 furlong"), Err(ValueError::Bad(_))));
        assert!(matches!(zeiss_angle("10 deg"), Ok(v) if (v - 10f64.to_radians()).abs() < 1e-15));
    }

    #[test]
    fn zeiss_screen_pixel_is_not_used() {
        let m = parse_zeiss("AP_PIXEL_SIZE\nPixel Size = 1.1 nm\nAP_STAGE_AT_T\nStage at T = 0.0 °\n");
        assert_eq!(m.pixel_width_m, None);
        assert_eq!(m.stage_tilt_rad, Some(0.0));
        assert_eq!(m.warnings.len(), 1);
        assert!(m.warnings[0].contains("AP_PIXEL_SIZE"), "{:?}", m.warnings);
    }

    #[test]
    fn tescan_prefers_sem_section_and_converts_degrees() {
        let text = "[MAIN]\r\nPixelSizeX=5e-9\r\nPixelSizeY=6e-9\r\nStageTilt=10\r\nMagnification=1000\r\n\
                    [SEM]\r\nPixelSizeX=1e-9\r\nPixelSizeY=2e-9\r\nStageTilt=30\r\nWD=0.01\r\nHV=15000\r\n";
        let m = parse_tescan(text);
        assert_eq!(m.vendor, Some(Vendor::Tescan));
        assert_eq!(m.pixel_width_m, Some(1e-9));
        assert_eq!(m.pixel_height_m, Some(2e-9));
        assert!((m.stage_tilt_rad.unwrap() - 30f64.to_radians()).abs() < 1e-15);
        assert_eq!(m.working_distance_m, Some(0.01));
        assert_eq!(m.high_voltage_v, Some(15000.0));
        assert_eq!(m.magnification, Some(1000.0));
        assert!(m.warnings.is_empty(), "{:?}", m.warnings);
    }

    #[test]
    fn latin1_and_utf8_bytes_decode() {
        assert_eq!(decode_text(b"3 \xb5m"), "3 µm");
        assert_eq!(decode_text("3 µm".as_bytes()), "3 µm");
        assert_eq!(decode_text(b"a\xff\xfeb"), "a\u{ff}\u{fe}b");
    }

    #[test]
    fn read_meta_finds_tags_in_either_byte_order() {
        for big in [false, true] {
            let bytes = build_tiff(big, &[(TAG_FEI_HELIOS, 2, FEI.as_bytes())]);
            let m = read_meta(&bytes);
            assert_eq!(m.vendor, Some(Vendor::Fei), "big endian: {big}");
            assert_eq!(m.pixel_width_m, Some(9.76562e-8));
            assert!(m.warnings.is_empty(), "{:?}", m.warnings);
        }
        let zeiss = tiff_with(&[(
            TAG_CZ_SEM,
            7,
            b"AP_IMAGE_PIXEL_SIZE\r\nImage Pixel Size = 1 \xb5m\r\n",
        )]);
        let m = read_meta(&zeiss);
        assert_eq!(m.pixel_width_m, Some(1e-6));
        assert_eq!(
            m.warnings,
            vec!["ZEISS: no stage tilt (AP_STAGE_AT_T is missing or unreadable)"]
        );
    }

    #[test]
    fn read_meta_without_vendor_tag_or_tiff_is_empty() {
        assert_eq!(read_meta(&tiff_with(&[])), ImageMeta::default());
        assert_eq!(read_meta(b""), ImageMeta::default());
        assert_eq!(read_meta(b"\x89PNG\r\n\x1a\n garbage"), ImageMeta::default());
    }

    #[test]
    fn corrupt_tiff_warns() {
        let m = read_meta(b"II*\0\xff\xff\xff\x7f");
        assert_eq!(m.vendor, None);
        assert_eq!(m.warnings.len(), 1);
        assert!(
            m.warnings[0].contains("the TIFF's tags could not be read"),
            "{:?}",
            m.warnings
        );
    }

    #[test]
    fn tag_value_past_the_end_warns() {
        let mut bytes = tiff_with(&[(TAG_TESCAN, 2, b"[MAIN]\nPixelSizeX=1e-9\nPixelSizeY=1e-9\n")]);
        bytes.truncate(bytes.len() - 10);
        let m = read_meta(&bytes);
        assert_eq!(m.vendor, Some(Vendor::Tescan));
        assert_eq!(m.pixel_width_m, None);
        assert!(m.warnings[0].contains("could not be read"), "{:?}", m.warnings);
    }

    /// A tiny xorshift generator: deterministic mutations without a dependency.
    fn next(state: &mut u64) -> u64 {
        *state ^= *state << 13;
        *state ^= *state >> 7;
        *state ^= *state << 17;
        *state
    }

    #[test]
    fn truncated_and_mutated_files_never_panic() {
        let zeiss = "AP_IMAGE_PIXEL_SIZE\r\nImage Pixel Size = 3.572 nm\r\nAP_STAGE_AT_T = 5 °\r\n";
        let seeds = [
            tiff_with(&[(TAG_FEI_HELIOS, 2, FEI.as_bytes())]),
            build_tiff(true, &[(TAG_CZ_SEM, 1, zeiss.as_bytes())]),
            tiff_with(&[(TAG_TESCAN, 7, b"[SEM]\nPixelSizeX=1e-9\nStageTilt=3\n")]),
        ];
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        for seed in &seeds {
            for len in 0..seed.len() {
                let _ = read_meta(&seed[..len]);
            }
            for _ in 0..3000 {
                let mut bytes = seed.clone();
                for _ in 0..1 + next(&mut state) % 8 {
                    let at = (next(&mut state) % bytes.len() as u64) as usize;
                    bytes[at] = next(&mut state) as u8;
                }
                let m = read_meta(&bytes);
                // Whatever was read must be finite.
                for v in [m.pixel_width_m, m.stage_tilt_rad, m.working_distance_m]
                    .into_iter()
                    .flatten()
                {
                    assert!(v.is_finite());
                }
            }
        }
        for _ in 0..2000 {
            let len = (next(&mut state) % 300) as usize;
            let mut text = String::new();
            const ALPHABET: &[u8] = b"=[]\r\n\0 .eE-+0123456789AP_WDnm\xc2\xb5 K X,abc";
            for _ in 0..len {
                let c = ALPHABET[(next(&mut state) % ALPHABET.len() as u64) as usize];
                text.push(char::from(c));
            }
            let _ = parse_fei(&text);
            let _ = parse_zeiss(&text);
            let _ = parse_tescan(&text);
        }
    }
}

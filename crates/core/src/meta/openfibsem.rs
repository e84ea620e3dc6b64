//! OpenFIBSEM (fibsemOS) metadata: the JSON its `FibsemImage` writes into
//! the TIFF ImageDescription (tag 270), as lift-out automation built on it
//! (AutoLiftout, AutoLamella) saves every image.
//!
//! Read, in the SI units written: `pixel_size.x` / `.y` (metres; else
//! `hfw` over `resolution[0]`, square pixels), `beam_type` (`ELECTRON` or
//! `ION`), `microscope_state.absolute_position.t` (the stage tilt,
//! radians), and from the settings of the image's own beam
//! (`microscope_state.eb_settings` or `.ib_settings`) `working_distance`
//! (metres) and `voltage` (volts). OpenFIBSEM writes no magnification.

use serde_json::{Map, Value};

use super::{quote, Beam, ImageMeta, Vendor};

/// Whether `text` is OpenFIBSEM's JSON: an object with a `beam_type` and a
/// `microscope_state` or a `pixel_size`. Other JSON (or none) is not.
fn document(text: &str) -> Option<Map<String, Value>> {
    let text = text.trim_matches(|c: char| c == '\0' || c.is_whitespace());
    if !text.starts_with('{') {
        return None;
    }
    let Ok(Value::Object(doc)) = serde_json::from_str::<Value>(text) else {
        return None;
    };
    (doc.contains_key("beam_type")
        && (doc.contains_key("microscope_state") || doc.contains_key("pixel_size")))
    .then_some(doc)
}

/// The value at `path` (object keys) in `doc`.
fn at<'a>(doc: &'a Map<String, Value>, path: &[&str]) -> Option<&'a Value> {
    let (first, rest) = path.split_first()?;
    rest.iter().try_fold(doc.get(*first)?, |v, key| v.get(key))
}

/// The number at `path`, `None` without a warning when absent or null; a
/// warning naming the path when it is something else, or not `accept`ed
/// (`what` says what was expected).
fn number(
    doc: &Map<String, Value>,
    path: &[&str],
    accept: fn(f64) -> bool,
    what: &str,
    warnings: &mut Vec<String>,
) -> Option<f64> {
    let value = at(doc, path).filter(|v| !v.is_null())?;
    match value.as_f64().filter(|v| v.is_finite() && accept(*v)) {
        Some(v) => Some(v),
        None => {
            warnings.push(format!(
                "OpenFIBSEM {} is '{}', not {what}",
                path.join("."),
                quote(&value.to_string())
            ));
            None
        }
    }
}

fn positive(v: f64) -> bool {
    v > 0.0
}

/// The metadata in an ImageDescription's `text`, `None` when it is not
/// OpenFIBSEM's JSON (see the module docs for the keys).
pub fn parse_openfibsem(text: &str) -> Option<ImageMeta> {
    let doc = document(text)?;
    let mut meta = ImageMeta::for_vendor(Vendor::OpenFibsem);
    let w = &mut meta.warnings;
    meta.beam = match doc.get("beam_type").and_then(Value::as_str) {
        Some(b) if b.eq_ignore_ascii_case("electron") => Some(Beam::Electron),
        Some(b) if b.eq_ignore_ascii_case("ion") => Some(Beam::Ion),
        other => {
            w.push(format!(
                "OpenFIBSEM beam_type is '{}', not ELECTRON or ION",
                quote(&other.map_or_else(|| doc["beam_type"].to_string(), str::to_string))
            ));
            None
        }
    };

    let width = number(&doc, &["pixel_size", "x"], positive, "a positive length", w);
    let height = number(&doc, &["pixel_size", "y"], positive, "a positive length", w);
    if width.is_some() != height.is_some() {
        w.push("OpenFIBSEM pixel_size has one side only: square pixels assumed".to_string());
    }
    meta.pixel_width_m = width.or(height);
    meta.pixel_height_m = height.or(width);
    if meta.pixel_width_m.is_none() {
        let field = number(&doc, &["hfw"], positive, "a positive length", w);
        let columns = doc
            .get("resolution")
            .and_then(|r| r.get(0))
            .and_then(Value::as_f64)
            .filter(|c| *c >= 1.0);
        match (field, columns) {
            (Some(field), Some(columns)) => {
                meta.pixel_width_m = Some(field / columns);
                meta.pixel_height_m = Some(field / columns);
                w.push("OpenFIBSEM pixel size derived from hfw / resolution[0] (no pixel_size): square pixels assumed".to_string());
            }
            _ => w.push(
                "OpenFIBSEM: no pixel size (pixel_size and hfw with resolution are missing or unreadable)"
                    .to_string(),
            ),
        }
    }

    meta.stage_tilt_rad = number(
        &doc,
        &["microscope_state", "absolute_position", "t"],
        |_| true,
        "a number (radians)",
        w,
    );
    if meta.stage_tilt_rad.is_none() {
        w.push("OpenFIBSEM: no stage tilt (microscope_state.absolute_position.t is missing)".to_string());
    }

    let settings = match meta.beam {
        Some(Beam::Ion) => Some("ib_settings"),
        Some(Beam::Electron) => Some("eb_settings"),
        None => None,
    };
    if let Some(settings) = settings {
        meta.working_distance_m = number(
            &doc,
            &["microscope_state", settings, "working_distance"],
            positive,
            "a positive length",
            w,
        );
        meta.high_voltage_v = number(
            &doc,
            &["microscope_state", settings, "voltage"],
            positive,
            "a positive voltage",
            w,
        );
    }
    Some(meta)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What fibsemOS wrote for an ion-beam image of a lamella site (cut
    /// down from `fibsem_tilt/undercut_stage30deg_ib.tif`).
    pub(crate) const ION_IMAGE: &str = r#"{"beam_type": "ION", "resolution": [1536, 1024], "hfw": 0.00015,
        "version": "v1", "pixel_size": {"x": 9.765624999999999e-08, "y": 9.765624999999999e-08},
        "microscope_state": {"absolute_position": {"x": 0.00316725, "y": 0.00372525, "z": 0.0320671,
        "r": 0.8552263830717237, "t": 0.5235865576931467, "coordinate_system": "RAW"},
        "eb_settings": {"beam_type": "ELECTRON", "working_distance": 0.0039, "voltage": 2000.0},
        "ib_settings": {"beam_type": "ION", "working_distance": 0.0165, "voltage": 30000.0}}}"#;

    #[test]
    fn an_ion_image_gives_its_own_beams_settings() {
        let m = parse_openfibsem(ION_IMAGE).expect("OpenFIBSEM JSON");
        assert_eq!(m.vendor, Some(Vendor::OpenFibsem));
        assert_eq!(m.beam, Some(Beam::Ion));
        assert_eq!(m.pixel_width_m, Some(9.765624999999999e-08));
        assert_eq!(m.pixel_height_m, Some(9.765624999999999e-08));
        assert_eq!(m.stage_tilt_rad, Some(0.5235865576931467));
        assert_eq!(m.working_distance_m, Some(0.0165));
        assert_eq!(m.high_voltage_v, Some(30000.0));
        assert_eq!(m.magnification, None);
        assert!(m.warnings.is_empty(), "{:?}", m.warnings);
        let electron = ION_IMAGE.replace(
            r#""beam_type": "ION", "resolution""#,
            r#""beam_type": "ELECTRON", "resolution""#,
        );
        let m = parse_openfibsem(&electron).expect("OpenFIBSEM JSON");
        assert_eq!(
            (m.beam, m.working_distance_m, m.high_voltage_v),
            (Some(Beam::Electron), Some(0.0039), Some(2000.0))
        );
    }

    #[test]
    fn a_missing_pixel_size_comes_from_the_field_width_and_bad_values_are_named() {
        let no_pixel = ION_IMAGE.replace(
            r#""pixel_size": {"x": 9.765624999999999e-08, "y": 9.765624999999999e-08},"#,
            "",
        );
        let m = parse_openfibsem(&no_pixel).expect("OpenFIBSEM JSON");
        assert!((m.pixel_width_m.unwrap() - 0.00015 / 1536.0).abs() < 1e-18);
        assert!(m.warnings[0].contains("derived from hfw"), "{:?}", m.warnings);
        let bad = ION_IMAGE
            .replace(r#""t": 0.5235865576931467"#, r#""t": "thirty""#)
            .replace(r#""x": 9.765624999999999e-08"#, r#""x": -1"#);
        let m = parse_openfibsem(&bad).expect("OpenFIBSEM JSON");
        assert_eq!(m.stage_tilt_rad, None);
        assert_eq!(m.pixel_width_m, m.pixel_height_m);
        let all = m.warnings.join(" | ");
        assert!(
            all.contains("microscope_state.absolute_position.t is '\"thirty\"', not a number"),
            "{all}"
        );
        assert!(
            all.contains("pixel_size.x is '-1', not a positive length"),
            "{all}"
        );
    }

    #[test]
    fn other_descriptions_are_not_openfibsem() {
        for text in [
            "",
            "Made with ImageJ",
            "{\"spacing\": 1}",
            "[1, 2]",
            "{not json",
            "{\"beam_type\": \"ION\"}",
        ] {
            assert_eq!(parse_openfibsem(text), None, "{text}");
        }
    }
}

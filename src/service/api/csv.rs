//! Tabular output of pair results (CSV), shared by `semdepth process` and
//! the service's `GET /v1/sessions/{id}/results?format=csv`.

use super::results::{ObjectResult, PairResult, Relative};

/// The CSV header of [`csv_record`].
pub const CSV_HEADER: &str = "frame,name,status,reason,left_x,left_y,left_angle_rad,left_contrast,\
right_x,right_y,right_angle_rad,right_contrast,disparity_x_px,disparity_y_px,disparity_axis_px,\
relative_disparity_axis_px,angle_diff_rad,z_um,disparity_std_px,z_std_um,left_pixel_width_m,left_pixel_height_m,left_stage_tilt_rad,\
left_beam,right_pixel_width_m,right_pixel_height_m,right_stage_tilt_rad,right_beam,stage_tilt_difference_rad,warnings";

/// The CSV header of [`objects_csv_records`]: [`CSV_HEADER`] with the
/// columns `object` and `relative_to` after `name`.
pub static OBJECTS_CSV_HEADER: std::sync::LazyLock<String> = std::sync::LazyLock::new(|| {
    let rest = CSV_HEADER.strip_prefix("frame,name,").unwrap_or(CSV_HEADER);
    format!("frame,name,object,relative_to,{rest}")
});

/// The rows of a pair measured for named objects: one per object (its
/// name in `object`, `relative_to` empty), then one per ordered pair of
/// objects (`object` minus `relative_to`: the relative disparity in
/// `disparity_axis_px`, its error in `disparity_std_px`, the height
/// difference in `z_um` and its error in `z_std_um`; status `lost` and
/// empty numbers when either object is not measured).
pub fn objects_csv_records(
    frame: u64,
    objects: &[ObjectResult],
    relative: &[Relative],
    name: &str,
) -> Vec<String> {
    let mut rows = Vec::with_capacity(objects.len() + relative.len());
    for o in objects {
        let mut cells = csv_cells(&o.result, name);
        cells.insert(2, csv_text(&o.name));
        cells.insert(3, String::new());
        rows.push(cells.join(","));
    }
    let columns = OBJECTS_CSV_HEADER.split(',').count();
    let column = |c: &str| OBJECTS_CSV_HEADER.split(',').position(|h| h == c);
    for r in relative {
        let mut cells = vec![String::new(); columns];
        cells[0] = frame.to_string();
        cells[1] = csv_text(name);
        cells[2] = csv_text(&r.from);
        cells[3] = csv_text(&r.to);
        let measured = r.disparity_axis_px.is_some();
        cells[4] = if measured { "tracked" } else { "lost" }.into();
        for (c, v) in [
            ("disparity_axis_px", r.disparity_axis_px),
            ("disparity_std_px", r.disparity_std_px),
            ("z_um", r.dz_um),
            ("z_std_um", r.dz_std_um),
        ] {
            if let Some(i) = column(c) {
                cells[i] = num(v);
            }
        }
        rows.push(cells.join(","));
    }
    rows
}

/// Same number format as the JSON output (shortest round-trip form; a
/// non-finite value, which JSON cannot hold either, is an empty cell).
fn num(v: Option<f64>) -> String {
    v.filter(|v| v.is_finite())
        .and_then(|v| serde_json::to_string(&v).ok())
        .unwrap_or_default()
}

/// One CSV row: `name` is the pair's name (file stem, or session id).
pub fn csv_record(r: &PairResult, name: &str) -> String {
    csv_cells(r, name).join(",")
}

fn csv_cells(r: &PairResult, name: &str) -> Vec<String> {
    let mut cells = vec![
        r.frame.to_string(),
        csv_text(name),
        r.status.name().to_string(),
        r.reason
            .as_deref()
            .map(|t| quote(&neutralised(t)))
            .unwrap_or_default(),
    ];
    for image in [&r.left, &r.right] {
        cells.push(num(image.as_ref().map(|i| i.centroid[0])));
        cells.push(num(image.as_ref().map(|i| i.centroid[1])));
        cells.push(num(image.as_ref().map(|i| i.angle_rad)));
        cells.push(num(image.as_ref().map(|i| i.contrast)));
    }
    cells.push(num(r.disparity_px.map(|d| d[0])));
    cells.push(num(r.disparity_px.map(|d| d[1])));
    cells.push(num(r.disparity_axis_px));
    cells.push(num(r.relative_disparity_axis_px));
    cells.push(num(r.angle_diff_rad));
    cells.push(num(r.z_um));
    cells.push(num(r.disparity_std_px));
    cells.push(num(r.z_std_um));
    let meta = r.metadata.as_ref();
    for view in [meta.map(|m| m.left), meta.map(|m| m.right)] {
        cells.push(num(view.and_then(|v| v.pixel_width_m)));
        cells.push(num(view.and_then(|v| v.pixel_height_m)));
        cells.push(num(view.and_then(|v| v.stage_tilt_rad)));
        cells.push(
            view.and_then(|v| v.beam)
                .map_or(String::new(), |b| b.name().to_string()),
        );
    }
    cells.push(num(meta.and_then(|m| m.stage_tilt_difference_rad)));
    cells.push(if r.warnings.is_empty() {
        String::new()
    } else {
        quote(&neutralised(&r.warnings.join("; ")))
    });
    cells
}

/// A text cell: [`neutralised`], and quoted (RFC 4180) when it holds a
/// comma, a quote or a line break.
pub fn csv_text(s: &str) -> String {
    let s = neutralised(s);
    if s.contains([',', '"', '\n', '\r']) {
        quote(&s)
    } else {
        s
    }
}

/// Text a spreadsheet would read as a formula (it begins with `=`, `+`,
/// `-`, `@`, a tab or a carriage return) with a single quote in front, as
/// OWASP advises; other text as it is. Numbers are written by [`num`],
/// never through this, so a negative number stays a number.
fn neutralised(s: &str) -> String {
    if s.starts_with(['=', '+', '-', '@', '\t', '\r']) {
        format!("'{s}")
    } else {
        s.to_string()
    }
}

fn quote(s: &str) -> String {
    format!("\"{}\"", s.replace('"', "\"\""))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_quotes_reason_and_leaves_nulls_empty() {
        // Built from JSON so that fields added to PairResult later (all
        // optional) do not break the test.
        let r: PairResult = serde_json::from_value(serde_json::json!({
            "frame": 3,
            "status": "lost",
            "reason": "contrast \"collapsed\", left",
        }))
        .unwrap();
        let line = csv_record(&r, "a,b");
        let expected = format!(
            "3,\"a,b\",lost,\"contrast \"\"collapsed\"\", left\"{}",
            ",".repeat(26)
        );
        assert_eq!(line, expected);
        // Two of the commas are inside quoted cells.
        assert_eq!(line.matches(',').count() - 2, CSV_HEADER.matches(',').count());
    }

    #[test]
    fn cells_a_spreadsheet_would_run_are_neutralised() {
        for (text, cell) in [
            ("=cmd|' /C calc'!A0", "'=cmd|' /C calc'!A0"),
            ("+1", "'+1"),
            ("-2", "'-2"),
            ("@SUM(A1)", "'@SUM(A1)"),
            ("\tx", "'\tx"),
            ("\rx", "\"'\rx\""),
            ("=a,b", "\"'=a,b\""),
            ("plain-name", "plain-name"),
        ] {
            assert_eq!(csv_text(text), cell, "{text:?}");
        }
        // A negative number is a number, not a label.
        let r: PairResult = serde_json::from_value(serde_json::json!({
            "frame": 0, "status": "tracked", "disparity_axis_px": -1.5,
        }))
        .unwrap();
        assert!(csv_record(&r, "-x").starts_with("0,'-x,tracked,"));
        assert!(csv_record(&r, "p").contains(",-1.5,"));
    }
}

//! A drawn outline as the hint: the region a person's lasso encloses is
//! the object, scored like a found region and moved onto the object's
//! edges like one ([`super::fitted_to_edge`]); a lasso drawn loosely round
//! it, beyond the edge fit's reach, is first shrunk onto it by the
//! region-based fit.

use crate::energy::{data_term, michelson, EnergyParams, INTENSITY_OFFSET};
use crate::fit::{fit_free_avoiding, free_fit_tables, FreeFitParams, RigidTemplate};
use crate::geometry::Polygon;
use crate::imageio::GrayFrame;
use crate::region::{PixelRect, PrefixSums, RegionSum};

use super::{
    edge_stage, fitted_to_edge, side_names, Hints, InitDiagnostics, InitError, InitParams, InitResult, Score,
    Source,
};

/// Width of the surroundings an outlined region's contrast is measured
/// against, as a share of its mean thickness 2A/L: the window is its box
/// grown by that much (at least [`MIN_MARGIN_PX`]).
const MARGIN_SHARE: f64 = 0.5;

/// Least margin of an outlined region's window, pixels.
const MIN_MARGIN_PX: f64 = 4.0;

/// How far past the drawn outline the region-based fit may move the
/// object's outline, pixels: a line drawn along the edge falls a little
/// inside it here and there.
const DRAWN_SLACK_PX: f64 = 3.0;

/// The object the drawn `outline` names in `frame`: the region it encloses
/// inside the image, resampled to the contour spacing, crossing the image
/// sides the outline was drawn across. Its score is that of a candidate
/// region (the two-region log-likelihood ratio of its inside against the
/// rest of a window, its box grown by half its mean thickness, per pixel of
/// outline off the border) and its contrast must fit the `polarity` hint.
pub(super) fn outlined(
    frame: &GrayFrame,
    params: &InitParams,
    hints: &Hints,
    outline: &[[f64; 2]],
) -> Result<InitResult, InitError> {
    let (lx, ly) = (frame.width as f64 - 0.5, frame.height as f64 - 0.5);
    let drawn = Polygon::new(outline.to_vec());
    let [x0, y0, x1, y1] = drawn.bounds();
    let border = side_names([x0 < -0.5, y0 < -0.5, x1 > lx, y1 > ly]);
    let mut contour = drawn.clipped_to_box([-0.5, -0.5, lx, ly]);
    // Vertices clockwise on screen, as the found regions' are.
    if contour.signed_area() < 0.0 {
        contour.points.reverse();
    }
    let contour = contour.resampled_every(params.contour_spacing_px, 8);
    // Drawn along the edge, the outline is moved onto it by the edge fit;
    // drawn loosely round the object, beyond that fit's reach, it is
    // shrunk onto the object first. The region is scored before its edge
    // fit.
    let (contour, on_edge) = match fitted_to_edge(frame, &contour) {
        Some((moved, _)) => (contour, Some(moved)),
        None => {
            let shrunk = shrunk_onto_object(frame, &contour).resampled_every(params.contour_spacing_px, 8);
            let moved = fitted_to_edge(frame, &shrunk).map(|(moved, _)| moved);
            (shrunk, moved)
        }
    };
    let score = score(frame, &contour, border.is_empty());
    if let Some(s) = score.filter(|s| !hints.polarity.admits(s.contrast)) {
        return Err(InitError::HintMatchesNothing {
            hint: format!("outline and polarity {}", hints.polarity.name()),
            found: format!(
                "the outlined region is {} than its surroundings (contrast {:+.3})",
                if s.contrast > 0.0 { "brighter" } else { "darker" },
                s.contrast
            ),
        });
    }
    let stage = edge_stage(frame, params, hints)?;
    let contour = on_edge.unwrap_or(contour);
    Ok(InitResult {
        centroid: contour.centroid(),
        area_px: contour.area(),
        bbox: contour.bounds(),
        contour,
        rim_px: 0.0,
        edge_support: None,
        core: None,
        score,
        source: Source::Outline,
        border,
        cut_at_box: Vec::new(),
        diagnostics: InitDiagnostics {
            scale: stage.scale,
            noise_sigma: stage.noise_work * stage.scale as f32,
            sigma: stage.sigma,
            low_threshold: stage.low,
            high_threshold: stage.high,
            dilation_radius: 0,
            edge_pixels: stage.edge_pixels,
            candidates: 1,
            runners_up: Vec::new(),
        },
    })
}

/// The region-based active contour's free fit (Dahmen et al., section 3)
/// from the `drawn` outline, its vertices held within [`DRAWN_SLACK_PX`]
/// of it: a lasso drawn loosely round the object shrinks onto the object
/// it encloses. The drawn outline itself when the fit leaves less than
/// [`super::MIN_OUTLINE_AREA_PX`] or cannot run (outside the image).
fn shrunk_onto_object(frame: &GrayFrame, drawn: &Polygon) -> Polygon {
    let image = PixelRect::full(frame).extent();
    let start = drawn.snapped_to_box(image, RigidTemplate::ON_BORDER_PX);
    let energy = EnergyParams::default();
    let Some(sums) = free_fit_tables(frame, &start, &energy) else {
        return drawn.clone();
    };
    let allowed = start.offset_along_normals(DRAWN_SLACK_PX);
    let [x0, y0, x1, y1] = allowed.bounds();
    let bounds = [
        x0.max(image[0]),
        y0.max(image[1]),
        x1.min(image[2]),
        y1.min(image[3]),
    ];
    let fitted = fit_free_avoiding(
        &sums,
        &start,
        &energy,
        &FreeFitParams::default(),
        Some(bounds),
        &|p| !allowed.contains(p),
    )
    .polygon;
    if fitted.area() >= super::MIN_OUTLINE_AREA_PX {
        fitted
    } else {
        drawn.clone()
    }
}

/// A candidate's score of the region inside `contour` (see [`outlined`]);
/// `None` when its window holds nothing but it. The outline's length
/// counts only off the image border (all of it when `inside` the image).
fn score(frame: &GrayFrame, contour: &Polygon, inside: bool) -> Option<Score> {
    let (area, length) = (contour.area(), contour.length());
    let thickness = 2.0 * area / length.max(1e-9);
    let margin = (MARGIN_SHARE * thickness).max(MIN_MARGIN_PX);
    let rect = PixelRect::around(contour.bounds(), margin, frame.width, frame.height)?;
    let sums = PrefixSums::new(frame, rect, INTENSITY_OFFSET);
    let (region, window) = (sums.polygon(&contour.points), sums.total());
    let rest = RegionSum {
        count: window.count - region.count,
        sum: window.sum - region.sum,
    };
    let data = data_term(region, window)? / window.mean();
    let [x0, y0, x1, y1] = PixelRect::full(frame).extent();
    let on_border = |p: [f64; 2]| {
        let d = [p[0] - x0, p[1] - y0, x1 - p[0], y1 - p[1]];
        d.iter().any(|&d| d < 0.5)
    };
    let outline_px = if inside {
        length
    } else {
        contour
            .edges()
            .filter(|(a, b)| !(on_border(*a) && on_border(*b)))
            .map(|(a, b)| (b[0] - a[0]).hypot(b[1] - a[1]))
            .sum()
    };
    Some(Score {
        score: data / outline_px.max(1.0),
        contrast: michelson(region.mean(), rest.mean()),
        data,
        outline_px,
        area_px: area,
    })
}

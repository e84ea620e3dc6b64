//! The standard error of a fitted view along the disparity axis (see
//! [`crate::uncertainty`]) and the noise it is measured on.

use crate::calib::axis_component;
use crate::energy::window_of;
use crate::fit::{place, Pose, RigidTemplate};
use crate::geometry::{HalfPlane, Point, Polygon};
use crate::imageio::GrayFrame;
use crate::occlusion::SectorTemplate;
use crate::region::PrefixSums;
use crate::uncertainty;

use super::state::TrackerState;
use super::substrate;
use super::view_fit::{either, ImageFit};
use super::StereoTracker;

/// The share of the information on the weakest direction of the
/// sectors seen (not marked in `unseen`) that those not `left_out` keep:
/// `lambda_min` of their geometric information matrices
/// ([`uncertainty::weakest_information`]), in 0..=1 (1 when the seen ones
/// fix no direction either). Its inverse square root bounds how much the
/// position's standard error in that direction grows from what is left
/// out.
pub(super) fn fixed_share(sectors: &SectorTemplate, pose: Pose, unseen: &[bool], left_out: &[bool]) -> f64 {
    if unseen == left_out {
        return 1.0;
    }
    let seen = uncertainty::weakest_information(&sectors.visible_arcs(pose, unseen));
    if seen <= 0.0 {
        return 1.0;
    }
    (uncertainty::weakest_information(&sectors.visible_arcs(pose, left_out)) / seen).min(1.0)
}

/// Where the noise is measured for the standard errors of each view, how
/// the frames were smoothed and, for a smoothed object, the noise each
/// view had before: measured in the same bands along the whole outline at
/// its pose in `raws` (the frames before smoothing).
pub(super) fn noise_bands(
    state: &TrackerState,
    template: &RigidTemplate,
    sectors: &SectorTemplate,
    raws: [(&GrayFrame, Pose); 2],
) -> [uncertainty::NoiseBands; 2] {
    let outer_offset_px = rim_offset(state);
    let smoothing_px = state.prefilter_sigma_px;
    raws.map(|(raw, pose)| {
        let unsmoothed = uncertainty::NoiseBands {
            outer_offset_px,
            ..uncertainty::NoiseBands::default()
        };
        let raw_noise = (smoothing_px > 0.0)
            .then(|| {
                uncertainty::band_sigma(
                    raw,
                    &sectors.visible_arcs(pose, &[]),
                    outward(template),
                    unsmoothed,
                )
            })
            .flatten();
        uncertainty::NoiseBands {
            smoothing_px,
            raw_noise,
            ..unsmoothed
        }
    })
}

/// What the cuts of a template crossing the image border add to
/// [`uncertainty::weighted_length`]'s `S` (see [`uncertainty::cut_length`]):
/// each cut carries a strip of the object's pixels in or out of both the
/// object's region and the window as the template moves along `u`. Nothing
/// in a domain fixed in the image ([`RigidTemplate::fixed`]), where the
/// cuts stay put.
pub(super) fn cut_length(
    template: &RigidTemplate,
    sums: &PrefixSums,
    pose: Pose,
    u: Point,
    means: [f64; 2],
) -> f64 {
    if template.cuts.is_empty() || template.fixed.is_some() {
        return 0.0;
    }
    let extent = sums.image_extent();
    let inside = HalfPlane::sides_of_box(extent)
        .iter()
        .fold(place(&template.points, pose), |p, side| side.clip(&p));
    let region = template
        .cuts_at(pose)
        .iter()
        .fold(inside.clone(), |p, cut| cut.clip(&p));
    let area = Polygon::new(region.clone()).area();
    // The region's box grown by the margin, within the image.
    let [x0, y0, x1, y1] = window_of(&region, template.margin);
    let [ex0, ey0, ex1, ey1] = extent;
    let window = (x1.min(ex1) - x0.max(ex0)).max(0.0) * (y1.min(ey1) - y0.max(ey0)).max(0.0);
    template
        .cuts
        .iter()
        .map(|c| c.moved(pose.theta, [pose.x, pose.y]))
        .map(|cut| {
            let area_at = |d: f64| {
                let moved = HalfPlane {
                    offset: cut.offset + d,
                    ..cut
                };
                Polygon::new(moved.clip(&inside)).area()
            };
            let chord = (area_at(-0.5) - area_at(0.5)).max(0.0);
            let along = cut.normal[0] * u[0] + cut.normal[1] * u[1];
            uncertainty::cut_length(chord * along * along, means, area / window.max(area).max(1.0))
        })
        .sum()
}

/// The sign of the template's signed area: +1 when its normals, as
/// [`Polygon::outward_normals`] turns them, point out.
pub(super) fn outward(template: &RigidTemplate) -> f64 {
    Polygon::new(template.points.clone()).signed_area().signum()
}

/// How far the object's reported outline runs outside its template on
/// average (a dark object's bright rim), pixels; 0 without an outline.
pub(super) fn rim_offset(state: &TrackerState) -> f64 {
    if state.outline.is_empty() {
        return 0.0;
    }
    let (outline, template) = (
        Polygon::new(state.outline.clone()),
        Polygon::new(state.template.clone()),
    );
    ((outline.area() - template.area()) / template.length().max(1.0)).max(0.0)
}

/// What [`StereoTracker::axis_std`] measures of a fit.
#[derive(Clone, Debug)]
pub(super) struct AxisStd {
    /// The standard error along the axis without the masked runs' shift
    /// (the marginal one: the curvature's conditional figure times
    /// [`uncertainty::marginal_factor`]), pixels; NaN when unmeasured.
    std: f64,
    /// For a fit with hidden sectors, the variance the noise alone gives
    /// the masked runs' shift relative to `std`'s square
    /// ([`uncertainty::difference_variance`]).
    difference: f64,
    /// The same for the shift along the axis alone
    /// ([`uncertainty::line_difference_variance`]).
    line_difference: f64,
    /// The noise `std` was measured with ([`uncertainty::band_sigma`]),
    /// grey levels; NaN when unmeasured.
    sigma: f64,
    /// The visible outline's [`uncertainty::weakest_direction_factor`]
    /// relative to `std`.
    weakest_factor: f64,
    /// The direction of [`uncertainty::weakest_direction`].
    weakest_direction: Point,
    /// [`fixed_share`] of what is seen.
    fixed_share: f64,
    /// The sectors left out of `std` (not seen, or occluded).
    left_out: Vec<bool>,
}

impl StereoTracker {
    /// Standard error of `fit` along the disparity axis, pixels, for the
    /// objective the fit minimised (the full energy, or the band energy
    /// over the visible sectors when some were occluded), from its
    /// curvature and the grey-level spread near it (see
    /// [`crate::uncertainty`]); NaN when it cannot be measured.
    /// `bands`: how far outside the template the object's outline runs, and
    /// the smoothing the frames had. Sets `fit.axis_std_px` (with the masked
    /// runs' shift in quadrature, also kept as `fit.axis_bias_px`), the
    /// noise it was measured with and where, and `fit.weakest_factor`.
    pub(super) fn measure_std(
        &self,
        frame: &GrayFrame,
        sums: &PrefixSums,
        (template, sectors): (&RigidTemplate, &SectorTemplate),
        fit: &mut ImageFit,
        bands: uncertainty::NoiseBands,
    ) {
        let m = self.axis_std(frame, sums, template, sectors, fit, bands);
        // The masked runs' shift less what the noise alone moves it by: the
        // fit with the runs grown is the less efficient of the two, and
        // their difference has the difference of their variances.
        let bias = (fit.mask_shift_px.powi(2) - m.difference * m.std * m.std)
            .max(0.0)
            .sqrt();
        fit.axis_std_px = m.std.hypot(bias);
        fit.axis_bias_px = bias;
        fit.line_difference = m.line_difference;
        fit.noise_sigma = m.sigma;
        fit.measured_without = m.left_out;
        fit.weakest_factor = m.weakest_factor;
        fit.weakest_direction = m.weakest_direction;
        fit.fixed_share = m.fixed_share;
    }

    /// [`Self::measure_std`]'s standard error along the axis, without the
    /// masked runs' shift, and what goes with it (see [`AxisStd`]).
    pub(super) fn axis_std(
        &self,
        frame: &GrayFrame,
        sums: &PrefixSums,
        template: &RigidTemplate,
        sectors: &SectorTemplate,
        fit: &ImageFit,
        bands: uncertainty::NoiseBands,
    ) -> AxisStd {
        let u = self.disparity_axis();
        let pose = fit.pose;
        // The outline along the image border or a cut is no edge of the
        // object: its sectors count like occluded ones.
        let unseen: Vec<bool> = if template.cuts.is_empty() {
            vec![false; sectors.len()]
        } else {
            sectors
                .band_sums(sums, pose)
                .iter()
                .map(Option::is_none)
                .collect()
        };
        let left_out = either(&unseen, &fit.occluded);
        let arcs = sectors.visible_arcs(pose, &left_out);
        // The fit moves the outline across the axis too: the curvature
        // along it alone gives the conditional standard error, and the
        // marginal one is larger for a slender outline at an angle to the
        // axis. Not for a fit with hidden sectors, whose figure already
        // carries the masked runs' shift, an estimate of their bias that
        // still over-reports (docs/uncertainty.md); nor where the
        // arcs fix no position in some direction, which the weakest
        // direction's checks judge instead.
        let occluded = fit.occluded.contains(&true);
        let marginal = Some(uncertainty::marginal_factor(&arcs, u))
            .filter(|f| f.is_finite() && !occluded)
            .unwrap_or(1.0);
        // The variance of the masked runs' shift that the noise alone
        // gives (see `measure_std`), relative to the conditional one; the
        // shift, where measured, is with the runs grown by one sector.
        let (difference, line_difference) = if fit.mask_shift_px != 0.0 {
            let wider = crate::occlusion::grown(&fit.occluded);
            let fewer = sectors.visible_arcs(pose, &either(&unseen, &wider));
            (
                uncertainty::difference_variance(&arcs, &fewer, u),
                uncertainty::line_difference_variance(&arcs, &fewer, u),
            )
        } else {
            (0.0, 0.0)
        };
        let measured = AxisStd {
            std: f64::NAN,
            difference,
            line_difference,
            sigma: f64::NAN,
            // Relative to the marginal standard error this returns.
            weakest_factor: uncertainty::weakest_direction_factor(&arcs, u) / marginal,
            weakest_direction: uncertainty::weakest_direction(&arcs),
            fixed_share: fixed_share(sectors, pose, &unseen, &left_out),
            left_out,
        };
        let Some(sigma) = uncertainty::band_sigma(frame, &arcs, outward(template), bands) else {
            return measured;
        };
        let shifted = |d: f64| pose.moved_along(u, d);
        let m_ref = sums.reference_mean();
        let s = uncertainty::weighted_length(&arcs, u);
        let std = if occluded {
            let (a, b) = sectors.visible_bands(sums, pose, &fit.occluded);
            let means = [a.mean(), b.mean()];
            let s = s + cut_length(template, sums, pose, u, means);
            let energy = |d: f64| sectors.masked_energy(sums, shifted(d), &fit.occluded, m_ref);
            uncertainty::axis_std(energy, m_ref, means, s, sigma)
        } else {
            let terms = template.energy_at(sums, pose, &self.params.energy);
            let means = [terms.mean_inside, terms.mean_outside];
            let s = s + cut_length(template, sums, pose, u, means);
            let energy = |d: f64| template.energy_at(sums, shifted(d), &self.params.energy).energy;
            marginal * uncertainty::axis_std(energy, m_ref, means, s, sigma)
        };
        AxisStd {
            std,
            sigma,
            ..measured
        }
    }

    /// Measures the noise of both fits' share of the disparity's standard
    /// error on the pair itself ([`uncertainty::pair_sigma`] over the
    /// bands both standard errors were measured on, at the fitted poses in
    /// `frames`), and adds the surroundings' lag behind the object
    /// ([`substrate::lag`], less its own noise and the disparity's) in
    /// quadrature: sets each fit's `pair_scale` to what the pair's noise
    /// makes of the noise part of its `axis_std_px` (at most 1; the
    /// masked runs' shift stays, except where both views left out the
    /// same sectors: the difference of their signed shifts then counts
    /// once, on the right fit) and the right fit's `lag_px`. A view's own
    /// bands count as noise the texture and edges near the outline, which
    /// move with the object when they lie at its height; what the two
    /// views differ by can move the disparity, and texture at another
    /// height by as much as it lags. Where that sum exceeds the views' own
    /// figure, the views' figure stands.
    ///
    /// Left at the view's figure while a run of `uncertain` pairs is open:
    /// the pair's noise says that the views agree at their poses, not that
    /// the contour is on the object, and a contour carried onto an edge at
    /// another height by unverified moves agrees in both views (a rod
    /// under a dark bar, its left centroid 6 px off after two uncertain
    /// pairs, measured 0.16 px with the pair's noise against 0.57 px).
    /// Left too when a view is unmeasured or the frames were smoothed
    /// (their noise is measured before smoothing, see
    /// [`uncertainty::band_sigma`]).
    pub(super) fn use_pair_noise(
        &self,
        frames: [&GrayFrame; 2],
        (template, sectors): (&RigidTemplate, &SectorTemplate),
        bands: [uncertainty::NoiseBands; 2],
        [left, right]: [&mut ImageFit; 2],
    ) {
        let in_run = self.state.as_ref().is_some_and(|s| s.uncertain_run.is_some());
        if in_run
            || bands.iter().any(|b| b.smoothing_px > 0.0)
            || !(left.noise_sigma > 0.0 && right.noise_sigma > 0.0)
        {
            return;
        }
        let without = either(&left.measured_without, &right.measured_without);
        let arcs = [left.pose, right.pose].map(|pose| sectors.visible_arcs(pose, &without));
        let Some(sigma) = uncertainty::pair_sigma(
            frames,
            [&arcs[0], &arcs[1]],
            outward(template),
            bands[0].outer_offset_px,
        ) else {
            return;
        };
        let noise = [&*left, &*right].map(|fit| {
            let scale = (sigma / fit.noise_sigma).min(1.0);
            (fit.axis_std_px.powi(2) - fit.axis_bias_px.powi(2))
                .max(0.0)
                .sqrt()
                * scale
        });
        // Where both views masked the same sectors, growing the masked runs
        // moves both poses alike as far as the views are alike: the
        // disparity moves by the difference of the two shifts, which the
        // right view's figure carries, less what the pair's noise alone
        // moves it by (each view's as in `measure_std`); elsewhere each
        // view's shift stays.
        let scaled = if left.occluded == right.occluded && left.occluded.contains(&true) {
            let by_noise = left.line_difference * noise[0].powi(2) + right.line_difference * noise[1].powi(2);
            let pair_bias = ((right.mask_shift_line_px - left.mask_shift_line_px).powi(2) - by_noise)
                .max(0.0)
                .sqrt();
            [noise[0], noise[1].hypot(pair_bias)]
        } else {
            [
                noise[0].hypot(left.axis_bias_px),
                noise[1].hypot(right.axis_bias_px),
            ]
        };
        let views = left.axis_std_px.hypot(right.axis_std_px);
        // Where the pair's noise is no smaller than the views' (each view
        // at its cap), no lag can bring the sum below the views' figure:
        // the registration is not made.
        let pair = scaled[0].hypot(scaled[1]);
        if pair >= views {
            return;
        }
        // The lag registered at the fitted poses carries the disparity's
        // own error with its sign turned (surroundings that moved with the
        // object lag by what the fits missed), whose variance `pair` is:
        // only its excess over that and over its own noise counts, as for
        // the masked runs' shifts.
        let reach = (template.margin, bands[0].outer_offset_px);
        let lag = substrate::lag(
            frames,
            &template.points,
            [left.pose, right.pose],
            reach,
            self.disparity_axis(),
        )
        .map_or(0.0, |l| {
            (l.px * l.px - l.std_px * l.std_px - pair * pair).max(0.0).sqrt()
        });
        if pair.hypot(lag) >= views {
            return;
        }
        for (fit, scaled) in [&mut *left, &mut *right].into_iter().zip(scaled) {
            if fit.axis_std_px > 0.0 {
                fit.pair_scale = scaled / fit.axis_std_px;
            }
        }
        right.lag_px = lag;
    }

    /// The unit vector across the tilt axis, along which the disparity is
    /// measured (see [`axis_component`]).
    pub(super) fn disparity_axis(&self) -> Point {
        let t = self.params.tilt_axis_deg.to_radians();
        [t.sin(), -t.cos()]
    }

    /// How far `to` lies from `from` along the disparity axis, pixels (0
    /// when not finite).
    pub(super) fn axis_shift(&self, from: Pose, to: Pose) -> f64 {
        self.signed_axis_shift(from, to).abs()
    }

    /// [`Self::axis_shift`] with its sign (positive along the axis).
    pub(super) fn signed_axis_shift(&self, from: Pose, to: Pose) -> f64 {
        let d = axis_component(self.params.tilt_axis_deg, [to.x - from.x, to.y - from.y]);
        if d.is_finite() {
            d
        } else {
            0.0
        }
    }
}

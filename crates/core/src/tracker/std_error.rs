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

impl StereoTracker {
    /// Standard error of `fit` along the disparity axis, pixels, for the
    /// objective the fit minimised (the full energy, or the band energy
    /// over the visible sectors when some were occluded), from its
    /// curvature and the grey-level spread near it (see
    /// [`crate::uncertainty`]); NaN when it cannot be measured.
    /// `bands`: how far outside the template the object's outline runs, and
    /// the smoothing the frames had. Sets `fit.axis_std_px` (with the masked
    /// runs' shift in quadrature) and `fit.weakest_factor`.
    pub(super) fn measure_std(
        &self,
        frame: &GrayFrame,
        sums: &PrefixSums,
        (template, sectors): (&RigidTemplate, &SectorTemplate),
        fit: &mut ImageFit,
        bands: uncertainty::NoiseBands,
    ) {
        let ((std, difference), (factor, direction, share)) =
            self.axis_std(frame, sums, template, sectors, fit, bands);
        // The masked runs' shift less what the noise alone moves it by: the
        // fit with the runs grown is the less efficient of the two, and
        // their difference has the difference of their variances.
        let bias = (fit.mask_shift_px.powi(2) - difference * std * std)
            .max(0.0)
            .sqrt();
        fit.axis_std_px = std.hypot(bias);
        fit.weakest_factor = factor;
        fit.weakest_direction = direction;
        fit.fixed_share = share;
    }

    /// [`Self::measure_std`]'s standard error along the axis, without the
    /// masked runs' shift (the marginal one: the curvature's conditional
    /// figure times [`uncertainty::marginal_factor`]) and, for a fit with
    /// hidden sectors, the variance the noise alone gives that shift
    /// relative to its square ([`uncertainty::difference_variance`]); and
    /// the visible outline's [`uncertainty::weakest_direction_factor`]
    /// relative to it.
    pub(super) fn axis_std(
        &self,
        frame: &GrayFrame,
        sums: &PrefixSums,
        template: &RigidTemplate,
        sectors: &SectorTemplate,
        fit: &ImageFit,
        bands: uncertainty::NoiseBands,
    ) -> ((f64, f64), (f64, Point, f64)) {
        let t = self.params.tilt_axis_deg.to_radians();
        let u = [t.sin(), -t.cos()];
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
        let difference = if fit.mask_shift_px > 0.0 {
            let wider = crate::occlusion::grown(&fit.occluded);
            let fewer = sectors.visible_arcs(pose, &either(&unseen, &wider));
            uncertainty::difference_variance(&arcs, &fewer, u)
        } else {
            0.0
        };
        let weakest = (
            // Relative to the marginal standard error this returns.
            uncertainty::weakest_direction_factor(&arcs, u) / marginal,
            uncertainty::weakest_direction(&arcs),
            fixed_share(sectors, pose, &unseen, &left_out),
        );
        let Some(sigma) = uncertainty::band_sigma(frame, &arcs, outward(template), bands) else {
            return ((f64::NAN, difference), weakest);
        };
        let shifted = |d: f64| Pose {
            x: pose.x + d * u[0],
            y: pose.y + d * u[1],
            ..pose
        };
        let m_ref = sums.reference_mean();
        let s = uncertainty::weighted_length(&arcs, u);
        if occluded {
            let (a, b) = sectors.visible_bands(sums, pose, &fit.occluded);
            let means = [a.mean(), b.mean()];
            let s = s + cut_length(template, sums, pose, u, means);
            let energy = |d: f64| sectors.masked_energy(sums, shifted(d), &fit.occluded, m_ref);
            (
                (uncertainty::axis_std(energy, m_ref, means, s, sigma), difference),
                weakest,
            )
        } else {
            let terms = template.energy_at(sums, pose, &self.params.energy);
            let means = [terms.mean_inside, terms.mean_outside];
            let s = s + cut_length(template, sums, pose, u, means);
            let energy = |d: f64| template.energy_at(sums, shifted(d), &self.params.energy).energy;
            (
                (
                    marginal * uncertainty::axis_std(energy, m_ref, means, s, sigma),
                    difference,
                ),
                weakest,
            )
        }
    }

    /// How far `to` lies from `from` along the disparity axis, pixels (0
    /// when not finite).
    pub(super) fn axis_shift(&self, from: Pose, to: Pose) -> f64 {
        let d = axis_component(self.params.tilt_axis_deg, [to.x - from.x, to.y - from.y]);
        if d.is_finite() {
            d.abs()
        } else {
            0.0
        }
    }
}

//! The first pair, or the first after a loss: find the object, fit it
//! freely, make the rigid template and search the right view; a fresh
//! object unlike the lost one is refused.

use crate::calib::axis_component;
use crate::energy::EnergyTerms;
use crate::fit::{
    fit_free_within, fit_rigid, free_fit_tables, place, Pose, RigidSearch, RigidTemplate, MIN_FREE_VERTICES,
};
use crate::geometry::{polygon_iou, Point, Polygon};
use crate::imageio::GrayFrame;
use crate::init::{edge_width, fitted_to_edge, initialise, InitError, InitResult};
use crate::occlusion::{grey_quantiles, SectorTemplate};
use crate::prefilter;
use crate::region::{PixelRect, PrefixSums};
use crate::scatter::DisparityRun;
use crate::strips::refit_without_strips;

use super::border::{free_end_area, shared_view_limits};
use super::params::TrackerParams;
use super::profile::{best_shift_along, profile, reliability, slide_reference, weights_along};
use super::result::{PairResult, Status, TrackError};
use super::state::{Phase, TrackerState};
use super::std_error::noise_bands;
use super::view_fit::ImageFit;
use super::StereoTracker;

/// Least ratio of each principal spread (see
/// [`Polygon::principal_spreads`]) of an object initialised afresh after a
/// loss to the lost template's, and of the lost one's to it: an object
/// found afresh beyond it is taken for part of the lost one (what an
/// occluder leaves visible: half a rod's width beside a dark bar, whose
/// disparity mixes the bar's in, 0.85-1.5 px off) or for another object,
/// and the lost template is sought again. See [`REFUSED_INITS`].
pub const MIN_SPREAD_RATIO: f64 = 0.85;

/// Least ratio of a lost template's principal spreads (along over across)
/// for it to count as a tool whose width is compared with a fresh one's
/// when it is cut by the image border (see [`MIN_SPREAD_RATIO`]): a needle
/// has 20 or more, a disc cut in half by the border less than 2.
pub const ELONGATED: f64 = 4.0;

/// Fresh initialisations after a loss refused as unlike the lost object
/// (see [`MIN_SPREAD_RATIO`]) before the next one is taken as it is: an
/// object changed beyond recognition for that long is the object as it is
/// now. Each refusal is followed by [`REACQUIRE_PAIRS`] pairs that seek the
/// lost template again.
pub const REFUSED_INITS: u32 = 3;

/// Least IoU of a hinted object's freely fitted region with its
/// initialisation for the fit to be kept (see `StereoTracker::template_from`).
pub const FREE_FIT_MIN_IOU: f64 = 0.8;

/// A first pair's right view looks like its left view when the correlation
/// of their outline profiles at its best offset along the disparity axis
/// ([`best_shift_along`]) reaches this share of the left profile's own
/// [`reliability`]: views that differ by independent noise alone reach
/// 0.61-0.77 of it (the static scans), a quartz grain seen at twice the
/// tilt 0.28 (its profiles' best offset 15 px from the energy's pose,
/// which is right to 1.3 px).
pub const ALIKE_SHARE: f64 = 0.5;

/// Where the views look alike, the right view's fit lies within this many
/// of the disparity's standard errors, plus a pixel (what whole-pixel
/// shifts refined by a parabola resolve), of where its outline looks most
/// like the left view's; further, the region energy has placed it on
/// something else (a low-contrast lamella between a needle and a post,
/// whose energy along the line changes by 14 units over 20 px: 20 px off
/// at a reported 3.2 px). On the synthetic suites and the other real pairs
/// the two lie within 0.8 px, or at most 2.6 standard errors apart.
pub const APPEARANCE_STDS: f64 = 4.0;

/// A first pair's fit in either view must be a minimum of its energy along
/// the disparity axis over this many of its standard errors (at least a
/// pixel, past the sub-pixel tolerance the fit settles to): the standard
/// error is read off the energy's curvature at the fit, which a fit held
/// against the edge of its domain, its energy falling beyond it, also has
/// (a lasso round a lamella whose energy falls towards the needle beside
/// it: the left view's fit at the lasso, its standard error under 0.01 px).
pub const BASIN_STDS: f64 = 3.0;

impl StereoTracker {
    /// First pair (or after a loss): find, fit, search the right view. On
    /// the very first pair a `point` or `polarity` hint that no region
    /// satisfies is an error (the object it names is not in view, and
    /// another is not taken in its place); after a loss the pair is lost.
    pub(super) fn initialise(
        &mut self,
        frame: u64,
        left: &GrayFrame,
        right: &GrayFrame,
    ) -> Result<PairResult, TrackError> {
        match initialise(left, &self.params.init) {
            Ok(found) => Ok(self.initialise_found(frame, left, right, found)),
            Err(e @ InitError::HintMatchesNothing { .. }) if self.state.is_none() => Err(TrackError::Hint(e)),
            Err(e) => Ok(PairResult::lost(frame, format!("initialisation failed: {e}"))),
        }
    }

    /// The left outline a first pair reports for the object `found` in
    /// `left` by [`crate::init::initialise`] with `params.init`: fitted
    /// freely, with the strips of substrate it holds cut out
    /// ([`crate::strips`]), and moved onto the object's edge. `None` when
    /// the fit leaves the image (the initialisation's outline is then the
    /// best there is). Shows a person the contour tracking starts from.
    pub fn first_outline(params: &TrackerParams, left: &GrayFrame, found: InitResult) -> Option<Polygon> {
        let mut tracker = StereoTracker::new(params.clone());
        let first = tracker.initialise_found(0, left, left, found);
        first
            .left
            .filter(|_| first.status == Status::Initialised)
            .map(|l| Polygon::new(l.contour))
    }

    /// [`Self::initialise`] once the object is found.
    pub(super) fn initialise_found(
        &mut self,
        frame: u64,
        left: &GrayFrame,
        right: &GrayFrame,
        found: InitResult,
    ) -> PairResult {
        let previous_reference = self
            .state
            .as_ref()
            .map(|s| (s.first_disparity_axis_px, s.first_disparity_px));
        // A dark object's template is the region inside its bright rim:
        // the two-region energy sees the rim as substrate.
        let fitted = found.core.as_ref().unwrap_or(&found.contour);
        // A blurred object is fitted on both images smoothed to its edge's
        // width, where the noise around it is white (the matched filter's
        // premise); its outline is measured on the image as it is.
        let raw_left = left;
        let white = || {
            prefilter::substrate_whiteness(left, &found.contour)
                .is_some_and(|w| w >= prefilter::MIN_WHITENESS)
        };
        let prefilter_sigma_px = match (self.params.prefilter_sigma_px, &found.core) {
            (Some(sigma), _) => sigma,
            (None, _) if !white() => 0.0,
            // A dark object's core meets its rim in a rise over the rim's
            // inner half (the rim: the outline's mean distance outside the
            // core).
            (None, Some(core)) => (0.5 * (found.contour.area() - core.area()) / core.length().max(1.0))
                .clamp(prefilter::MIN_RIM_SIGMA_PX, prefilter::MAX_RIM_SIGMA_PX),
            (None, None) => edge_width(left, fitted)
                .filter(|&w| w >= prefilter::MIN_EDGE_WIDTH_PX)
                .unwrap_or(0.0),
        };
        let mut prefiltered = std::mem::take(&mut self.prefiltered);
        let whole = [PixelRect::full(left); 2];
        let pair = prefiltered.pair(left, right, prefilter_sigma_px, whole);
        let result = self.initialise_on(
            frame,
            (raw_left, right),
            &found,
            pair,
            prefilter_sigma_px,
            previous_reference,
        );
        self.prefiltered = prefiltered;
        result
    }

    /// After a loss, a fresh template unlike the lost one (a principal
    /// spread off by more than [`MIN_SPREAD_RATIO`]) is refused, up to
    /// [`REFUSED_INITS`] times: the reason of the lost pair, the state set
    /// to seek the lost template again. Of a lost object cut by the image
    /// border only a tool's width and free end are compared (a spread across it at most
    /// [`ELONGATED`] times smaller than along it): the visible part of a
    /// tool changes in length as it moves in or out, not in width (a
    /// needle lost with its tip over a grain was found afresh as needle
    /// and grain together, 5 px off in disparity, `tracked`), and its free
    /// end (the area within its width of the tip, by the same ratio: found
    /// afresh with a patch of the grain's rim at its tip, the needle's
    /// disparity was 1.4 px off, `tracked`); a
    /// fresh one cut by the border, where the lost one was whole, is
    /// refused only when it is larger than the lost object (a spread over
    /// `1 / MIN_SPREAD_RATIO` times its), as the part of it the frame
    /// shows cannot be: it is another object, or the object merged with
    /// one (a rod half under a bright bar running out of the frame was
    /// found afresh as rod and bar together, its centroid 35 px off,
    /// `initialised`).
    pub(super) fn refuse_unlike_lost(&mut self, template: &RigidTemplate) -> Option<String> {
        let state = self.state.as_mut().filter(|s| s.is_lost())?;
        if state.refused_inits >= REFUSED_INITS {
            return None;
        }
        let new_polygon = Polygon::new(template.points.clone());
        let old_polygon = Polygon::new(state.template.clone());
        let [new_long, new_short] = new_polygon.principal_spreads();
        let [old_long, old_short] = old_polygon.principal_spreads();
        // A fresh spread at most 1 / MIN_SPREAD_RATIO times the lost one's.
        let within = |a: f64, b: f64| MIN_SPREAD_RATIO * a <= b;
        let (fits, what, why) = if !state.template_cuts.is_empty() {
            if old_long < ELONGATED * old_short {
                return None;
            }
            // Its free end, over the length of its width (a bar's width is
            // sqrt(12) times its spread across).
            let length = 12f64.sqrt() * old_short;
            let old_axis = {
                let (s, c) = old_polygon.orientation().sin_cos();
                [c, s]
            };
            let ends = || {
                Some((
                    free_end_area(&old_polygon, old_axis, &state.template_cuts, length)?,
                    free_end_area(&new_polygon, template.axis, &template.cuts, length)?,
                ))
            };
            if !(within(new_short, old_short) && within(old_short, new_short)) {
                (
                    false,
                    "of another width than the lost tool cut by the image border".into(),
                    "another object, or the tool merged with one",
                )
            } else {
                match ends() {
                    Some((old_end, new_end)) if !(within(new_end, old_end) && within(old_end, new_end)) => (
                        false,
                        format!(
                            "a tool cut by the image border whose free end is unlike the lost one's ({new_end:.0} px² against {old_end:.0} px² within {length:.1} px of it)"
                        ),
                        "the tool merged with what its tip touches",
                    ),
                    _ => (true, String::new(), ""),
                }
            }
        } else if template.cuts.is_empty() {
            (
                within(new_long, old_long)
                    && within(old_long, new_long)
                    && within(new_short, old_short)
                    && within(old_short, new_short),
                "unlike the lost one".into(),
                "part of it, or another object",
            )
        } else {
            (
                within(new_long, old_long) && within(new_short, old_short),
                "cut by the image border and larger than the lost one".into(),
                "another object, or the object merged with one",
            )
        };
        if fits {
            return None;
        }
        state.refused_inits += 1;
        state.phase = Phase::Searching { missed: 0 };
        Some(format!(
            "lost; the object found afresh is {what} (spread {new_long:.1} x {new_short:.1} px against {old_long:.1} x {old_short:.1} px; ratio limit {MIN_SPREAD_RATIO}): {why}; its template is sought again ({} of {REFUSED_INITS} such refusals before one is taken)",
            state.refused_inits
        ))
    }

    /// The rest of [`Self::initialise`] once the object is `found` in
    /// `raw_left`: the fits on the (possibly smoothed) pair.
    pub(super) fn initialise_on(
        &mut self,
        frame: u64,
        (raw_left, raw_right): (&GrayFrame, &GrayFrame),
        found: &InitResult,
        (left, right): (&GrayFrame, &GrayFrame),
        prefilter_sigma_px: f64,
        previous_reference: Option<(f64, Option<Point>)>,
    ) -> PairResult {
        let fitted = found.core.as_ref().unwrap_or(&found.contour);
        let within = self
            .params
            .init
            .fit_domain(left.width, left.height, &found.cut_at_box);
        let Some((template, left_pose, left_terms, left_sums)) = self.template_from(left, fitted, within)
        else {
            return PairResult::lost(frame, "initial contour lies outside the image".into());
        };
        if let Some(reason) = self.refuse_unlike_lost(&template) {
            return PairResult::lost(frame, reason);
        }
        let energy = &self.params.energy;
        // The reported outline: a dark object's runs over its rim; any
        // other's is the fitted template moved onto the object's edge,
        // where the region energy leaves it 0.2-1 px outside a blurred
        // edge (see `init::edge_fit`). It moves with the template's pose.
        let outline = match &found.core {
            Some(_) => Some(found.contour.clone()),
            // Where its edge cannot be measured (a strong blur), the
            // initialisation's outline, which lies closer to it.
            None => fitted_to_edge(raw_left, &Polygon::new(place(&template.points, left_pose)))
                // No part of it moved past the box where it was cut.
                .map(|(p, _)| {
                    self.params
                        .init
                        .held_at_cut(p, left.width, left.height, &found.cut_at_box)
                })
                .or_else(|| found.border.is_empty().then(|| found.contour.clone())),
        };
        let outline = match outline {
            Some(outline) => {
                let (s, c) = (-left_pose.theta).sin_cos();
                let outline = outline.points.iter().map(|p| {
                    let [dx, dy] = [p[0] - left_pose.x, p[1] - left_pose.y];
                    [c * dx - s * dy, s * dx + c * dy]
                });
                outline.collect()
            }
            None => Vec::new(),
        };
        let right_pose = match self.search_right(right, &template, left_pose, None) {
            Some(p) => p,
            None => return PairResult::lost(frame, "object not found in the right image".into()),
        };
        // Both views of an object cut by the border fit the part of it that
        // both show.
        let (left_pose, left_terms, right_pose) = if template.cuts.is_empty() {
            (left_pose, left_terms, right_pose)
        } else {
            let disparity = [right_pose.x - left_pose.x, right_pose.y - left_pose.y];
            let [l, r] = shared_view_limits(&template, left_pose, disparity, [left.width, left.height]);
            let rigid = &self.params.rigid;
            let image = PixelRect::full(left).extent();
            let left_fixed = template
                .limited_to(l)
                .fixed_at(image, left_pose, Self::NEAR_REACH_PX);
            let left_fit = fit_rigid(
                &left_sums,
                &left_fixed,
                left_pose,
                energy,
                rigid,
                RigidSearch::settle(),
            );
            let limited = template.limited_to(r);
            let right_fixed = limited.with_fixed(left_fixed.fixed.as_ref().map(|f| f.moved(disparity)));
            let right_sums = self.sums_around(right, &limited, right_pose, Self::NEAR_REACH_PX);
            let right_fit = fit_rigid(
                &right_sums,
                &right_fixed,
                right_pose,
                energy,
                rigid,
                RigidSearch::settle(),
            );
            if left_fit.terms.energy.is_finite() && right_fit.terms.energy.is_finite() {
                let right_pose = self.mirrored_right_pose(
                    (left, right),
                    &limited,
                    [left_fit.pose, right_fit.pose],
                    within,
                );
                (left_fit.pose, left_fit.terms, right_pose)
            } else {
                (left_pose, left_terms, right_pose)
            }
        };
        let sectors = SectorTemplate::new(&template, self.params.occlusion.sectors);
        // Stored as the reference appearance; a sector not seen (cut off by
        // the image border) is stored as 0, which is never judged.
        let reference = |contrasts: Vec<f64>| -> Vec<f64> {
            contrasts
                .into_iter()
                .map(|c| if c.is_finite() { c } else { 0.0 })
                .collect()
        };
        let left_look = sectors.look(&left_sums, left_pose);
        let right_sums = self.sums_around(right, &template, right_pose, Self::NEAR_REACH_PX);
        // On the tables every later pair uses, so that the energy is scaled
        // as it will be then (the search's tables reach along the whole
        // disparity range).
        let right_terms = template.energy_at(&right_sums, right_pose, energy);
        let right_look = sectors.look(&right_sums, right_pose);
        let disparity = [right_pose.x - left_pose.x, right_pose.y - left_pose.y];
        let axis = axis_component(self.params.tilt_axis_deg, disparity);
        let mut state = TrackerState {
            template: template.points.clone(),
            template_cuts: template.cuts.clone(),
            left: left_pose,
            right: right_pose,
            reference_contrast: left_terms.contrast(),
            first_disparity_axis_px: previous_reference.map_or(axis, |r| r.0),
            first_disparity_px: previous_reference.map_or(Some(disparity), |r| r.1),
            width: left.width,
            height: left.height,
            phase: Phase::Tracking {
                velocity_measured: false,
            },
            left_velocity: [0.0; 3],
            left_sector_contrasts: reference(left_look.contrasts),
            right_sector_contrasts: reference(right_look.contrasts),
            left_sector_inner: reference(left_look.inner),
            right_sector_inner: reference(right_look.inner),
            grey_quantiles: Some([grey_quantiles(left), grey_quantiles(right)]),
            outline,
            prefilter_sigma_px,
            refused_inits: 0,
            uncertain_run: None,
            first_disparity_std_px: 0.0,
            edge_support: found.edge_support,
            disparity_run: DisparityRun::default(),
        };
        let [left_bands, right_bands] = noise_bands(
            &state,
            &template,
            &sectors,
            [(raw_left, left_pose), (raw_right, right_pose)],
        );
        // The standard errors on the energy the poses were fitted with.
        let left_fixed = template.fixed_at(PixelRect::full(left).extent(), left_pose, Self::NEAR_REACH_PX);
        let right_fixed = template.with_fixed(left_fixed.fixed.as_ref().map(|f| f.moved(disparity)));
        let mut left_fit = ImageFit::full(left_pose, left_terms);
        self.measure_std(
            left,
            &left_sums,
            (&left_fixed, &sectors),
            &mut left_fit,
            left_bands,
        );
        let mut right_fit = ImageFit::full(right_pose, right_terms);
        self.measure_std(
            right,
            &right_sums,
            (&right_fixed, &sectors),
            &mut right_fit,
            right_bands,
        );
        self.use_pair_noise(
            [left, right],
            (&template, &sectors),
            [left_bands, right_bands],
            [&mut left_fit, &mut right_fit],
        );
        let mut result = self.pair_result(
            frame,
            Status::Initialised,
            &state,
            &template,
            &left_fit,
            &right_fit,
        );
        let reason = self
            .loss_reason(&state, &template, &left_fit, &right_fit)
            .or_else(|| {
                let std = result.disparity_std_px?;
                self.unlike_left_view([left, right], &sectors, [left_pose, right_pose], std)
            })
            .or_else(|| {
                [
                    ("left", left, &left_fixed, &left_fit),
                    ("right", right, &right_fixed, &right_fit),
                ]
                .into_iter()
                .find_map(|(name, frame, fixed, fit)| self.no_basin(name, frame, fixed, fit))
            });
        if let Some(reason) = reason {
            result.mark_lost(reason);
            self.state = None;
            self.template = None;
            self.last_profile = None;
            return result;
        }
        // After a loss the object's first initialisation stays the
        // reference when its standard error was the lower: an object found
        // afresh with too little of it visible sets no looser limit for
        // itself (a rod half under a bar, re-initialised on the visible
        // half with a standard error of 2.5 px, then `tracked` at 3.2 px
        // against 4 times its own 2.5, 4.5 px off).
        let own = result.disparity_std_px.unwrap_or(0.0);
        state.first_disparity_std_px = match self.state.as_ref().map(|s| s.first_disparity_std_px) {
            Some(previous) if previous > 0.0 && own > 0.0 => previous.min(own),
            Some(previous) if previous > 0.0 => previous,
            _ => own,
        };
        self.last_profile = slide_reference(left, (&template, &sectors), state.left);
        self.state = Some(state);
        self.template = Some((template, sectors));
        result
    }

    /// Why a first pair's right view is not where it looks like the left
    /// view, if it is not (see [`APPEARANCE_STDS`]): the views look alike
    /// ([`ALIKE_SHARE`]) and the right pose lies more than
    /// [`APPEARANCE_STDS`] standard errors (`std`, the disparity's) plus a
    /// pixel from where the right outline's profile correlates best with
    /// the left's. The region energy places the right view; the profile,
    /// which affine grey changes leave alone, says which object it placed.
    pub(super) fn unlike_left_view(
        &self,
        [left, right]: [&GrayFrame; 2],
        sectors: &SectorTemplate,
        [left_pose, right_pose]: [Pose; 2],
        std: f64,
    ) -> Option<String> {
        let u = self.disparity_axis();
        let reach = self.params.max_disparity_px.ceil() as i64;
        let (reference, weights) = (
            profile(left, sectors, left_pose),
            weights_along(sectors, left_pose, u),
        );
        let [offset, best, here] =
            best_shift_along((&reference, &weights), right, sectors, right_pose, u, reach)?;
        let limit = APPEARANCE_STDS * std + 1.0;
        if offset.abs() <= limit {
            return None;
        }
        let own = reliability(&reference, &weights);
        (best >= ALIKE_SHARE * own).then(|| {
            format!(
                "the right view's fit lies {:.1} px along the disparity axis from where its outline looks most like the left view's (limit {limit:.1} px: {APPEARANCE_STDS} standard errors of {std:.2} px and a pixel; profile correlation {here:.2} at the fit against {best:.2} there, and the left view's with itself {own:.2}): the region energy placed it on something else; the object is initialised afresh on the next pair",
                offset.abs()
            )
        })
    }

    /// Why `fit`'s pose in `frame` (the view `name`) is no minimum of the
    /// energy of `template` along the disparity axis over the span its
    /// standard error claims ([`BASIN_STDS`]), if it is not: the energy
    /// lower at either end of the span than at the fit.
    pub(super) fn no_basin(
        &self,
        name: &str,
        frame: &GrayFrame,
        template: &RigidTemplate,
        fit: &ImageFit,
    ) -> Option<String> {
        let std = fit.axis_std_px;
        if !std.is_finite() {
            return None;
        }
        let span = (BASIN_STDS * std).max(1.0);
        let u = self.disparity_axis();
        let sums = self.sums_around(frame, template, fit.pose, span + Self::NEAR_REACH_PX);
        let at = |d: f64| {
            template
                .energy_at(&sums, fit.pose.moved_along(u, d), &self.params.energy)
                .energy
        };
        let (centre, minus, plus) = (at(0.0), at(-span), at(span));
        (minus.min(plus) < centre).then(|| format!(
            "the {name} view's energy falls {:.1} px along the disparity axis from its fit ({BASIN_STDS} of its standard errors of {std:.2} px, or a pixel): its fit is no minimum of the energy over the span its standard error claims; the object is initialised afresh on the next pair",
            span
        ))
    }

    /// Free fit from `contour` in `frame`, kept `within` the box where the
    /// hints put the object (when given): the rigid template of the result
    /// (cut where it runs along the image border), its pose settled on the
    /// rigid energy, the energy there and the tables it was settled on;
    /// `None` when the contour lies outside the image.
    pub(super) fn template_from<'f>(
        &self,
        frame: &'f GrayFrame,
        contour: &Polygon,
        within: Option<[f64; 4]>,
    ) -> Option<(RigidTemplate, Pose, EnergyTerms, PrefixSums<'f>)> {
        let energy = &self.params.energy;
        let sums = free_fit_tables(frame, contour, energy)?;
        // An outline along the image border lies on the border itself, the
        // edge of the last pixels' boxes, so that the region takes them in.
        let image = PixelRect::full(frame).extent();
        let on_border = RigidTemplate::ON_BORDER_PX;
        // A roi or an outline says where the object lies (`within`, see
        // `InitParams::fit_domain`): the fit stays there.
        let fitted = fit_free_within(
            &sums,
            &contour.snapped_to_box(image, on_border),
            energy,
            &self.params.free,
            within,
        );
        // A strip of substrate held inside by a bright line that meets the
        // object is cut out (see [`crate::strips`]).
        let fitted = refit_without_strips(frame, &sums, &fitted.polygon, energy, &self.params.free, within)
            .unwrap_or(fitted);
        // With a hint the initialisation chose the object by its edges
        // within it; a free fit that keeps less than FREE_FIT_MIN_IOU of that
        // region has left for what the two-region model prefers (the real
        // lamella's bright front face without its top face, whose grey is
        // the background's: IoU 0.61), and the initial outline stays.
        let hinted = self.params.init.names_region();
        let fitted = match fitted.polygon {
            f if hinted && polygon_iou(&f, contour) < FREE_FIT_MIN_IOU => {
                let start = match within {
                    Some(b) => contour.clipped_to_box(b),
                    None => contour.clone(),
                };
                start.resampled_every(self.params.free.spacing_px, MIN_FREE_VERTICES)
            }
            f => f,
        };
        let outline = match self.params.template_spacing_px {
            Some(spacing) => fitted.resampled_every(spacing, 16),
            None => fitted,
        }
        .snapped_to_box(image, on_border);
        let (template, fitted_pose) = RigidTemplate::new(&outline, self.params.rigid.coarse_vertices, energy);
        let template = template.cut_by(image, fitted_pose);
        // Settle the pose on the rigid energy too, so that the left and
        // right views are measured by the same criterion (identical views
        // then give zero disparity).
        let sums = self.sums_around(frame, &template, fitted_pose, Self::NEAR_REACH_PX);
        let fixed = template.fixed_at(image, fitted_pose, Self::NEAR_REACH_PX);
        let settled = fit_rigid(
            &sums,
            &fixed,
            fitted_pose,
            energy,
            &self.params.rigid,
            RigidSearch::settle(),
        );
        Some((template, settled.pose, settled.terms, sums))
    }

    /// The right pose of a first pair whose template is cut by the border,
    /// measured both ways. A template sits sharply on its own image's noise
    /// and not quite where it fits an independent image; along a slender
    /// tool's axis the two differ by up to 1.5 px, and only the first pair
    /// compares the template's own image with another. So the right view's
    /// part of the object (within `template`'s limits there) gets a template
    /// of its own, fitted back into the left view, and the disparity is the
    /// mean of the two ways, in which that difference cancels (border_tool,
    /// seeds 300-304 and 500-504: disparity RMS 0.169 and 0.168 px measured
    /// one way, 0.141 both ways).
    pub(super) fn mirrored_right_pose(
        &self,
        (left, right): (&GrayFrame, &GrayFrame),
        template: &RigidTemplate,
        [left_pose, right_pose]: [Pose; 2],
        within: Option<[f64; 4]>,
    ) -> Pose {
        let placed =
            Polygon::new(place(&template.points, right_pose)).clipped_to_box(PixelRect::full(right).extent());
        let placed = Polygon::new(
            template
                .cuts_at(right_pose)
                .iter()
                .fold(placed.points, |p, cut| cut.clip(&p)),
        );
        let Some((mirror, own_pose, _, _)) = self.template_from(right, &placed, within) else {
            return right_pose;
        };
        let start = Pose {
            x: own_pose.x - (right_pose.x - left_pose.x),
            y: own_pose.y - (right_pose.y - left_pose.y),
            theta: own_pose.theta,
        };
        let disparity = [right_pose.x - left_pose.x, right_pose.y - left_pose.y];
        let [l, _] = shared_view_limits(template, left_pose, disparity, [left.width, left.height]);
        let mirror =
            mirror
                .limited_to(l)
                .fixed_at(PixelRect::full(left).extent(), start, Self::NEAR_REACH_PX);
        let sums = self.sums_around(left, &mirror, start, self.params.rigid.search_radius_px);
        let back = fit_rigid(
            &sums,
            &mirror,
            start,
            &self.params.energy,
            &self.params.rigid,
            RigidSearch::settle(),
        );
        if !back.terms.energy.is_finite() {
            return right_pose;
        }
        let mean = |forth: f64, own: f64, back: f64, from: f64| from + 0.5 * (forth - from + own - back);
        Pose {
            x: mean(right_pose.x, own_pose.x, back.pose.x, left_pose.x),
            y: mean(right_pose.y, own_pose.y, back.pose.y, left_pose.y),
            theta: right_pose.theta,
        }
    }
}

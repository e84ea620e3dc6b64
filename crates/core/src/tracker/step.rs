//! A later pair: both views fitted rigidly from their predictions, the
//! right one along its epipolar line, with the rules that keep a fit that
//! left the object from being reported.

use crate::fit::{Pose, RigidTemplate};
use crate::geometry::{dist, Point};
use crate::imageio::GrayFrame;
use crate::occlusion::{runs_at_least, SectorTemplate};
use crate::region::PixelRect;
use crate::uncertainty;
use std::borrow::Cow;

use super::border::shared_view_limits;
use super::profile::{correlation, profile, slide_reference, weights_along};
use super::reacquire::REACQUIRE_OCCLUDED_FRACTION;
use super::result::{PairResult, Status, GOES_ON, UNCERTAIN};
use super::state::{Phase, TrackerState};
use super::view_fit::{fraction, ImageFit, ViewSearch};
use super::StereoTracker;

/// A left fit that moved more than this many pixels from its prediction
/// (and from the last pose) is lost as occluded when more than
/// [`FAR_MOVE_LEFT_OUT`] of its sectors are left out: too little of its
/// outline is seen to tell the object from what covers it.
pub(super) const FAR_MOVE_PX: f64 = 3.0;

/// The share of sectors left out beyond which a move of more than
/// [`FAR_MOVE_PX`] is not followed: more than half (a rod with a bar
/// along it, 58% left out, moved 3.2 px along its axis).
pub(super) const FAR_MOVE_LEFT_OUT: f64 = 0.55;

/// A masked left fit whose visible outline leaves its rotation's variance
/// more than this many times that of the whole outline
/// ([`uncertainty::rotation_variance`]) does not turn. Visible arcs of a
/// tool's round head gave 200-680; at 100 no figure of the occluder suites
/// changed, at 16 occluded rods that turn lagged behind (seeds 2000-2019:
/// left centroid RMS 0.23 -> 0.34 px, one confident wrong pair).
pub(super) const ROTATION_BLIND_RATIO: f64 = 100.0;

/// A fit with this many adjacent sectors over bare substrate
/// ([`crate::occlusion::overhanging`]) left the object's edge and is
/// lost. Single sectors are not enough: at 1, 40 more pairs of the
/// occluder suites (seeds 2000-2019) were lost, none of them wrong.
pub(super) const OVERHANG_RUN: usize = 2;

/// How far both views' fits may move from their predictions, pixels,
/// before the left view is fitted again from the right view's result (see
/// [`StereoTracker::track`]).
pub(super) const CROSS_CHECK_PX: f64 = 1.5;

/// How far the right view's fit may move from its prediction, pixels,
/// before the right image is searched along the whole epipolar line (see
/// [`StereoTracker::track`]).
pub(super) const DISPARITY_JUMP_PX: f64 = 3.0;

/// Largest standard error of the left pose in its weakest direction,
/// pixels, at which a pair of an object inside the image is tracked: the
/// left centroid is then within 3 px of the truth at two standard errors.
/// Not for a template cut by the border (see `StereoTracker::track`): the
/// real needle in contact with its lamella (contact_1), its tip's and
/// lower side's sectors left out after a tone change, was fixed to 1.8-5.7
/// px along its axis while its contour stayed on it and its disparity
/// within 0.07 px (6 pairs withheld).
pub(super) const MAX_POSITION_STD_PX: f64 = 1.5;

/// On a pair whose position is fixed only to more than
/// [`MAX_POSITION_STD_PX`] in one direction, a move of the left fit from its
/// prediction along that direction, towards a hidden end of the object,
/// of more than this many times the position's standard error is not
/// followed (see `StereoTracker::track`).
pub(super) const UNFOLLOWED_MOVE: f64 = 2.0;

/// Largest occluded share of the left outline at which a disparity that
/// jumped by more than [`DISPARITY_JUMP_PX`] is still trusted.
pub(super) const OCCLUDED_JUMP_FRACTION: f64 = 0.25;

/// The same share ([`fixed_share`]) below which a tracked pair's position
/// is `uncertain`: its standard error in the weakest direction more than
/// about 6 times what the whole outline gives. Below it, what holds the
/// position is the last pixels of the visible runs, where they round into
/// what is left out (a rod with a bright bar along one side and over one
/// end kept 0.1-1.2%, and its contour slid 14 px along its axis). Objects
/// held correctly with up to 40% of their outline hidden keep more (a rod
/// a third hidden: 6-9%): on the synthetic occluded, crossing and combined
/// presets (seeds 100-119 and 2000-2019) it leaves 2 such pairs of 10,507
/// more without numbers.
pub(super) const MIN_HELD_SHARE: f64 = 0.03;

/// A left fit of a template cut by the border that moved further than this
/// from where its domain was fixed is fitted again in the domain at its
/// pose, pixels.
pub(super) const FIXED_REFIT_PX: f64 = 0.5;

/// Where the left-out sectors of `fit` lie along the unit direction `w`,
/// relative to its pose, when they lie towards one end of the object
/// along it (their mean more than half-way from the pose to that end);
/// None otherwise (none left out, or left out along its sides).
pub(super) fn hidden_end(sectors: &SectorTemplate, fit: &ImageFit, w: Point) -> Option<f64> {
    if !fit.occluded.contains(&true) {
        return None;
    }
    let along = |p: &Point| (p[0] - fit.pose.x) * w[0] + (p[1] - fit.pose.y) * w[1];
    let reach = sectors
        .visible_arcs(fit.pose, &[])
        .iter()
        .flatten()
        .map(|p| along(p).abs())
        .fold(0.0, f64::max);
    let seen: Vec<bool> = fit.occluded.iter().map(|o| !o).collect();
    let hidden: Vec<f64> = sectors
        .visible_arcs(fit.pose, &seen)
        .iter()
        .flatten()
        .map(along)
        .collect();
    let mean = hidden.iter().sum::<f64>() / hidden.len() as f64;
    (mean.abs() > 0.5 * reach).then_some(mean)
}

impl StereoTracker {
    /// A later pair: rigid fits from the predicted poses (`from_search`:
    /// the poses a search over this pair found, not the last pair's).
    pub(super) fn track(
        &mut self,
        frame: u64,
        (left, right): (&GrayFrame, &GrayFrame),
        [left_bands, right_bands]: [uncertainty::NoiseBands; 2],
        mut state: TrackerState,
        templates: &(RigidTemplate, SectorTemplate),
        from_search: bool,
    ) -> PairResult {
        let template = &templates.0;
        let v = state.left_velocity;
        let [left_predicted, _] = state.predicted();
        let left_search = ViewSearch {
            coarse_step_px: self.params.rigid.coarse_step_px,
            rotate: self.params.rigid.rotate,
            line: None,
            last: Some(state.left),
        };
        let shared = (!template.cuts.is_empty()).then(|| {
            let disparity = state.disparity();
            let [l, r] = shared_view_limits(template, state.left, disparity, [left.width, left.height]);
            [
                (template.limited_to(l.clone()), templates.1.limited_to(l)),
                (template.limited_to(r.clone()), templates.1.limited_to(r)),
            ]
        });
        let (left_templates, right_templates) = match &shared {
            Some([l, r]) => (l, r),
            None => (templates, templates),
        };
        // A template cut by the border is fitted with its cuts and window
        // fixed in the image where each fit starts (RigidTemplate::fixed_at);
        // the right view's are the left view's at the left pose, moved by
        // the last disparity, so that both views look at the same part of
        // the object.
        let image = PixelRect::full_size(left.width, left.height).extent();
        let reach = self.params.rigid.search_radius_px;
        let fixing = shared.is_some();
        let left_at = |at: Pose| -> Cow<(RigidTemplate, SectorTemplate)> {
            if fixing {
                Cow::Owned((
                    left_templates.0.fixed_at(image, at, reach),
                    left_templates.1.clone(),
                ))
            } else {
                Cow::Borrowed(left_templates)
            }
        };
        let right_at_disparity =
            |left_pose: Pose, disparity: Point| -> Cow<(RigidTemplate, SectorTemplate)> {
                if fixing {
                    let domain = left_templates.0.domain_at(image, left_pose, reach);
                    let right = right_templates.0.with_fixed(domain.map(|d| d.moved(disparity)));
                    Cow::Owned((right, right_templates.1.clone()))
                } else {
                    Cow::Borrowed(right_templates)
                }
            };
        let right_at = |left_pose: Pose| right_at_disparity(left_pose, state.disparity());
        // A left fit in a domain fixed where it started, fitted again in
        // the domain at its own pose when it moved (the right view's domain
        // is placed from the left pose).
        let left_fit_from = |start: Pose, search: ViewSearch| {
            let fit = self.fit_view(
                left,
                &left_at(start),
                state.left_look(),
                start,
                search,
                left_bands,
            );
            if fixing
                && fit.terms.energy.is_finite()
                && dist(fit.pose.center(), start.center()) > FIXED_REFIT_PX
            {
                let again = self.fit_view(
                    left,
                    &left_at(fit.pose),
                    state.left_look(),
                    fit.pose,
                    ViewSearch {
                        coarse_step_px: 1.0,
                        ..search
                    },
                    left_bands,
                );
                if again.terms.energy.is_finite() {
                    return again;
                }
            }
            fit
        };
        let mut left_fit = left_fit_from(left_predicted, left_search);
        if !left_fit.terms.energy.is_finite() && v != [0.0; 3] {
            // The motion reversed (a tool moved in, then out): the last
            // pose is nearer than its continuation.
            left_fit = left_fit_from(state.left, left_search);
        }
        // What a masked fit leaves visible may fix no rotation: an arc of a
        // circle turns about its centre unseen (a tool's round head, the
        // rest of it before a particle as bright as itself, turned 0.02-0.05
        // rad per pair onto the particle's edge, its turn carried on by the
        // prediction, and was `tracked` 3-9 px off). Such a fit is made
        // again from the prediction at the last rotation, without turning.
        if left_search.rotate
            && template.rotation_observable
            && left_fit.occluded.contains(&true)
            && left_fit.terms.energy.is_finite()
        {
            let sectors = &templates.1;
            let centre = left_fit.pose.center();
            let seen = uncertainty::rotation_variance(
                &sectors.visible_arcs(left_fit.pose, &left_fit.occluded),
                centre,
            );
            let all = uncertainty::rotation_variance(&sectors.visible_arcs(left_fit.pose, &[]), centre);
            if seen > ROTATION_BLIND_RATIO * all {
                let start = Pose {
                    theta: state.left.theta,
                    ..left_predicted
                };
                let again = left_fit_from(
                    start,
                    ViewSearch {
                        rotate: false,
                        ..left_search
                    },
                );
                if again.terms.energy.is_finite() {
                    left_fit = again;
                }
            }
        }
        let right_search = ViewSearch {
            // No coarse stage: the prediction (left pose plus the last
            // disparity) is good, and starting the fine stage there makes
            // identical views give identical poses.
            coarse_step_px: 1.0,
            rotate: self.params.rigid.rotate && self.params.right_rotation,
            // Along the epipolar line, across the tilt axis.
            line: self.params.epipolar.then(|| self.disparity_axis()),
            last: None,
        };
        // The right view from a left pose: predicted with the last
        // disparity and fitted; when the disparity jumped (the tilt changed
        // between pairs, or the right fit walked along a weak edge), it is
        // searched along the whole epipolar line, as on the first pair (the
        // quartz grain, pairs 01-02 then 01-03: the fit walked 47 px from
        // its prediction to 73.9 px of disparity along the grain, where the
        // pair alone gives 55.1).
        let right_from = |left_pose: Pose| {
            let right_predicted = Pose {
                x: left_pose.x + state.right.x - state.left.x,
                y: left_pose.y + state.right.y - state.left.y,
                theta: left_pose.theta + state.right.theta - state.left.theta,
            };
            let fit = self.fit_view(
                right,
                &right_at(left_pose),
                state.right_look(),
                right_predicted,
                right_search,
                right_bands,
            );
            let fit = if dist(fit.pose.center(), right_predicted.center()) > DISPARITY_JUMP_PX {
                let last = state.disparity();
                match self.searched_right(
                    right,
                    right_templates,
                    (left_pose, last),
                    &fit,
                    right_search,
                    right_bands,
                ) {
                    // The search moves a template's cuts with it; where it
                    // settles, the fit is made again with the domain fixed
                    // where the left view's lies, moved by the disparity
                    // found, so that both views see the same part of the
                    // object (a needle along the axis, found again after a
                    // loss: the moving cut left its right contour 3.8 px
                    // short of the tip, `tracked` at 0.16 px).
                    Some(found) if fixing => {
                        let disparity = [found.pose.x - left_pose.x, found.pose.y - left_pose.y];
                        let mut again = self.fit_view(
                            right,
                            &right_at_disparity(left_pose, disparity),
                            state.right_look(),
                            found.pose,
                            right_search,
                            right_bands,
                        );
                        // It reports the larger of the two fits' standard
                        // errors: placed where a search put it, the domain
                        // can hold a wrong pose as well (a needle over a
                        // grain, 3.6 px off, its search's fit at 0.66 px
                        // and the refit at 0.39 px, under the limit).
                        if again.terms.energy.is_finite() {
                            if found.axis_std_px > again.axis_std_px {
                                again.axis_std_px = found.axis_std_px;
                            }
                            again
                        } else {
                            found
                        }
                    }
                    Some(found) => found,
                    None => fit,
                }
            } else {
                fit
            };
            (fit, right_predicted)
        };
        let (mut right_fit, right_predicted) = right_from(left_fit.pose);
        // Both fits left their predictions: the object moved unlike its
        // last motion, and the right view, predicted from the left fit,
        // found it elsewhere. The left fit may have settled beside the
        // object (a border tool reversing: its left contour stopped 7 px
        // short along its axis while the right one reached the object, 6.8
        // px of disparity error, reported `tracked`). A change of disparity
        // alone moves only the right view and needs no second fit. The left
        // view is fitted again from where the right view puts it, and the
        // fit with the lower energy stands, with the right view fitted
        // again from it (the right fit moves only along its line and keeps
        // the old left pose's offset across it). Only full fits compare
        // (masked energies over different sectors do not; with occluders
        // moving past, the check pulled contours onto them).
        let full = |fit: &ImageFit| !fit.occluded.contains(&true);
        if dist(left_fit.pose.center(), left_predicted.center()) > CROSS_CHECK_PX
            && dist(right_fit.pose.center(), right_predicted.center()) > CROSS_CHECK_PX
            && full(&left_fit)
            && full(&right_fit)
        {
            let from_right = Pose {
                x: right_fit.pose.x - (state.right.x - state.left.x),
                y: right_fit.pose.y - (state.right.y - state.left.y),
                theta: right_fit.pose.theta - (state.right.theta - state.left.theta),
            };
            let again = left_fit_from(
                from_right,
                ViewSearch {
                    coarse_step_px: 1.0,
                    ..left_search
                },
            );
            if full(&again) && self.lower_energy(left, &left_templates.0, again.pose, left_fit.pose) {
                left_fit = again;
                right_fit = right_from(left_fit.pose).0;
            }
        }
        // The disparity jumped while much of the left outline is hidden:
        // too little is visible to tell the object's disparity from the
        // occluder's, or from a guess along the line (a rod 58% occluded
        // was reported 32 px off, `tracked`).
        let jump = dist(
            [
                right_fit.pose.x - left_fit.pose.x,
                right_fit.pose.y - left_fit.pose.y,
            ],
            state.disparity(),
        );
        let occluded_jump = (jump > DISPARITY_JUMP_PX
            && left_fit.occluded_fraction() > OCCLUDED_JUMP_FRACTION)
            .then(|| {
                format!(
                    "occluded: the disparity jumped {jump:.1} px while {:.0}% of the left outline is hidden (limit {:.0}%)",
                    100.0 * left_fit.occluded_fraction(),
                    100.0 * OCCLUDED_JUMP_FRACTION
                )
            });
        let reach = self.params.rigid.search_radius_px;
        // A left fit that ended past the search discs (around the
        // prediction and the last pose) went further than the object may
        // move between pairs: the full fit, bounded by its disc, ran to the
        // edge, and the masked fit that followed walked on. It stands only
        // where no more of its outline is left out than a template found
        // after a loss may have (40%): a real grain between tilts
        // moved 25.7 px with a third of its sectors left out; a bar as
        // bright as a rod, over its upper half, took both contours 31 px
        // onto itself with 62% left out (`tracked` 1.3 px off at a
        // reported 0.26 px).
        let moved = dist(left_fit.pose.center(), left_predicted.center())
            .min(dist(left_fit.pose.center(), state.left.center()));
        let left_out = fraction(&left_fit.occluded);
        let limit = REACQUIRE_OCCLUDED_FRACTION.min(self.params.occlusion.max_occluded_fraction);
        // Within the discs, a long move to where most of the outline is left
        // out is no better placed: what is left cannot tell the object from
        // what covers it (a blob that started to move as a bright bar came
        // over a quarter of it was taken 23 px onto the bar, 83% left out;
        // a rod with a bar along it slid 3.2 px along its axis, 58% left
        // out, and was `tracked` 4 px off).
        let moved_unseen = if moved > reach && left_out > limit {
            Some(format!(
                "occluded: the left contour moved {moved:.1} px from its prediction, past the search radius ({reach} px), to where {:.0}% of its outline looks unlike the object's (limit {:.0}%)",
                100.0 * left_out,
                100.0 * limit
            ))
        } else if moved > FAR_MOVE_PX && left_out > FAR_MOVE_LEFT_OUT {
            Some(format!(
                "occluded: the left contour moved {moved:.1} px from its prediction (more than {FAR_MOVE_PX} px) to where {:.0}% of its outline looks unlike the object's (limit {:.0}% after such a move)",
                100.0 * left_out,
                100.0 * FAR_MOVE_LEFT_OUT
            ))
        } else {
            None
        };
        // The left pose's change over the pair, the next pair's prediction.
        let velocity = |pose: Pose| {
            [
                (pose.x - state.left.x).clamp(-reach, reach),
                (pose.y - state.left.y).clamp(-reach, reach),
                pose.theta - state.left.theta,
            ]
        };
        let mut candidate = TrackerState {
            left: left_fit.pose,
            right: right_fit.pose,
            left_velocity: velocity(left_fit.pose),
            phase: Phase::Tracking {
                velocity_measured: true,
            },
            ..state.clone()
        };
        self.use_pair_noise(
            [left, right],
            (template, &templates.1),
            [left_bands, right_bands],
            [&mut left_fit, &mut right_fit],
        );
        let mut result = self.pair_result(
            frame,
            Status::Tracked,
            &candidate,
            template,
            &left_fit,
            &right_fit,
        );
        // A fit whose outline runs over bare substrate along a run of
        // sectors left the object's edge there, whatever holds the rest in
        // place (a rod under a bar across one end, started to move along
        // its axis: its other end's sectors, past the rod's end, were left
        // out as hidden, and it was `tracked` 19 px along its axis).
        let overhang = [("left", &left_fit), ("right", &right_fit)]
            .into_iter()
            .find_map(|(name, fit)| {
                let runs = runs_at_least(&fit.overhang, OVERHANG_RUN);
                let sectors = runs.iter().filter(|&&r| r).count();
                (sectors > 0).then(|| {
                    format!(
                        "the {name} contour left the object's edge: {sectors} sectors of its outline, {OVERHANG_RUN} or more side by side, lie on bare substrate"
                    )
                })
            });
        if let Some(reason) = occluded_jump
            .or(moved_unseen)
            .or(overhang)
            .or_else(|| self.loss_reason(&candidate, template, &left_fit, &right_fit))
        {
            // Keep the last good poses; the next pair searches for the
            // template.
            result.mark_lost(reason);
            state.phase = Phase::Searching { missed: 0 };
            self.state = Some(state);
        } else {
            // The left contour's centroid is reported: a visible outline
            // that fixes it in one direction only (a slender object whose
            // ends and one side are hidden) gives a position the object
            // need not have, while the disparity, measured on the same edge
            // in both views, may still be right. Tracking goes on from the
            // fit; but a move from the prediction along that direction,
            // towards an end of the object whose sectors are hidden, of
            // more than UNFOLLOWED_MOVE times the position's standard error
            // is an occluder over that end pulling the contour onto itself,
            // and tracking goes on from the prediction along it (a rod
            // whose lower end went under a bright bar slid 5 px along its
            // axis, its position fixed to 2 px; from there its upper end's
            // sectors, inside the rod, looked like a new backdrop, and the
            // next pairs were `tracked` 15-35 px off). A position held by
            // less than MIN_HELD_SHARE of what the seen outline gives in
            // that direction is bias, not noise, whatever its standard
            // error says: the pair is `uncertain` too. A template cut by
            // the border is exempt from the looseness (not from the held
            // share): a tool is placed along its axis by its tip alone, so
            // its position is loose along it whenever the tip's sectors
            // are left out, and its moves along that direction are judged
            // by the outline's look instead (`unconfirmed_slide`).
            let position_std = left_fit.axis_std_px * left_fit.weakest_factor;
            // The fit's move from the prediction along its weakest
            // direction, and how much of it the poses give back.
            let w = left_fit.weakest_direction;
            let along =
                (left_fit.pose.x - left_predicted.x) * w[0] + (left_fit.pose.y - left_predicted.y) * w[1];
            let loose = position_std > MAX_POSITION_STD_PX && templates.0.cuts.is_empty();
            let unfixed = left_fit.fixed_share < MIN_HELD_SHARE;
            let given_back = if loose || unfixed {
                result.mark_lost(if loose {
                    format!(
                        "{UNCERTAIN}: what is visible of the left outline fixes the object's position only to {position_std:.1} px in one direction (limit {MAX_POSITION_STD_PX} px){GOES_ON}"
                    )
                } else {
                    format!(
                        "{UNCERTAIN}: what keeps its contrast of the left outline carries {:.0}% of the information on the object's position in its weakest direction that all of it seen gives (least {:.0}%){GOES_ON}",
                        100.0 * left_fit.fixed_share,
                        100.0 * MIN_HELD_SHARE
                    )
                });
                let towards_hidden_end =
                    hidden_end(&templates.1, &left_fit, w).is_some_and(|end| end.signum() == along.signum());
                Some(
                    if towards_hidden_end && along.abs() > UNFOLLOWED_MOVE * position_std {
                        along
                    } else {
                        0.0
                    },
                )
            } else if let Some([at_fit, at_prediction]) = self.unconfirmed_slide(
                left,
                left_templates,
                (&state, from_search),
                (left_fit.pose, w),
                along,
            ) {
                // A tool cut by the border is placed along its axis by its
                // tip alone: a fit that left the prediction along that axis
                // for a pose where its outline looks less like the last
                // pair's than at the prediction (a needle's tip over a
                // grain as bright as itself: its contour stopped where the
                // needle seemed to end) is not followed.
                result.mark_lost(format!(
                    "{UNCERTAIN}: the contour of an object cut by the border moved {:.1} px along its weakest direction from the prediction, to where the outline that places it along that direction looks less like the last pair's than at the prediction (correlation {at_fit:.2} against {at_prediction:.2}){GOES_ON}",
                    along.abs(),
                ));
                Some(along)
            } else {
                None
            };
            if let Some(back) = given_back {
                // The move not followed is not verified either: the run of
                // uncertain pairs counts it (see MAX_UNVERIFIED_MOVE_PX and
                // `bound_unverified_moves`, which says when).
                candidate.uncertain_run = Some(candidate.uncertain_run.unwrap_or(0.0) + back.abs());
                for pose in [&mut candidate.left, &mut candidate.right] {
                    pose.x -= back * w[0];
                    pose.y -= back * w[1];
                }
                candidate.left_velocity = velocity(candidate.left);
            } else {
                self.last_profile = slide_reference(left, (&templates.0, &templates.1), candidate.left);
            }
            self.state = Some(candidate);
        }
        result
    }

    /// For a template cut by the border whose left fit at `pose` moved
    /// `along` px from the prediction along its weakest direction `w`, more
    /// than [`FAR_MOVE_PX`]: the correlations of the grey profile across
    /// its outline with the last followed pair's ([`profile`]), at `pose`
    /// and at the prediction, when the first is not the higher. Each
    /// sample is weighted by what its vertex fixes along `w`, so a needle's
    /// tip carries the comparison and its sides, whose backdrop changes as
    /// it slides over a structured substrate, carry little. A needle that
    /// moved along its axis shows its tip where it was fitted and its shank
    /// at the prediction; a contour that stopped short of a tip gone over
    /// a grain as bright as itself, or ran on along a grain, shows the
    /// tip's look at the prediction better than where it went. No
    /// reference (a restored tracker, or one given new parameters, before
    /// its first followed pair): not confirmed. The correlation ignores
    /// affine grey changes between the pairs. Not judged on the pair after
    /// an initialisation (`from_search` false and no velocity measured),
    /// whose prediction is only the last pose.
    pub(super) fn unconfirmed_slide(
        &self,
        left: &GrayFrame,
        (template, sectors): &(RigidTemplate, SectorTemplate),
        (state, from_search): (&TrackerState, bool),
        (pose, w): (Pose, Point),
        along: f64,
    ) -> Option<[f64; 2]> {
        // The pair after an initialisation predicts the last pose, which
        // the whole object's outline placed: a move from it is the
        // object's own motion as much as a slide (`bound_unverified_moves`
        // counts it alike). A pose a search found, by the template's match
        // alone, is judged.
        let unpredicted = state.phase
            == Phase::Tracking {
                velocity_measured: false,
            }
            && !from_search;
        if template.cuts.is_empty() || along.abs() <= FAR_MOVE_PX || unpredicted {
            return None;
        }
        let weights = weights_along(sectors, pose, w);
        let Some(last) = self.last_profile.as_ref().filter(|p| p.len() == weights.len()) else {
            return Some([f64::NAN; 2]);
        };
        let [predicted, _] = state.predicted();
        let [at_fit, at_prediction] =
            [pose, predicted].map(|p| correlation(last, &profile(left, sectors, p), &weights));
        (at_fit.is_nan() || at_fit <= at_prediction.max(-1.0)).then_some([at_fit, at_prediction])
    }
}

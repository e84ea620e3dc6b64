//! After a loss: the object sought by its own template over the hint box,
//! then the whole image, and taken where both views show it as on its
//! first pair; after a change of the frame's tone curve that no gain and
//! offset explain, initialised afresh where it was last seen.

use crate::energy::INTENSITY_OFFSET;
use crate::fit::{fit_rigid, place, Pose, RigidSearch, RigidTemplate};
use crate::geometry::{polygon_iou, Polygon};
use crate::imageio::GrayFrame;
use crate::init::initialise;
use crate::occlusion::{
    edgeless, grey_change, grey_quantiles, judge_look, GreyMap, SectorReference, SectorTemplate,
    GREY_QUANTILES,
};
use crate::region::{PixelRect, PrefixSums};

use super::result::{PairResult, Status, FOUND_AFRESH, REACQUIRED};
use super::state::{Phase, TrackerState, REACQUIRE_PAIRS};
use super::std_error::{fixed_share, noise_bands};
use super::view_fit::{either, fraction, masked_fit, ImageFit};
use super::StereoTracker;

/// Least change of the object's grey against its surroundings
/// ([`crate::occlusion::grey_change`]) at which a template found after a
/// loss shows the object (and most, its inverse): the template placed in
/// a bright bar beside a rod, along its edge, kept the rod's contrast there
/// while its inside showed 0.62-0.72 of the rod's grey (its bright rim
/// included) against the same background (crossing rod 2005, taken 36 px
/// off and `tracked`). Objects under flicker (gain 0.8-1.2) and in the
/// other classes are found again after a loss as often with the bound as
/// without it (BENCHMARKS.md).
pub(super) const MIN_GREY_CHANGE: f64 = 0.8;

/// Largest share of occluded sectors at which a template found after a loss
/// is taken: the coverage up to which an occluded object is to be held
/// (issue #17). A bright bar beside a rod changes the contrast of the
/// sectors facing it: crossing rod 118 (seeds 100-119, 20 pairs), in full
/// view beside the bar, was refused at 0.38-0.5 with a limit of 0.25, and
/// lost for the rest of its run.
pub(super) const REACQUIRE_OCCLUDED_FRACTION: f64 = 0.4;

/// Least share of the information on the weakest direction of what is
/// seen of the outline ([`fixed_share`]) that the sectors keeping their
/// contrast must carry for a template found by search to show the object:
/// its position's standard error in that direction at most doubled. A
/// search looks everywhere, with no prediction to hold the pose: a needle's
/// shank matched along its axis, its tip inside the shank, keeps 9-21%.
pub(super) const MIN_FIXED_SHARE: f64 = 0.25;

/// Largest share of a frame's grey levels that a gain and offset from the
/// template's first pair may leave unexplained ([`GreyMap::unexplained`])
/// before a lost object the search does not find is initialised afresh
/// where it was last seen ([`StereoTracker::found_afresh_where_lost`]):
/// between the real sequences' frames 0.011 at most, after a regrade of
/// 8-bit levels 0.012; after the contact sequence's tone change
/// 0.079-0.104.
pub const MAX_UNEXPLAINED_GREY: f64 = 0.03;

/// Least IoU of an object initialised afresh after a failed search with
/// the outline it was last seen with
/// ([`StereoTracker::found_afresh_where_lost`]): the usual overlap at which
/// two regions name one object.
pub const AFRESH_MIN_IOU: f64 = 0.5;

/// How many of the lowest local minima of the template's energy over the
/// image the search after a loss fits: the first count, then up to the
/// second when none of those shows the object. A bright bar gives many
/// minima lower than the object's: with 5, crossing rod 118 was not among
/// them in a pair where nothing covered it; 15 and 40 find the same pairs.
pub(super) const SEARCH_MINIMA: [usize; 2] = [5, 15];

impl StereoTracker {
    /// Whether the template at `pose` shows the object as on the first pair
    /// (`reference`: that pair's sector contrasts in this view; `map`: the
    /// change of grey levels since, through which the look at `pose` is
    /// mapped back before it is compared, so that the microscope's
    /// automatic brightness and contrast change nothing): no sector
    /// hidden (its inside changed), at most [`REACQUIRE_OCCLUDED_FRACTION`]
    /// of them with a changed contrast, the median sector within 0.7-1.43
    /// of its first contrast, its grey against its surroundings within
    /// [`MIN_GREY_CHANGE`] of its first, and the sectors that keep their
    /// contrast fixing its position in its weakest direction with at least
    /// [`MIN_FIXED_SHARE`] of the information all seen ones give. With more
    /// of it changed, a slender
    /// object slid along its axis, or something like it, matches as well (a
    /// rod under a bar was taken again 10 px along its axis in one view
    /// only, 1.3 px of disparity off); the object is sought again on the
    /// next pair.
    pub(super) fn shows_object(
        &self,
        sums: &PrefixSums,
        sectors: &SectorTemplate,
        (reference, map): (SectorReference, Option<GreyMap>),
        pose: Pose,
    ) -> bool {
        let occlusion = &self.params.occlusion;
        let look = sectors.look(sums, pose);
        let look = match map {
            Some(m) => m.look_back(&look),
            None => look,
        };
        let judged = judge_look(
            reference,
            &look,
            occlusion.min_contrast_ratio,
            occlusion.max_contrast_ratio,
        );
        // What keeps its contrast must still fix the position about as well
        // as all that is seen: a border tool's shank slid along its axis
        // matches everywhere, its tip's few sectors left out as before a new
        // backdrop (a needle over a grain was taken again 117 px along its
        // axis, its tip's sectors inside the shank, and `tracked` on).
        let unseen: Vec<bool> = (0..sectors.len())
            .map(|k| {
                !(look.contrasts.get(k).is_some_and(|c| c.is_finite())
                    && reference
                        .contrasts
                        .get(k)
                        .is_some_and(|&c| c.is_finite() && c != 0.0))
            })
            .collect();
        let left_out = either(&unseen, &judged.occluded);
        fixed_share(sectors, pose, &unseen, &left_out) >= MIN_FIXED_SHARE
            && !judged.hidden.contains(&true)
            // Sectors before a new backdrop (judged by their inner bands)
            // do not count against it, while most of the outline keeps its
            // contrast.
            && fraction(&judged.occluded) <= REACQUIRE_OCCLUDED_FRACTION.min(occlusion.max_occluded_fraction)
            && (0.7..=1.0 / 0.7).contains(&judged.median_ratio)
            && grey_change(reference, &look)
                .is_none_or(|g| (MIN_GREY_CHANGE..=1.0 / MIN_GREY_CHANGE).contains(&g))
    }

    /// The object sought by its template after a loss, over the hint box
    /// and, when it is not found there, over the whole image (a stage move
    /// carries an object out of the box it was named in): the lowest local
    /// minima of the decimated template's energy on a grid of centres
    /// (steps of half the template's thickness, coarser on large images: at
    /// most about 20,000 points) at the last rotation, each fitted rigidly
    /// within two steps; the lowest energy among the fits whose sectors
    /// show the object as on the first pair stands. The five lowest minima
    /// are fitted first, the next ten only when none of those shows the
    /// object ([`SEARCH_MINIMA`]).
    pub(super) fn search_template(
        &self,
        frame: &GrayFrame,
        templates: &(RigidTemplate, SectorTemplate),
        reference: (SectorReference, Option<GreyMap>),
        theta: f64,
    ) -> Option<Pose> {
        let [x, y, w, h] = self.params.init.hints_for(frame.width, frame.height).ok()?.roi;
        let whole = [0, 0, frame.width, frame.height];
        let found = self.search_within(frame, templates, reference, theta, [x, y, w, h]);
        if found.is_some() || [x, y, w, h] == whole {
            return found;
        }
        self.search_within(frame, templates, reference, theta, whole)
    }

    /// [`Self::search_template`] over the box `[x, y, w, h]`.
    fn search_within(
        &self,
        frame: &GrayFrame,
        (template, sectors): &(RigidTemplate, SectorTemplate),
        reference: (SectorReference, Option<GreyMap>),
        theta: f64,
        [x, y, w, h]: [u32; 4],
    ) -> Option<Pose> {
        let (x0, y0, x1, y1) = (x as f64, y as f64, (x + w) as f64, (y + h) as f64);
        let reach = template.radius + template.margin + 2.0;
        let rect = PixelRect::around([x0, y0, x1, y1], reach, frame.width, frame.height)?;
        let sums = PrefixSums::new(frame, rect, INTENSITY_OFFSET);
        let step = (template.area / template.length)
            .max(((x1 - x0) * (y1 - y0) / 20_000.0).sqrt())
            .max(1.5);
        let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
        let half = [
            (0.5 * (x1 - x0) / step).ceil() as i64,
            (0.5 * (y1 - y0) / step).ceil() as i64,
        ];
        let pose_at = |i: i64, j: i64| {
            Some(Pose {
                x: cx + i as f64 * step,
                y: cy + j as f64 * step,
                theta,
            })
        };
        let starts = template.lowest_on_grid(&sums, &self.params.energy, half, pose_at, SEARCH_MINIMA[1]);
        // The lowest minima first; the next ones only when none of those
        // shows the object (each fit costs about 2 ms at 1024x768).
        let (first, rest) = starts.split_at(starts.len().min(SEARCH_MINIMA[0]));
        for batch in [first, rest] {
            if let Some(pose) = self.best_shown(&sums, (template, sectors), reference, batch, step) {
                return Some(pose);
            }
        }
        None
    }

    /// Of the rigid fits from `starts` (each within two grid `step`s), the
    /// lowest-energy one whose sectors show the object
    /// ([`Self::shows_object`]). A fit that does not is fitted again from
    /// its pose, by the band energy of the sectors that showed an edge of
    /// the object on the first pair ([`edgeless`] ones left out, from half
    /// a grid step, as far as that energy leads: the look judges where it
    /// lands, ranked by the full energy there): beside something as bright
    /// as the object the full energy hardly changes as the template slides
    /// towards it, and the rest of the outline places it (a lamella on a
    /// needle's tip, carried about 68 px by a stage move: every full fit
    /// stopped 28 px along the needle, the lamella's far end on the void).
    pub(super) fn best_shown(
        &self,
        sums: &PrefixSums,
        (template, sectors): (&RigidTemplate, &SectorTemplate),
        reference: (SectorReference, Option<GreyMap>),
        starts: &[Pose],
        step: f64,
    ) -> Option<Pose> {
        let (rigid, energy) = (&self.params.rigid, &self.params.energy);
        let search = RigidSearch {
            within_px: 2.0 * step,
            ..RigidSearch::of(rigid)
        };
        let edgeless = edgeless(reference.0.contrasts);
        let masked = edgeless
            .contains(&true)
            .then(|| self.masked_search(template, 0.5 * step, true, None));
        starts
            .iter()
            .filter_map(|&start| {
                let out = fit_rigid(sums, template, start, energy, rigid, search);
                if !out.terms.energy.is_finite() {
                    return None;
                }
                if self.shows_object(sums, sectors, reference, out.pose) {
                    return Some(ImageFit::full(out.pose, out.terms));
                }
                let pose = masked_fit(sums, sectors, out.pose, &edgeless, masked.as_ref()?);
                let terms = template.energy_at(sums, pose, energy);
                (terms.energy.is_finite() && self.shows_object(sums, sectors, reference, pose))
                    .then(|| ImageFit::full(pose, terms))
            })
            .min_by(|a, b| a.terms.energy.total_cmp(&b.terms.energy))
            .map(|fit| fit.pose)
    }

    /// A pair after a loss: the object sought by its own template in the
    /// left view ([`StereoTracker::search_template`]) and along the epipolar
    /// line in the right one, found where both views show the object as on
    /// the first pair; the tracking step from there gives the pair, with
    /// reason [`REACQUIRED`] (its judgement of the sectors leaves out what
    /// changed, which the search's full fits do not). Otherwise lost; after
    /// [`REACQUIRE_PAIRS`] such pairs the next one initialises afresh.
    /// With it, whether the search missed after a change of the left
    /// frame's grey levels since the first pair that no gain and offset
    /// explain ([`GreyMap::unexplained`] over [`MAX_UNEXPLAINED_GREY`], on
    /// the frames the looks are compared on): then the caller tries
    /// [`Self::found_afresh_where_lost`].
    pub(super) fn reacquire(
        &mut self,
        frame: u64,
        (raw_left, raw_right): (&GrayFrame, &GrayFrame),
        (left, right): (&GrayFrame, &GrayFrame),
        mut state: TrackerState,
        templates: &(RigidTemplate, SectorTemplate),
    ) -> (PairResult, bool) {
        let (template, sectors) = templates;
        // The first pair's look in each view, seen through the change of
        // grey levels since (the looks' contrasts and grey ratios are
        // invariant to a gain, not to an offset); the right view's only
        // once the left view has shown the object.
        let map = |view: usize, now: &[f64; GREY_QUANTILES]| {
            state.grey_quantiles.and_then(|q| GreyMap::between(&q[view], now))
        };
        let left_now = grey_quantiles(left);
        let left_map = map(0, &left_now);
        let found = self
            .search_template(left, templates, (state.left_look(), left_map), state.left.theta)
            .and_then(|left_pose| {
                let last = state.disparity();
                let pose = self.search_right(right, template, left_pose, Some(last))?;
                let sums = self.sums_around(right, template, pose, Self::NEAR_REACH_PX);
                let right_map = map(1, &grey_quantiles(right));
                self.shows_object(&sums, sectors, (state.right_look(), right_map), pose)
                    .then_some((left_pose, pose))
            });
        let Some((left_pose, right_pose)) = found else {
            // A change of grey levels that no gain and offset explain: the
            // looks cannot be mapped back (see `found_afresh_where_lost`).
            let retoned = state
                .grey_quantiles
                .zip(left_map)
                .is_some_and(|(q, m)| m.unexplained(&q[0], &left_now) > MAX_UNEXPLAINED_GREY);
            let missed = state.miss();
            let reason = format!(
                "lost; its template was not found in this pair ({missed} of {REACQUIRE_PAIRS} pairs searched; then the object is initialised afresh)"
            );
            self.state = Some(state);
            return (PairResult::lost(frame, reason), retoned);
        };
        let candidate = TrackerState {
            left: left_pose,
            right: right_pose,
            left_velocity: [0.0; 3],
            phase: Phase::Tracking {
                velocity_measured: false,
            },
            ..state.clone()
        };
        let [left_bands, right_bands] = noise_bands(
            &candidate,
            template,
            sectors,
            [(raw_left, left_pose), (raw_right, right_pose)],
        );
        // The tracking step from there, as from the last pair: it judges
        // the sectors and leaves out those that changed (the search's full
        // fits do not).
        let mut result = self.track(
            frame,
            (left, right),
            [left_bands, right_bands],
            candidate,
            templates,
            true,
        );
        if self.state.as_ref().is_none_or(|s| s.is_lost()) {
            state.miss();
            self.state = Some(state);
        } else if result.status == Status::Tracked && result.reason.is_none() {
            result.reason = Some(REACQUIRED.into());
        }
        (result, false)
    }

    /// A pair on which the search found no template, after a change of the
    /// frame's grey levels since the template's first pair that no gain
    /// and offset explain (see [`Self::reacquire`]): the looks the search judges by cannot be
    /// mapped back, and the template may no longer be the object's shape
    /// in grey (the real needle after the microscope's tone change, darker
    /// now than the substrate below it: its template, shaped by the first
    /// frame's light and shade, matched elsewhere, and the box the person
    /// drew on the first frame then framed the trench). The object is
    /// initialised afresh from the outline it was last seen with: its
    /// template at the last left pose, given as the `outline` hint (a
    /// lasso, moved onto the edges near it; its part on the image border
    /// drawn past it), the fits kept to where that outline lies. The fresh
    /// region must overlap that outline by [`AFRESH_MIN_IOU`], and the
    /// first pair's checks and [`Self::refuse_unlike_lost`] judge it as any
    /// fresh start; its reason is [`FOUND_AFRESH`]. `None`, with the
    /// search's state and template kept, when it is not taken.
    pub(super) fn found_afresh_where_lost(
        &mut self,
        frame: u64,
        left: &GrayFrame,
        right: &GrayFrame,
    ) -> Option<PairResult> {
        let state = self
            .state
            .as_ref()
            .filter(|s| matches!(s.phase, Phase::Searching { .. }))?;
        let last = Polygon::new(place(&state.template, state.left));
        // Its vertices on the image border drawn a pixel past it.
        let [x0, y0, x1, y1] = PixelRect::full(left).extent();
        let lasso = last.snapped_to_box(
            [x0 - 1.0, y0 - 1.0, x1 + 1.0, y1 + 1.0],
            RigidTemplate::ON_BORDER_PX + 1.0,
        );
        let mut hints = self.params.init.clone();
        (hints.roi, hints.point, hints.exclude) = (None, None, Vec::new());
        hints.outline = Some(lasso.points);
        let found = initialise(left, &hints).ok()?;
        if polygon_iou(&found.contour, &last) < AFRESH_MIN_IOU {
            return None;
        }
        let kept = (
            self.state.clone(),
            self.template.clone(),
            self.last_profile.clone(),
        );
        let named = std::mem::replace(&mut self.params.init, hints);
        let mut result = self.initialise_found(frame, left, right, found);
        self.params.init = named;
        if result.status == Status::Lost {
            (self.state, self.template, self.last_profile) = kept;
            return None;
        }
        result.reason.get_or_insert_with(|| FOUND_AFRESH.into());
        Some(result)
    }
}

//! The stereo tracker (Dahmen et al., ICINCO 2009, sections 3 and 4; method
//! note, pipeline): on the first pair the object is found in the left image
//! ([`crate::init`]) and fitted freely ([`crate::fit::fit_free`]); the fitted
//! contour becomes a rigid template, searched for in the right image along the
//! disparity axis. On every later pair both contours move rigidly
//! ([`crate::fit::fit_rigid`]): the left one from its last pose, the right one
//! from the new left pose plus the last disparity. Each pair yields the
//! disparity (right minus left centroid), its component across the tilt axis
//! and the angle difference, or a "lost" status with a reason instead of a
//! confident wrong answer.

mod border;
mod epipolar;
mod first_pair;
mod loss;
mod params;
mod profile;
mod reacquire;
mod result;
mod state;
mod std_error;
mod step;
mod substrate;
mod tables;
#[cfg(test)]
mod tests;
mod view_fit;

use crate::calib::axis_component;
use crate::fit::{Pose, RigidTemplate};
use crate::geometry::dist;
use crate::imageio::{check_pair, GrayFrame, ImageInputError};
use crate::occlusion::SectorTemplate;
use crate::prefilter;
use crate::region::PixelRect;
use crate::scatter::Measured;

pub use first_pair::{ELONGATED, FREE_FIT_MIN_IOU, MIN_SPREAD_RATIO, REFUSED_INITS};
pub use params::{TrackerParams, STD_GROWTH};
pub use result::{
    ImageResult, PairResult, Status, TrackError, DISPARITY_STD_FLOOR_PX, FOUND_AFRESH, REACQUIRED, UNCERTAIN,
};
pub use state::REACQUIRE_PAIRS;
pub use state::{Phase, TrackerState};

use result::GOES_ON;
use state::templates;
use std_error::noise_bands;

pub use crate::energy::INTENSITY_OFFSET;

/// Farthest the left contour may move from its predictions, summed over a
/// run of `uncertain` pairs, before the object counts as lost and the next
/// pair seeks its template: no pair of the run verified those moves, and a
/// left centroid 3 px off is a confident wrong answer once a pair is
/// `tracked` again (a rod under a bright bar along it slid 4.3 px along its
/// axis over five such pairs, the next one `tracked`). A fit's move that
/// the tracker did not follow counts too: the prediction it kept instead
/// is no better verified (a needle's tip over a grain, its fits stopped
/// 5-10 px short on three pairs, the prediction carried on past the
/// needle's reversal, and the next pair was `tracked` 35 px off).
pub const MAX_UNVERIFIED_MOVE_PX: f64 = 3.0;

/// Share of the standard error's limit ([`TrackerParams::std_limit`]) a
/// pair must keep under to end a run of `uncertain` pairs: a fit that has
/// just been doubtful and comes back at the edge of the limit is as likely
/// still doubtful (a needle's right view, its tip beyond the template's,
/// was `uncertain` at 0.56 px, then `tracked` at 0.38 px 4.0 px off, then
/// `uncertain` at 0.41 px).
pub const RETURN_STD_SHARE: f64 = 0.9;

/// Least share of the outline as named that must follow an edge (see
/// [`crate::init::InitResult::edge_support`]) for its pairs to carry
/// numbers: a region most of whose outline follows none may hold more or
/// less than the object (issue #64: a lamella's dark face taken with the
/// soft shadow above it, 0.47). The accuracy suites' synthetic objects
/// show 0.74 or more, the real lift-out and tilt frames 0.51-1.0.
pub const MIN_EDGE_SUPPORT: f64 = 0.5;

/// Shortest side of an image's working copy that initialisation accepts
/// (see [`InitParams::working_size`]).
const MIN_WORKING_SIDE: u32 = 8;

/// Buffers for a pair smoothed by the object's pre-filter, reused from
/// pair to pair.
#[derive(Clone, Debug, Default)]
struct Prefiltered {
    smoother: prefilter::Smoother,
    left: Option<GrayFrame>,
    right: Option<GrayFrame>,
}

impl Prefiltered {
    /// The pair smoothed by `sigma` pixels within `windows` (left, right),
    /// or as it is when `sigma` is 0.
    fn pair<'a>(
        &'a mut self,
        left: &'a GrayFrame,
        right: &'a GrayFrame,
        sigma: f64,
        windows: [PixelRect; 2],
    ) -> (&'a GrayFrame, &'a GrayFrame) {
        if sigma <= 0.0 {
            return (left, right);
        }
        let (out_left, out_right) = (
            self.left.get_or_insert_with(|| left.clone()),
            self.right.get_or_insert_with(|| right.clone()),
        );
        self.smoother.smooth_into(left, sigma, windows[0], out_left);
        self.smoother.smooth_into(right, sigma, windows[1], out_right);
        (out_left, out_right)
    }
}

/// One tracked object in a stereo sequence.
#[derive(Clone, Debug)]
pub struct StereoTracker {
    params: TrackerParams,
    state: Option<TrackerState>,
    /// Rigid template and its sectors, derived from `state.template`.
    template: Option<(RigidTemplate, SectorTemplate)>,
    /// Pairs processed so far (the next pair's frame index).
    frames: u64,
    /// Scratch for the smoothed pair of a blurred object.
    prefiltered: Prefiltered,
    /// The grey profile across the left outline on the last pair whose
    /// pose was followed ([`profile::profile`]), which a slide along the
    /// object's weakest direction is compared with; not stored (a restored
    /// tracker takes it from its next such pair).
    last_profile: Option<Vec<f64>>,
}

impl StereoTracker {
    /// A tracker awaiting its first pair. Panics never: invalid parameters
    /// are reported by [`TrackerParams::validate`], which callers run first.
    pub fn new(params: TrackerParams) -> Self {
        Self {
            params,
            state: None,
            template: None,
            frames: 0,
            prefiltered: Prefiltered::default(),
            last_profile: None,
        }
    }

    /// A tracker continuing from a saved state after `frames` pairs.
    pub fn from_state(params: TrackerParams, state: Option<TrackerState>, frames: u64) -> Self {
        let template = state.as_ref().map(|s| templates(s, &params));
        Self {
            params,
            state,
            template,
            frames,
            prefiltered: Prefiltered::default(),
            last_profile: None,
        }
    }

    /// The parameters.
    pub fn params(&self) -> &TrackerParams {
        &self.params
    }

    /// Replaces the parameters from the next pair on (the rigid template is
    /// rebuilt with them; the contour and pose are kept). Validate first.
    pub fn set_params(&mut self, params: TrackerParams) {
        self.template = self.state.as_ref().map(|s| templates(s, &params));
        // The rebuilt template may have other vertices.
        self.last_profile = None;
        self.params = params;
    }

    /// Measures disparities across a tilt axis at `deg` (degrees from +x
    /// towards +y) from the next pair on; the first pair's reference for
    /// `relative_disparity_axis_px` follows when the state knows its whole
    /// disparity. A session with a calibration uses the calibration's axis.
    pub fn set_tilt_axis_deg(&mut self, deg: f64) {
        if self.params.tilt_axis_deg == deg {
            return;
        }
        self.params.tilt_axis_deg = deg;
        if let Some(state) = &mut self.state {
            if let Some(d) = state.first_disparity_px {
                state.first_disparity_axis_px = axis_component(deg, d);
            }
        }
    }

    /// The durable state (None before the first successful initialisation).
    pub fn state(&self) -> Option<&TrackerState> {
        self.state.as_ref()
    }

    /// Pairs processed so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// Forgets the object: the next pair initialises again (the reference
    /// for relative disparity is kept only until then).
    pub fn reset(&mut self) {
        self.state = None;
        self.template = None;
        self.last_profile = None;
    }

    /// Processes one stereo pair.
    pub fn process(&mut self, left: &GrayFrame, right: &GrayFrame) -> Result<PairResult, TrackError> {
        check_pair(left, right)?;
        if let Some(s) = &self.state {
            if (s.width, s.height) != (left.width, left.height) {
                return Err(TrackError::SizeChanged {
                    width: left.width,
                    height: left.height,
                    expected_width: s.width,
                    expected_height: s.height,
                });
            }
        }
        let phase = self.state.as_ref().map(|s| s.phase);
        let searching = matches!(phase, Some(Phase::Searching { .. })) && self.template.is_some();
        let initialising = !matches!(phase, Some(Phase::Tracking { .. })) && !searching;
        if initialising {
            let (working_width, working_height) = self.params.init.working_size(left.width, left.height);
            if working_width < MIN_WORKING_SIDE || working_height < MIN_WORKING_SIDE {
                return Err(TrackError::Input(ImageInputError::TooThin {
                    width: left.width,
                    height: left.height,
                    working_width,
                    working_height,
                    working_max_side: self.params.init.working_max_side,
                    min: MIN_WORKING_SIDE,
                }));
            }
            self.params
                .init
                .hints_for(left.width, left.height)
                .map_err(TrackError::Hint)?;
        }
        let frame = self.frames;
        self.frames += 1;
        let predicted = self
            .state
            .as_ref()
            .filter(|s| {
                s.phase
                    == Phase::Tracking {
                        velocity_measured: true,
                    }
            })
            .map(|s| s.predicted()[0]);
        // The templates are lent to the step, not copied: tracking does not
        // change them, and initialising replaces them.
        let mut result = match (&self.state, self.template.take()) {
            (Some(state), Some(templates)) if !state.is_lost() => {
                let state = state.clone();
                let [left_predicted, right_predicted] = state.predicted();
                let bands = noise_bands(
                    &state,
                    &templates.0,
                    &templates.1,
                    [(left, left_predicted), (right, right_predicted)],
                );
                let mut prefiltered = std::mem::take(&mut self.prefiltered);
                let sigma = state.prefilter_sigma_px;
                let (left, right) = if sigma > 0.0 {
                    let windows = self.prefilter_windows(&state, &templates.0, left);
                    prefiltered.pair(left, right, sigma, windows)
                } else {
                    (left, right)
                };
                let result = self.track(frame, (left, right), bands, state, &templates, false);
                self.prefiltered = prefiltered;
                self.template = Some(templates);
                result
            }
            (Some(state), Some(templates)) if searching => {
                let state = state.clone();
                let mut prefiltered = std::mem::take(&mut self.prefiltered);
                let sigma = state.prefilter_sigma_px;
                let whole = [PixelRect::full(left); 2];
                let smoothed = prefiltered.pair(left, right, sigma, whole);
                let (result, retoned) = self.reacquire(frame, (left, right), smoothed, state, &templates);
                self.prefiltered = prefiltered;
                self.template = Some(templates);
                // Not found by its template after a change of tone: afresh
                // where it was last seen.
                if retoned {
                    self.found_afresh_where_lost(frame, left, right).unwrap_or(result)
                } else {
                    result
                }
            }
            (_, templates) => {
                self.template = templates;
                // A refused first pair is not counted.
                self.initialise(frame, left, right)
                    .inspect_err(|_| self.frames = frame)?
            }
        };
        let first = self.state.as_ref().map_or(0.0, |s| s.first_disparity_std_px);
        let in_run = self.state.as_ref().is_some_and(|s| s.uncertain_run.is_some());
        let full = self.params.std_limit(first);
        let limit = if in_run { RETURN_STD_SHARE * full } else { full };
        if let Some(std) = result
            .disparity_std_px
            .filter(|&std| std > limit && result.status != Status::Lost)
        {
            let run = if in_run {
                format!(", {RETURN_STD_SHARE} of it to end a run of uncertain pairs")
            } else {
                String::new()
            };
            result.mark_lost(format!(
                "{UNCERTAIN}: the disparity's standard error is {std:.2} px (limit {limit:.2} px: max_disparity_std_px {:.2}, or more for an object whose first pair exceeded it; its first pair's {first:.2} px{run}){GOES_ON}",
                self.params.max_disparity_std_px
            ));
        }
        self.bound_unverified_moves(&mut result, predicted, searching);
        self.withhold_unsupported(&mut result);
        self.scale_by_scatter(&mut result);
        Ok(result)
    }

    /// Withholds a pair with numbers whose object's outline as named mostly
    /// follows no edge ([`MIN_EDGE_SUPPORT`]) as `uncertain`; after the
    /// run of `uncertain` pairs is judged, which such a pair neither starts
    /// nor ends: what it says holds for every pair with this template.
    fn withhold_unsupported(&mut self, result: &mut PairResult) {
        let Some(support) = self.state.as_ref().and_then(|s| s.edge_support) else {
            return;
        };
        if support < MIN_EDGE_SUPPORT && result.status != Status::Lost {
            result.mark_lost(format!(
                "{UNCERTAIN}: {:.0}% of the object's outline as named follows an edge in the image (least {:.0}%), so the region may hold more or less than the object: name it by a box drawn close around it or by its outline{GOES_ON}",
                100.0 * support,
                100.0 * MIN_EDGE_SUPPORT
            ));
        }
    }

    /// Scales a pair with numbers' standard error by how much more the
    /// run's disparities scatter than their fits say ([`crate::scatter`]),
    /// then adds the pair to the run. After the limit of
    /// [`TrackerParams::max_disparity_std_px`], which judges the pair's own
    /// fits: a run's scatter does not make its pairs `uncertain`.
    fn scale_by_scatter(&mut self, result: &mut PairResult) {
        let Some(state) = self.state.as_mut().filter(|s| !s.is_lost()) else {
            return;
        };
        if !matches!(result.status, Status::Tracked | Status::Initialised) {
            return;
        }
        let (Some(std), Some(axis)) = (result.disparity_std_px, result.disparity_axis_px) else {
            return;
        };
        let factor = state.disparity_run.factor();
        state.disparity_run.push(Measured {
            frame: result.frame,
            disparity_px: axis,
            std_px: std,
        });
        result.disparity_std_px = Some(std * factor);
    }

    /// Adds how far an `uncertain` pair moved the left contour from its
    /// prediction (`predicted`, None after a loss or while the velocity is
    /// unmeasured) to the run's sum; past [`MAX_UNVERIFIED_MOVE_PX`] the
    /// object counts as lost, which the reason says, and the next pair
    /// seeks its template. A pair with numbers ends the run. The sum holds
    /// any move the step did not follow, except on the pair after an
    /// initialisation, whose outline the whole object placed (a rod whose
    /// end went under a bar slid 5 px along its axis there; not followed,
    /// the next pairs were right); on a pair whose object a search found
    /// (`searched`), where only the template's match placed it, that move
    /// counts (a needle found again with its tip over a grain slid 5.9 px
    /// along its axis; not followed, and not counted, the next pair was
    /// `tracked` with the tip 8.4 px off).
    fn bound_unverified_moves(&mut self, result: &mut PairResult, predicted: Option<Pose>, searched: bool) {
        let Some(state) = self.state.as_mut().filter(|s| !s.is_lost()) else {
            return;
        };
        let uncertain = result.status == Status::Lost
            && result.reason.as_deref().is_some_and(|r| r.starts_with(UNCERTAIN));
        if !uncertain {
            state.uncertain_run = None;
            return;
        }
        let so_far = state.uncertain_run.unwrap_or(0.0);
        let moved = match predicted {
            Some(predicted) => so_far + dist(predicted.center(), state.left.center()),
            None if !searched => 0.0,
            None => so_far,
        };
        if moved > MAX_UNVERIFIED_MOVE_PX {
            if let Some(reason) = result.reason.as_mut() {
                reason.truncate(reason.strip_suffix(GOES_ON).map_or(reason.len(), str::len));
                reason.push_str(&format!(
                    "; over this run of uncertain pairs the contour moved {moved:.1} px from its predictions (limit {MAX_UNVERIFIED_MOVE_PX} px): the object counts as lost and its template is sought from the next pair"
                ));
            }
            state.phase = Phase::Searching { missed: 0 };
            state.uncertain_run = None;
        } else {
            state.uncertain_run = Some(moved);
        }
    }

    /// Where a tracking step can read each image of the pair: the
    /// template's reach from its predicted poses within the rigid search
    /// radius, the right one stretched along the disparity axis by the
    /// largest disparity (the right view's re-search), and the smoothing's
    /// own reach. The pre-filter smooths only these.
    fn prefilter_windows(
        &self,
        state: &TrackerState,
        template: &RigidTemplate,
        frame: &GrayFrame,
    ) -> [PixelRect; 2] {
        let reach = self.params.rigid.search_radius_px + 3.0 * state.prefilter_sigma_px + 1.0;
        let rect = |pose: Pose, [sx, sy]: [f64; 2]| {
            let [x0, y0, x1, y1] = template.reach(pose, reach);
            PixelRect::covering(x0 - sx, y0 - sy, x1 + sx, y1 + sy, frame.width, frame.height)
                .unwrap_or(PixelRect::full(frame))
        };
        let [left_predicted, right_predicted] = state.predicted();
        // The disparity axis, n = (sin t, -cos t) (see `axis_component`).
        let t = self.params.tilt_axis_deg.to_radians();
        let d = self.params.max_disparity_px;
        [
            rect(left_predicted, [0.0, 0.0]),
            rect(right_predicted, [d * t.sin().abs(), d * t.cos().abs()]),
        ]
    }
}

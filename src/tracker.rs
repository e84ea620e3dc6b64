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

use serde::{Deserialize, Serialize};

use crate::calib::{axis_component, Calibration};
use crate::energy::{evaluate, EnergyParams, EnergyTerms};
use crate::fit::{fit_free, fit_rigid, place, FreeFitParams, Pose, RigidParams, RigidTemplate};
use crate::geometry::{Point, Polygon};
use crate::imageio::{check_pair, GrayFrame, ImageInputError};
use crate::init::{initialise, InitParams};
use crate::region::{PixelRect, PrefixSums};

/// Added to every grey value so that f(z) = z ln z is defined (method note:
/// "+1 on 8-bit counts"); the same for every frame, so energies compare.
pub const INTENSITY_OFFSET: f64 = 1.0;

/// All tracking parameters, with documented defaults.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrackerParams {
    /// Automatic initialisation on the first pair.
    pub init: InitParams,
    /// The energy (lambda, k, window margin).
    pub energy: EnergyParams,
    /// The free fit on the first left image.
    pub free: FreeFitParams,
    /// The rigid fits.
    pub rigid: RigidParams,
    /// Direction of the beam's tilt axis in the image, degrees from +x
    /// towards +y. Default 90 (the image y axis): disparity is then along x.
    pub tilt_axis_deg: f64,
    /// On the first pair, how far (pixels, along the disparity axis) the
    /// right view is searched from the left position. Default 64.
    pub max_disparity_px: f64,
    /// Vertex spacing of the rigid template, pixels. Default 2.
    pub template_spacing_px: f64,
    /// The pair is lost when the contrast in either image falls below this
    /// fraction of the contrast at initialisation. Default 0.3.
    pub min_contrast_ratio: f64,
}

impl Default for TrackerParams {
    fn default() -> Self {
        Self {
            init: InitParams::default(),
            energy: EnergyParams::default(),
            free: FreeFitParams::default(),
            rigid: RigidParams::default(),
            tilt_axis_deg: 90.0,
            max_disparity_px: 64.0,
            template_spacing_px: 2.0,
            min_contrast_ratio: 0.3,
        }
    }
}

impl TrackerParams {
    /// Checks every part; the message names the field and what was expected.
    pub fn validate(&self) -> Result<(), String> {
        self.init.validate().map_err(|e| format!("init: {e}"))?;
        self.energy
            .validate()
            .map_err(|e| format!("tracker.energy: {e}"))?;
        self.free.validate().map_err(|e| format!("tracker.free: {e}"))?;
        self.rigid.validate().map_err(|e| format!("tracker.rigid: {e}"))?;
        if !(self.tilt_axis_deg.is_finite() && (-360.0..=360.0).contains(&self.tilt_axis_deg)) {
            return Err(format!(
                "invalid tilt_axis_deg {} (expected -360..=360)",
                self.tilt_axis_deg
            ));
        }
        if !(self.max_disparity_px.is_finite() && (0.0..=4096.0).contains(&self.max_disparity_px)) {
            return Err(format!(
                "invalid max_disparity_px {} (expected 0..=4096)",
                self.max_disparity_px
            ));
        }
        if !(self.template_spacing_px.is_finite() && (0.5..=20.0).contains(&self.template_spacing_px)) {
            return Err(format!(
                "invalid template_spacing_px {} (expected 0.5..=20)",
                self.template_spacing_px
            ));
        }
        if !(self.min_contrast_ratio.is_finite() && (0.0..=1.0).contains(&self.min_contrast_ratio)) {
            return Err(format!(
                "invalid min_contrast_ratio {} (expected 0..=1)",
                self.min_contrast_ratio
            ));
        }
        Ok(())
    }
}

/// Outcome of one pair.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    /// The object was (re)found and fitted on this pair.
    Initialised,
    /// Both contours followed the object.
    Tracked,
    /// No trustworthy measurement; `reason` says why.
    Lost,
}

impl Status {
    /// The snake_case name used in JSON and CSV.
    pub fn name(self) -> &'static str {
        match self {
            Status::Initialised => "initialised",
            Status::Tracked => "tracked",
            Status::Lost => "lost",
        }
    }
}

/// The contour in one image of a pair.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ImageResult {
    /// Contour vertices, pixels.
    pub contour: Vec<Point>,
    /// Area centroid of the contour, pixels.
    pub centroid: Point,
    /// Orientation of the contour's principal axis, radians in (-pi/2, pi/2].
    pub angle_rad: f64,
    /// Energy of the contour (lower is better).
    pub energy: f64,
    /// Michelson contrast of inside against the background window, -1..=1.
    pub contrast: f64,
}

/// The measurement of one stereo pair.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PairResult {
    /// Index of the pair in the sequence, from 0.
    pub frame: u64,
    /// What happened.
    pub status: Status,
    /// Why the pair is lost (or re-initialised); null otherwise.
    pub reason: Option<String>,
    /// The left contour (null when nothing was found).
    pub left: Option<ImageResult>,
    /// The right contour.
    pub right: Option<ImageResult>,
    /// Right minus left centroid, pixels.
    pub disparity_px: Option<Point>,
    /// Component of the disparity across the tilt axis, pixels.
    pub disparity_axis_px: Option<f64>,
    /// `disparity_axis_px` minus its value on the first pair of the session.
    pub relative_disparity_axis_px: Option<f64>,
    /// Rotation of the right contour minus that of the left, radians.
    pub angle_diff_rad: Option<f64>,
    /// Height from the calibration, micrometres; null without one.
    pub z_um: Option<f64>,
}

impl PairResult {
    /// Fills `z_um` from a calibration (leaves it null for lost pairs).
    pub fn apply_calibration(&mut self, calibration: Option<&Calibration>) {
        self.z_um = match (calibration, self.disparity_px, self.status) {
            (Some(c), Some(d), Status::Initialised | Status::Tracked) => Some(c.z_um(d)),
            _ => None,
        };
    }
}

/// Why a pair could not be processed at all (as opposed to a lost object).
#[derive(Debug, thiserror::Error)]
pub enum TrackError {
    /// The two images differ in size (or another input problem).
    #[error(transparent)]
    Input(#[from] ImageInputError),
    /// The pair's size differs from the session's earlier pairs.
    #[error("pair is {width}x{height} but the session's pairs are {expected_width}x{expected_height} (expected the same size throughout; reset the session to change it)")]
    SizeChanged {
        width: u32,
        height: u32,
        expected_width: u32,
        expected_height: u32,
    },
}

/// The tracker's durable state: enough to continue a session after a restart.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrackerState {
    /// Rigid template: contour vertices relative to their area centroid.
    pub template: Vec<Point>,
    /// Current pose in the left image.
    pub left: Pose,
    /// Current pose in the right image.
    pub right: Pose,
    /// Left contrast at initialisation (the reference for "lost").
    pub reference_contrast: f64,
    /// Disparity-axis component on the session's first pair.
    pub first_disparity_axis_px: f64,
    /// Frame size the state belongs to.
    pub width: u32,
    /// See `width`.
    pub height: u32,
    /// True after a lost pair: the next pair initialises again.
    pub lost: bool,
}

/// One tracked object in a stereo sequence.
#[derive(Clone, Debug)]
pub struct StereoTracker {
    params: TrackerParams,
    state: Option<TrackerState>,
    template: Option<RigidTemplate>,
    /// Pairs processed so far (the next pair's frame index).
    frames: u64,
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
        }
    }

    /// A tracker continuing from a saved state after `frames` pairs.
    pub fn from_state(params: TrackerParams, state: Option<TrackerState>, frames: u64) -> Self {
        let template = state.as_ref().map(|s| rigid_template(&s.template, &params));
        Self {
            params,
            state,
            template,
            frames,
        }
    }

    /// The parameters.
    pub fn params(&self) -> &TrackerParams {
        &self.params
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
        let frame = self.frames;
        self.frames += 1;
        let result = match (&self.state, &self.template) {
            (Some(state), Some(template)) if !state.lost => {
                let (state, template) = (state.clone(), template.clone());
                self.track(frame, left, right, state, &template)
            }
            _ => self.initialise(frame, left, right),
        };
        Ok(result)
    }

    /// First pair (or after a loss): find, fit, search the right view.
    fn initialise(&mut self, frame: u64, left: &GrayFrame, right: &GrayFrame) -> PairResult {
        let previous_reference = self.state.as_ref().map(|s| s.first_disparity_axis_px);
        let found = match initialise(left, &self.params.init) {
            Ok(found) => found,
            Err(e) => return lost_result(frame, format!("initialisation failed: {e}")),
        };
        let energy = &self.params.energy;
        let margin = energy.margin_for_area(found.area_px);
        let [bx0, by0, bx1, by1] = found.bbox;
        let slack = margin + 16.0;
        let Some(rect) = PixelRect::covering(
            bx0 - slack,
            by0 - slack,
            bx1 + slack,
            by1 + slack,
            left.width,
            left.height,
        ) else {
            return lost_result(frame, "initial contour lies outside the image".into());
        };
        let left_sums = PrefixSums::new(left, rect, INTENSITY_OFFSET);
        let fitted = fit_free(&left_sums, &found.contour, energy, &self.params.free);
        let n = ((fitted.polygon.length() / self.params.template_spacing_px).round() as usize).max(16);
        let outline = fitted.polygon.resampled(n);
        let (template, left_pose) = RigidTemplate::new(&outline, self.params.rigid.coarse_vertices, energy);
        let left_terms = evaluate(
            &left_sums,
            &place(&template.points, left_pose),
            energy,
            template.margin,
        );

        let right_pose = match self.search_right(right, &template, left_pose) {
            Some(p) => p,
            None => return lost_result(frame, "object not found in the right image".into()),
        };
        let right_terms = right_pose.1;
        let disparity = [right_pose.0.x - left_pose.x, right_pose.0.y - left_pose.y];
        let axis = axis_component(self.params.tilt_axis_deg, disparity);
        let state = TrackerState {
            template: template.points.clone(),
            left: left_pose,
            right: right_pose.0,
            reference_contrast: left_terms.contrast(),
            first_disparity_axis_px: previous_reference.unwrap_or(axis),
            width: left.width,
            height: left.height,
            lost: false,
        };
        let mut result = self.pair_result(
            frame,
            Status::Initialised,
            &state,
            &template,
            left_terms,
            right_terms,
        );
        if let Some(reason) = self.loss_reason(&state, &template, left_terms, right_terms) {
            result.status = Status::Lost;
            result.reason = Some(reason);
            self.state = None;
            self.template = None;
            return result;
        }
        self.state = Some(state);
        self.template = Some(template);
        result
    }

    /// A later pair: rigid fits from the last poses.
    fn track(
        &mut self,
        frame: u64,
        left: &GrayFrame,
        right: &GrayFrame,
        mut state: TrackerState,
        template: &RigidTemplate,
    ) -> PairResult {
        let energy = &self.params.energy;
        let rigid = &self.params.rigid;
        let left_sums = self.sums_around(left, template, state.left, rigid.search_radius_px);
        let left_fit = fit_rigid(&left_sums, template, state.left, energy, rigid);
        let last_disparity = [state.right.x - state.left.x, state.right.y - state.left.y];
        let last_angle_diff = state.right.theta - state.left.theta;
        let right_start = Pose {
            x: left_fit.pose.x + last_disparity[0],
            y: left_fit.pose.y + last_disparity[1],
            theta: left_fit.pose.theta + last_angle_diff,
        };
        let right_sums = self.sums_around(right, template, right_start, rigid.search_radius_px);
        let right_fit = fit_rigid(&right_sums, template, right_start, energy, rigid);
        let candidate = TrackerState {
            left: left_fit.pose,
            right: right_fit.pose,
            ..state.clone()
        };
        let mut result = self.pair_result(
            frame,
            Status::Tracked,
            &candidate,
            template,
            left_fit.terms,
            right_fit.terms,
        );
        if let Some(reason) = self.loss_reason(&candidate, template, left_fit.terms, right_fit.terms) {
            // Keep the last good poses; the next pair initialises again.
            result.status = Status::Lost;
            result.reason = Some(reason);
            state.lost = true;
            self.state = Some(state);
        } else {
            self.state = Some(candidate);
        }
        result
    }

    /// Searches the right image along the disparity axis for the template
    /// placed at the left pose: a scan in 2-px steps over
    /// +-`max_disparity_px` with the decimated contour, then rigid fits from
    /// the three best local minima; returns the best pose and its energy.
    fn search_right(
        &self,
        right: &GrayFrame,
        template: &RigidTemplate,
        left: Pose,
    ) -> Option<(Pose, EnergyTerms)> {
        let energy = &self.params.energy;
        let max_d = self.params.max_disparity_px;
        let t = self.params.tilt_axis_deg.to_radians();
        // Unit vector across the tilt axis (the disparity direction).
        let dir = [t.sin(), -t.cos()];
        let [x0, y0, x1, y1] = template.reach(left, 8.0);
        let (ex, ey) = (dir[0].abs() * max_d, dir[1].abs() * max_d);
        let rect = PixelRect::covering(x0 - ex, y0 - ey, x1 + ex, y1 + ey, right.width, right.height)?;
        let sums = PrefixSums::new(right, rect, INTENSITY_OFFSET);
        let steps = (max_d / 2.0).ceil() as i64;
        let scan: Vec<(f64, f64)> = (-steps..=steps)
            .map(|k| {
                let d = (k as f64 * 2.0).clamp(-max_d, max_d);
                let pose = Pose {
                    x: left.x + d * dir[0],
                    y: left.y + d * dir[1],
                    theta: left.theta,
                };
                (
                    d,
                    evaluate(&sums, &place(&template.coarse, pose), energy, template.margin).energy,
                )
            })
            .collect();
        let mut minima: Vec<(f64, f64)> = (0..scan.len())
            .filter(|&i| {
                let e = scan[i].1;
                e.is_finite() && (i == 0 || scan[i - 1].1 >= e) && (i + 1 == scan.len() || scan[i + 1].1 > e)
            })
            .map(|i| scan[i])
            .collect();
        minima.sort_by(|a, b| a.1.total_cmp(&b.1));
        let rigid = RigidParams {
            coarse_step_px: 2.0,
            ..self.params.rigid.clone()
        };
        minima
            .iter()
            .take(3)
            .map(|&(d, _)| {
                let start = Pose {
                    x: left.x + d * dir[0],
                    y: left.y + d * dir[1],
                    theta: left.theta,
                };
                let out = fit_rigid(&sums, template, start, energy, &rigid);
                (out.pose, out.terms)
            })
            .filter(|(_, terms)| terms.energy.is_finite())
            .min_by(|a, b| a.1.energy.total_cmp(&b.1.energy))
    }

    /// Prefix sums over what the template can reach from `pose` within `reach`.
    fn sums_around(&self, frame: &GrayFrame, template: &RigidTemplate, pose: Pose, reach: f64) -> PrefixSums {
        let [x0, y0, x1, y1] = template.reach(pose, reach);
        let rect =
            PixelRect::covering(x0, y0, x1, y1, frame.width, frame.height).unwrap_or(PixelRect::full(frame));
        PrefixSums::new(frame, rect, INTENSITY_OFFSET)
    }

    /// Why the measurement cannot be trusted, if it cannot.
    fn loss_reason(
        &self,
        state: &TrackerState,
        template: &RigidTemplate,
        left: EnergyTerms,
        right: EnergyTerms,
    ) -> Option<String> {
        for (name, pose, terms) in [("left", state.left, left), ("right", state.right, right)] {
            let pts = place(&template.points, pose);
            let inside = pts.iter().all(|p| {
                p[0] >= 0.0
                    && p[1] >= 0.0
                    && p[0] <= (state.width - 1) as f64
                    && p[1] <= (state.height - 1) as f64
            });
            if !inside {
                return Some(format!("the contour left the {name} image"));
            }
            if !terms.energy.is_finite() {
                return Some(format!("no valid contour position in the {name} image"));
            }
            let reference = state.reference_contrast;
            let contrast = terms.contrast();
            if contrast * reference.signum() < self.params.min_contrast_ratio * reference.abs() {
                return Some(format!(
                    "contrast collapsed in the {name} image ({contrast:.3}, was {reference:.3} at initialisation; limit {:.2} of it)",
                    self.params.min_contrast_ratio
                ));
            }
        }
        None
    }

    fn pair_result(
        &self,
        frame: u64,
        status: Status,
        state: &TrackerState,
        template: &RigidTemplate,
        left: EnergyTerms,
        right: EnergyTerms,
    ) -> PairResult {
        let image = |pose: Pose, terms: EnergyTerms| {
            let contour = place(&template.points, pose);
            let angle = Polygon::new(contour.clone()).orientation();
            ImageResult {
                contour,
                centroid: pose.center(),
                angle_rad: angle,
                energy: terms.energy,
                contrast: terms.contrast(),
            }
        };
        let disparity = [state.right.x - state.left.x, state.right.y - state.left.y];
        let axis = axis_component(self.params.tilt_axis_deg, disparity);
        PairResult {
            frame,
            status,
            reason: None,
            left: Some(image(state.left, left)),
            right: Some(image(state.right, right)),
            disparity_px: Some(disparity),
            disparity_axis_px: Some(axis),
            relative_disparity_axis_px: Some(axis - state.first_disparity_axis_px),
            angle_diff_rad: Some(state.right.theta - state.left.theta),
            z_um: None,
        }
    }
}

fn rigid_template(points: &[Point], params: &TrackerParams) -> RigidTemplate {
    // The saved template is relative to its centroid already.
    RigidTemplate::new(
        &Polygon::new(points.to_vec()),
        params.rigid.coarse_vertices,
        &params.energy,
    )
    .0
}

fn lost_result(frame: u64, reason: String) -> PairResult {
    PairResult {
        frame,
        status: Status::Lost,
        reason: Some(reason),
        left: None,
        right: None,
        disparity_px: None,
        disparity_axis_px: None,
        relative_disparity_axis_px: None,
        angle_diff_rad: None,
        z_um: None,
    }
}

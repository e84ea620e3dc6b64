//! The rigid fit: translation and rotation of a template, coarse to fine
//! (method note, section 2, "Minimisation").

use crate::energy::{EnergyParams, EnergyTerms};
use crate::geometry::Point;
use crate::region::PrefixSums;

use super::search::{line_polish, newton_polish, CompassSearch};
use super::template::RigidTemplate;
use super::{place_into, Pose};

/// Parameters of the rigid fit.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
pub struct RigidParams {
    /// Largest motion between two pairs that the search is built to catch,
    /// pixels; the prefix sums cover the contour's reach plus this (the
    /// tracker first covers 6 px around a prediction and widens to this
    /// when the sectors do not confirm the prediction or the fit needs
    /// more). Default 24; range 1..=500.
    pub search_radius_px: f64,
    /// First step of the coarse stage, pixels. Default 8. With occlusion
    /// handling on, the tracker skips the coarse stage when the sectors
    /// confirm the predicted pose (each keeps >= 70% of its contrast there).
    pub coarse_step_px: f64,
    /// Vertices of the decimated contour used in the coarse stage. Default 48.
    pub coarse_vertices: usize,
    /// Smallest step of the compass search, pixels (rotation: arc length at
    /// the contour's outermost vertex); Newton steps on a local quadratic
    /// model refine the pose below it. Default 1/8: the same accuracy as 1/64
    /// on the synthetic suites (disparity RMS within 0.005 px, better on
    /// clean sequences: 0.025 against 0.030 px) with about 30 fewer energy
    /// evaluations per view.
    pub min_step_px: f64,
    /// Also search the rotation (the paper does). Default true.
    pub rotate: bool,
    /// Cap on energy evaluations per fit. Default 3000.
    pub max_evaluations: usize,
}

impl Default for RigidParams {
    fn default() -> Self {
        Self {
            search_radius_px: 24.0,
            coarse_step_px: 8.0,
            coarse_vertices: 48,
            min_step_px: 0.125,
            rotate: true,
            max_evaluations: 3000,
        }
    }
}

impl RigidParams {
    /// Checks ranges; the message says what was expected.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.search_radius_px.is_finite() && (1.0..=500.0).contains(&self.search_radius_px)) {
            return Err(format!(
                "invalid search_radius_px {} (expected 1..=500)",
                self.search_radius_px
            ));
        }
        if !(self.min_step_px > 0.0 && self.min_step_px <= 1.0) {
            return Err(format!(
                "invalid min_step_px {} (expected 0 < min_step_px <= 1)",
                self.min_step_px
            ));
        }
        if !(self.coarse_step_px.is_finite() && (1.0..=100.0).contains(&self.coarse_step_px)) {
            return Err(format!(
                "invalid coarse_step_px {} (expected 1..=100)",
                self.coarse_step_px
            ));
        }
        if !(8..=4096).contains(&self.coarse_vertices) {
            return Err(format!(
                "invalid coarse_vertices {} (expected 8..=4096)",
                self.coarse_vertices
            ));
        }
        if !(10..=1_000_000).contains(&self.max_evaluations) {
            return Err(format!(
                "invalid max_evaluations {} (expected 10..=1000000)",
                self.max_evaluations
            ));
        }
        Ok(())
    }
}

/// Result of a rigid fit.
#[derive(Clone, Copy, Debug)]
pub struct RigidOutcome {
    /// Best pose found.
    pub pose: Pose,
    /// Energy there.
    pub terms: EnergyTerms,
    /// Energy evaluations used.
    pub evaluations: usize,
    /// Some evaluated pose had no finite energy: its contour left the area
    /// the prefix sums cover (or a region was empty). The search could not
    /// go there, so a caller that built the sums over a short reach
    /// rebuilds them over a longer one and fits again.
    pub outside_area: bool,
}

/// How one rigid fit searches: what its caller sets for the call, apart
/// from the user's tuning in [`RigidParams`] (smallest step, evaluation
/// cap).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RigidSearch {
    /// First step of the coarse stage, pixels; 1 or less: no coarse stage.
    pub coarse_step_px: f64,
    /// Fit the rotation too (where the template shows it).
    pub rotate: bool,
    /// Translate only along this unit vector (image coordinates), with
    /// [`line_polish`] in place of [`newton_polish`]: the right view of a
    /// stereo pair moves across the tilt axis, along its epipolar line.
    pub line: Option<Point>,
    /// Poses further than this from the start are invalid, pixels: a
    /// tracking step's object moves no further between pairs, and beyond
    /// lie other things (a contour the tables' corners still reach).
    pub within_px: f64,
}

impl RigidSearch {
    /// The search `params` describe: their coarse step and rotation, free
    /// translation, no bound on the distance.
    pub fn of(params: &RigidParams) -> Self {
        Self {
            coarse_step_px: params.coarse_step_px,
            rotate: params.rotate,
            line: None,
            within_px: f64::INFINITY,
        }
    }

    /// A fit that settles a pose already near the minimum: the fine stage
    /// alone, without rotation.
    pub fn settle() -> Self {
        Self {
            coarse_step_px: 1.0,
            rotate: false,
            line: None,
            within_px: f64::INFINITY,
        }
    }

    /// This search without its coarse stage.
    pub fn fine_only(self) -> Self {
        Self {
            coarse_step_px: 1.0,
            ..self
        }
    }
}

/// Rigid minimisation by compass search, in the paper's order: translation
/// in x, translation in y, rotation about the centroid; a move that helps is
/// repeated while it keeps helping. Each step size gets one such round and
/// then halves; at `min_step_px` rounds repeat until nothing improves. The
/// coarse stage runs on a decimated contour with steps from the search's
/// `coarse_step_px` down to 1 px (translation only), so motion of tens of
/// pixels costs little; the fine stage uses every vertex, with steps from
/// 0.5 px down to `min_step_px`, then [`newton_polish`] (or [`line_polish`]
/// along the search's line).
pub fn fit_rigid(
    sums: &PrefixSums,
    template: &RigidTemplate,
    start: Pose,
    energy: &EnergyParams,
    params: &RigidParams,
    search: RigidSearch,
) -> RigidOutcome {
    let RigidSearch {
        coarse_step_px,
        rotate,
        line,
        within_px,
    } = search;
    // One vertex buffer for every evaluation (no allocation per pose).
    let placed = std::cell::RefCell::new(Vec::with_capacity(template.points.len()));
    // The lowest-energy pose of the fine stage with its terms: the fit ends
    // there, so its terms need no evaluation of their own (one of about 30
    // per view).
    let lowest = std::cell::Cell::new(None::<(Pose, EnergyTerms)>);
    let outside_area = std::cell::Cell::new(false);
    let eval_terms = |pts: &[Point], length: f64, pose: Pose| {
        if (pose.x - start.x).hypot(pose.y - start.y) > within_px {
            return EnergyTerms::INVALID;
        }
        let mut placed = placed.borrow_mut();
        place_into(pts, pose, &mut placed);
        let terms = template.energy_of(sums, &placed, pose, length, energy);
        if !terms.energy.is_finite() {
            outside_area.set(true);
        }
        terms
    };
    let eval = |pts: &[Point], length: f64, pose: Pose| eval_terms(pts, length, pose).energy;
    let mut pose = start;
    let mut evaluations = 0;
    // Coarse stage: translation only, decimated contour.
    if coarse_step_px > 1.0 {
        let coarse = CompassSearch {
            first_step: coarse_step_px,
            min_step: 1.0,
            radius: template.radius,
            rotate: false,
            max_evaluations: params.max_evaluations,
            settle_every_step: false,
            along: template.search_axis(),
            only: line,
        };
        let (p, _, used) = coarse.run(pose, |p| eval(&template.coarse, template.coarse_length, p));
        pose = p;
        evaluations += used;
    }
    // Fine stage: every vertex, with rotation.
    let fine = CompassSearch {
        // Half a pixel, after a coarse stage (translation to 1 px) or from
        // the right view's prediction: a round at 1 px rarely moved, and a
        // move that helps is repeated anyway (measured: 4 fewer evaluations
        // per 1024x768 step, synthetic suites unchanged to 1e-4 px).
        first_step: 0.5f64.max(params.min_step_px),
        min_step: params.min_step_px,
        radius: template.radius,
        rotate: rotate && template.rotation_observable,
        max_evaluations: params.max_evaluations.saturating_sub(evaluations).max(1),
        settle_every_step: false,
        along: template.search_axis(),
        only: line,
    };
    // The window moves with the contour, so the energy is a function of the
    // pose alone: two fits of the same image from different starts share
    // their minimum (a window held where each fit's coarse stage ended gave
    // identical images a disparity of up to 1.8 px on the quartz images).
    let energy_at = |p: Pose| {
        let terms = eval_terms(&template.points, template.length, p);
        if lowest.get().is_none_or(|(_, t)| terms.energy < t.energy) {
            lowest.set(Some((p, terms)));
        }
        terms.energy
    };
    let (pose, best, used) = fine.run(pose, energy_at);
    let (pose, _, polished) = match line {
        Some(u) => line_polish(pose, best, u, energy_at),
        None => newton_polish(pose, best, template.radius, fine.rotate, energy_at),
    };
    let terms = match lowest.get() {
        Some((at, terms)) if at == pose => terms,
        _ => template.energy_at(sums, pose, energy),
    };
    RigidOutcome {
        pose,
        terms,
        evaluations: evaluations + used + polished,
        outside_area: outside_area.get(),
    }
}

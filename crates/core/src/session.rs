//! A measurement session: one to [`MAX_OBJECTS`] named objects, each with
//! its own hints and [`StereoTracker`], measured on every stereo pair; their
//! heights through one calibration, across one tilt axis; and the height of
//! every object relative to every other (a tool above the part it handles).
//!
//! The rule for the tilt axis: with a calibration, every object measures
//! its disparity across the calibration's axis, the one its `z_um` uses;
//! without one, across its tracker's `tilt_axis_deg`.
//!
//! Relative heights. For objects `a` and `b` tracked on the same pair,
//! `disparity_axis_px = d_a - d_b` with standard error
//! `sqrt(s_a^2 + s_b^2)`: the two disparities are fitted on disjoint parts
//! of the images, so their pixel noise is independent, while what the two
//! share (the frames' drift and line jitter, the calibration's intercept)
//! cancels in the difference. The `s` are the fits' own standard errors,
//! not scaled by each object's run ([`crate::scatter`]): an error the two
//! objects share (both drifting alike across the pixel grid) scatters each
//! disparity but not their difference, and the difference's own run
//! cannot tell a tool's steps of a few standard errors from noise. `dz_um`
//! and `dz_std_um` come from [`Calibration::dz_for_pair`], which adds a
//! fitted calibration's coefficient uncertainty at the two disparities
//! together.

use crate::calib::{Calibration, MetaWatch};
use crate::geometry::{polygon_iou, Polygon};
use crate::imageio::GrayFrame;
use crate::init::{InitError, SAME_REGION_IOU};
use crate::meta::ImageMeta;
use crate::tracker::{PairResult, Status, StereoTracker, TrackError, TrackerParams, TrackerState};

/// Most objects a session holds.
pub const MAX_OBJECTS: usize = 16;

/// Name of a session's object when none is named.
pub const DEFAULT_OBJECT_NAME: &str = "object";

/// Longest object name, characters.
pub const MAX_NAME_LEN: usize = 64;

/// Checks an object name: 1 to [`MAX_NAME_LEN`] ASCII letters, digits,
/// `_`, `-` or `.` (names appear in URLs and CSV cells as they are).
pub fn check_object_name(name: &str) -> Result<(), SessionError> {
    let ok = (1..=MAX_NAME_LEN).contains(&name.len())
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'_' | b'-' | b'.'));
    if ok {
        Ok(())
    } else {
        Err(SessionError::InvalidName(name.chars().take(80).collect()))
    }
}

/// Why a session cannot be built or changed as asked.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SessionError {
    /// A name outside the allowed characters or length.
    #[error("invalid object name {0:?} (expected 1..={MAX_NAME_LEN} of A-Z a-z 0-9 _ - .)")]
    InvalidName(String),
    /// Two objects with one name.
    #[error("object name {0:?} given twice (expected each name once)")]
    DuplicateName(String),
    /// More than [`MAX_OBJECTS`] objects.
    #[error("{0} objects (expected 1..={MAX_OBJECTS})")]
    ObjectCount(usize),
    /// No object with that name.
    #[error("no object named {0:?}")]
    UnknownObject(String),
}

impl SessionError {
    /// A snake_case code for error bodies and CLI messages.
    pub fn code(&self) -> &'static str {
        match self {
            Self::InvalidName(_) => "invalid_object_name",
            Self::DuplicateName(_) => "duplicate_object",
            Self::ObjectCount(_) => "object_count",
            Self::UnknownObject(_) => "object_not_found",
        }
    }
}

/// A pair that could not be measured for one of the objects (none has
/// moved on).
#[derive(Debug, thiserror::Error)]
#[error("object {object:?}: {error}")]
pub struct MeasureError {
    /// The object's name.
    pub object: String,
    /// What went wrong.
    #[source]
    pub error: TrackError,
}

/// One tracked object of a session.
pub struct SessionObject {
    /// Its name, unique in the session.
    pub name: String,
    /// Its tracker (parameters with its hints, contour, pose).
    pub tracker: StereoTracker,
}

impl SessionObject {
    /// A new object that initialises on the next pair with `params`.
    pub fn new(name: impl Into<String>, params: TrackerParams) -> Self {
        Self {
            name: name.into(),
            tracker: StereoTracker::new(params),
        }
    }
}

/// One object's measurement of a pair.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct ObjectResult {
    /// The object's name.
    pub name: String,
    /// Its measurement (status, contours, disparity, z and their errors).
    #[cfg_attr(feature = "serde", serde(flatten))]
    pub result: PairResult,
}

/// The height of one object relative to another on the same pair; null
/// numbers when either is not measured (lost), or without a calibration
/// for `dz_um`.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Relative {
    /// The object measured.
    pub from: String,
    /// The object it is measured against.
    pub to: String,
    /// `from`'s disparity across the tilt axis minus `to`'s, pixels.
    pub disparity_axis_px: Option<f64>,
    /// Standard error of `disparity_axis_px`, pixels: the two fits' own
    /// in quadrature (see the module docs).
    pub disparity_std_px: Option<f64>,
    /// `from`'s height minus `to`'s, micrometres.
    pub dz_um: Option<f64>,
    /// Standard error of `dz_um`, micrometres.
    pub dz_std_um: Option<f64>,
}

/// A session's measurement of one pair.
#[derive(Clone, Debug, PartialEq)]
pub struct Measurement {
    /// Index of the pair in the session, from 0.
    pub frame: u64,
    /// Every object's measurement, in the session's order.
    pub objects: Vec<ObjectResult>,
    /// Every ordered pair of objects (none for a one-object session).
    pub relative: Vec<Relative>,
}

/// The objects of a session and what they share: the frame count and the
/// last pixel size the pairs' metadata gave.
pub struct Session {
    objects: Vec<SessionObject>,
    frames: u64,
    meta_watch: MetaWatch,
}

impl Session {
    /// A session of `objects` (1..=[`MAX_OBJECTS`], unique valid names)
    /// that has seen `frames` pairs.
    pub fn new(objects: Vec<SessionObject>, frames: u64) -> Result<Self, SessionError> {
        if !(1..=MAX_OBJECTS).contains(&objects.len()) {
            return Err(SessionError::ObjectCount(objects.len()));
        }
        for (i, o) in objects.iter().enumerate() {
            check_object_name(&o.name)?;
            if objects[..i].iter().any(|p| p.name == o.name) {
                return Err(SessionError::DuplicateName(o.name.clone()));
            }
        }
        Ok(Self {
            objects,
            frames,
            meta_watch: MetaWatch::default(),
        })
    }

    /// A session with one object, [`DEFAULT_OBJECT_NAME`].
    pub fn single(params: TrackerParams) -> Self {
        Self {
            objects: vec![SessionObject::new(DEFAULT_OBJECT_NAME, params)],
            frames: 0,
            meta_watch: MetaWatch::default(),
        }
    }

    /// The objects, in order.
    pub fn objects(&self) -> &[SessionObject] {
        &self.objects
    }

    /// The objects, to change their trackers.
    pub fn objects_mut(&mut self) -> &mut [SessionObject] {
        &mut self.objects
    }

    /// Sets the count of pairs measured (a session restored from storage).
    pub fn set_frames(&mut self, frames: u64) {
        self.frames = frames;
    }

    /// The object named `name`.
    pub fn object_mut(&mut self, name: &str) -> Result<&mut SessionObject, SessionError> {
        self.objects
            .iter_mut()
            .find(|o| o.name == name)
            .ok_or_else(|| SessionError::UnknownObject(name.into()))
    }

    /// Adds an object; it initialises on the next pair.
    pub fn add(&mut self, object: SessionObject) -> Result<(), SessionError> {
        check_object_name(&object.name)?;
        if self.objects.iter().any(|o| o.name == object.name) {
            return Err(SessionError::DuplicateName(object.name));
        }
        if self.objects.len() >= MAX_OBJECTS {
            return Err(SessionError::ObjectCount(self.objects.len() + 1));
        }
        self.objects.push(object);
        Ok(())
    }

    /// Removes the object named `name` (a session keeps at least one).
    pub fn remove(&mut self, name: &str) -> Result<SessionObject, SessionError> {
        let i = self
            .objects
            .iter()
            .position(|o| o.name == name)
            .ok_or_else(|| SessionError::UnknownObject(name.into()))?;
        if self.objects.len() == 1 {
            return Err(SessionError::ObjectCount(0));
        }
        Ok(self.objects.remove(i))
    }

    /// Pairs measured so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// Measures every object on one pair: its tracker's result with the
    /// images' metadata and the calibration's height applied, then every
    /// relative height. On an error (images of another size, a hint that
    /// does not fit them) no object has moved on: the pair does not count.
    pub fn measure(
        &mut self,
        left: &GrayFrame,
        right: &GrayFrame,
        meta: Option<(&ImageMeta, &ImageMeta)>,
        calibration: Option<&Calibration>,
    ) -> Result<Measurement, MeasureError> {
        self.measure_on(left, right, meta, calibration, 1)
    }

    /// How many threads the next pair's objects are worth: one per object
    /// when any of them initialises or searches for itself (tens of
    /// milliseconds each), else 1. A tracking step (about 0.5 ms at
    /// 1024x768) gains nothing from a thread of its own: two objects over
    /// one WebSocket on 2 cores gave 534 pairs/s side by side against 689
    /// one after the other (BENCHMARKS.md).
    pub fn useful_threads(&self) -> usize {
        let searching = |o: &SessionObject| o.tracker.state().is_none_or(|s| s.is_lost());
        if self.objects.len() > 1 && self.objects.iter().any(searching) {
            self.objects.len()
        } else {
            1
        }
    }

    /// [`Session::measure_on`] on a decoded pair, with its files' metadata.
    pub fn measure_pair(
        &mut self,
        pair: &crate::pair::DecodedPair,
        calibration: Option<&Calibration>,
        threads: usize,
    ) -> Result<Measurement, MeasureError> {
        let meta = pair.meta.as_ref().map(|(l, r)| (l, r));
        self.measure_on(&pair.left, &pair.right, meta, calibration, threads)
    }

    /// [`Session::measure`] with the objects tracked on up to `threads`
    /// threads at once (each object's tracker is independent of the
    /// others', so the results are the same for any count; 0 and 1 track
    /// them one after the other on the calling thread).
    pub fn measure_on(
        &mut self,
        left: &GrayFrame,
        right: &GrayFrame,
        meta: Option<(&ImageMeta, &ImageMeta)>,
        calibration: Option<&Calibration>,
        threads: usize,
    ) -> Result<Measurement, MeasureError> {
        let before: Vec<_> = self
            .objects
            .iter()
            .map(|o| (o.tracker.state().cloned(), o.tracker.frames()))
            .collect();
        if let Some(c) = calibration {
            for object in &mut self.objects {
                object.tracker.set_tilt_axis_deg(c.tilt_axis_deg());
            }
        }
        let track = |objects: &mut [SessionObject]| -> Vec<Result<PairResult, TrackError>> {
            objects
                .iter_mut()
                .map(|o| o.tracker.process(left, right))
                .collect()
        };
        let outcomes = if threads <= 1 || self.objects.len() < 2 {
            track(&mut self.objects)
        } else {
            let per_thread = self.objects.len().div_ceil(threads);
            std::thread::scope(|scope| {
                let handles: Vec<_> = self
                    .objects
                    .chunks_mut(per_thread)
                    .map(|chunk| scope.spawn(move || track(chunk)))
                    .collect();
                handles
                    .into_iter()
                    .flat_map(|h| h.join().unwrap_or_else(|panic| std::panic::resume_unwind(panic)))
                    .collect()
            })
        };
        let mut objects = Vec::with_capacity(self.objects.len());
        for (object, outcome) in self.objects.iter_mut().zip(outcomes) {
            match outcome {
                Ok(mut result) => {
                    result.frame = self.frames;
                    if let Some((l, r)) = meta {
                        result.apply_metadata(l, r);
                    }
                    result.apply_calibration(calibration, &mut self.meta_watch);
                    objects.push(ObjectResult {
                        name: object.name.clone(),
                        result,
                    });
                }
                Err(error) => {
                    let object = object.name.clone();
                    self.restore(before);
                    return Err(MeasureError { object, error });
                }
            }
        }
        if let Some((object, error)) = same_region(&objects) {
            self.restore(before);
            return Err(MeasureError {
                object,
                error: TrackError::Hint(error),
            });
        }
        let frame = self.frames;
        // Each object's fits' own standard error on this pair, which its
        // tracker keeps as the last pair of its run.
        let fit_stds: Vec<Option<f64>> = self
            .objects
            .iter()
            .map(|o| {
                let last = o.tracker.state().and_then(|s| s.disparity_run.last());
                last.filter(|m| m.frame + 1 == o.tracker.frames())
                    .map(|m| m.std_px)
            })
            .collect();
        let relative = relative_heights(&objects, &fit_stds, calibration);
        self.frames += 1;
        Ok(Measurement {
            frame,
            objects,
            relative,
        })
    }
}

impl Session {
    /// Every object's tracker as it was before a pair (`before`: each one's
    /// state and frame count): a refused pair moves none of them on.
    fn restore(&mut self, before: Vec<(Option<TrackerState>, u64)>) {
        for (o, (state, frames)) in self.objects.iter_mut().zip(before) {
            let params = o.tracker.params().clone();
            o.tracker = StereoTracker::from_state(params, state, frames);
        }
    }
}

/// The first object initialised on this pair whose left outline overlaps an
/// earlier object's (also initialised here, or already tracked) by more
/// than [`SAME_REGION_IOU`], with the error naming the other.
fn same_region(objects: &[ObjectResult]) -> Option<(String, InitError)> {
    let outline = |o: &ObjectResult| o.result.left.as_ref().map(|l| Polygon::new(l.contour.clone()));
    for (k, later) in objects.iter().enumerate() {
        if later.result.status != Status::Initialised {
            continue;
        }
        let Some(b) = outline(later) else { continue };
        for earlier in &objects[..k] {
            let Some(a) = outline(earlier) else { continue };
            let iou = polygon_iou(&a, &b);
            if iou > SAME_REGION_IOU {
                return Some((
                    later.name.clone(),
                    InitError::SameRegion {
                        other: earlier.name.clone(),
                        iou,
                    },
                ));
            }
        }
    }
    None
}

/// Every ordered pair of distinct objects (see the module docs).
/// `fit_stds` holds each object's fits' own standard error on this pair
/// (None: its reported one).
pub fn relative_heights(
    objects: &[ObjectResult],
    fit_stds: &[Option<f64>],
    calibration: Option<&Calibration>,
) -> Vec<Relative> {
    let measured = |r: &PairResult| {
        matches!(r.status, Status::Initialised | Status::Tracked)
            .then_some(())
            .and(r.disparity_px.zip(r.disparity_axis_px))
    };
    let fit_std = |i: usize| {
        fit_stds
            .get(i)
            .copied()
            .flatten()
            .or(objects[i].result.disparity_std_px)
    };
    let mut out = Vec::new();
    for (i, a) in objects.iter().enumerate() {
        for (j, b) in objects.iter().enumerate() {
            if i == j {
                continue;
            }
            let mut rel = Relative {
                from: a.name.clone(),
                to: b.name.clone(),
                disparity_axis_px: None,
                disparity_std_px: None,
                dz_um: None,
                dz_std_um: None,
            };
            if let (Some((da, aa)), Some((db, ab))) = (measured(&a.result), measured(&b.result)) {
                rel.disparity_axis_px = Some(aa - ab);
                let stds = fit_std(i).zip(fit_std(j));
                rel.disparity_std_px = stds.map(|(sa, sb)| sa.hypot(sb));
                if let Some(c) = calibration {
                    let meta = a.result.metadata.as_ref();
                    let std = stds.map_or([f64::NAN; 2], |(sa, sb)| [sa, sb]);
                    if let Ok((dz, dz_std)) = c.dz_for_pair(da, db, std, meta) {
                        rel.dz_um = dz.is_finite().then_some(dz);
                        rel.dz_std_um = dz_std.filter(|_| stds.is_some());
                    }
                }
            }
            out.push(rel);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_checked() {
        for bad in ["", "a b", "n/1", "é", &"x".repeat(65)] {
            assert!(check_object_name(bad).is_err(), "{bad:?}");
        }
        for good in ["needle", "lamella-2", "tip_1.a", &"x".repeat(64)] {
            assert!(check_object_name(good).is_ok(), "{good:?}");
        }
        let two = |a: &str, b: &str| {
            Session::new(
                vec![
                    SessionObject::new(a, TrackerParams::default()),
                    SessionObject::new(b, TrackerParams::default()),
                ],
                0,
            )
        };
        assert_eq!(two("a", "a").err(), Some(SessionError::DuplicateName("a".into())));
        assert!(two("a", "b").is_ok());
        assert_eq!(
            Session::new(Vec::new(), 0).err(),
            Some(SessionError::ObjectCount(0))
        );
        let mut one = Session::single(TrackerParams::default());
        assert_eq!(one.remove("object").err(), Some(SessionError::ObjectCount(0)));
        for i in 1..MAX_OBJECTS {
            one.add(SessionObject::new(format!("o{i}"), TrackerParams::default()))
                .unwrap();
        }
        assert_eq!(
            one.add(SessionObject::new("extra", TrackerParams::default()))
                .err(),
            Some(SessionError::ObjectCount(MAX_OBJECTS + 1))
        );
    }

    #[test]
    fn a_pair_that_fails_for_one_object_moves_none_on() {
        let cfg = crate::synth::SynthConfig {
            frames: 2,
            ..crate::synth::SynthConfig::preset(crate::synth::Preset::Clean, crate::synth::Shape::Sphere, 7)
        };
        let scene = crate::synth::Scene::new(&cfg).unwrap();
        let first = scene.render(0);
        let mut session = Session::new(
            vec![
                SessionObject::new("a", TrackerParams::default()),
                SessionObject::new(
                    "b",
                    TrackerParams {
                        init: crate::init::InitParams {
                            roi: Some([5000, 5000, 40, 40]),
                            ..Default::default()
                        },
                        ..TrackerParams::default()
                    },
                ),
            ],
            0,
        )
        .unwrap();
        let err = session
            .measure(&first.left, &first.right, None, None)
            .unwrap_err();
        assert!(matches!(err.error, TrackError::Hint(_)), "{err}");
        assert_eq!(err.object, "b");
        assert_eq!(session.frames(), 0);
        assert!(session.objects()[0].tracker.state().is_none());
        assert_eq!(session.objects()[0].tracker.frames(), 0);
    }

    /// Tracker parameters with the hints `roi` and `point`.
    fn hinted(roi: Option<[i64; 4]>, point: Option<[f64; 2]>) -> TrackerParams {
        TrackerParams {
            init: crate::init::InitParams {
                roi,
                point,
                ..Default::default()
            },
            ..TrackerParams::default()
        }
    }

    /// Two scenes side by side: one frame with an object in each half.
    fn two_scenes(seeds: [u64; 2]) -> (Vec<crate::synth::Scene>, u32) {
        let scenes: Vec<_> = seeds
            .iter()
            .map(|&seed| {
                let cfg = crate::synth::SynthConfig {
                    frames: 3,
                    ..crate::synth::SynthConfig::preset(
                        crate::synth::Preset::Noisy,
                        crate::synth::Shape::Tip,
                        seed,
                    )
                };
                crate::synth::Scene::new(&cfg).unwrap()
            })
            .collect();
        let width = scenes[0].render(0).left.width;
        (scenes, width)
    }

    fn side_by_side(a: &GrayFrame, b: &GrayFrame) -> GrayFrame {
        let (w, h) = (a.width as usize, a.height as usize);
        let data = (0..h)
            .flat_map(|y| {
                a.data[y * w..(y + 1) * w]
                    .iter()
                    .chain(&b.data[y * w..(y + 1) * w])
                    .copied()
            })
            .collect();
        GrayFrame::new(2 * a.width, a.height, a.bit_depth, data).unwrap()
    }

    /// Issue #65: two objects whose hints resolve to one region (a box and
    /// a point on one tip) are refused on their first pair, naming both,
    /// and neither tracker moves on.
    #[test]
    fn two_objects_on_one_region_are_refused() {
        let (scenes, _) = two_scenes([11, 12]);
        let truth = scenes[0].render(0).truth.left;
        let mut session = Session::new(
            vec![
                SessionObject::new("box", hinted(Some(truth.roi_hint(0.1)), None)),
                SessionObject::new("point", hinted(None, Some(truth.visible_centroid))),
            ],
            0,
        )
        .unwrap();
        let pair = scenes[0].render(0);
        let err = session.measure(&pair.left, &pair.right, None, None).unwrap_err();
        assert_eq!(err.object, "point");
        assert!(
            matches!(&err.error, TrackError::Hint(InitError::SameRegion { other, .. }) if other == "box"),
            "{err}"
        );
        assert_eq!(session.frames(), 0);
        assert!(session.objects().iter().all(|o| o.tracker.state().is_none()));
    }

    #[test]
    fn objects_tracked_side_by_side_measure_as_one_after_the_other() {
        let (scenes, width) = two_scenes([11, 12]);
        let (a, b) = (scenes[0].render(0).truth.left, scenes[1].render(0).truth.left);
        let session = || {
            // One object in each half: from a box in the left one, from a
            // point in the right one.
            let [x, y, w, h] = a.roi_hint(0.1);
            let [px, py] = b.visible_centroid;
            Session::new(
                vec![
                    SessionObject::new("box", hinted(Some([x, y, w, h]), None)),
                    SessionObject::new("point", hinted(None, Some([px + f64::from(width), py]))),
                ],
                0,
            )
            .unwrap()
        };
        let (mut one, mut threaded) = (session(), session());
        for k in 0..3 {
            let (p, q) = (scenes[0].render(k), scenes[1].render(k));
            let (left, right) = (side_by_side(&p.left, &q.left), side_by_side(&p.right, &q.right));
            let a = one.measure_on(&left, &right, None, None, 1).unwrap();
            let b = threaded.measure_on(&left, &right, None, None, 2).unwrap();
            assert_eq!(a.objects.len(), 2);
            for (x, y) in a.objects.iter().zip(&b.objects) {
                assert_eq!(x.name, y.name);
                assert_eq!(x.result.status, y.result.status, "pair {k}, {}", x.name);
                assert_eq!(
                    x.result.disparity_px, y.result.disparity_px,
                    "pair {k}, {}",
                    x.name
                );
                assert_eq!(x.result.disparity_std_px, y.result.disparity_std_px);
                assert!(
                    x.result.disparity_px.is_some(),
                    "pair {k}, {}: {:?}",
                    x.name,
                    x.result.reason
                );
            }
        }
    }
}

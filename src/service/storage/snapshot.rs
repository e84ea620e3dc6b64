//! The stored form of a session's objects: the service's own versioned
//! JSON, read tolerantly, so that a renamed or removed tuning field never
//! makes a stored database unreadable.
//!
//! Two columns of the `sessions` table hold it:
//! - `params`: `{"version": 2, "objects": [{"name", "params"}]}`, the
//!   objects and their tracker parameters (changed by create, PATCH and
//!   the object routes);
//! - `tracker_state`: `{"version": 2, "objects": [{"name", "frames",
//!   "state"}]}`, where each object's tracker stands (changed by every pair).
//!
//! Version 1 (every release before objects) stored one bare
//! `TrackerParams` and one bare `TrackerState`: such a session reads as one
//! object named [`DEFAULT_OBJECT_NAME`].
//!
//! Tolerance. Stored parameters are read field by field over the current
//! defaults: a field the build no longer knows is dropped, one it cannot
//! read takes its default, and the names of both are returned so the
//! caller can say so. A tracker state that no longer reads is dropped:
//! the object initialises again on its next pair (its results stay).

use serde::{Deserialize, Serialize};
use serde_json::Value;

use semdepth_core::fit::Pose;
use semdepth_core::geometry::{HalfPlane, Point};
use semdepth_core::scatter::{DisparityRun, Measured};
use semdepth_core::session::DEFAULT_OBJECT_NAME;
use semdepth_core::tracker::{Phase, TrackerParams, TrackerState, REACQUIRE_PAIRS};

/// Parameters are stored in the API's form ([`crate::service::api::TrackerParams`]).
use crate::service::api::TrackerParams as StoredParams;

/// Version written by this build.
pub const SNAPSHOT_VERSION: u64 = 2;

/// One object of a stored session, as the service keeps it.
#[derive(Clone, Debug, PartialEq)]
pub struct ObjectRecord {
    /// Unique in the session.
    pub name: String,
    /// Its tracker's parameters (hints included).
    pub params: TrackerParams,
    /// Pairs its tracker has processed.
    pub frames: u64,
    /// Where its tracker stands; None before its first pair or after a reset.
    pub tracker_state: Option<TrackerState>,
}

/// A tracker's state as stored: flat fields, each added one read with its
/// default, so that a state written by any release since version 1 reads.
/// The tracker's phase is stored as the flags it was once kept as.
#[derive(Serialize, Deserialize)]
struct StoredState {
    template: Vec<Point>,
    left: StoredPose,
    right: StoredPose,
    reference_contrast: f64,
    first_disparity_axis_px: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    first_disparity_px: Option<Point>,
    width: u32,
    height: u32,
    /// Not [`Phase::Tracking`].
    lost: bool,
    #[serde(default)]
    left_velocity: [f64; 3],
    #[serde(default)]
    left_sector_contrasts: Vec<f64>,
    #[serde(default)]
    right_sector_contrasts: Vec<f64>,
    #[serde(default)]
    left_sector_inner: Vec<f64>,
    #[serde(default)]
    right_sector_inner: Vec<f64>,
    /// Left and right; a state whose lists are not as long as this
    /// build's quantiles reads as one stored before they were kept.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    grey_quantiles: Option<[Vec<f64>; 2]>,
    #[serde(default)]
    template_cuts: Vec<StoredHalfPlane>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    outline: Vec<Point>,
    #[serde(default)]
    prefilter_sigma_px: f64,
    /// [`Phase::Searching`]'s `missed`; [`REACQUIRE_PAIRS`] for
    /// [`Phase::Reinitialising`].
    #[serde(default)]
    missed_searches: u32,
    #[serde(default)]
    refused_inits: u32,
    /// [`TrackerState::uncertain_run`]'s moves (0 outside a run).
    #[serde(default)]
    unverified_move_px: f64,
    /// Whether [`TrackerState::uncertain_run`] is set.
    #[serde(default)]
    uncertain_run: bool,
    #[serde(default)]
    first_disparity_std_px: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    edge_support: Option<f64>,
    /// Not [`Phase::Tracking`]'s `velocity_measured`.
    #[serde(default)]
    unmeasured_velocity: bool,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    disparity_run: Vec<StoredMeasured>,
}

/// A pose as stored.
#[derive(Clone, Copy, Serialize, Deserialize)]
struct StoredPose {
    x: f64,
    y: f64,
    theta: f64,
}

/// A cut of the image border as stored.
#[derive(Clone, Copy, Serialize, Deserialize)]
struct StoredHalfPlane {
    normal: Point,
    offset: f64,
}

/// A pair of a run as stored.
#[derive(Clone, Copy, Serialize, Deserialize)]
struct StoredMeasured {
    frame: u64,
    disparity_px: f64,
    std_px: f64,
}

impl From<Pose> for StoredPose {
    fn from(p: Pose) -> Self {
        Self {
            x: p.x,
            y: p.y,
            theta: p.theta,
        }
    }
}

impl From<StoredPose> for Pose {
    fn from(p: StoredPose) -> Self {
        Self {
            x: p.x,
            y: p.y,
            theta: p.theta,
        }
    }
}

impl From<&TrackerState> for StoredState {
    fn from(s: &TrackerState) -> Self {
        let (lost, missed_searches, unmeasured_velocity) = match s.phase {
            Phase::Tracking { velocity_measured } => (false, 0, !velocity_measured),
            Phase::Searching { missed } => (true, missed, true),
            Phase::Reinitialising => (true, REACQUIRE_PAIRS, true),
        };
        Self {
            template: s.template.clone(),
            left: s.left.into(),
            right: s.right.into(),
            reference_contrast: s.reference_contrast,
            first_disparity_axis_px: s.first_disparity_axis_px,
            first_disparity_px: s.first_disparity_px,
            width: s.width,
            height: s.height,
            lost,
            left_velocity: s.left_velocity,
            left_sector_contrasts: s.left_sector_contrasts.clone(),
            right_sector_contrasts: s.right_sector_contrasts.clone(),
            left_sector_inner: s.left_sector_inner.clone(),
            right_sector_inner: s.right_sector_inner.clone(),
            grey_quantiles: s.grey_quantiles.map(|[l, r]| [l.to_vec(), r.to_vec()]),
            template_cuts: s
                .template_cuts
                .iter()
                .map(|h| StoredHalfPlane {
                    normal: h.normal,
                    offset: h.offset,
                })
                .collect(),
            outline: s.outline.clone(),
            prefilter_sigma_px: s.prefilter_sigma_px,
            missed_searches,
            refused_inits: s.refused_inits,
            unverified_move_px: s.uncertain_run.unwrap_or(0.0),
            uncertain_run: s.uncertain_run.is_some(),
            first_disparity_std_px: s.first_disparity_std_px,
            edge_support: s.edge_support,
            unmeasured_velocity,
            disparity_run: s
                .disparity_run
                .pairs()
                .map(|m| StoredMeasured {
                    frame: m.frame,
                    disparity_px: m.disparity_px,
                    std_px: m.std_px,
                })
                .collect(),
        }
    }
}

impl From<StoredState> for TrackerState {
    fn from(s: StoredState) -> Self {
        let phase = match (s.lost, s.missed_searches) {
            (false, _) => Phase::Tracking {
                velocity_measured: !s.unmeasured_velocity,
            },
            (true, missed) if missed < REACQUIRE_PAIRS => Phase::Searching { missed },
            (true, _) => Phase::Reinitialising,
        };
        Self {
            template: s.template,
            left: s.left.into(),
            right: s.right.into(),
            reference_contrast: s.reference_contrast,
            first_disparity_axis_px: s.first_disparity_axis_px,
            first_disparity_px: s.first_disparity_px,
            width: s.width,
            height: s.height,
            phase,
            left_velocity: s.left_velocity,
            left_sector_contrasts: s.left_sector_contrasts,
            right_sector_contrasts: s.right_sector_contrasts,
            left_sector_inner: s.left_sector_inner,
            right_sector_inner: s.right_sector_inner,
            grey_quantiles: s
                .grey_quantiles
                .and_then(|[l, r]| Some([l.try_into().ok()?, r.try_into().ok()?])),
            template_cuts: s
                .template_cuts
                .into_iter()
                .map(|h| HalfPlane {
                    normal: h.normal,
                    offset: h.offset,
                })
                .collect(),
            outline: s.outline,
            prefilter_sigma_px: s.prefilter_sigma_px,
            refused_inits: s.refused_inits,
            uncertain_run: s.uncertain_run.then_some(s.unverified_move_px),
            first_disparity_std_px: s.first_disparity_std_px,
            edge_support: s.edge_support,
            disparity_run: DisparityRun::from_pairs(s.disparity_run.into_iter().map(|m| Measured {
                frame: m.frame,
                disparity_px: m.disparity_px,
                std_px: m.std_px,
            })),
        }
    }
}

#[derive(Serialize, Deserialize)]
struct Definitions {
    version: u64,
    objects: Vec<Definition>,
}

#[derive(Serialize, Deserialize)]
struct Definition {
    name: String,
    params: Value,
}

#[derive(Serialize, Deserialize)]
struct States {
    version: u64,
    objects: Vec<StateOf>,
}

#[derive(Serialize, Deserialize)]
struct StateOf {
    name: String,
    frames: u64,
    state: Option<Value>,
}

/// The `params` column for `objects`.
pub fn encode_definitions(objects: &[ObjectRecord]) -> Result<String, serde_json::Error> {
    let objects = objects
        .iter()
        .map(|o| {
            Ok(Definition {
                name: o.name.clone(),
                params: serde_json::to_value(StoredParams::from(o.params.clone()))?,
            })
        })
        .collect::<Result<_, serde_json::Error>>()?;
    serde_json::to_string(&Definitions {
        version: SNAPSHOT_VERSION,
        objects,
    })
}

/// The `tracker_state` column for `objects`.
pub fn encode_states(objects: &[ObjectRecord]) -> Result<String, serde_json::Error> {
    let objects = objects
        .iter()
        .map(|o| {
            Ok(StateOf {
                name: o.name.clone(),
                frames: o.frames,
                state: o
                    .tracker_state
                    .as_ref()
                    .map(|s| serde_json::to_value(StoredState::from(s)))
                    .transpose()?,
            })
        })
        .collect::<Result<_, serde_json::Error>>()?;
    serde_json::to_string(&States {
        version: SNAPSHOT_VERSION,
        objects,
    })
}

/// [`encode_states`], checked to read back: every state written reads as
/// a tracker state again (a non-finite number is written as `null` and
/// would not). The error names the object.
pub fn encode_states_checked(objects: &[ObjectRecord]) -> Result<String, String> {
    let text = encode_states(objects).map_err(|e| e.to_string())?;
    let read: States = serde_json::from_str(&text).map_err(|e| e.to_string())?;
    for (object, stored) in objects.iter().zip(read.objects) {
        if let (Some(_), Some(state)) = (&object.tracker_state, stored.state) {
            serde_json::from_value::<StoredState>(state)
                .map_err(|e| format!("object {:?}: {e}", object.name))?;
        }
    }
    Ok(text)
}

/// What reading a stored session's objects found.
#[derive(Debug, Default)]
pub struct Decoded {
    /// The objects.
    pub objects: Vec<ObjectRecord>,
    /// What could not be kept (fields dropped or reset, states dropped),
    /// for a warning; empty when everything read as it was written.
    pub notes: Vec<String>,
}

/// Reads the two columns of a session that has seen `frames` pairs. An
/// error (text that is not JSON, a version this build does not know, no
/// objects) says what is wrong with which column.
pub fn decode(params: &str, states: Option<&str>, frames: u64) -> Result<Decoded, String> {
    let params: Value = serde_json::from_str(params).map_err(|e| format!("column params: {e}"))?;
    let states: Option<Value> = states
        .map(serde_json::from_str)
        .transpose()
        .map_err(|e| format!("column tracker_state: {e}"))?;
    let mut out = Decoded::default();
    match version_of(&params) {
        None => {
            // Version 1: one bare TrackerParams, one bare TrackerState.
            let params = lenient_params(params, DEFAULT_OBJECT_NAME, &mut out.notes);
            let tracker_state = states.and_then(|s| lenient_state(s, DEFAULT_OBJECT_NAME, &mut out.notes));
            out.objects.push(ObjectRecord {
                name: DEFAULT_OBJECT_NAME.into(),
                params,
                frames,
                tracker_state,
            });
        }
        Some(SNAPSHOT_VERSION) => {
            let defs: Definitions =
                serde_json::from_value(params).map_err(|e| format!("column params: {e}"))?;
            let states: Vec<StateOf> = match states {
                Some(s) => {
                    let s: States = serde_json::from_value(s).map_err(|e| format!("column tracker_state: {e}"))?;
                    s.objects
                }
                None => Vec::new(),
            };
            if defs.objects.is_empty() {
                return Err("column params: no objects".into());
            }
            for def in defs.objects {
                let params = lenient_params(def.params, &def.name, &mut out.notes);
                let stored = states.iter().find(|s| s.name == def.name);
                let tracker_state = stored
                    .and_then(|s| s.state.clone())
                    .and_then(|s| lenient_state(s, &def.name, &mut out.notes));
                out.objects.push(ObjectRecord {
                    frames: stored.map_or(0, |s| s.frames),
                    name: def.name,
                    params,
                    tracker_state,
                });
            }
        }
        Some(v) => {
            return Err(format!(
                "column params: snapshot version {v} (this build reads 1..={SNAPSHOT_VERSION}; it was written by a newer semdepth)"
            ))
        }
    }
    Ok(out)
}

/// The `version` of a stored snapshot; None for version 1 (no envelope).
fn version_of(v: &Value) -> Option<u64> {
    match v.get("version") {
        Some(version) if v.get("objects").is_some() => Some(version.as_u64().unwrap_or(u64::MAX)),
        _ => None,
    }
}

/// Stored parameters over the current defaults, field by field (see the
/// module docs); what could not be kept is noted.
fn lenient_params(stored: Value, object: &str, notes: &mut Vec<String>) -> TrackerParams {
    if let Some(p) = valid_params(stored.clone()) {
        return p;
    }
    let mut current = serde_json::to_value(StoredParams::default()).unwrap_or(Value::Null);
    overlay(&mut current, &stored, "", object, notes);
    match valid_params(current) {
        Some(p) => p,
        _ => {
            notes.push(format!(
                "object {object:?}: stored parameters unreadable, defaults used"
            ));
            TrackerParams::default()
        }
    }
}

/// Parameters as stored ([`StoredParams`]) that read and are valid.
fn valid_params(stored: Value) -> Option<TrackerParams> {
    let params: TrackerParams = serde_json::from_value::<StoredParams>(stored).ok()?.into();
    params.validate().is_ok().then_some(params)
}

/// Copies `stored`'s members onto `target` where `target` has them and the
/// result still reads as valid parameters; objects recursively.
fn overlay(target: &mut Value, stored: &Value, path: &str, object: &str, notes: &mut Vec<String>) {
    let Value::Object(members) = stored else {
        return;
    };
    for (key, value) in members {
        let field = if path.is_empty() {
            key.clone()
        } else {
            format!("{path}.{key}")
        };
        let Some(slot) = target.get(key).cloned() else {
            notes.push(format!(
                "object {object:?}: stored field {field} is no longer known (dropped)"
            ));
            continue;
        };
        if slot.is_object() && value.is_object() {
            let mut sub = slot;
            overlay(&mut sub, value, &field, object, notes);
            target[key.as_str()] = sub;
            continue;
        }
        let before = std::mem::replace(&mut target[key.as_str()], value.clone());
        let reads = valid_params(root_of(target, path)).is_some();
        if !reads {
            target[key.as_str()] = before;
            notes.push(format!(
                "object {object:?}: stored field {field} no longer reads (default used)"
            ));
        }
    }
}

/// While overlaying a nested object only the nested part is at hand: it is
/// checked inside default parameters at its path.
fn root_of(part: &Value, path: &str) -> Value {
    let mut root = serde_json::to_value(StoredParams::default()).unwrap_or(Value::Null);
    if path.is_empty() {
        return part.clone();
    }
    let mut slot = &mut root;
    for key in path.split('.') {
        slot = &mut slot[key];
    }
    *slot = part.clone();
    root
}

/// A stored tracker state, or None (noted) when it no longer reads.
fn lenient_state(stored: Value, object: &str, notes: &mut Vec<String>) -> Option<TrackerState> {
    if stored.is_null() {
        return None;
    }
    match serde_json::from_value::<StoredState>(stored) {
        Ok(s) => Some(s.into()),
        Err(e) => {
            notes.push(format!(
                "object {object:?}: stored tracker state no longer reads ({e}); it initialises again on its next pair"
            ));
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn object(name: &str) -> ObjectRecord {
        ObjectRecord {
            name: name.into(),
            params: TrackerParams {
                max_disparity_px: 40.0,
                ..TrackerParams::default()
            },
            frames: 3,
            tracker_state: None,
        }
    }

    #[test]
    fn snapshots_round_trip() {
        let objects = vec![object("needle"), object("lamella")];
        let params = encode_definitions(&objects).unwrap();
        let states = encode_states(&objects).unwrap();
        let decoded = decode(&params, Some(&states), 3).unwrap();
        assert_eq!(decoded.objects, objects);
        assert!(decoded.notes.is_empty(), "{:?}", decoded.notes);
    }

    #[test]
    fn version_1_reads_as_one_object() {
        let params = serde_json::to_string(&StoredParams::from(object("x").params)).unwrap();
        let decoded = decode(&params, None, 7).unwrap();
        assert_eq!(decoded.objects.len(), 1);
        assert_eq!(decoded.objects[0].name, DEFAULT_OBJECT_NAME);
        assert_eq!(decoded.objects[0].frames, 7);
        assert_eq!(decoded.objects[0].params.max_disparity_px, 40.0);
    }

    #[test]
    fn renamed_and_broken_fields_are_dropped_and_named() {
        // A field renamed since (rigid.search_radius), one of a wrong type,
        // one out of range; the rest is kept.
        let stored = r#"{"max_disparity_px": 40, "rigid": {"search_radius": 9, "coarse_step_px": "big",
            "max_evaluations": 900}, "min_contrast_ratio": -3, "no_such_field": true}"#;
        let decoded = decode(stored, None, 0).unwrap();
        let p = &decoded.objects[0].params;
        assert_eq!(p.max_disparity_px, 40.0);
        assert_eq!(p.rigid.max_evaluations, 900);
        let d = TrackerParams::default();
        assert_eq!(p.rigid.coarse_step_px, d.rigid.coarse_step_px);
        assert_eq!(p.min_contrast_ratio, d.min_contrast_ratio);
        let notes = decoded.notes.join("\n");
        for field in [
            "rigid.search_radius",
            "rigid.coarse_step_px",
            "min_contrast_ratio",
            "no_such_field",
        ] {
            assert!(notes.contains(field), "{field} not noted: {notes}");
        }
        // A state that no longer reads is dropped, not an error.
        let decoded = decode(stored, Some(r#"{"templ": []}"#), 4).unwrap();
        assert_eq!(decoded.objects[0].tracker_state, None);
        assert!(decoded.notes.iter().any(|n| n.contains("tracker state")));
    }

    /// The first pair's grey deciles are kept; lists of another length
    /// (a build with other quantiles) read as a state stored before they
    /// were kept, not as an error.
    #[test]
    fn grey_quantiles_round_trip_and_other_lengths_read_as_none() {
        let state = crate::service::storage::tests::tracker_state(1);
        assert!(state.grey_quantiles.is_some());
        let mut stored = serde_json::to_value(StoredState::from(&state)).unwrap();
        let back: TrackerState = serde_json::from_value::<StoredState>(stored.clone())
            .unwrap()
            .into();
        assert_eq!(back.grey_quantiles, state.grey_quantiles);
        stored["grey_quantiles"] = serde_json::json!([[60.0, 70.0, 80.0], [60.0, 70.0, 80.0]]);
        let back: TrackerState = serde_json::from_value::<StoredState>(stored.clone())
            .unwrap()
            .into();
        assert_eq!(back.grey_quantiles, None);
        assert_eq!(
            TrackerState {
                grey_quantiles: None,
                ..back
            },
            TrackerState {
                grey_quantiles: None,
                ..state
            }
        );
    }

    #[test]
    fn what_cannot_be_read_is_an_error_naming_the_column() {
        assert!(decode("nope", None, 0).unwrap_err().contains("params"));
        assert!(decode("{}", Some("[garbage"), 0)
            .unwrap_err()
            .contains("tracker_state"));
        let future = r#"{"version": 9, "objects": []}"#;
        assert!(decode(future, None, 0).unwrap_err().contains("version 9"));
    }
}

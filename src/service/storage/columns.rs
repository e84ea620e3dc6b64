//! The JSON columns as written: each checked to read back before it is
//! stored.

use super::snapshot::{encode_definitions, encode_states_checked, ObjectRecord};
use crate::service::api::CalibrationBody;
use semdepth_core::calib::Calibration;

use super::{CalibrationRecord, StorageError};

pub(super) fn calibration_json(rec: &CalibrationRecord) -> Result<String, StorageError> {
    let body = serde_json::to_string(&CalibrationBody::from(&rec.calibration))
        .map_err(|e| StorageError::Unstorable(format!("calibration {:?}: body: {e}", rec.id)))?;
    // The body is validated again when read: refuse now what would not read back.
    calibration_of(&body).map_err(|e| {
        StorageError::Unstorable(format!("calibration {:?}: body would not read back: {e}", rec.id))
    })?;
    Ok(body)
}

/// The calibration a stored body holds, rebuilt from its parameters.
pub(super) fn calibration_of(body: &str) -> Result<Calibration, String> {
    let body: CalibrationBody = serde_json::from_str(body).map_err(|e| e.to_string())?;
    Calibration::try_from(body).map_err(|e| e.to_string())
}

/// The `params` and `tracker_state` columns of a session's objects,
/// checked to read back as they are (JSON has no NaN or infinity:
/// serde_json writes them as `null`, which would not read back).
pub(super) fn snapshot_checked(
    objects: &[ObjectRecord],
    kind: &str,
    id: &str,
) -> Result<(String, String), StorageError> {
    let params = encode_definitions(objects)
        .map_err(|e| StorageError::Unstorable(format!("{kind} {id:?}: params: {e}")))?;
    match super::snapshot::decode(&params, None, 0) {
        Ok(d) if d.notes.is_empty() => {}
        Ok(d) => {
            return Err(StorageError::Unstorable(format!(
                "{kind} {id:?}: params would not read back (non-finite number?): {}",
                d.notes.join("; ")
            )))
        }
        Err(e) => return Err(StorageError::Unstorable(format!("{kind} {id:?}: {e}"))),
    }
    Ok((params, states_checked(objects, kind, id)?))
}

/// The `tracker_state` column alone (stored after every pair), checked to
/// read back as [`snapshot_checked`] checks it.
pub(super) fn states_checked(objects: &[ObjectRecord], kind: &str, id: &str) -> Result<String, StorageError> {
    encode_states_checked(objects).map_err(|e| {
        StorageError::Unstorable(format!(
            "{kind} {id:?}: tracker_state would not read back (non-finite number?): {e}"
        ))
    })
}

pub(super) fn to_i64(value: u64, kind: &str, id: &str, what: &str) -> Result<i64, StorageError> {
    i64::try_from(value).map_err(|_| {
        StorageError::Unstorable(format!(
            "{kind} {id:?}: {what} = {value} exceeds SQLite's integer range"
        ))
    })
}

pub(super) fn from_i64(value: i64, kind: &str, id: &str, what: &str) -> Result<u64, StorageError> {
    u64::try_from(value)
        .map_err(|_| StorageError::Corrupt(format!("{kind} {id:?}: {what} is negative ({value})")))
}

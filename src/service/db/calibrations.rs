//! The calibrations a running service holds: the table in memory, written
//! through to storage before a change is answered, with one refit at a time.

use std::collections::BTreeMap;
use std::sync::RwLock;

use tokio::sync::Mutex;

use semdepth_core::calib::{CalibError, Calibration};

use crate::service::error::ApiError;
use crate::service::stamp::{new_id, now_rfc3339};
use crate::service::storage::{CalibrationRecord, Storage};

/// The calibrations by id, and the lock that serialises their refits.
pub struct Calibrations {
    table: RwLock<BTreeMap<String, CalibrationRecord>>,
    /// Serialises read-modify-write of a calibration (changing its samples):
    /// two concurrent changes must not both start from the same samples.
    writes: Mutex<()>,
    storage: Storage,
}

impl Calibrations {
    /// The table of `restored` calibrations.
    pub fn new(restored: Vec<CalibrationRecord>, storage: Storage) -> Self {
        Self {
            table: RwLock::new(restored.into_iter().map(|c| (c.id.clone(), c)).collect()),
            writes: Mutex::new(()),
            storage,
        }
    }

    fn read(&self) -> Result<std::sync::RwLockReadGuard<'_, BTreeMap<String, CalibrationRecord>>, ApiError> {
        self.table
            .read()
            .map_err(|_| ApiError::internal("calibration table lock poisoned"))
    }

    fn write(
        &self,
    ) -> Result<std::sync::RwLockWriteGuard<'_, BTreeMap<String, CalibrationRecord>>, ApiError> {
        self.table
            .write()
            .map_err(|_| ApiError::internal("calibration table lock poisoned"))
    }

    /// The calibration with this id, or 404.
    pub fn get(&self, id: &str) -> Result<CalibrationRecord, ApiError> {
        self.read()?
            .get(id)
            .cloned()
            .ok_or_else(|| ApiError::calibration_not_found(id))
    }

    /// The calibration for computing z and its version, if the id names one.
    pub fn model(&self, id: Option<&str>) -> Option<(Calibration, u64)> {
        let id = id?;
        let table = self.table.read().ok()?;
        table.get(id).map(|r| (r.calibration.clone(), r.version))
    }

    /// Every calibration, oldest first (UUIDv7 ids sort in creation order).
    pub fn all(&self) -> Result<Vec<CalibrationRecord>, ApiError> {
        Ok(self.read()?.values().cloned().collect())
    }

    /// Version `version` of calibration `id` as it was, or 404 naming the
    /// versions there are.
    pub async fn version(&self, id: &str, version: u64) -> Result<CalibrationRecord, ApiError> {
        let current = self.get(id)?;
        let stored = if (1..=current.version).contains(&version) {
            self.storage.calibration_version(id, version).await?
        } else {
            None
        };
        stored.ok_or_else(|| {
            ApiError::NotFound(
                "calibration_version_not_found",
                format!(
                    "calibration {id:?} has no version {version} (expected 1..={})",
                    current.version
                ),
            )
        })
    }

    /// Stores a new calibration (version 1) and holds it.
    pub async fn create(
        &self,
        name: Option<String>,
        calibration: Calibration,
    ) -> Result<CalibrationRecord, ApiError> {
        let now = now_rfc3339();
        let record = CalibrationRecord {
            id: new_id("c"),
            name,
            calibration,
            created_at: now.clone(),
            updated_at: now,
            version: 1,
        };
        self.storage.insert_calibration(record.clone()).await?;
        self.write()?.insert(record.id.clone(), record.clone());
        Ok(record)
    }

    /// Deletes calibration `id` from storage and the table; 404 when unknown.
    pub async fn remove(&self, id: &str) -> Result<(), ApiError> {
        if !self.storage.delete_calibration(id).await? {
            return Err(ApiError::calibration_not_found(id));
        }
        self.write()?.remove(id);
        Ok(())
    }

    /// Changes the samples of the fitted calibration `id` by `change` (which
    /// refits) and stores it as the next version; on any error it stays as
    /// it was. 409 `not_a_fit_calibration` for a geometric one.
    pub async fn refit(
        &self,
        id: &str,
        change: impl FnOnce(&mut Calibration) -> Result<(), CalibError>,
    ) -> Result<CalibrationRecord, ApiError> {
        let _guard = self.writes.lock().await;
        let mut record = self.get(id)?;
        if !record.calibration.is_fit() {
            return Err(ApiError::conflict(
                "not_a_fit_calibration",
                format!(
                    "calibration {id:?} is geometric (expected a \"fit\" calibration, whose samples can change)"
                ),
            ));
        }
        let mut calibration = record.calibration.clone();
        change(&mut calibration)?;
        record.calibration = calibration;
        record.updated_at = now_rfc3339();
        record.version += 1;
        if !self.storage.update_calibration(record.clone()).await? {
            return Err(ApiError::calibration_not_found(id));
        }
        self.write()?.insert(record.id.clone(), record.clone());
        Ok(record)
    }
}

//! The memory budget for work in flight: request bodies as they are read,
//! WebSocket messages waiting for processing, and the images decoded from
//! them (`--max-inflight-mib`). A request that does not fit is answered 503
//! `busy` with `Retry-After` before its body is read; a stream that does not
//! fit waits, and stops reading its socket meanwhile (TCP back-pressure).
//! Without it, concurrent large uploads grow the process past any memory
//! limit (BENCHMARKS.md).

use std::sync::Arc;

use tokio::sync::{OwnedSemaphorePermit, Semaphore, TryAcquireError};

use super::error::{ApiError, RETRY_AFTER_S};

/// Bytes held for one decoded pixel of a pair's two images: the decoder's
/// own buffer (up to 16 bits) and the 16-bit frame it becomes, per image.
pub const DECODED_BYTES_PER_PIXEL: usize = 2 * (2 + 2);

/// Shared byte budget, counted in KiB.
#[derive(Clone)]
pub struct MemoryBudget {
    kib: Arc<Semaphore>,
    total_kib: u32,
}

/// Bytes of the budget held until dropped.
#[derive(Debug)]
pub struct Reservation {
    _permit: Option<OwnedSemaphorePermit>,
}

impl MemoryBudget {
    /// A budget of `bytes` (at least 1 KiB).
    pub fn new(bytes: usize) -> Self {
        let total_kib = u32::try_from(bytes.div_ceil(1024)).unwrap_or(u32::MAX).max(1);
        Self {
            kib: Arc::new(Semaphore::new(total_kib as usize)),
            total_kib,
        }
    }

    /// KiB for `bytes`; a request larger than the whole budget takes all of
    /// it (it then runs alone).
    fn kib_for(&self, bytes: usize) -> u32 {
        u32::try_from(bytes.div_ceil(1024))
            .unwrap_or(u32::MAX)
            .min(self.total_kib)
    }

    /// Bytes in use now.
    pub fn used_bytes(&self) -> u64 {
        u64::from(self.total_kib).saturating_sub(self.kib.available_permits() as u64) * 1024
    }

    /// Holds `bytes` if they are free now, else 503 `busy` naming `what`.
    pub fn try_reserve(&self, bytes: usize, what: &str) -> Result<Reservation, ApiError> {
        let kib = self.kib_for(bytes);
        if kib == 0 {
            return Ok(Reservation { _permit: None });
        }
        match self.kib.clone().try_acquire_many_owned(kib) {
            Ok(permit) => Ok(Reservation { _permit: Some(permit) }),
            Err(TryAcquireError::NoPermits) => Err(ApiError::Busy(format!(
                "{what} needs {:.1} MiB and {:.1} of the {:.0} MiB for work in flight are in use (--max-inflight-mib); retry in {RETRY_AFTER_S} s",
                bytes as f64 / 1048576.0,
                self.used_bytes() as f64 / 1048576.0,
                f64::from(self.total_kib) / 1024.0
            ))),
            Err(TryAcquireError::Closed) => Err(ApiError::shutting_down()),
        }
    }

    /// Holds `bytes`, waiting until they are free.
    pub async fn reserve(&self, bytes: usize) -> Result<Reservation, ApiError> {
        let kib = self.kib_for(bytes);
        if kib == 0 {
            return Ok(Reservation { _permit: None });
        }
        self.kib
            .clone()
            .acquire_many_owned(kib)
            .await
            .map(|permit| Reservation {
                _permit: Some(permit),
            })
            .map_err(|_| ApiError::shutting_down())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn reservations_hold_bytes_until_dropped() {
        let budget = MemoryBudget::new(10 << 20);
        let a = budget.try_reserve(6 << 20, "a body").unwrap();
        assert_eq!(budget.used_bytes(), 6 << 20);
        let e = budget.try_reserve(6 << 20, "a body").unwrap_err();
        assert_eq!((e.status().as_u16(), e.code()), (503, "busy"));
        let message = e.parts().1;
        assert!(
            message.contains("6.0 MiB") && message.contains("of the 10 MiB"),
            "{message}"
        );
        drop(a);
        assert_eq!(budget.used_bytes(), 0);
        // Larger than the whole budget: takes all of it, alone.
        let all = budget.reserve(64 << 20).await.unwrap();
        assert_eq!(budget.used_bytes(), 10 << 20);
        assert!(budget.try_reserve(1, "a byte").is_err());
        drop(all);
        assert!(budget.try_reserve(0, "nothing").is_ok());
    }
}
